"""Shared machinery of the reports and the benchmark: one scene's equations on the Python side (settled start
state, piecewise-constant input schedules, the CasADi reference integrator, scipy peers), an FMU runner that
starts from exactly the same state, and the error metrics.

The ODE is the FMU's: x = [q, u, w], qdot = u, M(q) udot = f(q, u, inp), wdot = power. On the Python side udot is
`casadi.solve(M, f)` inside an MX graph (a numeric linear solve at each evaluation, never a symbolic inverse).
Inputs change only at the schedule's breakpoints (multiples of 0.1 s, the coarsest communication step), so every
communication step size sees the same input; every integrator is restarted at each breakpoint.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from cedra.contract import SOLVER_METHODS

SOLVER_CODES = {name: k for k, name in enumerate(SOLVER_METHODS)}


def announce(what: str, expected: str, quiet: bool = False) -> None:
    """A long report says how long it takes before it starts (stderr)."""
    import sys
    if not quiet:
        print(f"{what}: expect {expected}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------ inputs
@dataclass
class Schedule:
    """Piecewise-constant inputs: `values[k]` (name -> value) holds on [times[k], times[k+1]). Names not given
    keep the scene's start value."""
    times: list[float]
    values: list[dict]

    def at(self, t: float) -> dict:
        k = max(i for i, tk in enumerate(self.times) if tk <= t + 1e-12)
        return self.values[k]

    def breakpoints(self, t_end: float) -> list[float]:
        return [t for t in self.times if 0 < t < t_end - 1e-12]


def torques(tau, **extra) -> dict:
    """All six wheel torques equal to tau (or a list of six), plus other inputs."""
    taus = tau if isinstance(tau, (list, tuple)) else [tau] * 6
    return {f"tau[{i + 1}]": float(v) for i, v in enumerate(taus)} | extra


# ------------------------------------------------------------------ the scene's equations in Python
class Problem:
    """A scene's equations, parameters and inputs on the Python side.

    overrides: parameter or input start values by name (e.g. ground_k, v_eps, mu, terrain_h)."""

    def __init__(self, scene, overrides: dict | None = None):
        self.scene = scene
        self.model = scene.model()
        self.spec = scene.spec(self.model)
        self.fns = self.spec.functions
        overrides = dict(overrides or {})
        pnames = [p.name for p in self.spec.params]
        inames = [p.name for p in self.spec.inputs]
        unknown = set(overrides) - set(pnames) - set(inames)
        if unknown:
            raise KeyError(f"{scene.name}: unknown parameters/inputs {sorted(unknown)}")
        self.overrides = overrides
        self.par = np.array([overrides.get(p.name, p.start) for p in self.spec.params], float)
        self.inp0 = np.array([overrides.get(p.name, p.start) for p in self.spec.inputs], float)
        self.pnames, self.inames = pnames, inames
        self.q_names = list(self.spec.q_names)
        self.nq = len(self.q_names)
        self.nx = 2 * self.nq + 1
        self.out_names = [o.name for o in self.spec.outputs]
        self._build()

    def inp(self, values: dict) -> np.ndarray:
        v = self.inp0.copy()
        for name, value in values.items():
            v[self.inames.index(name)] = value
        return v

    def _build(self):
        nq = self.nq
        x = ca.MX.sym("x", self.nx)
        inp = ca.MX.sym("inp", len(self.inames))
        par = ca.MX.sym("par", len(self.pnames))
        q, u = x[:nq], x[nq:2 * nq]
        f, power = self.fns["cedra_f"](q, u, inp, par)
        if "cedra_fc" in self.fns:                     # the collision points' forces (the FMU gates them)
            f = f + self.fns["cedra_fc"](q, u, inp, par)
        udot = ca.solve(self.fns["cedra_M"](q, par), f)
        xdot = ca.vertcat(u, udot, power)
        self.x_sym, self.p_sym = x, ca.vertcat(inp, par)
        self.xdot_expr = xdot
        self.rhs = ca.Function("rhs", [x, self.p_sym], [xdot])
        self.jac = ca.Function("rhs_jac", [x, self.p_sym], [ca.jacobian(xdot, x)])
        self.out_fn = self.fns["cedra_out"]

    # -------------------------------------------------------------- start state
    def settle(self, q_start=None, inp=None, tol=1e-12, max_iter=60) -> np.ndarray:
        """Static equilibrium as the FMU computes it: q = cedra_guess(q_start), then Newton on cedra_settle
        for the settle_idx coordinates, to a residual below tol (N, N.m) or a step below 1e-15. On a very stiff
        ground (where the guess's 1 mm penetration is far from equilibrium) Newton is continued from the
        scene's ground_k up to the case's, in factors of 10."""
        q = np.array(self.spec.q_start if q_start is None else q_start, float)
        inp = self.inp0 if inp is None else inp
        q = np.array(self.fns["cedra_guess"](q, inp, self.par)).ravel()
        try:
            return self._newton(q, inp, self.par, tol, max_iter)
        except (RuntimeError, np.linalg.LinAlgError):
            if "ground_k" not in self.pnames:
                raise
        ik = self.pnames.index("ground_k")
        k_target = self.par[ik]
        k0 = next(p.start for p in self.spec.params if p.name == "ground_k")
        par = self.par.copy()
        q = self._newton(q, inp, np.where(np.arange(len(par)) == ik, k0, par), tol, max_iter)
        n = int(np.ceil(abs(np.log10(k_target / k0))))
        for k in np.geomspace(k0, k_target, n + 1)[1:]:
            par[ik] = k
            q = self._newton(q, inp, par, tol, max_iter)
        return q

    def _newton(self, q, inp, par, tol, max_iter):
        idx = list(self.spec.settle_idx)
        settle = self.fns["cedra_settle"]
        for _ in range(max_iter):
            res, jac = settle(q, inp, par)
            res, jac = np.array(res).ravel(), np.array(jac)
            if np.max(np.abs(res)) < tol:
                return q
            dq = np.linalg.solve(jac, res)
            step = 1.0
            r0 = np.linalg.norm(res)
            while True:          # damped Newton: never accept a step that makes the residual worse
                qn = q.copy()
                qn[idx] -= step * dq
                rn = np.linalg.norm(np.array(settle(qn, inp, par)[0]).ravel())
                if rn < r0 or step * np.max(np.abs(dq)) < 1e-15:
                    break
                step /= 2
            q = qn
            if np.max(np.abs(step * dq)) < 1e-15:
                break
        res = np.array(settle(q, inp, par)[0]).ravel()
        if not np.max(np.abs(res)) < 1e-8 * max(1.0, float(par[self.pnames.index("ground_k")]) / 1e5
                                                 if "ground_k" in self.pnames else 1.0):
            raise RuntimeError(f"settle did not converge: residual {np.max(np.abs(res)):.3g}")
        return q

    def x0(self, q0, u0=None) -> np.ndarray:
        return np.concatenate([q0, np.zeros(self.nq) if u0 is None else u0, [0.0]])

    def outputs(self, x, inp) -> np.ndarray:
        nq = self.nq
        return np.array(self.out_fn(x[:nq], x[nq:2 * nq], x[2 * nq:], inp, self.par)).ravel()

    def outputs_many(self, X, inps) -> np.ndarray:
        """Outputs at many states (rows of X), one input vector per row."""
        nq = self.nq
        fm = self.out_fn.map(X.shape[0])
        Y = fm(X[:, :nq].T, X[:, nq:2 * nq].T, X[:, 2 * nq:].T, np.asarray(inps).T, self.par)
        return np.array(Y).T


# ------------------------------------------------------------------ runs on the Python side
@dataclass
class Run:
    """One simulation: the states at the grid times, wall time and counters. ok False: stopped early."""
    method: str
    setting: str
    t: np.ndarray
    X: np.ndarray
    wall: float
    steps: int = -1
    rhs_evals: int = -1
    ok: bool = True
    status: str = "ok"
    message: str = ""
    Y: np.ndarray | None = None            # outputs at the grid (FMU runs), names in `names`
    names: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)


def grid(t_end, dt):
    n = int(round(t_end / dt))
    return np.arange(n + 1) * dt


def _segments(sched: Schedule, tgrid):
    """(t0, t1, the grid points in (t0, t1], the inputs) for each constant-input segment."""
    t_end = tgrid[-1]
    bps = [0.0] + sched.breakpoints(t_end) + [t_end]
    for a, b in zip(bps[:-1], bps[1:]):
        pts = tgrid[(tgrid > a + 1e-12) & (tgrid <= b + 1e-12)]
        yield a, b, np.clip(pts, a, b), sched.at(a)


def run_casadi(prob: Problem, sched: Schedule, x0, tgrid, plugin="cvodes", tol=1e-12, label=None) -> Run:
    """CasADi's SUNDIALS integrators (cvodes: BDF/Newton; idas: the same ODE as an index-0 DAE), rtol = atol =
    tol, one integrator call per constant-input segment with outputs at the grid points."""
    dae = {"x": prob.x_sym, "p": prob.p_sym, "ode": prob.xdot_expr}
    opts = {"abstol": tol, "reltol": tol, "max_num_steps": 10 ** 8}
    if plugin == "cvodes":
        opts["linear_multistep_method"] = "bdf"
    cache = prob.__dict__.setdefault("_integrators", {}).setdefault((plugin, tol), {})
    # the ODE is time-invariant: one integrator per pattern of relative output times, kept on the Problem
    # (construction is not counted in a later run's wall time; the first run of a pattern pays it)
    X = [np.asarray(x0, float)]
    x = np.asarray(x0, float)
    steps = evals = 0
    wall = time.perf_counter()
    ok, msg = True, ""
    try:
        for a, b, pts, inp_values in _segments(sched, tgrid):
            out_t = list(pts) if len(pts) and abs(pts[-1] - b) < 1e-12 else list(pts) + [b]
            key = tuple(round(t - a, 10) for t in out_t)
            if key not in cache:
                cache[key] = ca.integrator("ref", plugin, dae, 0.0, list(key), opts)
            F = cache[key]
            res = F(x0=x, p=np.concatenate([prob.inp(inp_values), prob.par]))
            xf = np.array(res["xf"])
            st = F.stats()
            steps += int(st.get("nsteps", 0))
            evals += int(st.get("nfevals", 0))
            X += [xf[:, k] for k in range(len(pts))]
            x = xf[:, -1]
            if not np.all(np.isfinite(x)):
                raise RuntimeError("non-finite state")
    except RuntimeError as e:
        ok, msg = False, str(e).splitlines()[-1][:200]
    wall = time.perf_counter() - wall
    X = np.array(X)
    return Run(plugin, label or f"tol {tol:g}", tgrid[:len(X)], X, wall, steps, evals, ok,
               "ok" if ok else "error", msg)


def run_scipy(prob: Problem, sched: Schedule, x0, tgrid, method="Radau", rtol=1e-6, atol=None) -> Run:
    """scipy.integrate.solve_ivp on the same equations (the CasADi functions called from Python; the implicit
    methods get the exact Jacobian), restarted at each input breakpoint."""
    from scipy.integrate import solve_ivp
    atol = rtol if atol is None else atol
    X = [np.asarray(x0, float)]
    x = np.asarray(x0, float)
    evals = 0
    ok, msg = True, ""
    rhs, jac = prob.rhs, prob.jac
    wall = time.perf_counter()
    for a, b, pts, inp_values in _segments(sched, tgrid):
        p = np.concatenate([prob.inp(inp_values), prob.par])

        def f(t, y):
            return np.array(rhs(y, p)).ravel()

        def J(t, y):
            return np.array(jac(y, p))
        kw = {"jac": J} if method in ("Radau", "BDF", "LSODA") else {}
        sol = solve_ivp(f, (a, b), x, method=method, rtol=rtol, atol=atol, dense_output=False,
                        t_eval=np.concatenate([pts, [b]]) if not len(pts) or abs(pts[-1] - b) > 1e-12 else pts,
                        **kw)
        evals += sol.nfev
        n_ok = min(len(pts), sol.y.shape[1])
        X += [sol.y[:, k] for k in range(n_ok)]
        if sol.status != 0 or not np.all(np.isfinite(sol.y)):
            ok, msg = False, str(sol.message)
            break
        x = sol.y[:, -1]
    wall = time.perf_counter() - wall
    X = np.array(X)
    return Run(f"scipy {method}", f"rtol {rtol:g}", tgrid[:len(X)], X, wall, -1, evals, ok,
               "ok" if ok else "error", msg)


# ------------------------------------------------------------------ the FMU
def fmu_start_values(prob: Problem, q0, u0=None, method="rodas4", tol=1e-6, h_max=0.01, inputs=None,
                     settle=False) -> dict:
    """Start values by name: every coordinate and speed, no settle (the FMU starts from exactly q0, u0), the
    solver settings, and the parameter/input overrides."""
    v = {f"start.{n}": float(q0[k]) for k, n in enumerate(prob.q_names)}
    if u0 is not None:
        v |= {f"start.speed.{n}": float(u0[k]) for k, n in enumerate(prob.q_names)}
    v |= {"start.settle": settle, "solver.method": SOLVER_CODES[method], "solver.tol": tol, "solver.h_max": h_max}
    v |= {k: val for k, val in prob.overrides.items()}
    v |= dict(inputs or {})
    return v


class FastFMU:
    """RoverFMU plus vectorized getReal of a fixed list of outputs (one ctypes call per read)."""

    def __init__(self, path):
        from cedra.run.driver import RoverFMU
        self.f = RoverFMU(path)

    def vrs(self, names):
        return [self.f.vars[n].valueReference for n in names]


def run_fmu(fmu_path, prob: Problem, sched: Schedule, q0, t_end, comm, method="rodas4", tol=1e-6, h_max=0.01,
            record=None, record_every=None, u0=None, check_all=True, wall_budget=None) -> Run:
    """Run the FMU from q0 (start.settle = false) with the schedule's inputs, communication step `comm`.

    record: output names read at the grid points that are multiples of record_every (default: every point).
    check_all: read every Real output at every communication point and flag any non-finite value.
    wall_budget: stop (ok False, extra['timeout'] True) when the run has taken longer than this many seconds. The
    FMU's own per-call budget (solver.max_wall_time, 1 s by default) is lifted to it, as a sweep does, so that
    whether a hard case finishes does not depend on how loaded the machine is (ground_k 1e8 needs ~1 s for one
    communication step on a quiet machine); the run's budget still bounds every call."""
    from cedra.run.driver import RoverFMU
    fmu = RoverFMU(fmu_path)
    names = list(record or [])
    real_out = [v for v in fmu.md.modelVariables if v.causality == "output" and v.type == "Real"]
    all_vr = [v.valueReference for v in real_out]
    rec_vr = [fmu.vars[n].valueReference for n in names]
    counters = ["solver.steps", "solver.rejected", "solver.rhs_evals"]
    n = int(round(t_end / comm))
    every = 1 if record_every is None else max(1, int(round(record_every / comm)))
    T, Y = [], []
    nan_seen, nan_at = False, None
    getReal = fmu.fmu.getReal
    wall = time.perf_counter()
    ok = True
    try:
        start = fmu_start_values(prob, q0, u0, method, tol, h_max, sched.at(0.0))
        if wall_budget is not None and fmu.has("solver.max_wall_time"):
            start["solver.max_wall_time"] = float(wall_budget)
        fmu.start(start)
    except Exception as e:           # noqa: BLE001 - the FMU refused to initialize: reported, not raised
        fmu.status = "error"
        fmu.messages.append(f"initialization failed: {e}")
        ok = False
    timeout = False
    current = sched.at(0.0)
    k = 0
    while ok:
        t = k * comm
        if k % every == 0 and names:
            Y.append(getReal(rec_vr))
            T.append(t)
        if check_all:
            yall = getReal(all_vr)
            if not nan_seen and not all(np.isfinite(yall)):
                nan_seen, nan_at = True, t
        if k == n:
            break
        want = sched.at(t)
        if want is not current:
            fmu.set(want)
            current = want
        if not fmu.step((k + 1) * comm):
            ok = False
            break
        k += 1
        if wall_budget is not None and time.perf_counter() - wall > wall_budget:
            ok, timeout = False, True
            break
    wall = time.perf_counter() - wall
    stats = {}
    if fmu.status in ("ok", "warning", "discard"):
        try:
            stats = dict(zip(counters, fmu.get(counters)))
        except Exception:            # noqa: BLE001
            pass
    r = Run(f"FMU {method}", f"h {h_max:g}" if method == "rk4" else f"tol {tol:g}", np.array(T),
            np.empty((0, 0)), wall, int(stats.get("solver.steps", -1)), int(stats.get("solver.rhs_evals", -1)),
            ok, fmu.status, " | ".join(m for m in fmu.messages[-3:]), np.array(Y), names,
            dict(rejected=int(stats.get("solver.rejected", -1)), nan=nan_seen, nan_at=nan_at, comm=comm,
                 reached=k * comm, messages=list(fmu.messages), timeout=timeout))
    fmu.close()
    return r


# ------------------------------------------------------------------ errors
def position_names(prob: Problem):
    return [n for n in ("body.x", "body.y", "body.z") if n in prob.out_names]


def fn_names(prob: Problem):
    return [f"wheel[{i}].Fn" for i in range(1, 7) if f"wheel[{i}].Fn" in prob.out_names]


@dataclass
class Reference:
    t: np.ndarray
    Y: np.ndarray          # outputs at t (every output of cedra_out)
    names: list

    def cols(self, names):
        return self.Y[:, [self.names.index(n) for n in names]]


def reference_outputs(prob: Problem, sched: Schedule, run: Run) -> Reference:
    inps = np.array([prob.inp(sched.at(t)) for t in run.t])
    names = prob.out_names + ["energy.kinetic", "energy.potential", "energy.work"][:0]
    Y = prob.outputs_many(run.X, inps)
    names = prob.out_names
    return Reference(run.t, Y[:, :len(names)], names)


def errors(ref: Reference, t, Y, names, prob: Problem) -> dict:
    """Max over the common times of the body-position error (Euclidean, m) and of the normal-force error
    (largest over the wheels, N), absolute and relative (divided by the largest reference value over time:
    |body position| for the position, max Fn for the forces)."""
    t = np.asarray(t)
    idx = np.searchsorted(ref.t, t - 1e-9)
    keep = (idx < len(ref.t))
    keep[keep] &= np.abs(ref.t[idx[keep]] - t[keep]) < 1e-9
    if not np.any(keep):
        return dict(pos_abs=np.nan, pos_rel=np.nan, fn_abs=np.nan, fn_rel=np.nan, n=0)
    t_idx, r_idx = np.nonzero(keep)[0], idx[keep]
    Y = np.asarray(Y)
    pos, fns = position_names(prob), fn_names(prob)
    P = Y[np.ix_(t_idx, [names.index(n) for n in pos])]
    Pr = ref.cols(pos)[r_idx]
    F = Y[np.ix_(t_idx, [names.index(n) for n in fns])]
    Fr = ref.cols(fns)[r_idx]
    pos_abs = float(np.max(np.linalg.norm(P - Pr, axis=1)))
    fn_abs = float(np.max(np.abs(F - Fr)))
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(F))):
        pos_abs = fn_abs = np.inf
    return dict(pos_abs=pos_abs, pos_rel=pos_abs / float(np.max(np.linalg.norm(ref.cols(pos), axis=1))),
                fn_abs=fn_abs, fn_rel=fn_abs / float(np.max(np.abs(ref.cols(fns)))), n=int(len(t_idx)))


def python_run_outputs(prob: Problem, sched: Schedule, run: Run, names) -> np.ndarray:
    inps = np.array([prob.inp(sched.at(t)) for t in run.t])
    Y = prob.outputs_many(run.X, inps)
    return Y[:, [prob.out_names.index(n) for n in names]]


# ------------------------------------------------------------------ report helpers
def fmt(v, digits=3):
    if v is None:
        return "-"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return "-" if v < 0 else str(int(v))
    if not np.isfinite(v):
        return str(v)
    return f"{v:.{digits}g}"


def fmu_path(build, scene_name) -> Path:
    """<build>/<scene_name>.fmu; a shipped scene's or drive controller's is built there first when it is missing or
    stale (cedra.run.scenario.fmu, which says so)."""
    from cedra.models.controller import CONTROLLERS
    from cedra.models.scene import shipped
    if scene_name in CONTROLLERS or scene_name in shipped():
        from cedra.run.scenario import fmu
        return fmu(scene_name, build)
    return Path(build) / f"{scene_name}.fmu"


FN = [f"wheel[{i}].Fn" for i in range(1, 7)]


@dataclass
class Loop:
    """One run of the paper's closed loop (cedra.run.simulate.speed_loop) through an FMU: every sample's outputs
    (names), the CPU of the timed part and the solver's counters."""
    ok: bool
    status: str
    messages: list[str]
    cpu: float
    t: np.ndarray
    y: np.ndarray                   # samples x names
    names: list[str]
    counters: dict = field(default_factory=dict)

    @property
    def message(self) -> str:
        """The FMU's last message where the run stopped early, else empty."""
        return "" if self.ok else "; ".join(self.messages[-1:])

    def col(self, name):
        return self.y[:, self.names.index(name)]

    @property
    def fn(self):
        return self.y[:, [self.names.index(n) for n in FN]]

    @property
    def t_end(self):
        return float(self.t[-1])


def closed_loop(path, stop_time, settings: dict | None = None, extra=()) -> Loop:
    """The paper's run through the FMU at path (docs/model.md; the main job's loop cedra.run.simulate.speed_loop: its
    speed controller, equal torques, every 0.01 s), from fmi2Instantiate to stop_time or the first refused step,
    reading only body.vx (for the controller), body.x, the six wheel[i].Fn and those of `extra` the FMU has, in one
    fmi2GetReal per sample. The loop calls the FMU's fmi2 functions with buffers made once, as a compiled master
    would (FMPy's checked wrappers build the arrays on every call: ~20 us per sample on this machine, a fifth of a
    flat3d sample), so the CPU time is the FMU's and not the Python glue's. Timed with time.process_time from
    fmi2Instantiate (the static settle included) to the last step; the FMU's unzip is not timed. Every report's
    closed loop: the benchmark's (fmu_closed_loop), the defaults' and the figures'."""
    from cedra.run.driver import RoverFMU
    from cedra.run.simulate import speed_loop
    f = RoverFMU(path)
    names = ["body.vx", "body.x"] + FN + [n for n in extra if f.has(n)]
    ts, ys = [], []

    def record(k, t, y, tau):
        ts.append(t)
        ys.append(y)
        return False

    cpu = time.process_time()
    f.start(settings or {})
    ok = speed_loop(f, stop_time, names, record)
    cpu = time.process_time() - cpu
    counters = {k: int(v) for k, v in zip(("steps", "rejected", "rhs_evals"),
                                          f.get(["solver.steps", "solver.rejected", "solver.rhs_evals"]))}
    counters["jac_evals"] = int(f.get(["solver.jac_evals"])[0]) if f.has("solver.jac_evals") else -1
    status, messages = f.status, list(f.messages)
    f.close()
    return Loop(ok, status, messages, cpu, np.array(ts), np.array(ys), names, counters)


def fmu_closed_loop(path, stop_time, settings: dict | None = None, label="", record=()):
    """closed_loop as the benchmark's Result (cedra.reports.mujoco_model.Result, the MuJoCo runs' record): label, CPU,
    simulated time, steps, body.x and the six wheel[i].Fn over the samples. record: more outputs read in the same
    call, returned as extra["series"][name] (arrays over the samples)."""
    from cedra.reports.mujoco_model import Result
    r = closed_loop(path, stop_time, settings, record)
    msg = "" if r.ok else f"{r.status}: " + "; ".join(r.messages[-2:])
    series = {n: r.col(n) for n in record}
    c = r.counters
    return Result(label or f"FMU {Path(path).stem}", r.cpu, r.t_end, c["steps"], r.t, r.col("body.x"), r.fn, r.ok,
                  msg, extra=dict(rejected=c["rejected"], rhs_evals=c["rhs_evals"], jac_evals=c["jac_evals"],
                                  series=series))
