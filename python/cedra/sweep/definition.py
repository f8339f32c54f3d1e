"""The sweep file (its format: cedra.sweep): its keys and their checks, what one run runs (a Target: a scene's
main-job run or a scenario script), the runs and their ids, a scene's variant under the sweep's [options], and the
same sweep at a tightened solver setting (the convergence checks).
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from cedra.sweep.maps import check_map


CONTROLLER = {"tau_max": 4.0, "v_ref": 0.2}        # the main job's controller (cedra.run.simulate)
# summary outputs of one run (see summarize); status and reason are always kept
OUTPUTS = {
    "verdict": "over | stuck | hung up | tipped | failed: how the run ended (cedra.sweep.verdicts.VERDICTS)",
    "climbed": "1 if every wheel center passed the obstacle (x > obstacle end) before the stop time, upright, "
               "else 0",
    "t_over": "s: time when the last wheel center passed the obstacle (NaN if it did not)",
    "peak_Fn": "N: largest wheel normal force of the run (rigid contact: of wheel[i].Fn_mean, which carries the "
               "impacts; peak_ratio of the means too)",
    "peak_ratio": "largest friction/normal force ratio while a wheel carries more than 5 N",
    "max_slip": "m/s: largest |wheel slip velocity|",
    "final_x": "m: body.x at the end of the run",
    "t_end": "s: simulated time reached",
}
META = ["id", "status", "reason", "wall_s"]
RUN_TIMEOUT = 300.0


class SweepError(ValueError):
    """A bad sweep file: raised before any run starts."""


@dataclass
class Sweep:
    path: Path
    name: str
    target: "Target"                 # what one run runs: a scene's main-job run or a scenario script
    stop_time: float
    outputs: list[str]
    out: Path
    run_timeout: float
    fixed: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)
    random: dict = field(default_factory=dict)      # name -> (lo, hi)
    samples: int = 0
    seed: int = 0
    map: dict | None = None          # the [map] plot (cedra.sweep.maps)

    def actuation(self) -> str:
        """What turns a scene run's wheels, for the map and its report: "drives (stall T_s N.m, no-load w_0 rad/s)"
        or "plain torque"; each with the controller's tau_max (the command, which the drives clip by their envelope).
        Empty for a scenario script."""
        if self.target.kind != "scene":
            return ""
        values = {**CONTROLLER, **self.fixed}
        swept = set(self.grid) | set(self.random)
        tau = "tau_max swept" if "tau_max" in swept else f"tau_max {values['tau_max']:g} N.m"
        scene = self.target.scene
        if not scene.options.drives:
            return f"plain torque ({tau})"
        from cedra.rover.parameters import DEFAULTS
        par = {**DEFAULTS, **scene.parameters, **values}
        stall = "stall swept" if "drive_stall_torque" in swept else f"stall {par['drive_stall_torque']:g} N.m"
        w0 = ("no-load swept" if "drive_noload_speed" in swept
              else f"no-load {par['drive_noload_speed']:g} rad/s")
        return f"drives ({stall}, {w0}; {tau} commanded)"

    @property
    def table(self) -> Path:
        return self.out / f"{self.name}.csv"

    @property
    def parameters(self) -> list[str]:
        return list(self.fixed) + list(self.grid) + list(self.random)

    def runs(self) -> list[dict]:
        """Every run's parameter values (fixed, then grid, then random), in a reproducible order."""
        names = list(self.grid)
        points = [dict(zip(names, combo)) for combo in itertools.product(*self.grid.values())]
        draws = [{}]
        if self.random:
            rng = np.random.default_rng(self.seed)
            draws = [{k: float(rng.uniform(lo, hi)) for k, (lo, hi) in self.random.items()}
                     for _ in range(self.samples)]
        return [{**self.fixed, **p, **d} for p in points for d in draws]

    def run_id(self, params: dict) -> str:
        what = {self.target.kind: self.target.name, "stop_time": self.stop_time, "params": params}
        if self.target.options:          # a variant's runs never share an id with the plain scene's
            what["options"] = self.target.options
        key = json.dumps(what, sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]


# ------------------------------------------------------------------ the sweep file

def _fail(path, key, reason):
    raise SweepError(f"{path}: {key}: {reason}")


def _finite(path, key, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(path, key, f"expected a finite number, got {value!r}")
    return float(value)


def _values(path, key, spec) -> list[float]:
    if isinstance(spec, list):
        if not spec:
            _fail(path, key, "empty list: no values to run")
        return [_finite(path, f"{key}[{k}]", v) for k, v in enumerate(spec)]
    if isinstance(spec, dict):
        extra = set(spec) - {"from", "to", "num"}
        if extra or set(spec) != {"from", "to", "num"}:
            _fail(path, key, "a range is {from = a, to = b, num = n}" +
                  (f" (unknown keys: {', '.join(sorted(extra))})" if extra else ""))
        lo, hi = _finite(path, f"{key}.from", spec["from"]), _finite(path, f"{key}.to", spec["to"])
        num = spec["num"]
        if isinstance(num, bool) or not isinstance(num, int) or num < 1:
            _fail(path, f"{key}.num", f"expected an integer >= 1, got {num!r}")
        if num > 1 and lo == hi:
            _fail(path, key, f"empty range: from = to = {lo:g} with num = {num}")
        return [float(v) for v in np.linspace(lo, hi, num)]
    _fail(path, key, f"expected a list of numbers or {{from, to, num}}, got {spec!r}")


def scene_named(path: Path, name: str):
    """A shipped scene or a scene file (relative to the sweep file), or SweepError naming the sweep file."""
    from cedra.models.scene import SceneError, load, load_shipped, shipped
    try:
        if name in shipped():
            return load_shipped(name)
        file = (path.parent / name) if not Path(name).is_absolute() else Path(name)
        if file.suffix == ".toml" and file.exists():
            return load(file)
    except SceneError as e:
        _fail(path, "scene", str(e))
    _fail(path, "scene", f"{name!r} is neither a shipped scene ({', '.join(shipped())}) nor a scene file")


def settable(scene) -> dict[str, tuple]:
    """name -> (min, max) of everything a run may set: the scene FMU's Real parameters and inputs (solver.tol and
    solver.h_max too; not the torques the controller drives, not solver.max_wall_time: see run_one), and the
    controller's settings."""
    from cedra.fmu.variables import variables
    out = {}
    for v in variables(scene.spec()):
        if v.causality in ("parameter", "input") and v.type == "Real" and not v.name.startswith("tau[") \
                and v.name != "solver.max_wall_time":
            out[v.name] = (v.min, v.max)
    out.update({"tau_max": (0.0, None), "v_ref": (None, None)})
    return out


@dataclass
class Target:
    """What a sweep's run runs. kind "scene": the main job's run on a scene's FMU (the FMU's bytes go to the
    workers); kind "scenario": a scenario script of examples/ that declares PARAMETERS and SUMMARY (its run() is
    called with params=; the workers need this checkout and its build directory at the same path)."""
    kind: str
    name: str
    limits: dict          # parameter -> (min, max)
    outputs: dict         # output -> meaning
    stop_time: float      # default
    scene: object = None  # kind "scene": the Scene (with options: the variant)
    fmus: tuple = ()      # kind "scenario": the FMUs its run() opens (built before the runs start; a (scene,
    #                       {options}) entry is a variant, variant_fmu)
    options: dict = field(default_factory=dict)    # kind "scene": the sweep file's [options]
    variant: bool = False  # kind "scene": the options changed the scene: build target.scene, not the shipped FMU


def sweep_options(path: Path, data) -> dict:
    """The sweep file's [options]: known boolean scene keys, in SWEEP_OPTIONS order."""
    from cedra.models.scene import SWEEP_OPTIONS
    if not isinstance(data, dict):
        _fail(path, "options", "expected a table")
    for key, value in data.items():
        if key not in SWEEP_OPTIONS:
            _fail(path, f"options.{key}", f"unknown option (options: {', '.join(SWEEP_OPTIONS)})")
        if not isinstance(value, bool):
            _fail(path, f"options.{key}", f"expected true or false, got {value!r}")
    return {k: data[k] for k in SWEEP_OPTIONS if k in data}


def variant(path: Path, scene, options: dict):
    """The scene with these options: its file parsed again with the keys set, so that the scene's own checks apply
    (each key is applied in turn, and the first that the scene refuses is named). Named <scene>_<key> for each
    option that changes the scene (<scene>_no<key> for one turned off); the scene itself if none does."""
    from cedra.models.scene import SceneError, parse
    changed = {k: v for k, v in options.items() if getattr(scene.options, k) != v}
    if not changed:
        return scene
    try:
        data = tomllib.loads(Path(scene.path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        _fail(path, "options", f"cannot read the scene file {scene.path} again: {e}")
    name = scene.name + "".join(f"_{k}" if v else f"_no{k}" for k, v in changed.items())
    what = ", ".join(f"{k} = {str(v).lower()}" for k, v in changed.items())
    data.update(name=name, description=f"{scene.description} (a sweep's variant: {what})".strip())
    for key, value in changed.items():
        data[key] = value
        try:
            out = parse(data, scene.path)
        except SceneError as e:
            _fail(path, f"options.{key}", f"scene {scene.name} refuses it: {e}")
    return out


def _scene_target(path: Path, name: str, options: dict) -> Target:
    scene = scene_named(path, name)
    var = variant(path, scene, options)
    return Target("scene", name, settable(var), OUTPUTS, var.stop_time, var, options=options,
                  variant=var is not scene)


def _scenario_target(path: Path, name: str) -> Target:
    from cedra.run.scenario import ScenarioError, load as load_scenario
    try:
        mod = load_scenario(name)
    except ScenarioError as e:
        _fail(path, "scenario", str(e))
    if not all(isinstance(getattr(mod, a, None), c) for a, c in (("PARAMETERS", dict), ("SUMMARY", dict),
                                                                   ("FMUS", tuple))):
        _fail(path, "scenario", f"{name!r} does not declare PARAMETERS, SUMMARY and FMUS: it cannot be swept (see "
              f"examples/turn_flat.py for the pattern)")
    limits = {k: (d[1], d[2]) for k, d in mod.PARAMETERS.items()}
    return Target("scenario", name, limits, dict(mod.SUMMARY), float(mod.STOP_TIME), fmus=mod.FMUS)


def load(path) -> Sweep:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as e:
        raise SweepError(f"{path}: cannot read: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{path}: not valid TOML: {e}") from None
    known = {"name", "scene", "scenario", "stop_time", "outputs", "out", "run_timeout", "options", "fixed", "grid",
             "random", "map"}
    for key in data:
        if key not in known:
            _fail(path, key, f"unknown key (known: {', '.join(sorted(known))})")
    if ("scene" in data) == ("scenario" in data):
        _fail(path, "scene", "give either scene (a scene's main-job run) or scenario (a scenario script), not both"
              if "scene" in data else "missing: the scene or the scenario to run")
    for key in ("scene", "scenario"):
        if key in data and not isinstance(data[key], str):
            _fail(path, key, f"expected a name, got {data[key]!r}")
    if "options" in data and "scenario" in data:
        _fail(path, "options", "only for a scene (scene = ...): a scenario script opens its own FMUs")
    options = sweep_options(path, data.get("options", {}))
    target = (_scene_target(path, data["scene"], options) if "scene" in data
              else _scenario_target(path, data["scenario"]))
    stop_time = _finite(path, "stop_time", data.get("stop_time", target.stop_time))
    if stop_time <= 0:
        _fail(path, "stop_time", f"must be > 0, got {stop_time:g}")
    timeout = _finite(path, "run_timeout", data.get("run_timeout", RUN_TIMEOUT))
    if timeout <= 0:
        _fail(path, "run_timeout", f"must be > 0, got {timeout:g}")
    outputs = data.get("outputs", list(target.outputs))
    if not isinstance(outputs, list) or not outputs:
        _fail(path, "outputs", "expected a non-empty list of output names")
    for k, o in enumerate(outputs):
        if o not in target.outputs:
            _fail(path, f"outputs[{k}]", f"no output {o!r} (outputs: {', '.join(target.outputs)})")
    sw = Sweep(path=path, name=str(data.get("name", path.stem)), target=target, stop_time=stop_time,
               outputs=list(outputs), out=Path(data.get("out", f"out/{data.get('name', path.stem)}")),
               run_timeout=timeout)
    limits = target.limits
    for name in set(limits) & set(target.outputs):      # a table column each: the names must differ
        _fail(path, "scenario", f"{target.name} has a parameter and an output both named {name!r}")
    seen = {}

    def check_name(key, name):
        if name not in limits:
            _fail(path, key, f"unknown parameter {name!r} of {target.kind} {target.name} "
                  f"(parameters: {', '.join(sorted(limits))})")
        if name in seen:
            _fail(path, key, f"{name} is already set in [{seen[name]}]")
        seen[name] = key.split(".")[0]

    def check_value(key, name, v):
        lo, hi = limits[name]
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            _fail(path, key, f"{v:g} is outside the range of {name} [{lo}, {hi}]")

    for section in ("fixed", "grid", "random"):
        if section in data and not isinstance(data[section], dict):
            _fail(path, section, "expected a table")
    for name, value in data.get("fixed", {}).items():
        check_name(f"fixed.{name}", name)
        sw.fixed[name] = _finite(path, f"fixed.{name}", value)
        check_value(f"fixed.{name}", name, sw.fixed[name])
    for name, spec in data.get("grid", {}).items():
        check_name(f"grid.{name}", name)
        sw.grid[name] = _values(path, f"grid.{name}", spec)
        for v in sw.grid[name]:
            check_value(f"grid.{name}", name, v)
    rnd = dict(data.get("random", {}))
    if rnd:
        samples, seed = rnd.pop("samples", None), rnd.pop("seed", 0)
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            _fail(path, "random.samples", f"expected an integer >= 1, got {samples!r}")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            _fail(path, "random.seed", f"expected an integer >= 0, got {seed!r}")
        if not rnd:
            _fail(path, "random", "no parameter to draw")
        sw.samples, sw.seed = samples, seed
        for name, spec in rnd.items():
            key = f"random.{name}"
            check_name(key, name)
            if not (isinstance(spec, list) and len(spec) == 2):
                _fail(path, key, f"expected [lo, hi], got {spec!r}")
            lo, hi = _finite(path, f"{key}[0]", spec[0]), _finite(path, f"{key}[1]", spec[1])
            if not lo < hi:
                _fail(path, key, f"empty range: [{lo:g}, {hi:g}]")
            check_value(key, name, lo)
            check_value(key, name, hi)
            sw.random[name] = (lo, hi)
    if not sw.grid and not sw.random:
        _fail(path, "grid", "nothing to vary: give [grid] and/or [random]")
    if "map" in data:
        problem = check_map(data["map"], sw)
        if problem:
            key, reason = problem
            _fail(path, f"map.{key}" if key else "map", reason)
    sw.map = data.get("map")
    return sw


# answers converge in solver.tol; Moreau-Jean's (a fixed step) in solver.h_max, where solver.tol does nothing.
CHECKS = {"--check-tol": ("solver.tol", "tol"), "--check-h": ("solver.h_max", "h")}


def _steps_fixed(sw: Sweep) -> bool:
    """whether the sweep's scene steps by Moreau-Jean (its default solver method, or the sweep's fixed one)"""
    from cedra.contract import SOLVER_METHODS
    method = sw.fixed.get("solver.method")
    if method is not None:
        return SOLVER_METHODS[int(method)] == "moreau"
    return sw.target.scene.solver.get("method") == "moreau"


def tightened(sw: Sweep, value: float, flag: str = "--check-tol") -> Sweep:
    """The same sweep at the check's solver parameter = value (CHECKS): its own table <name>_<suffix><value>.csv in
    the same directory, no map."""
    key, suffix = CHECKS[flag]
    if sw.target.kind != "scene" or key not in sw.target.limits:
        raise SweepError(f"{sw.path}: {flag}: only for a scene's sweep (its runs' {key})")
    if key in sw.grid or key in sw.random:
        raise SweepError(f"{sw.path}: {flag}: {key} is what this sweep varies")
    fixed_step = _steps_fixed(sw)
    if fixed_step != (flag == "--check-h"):
        raise SweepError(f"{sw.path}: {flag}: this sweep's runs step " +
                         ("by Moreau-Jean (a fixed step, solver.tol does nothing there): use --check-h" if fixed_step
                          else "with an adaptive solver: use --check-tol"))
    lo, hi = sw.target.limits[key]
    if not (math.isfinite(value) and value > 0) or (lo is not None and value < lo) or \
            (hi is not None and value > hi):
        raise SweepError(f"{sw.path}: {flag}: {value:g} is outside the range of {key} [{lo}, {hi}]")
    return replace(sw, name=f"{sw.name}_{suffix}{value:g}", fixed={**sw.fixed, key: value}, map=None)


def resolve(name: str) -> Path:
    """A sweep file path, or the name of a shipped sweep in examples/sweeps/."""
    from cedra.run.scenario import EXAMPLES
    path = Path(name)
    if path.suffix == ".toml" or path.exists():
        return path
    shipped = EXAMPLES / "sweeps" / f"{name}.toml"
    if shipped.exists():
        return shipped
    known = ", ".join(p.stem for p in sorted((EXAMPLES / "sweeps").glob("*.toml")))
    raise SweepError(f"no sweep file {name!r} and no shipped sweep of that name (shipped: {known})")
