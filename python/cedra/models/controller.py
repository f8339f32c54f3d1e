"""The drive controller FMU (docs/model.md, Controller): the paper's inverse kinematics (Eqs. 9-13) and geometric
steering (Eqs. 14-22) in the loop, as a sampled-data block beside the plant FMU.

Every `ctrl.period` (default 0.01 s) it reads the commanded forward speed `cmd.v` and yaw rate `cmd.yaw_rate`
(3D) and the plant's outputs (connected name to name: `body.*`, `bogie.theta[1..2]`, `bogie.rate[1..2]`,
`fork.theta4`, `fork.rate4`, `steer.theta[1..2]`, `wheel[i].omega`, `wheel[i].psi_R`, `wheel[i].psi_R_rate`,
`wheel[i].xi`) and gives `tau[1..6]` and `steer[1..2]` (3D) with the plant's input names. Three modes:

    ctrl.mode = 1  inverse kinematics (the default): the wheel rates omega_ref of Eq. 13 for the commanded speed
                   and yaw rate at the measured pose, contact angles and slips; a PI loop per wheel (ctrl.rate_kp,
                   ctrl.rate_ki, anti-windup: no integration while clipped) turns omega_ref - omega into a torque
                   within +-ctrl.tau_max. Eq. 13 is kinematics: wheels that skid (the four fixed bogie wheels must,
                   in a turn) or slip make the rover slower and turn less than commanded, so an integral trim on
                   the measured speed and yaw rate (ctrl.trim_ki; |trim| <= 1 m/s, 1 rad/s) corrects the speed
                   and yaw rate handed to Eq. 13 until the measured ones match the commands (the steering keeps
                   the commanded turn center);
    ctrl.mode = 0  equal torques (the paper's run): one PI on the forward speed (ctrl.speed_kp,
                   ctrl.speed_ki), the same torque on all six wheels;
    ctrl.mode = 2  traction control: mode 0's speed PI gives the summed torque (6 times its per-wheel torque),
                   distributed over the wheels so that the largest friction ratio |T_i| / N_i is as small as
                   possible under the quasi-static balance at the measured pose (rover.statics): every wheel
                   gets the same ratio, found by a fixed number of Newton steps (TRACTION_NEWTON_STEPS), within
                   +-ctrl.ratio_max (a demand that needs more is a stall: shared at the loads of that ratio); a
                   torque that has turned its wheel past the wheel's rolling rate (rover.statics.rolling_rates:
                   the measured body motion, joint rates and contact angles) by ctrl.spin_margin (wider where
                   the sampled loop needs it: _guard_margin) is dropped (_spin_guard), and a loop (ctrl.roll_kp)
                   holds every wheel at its rolling rate, so a lifted wheel lands turning as the ground asks.
                   A rover that stalls (slower than a quarter of the command for ctrl.stall_time with the speed
                   loop at its limit) backs off and takes a run-up at ctrl.runup_v (_runup; ctrl.phase says which).
In every mode (3D) the steered wheels get the geometric steering angles (Eqs. 14-22) for (cmd.v, cmd.yaw_rate),
and the outputs ctrl.Fn_est[i] give the balance's normal forces for the commanded torques (no force sensor: the
pose, the contact angles and the torques only). Every mode is evaluated at every sample and the mode selects
(no branch in the C), so a sample costs the same whatever the mode.

The equations are kinematics.drive_expressions: the same CasADi graph the Python functions evaluate. The FMU
carries only the generated sample function (no solver, no contact code): fmu_src/controller.c.

Another rover's controller (rover_controller_spec; the rocker-bogie's rb_drive2d, rb_drive3d) has the same three
modes with the same loops and helpers, its wheel rates from cedra.mechanics.drive_kinematics (its own description's
Jacobians; a turn is skid-steered through them), its balance and rolling rates from cedra.mechanics.statics (the
same formulation, from its description) and its inputs named as its plant's outputs.
"""
from __future__ import annotations

import casadi as ca

from cedra.mechanics.drive_kinematics import drive_kinematics
from cedra.mechanics.statics import equal_ratio_tractions, loads_given_tractions, rover_statics
from cedra.rover.kinematics import KIN_PARAMS, drive_expressions, drive_symbols
from cedra.rover.parameters import DEFAULTS, ROVER, STEER_LIMIT
from cedra.mechanics.transforms import rot_z
from cedra.rover.statics import GROUPS, PAIR, STATICS_PARAMS, balance, multiplicity, rolling_rates
from cedra.contract import ModelSpec, Quantity

WHEELS = range(1, 7)
MODES = {"equal_torques": 0, "inverse_kinematics": 1, "traction_control": 2}
# Newton steps on the common friction ratio (mechanics.statics.equal_ratio_tractions): 5 reach the root to 1e-9 of the
# ratio on the test's random poses, so the cost of a sample is fixed
TRACTION_NEWTON_STEPS = 5
# the balance's parameters beyond the kinematics': the controller's own copy of the rover's masses and springs
CONTROLLER_PARAMS = KIN_PARAMS + tuple(n for n in STATICS_PARAMS if n not in KIN_PARAMS)
# the shipped controller FMUs (build/<name>.fmu): their rover (cedra.models.rovers) and dims
CONTROLLERS = {"drive2d": ("cedra", "2d"), "drive3d": ("cedra", "3d"),
               "rb_drive2d": ("rocker_bogie", "2d"), "rb_drive3d": ("rocker_bogie", "3d")}


def _geometry_params() -> list[Quantity]:
    table = {q.name: q for q in ROVER}
    return [Quantity(n, DEFAULTS[n], table[n].unit, table[n].description + " (the controller's kinematics)",
                     table[n].min, table[n].max) for n in CONTROLLER_PARAMS]


def params() -> list[Quantity]:
    return [
        Quantity("ctrl.period", 0.01, "s", "sample period of the controller", 1e-6, 1e3),
        Quantity("ctrl.mode", 1, "1", "0 equal torques from a PI on the forward speed (the paper's "
                 "run); 1 inverse kinematics (Eq. 13) with a PI loop per wheel rate; 2 traction control: the speed "
                 "PI's summed torque distributed for the least largest friction ratio", 0, 2, type="Integer"),
        Quantity("ctrl.tau_max", 4.0, "N.m", "torque limit of every wheel", 0.0, 1e3),
        Quantity("ctrl.ramp_time", 0.0, "s", "the commands ramp up linearly from 0 over this time after the start "
                 "(0: no ramp, the commands act at once)", 0.0, 1e4),
        Quantity("ctrl.speed_kp", 3.0, "N.m.s/m", "equal-torque and traction modes: proportional gain on the speed "
                 "error (per wheel)", 0.0),
        Quantity("ctrl.speed_ki", 6.0, "N.m/m", "equal-torque and traction modes: integral gain on the speed error "
                 "(per wheel)", 0.0),
        # a slipping wheel's own spin inertia (m_w R_w^2 / 2 = 1e-3 kg.m^2) is what the rate loop drives when the
        # wheel skids: Kp T / J must stay well below 1 at T = 0.01 s, hence a soft Kp; loaded wheels (~0.02 kg.m^2
        # with their share of the rover) then respond in ~0.4 s
        Quantity("ctrl.rate_kp", 0.05, "N.m.s/rad", "inverse-kinematics mode: proportional gain on a wheel's rate "
                 "error", 0.0),
        Quantity("ctrl.rate_ki", 1.0, "N.m/rad", "inverse-kinematics mode: integral gain on a wheel's rate error",
                 0.0),
        Quantity("ctrl.trim_ki", 2.0, "1/s", "inverse-kinematics mode: integral gain of the speed and yaw-rate "
                 "trims (0: Eq. 13 open loop)", 0.0),
        Quantity("ctrl.spin_margin", 10.0, "rad/s", "traction mode: a torque that has turned its wheel past the "
                 "wheel's rolling rate by more than this is dropped (it fades out linearly over this margin)", 1e-3),
        Quantity("ctrl.ratio_max", 0.6, "1", "traction mode: the largest common friction ratio whose load transfer the "
                 "balance is trusted for; a demand that needs more (a stall) is shared in proportion to the loads at "
                 "this ratio", 0.05, 2.0),
        # a wheel in the air has only its own spin inertia J = m_w R_w^2 / 2 (1.06e-3 kg.m^2): Kp T / J = 0.95
        # at T = 0.01 s, so a lifted wheel is back at its rolling rate within about one sample (stable below 2)
        Quantity("ctrl.roll_kp", 0.1, "N.m.s/rad", "traction mode: gain of the loop that holds every wheel at its "
                 "rolling rate (what keeps a lifted wheel ready to land)", 0.0),
    ] + _runup_params() + _geometry_params()


def _runup_params() -> list[Quantity]:
    """Mode 2's stall recovery (_runup); every rover's controller."""
    return [
        Quantity("ctrl.runup_v", 0.6, "m/s", "traction mode: a stalled rover backs off and takes a run-up at this "
                 "speed (or the commanded one if faster; 0: no run-up, a stalled rover stays where it stalled)",
                 0.0, 5.0),
        Quantity("ctrl.stall_time", 1.5, "s", "traction mode: the rover has stalled when its speed has stayed below "
                 "a quarter of the commanded speed for this long with the speed loop at its torque limit", 1e-3, 1e4),
        Quantity("ctrl.backoff_time", 1.5, "s", "traction mode: a stalled rover backs off at the commanded speed for "
                 "this long before its run-up", 0.0, 1e4),
        Quantity("ctrl.runup_time", 3.0, "s", "traction mode: the run-up lasts this long, then the commanded speed "
                 "holds again (a rover that stalls again backs off again)", 0.0, 1e4),
    ]


def inputs(dims: str) -> list[Quantity]:
    three = dims == "3d"
    ins = [Quantity("cmd.v", 0.0, "m/s", "commanded forward speed (along the body's heading)", -5.0, 5.0)]
    if three:
        ins.append(Quantity("cmd.yaw_rate", 0.0, "rad/s", "commanded yaw rate (positive turns left)", -5.0, 5.0))
    ins.append(Quantity("body.vx", 0.0, "m/s", "measured: body velocity along world X"))
    if three:
        ins += [Quantity("body.vy", 0.0, "m/s", "measured: body velocity along world Y"),
                Quantity("body.yaw", 0.0, "rad", "measured: body yaw"),
                Quantity("body.wz", 0.0, "rad/s", "measured: body yaw rate (angular velocity about world Z)")]
    # the rest of the body's motion (an IMU's): the traction mode's rolling rates (rover.statics.rolling_rates)
    ins.append(Quantity("body.vz", 0.0, "m/s", "measured: body velocity along world Z"))
    if three:
        ins.append(Quantity("body.wx", 0.0, "rad/s", "measured: body angular velocity about world X"))
    ins.append(Quantity("body.wy", 0.0, "rad/s", "measured: body angular velocity about world Y"))
    ins.append(Quantity("body.pitch", 0.0, "rad", "measured: body pitch (positive nose down)"))
    if three:
        ins.append(Quantity("body.roll", 0.0, "rad", "measured: body roll"))
    ins += [Quantity("bogie.theta[1]", 0.0, "rad", "measured: left bogie angle"),
            Quantity("bogie.theta[2]", 0.0, "rad", "measured: right bogie angle"),
            Quantity("fork.theta4", DEFAULTS["fork_theta4_ref"], "rad", "measured: four-bar lower link angle"),
            Quantity("bogie.rate[1]", 0.0, "rad/s", "measured: left bogie rate"),
            Quantity("bogie.rate[2]", 0.0, "rad/s", "measured: right bogie rate"),
            Quantity("fork.rate4", 0.0, "rad/s", "measured: four-bar lower link rate")]
    if three:
        ins += [Quantity("steer.theta[1]", 0.0, "rad", "measured: steering angle of wheel 5"),
                Quantity("steer.theta[2]", 0.0, "rad", "measured: steering angle of wheel 6")]
    for i in WHEELS:
        ins += [Quantity(f"wheel[{i}].omega", 0.0, "rad/s", f"measured: wheel {i} spin rate"),
                Quantity(f"wheel[{i}].psi_R", 0.0, "rad", f"measured: wheel {i} contact angle in the rover frame"),
                Quantity(f"wheel[{i}].psi_R_rate", 0.0, "rad/s", f"measured: wheel {i} contact angle rate"),
                Quantity(f"wheel[{i}].xi", 0.0, "rad", f"measured: wheel {i} rotational slip angle")]
    return ins


def outputs(dims: str) -> list[Quantity]:
    outs = [Quantity(f"tau[{i}]", 0.0, "N.m", f"motor torque command of wheel {i}") for i in WHEELS]
    if dims == "3d":
        outs += [Quantity("steer[1]", 0.0, "rad", "steering angle command of wheel 5 (Eqs. 14-22, within the servo's "
                          f"range +-{STEER_LIMIT:g} rad)"),
                 Quantity("steer[2]", 0.0, "rad", "steering angle command of wheel 6 (Eqs. 14-22, within the servo's "
                          f"range +-{STEER_LIMIT:g} rad)")]
    outs += [Quantity(f"ctrl.omega_ref[{i}]", 0.0, "rad/s", f"wheel {i} rate from the inverse kinematics (Eq. 13)")
             for i in WHEELS]
    outs.append(Quantity("ctrl.v", 0.0, "m/s", "measured forward speed the controller used"))
    return outs + _estimate_outputs()


def _estimate_outputs() -> list[Quantity]:
    """The load estimate's outputs (_estimate); every rover's controller."""
    outs = [Quantity(f"ctrl.Fn_est[{i}]", 0.0, "N", f"wheel {i} normal force the quasi-static balance estimates for "
                     "the commanded torques") for i in WHEELS]
    outs.append(Quantity("ctrl.ratio", 0.0, "1", "largest |tau_i| / (R_w Fn_est_i) over the wheels the balance "
                         "loads: the friction the commanded torques ask for"))
    outs.append(Quantity("ctrl.phase", 0.0, "1", "traction mode's stall recovery: 0 driving at the commanded speed, "
                         "1 backing off after a stall, 2 taking the run-up (0 in the other modes)"))
    return outs


def _pi(error, integral, kp, ki, limit, period):
    """u = Kp e + Ki (I + e T), clipped to +-limit; I integrates only while u is within the limit (the paper's run)."""
    u = kp * error + ki * (integral + error * period)
    return ca.fmin(ca.fmax(u, -limit), limit), ca.if_else(ca.fabs(u) <= limit, integral + error * period, integral)


STATES = ["speed_integral"] + [f"rate_integral[{k}]" for k in WHEELS] + ["speed_trim", "yaw_trim", "elapsed",
                                                                         "runup_phase", "phase_time", "stall_time"]
TRIM_LIMITS = (1.0, 1.0)    # m/s, rad/s: the trims correct skid and slip, they do not take over the command
# mode 2's stall recovery (_runup): its phases (the state runup_phase, the output ctrl.phase) and what a stall is
DRIVE, BACK_OFF, RUN_UP = 0, 1, 2
STALL_FRACTION = 0.25       # of the commanded speed
MIN_COMMAND = 1e-3          # m/s: a smaller command is a stop, never a stall


def _phase_speed(phase, cmd_v, p):
    """The speed mode 2's speed loop follows in a phase of its stall recovery (_runup)."""
    run_up = ca.sign(cmd_v) * ca.fmax(p["ctrl.runup_v"], ca.fabs(cmd_v))
    return ca.if_else(phase < 0.5, cmd_v, ca.if_else(phase < 1.5, -cmd_v, run_up))


def _runup(p, xd, cmd_v, v):
    """Mode 2's stall recovery: (the speed its speed loop follows, whether that loop's integral restarts, the next
    (runup_phase, phase_time, stall_time) of STATES).

    Traction control holds the commanded speed with every wheel at the smallest common friction ratio, so where
    the friction cannot carry the rover up an obstacle at that speed it stops there, every wheel sliding at mu (a
    0.5 R_w step at mu 0.4: CEDRA stops with its bogies' rear wheels on the face). Such an obstacle may still be
    climbed dynamically, as a driver would: back off, then take a run-up. The rover has stalled when its speed has
    stayed below STALL_FRACTION of the command for ctrl.stall_time while the speed loop asks all it can (its
    output at +-ctrl.tau_max in the command's direction): a rover that stands at a face while the loop's integral
    still grows often gets up once the torque suffices, and backing off would throw that away. Stalled, it backs
    off at the commanded speed for ctrl.backoff_time, then drives at ctrl.runup_v (the command's direction; the
    command if faster) for ctrl.runup_time, and then at the command again; a rover that stalls in its run-up backs
    off again. Each switch of direction restarts the speed loop's integral, so the wound-up torque of the stall
    does not delay the back-off. A command below MIN_COMMAND, or ctrl.runup_v = 0, returns to driving at the
    command."""
    T, lim = p["ctrl.period"], p["ctrl.tau_max"]
    phase, phase_time, stall_time = xd[10], xd[11], xd[12]
    speed = ca.fabs(cmd_v)
    direction = ca.sign(cmd_v)
    active = ca.logic_and(speed > MIN_COMMAND, p["ctrl.runup_v"] > 0)
    backing = ca.fabs(phase - BACK_OFF) < 0.5
    running = ca.fabs(phase - RUN_UP) < 0.5
    # the speed loop at this sample's phase, before any switch: at its limit in the command's direction?
    asked, _ = _pi(_phase_speed(phase, cmd_v, p) - v, xd[0], p["ctrl.speed_kp"], p["ctrl.speed_ki"], lim, T)
    all_it_can = direction * asked >= lim
    slow = ca.logic_and(v * direction < STALL_FRACTION * speed, all_it_can)
    stall_next = ca.if_else(ca.logic_and(active, ca.logic_and(slow, ca.logic_not(backing))), stall_time + T, 0)
    time_next = phase_time + T
    # the transitions, the weakest first: each later one overrides what the earlier ones chose
    phase_next = ca.if_else(backing, BACK_OFF, ca.if_else(running, RUN_UP, DRIVE))
    phase_next = ca.if_else(ca.logic_and(running, time_next >= p["ctrl.runup_time"]), DRIVE, phase_next)
    phase_next = ca.if_else(ca.logic_and(backing, time_next >= p["ctrl.backoff_time"]), RUN_UP, phase_next)
    phase_next = ca.if_else(stall_next >= p["ctrl.stall_time"], BACK_OFF, phase_next)
    phase_next = ca.if_else(active, phase_next, DRIVE)
    switched = ca.fabs(phase_next - phase) > 0.5
    restart = ca.logic_and(switched, phase_next > 0.5)
    states = ca.vertcat(phase_next, ca.if_else(switched, 0, time_next), ca.if_else(switched, 0, stall_next))
    return _phase_speed(phase_next, cmd_v, p), restart, states


def _by_mode(mode, equal_torques, inverse_kinematics, traction):
    """The value of the selected mode (mode 2 and above: traction; the variable's range keeps it within 0..2)."""
    return ca.if_else(mode < 0.5, equal_torques, ca.if_else(mode < 1.5, inverse_kinematics, traction))


def _select(mode, speed, ik, traction, xd, trim_v, trim_w, period):
    """The selected mode's six torques, the next states (STATES) and the output ctrl.phase: the speed PI (torque,
    integral) for mode 0, the rate loops ((torque, integral) per wheel) and the trims for mode 1, and for mode 2
    its torques, its speed PI's integral and its stall recovery's states (_runup); every rover's controller."""
    speed_tau, speed_int = speed
    traction_tau, traction_int, runup = traction
    tau = [_by_mode(mode, speed_tau, ik[k][0], traction_tau[k]) for k in range(6)]
    xd_next = ca.vertcat(_by_mode(mode, speed_int, xd[0], traction_int),
                         *[_by_mode(mode, xd[1 + k], ik[k][1], xd[1 + k]) for k in range(6)],
                         _by_mode(mode, xd[7], trim_v, xd[7]), _by_mode(mode, xd[8], trim_w, xd[8]), xd[9] + period,
                         *[_by_mode(mode, xd[10 + k], xd[10 + k], runup[k]) for k in range(3)])
    return tau, xd_next, _by_mode(mode, 0, 0, runup[0])


def _traction_speed_loop(p, xd, cmd_v, v):
    """Mode 2's speed PI on the speed its stall recovery asks for (_runup): (summed torque demand, next integral,
    next recovery states); every rover's controller."""
    target, restart, runup = _runup(p, xd, cmd_v, v)
    tau, integral = _pi(target - v, ca.if_else(restart, 0, xd[0]), p["ctrl.speed_kp"], p["ctrl.speed_ki"],
                        p["ctrl.tau_max"], p["ctrl.period"])
    return 6 * tau, integral, runup


def _loads(dims, i, p):
    """The quasi-static balance at the measured pose: N = N0 + B T per wheel group (rover.statics)."""
    three = dims == "3d"
    A, b = balance(dims, i["body.pitch"], i["body.roll"] if three else 0,
                   ca.vertcat(i["bogie.theta[1]"], i["bogie.theta[2]"], i["fork.theta4"]),
                   ca.vertcat(i["steer.theta[1]"], i["steer.theta[2]"]) if three else ca.DM.zeros(2),
                   ca.vertcat(*[i[f"wheel[{k}].psi_R"] for k in WHEELS]),
                   ca.vertcat(*[p[n] for n in STATICS_PARAMS]))
    n0, B, _, _ = loads_given_tractions(A, b, len(GROUPS[dims]), three)
    return n0, B


def _group(dims, wheel):
    return GROUPS[dims].index(PAIR.get(wheel, wheel) if dims == "2d" else wheel)


def _traction_torques(loads, p, demand, multiplicity, group_of):
    """Mode 2: the summed torque `demand` at one friction ratio on every wheel (wheel k in group group_of[k - 1],
    each group standing for multiplicity[g] wheels); a wheel the balance leaves unloaded gets no torque, and every
    torque stays within +-ctrl.tau_max. Every rover's controller."""
    n0, B = loads
    weights = p["R_w"] * ca.DM(multiplicity)
    _, ratio, normal = equal_ratio_tractions(n0, B, weights, demand, TRACTION_NEWTON_STEPS, p["ctrl.ratio_max"])
    lim = p["ctrl.tau_max"]
    return [ca.fmin(ca.fmax(p["R_w"] * ratio * ca.fmax(normal[group_of[k - 1]], 0), -lim), lim) for k in WHEELS]


def _spin_guard(tau, omega, rolling, margin):
    """tau, faded out where it has already turned the wheel past its rolling rate in its own direction: full while
    the wheel is within that rate, none from margin past it on, linear between; a torque that turns the wheel back
    towards its rolling rate is never touched. The balance cannot see a wheel that has left the ground (it gives it
    a load from the pose), and a torque on a wheel in the air only spins it, up or backwards: without this a
    stalled climb (3 R_w at mu 0.4, no drives) spun a wheel to 29,000 rad/s, and a braking torque on a lifted wheel
    spun it backwards until it landed sliding."""
    excess = ca.sign(tau) * (omega - rolling)
    return tau * ca.fmin(1, ca.fmax(0, 1 - excess / margin))


def _body_motion(i, three):
    """The measured body velocity and angular velocity in the heading's axes (world axes turned by the measured
    yaw), where the balance takes the pose; every rover's controller."""
    yaw = i["body.yaw"] if three else 0
    turn = rot_z(-yaw)
    velocity = turn @ ca.vertcat(i["body.vx"], i["body.vy"] if three else 0, i["body.vz"])
    omega = turn @ ca.vertcat(i["body.wx"] if three else 0, i["body.wy"], i["body.wz"] if three else 0)
    return velocity, omega


def _rolling(dims, i, p):
    """The rolling rate of every wheel for the measured body motion, joint rates and contact angles."""
    three = dims == "3d"
    velocity, omega = _body_motion(i, three)
    return rolling_rates(dims, i["body.pitch"], i["body.roll"] if three else 0,
                         ca.vertcat(i["bogie.theta[1]"], i["bogie.theta[2]"], i["fork.theta4"]),
                         ca.vertcat(i["steer.theta[1]"], i["steer.theta[2]"]) if three else ca.DM.zeros(2),
                         ca.vertcat(*[i[f"wheel[{k}].psi_R"] for k in WHEELS]),
                         ca.vertcat(*[p[n] for n in STATICS_PARAMS]), velocity, omega,
                         ca.vertcat(i["bogie.rate[1]"], i["bogie.rate[2]"], i["fork.rate4"]))


def _traction_control(dims, i, p, loads, demand):
    """Mode 2's torques: the equal-ratio distribution of `demand` (spin-guarded) plus a proportional loop on
    every wheel's rolling rate. A wheel on the ground turns at its rolling rate up to its small slip, so the loop
    adds little there; a wheel the balance loads but the ground does not (lifted, or about to land) has nothing
    else to hold it, and it lands turning at the rate the ground asks for instead of sliding."""
    torques = _traction_torques(loads, p, demand, multiplicity(dims), [_group(dims, k) for k in WHEELS])
    return _guarded(torques, i, p, _rolling(dims, i, p))


def _guarded(torques, i, p, rolling):
    """The traction torques spin-guarded (_spin_guard) plus the loop that holds every wheel at its rolling rate
    (ctrl.roll_kp), within +-ctrl.tau_max; every rover's controller."""
    lim = p["ctrl.tau_max"]
    out = []
    for k, t in enumerate(torques):
        omega = i[f"wheel[{k + 1}].omega"]
        hold = p["ctrl.roll_kp"] * (rolling[k] - omega)
        out.append(ca.fmin(ca.fmax(_spin_guard(t, omega, rolling[k], _guard_margin(t, p)) + hold, -lim), lim))
    return out


def _guard_margin(tau, p):
    """The spin guard's fade width for the torque tau: ctrl.spin_margin, widened so that the sampled loop stays
    stable. The fade's slope |tau| / margin is a gain on the wheel's spin error, and a sliding wheel has only its
    own spin inertia J = m_w R_w^2 / 2 behind it: one period T moves its rate by T / J times the torque change, so
    the loop's gain per sample is T |tau| / (J margin). With the 10 rad/s default and 4 N.m that is 3.8, and above
    2 the loop does not settle: a rover stalled at a step (CEDRA, 0.5 R_w, mu 0.4) had wheel 1 swapping between
    -0.1 and 8.0 rad/s and 3.1 and -0.2 N.m on alternate samples, for good. The margin is at least 2 T |tau| / J
    (75 rad/s at 4 N.m), so the guard's gain is at most 1/2, and with the rolling-rate hold's (ctrl.roll_kp T / J,
    0.95 by default) the sum stays below 2."""
    return ca.fmax(p["ctrl.spin_margin"], 2 * ca.fabs(tau) * p["ctrl.period"] / (p["m_w"] * p["R_w"] ** 2 / 2))


def _estimate(loads, p, tau, group_of):
    """The balance's normal forces for the commanded torques (wheel k in group group_of[k - 1]; a group's traction
    is the mean of its wheels' torques) and the largest friction ratio they ask of a loaded wheel; every rover's
    controller."""
    n0, B = loads
    members = {g: [k for k in WHEELS if group_of[k - 1] == g] for g in range(n0.numel())}
    traction = ca.vertcat(*[sum(tau[k - 1] for k in m) / (len(m) * p["R_w"]) for m in members.values()])
    normal = n0 + B @ traction
    ratios = [ca.if_else(normal[g] > 0, ca.fabs(traction[g]) / ca.fmax(normal[g], 1e-9), 0) for g in members]
    return [normal[group_of[k - 1]] for k in WHEELS], ca.mmax(ca.vertcat(*ratios))


def _commands_and_trims(i, p, xd, three):
    """The ramped commands (cmd_v, cmd_yaw), the measured forward speed v and the next speed and yaw-rate trims
    (xd[7], xd[8]: integral on the measured speed and yaw rate, within TRIM_LIMITS); every rover's controller."""
    T = p["ctrl.period"]
    # the ramp counts samples (xd[9] = k T at sample k), so it is the same whatever time arithmetic a master uses
    ramp = ca.if_else(p["ctrl.ramp_time"] > 0, ca.fmin(1, xd[9] / p["ctrl.ramp_time"]), 1)
    cmd_v = i["cmd.v"] * ramp
    cmd_yaw = i["cmd.yaw_rate"] * ramp if three else 0
    v = i["body.vx"] * ca.cos(i["body.yaw"]) + i["body.vy"] * ca.sin(i["body.yaw"]) if three else i["body.vx"]
    trim_v = ca.fmin(ca.fmax(xd[7] + p["ctrl.trim_ki"] * (cmd_v - v) * T, -TRIM_LIMITS[0]), TRIM_LIMITS[0])
    trim_w = ca.fmin(ca.fmax(xd[8] + p["ctrl.trim_ki"] * (cmd_yaw - i["body.wz"]) * T, -TRIM_LIMITS[1]),
                     TRIM_LIMITS[1]) if three else 0
    return cmd_v, cmd_yaw, v, trim_v, trim_w


def _sample_symbols(ins, pars):
    """A controller's sample arguments (inp, par, xd as in STATES) and its inputs and parameters by name."""
    inp, par, xd = ca.SX.sym("inp", len(ins)), ca.SX.sym("par", len(pars)), ca.SX.sym("xd", len(STATES))
    return inp, par, xd, {q.name: inp[k] for k, q in enumerate(ins)}, {q.name: par[k] for k, q in enumerate(pars)}


def sample_function(dims: str) -> ca.Function:
    """cedra_sample(inp, par, xd) -> (y, xd_next); xd as in STATES."""
    ins, pars, outs = inputs(dims), params(), outputs(dims)
    inp, par, xd, i, p = _sample_symbols(ins, pars)
    three = dims == "3d"
    T, lim = p["ctrl.period"], p["ctrl.tau_max"]
    cmd_v, cmd_yaw, v, trim_v, trim_w = _commands_and_trims(i, p, xd, three)
    s = drive_symbols()
    values = dict(xdot_d=cmd_v + trim_v, phidot_d=cmd_yaw + trim_w,
                  theta=ca.vertcat(i["bogie.theta[1]"], i["bogie.theta[2]"], i["fork.theta4"]),
                  theta_dot=ca.vertcat(i["bogie.rate[1]"], i["bogie.rate[2]"], i["fork.rate4"]),
                  psi=ca.vertcat(*[i[f"wheel[{k}].psi_R"] for k in WHEELS]),
                  psi_dot=ca.vertcat(*[i[f"wheel[{k}].psi_R_rate"] for k in WHEELS]),
                  xi=ca.vertcat(*[i[f"wheel[{k}].xi"] for k in WHEELS]),
                  steer=ca.vertcat(i["steer.theta[1]"], i["steer.theta[2]"]) if three else ca.DM.zeros(2),
                  par=ca.vertcat(*[p[n] for n in KIN_PARAMS]))
    e = drive_expressions(s)

    def at(expr, vals):
        return ca.substitute([expr], [s[k] for k in vals], list(vals.values()))[0]

    rates = at(e["rates"], values)
    # the steered wheels point at the turn center of the COMMANDED motion: the trims (skid and slip corrections)
    # act through the wheel rates only, so the axles stay on the center the rover is asked to turn about
    steer = at(e["steer"], dict(values, xdot_d=cmd_v, phidot_d=cmd_yaw))
    # a turn center close beside a steered wheel asks for more than its servo can turn: the servo's range it is
    steer = ca.fmin(ca.fmax(steer, -STEER_LIMIT), STEER_LIMIT)
    speed_tau, speed_int = _pi(cmd_v - v, xd[0], p["ctrl.speed_kp"], p["ctrl.speed_ki"], lim, T)
    ik = [_pi(rates[k] - i[f"wheel[{k + 1}].omega"], xd[1 + k], p["ctrl.rate_kp"], p["ctrl.rate_ki"], lim, T)
          for k in range(6)]
    mode = p["ctrl.mode"]
    loads = _loads(dims, i, p)
    demand, traction_int, runup = _traction_speed_loop(p, xd, cmd_v, v)
    traction = (_traction_control(dims, i, p, loads, demand), traction_int, runup)
    tau, xd_next, phase = _select(mode, (speed_tau, speed_int), ik, traction, xd, trim_v, trim_w, T)
    fn_est, ratio = _estimate(loads, p, tau, [_group(dims, k) for k in WHEELS])
    y = tau + ([steer[0], steer[1]] if three else []) + [rates[k] for k in range(6)] + [v] + fn_est + [ratio, phase]
    assert len(y) == len(outs)
    return ca.Function("cedra_sample", [inp, par, xd], [ca.vertcat(*y), xd_next], ["inp", "par", "xd"],
                       ["y", "xd_next"])


def shipped_controller(name: str) -> ModelSpec:
    """The spec of the shipped controller FMU `name` (CONTROLLERS)."""
    if name not in CONTROLLERS:
        raise ValueError(f"no drive controller {name!r} ({', '.join(CONTROLLERS)})")
    rover, dims = CONTROLLERS[name]
    return controller_spec(dims, name, rover)


def controller_spec(dims: str = "3d", name: str | None = None, rover: str = "cedra") -> ModelSpec:
    """The drive controller for a 2D or 3D plant of `rover` (cedra.models.rovers): CEDRA's (3D: with steering and
    the yaw rate command), or another rover's (rover_controller_spec)."""
    if dims not in ("2d", "3d"):
        raise ValueError(f"dims must be 2d or 3d, got {dims!r}")
    if rover != "cedra":
        return rover_controller_spec(rover, dims, name)
    spec = ModelSpec(
        name=name or f"drive{dims[0]}d", block="controller",
        description=f"CEDRA drive controller ({dims}): the paper's inverse kinematics (Eqs. 9-13) and geometric "
        "steering (Eqs. 14-22) with a PI loop per wheel rate, or the paper's equal-torque speed loop; sampled "
        "every ctrl.period",
        q_names=[], z_names=[], params=params(), inputs=inputs(dims), outputs=outputs(dims), q_start=[],
        settle_idx=[], functions={"cedra_sample": sample_function(dims)}, d_names=list(STATES), stop_time=15.0,
        output_interval=0.01)
    spec.check()
    return spec


# ---------------------------------------------------------------- any other rover: its description's kinematics

ROVER_MODES = ("equal_torques", "inverse_kinematics", "traction_control")      # modes 0, 1, 2
_ROVER_CTRL = ("ctrl.period", "ctrl.tau_max", "ctrl.ramp_time", "ctrl.speed_kp", "ctrl.speed_ki", "ctrl.rate_kp",
               "ctrl.rate_ki", "ctrl.trim_ki", "ctrl.spin_margin", "ctrl.ratio_max", "ctrl.roll_kp", "ctrl.runup_v",
               "ctrl.stall_time", "ctrl.backoff_time", "ctrl.runup_time")


def _rover_kind(rover: str):
    from cedra.models.rovers import ROVERS
    if rover not in ROVERS:
        raise ValueError(f"unknown rover {rover!r} ({', '.join(ROVERS)})")
    return ROVERS[rover]


def rover_params(rover: str, dims: str) -> list[Quantity]:
    """The parameters of `rover`'s controller: CEDRA's controller's loops and the geometry, masses and stops its
    inverse kinematics and its quasi-static balance depend on."""
    kind = _rover_kind(rover)
    ours = {q.name: q for q in params()}
    table = {q.name: q for q in kind.parameters}
    mode = Quantity("ctrl.mode", 1, "1", "0 equal torques from a PI on the forward speed (straight: the yaw rate "
                    "command acts in mode 1); 1 inverse kinematics (the rover's wheel Jacobians, skid steering) with "
                    "a PI loop per wheel rate; 2 traction control: the speed PI's summed torque distributed for the "
                    "least largest friction ratio (straight)", 0, len(ROVER_MODES) - 1, type="Integer")
    trim = ours["ctrl.trim_ki"]
    trim = Quantity(trim.name, trim.start, trim.unit, "inverse-kinematics mode: integral gain of the speed and "
                    "yaw-rate trims (0: the inverse kinematics open loop)", trim.min, trim.max)
    loops = [{"ctrl.trim_ki": trim}.get(n, ours[n]) for n in _ROVER_CTRL]
    loops.insert(1, mode)                                       # after ctrl.period, as in CEDRA's
    kinematics = drive_kinematics(kind, dims).params
    names = kinematics + tuple(n for n in rover_statics(kind, dims).params if n not in kinematics)
    geometry = [Quantity(n, table[n].start, table[n].unit, table[n].description + " (the controller's kinematics)",
                         table[n].min, table[n].max) for n in names]
    return loops + geometry


def rover_inputs(rover: str, dims: str) -> list[Quantity]:
    """The controller's inputs: the commands and the plant outputs it measures, with the plant's names."""
    dk = drive_kinematics(_rover_kind(rover), dims)
    three = dims == "3d"
    ins = [Quantity("cmd.v", 0.0, "m/s", "commanded forward speed (along the body's heading)", -5.0, 5.0)]
    if three:
        ins.append(Quantity("cmd.yaw_rate", 0.0, "rad/s", "commanded yaw rate (positive turns left; skid steering)",
                            -5.0, 5.0))
    ins.append(Quantity("body.vx", 0.0, "m/s", "measured: body velocity along world X"))
    if three:
        ins += [Quantity("body.vy", 0.0, "m/s", "measured: body velocity along world Y"),
                Quantity("body.yaw", 0.0, "rad", "measured: body yaw"),
                Quantity("body.wx", 0.0, "rad/s", "measured: body angular velocity about world X")]
    # the traction mode's rolling rates need the body's vertical motion too (an IMU's)
    ins.append(Quantity("body.vz", 0.0, "m/s", "measured: body velocity along world Z"))
    ins.append(Quantity("body.wy", 0.0, "rad/s", "measured: body angular velocity about world Y"))
    if three:
        ins.append(Quantity("body.wz", 0.0, "rad/s", "measured: body yaw rate (angular velocity about world Z)"))
    ins.append(Quantity("body.pitch", 0.0, "rad", "measured: body pitch (positive nose down)"))
    if three:
        ins.append(Quantity("body.roll", 0.0, "rad", "measured: body roll"))
    ins += [Quantity(a, 0.0, "rad", f"measured: joint angle {n}") for n, a in zip(dk.joints, dk.angle_outputs)]
    ins += [Quantity(r, 0.0, "rad/s", f"measured: joint rate of {n}") for n, r in zip(dk.joints, dk.rate_outputs)
            if r is not None]
    for i in WHEELS:
        ins += [Quantity(f"wheel[{i}].omega", 0.0, "rad/s", f"measured: wheel {i} spin rate"),
                Quantity(f"wheel[{i}].psi_R", 0.0, "rad", f"measured: wheel {i} contact angle in the rover frame")]
    return ins


def rover_outputs(rover: str, dims: str) -> list[Quantity]:
    outs = [Quantity(f"tau[{i}]", 0.0, "N.m", f"motor torque command of wheel {i}") for i in WHEELS]
    outs += [Quantity(f"ctrl.omega_ref[{i}]", 0.0, "rad/s", f"wheel {i} rate from the inverse kinematics (its "
                      "rolling rate for the trimmed commands)") for i in WHEELS]
    outs.append(Quantity("ctrl.v", 0.0, "m/s", "measured forward speed the controller used"))
    return outs + _estimate_outputs()


def _rover_loads_and_rolling(kind, dims, i, p):
    """The quasi-static balance of `kind` at the measured pose, N = N0 + B T per wheel group, and every wheel's
    rolling rate for the measured motion (cedra.mechanics.statics)."""
    st = rover_statics(kind, dims)
    dk = drive_kinematics(kind, dims)
    three = dims == "3d"
    zero = ca.SX(0)
    pose = (i["body.pitch"], i["body.roll"] if three else zero, ca.vertcat(*[i[a] for a in dk.angle_outputs]),
            ca.vertcat(*[i[f"wheel[{k}].psi_R"] for k in WHEELS]), ca.vertcat(*[p[n] for n in st.params]))
    A, b = st.balance(*pose)
    n0, B, _, _ = loads_given_tractions(A, b, len(st.groups), three)
    velocity, omega = _body_motion(i, three)
    rates = ca.vertcat(*[i[r] if r is not None else 0 for r in dk.rate_outputs])
    return (n0, B), st.rolling(*pose, velocity, omega, rates)


def rover_sample_function(rover: str, dims: str) -> ca.Function:
    """cedra_sample(inp, par, xd) -> (y, xd_next) of `rover`'s controller; xd as in STATES (the loops of CEDRA's
    three modes; the wheel rates from cedra.mechanics.drive_kinematics, the balance and the rolling rates from
    cedra.mechanics.statics)."""
    kind = _rover_kind(rover)
    dk = drive_kinematics(kind, dims)
    ins, pars, outs = rover_inputs(rover, dims), rover_params(rover, dims), rover_outputs(rover, dims)
    inp, par, xd, i, p = _sample_symbols(ins, pars)
    three = dims == "3d"
    T, lim = p["ctrl.period"], p["ctrl.tau_max"]
    cmd_v, cmd_yaw, v, trim_v, trim_w = _commands_and_trims(i, p, xd, three)
    zero = ca.SX(0)
    rates = dk.function(cmd_v + trim_v, cmd_yaw + trim_w, i["body.pitch"], i["body.roll"] if three else zero,
                        i["body.wx"] if three else zero, i["body.wy"],
                        ca.vertcat(*[i[a] for a in dk.angle_outputs]),
                        ca.vertcat(*[i[r] if r is not None else 0 for r in dk.rate_outputs]),
                        ca.vertcat(*[i[f"wheel[{k}].psi_R"] for k in WHEELS]),
                        ca.vertcat(*[p[n] for n in dk.params]))
    speed_tau, speed_int = _pi(cmd_v - v, xd[0], p["ctrl.speed_kp"], p["ctrl.speed_ki"], lim, T)
    ik = [_pi(rates[k] - i[f"wheel[{k + 1}].omega"], xd[1 + k], p["ctrl.rate_kp"], p["ctrl.rate_ki"], lim, T)
          for k in range(6)]
    mode = p["ctrl.mode"]
    st = rover_statics(kind, dims)
    loads, rolling = _rover_loads_and_rolling(kind, dims, i, p)
    demand, traction_int, runup = _traction_speed_loop(p, xd, cmd_v, v)
    traction = (_guarded(_traction_torques(loads, p, demand, st.multiplicity, st.group_of), i, p, rolling),
                traction_int, runup)
    tau, xd_next, phase = _select(mode, (speed_tau, speed_int), ik, traction, xd, trim_v, trim_w, T)
    fn_est, ratio = _estimate(loads, p, tau, st.group_of)
    y = tau + [rates[k] for k in range(6)] + [v] + fn_est + [ratio, phase]
    assert len(y) == len(outs)
    return ca.Function("cedra_sample", [inp, par, xd], [ca.vertcat(*y), xd_next], ["inp", "par", "xd"],
                       ["y", "xd_next"])


def rover_controller_spec(rover: str, dims: str = "3d", name: str | None = None) -> ModelSpec:
    """The drive controller of a rover other than CEDRA: modes 0, 1 and 2 with the inverse kinematics, the
    quasi-static balance and the rolling rates of its own description (cedra.mechanics.drive_kinematics,
    cedra.mechanics.statics); no steering (a turn is skid-steered through the wheel rates)."""
    kind = _rover_kind(rover)
    if kind.steering:
        raise ValueError(f"rover {rover}: a controller for a rover with steering joints is CEDRA's only")
    spec = ModelSpec(
        name=name or f"{rover}_drive{dims[0]}d", block="controller",
        description=f"{rover} drive controller ({dims}): the inverse kinematics of the rover's own description "
        "(every wheel's rolling rate for the commanded speed and yaw rate at the measured pose, joints and contact "
        "angles; skid steering) with a PI loop per wheel rate, equal torques from a speed loop, or traction control "
        "(the speed loop's summed torque at one friction ratio on every wheel); sampled every ctrl.period",
        q_names=[], z_names=[], params=rover_params(rover, dims), inputs=rover_inputs(rover, dims),
        outputs=rover_outputs(rover, dims), q_start=[], settle_idx=[],
        functions={"cedra_sample": rover_sample_function(rover, dims)}, d_names=list(STATES), stop_time=15.0,
        output_interval=0.01)
    spec.check()
    return spec
