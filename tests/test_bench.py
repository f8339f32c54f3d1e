"""`python -m cedra bench` compiles the generated functions itself (cedra.reports.bench.compile_functions): a
scene whose functions call the analytic terrain's contact search gets fmu_src/rim.c linked in, and its cedra_f
gives what the Python side's does."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cedra.models.scene import load_shipped
from cedra.reports.bench import compile_functions
from cedra.reports.common import Problem


def test_compiled_functions_with_the_contact_search_equal_the_python_side(tmp_path: Path):
    prob = Problem(load_shipped("bump2d"))
    q = prob.settle()
    u = np.zeros(prob.nq)
    u[prob.q_names.index("x")] = 0.2
    q[prob.q_names.index("x")] = 0.9                   # the front wheels on the bump: the search is called
    ext = compile_functions(prob.fns, ["cedra_f", "cedra_M"], tmp_path)
    for name, args in (("cedra_f", (q, u, prob.inp0, prob.par)), ("cedra_M", (q, prob.par))):
        got = np.array(ext[name](*args)[0] if ext[name].n_out() > 1 else ext[name](*args))
        want = np.array(prob.fns[name](*args)[0] if prob.fns[name].n_out() > 1 else prob.fns[name](*args))
        assert np.max(np.abs(got - want)) <= 1e-12 * max(1.0, np.max(np.abs(want))), name
