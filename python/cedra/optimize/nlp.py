"""The optimal control problem solved by IPOPT through CasADi's nlpsol, on either transcription
(cedra.optimize.shooting: every shooting state a node decision; cedra.optimize.carried_spin: the wheels' spin
rates carried through the intervals), and the continuation over the contact law's smoothing widths.

Decisions: one torque per wheel pair and interval, piecewise constant, each |tau[i]| <= torque_max (default: the
drive model's stall torque); the node states; the interval length (the time objective); the epigraph variable
(peak_friction).

Objectives (problem key `objective`):
  energy         the integral of sum_i tau_i^2 over the six wheels (N^2.m^2.s): the motors' copper loss up to
                 the constant R / k_t^2, the cost of current; exact for piecewise constant torques. Fixed horizon.
  peak_friction  the peak over the grid nodes and the wheels of |Fx| / Fn, as an epigraph variable s with
                 -s Fn <= Fx <= s Fn at every node (no division: a wheel in the air has Fn = Fx = 0). Fixed horizon.
  time           the final time, free (the interval length is a decision variable).
peak_friction and time add `regularization` x energy (default 1e-3), which picks one of the many torque histories
with the same peak or time. Terminal condition: body.x >= terrain_x0 + margin at the final time.

Continuation (`solver.smoothing`): one stage per width, each started from the previous stage's decisions and
multipliers (cedra.optimize.dynamics: the smoothed law)."""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from cedra.optimize.carried_spin import CarriedSpinHessian, CarriedSpinShooting, carried_constraints
from cedra.optimize.dynamics import Dynamics, state_bounds
from cedra.optimize.problem import Problem, at_stage
from cedra.optimize.shooting import ShootingHessian, interval_jacobian, lifted_constraints, objective_hessian, \
    objective_part

WARM_DUALS = True            # a continuation stage starts from the previous one's multipliers too


def solve(problem: Problem, dyn: Dynamics, x0, X_guess, U_guess, dt_guess: float, goal_x: float,
          log: bool = False, warm: dict | None = None, proximal: float = 0.0, hessian: str = "objective",
          spin_rates: str = "nodes") -> dict:
    """Multiple shooting: decisions X_0..X_N (shooting states, X_0 fixed at x0; with spin_rates "carried" the body
    and joint states only, cedra.optimize.carried_spin), U_0..U_{N-1} (four torques each), the interval length dt (free for
    the time objective), the epigraph s (peak_friction), on the equations at the contact law's smoothing width
    dyn.width. The intervals are integrated on `problem.threads` threads (carried: their Jacobians).
    warm: a previous solve's result (a continuation stage), its decisions and multipliers the starting point."""
    n = U_guess.shape[0]
    free_dt = problem.objective == "time"
    peak = problem.objective == "peak_friction"
    lo, hi = (dyn.reduced(b) for b in state_bounds(dyn))
    X_start = dyn.reduced(X_guess)
    x0r = dyn.reduced(x0)
    if spin_rates == "carried":
        shooting = CarriedSpinShooting(dyn, x0, n, dt_guess, problem.integrator_tol, goal_x, free_dt, peak,
                                       problem.threads)
        keep, (w, U, dt, s, g, lbg, ubg) = shooting.body, carried_constraints(shooting, n, peak)
        extra = {"jac_g": shooting.jac_g()}
    else:
        keep, (w, U, dt, s, g, lbg, ubg) = list(range(dyn.nr)), lifted_constraints(problem, dyn, n, dt_guess, goal_x)
        extra = {}
    nx = len(keep)
    weights = ca.DM([2, 2, 1, 1])              # tau[1] = tau[3], tau[2] = tau[4]: each pair's torque counts twice
    energy = dt * ca.sum2(ca.mtimes(weights.T, U ** 2))
    if problem.objective == "energy":
        J = energy
    elif problem.objective == "time":
        J = n * dt + problem.regularization * energy
    else:
        J = s + problem.regularization * energy
    x_lo = np.tile(lo[keep, None], (1, n + 1))
    x_hi = np.tile(hi[keep, None], (1, n + 1))
    x_lo[:, 0] = x_hi[:, 0] = x0r[keep]
    u_bound = np.full((4, n), problem.torque_max)
    if problem.objective == "time":
        dt_lo, dt_hi = 0.25 * dt_guess, 2.0 * dt_guess
    else:
        dt_lo = dt_hi = dt_guess
    lbw = np.concatenate([x_lo.ravel(order="F"), -u_bound.ravel(order="F"), [dt_lo], [0.0]])
    ubw = np.concatenate([x_hi.ravel(order="F"), u_bound.ravel(order="F"), [dt_hi],
                          [np.inf if peak else 0.0]])
    s0 = 1.0 if peak else 0.0
    w0 = np.concatenate([X_start[keep].ravel(order="F"), np.clip(U_guess.T, -problem.torque_max,
                                                          problem.torque_max).ravel(order="F"), [dt_guess], [s0]])
    warm_opts = {}
    if warm is not None:
        w0 = warm["w"]
        if WARM_DUALS:
            warm_opts = {"warm_start_init_point": "yes", "mu_init": 1e-4, "warm_start_bound_push": 1e-6,
                         "warm_start_mult_bound_push": 1e-6}
    nlp = {"x": w, "f": J, "g": ca.vertcat(*g)}
    if hessian == "objective":
        hess = {"hess_lag": objective_hessian(w, J, nlp["g"].numel(), nx * (n + 1), proximal)}
    elif hessian == "differenced" and spin_rates == "carried":
        hess = {"hess_lag": CarriedSpinHessian(shooting, objective_part(w, J, nx * (n + 1), proximal))}
    elif hessian == "differenced":
        hess = {"hess_lag": ShootingHessian(w, J, nlp["g"].numel(), n, interval_jacobian(
            dyn.integrator(problem.integrator_tol, dt=dt_guess), nx, 4), problem.threads, proximal)}
    else:
        hess = {}
    opts = {"ipopt": {"max_iter": problem.max_iter, "tol": problem.tol,
                      "hessian_approximation": "exact" if hess else "limited-memory",
                      "print_level": 5 if log else 0, "sb": "yes",
                      # the sensitivities carry no jump term where a contact law switches (cedra.optimize.dynamics),
                      # which keeps the dual infeasibility at 1e-3..1e-2 near the optimum: stop there
                      # once the objective has levelled off, with the shooting defects closed
                      "acceptable_tol": 1e-2, "acceptable_iter": 3, "acceptable_obj_change_tol": 1e-3,
                      "acceptable_constr_viol_tol": 1e-5,
                      # the filter accepts no trial point whose constraint violation (1-norm) exceeds the start's
                      # (at least 1): the Gauss-Newton steps otherwise trade a large violation for objective
                      "theta_max_fact": 1.0, **warm_opts}, "print_time": False, **hess, **extra}
    solver = ca.nlpsol("climb", "ipopt", nlp, opts)
    t0 = time.perf_counter()
    lbg, ubg = np.concatenate(lbg), np.concatenate(ubg)
    duals = dict(lam_x0=warm["lam_x"], lam_g0=warm["lam_g"]) if warm is not None and WARM_DUALS else {}
    sol = solver(x0=w0, lbx=lbw, ubx=ubw, lbg=lbg, ubg=ubg, **duals)
    wall = time.perf_counter() - t0
    stats = solver.stats()
    wv = np.array(sol["x"]).ravel()
    Xo = shooting.nodes(wv) if spin_rates == "carried" else wv[:nx * (n + 1)].reshape((nx, n + 1), order="F")
    Uo = wv[nx * (n + 1):nx * (n + 1) + 4 * n].reshape((4, n), order="F").T
    objective, violation = _evaluate(nlp, wv, lbg, ubg)
    return dict(X=Xo, U=Uo, dt=float(wv[-2]), s=float(wv[-1]), objective=objective, wall=wall,
                iterations=int(stats["iter_count"]), status=stats["return_status"], success=bool(stats["success"]),
                violation=violation, width=dyn.width, w=wv, lam_x=np.array(sol["lam_x"]).ravel(),
                lam_g=np.array(sol["lam_g"]).ravel())


def _evaluate(nlp: dict, wv: np.ndarray, lbg: np.ndarray, ubg: np.ndarray) -> tuple[float, float]:
    """The objective and the largest constraint violation at the point IPOPT returns, evaluated afresh: after a
    failed evaluation (Invalid_Number_Detected: the shooting integrator could not integrate a trial point) the
    solver's own f and g are zeros, which would read as a feasible point. NaN and inf where the point itself
    cannot be evaluated."""
    try:
        f, g = ca.Function("fg", [nlp["x"]], [nlp["f"], nlp["g"]])(wv)
    except RuntimeError:
        return float("nan"), float("inf")
    gv = np.array(g).ravel()
    if not np.all(np.isfinite(gv)):
        return float(f), float("inf")
    return float(f), float(max(np.max(np.maximum(lbg - gv, 0)), np.max(np.maximum(gv - ubg, 0))))


def continuation(problem: Problem, dyn: Dynamics, x0, X_guess, U_guess, dt: float, goal_x: float, say,
                 log: bool = False) -> tuple[dict, list[dict]]:
    """One solve per smoothing width of the problem (a continuation stage), each started from the previous stage's
    decisions and multipliers on a law nearer the FMU's; returns the last stage's result and every stage's
    summary. say: the progress lines' printer."""
    result, stages = None, []
    for width in problem.smoothing:
        dyn.width = width
        if len(problem.smoothing) > 1:
            say(f"stage {len(stages) + 1}/{len(problem.smoothing)}: contact smoothing width {width:g} m")
        proximal, hessian = at_stage(problem.proximal, len(stages)), at_stage(problem.hessian, len(stages))
        result = solve(problem, dyn, x0, X_guess, U_guess, dt, goal_x, log=log, warm=result, proximal=proximal,
                       hessian=hessian, spin_rates=problem.spin_rates)
        stages.append({k: result[k] for k in ("width", "status", "iterations", "wall", "objective", "violation",
                                              "success")} | {"proximal": proximal, "hessian": hessian})
        say(f"IPOPT: {result['status']} after {result['iterations']} iterations, {result['wall']:.1f} s, "
            f"constraint violation {result['violation']:.1e}, objective {result['objective']:.6g}")
    return result, stages
