"""What the scenario scripts in examples/ share: finding (or building) the FMUs, a progress bar for runs longer than
a couple of seconds, CSV output, and the registry behind `python -m cedra simulate <scenario>` / `--list`.

A scenario script is a short module in examples/ with a docstring (its first line is the --list entry) and
    run(out_dir="out/<name>", build_dir="build", stop_time=None, quiet=False, watch=True) -> dict   (the summary)
(watch: also the run's view.html, and animation.gif for 2D runs: `watch_run` below; `--no-video` turns it off; a
script that a sweep runs with `params=` leaves it off for those runs, as turn_flat does.)
Copy one, edit its numbers, run it: `python examples/<name>.py` or `python -m cedra simulate <name>`.
"""
from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

from cedra.fmu.packaging import REPO_ROOT
from cedra.run.progress import Progress

EXAMPLES = REPO_ROOT / "examples"
MAIN_JOB = "bump2d"                      # `simulate bump2d` stays the main job (cedra.run.simulate)


class ScenarioError(ValueError):
    """Bad scenario input, raised before any simulation starts."""


def fmu(name: str, build_dir="build") -> Path:
    """build/<name>.fmu for a shipped scene or controller, built there first if it is missing or stale (its build
    stamp does not match today's sources: cedra.fmu.packaging.ensure_fmu, which says so on stderr); a scene's
    variant: cedra.sweep.variant_fmu."""
    from cedra.models.controller import CONTROLLERS
    from cedra.fmu.packaging import ensure_fmu
    from cedra.models.scene import shipped
    if name not in CONTROLLERS and name not in shipped():
        raise ScenarioError(f"no FMU {name!r}: not a shipped scene or controller")
    return ensure_fmu(name, build_dir)


def run_loop(loop, label: str, stop_time: float, step: float, commands, record, quiet: bool = False):
    """loop.run with a progress bar; the loop is closed afterwards; RuntimeError with the FMUs' last messages if the
    run stopped early. Returns the LoopResult."""
    progress = Progress(stop_time, label, quiet=quiet)
    try:
        r = loop.run(stop_time, step, commands, record, progress)
    finally:
        progress.done()
        loop.close()
    if not r.ok:
        raise RuntimeError(f"{label} stopped early: " + "; ".join(r.messages[-2:]))
    return r


def parameters(declared: dict, given: dict | None) -> dict:
    """A scenario's parameter values: its PARAMETERS' defaults (name -> (default, min, max, meaning)) updated by
    `given` (a sweep's run); ScenarioError for an unknown name or a value out of range."""
    values = {k: d[0] for k, d in declared.items()}
    for k, v in (given or {}).items():
        if k not in declared:
            raise ScenarioError(f"unknown parameter {k!r} (parameters: {', '.join(declared)})")
        lo, hi = declared[k][1], declared[k][2]
        if not lo <= v <= hi:
            raise ScenarioError(f"{k} = {v:g} is outside [{lo:g}, {hi:g}]")
        values[k] = float(v)
    return values


def write_csv(path, names, rows) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for r in rows:
            w.writerow([f"{v:.10g}" for v in r])
    return path


def watch_run(out_dir, names, rows, fmu_path, title: str, enabled: bool = True, stem: str = "") -> dict:
    """A run's animation (2D runs) and view.html (cedra.run.watch; the run must have recorded
    cedra.run.watch.WATCHED), unless disabled; returns what watch() returns ({} when disabled)."""
    if not enabled:
        return {}
    from cedra.run.watch import watch
    return watch(out_dir, names, rows, fmu_path, title=title, stem=stem)


def scenarios() -> dict[str, str]:
    """name -> first docstring line of every scenario script in examples/."""
    out = {}
    for path in sorted(EXAMPLES.glob("*.py")):
        mod = _load(path)
        if callable(getattr(mod, "run", None)):
            out[path.stem] = (mod.__doc__ or "").strip().splitlines()[0] if mod.__doc__ else ""
    return out


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(f"cedra_example_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def load(name: str):
    """The scenario script's module; ScenarioError naming the known ones if there is none."""
    path = EXAMPLES / f"{name}.py"
    if not path.exists() or not callable(getattr(_load(path), "run", None)):
        known = ", ".join(scenarios())
        raise ScenarioError(f"unknown scenario {name!r} (known: {known}; `python -m cedra simulate --list`)")
    return _load(path)
