"""Geometry and kinematics of the CEDRA model against docs/model.md, computed independently where
possible: design pose, four-bar closure, assembly check, and symbolic velocities vs finite differences."""
import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import CedraModel, ModelOptions
from cedra.rover.parameters import DEFAULTS
from cedra.rover.mechanism import four_bar
from cedra.mechanics.transforms import rot_x, rot_y, rot_z

D = DEFAULTS


@pytest.fixture(scope="module")
def m2():
    return CedraModel(ModelOptions(dims="2d", terrain="flat"))


@pytest.fixture(scope="module")
def m3():
    return CedraModel(ModelOptions(dims="3d", terrain="flat", steering=True))


def _fn(m, exprs, with_u=False):
    args = [m.q, m.u, m.par] if with_u else [m.q, m.par]
    return ca.Function("f", args, [ca.vertcat(*[ca.vec(e) for e in exprs])])


def _theta5_numpy(theta4, p=D):
    """The mechanism (docs/model.md), written out with numpy (no transforms): theta5 of the four-bar."""
    A = np.array([p["fork_ax"], 0, p["fork_az"]])
    B = np.array([p["fork_bx"], 0, p["fork_bz"]])
    C = A + p["fork_a"] * np.array([np.cos(theta4), 0, np.sin(theta4)])
    d = C - B
    dn = np.linalg.norm(d)
    K = (p["fork_b"] ** 2 - d @ d - p["fork_c"] ** 2) / (2 * p["fork_c"])
    return C, np.arctan2(d[2], d[0]) + np.arccos(K / dn)


# ---------------------------------------------------------------- design pose
@pytest.mark.parametrize("which", ["m2", "m3"])
def test_design_pose(which, request):
    m = request.getfixturevalue(which)
    spec = m.spec("design")
    q = np.array(spec.q_start)
    par = m.default_par()
    centers = np.array(_fn(m, [w.center for w in m.rover.wheels])(q, par)).reshape(6, 3)
    assert [w.index for w in m.rover.wheels] == [1, 2, 3, 4, 5, 6]
    np.testing.assert_allclose(centers[:, 2], D["R_w"], rtol=0, atol=1e-12)
    body = np.array(_fn(m, [m.rover.bodies[0].position])(q, par)).ravel()
    assert abs(body[2] - 0.20) < 1e-12
    # wheel centers where docs/model.md puts them (x in the body frame = world frame in the design pose)
    xs = [D["bogie_x"] + D["bogie_half"], D["bogie_x"] - D["bogie_half"]] * 2 + [D["rear_x"], 0.30]
    ys = [D["bogie_y"], D["bogie_y"], -D["bogie_y"], -D["bogie_y"], 0, 0]
    np.testing.assert_allclose(centers[:, 0], xs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(centers[:, 1], ys, rtol=0, atol=1e-12)
    # the coupler points straight up in the design pose (theta5 = pi/2 with the model's numbers)
    th5 = float(_fn(m, [m.rover.theta5])(q, par))
    assert abs(th5 - np.pi / 2) < 1e-12
    # the same numbers through the contract's output function
    fns = m.functions()
    y = np.array(fns["cedra_out"](q, np.zeros(len(q)), 0, m.default_inp(), par)).ravel()
    names = [o.name for o in spec.outputs]
    for i in range(1, 7):
        assert abs(y[names.index(f"wheel[{i}].cz")] - D["R_w"]) < 1e-12
        assert abs(y[names.index(f"wheel[{i}].pz")]) < 1e-12          # the contact point is on the ground
    assert abs(y[names.index("body.z")] - 0.20) < 1e-12
    assert abs(y[names.index("fork.theta5")] - np.pi / 2) < 1e-12


# ---------------------------------------------------------------- four-bar
def test_four_bar_closure_over_fork_range():
    th4 = ca.SX.sym("th4")
    C, theta5, closure = four_bar(th4, D)
    f = ca.Function("fb", [th4], [C, theta5, closure])
    A = np.array([D["fork_ax"], 0, D["fork_az"]])
    B = np.array([D["fork_bx"], 0, D["fork_bz"]])
    for t in np.linspace(D["fork_stop_lo"], D["fork_stop_hi"], 57):
        Cn, t5, cl = (np.array(v).ravel() for v in f(t))
        t5 = float(t5[0])
        assert abs(cl[0]) < 1, t
        # lower link: C = A + fork_a e(theta4)
        np.testing.assert_allclose(Cn, A + D["fork_a"] * np.array([np.cos(t), 0, np.sin(t)]), rtol=0, atol=1e-14)
        Dn = Cn + D["fork_c"] * np.array([np.cos(t5), 0, np.sin(t5)])
        assert abs(np.linalg.norm(Dn - B) - D["fork_b"]) < 1e-12, t
        # the branch that keeps the coupler pointing up (D above C)
        assert Dn[2] > Cn[2]
        assert abs(t5 - _theta5_numpy(t)[1]) < 1e-12


def test_assembly_check(m3):
    fns = m3.functions()
    par, inp = m3.default_par(), m3.default_inp()
    n = len(m3.q_names)
    i4 = m3.q_names.index("theta4")
    th5 = _fn(m3, [m3.rover.theta5])
    q = np.array(m3.spec("x").q_start)
    for t in np.linspace(D["fork_stop_lo"], D["fork_stop_hi"], 15):
        q[i4] = t
        assert float(fns["cedra_check"](q, np.zeros(n), inp, par)) == 1
        assert np.isfinite(float(th5(q, par)))
    for t in (-1.5, -2.0, -1.0):          # beyond the toggle (|K| > |d| for theta4 below about -0.95)
        q[i4] = t
        assert float(fns["cedra_check"](q, np.zeros(n), inp, par)) == -1, t   # spec.CHECK_REASONS
        assert np.isnan(float(th5(q, par))), t
    q = np.array(m3.spec("x").q_start)
    for name, angle, code in (("pitch", 1.39, 1), ("pitch", -1.41, -2), ("roll", 1.41, -2), ("roll", -1.39, 1)):
        qq = q.copy()
        qq[m3.q_names.index(name)] = angle     # tipped over beyond 80 deg: outside the model's domain
        assert float(fns["cedra_check"](qq, np.zeros(n), inp, par)) == code, (name, angle)


# ---------------------------------------------------------------- velocities vs finite differences
def _random_states(m, rng, k):
    n = len(m.q_names)
    out = []
    for _ in range(k):
        q = rng.uniform(-0.4, 0.4, n)
        q[m.q_names.index("z")] = 0.2 + rng.uniform(-0.05, 0.05)
        q[m.q_names.index("theta4")] = D["fork_theta4_ref"] + rng.uniform(-0.4, 0.4)
        for g in range(1, 7):
            q[m.q_names.index(f"gamma{g}")] = rng.uniform(-3, 3)
        out.append((q, rng.uniform(-1, 1, n)))
    return out


def test_linear_velocities_fd(m3):
    rng = np.random.default_rng(7)
    par = m3.default_par()
    points = [w.center for w in m3.rover.wheels] + [b.position for b in m3.rover.bodies[:2]]
    vels = [w.velocity for w in m3.rover.wheels] + [m3.rate(b.position) for b in m3.rover.bodies[:2]]
    # the body's own velocity output and the Kane machinery's velocity (jtimes) are the same thing
    vels[-2] = m3.rover.body_velocity
    pos = _fn(m3, points)
    vel = _fn(m3, vels, with_u=True)
    h = 1e-5
    for q, u in _random_states(m3, rng, 6):
        fd = (np.array(pos(q + h * u, par)) - np.array(pos(q - h * u, par))).ravel() / (2 * h)
        v = np.array(vel(q, u, par)).ravel()
        np.testing.assert_allclose(v, fd, rtol=0, atol=1e-7)
        assert np.max(np.abs(v)) > 0.1          # not trivially zero


def _rotations_numpy(qd, names):
    """World rotation matrices of the body, the fork coupler and the six wheels, built from docs/model.md's words
    (Euler ZYX body; bogies rotate about -y; wheel spin about +y; rear steer about body z; coupler about -y by
    theta5; front steer about the coupler's x axis s), with theta5 computed by numpy."""
    v = dict(zip(names, qd))
    R = np.array(rot_z(v["yaw"]) @ rot_y(v["pitch"]) @ rot_x(v["roll"]), dtype=float)
    Ry = lambda a: np.array(rot_y(a), dtype=float)
    Rx = lambda a: np.array(rot_x(a), dtype=float)
    Rz = lambda a: np.array(rot_z(a), dtype=float)
    _, t5 = _theta5_numpy(v["theta4"])
    coupler = R @ Ry(-t5)
    wheels = [R @ Ry(-v["theta1"]) @ Ry(v["gamma1"]), R @ Ry(-v["theta1"]) @ Ry(v["gamma2"]),
              R @ Ry(-v["theta2"]) @ Ry(v["gamma3"]), R @ Ry(-v["theta2"]) @ Ry(v["gamma4"]),
              R @ Rz(v["theta3"]) @ Ry(v["gamma5"]), coupler @ Rx(v["theta6"]) @ Ry(v["gamma6"])]
    return [R, coupler] + wheels


def test_angular_velocities_fd(m3):
    rng = np.random.default_rng(11)
    par = m3.default_par()
    omegas = [m3.rover.body_omega, m3.rover.bodies[1].omega] + [w.omega for w in m3.rover.wheels]
    om = _fn(m3, omegas, with_u=True)
    axles = _fn(m3, [w.axle for w in m3.rover.wheels])
    h = 1e-5
    for q, u in _random_states(m3, rng, 6):
        w = np.array(om(q, u, par)).reshape(8, 3)
        Rp, Rm, R0 = (_rotations_numpy(x, m3.q_names) for x in (q + h * u, q - h * u, q))
        for k in range(8):
            W = (Rp[k] - Rm[k]) / (2 * h) @ R0[k].T
            np.testing.assert_allclose(W, -W.T, atol=1e-7)
            np.testing.assert_allclose(w[k], [W[2, 1], W[0, 2], W[1, 0]], rtol=0, atol=1e-7, err_msg=str(k))
        # the wheel axles are the y axes of those frames
        a = np.array(axles(q, par)).reshape(6, 3)
        for k in range(6):
            np.testing.assert_allclose(a[k], R0[2 + k][:, 1], atol=1e-12)
