"""What every page a command writes shares (a report's, a sweep map's): the line that says which command, code and
machine made its figures, the load average it is measured at, and its Markdown tables. Below every package that
writes such a page, so that a sweep and a report write them the same way.
"""
from __future__ import annotations

from pathlib import Path


def load_average() -> float:
    try:
        import os
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def provenance(command: str, wall: float, load_at_start: float) -> str:
    """One Markdown line: the command, when, which code and which machine made a report's figures."""
    import os
    import platform
    import subprocess
    from datetime import datetime, timezone
    from cedra import __version__
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        here = Path(__file__).resolve().parent          # python/cedra, inside the checkout
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=here,
                             timeout=10).stdout.strip()
        code = ["python", "fmu_src", "modelDescription", "examples", "tools"]     # what makes the figures (not docs)
        if rev and subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *code],
                                  capture_output=True, text=True, cwd=here.parents[1], timeout=10).stdout.strip():
            rev += " with local changes to the code"
    except (OSError, subprocess.SubprocessError):
        rev = ""
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (f"Made by `{command}` on {when} in {wall:.0f} s: cedra {__version__}" + (f" (git {rev})" if rev else "")
            + f", {cpu}, {os.cpu_count()} cores, load average {load_at_start:.1f} at the start.")


def md_table(header, rows) -> str:
    """A Markdown table: the header, then one line per row; a cell's text with its '|' as '/' (a cell holds no
    column break)."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c).replace("|", "/") for c in r) + " |" for r in rows]
    return "\n".join(out)
