/* The contacts of a wheel on an analytic terrain (docs: the model, several contacts per wheel): the local maxima
 * of g(beta) = f(p_X, p_Y) - p_Z on the lower half rim and the saddles between neighbouring maxima.
 *
 * cedra_rim_search is a CasADi external function: (x[15] = [wheel center c, unit axle a, radius R, the terrain's
 * inputs padded to 8]) -> (r[8] = [beta of maxima 1..3, beta of saddles 1..2, presence of maxima 1..3]). The
 * model (cedra.mechanics.contact.rim_contacts) stands free symbols in for r while it takes derivatives and puts
 * this function back afterwards: a maximum's angle enters as b - g'(b)/g''(b) and a saddle through g alone, so
 * derivatives need nothing from here (implicit function theorem; jac_cedra_rim_search is zero, exact at
 * convergence). The terrain is the scene's generated cedra_terrain: (xy[2], tin[8]) -> (h, gradient[2],
 * Hessian[2x2]).
 *
 * The search: g at 13 angles beta_j = (j - 6) pi/12 (in 3D and on a heightmap each arc near touching sampled
 * again, see RIM_BAND); a sample is a maximum where it is >= its left neighbour and > its right one (an end where g rises
 * toward it); the three highest maxima are kept; each is polished by safeguarded Newton on g' = 0 inside its
 * samples' bracket (a Newton step that leaves the bracket or meets g'' of the wrong sign is replaced by
 * bisection), started from the vertex of the samples' parabola; each saddle from the lowest sample between two
 * kept maxima the same way. At most RIM_ITER iterations each: a bounded cost.
 *
 * One maximum, proven (search_one): with G >= |gradient f| and U >= the largest eigenvalue of f's Hessian over
 * the whole terrain (the scene's generated cedra_terrain_bounds), every stationary point of g on the half rim is
 * a strict maximum when (N = (-grad f, 1) at the rim point, w its radius direction, u its tangent, a the axle)
 *   1. L = |a_XY| - |a_Z| G > 0: at a stationary point (N.u = 0) |N.w| = |N x a| >= L;
 *   2. R max(U, 0) < L: there g'' = R^2 u_XY' H u_XY + R N.w < 0 wherever N.w < 0;
 *   3. (1 - G |grad f(c)|) / |N(c)| > |n0.a| (|a_Z| + G |a_XY|): N.t > 0 at every rim point (t: n0 in the rim's
 *      plane, n0 the unit normal at the center), while a stationary point with N.w > 0 on the half rim
 *      (w.t <= 0) has N.t = (N.w)(w.t) <= 0; so N.w < 0 at every stationary point.
 * A function on an interval whose stationary points are all strict maxima has at most one of them: g rises,
 * then falls (or is monotone), and the rim has exactly the one maximum the samples would find. It is then found
 * from beta = 0 by the same safeguarded Newton on [-pi/2, pi/2] without the samples; an end is the maximum
 * where g rises toward it (checked the first time a step would leave the bracket or meet g'' >= 0). */
#include <math.h>
#include <stddef.h>
#include <string.h>

#ifndef RIM_HOST
#include "cedra_vars.h"         /* CEDRA_HEIGHTMAP (the Python side's host library defines it itself) */
#endif
#if CEDRA_HEIGHTMAP
#include "heightmap.h"          /* heightmap_active_id: the memo's key besides the wheel */
#endif

typedef long long int casadi_int;

int cedra_terrain(const double **arg, double **res, casadi_int *iw, double *w, int mem);
int cedra_terrain_work(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);
int cedra_rim_samples(const double **arg, double **res, casadi_int *iw, double *w, int mem);
int cedra_rim_samples_work(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);

#define RIM_NX 15
#define RIM_NR 8
#define RIM_NSAMPLE 13
#define RIM_MAXC 3
#define RIM_ITER 40
#define RIM_WORK 1024

typedef struct {
    const double *c, *a, *tin;
    double R, r1[3], r2[3];
    const double *arg[64];
    double *res[64];
    casadi_int iw[256];
    double w[RIM_WORK];
} rim_ctx;

static int terrain_at(rim_ctx *k, double X, double Y, double *h, double g[2], double H[4]) {
    double xy[2] = {X, Y};
    k->arg[0] = xy;
    k->arg[1] = k->tin;
    k->res[0] = h;
    k->res[1] = g;
    k->res[2] = H;
    return cedra_terrain(k->arg, k->res, k->iw, k->w, 0) || !isfinite(*h);
}

/* g(beta) and its first two beta-derivatives (the chain rule on the terrain's gradient and Hessian), at the rim
 * point of angle beta whose cosine and sine are cb, sb */
static int gfun_cs(rim_ctx *k, double cb, double sb, double *g0, double *d1, double *d2) {
    double p[3], dp[3], ddp[3], h, g[2], H[4];
    for (int i = 0; i < 3; i++) {
        p[i] = k->c[i] + k->R * (cb * k->r1[i] + sb * k->r2[i]);
        dp[i] = k->R * (-sb * k->r1[i] + cb * k->r2[i]);
        ddp[i] = k->c[i] - p[i];
    }
    if (terrain_at(k, p[0], p[1], &h, g, H)) return 1;
    *g0 = h - p[2];
    *d1 = g[0] * dp[0] + g[1] * dp[1] - dp[2];
    *d2 = dp[0] * (H[0] * dp[0] + H[2] * dp[1]) + dp[1] * (H[1] * dp[0] + H[3] * dp[1]) + g[0] * ddp[0] +
          g[1] * ddp[1] - ddp[2];
    return !(isfinite(*d1) && isfinite(*d2));
}

static int gfun(rim_ctx *k, double b, double *g0, double *d1, double *d2) {
    return gfun_cs(k, cos(b), sin(b), g0, d1, d2);
}

/* the vertex of the parabola through (b - h, gl), (b, gc), (b + h, gr), where it bends the extremum's way */
static double vertex(double b, double h, double gl, double gc, double gr, int maximum) {
    double curv = gl - 2 * gc + gr;
    if (maximum ? !(curv < 0) : !(curv > 0)) return b;
    return b + 0.5 * h * (gl - gr) / curv;
}

/* the extremum of g in [lo, hi] from b: safeguarded Newton on g' = 0 */
static int polish(rim_ctx *k, double b, double lo, double hi, int maximum, double *out) {
    const double sign = maximum ? 1.0 : -1.0;     /* g' sign > 0 left of the extremum */
    if (!(b >= lo && b <= hi)) b = 0.5 * (lo + hi);
    for (int it = 0; it < RIM_ITER; it++) {
        double g0, d1, d2;
        if (gfun(k, b, &g0, &d1, &d2)) return 1;
        if (d1 == 0) break;
        if (d1 * sign > 0) lo = b;
        else hi = b;
        double next = 0.5 * (lo + hi);
        int newton_step = 0;
        if (d2 * sign < 0) {
            double newton = b - d1 / d2;
            if (newton >= lo && newton <= hi) next = newton, newton_step = 1;
        }
        /* converged: a Newton step of 1e-13 rad leaves an error of order 1e-26 (quadratic convergence) */
        if (next == b || (newton_step && fabs(next - b) < 1e-13) || hi - lo <= 4 * 2.2e-16 * fabs(b)) {
            b = next;
            break;
        }
        b = next;
    }
    *out = b;
    return 0;
}

int cedra_terrain_bounds(const double **arg, double **res, casadi_int *iw, double *w, int mem);
int cedra_terrain_bounds_work(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);

/* The rim's frame as cedra_rim_samples forms it: beta = 0 along -t, t the terrain's unit normal at the center
 * projected into the rim's plane; r2 = a x r1 */
static void rim_frame(rim_ctx *k, const double n0[3]) {
    const double *a = k->a;
    double na = n0[0] * a[0] + n0[1] * a[1] + n0[2] * a[2], t[3];
    for (int i = 0; i < 3; i++) t[i] = n0[i] - na * a[i];
    double tn = sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
    for (int i = 0; i < 3; i++) k->r1[i] = -(t[i] / tn);
    k->r2[0] = a[1] * k->r1[2] - a[2] * k->r1[1];
    k->r2[1] = a[2] * k->r1[0] - a[0] * k->r1[2];
    k->r2[2] = a[0] * k->r1[1] - a[1] * k->r1[0];
}

/* 1 where the terrain's bounds prove that the rim has one maximum (the test at the top of this file), with n0
 * the unit normal at the center (n0 NULL: not needed); 0 where they do not */
static int proven_one(rim_ctx *k, double *n0) {
    const double margin = 1e-9, *a = k->a;
    double bounds[2], hc, gc[2], Hc[4], n0_[3];
    k->arg[0] = k->tin;
    k->res[0] = bounds;
    if (cedra_terrain_bounds(k->arg, k->res, k->iw, k->w, 0)) return 0;
    double G = bounds[0], U = bounds[1];
    if (!(isfinite(G) && isfinite(U) && G >= 0)) return 0;
    double a_xy = sqrt(a[0] * a[0] + a[1] * a[1]), a_z = fabs(a[2]), L = a_xy - a_z * G;
    if (!(L > 0 && k->R * fmax(U, 0.0) < (1 - margin) * L)) return 0;                 /* 1 and 2 */
    /* 3 without the terrain at the center: (1 - G s) / sqrt(1 + s^2) falls with s = |grad f(c)| <= G, and
     * |n0.a| <= a_Z + G a_XY, so (1 - G^2) / sqrt(1 + G^2) > (a_Z + G a_XY)^2 implies 3 (one spline evaluation
     * less per wheel and call on a heightmap, whose model does not need n0) */
    if (!n0 && (1 - G * G) / sqrt(1 + G * G) > (a_z + G * a_xy) * (a_z + G * a_xy) + margin) return 1;
    if (!n0) n0 = n0_;
    if (terrain_at(k, k->c[0], k->c[1], &hc, gc, Hc)) return 0;
    double nN = sqrt(gc[0] * gc[0] + gc[1] * gc[1] + 1);
    n0[0] = -gc[0] / nN, n0[1] = -gc[1] / nN, n0[2] = 1 / nN;
    double na = fabs(n0[0] * a[0] + n0[1] * a[1] + n0[2] * a[2]);
    return (1 - G * sqrt(gc[0] * gc[0] + gc[1] * gc[1])) / nN > na * (a_z + G * a_xy) + margin;      /* 3 */
}

/* The search where the terrain's bounds prove one maximum: safeguarded Newton from beta = 0 (polish's steps and
 * stopping rule). The maximum lies on the side where g rises at 0; that side's end is checked the first time a
 * step is not a Newton step inside the bracket. *one = 0: not proven (the caller samples the rim). */
static int search_one(rim_ctx *k, double *r, int *one) {
    const double step = 3.14159265358979323846 / 12;
    double n0[3];
    *one = 0;
#if CEDRA_HEIGHTMAP
    if (!proven_one(k, NULL)) return 0;
#else
    if (!proven_one(k, n0)) return 0;
#endif
#if CEDRA_HEIGHTMAP
    /* the heightmap's model takes a rim with one maximum from its own single-contact search (heightmap.c) and
     * reads nothing here but the presence flags: the angle is not needed */
    memset(r, 0, RIM_NR * sizeof *r);
    r[5] = 1;
    *one = 1;
    return 0;
#endif
    rim_frame(k, n0);
    double b = 0, g0, d1, d2;
    if (gfun(k, b, &g0, &d1, &d2)) return 1;
    double end = d1 > 0 ? 6 * step : -6 * step, lo = -6 * step, hi = 6 * step;
    int end_checked = 0;
    for (int it = 0; it < RIM_ITER && d1 != 0; it++) {
        if (d1 > 0) lo = b;
        else hi = b;
        double next = 0.5 * (lo + hi);
        int newton_step = 0;
        if (d2 < 0) {
            double newton = b - d1 / d2;
            if (newton >= lo && newton <= hi) next = newton, newton_step = 1;
        }
        if (!newton_step && !end_checked) {
            double ge, d1e, d2e;
            end_checked = 1;
            if (gfun(k, end, &ge, &d1e, &d2e)) return 1;
            if (end > 0 ? d1e > 0 : d1e < 0) {          /* g rises toward the end: the end is the maximum */
                b = end;
                break;
            }
        }
        if (next == b || (newton_step && fabs(next - b) < 1e-13) || hi - lo <= 4 * 2.2e-16 * fabs(b)) {
            b = next;
            break;
        }
        b = next;
        if (gfun(k, b, &g0, &d1, &d2)) return 1;
    }
    memset(r, 0, RIM_NR * sizeof *r);
    r[0] = b;
    r[5] = 1;
    *one = 1;
    return 0;
}

static int work_fits(void) {
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    int (*work[3])(casadi_int *, casadi_int *, casadi_int *, casadi_int *) = {
        cedra_terrain_work, cedra_rim_samples_work, cedra_terrain_bounds_work};
    for (int i = 0; i < 3; i++) {
        work[i](&sz_arg, &sz_res, &sz_iw, &sz_w);
        if (sz_arg > 64 || sz_res > 64 || sz_iw > 256 || sz_w > RIM_WORK) return 0;
    }
    return 1;
}

static void bind(rim_ctx *k, const double *x) {
    k->c = x;
    k->a = x + 3;
    k->R = x[6];
    k->tin = x + 7;
}

/* For the tests (the FMU does not export it): 1 where search_one takes the wheel x = [c, a, R, tin] */
int cedra_rim_one_maximum(const double *x);
int cedra_rim_one_maximum(const double *x) {
    rim_ctx k;
    double n0[3];
    if (!work_fits()) return 0;
    bind(&k, x);
    return proven_one(&k, n0);
}

/* Two maxima can lie within one 15-degree arc: a heightmap's spline holds features that narrow (a block's edge,
 * the spline's ripple beside it), and a wheel that meets a smoothed stair edge obliquely sees the edge and the
 * tread as two maxima about 20 degrees apart on a plateau whose saddle is a few hundredths of a millimetre deep
 * (measured on the rocker-bogie's stairs run); the 15-degree samples then see one maximum, and the Newton
 * polish lands on either, so the force jumps between the two points. So on every terrain an arc whose end
 * samples lie within RIM_BAND of touching (g > -RIM_BAND) is sampled again at RIM_SPLIT equal parts, on a
 * heightmap and in 3D (CEDRA_RIM_REFINE). A planar scene's wheel meets the features square on, where the 13
 * samples find every maximum (tests/test_contact_multi.py: the exhaustive search on the shipped runs). */
#define RIM_BAND 0.002
#define RIM_SPLIT 8
#define RIM_MAXS (RIM_NSAMPLE + (RIM_NSAMPLE - 1) * (RIM_SPLIT - 1))

/* the vertex of the parabola through three samples (any spacing), where it bends the extremum's way */
static double vertex3(const double *b, const double *g, int maximum) {
    if (b[1] - b[0] == b[2] - b[1]) return vertex(b[1], b[1] - b[0], g[0], g[1], g[2], maximum);
    double d1 = (g[1] - g[0]) / (b[1] - b[0]), d2 = (g[2] - g[1]) / (b[2] - b[1]);
    double curv = (d2 - d1) / (b[2] - b[0]);
    if (maximum ? !(curv < 0) : !(curv > 0)) return b[1];
    return 0.5 * (b[0] + b[1]) - 0.5 * d1 / curv;
}

static int search(const double *x, double *r) {
    rim_ctx k;
    if (!work_fits()) return 1;
    bind(&k, x);
    int one;
    if (search_one(&k, r, &one)) return 1;
    if (one) return 0;
    /* the samples, the frame (beta = 0 along the normal under the center projected into the rim's plane) and
     * g' at both ends, from the scene's generated cedra_rim_samples (straight-line code) */
    const double pi = 3.14159265358979323846, step = pi / 12;
    double coarse[RIM_NSAMPLE], frame[6], d1_end[2];
    k.arg[0] = x;
    k.res[0] = coarse;
    k.res[1] = frame;
    k.res[2] = d1_end;
    if (cedra_rim_samples(k.arg, k.res, k.iw, k.w, 0)) return 1;
    for (int j = 0; j < RIM_NSAMPLE; j++)
        if (!isfinite(coarse[j])) return 1;
    for (int i = 0; i < 3; i++) k.r1[i] = frame[i], k.r2[i] = frame[3 + i];
    double beta[RIM_MAXS], gs[RIM_MAXS];
    int n = 0;
    for (int j = 0; j < RIM_NSAMPLE; j++) {
        beta[n] = (j - 6) * step;
        gs[n++] = coarse[j];
#if CEDRA_RIM_REFINE
        if (j + 1 < RIM_NSAMPLE && fmax(coarse[j], coarse[j + 1]) > -RIM_BAND)
            for (int m = 1; m < RIM_SPLIT; m++) {
                double d1, d2;
                beta[n] = (j - 6 + (double)m / RIM_SPLIT) * step;
                if (gfun(&k, beta[n], &gs[n], &d1, &d2)) return 1;
                n++;
            }
#endif
    }
    /* the maxima of the samples (a sample >= its left neighbour and > its right one; an end where g rises toward
     * it): the RIM_MAXC highest are kept (the deepest contacts), in their order by beta */
    int idx[RIM_MAXS], nmax = 0;
    for (int j = 0; j < n; j++) {
        int left = j == 0 || gs[j] >= gs[j - 1];
        int right = j == n - 1 || gs[j] > gs[j + 1];
        if (left && right) idx[nmax++] = j;
    }
    while (nmax > RIM_MAXC) {          /* drop the lowest */
        int low = 0;
        for (int m2 = 1; m2 < nmax; m2++)
            if (gs[idx[m2]] < gs[idx[low]]) low = m2;
        for (int m2 = low; m2 + 1 < nmax; m2++) idx[m2] = idx[m2 + 1];
        nmax--;
    }
    memset(r, 0, RIM_NR * sizeof *r);
    for (int m2 = 0; m2 < nmax; m2++) {
        int j = idx[m2];
        double b;
        if ((j == 0 && d1_end[0] < 0) || (j == n - 1 && d1_end[1] > 0)) {
            b = beta[j];                               /* g rises toward the end: the end is the maximum */
        } else {
            int jl = j > 0 ? j - 1 : 0, jh = j < n - 1 ? j + 1 : n - 1;
            double lo = beta[jl], hi = beta[jh];
            double start = (j > 0 && j < n - 1) ? vertex3(beta + j - 1, gs + j - 1, 1) : beta[j];
            if (polish(&k, fmin(hi, fmax(lo, start)), lo, hi, 1, &b)) return 1;
        }
        r[m2] = b;
        r[5 + m2] = 1;
    }
    for (int m2 = 0; m2 + 1 < nmax; m2++) {
        int lowest = -1;
        for (int j = idx[m2] + 1; j < idx[m2 + 1]; j++)
            if (lowest < 0 || gs[j] < gs[lowest]) lowest = j;
        if (lowest < 0) return 1;                      /* two maxima are never neighbouring samples */
        double lo = beta[lowest - 1], hi = beta[lowest + 1], b;
        double start = vertex3(beta + lowest - 1, gs + lowest - 1, 0);
        if (polish(&k, fmin(hi, fmax(lo, start)), lo, hi, 0, &b)) return 1;
        r[3 + m2] = b;
    }
    return 0;
}

static const casadi_int SP_X[] = {RIM_NX, 1, 0, RIM_NX, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14};
static const casadi_int SP_R[] = {RIM_NR, 1, 0, RIM_NR, 0, 1, 2, 3, 4, 5, 6, 7};
/* the Jacobian of r by x: 8 x 15 dense, every entry 0 */
static const casadi_int SP_J[] = {RIM_NR, RIM_NX, 0, 8, 16, 24, 32, 40, 48, 56, 64, 72, 80, 88, 96, 104, 112, 120,
                                  0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7,
                                  0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7,
                                  0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7,
                                  0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7,
                                  0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7};

casadi_int cedra_rim_search_n_in(void) { return 1; }
casadi_int cedra_rim_search_n_out(void) { return 1; }
const casadi_int *cedra_rim_search_sparsity_in(casadi_int i) { return i == 0 ? SP_X : NULL; }
const casadi_int *cedra_rim_search_sparsity_out(casadi_int i) { return i == 0 ? SP_R : NULL; }
casadi_int jac_cedra_rim_search_n_in(void) { return 2; }
casadi_int jac_cedra_rim_search_n_out(void) { return 1; }
const casadi_int *jac_cedra_rim_search_sparsity_in(casadi_int i) { return i == 0 ? SP_X : i == 1 ? SP_R : NULL; }
const casadi_int *jac_cedra_rim_search_sparsity_out(casadi_int i) { return i == 0 ? SP_J : NULL; }

static const double ZERO_X[RIM_NX];     /* CasADi passes NULL for an all-zero argument */

/* The recent searches of this thread, by their exact input (and map): an implicit solver's Jacobian is taken at the
 * state where it just evaluated the right-hand side, and the switching functions at the end of a step are the
 * next step's start, so a pose is searched several times in a row. A pure cache: the result for a given x is
 * the same whichever instance or call asked first, so it changes no result and needs no per-instance state.
 * Two ways per set, the set picked by the wheel center's bits; a miss replaces the way used less recently. */
#define RIM_MEMO_SETS_BITS 5
typedef struct {
    double x[RIM_NX], r[RIM_NR];
    unsigned long long map;     /* a heightmap scene: the map searched (instances may read different grids) */
    int used;
} rim_memo_entry;
static __thread struct {
    rim_memo_entry e[1 << RIM_MEMO_SETS_BITS][2];
    unsigned char recent[1 << RIM_MEMO_SETS_BITS];
} memo;

static unsigned memo_set(const double *x) {
    unsigned long long h = 0, bits;
    for (int i = 0; i < 3; i++) {
        memcpy(&bits, &x[i], sizeof bits);
        h = (h ^ bits) * 0x9E3779B97F4A7C15ULL;
    }
    return (unsigned)(h >> (64 - RIM_MEMO_SETS_BITS));
}

int cedra_rim_search(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    const double *x = arg[0] ? arg[0] : ZERO_X;
#ifdef RIM_HOST
    /* the Python side's host library: no memo (on a heightmap the map is not part of x, and tests load several
     * maps; elsewhere the Python side's evaluations are few) */
    double r[RIM_NR];
    if (search(x, r)) return 1;
    if (res[0]) memcpy(res[0], r, sizeof r);
    return 0;
#else
    unsigned set = memo_set(x);
    rim_memo_entry *m = NULL;
#if CEDRA_HEIGHTMAP
    unsigned long long map = heightmap_active_id();
#else
    unsigned long long map = 0;
#endif
    for (int way = 0; way < 2 && !m; way++) {
        rim_memo_entry *e = &memo.e[set][way];
        if (e->used && e->map == map && memcmp(e->x, x, sizeof e->x) == 0) {
            m = e;
            memo.recent[set] = (unsigned char)way;
        }
    }
    if (!m) {
        double r[RIM_NR];
        if (search(x, r)) return 1;
        int way = !memo.recent[set];
        m = &memo.e[set][way];
        memcpy(m->x, x, sizeof m->x);
        memcpy(m->r, r, sizeof r);
        m->map = map;
        m->used = 1;
        memo.recent[set] = (unsigned char)way;
    }
    if (res[0]) memcpy(res[0], m->r, sizeof m->r);
    return 0;
#endif
}

int jac_cedra_rim_search(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)arg, (void)iw, (void)w, (void)mem;
    if (res[0]) memset(res[0], 0, RIM_NR * RIM_NX * sizeof *res[0]);
    return 0;
}
