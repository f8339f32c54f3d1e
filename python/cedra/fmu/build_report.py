"""The build's own report: <build>/build-report.md, written by every `python -m cedra build`.

For each FMU: whether it was up to date (its stamp matched) or built, the seconds to form the model and to generate,
compile and package it, how many of its C files were compiled and how many came from the object cache, the
compiles' CPU and the size of its generated C. Under ./build.sh (which exports CEDRA_BUILD_START, its own start
as a Unix time) the page also gives the wall time since ./build.sh started, the virtual environment and pip
install included. docs/reports/build.md is such a page; the docs quote build times from it.
"""
from __future__ import annotations

import os
import platform
import time
from datetime import datetime, timezone
from pathlib import Path

from cedra import __version__

PAGE = "build-report.md"
START_ENV = "CEDRA_BUILD_START"


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def text(rows: list[dict], wall_s: float, procs: int, threads: int, command: str, since_start: float | None) -> str:
    built = [r for r in rows if r["state"] == "built"]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        "# Build report", "",
        f"`{command}` on {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, cedra {__version__}, {_cpu()}, "
        f"{os.cpu_count()} cores, load {load:.2f} at the end; {procs} FMU(s) built at once, {threads} compile(s) "
        "each.", "",
        f"- wall time of the build command: {wall_s:.1f} s ({len(built)} of {len(rows)} FMUs built, "
        f"{len(rows) - len(built)} up to date)",
    ]
    if since_start is not None:
        lines.append(f"- wall time since `./build.sh` started (virtual environment and pip install included): "
                     f"{since_start:.1f} s")
    if built:
        lines.append(f"- C files compiled: {sum(r['compiled'] for r in built)}, taken from the object cache: "
                     f"{sum(r['cached'] for r in built)}; compile CPU {sum(r['compile_cpu_s'] for r in built):.1f} s")
    lines += ["", "| FMU | state | model (s) | C code and compile (s) | files compiled | from the cache | "
              "compile CPU (s) | generated C (kB) |", "|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: r["fmu"]):
        if r["state"] == "built":
            lines.append(f"| {r['fmu']} | built | {r['model_s']:.1f} | {r['code_s']:.1f} | {r['compiled']} | "
                         f"{r['cached']} | {r['compile_cpu_s']:.1f} | {r['generated_bytes'] / 1e3:.0f} |")
        else:
            lines.append(f"| {r['fmu']} | up to date | | | | | | |")
    return "\n".join(lines) + "\n"


def write(out_dir: Path, rows: list[dict], wall_s: float, procs: int, threads: int, command: str) -> Path:
    start = os.environ.get(START_ENV)
    since = time.time() - float(start) if start else None
    page = Path(out_dir) / PAGE
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(text(rows, wall_s, procs, threads, command, since))
    return page
