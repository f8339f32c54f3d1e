"""Wheel kinematics (paper Eqs. 5-22, docs/model.md, Kinematics): Jacobians against finite differences of the transform
chains, the inverse solution against a forward rigid-body check, Eq. 11 against the closed forms of Eq. 13, and
the geometric steering angles against the turn center."""
import numpy as np
import pytest

from cedra.rover import kinematics as kin
from cedra.rover.parameters import DEFAULTS

D = DEFAULTS
RNG = np.random.default_rng(7)


def _random_pose():
    q = np.array([RNG.uniform(-0.4, 0.4), RNG.uniform(-0.4, 0.4), D["fork_theta4_ref"] + RNG.uniform(-0.3, 0.3),
                  RNG.uniform(-0.5, 0.5), RNG.uniform(-0.5, 0.5)])
    return q, RNG.uniform(-0.4, 0.4), RNG.uniform(-0.3, 0.3)


@pytest.mark.parametrize("i", range(1, 7))
def test_jacobian_matches_finite_differences_of_the_chain(i):
    """(d) Each column of J_i is minus the twist of M_i in R, -(dT/dq_k) T^-1, by central differences."""
    jfun, tfun = kin.wheel_jacobian(i), kin.chain(i)
    for _ in range(3):
        q, psi, xi = _random_pose()
        jac = np.array(jfun(q, psi, xi))
        assert jac.shape == (6, len(kin.rate_names(i)))
        base = dict(q=q, psi=psi, xi=xi, gamma=0.0)
        t_inv = np.linalg.inv(np.array(tfun(q, psi, xi, 0.0)))
        names = list(kin.CARRIER[i]) + ["gamma", "xi", "psi"]
        h = 1e-6
        for k, name in enumerate(names):
            args = []
            for sgn in (1, -1):
                a = {key: (np.array(v, dtype=float).copy() if key == "q" else v) for key, v in base.items()}
                if name in kin.JOINTS:
                    a["q"][kin.JOINTS.index(name)] += sgn * h
                else:
                    a[name] += sgn * h
                args.append(np.array(tfun(a["q"], a["psi"], a["xi"], a["gamma"])))
            x = -(args[0] - args[1]) / (2 * h) @ t_inv
            col = np.array([x[0, 3], x[1, 3], x[2, 3], x[1, 0], x[0, 2], x[2, 1]])
            np.testing.assert_allclose(jac[:, k], col, atol=1e-7, rtol=0, err_msg=f"wheel {i}, {name}")


def _random_inputs():
    return dict(xdot_d=RNG.uniform(-0.5, 0.5), phidot_d=RNG.uniform(-0.8, 0.8),
                theta=[RNG.uniform(-0.4, 0.4), RNG.uniform(-0.4, 0.4), D["fork_theta4_ref"] + RNG.uniform(-0.3, 0.3)],
                theta_dot=RNG.uniform(-1, 1, 3), psi=RNG.uniform(-0.4, 0.4, 6), psi_dot=RNG.uniform(-1, 1, 6),
                xi=RNG.uniform(-0.3, 0.3, 6), steer=RNG.uniform(-0.5, 0.5, 2))


def test_eq11_numeric_equals_eq13_closed_form():
    """(c) The actuated inverse solution with the Jacobians equals the closed forms at random inputs."""
    for _ in range(20):
        args = _random_inputs()
        np.testing.assert_allclose(kin.wheel_rates(**args), kin.wheel_rates_numeric(**args), atol=1e-9, rtol=0)


LEVEL = [0.0, 0.0, D["fork_theta4_ref"]]
ZERO3, ZERO6 = np.zeros(3), np.zeros(6)
MOTIONS = [(0.2, 0.5), (0.2, -0.5), (-0.3, 0.8), (0.1, -1.5), (0.25, 0.0)]


def _contact(i, psi, theta=LEVEL, steer=(0.0, 0.0)):
    """Contact point, rolling direction x_C, axle y_C and normal z_C of wheel i in R, from the chain at xi = 0."""
    t = np.array(kin.chain(i)(np.r_[theta, steer], psi, 0.0, 0.0))
    return t[:3, 3], t[:3, 0], t[:3, 1], t[:3, 2]


@pytest.mark.parametrize("psi", [0.0, 0.25, -0.3])
@pytest.mark.parametrize("xdot_d, phidot_d", MOTIONS)
def test_inverse_reproduces_rigid_body_motion(psi, xdot_d, phidot_d):
    """(a) The rover slides along the (possibly inclined, psi_i all equal) ground with forward speed xdot_d and
    yaw rate phidot_d: v tangent to the ground with v_x = xdot_d, w along the ground normal with w_z = phidot_d.
    Each bogie wheel's contact point then moves at v + w x r; R_w gammadot_i is its rolling-direction component."""
    rates = kin.wheel_rates(xdot_d, phidot_d, LEVEL, ZERO3, np.full(6, psi), ZERO6, ZERO6, (0.0, 0.0))
    for i in range(1, 5):
        r, x_c, y_c, z_c = _contact(i, psi)
        v = np.array([xdot_d, 0.0, -xdot_d * z_c[0] / z_c[2]])           # v . z_C = 0, v_y = 0
        w = phidot_d / z_c[2] * z_c
        assert abs(v @ z_c) < 1e-12
        assert abs(D["R_w"] * rates[i - 1] - (v + np.cross(w, r)) @ x_c) < 1e-9, i


def _line_distance(point, through, direction):
    """Distance in R's x-y plane from point to the line through `through` along `direction` (projected)."""
    d = direction[:2] / np.linalg.norm(direction[:2])
    e = point[:2] - through[:2]
    return abs(e[0] * d[1] - e[1] * d[0])


def _random_config():
    return dict(theta=[RNG.uniform(-0.3, 0.3), RNG.uniform(-0.3, 0.3), D["fork_theta4_ref"] + RNG.uniform(-0.2, 0.2)],
                theta_dot=RNG.uniform(-0.5, 0.5, 3), psi=RNG.uniform(-0.3, 0.3, 6), psi_dot=RNG.uniform(-0.5, 0.5, 6))


@pytest.mark.parametrize("xdot_d, phidot_d", [m for m in MOTIONS if m[1] != 0])
def test_steered_axles_pass_through_the_turn_center(xdot_d, phidot_d):
    """(b) Level rover on flat ground, left and right turns: the turn center lies at y = xdot_d / phidot_d on the
    bogies' mean axle (the line through the pivots; the four bogie axles are parallel lines at distinct x, so no
    point lies on all of them: each fixed wheel's own center c_i lies on its own axle), and the axles of the
    steered wheels 5 and 6 pass through it. Also at random poses, rates and contact angles for wheels 5 and 6."""
    centers, center = kin.turn_centers(xdot_d, phidot_d, LEVEL, ZERO3, ZERO6, ZERO6)
    assert abs(center[1] - xdot_d / phidot_d) < 1e-9
    assert _line_distance(center, np.array([D["bogie_x"], 0, 0]), np.array([0, 1.0, 0])) < 1e-9
    for i in range(1, 5):
        r, _, y_c, z_c = _contact(i, 0.0)
        assert _line_distance(centers[i - 1], r + D["R_w"] * z_c, y_c) < 1e-9
    th3, th6 = kin.steering_angles(xdot_d, phidot_d, LEVEL, ZERO3, ZERO6, ZERO6)
    assert np.sign(th3) == -np.sign(phidot_d * xdot_d) and np.sign(th6) == np.sign(phidot_d * xdot_d)
    configs = [dict(theta=LEVEL, theta_dot=ZERO3, psi=ZERO6, psi_dot=ZERO6)] + [_random_config() for _ in range(5)]
    for cfg in configs:
        _, center = kin.turn_centers(xdot_d, phidot_d, **cfg)
        steer = kin.steering_angles(xdot_d, phidot_d, **cfg)
        for i in (5, 6):
            r, _, y_c, z_c = _contact(i, cfg["psi"][i - 1], cfg["theta"], steer)
            assert _line_distance(center, r + D["R_w"] * z_c, y_c) < 1e-9, (i, cfg)


def test_straight_means_zero_steering():
    assert kin.steering_angles(0.3, 0.0, LEVEL, ZERO3, ZERO6, ZERO6) == (0.0, 0.0)
    assert kin.steering_angles(0.3, 0.0, **_random_config()) == (0.0, 0.0)


@pytest.mark.parametrize("xdot_d, phidot_d", [m for m in MOTIONS if m[1] != 0])
def test_steered_wheels_roll_without_side_slip_about_the_turn_center(xdot_d, phidot_d):
    """Flat ground, level rover turning rigidly about the estimated turn center (v = w x (0 - center)): the
    steered wheels' contact points move along their rolling directions, at R_w gammadot from the inverse solution."""
    _, center = kin.turn_centers(xdot_d, phidot_d, LEVEL, ZERO3, ZERO6, ZERO6)
    steer = kin.steering_angles(xdot_d, phidot_d, LEVEL, ZERO3, ZERO6, ZERO6)
    rates = kin.wheel_rates(xdot_d, phidot_d, LEVEL, ZERO3, ZERO6, ZERO6, ZERO6, steer)
    w = np.array([0, 0, phidot_d])
    v = np.cross(w, -np.r_[center[:2], 0.0])
    assert abs(v[0] - xdot_d) < 1e-12
    for i in (5, 6):
        r, x_c, y_c, _ = _contact(i, 0.0, LEVEL, steer)
        vc = v + np.cross(w, r)
        assert abs(vc @ y_c) < 1e-9, i
        assert abs(D["R_w"] * rates[i - 1] - vc @ x_c) < 1e-9, i
