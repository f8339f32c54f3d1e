"""The MuJoCo side by side of the benchmark: cedra.reports.mujoco_model and `python -m cedra bench
--quick`. mujoco is an optional dependency (the `bench` extra, which ./build.sh installs); without it these tests
are skipped, and nothing else in the project needs it."""
from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="mujoco (the optional 'bench' extra: pip install -e '.[bench]') "
                                              "is not importable: the MuJoCo side by side is not tested",
                             exc_type=ImportError)

from cedra.reports import bench
from cedra.reports import mujoco_model as mm                # noqa: E402
from cedra.rover.parameters import DEFAULTS                      # noqa: E402
from cedra.models.scene import load_shipped                       # noqa: E402
from cedra.run.simulate import run_bump                        # noqa: E402
from fmu_harness import shipped_fmu

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory):
    """The benchmark's FMUs: build/<scene>.fmu when ./build.sh made them (CI), else built here."""
    d = tmp_path_factory.mktemp("bench_build")
    for name in bench.FMU_RUNS:
        (d / f"{name}.fmu").symlink_to(shipped_fmu(name, tmp_path_factory))
    return d


def ray_height(rover, x, y):
    geomid = np.zeros(1, np.int32)
    dist = mujoco.mj_ray(rover.model, rover.data, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1,
                         geomid)
    return 5.0 - dist


def test_model_loads_with_the_projects_numbers():
    sc = load_shipped("bump3d")
    r = mm.Rover(sc, "hfield")
    m = r.model
    assert m.nu == 6 and m.neq == 1 and m.nbody == 13            # world, body, 2 bogies, 6 wheels, 3 fork links
    spec_mass = DEFAULTS["m_B"] + DEFAULTS["m_F"] + 6 * DEFAULTS["m_w"]
    assert m.body_subtreemass[1] == pytest.approx(spec_mass + 4 * mm.LINK_MASS, abs=1e-12)
    assert m.opt.gravity[2] == -DEFAULTS["g"] and m.opt.timestep == 1e-3
    wheel = m.geom(mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "wheel6_geom"))
    assert wheel.size[0] == DEFAULTS["R_w"] and wheel.friction[0] == sc.inputs.get("mu", 0.8)
    # the design pose: every wheel center R_w above the flat ground under the start, the four-bar closed
    mujoco.mj_forward(m, r.data)
    for i in range(1, 7):
        assert r.data.body(f"wheel{i}").xpos[2] == pytest.approx(DEFAULTS["R_w"], abs=1e-9)   # bump: 1.6e-11 m there
    g = mm.geometry(mm.numbers(sc))
    assert np.linalg.norm(g["D"] - g["B"]) == pytest.approx(DEFAULTS["fork_b"], abs=1e-12)
    d_coupler = r.data.body("coupler").xpos + r.data.body("coupler").xmat.reshape(3, 3) @ (g["D"] - g["C"])
    d_upper = r.data.body("fork_upper").xpos + r.data.body("fork_upper").xmat.reshape(3, 3) @ (g["D"] - g["B"])
    assert np.linalg.norm(d_coupler - d_upper) < 1e-12
    # a scene's own numbers reach the model (one source of truth)
    sc.parameters = {**sc.parameters, "m_B": 25.0, "R_w": 0.07}
    sc.inputs = {**sc.inputs, "mu": 0.5, "terrain_h": 0.1}
    r2 = mm.Rover(sc, "hfield")
    assert r2.model.body_subtreemass[1] == pytest.approx(spec_mass + 5 + 4 * mm.LINK_MASS, abs=1e-12)
    w2 = r2.model.geom(mujoco.mj_name2id(r2.model, mujoco.mjtObj.mjOBJ_GEOM, "wheel1_geom"))
    assert w2.size[0] == 0.07 and w2.friction[0] == 0.5
    assert ray_height(r2, 1.0, 0.0) == pytest.approx(0.1, abs=1e-7)


def test_height_fields_hold_the_scenes_terrain():
    """The bump: the Gaussian at the 1 cm nodes, constant in Y; hills3d: its grid file's heights at its nodes
    (hills3d is not symmetric in Y, so this also checks the row order MuJoCo expects)."""
    r = mm.Rover(load_shipped("bump3d"), "hfield")
    for x in (0.5, 0.9, 0.95, 1.0, 1.13, 1.5):
        h = 0.14625 * math.exp(-((x - 1.0) / 0.14625) ** 2)
        for y in (-0.3, 0.0, 0.17):
            assert ray_height(r, x, y) == pytest.approx(h, abs=1e-7), (x, y)     # MuJoCo keeps float32
    sc = load_shipped("hills3d")
    g = mm.heightmap_grid(sc.options.heightmap)
    r = mm.Rover(sc, "hfield")
    rng = np.random.default_rng(1)
    checked = 0
    for j, i in zip(rng.integers(1, g.Z.shape[0] - 1, 40), rng.integers(1, g.Z.shape[1] - 1, 40)):
        x, y = g.x0 + i * g.dx, g.y0 + j * g.dy
        assert ray_height(r, x, y) == pytest.approx(g.Z[j, i], abs=1e-7), (x, y)
        checked += g.Z[j, i] > 0.01
    assert checked >= 3             # some nodes on the hills, not only on the flat ground
    assert g.Z[12, 46] != g.Z[g.Z.shape[0] - 1 - 12, 46]


def test_static_wheel_loads_match_the_fmu(tmp_path_factory):
    """MuJoCo at rest on a plane vs the FMU's settled loads (flat3d, and bump3d at its flat start): within 5 %
    per wheel (MuJoCo's soft contact, the cylinders' width and 0.04 kg of link masses differ; measured:
    50.8 / 17.4 / 15.2 N against 50.6 / 17.6 / 15.4 N)."""
    mj = mm.static_loads(load_shipped("flat3d"), "plane")
    mj_bump = mm.static_loads(load_shipped("bump3d"), "hfield")
    for name in ("flat3d", "bump3d"):
        path = shipped_fmu(name, tmp_path_factory)
        names, rows, _, _ = run_bump(path, 0.01)
        fmu = np.array([rows[0][names.index(f"wheel[{i}].Fn")] for i in range(1, 7)])
        for loads in (mj, mj_bump):
            assert np.all(np.abs(loads - fmu) <= 0.05 * fmu), (name, loads, fmu)
    assert mj.sum() == pytest.approx((DEFAULTS["m_B"] + DEFAULTS["m_F"] + 6 * DEFAULTS["m_w"] + 4 * mm.LINK_MASS)
                                     * DEFAULTS["g"], rel=1e-3)


def test_rover_drives_forward_under_the_controller():
    r = mm.run(load_shipped("flat3d"), "plane", 1e-3, 3.0)
    assert r.ok and r.steps == 3000 and len(r.t) == 301
    assert r.x[0] == pytest.approx(0.0, abs=2e-3)                # settled where it was put
    assert np.all(np.diff(r.x) > -1e-4)                         # never rolls back
    v_end = (r.x[-1] - r.x[-51]) / 0.5
    assert v_end == pytest.approx(0.2, abs=0.01)                # the controller holds 0.2 m/s
    assert r.cpu > 0


def test_quick_bench_prints_every_row(build_dir):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = bench.main(SimpleNamespace(build=str(build_dir), stop_time=10.0, quick=True, side_by_side=False))
    text = out.getvalue()
    assert rc == 0, text
    lines = text.splitlines()
    for name in bench.MUJOCO_RUNS:
        for dt in bench.MUJOCO_DTS:
            label = f"MuJoCo {name} {dt * 1e3:g} ms"
            assert any(ln.startswith(f"| {label} | ") for ln in lines), (label, text)
    for name in bench.FMU_RUNS:
        row = [ln for ln in lines if ln.startswith(f"| FMU {name} | ")]
        assert len(row) == 1, (name, text)
        cells = [c.strip() for c in row[0].strip("|").split("|")]
        cpu, rtf, x, peak = (float(c) for c in cells[1:5])
        assert cpu > 0 and rtf > 0 and 0.1 < x < 0.3 and 40 < peak < 100, row   # 1 s at ~0.2 m/s, flat ground
        assert int(cells[5].split()[0]) > 0
    for fmu, mj in bench.PAIRS:
        assert any(ln.startswith(f"- {mj} / FMU {fmu} CPU: x") for ln in lines), (fmu, mj, text)


def test_boxes_hold_the_stairs_and_the_step():
    """scene_boxes: stairs3d's box tops (j + 1) terrain_h from edge j on, turned by terrain_yaw (a ray 1 cm on
    either side of each edge, at several places along it), and step2d's one box at terrain_x0."""
    from cedra.reports.bench_steps import across, geometry
    sc = load_shipped("stairs3d")
    p = mm.numbers(sc)
    r = mm.Rover(sc, "boxes")
    geo = geometry(sc)
    c, s = math.cos(geo["yaw"]), math.sin(geo["yaw"])
    for j in range(sc.options.stairs_steps):
        for v in (-0.4, 0.0, 0.3):                       # along the edge
            for du, top in ((-0.01, j * p["terrain_h"]), (0.01, (j + 1) * p["terrain_h"])):
                u = j * p["terrain_w"] + du
                x, y = geo["x0"] + u * c - v * s, geo["y0"] + u * s + v * c
                assert across(geo, x, y) == pytest.approx(u)
                assert ray_height(r, x, y) == pytest.approx(top, abs=1e-9), (j, v, du)
    st = load_shipped("step2d")
    r = mm.Rover(st, "boxes")
    h = mm.numbers(st)["terrain_h"]
    assert ray_height(r, 0.99, 0.1) == pytest.approx(0.0, abs=1e-9)
    assert ray_height(r, 1.01, -0.2) == pytest.approx(h, abs=1e-9)
    with pytest.raises(ValueError, match="no boxes for terrain kind 'bump'"):
        mm.scene_boxes(load_shipped("bump2d"))


def test_drives_hold_the_wheels_to_the_motor_envelope():
    """A scene with drives: MuJoCo's torques are clipped to the envelope every step, so full torque on flat ground
    cannot spin a wheel past the no-load speed (without the clip 4 N.m would spin them far beyond it)."""
    sc = load_shipped("stairs2d")                        # drives on; the front wheel meets the first edge at ~1 s
    assert sc.options.drives
    r = mm.Rover(sc, "boxes")
    mm.settle(r)
    r.set_torques(np.full(6, 4.0))
    fastest = 0.0
    for _ in range(900):
        r.step()
        fastest = max(fastest, float(np.max(np.abs(r.data.qvel[r.spin_dofs]))))
    w0 = mm.numbers(sc)["drive_noload_speed"]
    assert 0.9 * w0 < fastest <= w0 * (1 + 1e-3)


def test_energy_audit():
    """largest_rise finds the largest rise over any interval; on flat ground before the step MuJoCo's E - W does
    not rise (contact and joints only take energy), while it does rise by what a test adds in."""
    from cedra.reports.bench_steps import largest_rise, mujoco_energy
    t = np.arange(6.0)
    assert largest_rise(t, [0, -1, 2, -5, -2, -4]) == (3.0, 2.0)
    assert largest_rise(t, [3, 2, 1, 0, -1, -2]) == (0.0, 0.0)
    unpaid, _ = mujoco_energy(load_shipped("step2d"), multiccd=False, stop_time=2.0)   # x < 0.45 m: flat
    assert 0 <= unpaid < 0.05


def test_steps_table_prints_every_row(build_dir, tmp_path_factory):
    """`bench --steps` (2 s runs): a row per scene and run, the FMU's energy balance holds (E - W never rises by
    more than 1e-3 J) and every MuJoCo row is compared with the FMU."""
    from cedra.reports import bench_steps
    d = tmp_path_factory.mktemp("steps_build")
    for name in bench_steps.SCENES:
        (d / f"{name}.fmu").symlink_to(shipped_fmu(name, tmp_path_factory))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = bench.main(SimpleNamespace(build=str(d), stop_time=2.0, steps=True))
    text = out.getvalue()
    assert rc == 0, text
    lines = text.splitlines()
    for name in bench_steps.SCENES:
        rows = [ln for ln in lines if ln.startswith(f"| {name} | ")]
        assert len(rows) == 3, (name, text)
        fmu = [c.strip() for c in rows[2].strip("|").split("|")]
        assert fmu[1] == f"FMU {name}" and fmu[4] == "stuck"        # 2 s at 0.2 m/s: before the first edge
        assert float(fmu[6].split()[0]) < 1e-3, rows[2]
        assert sum(ln.startswith(f"- {name}: MuJoCo") for ln in lines) == 2
