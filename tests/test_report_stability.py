"""Stability campaign, small subset: the hardest stiff cases. The full campaign is
`python -m cedra report stability`."""
import pytest

from cedra.reports import stability as S
from test_report_precision import scene_fmu

CASES = {c.name.split(",")[0]: c for c in S.cases(quick=True)}


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    return scene_fmu("bump2d", tmp_path_factory).parent


def run(build, case, solver, budget=30.0):
    return S.run_case(CASES[case], solver, str(build), budget=budget)


@pytest.mark.parametrize("case", ["ground_k 1e+08", "v_eps 1e-05"])
def test_implicit_finishes_hardest_stiff_case(build, case):
    r = run(build, case, "rodas4")
    assert r.finished, (r.status, r.reason)
    assert not r.nan
    assert r.energy_ok, (r.e_increase, r.e_ref, r.e_tol)


def test_explicit_finishes_or_discards_loudly(build):
    r = run(build, "ground_k 1e+08", "dopri5")
    assert not r.nan
    assert r.finished or (r.status == "discard" and r.reason), (r.status, r.reason)
    if r.finished:
        assert r.energy_ok, (r.e_increase, r.e_ref, r.e_tol)


def test_rk4_too_long_a_step_fails_loudly(build):
    """rk4 with the scene's h_max = 0.01 s is far beyond its stability limit on the 1e5 N/m ground: it must stop
    with fmi2Discard and a reason, never hand out NaN."""
    case = CASES["drop from 0.3 m"]
    prob, q0, u0 = S.start_state(case)
    from cedra.reports.common import run_fmu
    r = run_fmu(build / "bump2d.fmu", prob, case.schedule, q0, case.t_end, case.comm, "rk4", 1e-6, 0.01,
                record=["body.z"], u0=u0, check_all=True, wall_budget=30)
    assert not r.extra["nan"], r.extra["nan_at"]
    assert r.ok or (r.status == "discard" and r.message), (r.status, r.message)


def test_drop_never_gains_energy(build):
    for solver in ("rodas4", "rk4"):
        r = run(build, "drop from 0.3 m", solver)
        assert r.finished and not r.nan, (solver, r.status, r.reason)
        assert r.energy_ok, (solver, r.e_increase, r.e_ref, r.e_tol)
