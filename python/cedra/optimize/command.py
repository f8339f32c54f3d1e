"""`python -m cedra optimize <problem.toml> [--out DIR] [--build DIR] [--quiet]`: the wheel torques over time that
take the planar rover over an obstacle at the least cost, then their open-loop replay through the scene's FMU and
the comparison with the drive controller's three modes on the same measures, from the same FMU runs
(docs/optimize.md)."""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from cedra.models.scene import SceneError
from cedra.optimize.dynamics import Dynamics, goal, model_path
from cedra.optimize.fmu_runs import controller_run, initial_guess, measures, replay
from cedra.optimize.problem import GUESSES, REPLAY_STEP, Problem, ProblemError, load
from cedra.optimize.report import arrival, write
from cedra.optimize.nlp import continuation
from cedra.optimize.modes import RoverHybrid

CONTROLLER_STOP = 40.0       # s: the controllers' runs stop here if they have not arrived


def run(problem: Problem, out_dir, build_dir="build", quiet=False) -> dict:
    """Solve the problem, replay the optimum through the FMU, run the controllers, write the report; returns the
    summary (also <out>/result.json)."""
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    t_start = time.perf_counter()
    # the hybrid method's equations are the modes' (cedra.optimize.modes); the controllers' runs and the replay
    # need only the scene's tables, which both carry
    dyn = RoverHybrid(problem) if problem.method == "hybrid" else Dynamics(problem)
    goal_x = goal(problem, dyn)
    runs = {}
    for mode in GUESSES:
        stop = max(CONTROLLER_STOP, 3 * (problem.horizon or 0))
        r = controller_run(problem, dyn, mode, stop, build_dir)
        runs[mode] = (r.names, r.rows, measures(r.names, r.rows, goal_x))
        say(f"{mode}: arrives {arrival(runs[mode][2])}, energy {runs[mode][2]['energy']:.3f} N^2.m^2.s, "
            f"peak |Fx|/Fn {runs[mode][2]['peak_friction']:.3f}")
    names, rows, m_guess = runs[problem.guess]
    dt = problem.interval
    if problem.guess == "traction_control":
        r = controller_run(problem, dyn, problem.guess, max(CONTROLLER_STOP, 3 * (problem.horizon or 0)), build_dir,
                           on_grid=True)
        names, rows, m_guess = r.names, r.rows, measures(r.names, r.rows, goal_x)
        say(f"traction_control sampled every {dt:g} s (the guess): arrives {arrival(m_guess)}, energy "
            f"{m_guess['energy']:.3f} N^2.m^2.s")
    horizon = problem.horizon or (math.ceil(m_guess["time"] / dt - 1e-9) * dt if m_guess["arrived"] else None)
    if horizon is None:
        raise RuntimeError(f"the {problem.guess} run did not reach body.x = {goal_x:g} m in {CONTROLLER_STOP:g} s: "
                           "give the problem a horizon")
    n = int(round(horizon / dt))
    X_guess, U_guess = initial_guess(names, rows, n, dt)
    x0 = X_guess[:, 0]
    say(f"solving: {n} intervals of {dt:g} s, objective {problem.objective}, from the {problem.guess} run"
        + (", the contact-mode sequence fixed" if problem.method == "hybrid" else ""))
    if problem.method == "hybrid":
        result, stages, path = hybrid_solve(problem, dyn, x0, X_guess, U_guess, dt, goal_x, build_dir, say,
                                            log=not quiet)
    else:
        result, stages = continuation(problem, dyn, x0, X_guess, U_guess, dt, goal_x, say, log=not quiet)
        path = model_path(dyn, x0, result["U"], result["dt"], problem.integrator_tol)
    replay_names, replay_rows, replay_ok = replay(problem, dyn, x0, result["U"], result["dt"], build_dir)
    k = min(path.shape[1], replay_rows.shape[0])
    col = {nm: replay_rows[:k, j] for j, nm in enumerate(replay_names)}
    deviation = float(np.max(np.hypot(col["body.x"] - path[0, :k], col["body.z"] - path[1, :k])))
    # the NLP's own node states against the replay at the node times: equal to the above once the shooting defects
    # are closed; while they are not (an unconverged solve) the integration of the torques is not the nodes' path
    at_nodes = np.minimum(np.arange(n + 1) * int(round(result["dt"] / REPLAY_STEP)), replay_rows.shape[0] - 1)
    replayed = {nm: replay_rows[at_nodes, j] for j, nm in enumerate(replay_names)}
    node_deviation = float(np.max(np.hypot(replayed["body.x"] - result["X"][0], replayed["body.z"] - result["X"][1])))
    m_opt = measures(replay_names, replay_rows, goal_x)
    summary = dict(problem=problem.name, scene=problem.scene, objective=problem.objective, goal_x=goal_x,
                   intervals=n, interval=dt, horizon=n * result["dt"], torque_max=problem.torque_max,
                   integrator_tol=problem.integrator_tol, iterations=sum(st["iterations"] for st in stages),
                   status=result["status"], success=result["success"], violation=result["violation"],
                   smoothing=result["width"], stages=stages, solve_time=sum(st["wall"] for st in stages),
                   nlp_objective=result["objective"],
                   replay_ok=replay_ok, replay_deviation=deviation, node_deviation=node_deviation, optimum=m_opt,
                   controllers={mode: runs[mode][2] for mode in GUESSES}, guess=problem.guess,
                   final_x_optimizer=float(result["X"][0, -1]), wall=time.perf_counter() - t_start,
                   method=problem.method, events=result.get("events"))
    write(Path(out_dir), problem, summary, result, path, (replay_names, replay_rows), runs)
    say(f"replay through the FMU: body path within {deviation:.2e} m of the optimizer's; "
        f"optimum energy {m_opt['energy']:.3f}, peak |Fx|/Fn {m_opt['peak_friction']:.3f}, "
        f"arrives {arrival(m_opt)} -> {out_dir}")
    return summary


def hybrid_solve(problem: Problem, sysm: RoverHybrid, x0, X_guess, U_guess, dt: float, goal_x: float, build_dir,
                 say, log: bool = False):
    """method = "hybrid": the guess's events (the FMU's run, each interval re-integrated from its node with the
    FMU's law mode by mode), the outer loop of solves on the mode sequence, each replayed through the FMU.
    Returns (result, one summary per round, the optimizer's own path at the replay's step)."""
    from cedra.optimize import hybrid
    from cedra.optimize.dynamics import state_bounds
    from cedra.optimize.fmu_runs import states_of
    starts = sysm.reduced(X_guess)
    run = sysm.simulate(starts, U_guess, dt)
    say(f"the guess's mode sequence: {len(run.events)} events")
    n = U_guess.shape[0]
    per = int(round(dt / REPLAY_STEP))

    def terminal(xe):
        return xe[0] - goal_x, 0.0, np.inf, "the goal"

    def fmu_nodes(U):
        names, rows, _ = replay(problem, sysm, x0, U, dt, build_dir)
        X = states_of(names, rows)
        return sysm.reduced(X[:, np.minimum(np.arange(n + 1) * per, X.shape[1] - 1)])
    lo, hi = (sysm.reduced(b) for b in state_bounds(sysm))
    result, history = hybrid.outer(
        sysm, run, starts, U_guess, dt, sysm.reduced(x0), terminal, fmu_nodes, problem.torque_max, [2, 2, 1, 1],
        problem.guard_rate, problem.min_phase, rounds=problem.rounds, say=say, path=problem.path,
        max_iter=problem.max_iter, tol=problem.tol, hessian=problem.hessian[0], proximal=problem.proximal[0],
        threads=problem.threads, state_lo=lo, state_hi=hi, log=log)
    stages = [{"width": 0.0, "hessian": problem.hessian[0], "proximal": problem.proximal[0]} | h for h in history]
    result = result | {"dt": dt, "width": 0.0, "X": hybrid.node_states(result), "events": len(result["event_times"])}
    return result, stages, hybrid.phase_path(sysm, result, REPLAY_STEP)


def add_parser(sub):
    p = sub.add_parser("optimize", help="optimal wheel torques over an obstacle (direct multiple shooting, IPOPT), "
                       "replayed through the FMU")
    p.add_argument("problem", help="a problem .toml (examples/optimize/)")
    p.add_argument("--out", default=None, help="output directory (default: out/optimize/<name>)")
    p.add_argument("--build", default="build", help="where the FMUs are (built there if missing)")
    p.add_argument("--quiet", action="store_true")


def main(args) -> int:
    import sys
    try:
        problem = load(args.problem)
    except (ProblemError, SceneError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        summary = run(problem, args.out or f"out/optimize/{problem.name}", args.build, args.quiet)
    except ProblemError as e:           # a mode sequence the guess cannot form (method = "hybrid")
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0 if summary["success"] else 1
