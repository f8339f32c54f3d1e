/* Test harness for fmu_src/solver.c and fmu_src/linalg.c, loaded through ctypes by tests/test_solvers.py.
 * Test problems (selected by `problem`, parameters in `par`):
 *   0 decay        x' = -par0 x                                  exact x0 exp(-par0 (t - t0))
 *   1 oscillator   x0' = x1, x1' = -x0                           exact rotation
 *   2 stiff linear x0' = -x0, x1' = -par0 (x1 - x0) - x0         eigenvalues -1, -par0; exact e^-t + c e^(-par0 t)
 *   3 Van der Pol  x0' = x1, x1' = par0 (1 - x0^2) x1 - x0       stiff for par0 = 1000
 *   4 failing      x0' = 1 (x1' = -x1); the rhs returns 1 when x0 > par0
 *   5 NaN          as 4, but the derivative is NaN when x0 > par0
 *   6 time-dependent x' = cos(t) x                               exact x0 exp(sin t - sin t0)
 *   7 limit cycle  x0' = -x1 + x0 s, x1' = x0 + x1 s, s = 1 - |x|^2   (nonlinear, exact: angle t - t0 and
 *                  r = 1 / sqrt(1 + (1/r0^2 - 1) exp(-2 (t - t0))))
 * The context records the latest t seen by the rhs so that the tests can check that the last step ends on t1. */
#include <math.h>
#include <string.h>

#include "linalg.h"
#include "solver.h"

typedef struct {
    int problem;
    const double *par;
    double t_max_seen;
    long calls;
} harness_ctx;

static int rhs(void *vctx, double t, const double *x, double *f) {
    harness_ctx *c = vctx;
    const double *p = c->par;
    c->calls++;
    if (t > c->t_max_seen) c->t_max_seen = t;
    switch (c->problem) {
    case 0: f[0] = -p[0] * x[0]; return 0;
    case 1: f[0] = x[1]; f[1] = -x[0]; return 0;
    case 2: f[0] = -x[0]; f[1] = -p[0] * (x[1] - x[0]) - x[0]; return 0;
    case 3: f[0] = x[1]; f[1] = p[0] * (1 - x[0] * x[0]) * x[1] - x[0]; return 0;
    case 4:
        if (x[0] > p[0]) return 1;
        f[0] = 1; f[1] = -x[1]; return 0;
    case 5:
        f[0] = x[0] > p[0] ? NAN : 1; f[1] = -x[1]; return 0;
    case 6: f[0] = cos(t) * x[0]; return 0;
    case 7: {
        double q = 1 - x[0] * x[0] - x[1] * x[1];
        f[0] = -x[1] + x[0] * q; f[1] = x[0] + x[1] * q; return 0;
    }
    default: return 1;
    }
}

static int jac(void *vctx, double t, const double *x, const double *xdot, double *J) {
    harness_ctx *c = vctx;
    const double *p = c->par;
    (void)xdot;
    switch (c->problem) {   /* column-major: J[i + j*n] = dF_i/dx_j */
    case 0: J[0] = -p[0]; return 0;
    case 1: J[0] = 0; J[1] = -1; J[2] = 1; J[3] = 0; return 0;
    case 2: J[0] = -1; J[1] = p[0] - 1; J[2] = 0; J[3] = -p[0]; return 0;
    case 3:
        J[0] = 0; J[1] = -2 * p[0] * x[0] * x[1] - 1;
        J[2] = 1; J[3] = p[0] * (1 - x[0] * x[0]);
        return 0;
    case 4: case 5: J[0] = 0; J[1] = 0; J[2] = 0; J[3] = -1; return 0;
    case 6: J[0] = cos(t); return 0;
    case 7: {
        double q = 1 - x[0] * x[0] - x[1] * x[1];
        J[0] = q - 2 * x[0] * x[0]; J[1] = 1 - 2 * x[0] * x[1];
        J[2] = -1 - 2 * x[0] * x[1]; J[3] = q - 2 * x[1] * x[1];
        return 0;
    }
    default: return 1;
    }
}

size_t harness_workspace(int method, int n) { return solver_workspace_size(method, n); }

/* stats_io: steps, rejected, rhs_evals, jac_evals, h_next (in and out); info_out: t_max_seen, rhs calls */
int harness_run(int problem, const double *par, int method, double tol, double h_max, long max_steps, double max_wall,
                int n, double *x, double t0, double t1, double *work, double *stats_io, double *info_out, char *msg,
                int msg_len) {
    harness_ctx c = {problem, par, -INFINITY, 0};
    solver_settings s = {method, tol, h_max, max_steps, max_wall};
    solver_stats st = {(long)stats_io[0], (long)stats_io[1], (long)stats_io[2], (long)stats_io[3], stats_io[4], 0};
    int rc = solver_integrate(&s, n, x, t0, t1, rhs, jac, &c, work, &st, msg, (size_t)msg_len);
    stats_io[0] = (double)st.steps;
    stats_io[1] = (double)st.rejected;
    stats_io[2] = (double)st.rhs_evals;
    stats_io[3] = (double)st.jac_evals;
    stats_io[4] = st.h_next;
    info_out[0] = c.t_max_seen;
    info_out[1] = (double)c.calls;
    return rc;
}

/* ROS34PW2 (the W-method) on a problem, with the Jacobian the method is given scaled by jac_scale (1: exact; a
 * W-method keeps its order with any matrix), F declared autonomous or not, and the kept Jacobian in `keep`
 * (solver_keep_size(n, 0) doubles; NULL: not kept between calls). stats_io: steps, rejected, rhs_evals, jac_evals,
 * h_next, jac_age (in and out). */
static double w_jac_scale = 1.0;
static int scaled_jac(void *vctx, double t, const double *x, const double *xdot, double *J) {
    harness_ctx *c = vctx;
    int rc = jac(vctx, t, x, xdot, J);
    int n = c->problem == 0 || c->problem == 6 ? 1 : 2;
    for (int k = 0; k < n * n; k++) J[k] *= w_jac_scale;
    return rc;
}

int harness_run_w(int problem, const double *par, double tol, double h_max, int n, double *x, double t0, double t1,
                  double *work, double *keep, double *stats_io, double jac_scale, int autonomous, char *msg,
                  int msg_len) {
    harness_ctx c = {problem, par, -INFINITY, 0};
    solver_settings s = {SOLVER_ROS34PW2, tol, h_max, 1000000, 100.0};
    solver_stats st = {(long)stats_io[0], (long)stats_io[1], (long)stats_io[2], (long)stats_io[3], stats_io[4],
                       (long)stats_io[5]};
    solver_structure sp = {0, 0, autonomous, 0, 0, NULL};
    w_jac_scale = jac_scale;
    int rc = solver_integrate_post(&s, n, x, t0, t1, rhs, scaled_jac, NULL, NULL, NULL, &c, work, &st, msg,
                                   (size_t)msg_len, &sp, keep);
    stats_io[0] = (double)st.steps;
    stats_io[1] = (double)st.rejected;
    stats_io[2] = (double)st.rhs_evals;
    stats_io[3] = (double)st.jac_evals;
    stats_io[4] = st.h_next;
    stats_io[5] = (double)st.jac_age;
    return rc;
}

/* Factor a copy of A (n <= 64) and solve A x = b in place on b; returns linalg_lu_factor's code. */
int harness_lu_solve(int n, const double *a, double *b) {
    double lu[64 * 64];
    int piv[64];
    if (n > 64) return -1;
    memcpy(lu, a, sizeof(double) * (size_t)n * (size_t)n);
    int rc = linalg_lu_factor(n, lu, piv);
    if (rc == 0) linalg_lu_solve(n, lu, piv, b);
    return rc;
}

/* Factor the symmetric A in its own order (n <= 64; its lower triangle is read) and solve A x = b in place on b;
 * returns linalg_chol_factor_perm's code. */
int harness_chol_solve(int n, const double *a, double *b) {
    double l[64 * 64];
    int order[64], nz[64];
    if (n > 64) return -1;
    for (int k = 0; k < n; k++) order[k] = k;
    int rc = linalg_chol_factor_perm(n, a, order, l, nz);
    if (rc == 0) linalg_chol_solve(n, l, b);
    return rc;
}

/* The same in the elimination order perm (linalg_chol_factor_perm: the FMU's mass-matrix factor); the factor of
 * P A P^T into l (n x n) as well, for its zeros. */
int harness_chol_solve_perm(int n, const double *a, const int *perm, double *b, double *l) {
    int nz[64];
    double work[64];
    if (n > 64) return -1;
    int rc = linalg_chol_factor_perm(n, a, perm, l, nz);
    if (rc == 0) linalg_chol_solve_perm(n, l, perm, b, work);
    return rc;
}

/* ---- the RODAS4 stage system with the second-order structure, and switch location ---- */

/* Solve (fac I - J) x = b for n <= 64 twice: densely (out_full) and with the n2 x n2 Schur complement (out_red).
 * M NULL: the reduced solve reads J too; else it reads Jm, J with its u rows premultiplied by M (solver.h mass_rows).
 * Returns the two factorizations' codes, full * 2 + reduced. */
int harness_stage_solve(int n, int n2, double fac, const double *J, const double *Jm, const double *M,
                        const double *b, double *out_full, double *out_red) {
    double work[64 * 64 + 64];
    int piv[64];
    if (n > 64 || n2 < 1 || 2 * n2 > n) return -1;
    memcpy(out_full, b, sizeof(double) * (size_t)n);
    memcpy(out_red, b, sizeof(double) * (size_t)n);
    int rf = solver_stage_factor(n, 0, fac, J, NULL, work, piv);
    if (rf == 0) solver_stage_solve(n, 0, fac, J, NULL, work, piv, out_full);
    const double *Jr = M ? Jm : J;
    int rr = solver_stage_factor(n, n2, fac, Jr, M, work, piv);
    if (rr == 0) solver_stage_solve(n, n2, fac, Jr, M, work, piv, out_red);
    return rf * 2 + rr;
}

/* A ball dropped on a compliant ground: z' = v, v' = -g + max(0, -k z - d v) for z < 0 (the contact law's jump of
 * d |v| at touchdown), with the switching function s = z. */
typedef struct {
    double g, k, d, loc_tol;
    int located;
    double t0, t1;          /* the first step that crossed the switch and was accepted */
    long cuts;
} ball_ctx;

static int ball_rhs(void *vctx, double t, const double *x, double *f) {
    ball_ctx *c = vctx;
    (void)t;
    f[0] = x[1];
    f[1] = -c->g + (x[0] < 0 ? fmax(0.0, -c->k * x[0] - c->d * x[1]) : 0.0);
    return 0;
}

static int ball_jac(void *vctx, double t, const double *x, const double *xdot, double *J) {
    ball_ctx *c = vctx;
    (void)t;
    (void)xdot;
    int on = x[0] < 0 && -c->k * x[0] - c->d * x[1] > 0;
    J[0] = 0; J[1] = on ? -c->k : 0; J[2] = 1; J[3] = on ? -c->d : 0;
    return 0;
}

static double ball_locate(void *vctx, double t, const double *x, double t_new, const double *x_new) {
    ball_ctx *c = vctx;
    int which;
    double len = solver_locate_switches(1, &x[0], &x_new[0], t, t_new, c->loc_tol, &which);
    if (which >= 0 && len >= t_new - t && !c->located) {
        c->located = 1;
        c->t0 = t;
        c->t1 = t_new;
    }
    if (len < t_new - t) c->cuts++;
    return len;
}

/* Drop from z0 (v = 0) over [0, t1]; with_locate 0: no location. out: located, t0, t1, cuts, steps, rejected, z, v */
int harness_ball(int method, double tol, double h_max, double z0, double t_end, int with_locate, int n2,
                 double *out, char *msg, int msg_len) {
    ball_ctx c = {9.81, 1e5, 600, 1e-10, 0, 0, 0, 0};
    solver_settings s = {method, tol, h_max, 1000000, 100.0};
    solver_stats st = {0, 0, 0, 0, 0, 0};
    double x[2] = {z0, 0}, work[64];
    if (solver_workspace_size(method, 2) > 64) return -1;
    solver_structure sp = {n2, 0, 0, 0, 0, NULL};
    int rc = solver_integrate_post(&s, 2, x, 0, t_end, ball_rhs, ball_jac, NULL, with_locate ? ball_locate : NULL,
                                   NULL, &c, work, &st, msg, (size_t)msg_len, &sp, NULL);
    out[0] = c.located; out[1] = c.t0; out[2] = c.t1; out[3] = (double)c.cuts;
    out[4] = (double)st.steps; out[5] = (double)st.rejected; out[6] = x[0]; out[7] = x[1];
    return rc;
}
