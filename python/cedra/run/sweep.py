"""Scenario sweeps on Dask: `python -m cedra sweep <sweep.toml> [--scheduler tcp://host:port] [--workers N]
[--resume | --overwrite] [--quiet] [--check-tol TOL]`.

A sweep file names what one run runs, the parameters to vary (a grid and/or seeded random samples), the summary
outputs to keep per run and where to write them:

    scene = "bump2d"                 # a shipped scene, or a scene file (relative to the sweep file); or instead
    # scenario = "turn_flat"         # a scenario script of examples/ that declares PARAMETERS, SUMMARY and FMUS
    #                                  (names, or (scene, {options}) for a variant: variant_fmu)
    stop_time = 15.0                 # s simulated per run (default: the scene's)
    outputs = ["climbed", "t_over", "peak_Fn", "final_x"]     # default: all of OUTPUTS
    out = "out/climb"                # the table: <out>/<name>.csv (relative to the working directory)
    run_timeout = 120.0              # s of wall time per run; a run past it is recorded as failed (default 300)
    [options]                        # scene runs only: the scene's boolean build options (SWEEP_OPTIONS of
    drives = true                    # cedra.models.scene); the sweep builds and runs that variant of the scene
    [fixed]                          # the same value in every run
    tau_max = 4.0
    [grid]                           # every combination: a list, or {from, to, num} (num points, both ends in)
    terrain_h = {from = 0.0, to = 0.195, num = 14}
    mu = [0.2, 0.6, 1.0]
    [random]                         # `samples` draws, uniform in [lo, hi], numpy's default_rng(seed)
    samples = 50
    seed = 1
    ground_k = [5e4, 2e5]

With both [grid] and [random], every grid point is combined with every draw. For a scene, the parameters are the
scene FMU's inputs and parameters (mu, terrain_h, terrain_w, ground_k, start.yaw, ...) and the main job's
controller settings (CONTROLLER: tau_max, v_ref); each run is the main job's run (docs/model.md: a PI speed loop,
equal torques clipped at tau_max) on that scene, summarized as OUTPUTS. For a scenario script, the parameters and
outputs are its own PARAMETERS and SUMMARY, and each run is its run(params=...). A bad sweep file fails before
any run (and before any build) naming the file, the key and the reason.

[options] makes a variant of the scene: its file parsed again with those keys set (the scene's own checks apply:
drives with locked_wheels fails, for instance), under its own model name (<scene>_drives; <scene>_nodrives for
drives = false on a scene that has them), built into <build>/variants/ and rebuilt only when its model or the FMU
sources changed. The options are part of every run's id, so the runs of two variants never mix in a table. A
scene file's FMU is kept the same way, in <build>/scenes/ (a heightmap scene's is built every time: its grid file
is not in the FMU's GUID).

Runs execute on Dask: a LocalCluster with one single-threaded worker process per core by default, or an existing
cluster with --scheduler (the same code; the workers need this package installed, e.g. `pip install -e .` in a
clone of the same commit; a scene's FMU is sent to them, no shared disk is needed; a scenario script reads its
FMUs from the build directory, which the workers then need at the same path). Results are appended to the CSV as
runs finish, so an interrupted sweep loses nothing, and --resume runs only the runs missing from the table (a run
is identified by a hash of its scene, its [options], stop time and parameter values). A run that fails (the FMU
refuses a step, the run times out, or its worker process dies) is recorded with its status and reason and the
sweep goes on.

A sweep with a [map] draws it (<out>/<name>.png, cedra.run.sweep_map) and writes its report next to it
(<out>/<name>.md, cedra.run.sweep_report). --check-tol TOL runs every run again at solver.tol = TOL (the table
<out>/<name>_tol<TOL>.csv) and the report says whether every verdict is the same.
"""
from __future__ import annotations

import atexit
import collections
import contextlib
import csv
import hashlib
import itertools
import json
import math
import os
import tempfile
import time
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from cedra.run.sweep_map import check_map, draw
from cedra.run.verdicts import STUCK_DX, STUCK_TIME, TIPPED, verdict

CONTROLLER = {"tau_max": 4.0, "v_ref": 0.2}        # the main job's controller (cedra.run.simulate)
# summary outputs of one run (see summarize); status and reason are always kept
OUTPUTS = {
    "verdict": "over | stuck | hung up | tipped | failed: how the run ended (cedra.run.verdicts.VERDICTS)",
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
    map: dict | None = None          # the [map] plot (cedra.run.sweep_map)

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


def _scene(path: Path, name: str):
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


def _options(path: Path, data) -> dict:
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
    scene = _scene(path, name)
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
    options = _options(path, data.get("options", {}))
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


# ------------------------------------------------------------------ one run (on a worker)

_FMU_FILES: dict[str, str] = {}          # per worker process: sha of the FMU's bytes -> a file holding them


def _remove_fmu_files():
    for name in _FMU_FILES.values():
        with contextlib.suppress(OSError):
            os.remove(name)


def _scratch_directory() -> str | None:
    """The Dask worker's own directory, which Dask removes when the worker closes and purges after a killed worker
    (a killed process runs no atexit handler); None outside a worker."""
    try:
        from distributed import get_worker
        return get_worker().local_directory
    except (ImportError, ValueError):
        return None


def _fmu_file(fmu_bytes: bytes) -> str:
    """The FMU's bytes (sent once to each worker) as a file this worker process reuses for all its runs, in the
    worker's directory (removed with the worker); outside a worker a temporary file removed at exit."""
    sha = hashlib.sha256(fmu_bytes).hexdigest()
    if sha not in _FMU_FILES or not os.path.exists(_FMU_FILES[sha]):
        if not _FMU_FILES:
            atexit.register(_remove_fmu_files)
        fd, name = tempfile.mkstemp(prefix=f"cedra-{sha[:12]}-", suffix=".fmu", dir=_scratch_directory())
        with os.fdopen(fd, "wb") as fh:
            fh.write(fmu_bytes)
        _FMU_FILES[sha] = name
    return _FMU_FILES[sha]


def obstacle_end(kind: str, p: dict, steps: int = 1) -> float:
    """X past which the terrain is flat again (the climb's goal line); steps: the stairs' number of steps."""
    if kind in ("bump", "bump3d"):
        return p["terrain_x0"] + 2.5 * p["terrain_w"]         # the Gaussian is below 0.2 % of its height there
    if kind == "step":
        return p["terrain_x0"] + 4.0 * p["terrain_s"]         # tanh within 0.03 % of the top
    if kind == "stairs":                                       # the top step's edge, the same way
        return p["terrain_x0"] + (steps - 1) * p["terrain_w"] + 4.0 * p["terrain_s"]
    return math.nan


def run_one(fmu_bytes: bytes, kind: str, params: dict, stop_time: float, timeout: float, steps: int = 1) -> dict:
    """The main job's run (PI speed loop, equal torques clipped at tau_max) with these parameter values; the
    summary (OUTPUTS) and status/reason. It stops early once the rover is past the obstacle or stuck."""
    from cedra.run.driver import RoverFMU
    from cedra.run.simulate import SAMPLE, SpeedController, speed_loop
    wall = time.perf_counter()
    fmu = RoverFMU(_fmu_file(fmu_bytes), instance_name="sweep")
    ctrl_keys = set(CONTROLLER)
    ctrl = SpeedController(v_ref=params.get("v_ref", CONTROLLER["v_ref"]),
                           tau_max=params.get("tau_max", CONTROLLER["tau_max"]))
    values = {k: v for k, v in params.items() if k not in ctrl_keys}
    # A verdict must not depend on how loaded the machine is: the FMU's per-step wall-clock budget (1 s by default)
    # gives way to the run's own timeout; the step-count budget (solver.max_steps) still bounds every step.
    values["solver.max_wall_time"] = timeout
    start = {n: float(fmu.vars[n].start) for n in ("terrain_x0", "terrain_w", "terrain_s") if fmu.has(n)}
    goal = obstacle_end(kind, {**start, **values}, steps)
    wheels = list(range(1, 7))
    # rigid contact: the forces' means over each communication step (impulse / step); a sample misses the impacts
    mean = "_mean" if fmu.has("wheel[1].Fn_mean") else ""
    fn = [f"wheel[{i}].Fn{mean}" for i in wheels]
    ft = [f"wheel[{i}].{c}{mean}" for i in wheels for c in ("Fx", "Fy")]
    attitude = [n for n in ("body.pitch", "body.roll") if fmu.has(n)]
    chassis = ["chassis.Fn"] if fmu.has("chassis.Fn") else []       # a model whose body and links touch the terrain
    names = (["body.x", "body.vx"] + attitude + fn + ft + [f"wheel[{i}].slip" for i in wheels] +
             [f"wheel[{i}].cx" for i in wheels] + chassis)
    s = dict(peak_Fn=0.0, peak_ratio=0.0, max_slip=0.0, t_over=math.nan, climbed=0, final_x=math.nan, t_end=0.0,
             status="ok", reason="")
    n = int(round(stop_time / SAMPLE))
    back = int(round(STUCK_TIME / SAMPLE))
    x_hist = []
    fn_hist = collections.deque(maxlen=back)         # chassis.Fn over the last STUCK_TIME
    tipped = []
    col = {name: k for k, name in enumerate(names)}
    i_fn, i_fx, i_fy = ([col[f"wheel[{i}].{q}{mean}"] for i in wheels] for q in ("Fn", "Fx", "Fy"))
    i_slip, i_cx = ([col[f"wheel[{i}].{q}"] for i in wheels] for q in ("slip", "cx"))

    def summarize(k, t, y, tau):
        """the summary so far; True where the run stops early"""
        Fn, Ft = y[i_fn], np.hypot(y[i_fx], y[i_fy])
        s["peak_Fn"] = max(s["peak_Fn"], float(Fn.max()))
        loaded = Fn > 5.0
        if loaded.any():
            s["peak_ratio"] = max(s["peak_ratio"], float((Ft[loaded] / Fn[loaded]).max()))
        s["max_slip"] = max(s["max_slip"], float(np.abs(y[i_slip]).max()))
        s["final_x"], s["t_end"] = float(y[col["body.x"]]), t
        if chassis:
            fn_hist.append(float(y[col["chassis.Fn"]]))
        if any(abs(y[col[a]]) > TIPPED for a in attitude):
            s["reason"] = f"tipped over: |body attitude| > {TIPPED} rad at t = {t:g}"
            tipped.append(t)
            return True
        if y[i_cx].min() > goal:
            s["climbed"], s["t_over"] = 1, t
            return True
        x_hist.append(y[col["body.x"]])
        if len(x_hist) > back and x_hist[-1] - x_hist[-1 - back] < STUCK_DX:
            s["reason"] = f"stuck: body.x advanced less than {STUCK_DX} m in {STUCK_TIME} s"
            return True
        if k < n and time.perf_counter() - wall > timeout:
            s["status"], s["reason"] = "timeout", f"run took more than {timeout:g} s of wall time at t = {t:g}"
            return True
        return False

    try:
        fmu.start(values)
        if not speed_loop(fmu, stop_time, names, summarize, ctrl):
            s["status"] = fmu.status
            s["reason"] = (fmu.messages[-1] if fmu.messages else "the FMU refused the step")[:300]
    except Exception as e:                        # an FMU call that raised (e.g. fmi2Error in a setter)
        s["status"], s["reason"] = "error", f"{type(e).__name__}: {e}"[:300]
    finally:
        fmu.close()
    if not all(math.isfinite(s[k]) for k in ("peak_Fn", "peak_ratio", "max_slip")):
        s["status"], s["reason"] = "error", "non-finite output"
    if s["status"] == "ok" and not s["climbed"] and not s["reason"]:
        s["reason"] = "not over the obstacle at the stop time"
    fn_mean = float(np.mean(fn_hist)) if chassis and fn_hist else None
    s["verdict"] = verdict(s["status"], bool(s["climbed"]), bool(tipped), fn_mean)
    if s["verdict"] == "hung up":
        s["reason"] += f"; hung up: chassis.Fn {fn_mean:.3g} N on mean over the last {STUCK_TIME:g} s"
    s["wall_s"] = time.perf_counter() - wall
    return s


def _flat(summary: dict, prefix: str = "") -> dict:
    """{"a": {"b": 1}} -> {"a.b": 1}: a scenario's nested summary (one per controller, say) as table columns."""
    out = {}
    for k, v in summary.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def run_scenario(name: str, build_dir: str, params: dict, stop_time: float, outputs: list) -> dict:
    """A scenario script's run() with these parameter values, in a scratch directory; its SUMMARY numbers."""
    from cedra.run.scenario import load as load_scenario
    wall = time.perf_counter()
    s = {o: math.nan for o in outputs} | dict(status="ok", reason="")
    try:
        with tempfile.TemporaryDirectory(prefix=f"cedra-sweep-{name}-") as tmp:
            summary = load_scenario(name).run(out_dir=tmp, build_dir=build_dir, stop_time=stop_time, quiet=True,
                                              params=params, watch=False)
        summary = _flat(summary)
        missing = [o for o in outputs if o not in summary]
        if missing:
            raise KeyError(f"run() returned no {', '.join(missing)}")
        s.update({o: float(summary[o]) for o in outputs})
    except Exception as e:                        # the run stopped early (RuntimeError with the FMUs' messages)
        s["status"], s["reason"] = "error", f"{type(e).__name__}: {e}"[:300]
    s["wall_s"] = time.perf_counter() - wall
    return s


# ------------------------------------------------------------------ the sweep (on the client)

def columns(sw: Sweep) -> list[str]:
    return ["id"] + sw.parameters + sw.outputs + ["status", "reason", "wall_s"]


def read_table(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if v != v else f"{v:.10g}"
    return str(v)


def execute(sw: Sweep, build_dir="build", scheduler: str | None = None, workers: int | None = None,
            resume: bool = False, overwrite: bool = False, quiet: bool = False, on_result=None) -> dict:
    """Run the sweep's missing runs on Dask and append each result to the table as it arrives. Returns counts.
    on_result(k, row), if given, is called in the client after each row is written (the tests use it to kill a
    worker mid-sweep or to interrupt)."""
    from distributed import Client, LocalCluster, as_completed
    from cedra.run.progress import Progress

    table = sw.table
    cols = columns(sw)
    done_rows = read_table(table)
    if done_rows and not (resume or overwrite):
        raise SweepError(f"{table} exists ({len(done_rows)} runs): pass --resume to run only the missing runs or "
                         f"--overwrite to start again")
    if done_rows and resume:
        header = list(done_rows[0].keys())
        if header != cols:
            raise SweepError(f"{table}: its columns are not this sweep's (was the sweep file changed?); "
                             f"use --overwrite")
    if overwrite:
        done_rows = []
    done = {r["id"] for r in done_rows}
    runs = [(sw.run_id(p), p) for p in sw.runs()]
    todo = [(i, p) for i, p in runs if i not in done]
    counts = dict(total=len(runs), skipped=len(runs) - len(todo), ran=0, failed=0)
    if not todo:
        return counts

    fmu_bytes = Path(_build(sw, build_dir)).read_bytes() if sw.target.kind == "scene" else None
    table.parent.mkdir(parents=True, exist_ok=True)
    fresh = not done_rows
    fh = open(table, "w" if fresh else "a", newline="")
    writer = csv.writer(fh)
    if fresh:
        writer.writerow(cols)
        fh.flush()
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=":0")   # the HTTP server on a free port: several may run
        client = Client(cluster)
    progress = Progress(len(todo), f"sweep {sw.name}", unit="runs", quiet=quiet, after=0.0)
    try:
        if sw.target.kind == "scene":
            data = client.scatter(fmu_bytes, broadcast=True, hash=False)
            kind, steps = sw.target.scene.options.terrain, sw.target.scene.options.stairs_steps
            futures = {client.submit(run_one, data, kind, p, sw.stop_time, sw.run_timeout, steps, key=f"run-{i}",
                                     pure=False): (i, p) for i, p in todo}
        else:
            from cedra.run.scenario import fmu
            for entry in sw.target.fmus:         # built here, once, not by several workers at a time
                if isinstance(entry, tuple):
                    variant_fmu(*entry, build_dir)
                else:
                    fmu(entry, build_dir)
            build = str(Path(build_dir).resolve())
            futures = {client.submit(run_scenario, sw.target.name, build, p, sw.stop_time, sw.outputs,
                                     key=f"run-{i}", pure=False): (i, p) for i, p in todo}
        for fut in as_completed(futures):
            i, p = futures[fut]
            try:
                r = fut.result()
            except Exception as e:       # the worker died running it (KilledWorker) or the task could not run
                r = {o: math.nan for o in sw.outputs}
                r.update(verdict="failed", status="failed", reason=f"{type(e).__name__}: {e}"[:300], wall_s=math.nan)
            row = {"id": i, **p, **r}
            writer.writerow([_fmt(row.get(c, "")) for c in cols])
            fh.flush()
            counts["ran"] += 1
            counts["failed"] += row["status"] != "ok"
            progress(counts["ran"], f"{counts['failed']} failed")
            if on_result:
                on_result(counts["ran"], row)
    finally:
        progress.done()
        fh.close()
        client.close()
        if cluster is not None:
            cluster.close()
    return counts


def _build(sw: Sweep, build_dir) -> Path:
    from cedra.models.scene import shipped
    from cedra.run.scenario import fmu
    if sw.target.variant:
        return _variant_fmu(sw.target.scene, Path(build_dir) / "variants")
    if sw.target.name in shipped():
        return fmu(sw.target.name, build_dir)
    return _variant_fmu(sw.target.scene, Path(build_dir) / "scenes")


def variant_fmu(name: str, options: dict, build_dir="build") -> Path:
    """The FMU of scene `name` (shipped, or a scene file's path) with these [options] (a scenario's plant):
    <build_dir>/variants/<variant>.fmu, built unless up to date; where the options change nothing, the shipped
    scene's own FMU, or a scene file's in <build_dir>/scenes/."""
    from cedra.run.scenario import ScenarioError, fmu
    where = Path(f"<scene {name}>")
    try:
        scene = _scene(where, name)
        var = variant(where, scene, _options(where, options))
    except SweepError as e:
        raise ScenarioError(str(e)) from e
    if var is not scene:
        return _variant_fmu(var, Path(build_dir) / "variants")
    from cedra.models.scene import shipped
    return fmu(name, build_dir) if name in shipped() else _variant_fmu(scene, Path(build_dir) / "scenes")


def _variant_fmu(scene, build_dir: Path) -> Path:
    """<build_dir>/<variant>.fmu, built unless its build stamp says it is this scene's (its content, its heightmap's
    grid) from today's sources and flags (cedra.fmu.packaging.ensure_fmu)."""
    from cedra.fmu.packaging import ensure_fmu
    return ensure_fmu(scene, build_dir)


# the convergence checks: flag -> (the solver parameter it sets, the table's suffix). The adaptive solvers'
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


# ------------------------------------------------------------------ command line

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


def add_parser(sub):
    p = sub.add_parser("sweep", help="run a sweep file on Dask (local cluster by default)")
    p.add_argument("file", help="a sweep .toml, or a shipped sweep in examples/sweeps/ (climb, climb_rigid)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786 "
                   "(default: a local cluster)")
    p.add_argument("--workers", type=int, help="local cluster: worker processes (default: one per core)")
    p.add_argument("--build", default="build")
    p.add_argument("--resume", action="store_true", help="run only the runs missing from the table")
    p.add_argument("--overwrite", action="store_true", help="start the table again")
    p.add_argument("--quiet", action="store_true", help="no progress")
    check = p.add_mutually_exclusive_group()
    check.add_argument("--check-tol", type=float, metavar="TOL",
                       help="run every run again at solver.tol = TOL; the map's report says whether every verdict is "
                       "the same (e.g. 1e-9)")
    check.add_argument("--check-h", type=float, metavar="H",
                       help="for scenes stepped by Moreau-Jean (rigid contact): run every run again at solver.h_max = "
                       "H; the map's report says whether every verdict is the same (e.g. a quarter of the scene's)")


def command(args) -> str:
    """The command line of these arguments, for the report."""
    words = ["python -m cedra sweep", args.file]
    for flag in ("scheduler", "workers", "check_tol", "check_h"):
        if getattr(args, flag, None) is not None:
            words.append(f"--{flag.replace('_', '-')} {getattr(args, flag)}")
    if args.build != "build":
        words.append(f"--build {args.build}")
    words += [f"--{flag}" for flag in ("resume", "overwrite", "quiet") if getattr(args, flag)]
    return " ".join(words)


def main(args) -> int:
    import sys
    from cedra.reports.common import load_average
    from cedra.run import sweep_report
    load_at_start = load_average()
    check_h = getattr(args, "check_h", None)         # argparse makes --check-tol and --check-h exclusive
    flag, check = ("--check-h", check_h) if check_h is not None else ("--check-tol", getattr(args, "check_tol", None))
    try:
        sw = load(resolve(args.file))
        if args.workers is not None and args.workers < 1:
            raise SweepError(f"--workers: expected >= 1, got {args.workers}")
        tight = tightened(sw, check, flag) if check is not None else None
        if tight is not None and not sw.map:
            raise SweepError(f"{sw.path}: {flag}: the sweep has no [map], whose report it goes into")
        t0 = t_all = time.perf_counter()
        sweeps = [sw] + ([tight] if tight else [])
        for s in sweeps:
            c = execute(s, args.build, args.scheduler, args.workers, args.resume, args.overwrite, args.quiet)
            wall = time.perf_counter() - t0
            rate = f", {60 * c['ran'] / wall:.1f} runs/min" if c["ran"] else ""
            print(f"sweep {s.name}: {c['total']} runs, {c['skipped']} already in the table, {c['ran']} run "
                  f"({c['failed']} failed) in {wall:.1f} s{rate}; table {s.table}")
            t0 = time.perf_counter()
    except SweepError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if sw.map:
        rows = read_table(sw.table)
        print(f"map {draw(sw, rows)}")
        checked = (CHECKS[flag][0], check, tight, read_table(tight.table)) if tight else None
        elapsed = time.perf_counter() - t_all
        print(f"report {sweep_report.write(sw, rows, command(args), elapsed, load_at_start, checked)}")
    return 0
