"""The heightmap terrain (spec section 5): the C spline against an independent one, its derivatives, the file
reader's errors, the model on a heightmap of a plane against the analytic slope, and the FMU reading its grid
from resources/ (per instance, loud when the rover leaves the grid)."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from cedra.mechanics import heightmap
from cedra.models import scene
from cedra.models.plant import CedraModel, ModelOptions

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
import hills  # noqa: E402


def natural_spline_2d(xs, ys, Z, X, Y):
    """Independent reference: the tensor-product natural cubic spline by scipy, one dimension after the other."""
    col = np.array([CubicSpline(xs, Z[j], bc_type="natural")(X) for j in range(len(ys))])
    return float(CubicSpline(ys, col, bc_type="natural")(Y))


@pytest.fixture()
def random_map(tmp_path):
    rng = np.random.default_rng(7)
    x0, y0, dx, dy = -0.3, 0.2, 0.15, 0.1
    Z = rng.normal(size=(7, 9)) * 0.05                       # ny = 7 rows, nx = 9 columns
    path = heightmap.write(tmp_path / "map.txt", Z, x0, y0, dx, dy, "random test map")
    heightmap.load(path)
    return x0 + dx * np.arange(9), y0 + dy * np.arange(7), Z


def terrain_fn():
    x = ca.SX.sym("x", 2)
    h, g, H = heightmap.external()(x)
    T = ca.jacobian(ca.vec(H), x)          # third derivatives: jac_cedra_heightmap
    return ca.Function("t", [x], [h, g, H, T])


def test_spline_equals_the_natural_spline_of_scipy(random_map):
    xs, ys, Z = random_map
    f = terrain_fn()
    rng = np.random.default_rng(1)
    for X, Y in zip(rng.uniform(xs[0], xs[-1], 30), rng.uniform(ys[0], ys[-1], 30)):
        assert abs(float(f(np.array([X, Y]))[0]) - natural_spline_2d(xs, ys, Z, X, Y)) < 1e-12
    for i, j in [(0, 0), (8, 6), (3, 2), (8, 0)]:                       # interpolates, edges included
        assert abs(float(f(np.array([xs[i], ys[j]]))[0]) - Z[j, i]) < 1e-12


def test_derivatives_match_finite_differences(random_map):
    xs, ys, _ = random_map
    f = terrain_fn()
    d = 1e-6
    for p in ([0.31, 0.47], [xs[4] + 1e-3, ys[3] - 2e-3], [0.9 - 1e-5, 0.75]):   # in cells, by grid lines, edge
        p = np.array(p)
        base = [np.array(v) for v in f(p)]
        for k in range(2):
            e = np.eye(2)[k] * d
            hi, lo = [np.array(v) for v in f(p + e)], [np.array(v) for v in f(p - e)]
            assert abs((hi[0] - lo[0]).item() / (2 * d) - base[1][k].item()) < 1e-8
            assert np.max(np.abs((hi[1] - lo[1]).ravel() / (2 * d) - base[2][:, k])) < 1e-7
            assert np.max(np.abs((hi[2] - lo[2]).ravel(order="F") / (2 * d) - base[3][:, k])) < 1e-5


def test_a_plane_is_reproduced_exactly(tmp_path):
    X = -1 + 0.2 * np.arange(6)
    Y = 0.5 + 0.3 * np.arange(4)
    Z = 0.1 - 0.25 * X[None, :] + 0.4 * Y[:, None]
    heightmap.load(heightmap.write(tmp_path / "plane.txt", Z, -1, 0.5, 0.2, 0.3))
    f = terrain_fn()
    for p in ([-0.83, 0.61], [-0.01, 1.39], [0.0, 1.4]):
        h, g, H, T = [np.array(v) for v in f(np.array(p))]
        assert abs(h.item() - (0.1 - 0.25 * p[0] + 0.4 * p[1])) < 1e-13
        assert np.allclose(g.ravel(), [-0.25, 0.4], atol=1e-12, rtol=0)
        assert np.max(np.abs(H)) < 1e-11 and np.max(np.abs(T)) < 1e-9


@pytest.mark.parametrize("text, reason", [
    ("cedra-heightmap 2\n2 2 0 0 1 1\n0 0 0 0\n", "line 1: expected the header 'cedra-heightmap 1'"),
    ("cedra-heightmap 1\n2 2 0 0 1\n", "expected 'nx ny x0 y0 dx dy'"),
    ("cedra-heightmap 1\n1 3 0 0 1 1\n0 0 0\n", "need whole numbers >= 2"),
    ("cedra-heightmap 1\n2 2 0 0 0 1\n0 0 0 0\n", "the spacings must be > 0"),
    ("cedra-heightmap 1\n2 2 0 0 1 1\n0 0\n0\n", "height 4 of 4 (row 1) is missing"),
    ("cedra-heightmap 1\n2 2 0 0 1 1\n0 nan 0 0\n", "line 3: height 2 of 4 (row 0) is missing or not a finite"),
    ("# comment\ncedra-heightmap 1\n2 2 0 0 1 1\n0 0\n0 0\n1\n", "line 6: more than nx * ny = 4 heights"),
])
def test_bad_files_are_refused_with_line_and_reason(tmp_path, text, reason):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(heightmap.HeightmapError) as e:
        heightmap.load(path)
    assert str(path) in str(e.value) and reason in str(e.value)


def test_missing_file(tmp_path):
    with pytest.raises(heightmap.HeightmapError, match="cannot open the heightmap .*nothere.txt"):
        heightmap.load(tmp_path / "nothere.txt")


def test_scene_errors_name_file_and_key(tmp_path):
    base = 'name = "s"\ndims = "3d"\nterrain = "heightmap"\n'
    cases = [
        (base, "key 'heightmap': missing"),
        (base + 'heightmap = "nothere.txt"\n', "key 'heightmap': cannot open the heightmap"),
        ('name = "s"\ndims = "2d"\nterrain = "heightmap"\nheightmap = "h.txt"\n', "needs dims = '3d'"),
        ('name = "s"\ndims = "3d"\nterrain = "flat"\nheightmap = "h.txt"\n', "only for terrain = 'heightmap'"),
    ]
    for k, (text, reason) in enumerate(cases):
        path = tmp_path / f"s{k}.toml"
        path.write_text(text)
        with pytest.raises(scene.SceneError) as e:
            scene.load(path)
        assert str(path) in str(e.value) and reason in str(e.value), str(e.value)


def test_shipped_grid_is_what_the_example_makes():
    X, Y, Z = hills.grid()
    lines = [ln for ln in hills.SHIPPED.read_text().splitlines() if not ln.startswith("#")]
    assert lines[0] == "cedra-heightmap 1"
    nx, ny, x0, y0, dx, dy = map(float, lines[1].split())
    assert (nx, ny, x0, y0, dx, dy) == (len(X), len(Y), X[0], Y[0], hills.GRID["dx"], hills.GRID["dy"])
    shipped = np.array([[float(v) for v in ln.split()] for ln in lines[2:]])
    assert np.max(np.abs(shipped - Z)) < 1e-9


def test_model_on_a_heightmap_plane_equals_the_analytic_slope(tmp_path):
    """The heightmap path (external terrain, rim search with Newton steps) against the analytic 'slope' kind
    (closed-form contact point) on the same plane: f, M and the outputs agree at random states."""
    slope = 0.12
    X = -2 + 0.25 * np.arange(17)
    Y = -1 + 0.25 * np.arange(9)
    Z = np.repeat((-np.tan(slope) * X)[None, :], len(Y), axis=0)
    path = heightmap.write(tmp_path / "plane.txt", Z, -2, -1, 0.25, 0.25)
    hm = CedraModel(ModelOptions(dims="3d", terrain="heightmap", heightmap=str(path)))
    sl = CedraModel(ModelOptions(dims="3d", terrain="slope"))
    fh, fs = hm.functions(), sl.functions()
    par = np.array([q.start for q in hm.params])
    inp_h = np.array([q.start for q in hm.inputs])
    inp_s = np.array([slope if q.name == "terrain_slope" else q.start for q in sl.inputs])
    q0 = np.array(hm.spec("t").q_start)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = q0 + rng.normal(scale=0.02, size=q0.size)
        q[hm.q_names.index("z")] -= 0.004                   # wheels a few mm into the ground: forces act
        u = rng.normal(scale=0.2, size=q0.size)
        a = [np.array(v) for v in fh["cedra_f"](q, u, inp_h, par)]
        b = [np.array(v) for v in fs["cedra_f"](q, u, inp_s, par)]
        assert np.max(np.abs(b[0])) > 10                     # in contact
        assert np.max(np.abs(a[0] - b[0])) <= 1e-9 * np.max(np.abs(b[0]))
        ya = np.array(fh["cedra_out"](q, u, [0.0], inp_h, par)).ravel()
        yb = np.array(fs["cedra_out"](q, u, [0.0], inp_s, par)).ravel()
        assert np.max(np.abs(ya - yb)) <= 1e-9 * np.max(np.abs(yb))
        ja = [np.array(v) for v in fh["cedra_rjac"](q, u, u, inp_h, par)]
        jb = [np.array(v) for v in fs["cedra_rjac"](q, u, u, inp_s, par)]
        for x, y in zip(ja[:2], jb[:2]):
            assert np.max(np.abs(x - y)) <= 1e-8 * np.max(np.abs(y))
