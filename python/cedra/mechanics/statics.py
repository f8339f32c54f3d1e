"""Quasi-static force balance and rolling rates of any rover at a measured pose (docs/model.md, Controller, traction
control), from the rover's own description (`RoverKind.describe`: the same CasADi graph the plant is built from).

The measured pose is the body's pitch and roll, the rover's measured joints (the joints of
cedra.mechanics.drive_kinematics: its joint outputs) and the contact angles psi_i. Per wheel the contact force acts
at the rim point below the center along the contact normal at psi_i, n_i = cos(psi_i) u_i + sin(psi_i) a_i x u_i
(u_i the wheel's `up`, a_i its axle; drive_kinematics' contact frame): F_i = N_i n_i + T_i x_i (+ L_i a_i in 3D)
with the tangent x_i = a_i x n_i. The wheel is quasi-static, so its motor torque is tau_i = R_w T_i.

The equations are the generalized forces along the free directions, by virtual work (Kane's partial velocities of
the description): the scene's coordinates minus the spins and the steering joints (held by their servos), a
coordinate the planar map merges others into moving them together (2D: x, z, pitch and the joints the map keeps).
On them act the contact forces, gravity, the joints' own torques at zero rates (springs, stops) and a d'Alembert
force -m_k a along the heading on every mass (the acceleration a is one more unknown: the tractions set it, the
rest of the balance sets the loads):

    A(pose) u = b(pose),   u = (N, T, L (3D), a) per wheel group

A wheel group is a wheel whose spin the scene keeps and the wheels whose spins the planar map merges into it (2D:
left and right twins carry one force each); in 3D every wheel is its own group. `cedra.rover.statics` is CEDRA's
own form of the same balance (its contact frames from the paper's kinematics); formed from CEDRA's description
this module gives the same A and b.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from cedra.mechanics.drive_kinematics import _scene_coordinates, drive_kinematics
from cedra.mechanics.rover_kind import SPINS, RoverKind

_FORMED: dict[tuple[str, str], "RoverStatics"] = {}
BALANCE_ARGS = ("pitch", "roll", "joints", "psi", "par")
ROLLING_ARGS = BALANCE_ARGS + ("velocity", "omega", "joint_rates")


@dataclass(frozen=True)
class RoverStatics:
    """A rover's quasi-static balance and rolling rates for one scene dimension.

    balance(pitch, roll, joints, psi[6], par) -> (A, b);
    rolling(pitch, roll, joints, psi[6], par, velocity[3], omega[3], joint_rates) -> rates[6]
    (2D: roll is not used)."""
    rover: str
    dims: str
    joints: tuple[str, ...]         # the measured joint coordinates, in the order of `joints` (drive_kinematics')
    free: tuple[str, ...]           # the scene coordinates the balance's equations are along, in row order
    groups: tuple[int, ...]         # each wheel group's own wheel (the one whose spin the scene keeps)
    group_of: tuple[int, ...]       # wheel 1..6 -> the index of its group
    params: tuple[str, ...]         # the rover's parameters the balance and the rates depend on, in `par` order
    balance: ca.Function
    rolling: ca.Function

    @property
    def multiplicity(self) -> list[int]:
        """How many wheels each group stands for."""
        return [self.group_of.count(g) for g in range(len(self.groups))]


def rover_statics(kind: RoverKind, dims: str) -> RoverStatics:
    """The balance and rolling rates of `kind` in a 2D or 3D scene (see the module's docstring); formed once per
    rover and dimension."""
    key = (kind.name, dims)
    if key not in _FORMED:
        _FORMED[key] = _form(kind, dims)
    return _FORMED[key]


def _wheel_groups(planar: dict) -> tuple[tuple[int, ...], tuple[int, ...]]:
    own = [int(planar.get(s, s)[len("gamma"):]) for s in SPINS]      # the wheel whose spin each wheel's is
    groups = tuple(dict.fromkeys(own))
    return groups, tuple(groups.index(w) for w in own)


def _contact(wheel, psi):
    """The wheel's contact normal and tangent at contact angle psi (drive_kinematics' convention)."""
    normal = ca.cos(psi) * wheel.up + ca.sin(psi) * ca.cross(wheel.axle, wheel.up)
    return normal, ca.cross(wheel.axle, normal)


def _rim_velocity(wheel, normal, radius):
    """The velocity of the rim's material point at the contact: v_c + omega x (p - c)."""
    return wheel.velocity + ca.cross(wheel.omega, -radius * normal)


def _form(kind: RoverKind, dims: str) -> RoverStatics:
    kind.check()
    scene, planar = _scene_coordinates(kind, dims)
    joints = drive_kinematics(kind, dims).joints
    names, idx = kind.coordinates, kind.index
    q, qd = ca.SX.sym("q", len(names)), ca.SX.sym("qd", len(names))
    p = {x.name: ca.SX.sym(x.name) for x in kind.parameters}
    rover = kind.describe(q, lambda e: ca.jtimes(e, q, qd), p, ca.SX.zeros(6), None)
    groups, group_of = _wheel_groups(planar)
    free = tuple(n for n in scene if n not in SPINS and n not in kind.steering)

    sym = ca.SX.sym
    pitch, roll, angles, psi = sym("pitch"), sym("roll"), sym("joints", len(joints)), sym("psi", 6)
    at = {"pitch": pitch, "roll": roll if dims == "3d" else 0}
    at.update({n: angles[k] for k, n in enumerate(joints)})
    # the full coordinates at the measured pose: yaw, position and spins 0, a merged coordinate its keeper's value
    pose = ca.vertcat(*[at.get(planar.get(n, n), 0) if planar.get(n, n) is not None else 0 for n in names])

    A, b = _balance(rover, q, qd, p, psi, names, planar, free, group_of, len(groups), dims == "3d")
    A, b = ca.substitute([A, b], [q], [pose])
    rates = _rolling(rover, kind, q, qd, p, psi, joints, planar)
    velocity, omega, joint_rates = sym("velocity", 3), sym("omega", 3), sym("joint_rates", len(joints))
    rates = ca.substitute(rates, qd, _rate_values(rover, qd, idx, names, planar, joints, kind.steering,
                                                  velocity, omega, joint_rates))
    rates = ca.substitute(rates, q, pose)
    used = [x.name for x in kind.parameters if ca.depends_on(ca.vertcat(ca.vec(A), b, rates), p[x.name])]
    par = sym("par", len(used))
    old, new = ca.vertcat(*[p[n] for n in used]), par
    A, b, rates = ca.substitute([A, b, rates], [old], [new])
    if ca.depends_on(rates, qd) or ca.depends_on(ca.vertcat(ca.vec(A), b), ca.vertcat(q, qd)):
        raise RuntimeError(f"rover {kind.name}: the balance depends on a coordinate or rate left unset")
    args = [pitch, roll, angles, psi, par]
    balance = ca.Function(f"balance_{kind.name}_{dims}", args, [A, b], list(BALANCE_ARGS), ["A", "b"])
    rolling = ca.Function(f"rolling_{kind.name}_{dims}", args + [velocity, omega, joint_rates], [rates],
                          list(ROLLING_ARGS), ["rates"])
    return RoverStatics(kind.name, dims, tuple(joints), free, groups, group_of, tuple(used), balance, rolling)


def _balance(rover, q, qd, p, psi, names, planar, free, group_of, n_groups, lateral):
    """A, b of the balance as expressions of the full coordinates q (module docstring)."""
    N, T = ca.SX.sym("N", n_groups), ca.SX.sym("T", n_groups)
    L = ca.SX.sym("L", n_groups) if lateral else ca.SX.zeros(n_groups)
    a = ca.SX.sym("a")
    force_work = 0                                          # sum of F_i . v_p,i: linear in qd
    for wheel in rover.wheels:
        k = group_of[wheel.index - 1]
        normal, tangent = _contact(wheel, psi[wheel.index - 1])
        force = N[k] * normal + T[k] * tangent + L[k] * wheel.axle
        force_work += ca.dot(force, _rim_velocity(wheel, normal, p["R_w"]))
    work = with_body_work(force_work, rover, q, qd, a, p["g"])
    residual = []
    for coordinate in free:                                 # the generalized force along each free direction
        direction = ca.DM([1.0 if planar.get(n, n) == coordinate else 0.0 for n in names])
        residual.append(ca.substitute(ca.jacobian(work, qd) @ direction, qd, ca.DM.zeros(qd.numel())))
    residual = ca.vertcat(*residual)
    u = ca.vertcat(N, T, L, a) if lateral else ca.vertcat(N, T, a)
    return ca.jacobian(residual, u), -ca.substitute(residual, u, ca.DM.zeros(u.numel()))


def with_body_work(force_work, rover, q, qd, a, g):
    """The contact forces' virtual power `force_work` plus that of everything else, linear in the rates qd: the
    d'Alembert force -m a along the heading on every body (the pose is taken at yaw = 0), gravity, and the joints'
    own torques at zero rates (springs, stops). Every rover's balance, CEDRA's own (cedra.rover.statics) too;
    summed in this order, so the generated expressions (and the controllers' GUIDs) are the same for both."""
    heading = ca.DM([1, 0, 0])
    inertial_work = -a * sum(b.mass * ca.dot(heading, ca.jtimes(b.position, q, qd)) for b in rover.bodies)
    gravity_work = -ca.dot(ca.gradient(sum(b.mass * g * b.position[2] for b in rover.bodies), q), qd)
    joint_work = ca.dot(ca.substitute(rover.coordinate_torques, qd, ca.DM.zeros(qd.numel())), qd)
    return force_work + inertial_work + gravity_work + joint_work


def _rolling(rover, kind, q, qd, p, psi, joints, planar):
    """Every wheel's spin rate at which its rim point at the contact does not slide along the contact tangent, as
    expressions of the full coordinates and the other coordinates' rates."""
    spins = [kind.index[s] for s in SPINS]
    rates = []
    for wheel in rover.wheels:
        normal, tangent = _contact(wheel, psi[wheel.index - 1])
        sliding = ca.dot(_rim_velocity(wheel, normal, p["R_w"]), tangent)   # affine in the wheel's own spin rate
        spin = qd[spins[wheel.index - 1]]
        rates.append(-ca.substitute(sliding, spin, 0) / ca.jacobian(sliding, spin))
    return ca.substitute(ca.vertcat(*rates), qd[spins], ca.DM.zeros(len(spins)))


def _rate_values(rover, qd, idx, names, planar, joints, steering, velocity, omega, joint_rates):
    """The full coordinates' rates from the measured motion: the mass center's velocity, the Euler rates of the
    measured angular velocity (body_omega is linear in them), the measured joint rates (a merged joint its
    keeper's, steering 0: the kinematics' convention); spins 0 (the rates solve for them)."""
    euler = [idx[n] for n in ("yaw", "pitch", "roll")]
    euler_rates = ca.solve(ca.jacobian(rover.body_omega, qd[euler]), omega)
    known = {"x": velocity[0], "y": velocity[1], "z": velocity[2], "yaw": euler_rates[0],
             "pitch": euler_rates[1], "roll": euler_rates[2]}
    known.update({n: joint_rates[k] for k, n in enumerate(joints) if n not in steering})
    return ca.vertcat(*[known[n] if n in known else known.get(planar.get(n, n), 0) for n in names])


def loads_given_tractions(A, b, n_groups: int, lateral: bool):
    """The loads as affine functions of the tractions T: (N0, B) with N = N0 + B T, and (a0, a_T) with the
    acceleration a = a0 + a_T T. With lateral forces (3D) the balance does not determine them (the rover can
    squeeze its wheels sideways): the least-squares ones it allows are taken."""
    n = n_groups
    cols_T = list(range(n, 2 * n))
    cols_y = [k for k in range(A.shape[1]) if k not in cols_T]        # N, (L), a
    A_T, A_y = A[:, cols_T], A[:, cols_y]
    rhs = ca.horzcat(b, -A_T)                                          # y = Y[:, 0] + Y[:, 1:] T
    if not lateral:
        Y = ca.solve(A_y, rhs)
    else:
        # min 0.5 |L|^2 subject to A_y y = rhs: its KKT system (N and a are fixed by the balance)
        ny, m = A_y.shape[1], A_y.shape[0]
        w = ca.diag(ca.vertcat(ca.DM.zeros(n), ca.DM.ones(n), ca.DM.zeros(1)))
        kkt = ca.vertcat(ca.horzcat(w, A_y.T), ca.horzcat(A_y, ca.SX.zeros(m, m)))
        Y = ca.solve(kkt, ca.vertcat(ca.SX.zeros(ny, rhs.shape[1]), rhs))[:ny, :]
    return Y[:n, 0], Y[:n, 1:], Y[-1, 0], Y[-1, 1:]


def equal_ratio_tractions(N0, B, weights, demand, iterations: int, ratio_max=None):
    """The tractions T with T_i / N_i(T) = s for every group and sum(weights_i T_i) = demand. N = N0 + B T gives
    T = s (I - s B)^-1 N0, so s is the root of h(s) = s weights' (I - s B)^-1 N0 - demand: a FIXED number of
    Newton steps from s = demand / weights' N0 (the total load changes with the tractions only through the tilted
    contact normals, so h is nearly linear and the start is close). Returns T, s, N.

    ratio_max (None: no bound): the largest ratio whose load transfer the balance is trusted for. The ground
    passes at most its friction coefficient, so a demand that needs a higher common ratio is a stall: the wheels
    slide at mu and carry the loads of tractions at mu, not the loads the balance gives at the impossible ratio
    (there the tractions' own moments move the load off the wheels that climb). Past ratio_max the loads are
    held at N(ratio_max) and the demand is shared in proportion to them (the ratio s grows, the loads do not);
    continuous at s = ratio_max."""
    n = N0.numel()
    eye = ca.DM.eye(n)
    s = demand / ca.dot(weights, N0)
    bound = None if ratio_max is None else ca.sign(demand) * ratio_max
    for _ in range(iterations):
        if bound is not None:                                # the root sought lies within the bound
            s = ca.if_else(ca.fabs(s) > ratio_max, bound, s)
        loads = ca.solve(eye - s * B, N0)                    # N(s)
        slope = ca.solve(eye - s * B, B @ loads)             # dN/ds
        h = s * ca.dot(weights, loads) - demand
        dh = ca.dot(weights, loads) + s * ca.dot(weights, slope)
        s = s - h / dh
    loads = ca.solve(eye - s * B, N0)
    if bound is None:
        return s * loads, s, loads
    held = ca.solve(eye - bound * B, N0)                     # N(ratio_max)
    stalled = ca.fabs(demand) > ratio_max * ca.fabs(ca.dot(weights, held))
    s = ca.if_else(stalled, demand / ca.dot(weights, held), s)
    loads = ca.if_else(stalled, held, loads)
    return s * loads, s, loads
