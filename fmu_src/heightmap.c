/* The heightmap terrain: file reader, natural bicubic spline fit and evaluation, and the CasADi external
 * functions the generated model calls (see heightmap.h). */
#include "heightmap.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define MAX_NODES 4000000   /* a sanity bound on nx * ny (32 MB of heights) */

/* ---------------------------------------------------------------------------------------------- reading */

typedef struct {
    FILE *f;
    int line;
    char tok[128];
} reader;

/* the next whitespace-separated token (comments skipped) into r->tok; 0, or 1 at the end of the file */
static int next_token(reader *r) {
    int ch, n = 0;
    for (;;) {
        ch = fgetc(r->f);
        if (ch == EOF) return 1;
        if (ch == '\n') r->line++;
        if (ch == '#') {
            while ((ch = fgetc(r->f)) != EOF && ch != '\n') {
            }
            if (ch == EOF) return 1;
            r->line++;
            continue;
        }
        if (!isspace(ch)) break;
    }
    while (ch != EOF && !isspace(ch) && ch != '#') {
        if (n + 1 < (int)sizeof r->tok) r->tok[n++] = (char)ch;
        ch = fgetc(r->f);
    }
    r->tok[n] = '\0';
    if (ch == '#') ungetc(ch, r->f);
    if (ch == '\n') ungetc(ch, r->f);
    return 0;
}

static int read_number(reader *r, double *v) {
    char *end;
    if (next_token(r)) return 1;
    errno = 0;
    *v = strtod(r->tok, &end);
    return *end != '\0' || errno == ERANGE || !isfinite(*v);
}

/* ------------------------------------------------------------------------------------------------ fitting */

/* Natural cubic spline on unit-spaced nodes as uniform B-spline coefficients: z[0..n-1] (stride sz) ->
 * c[0..n+1] (stride sc) with c[k] the coefficient of the basis centred on node k-1. Interpolation
 * (c[k-1] + 4 c[k] + c[k+1]) / 6 = z and zero second derivative at both ends give c at the end nodes directly and a
 * tridiagonal, diagonally dominant system for the interior (Thomas algorithm, work holds n doubles). */
static void fit_line(const double *z, int sz, double *c, int sc, int n, double *work) {
    c[1 * sc] = z[0];
    c[n * sc] = z[(n - 1) * sz];
    if (n > 2) {
        /* unknowns c[2..n-1] (nodes 1..n-2): c[k-1] + 4 c[k] + c[k+1] = 6 z[k-1] */
        int m = n - 2;
        double *cp = work;              /* modified super-diagonal */
        double prev = 0.0;
        for (int i = 0; i < m; i++) {
            double rhs = 6.0 * z[(i + 1) * sz];
            if (i == 0) rhs -= c[1 * sc];
            if (i == m - 1) rhs -= c[n * sc];
            double denom = 4.0 - (i > 0 ? cp[i - 1] : 0.0);
            cp[i] = 1.0 / denom;
            prev = (rhs - (i > 0 ? prev : 0.0)) / denom;
            c[(i + 2) * sc] = prev;
        }
        for (int i = m - 2; i >= 0; i--) c[(i + 2) * sc] -= cp[i] * c[(i + 3) * sc];
    }
    c[0] = 2.0 * c[1 * sc] - c[2 * sc];
    c[(n + 1) * sc] = 2.0 * c[n * sc] - c[(n - 1) * sc];
}

/* hm->bound from the coefficients: a derivative of the spline is a spline of one degree less in that direction
 * whose coefficients are the coefficients' differences (divided by the spacing), and a spline lies between its
 * smallest and largest coefficient (the basis is nonnegative and sums to 1). So |h_X| <= max |D_X c| / dx (the
 * same in Y), h_XX <= max D_XX c / dx^2, h_YY <= max D_YY c / dy^2, |h_XY| <= max |D_X D_Y c| / (dx dy), and
 * the Hessian's largest eigenvalue max_v (h_XX v1^2 + 2 h_XY v1 v2 + h_YY v2^2) is at most that of
 * [[A, B], [B, D]] with A, D, B these bounds. Rounding: 1e-12 of the largest coefficient's size added. */
static void derivative_bounds(heightmap *hm) {
    int mx = hm->nx + 2, my = hm->ny + 2;
    double gx = 0, gy = 0, A = -INFINITY, D = -INFINITY, B = 0, cmax = 0;
    const double *c = hm->coef;
#define C(i, j) c[(size_t)(j) * mx + (i)]
    for (int j = 0; j < my; j++)
        for (int i = 0; i < mx; i++) {
            cmax = fmax(cmax, fabs(C(i, j)));
            if (i + 1 < mx) gx = fmax(gx, fabs(C(i + 1, j) - C(i, j)));
            if (j + 1 < my) gy = fmax(gy, fabs(C(i, j + 1) - C(i, j)));
            if (i + 2 < mx) A = fmax(A, C(i + 2, j) - 2 * C(i + 1, j) + C(i, j));
            if (j + 2 < my) D = fmax(D, C(i, j + 2) - 2 * C(i, j + 1) + C(i, j));
            if (i + 1 < mx && j + 1 < my) B = fmax(B, fabs(C(i + 1, j + 1) - C(i, j + 1) - C(i + 1, j) + C(i, j)));
        }
#undef C
    double eps = 1e-12 * cmax, ix = 1 / hm->dx, iy = 1 / hm->dy;
    gx = (gx + eps) * ix, gy = (gy + eps) * iy;
    A = (A + eps) * ix * ix, D = (D + eps) * iy * iy, B = (B + eps) * ix * iy;
    hm->bound[0] = sqrt(gx * gx + gy * gy);
    hm->bound[1] = 0.5 * (A + D) + sqrt(0.25 * (A - D) * (A - D) + B * B);
}

static int fit(heightmap *hm, const double *z, heightmap_alloc alloc, heightmap_free_fn fr) {
    int nx = hm->nx, ny = hm->ny, mx = nx + 2;
    double *tmp = (double *)alloc((size_t)mx * (size_t)ny, sizeof(double));   /* rows fitted along X */
    int nmax = nx > ny ? nx : ny;
    double *work = (double *)alloc((size_t)nmax + 2, sizeof(double));
    if (!tmp || !work) {
        if (tmp) fr(tmp);
        if (work) fr(work);
        return 1;
    }
    for (int j = 0; j < ny; j++) fit_line(z + (size_t)j * nx, 1, tmp + (size_t)j * mx, 1, nx, work);
    for (int k = 0; k < mx; k++) fit_line(tmp + k, mx, hm->coef + k, mx, ny, work);
    fr(tmp);
    fr(work);
    hm->cellmax = (double *)alloc((size_t)(nx - 1) * (size_t)(ny - 1), sizeof(double));
    hm->cellmin = (double *)alloc((size_t)(nx - 1) * (size_t)(ny - 1), sizeof(double));
    if (!hm->cellmax || !hm->cellmin) return 1;
    for (int j = 0; j < ny - 1; j++)
        for (int i = 0; i < nx - 1; i++) {
            double hi = hm->coef[(size_t)j * mx + i], lo = hi;
            for (int jj = j; jj < j + 4; jj++)
                for (int ii = i; ii < i + 4; ii++) {
                    double v = hm->coef[(size_t)jj * mx + ii];
                    if (v > hi) hi = v;
                    if (v < lo) lo = v;
                }
            hm->cellmax[(size_t)j * (nx - 1) + i] = hi;
            hm->cellmin[(size_t)j * (nx - 1) + i] = lo;
        }
    derivative_bounds(hm);
    return 0;
}

int heightmap_read(heightmap *hm, const char *path, heightmap_alloc alloc, heightmap_free_fn fr, char *msg,
                   size_t msg_len) {
    static unsigned long long last_id;
    reader r = {NULL, 1, {0}};
    double head[6], *z = NULL;
    int rc = 1;
    memset(hm, 0, sizeof *hm);
    hm->id = __sync_add_and_fetch(&last_id, 1);     /* instances may be made in several threads at once */
    r.f = fopen(path, "r");
    if (!r.f) {
        snprintf(msg, msg_len, "cannot open the heightmap %s: %s", path, strerror(errno));
        return 1;
    }
    if (next_token(&r) || strcmp(r.tok, "cedra-heightmap") != 0 || next_token(&r) || strcmp(r.tok, "1") != 0) {
        snprintf(msg, msg_len, "%s: line %d: expected the header 'cedra-heightmap 1'", path, r.line);
        goto done;
    }
    for (int i = 0; i < 6; i++)
        if (read_number(&r, &head[i])) {
            snprintf(msg, msg_len, "%s: line %d: expected 'nx ny x0 y0 dx dy' (6 numbers)", path, r.line);
            goto done;
        }
    if (head[0] != floor(head[0]) || head[1] != floor(head[1]) || head[0] < 2 || head[1] < 2 ||
        head[0] * head[1] > MAX_NODES) {
        snprintf(msg, msg_len, "%s: nx = %g, ny = %g: need whole numbers >= 2 with nx * ny <= %d", path, head[0],
                 head[1], MAX_NODES);
        goto done;
    }
    if (!(head[4] > 0) || !(head[5] > 0)) {
        snprintf(msg, msg_len, "%s: dx = %g, dy = %g: the spacings must be > 0", path, head[4], head[5]);
        goto done;
    }
    hm->nx = (int)head[0];
    hm->ny = (int)head[1];
    hm->x0 = head[2];
    hm->y0 = head[3];
    hm->dx = head[4];
    hm->dy = head[5];
    size_t n = (size_t)hm->nx * (size_t)hm->ny;
    z = (double *)alloc(n, sizeof(double));
    hm->coef = (double *)alloc((size_t)(hm->nx + 2) * (size_t)(hm->ny + 2), sizeof(double));
    if (!z || !hm->coef) {
        snprintf(msg, msg_len, "%s: out of memory for a %d x %d grid", path, hm->nx, hm->ny);
        goto done;
    }
    for (size_t i = 0; i < n; i++)
        if (read_number(&r, &z[i])) {
            snprintf(msg, msg_len, "%s: line %d: height %zu of %zu (row %zu) is missing or not a finite number",
                     path, r.line, i + 1, n, i / (size_t)hm->nx);
            goto done;
        }
    if (!next_token(&r)) {
        snprintf(msg, msg_len, "%s: line %d: more than nx * ny = %zu heights", path, r.line, n);
        goto done;
    }
    if (fit(hm, z, alloc, fr)) {
        snprintf(msg, msg_len, "%s: out of memory fitting the spline", path);
        goto done;
    }
    rc = 0;
done:
    fclose(r.f);
    if (z) fr(z);
    if (rc) heightmap_release(hm, fr);
    return rc;
}

void heightmap_release(heightmap *hm, heightmap_free_fn fr) {
    if (hm->coef) fr(hm->coef);
    if (hm->cellmax) fr(hm->cellmax);
    if (hm->cellmin) fr(hm->cellmin);
    hm->coef = hm->cellmax = hm->cellmin = NULL;
}

/* ---------------------------------------------------------------------------------------------- evaluating */

/* uniform cubic B-spline basis on one cell, t in [0, 1]: b[d][k] = d-th derivative of basis k */
static void basis(double t, double b[4][4]) {
    double s = 1.0 - t, t2 = t * t, t3 = t2 * t;
    b[0][0] = s * s * s / 6.0;
    b[0][1] = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
    b[0][2] = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0;
    b[0][3] = t3 / 6.0;
    b[1][0] = -0.5 * s * s;
    b[1][1] = 1.5 * t2 - 2.0 * t;
    b[1][2] = -1.5 * t2 + t + 0.5;
    b[1][3] = 0.5 * t2;
    b[2][0] = s;
    b[2][1] = 3.0 * t - 2.0;
    b[2][2] = 1.0 - 3.0 * t;
    b[2][3] = t;
    b[3][0] = -1.0;
    b[3][1] = 3.0;
    b[3][2] = -3.0;
    b[3][3] = 1.0;
}

/* the cell of grid coordinate u (clamped to [0, n-1]; the last node belongs to the last cell) */
static int cell(double u, int n) {
    int i = (int)floor(fmin(fmax(u, 0.0), n - 1));
    return i > n - 2 ? n - 2 : i;
}

int heightmap_eval(const heightmap *hm, double X, double Y, double *h, double *d1, double *d2, double *d3) {
    double u = (X - hm->x0) / hm->dx, v = (Y - hm->y0) / hm->dy;
    const double slack = 1e-9;
    if (!(u >= -slack && u <= hm->nx - 1 + slack && v >= -slack && v <= hm->ny - 1 + slack)) return 1;
    double bu[4][4], bv[4][4];
    int i = cell(u, hm->nx), j = cell(v, hm->ny);
    basis(u - i, bu);                              /* within slack of an edge: the edge cell's polynomial */
    basis(v - j, bv);
    /* s[a][b] = d^(a+b) h / du^a dv^b for a + b <= 3 */
    double s[4][4] = {{0}};
    int mx = hm->nx + 2;
    for (int l = 0; l < 4; l++) {
        const double *row = hm->coef + (size_t)(j + l) * mx + i;
        double r[4] = {0};
        for (int k = 0; k < 4; k++)
            for (int a = 0; a < 4; a++) r[a] += bu[a][k] * row[k];
        for (int a = 0; a < 4; a++)
            for (int b = 0; a + b < 4; b++) s[a][b] += r[a] * bv[b][l];
    }
    double ix = 1.0 / hm->dx, iy = 1.0 / hm->dy;
    if (h) *h = s[0][0];
    if (d1) {
        d1[0] = s[1][0] * ix;
        d1[1] = s[0][1] * iy;
    }
    if (d2) {
        d2[0] = s[2][0] * ix * ix;
        d2[1] = d2[2] = s[1][1] * ix * iy;
        d2[3] = s[0][2] * iy * iy;
    }
    if (d3) {
        double xxx = s[3][0] * ix * ix * ix, xxy = s[2][1] * ix * ix * iy, xyy = s[1][2] * ix * iy * iy,
               yyy = s[0][3] * iy * iy * iy;
        d3[0] = xxx, d3[1] = xxy, d3[2] = xxy, d3[3] = xyy;       /* d/dX of [h_XX, h_YX, h_XY, h_YY] */
        d3[4] = xxy, d3[5] = xyy, d3[6] = xyy, d3[7] = yyy;       /* d/dY */
    }
    return 0;
}

/* The rim search's evaluations (~20 points per wheel and model evaluation): the same spline, unrolled for what
 * the search needs (the height alone at the 13 samples; height, gradient and Hessian at the Newton points).
 * The cell and its local coordinates: 0, or 1 outside the grid (as heightmap_eval). */
/* the cell (i, j) of grid coordinates (u, v) within slack of the grid: truncation = floor here, the last node in
 * the last cell */
static void grid_cell(const heightmap *hm, double u, double v, int *i, int *j) {
    *i = u > 0.0 ? (int)u : 0;
    *j = v > 0.0 ? (int)v : 0;
    if (*i > hm->nx - 2) *i = hm->nx - 2;
    if (*j > hm->ny - 2) *j = hm->ny - 2;
}

static int locate(const heightmap *hm, double X, double Y, const double **c, double *t, double *s) {
    double u = (X - hm->x0) / hm->dx, v = (Y - hm->y0) / hm->dy;
    const double slack = 1e-9;
    if (!(u >= -slack && u <= hm->nx - 1 + slack && v >= -slack && v <= hm->ny - 1 + slack)) return 1;
    int i, j;
    grid_cell(hm, u, v, &i, &j);
    *c = hm->coef + (size_t)j * (hm->nx + 2) + i;
    *t = u - i;
    *s = v - j;
    return 0;
}

/* The basis rows scaled to whole coefficients (6 b, 2 b', b'' of basis()): the scale is applied once to the
 * sums instead of to every basis value. */
static void rows0(double t, double b0[4]) {
    double s = 1.0 - t, t2 = t * t, t3 = t2 * t;
    b0[0] = s * s * s;
    b0[1] = 3.0 * t3 - 6.0 * t2 + 4.0;
    b0[2] = -3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0;
    b0[3] = t3;
}

static void rows2(double t, double b0[4], double b1[4], double b2[4]) {
    double s = 1.0 - t, t2 = t * t;
    rows0(t, b0);
    b1[0] = -s * s;
    b1[1] = 3.0 * t2 - 4.0 * t;
    b1[2] = -3.0 * t2 + 2.0 * t + 1.0;
    b1[3] = t2;
    b2[0] = s;
    b2[1] = 3.0 * t - 2.0;
    b2[2] = 1.0 - 3.0 * t;
    b2[3] = t;
}

static int eval_h(const heightmap *hm, double X, double Y, double *h) {
    const double *c;
    double t, s, bu[4], bv[4];
    if (locate(hm, X, Y, &c, &t, &s)) return 1;
    rows0(t, bu);
    rows0(s, bv);
    int mx = hm->nx + 2;
    double sum = 0.0;
    for (int l = 0; l < 4; l++, c += mx) sum += (bu[0] * c[0] + bu[1] * c[1] + bu[2] * c[2] + bu[3] * c[3]) * bv[l];
    *h = sum / 36.0;
    return 0;
}

/* height, gradient and Hessian [h_XX, h_XY, h_YY] */
static int eval_h2(const heightmap *hm, double X, double Y, double *h, double g[2], double H[3]) {
    const double *c;
    double t, s, u0[4], u1[4], u2[4], v0[4], v1[4], v2[4];
    if (locate(hm, X, Y, &c, &t, &s)) return 1;
    rows2(t, u0, u1, u2);
    rows2(s, v0, v1, v2);
    int mx = hm->nx + 2;
    double h0 = 0, hx = 0, hy = 0, hxx = 0, hxy = 0, hyy = 0;
    for (int l = 0; l < 4; l++, c += mx) {
        double r0 = u0[0] * c[0] + u0[1] * c[1] + u0[2] * c[2] + u0[3] * c[3];
        double r1 = u1[0] * c[0] + u1[1] * c[1] + u1[2] * c[2] + u1[3] * c[3];
        double r2 = u2[0] * c[0] + u2[1] * c[1] + u2[2] * c[2] + u2[3] * c[3];
        h0 += r0 * v0[l];
        hy += r0 * v1[l];
        hyy += r0 * v2[l];
        hx += r1 * v0[l];
        hxy += r1 * v1[l];
        hxx += r2 * v0[l];
    }
    double ix = 1.0 / hm->dx, iy = 1.0 / hm->dy;
    *h = h0 / 36.0;
    g[0] = hx * ix / 12.0;
    g[1] = hy * iy / 12.0;
    H[0] = hxx * ix * ix / 6.0;
    H[1] = hxy * ix * iy / 4.0;
    H[2] = hyy * iy * iy / 6.0;
    return 0;
}

/* ------------------------------------------------------------------------------------- the rim search */

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static void cross3(const double *a, const double *b, double *c) {
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

#define RIM_ITER 40         /* evaluations of the polish at most: a bounded cost */

/* The largest height of the patch of the cell that holds (X, Y) on the grid (the cell eval_h uses): at most its
 * largest B-spline coefficient, the basis being nonnegative and summing to 1 up to rounding. */
static double cell_bound(const heightmap *hm, double X, double Y) {
    int i, j;
    grid_cell(hm, (X - hm->x0) / hm->dx, (Y - hm->y0) / hm->dy, &i, &j);
    size_t k = (size_t)j * (size_t)(hm->nx - 1) + (size_t)i;
    return hm->cellmax[k] + 1e-12 * (fabs(hm->cellmax[k]) + fabs(hm->cellmin[k]));
}

/* What the search leaves for its Jacobian: the frame under the center and the final point's terrain data. */
typedef struct {
    double e[6];                                         /* p, h(p), h_X(p), h_Y(p) */
    double H0[3], n0[3], mn, na, tn, r1[3], r2[3];       /* the frame: Hessian and normal under the center */
    double cb, sb, dp[3], g[2], H[3], d2;                /* the final beta: cos, sin, p', gradient, Hessian, g'' */
} rim_final;

static int rim_search(const heightmap *hm, const double x[7], rim_final *f, double bad[2]) {
    const double *c = x, *a = x + 3, R = x[6];
    double h0, g0[2];
    if (eval_h2(hm, c[0], c[1], &h0, g0, f->H0)) {
        bad[0] = c[0], bad[1] = c[1];
        return 1;
    }
    /* the frame: n0 the unit normal under the center, t its part perpendicular to the axle, r1 = -t/|t|,
     * r2 = a x r1 (contact.rim_point's formulas, operation for operation where it matters) */
    double m[3] = {-g0[0], -g0[1], 1.0}, t[3], *n0 = f->n0, *r1 = f->r1, *r2 = f->r2;
    f->mn = sqrt(dot3(m, m));
    for (int k = 0; k < 3; k++) n0[k] = m[k] / f->mn;
    f->na = dot3(n0, a);
    for (int k = 0; k < 3; k++) t[k] = n0[k] - f->na * a[k];
    f->tn = sqrt(dot3(t, t));
    for (int k = 0; k < 3; k++) r1[k] = -(t[k] / f->tn);
    cross3(a, r1, r2);
    /* 13 samples of g(beta) = h(p) - p_Z on the lower half of the rim: beta = 0 first, then k = -6..6 */
    static const int ORDER[13] = {0, -6, -5, -4, -3, -2, -1, 1, 2, 3, 4, 5, 6};
    /* cos and sin of k pi / 12, k = 0..6, as the C library gives them (and CasADi folded them before) */
    static const double COS[7] = {1.0, 0.96592582628906831, 0.86602540378443871, 0.70710678118654757,
                                  0.50000000000000011, 0.25881904510252074, 6.123233995736766e-17};
    static const double SIN[7] = {0.0, 0.25881904510252074, 0.49999999999999994, 0.70710678118654746,
                                  0.8660254037844386, 0.96592582628906831, 1.0};
    const double pi = 3.14159265358979323846;
    /* Pruning, exact: every sample lies within R of the center horizontally; where that square is on the grid,
     * the spline under it is at most the largest B-spline coefficient of its cells (the basis is nonnegative and
     * sums to 1 there), so a sample whose p_Z is so high that even that height could not beat the best g so far
     * is not evaluated: it could not have been chosen; a sample that passes is tested again against the bound of its
     * own cell (cell_bound). (Off the grid's edge nothing is pruned, so a point off the grid still fails the
     * evaluation as before.) */
    double hmax = 0.0;
    int prune = 0;
    {
        double Rb = R * (1.0 + 1e-9) + 1e-12;
        double u0 = (c[0] - Rb - hm->x0) / hm->dx, u1 = (c[0] + Rb - hm->x0) / hm->dx;
        double v0 = (c[1] - Rb - hm->y0) / hm->dy, v1 = (c[1] + Rb - hm->y0) / hm->dy;
        if (u0 >= 0.0 && u1 <= hm->nx - 1 && v0 >= 0.0 && v1 <= hm->ny - 1) {
            int i0 = cell(u0, hm->nx), i1 = cell(u1, hm->nx), j0 = cell(v0, hm->ny), j1 = cell(v1, hm->ny);
            if ((i1 - i0 + 4) * (j1 - j0 + 4) <= 64) {
                /* the coefficients of cells i0..i1 x j0..j1 are rows j0..j1+3 x columns i0..i1+3 */
                const int mc = hm->nx - 1;
                double lo = hm->cellmin[(size_t)j0 * mc + i0], hi = hm->cellmax[(size_t)j0 * mc + i0];
                for (int jj = j0; jj <= j1; jj++)
                    for (int ii = i0; ii <= i1; ii++) {
                        if (hm->cellmax[(size_t)jj * mc + ii] > hi) hi = hm->cellmax[(size_t)jj * mc + ii];
                        if (hm->cellmin[(size_t)jj * mc + ii] < lo) lo = hm->cellmin[(size_t)jj * mc + ii];
                    }
                hmax = hi + 1e-12 * (fabs(hi) + fabs(lo));     /* the basis sums to 1 up to rounding */
                prune = 1;
            }
        }
    }
    double best_b = 0.0, best_g = 0.0;
    for (int kk = 0; kk < 13; kk++) {
        int k = ORDER[kk], ka = k < 0 ? -k : k;
        double b = k * pi / 12, cb = COS[ka], sb = k < 0 ? -SIN[ka] : SIN[ka], p[3], h;
        p[2] = c[2] + R * (cb * r1[2] + sb * r2[2]);            /* the height first: enough to prune */
        if (prune && kk > 0 && hmax - p[2] < best_g) continue;
        for (int i = 0; i < 2; i++) p[i] = c[i] + R * (cb * r1[i] + sb * r2[i]);
        if (prune && kk > 0 && cell_bound(hm, p[0], p[1]) - p[2] < best_g) continue;   /* the same, per cell */
        if (eval_h(hm, p[0], p[1], &h)) {
            bad[0] = p[0], bad[1] = p[1];
            return 1;
        }
        double g = h - p[2];
        if (kk == 0 || g > best_g) best_b = b, best_g = g;
    }
    /* The maximum of g in the best sample's bracket [best - pi/12, best + pi/12] (within the half rim):
     * safeguarded Newton on g'(beta) = 0, a step that leaves the bracket or meets g'' >= 0 replaced by bisection
     * on the sign of g' (the contact search's polish, rim.c), to convergence or RIM_ITER evaluations; where g
     * rises toward an end of the half rim the end is the maximum. Converged, the point is the rim's maximum
     * whatever sample started it, so it does not jump when the best sample changes (on sharp terrain 4 plain
     * Newton steps did not converge, and the force jumped with the start). */
    double b = best_b, p[3], h, *dp = f->dp, *g = f->g, *H = f->H, d1 = 0.0, d2 = 0.0, cb = 0.0, sb = 0.0;
    double lo = fmax(best_b - pi / 12, -pi / 2), hi = fmin(best_b + pi / 12, pi / 2);
    for (int it = 0;; it++) {
        cb = cos(b), sb = sin(b);
        for (int i = 0; i < 3; i++) {
            p[i] = c[i] + R * (cb * r1[i] + sb * r2[i]);
            dp[i] = R * (-sb * r1[i] + cb * r2[i]);
        }
        if (eval_h2(hm, p[0], p[1], &h, g, H)) {
            bad[0] = p[0], bad[1] = p[1];
            return 1;
        }
        double ddp[3] = {c[0] - p[0], c[1] - p[1], c[2] - p[2]};
        d1 = g[0] * dp[0] + g[1] * dp[1] - dp[2];
        d2 = dp[0] * (H[0] * dp[0] + H[1] * dp[1]) + dp[1] * (H[1] * dp[0] + H[2] * dp[1]) + g[0] * ddp[0] +
             g[1] * ddp[1] - ddp[2];
        if (it == RIM_ITER || d1 == 0) break;        /* the final point: p, h, g, H, d2 are its */
        if (d1 > 0) lo = b;
        else hi = b;
        double next = 0.5 * (lo + hi);
        int newton_step = 0;
        if (d2 < 0) {
            double newton = b - d1 / d2;
            if (newton >= lo && newton <= hi) next = newton, newton_step = 1;
        }
        /* converged: a Newton step below 1e-13 rad leaves an error of order 1e-26; an end where g rises toward
         * it, or a bracket down to rounding, cannot move b */
        if (next == b || (newton_step && fabs(next - b) < 1e-13) || hi - lo <= 4 * 2.2e-16 * fmax(1.0, fabs(b)))
            break;
        b = next;
    }
    /* an end of the half rim where g still rises is no stationary point: its angle is a constant (rim_jacobian) */
    f->cb = cb, f->sb = sb, f->d2 = fabs(b) < pi / 2 - 1e-12 ? d2 : 0.0;
    f->e[0] = p[0], f->e[1] = p[1], f->e[2] = p[2], f->e[3] = h, f->e[4] = g[0], f->e[5] = g[1];
    return 0;
}

/* The Jacobian d e / d x, x = [c, a, R]. At the final beta where g'' < 0 the point is the rim's tangency
 * point (g'(beta) = 0): the implicit function theorem gives d beta = -(d g' at fixed beta) / g'', so p's
 * derivative is the derivative of the stationary point itself, whatever frame beta is measured in (exact
 * at convergence, which the polish reaches). At an end of the half rim, or where g'' >= 0, beta is held
 * constant and p moves with the frame (r1 follows the normal under the center: its Hessian). */
static void rim_jacobian(const double x[7], const rim_final *f, double *J) {
    const double *a = x + 3, R = x[6], *H0 = f->H0, *n0 = f->n0, *r1 = f->r1, *r2 = f->r2, *dp = f->dp;
    const double *g = f->g, *H = f->H, cb = f->cb, sb = f->sb, mn = f->mn, na = f->na, tn = f->tn, d2 = f->d2;
    int implicit = d2 < 0;
    for (int col = 0; col < 7; col++) {
        double dc[3] = {0, 0, 0}, da[3] = {0, 0, 0}, dR = 0.0;
        if (col < 3) dc[col] = 1.0;
        else if (col < 6) da[col - 3] = 1.0;
        else dR = 1.0;
        /* d n0 (only c_X, c_Y move it), d t, d r1, d r2 */
        double dm[3] = {-(H0[0] * dc[0] + H0[1] * dc[1]), -(H0[1] * dc[0] + H0[2] * dc[1]), 0.0};
        double dn0[3], dmn = dot3(n0, dm);
        for (int k = 0; k < 3; k++) dn0[k] = (dm[k] - n0[k] * dmn) / mn;
        double dna = dot3(dn0, a) + dot3(n0, da), dt[3], dr1[3], dr2[3], tmp[3];
        for (int k = 0; k < 3; k++) dt[k] = dn0[k] - dna * a[k] - na * da[k];
        double r1dt = dot3(r1, dt);
        for (int k = 0; k < 3; k++) dr1[k] = -(dt[k] - r1[k] * r1dt) / tn;
        cross3(da, r1, dr2);
        cross3(a, dr1, tmp);
        for (int k = 0; k < 3; k++) dr2[k] += tmp[k];
        /* at fixed beta: d p and d p' (p' = dp/dbeta) */
        double dpf[3], ddp1[3];
        for (int k = 0; k < 3; k++) {
            dpf[k] = dc[k] + dR * (cb * r1[k] + sb * r2[k]) + R * (cb * dr1[k] + sb * dr2[k]);
            ddp1[k] = dR * (-sb * r1[k] + cb * r2[k]) + R * (-sb * dr1[k] + cb * dr2[k]);
        }
        double dbeta = 0.0;
        if (implicit) {
            double Hx = H[0] * dpf[0] + H[1] * dpf[1], Hy = H[1] * dpf[0] + H[2] * dpf[1];
            double dG = Hx * dp[0] + Hy * dp[1] + g[0] * ddp1[0] + g[1] * ddp1[1] - ddp1[2];
            dbeta = -dG / d2;
        }
        double dpt[3];
        for (int k = 0; k < 3; k++) dpt[k] = dpf[k] + dp[k] * dbeta;
        double *Jc = J + 6 * col;
        Jc[0] = dpt[0], Jc[1] = dpt[1], Jc[2] = dpt[2];
        Jc[3] = g[0] * dpt[0] + g[1] * dpt[1];
        Jc[4] = H[0] * dpt[0] + H[1] * dpt[1];
        Jc[5] = H[1] * dpt[0] + H[2] * dpt[1];
    }
}

int heightmap_rim(const heightmap *hm, const double x[7], double e[6], double *J, double bad[2]) {
    rim_final f;
    if (rim_search(hm, x, &f, bad)) return 1;
    memcpy(e, f.e, sizeof f.e);
    if (J) rim_jacobian(x, &f, J);
    return 0;
}

/* The memo of the last searches (heightmap_memo): the model evaluates the same wheel at the same pose several
 * times (a step's end for its switches, then the next step's start for F; the outputs at a communication point;
 * F and then its Jacobian), so a search whose input is bit for bit one of the last RIM_MEMO is not done again. The
 * search is a function of x alone: the memo changes no result, only the work. */
#define RIM_MEMO 32
struct heightmap_memo {
    double x[RIM_MEMO][7];
    rim_final f[RIM_MEMO];
    int n, next;
    long hits, misses;
};

size_t heightmap_memo_size(void) { return sizeof(heightmap_memo); }

static int rim_memoized(const heightmap *hm, heightmap_memo *memo, const double x[7], double e[6], double *J,
                        double bad[2]) {
    if (!memo) return heightmap_rim(hm, x, e, J, bad);
    const rim_final *f = NULL;
    for (int i = 0; i < memo->n && !f; i++)
        if (memo->x[i][0] == x[0] && memcmp(memo->x[i], x, sizeof memo->x[i]) == 0) f = &memo->f[i];
    if (f) {
        memo->hits++;
    } else {
        rim_final found;
        if (rim_search(hm, x, &found, bad)) return 1;
        memo->misses++;
        int k = memo->next;
        memcpy(memo->x[k], x, sizeof memo->x[k]);
        memo->f[k] = found;
        memo->next = (k + 1) % RIM_MEMO;
        if (memo->n < RIM_MEMO) memo->n++;
        f = &memo->f[k];
    }
    memcpy(e, f->e, sizeof f->e);
    if (J) rim_jacobian(x, f, J);
    return 0;
}

/* ------------------------------------------------------------------------------- CasADi external functions */

typedef long long int casadi_int;

static __thread heightmap *active;
static __thread heightmap_memo *active_memo;

void heightmap_activate(heightmap *hm, heightmap_memo *memo) {
    active = hm;
    active_memo = hm ? memo : NULL;
}

unsigned long long heightmap_active_id(void) { return active ? active->id : 0; }

static int outside(const double *x) {
    snprintf(active->msg, sizeof active->msg,
             "the terrain was evaluated at (X, Y) = (%.6g, %.6g) m, outside the heightmap [%.6g, %.6g] x "
             "[%.6g, %.6g] m",
             x[0], x[1], active->x0, active->x0 + (active->nx - 1) * active->dx, active->y0,
             active->y0 + (active->ny - 1) * active->dy);
    return 1;
}

static int eval_active(const double *x, double *h, double *d1, double *d2, double *d3) {
    if (!active) return 1;
    if (!d3) {     /* the model's evaluations (height, gradient, Hessian): the unrolled evaluation */
        double h0, g[2], H[3];
        if (eval_h2(active, x[0], x[1], &h0, g, H)) return outside(x);
        if (h) *h = h0;
        if (d1) d1[0] = g[0], d1[1] = g[1];
        if (d2) d2[0] = H[0], d2[1] = d2[2] = H[1], d2[3] = H[2];
        return 0;
    }
    return heightmap_eval(active, x[0], x[1], h, d1, d2, d3) ? outside(x) : 0;
}

/* CasADi compressed column sparsity: nrow, ncol, colind[ncol + 1], row[nnz] */
static const casadi_int SP_X[] = {2, 1, 0, 2, 0, 1};
static const casadi_int SP_1[] = {1, 1, 0, 1, 0};
static const casadi_int SP_1X2[] = {1, 2, 0, 1, 2, 0, 0};
static const casadi_int SP_2X2[] = {2, 2, 0, 2, 4, 0, 1, 0, 1};
static const casadi_int SP_4X2[] = {4, 2, 0, 4, 8, 0, 1, 2, 3, 0, 1, 2, 3};
static const casadi_int SP_7[] = {7, 1, 0, 7, 0, 1, 2, 3, 4, 5, 6};
static const casadi_int SP_6[] = {6, 1, 0, 6, 0, 1, 2, 3, 4, 5};
static const casadi_int SP_8[] = {8, 1, 0, 8, 0, 1, 2, 3, 4, 5, 6, 7};
static const casadi_int SP_2[] = {2, 1, 0, 2, 0, 1};
static const casadi_int SP_6X7[] = {6, 7, 0, 6, 12, 18, 24, 30, 36, 42,
                                    0, 1, 2, 3, 4, 5, 0, 1, 2, 3, 4, 5, 0, 1, 2, 3, 4, 5, 0, 1, 2, 3, 4, 5,
                                    0, 1, 2, 3, 4, 5, 0, 1, 2, 3, 4, 5, 0, 1, 2, 3, 4, 5};

#define EXTERNAL_SHAPE(name, n_in, n_out, sp_in, sp_out)                                                   \
    casadi_int name##_n_in(void) { return n_in; }                                                          \
    casadi_int name##_n_out(void) { return n_out; }                                                        \
    const casadi_int *name##_sparsity_in(casadi_int i) { return i >= 0 && i < n_in ? sp_in[i] : NULL; }    \
    const casadi_int *name##_sparsity_out(casadi_int i) { return i >= 0 && i < n_out ? sp_out[i] : NULL; }

/* cedra_heightmap: (x[2]) -> (h, gradient[2], Hessian[2x2]): the model uses all three explicitly (the rim
 * search's Newton steps need the Hessian), so symbolic differentiation of the model (the implicit solver's
 * Jacobian, the settle Jacobian) needs one level more: jac_cedra_heightmap: (x, h, gradient, Hessian) ->
 * (dh/dx [1x2], dgradient/dx [2x2], dvec(Hessian)/dx [4x2]), third derivatives included. Deeper levels are not
 * provided: the model generator fails loudly if a formula would need them. */
static const casadi_int *const IN0[] = {SP_X};
static const casadi_int *const OUT0[] = {SP_1, SP_X, SP_2X2};
static const casadi_int *const IN1[] = {SP_X, SP_1, SP_X, SP_2X2};
static const casadi_int *const OUT1[] = {SP_1X2, SP_2X2, SP_4X2};

/* cedra_rim_contact: (x[7] = [wheel center c, unit axle a, radius R]) -> (e[6] = [p, h(p), h_X(p), h_Y(p)],
 * J[6x7] = de/dx): the wheel's contact point p (docs/model.md, Contact: the best of 13 samples polished to the
 * maximum, in C, heightmap_rim) with the terrain's height and gradient there, and their exact derivative with
 * respect to the wheel's pose (implicit function theorem at the tangency point). The model uses J explicitly
 * (cedra.mechanics.terrain: the contact's chain rule), so nothing differentiates this function. cedra_rim_point:
 * the same without J (the functions that hold no derivative, cedra_f above all). */
static const casadi_int *const IN2[] = {SP_7};
static const casadi_int *const OUT2[] = {SP_6, SP_6X7};
/* jac_cedra_rim_point: (x, e) -> (de/dx [6x7]): cedra_rim_point differentiable once (CasADi's AD of a function
 * that calls it, e.g. the Python side's MX Jacobian of cedra_f in cedra.reports.common) */
static const casadi_int *const IN3[] = {SP_7, SP_6};
static const casadi_int *const OUT3[] = {SP_6X7};

/* the metadata CasADi reads when it loads the functions from a shared library (Python side,
 * cedra.mechanics.heightmap) */
EXTERNAL_SHAPE(cedra_heightmap, 1, 3, IN0, OUT0)
EXTERNAL_SHAPE(jac_cedra_heightmap, 4, 3, IN1, OUT1)
EXTERNAL_SHAPE(cedra_rim_contact, 1, 2, IN2, OUT2)
EXTERNAL_SHAPE(cedra_rim_point, 1, 1, IN2, OUT2)
EXTERNAL_SHAPE(jac_cedra_rim_point, 2, 1, IN3, OUT3)
/* cedra_heightmap_bounds: (tin[8], unused: a heightmap has no terrain inputs) -> (bounds[2] = heightmap.bound):
 * the terrain's cedra_terrain_bounds for the contact search (rim.c) */
static const casadi_int *const IN4[] = {SP_8};
static const casadi_int *const OUT4[] = {SP_2};
EXTERNAL_SHAPE(cedra_heightmap_bounds, 1, 1, IN4, OUT4)

static const double ORIGIN[2] = {0.0, 0.0};     /* CasADi passes NULL for an all-zero argument */

int cedra_heightmap(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return eval_active(arg[0] ? arg[0] : ORIGIN, res[0], res[1], res[2], NULL);
}

int jac_cedra_heightmap(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return eval_active(arg[0] ? arg[0] : ORIGIN, NULL, res[0], res[1], res[2]);
}

int cedra_heightmap_bounds(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)arg, (void)iw, (void)w, (void)mem;
    if (!active) return 1;
    if (res[0]) res[0][0] = active->bound[0], res[0][1] = active->bound[1];
    return 0;
}

static const double ZERO7[7] = {0, 0, 0, 0, 0, 0, 0};

static int rim_active(const double *x, double *e_out, double *J_out) {
    double e[6], J[42], bad[2];
    if (!active) return 1;
    if (rim_memoized(active, active_memo, x ? x : ZERO7, e, J_out ? J : NULL, bad)) return outside(bad);
    if (e_out) memcpy(e_out, e, sizeof e);
    if (J_out) memcpy(J_out, J, sizeof J);
    return 0;
}

int cedra_rim_contact(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return rim_active(arg[0], res[0], res[1]);
}

int cedra_rim_point(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return rim_active(arg[0], res[0], NULL);
}

int jac_cedra_rim_point(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return rim_active(arg[0], NULL, res[0]);
}

#ifdef CEDRA_HEIGHTMAP_HOST
/* for Python (cedra.mechanics.heightmap): one process-wide map, loaded with malloc and active in the loading thread */
static heightmap host_map;
static char host_msg[512];

static heightmap_memo *host_memo;      /* cedra_heightmap_host_memo (loading a map removes it) */

int cedra_heightmap_host_load(const char *path) {
    free(host_memo);
    host_memo = NULL;
    heightmap_release(&host_map, free);
    if (heightmap_read(&host_map, path, calloc, free, host_msg, sizeof host_msg)) return 1;
    heightmap_activate(&host_map, NULL);
    return 0;
}

const char *cedra_heightmap_host_message(void) { return host_msg[0] ? host_msg : host_map.msg; }

/* the memo for the loading thread's map (tests: it must change no result); on = 0 removes it. Counts: hits, misses */

int cedra_heightmap_host_memo(int on) {
    free(host_memo);
    host_memo = on ? (heightmap_memo *)calloc(1, sizeof *host_memo) : NULL;
    if (on && !host_memo) return 1;
    heightmap_activate(&host_map, host_memo);
    return 0;
}

void cedra_heightmap_host_memo_counts(long counts[2]) {
    counts[0] = host_memo ? host_memo->hits : 0;
    counts[1] = host_memo ? host_memo->misses : 0;
}
#endif
