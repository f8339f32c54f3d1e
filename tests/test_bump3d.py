"""bump3d: the paper's run in 3D, on the `bump` terrain (constant in Y). Started symmetric
(start.y = 0, start.yaw = 0, the same torque on all six wheels) under the main job's controller
(cedra.run.simulate.run_bump), it must give the planar scene bump2d's results.

How the wheels pair up (docs/model.md, Scenes): the planar model's coordinates move wheels 1 and 3 (and 2 and 4) as one,
so its equations carry both wheels' masses and contact forces; its outputs still report each wheel's own force
(the 3D equations are projected, `P' M P, P' f`, and each of the six contacts is computed on its own), so 2D
`wheel[1].Fn` = `wheel[3].Fn` = the force on ONE bogie front wheel, half of what the pair carries. Checked here:
the six settled loads add up to the rover's weight in both scenes. So 3D wheel[i] is compared with 2D wheel[i]
for every i (3D wheel 3 with 2D wheel 3, which equals 2D wheel 1), and the pair sums wheel[1] + wheel[3],
wheel[2] + wheel[4] agree as well.

Bounds (the solver's own error scale; solver.tol is one mixed absolute/relative tolerance, a component x_i is
held to tol (1 + |x_i|) per step, fmu_src/solver.c err_norm):
- body.x: tol (1 + max |body.x|), one step's allowed error of that component (the two runs integrate different
  systems, 19 and 31 states, with their own step sequences, so they agree only to the solvers' errors).
- normal forces: F_n = ground_k delta - ground_d v_n, and delta, v_n are held to tol (1 + |z|), tol (1 + |v|):
  ground_k tol (1 + max body.z) + ground_d tol (1 + max |v|), with max |v| bounded by 1 m/s (the rover drives at
  0.2 m/s, the wheels' vertical speeds stay below that) -- about 0.12 N at tol 1e-6 on peaks of 494 N.
- body.y, body.roll, body.yaw, theta1 - theta2: 1e-9 (m, rad): the mirror symmetry holds exactly in the
  equations, so only round-off (~1e-14) may appear; any asymmetric term would show at 1e-4 or more.
Measured (this change): at tol 1e-6, |dx| 4.2e-9 m, |dFn| 1.2e-3 N; at tol 1e-8, 1.9e-10 m, 1.3e-5 N (the
difference shrinks with the tolerance: it is the solvers' error, not a model difference); y, roll, yaw < 3e-14.
"""
from __future__ import annotations


import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import CedraModel
from cedra.rover.parameters import DEFAULTS
from cedra.models.scene import load_shipped
from cedra.run.simulate import run_bump
from fmu_harness import shipped_fmu

STOP = 8.0          # over the whole bump: the front wheel meets it near t = 3.5 s, the rear wheel leaves ~7.5 s
V_MAX = 1.0         # m/s, bound on the speeds entering the force's error scale (see the module docstring)
SYM = 1e-9
EXTRA = ["body.y", "body.yaw", "body.roll", "bogie.theta[2]"]


def fmu_of(name, tmp_path_factory):
    return shipped_fmu(name, tmp_path_factory)


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return {n: fmu_of(n, tmp_path_factory) for n in ("bump2d", "bump3d")}


def columns(names, rows):
    return {n: rows[:, k] for k, n in enumerate(names)}


def test_bump3d_scene_is_the_bump2d_run_in_3d():
    s2, s3 = load_shipped("bump2d"), load_shipped("bump3d")
    assert s3.options.dims == "3d" and s3.options.terrain == "bump"
    assert not s3.options.steering and s3.options.contact == "compliant" and not s3.options.locked_wheels
    assert s3.inputs == s2.inputs and s3.parameters == s2.parameters and s3.solver == s2.solver
    assert s3.stop_time == s2.stop_time and s3.output_interval == s2.output_interval
    assert s3.start == {"x": s2.start["x"], "y": 0.0, "yaw": 0.0}


def test_bump_terrain_is_constant_in_y_in_3d():
    """The `bump` kind in a 3D model: the terrain's height, gradient and Hessian do not depend on Y, and the
    whole model is invariant under a shift in Y (M, f and the outputs but body.y and the Y coordinates)."""
    m = CedraModel(load_shipped("bump3d").options)
    X, Y = ca.SX.sym("X"), ca.SX.sym("Y")
    terr = ca.Function("t", [X, Y, m.inp], list(m.terrain.local(X, Y)))
    inp = m.default_inp(**load_shipped("bump3d").inputs)
    for x in (0.0, 0.9, 1.0, 1.07, 1.3):
        h0, g0, H0 = (np.array(v) for v in terr(x, 0.0, inp))
        assert abs(h0.item() - 0.14625 * np.exp(-((x - 1.0) / 0.14625) ** 2)) < 1e-15
        for y in (-0.5, -0.17, 0.17, 2.0):
            h, g, H = (np.array(v) for v in terr(x, y, inp))
            assert h.item() == h0.item() and g[0, 0] == g0[0, 0] and g[1, 0] == 0.0 and np.all(H[1, :] == 0.0)
    fns, par = m.functions(), m.default_par()
    rng = np.random.default_rng(13)
    iy = m.q_names.index("y")
    for x in (0.3, 0.95, 1.1):
        q = np.array(m.spec("t").q_start, dtype=float)
        q[m.q_names.index("x")] = x
        q = np.array(fns["cedra_guess"](q, inp, par)).ravel()      # in the ground (the guess's pose)
        q += 1e-4 * rng.standard_normal(len(q))
        u = 0.1 * rng.standard_normal(len(m.q_names))
        q0, q1 = q.copy(), q.copy()
        q0[iy], q1[iy] = 0.0, 0.37
        f0, f1 = (np.array(fns["cedra_f"](qq, u, inp, par)[0]).ravel() for qq in (q0, q1))
        assert np.max(np.abs(f0 - f1)) <= 1e-9 * max(1.0, np.max(np.abs(f0))), x
        y0, y1 = (np.array(fns["cedra_out"](qq, u, 0.0, inp, par)).ravel() for qq in (q0, q1))
        names = [o.name for o, _ in m.outputs()] + ["energy.kinetic", "energy.potential", "energy.work"]
        assert sum(y0[names.index(f"wheel[{i}].Fn")] > 10.0 for i in range(1, 7)) >= 5   # wheels in contact
        for k, n in enumerate(names):
            shift = 0.37 if n == "body.y" or (n.startswith("wheel[") and n[-3:] in (".cy", ".py")) else 0.0
            assert abs(y1[k] - y0[k] - shift) <= 1e-9 * max(1.0, abs(y0[k])), (x, n, y0[k], y1[k])


def run_pair(fmus, tol):
    n2, d2, t2, i2 = run_bump(fmus["bump2d"], STOP, {"solver.tol": tol})
    n3, d3, t3, i3 = run_bump(fmus["bump3d"], STOP, {"solver.tol": tol}, extra=EXTRA)
    assert i2["ok"] and i3["ok"], (i2["messages"][-3:], i3["messages"][-3:])
    return columns(n2, d2), columns(n3, d3)


def test_settled_loads_are_per_wheel_in_both(fmus):
    """wheel[i].Fn is one wheel's force in 2D too: the six loads carry the whole weight, the pairs equal."""
    weight = (DEFAULTS["m_B"] + DEFAULTS["m_F"] + 6 * DEFAULTS["m_w"]) * DEFAULTS["g"]
    for name in ("bump2d", "bump3d"):
        n, d, _, info = run_bump(fmus[name], 0.01)
        c = columns(n, d)
        loads = np.array([c[f"wheel[{i}].Fn"][0] for i in range(1, 7)])
        assert abs(loads.sum() - weight) < 1e-6 * weight, (name, loads, weight)
        assert abs(loads[0] - loads[2]) < 1e-9 and abs(loads[1] - loads[3]) < 1e-9, (name, loads)
        assert 40 < loads[0] < 60, (name, loads)          # one wheel, not the pair (~101 N)


@pytest.mark.parametrize("tol", [1e-6, 1e-8])
def test_symmetric_bump3d_gives_bump2d(fmus, tol):
    c2, c3 = run_pair(fmus, tol)
    assert np.array_equal(c2["time"], c3["time"]) and c2["time"][-1] == pytest.approx(STOP)
    assert c3["body.x"][-1] > 1.5                      # it did cross the bump (at X = 1 m)
    assert max(c3["wheel[5].Fn"]) > 400                # ... with the rear wheel's landing spike
    # body.x
    bound_x = tol * (1 + np.max(np.abs(c2["body.x"])))
    dx = np.max(np.abs(c2["body.x"] - c3["body.x"]))
    assert dx <= bound_x, (dx, bound_x)
    # normal forces, wheel by wheel and by pairs
    bound_f = DEFAULTS["ground_k"] * tol * (1 + np.max(c2["body.z"])) + DEFAULTS["ground_d"] * tol * (1 + V_MAX)
    for i in range(1, 7):
        d = np.max(np.abs(c2[f"wheel[{i}].Fn"] - c3[f"wheel[{i}].Fn"]))
        assert d <= bound_f, (i, d, bound_f)
    for a, b in ((1, 3), (2, 4)):
        s2 = c2[f"wheel[{a}].Fn"] + c2[f"wheel[{b}].Fn"]
        s3 = c3[f"wheel[{a}].Fn"] + c3[f"wheel[{b}].Fn"]
        assert np.max(np.abs(s2 - s3)) <= 2 * bound_f, (a, b)
    # the 3D rover stays in the plane
    for n in ("body.y", "body.yaw", "body.roll"):
        assert np.max(np.abs(c3[n])) < SYM, (n, np.max(np.abs(c3[n])))
    assert np.max(np.abs(c3["bogie.theta[1]"] - c3["bogie.theta[2]"])) < SYM
