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
    return 0;
}

int heightmap_read(heightmap *hm, const char *path, heightmap_alloc alloc, heightmap_free_fn fr, char *msg,
                   size_t msg_len) {
    reader r = {NULL, 1, {0}};
    double head[6], *z = NULL;
    int rc = 1;
    memset(hm, 0, sizeof *hm);
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
    hm->coef = NULL;
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

/* ------------------------------------------------------------------------------- CasADi external functions */

typedef long long int casadi_int;

static __thread heightmap *active;

void heightmap_activate(heightmap *hm) { active = hm; }

static int eval_active(const double *x, double *h, double *d1, double *d2, double *d3) {
    if (!active) return 1;
    if (heightmap_eval(active, x[0], x[1], h, d1, d2, d3)) {
        snprintf(active->msg, sizeof active->msg,
                 "the terrain was evaluated at (X, Y) = (%.6g, %.6g) m, outside the heightmap [%.6g, %.6g] x "
                 "[%.6g, %.6g] m",
                 x[0], x[1], active->x0, active->x0 + (active->nx - 1) * active->dx, active->y0,
                 active->y0 + (active->ny - 1) * active->dy);
        return 1;
    }
    return 0;
}

/* CasADi compressed column sparsity: nrow, ncol, colind[ncol + 1], row[nnz] */
static const casadi_int SP_X[] = {2, 1, 0, 2, 0, 1};
static const casadi_int SP_1[] = {1, 1, 0, 1, 0};
static const casadi_int SP_1X2[] = {1, 2, 0, 1, 2, 0, 0};
static const casadi_int SP_2X2[] = {2, 2, 0, 2, 4, 0, 1, 0, 1};
static const casadi_int SP_4X2[] = {4, 2, 0, 4, 8, 0, 1, 2, 3, 0, 1, 2, 3};

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

/* the metadata CasADi reads when it loads the functions from a shared library (Python side, cedra.mechanics.heightmap) */
EXTERNAL_SHAPE(cedra_heightmap, 1, 3, IN0, OUT0)
EXTERNAL_SHAPE(jac_cedra_heightmap, 4, 3, IN1, OUT1)

static const double ORIGIN[2] = {0.0, 0.0};     /* CasADi passes NULL for an all-zero argument */

int cedra_heightmap(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return eval_active(arg[0] ? arg[0] : ORIGIN, res[0], res[1], res[2], NULL);
}

int jac_cedra_heightmap(const double **arg, double **res, casadi_int *iw, double *w, int mem) {
    (void)iw, (void)w, (void)mem;
    return eval_active(arg[0] ? arg[0] : ORIGIN, NULL, res[0], res[1], res[2]);
}

#ifdef CEDRA_HEIGHTMAP_HOST
/* for Python (cedra.mechanics.heightmap): one process-wide map, loaded with malloc and active in the loading thread */
static heightmap host_map;
static char host_msg[512];

int cedra_heightmap_host_load(const char *path) {
    heightmap_release(&host_map, free);
    if (heightmap_read(&host_map, path, calloc, free, host_msg, sizeof host_msg)) return 1;
    heightmap_activate(&host_map);
    return 0;
}

const char *cedra_heightmap_host_message(void) { return host_msg[0] ? host_msg : host_map.msg; }
#endif
