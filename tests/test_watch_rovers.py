"""The views of a rocker-bogie run (cedra.rover.skeleton's drawing of that rover, cedra.run.watch): the drawing's
wheel centers are the FMU's, the page draws the rockers, the bogies and six wheels in headless Chromium, and a run
that records neither rover's joints is refused naming what each drawing lacks."""
from __future__ import annotations

import time

import numpy as np
import pytest

from cedra.rover.skeleton import RB_LINKS, drawing, skeleton
from cedra.run import simulate, watch
from fmu_harness import shipped_fmu

CENTERS = [f"wheel[{i}].c{a}" for i in range(1, 7) for a in "xyz"]


def _run(name, stop_time, tmp_path_factory):
    fmu = shipped_fmu(name, tmp_path_factory)
    names, rows, _, info = simulate.run_bump(fmu, stop_time, extra=CENTERS)
    assert info["ok"]
    return fmu, names, rows


@pytest.fixture(scope="module")
def rb_run(tmp_path_factory):
    return _run("rb_bump2d", 6.0, tmp_path_factory)


@pytest.fixture(scope="module")
def rb_stairs3d(tmp_path_factory):
    return _run("rb_stairs3d", 8.0, tmp_path_factory)


@pytest.mark.parametrize("run", ["rb_run", "rb_stairs3d"])
def test_the_rocker_bogies_drawing_has_the_fmus_wheel_centers(run, request):
    """Over the paper's bump (2D: the bogies turning) and up the turned stairs (3D: the differential turning the
    rockers against each other, the body rolling), the drawing's six wheel centers are the FMU's own wheel[i].c*
    to 1e-9 m; each bogie's wheels stay 2 bogie_half apart, each rocker's front wheel a fixed distance from its
    pivot."""
    fmu, names, rows = request.getfixturevalue(run)
    cols = watch.columns(names, rows)
    assert "rocker.rho" in cols and "bogie.beta[1]" in cols and "fork.theta4" not in cols
    assert np.ptp(cols["bogie.beta[1]"]) > 0.05                   # the bogies turned
    if run == "rb_stairs3d":
        assert np.ptp(cols["rocker.rho"]) > 0.05 and np.ptp(cols["body.roll"]) > 0.05
    p = watch.fmu_numbers(fmu)
    sk = skeleton(cols, p)
    assert sk.rover == "the rocker-bogie" and sk.links == RB_LINKS
    fmu_c = np.stack([np.stack([cols[f"wheel[{i}].c{a}"] for a in "xyz"], axis=-1) for i in range(1, 7)], axis=1)
    err = np.abs(sk.centers() - fmu_c).max()
    print(f"{run}: drawing's wheel centers vs the FMU's: {err:.2e} m")
    assert err < 1e-9
    for a, b in (("c2", "c3"), ("c5", "c6")):
        assert np.allclose(np.linalg.norm(sk.point(a) - sk.point(b), axis=-1), 2 * p["bogie_half"], atol=1e-12)
    for c, q in (("c1", "Q_L"), ("c4", "Q_R")):
        assert np.ptp(np.linalg.norm(sk.point(c) - sk.point(q), axis=-1)) < 1e-12
    assert np.allclose(np.linalg.norm(sk.axles, axis=-1), 1) and np.abs(np.sum(sk.axles * sk.spokes, -1)).max() < 1e-12


def test_a_run_no_drawing_can_draw_is_refused_naming_what_each_lacks():
    cols = {"time": np.zeros(2), "body.x": np.zeros(2), "rocker.rho": np.zeros(2)}
    with pytest.raises(ValueError) as e:
        drawing(cols)
    msg = str(e.value)
    assert "CEDRA: [" in msg and "'fork.theta4'" in msg
    assert "the rocker-bogie: [" in msg and "'bogie.beta[1]'" in msg and "'rocker.rho'" not in msg, msg


def test_the_page_draws_the_rockers_bogies_and_six_wheels(rb_run, tmp_path):
    """view.html of the rocker-bogie run in headless Chromium: it renders, draws its four links (two rockers, two
    bogies) whole and six wheel discs, the body's orange is in the picture, and the console has no errors."""
    from test_view import Chromium, _need_browser, body_mask
    _need_browser()
    fmu, names, rows = rb_run
    page = watch.watch(tmp_path / "rb", names, rows, fmu, video=False)["view"]
    b = Chromium(tmp_path / "profile")
    try:
        b.open(page.resolve().as_uri() + "#follow=0&play=0&t=3")
        deadline = time.monotonic() + 20
        while not b.eval("window.cedraView ? window.cedraView.renders : 0"):
            assert time.monotonic() < deadline, "the page never rendered"
            time.sleep(0.1)
        time.sleep(0.3)
        assert b.eval("cedraView.rover") == "the rocker-bogie"
        drawn = b.eval("cedraView.drawn")
        print("drawn:", drawn)
        assert drawn["links"] == len(RB_LINKS) == 4 and drawn["wheels"] == 6, drawn
        assert body_mask(b.screenshot()).sum() > 500
        assert b.errors() == []
    finally:
        b.close()
