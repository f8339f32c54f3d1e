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


def _default_setting(name):
    from cedra.models.scene import load_shipped
    s = load_shipped(name).solver
    return f"{s['method']} tol {s['tol']:g}"


def test_defaults_and_another_method_on_flat_ground(build):
    d = D.compare("flat3d", build)
    assert d.ok and d.setting == _default_setting("flat3d")
    assert 0 < d.peak_rel <= D.CRITERION and d.peak == pytest.approx(d.peak_tight, rel=1e-5)
    assert D.keeps_guarantee(d)                                      # the scene's default keeps the whole history
    other = ("rodas4", 1e-6) if d.setting != "rodas4 tol 1e-06" else ("ros34pw2", 1e-4)
    w = D.compare("flat3d", build, tol=other[1], method=other[0])
    assert w.ok and w.setting == f"{other[0]} tol {other[1]:g}"
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
    assert r.ok and r.setting == _default_setting("flat3d") + " h_max 0.005" and r.tight == "rodas4 tol 1e-9"
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


def _row(setting, cpu, peak_rel=1e-5, dev_rel=1e-4, ok=True):
    return D.Row("s", 10.0, setting, "rodas4 tol 1e-9", 50.0, 50.0, peak_rel, dev_rel, "Fn", cpu, 1.0, ok)


def test_choice_is_the_cheapest_setting_that_keeps_the_whole_history():
    loose = _row("ros34pw2 tol 0.001", 0.05, dev_rel=2e-3)          # its peak is fine, one sample is not
    fast = _row("ros34pw2 tol 0.0001", 0.10)
    tight_as_fast = _row("rodas4 tol 0.0001", 0.108)                 # within the noise of the cheapest: tighter wins
    slow = _row("rodas4 tol 1e-06", 0.30)
    failed = _row("rodas4 tol 1e-05", 0.01, ok=False)
    assert D.pick([loose, fast, slow]) is fast
    assert D.pick([loose, fast, tight_as_fast, failed, slow]) is tight_as_fast
    assert D.pick([loose, _row("x", 0.2, peak_rel=2e-3), failed]) is None


def test_record_writes_the_choice_into_the_solver_table(tmp_path):
    from importlib import resources
    from cedra.models.scene import load, load_shipped
    path = tmp_path / "flat3d.toml"
    path.write_text((resources.files("cedra.models.scenes") / "flat3d.toml").read_text())
    D.record("flat3d", "ros34pw2 tol 0.0001", path)
    before, after = load_shipped("flat3d"), load(path)
    assert after.solver == dict(before.solver, method="ros34pw2", tol=1e-4)
    assert (after.options, after.inputs, after.stop_time) == (before.options, before.inputs, before.stop_time)


def test_choose_takes_no_setting_and_record_needs_choose(tmp_path, capsys):
    base = dict(scene=["flat3d"], build="build", out=str(tmp_path), quiet=True, tol=None, method=None, h_max=None)
    assert D.main(SimpleNamespace(**base, choose=False, record=True)) == 2
    assert "--record writes what --choose chose" in capsys.readouterr().err
    assert D.main(SimpleNamespace(**dict(base, tol=1e-4), choose=True, record=False)) == 2
    assert "no --tol, --method or --h-max" in capsys.readouterr().err
    assert not (tmp_path / "defaults-choice.md").exists()
