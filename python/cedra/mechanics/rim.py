"""The contact search of a wheel on an analytic terrain, in C (fmu_src/rim.c), for the symbolic model.

The FMU compiles fmu_src/rim.c with the scene's generated cedra_terrain (the contract). The symbolic model calls
the same search as a CasADi external function, cedra_rim_search, from a small host library: the scene's
cedra_terrain generated to C (here) and compiled with rim.c. One implementation of the search for the FMU, the
Python-side model and the tests. The search makes only discrete choices and converged angles, so the model never
differentiates it (cedra.mechanics.contact.rim_contacts).

This module compiles nothing. Compiling is the business of the layers that know the build (the compile helper
cedra.compile, its object cache and build directories); mechanics sits below them and names no build tree, so it
asks a builder for the library: `set_library_builder(build)`, which cedra.models sets when it is imported
(cedra.models.host: build(terrain C, on_heightmap, refine) -> the library's path). Asking for the library with no
builder set raises RimBuildError saying so. A builder handed in from above, rather than a compile call made
through a low-level helper, keeps this package free of compilers and subprocesses altogether
(tests/test_layers.py checks it)."""
from __future__ import annotations

import ctypes
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np

from cedra.contract import TERRAIN_TIN
from cedra.mechanics import heightmap
from cedra.mechanics.contact import rim_samples_function
from cedra.mechanics.terrain import Terrain

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


_builder: Callable[[str, bool, bool], Path] | None = None


def set_library_builder(build: Callable[[str, bool, bool], Path]) -> None:
    """Who builds the search's host library: build(terrain C, on_heightmap, refine) -> the shared library's path
    (cedra.models.host sets it at the import of cedra.models)."""
    global _builder
    _builder = build
    _library.cache_clear()


@lru_cache(maxsize=None)
def _library(code: str, on_heightmap: bool = False, refine: bool = False) -> Path:
    """rim.c and the terrain's generated code as a shared library (the builder's). on_heightmap: the terrain calls
    the heightmap's external functions, which this library takes from the heightmap's host library (the one
    process-wide map, cedra.mechanics.heightmap), and a rim proven to have one maximum returns its presence flags
    alone, as in a heightmap scene's FMU (CEDRA_HEIGHTMAP: the model takes that maximum from the heightmap's own
    search). refine: every arc near touching sampled again (CEDRA_RIM_REFINE)."""
    if _builder is None:
        raise RimBuildError("the contact search's host library has no builder: import cedra.models first (it sets "
                            "cedra.mechanics.rim.set_library_builder)")
    return _builder(code, on_heightmap, refine)


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
