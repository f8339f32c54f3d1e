"""Chassis and link contact (docs/model.md, Chassis and links): the body's box, the bogies and the fork touch the
terrain through collision points with the wheels' compliant law. Checked against an independent derivation of the
points from the model's own outputs (body pose, wheel centers, fork angles), the planar model as the projection of
the 3D one (in 2D one point stands for its twins across the rover), the forces as the potential's gradient, energy
conservation through a belly landing, and the scene file's checks."""
import math

import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import ModelOptions, projection
from cedra.models.scene import SceneError, parse
from cedra.rover.parameters import DEFAULTS as D
from model_harness import Built

STEP = dict(terrain_h=0.08, terrain_x0=1.0, terrain_s=0.01)


@pytest.fixture(scope="module")
def b2():
    return Built(ModelOptions(dims="2d", terrain="step", chassis=True))


@pytest.fixture(scope="module")
def b3():
    return Built(ModelOptions(dims="3d", terrain="step", chassis=True))


@pytest.fixture(scope="module")
def flat2():
    return Built(ModelOptions(dims="2d", terrain="flat", chassis=True))


def _pose(b, **values):
    q = np.zeros(b.n)
    q[b.names.index("z")] = 0.2
    q[b.names.index("theta4")] = D["fork_theta4_ref"]
    for name, v in values.items():
        q[b.names.index(name)] = v
    return q


def _points_from_outputs(y, pitch):
    """The collision points of a planar pose in world (X, Z), from docs/model.md's geometry and the model's outputs
    only: the body's box from body.x/z/pitch, the bogie points from the wheel centers, the fork's from the
    four-bar's angles (theta4, theta5). Each with its count in the plane (its twins across the rover)."""
    c, s = math.cos(pitch), math.sin(pitch)

    def body(bx, bz):        # R_y(pitch): positive pitch is nose down
        return np.array([y["body.x"] + c * bx + s * bz, y["body.z"] - s * bx + c * bz])
    pts = [(body(-0.30 + 0.04 * k, -0.06), 3) for k in range(13)]
    pts += [(body(bx, bz), 3) for bx in (-0.30, 0.18) for bz in (-0.02, 0.03, 0.08)]
    c1, c2 = (np.array([y[f"wheel[{i}].cx"], y[f"wheel[{i}].cz"]]) for i in (1, 2))
    pts += [(c2 + f * (c1 - c2), 2) for f in (0.25, 0.5, 0.75)]
    e = lambda a: np.array([math.cos(a), math.sin(a)])        # noqa: E731
    A, B = np.array([D["fork_ax"], D["fork_az"]]), np.array([D["fork_bx"], D["fork_bz"]])
    C = A + D["fork_a"] * e(y["fork.theta4"])
    Dp = C + D["fork_c"] * e(y["fork.theta5"])
    assert abs(np.linalg.norm(Dp - B) - D["fork_b"]) < 1e-12          # the four-bar closes: theta5 is right
    pts += [(body(*p), 1) for p in (C, Dp, 0.5 * (A + C), 0.5 * (B + Dp), 0.5 * (C + Dp))]
    return pts


@pytest.mark.parametrize("pitch, z", [(-0.4, 0.165), (0.45, 0.17), (0.0, 0.12)])
def test_outputs_against_the_points_derived_from_the_outputs(flat2, pitch, z):
    """On flat ground at rest: chassis.clearance is the lowest point's height, chassis.Fn = sum count k depth."""
    b = flat2
    par, inp = b.m.default_par(), b.m.default_inp()
    q = _pose(b, pitch=pitch, z=z)
    y = b.out(q, np.zeros(b.n), inp, par)
    pts = _points_from_outputs(y, pitch)
    assert len(pts) == len(b.m.chassis) == 27
    heights = np.array([p[1] for p, _ in pts])
    counts = np.array([n for _, n in pts])
    assert abs(y["chassis.clearance"] - heights.min()) < 1e-12
    fn = float(np.sum(counts * D_ground_k(b) * np.maximum(0, -heights)))
    assert fn > 50                                       # the pose really touches (belly, rear face or fork)
    assert abs(y["chassis.Fn"] - fn) < 1e-9 * fn


def D_ground_k(b):
    return b.m.default_par()[[p.name for p in b.m.params].index("ground_k")]


def test_planar_model_is_the_projection_of_the_3d_one(b2, b3):
    """The 2D equations (27 points, counted for their twins) are P' of the 3D ones (68 points) at poses where
    the belly, a bogie and the fork sit on the step's edge, moving (damping and friction exercised)."""
    names2, P2 = projection(b2.m.opt)
    names3, P3 = projection(b3.m.opt)
    P = P3.T @ P2                                        # q3 = P q2
    rng = np.random.default_rng(3)
    touched = 0
    for k in range(6):
        q = _pose(b2, x=1.0 + rng.uniform(-0.25, 0.25), z=0.2 + 0.08 * rng.uniform(-0.6, 0.6),
                  pitch=rng.uniform(-0.3, 0.3), theta1=rng.uniform(-0.3, 0.3))
        u = rng.uniform(-0.5, 0.5, b2.n)
        inp2 = b2.m.default_inp(mu=0.7, **STEP)
        inp3 = b3.m.default_inp(mu=0.7, **STEP)
        par2, par3 = b2.m.default_par(), b3.m.default_par()
        f2, _ = b2.f(q, u, inp2, par2)
        f3, _ = b3.f(P @ q, P @ u, inp3, par3)
        np.testing.assert_allclose(f2, P.T @ f3, rtol=0, atol=1e-9 * max(1, np.max(np.abs(f2))))
        y2, y3 = b2.out(q, u, inp2, par2), b3.out(P @ q, P @ u, inp3, par3)
        for nm in ("chassis.Fn", "chassis.clearance", "energy.potential"):
            assert abs(y2[nm] - y3[nm]) <= 1e-9 * max(1, abs(y2[nm])), nm
        touched += y2["chassis.Fn"] > 1
    assert touched >= 3


def test_chassis_forces_are_the_potential_gradient_3d():
    """At rest on flat ground without damping, the chassis points' generalized forces are -dV/dq of their
    springs (0.5 k delta^2 per point), by central differences, at a rolled and pitched pose."""
    with_ = Built(ModelOptions(dims="3d", terrain="flat", chassis=True))
    without = Built(ModelOptions(dims="3d", terrain="flat"))
    m = with_.m
    par = m.default_par(ground_d=0.0)
    inp = m.default_inp(mu=0.0)
    q = _pose(with_, z=0.15, pitch=0.2, roll=0.25, theta1=0.2, theta2=-0.1)
    u = np.zeros(with_.n)
    f_ch = with_.f(q, u, inp, par)[0] - without.f(q, u, without.m.default_inp(mu=0.0),
                                                  without.m.default_par(ground_d=0.0))[0]
    V = ca.Function("V", [m.q, m.par], [sum(c["weight"] * ca.if_else(c["depth"] > 0, 0.5 * m.p["ground_k"] *
                                                                       c["depth"] ** 2, 0) for c in m.chassis)])
    assert float(V(q, par)) > 1.0
    h = 1e-7
    grad = np.array([(float(V(q + h * e, par)) - float(V(q - h * e, par))) / (2 * h) for e in np.eye(with_.n)])
    np.testing.assert_allclose(f_ch, -grad, rtol=0, atol=1e-5 * np.max(np.abs(grad)))


def test_energy_conserved_through_a_belly_landing(flat2):
    """mu = 0 and no damping anywhere: the rover thrown down onto soft flat ground (ground_k 1000 N/m, so the
    wheels sink far enough for the bogies, the fork and the belly to land) keeps K + V constant, V with the
    chassis springs."""
    b, m = flat2, flat2.m
    par = m.default_par(ground_k=1000.0, ground_d=0.0, fork_d=0.0, stop_d=0.0)
    inp = m.default_inp(mu=0.0)
    q = b.settle(inp, par)
    u = np.zeros(b.n)
    u[b.names.index("z")] = -1.0
    u[b.names.index("pitch")] = 2.0
    E = ca.Function("E", [m.q, m.u, m.inp, m.par], [m.kane.kinetic_energy(), m.potential])
    Fch = ca.Function("F", [m.q, m.u, m.inp, m.par], [sum(c["weight"] * c["Fn"] for c in m.chassis)])
    t, X = b.integrate(q, u, inp, par, 0.5, 250)
    TV = np.array([np.array(E(X[:b.n, k], X[b.n:, k], inp, par)).ravel() for k in range(X.shape[1])])
    Fc = np.array([float(Fch(X[:b.n, k], X[b.n:, k], inp, par)) for k in range(X.shape[1])])
    print(f"peak chassis force {Fc.max():.1f} N, K max {TV[:, 0].max():.3f} J, drift {np.max(np.abs(TV.sum(axis=1) - TV.sum(axis=1)[0])):.2e} J")
    assert Fc.max() > 20                                  # the chassis really carried part of the landing
    Etot = TV.sum(axis=1)
    drift = np.max(np.abs(Etot - Etot[0]))
    assert TV[:, 0].max() > 1.0
    assert drift < 1e-6 * TV[:, 0].max(), drift


@pytest.mark.parametrize("extra, key, reason", [
    ('chassis = 1', "chassis", "expected true or false"),
])
def test_scene_file_checks(extra, key, reason):
    import tomllib
    text = f'name = "s"\ndims = "2d"\nterrain = "step"\n{extra}\n'
    with pytest.raises(SceneError) as e:
        parse(tomllib.loads(text), "s.toml")
    assert f"s.toml: key '{key}'" in str(e.value) and reason in str(e.value)
