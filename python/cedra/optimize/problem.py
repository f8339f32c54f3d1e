"""The optimizer's problem file (TOML): its keys, their defaults, and the checks that fail before any work,
each error naming the file, the key and the reason (as scene files do: cedra.models.scene's checks).

    scene = "bump2d"                # a shipped 2D compliant scene without drives (the shipped problems: bump2d,
                                    # step2d)
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
    method = "shooting"             # shooting: multiple shooting on the control grid (the law smoothed or not) |
                                    # hybrid: the contact-mode sequence of the guess fixed, the event times free
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
    guard_rate = 1e-5               # hybrid: m/s, the least rate of a guard at its event (no event grazes)
    min_phase = 1e-4                # hybrid: s, the shortest phase (an event this close to a node is on its bound)
    rounds = 5                      # hybrid: the outer loop's solves at most (re-binned on the replay's events)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cedra.models.scene import choice, fail, load_shipped, number, read_toml, shipped
from cedra.rover.parameters import DEFAULTS

OBJECTIVES = ("energy", "peak_friction", "time")
GUESSES = {"equal_torques": 0, "inverse_kinematics": 1, "traction_control": 2}     # ctrl.mode of the drive controller
REPLAY_STEP = 0.01           # s: the FMU replay's communication step (the controllers' runs use it too)
TOP_KEYS = {"name", "scene", "objective", "margin", "interval", "horizon", "torque_max", "start_x", "guess", "speed",
            "regularization", "method", "inputs", "solver"}
SOLVER_KEYS = {"max_iter", "tol", "integrator_tol", "threads", "hessian", "proximal", "smoothing", "spin_rates",
               "guard_rate", "min_phase", "rounds"}
METHODS = ("hybrid", "shooting")
HYBRID_ONLY = ("guard_rate", "min_phase", "rounds")
SMOOTHING_MAX = 0.01         # m: the largest smoothing width of the contact law a problem may give
HESSIANS = ("objective", "limited-memory", "differenced")
SPIN_RATES = ("carried", "nodes")     # the wheels' spin rates: carried through the intervals | node decisions


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
    method: str = "shooting"
    guard_rate: float = 1e-5
    min_phase: float = 1e-4
    rounds: int = 5
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
    problem.method = _choice(path, "method", data.get("method", "shooting"), METHODS)
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
        elif key == "guard_rate":
            problem.guard_rate = _number(path, k, value, 0.0, 1.0)
        elif key == "min_phase":
            problem.min_phase = _number(path, k, value, 1e-9, 0.25 * interval)
        elif key == "rounds":
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 50:
                _fail(path, k, f"expected an integer in 1..50, got {value!r}")
            problem.rounds = value
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
    if problem.method == "hybrid":
        _hybrid_checks(path, problem, solver)
    else:
        for key in HYBRID_ONLY:
            if key in solver:
                _fail(path, f"solver.{key}", "is a setting of method = \"hybrid\"")
    return problem


def _hybrid_checks(path, problem: Problem, solver: dict):
    """What method = "hybrid" forms: the FMU's law on every phase (no smoothing), the energy objective on a fixed
    horizon, every shooting state a node, scenes whose switching laws are wheel contacts and joint stops."""
    if problem.objective != "energy":
        _fail(path, "objective", f"method = \"hybrid\" is formed for the energy objective, got {problem.objective!r}")
    if "smoothing" in solver and problem.smoothing != (0.0,):
        _fail(path, "solver.smoothing", "method = \"hybrid\" integrates the FMU's law in every phase: no smoothing")
    if problem.spin_rates != "nodes":
        _fail(path, "solver.spin_rates", "method = \"hybrid\" makes every shooting state a node decision")
    if any(h == "differenced" for h in problem.hessian) or len(problem.hessian) > 1 or len(problem.proximal) > 1:
        _fail(path, "solver.hessian", "method = \"hybrid\" takes one Hessian: objective or limited-memory")
    if load_shipped(problem.scene).options.chassis:
        _fail(path, "method", f"\"hybrid\" is formed for scenes without chassis contact (scene {problem.scene} "
              "has collision points)")


def _stage_values(value) -> list:
    """A per-stage setting's values: a non-empty list as given, anything else one value for every stage."""
    return value if isinstance(value, list) and value else [value]


def at_stage(values: tuple, stage: int):
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


