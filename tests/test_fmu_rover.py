"""The rover-specific behaviour an importer relies on: the FMU rebuilt from its sources gives the same results, the
three solvers agree, bad input is refused with a logged reason, FMU state round trips. The checkers (fmpy validate,
VDMCheck2, the start value round trip, libcosim against FMPy) run on every shipped FMU as `python -m cedra check
build/*.fmu` in `./build.sh test`, before the tests (tests/test_cli_check.py tests the command).

Uses build/<scene>.fmu when `./build.sh` has built it (CI does), else builds into pytest's tmp dir."""
from __future__ import annotations

import numpy as np
import pytest

from cedra.fmu import checks
from cedra.run.driver import RoverFMU
from fmu_harness import shipped_fmu


@pytest.fixture(scope="module")
def fmu_paths(tmp_path_factory):
    return {name: shipped_fmu(name, tmp_path_factory) for name in ("bump2d", "bump2d_rigid")}


def test_source_fmu_gives_the_same_results(fmu_paths):
    outs = ["body.x", "body.z", "wheel[1].Fn", "wheel[5].Fn"]
    a = checks.fmpy_run(fmu_paths["bump2d"], 0.01, 0.5, outputs=outs)
    b = checks.fmpy_run(fmu_paths["bump2d"], 0.01, 0.5, outputs=outs, use_source=True)
    for name, (dabs, drel, _) in checks.compare_runs(a, b, outs).items():
        assert dabs <= 1e-9 or drel <= 1e-9, (name, dabs, drel)     # -O2 binary vs FMPy's -O3 build


def run(path, method, tol, h_max, stop=1.0):
    f = RoverFMU(path)
    f.start({"solver.method": method, "solver.tol": tol, "solver.h_max": h_max})
    f.set({f"tau[{i}]": 1.0 for i in range(1, 7)})
    for k in range(1, int(round(stop / 0.01)) + 1):
        assert f.step(k * 0.01), f.messages
    y = f.get(["body.x", "body.z", "body.pitch"])
    f.close()
    return y


def test_three_solvers_agree_on_the_bump_scene(fmu_paths):
    # reference rodas4 at 1e-9: at 1e-10 it underflows at a touchdown, where the compliant contact law
    # max(0, k delta - d v_n) jumps by d |v_n| (a discontinuous right-hand side; docs/solvers.md, Force-law switches)
    ref = run(fmu_paths["bump2d"], 2, 1e-9, 0.01)
    for method, tol, h_max, bound in ((2, 1e-7, 0.01, 1e-5), (1, 1e-7, 0.01, 1e-5), (0, 1.0, 5e-5, 1e-5),
                                      (3, 1e-7, 0.01, 1e-5)):
        y = run(fmu_paths["bump2d"], method, tol, h_max)
        assert np.max(np.abs(y - ref)) < bound, (method, y - ref)


def refused(fmu, call):
    from fmpy.fmi1 import FMICallException
    n = len(fmu.messages)
    with pytest.raises(FMICallException):
        call()
    return fmu.messages[n:]


def test_bad_input_is_refused_with_a_reason(fmu_paths):
    f = RoverFMU(fmu_paths["bump2d"])
    v = f.vars
    f.fmu.instantiate(callbacks=f._callbacks)
    f.fmu.setupExperiment(startTime=0.0)
    msg = refused(f, lambda: f.fmu.doStep(0.0, 0.01))                       # wrong call order
    assert any("fmi2DoStep" in m for m in msg), msg
    f.fmu.enterInitializationMode()
    msg = refused(f, lambda: f.fmu.setReal([v["R_w"].valueReference], [-0.1]))
    assert any("R_w" in m for m in msg), msg
    msg = refused(f, lambda: f.fmu.setReal([v["solver.tol"].valueReference], [-1e-6]))
    assert any("solver.tol" in m for m in msg), msg
    msg = refused(f, lambda: f.fmu.setInteger([v["solver.method"].valueReference], [4]))   # moreau: rigid only
    assert any("solver.method" in m and "<= 3" in m for m in msg), msg
    msg = refused(f, lambda: f.fmu.setReal([999999], [1.0]))
    assert any("999999" in m for m in msg), msg
    f.fmu.exitInitializationMode()
    msg = refused(f, lambda: f.fmu.setReal([v["tau[1]"].valueReference], [float("nan")]))
    assert any("tau[1]" in m for m in msg), msg
    assert f.step(0.01)                                                     # nothing was lost
    assert np.all(np.isfinite(f.get(["body.x", "wheel[1].Fn"])))
    f.close()


@pytest.mark.parametrize("scene, method", [("bump2d", 2), ("bump2d", 3), ("bump2d_rigid", 2)],
                         ids=["rodas4", "ros34pw2", "rigid"])
def test_fmu_state_round_trip_is_bit_identical(fmu_paths, scene, method):
    """(ros34pw2 keeps its Jacobian from call to call: it is part of the state, or a restored run would differ;
    rigid contact's mean forces come from impulses the state carries over the step)"""
    f = RoverFMU(fmu_paths[scene])
    f.start({"solver.method": method})
    f.set({f"tau[{i}]": 1.0 for i in range(1, 7)})
    for k in range(1, 11):
        assert f.step(k * 0.01)
    state = f.fmu.getFMUState()
    blob = f.fmu.serializeFMUState(state)
    names = ["body.x", "body.z", "wheel[1].Fn", "solver.steps"] + \
        [f"wheel[{i}].Fn_mean" for i in (1, 5) if f.has(f"wheel[{i}].Fn_mean")]
    first = []
    for k in range(11, 31):
        assert f.step(k * 0.01)
        first.append(f.get(names))
    for restore in (lambda: f.fmu.setFMUState(state),
                    lambda: f.fmu.setFMUState(f.fmu.deserializeFMUState(blob))):
        restore()
        f.time = 0.1
        again = []
        for k in range(11, 31):
            assert f.step(k * 0.01)
            again.append(f.get(names))
        assert np.array_equal(np.array(first), np.array(again))
    f.fmu.freeFMUState(state)
    f.close()
