/* Small dense linear algebra for the glue and the implicit solver (column-major, n <= a few dozen). */
#ifndef CEDRA_LINALG_H
#define CEDRA_LINALG_H

/* LU factorization with partial pivoting in place; returns 0, or 1 if the matrix is singular/non-finite. */
int linalg_lu_factor(int n, double *a, int *piv);
/* Solve A x = b in place on b with the factors of linalg_lu_factor. */
void linalg_lu_solve(int n, const double *lu, const int *piv, double *b);

#endif
