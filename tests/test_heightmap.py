"""The heightmap terrain (docs/model.md, Terrain): the C spline against an independent one, its derivatives, the file
reader's errors, the model on a heightmap of a plane against the analytic slope, and the FMU reading its grid
from resources/ (per instance, loud when the rover leaves the grid)."""
from __future__ import annotations

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
import rubble  # noqa: E402


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


def sampled_slope_and_curvature(f, xs, ys):
    """The largest |gradient| and Hessian eigenvalue of the active map, sampled on a fine grid."""
    X, Y = np.meshgrid(np.linspace(xs[0], xs[-1], 161), np.linspace(ys[0], ys[-1], 121))
    out = f.map(X.size)(np.vstack([X.ravel(), Y.ravel()]))
    grad, hess = np.array(out[1]), np.array(out[2]).reshape(2, 2, -1, order="F")
    a, b, d = hess[0, 0], hess[0, 1], hess[1, 1]
    return np.hypot(grad[0], grad[1]).max(), (0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b ** 2)).max()


def test_derivative_bounds_hold(random_map):
    """The grid's bounds for the contact search's one-maximum test (rim.c): |gradient| <= G and the Hessian's
    largest eigenvalue <= U everywhere on the grid (sampled densely), on a map of noise; on the shipped hills they
    are close enough to prove one maximum (within 1.5 times what is sampled)."""
    xs, ys, _ = random_map
    f = terrain_fn()
    G, U = np.array(heightmap.bounds_external()(np.zeros(8))).ravel()
    slope, top = sampled_slope_and_curvature(f, xs, ys)
    assert slope <= G and top <= U
    heightmap.load(scene.load_shipped("hills3d").options.heightmap)
    X, Y, _ = hills.grid()
    G, U = np.array(heightmap.bounds_external()(np.zeros(8))).ravel()
    slope, top = sampled_slope_and_curvature(f, X, Y)
    assert slope <= G < 1.5 * slope and top <= U < 1.5 * top


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


@pytest.mark.parametrize("example, rounding", [(hills, 1e-9), (rubble, 1e-6)])
def test_shipped_grid_is_what_the_example_makes(example, rounding):
    X, Y, Z = example.grid()
    lines = [ln for ln in example.SHIPPED.read_text().splitlines() if not ln.startswith("#")]
    assert lines[0] == "cedra-heightmap 1"
    nx, ny, x0, y0, dx, dy = map(float, lines[1].split())
    assert (nx, ny, x0, y0, dx, dy) == (len(X), len(Y), X[0], Y[0], example.GRID["dx"], example.GRID["dy"])
    shipped = np.array([[float(v) for v in ln.split()] for ln in lines[2:]])
    assert np.max(np.abs(shipped - Z)) <= 0.5 * rounding * (1 + 1e-9)


def test_model_on_a_heightmap_plane_equals_the_analytic_slope(tmp_path):
    """The heightmap path (external terrain, contact search in C) against the analytic 'slope' kind (closed-form
    contact point) on the same plane: f, M and the outputs agree at random states."""
    slope = 0.12
    X = -2 + 0.25 * np.arange(17)
    Y = -1 + 0.25 * np.arange(9)
    Z = np.repeat((-np.tan(slope) * X)[None, :], len(Y), axis=0)
    path = heightmap.write(tmp_path / "plane.txt", Z, -2, -1, 0.25, 0.25)
    hm = CedraModel(ModelOptions(dims="3d", terrain="heightmap", heightmap=str(path)))
    sl = CedraModel(ModelOptions(dims="3d", terrain="slope"))
    fh, fs = hm.functions(), sl.functions()
    names_h, names_s = ([o.name for o, _ in m.outputs()] for m in (hm, sl))
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
        ya = dict(zip(names_h, np.array(fh["cedra_out"](q, u, [0.0], inp_h, par)).ravel()))
        yb = dict(zip(names_s, np.array(fs["cedra_out"](q, u, [0.0], inp_s, par)).ravel()))
        scale = max(abs(v) for v in yb.values())
        assert max(abs(ya[n] - v) for n, v in yb.items()) <= 1e-9 * scale
        # the heightmap has several contacts per wheel: on a plane one, the wheel's own, the others absent
        for k in range(1, 7):
            assert ya[f"wheel[{k}].contacts"] in (0, 1)
            assert abs(ya[f"wheel[{k}].contact[1].Fn"] - yb[f"wheel[{k}].Fn"]) <= 1e-9 * scale
            assert ya[f"wheel[{k}].contact[2].Fn"] == ya[f"wheel[{k}].contact[3].Fn"] == 0
        ja = [np.array(v) for v in fh["cedra_rjac"](q, u, u, inp_h, par)]
        jb = [np.array(v) for v in fs["cedra_rjac"](q, u, u, inp_s, par)]
        for x, y in zip(ja[:2], jb[:2]):
            assert np.max(np.abs(x - y)) <= 1e-8 * np.max(np.abs(y))


# ---------------------------------------------------------------- the wheel's contact point in C
def hills_states(model, n, seed):
    """n random states of the hills3d model with the rover on the hills (X 0.8..3.2 m), its wheels pressed a few
    mm into the ground (cedra_guess), joints and speeds perturbed. Makes the shipped grid the active map (another
    test may have loaded its own; off the active grid the Python-side functions would quietly give 0)."""
    heightmap.load(scene.load_shipped("hills3d").options.heightmap)
    fns = model.functions()
    names = model.q_names
    par = model.default_par()
    inp = model.default_inp(**{f"tau[{i}]": 1.0 for i in range(1, 7)})
    q0 = np.array(model.spec("t").q_start)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        q = q0 + rng.normal(scale=0.02, size=q0.size)
        q[names.index("x")] = rng.uniform(0.8, 3.2)
        q[names.index("y")] = rng.uniform(-0.4, 0.4)
        q = np.array(fns["cedra_guess"](q, inp, par)).ravel() + rng.normal(scale=0.005, size=q0.size)
        u = rng.normal(scale=0.2, size=q0.size)
        assert np.max(np.abs(np.array(fns["cedra_f"](q, u, inp, par)[0]))) > 10      # in contact, on the grid
        out.append((q, u, rng.normal(size=q0.size)))
    return fns, par, inp, out


@pytest.fixture(scope="module")
def hills_models():
    opt = scene.load_shipped("hills3d").options
    return CedraModel(opt), CedraModel(opt, symbolic_rim=True)


def test_c_rim_search_equals_the_symbolic_search(hills_models):
    """The C search (one cedra_rim_contact per wheel, its Jacobian by the implicit function theorem) against the
    symbolic one it replaces (13 samples and 4 Newton steps of the point external, differentiated by CasADi):
    f, the outputs, the settle residual and every Jacobian agree at random states on the hills."""
    new, old = hills_models
    fn, par, inp, states = hills_states(new, 6, seed=11)
    fo = old.functions()
    moved = 0
    for q, u, a in states:
        f_new, f_old = (np.array(f["cedra_f"](q, u, inp, par)[0]).ravel() for f in (fn, fo))
        assert np.max(np.abs(f_old)) > 10                                  # in contact
        assert np.max(np.abs(f_new - f_old)) <= 1e-12 * np.max(np.abs(f_old))
        y_new, y_old = (dict(zip([o.name for o, _ in m.outputs()],
                                 np.array(f["cedra_out"](q, u, [0.0], inp, par)).ravel()))
                        for f, m in ((fn, new), (fo, old)))
        scale = max(abs(v) for v in y_old.values())
        assert max(abs(y_new[n] - v) for n, v in y_old.items()) <= 1e-12 * scale
        for x, y in zip(*(f["cedra_rjac"](q, u, a, inp, par) for f in (fn, fo))):
            x, y = np.array(x), np.array(y)
            assert np.max(np.abs(x - y)) <= 1e-12 * max(1.0, np.max(np.abs(y)))
        for x, y in zip(*(f["cedra_settle"](q, inp, par) for f in (fn, fo))):
            x, y = np.array(x), np.array(y)
            assert np.max(np.abs(x - y)) <= 1e-12 * max(1.0, np.max(np.abs(y)))
        # the contact points are off the sample angles: the Newton steps (and their derivatives) did work
        moved += sum(abs(y_new[f"wheel[{k}].psi"]) > 1e-3 for k in range(1, 7))
    assert moved > 6


def rim_cases(seed, n):
    """Random wheel poses x = [center, unit axle, radius] over the shipped hills."""
    rng = np.random.default_rng(seed)
    X, Y, _ = hills.grid()
    cases = []
    for _ in range(n):
        c = np.array([rng.uniform(0.8, 3.2), rng.uniform(-0.6, 0.6), 0.0])
        c[2] = hills.heights(c[0], c[1]) + rng.uniform(0.04, 0.064)
        yaw, tilt = rng.uniform(-np.pi, np.pi), rng.normal(scale=0.2)
        a = np.array([-np.sin(yaw) * np.cos(tilt), np.cos(yaw) * np.cos(tilt), np.sin(tilt)])
        cases.append(np.concatenate([c, a, [0.065]]))
    return cases


@pytest.fixture()
def shipped_map():
    heightmap.load(scene.load_shipped("hills3d").options.heightmap)


def test_rim_contact_is_the_deepest_rim_point(shipped_map):
    """Independent of the search: the contact point is the point of the lower rim with the largest
    g = h(p) - p_Z on a dense scan (20001 angles), and the height and gradient it returns are the terrain's there."""
    ext, point, pt = heightmap.rim_external(), heightmap.rim_external(jacobian=False), terrain_fn()
    scan = pt.map(20001)
    for x in rim_cases(5, 20):
        e = np.array(ext(x)[0]).ravel()
        assert np.array_equal(np.array(point(x)).ravel(), e)          # cedra_rim_point: the same, no Jacobian
        c, a, R = x[:3], x[3:6], x[6]
        r1 = np.cross(a, [0.0, 0.0, 1.0])
        r1 = np.cross(r1, a)
        r1 = -r1 / np.linalg.norm(r1)                      # lowest rim point's direction; the scan covers +-90 deg
        r2 = np.cross(a, r1)
        b = np.linspace(-np.pi / 2, np.pi / 2, 20001)
        P = c[:, None] + R * (np.cos(b)[None, :] * r1[:, None] + np.sin(b)[None, :] * r2[:, None])
        g = np.array(scan(P[:2])[0]).ravel() - P[2]
        k = int(np.argmax(g))
        assert np.linalg.norm(e[:3] - P[:, k]) < R * np.pi / 20000         # within the scan's resolution
        assert abs(np.dot(e[:3] - c, a)) < 1e-14 and abs(np.linalg.norm(e[:3] - c) - R) < 1e-14   # on the rim
        h, grad = (np.array(v).ravel() for v in pt(e[:2])[:2])
        assert abs(e[3] - h[0]) < 1e-15 and np.max(np.abs(e[4:6] - grad)) < 1e-14
        assert g[k] - 1e-15 <= e[3] - e[2] <= g[k] + 1e-9       # no scanned point is deeper, the scan comes close


def test_rim_contact_jacobian_matches_finite_differences(shipped_map):
    ext = heightmap.rim_external()
    d = 1e-6
    for x in rim_cases(9, 20):
        J = np.array(ext(x)[1])
        for k in range(7):
            dx = np.eye(7)[k] * d
            fd = (np.array(ext(x + dx)[0]) - np.array(ext(x - dx)[0])).ravel() / (2 * d)
            assert np.max(np.abs(fd - J[:, k])) < 1e-7 * max(1.0, np.max(np.abs(J[:, k]))), (x, k)


def test_model_jacobian_matches_finite_differences(hills_models):
    """The contact point's dependence on the pose enters cedra_rjac exactly: dr/dq and dr/du of r = M a - f
    against central differences of cedra_M and cedra_f on the hills."""
    m = hills_models[0]
    fns, par, inp, states = hills_states(m, 3, seed=4)
    d = 1e-7

    def r(q, u, a):
        return np.array(fns["cedra_M"](q, par)) @ a - np.array(fns["cedra_f"](q, u, inp, par)[0]).ravel()

    for q, u, a in states:
        dq, du = (np.array(v) for v in fns["cedra_rjac"](q, u, a, inp, par)[:2])
        scale = max(np.max(np.abs(dq)), 1.0)
        for k in range(q.size):
            e = np.eye(q.size)[k] * d
            assert np.max(np.abs((r(q + e, u, a) - r(q - e, u, a)) / (2 * d) - dq[:, k])) < 1e-6 * scale, k
            assert np.max(np.abs((r(q, u + e, a) - r(q, u - e, a)) / (2 * d) - du[:, k])) < 1e-6 * scale, k


def test_c_rim_search_on_rough_ground_equals_the_symbolic_search(tmp_path):
    """On a rough random grid (bumps as high as the wheel's radius within a few cells: the best sample often
    not at the bottom, g'' >= 0 at some, steep faces) the C search (the best sample polished to its maximum)
    against contact.rim_point's 4 plain Newton steps, formed symbolically through the point external: where those
    converged (almost always) the same point to 1e-12 m and CasADi's derivative of the 4 steps equals the implicit
    function theorem's."""
    from cedra.mechanics.contact import rim_point
    from cedra.mechanics.terrain import Terrain
    rng = np.random.default_rng(21)
    Z = rng.normal(size=(15, 15)) * 0.03
    path = heightmap.write(tmp_path / "rough.txt", Z, -0.35, -0.35, 0.05, 0.05)
    terrain = Terrain("heightmap", {}, str(path), symbolic_rim=True)
    x = ca.SX.sym("x", 7)
    p = rim_point(x[0:3], x[3:6], terrain, x[6])
    sym = ca.Function("rim", [x], [p, ca.jacobian(p, x)])
    ext = heightmap.rim_external()
    n_off_bottom = n_compared = n_shallower = 0
    for _ in range(200):
        c = np.array([*rng.uniform(-0.2, 0.2, 2), 0.0])
        c[2] = float(terrain.height(c[0], c[1])) + rng.uniform(-0.02, 0.06)
        yaw, tilt = rng.uniform(-np.pi, np.pi), rng.normal(scale=0.3)
        a = np.array([-np.sin(yaw) * np.cos(tilt), np.cos(yaw) * np.cos(tilt), np.sin(tilt)])
        xv = np.concatenate([c, a, [0.065]])
        e, J = (np.array(v) for v in ext(xv))
        ps, Js = (np.array(v) for v in sym(xv))
        g_c, g_s = e[3, 0] - e[2, 0], float(terrain.height(ps[0], ps[1])) - ps[2, 0]
        n_shallower += g_c < g_s - 1e-15
        n_off_bottom += abs(e[2, 0] - c[2] + 0.065) > 5e-3
        if np.max(np.abs(e[:3].ravel() - ps.ravel())) < 1e-12 and \
                np.max(np.abs(J[:3] - Js)) < 1e-9 * max(1.0, np.max(np.abs(Js))):
            n_compared += 1
    assert n_off_bottom > 100           # the rough ground did move the contact away from the rim's bottom
    assert n_compared >= 195
    # the polish keeps to the best sample's bracket; unbounded Newton steps may land on another, deeper maximum
    assert n_shallower <= 5


def test_cedra_f_is_differentiable_once_through_the_rim_point(hills_models):
    """CasADi's own derivative of cedra_f (what the Python side's reference integrators take: its MX Jacobian goes
    through jac_cedra_rim_point) equals cedra_rjac's: at a = 0, dr/dq = -df/dq and dr/du = -df/du."""
    m = hills_models[0]
    fns, par, inp, states = hills_states(m, 2, seed=8)
    q, u = ca.MX.sym("q", m.q.numel()), ca.MX.sym("u", m.q.numel())
    f = fns["cedra_f"](q, u, inp, par)[0]
    jf = ca.Function("jf", [q, u], [ca.jacobian(f, q), ca.jacobian(f, u)])
    zero = np.zeros(m.q.numel())
    for qv, uv, _ in states:
        dq, du = (np.array(v) for v in fns["cedra_rjac"](qv, uv, zero, inp, par)[:2])
        fq, fu = (np.array(v) for v in jf(qv, uv))
        assert np.max(np.abs(fq + dq)) <= 1e-10 * np.max(np.abs(dq))
        assert np.max(np.abs(fu + du)) <= 1e-10 * np.max(np.abs(du))


def test_the_rim_search_memo_changes_no_result(shipped_map):
    """The FMU keeps its last rim searches (heightmap.c: rim_memoized) because the model asks for the same wheel pose
    several times; a repeated pose must give bit for bit what a fresh search gives, with or without the Jacobian,
    also after the pose has left the memo (more poses than it holds)."""
    ext, point = heightmap.rim_external(), heightmap.rim_external(jacobian=False)
    cases = rim_cases(11, 40)                         # more than the memo's 32 entries
    fresh = [(np.array(point(x)), np.array(ext(x)[0]), np.array(ext(x)[1])) for x in cases]
    heightmap.use_memo(True)
    try:
        order = [0, 0, 1, 0, 1, 2] + list(range(40)) + [39, 38, 0, 1] + list(range(40))[::-1]
        for i in order:
            x = cases[i]
            e, (e2, J) = np.array(point(x)), (np.array(v) for v in ext(x))
            assert np.array_equal(e, fresh[i][0]) and np.array_equal(e2, fresh[i][1])
            assert np.array_equal(J, fresh[i][2])
        hits, misses = heightmap.memo_counts()
    finally:
        heightmap.use_memo(False)
    assert hits >= len(order) and misses >= 40 + 2     # the memo was used, and poses left it and came back
