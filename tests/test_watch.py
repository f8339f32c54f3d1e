"""Runs a person can watch (cedra.run.watch, cedra.rover.skeleton): the drawing's geometry is the
FMU's, the ground forces add up to the weight at rest, the terrain is the FMU's, the GIF has a frame per 1/12 s
and they differ, the page is self-contained, and the main job writes both (`--no-video`: neither)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cedra.rover.parameters import DEFAULTS
from cedra.rover.skeleton import POINTS, skeleton
from cedra.run import simulate, watch

REPO = Path(__file__).resolve().parents[1]
BUILD = REPO / "build"
WEIGHT = (DEFAULTS["m_B"] + DEFAULTS["m_F"] + 6 * DEFAULTS["m_w"]) * DEFAULTS["g"]
CENTERS = [f"wheel[{i}].c{a}" for i in range(1, 7) for a in "xyz"]


@pytest.fixture(scope="module")
def bump():
    names, rows, _, info = simulate.run_bump(BUILD / "bump2d.fmu", 4.0, extra=CENTERS)
    assert info["ok"]
    return names, rows


@pytest.fixture(scope="module")
def turn():
    """flat3d + drive3d turning (steering angles nonzero), 3 s."""
    from cedra.run.cosim import DriveLoop
    loop = DriveLoop(BUILD / "flat3d.fmu", BUILD / "drive3d.fmu")
    r = loop.run(3.0, 0.01, lambda t: {"cmd.v": 0.2, "cmd.yaw_rate": 0.3}, watch.plus_watched(CENTERS))
    loop.close()
    assert r.ok
    return r.names, r.rows


@pytest.mark.parametrize("run", ["bump", "turn"])
def test_skeleton_wheel_centers_are_the_fmus(run, request):
    names, rows = request.getfixturevalue(run)
    cols = watch.columns(names, rows)
    if run == "turn":
        assert np.abs(cols["steer.theta[2]"]).max() > 0.05        # the steered wheels did steer
    sk = skeleton(cols, watch.fmu_numbers(BUILD / ("bump2d.fmu" if run == "bump" else "flat3d.fmu")))
    fmu = np.stack([np.stack([cols[f"wheel[{i}].c{a}"] for a in "xyz"], axis=-1) for i in range(1, 7)], axis=1)
    err = np.abs(sk.centers() - fmu).max()
    print(f"{run}: skeleton wheel centers vs the FMU's: {err:.2e} m")
    assert err < 1e-9
    # unit axles, spokes on the rim plane, the four-bar's links at their lengths
    assert np.allclose(np.linalg.norm(sk.axles, axis=-1), 1) and np.allclose(np.linalg.norm(sk.spokes, axis=-1), 1)
    assert np.abs(np.sum(sk.axles * sk.spokes, axis=-1)).max() < 1e-12
    p = DEFAULTS
    assert np.allclose(np.linalg.norm(sk.point("C") - sk.point("A"), axis=-1), p["fork_a"])
    assert np.allclose(np.linalg.norm(sk.point("D") - sk.point("B"), axis=-1), p["fork_b"])


def test_spokes_turn_with_the_wheels(bump):
    """The spoke's angle about the axle advances by the integral of the spin rate plus the carrier's rotation."""
    cols = watch.columns(*bump)
    sk = skeleton(cols, DEFAULTS)
    s = sk.spokes[:, 4]                       # the rear wheel 5, carried by the body: carrier angle = pitch
    angle = np.arctan2(-s[:, 2], s[:, 0])                  # about +y: x turns toward -z
    gamma = np.concatenate([[0], np.cumsum(0.5 * (cols["wheel[5].omega"][1:] + cols["wheel[5].omega"][:-1]) *
                                           np.diff(cols["time"]))])
    d = np.angle(np.exp(1j * (angle - cols["body.pitch"] - gamma)))
    assert np.abs(d - d[0]).max() < 1e-9
    assert gamma[-1] > 3.0                                  # it did roll


@pytest.mark.parametrize("run", ["bump", "turn"])
def test_ground_forces_carry_the_weight_at_rest(run, request):
    names, rows = request.getfixturevalue(run)
    cols = watch.columns(names, rows)
    fmu = BUILD / ("bump2d.fmu" if run == "bump" else "flat3d.fmu")
    sk = skeleton(cols, watch.fmu_numbers(fmu), [0])
    P, F = watch.ground_forces(cols, sk.axles, watch.TerrainMap(fmu), [0])
    total = F[0].sum(axis=0)
    print(f"{run}: ground forces at the settled start {total} N, weight {WEIGHT:.2f} N")
    assert abs(total[2] - WEIGHT) < 1e-3 * WEIGHT
    assert np.hypot(total[0], total[1]) < 1e-3 * WEIGHT
    assert np.abs(P[0, :, 2]).max() < 1e-3                # contact points on the flat ground


def test_terrain_is_the_fmus():
    t = watch.TerrainMap(BUILD / "bump2d.fmu")
    X = np.linspace(-1, 3, 41)
    w, x0 = 0.14625, 1.0
    assert t.kind == "bump"
    assert np.allclose(t.height(X, 0.3), 0.14625 * np.exp(-((X - x0) / w) ** 2), atol=1e-12)
    s = watch.TerrainMap(BUILD / "slope3d.fmu")
    assert s.kind == "slope" and s.values["terrain_slope"] != 0
    assert np.allclose(s.height(X, 0.5), -np.tan(s.values["terrain_slope"]) * X, atol=1e-12)
    n = s.normal(0.0, 0.0)
    assert np.isclose(n[2], np.cos(s.values["terrain_slope"]))
    f = watch.TerrainMap(BUILD / "flat3d.fmu")
    assert f.kind == "flat" and np.all(f.height(X, X) == 0)
    m = watch.TerrainMap(BUILD / "hills3d.fmu")
    assert m.kind == "heightmap" and m.extent is not None
    hills = m.height(np.linspace(m.extent[0], m.extent[1], 50), 0.0)
    assert np.ptp(hills) > 0.01


def test_animation_gif(bump, tmp_path):
    from PIL import Image
    cols = watch.columns(*bump)
    fmu = BUILD / "bump2d.fmu"
    path = watch.animation(cols, watch.fmu_numbers(fmu), watch.TerrainMap(fmu), tmp_path / "animation", fmt="gif")
    assert path.suffix == ".gif"
    im = Image.open(path)
    n = im.n_frames
    assert n == 4 * watch.FPS + 1, n
    assert im.info["duration"] == round(1000 / watch.FPS)
    frames = []
    for k in range(n):
        im.seek(k)
        frames.append(np.asarray(im.convert("RGB")).astype(int))
    changed = [int((np.abs(a - b).sum(axis=2) > 30).sum()) for a, b in zip(frames, frames[1:])]
    assert min(changed) > 0                                   # every frame differs from the one before
    assert int((np.abs(frames[0] - frames[-1]).sum(axis=2) > 30).sum()) > 5000     # the rover drove on
    red = [((f[..., 0] > 180) & (f[..., 1] < 80) & (f[..., 2] < 90)).sum() for f in frames]
    orange = [((f[..., 0] > 200) & (abs(f[..., 1] - 137) < 25) & (f[..., 2] < 80)).sum() for f in frames]
    assert min(red) > 20 and min(orange) > 2000               # force arrows and the body in every frame
    print(f"{n} frames, {path.stat().st_size / 1e3:.0f} kB, changed pixels per frame {min(changed)}..{max(changed)}")
    assert path.stat().st_size < 2e6


def test_view_page_is_self_contained(bump, tmp_path):
    path = watch.watch(tmp_path, *bump, BUILD / "bump2d.fmu", video=False)["view"]
    text = path.read_text()
    assert "http://" not in text and "https://" not in text and " src=" not in text and "import " not in text
    blob = text.split("const D = ", 1)[1].split(";\nconst NF", 1)[0]
    data = json.loads(blob)
    nf = len(data["t"])
    assert nf == 4 * watch.VIEW_FPS + 1
    assert np.array(data["p"]).shape == (nf, len(POINTS), 3)
    assert np.array(data["force"]).shape == (nf, 6, 3)
    tr = data["terrain"]
    z = np.array(tr["z"]).reshape(tr["ny"], tr["nx"])
    X = np.linspace(tr["x0"], tr["x1"], tr["nx"])
    assert np.allclose(z[0], 0.14625 * np.exp(-((X - 1.0) / 0.14625) ** 2), atol=1e-4)
    assert data["planar"] is True


def test_main_job_writes_the_animation_and_the_page(tmp_path):
    run = [sys.executable, "-m", "cedra", "simulate", "bump2d", "--stop-time", "1", "--build", str(BUILD)]
    r = subprocess.run(run + ["--out", str(tmp_path / "a")], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "a" / "bump2d"
    assert (out / f"animation.{watch.video_format()}").stat().st_size > 0 and (out / "view.html").stat().st_size > 0
    assert "animation" in r.stdout and "view.html" in r.stdout
    r = subprocess.run(run + ["--out", str(tmp_path / "b"), "--no-video"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    files = {p.name for p in (tmp_path / "b" / "bump2d").iterdir()}
    assert files == {"bump2d.csv", "forces.png", "path.png"}, files


def test_watch_a_csv(tmp_path):
    """`python -m cedra watch <csv> --fmu` (the main job's CSV); a CSV without the drawing's outputs is refused
    naming them."""
    r = subprocess.run([sys.executable, "-m", "cedra", "simulate", "bump2d", "--stop-time", "1", "--build",
                        str(BUILD), "--out", str(tmp_path), "--no-video"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    csv = tmp_path / "bump2d" / "bump2d.csv"
    r = subprocess.run([sys.executable, "-m", "cedra", "watch", str(csv), "--fmu", str(BUILD / "bump2d.fmu")],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert (csv.parent / "view.html").exists() and (csv.parent / f"animation.{watch.video_format()}").exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("time,body.x\n0,0\n0.01,0.001\n")
    r = subprocess.run([sys.executable, "-m", "cedra", "watch", str(bad), "--fmu", str(BUILD / "bump2d.fmu")],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 2 and "did not record" in r.stderr and "fork.theta4" in r.stderr, r.stderr
