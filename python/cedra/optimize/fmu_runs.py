"""The optimizer's runs through the scene's FMU: the drive controller's runs (the initial guess, and what the
optimum is compared with), the open-loop replay of the optimal torques, and the measures taken on both.

Initial guess (problem key `guess`): a drive controller's run from the same start, its states at the grid nodes
and its mean torques per interval (initial_guess). The equal-torque and inverse-kinematics controllers sample
every 0.01 s, so their torques vary within an interval and the guess's shooting defects are large (up to
100 rad/s in the wheel rates on the bump at 0.2 s intervals); "traction_control" samples the traction controller
once per interval (its rolling-rate hold's gain scaled to the period), so its torques are piecewise constant on
the grid and the guess is a point of the shooting problem up to the integrators' tolerances (defects 1e-4 on the
bump at 0.1 s intervals)."""
from __future__ import annotations

import numpy as np

from cedra.optimize.dynamics import PAIRS, WHEELS, Dynamics
from cedra.optimize.problem import GUESSES, REPLAY_STEP, Problem

ARRIVAL_TOL = 1e-4           # m: the goal counts as reached this close (the optimum ends on it, the replay within this)
FN_MIN = 1.0                 # N: a wheel counts in the friction ratio while it carries more than this


def plant_values(problem: Problem, dyn: Dynamics) -> dict:
    v = dict(problem.inputs)
    if problem.start_x is not None:
        v["start.x"] = problem.start_x
    return v


def controller_run(problem: Problem, dyn: Dynamics, mode: str, stop_time: float, build_dir, on_grid=False):
    """The drive controller in mode `mode` on the scene's FMU from the problem's start (cedra.run.cosim).
    on_grid: sampled once per control interval (traction control only: its rolling-rate hold's gain scaled to the
    period, 0.95 J / T as the controller's default at 0.01 s), so its torques are piecewise constant on the
    problem's grid and its states at the nodes are a point of the shooting problem up to the integrators'
    tolerances."""
    from cedra.run.cosim import DriveLoop
    from cedra.run.scenario import fmu
    values = {"ctrl.mode": GUESSES[mode], "ctrl.tau_max": problem.torque_max}
    if on_grid:
        if mode != "traction_control":
            raise ValueError("only the traction controller is sampled on the problem's grid")
        spin_inertia = dyn.par[[q.name for q in dyn.model.params].index("m_w")] * \
            dyn.par[[q.name for q in dyn.model.params].index("R_w")] ** 2 / 2
        values |= {"ctrl.period": problem.interval, "ctrl.roll_kp": 0.95 * spin_inertia / problem.interval}
    loop = DriveLoop(fmu(problem.scene, build_dir), fmu("drive2d", build_dir), plant_values=plant_values(problem, dyn),
                     controller_values=values)
    try:
        r = loop.run(stop_time, REPLAY_STEP, lambda t: {"cmd.v": problem.speed}, record_names())
    finally:
        loop.close()
    return r


def record_names() -> list[str]:
    states = ["body.x", "body.z", "body.pitch", "bogie.theta[1]", "fork.theta4", "body.vx", "body.vz", "body.wy",
              "bogie.rate[1]", "fork.rate4"]
    return (states + [f"wheel[{k}].omega" for k in WHEELS] + [f"wheel[{k}].{q}" for k in WHEELS for q in ("Fn", "Fx")]
            + [f"tau[{k}]" for k in range(1, 7)] + ["energy.work"])


def states_of(names, rows) -> np.ndarray:
    """The model state [q; u] at each recorded row: the coordinates and rates are outputs of the FMU (body.wy is
    the pitch rate in the plane), the wheel angles the integral of their rates (they enter no force)."""
    col = {n: rows[:, k] for k, n in enumerate(names)}
    t = col["time"]
    omega = np.array([col[f"wheel[{k}].omega"] for k in WHEELS])
    gamma = np.concatenate([np.zeros((4, 1)), np.cumsum(0.5 * (omega[:, 1:] + omega[:, :-1]) * np.diff(t), axis=1)],
                           axis=1)
    q = np.array([col["body.x"], col["body.z"], col["body.pitch"], col["bogie.theta[1]"], col["fork.theta4"], *gamma])
    u = np.array([col["body.vx"], col["body.vz"], col["body.wy"], col["bogie.rate[1]"], col["fork.rate4"], *omega])
    return np.vstack([q, u])


def measures(names, rows, goal_x: float) -> dict:
    """What the report compares, from one FMU run recorded every REPLAY_STEP: the arrival time (body.x first at
    the goal), and up to it the energy integral of sum tau_i^2 (each row's torque held over the next step), the peak
    |Fx| / Fn over wheels carrying more than FN_MIN and the motors' mechanical work."""
    col = {n: rows[:, k] for k, n in enumerate(names)}
    t, x = col["time"], col["body.x"]
    arrived = np.nonzero(x >= goal_x - ARRIVAL_TOL)[0]
    k_end = int(arrived[0]) if arrived.size else len(t) - 1
    dt = np.diff(t)[:k_end]
    tau2 = sum(col[f"tau[{k}]"][:k_end] ** 2 for k in range(1, 7))
    fn = np.array([col[f"wheel[{k}].Fn"][:k_end + 1] for k in WHEELS])
    fx = np.array([col[f"wheel[{k}].Fx"][:k_end + 1] for k in WHEELS])
    loaded = fn > FN_MIN
    return dict(arrived=bool(arrived.size), time=float(t[k_end]), energy=float(np.sum(tau2 * dt)),
                peak_friction=float(np.max(np.abs(fx[loaded]) / fn[loaded])) if loaded.any() else 0.0,
                work=float(col["energy.work"][k_end]),
                peak_torque=float(max(np.abs(col[f"tau[{k}]"][:k_end + 1]).max() for k in range(1, 7))))


def replay(problem: Problem, dyn: Dynamics, x0, torques: np.ndarray, dt: float, build_dir, solver: dict | None = None):
    """The optimal torques open loop through the scene's FMU from the optimizer's start state x0 (not settled
    again), held over each interval, recorded every REPLAY_STEP. Returns (names, rows, ok)."""
    from cedra.run.driver import RoverFMU
    from cedra.run.scenario import fmu
    plant = RoverFMU(fmu(problem.scene, build_dir), "replay")
    names = ["time"] + record_names()
    q_names = dyn.model.q_names
    values = dict(problem.inputs) | {"start.settle": False} | dict(solver or {})
    values |= {f"start.{n}": float(x0[k]) for k, n in enumerate(q_names)}
    values |= {f"start.speed.{n}": float(x0[dyn.nq + k]) for k, n in enumerate(q_names)}
    n_sub = int(round(dt / REPLAY_STEP))
    h = dt / n_sub
    rows, ok = [], True
    try:
        plant.start(values)
        for k in range(len(torques) * n_sub + 1):
            tau = torques[min(k // n_sub, len(torques) - 1)]
            plant.set({f"tau[{i + 1}]": tau[PAIRS[i]] for i in range(6)})
            out = plant.get([n for n in record_names() if not n.startswith("tau[")])
            rows.append(np.concatenate([[k * h], out[:names.index("tau[1]") - 1], [tau[p] for p in PAIRS], out[-1:]]))
            if k == len(torques) * n_sub:
                break
            if not plant.step((k + 1) * h):
                ok = False
                break
    finally:
        plant.close()
    return names, np.array(rows), ok


def initial_guess(names, rows, n: int, dt: float):
    """States at the grid nodes and each interval's mean torques per wheel pair, from a controller run recorded
    every REPLAY_STEP (held at its last row beyond its end)."""
    X = states_of(names, rows)
    col = {nm: rows[:, k] for k, nm in enumerate(names)}
    per = int(round(dt / REPLAY_STEP))
    idx = np.minimum(np.arange(n + 1) * per, rows.shape[0] - 1)
    pair = [0.5 * (col["tau[1]"] + col["tau[3]"]), 0.5 * (col["tau[2]"] + col["tau[4]"]), col["tau[5]"], col["tau[6]"]]
    U = np.array([[np.mean(p[min(k * per, len(p) - 1):min((k + 1) * per, len(p))] if k * per < len(p) else p[-1])
                   for p in pair] for k in range(n)])
    return X[:, idx], U
