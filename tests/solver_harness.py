"""tests/c/solver_harness.c with the FMU's solver.c and linalg.c, compiled once per test module into a shared
library (test_solvers, test_solver_events): the embedded solvers driven on small problems from Python."""
from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "fmu_src"
HARNESS = ROOT / "tests" / "c" / "solver_harness.c"
CFLAGS = ["-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-pedantic"]


def compile_harness(out_dir: Path) -> ctypes.CDLL:
    """The harness library (skips the test module without gcc; a warning fails it)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("gcc not available")
    out = out_dir / "libsolver_harness.so"
    cmd = [gcc, *CFLAGS, "-shared", f"-I{SRC}", str(HARNESS), str(SRC / "solver.c"), str(SRC / "linalg.c"),
           "-lm", "-o", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0 and res.stderr.strip() == "", f"gcc failed or warned:\n{res.stderr}"
    return ctypes.CDLL(str(out))
