/* What the generic FMI 2.0 glue (fmi2_glue.c) and the FMU's block share: the instance, its plain-struct state,
 * logging, and the block interface. A block is what the FMU computes between communication points:
 *   plant.c       the model x' = F(x) integrated by an embedded solver (every scene's FMU),
 *   controller.c  a sampled-data controller (the drive controller FMU).
 * The generated cedra_vars.h says which (CEDRA_CONTROLLER) and gives the sizes; the block's own state lives in
 * `block_state` (plant.h or controller.h), a plain struct inside cedra_state, so FMU state get/set/serialize
 * stay copies of one struct. */
#ifndef CEDRA_GLUE_H
#define CEDRA_GLUE_H

#include <stddef.h>
#include <stdint.h>

#include "fmi2Functions.h"

#include "cedra_vars.h"

#define DIM(n) ((n) > 0 ? (n) : 1)
#define MSG_LEN 512

#if CEDRA_CONTROLLER
#include "controller.h"
#else
#include "plant.h"
#endif

enum phase {
    PH_INSTANTIATED = 1 << 0,
    PH_INIT = 1 << 1,
    PH_STEP_COMPLETE = 1 << 2,
    PH_STEP_FAILED = 1 << 3,    /* a step was discarded: fmi2Terminated is true */
    PH_TERMINATED = 1 << 4,
};

enum log_cat { CAT_EVENTS, CAT_WARNING, CAT_DISCARD, CAT_ERROR, CAT_FATAL, CAT_ALL, N_CATS };

typedef struct {
    unsigned int magic;
    unsigned int size;
    char guid[64];
    int phase;
    double time;
    double start_time;
    double last_good_time;
    int terminated;                 /* fmi2Terminated status */
    int outputs_valid;              /* y agrees with the current settings */
    double inp[DIM(CEDRA_NI)];
    double par[DIM(CEDRA_NP)];
    double y[DIM(CEDRA_NY)];
    block_state b;                  /* the block's own state (plant.h, controller.h) */
    uint64_t checksum;              /* of a serialized state: FNV-1a over its bytes with this field zero */
} cedra_state;

typedef struct block_ws block_ws;   /* the block's scratch memory: not FMU state */

typedef struct {
    cedra_state s;
    char *name;
    fmi2CallbackLogger logger;
    fmi2CallbackAllocateMemory alloc;
    fmi2CallbackFreeMemory free;
    fmi2ComponentEnvironment env;
    int log_on[N_CATS];
    block_ws *ws;
    char msg[2 * MSG_LEN];          /* a block's reason for a refused or discarded step */
} instance;

/* sends a message to the importer's logger (fmi2OK messages only where debug logging is on for the category) */
void log_msg(instance *c, fmi2Status status, int cat, const char *fmt, ...);

/* The smallest step the FMU resolves at time t: 1e-12 max(1, |t|) (the embedded solvers use the same). */
double time_resolution(double t);
/* 1 if all n values are finite */
int all_finite(const double *v, int n);

/* ---------------------------------------------------------------------------------- the block's side */

/* fmi2Instantiate: allocate c->ws (c->alloc) and read resources; 0, or 1 (logged, c->ws may be partly made) */
int block_instantiate(instance *c, const char *resource_location);
/* fmi2FreeInstance (also after a failed block_instantiate) */
void block_free(instance *c);
/* the block state's defaults (from the variable table's start values) */
void block_defaults(cedra_state *s);
/* value of a variable of one of the block's own kinds; 0, or 1 if v is not of the block's kinds */
int block_value(const cedra_state *s, const cedra_var *v, double *out);
/* store a checked value of one of the block's kinds (the glue has checked type, causality, phase and range) */
void block_store(cedra_state *s, const cedra_var *v, double d);
/* the importer's tolerance from fmi2SetupExperiment (already checked: > 0, finite) */
void block_tolerance(instance *c, double tolerance);
/* s->y for the current settings in initialization mode (then outputs_valid); 0, or 1 (logged, state unchanged) */
int block_outputs(instance *c, const char *fn);
/* fmi2ExitInitializationMode: the start state; 0, or 1 (logged, state unchanged) */
int block_initialize(instance *c, const char *fn);
/* 1 if fmi2DoStep(t, h) cannot be done within the block's bounds (reason in c->msg; nothing changed), else 0 */
int block_refuse_step(instance *c, double t, double h);
/* integrate or sample from t to t + h: fmi2OK with everything done (s->y updated), or fmi2Discard with the
 * reason in c->msg and the block's state back at t */
fmi2Status block_step(instance *c, double t, double h);
/* NULL if a state's block part is one the block could have made, else the reason (written into buf) */
const char *block_state_problem(instance *c, const cedra_state *st, char *buf, size_t len);

#endif
