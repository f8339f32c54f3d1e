/* Small dense linear algebra for the glue and the implicit solver (column-major, n <= a few dozen). */
#ifndef CEDRA_LINALG_H
#define CEDRA_LINALG_H

/* LU factorization with partial pivoting in place; returns 0, or 1 if the matrix is singular/non-finite. */
int linalg_lu_factor(int n, double *a, int *piv);
/* Solve A x = b in place on b with the factors of linalg_lu_factor. */
void linalg_lu_solve(int n, const double *lu, const int *piv, double *b);
/* Cholesky factorization A = L L^T of a symmetric matrix in place (its lower triangle is read, L overwrites it);
 * returns 0, or 1 if A is not (numerically) positive definite or not finite. About a third of the LU's work, and
 * no pivoting: the mass matrix of a mechanism is symmetric positive definite. */
int linalg_chol_factor(int n, double *a);
/* Solve A x = b in place on b with the factor of linalg_chol_factor. */
void linalg_chol_solve(int n, const double *l, double *b);

#endif
