"""Several contacts per wheel (docs: the model's contact laws, several contacts per wheel).

- The search agrees with an exhaustive one (tests/contact_reference.py: g every 0.01 degree, every maximum and
  saddle polished by Newton) to 1e-9 m in every delta_k: at wheel positions around a sharp step's corner and edge,
  around a stair edge met obliquely (two maxima within one of the coarse samples' arcs), and at the states of the
  shipped runs on curved terrain (bump2d, step2d, bump3d, stairs2d, stairs3d, and the heightmaps hills3d and
  rubble3d: every 0.25 s).
- A wheel center driven along a path into the corner of ground and face and up over the edge: the wheel's total
  force is continuous (its largest jump between path points shrinks with the path's spacing) and equals the sum
  of its contacts.
- Static corner equilibrium: a wheel pressed into the corner by a known force, mu = 0: where the contacts balance
  it, each contact carries what statics says for the two normals.
- The model's Jacobian (derivatives through the frozen search, implicit function theorem) against central
  differences of cedra_f at a state with two contacts on a wheel.
- The search's shortcut where the terrain's bounds prove one maximum (fmu_src/rim.c, no samples): it takes every
  pose on terrains whose bounds allow it, each with exactly one maximum in the exhaustive search and the same
  contact; it takes none on terrains that can hold a second maximum (a dip narrower than the wheel, a dip just
  past the wheel's curvature, the step's foot), where the exhaustive search finds two.
- The contract functions' one-maximum form (CedraModel._contract: where every wheel has one maximum, the absent
  contacts folded away) gives bit for bit what the full form gives, over bump2d's bump and at step2d's step; and
  CasADi's derivative of cedra_f (what the reports' implicit peers use) is cedra_rjac's.
"""
from __future__ import annotations

import numpy as np
import pytest
import casadi as ca

import contact_reference as ref
from cedra.mechanics import rim
from cedra.mechanics.contact import compliant_force, rim_contacts
from cedra.mechanics.terrain import Terrain, terrain_inputs
from cedra.models.plant import CedraModel
from cedra.models.scene import load_shipped

R_W = 0.065
STEP = dict(terrain_h=0.08, terrain_s=0.01, terrain_x0=1.0)      # step2d's step


class Wheel:
    """One wheel on an analytic terrain: the model's contacts and forces as CasADi functions of its center."""

    def __init__(self, kind, values, dims="2d", heightmap_file=""):
        self.names = terrain_inputs(kind, dims)
        ins = {n: ca.SX.sym(n) for n in self.names}
        self.t = [values[n] for n in self.names]
        terrain = self.terrain = Terrain(kind, ins, heightmap_file)
        c, a, v = ca.SX.sym("c", 3), ca.SX.sym("a", 3), ca.SX.sym("v", 3)
        k, d, mu = ca.SX.sym("k"), ca.SX.sym("d"), ca.SX.sym("mu")
        # the plant's search for these dims (3D: every arc near touching sampled again, CedraModel.rim_refine)
        search = rim.search_external(terrain, dims == "3d")(rim.search_input(c, a, R_W, terrain))
        geos, present = rim_contacts(c, a, terrain, R_W, search)
        forces = [compliant_force(g, v, k, d, mu, 0.01) for g in geos]
        total = sum(f[0] for f in forces)
        outs = [ca.vertcat(*[g.depth for g in geos]), ca.vertcat(*present), ca.horzcat(*[f[0] for f in forces]),
                total, ca.horzcat(*[g.normal for g in geos])]
        # a heightmap's single-contact search: its frozen symbols put back (terrain.Terrain)
        self.f = ca.Function("wheel", [c, a, v, k, d, mu] + list(ins.values()), terrain.resolve(outs))
        X, Y = ca.SX.sym("X"), ca.SX.sym("Y")
        self.hf = ca.Function("h", [X, Y] + list(ins.values()), [terrain.height(X, Y), terrain.normal(X, Y)])
        self._maps, self._reference = {}, {}       # height's map per size; reference_depths per pose

    def height(self, X, Y):
        X, Y = np.broadcast_arrays(np.atleast_1d(X), np.atleast_1d(Y))
        m = self._maps.get(X.size) or self._maps.setdefault(X.size, self.hf.map(X.size))
        return np.array(m(X.reshape(1, -1), Y.reshape(1, -1), *self.t)[0]).ravel()

    def normal(self, X, Y):
        return np.array(self.hf(X, Y, *self.t)[1]).ravel()

    def __call__(self, center, axle=(0, 1, 0), v=(0, 0, 0), k=1e5, d=0.0, mu=0.0):
        r = self.f(center, axle, v, k, d, mu, *self.t)
        return [np.array(x) for x in r]

    def model_depths(self, center, axle=(0, 1, 0)):
        depth, present = self(center, axle)[:2]
        return [x for x, p in zip(depth.ravel(), present.ravel()) if p]

    def reference_depths(self, center, axle=(0, 1, 0)):
        """The exhaustive search's penetrations (remembered per pose: a test that picks poses by them asks twice)."""
        key = tuple(np.asarray(center, float)) + tuple(np.asarray(axle, float))
        if key not in self._reference:
            self._reference[key] = [d for _, _, d in ref.wheel_contacts(self.height, self.normal, np.asarray(key[:3]),
                                                                        np.asarray(key[3:]), R_W)]
        return self._reference[key]


def touching(depths):
    """The penetrations of the contacts that touch, deepest first, padded with zeros to three. A maximum of g
    below the terrain's surface carries no force whichever search finds it (its saddle is below zero too, so it
    shares nothing): the comparison is over what touches."""
    d = sorted((x for x in depths if x > 0), reverse=True)
    return np.array(d + [0.0] * (3 - len(d)))


def assert_search_exact(wheel, centers, axles=None):
    """Every delta_k of the model's search within 1e-9 m of the exhaustive search's."""
    worst, two = 0.0, 0
    for i, c in enumerate(centers):
        a = (0, 1, 0) if axles is None else axles[i]
        got, want = touching(wheel.model_depths(c, a)), touching(wheel.reference_depths(c, a))
        worst = max(worst, float(np.max(np.abs(got - want))))
        assert worst < 1e-9, (c, got, want)
        two += np.count_nonzero(want) > 1
    return worst, two


@pytest.fixture(scope="module")
def step_wheel():
    return Wheel("step", STEP)


def test_search_is_exhaustive_at_the_step(step_wheel):
    """Wheel centers around the step's foot, face and edge (within 5 mm of touching anything)."""
    rng = np.random.default_rng(7)
    centers = []
    while len(centers) < 40:       # half of them in the corner, where the wheel meets the ground and the face
        corner = len(centers) % 2
        c = np.array([rng.uniform(0.92, 0.97) if corner else rng.uniform(0.9, 1.06), 0.0,
                      rng.uniform(0.06, 0.07) if corner else rng.uniform(0.06, 0.15)])
        gap = step_wheel.reference_depths(c)
        if max(gap) > -0.005:
            centers.append(c)
    worst, two = assert_search_exact(step_wheel, centers)
    print(f"step: worst {worst:.1e} m over {len(centers)} positions, {two} with several maxima")
    assert two >= 5


# stairs3d's stairs (rise 1.5 R_w, run 4 R_w, turned by 20 degrees) and a wheel of the rocker-bogie's stairs run
# that meets an edge obliquely (t = 11.5 s): the edge and the tread are two maxima about 20 degrees apart on the rim,
# with a saddle 0.03 mm below the lower one, inside what the 15-degree samples see as one maximum
STAIRS3D = dict(terrain_h=0.0975, terrain_w=0.26, terrain_x0=1.0, terrain_y0=0.0, terrain_s=0.01,
                terrain_yaw=0.3490658503988659)
OBLIQUE = (np.array([1.76232486, -1.4668244, 0.15805834]), np.array([0.59333706, 0.72097732, 0.35797043]))


def test_search_is_exhaustive_where_a_wheel_meets_a_stair_edge_obliquely():
    wheel = Wheel("stairs", STAIRS3D, "3d")
    c0, a = OBLIQUE
    # the wheel pressed 2 mm deeper to 0.5 mm higher: the two maxima stay (the search without the arcs' second
    # sampling finds one of them, and the force jumps between their points)
    centers = [c0 + (0, 0, dz) for dz in np.linspace(-0.002, 0.0005, 11)]
    worst, two = assert_search_exact(wheel, centers, [a] * len(centers))
    print(f"oblique stair edge: worst {worst:.1e} m over {len(centers)} positions, {two} with two contacts")
    assert two == len(centers)


def corner_path(n):
    """The wheel center rolls along the ground into the step's face, then up the face and over the edge: x
    toward the corner at a constant 1 mm of penetration, then z up at the corner's x, then x over the top."""
    xs = np.linspace(0.90, 0.945, n)
    zs = np.linspace(R_W - 1e-3, 0.08 + R_W - 1e-3, n)
    top = np.linspace(0.945, 1.05, n)
    return ([np.array([x, 0, R_W - 1e-3]) for x in xs] + [np.array([0.945, 0, z]) for z in zs]
            + [np.array([x, 0, 0.08 + R_W - 1e-3]) for x in top])


def test_force_continuous_and_the_sum_of_the_contacts(step_wheel):
    jumps = []
    for n in (200, 800):
        prev, biggest, several = None, 0.0, 0
        for c in corner_path(n):
            _, present, parts, total, _ = step_wheel(c, k=1e5, d=0.0, mu=0.0)
            assert np.allclose(parts.sum(axis=1), total.ravel(), atol=1e-9)
            several += int(present.sum()) > 1 and np.count_nonzero(np.linalg.norm(parts, axis=0) > 0) > 1
            if prev is not None:
                biggest = max(biggest, np.linalg.norm(total.ravel() - prev))
            prev = total.ravel()
        jumps.append(biggest)
        assert several > 0                  # the path does pass a two-contact place
    # continuous: the largest change between neighbouring points falls with their spacing (4x finer: ~4x less)
    assert jumps[1] < 0.4 * jumps[0], jumps
    print(f"largest force change between path points: {jumps[0]:.3g} N (200 per leg), {jumps[1]:.3g} N (800)")


def test_static_corner_equilibrium(step_wheel):
    """mu = 0, no damping: the wheel's weight W and a push P toward the face. Find the center where the contacts
    balance (-P... the load): N_1 n_1 + N_2 n_2 = (P, 0, W) with the contacts' own normals; statics then gives N_1,
    N_2 from the normals alone, and the contacts carry exactly that."""
    W, P = 50.0, 20.0
    load = np.array([-P, 0, W])      # the contact forces must push back (-X) and up
    c = np.array([0.94, 0.0, R_W - 1e-4])
    for _ in range(40):              # Newton on the center (x, z) with a finite-difference Jacobian
        f = step_wheel(c)[3].ravel()[[0, 2]] - load[[0, 2]]
        if np.linalg.norm(f) < 1e-9:
            break
        J = np.zeros((2, 2))
        for j, idx in enumerate((0, 2)):
            e = np.zeros(3)
            e[idx] = 1e-8
            J[:, j] = (step_wheel(c + e)[3].ravel()[[0, 2]] - step_wheel(c - e)[3].ravel()[[0, 2]]) / 2e-8
        c[[0, 2]] -= np.linalg.solve(J, f)
    depth, present, parts, total, normals = step_wheel(c)
    active = [k for k in range(3) if present.ravel()[k] and depth.ravel()[k] > 0]
    assert len(active) == 2, (c, depth.ravel())
    n2 = normals[[0, 2]][:, active]
    N = np.linalg.solve(n2, load[[0, 2]])             # statics with the two normals
    got = [float(np.linalg.norm(parts[:, k])) for k in active]
    assert np.allclose(got, N, rtol=1e-9, atol=1e-9), (got, N)
    print(f"corner equilibrium at x = {c[0]:.6f}, z = {c[2]:.6f}: contacts carry {got[0]:.6f} N and {got[1]:.6f} N")


def test_jacobian_through_two_contacts():
    """cedra_rjac = d(M a - f)/dq and /du at a = 0 against central differences of cedra_f, at step2d's rover
    placed with its front wheel in the step's corner (two contacts there)."""
    sc = load_shipped("step2d")
    m = CedraModel(sc.options)
    par, inp = m.default_par(), m.default_inp(**sc.inputs)
    q = np.array(sc.spec(m).q_start, float)
    names = m.q_names
    out_names = [o.name for o, _ in m.outputs()]
    f_fn, j_fn, o_fn = m._num["cedra_f"], m._num["cedra_rjac"], m._num["cedra_out"]
    # slide the rover until wheel 6 (the front) presses on the ground and the step's face, each with 2 N or more
    for x in np.linspace(0.6, 0.95, 3501):
        q[names.index("x")] = x
        y = np.array(o_fn(q, np.zeros_like(q), [0.0], inp, par)).ravel()
        fn = sorted(y[out_names.index(f"wheel[6].contact[{j}].Fn")] for j in (1, 2, 3))
        if fn[1] > 2.0:
            break
    else:
        pytest.fail("no two-contact pose found")
    rng = np.random.default_rng(1)
    u = rng.normal(0, 0.05, q.size)
    Jq, Ju = [np.array(x) for x in j_fn(q, u, np.zeros_like(q), inp, par)[:2]]
    for J, which in ((Jq, "q"), (Ju, "u")):
        fd = np.zeros_like(J)
        for j in range(q.size):
            e = np.zeros(q.size)
            e[j] = 1e-7
            if which == "q":
                fp, fm = f_fn(q + e, u, inp, par)[0], f_fn(q - e, u, inp, par)[0]
            else:
                fp, fm = f_fn(q, u + e, inp, par)[0], f_fn(q, u - e, inp, par)[0]
            fd[:, j] = -(np.array(fp) - np.array(fm)).ravel() / 2e-7
        scale = np.max(np.abs(fd))
        assert np.max(np.abs(J - fd)) < 1e-5 * scale, (which, np.max(np.abs(J - fd)), scale)


def test_shared_penetration_matches_the_reference_rule():
    """The model's sharing (contact.shared_depths, symbolic) against the reference's own recursion over random
    maxima and saddles, one, two and three maxima, saddles above and below zero."""
    from cedra.mechanics.contact import shared_depths
    rng = np.random.default_rng(3)
    for n in (2, 3):
        g = ca.SX.sym("g", n)
        s = ca.SX.sym("s", n - 1)
        f = ca.Function("f", [g, s], [ca.vertcat(*shared_depths([g[k] for k in range(n)],
                                                               [s[k] for k in range(n - 1)]))])
        for _ in range(300):
            gv = rng.uniform(-0.01, 0.02, n)
            sv = [min(gv[k], gv[k + 1]) - rng.uniform(0, 0.015) for k in range(n - 1)]
            got = np.array(f(gv, sv)).ravel()
            want = ref.shares(list(gv), sv)
            assert np.allclose(got, want, atol=1e-15), (gv, sv, got, want)
            if all(x > 0 for x in sv):         # one arc: the shares add up to g1 + ... + gn - saddles
                assert np.isclose(sum(got), sum(gv) - sum(sv), atol=1e-15)


def run_states(scene, seconds):
    """(centers, axles) of every wheel every 0.25 s of the scene's main run (the shipped FMU, build/)."""
    from model_harness import run_coordinates
    sc = load_shipped(scene)
    m = CedraModel(sc.options)
    geo = ca.Function("geo", [m.q, m.par], [ca.horzcat(*[w.center for w in m.rover.wheels]),
                                            ca.horzcat(*[w.axle for w in m.rover.wheels])])
    par = m.default_par()
    states = []
    for q in run_coordinates(scene, m, seconds, every=25):
        c, a = [np.array(v) for v in geo(q, par)]
        states += [(c[:, i], a[:, i]) for i in range(c.shape[1])]
    return sc, states


@pytest.mark.parametrize("scene, seconds", [("bump2d", 15.0), ("step2d", 15.0), ("bump3d", 15.0), ("stairs2d", 20.0),
                                            ("stairs3d", 10.0),
                                            ("hills3d", 15.0), ("rubble3d", 7.5)])
def test_search_is_exhaustive_on_the_shipped_runs(scene, seconds):
    sc, states = run_states(scene, seconds)
    values = {q.name: q.start for q in sc.spec().inputs} | sc.inputs
    wheel = Wheel(sc.options.terrain, values, sc.options.dims, sc.options.heightmap)
    near = [(c, a) for c, a in states if max(wheel.reference_depths(c, a) or [-1]) > -0.01]
    worst, two = assert_search_exact(wheel, [c for c, _ in near], [a for _, a in near])
    print(f"{scene}: worst {worst:.1e} m over {len(near)} wheel poses near the ground, {two} with several contacts")


def test_search_is_exhaustive_on_the_rubble_blocks():
    """The shipped rubble (a heightmap of blocks with smoothed edges, whose spline has ripples of ~0.5 mm beside
    the edges): 150 wheel poses around the blocks, each touching, tilted and turned at random: every delta_k
    within 1e-9 m of the exhaustive search's (rim.c samples the arcs near touching again on a heightmap)."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
    import rubble
    wheel = Wheel("heightmap", {}, "3d", load_shipped("rubble3d").options.heightmap)
    rng = np.random.default_rng(5)
    blocks, centers, axles = rubble.blocks(), [], []
    while len(centers) < 150:
        x, y = blocks[rng.integers(len(blocks))][:2]
        c = np.array([x + rng.uniform(-0.15, 0.15), y + rng.uniform(-0.15, 0.15), 0.0])
        c[2] = 0.065 + float(rubble.heights(c[0], c[1])) + rng.uniform(-0.002, 0.03)
        yaw, tilt = rng.uniform(-np.pi, np.pi), rng.normal(scale=0.1)
        a = np.array([-np.sin(yaw) * np.cos(tilt), np.cos(yaw) * np.cos(tilt), np.sin(tilt)])
        if np.any(touching(wheel.reference_depths(c, a)) > 0):
            centers.append(c)
            axles.append(a)
    worst, two = assert_search_exact(wheel, centers, axles)
    print(f"rubble: worst {worst:.1e} m over {len(centers)} touching poses, {two} with several contacts")
    assert two >= 3                     # the blocks did give wheels several contacts


def touching_poses(wheel, xs, rng, n, tilt=0.0, ys=(0.0, 0.0)):
    """n wheel poses (center, axle) over X in xs (Y in ys), the axle rolled and yawed by up to tilt rad, the center
    placed between 5 mm into the terrain and 2 mm above touching it (the highest g of the rim at center Z = 0)."""
    poses = []
    b = np.linspace(-np.pi / 2, np.pi / 2, 3601)
    for _ in range(n):
        X, Y = rng.uniform(*xs), rng.uniform(*ys)
        roll, yaw = rng.uniform(-tilt, tilt, 2)
        a = np.array([-np.sin(yaw) * np.cos(roll), np.cos(yaw) * np.cos(roll), np.sin(roll)])
        r1, r2 = ref.rim_frame(None, a, wheel.normal(X, Y))
        z = np.max(ref.g_of(wheel.height, (X, Y, 0.0), R_W, r1, r2)(b))
        poses.append((np.array([X, Y, z + rng.uniform(-0.005, 0.002)]), a))
    return poses


def reference_maxima(wheel, center, axle):
    r1, r2 = ref.rim_frame(center, axle, wheel.normal(center[0], center[1]))
    return len(ref.extrema(ref.g_of(wheel.height, center, R_W, r1, r2))[0])


@pytest.mark.parametrize("kind, values, dims, xs, tilt, proven", [
    ("bump", dict(terrain_h=0.14625, terrain_w=0.14625, terrain_x0=1.0), "2d", (0.7, 1.3), 0.0, True),
    ("bump", dict(terrain_h=0.14625, terrain_w=0.14625, terrain_x0=1.0), "3d", (0.7, 1.3), 0.05, True),
    # a dip whose bottom bends at 0.9 of the wheel's curvature (R |f''| = 0.9) and one at 1.1
    ("bump", dict(terrain_h=-0.9 * 0.1 ** 2 / (2 * R_W), terrain_w=0.1, terrain_x0=1.0), "2d", (0.85, 1.15), 0.0, True),
    ("bump", dict(terrain_h=-1.1 * 0.1 ** 2 / (2 * R_W), terrain_w=0.1, terrain_x0=1.0), "2d", (0.997, 1.003), 0.0,
     False),
    ("bump", dict(terrain_h=-0.03, terrain_w=0.04, terrain_x0=1.0), "2d", (0.93, 1.07), 0.0, False),
    ("step", dict(terrain_h=0.08, terrain_s=0.1, terrain_x0=1.0), "2d", (0.7, 1.3), 0.0, True),
    ("step", STEP, "2d", (0.9, 0.97), 0.0, False),
    ("waves", dict(terrain_h=0.01, terrain_w=0.5), "3d", (0.0, 0.5), 0.3, True),
])
def test_one_maximum_shortcut_never_hides_a_second(kind, values, dims, xs, tilt, proven):
    wheel = Wheel(kind, values, dims)
    test = rim.one_maximum_test(wheel.terrain)
    rng = np.random.default_rng(11)
    poses = touching_poses(wheel, xs, rng, 30, tilt, (0.0, 0.5) if kind == "waves" else (0.0, 0.0))
    taken, several = 0, 0
    for c, a in poses:
        maxima = reference_maxima(wheel, c, a)
        took = test(c, a, R_W, wheel.t)
        assert not (took and maxima > 1), (c, a, maxima)
        taken += took
        several += maxima > 1
    assert taken == (len(poses) if proven else 0), (taken, len(poses))
    if proven:
        assert_search_exact(wheel, [c for c, _ in poses], [a for _, a in poses])
    else:
        assert several > 0          # these terrains do hold a second maximum
    print(f"{kind} {values}: shortcut at {taken} of {len(poses)} poses, {several} with several maxima")


@pytest.mark.parametrize("scene, xs", [("bump2d", (0.3, 1.7)), ("step2d", (0.6, 1.0))])
def test_one_maximum_form_is_the_full_form(scene, xs):
    sc = load_shipped(scene)
    m = CedraModel(sc.options)
    par, inp = m.default_par(), m.default_inp(**sc.inputs)
    fns, full = m._num, m.functions(one=False)
    wheel = Wheel(sc.options.terrain, {q.name: q.start for q in sc.spec(m).inputs} | sc.inputs, sc.options.dims)
    test = rim.one_maximum_test(wheel.terrain)
    geo = ca.Function("geo", [m.q, m.par], [ca.horzcat(*[w.center for w in m.rover.wheels]),
                                            ca.horzcat(*[w.axle for w in m.rover.wheels])])
    rng = np.random.default_rng(5)
    q0 = np.array(sc.spec(m).q_start, float)
    ones = 0
    for x in np.linspace(*xs, 40):
        q0[m.q_names.index("x")] = x
        q = np.array(fns["cedra_guess"](q0, inp, par)).ravel() + rng.normal(0, 1e-3, q0.size)
        u, a = rng.normal(0, 0.1, q.size), rng.normal(0, 1.0, q.size)
        c, ax = [np.array(v) for v in geo(q, par)]
        ones += all(test(c[:, i], ax[:, i], R_W, wheel.t) for i in range(c.shape[1]))
        args = {"cedra_f": (q, u, inp, par), "cedra_rjac": (q, u, a, inp, par), "cedra_out": (q, u, [0.0], inp, par),
                "cedra_switch": (q, u, inp, par, ca.DM(0, 1)), "cedra_settle": (q, inp, par)}
        for name, arg in args.items():
            arg = [ca.DM(v) for v in arg]
            for got, want in zip(fns[name].call(arg), full[name].call(arg)):
                assert np.array_equal(np.array(got), np.array(want)), (scene, x, name)
    if scene == "bump2d":
        assert ones == 40          # the shortcut proves one maximum on every wheel: the one-maximum form throughout


def test_cedra_f_differentiates_as_cedra_rjac():
    """The MX Jacobian of cedra_f (cedra.reports.common: the peers' exact Jacobian) through the searches and the
    two forms equals -cedra_rjac (a = 0) on bump2d's bump: the implicit function theorem reaches both."""
    sc = load_shipped("bump2d")
    m = CedraModel(sc.options)
    par, inp = m.default_par(), m.default_inp(**sc.inputs)
    q0 = np.array(sc.spec(m).q_start, float)
    q0[m.q_names.index("x")] = 0.95
    q = np.array(m._num["cedra_guess"](q0, inp, par)).ravel()
    u = np.random.default_rng(1).normal(0, 0.1, q.size)
    Q = ca.MX.sym("q", q.size)
    J = np.array(ca.Function("J", [Q], [ca.jacobian(m._num["cedra_f"](Q, u, inp, par)[0], Q)])(q))
    R = np.array(m._num["cedra_rjac"](q, u, np.zeros_like(q), inp, par)[0])
    assert np.max(np.abs(J + R)) < 1e-12 * np.max(np.abs(R))
