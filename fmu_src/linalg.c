/* Small dense linear algebra (see linalg.h): LU with partial pivoting, column-major, a(i, j) = a[i + j*n]. */
#include "linalg.h"

#include <math.h>
#include <stddef.h>

int linalg_lu_factor(int n, double *a, int *piv) {
    for (int k = 0; k < n; k++) {
        double *colk = a + (size_t)k * n;
        /* Partial pivoting: the largest magnitude in the column bounds the multipliers by 1. */
        int p = k;
        double amax = fabs(colk[k]);
        for (int i = k + 1; i < n; i++) {
            double v = fabs(colk[i]);
            if (v > amax || isnan(v)) {        /* a NaN is picked up so that it is reported, not hidden */
                p = i;
                amax = v;
            }
        }
        piv[k] = p;
        if (amax == 0.0 || !isfinite(amax)) return 1;
        if (p != k) {                          /* swap whole rows so that the L part stays consistent */
            for (int j = 0; j < n; j++) {
                double *c = a + (size_t)j * n, tmp = c[k];
                c[k] = c[p];
                c[p] = tmp;
            }
        }
        double inv = 1.0 / colk[k];
        for (int i = k + 1; i < n; i++) colk[i] *= inv;
        /* Column-oriented rank-1 update: the inner loop runs down contiguous memory. */
        for (int j = k + 1; j < n; j++) {
            double *c = a + (size_t)j * n, akj = c[k];
            if (akj == 0.0) continue;
            for (int i = k + 1; i < n; i++) c[i] -= colk[i] * akj;
        }
    }
    return 0;
}

void linalg_lu_solve(int n, const double *lu, const int *piv, double *b) {
    /* the row interchanges of the factorization, in the order they were made */
    for (int k = 0; k < n; k++) {
        int p = piv[k];
        if (p != k) {
            double tmp = b[k];
            b[k] = b[p];
            b[p] = tmp;
        }
    }
    /* L y = P b (unit lower triangle), column-oriented */
    for (int j = 0; j < n; j++) {
        const double *c = lu + (size_t)j * n;
        double bj = b[j];
        if (bj == 0.0) continue;
        for (int i = j + 1; i < n; i++) b[i] -= c[i] * bj;
    }
    /* U x = y */
    for (int j = n - 1; j >= 0; j--) {
        const double *c = lu + (size_t)j * n;
        b[j] /= c[j];
        double bj = b[j];
        for (int i = 0; i < j; i++) b[i] -= c[i] * bj;
    }
}

void linalg_chol_solve(int n, const double *l, double *b) {
    for (int j = 0; j < n; j++) {                      /* L y = b */
        const double *c = l + (size_t)j * n;
        double bj = b[j] / c[j];
        b[j] = bj;
        for (int i = j + 1; i < n; i++) b[i] -= c[i] * bj;
    }
    for (int j = n - 1; j >= 0; j--) {                 /* L^T x = y */
        const double *c = l + (size_t)j * n;
        double acc = b[j];
        for (int i = j + 1; i < n; i++) acc -= c[i] * b[i];
        b[j] = acc / c[j];
    }
}

int linalg_chol_factor_perm(int n, const double *a, const int *perm, double *l, int *nz) {
    for (int j = 0; j < n; j++)                        /* l = P A P^T, lower triangle */
        for (int i = j; i < n; i++) l[(size_t)j * n + i] = a[(size_t)perm[j] * n + perm[i]];
    /* right-looking, column by column: column k of L, then the trailing lower triangle updated by it - only where
     * column k is nonzero (nz lists those rows): a zero there makes every product with it an exact no-op */
    for (int k = 0; k < n; k++) {
        double *colk = l + (size_t)k * n;
        double d = colk[k];
        if (!(d > 0.0) || !isfinite(d)) return 1;
        d = sqrt(d);
        colk[k] = d;
        double inv = 1.0 / d;
        int m = 0;
        for (int i = k + 1; i < n; i++) {
            colk[i] *= inv;
            if (colk[i] != 0.0) nz[m++] = i;
        }
        for (int jj = 0; jj < m; jj++) {
            int j = nz[jj];
            double *c = l + (size_t)j * n, ljk = colk[j];
            for (int ii = jj; ii < m; ii++) c[nz[ii]] -= colk[nz[ii]] * ljk;
        }
    }
    return 0;
}

void linalg_chol_solve_perm(int n, const double *l, const int *perm, double *b, double *work) {
    for (int k = 0; k < n; k++) work[k] = b[perm[k]];
    linalg_chol_solve(n, l, work);
    for (int k = 0; k < n; k++) b[perm[k]] = work[k];
}
