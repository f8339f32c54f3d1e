"""The heightmap scene's FMU (hills3d): it reads its grid from resources/ per instance, agrees with the analytic
flat ground where the grid is flat, drives across the hills, and fails loudly without its grid or off it.

Uses build/hills3d.fmu and build/flat3d.fmu when `./build.sh` has built them (CI does), else builds them."""
from __future__ import annotations

import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cedra.run.driver import RoverFMU
from cedra.run.simulate import SpeedController

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
import hills  # noqa: E402
from fmu_harness import shipped_fmu

FN = [f"wheel[{k}].Fn" for k in range(1, 7)]


def fmu_of(name, tmp_path_factory):
    return shipped_fmu(name, tmp_path_factory)


@pytest.fixture(scope="module")
def hills_fmu(tmp_path_factory):
    return fmu_of("hills3d", tmp_path_factory)


def with_resource(fmu, out, text):
    """A copy of fmu with resources/heightmap.txt replaced by text (None: removed)."""
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            if item.filename != "resources/heightmap.txt":
                dst.writestr(item, src.read(item.filename))
        if text is not None:
            dst.writestr("resources/heightmap.txt", text)
    return out


def raised_map(fmu, out, dz):
    """The hills FMU with every grid height raised by dz."""
    X, Y, Z = hills.grid()
    from cedra.mechanics import heightmap
    tmp = heightmap.write(out.with_suffix(".txt"), Z + dz, X[0], Y[0], hills.GRID["dx"], hills.GRID["dy"])
    return with_resource(fmu, out, tmp.read_text())


def test_settled_start_equals_the_analytic_flat_ground(hills_fmu, tmp_path_factory):
    """Under the start pose the hills grid is flat (the nearest hill adds < 1e-8 m): pose and wheel loads after the
    settle equal those of flat3d (same rover, analytic flat terrain)."""
    names = ["body.z", "body.pitch", "body.roll"] + FN
    out = {}
    for name, path in (("hills", hills_fmu), ("flat", fmu_of("flat3d", tmp_path_factory))):
        f = RoverFMU(path)
        f.start()
        out[name] = f.get(names)
        f.close()
    assert np.sum(out["flat"][3:]) > 200
    assert np.max(np.abs(out["hills"][:3] - out["flat"][:3])) < 1e-6
    assert np.max(np.abs(out["hills"][3:] - out["flat"][3:])) < 1e-4 * np.sum(out["flat"][3:])


def test_drives_across_the_hills():
    names, rows = hills.drive(stop_time=6.0)
    col = dict(zip(names, rows.T))
    assert np.all(np.isfinite(rows))
    assert col["body.x"][-1] > 1.1                          # the front wheels past the first hill's crest
    assert np.max(np.abs(col["body.roll"])) > 0.02          # the hills are not symmetric about the track
    assert np.all(np.array([col[n] for n in FN]) >= 0)


def test_each_instance_reads_its_own_grid(hills_fmu, tmp_path):
    """Two instances in one process, the second on the same hills raised by 0.1 m, stepped in turn: the second
    runs 0.1 m higher and otherwise identically (each evaluation uses its own instance's map)."""
    raised = raised_map(hills_fmu, tmp_path / "raised.fmu", 0.1)
    a, b = RoverFMU(hills_fmu, "a"), RoverFMU(raised, "b")
    ctrl_a, ctrl_b = SpeedController(), SpeedController()
    try:
        a.start(start_time=0.0)
        b.start(start_time=0.0)
        for k in range(1, 301):
            for f, c in ((a, ctrl_a), (b, ctrl_b)):
                tau = c(f.get(["body.vx"])[0])
                f.set({f"tau[{i}]": tau for i in range(1, 7)})
                assert f.step(k * 0.01), f.messages
        ya, yb = a.get(["body.x", "body.z", "body.roll"]), b.get(["body.x", "body.z", "body.roll"])
    finally:
        a.close()
        b.close()
    assert ya[0] > 0.5
    assert abs(yb[1] - ya[1] - 0.1) < 1e-6
    assert abs(yb[0] - ya[0]) < 1e-6 and abs(yb[2] - ya[2]) < 1e-6


def drive(fmus, steps):
    """Step the started instances in turn under the speed controller; their body.x, body.z, body.pitch, Fn."""
    ctrls = [SpeedController() for _ in fmus]
    for k in range(1, steps + 1):
        for f, c in zip(fmus, ctrls):
            tau = c(f.get(["body.vx"])[0])
            f.set({f"tau[{i}]": tau for i in range(1, 7)})
            assert f.step(k * 0.01), f.messages
    return [np.array(f.get(["body.x", "body.z", "body.pitch"] + FN)) for f in fmus]


def test_one_library_two_grids_in_one_thread(hills_fmu, tmp_path, monkeypatch):
    """Two instances of ONE loaded library (the second's directory links the first's binary, so they share its
    static data: the contact search's memo among them), in one thread, on the hills and on the hills with a ridge
    at X = 0.7 m: the second gives bit for bit what it gives alone (a separate library), and differs from the
    first."""
    import cedra.run.driver as driver
    X, Y, Z = hills.grid()
    from cedra.mechanics import heightmap
    ridge = Z + 0.03 * np.exp(-((X[None, :] - 0.7) / 0.05) ** 2)
    text = heightmap.write(tmp_path / "ridge.txt", ridge, X[0], Y[0], hills.GRID["dx"], hills.GRID["dy"]).read_text()
    alone_fmu = with_resource(hills_fmu, tmp_path / "ridge.fmu", text)
    alone = RoverFMU(alone_fmu, "alone")
    try:
        alone.start(start_time=0.0)
        [y_alone] = drive([alone], 600)
    finally:
        alone.close()
    a = RoverFMU(hills_fmu, "a")
    linked = tmp_path / "linked"
    for part in ("modelDescription.xml", "resources", "binaries/linux64"):
        (linked / part).parent.mkdir(parents=True, exist_ok=True)
    (linked / "modelDescription.xml").write_bytes((Path(a.unzipdir) / "modelDescription.xml").read_bytes())
    (linked / "resources").mkdir()
    (linked / "resources" / "heightmap.txt").write_text(text)
    (linked / "binaries" / "linux64").mkdir(exist_ok=True)
    (linked / "binaries" / "linux64" / "hills3d.so").symlink_to(Path(a.unzipdir) / "binaries/linux64/hills3d.so")
    monkeypatch.setattr(driver, "extract", lambda path: str(linked))
    b = RoverFMU(hills_fmu, "b")
    try:
        a.start(start_time=0.0)
        b.start(start_time=0.0)
        y_a, y_b = drive([a, b], 600)
    finally:
        a.close()
        b.close()
    assert y_b[0] > 0.9                                          # over the ridge
    assert np.max(np.abs(y_b - y_a)) > 1e-3                      # the ridge is felt
    assert np.array_equal(y_b, y_alone)


def test_missing_grid_fails_at_instantiate(hills_fmu, tmp_path):
    f = RoverFMU(with_resource(hills_fmu, tmp_path / "nogrid.fmu", None))
    with pytest.raises(Exception):
        f.start()
    assert any("cannot open the heightmap" in m and "heightmap.txt" in m for m in f.messages), f.messages


def test_bad_grid_fails_at_instantiate(hills_fmu, tmp_path):
    f = RoverFMU(with_resource(hills_fmu, tmp_path / "bad.fmu", "cedra-heightmap 1\n3 2 0 0 1 1\n0 0 0\n0 0\n"))
    with pytest.raises(Exception):
        f.start()
    assert any("height 6 of 6 (row 1) is missing" in m for m in f.messages), f.messages


def test_start_off_the_grid_is_refused(hills_fmu):
    f = RoverFMU(hills_fmu)
    with pytest.raises(Exception):
        f.start({"start.x": 3.9})
    f.close()
    assert any("outside the heightmap" in m for m in f.messages), f.messages


def test_driving_off_the_grid_is_a_discard_naming_the_point(hills_fmu, tmp_path):
    """On a flat grid that ends at X = 1 m, full torque drives the front wheels over the edge within 4 s."""
    from cedra.mechanics import heightmap
    grid = heightmap.write(tmp_path / "short.txt", np.zeros((41, 41)), -1.0, -1.0, 0.05, 0.05).read_text()
    f = RoverFMU(with_resource(hills_fmu, tmp_path / "short.fmu", grid))
    f.start({f"tau[{i}]": 1.0 for i in range(1, 7)})
    ok = all(f.step(k * 0.05) for k in range(1, 81))
    terminated = f.terminated()
    f.close()
    assert not ok and f.status == "discard" and terminated
    assert any("outside the heightmap [-1, 1] x [-1, 1] m" in m for m in f.messages), f.messages
