"""The actuated inverse kinematics of any rover (docs/model.md, The rocker-bogie, Controller): every wheel's rolling
rate for a commanded body speed and yaw rate at the measured pose, joint angles and rates and contact angles,
from the rover's own description (`RoverKind.describe`: the same CasADi graph the plant is built from).

For wheel i (center c_i, axle a_i, the normal u_i of its contact frame at psi = 0, all in the world):

- the contact normal at the measured contact angle psi_i (the plant's `wheel[i].psi_R`: the angle of the normal
  about the axle from u_i) is n_i = cos(psi_i) u_i + sin(psi_i) a_i x u_i, the contact tangent x_i = a_i x n_i and
  the contact point c_i - R_w n_i;
- the coordinate rates are built from the commands and the measurements: the body's mass center moves along the
  heading at the commanded speed v with no sideways velocity, its angular velocity is the measured one about the
  world's X and Y with the commanded yaw rate about Z (ZYX Euler rates solved from it), the joints move at their
  measured rates (steering joints at 0: the kinematics' convention), and the body's vertical velocity is free;
- the wheel center's velocity is its Jacobian with respect to the full coordinates times these rates
  (`Wheel.velocity`); the free vertical velocity is the one that keeps it in the contact plane
  (c_i' . n_i = 0), so each wheel climbs the slope it touches (the paper's Eq. 11 leaves the body's vertical
  motion to each wheel's contact in the same way);
- the wheel's spin rate relative to its carrier is the one at which the rim's material point at the contact does
  not slide along x_i (no slip at the contact): c_i' . x_i + (omega_i x (-R_w n_i)) . x_i = 0, affine in it.

A sideways slide of the contact (a skid-steered rover's wheels in a turn, or lateral slip) is left free, so with a
yaw rate the wheels at lateral offset y from the mass center get v - yaw_rate y along their heading: skid steering.
Nothing here is specific to a rover: a rover gets its inverse kinematics from its description and its joint
outputs (the measured joints are the joint outputs that are a coordinate or a coordinate's rate).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from cedra.mechanics.rover_kind import POSE, SPINS, RoverKind

# the contact normal's vertical component the free vertical velocity divides by is held at this or more: a wheel
# against a wall (psi_R -> 90 deg) would ask for an unbounded rate, this bounds it at 1 / cos(80 deg) = 5.8 times
# the rate on level ground
NORMAL_Z_MIN = float(np.cos(np.radians(80.0)))
_FORMED: dict[tuple[str, str], "DriveKinematics"] = {}
ARGS = ("v", "yaw_rate", "pitch", "roll", "wx", "wy", "joints", "joint_rates", "psi", "par")


@dataclass(frozen=True)
class DriveKinematics:
    """A rover's inverse kinematics for one scene dimension: `function(v, yaw_rate, pitch, roll, wx, wy,
    joints, joint_rates, psi[6], par) -> rates[6]` (2D: yaw_rate, roll and wx are not used)."""
    rover: str
    dims: str
    joints: tuple[str, ...]                 # the measured joint coordinates, in the order of `joints`
    angle_outputs: tuple[str, ...]          # the plant outputs that give them
    rate_outputs: tuple[str | None, ...]    # the plant outputs that give their rates (None: taken as 0)
    params: tuple[str, ...]                 # the rover's parameters the rates depend on, in `par` order
    function: ca.Function


def _scene_coordinates(kind: RoverKind, dims: str) -> tuple[list[str], dict]:
    if dims not in ("2d", "3d"):
        raise ValueError(f"dims must be 2d or 3d, got {dims!r}")
    planar = kind.planar if dims == "2d" else {}
    return [n for n in kind.coordinates if planar.get(n, n) == n], planar


def _measured_joints(kind, scene, q, qd, qf, qdf, description):
    """(coordinate, angle output, rate output or None) for every scene joint, from the rover's joint outputs."""
    outs = kind.joint_outputs(qf, qdf, kind.index, description, bool(kind.steering))
    joints = [n for n in scene if n not in POSE and n not in SPINS]
    found = []
    for n in joints:
        k = scene.index(n)
        angle = next((o.name for o, e in outs if ca.is_equal(e, q[k])), None)
        rate = next((o.name for o, e in outs if ca.is_equal(e, qd[k])), None)
        if angle is None:
            raise ValueError(f"rover {kind.name}: no joint output gives the angle of its joint {n!r} (joint_outputs)")
        if rate is None and n not in kind.steering:
            raise ValueError(f"rover {kind.name}: no joint output gives the rate of its joint {n!r} (joint_outputs)")
        found.append((n, angle, rate))
    return found


def drive_kinematics(kind: RoverKind, dims: str) -> DriveKinematics:
    """The inverse kinematics of `kind` in a 2D or 3D scene (see the module's docstring); formed once per rover
    and dimension."""
    key = (kind.name, dims)
    if key not in _FORMED:
        _FORMED[key] = _form(kind, dims)
    return _FORMED[key]


def _form(kind: RoverKind, dims: str) -> DriveKinematics:
    kind.check()
    scene, planar = _scene_coordinates(kind, dims)
    q, qd = ca.SX.sym("q", len(scene)), ca.SX.sym("qd", len(scene))

    def full(v):
        return ca.vertcat(*[v[scene.index(planar.get(n, n))] if planar.get(n, n) is not None else 0
                            for n in kind.coordinates])

    qf, qdf = full(q), full(qd)
    p = {x.name: ca.SX.sym(x.name) for x in kind.parameters}
    if "R_w" not in p:
        raise ValueError(f"rover {kind.name}: no parameter R_w (the wheel radius)")
    rover = kind.describe(qf, lambda e: ca.jtimes(e, q, qd), p, ca.SX.zeros(6), None)
    joints = _measured_joints(kind, scene, q, qd, qf, qdf, rover)

    sym = ca.SX.sym
    v, yaw_rate, pitch, roll, wx, wy = (sym(n) for n in ARGS[:6])
    angles, rates_in = sym("joints", len(joints)), sym("joint_rates", len(joints))
    psi = sym("psi", 6)
    at = {"pitch": pitch, "roll": roll}
    at.update({n: angles[k] for k, (n, _, _) in enumerate(joints)})
    pose = ca.vertcat(*[at.get(n, 0) for n in scene])       # x, y, z, yaw, spins: 0 (the pose at yaw = 0)

    # the measured and commanded rates: heading speed, no sideways velocity; Euler rates from the angular velocity
    known = {n: 0 for n in scene}
    known["x"] = v
    known.update({n: rates_in[k] if r else 0 for k, (n, _, r) in enumerate(joints)})
    euler = [n for n in ("yaw", "pitch", "roll") if n in scene]
    e_idx = [scene.index(n) for n in euler]
    J = ca.jacobian(rover.body_omega, qd[e_idx])
    euler_rates = ca.solve(J.T @ J, J.T @ ca.vertcat(wx, wy, yaw_rate))    # exact: J has full column rank
    known.update({n: euler_rates[k] for k, n in enumerate(euler)})
    zdot = qd[scene.index("z")]

    out = []
    for wheel in rover.wheels:
        k = wheel.index - 1
        up, axle = wheel.up, wheel.axle
        normal = ca.cos(psi[k]) * up + ca.sin(psi[k]) * ca.cross(axle, up)
        tangent = ca.cross(axle, normal)
        spin = qd[scene.index(planar.get(f"gamma{wheel.index}", f"gamma{wheel.index}"))]
        rates = ca.vertcat(*[spin if ca.is_equal(qd[i], spin) else (zdot if n == "z" else known[n])
                             for i, n in enumerate(scene)])
        center = ca.substitute(wheel.velocity, qd, rates)
        omega = ca.substitute(wheel.omega, qd, rates)
        # the free vertical velocity keeps the center in the contact plane
        into = ca.dot(center, normal)
        climb = -ca.substitute(into, zdot, 0) / ca.fmax(ca.jacobian(into, zdot), NORMAL_Z_MIN)
        sliding = ca.dot(center + ca.cross(omega, -p["R_w"] * normal), tangent)
        sliding = ca.substitute(sliding, zdot, climb)
        out.append(-ca.substitute(sliding, spin, 0) / ca.jacobian(sliding, spin))
    result = ca.substitute(ca.vertcat(*out), q, pose)
    used = [x.name for x in kind.parameters if ca.depends_on(result, p[x.name])]
    par = ca.SX.sym("par", len(used))
    if used:
        result = ca.substitute(result, ca.vertcat(*[p[n] for n in used]), par)
    if ca.depends_on(result, qd):
        raise RuntimeError(f"rover {kind.name}: the wheel rates depend on a rate left unset")
    fun = ca.Function(f"wheel_rates_{kind.name}_{dims}",
                      [v, yaw_rate, pitch, roll, wx, wy, angles, rates_in, psi, par], [result],
                      list(ARGS), ["rates"])
    return DriveKinematics(kind.name, dims, tuple(n for n, _, _ in joints), tuple(a for _, a, _ in joints),
                           tuple(r for _, _, r in joints), tuple(used), fun)
