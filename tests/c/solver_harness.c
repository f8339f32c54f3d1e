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
    solver_stats st = {(long)stats_io[0], (long)stats_io[1], (long)stats_io[2], (long)stats_io[3], stats_io[4]};
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
