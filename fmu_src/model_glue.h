/* The model side of the FMU: x' = F(x) from the generated CasADi functions (x = [q, u, z]), its Jacobian for the
 * implicit solver, outputs, the state check and the static-equilibrium solve. Knows nothing about FMI. */
#ifndef CEDRA_MODEL_GLUE_H
#define CEDRA_MODEL_GLUE_H

#include <stddef.h>

#include "solver.h"

typedef struct model_ws model_ws;

/* bytes of one workspace (the caller allocates it zeroed, e.g. with fmi2's allocateMemory) */
size_t model_ws_size(void);
/* the inputs and parameters the next evaluations use (pointers kept, not copied) */
void model_bind(model_ws *ws, const double *inp, const double *par);
/* the terrain data of a heightmap scene and its rim searches' memo (heightmap.h; kept, not copied, memo may be NULL);
 * every evaluation activates them */
void model_bind_terrain(model_ws *ws, void *terrain, void *memo);
/* the reason of the last failure (a finished sentence, no trailing newline) */
const char *model_message(const model_ws *ws);
void model_clear_message(model_ws *ws);

/* what the solvers may assume of model_rhs and model_jac (solver.h): x = [q, u, z] with q' = u (RODAS4's stage
 * systems reduce to NQ x NQ; a build with -DCEDRA_SCHUR_N2=0 gets the dense NX x NX solve, the benchmark's
 * comparison), the u rows of the Jacobian given as -dr/dq, -dr/du with the mass matrix (compliant models), and no
 * explicit time dependence (inputs are held over a communication step) */
const solver_structure *model_structure(void);

/* solver callbacks (solver.h): ctx is the model_ws */
int model_rhs(void *ctx, double t, const double *x, double *xdot);
int model_jac(void *ctx, double t, const double *x, const double *xdot, double *jac);

/* step-acceptance callback (solver.h): rigid contact touch-down location; accepts every step of compliant
 * models */
double model_accept_step(void *ctx, double t, const double *x, double t_new, const double *x_new);
/* switch-location callback (solver.h): cuts a step at the first force-law switch inside it (cedra_switch); accepts
 * every step of a model without switches */
double model_locate_step(void *ctx, double t, const double *x, double t_new, const double *x_new);
/* the switches located since the last reset: k < 0 resets the count and returns it; k >= 0 returns the count and,
 * for the k-th most recent of the last few kept, its name and the step [t0, t1] that crossed it (if the pointers
 * are not NULL) */
long model_take_located(model_ws *ws, int k, const char **name, double *t0, double *t1);
/* post-step callback (solver.h): rigid contact projection; does nothing for compliant models */
int model_post_step(void *ctx, double t, double *x);

/* a communication step starts at x: what x accumulates over one (a rigid contact's impulses) restarts at 0 */
void model_begin_interval(model_ws *ws, double *x);
/* after model_outputs at the step's end x, h after model_begin_interval: the outputs that are means over the step
 * (a rigid contact's wheel[k].F*_mean = impulse / h); nothing for compliant models */
void model_interval_outputs(model_ws *ws, const double *x, double h, double *y);
/* y = outputs at x; 0, or 1 (message) if the state cannot be evaluated or an output is not finite */
int model_outputs(model_ws *ws, const double *x, double *y);
/* 1 if cedra_check accepts (q, u), else 0 (message set) */
int model_check(model_ws *ws, const double *q, const double *u);
/* q := cedra_guess(q), then damped Newton on cedra_settle for the settle coordinates; 0, or 1 (message) */
int model_settle(model_ws *ws, double *q);

#endif
