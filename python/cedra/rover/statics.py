"""Quasi-static force balance of CEDRA at a measured pose (docs/model.md, Controller, mode 2).

What a rover can measure (body pitch and roll, bogie and fork angles, steering angles, the contact angles psi_i in
the rover frame) fixes the geometry; the balance then relates the contact forces to gravity, the fork spring and
the joint stops. Per wheel the contact force acts at the rim point below the center along the contact normal
(kinematics.contact_frame at psi_i): F_i = N_i z_Ci + T_i x_Ci (+ L_i y_Ci in 3D). The wheel itself is
quasi-static, so its motor torque is tau_i = R_w T_i (moment balance about the axle).

The equations are the generalized forces along the free coordinates, by virtual work (Kane's partial velocities
of mechanism.describe, the same bodies and joints the plant is built from): the body's 6 pose coordinates (2D:
x, z, pitch) and the passive joints theta1, theta2, theta4 (2D: theta1 = theta2). The steering joints are held by
their servos and the spin coordinates carry tau_i = R_w T_i, so neither gives an equation. One more unknown, the
acceleration `a` of the rover along its heading (a d'Alembert force -m_k a on every mass), lets the wheels push
more or less than what holds the rover still: the tractions set `a`, the rest of the balance sets the loads.

    A(pose) u = b(pose),   u = (N, T, L, a) per wheel group

2D: wheels 1, 3 and 2, 4 are pairs (one group each, the same force on both wheels), no lateral forces; 5
equations, 9 unknowns. 3D: 9 equations, 19 unknowns. Given the tractions T, the loads follow: in 2D uniquely, in
3D the lateral forces are not determined by the balance (the rover can squeeze its wheels sideways) and the
smallest ones (least squares) are taken. Everything is CasADi expressions, so the controller FMU's C has it.
"""
from __future__ import annotations

from functools import lru_cache

import casadi as ca

from cedra.mechanics.statics import equal_ratio_tractions, loads_given_tractions, with_body_work
from cedra.mechanics.transforms import rot_x, rot_y, rot_z
from cedra.rover.kinematics import contact_frame
from cedra.rover.mechanism import FULL_Q, IDX, describe
from cedra.rover.parameters import DEFAULTS

# the parameters the balance depends on (the rest of describe's, inertias and dampers, do not enter a statics)
STATICS_PARAMS = ("R_w", "bogie_x", "bogie_y", "bogie_z", "bogie_half", "rear_x", "rear_z", "fork_ax", "fork_az",
                  "fork_bx", "fork_bz", "fork_a", "fork_b", "fork_c", "fork_wheel", "fork_mass_at",
                  "fork_theta4_ref", "fork_k", "bogie_stop", "fork_stop_lo", "fork_stop_hi", "stop_k", "m_B",
                  "m_F", "m_w", "g")
GROUPS = {"2d": (1, 2, 5, 6), "3d": (1, 2, 3, 4, 5, 6)}    # wheel groups: the unknowns' wheels
PAIR = {3: 1, 4: 2}                                         # 2D: wheel 3 carries wheel 1's force, 4 wheel 2's
FREE = {"2d": (("x",), ("z",), ("pitch",), ("theta1", "theta2"), ("theta4",)),
        "3d": tuple((n,) for n in ("x", "y", "z", "yaw", "pitch", "roll", "theta1", "theta2", "theta4"))}


def multiplicity(dims: str) -> list[int]:
    """How many wheels each group stands for (2D: the pairs count twice)."""
    return [2 if dims == "2d" and g in PAIR.values() else 1 for g in GROUPS[dims]]


def pose_symbols(dims: str) -> dict:
    """The measured pose the balance takes: pitch, roll (0 in 2D), theta = (theta1, theta2, theta4),
    steer = (theta3, theta6), psi[6], par (STATICS_PARAMS)."""
    sym = ca.SX.sym
    return dict(pitch=sym("pitch"), roll=sym("roll"), theta=sym("theta", 3), steer=sym("steer", 2),
                psi=sym("psi", 6), par=sym("par", len(STATICS_PARAMS)))


def _unknowns(dims):
    n = len(GROUPS[dims])
    lateral = ca.SX.sym("L", n) if dims == "3d" else ca.SX.zeros(n)
    return ca.SX.sym("N", n), ca.SX.sym("T", n), lateral, ca.SX.sym("a")


def _pose(s: dict, dims: str) -> ca.SX:
    """The full coordinates at the measured pose of pose_symbols (yaw, position and spins 0; 2D: roll 0, the bogies
    together, no steering)."""
    pose = ca.SX.zeros(len(FULL_Q))
    pose[IDX["pitch"]] = s["pitch"]
    pose[IDX["roll"]] = s["roll"] if dims == "3d" else 0
    for n, v in (("theta1", s["theta"][0]), ("theta2", s["theta"][1] if dims == "3d" else s["theta"][0]),
                 ("theta4", s["theta"][2]), ("theta3", s["steer"][0] if dims == "3d" else 0),
                 ("theta6", s["steer"][1] if dims == "3d" else 0)):
        pose[IDX[n]] = v
    return pose


@lru_cache(maxsize=None)
def _balance_function(dims: str) -> ca.Function:
    """(pitch, roll, theta, steer, psi, par) -> (A, b) with A u = b, u = (N, T, L (3D), a)."""
    s = pose_symbols(dims)
    p = dict(DEFAULTS)
    p.update({n: s["par"][k] for k, n in enumerate(STATICS_PARAMS)})
    q, qd = ca.SX.sym("q", len(FULL_Q)), ca.SX.sym("qd", len(FULL_Q))
    rover = describe(q, lambda e: ca.jtimes(e, q, qd), p, ca.SX.zeros(6), None)
    N, T, L, a = _unknowns(dims)
    group = {g: k for k, g in enumerate(GROUPS[dims])}
    R = rot_z(q[IDX["yaw"]]) @ rot_y(q[IDX["pitch"]]) @ rot_x(q[IDX["roll"]])
    joints = ca.vertcat(*(q[IDX[n]] for n in ("theta1", "theta2", "theta4", "theta3", "theta6")))
    force_work = 0                                          # sum of F_i . v_p,i: linear in qd
    for wheel in rover.wheels:
        k = group[PAIR.get(wheel.index, wheel.index) if dims == "2d" else wheel.index]
        frame = R @ contact_frame(wheel.index, joints, s["psi"][wheel.index - 1], p)[0:3, 0:3]
        normal = frame[:, 2]
        point = wheel.center - p["R_w"] * normal
        # the rim's material point at the contact: v_c + omega x (p - c)
        velocity = wheel.velocity + ca.cross(wheel.omega, point - wheel.center)
        force = N[k] * frame[:, 2] + T[k] * frame[:, 0] + L[k] * frame[:, 1]
        force_work += ca.dot(force, velocity)
    work = with_body_work(force_work, rover, q, qd, a, p["g"])
    residual = []
    for names in FREE[dims]:                                # generalized force along each free direction
        direction = ca.DM.zeros(len(FULL_Q))
        for n in names:
            direction[IDX[n]] = 1
        residual.append(ca.substitute(ca.jacobian(work, qd) @ direction, qd, ca.DM.zeros(qd.numel())))
    residual = ca.vertcat(*residual)
    u = ca.vertcat(N, T, L, a) if dims == "3d" else ca.vertcat(N, T, a)
    A = ca.jacobian(residual, u)
    b = -ca.substitute(residual, u, ca.DM.zeros(u.numel()))
    A, b = ca.substitute([A, b], [q], [_pose(s, dims)])
    return ca.Function(f"balance{dims}", [s[k] for k in ("pitch", "roll", "theta", "steer", "psi", "par")],
                       [A, b], ["pitch", "roll", "theta", "steer", "psi", "par"], ["A", "b"])


def balance(dims: str, pitch, roll, theta, steer, psi, par):
    """A, b of the balance A u = b (see the module's docstring) for the measured pose; CasADi in, CasADi out."""
    return _balance_function(dims)(pitch, roll, theta, steer, psi, par)


@lru_cache(maxsize=None)
def traction_function(dims: str, iterations: int) -> ca.Function:
    """Numeric front end (tests, reports): (pitch, roll, theta, steer, psi, par, demand) -> (T, s, N, N0, B) with
    demand the summed wheel torque (N.m): sum_i tau_i = R_w sum_i T_i over all six wheels."""
    s = pose_symbols(dims)
    demand = ca.SX.sym("demand")
    args = [s[k] for k in ("pitch", "roll", "theta", "steer", "psi", "par")]
    A, b = balance(dims, *args)
    N0, B, _, _ = loads_given_tractions(A, b, len(GROUPS[dims]), dims == "3d")
    weights = s["par"][STATICS_PARAMS.index("R_w")] * ca.DM(multiplicity(dims))
    T, ratio, N = equal_ratio_tractions(N0, B, weights, demand, iterations)
    return ca.Function(f"traction{dims}", args + [demand], [T, ratio, N, N0, B],
                       ["pitch", "roll", "theta", "steer", "psi", "par", "demand"], ["T", "s", "N", "N0", "B"])


@lru_cache(maxsize=None)
def _rolling_function(dims: str) -> ca.Function:
    """(pitch, roll, theta, steer, psi, par, velocity, omega, theta_dot) -> the six wheels' rolling rates."""
    s = pose_symbols(dims)
    velocity, omega, theta_dot = ca.SX.sym("velocity", 3), ca.SX.sym("omega", 3), ca.SX.sym("theta_dot", 3)
    p = dict(DEFAULTS)
    p.update({n: s["par"][k] for k, n in enumerate(STATICS_PARAMS)})
    q, qd = ca.SX.sym("q", len(FULL_Q)), ca.SX.sym("qd", len(FULL_Q))
    rover = describe(q, lambda e: ca.jtimes(e, q, qd), p, ca.SX.zeros(6), None)
    R = rot_z(q[IDX["yaw"]]) @ rot_y(q[IDX["pitch"]]) @ rot_x(q[IDX["roll"]])
    joints = ca.vertcat(*(q[IDX[n]] for n in ("theta1", "theta2", "theta4", "theta3", "theta6")))
    spins = [IDX[f"gamma{i}"] for i in range(1, 7)]
    rates = []
    for wheel in rover.wheels:
        frame = R @ contact_frame(wheel.index, joints, s["psi"][wheel.index - 1], p)[0:3, 0:3]
        point = wheel.center - p["R_w"] * frame[:, 2]
        # the rim point at the contact slides along x_C at this speed: affine in the wheel's own spin rate
        sliding = ca.dot(wheel.velocity + ca.cross(wheel.omega, point - wheel.center), frame[:, 0])
        spin = qd[spins[wheel.index - 1]]
        rates.append(-ca.substitute(sliding, spin, 0) / ca.jacobian(sliding, spin))
    rates = ca.substitute(ca.vertcat(*rates), qd[spins], ca.DM.zeros(6))
    # the measured angular velocity gives the Euler rates: body_omega is linear in them
    euler = [IDX[n] for n in ("yaw", "pitch", "roll")]
    euler_rates = ca.solve(ca.jacobian(rover.body_omega, qd[euler]), omega)
    rate_values = ca.SX.zeros(len(FULL_Q))
    for k, n in enumerate(("x", "y", "z")):
        rate_values[IDX[n]] = velocity[k]
    for k, n in enumerate(euler):
        rate_values[n] = euler_rates[k]
    rate_values[IDX["theta1"]] = theta_dot[0]
    rate_values[IDX["theta2"]] = theta_dot[1] if dims == "3d" else theta_dot[0]
    rate_values[IDX["theta4"]] = theta_dot[2]
    rates = ca.substitute([ca.substitute(rates, qd, rate_values)], [q], [_pose(s, dims)])[0]
    names = ["pitch", "roll", "theta", "steer", "psi", "par", "velocity", "omega", "theta_dot"]
    return ca.Function(f"rolling{dims}", [s[k] for k in names[:6]] + [velocity, omega, theta_dot], [rates],
                       names, ["rates"])


def rolling_rates(dims: str, pitch, roll, theta, steer, psi, par, velocity, omega, theta_dot):
    """The spin rate at which each wheel's rim point at its contact (contact angle psi_i) does not slide along
    the contact tangent x_C, given the measured motion: the body's mass-center velocity and angular velocity
    (world axes turned by the measured yaw: the pose is taken at yaw = 0) and the joint rates theta_dot (steering
    rates taken as zero, as in the kinematics). A wheel in contact turns at this rate up to its slip; a wheel in
    the air must turn at it when it lands or it lands sliding. CasADi in, CasADi out."""
    return _rolling_function(dims)(pitch, roll, theta, steer, psi, par, velocity, omega, theta_dot)
