"""What the default settings guarantee (issue 13 item 6): every shipped scene run the way a user runs it - the
scene's FMU with its default solver settings, driven by the main job's closed loop (spec section 10: PI speed
loop, equal torques) - against the same run at rodas4 tol 1e-9 (the tight run). Reported per scene: the peak
normal force of each run, their relative difference, and the largest difference of any wheel's normal force at
any communication point relative to the tight run's peak. The normal force is wheel[i].Fn, for rigid contact
wheel[i].Fn_mean: an impact is an impulse, which the force at a sample misses and the mean over the
communication step (impulse / step) carries.

    python -m cedra report defaults [--scene NAME ...] [--tol TOL] [--method NAME] [--build build] [--out out/report]
                                    [--quiet]

(--tol, --method: the "default" run with this tolerance (rodas4 unless --method) or this method (the scene's
tolerance unless --tol) instead of the scene's defaults: what another setting would give, e.g. --method ros34pw2
--tol 1e-4, the W-method's fast setting.)

writes <out>/defaults.md and prints the table. Criterion (issue 13): peak normal forces within 1e-3 relative.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cedra.models.scene import load_shipped, shipped
from cedra.reports.common import SOLVER_CODES, fmt, fmu_path, md_table
from cedra.run.progress import Progress

TIGHT = {"solver.method": SOLVER_CODES["rodas4"], "solver.tol": 1e-9, "solver.max_wall_time": 1e3}
CRITERION = 1e-3
MAX_T_END = 15.0          # s: the scenes' own stop time, at most this


@dataclass
class Row:
    scene: str
    t_end: float
    setting: str
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


def compare(name: str, build="build", tol: float | None = None, method: str | None = None) -> Row:
    from cedra.run.simulate import run_bump
    scene = load_shipped(name)
    t_end = min(scene.stop_time, MAX_T_END)
    path = fmu_path(build, name)
    s = scene.solver
    if tol is None and method is None:
        setting, instead = f"{s.get('method', 'dopri5')} tol {s.get('tol', 1e-6):g}", {}
    else:
        m, t = method or "rodas4", s.get("tol", 1e-6) if tol is None else tol
        setting, instead = f"{m} tol {t:g}", {"solver.method": SOLVER_CODES[m], "solver.tol": t}
    c0 = time.process_time()
    names, rows, _, info = run_bump(path, t_end, instead)
    c1 = time.process_time()
    names_t, rows_t, _, info_t = run_bump(path, t_end, dict(TIGHT))
    c2 = time.process_time()
    if not (info["ok"] and info_t["ok"]):
        bad = info if not info["ok"] else info_t
        return Row(name, t_end, setting, np.nan, np.nan, np.inf, np.inf, "", c1 - c0, c2 - c1, False,
                   ("default" if bad is info else "tight") + ": " + " ".join(bad["messages"][-1:]))
    (force, fn), (_, fn_t) = _fn(names, rows), _fn(names_t, rows_t)
    peak, peak_t = float(fn.max()), float(fn_t.max())
    return Row(name, t_end, setting, peak, peak_t, abs(peak - peak_t) / peak_t, float(np.abs(fn - fn_t).max()) / peak_t,
               force, c1 - c0, c2 - c1, True)


def write(rows: list[Row], out: Path, cmd: str) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    table = [[r.scene, f"{r.t_end:g} s", r.setting, r.force, fmt(r.peak, 5), fmt(r.peak_tight, 5), fmt(r.peak_rel),
              fmt(r.dev_rel), f"{r.cpu:.2f} / {r.cpu_tight:.2f}",
              ("yes" if r.peak_rel <= CRITERION else "NO") if r.ok else f"failed: {r.message[:80]}"] for r in rows]
    md = ["# Default settings against a tight run", "",
          f"Command: `{cmd}`. Each scene's FMU, the main job's closed loop, default solver settings vs rodas4 tol "
          f"1e-9; normal forces at every communication point (0.01 s).", "",
          md_table(["scene", "run", "default", "force", "peak [N]", "tight peak [N]", "peak rel. diff",
                    "max abs dF / peak", "CPU s default / tight", f"peak within {CRITERION:g}"], table), ""]
    path = out / "defaults.md"
    path.write_text("\n".join(md))
    return path


def main(args) -> int:
    names = getattr(args, "scene", None) or shipped()
    build = getattr(args, "build", "build")
    quiet = getattr(args, "quiet", False)
    rows = []
    progress = Progress(len(names), "report defaults", unit="scenes", quiet=quiet)
    for k, name in enumerate(names):
        r = compare(name, build, getattr(args, "tol", None), getattr(args, "method", None))
        rows.append(r)
        if not quiet:
            print(f"{name:14s} {r.setting:18s} peak {r.force:7s} {r.peak:9.3f} N (tight {r.peak_tight:9.3f} N): "
                  f"rel. diff {r.peak_rel:.2e}, max |dF|/peak {r.dev_rel:.2e}, CPU {r.cpu:.2f} / {r.cpu_tight:.2f} s"
                  + ("" if r.ok else f"  [{r.message}]"), flush=True)
        progress(k + 1)
    progress.done()
    cmd = "python -m cedra report defaults" + "".join(f" --scene {n}" for n in getattr(args, "scene", None) or []) \
        + (f" --tol {args.tol:g}" if getattr(args, "tol", None) else "") \
        + (f" --method {args.method}" if getattr(args, "method", None) else "")
    print(f"wrote {write(rows, Path(getattr(args, 'out', 'out/report')), cmd)}")
    return 0 if all(r.ok and r.peak_rel <= CRITERION for r in rows) else 1
