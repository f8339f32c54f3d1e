"""One run of a sweep, on a Dask worker: the main job's run on a scene's FMU (its bytes sent once to each worker)
summarized as the sweep's OUTPUTS and a verdict, or a scenario script's run() with its SUMMARY numbers.
"""
from __future__ import annotations

import atexit
import collections
import contextlib
import hashlib
import math
import os
import tempfile
import time

import numpy as np

from cedra.sweep.definition import CONTROLLER
from cedra.sweep.verdicts import STUCK_DX, STUCK_TIME, TIPPED, verdict

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
