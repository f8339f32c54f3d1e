"""What the default settings guarantee: every shipped scene run the way a user runs it - the
scene's FMU with its default solver settings, driven by the main job's closed loop (docs/model.md: PI speed
loop, equal torques) - against the same run at rodas4 tol 1e-9 (the tight run). Reported per scene: the peak
normal force of each run, their relative difference, and the largest difference of any wheel's normal force at
any communication point relative to the tight run's peak. The normal force is wheel[i].Fn, for rigid contact
wheel[i].Fn_mean: an impact is an impulse, which the force at a sample misses and the mean over the
communication step (impulse / step) carries.

    python -m cedra report defaults [--scene NAME ...] [--tol TOL] [--method NAME] [--h-max H] [--build build]
                                    [--out out/report] [--quiet]

(--tol, --method: the "default" run with this tolerance (rodas4 unless --method) or this method (the scene's
tolerance unless --tol) instead of the scene's defaults: what another setting would give, e.g. --method ros34pw2
--tol 1e-4, the W-method's fast setting; --h-max: the largest step, the fixed step of rk4 and moreau.)

writes <out>/defaults.md and prints the table. Criterion: peak normal forces within 1e-3 relative.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cedra.models.scene import load_shipped, shipped
from cedra.reports.common import SOLVER_CODES, announce, fmt, fmu_path, load_average, md_table, provenance
from cedra.run.progress import Progress

TIGHT = {"solver.method": SOLVER_CODES["rodas4"], "solver.tol": 1e-9, "solver.max_wall_time": 1e3}
# rigid contact: Moreau-Jean at a tenth of the default step (its error is first order in h). rodas4 tol 1e-9 is no
# reference there: the held-mode integration's runs at tol 1e-7..1e-11 spread by 3e-3 among themselves.
TIGHT_RIGID = {"solver.method": SOLVER_CODES["moreau"], "solver.h_max": 1e-5, "solver.max_wall_time": 1e3}


def tight_settings(scene) -> tuple[str, dict]:
    """the tight run of a scene: its label and FMU settings"""
    if scene.options.contact == "rigid":
        return "moreau h_max 1e-5", dict(TIGHT_RIGID)
    return "rodas4 tol 1e-9", dict(TIGHT)
CRITERION = 1e-3
MAX_T_END = 15.0          # s: the scenes' own stop time, at most this


@dataclass
class Row:
    scene: str
    t_end: float
    setting: str
    tight: str
    peak: float
    peak_tight: float
    peak_rel: float           # |peak - peak_tight| / peak_tight
    dev_rel: float            # max over t, wheels |Fn - Fn_tight| / peak_tight
    force: str                # the output compared: "Fn", or "Fn_mean" (rigid contact)
    cpu: float
    cpu_tight: float
    ok: bool
    message: str = ""


def _fn(names, rows) -> tuple[str, np.ndarray]:
    force = "Fn_mean" if any(n.endswith(".Fn_mean") for n in names) else "Fn"
    return force, rows[:, [k for k, n in enumerate(names) if n.endswith(f".{force}")]]


def compare(name: str, build="build", tol: float | None = None, method: str | None = None,
            h_max: float | None = None) -> Row:
    from cedra.run.simulate import run_bump
    scene = load_shipped(name)
    t_end = min(scene.stop_time, MAX_T_END)
    path = fmu_path(build, name)
    s = scene.solver
    if tol is None and method is None:
        m, t, instead = s.get("method", "dopri5"), s.get("tol", 1e-6), {}
    else:
        m, t = method or "rodas4", s.get("tol", 1e-6) if tol is None else tol
        instead = {"solver.method": SOLVER_CODES[m], "solver.tol": t}
    if h_max is not None:
        instead["solver.h_max"] = h_max
    if m in ("moreau", "rk4"):        # fixed steps: their tolerance is not used, their step is
        setting = f"{m} h_max {s.get('h_max', 0.01) if h_max is None else h_max:g}"
    else:
        setting = f"{m} tol {t:g}" + (f" h_max {h_max:g}" if h_max is not None else "")
    c0 = time.process_time()
    names, rows, _, info = run_bump(path, t_end, instead)
    c1 = time.process_time()
    tight, tight_values = tight_settings(scene)
    names_t, rows_t, _, info_t = run_bump(path, t_end, tight_values)
    c2 = time.process_time()
    message = ""
    if not (info["ok"] and info_t["ok"]):
        # both runs stopped at the same communication point (e.g. the rover drove off a heightmap's edge, which the
        # main job's loop does not steer away from): the same run, compared over the time both have
        if not info["ok"] and not info_t["ok"] and abs(info["simulated"] - info_t["simulated"]) < 1e-9:
            t_end = info["simulated"]
            message = "both runs stop there: " + " ".join(info["messages"][-1:])
            rows, rows_t = rows[:len(rows_t)], rows_t[:len(rows)]
        else:
            bad = info if not info["ok"] else info_t
            return Row(name, t_end, setting, tight, np.nan, np.nan, np.inf, np.inf, "", c1 - c0, c2 - c1, False,
                       ("default" if bad is info else "tight") + ": " + " ".join(bad["messages"][-1:]))
    (force, fn), (_, fn_t) = _fn(names, rows), _fn(names_t, rows_t)
    peak, peak_t = float(fn.max()), float(fn_t.max())
    return Row(name, t_end, setting, tight, peak, peak_t, abs(peak - peak_t) / peak_t,
               float(np.abs(fn - fn_t).max()) / peak_t, force, c1 - c0, c2 - c1, True, message)


def write(rows: list[Row], out: Path, cmd: str, made_by: str = "") -> Path:
    out.mkdir(parents=True, exist_ok=True)
    table = [[r.scene, f"{r.t_end:g} s" + (" (both stop)" if r.ok and r.message else ""), r.setting, r.tight,
              r.force, fmt(r.peak, 5), fmt(r.peak_tight, 5), fmt(r.peak_rel), fmt(r.dev_rel),
              f"{r.cpu:.2f} / {r.cpu_tight:.2f}",
              ("yes" if r.peak_rel <= CRITERION else "NO") if r.ok else f"failed: {r.message[:80]}"] for r in rows]
    md = ["# Default settings against a tight run", ""] + ([made_by, ""] if made_by else []) + [
          f"Command: `{cmd}`. Each scene's FMU, the main job's closed loop, default solver settings vs the tight "
          f"run (rodas4 tol 1e-9; rigid contact: moreau h_max 1e-5); normal forces at every communication point "
          f"(0.01 s). A run marked \"both stop\" ended early at the same point in both settings (the reason is "
          f"below the table) and is compared over that time.", "",
          md_table(["scene", "run", "default", "tight", "force", "peak [N]", "tight peak [N]", "peak rel. diff",
                    "max abs dF / peak", "CPU s default / tight", f"peak within {CRITERION:g}"], table), ""] + [
          f"- {r.scene}: {r.message}" for r in rows if r.ok and r.message] + [""]
    path = out / "defaults.md"
    path.write_text("\n".join(md))
    return path


def main(args) -> int:
    names = getattr(args, "scene", None) or shipped()
    build = getattr(args, "build", "build")
    quiet = getattr(args, "quiet", False)
    rows = []
    load0, t0 = load_average(), time.perf_counter()
    announce("report defaults", f"about {5 * len(names)} s on two cores ({len(names)} scenes, each run twice)", quiet)
    progress = Progress(len(names), "report defaults", unit="scenes", quiet=quiet)
    for k, name in enumerate(names):
        r = compare(name, build, getattr(args, "tol", None), getattr(args, "method", None),
                    getattr(args, "h_max", None))
        rows.append(r)
        if not quiet:
            print(f"{name:14s} {r.setting:18s} peak {r.force:7s} {r.peak:9.3f} N (tight {r.peak_tight:9.3f} N): "
                  f"rel. diff {r.peak_rel:.2e}, max |dF|/peak {r.dev_rel:.2e}, CPU {r.cpu:.2f} / {r.cpu_tight:.2f} s"
                  + (f"  [{r.message}]" if r.message else ""), flush=True)
        progress(k + 1)
    progress.done()
    cmd = "python -m cedra report defaults" + "".join(f" --scene {n}" for n in getattr(args, "scene", None) or []) \
        + (f" --tol {args.tol:g}" if getattr(args, "tol", None) else "") \
        + (f" --method {args.method}" if getattr(args, "method", None) else "") \
        + (f" --h-max {args.h_max:g}" if getattr(args, "h_max", None) else "")
    made_by = provenance(cmd, time.perf_counter() - t0, load0)
    print(f"wrote {write(rows, Path(getattr(args, 'out', 'out/report')), cmd, made_by)}")
    return 0 if all(r.ok and r.peak_rel <= CRITERION for r in rows) else 1
