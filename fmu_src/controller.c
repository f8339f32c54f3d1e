/* The controller block (glue.h): a sampled-data block. Sample k, at t_k = start_time + k * period (the parameter
 * par[CEDRA_PERIOD_PAR]), evaluates the generated cedra_sample(inp, par, xd) -> (y, xd_next) on the inputs set at
 * that moment and holds its outputs y until the next sample.
 *
 * When a sample is taken: sample 0 in fmi2ExitInitializationMode (from the inputs set during initialization);
 * fmi2DoStep(t, h) takes every sample in (t, t + h] from the inputs set before the call (zero-order hold of the
 * inputs over the step), so after the step the outputs are those of the last sample at or before t + h. A master
 * that steps the plant first and then the controller with the plant's new outputs (Gauss-Seidel) therefore
 * applies u(t) = C(y(t)) over [t, t + h], exactly the main job's loop; a master that steps both from the
 * same outputs (Jacobi) applies C(y(t - h)): one communication step of delay. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "cedra_model.h"
#include "glue.h"

#define ND CEDRA_ND
#define MAX_SAMPLES_PER_STEP 1000000L   /* ~1 s of sampling: a bound on one call's cost */
#define SAMPLE_TOL 1e-9                 /* relative to the period: a sample at t + h up to rounding is in the step */

struct block_ws {
    const double *arg[cedra_sample_SZ_ARG > 0 ? cedra_sample_SZ_ARG : 1];
    double *res[cedra_sample_SZ_RES > 0 ? cedra_sample_SZ_RES : 1];
    long long iw[cedra_sample_SZ_IW > 0 ? cedra_sample_SZ_IW : 1];
    double w[cedra_sample_SZ_W > 0 ? cedra_sample_SZ_W : 1];
    double y[DIM(CEDRA_NY)];
    double xd[ND > 0 ? ND : 1];
};

int block_instantiate(instance *c, const char *resource_location) {
    (void)resource_location;
    c->ws = (block_ws *)c->alloc(1, sizeof(block_ws));
    if (!c->ws) {
        log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: out of memory");
        return 1;
    }
    return 0;
}

void block_free(instance *c) {
    if (c->ws) c->free(c->ws);
    c->ws = NULL;
}

void block_defaults(cedra_state *s) { memset(&s->b, 0, sizeof s->b); }

int block_value(const cedra_state *s, const cedra_var *v, double *out) {
    (void)s, (void)v, (void)out;
    return 1;                           /* the controller has no variables beyond parameters, inputs, outputs */
}

void block_store(cedra_state *s, const cedra_var *v, double d) { (void)s, (void)v, (void)d; }

void block_tolerance(instance *c, double tolerance) {
    log_msg(c, fmi2OK, CAT_EVENTS, "fmi2SetupExperiment: tolerance %g not used (a sampled controller has no "
            "solver)", tolerance);
}

static double period(const cedra_state *s) { return s->par[CEDRA_PERIOD_PAR]; }

/* one sample from the current inputs and the discrete state xd: c->ws->y and c->ws->xd; 0, or 1 (reason in msg) */
static int sample(instance *c, const double *xd) {
    block_ws *w = c->ws;
    w->arg[0] = c->s.inp;
    w->arg[1] = c->s.par;
    w->arg[2] = xd;
    w->res[0] = w->y;
    w->res[1] = w->xd;
    if (cedra_sample(w->arg, w->res, w->iw, w->w, 0)) {
        snprintf(c->msg, sizeof c->msg, "the controller's sample function failed");
        return 1;
    }
    for (int i = 0; i < CEDRA_NY; i++)
        if (!isfinite(w->y[i])) {
            snprintf(c->msg, sizeof c->msg, "the controller's output %s is not finite", CEDRA_Y_NAMES[i]);
            return 1;
        }
    for (int i = 0; i < ND; i++)
        if (!isfinite(w->xd[i])) {
            snprintf(c->msg, sizeof c->msg, "the controller's state is not finite");
            return 1;
        }
    return 0;
}

int block_outputs(instance *c, const char *fn) {
    if (c->s.outputs_valid) return 0;
    if (sample(c, c->s.b.xd)) {         /* a look at sample 0 without taking it: xd stays */
        log_msg(c, fmi2Error, CAT_ERROR, "%s: %s", fn, c->msg);
        return 1;
    }
    memcpy(c->s.y, c->ws->y, sizeof(double) * CEDRA_NY);
    c->s.outputs_valid = 1;
    return 0;
}

int block_initialize(instance *c, const char *fn) {
    cedra_state *s = &c->s;
    if (sample(c, s->b.xd)) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: sample 0: %s", fn, c->msg);
        return 1;
    }
    memcpy(s->y, c->ws->y, sizeof(double) * CEDRA_NY);
    memcpy(s->b.xd, c->ws->xd, sizeof(double) * ND);
    s->b.taken = 1;
    s->outputs_valid = 1;
    return 0;
}

/* the index of the last sample at or before t (up to rounding) */
static double last_sample_at(const cedra_state *s, double t) {
    return floor((t - s->start_time) / period(s) + SAMPLE_TOL);
}

int block_refuse_step(instance *c, double t, double h) {
    double n = last_sample_at(&c->s, t + h) + 1 - (double)c->s.b.taken;
    if (n > (double)MAX_SAMPLES_PER_STEP) {
        snprintf(c->msg, sizeof c->msg, "the communication step of %g s holds %.3g samples of ctrl.period = %g s, "
                 "more than %ld", h, n, period(&c->s), MAX_SAMPLES_PER_STEP);
        return 1;
    }
    (void)t;
    return 0;
}

fmi2Status block_step(instance *c, double t, double h) {
    cedra_state *s = &c->s;
    block_state saved = s->b;
    double y_saved[DIM(CEDRA_NY)];
    (void)t;
    memcpy(y_saved, s->y, sizeof y_saved);
    for (long k = s->b.taken; (double)k <= last_sample_at(s, t + h); k++) {
        if (sample(c, s->b.xd)) {
            s->b = saved;               /* back at t: state and outputs as they were */
            memcpy(s->y, y_saved, sizeof y_saved);
            return fmi2Discard;
        }
        memcpy(s->y, c->ws->y, sizeof(double) * CEDRA_NY);
        memcpy(s->b.xd, c->ws->xd, sizeof(double) * ND);
        s->b.taken = k + 1;
    }
    return fmi2OK;
}

const char *block_state_problem(instance *c, const cedra_state *st, char *buf, size_t len) {
    (void)c, (void)buf, (void)len;
    for (int i = 0; i < ND; i++)
        if (!isfinite(st->b.xd[i])) return "the controller's state is not finite";
    if (st->b.taken < 0) return "its sample count is negative";
    return NULL;
}
