"""Instances in threads: N = 4 instances stepped in 4 threads at once give, bit for bit, the results of the same
runs one after another (the fuzzer executable's thread mode, tools/fuzz/fmu_fuzz.c --threads: C pthreads, the
FMU linked in; bump2d and flat3d built with AddressSanitizer as for the fuzz tests, hills3d plain -O1 as for the
valgrind test, to compile its large generated model once). Compared: every Real output at every communication
point (100 steps of 0.01 s) and the serialized end state. Each thread drives a different scenario (its own
torques), so results mixed between instances would show; the executable also checks the scenarios differ.

hills3d runs with two different grids: threads 0 and 2 read the shipped grid, threads 1 and 3 a second one (the
hills 1.3 times higher and the whole grid 5 cm up), each instance activating its own thread-local map."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from cedra.fmu import fuzz
from cedra.mechanics import heightmap

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
import hills  # noqa: E402

N, STEPS = 4, 100


def check(p):
    assert p.returncode == 0, p.stdout + p.stderr[-3000:]
    assert f"THREADS n={N} steps={STEPS}" in p.stdout and "identical" in p.stdout, p.stdout
    print(p.stdout.strip())


@pytest.mark.parametrize("scene", ["bump2d", "flat3d"])
def test_threads_equal_one_after_another(scene):
    check(fuzz.run_mode(fuzz.resolve_fmu(scene), ["--threads", N, "--steps", STEPS]))


def test_heightmap_threads_with_two_grids(tmp_path):
    fmu = fuzz.resolve_fmu("hills3d")
    X, Y, Z = hills.grid()
    res = tmp_path / "resources"
    res.mkdir()
    heightmap.write(res / "heightmap.txt", 1.3 * Z + 0.05, X[0], Y[0], hills.GRID["dx"], hills.GRID["dy"])
    shipped = fuzz.resources_uri(fmu)
    assert (Path(shipped[len("file://"):]) / "heightmap.txt").read_text() != (res / "heightmap.txt").read_text()
    check(fuzz.run_mode(fmu, ["--threads", N, "--steps", STEPS], variant="plain",
                        resources=[shipped, res.as_uri() + "/"]))
