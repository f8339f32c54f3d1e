"""python -m cedra report figures: its counting helpers against hand counts, and its command line (the figures
themselves are measurements, printed and never asserted on; docs/reports/figures.md is one run's page)."""
from __future__ import annotations

import argparse

import casadi as ca
import numpy as np

from cedra.reports import figures


def test_cholesky_work_counts_the_multiply_adds_of_the_factor():
    for n in (1, 2, 5, 15):         # dense: sum over columns k of m (m + 1) / 2, m = n - 1 - k
        assert figures._cholesky_work(np.ones((n, n), bool), list(range(n))) == (n - 1) * n * (n + 1) // 6
    n = 6                           # an arrow matrix: the hub first fills everything, last fills nothing
    arrow = np.eye(n, dtype=bool)
    arrow[0, :] = arrow[:, 0] = True
    assert figures._cholesky_work(arrow, list(range(n))) == (n - 1) * n * (n + 1) // 6
    assert figures._cholesky_work(arrow, list(range(1, n)) + [0]) == n - 1
    assert figures._cholesky_work(np.eye(n, dtype=bool), list(range(n))) == 0


def test_size_counts_a_switch_by_its_two_forms():
    x = ca.SX.sym("x")
    small = ca.Function("small", [x], [x + 1])
    big = ca.Function("big", [x], [ca.sin(x) * ca.cos(x) + x * x])
    assert figures._size(big) == (big.n_instructions(), big.n_instructions())
    m = ca.MX.sym("m")
    pre = ca.Function("pre", [x], [2 * x])
    forms = ca.Function.if_else("forms", small, big)
    outer = ca.Function("outer", [m], [forms(m > 0, pre(m))])
    # if_else(name, f_true, f_false): the true branch is the one-maximum form (CedraModel._contract's order)
    assert figures._size(outer) == (pre.n_instructions() + small.n_instructions(),
                                    pre.n_instructions() + big.n_instructions())


def test_path_distance_is_the_largest_gap_either_way():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    assert figures._path_distance(p, p) == 0.0
    q = p + [0.0, 0.25]
    assert abs(figures._path_distance(p, q) - 0.25) < 1e-15
    assert abs(figures._path_distance(p, p[:2]) - 1.0) < 1e-15       # one path goes on where the other stops


def test_an_unknown_figure_is_refused_before_anything_runs(capsys):
    args = argparse.Namespace(figure=["nonsense"], build="build", out="out/report", quiet=True)
    assert figures.main(args) == 2
    assert "nonsense" in capsys.readouterr().err
