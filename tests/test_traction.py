"""Traction control (ctrl.mode = 2, docs/model.md, Controller): the quasi-static balance against the plant's settled
loads and against a whole-rover force and moment balance, the equal-ratio distribution against an LP's optimum,
the rolling rates against the plant's rolling wheels, the controller's fixed cost, and closed loops over the
bump."""
from __future__ import annotations

import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.optimize import linprog

from cedra.mechanics.statics import equal_ratio_tractions
from cedra.models.controller import STATES, TRACTION_NEWTON_STEPS, _spin_guard, inputs, params, sample_function
from cedra.rover.mechanism import FULL_Q, IDX, describe
from cedra.rover.parameters import DEFAULTS
from cedra.rover.statics import GROUPS, STATICS_PARAMS, balance, multiplicity, rolling_rates, traction_function
from cedra.run.cosim import DriveLoop
from cedra.run.driver import RoverFMU
from cedra.run.scenario import fmu as scenario_fmu
from cedra.rover.kinematics import contact_frame
from cedra.mechanics.transforms import rot_x, rot_y, rot_z

BUILD = Path(__file__).resolve().parents[1] / "build"
PAR = [DEFAULTS[n] for n in STATICS_PARAMS]
WEIGHT = (DEFAULTS["m_B"] + DEFAULTS["m_F"] + 6 * DEFAULTS["m_w"]) * DEFAULTS["g"]


def _settled(plant):
    """The plant's settled start (start.settle: static equilibrium) and its pose and wheel loads."""
    f = RoverFMU(scenario_fmu(plant, BUILD), "plant")
    try:
        f.start({})
        names = ["body.pitch", "body.roll", "bogie.theta[1]", "bogie.theta[2]", "fork.theta4", "steer.theta[1]",
                 "steer.theta[2]"] + [f"wheel[{i}].psi_R" for i in range(1, 7)] + \
            [f"wheel[{i}].Fn" for i in range(1, 7)]
        names = [n for n in names if f.has(n)]
        return {n: float(v) for n, v in zip(names, f.get(names))}
    finally:
        f.close()


@pytest.mark.parametrize("plant,dims", [("bump2d", "2d"), ("flat3d", "3d")])
def test_flat_ground_loads_are_the_plants_settled_loads(plant, dims):
    """At rest on flat ground (no traction) the estimate is the plant's settled wheel[i].Fn within 1 %, and the
    loads sum to the rover's weight."""
    v = _settled(plant)
    theta = [v["bogie.theta[1]"], v.get("bogie.theta[2]", v["bogie.theta[1]"]), v["fork.theta4"]]
    steer = [v.get("steer.theta[1]", 0.0), v.get("steer.theta[2]", 0.0)]
    psi = [v[f"wheel[{i}].psi_R"] for i in range(1, 7)]
    _, _, normal, _, _ = traction_function(dims, TRACTION_NEWTON_STEPS)(v["body.pitch"], v.get("body.roll", 0.0),
                                                                       theta, steer, psi, PAR, 0.0)
    normal = np.array(normal).ravel()
    true = np.array([v[f"wheel[{i}].Fn"] for i in GROUPS[dims]])
    print(f"{plant}: estimate {np.round(normal, 3)} N, plant {np.round(true, 3)} N")
    assert np.all(np.abs(normal / true - 1) < 0.01)
    assert abs(np.dot(multiplicity(dims), normal) / WEIGHT - 1) < 1e-9


def _world_forces(pose, u):
    """Contact points and forces in the world of a 3D pose, from the kinematics' contact frames alone."""
    q = ca.DM.zeros(len(FULL_Q))
    for n, val in pose.items():
        if n in IDX:
            q[IDX[n]] = val
    R = np.array(ca.evalf(rot_z(0) @ rot_y(pose["pitch"]) @ rot_x(pose["roll"])))
    joints = ca.vertcat(*(q[IDX[n]] for n in ("theta1", "theta2", "theta4", "theta3", "theta6")))
    N, T, L = u[0:6], u[6:12], u[12:18]
    points, forces = [], []
    for i in range(1, 7):
        frame = np.array(ca.evalf(contact_frame(i, joints, pose["psi"][i - 1], DEFAULTS)))
        rot, center = R @ frame[:3, :3], R @ frame[:3, 3]
        points.append(center - DEFAULTS["R_w"] * rot[:, 2])
        forces.append(N[i - 1] * rot[:, 2] + T[i - 1] * rot[:, 0] + L[i - 1] * rot[:, 1])
    return q, points, forces


def test_the_balance_holds_the_whole_rover_at_a_tilted_pose():
    """Any forces that satisfy the balance at a tilted 3D pose (pitch, roll, bogies, fork, steering, contact angles)
    hold the whole rover as one rigid system: the sum of the contact forces, the weights and the d'Alembert forces
    -m a x and the sum of their moments vanish. The check uses only the kinematics' contact frames and the bodies'
    positions, not the virtual work the balance is formed with."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        pose = dict(pitch=rng.uniform(-0.3, 0.3), roll=rng.uniform(-0.2, 0.2), theta1=rng.uniform(-0.3, 0.3),
                    theta2=rng.uniform(-0.3, 0.3), theta4=DEFAULTS["fork_theta4_ref"] + rng.uniform(-0.2, 0.2),
                    theta3=rng.uniform(-0.4, 0.4), theta6=rng.uniform(-0.4, 0.4), psi=rng.uniform(-0.6, 0.6, 6))
        A, b = (np.array(m) for m in balance("3d", pose["pitch"], pose["roll"],
                                              [pose["theta1"], pose["theta2"], pose["theta4"]],
                                              [pose["theta3"], pose["theta6"]], pose["psi"], PAR))
        u = np.linalg.lstsq(A, b.ravel(), rcond=None)[0] + \
            np.linalg.svd(A)[2][-1] * 10.0                 # a solution plus a null-space direction
        assert np.allclose(A @ u, b.ravel(), atol=1e-9)
        q, points, forces = _world_forces(pose, u)
        rover = describe(q, lambda e: ca.DM.zeros(e.shape), DEFAULTS, ca.DM.zeros(6), None)
        gravity = np.array([-u[18], 0.0, -DEFAULTS["g"]])   # weight and the d'Alembert force per unit mass
        masses = [(float(ca.evalf(bd.mass)), np.array(ca.evalf(bd.position)).ravel()) for bd in rover.bodies]
        force = sum(forces) + sum(m * gravity for m, _ in masses)
        moment = sum(np.cross(p, f) for p, f in zip(points, forces)) + \
            sum(np.cross(c, m * gravity) for m, c in masses)
        print(f"residual force {np.abs(force).max():.2e} N, moment {np.abs(moment).max():.2e} N.m")
        assert np.abs(force).max() < 1e-9 * WEIGHT and np.abs(moment).max() < 1e-9 * WEIGHT


def _lp_optimum(N0, B, weights, demand):
    """min over T of max_i |T_i| / N_i(T) subject to weights' T = demand: bisection on the ratio s, each s an
    LP feasibility problem (|T_i| <= s (N0 + B T)_i) solved by HiGHS; 2^-40 of the bracket."""
    n = len(N0)

    def feasible(s):
        a_ub = np.vstack([np.eye(n) - s * B, -np.eye(n) - s * B])
        r = linprog(np.zeros(n), A_ub=a_ub, b_ub=np.concatenate([s * N0, s * N0]), A_eq=weights[None],
                    b_eq=[demand], bounds=[(None, None)] * n, method="highs")
        return r.status == 0
    lo, hi = 0.0, 4.0
    for _ in range(40):
        lo, hi = (lo, (lo + hi) / 2) if feasible((lo + hi) / 2) else ((lo + hi) / 2, hi)
    return hi


@pytest.mark.parametrize("dims", ["2d", "3d"])
def test_the_fixed_iteration_distribution_is_the_lp_optimum(dims):
    """Random poses and demands: the controller's equal-ratio tractions (TRACTION_NEWTON_STEPS Newton steps) meet
    the demand and their largest ratio is the LP's optimum within 1e-6 (relative). Poses where the balance
    leaves a wheel unloaded at that ratio (N_i < 0: the rover would tip onto the others) are not instances of the
    problem and are skipped; at least 20 of 40 remain."""
    rng = np.random.default_rng(3)
    f = traction_function(dims, TRACTION_NEWTON_STEPS)
    weights = DEFAULTS["R_w"] * np.array(multiplicity(dims), float)
    gaps = []
    for _ in range(40):
        theta = [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), DEFAULTS["fork_theta4_ref"] + rng.uniform(-0.2, 0.2)]
        steer = rng.uniform(-0.4, 0.4, 2) if dims == "3d" else np.zeros(2)
        demand = rng.uniform(0.5, 12.0)
        out = f(rng.uniform(-0.3, 0.3), rng.uniform(-0.15, 0.15) if dims == "3d" else 0.0, theta, steer,
                rng.uniform(-0.6, 0.6, 6), PAR, demand)
        T, _, N, N0, B = (np.array(x) for x in out)
        T, N, N0 = T.ravel(), N.ravel(), N0.ravel()
        if N.min() <= 0:
            continue
        assert abs(weights @ T - demand) < 1e-9 * demand
        gaps.append(np.max(np.abs(T) / N) / _lp_optimum(N0, B, weights, demand) - 1)
    print(f"{len(gaps)} instances, largest relative gap to the LP {max(np.abs(gaps)):.2e}")
    assert len(gaps) >= 20
    assert max(np.abs(gaps)) < 1e-6


def test_a_demand_past_ratio_max_is_shared_at_the_loads_of_ratio_max():
    """A demand the capped ratio cannot pass (a stall) keeps the loads the balance gives at ratio_max and shares
    the demand in proportion to them; a demand within it is the uncapped solution; the two meet at the cap."""
    f = traction_function("2d", TRACTION_NEWTON_STEPS)
    out = f(-0.05, 0.0, [0.05, 0.05, DEFAULTS["fork_theta4_ref"]], [0.0, 0.0], [-0.3, 0, -0.3, 0, 0, 0], PAR, 1.0)
    N0, B = ca.DM(out[3]), ca.DM(out[4])        # wheels 1, 3 on a 17 degree face
    weights = DEFAULTS["R_w"] * ca.DM(multiplicity("2d"))
    cap = 0.6
    held = {sign: np.array(ca.solve(ca.DM.eye(4) - sign * cap * B, N0)).ravel() for sign in (1, -1)}
    passes = {sign: cap * float(weights.T @ held[sign]) for sign in (1, -1)}    # the demand the cap passes
    assert held[1].min() > 0
    for demand in (0.3 * passes[1], 0.999 * passes[1], 1.001 * passes[1], 4 * passes[1], -0.5 * passes[-1],
                   -4 * passes[-1]):
        T, s, N = (np.array(x).ravel() for x in equal_ratio_tractions(N0, B, weights, demand, TRACTION_NEWTON_STEPS,
                                                                      cap))
        T0, s0, _ = (np.array(x).ravel() for x in equal_ratio_tractions(N0, B, weights, demand,
                                                                        TRACTION_NEWTON_STEPS))
        assert abs(float(weights.T @ T) - demand) < 1e-9 * abs(demand)
        if abs(demand) <= passes[np.sign(demand)]:
            assert np.allclose(T, T0, rtol=1e-9) and abs(s - s0) < 1e-9
        else:
            assert np.allclose(N, held[np.sign(demand)], rtol=1e-12)
            assert np.allclose(T, s * N) and abs(s) > cap
    near = [np.array(equal_ratio_tractions(N0, B, weights, d, TRACTION_NEWTON_STEPS, cap)[0]).ravel()
            for d in (passes[1] * (1 - 1e-7), passes[1] * (1 + 1e-7))]
    assert np.allclose(near[0], near[1], rtol=1e-5)                        # continuous at the cap


@pytest.mark.parametrize("dims", ["2d", "3d"])
def test_the_spin_guard_settles_a_sliding_wheel(dims):
    """A wheel sliding against a constant friction torque, under the sampled spin guard and rolling-rate hold
    (its own spin inertia only, one controller period per step, the controller's function in the loop) settles
    to one rate, whatever the speed loop asks. The guard faded over the bare ctrl.spin_margin (10 rad/s, the
    same loop in Python) swaps between two rates for good at the largest demand's torque: the test can fail."""
    f = sample_function(dims)
    ins, pars = inputs(dims), params()
    p = {q.name: q.start for q in pars} | {"ctrl.mode": 2}
    J = DEFAULTS["m_w"] * DEFAULTS["R_w"] ** 2 / 2
    T, friction = p["ctrl.period"], 0.5

    def controller(u):                   # wheel 1's torque at its rate, the speed loop asking u N.m per wheel
        xd = np.zeros(len(STATES))
        xd[0] = u / p["ctrl.speed_ki"]   # the integral that asks u at no speed error
        inp = {q.name: q.start for q in ins} | {"cmd.v": 0.0}
        return lambda omega: float(f([(inp | {"wheel[1].omega": omega})[q.name] for q in ins],
                                     [p[q.name] for q in pars], xd)[0][0])

    def settle(torque_at):
        omega, rates = 0.0, []
        for _ in range(300):
            omega += T / J * (torque_at(omega) - friction)
            rates.append(omega)
        return np.array(rates[-50:])

    for u in (1.0, 2.0, 4.0):
        tau = controller(u)
        rates = settle(tau)
        assert tau(0.0) > friction and np.ptp(rates) < 1e-6, (u, tau(0.0), rates[-4:])
    full = controller(4.0)(0.0)          # wheel 1's share of the largest demand (the speed loop at its limit)
    assert full > 2.0
    bare = settle(lambda omega: float(_spin_guard(full, omega, 0.0, p["ctrl.spin_margin"]))
                  - p["ctrl.roll_kp"] * omega)
    assert np.ptp(bare) > 1.0


def test_a_sample_has_a_fixed_cost():
    """The generated C of cedra_sample is straight-line code: no loop, no jump, so every sample runs the same
    instructions whatever the mode and the measurements (every mode is evaluated and the mode selects)."""
    for dims in ("2d", "3d"):
        f = sample_function(dims)
        code = ca.CodeGenerator("sample.c", {"with_header": False})
        code.add(f)
        text = code.dump()
        body = text[text.index("static int casadi_f0"):]
        body = body[:body.index("\n}\n")]
        assert not re.search(r"\b(for|while|goto|do)\b", body), dims
        print(f"{dims}: {f.n_instructions()} instructions")


@pytest.fixture(scope="module")
def bump_climb():
    """4 s over the bump's rising flank (the rover starts 0.7 m before its top) in modes 1 and 2."""
    rec = [f"wheel[{i}].{q}" for i in (1, 2, 5, 6) for q in ("Fn", "Fx")] + ["body.x", "ctrl.ratio"]
    runs = {}
    for mode in (1, 2):
        loop = DriveLoop(scenario_fmu("bump2d", BUILD), scenario_fmu("drive2d", BUILD),
                         plant_values={"start.x": 0.3}, controller_values={"ctrl.mode": mode})
        try:
            runs[mode] = loop.run(4.0, 0.01, lambda t: {"cmd.v": 0.2}, record=rec)
        finally:
            loop.close()
        assert runs[mode].ok, runs[mode].messages[-3:]
    return runs


def _ratios(r):
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in (1, 2, 5, 6)])
    fx = np.array([r.column(f"wheel[{i}].Fx") for i in (1, 2, 5, 6)])
    return np.abs(fx)[fn > 1.0] / fn[fn > 1.0]


def test_traction_control_asks_less_friction_than_inverse_kinematics_on_the_bump(bump_climb):
    """The plant's friction ratios |Fx| / Fn over the climb: mode 2's 99th percentile is below mode 1's, and
    fewer of its samples are at the friction limit (mu = 0.8); both move on at about the commanded speed."""
    q99 = {m: np.quantile(_ratios(r), 0.99) for m, r in bump_climb.items()}
    sliding = {m: int(np.sum(_ratios(r) > 0.79)) for m, r in bump_climb.items()}
    print(f"99th percentile of |Fx|/Fn: IK {q99[1]:.3f}, traction {q99[2]:.3f}; samples at the limit: {sliding}")
    assert q99[2] < q99[1]
    assert sliding[2] <= sliding[1]
    for r in bump_climb.values():
        assert r.column("body.x")[-1] > 0.3 + 0.6


def test_a_stalled_climb_does_not_spin_a_wheel_up():
    """3 R_w at mu 0.4 (plain torques: the bump2d plant has no drives) stalls the rover on the bump; the balance
    still gives a lifted wheel a load, and without the spin guard its torque spun it to 29,000 rad/s. With it no
    wheel turns faster than 60 rad/s over 15 s (measured: 22.5 rad/s; the inverse kinematics' rate loops: 43)."""
    rec = [f"wheel[{i}].omega" for i in (1, 2, 5, 6)] + ["body.x"]
    loop = DriveLoop(scenario_fmu("bump2d", BUILD), scenario_fmu("drive2d", BUILD),
                     plant_values={"terrain_h": 0.195, "mu": 0.4}, controller_values={"ctrl.mode": 2})
    try:
        r = loop.run(15.0, 0.01, lambda t: {"cmd.v": 0.2}, record=rec)
    finally:
        loop.close()
    assert r.ok, r.messages[-3:]
    spin = max(float(np.max(np.abs(r.column(n)))) for n in rec[:-1])
    print(f"largest wheel rate {spin:.1f} rad/s, body.x {r.column('body.x')[-1]:.3f} m")
    assert spin < 60.0, spin
    assert r.column("body.x")[-1] < 1.0                 # stalled on the bump (at x = 1 m), as the other modes are


MEASURED = ["body.vx", "body.vz", "body.wy", "body.pitch", "bogie.theta[1]", "bogie.rate[1]", "fork.theta4",
            "fork.rate4"] + [f"wheel[{i}].{q}" for i in (1, 2, 5, 6) for q in ("omega", "psi_R", "Fn", "Fx")]


@pytest.fixture(scope="module")
def paper_runs():
    """The paper's run (bump2d from its start, 0.2 m/s, 15 s) in modes 1 and 2, with what the rolling rates need."""
    runs = {}
    for mode in (1, 2):
        loop = DriveLoop(scenario_fmu("bump2d", BUILD), scenario_fmu("drive2d", BUILD),
                         controller_values={"ctrl.mode": mode})
        try:
            runs[mode] = loop.run(15.0, 0.01, lambda t: {"cmd.v": 0.2}, record=MEASURED)
        finally:
            loop.close()
        assert runs[mode].ok, runs[mode].messages[-3:]
    return runs


def _rolling(r):
    """rover.statics.rolling_rates at every sample of a 2D run: (samples, wheels 1, 2, 5, 6)."""
    f = lambda n: r.column(n)                                              # noqa: E731
    psi = [f(f"wheel[{ {3: 1, 4: 2}.get(i, i)}].psi_R") for i in range(1, 7)]
    out = []
    for k in range(len(f("time"))):
        theta = [f("bogie.theta[1]")[k], f("bogie.theta[1]")[k], f("fork.theta4")[k]]
        rates = rolling_rates("2d", f("body.pitch")[k], 0.0, theta, [0.0, 0.0], [p[k] for p in psi], PAR,
                              [f("body.vx")[k], 0.0, f("body.vz")[k]], [0.0, f("body.wy")[k], 0.0],
                              [f("bogie.rate[1]")[k], f("bogie.rate[1]")[k], f("fork.rate4")[k]])
        out.append(np.array(rates).ravel()[[0, 1, 4, 5]])
    return np.array(out)


def test_the_rolling_rates_are_the_rates_of_the_wheels_that_roll(paper_runs):
    """Where a wheel carries load and asks well below the friction limit (it rolls, up to the friction law's small
    slip), its measured spin rate is the rolling rate the controller computes from the body's measured motion,
    the joint rates and the contact angle, within 0.15 rad/s (measured 0.12 rad/s; Eq. 13 for the commanded
    speed misses by up to 14 rad/s on the bump: it projects the body's vertical and pitch motion out)."""
    r = paper_runs[2]
    rolling = _rolling(r)
    worst = 0.0
    for k, i in enumerate((1, 2, 5, 6)):
        fn, fx = r.column(f"wheel[{i}].Fn"), r.column(f"wheel[{i}].Fx")
        rolls = (fn > 5.0) & (np.abs(fx) < 0.5 * fn)
        worst = max(worst, float(np.max(np.abs(r.column(f"wheel[{i}].omega") - rolling[:, k])[rolls])))
    print(f"largest |omega - rolling rate| of a rolling wheel: {worst:.3f} rad/s")
    assert worst < 0.15


def test_a_lifted_wheel_lands_at_its_rolling_rate(paper_runs):
    """Over the bump wheels leave the ground and land again. Traction control holds a lifted wheel at its rolling
    rate, so at the last sample before a touchdown its spin rate is within 1 rad/s of it (median) and 6 rad/s
    (worst; measured 0.52 and 4.7 rad/s over 11 touchdowns), where the inverse kinematics' rate loops (Eq. 13 for
    the command) miss by more (6.6 and 27 rad/s over 19); and it slides (|Fx| / Fn above 0.79, mu = 0.8) at no
    more than two samples x wheels (measured: one, wheel 5 landing at t = 4.09 s) against hundreds (212)."""
    misses, sliding = {}, {}
    for mode, r in paper_runs.items():
        rolling = _rolling(r)
        misses[mode], sliding[mode] = [], 0
        for k, i in enumerate((1, 2, 5, 6)):
            fn, omega = r.column(f"wheel[{i}].Fn"), r.column(f"wheel[{i}].omega")
            air = fn <= 0
            misses[mode] += list(np.abs(omega - rolling[:, k])[np.where(air[:-1] & ~air[1:])[0]])
            loaded = fn > 1.0
            sliding[mode] += int(np.sum(np.abs(r.column(f"wheel[{i}].Fx"))[loaded] > 0.79 * fn[loaded]))
    print({m: f"{len(v)} touchdowns, median miss {np.median(v):.2f}, worst {np.max(v):.2f} rad/s"
           for m, v in misses.items()}, "sliding samples", sliding)
    assert np.median(misses[2]) < 1.0 and np.max(misses[2]) < 6.0
    assert np.median(misses[1]) > np.median(misses[2])
    assert sliding[2] <= 2 < sliding[1]


def _phases(f, ins, outs, pars, values, speed_at, seconds):
    """ctrl.phase and the summed torque at every sample of `seconds` of a controller's sample function fed a
    commanded 0.2 m/s and the measured speed speed_at(phase) (the rest of its inputs at their start values)."""
    inp = {q.name: q.start for q in ins} | {"cmd.v": 0.2}
    par = [({q.name: q.start for q in pars} | values)[q.name] for q in pars]
    iy_phase, iy_tau = outs.index("ctrl.phase"), [outs.index(f"tau[{k}]") for k in range(1, 7)]
    xd, phase, history = np.zeros(len(STATES)), 0.0, []
    for _ in range(round(seconds / 0.01)):
        y, xd = f([(inp | {"body.vx": speed_at(phase)})[q.name] for q in ins], par, xd)
        y, xd = np.array(y).ravel(), np.array(xd).ravel()
        phase = y[iy_phase]
        history.append((phase, float(np.sum(y[iy_tau]))))
    return np.array(history)


def _assert_runs(phases, expected):
    """The phases of a history run as expected: (phase, samples), each but the last within two samples (the timers
    add periods, and a phase starts at the sample its timer passes)."""
    runs = [(int(p[0]), len(p)) for p in np.split(phases, np.flatnonzero(np.diff(phases)) + 1)]
    assert [r[0] for r in runs] == [e[0] for e in expected], runs
    assert all(abs(r[1] - e[1]) <= 2 for r, e in zip(runs[:-1], expected[:-1])), (runs, expected)


@pytest.mark.parametrize("rover", ["cedra", "rocker_bogie"])
def test_a_stalled_rover_backs_off_and_takes_a_run_up(rover):
    """Mode 2's stall recovery, sample by sample: a rover that does not move at the commanded 0.2 m/s has stalled
    once its speed loop has wound up to the torque limit and stayed there for ctrl.stall_time; it backs off for
    ctrl.backoff_time (the summed torque turns negative), takes a run-up at ctrl.runup_v (more torque than the
    command's loop asked at the same speed), and stalls again within it if it still does not move; a run-up that
    makes its speed lasts ctrl.runup_time and the command holds again. With ctrl.runup_v = 0, in mode 1, or at no
    command, it never leaves phase 0."""
    from cedra.models.controller import outputs, rover_inputs, rover_outputs, rover_params, rover_sample_function
    if rover == "cedra":
        f, ins, outs, pars = sample_function("2d"), inputs("2d"), [q.name for q in outputs("2d")], params()
    else:
        f, ins = rover_sample_function(rover, "2d"), rover_inputs(rover, "2d")
        outs, pars = [q.name for q in rover_outputs(rover, "2d")], rover_params(rover, "2d")
    p = {q.name: q.start for q in pars}
    T = p["ctrl.period"]

    def samples_to_stall(speed):       # the PI's integral from 0 to the limit at a constant error, then stall_time
        wind = (p["ctrl.tau_max"] - p["ctrl.speed_kp"] * speed) / (p["ctrl.speed_ki"] * speed * T)
        return wind + p["ctrl.stall_time"] / T

    back, run, drive = p["ctrl.backoff_time"] / T, p["ctrl.runup_time"] / T, samples_to_stall(0.2)
    stuck = _phases(f, ins, outs, pars, {"ctrl.mode": 2}, lambda phase: 0.0, 9.9)
    _assert_runs(stuck[:, 0], [(0, drive), (1, back), (2, samples_to_stall(p["ctrl.runup_v"])), (1, back), (2, 0)])
    torque = {phase: stuck[int(start + 50), 1] for phase, start in ((0, 0), (1, drive), (2, drive + back))}
    assert torque[1] < 0 < torque[0] < torque[2], torque
    # a run-up that makes its speed (half of ctrl.runup_v measured) is not a stall; then the command's speed again
    moving = _phases(f, ins, outs, pars, {"ctrl.mode": 2}, lambda phase: p["ctrl.runup_v"] / 2 if phase == 2 else 0,
                     (drive + back + run + 50) * T)
    _assert_runs(moving[:, 0], [(0, drive), (1, back), (2, run), (0, 0)])
    for values in ({"ctrl.mode": 2, "ctrl.runup_v": 0.0}, {"ctrl.mode": 1}):
        assert np.all(_phases(f, ins, outs, pars, values, lambda phase: 0.0, 3.0)[:, 0] == 0), values


def test_a_run_up_takes_the_rover_over_a_step_it_stalls_at():
    """CEDRA at a 0.5 R_w step with mu 0.4 (step2d, 0.2 m/s, 15 s): holding the commanded speed, traction control
    stops with its bogies' rear wheels at the face, every wheel sliding at mu (measured: body.x 1.037 m with
    ctrl.runup_v = 0); with the default stall recovery it backs off, takes a run-up and gets over."""
    rec = ["body.x", "ctrl.phase"]
    ends = {}
    for runup_v in (0.0, None):
        values = {"ctrl.mode": 2} | ({} if runup_v is None else {"ctrl.runup_v": runup_v})
        loop = DriveLoop(scenario_fmu("step2d", BUILD), scenario_fmu("drive2d", BUILD),
                         plant_values={"terrain_h": 0.0325, "mu": 0.4}, controller_values=values)
        try:
            r = loop.run(15.0, 0.01, lambda t: {"cmd.v": 0.2}, record=rec)
        finally:
            loop.close()
        assert r.ok, r.messages[-3:]
        ends[runup_v] = (r.column("body.x")[-1], set(np.unique(r.column("ctrl.phase"))))
    print(f"body.x at 15 s and the phases: without a run-up {ends[0.0]}, with {ends[None]}")
    assert ends[0.0][0] < 1.1 and ends[0.0][1] == {0.0}
    assert ends[None][0] > 2.0 and ends[None][1] == {0.0, 1.0, 2.0}
