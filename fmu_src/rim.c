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
 * The search: g at 13 angles beta_j = (j - 6) pi/12; a sample is a maximum where it is >= its left neighbour and
 * > its right one (an end where g rises toward it); the first three maxima by beta are kept; each is polished by
 * safeguarded Newton on g' = 0 inside its samples' bracket (a Newton step that leaves the bracket or meets g'' of
 * the wrong sign is replaced by bisection), started from the vertex of the samples' parabola; each saddle from
 * the lowest sample between two kept maxima the same way. At most RIM_ITER iterations each: a bounded cost. */
#include <math.h>
#include <stddef.h>
#include <string.h>

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

static int search(const double *x, double *r) {
    rim_ctx k;
    casadi_int sz_arg, sz_res, sz_iw, sz_w;
    cedra_terrain_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    if (sz_arg > 64 || sz_res > 64 || sz_iw > 256 || sz_w > RIM_WORK) return 1;
    cedra_rim_samples_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    if (sz_arg > 64 || sz_res > 64 || sz_iw > 256 || sz_w > RIM_WORK) return 1;
    k.c = x;
    k.a = x + 3;
    k.R = x[6];
    k.tin = x + 7;
    /* the samples, the frame (beta = 0 along the normal under the center projected into the rim's plane) and
     * g' at both ends, from the scene's generated cedra_rim_samples (straight-line code) */
    const double pi = 3.14159265358979323846, step = pi / 12;
    double beta[RIM_NSAMPLE], gs[RIM_NSAMPLE], frame[6], d1_end[2];
    k.arg[0] = x;
    k.res[0] = gs;
    k.res[1] = frame;
    k.res[2] = d1_end;
    if (cedra_rim_samples(k.arg, k.res, k.iw, k.w, 0)) return 1;
    for (int j = 0; j < RIM_NSAMPLE; j++) {
        beta[j] = (j - 6) * step;
        if (!isfinite(gs[j])) return 1;
    }
    for (int i = 0; i < 3; i++) k.r1[i] = frame[i], k.r2[i] = frame[3 + i];
    int idx[RIM_MAXC], nmax = 0;
    for (int j = 0; j < RIM_NSAMPLE && nmax < RIM_MAXC; j++) {
        int left = j == 0 || gs[j] >= gs[j - 1];
        int right = j == RIM_NSAMPLE - 1 || gs[j] > gs[j + 1];
        if (left && right) idx[nmax++] = j;
    }
    memset(r, 0, RIM_NR * sizeof *r);
    for (int m2 = 0; m2 < nmax; m2++) {
        int j = idx[m2];
        double b;
        if ((j == 0 && d1_end[0] < 0) || (j == RIM_NSAMPLE - 1 && d1_end[1] > 0)) {
            b = beta[j];                               /* g rises toward the end: the end is the maximum */
        } else {
            double lo = beta[j > 0 ? j - 1 : 0], hi = beta[j < RIM_NSAMPLE - 1 ? j + 1 : j];
            double start = (j > 0 && j < RIM_NSAMPLE - 1) ? vertex(beta[j], step, gs[j - 1], gs[j], gs[j + 1], 1)
                                                           : beta[j];
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
        double lo = beta[lowest] - step, hi = beta[lowest] + step, b;
        double start = vertex(beta[lowest], step, gs[lowest - 1], gs[lowest], gs[lowest + 1], 0);
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

/* The last RIM_MEMO searches of this thread, by their exact input: an implicit solver's Jacobian is taken at the
 * state where it just evaluated the right-hand side, and the switching functions at the end of a step are the
 * next step's start, so a pose is searched several times in a row. A pure cache: the result for a given x is
 * the same whichever instance or call asked first, so it changes no result and needs no per-instance state. */
#define RIM_MEMO 16
typedef struct {
    double x[RIM_NX], r[RIM_NR];
} rim_memo_entry;
static __thread rim_memo_entry memo[RIM_MEMO];
static __thread int memo_used, memo_next;

int cedra_rim_search(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    const double *x = arg[0] ? arg[0] : ZERO_X;
    double r[RIM_NR];
    int hit = -1;
    for (int i = 0; i < memo_used && hit < 0; i++)
        if (memcmp(memo[i].x, x, sizeof memo[i].x) == 0) hit = i;
    if (hit >= 0) {
        memcpy(r, memo[hit].r, sizeof r);
    } else {
        if (search(x, r)) return 1;
        memcpy(memo[memo_next].x, x, sizeof memo[memo_next].x);
        memcpy(memo[memo_next].r, r, sizeof r);
        memo_next = (memo_next + 1) % RIM_MEMO;
        if (memo_used < RIM_MEMO) memo_used++;
    }
    if (res[0]) memcpy(res[0], r, sizeof r);
    return 0;
}

int jac_cedra_rim_search(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)arg, (void)iw, (void)w, (void)mem;
    if (res[0]) memset(res[0], 0, RIM_NR * RIM_NX * sizeof *res[0]);
    return 0;
}
