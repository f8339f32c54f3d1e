/* The plant block (glue.h): the model x' = F(x), x = [q, u, z], integrated inside fmi2DoStep by an embedded solver
 * (solver.c) on the model's generated functions (model_glue.c). Its variables beyond parameters, inputs and
 * outputs: the start values of q and u, start.settle, the solver settings and the solver counters. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "glue.h"
#include "heightmap.h"
#include "model_glue.h"

#define NQ CEDRA_NQ
#define NZ CEDRA_NZ
#define NX CEDRA_NX
/* Switch location: steps are cut at the model's force-law switches (cedra_switch). A build with
 * -DCEDRA_LOCATE_FN=NULL integrates across them (error control only), for comparisons. */
#ifndef CEDRA_LOCATE_FN
#define CEDRA_LOCATE_FN model_locate_step
#endif

struct block_ws {
    model_ws *model;
    double *work;                   /* solver workspace (largest over the methods) */
    double x_save[NX];
    /* the kept Jacobian at the call's start: a discarded step leaves the instance as it was */
    double keep_save[NX * NX + NQ * NQ];
    long jac_age_save;
    double y_tmp[DIM(CEDRA_NY)];
    heightmap terrain;              /* heightmap scenes: resources/heightmap.txt (constant: not FMU state) */
    heightmap_memo *memo;           /* its rim searches' memo (changes no result: not FMU state either) */
};

/* the solver settings by the variable table's index (variables.py: 0 method, 1 tol, 2 h_max, 3 max_steps,
 * 4 max_wall_time) */
static double solver_value(const solver_settings *s, int index) {
    switch (index) {
        case 0: return (double)s->method;
        case 1: return s->tol;
        case 2: return s->h_max;
        case 3: return (double)s->max_steps;
        default: return s->max_wall;
    }
}

static void solver_store(solver_settings *s, int index, double d) {
    switch (index) {
        case 0: s->method = (int)d; break;
        case 1: s->tol = d; break;
        case 2: s->h_max = d; break;
        case 3: s->max_steps = (long)d; break;
        default: s->max_wall = d; break;
    }
}

/* ------------------------------------------------------------------------------------------- instance */

#if CEDRA_HEIGHTMAP
/* the local path of a file: URI (file:///p, file:/p or file://localhost/p; %XX decoded); 0, or 1 if it is not one */
static int uri_to_path(const char *uri, char *path, size_t len) {
    const char *p;
    size_t k = 0;
    if (!uri || strncmp(uri, "file:", 5) != 0) return 1;
    p = uri + 5;
    if (strncmp(p, "///", 3) == 0) p += 2;
    else if (strncmp(p, "//localhost/", 12) == 0) p += 11;
    else if (strncmp(p, "//", 2) == 0) return 1;            /* a remote host */
    for (; *p && k + 1 < len; p++) {
        unsigned int ch;
        if (p[0] == '%' && p[1] && p[2] && sscanf(p + 1, "%2x", &ch) == 1) {
            path[k++] = (char)ch;
            p += 2;
        } else {
            path[k++] = *p;
        }
    }
    path[k] = '\0';
    return *p != '\0';                                        /* too long */
}

/* reads <resources>/heightmap.txt into the terrain; 0, or 1 (logged) */
static int read_terrain(instance *c, const char *resource_location) {
    char dir[4096], path[4200], why[600];
    if (uri_to_path(resource_location, dir, sizeof dir)) {
        log_msg(c, fmi2Error, CAT_ERROR, "fmi2Instantiate: fmuResourceLocation %s is not a local file: URI "
                "(the heightmap terrain is read from resources/heightmap.txt)",
                resource_location ? resource_location : "(NULL)");
        return 1;
    }
    size_t n = strlen(dir);
    snprintf(path, sizeof path, "%s%sheightmap.txt", dir, n > 0 && dir[n - 1] == '/' ? "" : "/");
    if (heightmap_read(&c->ws->terrain, path, c->alloc, c->free, why, sizeof why)) {
        log_msg(c, fmi2Error, CAT_ERROR, "fmi2Instantiate: %s", why);
        return 1;
    }
    log_msg(c, fmi2OK, CAT_EVENTS, "fmi2Instantiate: terrain %s: %d x %d heights", path, c->ws->terrain.nx,
            c->ws->terrain.ny);
    return 0;
}
#endif

int block_instantiate(instance *c, const char *resource_location) {
    size_t nw = 0;
    if (solver_keep_size(NX, model_structure()->n2) > sizeof c->s.b.jac_keep / sizeof(double)) {
        log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: the solver's kept Jacobian does not fit the state");
        return 1;
    }
    for (int m = 0; m < SOLVER_N_METHODS; m++) {
        size_t w = solver_workspace_size(m, NX);
        if (w > nw) nw = w;
    }
    c->ws = (block_ws *)c->alloc(1, sizeof(block_ws));
    if (!c->ws) {
        log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: out of memory");
        return 1;
    }
    c->ws->model = (model_ws *)c->alloc(1, model_ws_size());
    c->ws->work = (double *)c->alloc(nw > 0 ? nw : 1, sizeof(double));
    if (!c->ws->model || !c->ws->work) {
        log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: out of memory");
        return 1;
    }
#if CEDRA_HEIGHTMAP
    if (read_terrain(c, resource_location)) return 1;
    c->ws->memo = (heightmap_memo *)c->alloc(1, heightmap_memo_size());
    if (!c->ws->memo) {
        log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: out of memory");
        return 1;
    }
    model_bind_terrain(c->ws->model, &c->ws->terrain, c->ws->memo);
#else
    (void)resource_location;
#endif
    return 0;
}

void block_free(instance *c) {
    if (!c->ws) return;
    heightmap_release(&c->ws->terrain, c->free);
    if (c->ws->memo) c->free(c->ws->memo);
    if (c->ws->work) c->free(c->ws->work);
    if (c->ws->model) c->free(c->ws->model);
    c->free(c->ws);
    c->ws = NULL;
}

/* ------------------------------------------------------------------------------------------- variables */

void block_defaults(cedra_state *s) {
    block_state *b = &s->b;
    for (int i = 0; i < NQ; i++) b->q_start[i] = CEDRA_Q_START[i];
    for (int i = 0; i < CEDRA_NVARS; i++) {
        const cedra_var *v = &CEDRA_VARS[i];
        if (v->kind == CEDRA_K_U_START) b->u_start[v->index] = v->start;
        if (v->kind == CEDRA_K_SETTLE) b->settle = v->start != 0.0;
        if (v->kind == CEDRA_K_SOLVER) solver_store(&b->solver, v->index, v->start);
    }
}

int block_value(const cedra_state *s, const cedra_var *v, double *out) {
    const block_state *b = &s->b;
    switch (v->kind) {
        case CEDRA_K_Q_START: *out = b->q_start[v->index]; return 0;
        case CEDRA_K_U_START: *out = b->u_start[v->index]; return 0;
        case CEDRA_K_SETTLE: *out = b->settle; return 0;
        case CEDRA_K_SOLVER: *out = solver_value(&b->solver, v->index); return 0;
        case CEDRA_K_STAT:
            *out = (double)(v->index == 0   ? b->stats.steps
                            : v->index == 1 ? b->stats.rejected
                            : v->index == 2 ? b->stats.rhs_evals
                                            : b->stats.jac_evals);
            return 0;
        default: return 1;
    }
}

void block_store(cedra_state *s, const cedra_var *v, double d) {
    block_state *b = &s->b;
    switch (v->kind) {
        case CEDRA_K_Q_START: b->q_start[v->index] = d; break;
        case CEDRA_K_U_START: b->u_start[v->index] = d; break;
        case CEDRA_K_SETTLE: b->settle = d != 0.0; break;
        case CEDRA_K_SOLVER:
            solver_store(&b->solver, v->index, d);
            if (v->index == 1) b->tol_explicit = 1;
            break;
        default: break;
    }
}

void block_tolerance(instance *c, double tolerance) {
    block_state *b = &c->s.b;
    if (b->tol_explicit) {
        log_msg(c, fmi2OK, CAT_EVENTS, "fmi2SetupExperiment: tolerance %g not used: solver.tol = %g was set "
                "explicitly", tolerance, b->solver.tol);
        return;
    }
    b->solver.tol = tolerance;
    c->s.outputs_valid = 0;
    log_msg(c, fmi2OK, CAT_EVENTS, "fmi2SetupExperiment: the embedded solver's tolerance solver.tol = %g (the "
            "importer's tolerance)", tolerance);
}

/* ------------------------------------------------------------------------------------------- initialization */

/* x from the start values (settled if start.settle) and the outputs there; 0 or 1 (logged, the state unchanged) */
int block_outputs(instance *c, const char *fn) {
    cedra_state *s = &c->s;
    block_state *b = &s->b;
    model_ws *ws = c->ws->model;
    double x[NX], *q = x, *u = x + NQ;
    if (s->outputs_valid) return 0;
    model_bind(ws, s->inp, s->par);
    memcpy(q, b->q_start, sizeof(double) * NQ);
    memcpy(u, b->u_start, sizeof(double) * NQ);
    for (int i = 2 * NQ; i < NX; i++) x[i] = 0.0;     /* the integrals (work; a rigid contact's impulses) */
    if (b->settle) {
        if (model_settle(ws, q)) {
            log_msg(c, fmi2Error, CAT_ERROR, "%s: static equilibrium at the start failed: %s", fn, model_message(ws));
            return 1;
        }
        log_msg(c, fmi2OK, CAT_EVENTS, "%s: settled the start pose in static equilibrium", fn);
    }
    if (!model_check(ws, q, u)) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: the start state cannot be evaluated: %s", fn, model_message(ws));
        return 1;
    }
    if (model_outputs(ws, x, c->ws->y_tmp)) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: outputs at the start: %s", fn, model_message(ws));
        return 1;
    }
    memcpy(b->x, x, sizeof x);
    memcpy(s->y, c->ws->y_tmp, sizeof(double) * CEDRA_NY);
    s->outputs_valid = 1;
    return 0;
}

int block_initialize(instance *c, const char *fn) {
    if (block_outputs(c, fn)) return 1;
    memset(&c->s.b.stats, 0, sizeof c->s.b.stats);
    return 0;
}

/* ------------------------------------------------------------------------------------------- stepping */

int block_refuse_step(instance *c, double t, double h) {
    /* settings or an interval that cannot be integrated within the call's budget: refused before any work */
    return solver_check(&c->s.b.solver, t, t + h, c->msg, sizeof c->msg);
}

/* back to the state at t (time and outputs untouched; the counters keep the failed attempt), the reason
 * `why` + `detail` in c->msg */
static fmi2Status step_failed(instance *c, const char *why, const char *detail) {
    block_state *b = &c->s.b;
    memcpy(b->x, c->ws->x_save, sizeof(double) * NX);
    if (b->solver.method == SOLVER_ROS34PW2) {
        memcpy(b->jac_keep, c->ws->keep_save, sizeof b->jac_keep);
        b->stats.jac_age = c->ws->jac_age_save;
    }
    snprintf(c->msg, sizeof c->msg, "%s%s%s", why, detail[0] ? "; model: " : "", detail);
    return fmi2Discard;
}

fmi2Status block_step(instance *c, double t, double h) {
    cedra_state *s = &c->s;
    block_state *b = &s->b;
    model_ws *ws = c->ws->model;
    char solver_msg[MSG_LEN];
    model_bind(ws, s->inp, s->par);
    memcpy(c->ws->x_save, b->x, sizeof(double) * NX);
    if (b->solver.method == SOLVER_ROS34PW2) {
        memcpy(c->ws->keep_save, b->jac_keep, sizeof b->jac_keep);
        c->ws->jac_age_save = b->stats.jac_age;
    }
    model_begin_interval(ws, b->x);      /* after the copy: a refused step leaves the instance as it was */
    solver_msg[0] = '\0';
    model_clear_message(ws);
    model_take_located(ws, -1, NULL, NULL, NULL);
    int failed = solver_integrate_post(&b->solver, NX, b->x, t, t + h, model_rhs, model_jac, model_accept_step,
                                       CEDRA_LOCATE_FN, model_post_step, ws, c->ws->work, &b->stats, solver_msg,
                                       sizeof solver_msg, model_structure(), b->jac_keep);
    long located = model_take_located(ws, 0, NULL, NULL, NULL);
    for (long k = 0; k < located && k < 8; k++) {   /* the most recent ones */
        const char *name = "";
        double t0 = 0, t1 = 0;
        model_take_located(ws, (int)k, &name, &t0, &t1);
        log_msg(c, fmi2OK, CAT_EVENTS, "fmi2DoStep: switch located (%ld in this call): %s in the step [%.17g, "
                "%.17g] (%.3g s)", located, name, t0, t1, t1 - t0);
    }
    if (failed) return step_failed(c, solver_msg[0] ? solver_msg : "the solver failed", model_message(ws));
    for (int i = 0; i < NX; i++)
        if (!isfinite(b->x[i])) return step_failed(c, "the state is not finite after the step", "");
    if (model_outputs(ws, b->x, c->ws->y_tmp)) return step_failed(c, model_message(ws), "");
    model_interval_outputs(ws, b->x, h, c->ws->y_tmp);
    memcpy(s->y, c->ws->y_tmp, sizeof(double) * CEDRA_NY);
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------- FMU state */

const char *block_state_problem(instance *c, const cedra_state *st, char *buf, size_t len) {
    const block_state *b = &st->b;
    if (!(b->settle == 0 || b->settle == 1) || !(b->tol_explicit == 0 || b->tol_explicit == 1))
        return "a flag is neither 0 nor 1";
    if (!all_finite(b->x, NX)) return "the state x or the outputs are not finite";
    if (b->stats.steps < 0 || b->stats.rejected < 0 || b->stats.rhs_evals < 0 || b->stats.jac_evals < 0 ||
        !(b->stats.h_next >= 0) || !isfinite(b->stats.h_next) || b->stats.jac_age < 0)
        return "a solver counter is negative or not finite";
    if (b->stats.jac_age > 0 && !all_finite(b->jac_keep, NX * NX + NQ * NQ))
        return "the solver's kept Jacobian is not finite";
    if (st->outputs_valid) {
        /* the model must accept the state (the bound inputs and parameters are the candidate's, then ours again) */
        model_bind(c->ws->model, st->inp, st->par);
        int ok = model_check(c->ws->model, b->x, b->x + NQ);
        if (!ok) snprintf(buf, len, "the model cannot evaluate its state: %s", model_message(c->ws->model));
        model_bind(c->ws->model, c->s.inp, c->s.par);
        if (!ok) return buf;
    }
    return NULL;
}
