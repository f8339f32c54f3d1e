"""What the scenario scripts in examples/ share: finding (or building) the FMUs, a progress bar for runs longer than
a couple of seconds, CSV output, and the registry behind `python -m cedra simulate <scenario>` / `--list`.

A scenario script is a short module in examples/ with a docstring (its first line is the --list entry) and
    run(out_dir="out/<name>", build_dir="build", stop_time=None, quiet=False) -> dict   (the summary)
Copy one, edit its numbers, run it: `python examples/<name>.py` or `python -m cedra simulate <name>`.
"""
from __future__ import annotations

import csv
import importlib.util
import sys
import time
from pathlib import Path

from .fmu import REPO_ROOT

EXAMPLES = REPO_ROOT / "examples"
MAIN_JOB = "bump2d"                      # `simulate bump2d` stays the main job (cedra.simulate)


class ScenarioError(ValueError):
    """Bad scenario input, raised before any simulation starts."""


def fmu(name: str, build_dir="build") -> Path:
    """build/<name>.fmu for a shipped scene or controller, built there first if it is missing."""
    path = Path(build_dir) / f"{name}.fmu"
    if path.exists():
        return path
    from .controller import CONTROLLERS, controller_spec
    from .fmu import build_fmu
    from .scene import load_shipped, shipped
    if name in CONTROLLERS:
        spec = controller_spec(CONTROLLERS[name])
    elif name in shipped():
        spec = load_shipped(name).spec()
    else:
        raise ScenarioError(f"no FMU {name!r}: not a shipped scene or controller")
    return build_fmu(spec, build_dir)


class Progress:
    """A progress bar on stderr for simulated time, shown once a run has taken more than `after` seconds of wall
    time: redrawn in place on a terminal, a plain line every quarter otherwise; nothing when quiet."""

    def __init__(self, total: float, label: str, quiet: bool = False, after: float = 2.0):
        self.total, self.label, self.quiet, self.after = total, label, quiet, after
        self.start = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.shown = False
        self.next_quarter = 0.25

    def __call__(self, t: float):
        if self.quiet:
            return
        wall = time.perf_counter() - self.start
        if wall < self.after:
            return
        frac = min(1.0, t / self.total) if self.total > 0 else 1.0
        if self.tty:
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\r{self.label} [{bar:<30}] {t:6.2f}/{self.total:g} s simulated, {wall:5.1f} s")
            self.shown = True
        elif frac >= self.next_quarter:
            sys.stderr.write(f"{self.label}: {t:.2f} of {self.total:g} s simulated ({wall:.1f} s)\n")
            self.next_quarter += 0.25

    def done(self):
        if self.shown:
            sys.stderr.write("\n")


def run_loop(loop, label: str, stop_time: float, step: float, commands, record, quiet: bool = False):
    """loop.run with a progress bar; the loop is closed afterwards; RuntimeError with the FMUs' last messages if the
    run stopped early. Returns the LoopResult."""
    progress = Progress(stop_time, label, quiet)
    try:
        r = loop.run(stop_time, step, commands, record, progress)
    finally:
        progress.done()
        loop.close()
    if not r.ok:
        raise RuntimeError(f"{label} stopped early: " + "; ".join(r.messages[-2:]))
    return r


def write_csv(path, names, rows) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for r in rows:
            w.writerow([f"{v:.10g}" for v in r])
    return path


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
