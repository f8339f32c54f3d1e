"""The rocker-bogie (docs/model.md, The rocker-bogie): the second rover, described through the
same interface as CEDRA (cedra.mechanics.rover_kind), so its equations, contact, drives and FMU come from the same
machinery.

Body with two rockers pivoting about its y axis and joined by a differential (the right rocker's angle is minus
the left's: one coordinate rho), a bogie on each rocker (beta_L, beta_R), six wheels: 1 and 4 the front wheels on
the rockers, 2 and 5 the bogies' front wheels, 3 and 6 their rear wheels. Rockers and bogies are massless; no
wheel steers (it turns by skid steering). In the design pose over flat ground every wheel center is R_w above the
ground with the body's mass center at 0.20 m, and the rocker's lever arms (0.30 m to the front wheel, 0.15 m to
the bogie pivot) with the bogie's equal arms give the six wheels equal static loads.
"""
from __future__ import annotations

import casadi as ca

from cedra.contract import Quantity as Q
from cedra.mechanics.kane import Body
from cedra.mechanics.rover_kind import POSE, SPINS, CollisionPoint, RoverDescription, RoverKind, Stop, Wheel
from cedra.mechanics.transforms import apply, homogeneous, rot_x, rot_y, rot_z
from cedra.rover import parameters
from cedra.rover.mechanism import stop_energy, stop_torque

COORDINATES = POSE + ("rho", "beta_L", "beta_R") + SPINS
IDX = {name: i for i, name in enumerate(COORDINATES)}
EY = ca.DM([0, 1, 0])
EZ = ca.DM([0, 0, 1])

# the rover's own geometry and body mass; wheel radius, stops' law, body inertia, wheel mass and g are CEDRA's
CEDRA_PARAMETERS = {q.name: q for q in parameters.ROVER}
PARAMETERS = [
    CEDRA_PARAMETERS["R_w"],
    Q("rocker_x", 0.0, "m", "rocker pivots Q = (rocker_x, +-rocker_y, rocker_z) in the body frame"),
    Q("rocker_y", 0.17, "m", "rocker pivots: half track", min=0.0),
    Q("rocker_z", -0.035, "m", "rocker pivots: z in the body frame"),
    Q("front_x", 0.30, "m", "front wheel centers in the design pose (on the rockers), x"),
    Q("front_z", -0.135, "m", "front wheel centers in the design pose, z"),
    Q("bogie_x", -0.15, "m", "bogie pivots in the design pose (on the rockers), x"),
    Q("bogie_z", -0.085, "m", "bogie pivots in the design pose, z"),
    Q("bogie_half", 0.15, "m", "bogie pivot to each bogie wheel, along x", min=1e-4),
    Q("bogie_drop", 0.05, "m", "bogie pivot to each bogie wheel, downward"),
    Q("rocker_stop", 0.5, "rad", "rocker joint stop |rho| <= rocker_stop", min=0.0),
    Q("bogie_stop", 0.6, "rad", "bogie joint stops |beta_L|, |beta_R| <= bogie_stop", min=0.0),
    CEDRA_PARAMETERS["stop_k"],
    CEDRA_PARAMETERS["stop_d"],
    Q("m_B", 21.0, "kg", "body mass (rockers and bogies are massless)", min=1e-6),
] + [CEDRA_PARAMETERS[n] for n in ("I_Bxx", "I_Byy", "I_Bzz", "m_w", "g")]
DEFAULTS = {p.name: p.start for p in PARAMETERS}

# the body's box in frame R (its floor, front and rear faces) and the links' points: each rocker's arm to its front
# wheel and to its bogie pivot at 1/2, each bogie's segment between its wheels at 1/4, 1/2, 3/4
BODY_BOX_X = [-0.24 + 0.04 * k for k in range(13)]      # -0.24 .. 0.24
BODY_BOX_Y = [-0.12, 0.0, 0.12]
BODY_FLOOR_Z = -0.02
BODY_FACE_Z = [0.0, 0.05, 0.10]


def lift(a):
    """Rl(a): the rotation in the x-z plane by which a positive angle lifts what lies ahead of its pivot."""
    return rot_y(-a)


def describe(qf, rate, p, tau, steer_cmd=None, stop_width=None) -> RoverDescription:
    """The rocker-bogie at full coordinates qf (15 expressions of a scene's coordinates); see cedra.mechanics.rover_kind.
    steer_cmd must be None: no wheel steers; stop_width: the joint stops' smoothing width (mechanism.stop_torque)."""
    if steer_cmd is not None:
        raise ValueError("the rocker-bogie has no steering joints")
    x, y, z, yaw, pitch, roll = (qf[IDX[n]] for n in POSE)
    rho, beta_l, beta_r = (qf[IDX[n]] for n in ("rho", "beta_L", "beta_R"))
    qdf = rate(qf)
    d = {n: qdf[IDX[n]] for n in COORDINATES}

    R = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
    T_OR = homogeneous(R, ca.vertcat(x, y, z))
    w_body = EZ * d["yaw"] + rot_z(yaw) @ (EY * d["pitch"]) + rot_z(yaw) @ rot_y(pitch) @ ca.DM([1, 0, 0]) * d["roll"]
    axle = R @ EY

    def world(point):
        return apply(T_OR, point)

    wheels, points = [], []
    # left side: rocker angle rho, bogie beta_L, wheels 1, 2, 3; right: -rho, beta_R, wheels 4, 5, 6
    for side, r, r_dot, b, b_dot, first in ((+1, rho, d["rho"], beta_l, d["beta_L"], 1),
                                            (-1, -rho, -d["rho"], beta_r, d["beta_R"], 4)):
        Qp = ca.vertcat(p["rocker_x"], side * p["rocker_y"], p["rocker_z"])
        front = ca.vertcat(p["front_x"], side * p["rocker_y"], p["front_z"])
        pivot = ca.vertcat(p["bogie_x"], side * p["rocker_y"], p["bogie_z"])
        c_front = Qp + lift(r) @ (front - Qp)
        P = Qp + lift(r) @ (pivot - Qp)
        c_mid = P + lift(r + b) @ ca.vertcat(p["bogie_half"], 0, -p["bogie_drop"])
        c_rear = P + lift(r + b) @ ca.vertcat(-p["bogie_half"], 0, -p["bogie_drop"])
        w_rocker = w_body - axle * r_dot
        w_bogie = w_rocker - axle * b_dot
        for k, (c, w_carrier) in enumerate(((c_front, w_rocker), (c_mid, w_bogie), (c_rear, w_bogie))):
            idx = first + k
            cw = world(c)
            wheels.append(Wheel(idx, cw, axle, w_carrier + axle * d[f"gamma{idx}"], rate(cw), R @ EZ))
        weight = 2 if side > 0 else 0       # 2D: the left side's points stand for both sides'
        points += [CollisionPoint("rocker", world(0.5 * (Qp + c_front)), weight),
                   CollisionPoint("rocker", world(0.5 * (Qp + P)), weight)]
        points += [CollisionPoint("bogie", world(c_rear + f * (c_mid - c_rear)), weight) for f in (0.25, 0.5, 0.75)]
    n_y = len(BODY_BOX_Y)
    body_points = [CollisionPoint("body", world(ca.vertcat(bx, by, BODY_FLOOR_Z)), n_y if by == 0 else 0)
                   for bx in BODY_BOX_X for by in BODY_BOX_Y]
    body_points += [CollisionPoint("body", world(ca.vertcat(bx, by, bz)), n_y if by == 0 else 0)
                    for bx in (BODY_BOX_X[0], BODY_BOX_X[-1]) for bz in BODY_FACE_Z for by in BODY_BOX_Y]

    mw, Rw = p["m_w"], p["R_w"]
    I_wheel = ca.diag(ca.vertcat(0.25, 0.5, 0.25)) * mw * Rw ** 2   # axle = the frame's y axis
    bodies = [Body("body", p["m_B"], ca.vertcat(x, y, z), w_body,
                   ca.diag(ca.vertcat(p["I_Bxx"], p["I_Byy"], p["I_Bzz"])), R)]
    bodies += [Body(f"wheel{wh.index}", mw, wh.center, wh.omega, I_wheel, R) for wh in wheels]

    Qc = ca.SX.zeros(len(COORDINATES))
    Qc[IDX["rho"]] = stop_torque(rho, d["rho"], -p["rocker_stop"], p["rocker_stop"], p["stop_k"], p["stop_d"],
                                 stop_width)
    for name in ("beta_L", "beta_R"):
        Qc[IDX[name]] = stop_torque(qf[IDX[name]], d[name], -p["bogie_stop"], p["bogie_stop"], p["stop_k"],
                                    p["stop_d"], stop_width)
    for i in range(6):
        Qc[IDX[f"gamma{i + 1}"]] = tau[i]
    V = sum(bd.mass * p["g"] * bd.position[2] for bd in bodies)
    V += stop_energy(rho, -p["rocker_stop"], p["rocker_stop"], p["stop_k"])
    V += stop_energy(beta_l, -p["bogie_stop"], p["bogie_stop"], p["stop_k"])
    V += stop_energy(beta_r, -p["bogie_stop"], p["bogie_stop"], p["stop_k"])
    return RoverDescription(bodies=bodies, wheels=wheels, coordinate_torques=Qc, potential=V, closure=ca.SX(0),
                            body_omega=w_body, body_velocity=rate(ca.vertcat(x, y, z)),
                            collision_points=body_points + points)


def design(p) -> dict:
    """The design pose over flat ground: the front wheels' centers R_w above it fix z; rockers and bogies level."""
    return {"z": p["R_w"] - p["front_z"], "rho": 0, "beta_L": 0, "beta_R": 0}


def _out(name, unit, description):
    return Q(name, 0.0, unit, description)


def joint_outputs(qf, qd, idx, rover, steering: bool) -> list:
    """The FMU outputs of the rocker-bogie's joints (steering: never; scenes refuse it)."""
    return [(_out("rocker.rho", "rad", "left rocker angle rho (the right one is -rho; positive lifts the front "
                  "wheel)"), qf[idx["rho"]]),
            (_out("bogie.beta[1]", "rad", "left bogie angle beta_L on its rocker (positive lifts the middle "
                  "wheel)"), qf[idx["beta_L"]]),
            (_out("bogie.beta[2]", "rad", "right bogie angle beta_R"), qf[idx["beta_R"]]),
            (_out("rocker.rate", "rad/s", "left rocker angle rate"), qd[idx["rho"]]),
            (_out("bogie.rate[1]", "rad/s", "left bogie angle rate"), qd[idx["beta_L"]]),
            (_out("bogie.rate[2]", "rad/s", "right bogie angle rate"), qd[idx["beta_R"]])]


ROCKER_BOGIE = RoverKind(
    name="rocker_bogie",
    coordinates=COORDINATES,
    # 2D: the terrain is constant in Y and the rover symmetric, so the differential holds rho at 0 (both rockers
    # move with the body), the bogies move together and each right wheel spins with its left twin
    planar={"y": None, "yaw": None, "roll": None, "rho": None, "beta_R": "beta_L", "gamma4": "gamma1",
            "gamma5": "gamma2", "gamma6": "gamma3"},
    steering=(),
    settle=("z", "pitch", "roll", "rho", "beta_L", "beta_R"),
    parameters=PARAMETERS,
    servo_parameters=[],
    steer_inputs=[],
    describe=describe,
    stops=(Stop("rho", "-rocker_stop", "rocker_stop"), Stop("beta_L", "-bogie_stop", "bogie_stop"),
           Stop("beta_R", "-bogie_stop", "bogie_stop")),
    design=design,
    joint_outputs=joint_outputs,
)
