/* Small dense linear algebra for the glue and the implicit solver (column-major, n <= a few dozen). */
#ifndef CEDRA_LINALG_H
#define CEDRA_LINALG_H

/* LU factorization with partial pivoting in place; returns 0, or 1 if the matrix is singular/non-finite. */
int linalg_lu_factor(int n, double *a, int *piv);
/* Solve A x = b in place on b with the factors of linalg_lu_factor. */
void linalg_lu_solve(int n, const double *lu, const int *piv, double *b);
/* Solve L L^T x = b in place on b, L from linalg_chol_factor_perm (the permuted system; linalg_chol_solve_perm
 * solves A's). */
void linalg_chol_solve(int n, const double *l, double *b);
/* Cholesky factorization P A P^T = L L^T of a symmetric A, perm[k] = the row and column of A eliminated k-th (the
 * identity: A itself; only A's lower triangle is then read); l (n x n, not a) receives L, nz is n ints of scratch.
 * Returns 0, or 1 if A is not (numerically) positive definite or not finite. About a third of the LU's work, and no
 * pivoting: the mass matrix of a mechanism is symmetric positive definite. The factor skips the exact zeros of L's
 * columns: with an order that keeps a sparse A's zeros zero (a mechanism's mass matrix with its wheels first:
 * cedra.fmu.mass_order) it does a fraction of the dense work. Solve: b := A^-1 b, work n doubles. */
int linalg_chol_factor_perm(int n, const double *a, const int *perm, double *l, int *nz);
void linalg_chol_solve_perm(int n, const double *l, const int *perm, double *b, double *work);

#endif
