"""`python -m cedra report defaults` (also with --method): a scene's run at its default
settings, or at another method / tolerance, against the same closed loop at rodas4 tol 1e-9."""
from types import SimpleNamespace

import pytest

from cedra.reports import defaults as D
from test_report_precision import scene_fmu


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    return scene_fmu("flat3d", tmp_path_factory).parent


def test_the_tight_settings_against_themselves_differ_by_nothing(build):
    r = D.compare("flat3d", build, tol=1e-9, method="rodas4")
    assert r.ok and r.setting == "rodas4 tol 1e-09" and r.force == "Fn"
    assert r.peak == r.peak_tight and r.peak_rel == 0.0 and r.dev_rel == 0.0


def test_defaults_and_the_w_method_on_flat_ground(build):
    d = D.compare("flat3d", build)
    assert d.ok and d.setting == "rodas4 tol 1e-06"
    assert 0 < d.peak_rel <= D.CRITERION and d.peak == pytest.approx(d.peak_tight, rel=1e-5)
    w = D.compare("flat3d", build, tol=1e-4, method="ros34pw2")
    assert w.ok and w.setting == "ros34pw2 tol 0.0001"
    assert w.peak_rel <= D.CRITERION and w.peak != d.peak          # a different solver ran, and it converged


def test_main_writes_the_command_with_the_method(build, tmp_path):
    args = SimpleNamespace(scene=["flat3d"], build=str(build), out=str(tmp_path), tol=1e-4, method="ros34pw2",
                           quiet=True)
    assert D.main(args) == 0
    text = (tmp_path / "defaults.md").read_text()
    assert "`python -m cedra report defaults --scene flat3d --tol 0.0001 --method ros34pw2`" in text
    assert "| flat3d | 10 s | ros34pw2 tol 0.0001 | rodas4 tol 1e-9 | Fn |" in text


def test_rigid_contact_is_compared_by_its_mean_forces():
    """an impact is an impulse: for rigid contact the report compares wheel[i].Fn_mean (impulse / step)"""
    import numpy as np
    rows = np.arange(8.0).reshape(2, 4)
    assert D._fn(["t", "wheel[1].Fn", "wheel[2].Fn", "body.x"], rows)[0] == "Fn"
    force, fn = D._fn(["wheel[1].Fn", "wheel[1].Fn_mean", "wheel[2].Fn", "wheel[2].Fn_mean"], rows)
    assert force == "Fn_mean" and np.array_equal(fn, rows[:, [1, 3]])


def test_the_largest_step_can_be_set(build):
    r = D.compare("flat3d", build, h_max=0.005)
    assert r.ok and r.setting == "rodas4 tol 1e-06 h_max 0.005" and r.tight == "rodas4 tol 1e-9"
    assert r.peak_rel <= D.CRITERION


def test_runs_that_stop_at_the_same_point_are_compared_up_to_it(build, monkeypatch):
    """rubble3d under the main job's loop drives off the heightmap's side at t = 9.25 s in every setting: the same
    run, compared over the time both have; runs that stop at different points (or one of them) fail the row."""
    import numpy as np
    import cedra.run.simulate as sim
    names = ["time", "wheel[1].Fn", "wheel[2].Fn"]
    ends = iter([9.25, 9.25, 9.25, 4.0])

    def fake_run(path, t_end, settings):
        t = next(ends)
        k = int(round(t / 0.01))
        rows = np.column_stack([np.arange(k) * 0.01, np.full(k, 50.0), np.full(k, 60.0 + (len(settings) > 2))])
        return names, rows, None, dict(ok=False, simulated=t, messages=[f"stopped at {t}"])
    monkeypatch.setattr(sim, "run_bump", fake_run)
    same = D.compare("flat3d", build)
    assert same.ok and same.t_end == 9.25 and same.message == "both runs stop there: stopped at 9.25"
    assert same.peak == 60.0 and same.peak_tight == 61.0
    apart = D.compare("flat3d", build)
    assert not apart.ok and apart.message == "default: stopped at 9.25"
