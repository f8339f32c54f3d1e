"""The CEDRA mechanism (docs/model.md, Mechanism): geometry by transform chains, masses, joint forces.

This module only *describes* the rover: given its generalized coordinates as expressions (the full 17 of
the 3D rover, each written in terms of a scene's own reduced coordinates), it returns bodies, wheels and the
torques acting on coordinates. `CEDRA` is the rover kind the equations are formed from (cedra.mechanics.rover_kind:
the interface; cedra.models.plant forms the equations and chooses the reduced coordinates).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from cedra.contract import Quantity
from cedra.mechanics.contact import sigmoid, softplus
from cedra.mechanics.kane import Body
from cedra.mechanics.rover_kind import CollisionPoint, RoverDescription, RoverKind, Stop, Wheel
from cedra.mechanics.transforms import apply, e_xz, homogeneous, rot_x, rot_y, rot_z, rotation, translation
from cedra.rover import parameters

FULL_Q = ["x", "y", "z", "yaw", "pitch", "roll", "theta1", "theta2", "theta4", "theta3", "theta6",
          "gamma1", "gamma2", "gamma3", "gamma4", "gamma5", "gamma6"]
IDX = {name: i for i, name in enumerate(FULL_Q)}
EY = ca.DM([0, 1, 0])
EZ = ca.DM([0, 0, 1])


# the body's box in frame R: its floor and its front and rear faces (docs/model.md, Chassis and links)
BODY_BOX_X = [-0.30 + 0.04 * k for k in range(13)]      # -0.30 .. 0.18
BODY_BOX_Y = [-0.12, 0.0, 0.12]
BODY_FLOOR_Z = -0.06
BODY_FACE_Z = [-0.02, 0.03, 0.08]


@dataclass
class CedraDescription(RoverDescription):
    theta5: ca.SX               # the four-bar's coupler angle (dependent: four_bar)


def four_bar(theta4, p):
    """Closed-form closure of the front four-bar (docs/model.md, Mechanism): (C, theta5, K/|d|)."""
    A = ca.vertcat(p["fork_ax"], 0, p["fork_az"])
    B = ca.vertcat(p["fork_bx"], 0, p["fork_bz"])
    C = apply(translation(A) @ homogeneous(rot_y(-theta4), ca.DM.zeros(3)), ca.vertcat(p["fork_a"], 0, 0))
    d = C - B
    dn = ca.norm_2(d)
    K = (p["fork_b"] ** 2 - ca.dot(d, d) - p["fork_c"] ** 2) / (2 * p["fork_c"])
    theta5 = ca.atan2(d[2], d[0]) + ca.acos(K / dn)
    return C, theta5, K / dn


def stop_torque(angle, rate, lo, hi, k, d, width=None):
    """Compliant joint stop: -k overshoot - d rate beyond a stop, clipped so it only pushes back out.

    width (rad, a symbol or a number >= 0): the smoothed law the optimizer may integrate instead (never an FMU's),
    the stop's counterpart of contact.compliant_law's: with e the overshoot beyond a stop,
    k softplus_w(e +- (d / k) rate sigmoid(e / w)) pushing back, the clip a softplus and the damping's onset a
    sigmoid over the angle width w; w = 0 is the law above exactly."""
    above = ca.fmin(0, -k * (angle - hi) - d * rate)
    below = ca.fmax(0, -k * (angle - lo) - d * rate)
    law = ca.if_else(angle > hi, above, ca.if_else(angle < lo, below, 0))
    if width is None:
        return law
    w = ca.if_else(width > 0, width, 1)
    over, under = angle - hi, lo - angle
    smooth = -k * softplus(over + d / k * rate * sigmoid(over, w), w) + \
        k * softplus(under - d / k * rate * sigmoid(under, w), w)
    return ca.if_else(width > 0, smooth, law)


def stop_energy(angle, lo, hi, k):
    return 0.5 * k * (ca.fmax(0, angle - hi) ** 2 + ca.fmax(0, lo - angle) ** 2)


def drive_torque(tau_cmd, omega, stall, noload, viscous):
    """The torque a drive applies to its wheel (docs/model.md, Drives): the command clipped to the DC motor's linear
    torque-speed envelope, seen at the wheel, minus the gear's viscous loss. omega is the wheel's spin rate relative
    to its carrier. Above the no-load speed the envelope's upper edge is negative, so no command can drive the wheel
    faster; the lower edge mirrors it for reverse."""
    upper = stall * (1 - omega / noload)
    lower = -stall * (1 + omega / noload)
    return ca.fmin(ca.fmax(tau_cmd, lower), upper) - viscous * omega


def describe(qf, rate, p, tau, steer_cmd, stop_width=None):
    """The rover for full coordinates qf (17 expressions of a scene's coordinates); rate(expr) is the time
    derivative of an expression; p: parameter symbols by name;
    tau: six torques applied to the wheels (the inputs, or the drives' output);
    steer_cmd: (theta3, theta6) commands or None when the scene has no steering;
    stop_width: the joint stops' smoothing width (stop_torque; None: the FMU's law)."""
    x, y, z, yaw, pitch, roll = (qf[IDX[n]] for n in ("x", "y", "z", "yaw", "pitch", "roll"))
    th1, th2, th4, th3, th6 = (qf[IDX[n]] for n in ("theta1", "theta2", "theta4", "theta3", "theta6"))
    qdf = rate(qf)
    d = {n: qdf[IDX[n]] for n in FULL_Q}

    R = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)                 # spec: R_OR = Rz Ry Rx (paper Eq. 37)
    T_OR = homogeneous(R, ca.vertcat(x, y, z))
    w_body = EZ * d["yaw"] + rot_z(yaw) @ (EY * d["pitch"]) + rot_z(yaw) @ rot_y(pitch) @ ca.DM([1, 0, 0]) * d["roll"]

    def world(T_local, point=ca.DM.zeros(3)):
        return apply(T_OR @ T_local, point)

    # bogies: rockers about the body's y axis; e(theta) lifts the front wheel = rotation about -y
    bogie_wheels = []
    for side, th, (front, rear) in ((+1, th1, (1, 2)), (-1, th2, (3, 4))):
        T_bogie = translation(ca.vertcat(p["bogie_x"], side * p["bogie_y"], p["bogie_z"])) @ \
            homogeneous(rot_y(-th), ca.DM.zeros(3))
        w_bogie = w_body - R @ EY * (d["theta1"] if side > 0 else d["theta2"])
        for idx, sign in ((front, 1), (rear, -1)):
            c = world(T_bogie, ca.vertcat(sign * p["bogie_half"], 0, 0))
            bogie_wheels.append((idx, c, R @ EY, w_bogie + R @ EY * d[f"gamma{idx}"], R, R @ EZ))

    # rear wheel: steering axis along body z
    R5 = rot_z(th3)
    c5 = world(translation(ca.vertcat(p["rear_x"], 0, p["rear_z"])))
    axle5 = R @ R5 @ EY
    w5 = w_body + R @ EZ * d["theta3"] + axle5 * d["gamma5"]

    # front four-bar: the coupler frame's x axis is s = e(theta5), its rotation is about -y
    C, theta5, closure = four_bar(th4, p)
    th5dot = rate(theta5)
    T_coupler = translation(C) @ homogeneous(rot_y(-theta5), ca.DM.zeros(3))
    w_coupler = w_body - R @ EY * th5dot
    R6 = rotation(T_coupler) @ rot_x(th6)                        # axle: y rotated about s by theta6
    c6 = world(T_coupler, ca.vertcat(-p["fork_wheel"], 0, 0))
    axle6 = R @ R6 @ EY
    s_world = R @ rotation(T_coupler) @ ca.DM([1, 0, 0])
    w6 = w_coupler + s_world * d["theta6"] + axle6 * d["gamma6"]
    fork_mass = world(T_coupler, ca.vertcat(p["fork_mass_at"], 0, 0))

    # collision points: the body's box (floor, front and rear faces), each bogie's segment between its wheel centers
    # at 1/4, 1/2, 3/4, the fork's joints C and D and the midpoints of its three links
    n_y = len(BODY_BOX_Y)
    points = [CollisionPoint("body", world(ca.SX.eye(4), ca.vertcat(bx, by, BODY_FLOOR_Z)), n_y if by == 0 else 0)
              for bx in BODY_BOX_X for by in BODY_BOX_Y]
    points += [CollisionPoint("body", world(ca.SX.eye(4), ca.vertcat(bx, by, bz)), n_y if by == 0 else 0)
               for bx in (BODY_BOX_X[0], BODY_BOX_X[-1]) for bz in BODY_FACE_Z for by in BODY_BOX_Y]
    for side, (front, rear) in ((+1, (0, 1)), (-1, (2, 3))):
        cf, cr = bogie_wheels[front][1], bogie_wheels[rear][1]
        points += [CollisionPoint("bogie", cr + f * (cf - cr), 2 if side > 0 else 0) for f in (0.25, 0.5, 0.75)]
    A = ca.vertcat(p["fork_ax"], 0, p["fork_az"])
    B = ca.vertcat(p["fork_bx"], 0, p["fork_bz"])
    D = C + p["fork_c"] * e_xz(theta5)
    points += [CollisionPoint("fork", world(ca.SX.eye(4), pt), 1)
               for pt in (C, D, 0.5 * (A + C), 0.5 * (B + D), 0.5 * (C + D))]

    mw, Rw = p["m_w"], p["R_w"]
    I_wheel = ca.diag(ca.vertcat(0.25, 0.5, 0.25)) * mw * Rw ** 2   # axle = the frame's y axis
    bodies = [Body("body", p["m_B"], ca.vertcat(x, y, z), w_body,
                   ca.diag(ca.vertcat(p["I_Bxx"], p["I_Byy"], p["I_Bzz"])), R),
              Body("fork", p["m_F"], fork_mass, w_coupler, p["I_F"] * ca.SX.eye(3), ca.SX.eye(3))]
    wheels = []
    up6 = R @ R6 @ rot_y(theta5) @ EZ      # kinematics: C6 = ... Rot_x(theta6) Rot_y(theta5 + psi6)
    for idx, c, axle, w, frame, up in bogie_wheels + [(5, c5, axle5, w5, R @ R5, R @ EZ),
                                                     (6, c6, axle6, w6, R @ R6, up6)]:
        bodies.append(Body(f"wheel{idx}", mw, c, w, I_wheel, frame))
        wheels.append(Wheel(idx, c, axle, w, rate(c), up))
    wheels.sort(key=lambda wh: wh.index)

    # torques on coordinates
    Q = ca.SX.zeros(len(FULL_Q))
    lo, hi = -p["bogie_stop"], p["bogie_stop"]
    Q[IDX["theta1"]] = stop_torque(th1, d["theta1"], lo, hi, p["stop_k"], p["stop_d"], stop_width)
    Q[IDX["theta2"]] = stop_torque(th2, d["theta2"], lo, hi, p["stop_k"], p["stop_d"], stop_width)
    Q[IDX["theta4"]] = -p["fork_k"] * (th4 - p["fork_theta4_ref"]) - p["fork_d"] * d["theta4"] + \
        stop_torque(th4, d["theta4"], p["fork_stop_lo"], p["fork_stop_hi"], p["stop_k"], p["stop_d"], stop_width)
    for i in range(6):
        Q[IDX[f"gamma{i + 1}"]] = tau[i]
    V = sum(b.mass * p["g"] * b.position[2] for b in bodies)
    V += 0.5 * p["fork_k"] * (th4 - p["fork_theta4_ref"]) ** 2
    V += stop_energy(th1, lo, hi, p["stop_k"]) + stop_energy(th2, lo, hi, p["stop_k"])
    V += stop_energy(th4, p["fork_stop_lo"], p["fork_stop_hi"], p["stop_k"])
    if steer_cmd is not None:
        for name, cmd in (("theta3", steer_cmd[0]), ("theta6", steer_cmd[1])):
            Q[IDX[name]] = -p["steer_k"] * (qf[IDX[name]] - cmd) - p["steer_d"] * d[name]
            V += 0.5 * p["steer_k"] * (qf[IDX[name]] - cmd) ** 2
    return CedraDescription(bodies=bodies, wheels=wheels, coordinate_torques=Q, potential=V, closure=closure,
                            body_omega=w_body, body_velocity=rate(ca.vertcat(x, y, z)), collision_points=points,
                            theta5=theta5)


def design(p) -> dict:
    """The design pose over flat ground: every wheel center R_w above it (the rear wheel's fixes z), bogies level,
    the fork at its spring's rest angle."""
    return {"z": p["R_w"] - p["rear_z"], "theta1": 0, "theta2": 0, "theta4": p["fork_theta4_ref"]}


def _out(name, unit, description):
    return Quantity(name, 0.0, unit, description)


def joint_outputs(qf, qd, idx, rover: CedraDescription, steering: bool) -> list:
    """The FMU outputs of CEDRA's joints: the bogies, the four-bar, the steering."""
    o = [(_out("bogie.theta[1]", "rad", "left bogie angle theta1 (positive lifts the front wheel)"), qf[idx["theta1"]]),
         (_out("bogie.theta[2]", "rad", "right bogie angle theta2"), qf[idx["theta2"]]),
         (_out("fork.theta4", "rad", "front four-bar lower link angle theta4"), qf[idx["theta4"]]),
         (_out("fork.theta5", "rad", "front four-bar coupler angle theta5 (dependent)"), rover.theta5),
         (_out("bogie.rate[1]", "rad/s", "left bogie angle rate thetadot1"), qd[idx["theta1"]]),
         (_out("bogie.rate[2]", "rad/s", "right bogie angle rate thetadot2"), qd[idx["theta2"]]),
         (_out("fork.rate4", "rad/s", "front four-bar lower link rate thetadot4"), qd[idx["theta4"]])]
    if steering:
        o += [(_out("steer.theta[1]", "rad", "steering angle of wheel 5 (theta3)"), qf[idx["theta3"]]),
              (_out("steer.theta[2]", "rad", "steering angle of wheel 6 (theta6)"), qf[idx["theta6"]])]
    return o


CEDRA = RoverKind(
    name="cedra",
    coordinates=tuple(FULL_Q),
    # 2D: the terrain is constant in Y and the rover symmetric: the bogies move together, wheels 3, 4 spin with
    # 1, 2, and nothing leaves the plane
    planar={"y": None, "yaw": None, "roll": None, "theta2": "theta1", "theta3": None, "theta6": None,
            "gamma3": "gamma1", "gamma4": "gamma2"},
    steering=("theta3", "theta6"),
    settle=("z", "pitch", "roll", "theta1", "theta2", "theta4"),
    parameters=parameters.ROVER,
    servo_parameters=parameters.SERVO,
    steer_inputs=[Quantity("steer[1]", 0.0, "rad", "commanded steering angle of wheel 5 (theta3)",
                           -parameters.STEER_LIMIT, parameters.STEER_LIMIT),
                  Quantity("steer[2]", 0.0, "rad", "commanded steering angle of wheel 6 (theta6)",
                           -parameters.STEER_LIMIT, parameters.STEER_LIMIT)],
    describe=describe,
    stops=(Stop("theta1", "-bogie_stop", "bogie_stop"), Stop("theta2", "-bogie_stop", "bogie_stop"),
           Stop("theta4", "fork_stop_lo", "fork_stop_hi")),
    design=design,
    joint_outputs=joint_outputs,
)
