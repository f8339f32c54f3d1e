/* Embedded ODE solvers (see solver.h): fixed-step RK4, adaptive Dormand-Prince 5(4), adaptive Rosenbrock RODAS4 and
 * Rosenbrock-W ROS34PW2.
 * No allocation, no globals: every vector lives in the caller's `work`; the only stack array is the pivot
 * vector of the (small, n <= a few dozen) iteration matrix, because `work` holds doubles only. */
#define _POSIX_C_SOURCE 200112L   /* clock_gettime: the wall-clock budget of a call */
#include "solver.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "linalg.h"

#define MAX_FAILS 15        /* consecutive failed evaluations (rhs/jac error, non-finite, singular W) per point */
#define SAFETY 0.9
#define FAC_SHRINK 0.2      /* smallest h_new/h after an error test */
/* A call's last step is stretched by up to this factor to land on t1 rather than taking two steps: the controller's
 * proposal carries SAFETY and the restart rule below, so a call a little longer than it usually passes the error
 * test in one step. Never a step cut at a switch (it must end there), one right after a rejection (it would fail
 * again), or a step of a model that holds modes over it (solver_structure.modes_held). Measured (hills3d,
 * ros34pw2 tol 1e-4): 2894 -> 2025 steps, CPU -19 %; 1.2 and 1.3 did about the same, 1.5 added rejections. */
#define LAST_STRETCH 1.25
#define FAIL_SHRINK 0.25    /* h_new/h after a failed evaluation: the step left the region where F is defined */
#define PI_BETA 0.04        /* Hairer's DOPRI5 PI controller (stabilizes h on the stability boundary) */

enum { EV_OK = 0, EV_FAILED, EV_NONFINITE, EV_JAC_FAILED, EV_JAC_NONFINITE, EV_SINGULAR, EV_EVENT };

static const char *ev_reason(int ev) {
    switch (ev) {
    case EV_FAILED: return "the right-hand side failed";
    case EV_NONFINITE: return "non-finite derivative or state";
    case EV_JAC_FAILED: return "the Jacobian failed";
    case EV_JAC_NONFINITE: return "non-finite Jacobian";
    case EV_SINGULAR: return "singular iteration matrix W";
    case EV_EVENT: return "an event inside the step (the step check)";
    default: return "error test failed";
    }
}

static void put_msg(char *msg, size_t len, const char *fmt, ...) {
    if (!msg || len == 0) return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, len, fmt, ap);
    va_end(ap);
}

/* seconds on a monotonic clock (the budget of one call; never part of a result) */
static double wall_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* 1 (message written) if the call has spent its wall-clock budget since `start` */
static int over_wall_budget(const solver_settings *s, double start, const char *name, long steps, double t,
                            double t1, char *msg, size_t msg_len) {
    double spent = wall_now() - start;
    if (spent <= s->max_wall) return 0;
    put_msg(msg, msg_len, "%s: the call's wall-clock budget of %g s is spent (%.3g s, %ld steps, reached t = %.15g "
            "of %.15g); raise solver.max_wall_time or shorten the communication step", name, s->max_wall, spent,
            steps, t, t1);
    return 1;
}

static int all_finite(int n, const double *v) {
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

/* One counted evaluation of F with the finiteness check every caller needs. */
static int eval(solver_rhs_fn rhs, void *ctx, double t, const double *x, double *xdot, int n, solver_stats *st) {
    st->rhs_evals++;
    if (rhs(ctx, t, x, xdot)) return EV_FAILED;
    return all_finite(n, xdot) ? EV_OK : EV_NONFINITE;
}

/* RMS of err_i / (tol + tol*max(|x_i|, |xnew_i|)): mixed absolute/relative test with a single tolerance. */
static double err_norm(int n, double tol, const double *err, const double *x, const double *xnew) {
    double s = 0;
    for (int i = 0; i < n; i++) {
        double sk = tol + tol * fmax(fabs(x[i]), fabs(xnew[i]));
        double r = err[i] / sk;
        s += r * r;
    }
    return n > 0 ? sqrt(s / n) : 0.0;
}

static double rms_scaled(int n, double tol, const double *v, const double *x) {
    double s = 0;
    for (int i = 0; i < n; i++) {
        double r = v[i] / (tol + tol * fabs(x[i]));
        s += r * r;
    }
    return n > 0 ? sqrt(s / n) : 0.0;
}

size_t solver_workspace_size(int method, int n) {
    size_t N = n > 0 ? (size_t)n : 0;
    switch (method) {
    case SOLVER_RK4: return 5 * N;                   /* k1..k4, stage state */
    case SOLVER_DOPRI5: return 9 * N;                /* k1..k7, stage state (then error), xnew */
    case SOLVER_RODAS4:                              /* f0, f_t, k1..k6, stage state, stage F; J, M, W */
    case SOLVER_ROS34PW2: return 10 * N + 3 * N * N; /* the same layout (k1..k4 and the error in k6's place) */
    case SOLVER_MOREAU: return N;                    /* the state before the step (a failed step is undone) */
    default: return 0;
    }
}

size_t solver_keep_size(int n, int n2) {
    return (size_t)(n > 0 ? n : 0) * (size_t)(n > 0 ? n : 0) + (size_t)(n2 > 0 ? n2 : 0) * (size_t)(n2 > 0 ? n2 : 0);
}

/* ------------------------------------------------------------------------------------------------------------- */
/* RK4: fixed step h_max; the last step is shortened so the interval is covered exactly. */

static int rk4(const solver_settings *s, int n, double *x, double t0, double t1, solver_rhs_fn rhs,
               solver_post_fn post, void *ctx, double *work, solver_stats *st, char *msg, size_t msg_len) {
    double *k1 = work, *k2 = k1 + n, *k3 = k2 + n, *k4 = k3 + n, *y = k4 + n;
    const double h = s->h_max, start = wall_now();
    /* The 1e-12 keeps an interval that is a multiple of h up to rounding (0.010000000000000009 / 0.001)
     * from getting a sliver step; a genuine remainder is never dropped, it becomes a shortened last step.
     * solver_check has bounded the count by max_steps, so the conversion is exact. */
    double ns = ceil((t1 - t0) / h - 1e-12);
    long nsteps = ns < 1 ? 1 : (long)ns;
    for (long k = 0; k < nsteps; k++) {
        if (k > 0 && over_wall_budget(s, start, "rk4", k, t0 + (double)k * h, t1, msg, msg_len)) return 1;
        /* t from t0 + k*h rather than accumulated sums, and the last step ends on t1 itself */
        double ta = t0 + (double)k * h, tb = (k == nsteps - 1) ? t1 : t0 + (double)(k + 1) * h, hs = tb - ta;
        int ev;
        if ((ev = eval(rhs, ctx, ta, x, k1, n, st)) != EV_OK) goto fail;
        for (int i = 0; i < n; i++) y[i] = x[i] + 0.5 * hs * k1[i];
        if ((ev = eval(rhs, ctx, ta + 0.5 * hs, y, k2, n, st)) != EV_OK) goto fail;
        for (int i = 0; i < n; i++) y[i] = x[i] + 0.5 * hs * k2[i];
        if ((ev = eval(rhs, ctx, ta + 0.5 * hs, y, k3, n, st)) != EV_OK) goto fail;
        for (int i = 0; i < n; i++) y[i] = x[i] + hs * k3[i];
        if ((ev = eval(rhs, ctx, tb, y, k4, n, st)) != EV_OK) goto fail;
        for (int i = 0; i < n; i++) y[i] = x[i] + hs / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
        if (!all_finite(n, y)) {
            put_msg(msg, msg_len, "rk4: non-finite state at t = %.15g (h = %.3g)", tb, hs);
            return 1;
        }
        memcpy(x, y, sizeof(double) * (size_t)n);   /* x changes only after a complete, finite step */
        st->steps++;
        if (post && post(ctx, tb, x) < 0) {
            put_msg(msg, msg_len, "rk4: the post-step projection failed at t = %.15g", tb);
            return 1;
        }
        continue;
    fail:
        if (ev == EV_FAILED)
            put_msg(msg, msg_len, "rk4: the right-hand side failed at t = %.15g (h = %.3g)", ta, hs);
        else
            put_msg(msg, msg_len, "rk4: non-finite state at t = %.15g (non-finite derivative, h = %.3g)", ta, hs);
        return 1;
    }
    return 0;
}

/* solver.method moreau: the model's own time stepper in fixed steps of h_max (the last one ends on t1) under the
 * same budgets as RK4; a step of its own is complete (no post-step callback) */
static int own_steps(const solver_settings *s, int n, double *x, double t0, double t1,
                     int (*step)(void *, double, double, double *), void *ctx, double *work, solver_stats *st,
                     char *msg, size_t msg_len) {
    if (!step) {
        put_msg(msg, msg_len, "moreau: this model has no time stepper of its own (rigid contact scenes have one)");
        return 1;
    }
    const double h = s->h_max, start = wall_now();
    /* an interval that is a multiple of h up to the rounding of t (0.01 s at t = 15 s is 0.01 +- 2e-15, 100 steps of
     * 1e-4 and 2e-11 of one) takes no sliver step: a remainder below 1e-9 steps stretches the last one */
    double ns = ceil((t1 - t0) / h - 1e-9);
    long nsteps = ns < 1 ? 1 : (long)ns;
    for (long k = 0; k < nsteps; k++) {
        if (k > 0 && over_wall_budget(s, start, "moreau", k, t0 + (double)k * h, t1, msg, msg_len)) return 1;
        double ta = t0 + (double)k * h, tb = (k == nsteps - 1) ? t1 : t0 + (double)(k + 1) * h;
        memcpy(work, x, sizeof(double) * (size_t)n);
        if (step(ctx, ta, tb - ta, x) || !all_finite(n, x)) {
            memcpy(x, work, sizeof(double) * (size_t)n);     /* x stays the last completed step's */
            put_msg(msg, msg_len, "moreau: the step from t = %.15g (h = %.3g) failed", ta, tb - ta);
            return 1;
        }
        st->steps++;
    }
    return 0;
}

/* ------------------------------------------------------------------------------------------------------------- */
/* Dormand & Prince 5(4), coefficients from Hairer, Norsett & Wanner, Solving ODE I, Table II.5.2 (dopri5.f). */

static const double dp_c2 = 1.0 / 5, dp_c3 = 3.0 / 10, dp_c4 = 4.0 / 5, dp_c5 = 8.0 / 9;
static const double dp_a21 = 1.0 / 5;
static const double dp_a31 = 3.0 / 40, dp_a32 = 9.0 / 40;
static const double dp_a41 = 44.0 / 45, dp_a42 = -56.0 / 15, dp_a43 = 32.0 / 9;
static const double dp_a51 = 19372.0 / 6561, dp_a52 = -25360.0 / 2187, dp_a53 = 64448.0 / 6561,
                    dp_a54 = -212.0 / 729;
static const double dp_a61 = 9017.0 / 3168, dp_a62 = -355.0 / 33, dp_a63 = 46732.0 / 5247, dp_a64 = 49.0 / 176,
                    dp_a65 = -5103.0 / 18656;
static const double dp_a71 = 35.0 / 384, dp_a73 = 500.0 / 1113, dp_a74 = 125.0 / 192, dp_a75 = -2187.0 / 6784,
                    dp_a76 = 11.0 / 84;
/* e = b(5th order) - b(4th order) */
static const double dp_e1 = 71.0 / 57600, dp_e3 = -71.0 / 16695, dp_e4 = 71.0 / 1920, dp_e5 = -17253.0 / 339200,
                    dp_e6 = 22.0 / 525, dp_e7 = -1.0 / 40;

/* DOPRI5 layout: k1..k7, y (stage state, then the error estimate), xnew. k1 = F(t, x) on entry; on success
 * k7 = F(t+h, xnew), the k1 of the next step (FSAL). */
#define DP_K(w, n, i) ((w) + (size_t)((i) - 1) * (n))
#define DP_ERR(w, n) ((w) + 7 * (size_t)(n))
#define DP_XNEW(w, n) ((w) + 8 * (size_t)(n))

static int dopri5_step(int n, const double *x, double t, double h, double tend, solver_rhs_fn rhs, void *ctx,
                       double *w, solver_stats *st) {
    double *k1 = DP_K(w, n, 1), *k2 = DP_K(w, n, 2), *k3 = DP_K(w, n, 3), *k4 = DP_K(w, n, 4), *k5 = DP_K(w, n, 5),
           *k6 = DP_K(w, n, 6), *k7 = DP_K(w, n, 7), *y = DP_ERR(w, n), *xnew = DP_XNEW(w, n);
    int ev;
    for (int i = 0; i < n; i++) y[i] = x[i] + h * dp_a21 * k1[i];
    if ((ev = eval(rhs, ctx, t + dp_c2 * h, y, k2, n, st))) return ev;
    for (int i = 0; i < n; i++) y[i] = x[i] + h * (dp_a31 * k1[i] + dp_a32 * k2[i]);
    if ((ev = eval(rhs, ctx, t + dp_c3 * h, y, k3, n, st))) return ev;
    for (int i = 0; i < n; i++) y[i] = x[i] + h * (dp_a41 * k1[i] + dp_a42 * k2[i] + dp_a43 * k3[i]);
    if ((ev = eval(rhs, ctx, t + dp_c4 * h, y, k4, n, st))) return ev;
    for (int i = 0; i < n; i++)
        y[i] = x[i] + h * (dp_a51 * k1[i] + dp_a52 * k2[i] + dp_a53 * k3[i] + dp_a54 * k4[i]);
    if ((ev = eval(rhs, ctx, t + dp_c5 * h, y, k5, n, st))) return ev;
    for (int i = 0; i < n; i++)
        y[i] = x[i] + h * (dp_a61 * k1[i] + dp_a62 * k2[i] + dp_a63 * k3[i] + dp_a64 * k4[i] + dp_a65 * k5[i]);
    if ((ev = eval(rhs, ctx, tend, y, k6, n, st))) return ev;
    for (int i = 0; i < n; i++)
        xnew[i] = x[i] + h * (dp_a71 * k1[i] + dp_a73 * k3[i] + dp_a74 * k4[i] + dp_a75 * k5[i] + dp_a76 * k6[i]);
    if (!all_finite(n, xnew)) return EV_NONFINITE;
    if ((ev = eval(rhs, ctx, tend, xnew, k7, n, st))) return ev;
    for (int i = 0; i < n; i++)   /* y is free again: it takes the error estimate */
        y[i] = h * (dp_e1 * k1[i] + dp_e3 * k3[i] + dp_e4 * k4[i] + dp_e5 * k5[i] + dp_e6 * k6[i] + dp_e7 * k7[i]);
    return EV_OK;
}

/* ------------------------------------------------------------------------------------------------------------- */
/* RODAS4 (Hairer & Wanner, Solving ODE II, Sec. VI.4, Table 4.? "RODAS"): coefficients copied from E. Hairer's
 * rodas.f (version of October 28, 1996; http://www.unige.ch/~hairer/prog/stiff/rodas.f), subroutine ROCOE, METH=1,
 * read from an f2c translation of that file in the public GitHub index. The stage formulation is the one of
 * rodas.f's ROSCOR (with IFCN=1, IDFX=0, identity mass matrix):
 *   (I/(h*gamma) - J) k_i = F(t + c_i h, x + sum_j a_ij k_j) + sum_j (c_ij/h) k_j + h d_i F_t
 * The last two stages evaluate at t+h with x5 = x + sum a_5j k_j, x6 = x5 + k5, and xnew = x6 + k6, so the method
 * is stiffly accurate (L-stable) and k6 is the difference to the embedded order-3 solution x6. */
static const double ro_gamma = 0.25;
static const double ro_c2 = 0.386, ro_c3 = 0.21, ro_c4 = 0.63;
static const double ro_d1 = 0.25, ro_d2 = -0.1043, ro_d3 = 0.1035, ro_d4 = -0.3620000000000023e-01;
static const double ro_a21 = 0.1544000000000000e+01;
static const double ro_a31 = 0.9466785280815826e+00, ro_a32 = 0.2557011698983284e+00;
static const double ro_a41 = 0.3314825187068521e+01, ro_a42 = 0.2896124015972201e+01,
                    ro_a43 = 0.9986419139977817e+00;
static const double ro_a51 = 0.1221224509226641e+01, ro_a52 = 0.6019134481288629e+01,
                    ro_a53 = 0.1253708332932087e+02, ro_a54 = -0.6878860361058950e+00;
static const double ro_c21 = -0.5668800000000000e+01;
static const double ro_c31 = -0.2430093356833875e+01, ro_c32 = -0.2063599157091915e+00;
static const double ro_c41 = -0.1073529058151375e+00, ro_c42 = -0.9594562251023355e+01,
                    ro_c43 = -0.2047028614809616e+02;
static const double ro_c51 = 0.7496443313967647e+01, ro_c52 = -0.1024680431464352e+02,
                    ro_c53 = -0.3399990352819905e+02, ro_c54 = 0.1170890893206160e+02;
static const double ro_c61 = 0.8083246795921522e+01, ro_c62 = -0.7981132988064893e+01,
                    ro_c63 = -0.3152159432874371e+02, ro_c64 = 0.1631930543123136e+02,
                    ro_c65 = -0.6058818238834054e+01;


/* The stage system (I/(h gamma) - J) k = r. With the second-order structure (n2 > 0) the Jacobian is
 * [[0, I, 0], [A, B, 0], [C, D, 0]] (x = [q, u, z]), and with c = 1/(h gamma) the rows read
 *   c kq - ku = rq,   -A kq + (c - B) ku = ru,   -C kq - D ku + c kz = rz,
 * so kq = (rq + ku)/c and the u rows become the n2 x n2 system S ku = c ru + A rq with S = c^2 I - c B - A (the
 * Schur complement of the q block), then kz = (rz + C kq + D ku)/c. One LU of n2 x n2 instead of n x n (2D rover:
 * 9 instead of 19, 3D: 15 instead of 31), and the solves shrink likewise. With mass rows (solver_structure) the u
 * rows hold M A and M B, and the system is solved as (M S) ku = c M ru + (M A) rq. */
size_t solver_stage_work_size(int n, int n2) {
    return n2 > 0 ? (size_t)n2 * (size_t)n2 + (size_t)n : (size_t)n * (size_t)n;
}

int solver_stage_factor(int n, int n2, double fac, const double *J, const double *M, double *work, int *piv) {
    if (n2 <= 0) {
        for (size_t k = 0; k < (size_t)n * n; k++) work[k] = -J[k];
        for (int i = 0; i < n; i++) work[i + (size_t)i * n] += fac;
        return linalg_lu_factor(n, work, piv);
    }
    /* S = c^2 I - c B - A, or with mass rows M S = c^2 M - c (M B) - (M A) from the rows as given */
    double *S = work;
    for (int j = 0; j < n2; j++)
        for (int i = 0; i < n2; i++) {
            double a = J[(size_t)(n2 + i) + (size_t)j * n], b = J[(size_t)(n2 + i) + (size_t)(n2 + j) * n];
            double m = M ? M[i + (size_t)j * n2] : (i == j ? 1.0 : 0.0);
            S[i + (size_t)j * n2] = -fac * b - a + fac * fac * m;
        }
    return linalg_lu_factor(n2, S, piv);
}

void solver_stage_solve(int n, int n2, double fac, const double *J, const double *M, double *work, const int *piv,
                        double *r) {
    if (n2 <= 0) {
        linalg_lu_solve(n, work, piv, r);
        return;
    }
    const double *S = work;
    double *rq = r, *ru = r + n2, *rz = r + 2 * n2, *t = work + (size_t)n2 * n2;
    const int nz = n - 2 * n2;
    if (M) {                                                        /* c M ru */
        for (int i = 0; i < n2; i++) t[i] = 0.0;
        for (int j = 0; j < n2; j++) {
            const double *col = M + (size_t)j * n2;
            double rj = fac * ru[j];
            for (int i = 0; i < n2; i++) t[i] += col[i] * rj;
        }
    } else {
        for (int i = 0; i < n2; i++) t[i] = fac * ru[i];
    }
    for (int j = 0; j < n2; j++) {                                  /* + A rq (M A with mass rows), column by column */
        const double *col = J + (size_t)j * n + n2;
        double rj = rq[j];
        if (rj == 0.0) continue;
        for (int i = 0; i < n2; i++) t[i] += col[i] * rj;
    }
    linalg_lu_solve(n2, S, piv, t);                                 /* ku */
    for (int i = 0; i < n2; i++) {
        rq[i] = (rq[i] + t[i]) / fac;                               /* kq */
        ru[i] = t[i];
    }
    for (int i = 0; i < nz; i++) {
        double acc = rz[i];
        for (int j = 0; j < 2 * n2; j++) acc += J[(size_t)(2 * n2 + i) + (size_t)j * n] * r[j];
        rz[i] = acc / fac;                                          /* kz */
    }
}

/* RODAS4 layout: f0, ft, k1..k6, y (stage state, then the embedded solution), dy (stage F, then xnew); J; W.
 * The error estimate is k6 = xnew - x_embedded. */
#define RO_F0(w, n) (w)
#define RO_FT(w, n) ((w) + (size_t)(n))
#define RO_K(w, n, i) ((w) + (size_t)((i) + 1) * (n))
#define RO_ERR(w, n) RO_K(w, n, 6)
#define RO_Y(w, n) ((w) + 8 * (size_t)(n))
#define RO_XNEW(w, n) ((w) + 9 * (size_t)(n))
#define RO_J(w, n) ((w) + 10 * (size_t)(n))
#define RO_M(w, n) ((w) + 10 * (size_t)(n) + (size_t)(n) * (n))
#define RO_W(w, n) ((w) + 10 * (size_t)(n) + 2 * (size_t)(n) * (n))

/* The Jacobian at (t, x) into J (with mass rows, M beside it at J + n n) and dF/dt into f_t, f0 = F(t, x) known.
 * dF/dt by a forward difference, as rodas.f does for a non-autonomous F without DFX (IDFX=0), at the price of one F
 * per step: without the d_i terms the methods drop to order 1 in an explicit time dependence. For an autonomous F it
 * is exactly 0 (solver_structure.autonomous: not evaluated). Backward if t + delta would pass t1, where inputs end. */
static int jacobian_at(int n, const solver_structure *sp, const double *x, double t, double tmax, solver_rhs_fn rhs,
                       solver_jac_fn jac, void *ctx, double *w, double *J, solver_stats *st) {
    double *f0 = RO_F0(w, n), *ft = RO_FT(w, n), *tmp = RO_XNEW(w, n);
    int ev;
    st->jac_evals++;
    if (jac(ctx, t, x, f0, J)) return EV_JAC_FAILED;
    if (!all_finite(n * n, J)) return EV_JAC_NONFINITE;
    if (sp->mass_rows && !all_finite(sp->n2 * sp->n2, J + (size_t)n * n)) return EV_JAC_NONFINITE;
    if (sp->autonomous) {
        for (int i = 0; i < n; i++) ft[i] = 0.0;
        return EV_OK;
    }
    double delt = sqrt(2.220446049250313e-16 * fmax(1e-5, fabs(t)));
    if (t + delt > tmax) delt = -delt;
    if ((ev = eval(rhs, ctx, t + delt, x, tmp, n, st))) return ev;
    for (int i = 0; i < n; i++) ft[i] = (tmp[i] - f0[i]) / delt;
    return EV_OK;
}

/* Data at the start of a RODAS4 step: F, the Jacobian and F_t at (t, x); kept when a step is rejected (a retry
 * from the same point, whatever its h, refactors only the n2 x n2 stage matrix: the Jacobian is reused).
 * RODAS4 does not reuse a Jacobian ACROSS accepted steps: its order conditions assume the exact Jacobian at the
 * step's start (it is not a W-method). The method that keeps one is ROS34PW2 below (solver.method 3). */
static int rodas4_start(int n, const solver_structure *sp, const double *x, double t, double tmax,
                        solver_rhs_fn rhs, solver_jac_fn jac, void *ctx, double *w, solver_stats *st) {
    int ev;
    if ((ev = eval(rhs, ctx, t, x, RO_F0(w, n), n, st))) return ev;
    return jacobian_at(n, sp, x, t, tmax, rhs, jac, ctx, w, RO_J(w, n), st);
}

static int rodas4_step(int n, const solver_structure *sp, const double *x, double t, double h, double tend,
                       solver_rhs_fn rhs, void *ctx, double *w, solver_stats *st) {
    double *f0 = RO_F0(w, n), *ft = RO_FT(w, n), *k1 = RO_K(w, n, 1), *k2 = RO_K(w, n, 2), *k3 = RO_K(w, n, 3),
           *k4 = RO_K(w, n, 4), *k5 = RO_K(w, n, 5), *k6 = RO_K(w, n, 6), *y = RO_Y(w, n), *dy = RO_XNEW(w, n),
           *J = RO_J(w, n), *W = RO_W(w, n);
    const int n2 = sp->n2;
    const double *M = sp->mass_rows ? RO_M(w, n) : NULL;
    int piv[n];   /* VLA: work holds doubles only, and n is a few dozen at most */
    int ev;
    /* W = I/(h*gamma) - J, factored once (reduced to n2 x n2 with the second-order structure) for all six stages */
    const double fac = 1.0 / (h * ro_gamma);
    if (solver_stage_factor(n, n2, fac, J, M, W, piv)) return EV_SINGULAR;

    for (int i = 0; i < n; i++) k1[i] = f0[i] + h * ro_d1 * ft[i];
    solver_stage_solve(n, n2, fac, J, M, W, piv, k1);

    for (int i = 0; i < n; i++) y[i] = x[i] + ro_a21 * k1[i];
    if ((ev = eval(rhs, ctx, t + ro_c2 * h, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++) k2[i] = dy[i] + h * ro_d2 * ft[i] + ro_c21 * k1[i] / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, k2);

    for (int i = 0; i < n; i++) y[i] = x[i] + ro_a31 * k1[i] + ro_a32 * k2[i];
    if ((ev = eval(rhs, ctx, t + ro_c3 * h, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++) k3[i] = dy[i] + h * ro_d3 * ft[i] + (ro_c31 * k1[i] + ro_c32 * k2[i]) / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, k3);

    for (int i = 0; i < n; i++) y[i] = x[i] + ro_a41 * k1[i] + ro_a42 * k2[i] + ro_a43 * k3[i];
    if ((ev = eval(rhs, ctx, t + ro_c4 * h, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++)
        k4[i] = dy[i] + h * ro_d4 * ft[i] + (ro_c41 * k1[i] + ro_c42 * k2[i] + ro_c43 * k3[i]) / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, k4);

    /* stages 5 and 6 sit at t+h with d5 = d6 = 0 (rodas.f passes HD = 0) */
    for (int i = 0; i < n; i++) y[i] = x[i] + ro_a51 * k1[i] + ro_a52 * k2[i] + ro_a53 * k3[i] + ro_a54 * k4[i];
    if ((ev = eval(rhs, ctx, tend, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++)
        k5[i] = dy[i] + (ro_c51 * k1[i] + ro_c52 * k2[i] + ro_c53 * k3[i] + ro_c54 * k4[i]) / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, k5);

    for (int i = 0; i < n; i++) y[i] += k5[i];   /* the embedded order-3 solution */
    if (!all_finite(n, y)) return EV_NONFINITE;
    if ((ev = eval(rhs, ctx, tend, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++)
        k6[i] = dy[i] + (ro_c61 * k1[i] + ro_c62 * k2[i] + ro_c63 * k3[i] + ro_c64 * k4[i] + ro_c65 * k5[i]) / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, k6);

    for (int i = 0; i < n; i++) dy[i] = y[i] + k6[i];   /* dy becomes xnew */
    return all_finite(n, dy) ? EV_OK : EV_NONFINITE;
}

/* ------------------------------------------------------------------------------------------------------------- */
/* ROS34PW2 (Rang & Angermann 2005): a Rosenbrock-W method, 4 stages, order 3 with an embedded order 2, L-stable and
 * stiffly accurate. A W-method keeps its order with ANY matrix in place of the Jacobian, so the Jacobian can be kept
 * over many steps (and communication steps): a step then costs 4 evaluations of F, one n2 x n2 factorization and 4
 * stage solves, where a RODAS4 step costs 6 F, a Jacobian, a factorization and 6 solves. An outdated Jacobian only
 * costs stability margin, which the error test watches: a step rejected with an outdated Jacobian is retried with a
 * fresh one. Coefficients in the transformed form of Hairer & Wanner (IV.7.25), as RODAS4's above, computed from
 * the published tableau (gamma, alpha_ij, gamma_ij, b, b_hat): a' = A Gamma^-1, c' = diag(1/gamma) - Gamma^-1,
 * m = b Gamma^-1 (= row 4 of a' plus e_4: stiffly accurate), e = (b - b_hat) Gamma^-1; d_i = the row sums of
 * Gamma (the dF/dt terms). */
static const double rw_gamma = 4.3586652150845900e-01;
static const double rw_c2 = 8.7173304301691801e-01, rw_c3 = 7.3157995778885238e-01;
static const double rw_d1 = 4.3586652150845900e-01, rw_d2 = -4.3586652150845900e-01, rw_d3 = -4.1333337623388650e-01;
static const double rw_a21 = 2.0;
static const double rw_a31 = 1.4192173174557652e+00, rw_a32 = -2.5923221167296978e-01;
static const double rw_a41 = 4.1847604823191613e+00, rw_a42 = -2.8519201735549599e-01, rw_a43 = 2.2942803602790423e+00;
static const double rw_c21 = -4.5885607205580836e+00;
static const double rw_c31 = -4.1847604823191613e+00, rw_c32 = 2.8519201735549599e-01;
static const double rw_c41 = -6.3681792001283597e+00, rw_c42 = -6.7956209444668367e+00, rw_c43 = 2.8700986043310555e+00;
static const double rw_e1 = 2.7774994764796900e-01, rw_e2 = -1.4032398951759988e+00, rw_e3 = 1.7726301276675507e+00,
                    rw_e4 = 0.5;
/* a kept Jacobian is renewed after this many steps even if no step was rejected */
#define W_MAX_AGE 50

/* a fresh Jacobian (and dF/dt) for ROS34PW2, f0 = F(t, x) known: jac_age = 1 (0 if it failed) */
static int w_fresh_jacobian(int n, const solver_structure *sp, const double *x, double t, double tmax,
                            solver_rhs_fn rhs, solver_jac_fn jac, void *ctx, double *w, double *J, solver_stats *st) {
    int ev = jacobian_at(n, sp, x, t, tmax, rhs, jac, ctx, w, J, st);
    st->jac_age = ev == EV_OK;
    return ev;
}

/* F at the step's start, and the Jacobian: the kept one while it may be (autonomous F, younger than W_MAX_AGE
 * steps), else a fresh one. A non-autonomous F gets a fresh one every step (dF/dt belongs to the step's start). */
static int w_start(int n, const solver_structure *sp, const double *x, double t, double tmax, solver_rhs_fn rhs,
                   solver_jac_fn jac, void *ctx, double *w, double *J, solver_stats *st) {
    int ev;
    if ((ev = eval(rhs, ctx, t, x, RO_F0(w, n), n, st))) return ev;
    if (sp->autonomous && st->jac_age > 0 && st->jac_age < W_MAX_AGE) {
        st->jac_age++;
        for (int i = 0; i < n; i++) RO_FT(w, n)[i] = 0.0;
        return EV_OK;
    }
    return w_fresh_jacobian(n, sp, x, t, tmax, rhs, jac, ctx, w, J, st);
}

static int ros34pw2_step(int n, const solver_structure *sp, const double *x, double t, double h, double tend,
                         solver_rhs_fn rhs, void *ctx, double *w, const double *J, solver_stats *st) {
    double *f0 = RO_F0(w, n), *ft = RO_FT(w, n), *u1 = RO_K(w, n, 1), *u2 = RO_K(w, n, 2), *u3 = RO_K(w, n, 3),
           *u4 = RO_K(w, n, 4), *err = RO_ERR(w, n), *y = RO_Y(w, n), *dy = RO_XNEW(w, n), *W = RO_W(w, n);
    const int n2 = sp->n2;
    const double *M = sp->mass_rows ? J + (size_t)n * n : NULL;
    int piv[n];
    int ev;
    const double fac = 1.0 / (h * rw_gamma);
    if (solver_stage_factor(n, n2, fac, J, M, W, piv)) return EV_SINGULAR;

    for (int i = 0; i < n; i++) u1[i] = f0[i] + h * rw_d1 * ft[i];
    solver_stage_solve(n, n2, fac, J, M, W, piv, u1);

    for (int i = 0; i < n; i++) y[i] = x[i] + rw_a21 * u1[i];
    if ((ev = eval(rhs, ctx, t + rw_c2 * h, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++) u2[i] = dy[i] + h * rw_d2 * ft[i] + rw_c21 * u1[i] / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, u2);

    for (int i = 0; i < n; i++) y[i] = x[i] + rw_a31 * u1[i] + rw_a32 * u2[i];
    if ((ev = eval(rhs, ctx, t + rw_c3 * h, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++) u3[i] = dy[i] + h * rw_d3 * ft[i] + (rw_c31 * u1[i] + rw_c32 * u2[i]) / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, u3);

    /* stage 4 at t + h (d4 = 0) */
    for (int i = 0; i < n; i++) y[i] = x[i] + rw_a41 * u1[i] + rw_a42 * u2[i] + rw_a43 * u3[i];
    if (!all_finite(n, y)) return EV_NONFINITE;
    if ((ev = eval(rhs, ctx, tend, y, dy, n, st))) return ev;
    for (int i = 0; i < n; i++) u4[i] = dy[i] + (rw_c41 * u1[i] + rw_c42 * u2[i] + rw_c43 * u3[i]) / h;
    solver_stage_solve(n, n2, fac, J, M, W, piv, u4);

    for (int i = 0; i < n; i++) {
        dy[i] = y[i] + u4[i];                                         /* xnew (stiffly accurate) */
        err[i] = rw_e1 * u1[i] + rw_e2 * u2[i] + rw_e3 * u3[i] + rw_e4 * u4[i];   /* xnew - x_embedded */
    }
    return all_finite(n, dy) ? EV_OK : EV_NONFINITE;
}

/* ------------------------------------------------------------------------------------------------------------- */
/* Shared adaptive driver for DOPRI5, RODAS4 and ROS34PW2. */

/* Hairer's HINIT (dopri5.f): an explicit Euler probe estimates the second derivative; h is chosen so that
 * h^order * max(|x''|, |x'|) ~ 0.01 in the tolerance-scaled norm. f0 = F(t, x). */
static double initial_step(int n, int n_err, const double *x, double t, const double *f0, double tol, double hmax,
                           double span, int order, solver_rhs_fn rhs, void *ctx, double *y1, double *f1,
                           solver_stats *st) {
    double dnf = rms_scaled(n_err, tol, f0, x), dny = rms_scaled(n_err, tol, x, x);
    double h = (dnf <= 1e-10 || dny <= 1e-10) ? 1e-6 : 0.01 * dny / dnf;
    h = fmin(h, fmin(hmax, span));   /* the probe stays inside [t0, t1]: F may not be defined beyond */
    for (int i = 0; i < n; i++) y1[i] = x[i] + h * f0[i];
    if (eval(rhs, ctx, t + h, y1, f1, n, st) != EV_OK) return h;   /* the step control takes over from here */
    for (int i = 0; i < n; i++) f1[i] -= f0[i];
    double der2 = rms_scaled(n_err, tol, f1, x) / h;
    double der12 = fmax(der2, dnf);
    double h1 = der12 <= 1e-15 ? fmax(1e-6, h * 1e-3) : pow(0.01 / der12, 1.0 / order);
    return fmin(fmin(100 * h, h1), hmax);
}

static int adaptive(const solver_settings *s, int n, const solver_structure *sp, double *x, double t0, double t1,
                    solver_rhs_fn rhs, solver_jac_fn jac, solver_accept_fn accept, solver_locate_fn locate,
                    solver_post_fn post, void *ctx, double *w, double *keep, solver_stats *st, char *msg,
                    size_t msg_len) {
    const int dopri = s->method == SOLVER_DOPRI5, wmeth = s->method == SOLVER_ROS34PW2;
    const int n_err = n - sp->quad_tail;     /* the components the error test weighs */
    const char *name = dopri ? "dopri5" : wmeth ? "ros34pw2" : "rodas4";
    /* The error estimate is O(h^(q+1)), q the lower of the two orders: 4 for DOPRI5, 3 for RODAS4, 2 for
     * ROS34PW2. */
    const double expo = dopri ? 1.0 / 5 : wmeth ? 1.0 / 3 : 1.0 / 4;
    /* ROS34PW2's Jacobian: kept in the caller's memory across calls, else in the workspace for this call only */
    double *Jw = keep ? keep : RO_J(w, n);
    int w_refresh = 0;      /* the last step was rejected with a kept (older) Jacobian: the retry gets a fresh one */
    if (wmeth && !keep) st->jac_age = 0;
    const double grow_max = dopri ? 10.0 : 5.0;
    const double tol = s->tol, hmax = s->h_max;
    double *f0 = w;   /* F(t, x) is the first block in both layouts */
    double *xnew = dopri ? DP_XNEW(w, n) : RO_XNEW(w, n), *errv = dopri ? DP_ERR(w, n) : RO_ERR(w, n);

    double t = t0, h, facold = 1e-4;
    const double start = wall_now();
    int have_start = 0, fails = 0, rejected_last = 0, last_ev = -1;
    /* a step cut at a switch (locate): retried with exactly that length (located), and the proposal before the
     * cut (h_uncut) is restored after it is accepted, so that a switch costs no slow regrowth of h */
    int located = 0;
    double h_uncut = 0;
    /* The step-size proposal after this call's first accepted step (no growth if rejections preceded it). A call
     * starts where the importer may have changed the inputs (the main job's controller changes the torques every
     * 0.01 s); the jump excites the wheels' fast slip transients (friction with v_eps = 0.01 m/s), which only a
     * short first step resolves. Carrying the previous call's last proposal into that restart cost 7-8 rejected
     * steps per call on the bump (measured: the rejections sat at the communication points, with the error
     * estimate falling like h). The next call therefore starts from this call's restart size; the step then grows
     * again by up to grow_max per step. */
    double h_restart = 0;
    long attempts_before_first = -1;
    long attempts = 0;

    if (st->h_next > 0 && isfinite(st->h_next)) {
        h = fmin(st->h_next, hmax);
    } else {
        int ev = dopri ? eval(rhs, ctx, t, x, f0, n, st)
                 : wmeth ? w_start(n, sp, x, t, t1, rhs, jac, ctx, w, Jw, st)
                         : rodas4_start(n, sp, x, t, t1, rhs, jac, ctx, w, st);
        have_start = ev == EV_OK;
        /* scratch for the probe: k4, k5 (DOPRI5) or k2, k3 (RODAS4, ROS34PW2) - never f0, f_t, J */
        h = have_start ? initial_step(n, n_err, x, t, f0, tol, hmax, t1 - t, dopri ? 5 : wmeth ? 3 : 4, rhs, ctx,
                                      w + 3 * (size_t)n, w + 4 * (size_t)n, st)
                       : fmin(hmax, 1e-6 * fmax(1.0, t1 - t0));
    }

    for (;;) {
        const double rem = t1 - t, hprop = fmin(h, hmax), hmin = solver_time_resolution(t);
        double hs;
        int last = 0, ev;
        /* Land on t1 exactly, stretching the step by up to LAST_STRETCH (and never beyond h_max); the 1e-9 only
         * absorbs rounding in t so that a multiple of h_max takes no extra sliver step. A remainder between one
         * and two steps is split evenly for the same reason. */
        const double stretch = located || rejected_last || (sp && sp->modes_held)
                                   ? 1 + 1e-9 : fmin(LAST_STRETCH, hmax / hprop * (1 + 1e-9));
        if (rem <= hprop * stretch) {
            hs = rem;
            last = 1;
        } else if (located) {
            hs = hprop;
        } else if (rem < 2 * hprop) {
            hs = 0.5 * rem;
        } else {
            hs = hprop;
        }
        if (!last && hs < hmin) goto underflow;
        if (++attempts > s->max_steps) {
            put_msg(msg, msg_len, "%s: too many steps (more than solver.max_steps = %ld in one call) at t = %.15g "
                    "(h = %.3g)", name, s->max_steps, t, hs);
            return 1;
        }
        if (attempts > 1 && over_wall_budget(s, start, name, attempts - 1, t, t1, msg, msg_len)) return 1;
        const double tend = last ? t1 : t + hs;

        ev = EV_OK;
        if (!have_start) {
            ev = dopri ? eval(rhs, ctx, t, x, f0, n, st)
                 : wmeth ? w_start(n, sp, x, t, t1, rhs, jac, ctx, w, Jw, st)
                         : rodas4_start(n, sp, x, t, t1, rhs, jac, ctx, w, st);
            have_start = ev == EV_OK;
            w_refresh = 0;
        } else if (w_refresh) {
            ev = w_fresh_jacobian(n, sp, x, t, t1, rhs, jac, ctx, w, Jw, st);
            w_refresh = 0;
        }
        if (ev == EV_OK)
            ev = dopri ? dopri5_step(n, x, t, hs, tend, rhs, ctx, w, st)
                 : wmeth ? ros34pw2_step(n, sp, x, t, hs, tend, rhs, ctx, w, Jw, st)
                         : rodas4_step(n, sp, x, t, hs, tend, rhs, ctx, w, st);
        double err = ev == EV_OK ? err_norm(n_err, tol, errv, x, xnew) : 0.0;
        if (ev == EV_OK && isnan(err)) ev = EV_NONFINITE;

        if (ev != EV_OK) {
            /* F (or J) could not be evaluated along this step: retry a much shorter one, a bounded number of
             * times; the step that failed says nothing about the local error, so no controller update */
            st->rejected++;
            rejected_last = 1;
            last_ev = ev;
            if (wmeth && st->jac_age > 1) w_refresh = 1;
            if (++fails > MAX_FAILS) {
                put_msg(msg, msg_len, "%s: %s %d times in a row at t = %.15g (h = %.3g)", name, ev_reason(ev),
                        fails, t, hs);
                return 1;
            }
            h = hs * FAIL_SHRINK;
            located = 0;
            h_uncut = 0;
            if (h < hmin) goto underflow;
            continue;
        }
        fails = 0;
        int crossed = 0;     /* the step crosses a switch and is at most the location tolerance long */
        if (!(err <= 1.0) && locate) {
            /* A step across a switch (a force law's jump) fails the error test at any length: cut it at the switch
             * instead of shrinking it toward the switch until the step size underflows. A step that cannot be
             * evaluated for its switches (a wild trial state) is just rejected. */
            double len = locate(ctx, t, x, tend, xnew);
            if (len == HUGE_VAL) {
                crossed = 1;
                err = 1.0;        /* accepted: the error is the jump times a step of at most the tolerance */
            } else if (len >= 0 && len < (tend - t) * (1 - 1e-9) &&
                       len <= hs * fmax(FAC_SHRINK, SAFETY * pow(err, -expo))) {
                /* (only a cut no longer than the error control's own retry: a trial state past the switch that
                 * failed the test for another reason must still shrink, or the same cut would repeat forever) */
                st->rejected++;
                rejected_last = 1;
                last_ev = EV_EVENT;
                h_uncut = fmax(h_uncut, located ? 0 : hs);
                located = 1;
                h = fmax(len, hmin);
                continue;
            }
        }
        if (!(err <= 1.0)) {
            st->rejected++;
            rejected_last = 1;
            last_ev = 0;
            if (wmeth && st->jac_age > 1) w_refresh = 1;
            located = 0;
            h_uncut = 0;
            h = hs * fmax(FAC_SHRINK, SAFETY * pow(err, -expo));
            if (h < hmin) goto underflow;
            continue;
        }

        if (accept && !crossed) {
            double factor = accept(ctx, t, x, tend, xnew);
            if (factor < 0) {
                put_msg(msg, msg_len, "%s: the step check failed at t = %.15g", name, tend);
                return 1;
            }
            if (factor < 1) {             /* an event inside the step: retry a shorter one, no error feedback */
                st->rejected++;
                rejected_last = 1;
                last_ev = EV_EVENT;
                h = hs * fmax(0.01, factor);
                located = 0;
                h_uncut = 0;
                if (h < hmin) goto underflow;
                continue;
            }
        }
        if (locate && !crossed) {
            double len = locate(ctx, t, x, tend, xnew);
            if (len == HUGE_VAL) len = tend - t;   /* located: accept */
            if (!(len >= 0)) {
                put_msg(msg, msg_len, "%s: the switch location failed at t = %.15g", name, tend);
                return 1;
            }
            if (len < (tend - t) * (1 - 1e-9)) {   /* a switch inside the step: retry ending at it */
                st->rejected++;
                rejected_last = 1;
                last_ev = EV_EVENT;
                h_uncut = fmax(h_uncut, hs);
                located = 1;
                h = fmax(len, hmin);
                continue;
            }
        }

        /* accepted: propose the next step */
        /* a force law switched at this step's end (a touchdown, a stop): the kept Jacobian is the other law's */
        if (wmeth && (located || crossed)) st->jac_age = 0;
        double q;   /* h / h_new */
        if (dopri) {
            q = pow(err, expo - 0.75 * PI_BETA) / pow(facold, PI_BETA) / SAFETY;
            facold = fmax(err, 1e-4);
        } else {
            q = pow(err, expo) / SAFETY;
        }
        q = fmax(1.0 / grow_max, fmin(1.0 / FAC_SHRINK, q));
        if (rejected_last && q < 1) q = 1;   /* no growth right after a rejection */
        double hnew = hs / q;
        /* a step shortened only to reach t1 (or to split the remainder) does not lower the proposal */
        if (hs < hprop && q <= 1 && !located) hnew = fmax(hnew, hprop);
        if (located) hnew = fmax(hnew, h_uncut);   /* a cut at a switch does not lower the proposal */
        located = 0;
        h_uncut = 0;
        h = fmin(hnew, hmax);

        memcpy(x, xnew, sizeof(double) * (size_t)n);
        t = tend;
        st->steps++;
        if (attempts_before_first < 0) {      /* this call's restart: its first accepted step */
            attempts_before_first = attempts - 1;
            h_restart = h;                        /* the controller's proposal after it */
        }
        st->h_next = h_restart > 0 ? fmin(h, h_restart) : h;
        rejected_last = 0;
        last_ev = -1;
        if (dopri)
            memcpy(f0, DP_K(w, n, 7), sizeof(double) * (size_t)n);   /* FSAL */
        else
            have_start = 0;
        if (post) {
            int pr = post(ctx, t, x);
            if (pr < 0) {
                put_msg(msg, msg_len, "%s: the post-step projection failed at t = %.15g", name, t);
                return 1;
            }
            if (pr > 0) have_start = 0;   /* x moved: F(t, x) (FSAL) is stale */
        }
        if (last) return 0;
    }

underflow:
    put_msg(msg, msg_len, "%s: step size underflow (h = %.3g) at t = %.15g%s%s", name, h, t,
            last_ev >= 0 ? "; last rejection: " : "", last_ev >= 0 ? ev_reason(last_ev) : "");
    return 1;
}

/* ------------------------------------------------------------------------------------------------------------- */

int solver_integrate(const solver_settings *s, int n, double *x, double t0, double t1, solver_rhs_fn rhs,
                     solver_jac_fn jac, void *ctx, double *work, solver_stats *stats, char *msg, size_t msg_len) {
    return solver_integrate_post(s, n, x, t0, t1, rhs, jac, NULL, NULL, NULL, ctx, work, stats, msg, msg_len, NULL,
                                 NULL);
}

double solver_locate_switches(int nsw, const double *s0, const double *s1, double t, double t_new, double loc_tol,
                              int *which) {
    const double len = t_new - t;
    double first = HUGE_VAL;
    if (which) *which = -1;
    for (int i = 0; i < nsw; i++) {
        if (!((s0[i] > 0 && s1[i] <= 0) || (s0[i] < 0 && s1[i] >= 0))) continue;
        double at = len * s0[i] / (s0[i] - s1[i]);    /* linear interpolation of s over the step */
        if (at < first) {
            first = at;
            if (which) *which = i;
        }
    }
    if (first == HUGE_VAL) return len;
    /* (t + loc_tol) - t is loc_tol only up to rounding in t: a step of loc_tol is "at most loc_tol" */
    if (len <= loc_tol * (1 + 1e-3)) return HUGE_VAL;
    /* More than loc_tol ahead: end a quarter of loc_tol short of the estimate (the next step then starts within
     * loc_tol of the switch, where the estimate is accurate); within loc_tol: a step of loc_tol crosses it. A cut
     * that would shorten the step by no more than loc_tol is none: the step already ends within loc_tol of the
     * crossing (retrying it a hair shorter would find the estimate at its end again, and creep: an s that jumps,
     * such as a contact slot that begins to hold a newborn maximum, always puts the estimate there). */
    const double cut = first > loc_tol ? first - 0.25 * loc_tol : loc_tol;
    return len - cut <= loc_tol ? len : cut;
}

double solver_time_resolution(double t) { return 1e-12 * fmax(1.0, fabs(t)); }

int solver_check(const solver_settings *s, double t0, double t1, char *msg, size_t msg_len) {
    static const char *const names[SOLVER_N_METHODS] = {"rk4", "dopri5", "rodas4", "ros34pw2", "moreau"};
    if (msg && msg_len) msg[0] = '\0';
    if (s->method < 0 || s->method >= SOLVER_N_METHODS) {
        put_msg(msg, msg_len, "solver: unknown method %d", s->method);
        return 1;
    }
    const char *name = names[s->method];
    if (!(t1 >= t0) || !isfinite(t0) || !isfinite(t1)) {
        put_msg(msg, msg_len, "%s: invalid interval [%.15g, %.15g]", name, t0, t1);
        return 1;
    }
    if (!(s->h_max > 0) || !isfinite(s->h_max)) {
        put_msg(msg, msg_len, "%s: h_max must be positive and finite (h_max = %g)", name, s->h_max);
        return 1;
    }
    if (s->method != SOLVER_RK4 && s->method != SOLVER_MOREAU && !(s->tol > 0)) {
        put_msg(msg, msg_len, "%s: tol must be positive (tol = %g)", name, s->tol);
        return 1;
    }
    if (!(s->max_steps >= 1)) {
        put_msg(msg, msg_len, "%s: max_steps must be >= 1 (max_steps = %ld)", name, s->max_steps);
        return 1;
    }
    if (!(s->max_wall > 0) || !isfinite(s->max_wall)) {
        put_msg(msg, msg_len, "%s: max_wall must be positive and finite (max_wall = %g)", name, s->max_wall);
        return 1;
    }
    /* every method takes at least (t1 - t0) / h_max steps: refuse what cannot fit the budget before any work */
    double least = ceil((t1 - t0) / s->h_max - 1e-12);
    if (least > (double)s->max_steps) {
        put_msg(msg, msg_len, "%s: the interval of %.15g s needs at least %.3g steps of solver.h_max = %g s, more "
                "than solver.max_steps = %ld", name, t1 - t0, least, s->h_max, s->max_steps);
        return 1;
    }
    return 0;
}

int solver_integrate_post(const solver_settings *s, int n, double *x, double t0, double t1, solver_rhs_fn rhs,
                          solver_jac_fn jac, solver_accept_fn accept, solver_locate_fn locate, solver_post_fn post,
                          void *ctx, double *work, solver_stats *stats, char *msg, size_t msg_len,
                          const solver_structure *structure, double *keep) {
    if (solver_check(s, t0, t1, msg, msg_len)) return 1;
    if ((s->method == SOLVER_RODAS4 || s->method == SOLVER_ROS34PW2) && !jac) {
        put_msg(msg, msg_len, "%s: no Jacobian function", s->method == SOLVER_RODAS4 ? "rodas4" : "ros34pw2");
        return 1;
    }
    if (n <= 0 || t1 == t0) return 0;   /* nothing to integrate */
    if (s->method == SOLVER_RK4) return rk4(s, n, x, t0, t1, rhs, post, ctx, work, stats, msg, msg_len);
    solver_structure sp = {0, 0, 0, 0, 0, NULL};
    if (structure) sp = *structure;
    if (s->method == SOLVER_MOREAU) return own_steps(s, n, x, t0, t1, sp.own_step, ctx, work, stats, msg, msg_len);
    if (sp.quad_tail < 0 || sp.quad_tail >= n) sp.quad_tail = 0;   /* not a tail x can have: none */
    /* rows premultiplied by M cannot be read without the structure they belong to */
    if (sp.mass_rows && (sp.n2 <= 0 || 2 * sp.n2 > n)) {
        put_msg(msg, msg_len, "solver: mass rows without a second-order structure (n2 = %d, n = %d)", sp.n2, n);
        return 1;
    }
    if (sp.n2 < 0 || 2 * sp.n2 > n) sp.n2 = 0;   /* not a structure x can have: none */
    return adaptive(s, n, &sp, x, t0, t1, rhs, jac, accept, locate, post, ctx, work, keep, stats, msg, msg_len);
}
