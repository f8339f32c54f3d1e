"""Work-precision report, small subset: the reference is converged, each solver's error falls with its
setting, the peers run on the same equations. The full sweep is `python -m cedra report precision`."""
import numpy as np
import pytest

from cedra.reports import precision as P
from cedra.reports.common import Problem, errors, grid, python_run_outputs, reference_outputs, run_casadi, \
    run_fmu, run_scipy, fn_names, position_names
from cedra.models.scene import load_shipped
from fmu_harness import shipped_fmu

T_END = 1.0


def scene_fmu(name, tmp_path_factory):
    """build/<name>.fmu when `./build.sh` has made it, else built here."""
    return shipped_fmu(name, tmp_path_factory)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    prob = Problem(load_shipped("bump2d"))
    sched = P.pi_schedule(prob, T_END)
    q0 = prob.settle()
    ref = run_casadi(prob, sched, prob.x0(q0), grid(T_END, P.OUT_DT), "cvodes", P.REF_TOL)
    assert ref.ok, ref.message
    R = reference_outputs(prob, sched, ref)
    watch = position_names(prob) + fn_names(prob)
    path = scene_fmu("bump2d", tmp_path_factory)

    def fmu(method, tol=1e-6, h_max=0.01, comm=0.01):
        r = run_fmu(path, prob, sched, q0, T_END, comm, method, tol, h_max, record=watch, record_every=P.OUT_DT)
        assert r.ok, (r.status, r.message)
        assert not r.extra["nan"]
        return errors(R, r.t, r.Y, watch, prob), r
    return prob, sched, q0, R, watch, fmu


def test_settle_is_static_equilibrium(setup):
    prob, sched, q0, *_ = setup
    x0 = prob.x0(q0)
    xdot = np.array(prob.rhs(x0, np.concatenate([prob.inp0, prob.par]))).ravel()      # zero torques
    assert np.max(np.abs(xdot)) < 1e-8      # measured ~7e-10 (udot of the spin coordinates)


def test_reference_converged_against_fmu_tightest(setup):
    """cvodes at 1e-12 and the FMU's rodas4 at 1e-10 are independent integrators of the same equations; they
    agree to ~4e-13 m and ~3e-8 N (measured), so bounds 1e-9 m / 1e-5 N leave room for platform round-off yet
    fail on any real disagreement (the loosest FMU runs are at 1e-8 m / 1e-2 N)."""
    _, _, _, R, _, fmu = setup
    e, r = fmu("rodas4", tol=1e-10)
    assert e["n"] == len(R.t)
    assert e["pos_abs"] < 1e-9 and e["fn_abs"] < 1e-5, e


@pytest.mark.parametrize("method,tols", [("rodas4", [1e-4, 1e-6, 1e-8]), ("dopri5", [1e-4, 1e-6, 1e-8])])
def test_adaptive_error_falls_with_tolerance(setup, method, tols):
    fmu = setup[-1]
    errs = [fmu(method, tol=t)[0] for t in tols]
    for a, b in zip(errs, errs[1:]):
        assert b["fn_abs"] < a["fn_abs"], errs
        assert b["pos_abs"] <= a["pos_abs"] * 1.01 + 1e-12, errs
    assert errs[-1]["fn_abs"] < errs[0]["fn_abs"] / 100


def test_rk4_error_falls_with_step(setup):
    fmu = setup[-1]
    errs = [fmu("rk4", h_max=h)[0] for h in (2e-4, 1e-4, 5e-5)]
    for a, b in zip(errs, errs[1:]):
        assert b["pos_abs"] < a["pos_abs"] and b["fn_abs"] < a["fn_abs"], errs


def test_comm_step_keeps_the_error(setup):
    """Inputs change only at multiples of 0.1 s: a coarse communication step may not spoil the solution."""
    fmu = setup[-1]
    e_fine, _ = fmu("rodas4", tol=1e-6, comm=1e-3)
    e_coarse, _ = fmu("rodas4", tol=1e-6, comm=0.1)
    assert e_fine["pos_abs"] < 1e-7 and e_coarse["pos_abs"] < 1e-7, (e_fine, e_coarse)


def test_peers_on_the_same_equations(setup):
    prob, sched, q0, R, watch, _ = setup
    tg = grid(T_END, P.OUT_DT)
    for run in (run_scipy(prob, sched, prob.x0(q0), tg, "Radau", 1e-6),
                run_casadi(prob, sched, prob.x0(q0), tg, "idas", 1e-6)):
        assert run.ok, run.message
        e = errors(R, run.t, python_run_outputs(prob, sched, run, watch), watch, prob)
        assert e["pos_abs"] < 1e-6 and e["fn_abs"] < 1e-1, (run.method, e)


def test_report_writes_markdown(tmp_path):
    from cedra.reports.common import Run
    res = P.SceneResult("toy", 1.0, Run("cvodes", "tol", np.zeros(1), np.zeros((1, 1)), 1.0, 10, 20))
    res.rows = [dict(method=m, setting="tol 1e-6", comm=0.01, wall=w, steps=1, evals=2, ok=True, status="ok",
                     message="", pos_abs=e, pos_rel=e, fn_abs=e, fn_rel=e)
                for m, w, e in (("FMU rodas4", 0.1, 1e-6), ("scipy Radau", 2.0, 1e-6), ("FMU rodas4", 0.05, 1e-3))]
    summary = P.write([res], tmp_path, "test", 1.0)
    text = (tmp_path / "precision.md").read_text()
    assert "| FMU rodas4 |" in text and (tmp_path / "precision_toy.png").exists()
    assert any("x20.0" in s for s in summary), summary
