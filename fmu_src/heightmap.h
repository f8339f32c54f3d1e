/* The heightmap terrain (docs/model.md, Terrain, kind "heightmap"): a grid of heights read from a text file and
 * interpolated by the natural bicubic spline (C2; plane data gives the plane exactly). The generated model calls
 * the terrain as CasADi external functions (cedra_rim_contact: a wheel's contact point with its derivatives;
 * cedra_heightmap and its Jacobians, up to third derivatives, for single points), which
 * read the heightmap made active for the calling thread: the glue activates its instance's map before every
 * model evaluation, so instances never share terrain data.
 *
 * File format (text; '#' starts a comment):
 *     cedra-heightmap 1
 *     nx ny x0 y0 dx dy            grid size (>= 2 each), the first node's X, Y (m), the spacings (m, > 0)
 *     z z z ...                    ny rows of nx heights (m): row j holds Y = y0 + j dy, X = x0 .. x0 + (nx-1) dx
 * The terrain is defined on [x0, x0 + (nx-1) dx] x [y0, y0 + (ny-1) dy]; evaluating outside fails (the model
 * reports the point) rather than inventing ground. */
#ifndef CEDRA_HEIGHTMAP_H
#define CEDRA_HEIGHTMAP_H

#include <stddef.h>

typedef struct {
    int nx, ny;
    double x0, y0, dx, dy;
    double *coef;           /* (nx + 2) * (ny + 2) B-spline coefficients, X fastest */
    /* (nx - 1) * (ny - 1), X fastest: the largest / smallest of the 16 coefficients a cell's patch is made of (the
     * rim search's bound on the height over a wheel's square, looked up per cell instead of scanned per search) */
    double *cellmax, *cellmin;
    /* over the whole grid: bound[0] >= |gradient|, bound[1] >= the Hessian's largest eigenvalue (from the
     * coefficients' differences; the contact search's test for one maximum, rim.c) */
    double bound[2];
    unsigned long long id;  /* this map among every map read in the process (1, 2, ...): caches key on it */
    char msg[256];          /* why the last evaluation failed (a point outside the grid) */
} heightmap;

typedef void *(*heightmap_alloc)(size_t n, size_t size);
typedef void (*heightmap_free_fn)(void *p);

/* reads and fits path into hm; 0, or 1 with the reason in msg (file, line, what) */
int heightmap_read(heightmap *hm, const char *path, heightmap_alloc alloc, heightmap_free_fn fr, char *msg,
                   size_t msg_len);
void heightmap_release(heightmap *hm, heightmap_free_fn fr);

/* A memo of the rim search's last results (heightmap.c: rim_memoized), heightmap_memo_size() bytes, zeroed before
 * first use; it belongs to one map (an FMU instance keeps one beside its map) and changes no result. */
typedef struct heightmap_memo heightmap_memo;
size_t heightmap_memo_size(void);

/* the map the external functions evaluate in this thread (NULL: they fail), and its memo (NULL: none) */
void heightmap_activate(heightmap *hm, heightmap_memo *memo);
/* the active map's id (0: none): what the contact search's memo (rim.c) keys on besides the wheel */
unsigned long long heightmap_active_id(void);

/* height and derivatives at (X, Y): d1 = [h_X, h_Y], d2 = [h_XX, h_YX, h_XY, h_YY] (column-major Hessian),
 * d3 = d vec(Hessian) / d[X, Y] (4 x 2 column-major); any of them may be NULL. 0, or 1 outside the grid. */
int heightmap_eval(const heightmap *hm, double X, double Y, double *h, double *d1, double *d2, double *d3);

/* the contact point of a wheel (docs/model.md, Contact) and its derivatives: x = [center c (3), unit axle a (3),
 * radius R]; e = [p (3), h(p), h_X(p), h_Y(p)]; J (6 x 7, column-major, may be NULL) = de/dx. 0, or 1 when a point
 * of the search is outside the grid (that point in bad). */
int heightmap_rim(const heightmap *hm, const double x[7], double e[6], double *J, double bad[2]);

#endif
