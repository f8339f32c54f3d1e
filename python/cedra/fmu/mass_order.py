"""The order in which the FMU's Cholesky factor of the mass matrix eliminates the coordinates (CEDRA_M_ORDER in the
generated cedra_vars.h; fmu_src/linalg.c: linalg_chol_factor_perm).

A rover's mass matrix is half zeros (hills3d: 118 of 225 entries at a generic pose): a wheel's spin couples only to
its carrier's joint and the body's rotation, never to another wheel. Eliminating the wheels first keeps those zeros
zero in the factor, and a factor that skips them does a fifth of the dense work (124 multiply-adds instead of 560).
The order is a greedy minimum-degree order on the union of the nonzero patterns of M at a few fixed poses near the
design pose (not the design pose alone: its symmetry zeroes entries that are nonzero everywhere else). Any order
gives the same M^-1 b up to rounding; the factor checks the actual values, so an entry that happens to be nonzero
where the pattern said zero is still used."""
from __future__ import annotations

import numpy as np

from cedra.contract import ModelSpec

N_POSES = 8
SPREAD = 0.2        # rad or m: the poses are the design pose plus N(0, SPREAD) per coordinate (fixed seed)


def nonzero_pattern(spec: ModelSpec) -> np.ndarray:
    """Union over the poses of M's nonzero entries (n x n, symmetric, bool)."""
    fM = spec.functions["cedra_M"]
    par = [p.start for p in spec.params]
    rng = np.random.default_rng(13)
    q0 = np.asarray(spec.q_start, dtype=float)
    pattern = np.zeros((spec.nq, spec.nq), dtype=bool)
    for k in range(N_POSES):
        q = q0 + (rng.normal(scale=SPREAD, size=q0.size) if k else 0.0)
        M = np.array(fM(q, par))
        pattern |= np.isfinite(M) & (M != 0)
    return pattern | pattern.T | np.eye(spec.nq, dtype=bool)


def minimum_degree(pattern: np.ndarray) -> list[int]:
    """Greedy minimum-degree elimination order (ties: the lower index), with the fill each elimination creates."""
    g = pattern.copy()
    np.fill_diagonal(g, False)
    left = list(range(len(g)))
    order = []
    while left:
        k = min(left, key=lambda i: (int(g[i, left].sum()), i))
        nb = [i for i in left if g[k, i]]
        for i in nb:                        # eliminating k connects its remaining neighbours (fill)
            for j in nb:
                if i != j:
                    g[i, j] = True
        left.remove(k)
        order.append(k)
    return order


def elimination_order(spec: ModelSpec) -> list[int]:
    """order[k] = the coordinate the Cholesky factor eliminates k-th (the identity for a block without M)."""
    if "cedra_M" not in spec.functions:
        return list(range(spec.nq))
    return minimum_degree(nonzero_pattern(spec))
