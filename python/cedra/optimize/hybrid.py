"""Hybrid multiple shooting with the contact-mode sequence fixed (`method = "hybrid"`, docs/optimize.md).

The mode sequence comes from a run (cedra.optimize.modes: every event of the guess located on its law's
indicator) and is binned into the control grid (Schedule). Each control interval is split at its events into
phases; each phase is one CVODES integration of its mode's law, time-scaled (dx/ds = h f_mode(x, u), s in
[0, 1]) so that its duration h is a decision: the event times move inside their control intervals while the
torque stays piecewise constant on the grid. The phases are split here rather than by an integrator's event
detection, which gives no sensitivities through the event (github.com/casadi/casadi/issues/2201 and
/issues/4303).

Constraints (transcribe): the defects of every phase; the phases of an interval fill it; at each event its
guard (the switching law's branch zero: the penetration at a touch-down, the normal law at a clip, the angle
beyond a stop at a stop) and a margin on the guard's rate in the crossing's direction (no event grazes); at every
node the sign conditions of the mode (an on law's penetration and normal law >= 0, an off law's active branch
<= 0) for every law that does not switch there; the goal.

The outer loop (outer) replays the solution (the FMU, or the system's own law for a test), forms the replay's
events, and where they differ from the schedule's (an event appears, disappears or changes interval) or an event
time sits on its bound, solves again on the replay's schedule from the solution."""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from cedra.optimize.modes import BRANCH_NAMES, DEPTH, Event, HybridSystem, Run
from cedra.optimize.problem import ProblemError
from cedra.optimize.shooting import mapped, objective_hessian


@dataclass
class Phase:
    interval: int
    mode: tuple
    event: Event | None          # the event that ends it (None: it ends at the interval's end)


@dataclass
class Schedule:
    """The mode sequence on the control grid: n intervals of dt, the start mode, the events in time order."""
    n: int
    dt: float
    start_mode: tuple
    events: list[Event]

    def phases(self) -> list[Phase]:
        out, on = [], tuple(self.start_mode)
        for k in range(self.n):
            for e in [e for e in self.events if e.interval == k]:
                out.append(Phase(k, on, e))
                on = tuple(int(e.on) if i == e.law else b for i, b in enumerate(on))
            out.append(Phase(k, on, None))
        return out

    def keys(self) -> list[tuple]:
        return [e.key() for e in self.events]


def schedule_of(run: Run, n: int, dt: float, guard_rate: float, min_phase: float, path: str = "<problem>",
                key: str = "guess", clamp: bool = False) -> Schedule:
    """The schedule of a run's events on the grid, or a ProblemError (file, key, reason) where none can be formed:
    an event that grazes (its guard's rate below guard_rate), crosses its guard against its rate, or (without
    clamp) leaves a phase shorter than min_phase. clamp (a replay's events, re-binned in the outer loop): an event
    at the horizon's end is left out (nothing follows it) and one closer than min_phase to a node or to the event
    before it is moved to that distance (the solver moves it back if it must)."""
    events, last = [], {}
    for e in run.events:
        if abs(e.rate) < guard_rate:
            raise ProblemError(f"{path}: key '{key}': no mode sequence: {run.describe(e)} grazes (the guard's rate "
                               f"below solver.guard_rate = {guard_rate:g} m/s)")
        if (e.rate > 0) != e.on:
            raise ProblemError(f"{path}: key '{key}': no mode sequence: {run.describe(e)} crosses its guard "
                               "against its rate")
        lo = last.get(e.interval, e.interval * dt) + min_phase
        hi = (e.interval + 1) * dt - min_phase
        if clamp and e.time > n * dt - min_phase:
            continue
        if not lo <= e.time <= hi:
            if not clamp or lo > hi:
                raise ProblemError(f"{path}: key '{key}': no mode sequence: {run.describe(e)} is within "
                                   f"solver.min_phase = {min_phase:g} s of another event or of a grid node")
            e = replace(e, time=min(max(e.time, lo), hi))
        last[e.interval] = e.time
        events.append(e)
    return Schedule(n, dt, tuple(run.start_mode), events)


def start_point(schedule: Schedule, starts: np.ndarray, run: Run):
    """The phases' start states and durations of a run on its own schedule: each interval's node state (starts),
    each event's state; durations from the event times."""
    X, H = [starts[:, 0]], []
    by_event = {e.key() + (k,): s for k, (e, s) in enumerate(zip(run.events, run.event_states))}
    count = {}
    t_prev = 0.0
    for ph in schedule.phases():
        if ph.event is None:
            t_end = (ph.interval + 1) * schedule.dt
            X.append(starts[:, ph.interval + 1] if ph.interval + 1 < starts.shape[1] else run.ends[:, ph.interval])
        else:
            t_end = ph.event.time
            key = ph.event.key()
            count[key] = count.get(key, -1) + 1
            X.append([v for kk, v in by_event.items() if kk[:4] == key][count[key]])
        H.append(t_end - t_prev)
        t_prev = t_end
    return np.array(X).T, np.array(H)


@dataclass
class Transcription:
    w: ca.MX
    g: ca.MX
    lbg: np.ndarray
    ubg: np.ndarray
    lbw: np.ndarray
    ubw: np.ndarray
    J: ca.MX
    n_nodes: int
    phases: list
    labels: list        # one per constraint row: what it is (for the report of the largest violation)

    def unpack(self, sys: HybridSystem, n: int, w):
        w = np.asarray(w).ravel()
        nn = self.n_nodes
        X = w[:sys.nx * nn].reshape(nn, sys.nx).T
        U = w[sys.nx * nn:sys.nx * nn + sys.nu * n].reshape(n, sys.nu)
        H = w[sys.nx * nn + sys.nu * n:]
        return X, U, H


def transcribe(sys: HybridSystem, schedule: Schedule, x0, X_start, terminal, torque_max: float,
               weights, guard_rate: float, min_phase: float, threads: int = 1, state_lo=None,
               state_hi=None) -> Transcription:
    """The NLP of one schedule. terminal(X_end) -> (g, lbg, ubg, label); weights: the energy's weight of each
    torque decision; X_start: the start point's node states (they choose each off law's branch at each node)."""
    phases = schedule.phases()
    P, n, nx, nu, dt = len(phases), schedule.n, sys.nx, sys.nu, schedule.dt
    X = ca.MX.sym("X", nx, P + 1)
    U = ca.MX.sym("U", nu, n)
    H = ca.MX.sym("H", P)
    g, lbg, ubg, labels = [], [], [], []

    def add(expr, lo, hi, label):
        expr = ca.vec(expr)
        g.append(expr)
        lbg.append(np.broadcast_to(lo, expr.shape[0]).astype(float))
        ubg.append(np.broadcast_to(hi, expr.shape[0]).astype(float))
        labels.extend([label] * expr.shape[0])

    # the defects: the phases of one mode integrated together (mapped over threads)
    xf = [None] * P
    for mode in sorted({ph.mode for ph in phases}):
        idx = [p for p, ph in enumerate(phases) if ph.mode == mode]
        F = mapped(sys.integrator(mode), len(idx), threads)
        ends = F(x0=X[:, idx], p=ca.vertcat(U[:, [phases[p].interval for p in idx]], H[idx].T))["xf"]
        for j, p in enumerate(idx):
            xf[p] = ends[:, j]
    for p, ph in enumerate(phases):
        add(xf[p] - X[:, p + 1], 0.0, 0.0, f"defect of phase {p} (interval {ph.interval})")
    # the phases of an interval fill it
    lbw_h, ubw_h = np.full(P, dt), np.full(P, dt)
    for k in range(n):
        idx = [p for p, ph in enumerate(phases) if ph.interval == k]
        if len(idx) > 1:
            add(ca.sum1(H[idx]) - dt, 0.0, 0.0, f"interval {k} filled")
            lbw_h[idx], ubw_h[idx] = min_phase, dt - min_phase * (len(idx) - 1)
    # guards and their rates at the events, the modes' sign conditions at the nodes
    x_sym = ca.MX.sym("x", nx)
    dep, frc = sys.branches(x_sym)
    branches = ca.Function("branches", [x_sym], [dep, frc])
    Xs = np.asarray(X_start)
    c_start = np.array(branches(Xs)[0]), np.array(branches(Xs)[1])
    for p, ph in enumerate(phases):
        node = p + 1
        switched = None
        if ph.event is not None:
            e = ph.event
            switched = e.law
            b = branches(X[:, node])[e.branch][e.law]
            add(b, 0.0, 0.0, f"guard of {sys.laws[e.law]} ({BRANCH_NAMES[e.branch]}) at node {node}")
            r = sys.rate_function(ph.mode, e.law, e.branch)(X[:, node], U[:, ph.interval])
            add(r if e.on else -r, guard_rate, np.inf, f"guard rate of {sys.laws[e.law]} at node {node}")
        bd, bf = branches(X[:, node])
        for i, on in enumerate(ph.mode):
            if i == switched:
                continue
            if on:
                add(ca.vertcat(bd[i], bf[i]), 0.0, np.inf, f"{sys.laws[i]} on at node {node}")
            else:
                use = DEPTH if c_start[0][i, node] <= c_start[1][i, node] else 1
                add([bd, bf][use][i], -np.inf, 0.0, f"{sys.laws[i]} off at node {node}")
    tg, tlo, thi, tlabel = terminal(X[:, P])
    add(tg, tlo, thi, tlabel)
    lo = np.full((nx, P + 1), -np.inf) if state_lo is None else np.tile(np.asarray(state_lo)[:, None], (1, P + 1))
    hi = np.full((nx, P + 1), np.inf) if state_hi is None else np.tile(np.asarray(state_hi)[:, None], (1, P + 1))
    lo[:, 0] = hi[:, 0] = np.asarray(x0).ravel()
    w = ca.vertcat(ca.vec(X), ca.vec(U), H)
    ub = np.full(nu * n, torque_max)
    lbw = np.concatenate([lo.ravel(order="F"), -ub, lbw_h])
    ubw = np.concatenate([hi.ravel(order="F"), ub, ubw_h])
    J = dt * ca.sum2(ca.mtimes(ca.DM(weights).T, U ** 2))
    return Transcription(w, ca.vertcat(*g), np.concatenate(lbg), np.concatenate(ubg), lbw, ubw, J, P + 1, phases,
                         labels)


def solve(sys: HybridSystem, schedule: Schedule, x0, X_start, U_start, H_start, terminal, torque_max: float,
          weights, guard_rate: float, min_phase: float, max_iter: int = 200, tol: float = 1e-8,
          hessian: str = "objective", proximal: float = 0.0, threads: int = 1, state_lo=None, state_hi=None,
          log: bool = False) -> dict:
    """IPOPT on one schedule from (X_start, U_start, H_start)."""
    tr = transcribe(sys, schedule, x0, X_start, terminal, torque_max, weights, guard_rate, min_phase, threads,
                    state_lo, state_hi)
    n = schedule.n
    w0 = np.concatenate([np.asarray(X_start).ravel(order="F"), np.asarray(U_start).ravel(),
                         np.clip(H_start, tr.lbw[-len(H_start):], tr.ubw[-len(H_start):])])
    w0 = np.clip(w0, tr.lbw, tr.ubw)
    nlp = {"x": tr.w, "f": tr.J, "g": tr.g}
    opts = {"ipopt": {"max_iter": max_iter, "tol": tol, "constr_viol_tol": 1e-8, "print_level": 5 if log else 0,
                      "sb": "yes", "theta_max_fact": 1.0,
                      "hessian_approximation": "limited-memory" if hessian == "limited-memory" else "exact"},
            "print_time": False}
    if hessian == "objective":
        opts["hess_lag"] = objective_hessian(tr.w, tr.J, tr.g.numel(), sys.nx * tr.n_nodes, proximal)
    solver = ca.nlpsol("hybrid", "ipopt", nlp, opts)
    t0 = time.perf_counter()
    sol = solver(x0=w0, lbx=tr.lbw, ubx=tr.ubw, lbg=tr.lbg, ubg=tr.ubg)
    wall = time.perf_counter() - t0
    stats = solver.stats()
    w = np.array(sol["x"]).ravel()
    X, U, H = tr.unpack(sys, n, w)
    gv = np.array(sol["g"]).ravel()
    viol = np.maximum(tr.lbg - gv, gv - tr.ubg)
    viol = np.maximum(viol, 0)
    worst = int(np.argmax(viol)) if viol.size else 0
    times = np.cumsum(H)
    at_bound = [ph.event for p, ph in enumerate(tr.phases)
                if ph.event is not None and (H[p] <= tr.lbw[-len(H) + p] + 1e-9 or
                                             (p + 1 < len(H) and H[p + 1] <= tr.lbw[-len(H) + p + 1] + 1e-9))]
    return dict(X=X, U=U, H=H, event_times=[float(times[p]) for p, ph in enumerate(tr.phases) if ph.event],
                status=stats["return_status"], success=bool(stats["success"]), iterations=stats["iter_count"],
                objective=float(sol["f"]), violation=float(viol.max()) if viol.size else 0.0,
                worst=tr.labels[worst] if viol.size else "", wall=wall, at_bound=at_bound, phases=tr.phases,
                schedule=schedule)


def node_states(result: dict) -> np.ndarray:
    """The solution's states at the grid nodes (the nodes that end an interval's last phase)."""
    keep = [0] + [p + 1 for p, ph in enumerate(result["phases"]) if ph.event is None]
    return result["X"][:, keep]


def outer(sys: HybridSystem, run: Run, starts: np.ndarray, U_start: np.ndarray, dt: float, x0, terminal,
          replay, torque_max: float, weights, guard_rate: float, min_phase: float, rounds: int = 5, say=print,
          path: str = "<problem>", **solve_opts) -> tuple[dict, list[dict]]:
    """Solve on the run's schedule; replay(U) -> the replay's node states (columns) under the solution's torques;
    re-bin on the replay's events and solve again from the solution until the replay's sequence is the
    schedule's and no event time sits on its bound (at most `rounds` solves). Returns the last result and a
    summary of every round."""
    n = U_start.shape[0]
    # an event of the guess within min_phase of a node is moved off it (the solver moves it back if it must)
    schedule = schedule_of(run, n, dt, guard_rate, min_phase, path, clamp=True)
    X0, H0 = start_point(schedule, starts, run)
    U0 = U_start
    history = []
    result = None
    for r in range(rounds):
        result = solve(sys, schedule, x0, X0, U0, H0, terminal, torque_max, weights, guard_rate, min_phase,
                       **solve_opts)
        nodes = replay(result["U"])
        rerun = sys.simulate(nodes, result["U"], dt, resync=True)
        rebinned = schedule_of(rerun, n, dt, guard_rate, min_phase, path, key="solution", clamp=True)
        same = rebinned.keys() == schedule.keys()
        history.append(dict(round=r + 1, events=len(schedule.events), phases=len(result["phases"]),
                            status=result["status"], iterations=result["iterations"], wall=result["wall"],
                            objective=result["objective"], violation=result["violation"], worst=result["worst"],
                            replay_events=len(rerun.events), same_sequence=same,
                            at_bound=[run_describe(sys, e) for e in result["at_bound"]]))
        say(f"round {r + 1}: {len(schedule.events)} events, IPOPT {result['status']} after {result['iterations']} "
            f"iterations, {result['wall']:.1f} s, violation {result['violation']:.1e} ({result['worst']}), "
            f"objective {result['objective']:.6g}; the replay has {len(rerun.events)} events"
            f"{'' if same else ', another sequence'}")
        if same and not result["at_bound"]:
            break
        # solve again from the solution, on the replay's sequence
        schedule = rebinned
        X0, H0 = start_point(schedule, nodes, rerun)
        U0 = result["U"]
    return result, history


def run_describe(sys: HybridSystem, e: Event) -> str:
    return f"{sys.laws[e.law]} {'on' if e.on else 'off'} near t = {e.time:.4f} s"


def phase_path(sys: HybridSystem, result: dict, step: float) -> np.ndarray:
    """The solution's own trajectory at every `step` from 0: each sample integrated in its phase's mode from the
    phase's start node over the time into the phase (the states the replay is compared with)."""
    X, U, H, phases = result["X"], result["U"], result["H"], result["phases"]
    starts = np.r_[0.0, np.cumsum(H)]
    total = starts[-1]
    out = [X[:, 0]]
    for t in np.arange(1, int(round(total / step)) + 1) * step:
        p = min(int(np.searchsorted(starts, t, side="left")) - 1, len(phases) - 1)
        p = max(p, 0)
        into = t - starts[p]
        if into <= 0:
            out.append(X[:, p])
            continue
        F = sys.integrator(phases[p].mode)
        out.append(np.array(F(x0=X[:, p], p=np.r_[U[phases[p].interval], into])["xf"]).ravel())
    return np.array(out).T
