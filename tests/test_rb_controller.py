"""The rocker-bogie's drive controller: its inverse kinematics (cedra.mechanics.drive_kinematics, formed from the
rover's description) against independent computations, and the FMUs rb_drive2d, rb_drive3d in the loop with the
rocker-bogie's plants: a skid-steered turn on flat ground follows the command, and the paper's bump is crossed in
every mode, traction control asking less friction than the inverse kinematics. (Its balance:
tests/test_statics.py.)
(The checkers every shipped controller passes run over CONTROLLERS in tests/test_controller.py and
tests/test_fmu_misuse.py.)"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from cedra.mechanics.drive_kinematics import drive_kinematics
from cedra.mechanics.transforms import rot_x, rot_y
from cedra.models.controller import rover_sample_function, shipped_controller
from cedra.rover import kinematics
from cedra.rover.mechanism import CEDRA
from cedra.rover.parameters import DEFAULTS as CEDRA_DEFAULTS
from cedra.rover.rocker_bogie import DEFAULTS, IDX, ROCKER_BOGIE
from cedra.run import scenario
from cedra.run.cosim import DriveLoop

BUILD = Path(__file__).resolve().parents[1] / "build"
RW = DEFAULTS["R_w"]


def rates(dims, v, yaw_rate=0.0, pitch=0.0, roll=0.0, wx=0.0, wy=0.0, joints=None, joint_rates=None, psi=None,
          kind=ROCKER_BOGIE, defaults=DEFAULTS):
    k = drive_kinematics(kind, dims)
    n = len(k.joints)
    joints = np.zeros(n) if joints is None else joints
    joint_rates = np.zeros(n) if joint_rates is None else joint_rates
    psi = np.zeros(6) if psi is None else psi
    par = [defaults[p] for p in k.params]
    return np.array(k.function(v, yaw_rate, pitch, roll, wx, wy, joints, joint_rates, psi, par)).ravel()


def test_the_measured_joints_are_the_plants_joint_outputs():
    assert drive_kinematics(ROCKER_BOGIE, "3d").angle_outputs == ("rocker.rho", "bogie.beta[1]", "bogie.beta[2]")
    assert drive_kinematics(ROCKER_BOGIE, "3d").rate_outputs == ("rocker.rate", "bogie.rate[1]", "bogie.rate[2]")
    assert drive_kinematics(ROCKER_BOGIE, "2d").angle_outputs == ("bogie.beta[1]",)     # 2D: rho = 0, beta_R = beta_L


def test_design_pose_on_flat_ground():
    """Level, joints still, contact normals straight up: every wheel rolls at v / R_w; with a yaw rate the left
    wheels at v - yaw_rate rocker_y, the right ones at v + yaw_rate rocker_y (skid steering)."""
    for dims in ("2d", "3d"):
        assert np.allclose(rates(dims, 0.2), 0.2 / RW, rtol=1e-12)
    half = DEFAULTS["rocker_y"]
    expected = np.array([0.2 - 0.3 * half] * 3 + [0.2 + 0.3 * half] * 3) / RW
    assert np.allclose(rates("3d", 0.2, yaw_rate=0.3), expected, rtol=1e-12)


def _centers():
    """The wheel centers as a function of the 15 full coordinates (the description's positions only)."""
    q = ca.SX.sym("q", len(IDX))
    p = {name: float(value) for name, value in DEFAULTS.items()}
    rover = ROCKER_BOGIE.describe(q, lambda e: ca.SX.zeros(e.shape), p, ca.SX.zeros(6))
    return ca.Function("centers", [q], [ca.horzcat(*[w.center for w in rover.wheels])])


def test_rates_against_finite_differences():
    """A pose with body pitch and roll, joint angles and rates, body angular velocity and a yaw rate, every wheel
    on its own contact angle: the rolling rate written by hand from the wheel centers' finite-difference
    velocities (no Jacobian), the contact frame rotated about the body's y axis and the carriers' rates about it
    (positive rho and beta lift what lies ahead, the right rocker turns by -rho)."""
    rng = np.random.default_rng(7)
    centers = _centers()
    for _ in range(5):
        pitch, roll, rho, bl, br = rng.uniform(-0.3, 0.3, 5)
        wx, wy, yaw_rate, rho_d, bl_d, br_d = rng.uniform(-0.5, 0.5, 6)
        v = rng.uniform(0.05, 0.4)
        psi = rng.uniform(-0.6, 0.6, 6)
        got = rates("3d", v, yaw_rate, pitch, roll, wx, wy, [rho, bl, br], [rho_d, bl_d, br_d], psi)
        # ZYX Euler rates at yaw 0 from omega = (wx, wy, yaw_rate): omega = (r' cos p, p', y' - r' sin p)
        roll_d = wx / np.cos(pitch)
        euler = {"yaw": yaw_rate + roll_d * np.sin(pitch), "pitch": wy, "roll": roll_d}
        q, qd = np.zeros(len(IDX)), np.zeros(len(IDX))
        for name, value in (("pitch", pitch), ("roll", roll), ("rho", rho), ("beta_L", bl), ("beta_R", br)):
            q[IDX[name]] = value
        for name, value in (("x", v), ("rho", rho_d), ("beta_L", bl_d), ("beta_R", br_d)):
            qd[IDX[name]] = value
        for name, value in euler.items():
            qd[IDX[name]] = value
        h = 1e-6
        cdot = (np.array(centers(q + h * qd)) - np.array(centers(q - h * qd))) / (2 * h)
        R = np.array(rot_y(pitch) @ rot_x(roll), dtype=float)
        up, axle = R[:, 2], R[:, 1]
        omega_body = np.array([roll_d * np.cos(pitch), wy, yaw_rate])
        carrier = [-rho_d, -rho_d - bl_d, -rho_d - bl_d, rho_d, rho_d - br_d, rho_d - br_d]   # about the axle
        for i in range(6):
            n = np.cos(psi[i]) * up + np.sin(psi[i]) * np.cross(axle, up)
            tangent = np.cross(axle, n)
            c = cdot[:, i] - np.dot(cdot[:, i], n) / n[2] * np.array([0, 0, 1.0])   # body vertical speed: free
            expected = np.dot(c, tangent) / RW - (np.dot(omega_body, axle) + carrier[i])
            assert got[i] == pytest.approx(expected, rel=1e-7, abs=1e-7), i


def test_the_same_formulation_gives_cedras_eq13():
    """Formed from CEDRA's description, the same formulation gives the paper's Eq. 13 (kinematics.wheel_rates)
    where the two agree by construction: level body, joints still, no contact-angle rates, no slip angle (the
    bogies tilted, the wheels on their own contact angles, turning)."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        theta = (*rng.uniform(-0.3, 0.3, 2), CEDRA_DEFAULTS["fork_theta4_ref"])
        psi = rng.uniform(-0.5, 0.5, 6)
        v, w = rng.uniform(0.05, 0.4), rng.uniform(-0.5, 0.5)
        general = rates("3d", v, w, joints=[*theta, 0, 0], psi=psi, kind=CEDRA, defaults=CEDRA_DEFAULTS)
        eq13 = kinematics.wheel_rates(v, w, theta, (0, 0, 0), psi, np.zeros(6), np.zeros(6), (0, 0))
        assert np.allclose(general, eq13, rtol=1e-10, atol=1e-12)


def test_a_rover_without_a_joint_output_is_refused():
    blind = dataclasses.replace(ROCKER_BOGIE, name="rb_blind", joint_outputs=lambda *a: [])
    with pytest.raises(ValueError, match="rover rb_blind: no joint output gives the angle of its joint 'rho'"):
        drive_kinematics(blind, "3d")


def test_the_controllers_geometry_and_modes():
    for name in ("rb_drive2d", "rb_drive3d"):
        spec = shipped_controller(name)
        pars = {p.name: p for p in spec.params}
        for n in ("R_w", "bogie_x", "bogie_half", "front_x"):
            assert pars[n].start == DEFAULTS[n]
        for n in ("m_B", "m_w", "g", "bogie_stop", "stop_k"):             # the balance's
            assert pars[n].start == DEFAULTS[n]
        assert (pars["ctrl.mode"].min, pars["ctrl.mode"].max) == (0, 2)
        outputs = {o.name for o in spec.outputs}
        assert {f"ctrl.Fn_est[{i}]" for i in range(1, 7)} | {"ctrl.ratio"} <= outputs
        assert not any(o.startswith("steer") for o in outputs)


def test_a_sample_has_a_fixed_cost():
    """The generated C of the rocker-bogie's sample function is straight-line code (every mode evaluated, the
    mode selects; the balance's Newton steps a fixed number)."""
    for dims in ("2d", "3d"):
        f = rover_sample_function("rocker_bogie", dims)
        code = ca.CodeGenerator("sample.c", {"with_header": False})
        code.add(f)
        text = code.dump()
        body = text[text.index("static int casadi_f0"):]
        body = body[:body.index("\n}\n")]
        assert not re.search(r"\b(for|while|goto|do)\b", body), dims
        print(f"{dims}: {f.n_instructions()} instructions")


def _run(plant, controller, stop, commands, record, **values):
    loop = DriveLoop(scenario.fmu(plant, BUILD), scenario.fmu(controller, BUILD), controller_values=values)
    try:
        r = loop.run(stop, 0.01, lambda t: commands, record=record)
    finally:
        loop.close()
    assert r.ok, r.messages[-3:]
    return r


def test_skid_steered_turn_on_flat_ground():
    """rb_flat3d + rb_drive3d (inverse kinematics) at 0.2 m/s and 0.2 rad/s: over the last 5 s of 15 s the mean
    yaw rate and speed are within 2 % of the commands (the yaw trim makes up for the skid)."""
    v_cmd, w_cmd = 0.2, 0.2
    r = _run("rb_flat3d", "rb_drive3d", 15.0, {"cmd.v": v_cmd, "cmd.yaw_rate": w_cmd},
             ["body.vx", "body.vy", "body.wz"] + [f"tau[{i}]" for i in range(1, 7)], **{"ctrl.mode": 1})
    late = r.column("time") >= 10.0
    wz = r.column("body.wz")[late].mean()
    speed = np.hypot(r.column("body.vx"), r.column("body.vy"))[late].mean()
    print(f"yaw rate {wz:.5f} rad/s ({w_cmd}), speed {speed:.5f} m/s ({v_cmd})")
    assert abs(wz / w_cmd - 1) < 0.02
    assert abs(speed / v_cmd - 1) < 0.02
    left = np.mean([r.column(f"tau[{i}]")[late].mean() for i in (1, 2, 3)])
    right = np.mean([r.column(f"tau[{i}]")[late].mean() for i in (4, 5, 6)])
    assert left < 0 < right                   # a left turn: the inner side brakes, the outer side drives


WHEELS_2D = (1, 2, 3)          # 2D: wheels 4, 5, 6 repeat 1, 2, 3


@pytest.fixture(scope="module")
def bump_runs():
    """rb_bump2d + rb_drive2d at 0.2 m/s, 15 s, in modes 0, 1 and 2 (about 0.3 s each)."""
    wheels = range(1, 7)
    rec = ["body.x", "body.vx", "body.pitch", "body.wy", "bogie.beta[1]", "bogie.rate[1]"] + \
        [f"wheel[{i}].{q}" for q in ("slip", "omega", "psi_R", "Fn", "Fx") for i in wheels] + \
        [f"ctrl.Fn_est[{i}]" for i in wheels]
    return {mode: _run("rb_bump2d", "rb_drive2d", 15.0, {"cmd.v": 0.2}, rec, **{"ctrl.mode": mode})
            for mode in (0, 1, 2)}


def test_bump_crossed_in_every_mode(bump_runs):
    """rb_bump2d + rb_drive2d at 0.2 m/s, 15 s: every mode gets over the bump; the inverse kinematics' mean slip
    stays below 1 % of the commanded speed (equal torques slip less on this rover: its six loads are equal). The
    wheel rates replayed over the equal-torque run with the measured speed in place of the command are the plant's
    wheel rates up to the wheels' small slip."""
    wheels = range(1, 7)
    slip = {}
    for mode, r in bump_runs.items():
        assert r.column("body.x")[-1] > 2.5
        slip[mode] = np.mean(np.abs([r.column(f"wheel[{i}].slip") for i in wheels]))
    print(f"mean |slip|: equal torques {slip[0]:.6f} m/s, inverse kinematics {slip[1]:.6f} m/s, traction control "
          f"{slip[2]:.6f} m/s")
    assert slip[1] < 0.002
    r, k = bump_runs[0], drive_kinematics(ROCKER_BOGIE, "2d")
    n = len(r.column("time"))
    zero = np.zeros(n)
    replay = np.array(k.function.map(n)(r.column("body.vx"), zero, r.column("body.pitch"), zero, zero,
                                        r.column("body.wy"), r.column("bogie.beta[1]")[None, :],
                                        r.column("bogie.rate[1]")[None, :],
                                        np.array([r.column(f"wheel[{i}].psi_R") for i in wheels]),
                                        np.array([DEFAULTS[p] for p in k.params])[:, None]))
    error = np.abs(replay - np.array([r.column(f"wheel[{i}].omega") for i in wheels]))
    print(f"replayed wheel rates against the plant's: mean {error.mean():.4f}, largest {error.max():.3f} rad/s")
    assert error.mean() < 0.02


def _friction_ratios(r):
    """The plant's |Fx| / Fn of the loaded wheels (Fn > 1 N) over the run."""
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in WHEELS_2D])
    fx = np.array([r.column(f"wheel[{i}].Fx") for i in WHEELS_2D])
    return np.abs(fx)[fn > 1.0] / fn[fn > 1.0]


def test_traction_control_asks_less_friction_than_inverse_kinematics_on_the_bump(bump_runs):
    """Over the bump the largest friction ratio |Fx| / Fn of a loaded wheel is lower under traction control than
    under the inverse kinematics (measured 0.235 against 0.798: at mu = 0.8 the inverse kinematics slides a
    lightly loaded wheel), and so is its 99th percentile."""
    peak = {m: float(np.max(_friction_ratios(bump_runs[m]))) for m in (1, 2)}
    q99 = {m: float(np.quantile(_friction_ratios(bump_runs[m]), 0.99)) for m in (1, 2)}
    print(f"largest |Fx|/Fn: IK {peak[1]:.3f}, traction {peak[2]:.3f}; 99th percentile IK {q99[1]:.3f}, traction "
          f"{q99[2]:.3f}")
    assert peak[2] < peak[1] and q99[2] < q99[1]
    assert peak[2] < 0.5


def test_the_load_estimate_follows_the_plants_normal_forces_on_the_bump(bump_runs):
    """Traction control's load estimate ctrl.Fn_est[i] (the balance at the measured pose for the commanded torques)
    against the plant's wheel[i].Fn over the bump: median error within 2 % of the load where a wheel carries more
    than 10 N, mean absolute error below 1 N per wheel (measured: 0.2 N)."""
    r = bump_runs[2]
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in WHEELS_2D])
    err = np.array([r.column(f"ctrl.Fn_est[{i}]") for i in WHEELS_2D]) - fn
    relative = float(np.median(np.abs(err)[fn > 10] / fn[fn > 10]))
    print(f"estimate - plant: mean |e| per wheel {np.round(np.mean(np.abs(err), axis=1), 2)} N, largest "
          f"{np.round(np.max(np.abs(err), axis=1), 1)} N, median relative {relative:.4f}")
    assert relative < 0.02
    assert np.all(np.mean(np.abs(err), axis=1) < 1.0)


def test_traction_control_in_3d_on_the_bump():
    """rb_bump3d + rb_drive3d in mode 2 (the 3D balance: least-squares lateral forces): over the bump at 0.2 m/s in
    15 s, the load estimate within 1 N of the plant's (mean absolute, per wheel; measured 0.19 to 0.22 N) and the
    largest friction ratio of a loaded wheel below 0.5 (measured 0.235, as in 2D: the bump is the same under both
    sides)."""
    wheels = range(1, 7)
    r = _run("rb_bump3d", "rb_drive3d", 15.0, {"cmd.v": 0.2}, ["body.x"] + [f"wheel[{i}].{q}" for i in wheels for q in
             ("Fn", "Fx")] + [f"ctrl.Fn_est[{i}]" for i in wheels], **{"ctrl.mode": 2})
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in wheels])
    fx = np.array([r.column(f"wheel[{i}].Fx") for i in wheels])
    error = np.mean(np.abs(np.array([r.column(f"ctrl.Fn_est[{i}]") for i in wheels]) - fn), axis=1)
    peak = float(np.max(np.abs(fx)[fn > 1.0] / fn[fn > 1.0]))
    print(f"body.x {r.column('body.x')[-1]:.3f} m, mean |estimate - plant| {np.round(error, 2)} N, peak ratio "
          f"{peak:.3f}")
    assert r.column("body.x")[-1] > 2.5
    assert np.all(error < 1.0) and peak < 0.5


def test_turn_flat_scenario_with_the_rocker_bogie(tmp_path):
    """examples/turn_flat.py with rover = "rocker_bogie" runs rb_flat3d + rb_drive3d and writes its files; an
    unknown rover is refused before anything runs."""
    turn = scenario.load("turn_flat")
    summary = turn.run(out_dir=str(tmp_path), build_dir=str(BUILD), stop_time=3.0, quiet=True, rover="rocker_bogie")
    assert summary["yaw_rate"] > 0
    assert {p.name for p in tmp_path.iterdir()} == {"turn_flat.csv", "path.png", "tracking.png"}
    with pytest.raises(scenario.ScenarioError, match="turn_flat: unknown rover 'mars'"):
        turn.run(out_dir=str(tmp_path / "no"), build_dir=str(BUILD), stop_time=1.0, quiet=True, rover="mars")
