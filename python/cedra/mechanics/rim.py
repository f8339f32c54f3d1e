"""The contact search of a wheel on an analytic terrain, in C (fmu_src/rim.c), for the symbolic model.

The FMU compiles fmu_src/rim.c with the scene's generated cedra_terrain (the contract). The symbolic model calls
the same search as a CasADi external function, cedra_rim_search, from a small host library: the scene's
cedra_terrain generated to C and compiled with rim.c (cached under build/host/ by a hash of both sources). One
implementation of the search for the FMU, the Python-side model and the tests. The search makes only discrete
choices and converged angles, so the model never differentiates it (cedra.mechanics.contact.rim_contacts)."""
from __future__ import annotations

import ctypes
import hashlib
import os
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np

from cedra.contract import TERRAIN_TIN
from cedra.mechanics import heightmap
from cedra.mechanics.contact import rim_samples_function
from cedra.mechanics.terrain import Terrain

REPO_ROOT = Path(__file__).resolve().parents[3]
SOURCE = REPO_ROOT / "fmu_src" / "rim.c"
HOST_DIR = REPO_ROOT / "build" / "host"
EXTERNAL_NAME = "cedra_rim_search"
N_RESULT = 8            # [beta of maxima 1..3, beta of saddles 1..2, presence of maxima 1..3]
ONE_MAXIMUM = {1: 0, 2: 0, 3: 0, 4: 0, 5: 1, 6: 0, 7: 0}     # the results where the search finds one maximum


class RimBuildError(RuntimeError):
    pass


def _terrain_c(terrain: Terrain) -> str:
    with tempfile.TemporaryDirectory() as d:
        cg = ca.CodeGenerator("cedra_terrain_host.c", {"casadi_real": "double", "casadi_int": "long long int",
                                                       "with_header": False, "verbose": False})
        cg.add(terrain.function())
        cg.add(rim_samples_function(terrain))
        cg.add(terrain.bounds_function())
        cg.generate(d + "/")
        return (Path(d) / "cedra_terrain_host.c").read_text()


@lru_cache(maxsize=None)
def _library(code: str, on_heightmap: bool = False, refine: bool = False) -> Path:
    """rim.c and the terrain's generated code as a shared library. on_heightmap: the terrain calls the heightmap's
    external functions, which this library takes from the heightmap's host library (the one process-wide map,
    cedra.mechanics.heightmap), and a rim proven to have one maximum returns its presence flags alone, as in a
    heightmap scene's FMU (CEDRA_HEIGHTMAP: the model takes that maximum from the heightmap's own search).
    refine: every arc near touching sampled again (CEDRA_RIM_REFINE). No memo here (RIM_HOST)."""
    rim = SOURCE.read_bytes()
    extra = ["-DRIM_HOST", f"-DCEDRA_HEIGHTMAP={int(on_heightmap)}", f"-DCEDRA_RIM_REFINE={int(refine)}"]
    if on_heightmap:
        hm = heightmap.host_library()
        extra += [str(hm), f"-Wl,-rpath,{hm.parent}"]
    # the key names the heightmap's library by its file name (a hash of its source), not its directory: the same
    # model formed in two checkouts gets the same library name, and the GUID (which hashes it) stays the same
    named = [f"-DCEDRA_HEIGHTMAP={int(on_heightmap)}", f"-DCEDRA_RIM_REFINE={int(refine)}"]
    if on_heightmap:
        named.append(hm.name)
    key = rim + code.encode() + " ".join(named).encode()
    lib = HOST_DIR / f"libcedra_rim_{hashlib.sha256(key).hexdigest()[:16]}.so"
    if not lib.exists():
        HOST_DIR.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory() as d:
            src = Path(d) / "cedra_terrain_host.c"
            src.write_text(code)
            fd, tmp = tempfile.mkstemp(suffix=".so", dir=HOST_DIR)     # parallel test workers: build, then rename
            os.close(fd)
            # -Bsymbolic: rim.c calls this library's own cedra_terrain, whatever other library is loaded
            cmd = ["gcc", "-std=c99", "-O2", "-fPIC", "-shared", "-Wl,-Bsymbolic", "-Wall", "-Wextra", "-Werror",
                   "-Wno-unused-parameter", "-Wno-unused-variable", "-Wno-unused-function",
                   "-Wno-unused-but-set-variable", "-Wno-sign-compare", str(SOURCE), str(src), "-o", tmp, *extra, "-lm"]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                os.unlink(tmp)
                raise RimBuildError(f"compiling {SOURCE} failed:\n{r.stderr}")
            os.replace(tmp, lib)
    return lib


def _host(terrain: Terrain, refine: bool = False) -> Path:
    on_heightmap = terrain.kind.name == "heightmap"
    if on_heightmap:
        heightmap.external()        # the host library loaded first: this library's dependency is that object
    return _library(_terrain_c(terrain), on_heightmap, refine or on_heightmap)


def search_external(terrain: Terrain, refine: bool = False) -> ca.Function:
    """cedra_rim_search for this terrain: (x[15] = [center, axle, radius, terrain inputs padded]) -> (r[8]).
    refine: every arc near touching sampled again (always on a heightmap; the plant asks for it in 3D)."""
    return ca.external(EXTERNAL_NAME, str(_host(terrain, refine)))


def search_input(center, axle, radius, terrain: Terrain):
    return ca.vertcat(center, axle, radius, terrain.tin())


def one_maximum_test(terrain: Terrain):
    """The C search's test for a rim with one maximum (cedra_rim_one_maximum in fmu_src/rim.c), for the tests:
    (center, axle, radius, terrain input values) -> True where the terrain's bounds prove one maximum (the search
    then skips the samples)."""
    fn = ctypes.CDLL(str(_host(terrain))).cedra_rim_one_maximum
    fn.argtypes, fn.restype = [ctypes.POINTER(ctypes.c_double)], ctypes.c_int

    def proven(center, axle, radius, tin) -> bool:
        x = np.zeros(7 + TERRAIN_TIN)
        x[0:3], x[3:6], x[6], x[7:7 + len(tin)] = center, axle, radius, tin
        return bool(fn(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))))
    return proven
