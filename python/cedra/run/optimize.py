"""Dynamics optimization of a climb: `python -m cedra optimize <problem.toml> [--out DIR] [--build DIR]`.

The wheel torques over time that take the planar rover over an obstacle at the least cost, on the very equations
the scene's FMU integrates (cedra_M, the forces f, the compliant contact and its contact search), solved by IPOPT
through CasADi's nlpsol. Then the optimal torques are replayed open loop through the scene's FMU, and the report
compares the optimum with the drive controller's three modes (equal torques, inverse kinematics, traction control)
on the same measures, from the same FMU runs.

Method: direct multiple shooting. The contact is stiff (a slipping wheel's spin relaxes at ~1e4 1/s: the friction
law's slope mu Fn / v_eps on the wheel's own small inertia), so a transcription has to integrate it with an
implicit, error-controlled method to follow the FMU to 1e-4 m. Collocation would need a grid fine enough for that
accuracy everywhere (thousands of intervals over a climb, each with its own contact switches); multiple shooting
keeps a coarse control grid (0.05-0.1 s) and lets CVODES (BDF, tolerances `solver.integrator_tol`) place its steps
and find each interval's end state and its sensitivities. One shooting interval per control interval.

The equations: the ODE [u; M^-1 f] formed from the model's own symbolic M and f (with the collision points' force
cedra_fc where the scene has chassis contact), generated to C with its Jacobian and compiled once per model (cached
under build/host/), as the FMU is. The contact search (cedra_rim_search, the FMU's C search) makes discrete choices
and returns converged angles: the model never differentiates it (cedra.mechanics.contact.rim_contacts), and
neither does the optimizer (casadi.stop_diff on its results). Second derivatives of the equations are not formed:
IPOPT's Hessian of the Lagrangian is by default the objective's own (exact for the energy, a sum of squares of the
torques) without the shooting constraints' curvature, a generalized Gauss-Newton method (`solver.hessian =
"objective"`); "differenced" adds that curvature, each interval's block from forward differences of its
sensitivities (ShootingHessian: Newton's method, at ten times an iteration's cost or more); "limited-memory" is
IPOPT's quasi-Newton approximation. CVODES' sensitivity Newton iteration uses the first-order Jacobian. The
wheels' spin angles enter no force, so the shooting state leaves them out (14 of the model's 18 states), and with
a fixed horizon the interval's length is a constant, not a parameter the sensitivities are taken for. The wheels'
spin rates are node decisions by default; `solver.spin_rates = "carried"` carries them from interval to interval
instead (cedra.run.shooting: a landing wheel's rate is a steep function of its touchdown), and "differenced" then
forms the chain's second-order adjoint (energy objective).

Initial guess (`guess`): a drive controller's run from the same start, its states at the grid nodes and its mean
torques per interval. The equal-torque and inverse-kinematics controllers sample every 0.01 s, so their torques
vary within an interval and the guess's shooting defects are large (up to 100 rad/s in the wheel rates on the
bump at 0.2 s intervals); "traction_control" samples the traction controller once per interval (its rolling-rate
hold's gain scaled to the period), so its torques are piecewise constant on the grid and the guess is a point of
the shooting problem up to the integrators' tolerances (defects 1e-4 on the bump at 0.1 s intervals).

Decisions: one torque per wheel pair and interval, piecewise constant. The planar model's wheels 3 and 4 share the
spin coordinates of wheels 1 and 2 (the left and right bogie wheels roll on the same profile), so tau[1] + tau[3]
is what drives gamma1: the optimizer sets tau[1] = tau[3], tau[2] = tau[4] (the split that costs least energy),
tau[5] and tau[6] on their own; each |tau[i]| <= torque_max (default: the drive model's stall torque).

Objectives (problem key `objective`):
  energy         the integral of sum_i tau_i^2 over the six wheels (N^2.m^2.s): the motors' copper loss up to
                 the constant R / k_t^2, the cost of current; exact for piecewise constant torques. Fixed horizon.
  peak_friction  the peak over the grid nodes and the wheels of |Fx| / Fn, as an epigraph variable s with
                 -s Fn <= Fx <= s Fn at every node (no division: a wheel in the air has Fn = Fx = 0). Fixed horizon.
  time           the final time, free (the interval length is a decision variable).
peak_friction and time add `regularization` x energy (default 1e-3), which picks one of the many torque histories
with the same peak or time. Terminal condition: body.x >= terrain_x0 + margin at the final time.

Contact non-smoothness: the compliant law's normal force max(0, k delta - d v_n) and its onset at delta = 0 are
kinks and a jump in the state derivative; the friction law is already regularized by v_eps. The integrator
crosses them with error control (the FMU locates them; CVODES shortens its steps), and the sensitivities carry no
jump term at a switch. `solver.smoothing` replaces them, in the optimizer's equations only, by the smoothed law
of contact.compliant_law (a softplus of the clip and a sigmoid of the onset over a depth width w, w = 0 the FMU's
law exactly), the joint stops' law likewise (mechanism.stop_torque, over w / R_w in radians: the same clip and
onset), and solves a continuation: one stage per width, each started from the previous stage's decisions
and multipliers. The width is an input of the compiled equations, so one library serves every stage; the FMUs
are generated without it. The replay integrates the FMU's own law, so with a last width > 0 its deviation from the
optimizer's path measures the smoothing too (docs/optimize.md).

Problem files (TOML), checked before anything runs, each error naming the file, the key and the reason:

    scene = "bump2d"                # a shipped 2D compliant scene without drives (bump2d, step2d, stairs2d)
    objective = "energy"            # energy | peak_friction | time
    margin = 0.4                    # m: body.x must end beyond terrain_x0 + margin (negative: short of it)
    interval = 0.1                  # s: the control grid (a whole number of the 0.01 s replay step)
    horizon = 6.0                   # s (time: the initial guess); default: the guess run's arrival, rounded up
    torque_max = 6.0                # N.m (default: drive_stall_torque)
    start_x = 0.0                   # m (default: the scene's start)
    guess = "inverse_kinematics"    # the controller run that starts the optimizer: inverse_kinematics |
                                    # equal_torques | traction_control (sampled on the grid)
    speed = 0.2                     # m/s: the controllers' commanded speed
    regularization = 1e-3           # weight of energy added to peak_friction and time
    [inputs]                        # the scene's inputs for this problem (terrain_h, mu, ...; not the torques)
    [solver]
    max_iter = 200                  # IPOPT iterations (of each stage)
    tol = 1e-6                      # IPOPT tolerance
    integrator_tol = 1e-8           # CVODES abstol = reltol of the shooting integrator
    threads = 1                     # the shooting intervals integrated on this many threads (CasADi map)
    hessian = "objective"           # objective: the objective's own Hessian (generalized Gauss-Newton) |
                                    # differenced: plus the shooting constraints' curvature, differenced from
                                    # the sensitivities (fixed horizon only) | limited-memory: IPOPT's
                                    # quasi-Newton approximation; a list: one per smoothing stage
    proximal = 0.0                  # hessian = "objective": this times the identity on the node states added
                                    # (shorter steps where the contact makes the linearization poor; a list:
                                    # one weight per smoothing stage)
    smoothing = [0.0]               # m: the contact law's smoothing width of each continuation stage, strictly
                                    # decreasing, each in [0, 0.01]; 0 is the FMU's law
    spin_rates = "nodes"            # the wheels' spin rates: decisions at every node | carried: through the
                                    # intervals (the shooting nodes hold the body and joint states)
"""
from __future__ import annotations

import hashlib
import math
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from cedra.models.scene import SceneError, choice, fail, load_shipped, number, read_toml, shipped
from cedra.rover.parameters import DEFAULTS
from cedra.run.oracle import NumpyFunction, hess_lag_io
from cedra.run.shooting import CarriedSpinHessian, CarriedSpinShooting, interval_jacobian, mapped

OBJECTIVES = ("energy", "peak_friction", "time")
GUESSES = {"equal_torques": 0, "inverse_kinematics": 1, "traction_control": 2}     # ctrl.mode of the drive controller
REPLAY_STEP = 0.01           # s: the FMU replay's communication step (the controllers' runs use it too)
PAIRS = (0, 1, 0, 1, 2, 3)   # tau[1..6] from the four decisions (wheel pairs 1/3, 2/4, then 5, 6)
WHEELS = (1, 2, 5, 6)        # the planar model's distinct wheels (3, 4 repeat 1, 2)
RATE_MAX = 200.0             # rad/s: bound of the wheels' spin rates at the nodes (state_bounds)
SPEED_MAX = 20.0             # m/s, rad/s: bound of the other rates at the nodes
ARRIVAL_TOL = 1e-4           # m: the goal counts as reached this close (the optimum ends on it, the replay within this)
FN_MIN = 1.0                 # N: a wheel counts in the friction ratio while it carries more than this
TOP_KEYS = {"name", "scene", "objective", "margin", "interval", "horizon", "torque_max", "start_x", "guess", "speed",
            "regularization", "inputs", "solver"}
SOLVER_KEYS = {"max_iter", "tol", "integrator_tol", "threads", "hessian", "proximal", "smoothing", "spin_rates"}
SMOOTHING_MAX = 0.01         # m: the largest smoothing width of the contact law a problem may give
HESSIANS = ("objective", "limited-memory", "differenced")
SPIN_RATES = ("carried", "nodes")     # the wheels' spin rates: carried through the intervals | node decisions
WARM_DUALS = True            # a continuation stage starts from the previous one's multipliers too


class ProblemError(ValueError):
    """A bad problem file, raised before anything runs."""


@dataclass
class Problem:
    name: str
    scene: str
    objective: str
    margin: float
    interval: float
    horizon: float | None
    torque_max: float
    start_x: float | None
    guess: str
    speed: float
    regularization: float
    inputs: dict = field(default_factory=dict)
    max_iter: int = 200
    tol: float = 1e-6
    integrator_tol: float = 1e-8
    threads: int = 1
    hessian: tuple = ("objective",)
    proximal: tuple = (0.0,)
    smoothing: tuple = (0.0,)
    spin_rates: str = "nodes"
    path: str = ""


def _fail(path, key, reason):
    fail(path, key, reason, ProblemError)


def _number(path, key, value, lo=None, hi=None, positive=False):
    return number(path, key, value, lo, hi, positive, error=ProblemError)


def _choice(path, key, value, choices):
    return choice(path, key, value, choices, ProblemError)


def _scene_choices() -> list[str]:
    """The shipped scenes the optimizer takes: planar, compliant, torque inputs straight to the wheels."""
    out = []
    for name in shipped():
        opt = load_shipped(name).options
        if opt.dims == "2d" and opt.contact == "compliant" and not opt.drives and not opt.locked_wheels:
            out.append(name)
    return out


def parse(data: dict, path: str = "<problem>") -> Problem:
    for key in data:
        if key not in TOP_KEYS:
            _fail(path, key, f"unknown key (known: {', '.join(sorted(TOP_KEYS))})")
    for key in ("scene", "objective", "margin", "interval"):
        if key not in data:
            _fail(path, key, "missing")
    scene = _choice(path, "scene", data["scene"], _scene_choices())
    objective = _choice(path, "objective", data["objective"], OBJECTIVES)
    name = data.get("name", Path(path).stem if path != "<problem>" else f"{scene}_{objective}")
    if not isinstance(name, str) or not name or "/" in name:
        _fail(path, "name", f"expected a file name without '/', got {name!r}")
    margin = _number(path, "margin", data["margin"], -2.0, 5.0)
    interval = _number(path, "interval", data["interval"], 0.01, 1.0)
    if abs(interval / REPLAY_STEP - round(interval / REPLAY_STEP)) > 1e-9:
        _fail(path, "interval", f"must be a whole number of the replay step {REPLAY_STEP} s, got {interval:g}")
    horizon = None
    if "horizon" in data:
        horizon = _number(path, "horizon", data["horizon"], positive=True, hi=60.0)
        if horizon < 2 * interval:
            _fail(path, "horizon", f"must hold at least two intervals ({2 * interval:g} s), got {horizon:g}")
    torque_max = _number(path, "torque_max", data.get("torque_max", DEFAULTS["drive_stall_torque"]),
                         positive=True, hi=100.0)
    start_x = _number(path, "start_x", data["start_x"], -5.0, 5.0) if "start_x" in data else None
    guess = _choice(path, "guess", data.get("guess", "inverse_kinematics"), tuple(GUESSES))
    speed = _number(path, "speed", data.get("speed", 0.2), 0.05, 0.5)
    reg = _number(path, "regularization", data.get("regularization", 1e-3), 0.0, 1.0)
    problem = Problem(name, scene, objective, margin, interval, horizon, torque_max, start_x, guess, speed, reg,
                      path=str(path))
    problem.inputs = _inputs(path, data.get("inputs", {}), scene)
    solver = data.get("solver", {})
    if not isinstance(solver, dict):
        _fail(path, "solver", "must be a table")
    for key, value in solver.items():
        k = f"solver.{key}"
        if key == "max_iter":
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 10000:
                _fail(path, k, f"expected an integer in 1..10000, got {value!r}")
            problem.max_iter = value
        elif key == "tol":
            problem.tol = _number(path, k, value, 1e-12, 1e-2)
        elif key == "integrator_tol":
            problem.integrator_tol = _number(path, k, value, 1e-14, 1e-4)
        elif key == "hessian":
            problem.hessian = tuple(_choice(path, k, v, HESSIANS) for v in _stage_values(value))
        elif key == "proximal":
            problem.proximal = tuple(_number(path, k, v, 0.0, 1e3) for v in _stage_values(value))
        elif key == "smoothing":
            problem.smoothing = _widths(path, k, value)
        elif key == "spin_rates":
            problem.spin_rates = _choice(path, k, value, SPIN_RATES)
        elif key == "threads":
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 64:
                _fail(path, k, f"expected an integer in 1..64, got {value!r}")
            problem.threads = value
        else:
            _fail(path, k, f"unknown key (known: {', '.join(sorted(SOLVER_KEYS))})")
    for key, values, what in (("proximal", problem.proximal, "weight"), ("hessian", problem.hessian, "Hessian")):
        if len(values) not in (1, len(problem.smoothing)):
            _fail(path, f"solver.{key}", f"a list must give one {what} per smoothing stage "
                  f"({len(problem.smoothing)}), got {len(values)}")
    if "differenced" in problem.hessian and objective == "time":
        _fail(path, "solver.hessian", "'differenced' needs a fixed horizon (objective energy or peak_friction)")
    if "differenced" in problem.hessian and problem.spin_rates == "carried" and objective != "energy":
        _fail(path, "solver.hessian", "'differenced' with the spin rates carried is formed for the energy "
              "objective (with peak_friction: solver.spin_rates = \"nodes\")")
    return problem


def _stage_values(value) -> list:
    """A per-stage setting's values: a non-empty list as given, anything else one value for every stage."""
    return value if isinstance(value, list) and value else [value]


def _at_stage(values: tuple, stage: int):
    """A per-stage setting's value at `stage` (0-based): one value serves every stage."""
    return values[min(stage, len(values) - 1)]


def _widths(path, key, value) -> tuple:
    """The continuation's smoothing widths (m): a non-empty list, each in [0, SMOOTHING_MAX], strictly
    decreasing (each stage starts from the previous one's solution on a law nearer the FMU's)."""
    if not isinstance(value, list) or not value:
        _fail(path, key, f"expected a non-empty list of widths in m, e.g. [1e-3, 1e-4, 0.0], got {value!r}")
    widths = tuple(_number(path, key, v, 0.0, SMOOTHING_MAX) for v in value)
    if any(b >= a for a, b in zip(widths, widths[1:])):
        _fail(path, key, f"the widths must decrease from stage to stage, got {list(widths)}")
    return widths


def _inputs(path, table, scene) -> dict:
    if not isinstance(table, dict):
        _fail(path, "inputs", "must be a table")
    known = {q.name: q for q in load_shipped(scene).model().inputs if not q.name.startswith("tau[")}
    values = {}
    for key, value in table.items():
        if key not in known:
            _fail(path, f"inputs.{key}", f"not an input of scene {scene} other than the torques "
                  f"(inputs: {', '.join(known)})")
        q = known[key]
        values[key] = _number(path, f"inputs.{key}", value, q.min, q.max)
    return values


def load(path) -> Problem:
    return parse(read_toml(path, ProblemError), str(path))


# ---------------- the equations ----------------
def _compiled(functions: list[ca.Function], stem: str) -> Path:
    """The functions as C (CasADi's code generator) in one shared library, compiled once per generated source."""
    from cedra.mechanics.rim import HOST_DIR
    cg = ca.CodeGenerator(f"{stem}.c", {"with_header": False})
    for fn in functions:
        cg.add(fn)
    code = cg.dump()
    lib = HOST_DIR / f"lib{stem}_{hashlib.sha256(code.encode()).hexdigest()[:16]}.so"
    if not lib.exists():
        HOST_DIR.mkdir(parents=True, exist_ok=True)
        src = lib.with_suffix(".c")
        src.write_text(code)
        tmp = lib.with_suffix(f".{time.time_ns()}.tmp")       # parallel builds: compile, then rename
        subprocess.run(["gcc", "-O1", "-fPIC", "-shared", str(src), "-o", str(tmp), "-lm"], check=True,
                       capture_output=True)
        tmp.replace(lib)
    return lib


class Dynamics:
    """The scene's planar equations as CasADi functions of the state x = [q; u], the four torque decisions and the
    problem's constant inputs and parameters."""

    def __init__(self, problem: Problem):
        from cedra.models.plant import CedraModel
        self.scene = load_shipped(problem.scene)
        # the scene's equations with the contact law's smoothing width a free input (0: the FMU's law exactly)
        self.model = m = CedraModel(self.scene.options, smooth_contact=True)
        self.width = 0.0            # m: the smoothing width the equations below are evaluated at
        self.par = m.default_par(**self.scene.parameters)
        self.inp = m.default_inp(**(self.scene.inputs | problem.inputs))
        self.nq = m.q.numel()
        self.nx = 2 * self.nq
        # the wheels' spin angles enter no force (a round wheel): the shooting state leaves them out, which spares
        # their sensitivities; full() puts zeros in their place for the equations
        self.kept = [k for k, n in enumerate(m.q_names) if not n.startswith("gamma")] + \
            list(range(self.nq, self.nx))
        self.nr = len(self.kept)
        self.select = ca.DM.zeros(self.nx, self.nr)
        for j, k in enumerate(self.kept):
            self.select[k, j] = 1
        frozen = ca.vertcat(*[s for s, _ in m._frozen]) if m._frozen else ca.SX(0, 1)
        searched = ca.vertcat(*[e for _, e in m._frozen]) if m._frozen else ca.SX(0, 1)
        x = ca.vertcat(m.q, m.u)
        f = m.f + (m.chassis_force if m.chassis else 0)
        ode = ca.vertcat(m.u, ca.solve(m.M, f))
        jac = ca.jacobian(ode, ca.vertcat(x, m.inp))
        width = m.contact_width
        body = ca.Function("opt_ode", [x, m.inp, m.par, frozen, width], [ode], {"cse": True})
        # CasADi's name for the derivative of an external: jac_<name>(inputs, outputs) -> d outputs / d inputs
        body_jac = ca.Function("jac_opt_ode", [x, m.inp, m.par, frozen, width, ca.SX.sym("out", self.nx)],
                               [jac[:, :self.nx], jac[:, self.nx:], ca.SX(self.nx, self.par.size),
                                ca.SX(self.nx, frozen.numel()), ca.SX(self.nx, 1)], {"cse": True})
        self.ode_c = ca.external("opt_ode", str(_compiled([body, body_jac], f"cedra_opt_{self.scene.name}")))
        self.search = ca.Function("opt_search", [m.q, m.inp, m.par], [searched])
        self.frozen = frozen
        forces = [(m.contacts[k - 1]["Fn"], m.contacts[k - 1]["Fx"]) for k in WHEELS]
        self.forces_sx = ca.Function("opt_forces", [x, m.inp, m.par, frozen, width],
                                     [ca.vertcat(*[a for a, _ in forces]), ca.vertcat(*[b for _, b in forces])])

    def full(self, xr):
        """The model state [q; u] of a shooting state (the spin angles set to zero)."""
        return ca.mtimes(self.select, xr)

    def reduced(self, x) -> np.ndarray:
        """The shooting state of model states (columns)."""
        return np.asarray(x)[self.kept]

    def inputs(self, tau4):
        """The scene's input vector with the four torque decisions put in as tau[1..6]."""
        rest = ca.DM(self.inp[6:])
        return ca.vertcat(*[tau4[k] for k in PAIRS], rest)

    def _searched(self, x, inp):
        # the contact search's results enter as constants of differentiation, as in the model's own Jacobians
        return ca.stop_diff(self.search(x[:self.nq], inp, ca.DM(self.par)), 1) if self.frozen.numel() else ca.MX(0, 1)

    def ode(self, x, tau4):
        inp = self.inputs(tau4)
        # second derivatives are declared zero: the compiled library holds first derivatives only
        return ca.stop_diff(self.ode_c(x, inp, ca.DM(self.par), self._searched(x, inp), self.width), 2)

    def forces(self, xr):
        """(Fn, Fx) of wheels 1, 2, 5, 6 at shooting state xr (the FMU's wheel[i].Fn, wheel[i].Fx)."""
        x = self.full(xr)
        inp = self.inputs([0, 0, 0, 0])
        return self.forces_sx(x, inp, ca.DM(self.par), self._searched(x, inp), self.width)

    def integrator(self, tol: float, n_out: int = 1, dt: float | None = None) -> ca.Function:
        """The shooting state at the end of one interval under dx/ds = dt ode(x, tau4) from x(0), p = [tau4; dt]
        (the time objective: dt is a decision) or p = tau4 with the interval's length fixed at `dt` (no
        sensitivity to it); n_out > 1: the states at n_out equally spaced points of the interval."""
        x, p = ca.MX.sym("x", self.nr), ca.MX.sym("p", 5 if dt is None else 4)
        length = p[4] if dt is None else dt
        grid = list(np.linspace(0, 1, n_out + 1)[1:])
        ode = length * self.ode(self.full(x), p[:4])[self.kept]
        # second_order_correction: CasADi's Newton matrix of the sensitivity-augmented system would carry the
        # equations' second derivatives, which are declared zero (first derivatives only): leaving the term out
        # gives the same sensitivities bit for bit at half the cost (the whole bump's interval Jacobians at 0.1 s,
        # measured: 4.8 -> 2.3 s for 14 of them)
        return ca.integrator("shoot", "cvodes", {"x": x, "p": p, "ode": ode}, 0, grid,
                             {"abstol": tol, "reltol": tol, "fsens_err_con": False, "max_num_steps": 100000,
                              "show_eval_warnings": False, "second_order_correction": False})


# ---------------- controller runs, the initial guess, the replay ----------------
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


def goal(problem: Problem, dyn: Dynamics) -> float:
    return float(dyn.inp[[q.name for q in dyn.model.inputs].index("terrain_x0")]) + problem.margin


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


def model_path(dyn: Dynamics, x0, torques, dt, tol) -> np.ndarray:
    """The optimizer's own trajectory at every REPLAY_STEP: its integrator from x0 over the optimal torques (the
    states at the replay's communication points)."""
    n_sub = int(round(dt / REPLAY_STEP))
    F = dyn.integrator(tol, n_sub, dt)
    xs, x = [dyn.reduced(x0)], dyn.reduced(x0)
    for tau in torques:
        r = np.array(F(x0=x, p=tau)["xf"])
        xs += list(r.T)
        x = r[:, -1]
    return np.array(xs).T


# ---------------- the optimal control problem ----------------
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


def solve(problem: Problem, dyn: Dynamics, x0, X_guess, U_guess, dt_guess: float, goal_x: float,
          log: bool = False, warm: dict | None = None, proximal: float = 0.0, hessian: str = "objective",
          spin_rates: str = "nodes") -> dict:
    """Multiple shooting: decisions X_0..X_N (shooting states, X_0 fixed at x0; with spin_rates "carried" the body
    and joint states only, cedra.run.shooting), U_0..U_{N-1} (four torques each), the interval length dt (free for
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
        keep, (w, U, dt, s, g, lbg, ubg) = shooting.body, _carried_constraints(shooting, n, peak)
        extra = {"jac_g": shooting.jac_g()}
    else:
        keep, (w, U, dt, s, g, lbg, ubg) = list(range(dyn.nr)), _lifted_constraints(problem, dyn, n, dt_guess, goal_x)
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
        hess = {"hess_lag": _objective_hessian(w, J, nlp["g"].numel(), nx * (n + 1), proximal)}
    elif hessian == "differenced" and spin_rates == "carried":
        hess = {"hess_lag": CarriedSpinHessian(shooting, _objective_part(w, J, nx * (n + 1), proximal))}
    elif hessian == "differenced":
        hess = {"hess_lag": ShootingHessian(w, J, nlp["g"].numel(), n, interval_jacobian(
            dyn.integrator(problem.integrator_tol, dt=dt_guess), nx, 4), problem.threads, proximal)}
    else:
        hess = {}
    opts = {"ipopt": {"max_iter": problem.max_iter, "tol": problem.tol,
                      "hessian_approximation": "exact" if hess else "limited-memory",
                      "print_level": 5 if log else 0, "sb": "yes",
                      # the sensitivities carry no jump term where a contact law switches (see the module
                      # docstring), which keeps the dual infeasibility at 1e-3..1e-2 near the optimum: stop there
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


def _lifted_constraints(problem: Problem, dyn: Dynamics, n: int, dt_guess: float, goal_x: float):
    """The decisions w = [vec(X); vec(U); dt; s] with every shooting state a node decision, and (w, U, dt, s,
    constraints, lower bounds, upper bounds): the shooting defects, the goal, peak_friction's node forces."""
    free_dt = problem.objective == "time"
    X = ca.MX.sym("X", dyn.nr, n + 1)
    U = ca.MX.sym("U", 4, n)
    dt = ca.MX.sym("dt")
    s = ca.MX.sym("s")
    F = dyn.integrator(problem.integrator_tol, dt=None if free_dt else dt_guess)
    F = mapped(F, n, problem.threads)
    xf = F(x0=X[:, :n], p=ca.vertcat(U, ca.repmat(dt, 1, n)) if free_dt else U)["xf"]
    g = [ca.vec(xf - X[:, 1:]), X[0, n] - goal_x]
    lbg = [np.zeros(dyn.nr * n), [0.0]]
    ubg = [np.zeros(dyn.nr * n), [np.inf]]
    if problem.objective == "peak_friction":
        fn, fx = _node_forces(dyn, X[:, 1:])
        g += [ca.vec(fx - s * fn), ca.vec(-fx - s * fn)]
        lbg += [np.full(2 * 4 * n, -np.inf)]
        ubg += [np.zeros(2 * 4 * n)]
    return ca.vertcat(ca.vec(X), ca.vec(U), dt, s), U, dt, s, g, lbg, ubg


def _carried_constraints(shooting: CarriedSpinShooting, n: int, peak: bool):
    """The same for the carried spin rates (cedra.run.shooting): the nodes hold the body and joint states."""
    w = ca.MX.sym("w", shooting.nw)
    U = ca.reshape(w[shooting.u_at:shooting.u_at + 4 * n], 4, n)
    lbg = [np.zeros(shooting.nb * n), [0.0]] + ([np.full(8 * n, -np.inf)] if peak else [])
    ubg = [np.zeros(shooting.nb * n), [np.inf]] + ([np.zeros(8 * n)] if peak else [])
    return w, U, w[-2], w[-1], [shooting.constraint(w)], lbg, ubg


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


def _objective_hessian(w, J, n_g: int, n_states: int, proximal: float) -> ca.Function:
    """The Hessian of the Lagrangian without the constraints' curvature: lam_f times the objective's own (the
    energy term is a sum of squares of the torques, so its Hessian is constant and exact). The shooting constraints'
    second derivatives are not available (the integrator's sensitivities are first order); left out, the steps
    are those of a generalized Gauss-Newton method, which the objective's curvature in the torques keeps short."""
    x = ca.MX.sym("x", w.numel())
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", n_g)
    return ca.Function("nlp_hess_l", [x, ca.MX(0, 1), lam_f, lam_g],
                       [ca.triu(lam_f * _objective_part(w, J, n_states, proximal)(x))],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])


def _objective_part(w, J, n_states: int, proximal: float) -> ca.Function:
    """w -> the objective's own Hessian plus `proximal` times the identity on the first n_states decisions (the
    node states): the Hessian of the Lagrangian without the constraints' curvature, per unit lam_f."""
    x = ca.MX.sym("x", w.numel())
    hess = ca.hessian(ca.Function("objective", [w], [J])(x), x)[0]
    return ca.Function("objective_part", [x], [hess + ca.diag(ca.vertcat(ca.DM.ones(n_states) * proximal,
                                                                          ca.DM.zeros(w.numel() - n_states)))])


class ShootingHessian(NumpyFunction):
    """The Hessian of the Lagrangian with the shooting constraints' curvature (solver.hessian = "differenced"):
    lam_f times the objective's own with the proximal term (_objective_part, as the Gauss-Newton Hessian) plus,
    for every interval k, the second derivative of lam_k . F(X_k, U_k) in the interval's own decisions
    z_k = (X_k, U_k), from forward differences of its Jacobian (CVODES' first-order sensitivities, `jacobian`:
    z -> d F / d z) in each component of z_k, symmetrized. The equations' own second
    derivatives are not compiled, and differencing the sensitivities costs len(z_k) more Jacobians an interval (on
    `threads` threads): on the whole bump (53 intervals of 0.1 s, 2 threads) an iteration takes about 50 s
    instead of the Gauss-Newton iteration's 4 s. The shooting constraints are the first nx n entries of g
    (X_{k+1} = F(X_k, U_k)); any further constraints (peak_friction's node forces) keep their curvature out, as in
    the Gauss-Newton Hessian. The decisions are w = [vec(X) (nx x (n + 1)); vec(U) (nu x n); anything else]."""

    STEP = 1e-5           # the forward difference's step, relative to max(1, |z|): the sensitivities are accurate to
    # about 1e-5 relative (docs/optimize.md), so the difference carries about that over the step, 1e-5 x |H|

    def __init__(self, w, J, n_g: int, n: int, jacobian: ca.Function, threads: int = 1, proximal: float = 0.0):
        self.nx, self.nu = jacobian.size1_out(0), jacobian.size2_out(0) - jacobian.size1_out(0)
        self.nw, self.n_g, self.n = w.numel(), n_g, n
        nz, nx = self.nx + self.nu, self.nx
        self.objective_part = _objective_part(w, J, nx * (n + 1), proximal)
        self.jacobians = mapped(jacobian, n * (nz + 1), threads)
        self.blocks = [np.r_[np.arange(k * nx, (k + 1) * nx), nx * (n + 1) + self.nu * k + np.arange(self.nu)]
                       for k in range(n)]
        # the pattern: every interval's block, the diagonal (proximal) and the objective's own Hessian
        own = self.objective_part.sparsity_out(0)
        rows = np.concatenate([np.repeat(idx, nz) for idx in self.blocks] + [np.arange(self.nw), own.row()])
        cols = np.concatenate([np.tile(idx, nz) for idx in self.blocks] + [np.arange(self.nw), own.get_col()])
        upper = rows <= cols
        self.sparsity = ca.Sparsity.triplet(self.nw, self.nw, rows[upper].tolist(), cols[upper].tolist())
        super().__init__("nlp_hess_l", *hess_lag_io(self.nw, n_g, self.sparsity))

    def evaluate(self, w, p, lam_f, lam_g):
        return [np.triu(self.matrix(w, lam_f[0], lam_g))]

    def matrix(self, w: np.ndarray, lam_f: float, lam_g: np.ndarray) -> np.ndarray:
        """The full (symmetric) Hessian of lam_f f + lam_g . g at w, as a dense array."""
        nx, n, nz = self.nx, self.n, self.nx + self.nu
        H = lam_f * np.array(self.objective_part(w))
        Z = np.stack([w[idx] for idx in self.blocks], axis=1)                 # nz x n: every interval's z_k
        steps = self.STEP * np.maximum(1.0, np.abs(Z))
        variants = [Z] + [Z + np.eye(nz)[:, [c]] * steps[c] for c in range(nz)]
        points = np.concatenate(variants, axis=1)                             # nz x n (nz + 1), variant-major
        jac = np.array(self.jacobians(points[:nx], points[nx:])).reshape(nx, nz + 1, n, nz)
        for k, idx in enumerate(self.blocks):
            lam = lam_g[k * nx:(k + 1) * nx]
            base = lam @ jac[:, 0, k, :]
            block = np.stack([(lam @ jac[:, 1 + c, k, :] - base) / steps[c, k] for c in range(nz)], axis=1)
            H[np.ix_(idx, idx)] += 0.5 * (block + block.T)
        return H


def state_bounds(dyn: Dynamics) -> tuple[np.ndarray, np.ndarray]:
    """Generous bounds on the nodes' states that keep IPOPT's trial points in the model's domain: the joints a
    little beyond their stops (the stops are springs), the pitch well inside the FMU's 80 deg tip-over limit, the
    rates beyond anything a climb at these torques reaches. Without them a long trial step puts the four-bar
    through its toggle, where the equations have no value."""
    p = dict(zip([q.name for q in dyn.model.params], dyn.par))
    span = {"pitch": (-1.0, 1.0), "theta1": (-p["bogie_stop"] - 0.2, p["bogie_stop"] + 0.2),
            "theta4": (p["fork_stop_lo"] - 0.2, p["fork_stop_hi"] + 0.2)}
    names = dyn.model.q_names
    inf = (-np.inf, np.inf)
    rate = [RATE_MAX if nm.startswith("gamma") else SPEED_MAX for nm in names]
    lo = [span.get(nm, inf)[0] for nm in names] + [-r for r in rate]
    hi = [span.get(nm, inf)[1] for nm in names] + rate
    return np.array(lo), np.array(hi)


def _node_forces(dyn: Dynamics, X):
    fn, fx = [], []
    for k in range(X.shape[1]):
        a, b = dyn.forces(X[:, k])
        fn.append(a)
        fx.append(b)
    return ca.horzcat(*fn), ca.horzcat(*fx)


# ---------------- the command ----------------
CONTROLLER_STOP = 40.0       # s: the controllers' runs stop here if they have not arrived


def run(problem: Problem, out_dir, build_dir="build", quiet=False) -> dict:
    """Solve the problem, replay the optimum through the FMU, run the controllers, write the report; returns the
    summary (also <out>/result.json)."""
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    t_start = time.perf_counter()
    dyn = Dynamics(problem)
    goal_x = goal(problem, dyn)
    runs = {}
    for mode in GUESSES:
        stop = max(CONTROLLER_STOP, 3 * (problem.horizon or 0))
        r = controller_run(problem, dyn, mode, stop, build_dir)
        runs[mode] = (r.names, r.rows, measures(r.names, r.rows, goal_x))
        say(f"{mode}: arrives {_arrival(runs[mode][2])}, energy {runs[mode][2]['energy']:.3f} N^2.m^2.s, "
            f"peak |Fx|/Fn {runs[mode][2]['peak_friction']:.3f}")
    names, rows, m_guess = runs[problem.guess]
    dt = problem.interval
    if problem.guess == "traction_control":
        r = controller_run(problem, dyn, problem.guess, max(CONTROLLER_STOP, 3 * (problem.horizon or 0)), build_dir,
                           on_grid=True)
        names, rows, m_guess = r.names, r.rows, measures(r.names, r.rows, goal_x)
        say(f"traction_control sampled every {dt:g} s (the guess): arrives {_arrival(m_guess)}, energy "
            f"{m_guess['energy']:.3f} N^2.m^2.s")
    horizon = problem.horizon or (math.ceil(m_guess["time"] / dt - 1e-9) * dt if m_guess["arrived"] else None)
    if horizon is None:
        raise RuntimeError(f"the {problem.guess} run did not reach body.x = {goal_x:g} m in {CONTROLLER_STOP:g} s: "
                           "give the problem a horizon")
    n = int(round(horizon / dt))
    X_guess, U_guess = initial_guess(names, rows, n, dt)
    x0 = X_guess[:, 0]
    say(f"solving: {n} intervals of {dt:g} s, objective {problem.objective}, from the {problem.guess} run")
    result, stages = None, []
    for width in problem.smoothing:
        dyn.width = width
        if len(problem.smoothing) > 1:
            say(f"stage {len(stages) + 1}/{len(problem.smoothing)}: contact smoothing width {width:g} m")
        proximal, hessian = _at_stage(problem.proximal, len(stages)), _at_stage(problem.hessian, len(stages))
        result = solve(problem, dyn, x0, X_guess, U_guess, dt, goal_x, log=not quiet, warm=result, proximal=proximal,
                       hessian=hessian, spin_rates=problem.spin_rates)
        stages.append({k: result[k] for k in ("width", "status", "iterations", "wall", "objective", "violation",
                                              "success")} | {"proximal": proximal, "hessian": hessian})
        say(f"IPOPT: {result['status']} after {result['iterations']} iterations, {result['wall']:.1f} s, "
            f"constraint violation {result['violation']:.1e}, objective {result['objective']:.6g}")
    replay_names, replay_rows, replay_ok = replay(problem, dyn, x0, result["U"], result["dt"], build_dir)
    path = model_path(dyn, x0, result["U"], result["dt"], problem.integrator_tol)
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
                   final_x_optimizer=float(result["X"][0, -1]), wall=time.perf_counter() - t_start)
    _write(Path(out_dir), problem, summary, result, path, (replay_names, replay_rows), runs)
    say(f"replay through the FMU: body path within {deviation:.2e} m of the optimizer's; "
        f"optimum energy {m_opt['energy']:.3f}, peak |Fx|/Fn {m_opt['peak_friction']:.3f}, "
        f"arrives {_arrival(m_opt)} -> {out_dir}")
    return summary


def _arrival(m: dict) -> str:
    return f"t = {m['time']:.2f} s" if m["arrived"] else "never"


def _write(out: Path, problem: Problem, summary: dict, result: dict, path, replayed, runs):
    import json
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.json").write_text(json.dumps(summary, indent=2) + "\n")
    t = np.arange(result["U"].shape[0]) * result["dt"]
    np.savetxt(out / "torques.csv", np.column_stack([t, result["U"]]), delimiter=",", fmt="%.10g",
               header="t_start,tau1_tau3,tau2_tau4,tau5,tau6", comments="")
    _figure(out / "climb.png", summary, result, path, replayed, runs)
    (out / "report.md").write_text(report_text(problem, summary))


def _figure(file: Path, summary, result, path, replayed, runs):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axs = plt.subplots(3, 1, figsize=(9, 9))
    n, dt = result["U"].shape[0], result["dt"]
    tt = np.arange(n + 1) * dt
    for j, label in enumerate(["tau[1] = tau[3]", "tau[2] = tau[4]", "tau[5]", "tau[6]"]):
        axs[0].step(tt, np.r_[result["U"][:, j], result["U"][-1, j]], where="post", label=label)
    axs[0].set_ylabel("optimal torque [N.m]")
    axs[0].set_xlabel("time [s]")
    axs[0].legend(fontsize=8, ncol=4)
    axs[0].set_title(f"{summary['problem']}: {summary['objective']}, {summary['status']}, "
                     f"{summary['iterations']} iterations")
    names, rows = replayed
    col = {nm: rows[:, j] for j, nm in enumerate(names)}
    for mode, (nm, rw, _) in runs.items():
        c = {a: rw[:, j] for j, a in enumerate(nm)}
        axs[1].plot(c["body.x"], c["body.z"], lw=1, label=mode.replace("_", " "))
    axs[1].plot(path[0], path[1], "k", lw=2, label="optimum (optimizer)")
    axs[1].plot(col["body.x"], col["body.z"], "r--", lw=1, label="optimum (FMU replay)")
    axs[1].axvline(summary["goal_x"], color="gray", ls=":", label="goal")
    axs[1].set_xlim(min(path[0]) - 0.1, summary["goal_x"] + 0.2)
    axs[1].set_xlabel("body.x [m]")
    axs[1].set_ylabel("body.z [m]")
    axs[1].legend(fontsize=8)
    k = min(path.shape[1], rows.shape[0])
    axs[2].semilogy(col["time"][:k], np.maximum(np.hypot(col["body.x"][:k] - path[0, :k],
                                                          col["body.z"][:k] - path[1, :k]), 1e-12))
    axs[2].set_ylabel("|FMU - optimizer| body (x, z) [m]")
    axs[2].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(file, dpi=90)
    plt.close(fig)


def report_text(problem: Problem, s: dict) -> str:
    rows = [("optimum (FMU replay)", s["optimum"])] + [(f"{m.replace('_', ' ')} controller", v)
                                                        for m, v in s["controllers"].items()]
    lines = [f"# Optimal climb: {s['problem']}", "",
             f"Scene {s['scene']}, objective `{s['objective']}`, goal body.x >= {s['goal_x']:.3f} m, "
             f"|tau| <= {s['torque_max']:g} N.m, {s['intervals']} intervals of {s['horizon'] / s['intervals']:.4g} s "
             f"(horizon {s['horizon']:.3f} s), initial guess: the {s['guess'].replace('_', ' ')} run.", "",
             "## Solve", "",
             f"- IPOPT: **{s['status']}** after {s['iterations']} iterations, {s['solve_time']:.1f} s "
             f"(whole command {s['wall']:.1f} s); NLP objective {s['nlp_objective']:.6g}, constraint violation "
             f"{s['violation']:.1e}",
             "- contact law of the optimizer's equations: "
             + ("the FMU's (no smoothing)" if s["smoothing"] == 0 else
                f"smoothed over {s['smoothing']:g} m (the FMU replay integrates the unsmoothed law)"),
             f"- shooting integrator: CVODES, abstol = reltol = {s['integrator_tol']:g}",
             f"- replay through the FMU (open loop, the scene's own solver settings): "
             f"{'completed' if s['replay_ok'] else 'STOPPED EARLY'}; the body path (x, z) stays within "
             f"**{s['replay_deviation']:.2e} m** of the optimizer's "
             f"({'holds' if s['replay_deviation'] <= 1e-4 else 'DOES NOT hold'} the 1e-4 m agreement)",
             f"- the NLP's node states against the replay at the node times: within **{s['node_deviation']:.2e} m** "
             + ("(the shooting defects are closed: the nodes are on the integrated path)"
                if s["violation"] <= 1e-5 and s["node_deviation"] <= 1e-4 else
                "(the shooting defects are NOT closed: the nodes are not on the torques' integrated path, and "
                "the solve is no certified optimum)"), "",
             *_stage_lines(s["stages"]),
             "## Against the controllers (same FMU, same measures)", "",
             "Measured on the FMU runs recorded every 0.01 s, up to the arrival (body.x first at the goal). "
             "energy: the integral of sum tau_i^2 over the six wheels; peak |Fx|/Fn: over wheels carrying more "
             f"than {FN_MIN:g} N; work: the motors' mechanical work (energy.work).", "",
             "| run | arrives | energy [N^2.m^2.s] | peak abs(Fx)/Fn | work [J] | peak torque [N.m] |",
             "|---|---|---|---|---|---|"]
    for label, m in rows:
        lines.append(f"| {label} | {_arrival(m)} | {m['energy']:.3f} | {m['peak_friction']:.3f} | {m['work']:.3f} "
                     f"| {m['peak_torque']:.2f} |")
    lines += ["", "![optimal torques and trajectory](climb.png)", "",
              f"Reproduce: `python -m cedra optimize {problem.path}`", ""]
    return "\n".join(lines)


def _stage_lines(stages) -> list[str]:
    if len(stages) < 2:
        return []
    lines = ["Continuation (each stage started from the previous one's solution and multipliers):", "",
             "| stage | smoothing width [m] | Hessian | proximal | IPOPT | iterations | time [s] "
             "| constraint violation | objective |", "|---|---|---|---|---|---|---|---|---|"]
    for k, st in enumerate(stages):
        lines.append(f"| {k + 1} | {st['width']:g} | {st['hessian']} | {st['proximal']:g} "
                     f"| {st['status']} | {st['iterations']} | {st['wall']:.1f} | {st['violation']:.1e} "
                     f"| {st['objective']:.6g} |")
    return lines + [""]


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
    summary = run(problem, args.out or f"out/optimize/{problem.name}", args.build, args.quiet)
    return 0 if summary["success"] else 1
