/* Embedded ODE solvers for x' = F(t, x): the contract between the FMI glue and the integrators.
 * The glue owns every buffer; the solvers never allocate. */
#ifndef CEDRA_SOLVER_H
#define CEDRA_SOLVER_H

#include <stddef.h>

/* SOLVER_MOREAU: a model's own fixed-step time stepper (solver_structure.own_step; rigid contact's Moreau-Jean) */
enum solver_method { SOLVER_RK4 = 0, SOLVER_DOPRI5 = 1, SOLVER_RODAS4 = 2, SOLVER_ROS34PW2 = 3, SOLVER_MOREAU = 4 };
#define SOLVER_N_METHODS 5

/* Return 0 on success; nonzero means the state cannot be evaluated (the callback has written why
 * into its context; the solver reports failure). */
typedef int (*solver_rhs_fn)(void *ctx, double t, const double *x, double *xdot);
/* Dense Jacobian dF/dx, column-major n x n, at (t, x) where xdot = F(t, x) is already known. */
typedef int (*solver_jac_fn)(void *ctx, double t, const double *x, const double *xdot, double *jac);

/* Called after every accepted step with the new state; it may change x in place (e.g. project a constrained
 * state back onto its constraints, or apply an impact). Returns 0 if x is unchanged, 1 if it changed (the
 * solver then re-evaluates F at x), negative on failure (the reason in the callback's context). */
typedef int (*solver_post_fn)(void *ctx, double t, double *x);

/* Called by the adaptive methods before they accept a step from (t, x) to (t_new, x_new) that passed the error
 * test: returns 1 to accept it, or a factor in (0, 1) to reject it and retry with the step size times that
 * factor (an event inside the step that must be located, e.g. a wheel that would land deep in the ground).
 * Negative on failure (the reason in the callback's context). RK4, a fixed-step method, does not call it. */
typedef double (*solver_accept_fn)(void *ctx, double t, const double *x, double t_new, const double *x_new);

/* Called by the adaptive methods for a step that passed the error test (after the accept callback) or failed it:
 * the length of the step to take instead when a switching function of the model changes sign inside the step
 * (0 < len < t_new - t: the step is retried with exactly that length, so that it ends at the switch, and the cut
 * does not lower the step-size proposal after it); HUGE_VAL when the step crosses a switch and is short enough
 * that the switch counts as located (the step is accepted even if it failed the error test: its error is the
 * force law's jump times that short step); t_new - t (or more) when no switch lies inside. Negative on failure
 * (for a step that failed the error test: then just rejected). solver_locate_switches is the usual body. */
typedef double (*solver_locate_fn)(void *ctx, double t, const double *x, double t_new, const double *x_new);

/* Locate the first sign change of nsw switching functions between s0 (at t) and s1 (at t_new): returns t_new - t
 * if none changes sign, HUGE_VAL if one does and the step is at most loc_tol long (located within loc_tol);
 * otherwise the length of the step to try instead: just short of the crossing (linear interpolation of s) when
 * it lies more than loc_tol ahead, loc_tol when it lies within loc_tol. *which (if not NULL) = the index of that
 * switch, or -1. A switch exactly 0 at t is not a crossing (the step starts on it). */
double solver_locate_switches(int nsw, const double *s0, const double *s1, double t, double t_new, double loc_tol,
                              int *which);

typedef struct {
    int method;        /* enum solver_method */
    double tol;        /* relative and absolute tolerance of the adaptive methods */
    double h_max;      /* largest step; RK4's fixed step */
    long max_steps;    /* budget of one call: attempted steps (accepted and rejected), >= 1 */
    double max_wall;   /* budget of one call: wall-clock seconds, > 0 and finite */
} solver_settings;

typedef struct {       /* counts since the start of the simulation (part of the FMU state) */
    long steps, rejected, rhs_evals, jac_evals;
    double h_next;     /* step size proposal carried between calls (adaptive methods) */
    long jac_age;      /* ROS34PW2: steps begun with the Jacobian kept in `keep` (0: none kept) */
} solver_stats;

/* The smallest step the solvers take at time t (1e-12 max(1, |t|)): below it time cannot be resolved, so an
 * interval shorter than that cannot be integrated, and an adaptive step that would have to be shorter fails
 * with "step size underflow". */
double solver_time_resolution(double t);

/* 0 if the settings can integrate [t0, t1] (t1 >= t0) within the call's budget, else 1 with the reason in msg:
 * invalid settings or interval, or an interval that needs more than max_steps steps of h_max. Nothing is
 * evaluated, so a caller can refuse a call before it changes anything. solver_integrate checks the same. */
int solver_check(const solver_settings *s, double t0, double t1, char *msg, size_t msg_len);

/* doubles of workspace the method needs for a system of size n */
size_t solver_workspace_size(int method, int n);

/* Integrate from t0 to t1 (t1 > t0) in place on x. The last step is shortened to land exactly on t1.
 * Returns 0 on success (x is the state at t1); on failure returns nonzero, leaves x at the last accepted state,
 * and writes the reason (e.g. "step size underflow h=1e-14 at t=0.53", "NaN in the derivative at t=...", a spent
 * budget: more than max_steps attempted steps or more than max_wall seconds) into msg. */
int solver_integrate(const solver_settings *s, int n, double *x, double t0, double t1,
                     solver_rhs_fn rhs, solver_jac_fn jac, void *ctx,
                     double *work, solver_stats *stats, char *msg, size_t msg_len);
/* What a model tells the solvers about F (all 0: nothing known). */
typedef struct {
    /* n2 > 0: x = [q (n2), u (n2), z (n - 2 n2)] with q' = u exactly and F independent of z, so the Jacobian is
     * [[0, I, 0], [A, B, 0], [C, D, 0]]; RODAS4 then solves its stage systems with an n2 x n2 Schur complement
     * instead of the n x n matrix */
    int n2;
    /* (n2 > 0 only) the Jacobian callback writes the u rows premultiplied by a nonsingular n2 x n2 matrix M: M A and
     * M B in place of A and B, and M itself (column-major) at jac + n * n. A model M(q) u' = f(q, u) hands over
     * -dr/dq and -dr/du (r = M u' - f) and its mass matrix, without the 2 n2 solves with M that A and B would cost;
     * the stage solves multiply by M instead (one matrix-vector product each). */
    int mass_rows;
    /* F does not depend on t explicitly (an FMU's inputs are held over a step): dF/dt = 0 exactly, so RODAS4 does
     * not spend an evaluation of F per step on its forward difference */
    int autonomous;
    /* F holds discrete modes chosen at a step's start over the step (a rigid contact's decision tree): a step is then
     * never longer than the controller proposed, not even the call's last (solver.c: LAST_STRETCH) */
    int modes_held;
    /* the last quad_tail components of x are quadratures (z' = a function of the others, never fed back: a rigid
     * contact's impulses over a communication step): integrated by every stage, left out of the error test and of
     * the first step's size, whose accuracy the state's own components decide */
    int quad_tail;
    /* a time stepper of the model's own (NULL: none), which solver.method moreau runs in fixed steps of h_max: one
     * step from (t, x) over h in place; 0, or nonzero on failure (the reason in the callback's context). The
     * rigid contact's Moreau-Jean scheme: forces and impacts as impulses over a step, which converge with h where
     * an integrator of the held-mode forces, switching modes at step ends, does not. */
    int (*own_step)(void *ctx, double t, double h, double *x);
} solver_structure;

/* the same, with a step-acceptance, a switch-location and a post-step callback (each NULL: none), and what is known
 * of F's structure (NULL: nothing) */
int solver_integrate_post(const solver_settings *s, int n, double *x, double t0, double t1,
                          solver_rhs_fn rhs, solver_jac_fn jac, solver_accept_fn accept, solver_locate_fn locate,
                          solver_post_fn post, void *ctx, double *work, solver_stats *stats, char *msg,
                          size_t msg_len, const solver_structure *structure, double *keep);
/* keep (ROS34PW2, may be NULL): solver_keep_size(n, n2) doubles the caller keeps with stats between calls (both part
 * of its state, e.g. an FMU's), where the W-method keeps its Jacobian from call to call; NULL: a call starts with a
 * fresh Jacobian. */
size_t solver_keep_size(int n, int n2);

/* The RODAS4 stage system (I/(h gamma) - J) k = r with fac = 1/(h gamma), for the structure of
 * solver_integrate_post (n2 > 0; n2 = 0: the dense n x n solve). M: NULL, or (n2 > 0) the mass_rows matrix, the
 * u rows of J then being M times the Jacobian's. work: solver_stage_work_size(n, n2) doubles, piv: n ints. Factor
 * once (returns 1 if singular), then solve any number of right-hand sides in place. Exposed for the tests (the
 * reduced solve equals the full one). */
size_t solver_stage_work_size(int n, int n2);
int solver_stage_factor(int n, int n2, double fac, const double *J, const double *M, double *work, int *piv);
void solver_stage_solve(int n, int n2, double fac, const double *J, const double *M, double *work, const int *piv,
                        double *r);

#endif
