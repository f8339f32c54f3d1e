"""The toy FMU through the three embedded solvers: they agree to their tolerance; communication steps that are not
a multiple of h_max land exactly on the communication points."""
from __future__ import annotations

import numpy as np
import pytest

from fmu_harness import Toy

NAMES = ("pos.x", "pos.z", "vel.x", "vel.z", "Fn", "energy.work")
DRIVE = {"F": 8.0, "start.speed.z": -0.05}


def _run(toy, settings, t_end=0.5, h=0.01):
    t = Toy(toy, name="solvers")
    try:
        t.start({**DRIVE, **settings})
        rows = t.run(t_end, h)
        return {n: np.array([r[n] for r in rows]) for n in NAMES + ("solver.steps", "solver.rhs_evals")}
    finally:
        t.close()


@pytest.fixture(scope="module")
def runs(toy):
    return {
        "rk4": _run(toy, {"solver.method": 0, "solver.h_max": 2.5e-4}),
        "dopri5": _run(toy, {"solver.method": 1, "solver.tol": 1e-10, "solver.h_max": 0.01}),
        "rodas4": _run(toy, {"solver.method": 2, "solver.tol": 1e-10, "solver.h_max": 0.01}),
    }


@pytest.mark.parametrize("method", ["rk4", "rodas4"])
def test_solvers_agree(runs, method):
    ref, got = runs["dopri5"], runs[method]
    for n in NAMES:
        scale = max(1.0, float(np.max(np.abs(ref[n]))))
        err = float(np.max(np.abs(got[n] - ref[n]))) / scale
        assert err < 1e-6, (method, n, err)


def test_the_model_moves(runs):
    r = runs["dopri5"]
    assert r["pos.x"][-1] > 0.1 and r["energy.work"][-1] > 0.5        # slides and F does work
    assert np.all(np.diff(r["solver.steps"]) >= 1)


def test_communication_step_not_a_multiple_of_h_max(toy):
    # RK4 with h_max = 0.7 ms and communication steps of 10 ms: each step is 15 RK4 steps, the last one shortened
    a = _run(toy, {"solver.method": 0, "solver.h_max": 0.0007}, t_end=0.2, h=0.01)
    assert list(np.diff(a["solver.steps"])) == [15] * 19
    b = _run(toy, {"solver.method": 1, "solver.tol": 1e-10}, t_end=0.2, h=0.01)
    for n in NAMES:
        assert np.max(np.abs(a[n] - b[n])) < 1e-5 * max(1.0, float(np.max(np.abs(b[n])))), n
    t = Toy(toy, name="times")
    try:
        t.start({**DRIVE, "solver.method": 1})
        for h in (0.0037, 0.011, 1e-5, 0.05):
            assert t.step(h) == "ok"
        assert t.time == pytest.approx(0.0037 + 0.011 + 1e-5 + 0.05, abs=0)
    finally:
        t.close()
