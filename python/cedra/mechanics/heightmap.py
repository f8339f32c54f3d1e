"""The heightmap terrain on the Python side: writing heightmap files, and the terrain's CasADi external functions.

One implementation only: the file reader, the natural bicubic spline and its derivatives are C
(fmu_src/heightmap.c, format in heightmap.h). The FMU compiles that file and reads resources/heightmap.txt at
fmi2Instantiate; here the same file is compiled into a small host library so that the symbolic model can call the
terrain (CasADi external functions: a wheel's contact point with its derivatives, cedra_rim_contact, and single
points with Jacobians to third order, cedra_heightmap), tests can evaluate it, and a scene's heightmap is
validated before any code is generated.

This module compiles nothing (as cedra.mechanics.rim, whose docstring says why): cedra.models hands it the host
library's builder when it is imported (set_library_builder; cedra.models.host), and asking for the library with
no builder set raises HeightmapError saying so.

The host library holds ONE process-wide map (the last one loaded), active in the thread that loaded it: the
Python-side model functions of a heightmap scene evaluate whichever map was loaded last.

Caveat (CasADi 3.8, Python side only): outside the grid the external fails, which `external()(x)` called
directly reports as an exception, but an SX function that embeds it (the model's functions) ignores the failure
and yields 0 there. The generated C code does check it: the FMU stops with fmi2Discard naming the point.
"""
from __future__ import annotations

import ctypes
from functools import lru_cache
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np

EXTERNAL_NAME = "cedra_heightmap"
RIM_EXTERNAL_NAME = "cedra_rim_contact"
RIM_POINT_EXTERNAL_NAME = "cedra_rim_point"        # the same without the Jacobian
BOUNDS_EXTERNAL_NAME = "cedra_heightmap_bounds"
RESOURCE_NAME = "heightmap.txt"      # the file's name inside the FMU's resources/


class HeightmapError(ValueError):
    pass


def write(path, Z, x0: float, y0: float, dx: float, dy: float, comment: str = "") -> Path:
    """Write heights Z[j, i] (row j: Y = y0 + j dy; column i: X = x0 + i dx) in the heightmap format."""
    Z = np.asarray(Z, dtype=float)
    if Z.ndim != 2 or min(Z.shape) < 2 or not np.all(np.isfinite(Z)) or dx <= 0 or dy <= 0:
        raise HeightmapError(f"{path}: need a finite 2-D grid of at least 2 x 2 heights and spacings > 0")
    ny, nx = Z.shape
    lines = [f"# {ln}" for ln in comment.splitlines()] + [
        "cedra-heightmap 1", " ".join([str(nx), str(ny)] + [repr(float(v)) for v in (x0, y0, dx, dy)])]
    lines += [" ".join(repr(float(v)) for v in row) for row in Z]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


_builder: Callable[[], Path] | None = None


def set_library_builder(build: Callable[[], Path]) -> None:
    """Who builds the host library: build() -> the path of fmu_src/heightmap.c compiled as a shared library with
    CEDRA_HEIGHTMAP_HOST (cedra.models.host sets it at the import of cedra.models)."""
    global _builder
    _builder = build
    host_library.cache_clear()


@lru_cache(maxsize=None)
def host_library() -> Path:
    """fmu_src/heightmap.c compiled for this process (the builder's library, one per source)."""
    if _builder is None:
        raise HeightmapError("the heightmap's host library has no builder: import cedra.models first (it sets "
                             "cedra.mechanics.heightmap.set_library_builder)")
    return _builder()


@lru_cache(maxsize=None)
def _ctypes_lib() -> ctypes.CDLL:
    lib = ctypes.CDLL(str(host_library()))
    lib.cedra_heightmap_host_load.argtypes = [ctypes.c_char_p]
    lib.cedra_heightmap_host_load.restype = ctypes.c_int
    lib.cedra_heightmap_host_message.restype = ctypes.c_char_p
    lib.cedra_heightmap_host_memo.argtypes = [ctypes.c_int]
    lib.cedra_heightmap_host_memo.restype = ctypes.c_int
    lib.cedra_heightmap_host_memo_counts.argtypes = [ctypes.POINTER(ctypes.c_long)]
    lib.cedra_heightmap_host_memo_counts.restype = None
    return lib


def load(path) -> None:
    """Read and fit the heightmap file (the C reader the FMU uses) and make it the active map of this thread;
    HeightmapError names the file, the line and the reason."""
    lib = _ctypes_lib()
    if lib.cedra_heightmap_host_load(str(Path(path)).encode()):
        raise HeightmapError(lib.cedra_heightmap_host_message().decode())


def use_memo(on: bool) -> None:
    """Give the loaded map the FMU's memo of recent rim searches (heightmap.c: rim_memoized) or take it away
    (loading a map also takes it away). For tests, which check that it changes no result; one thread only."""
    if _ctypes_lib().cedra_heightmap_host_memo(int(on)):
        raise MemoryError("no memory for the rim search memo")


def memo_counts() -> tuple[int, int]:
    """(hits, misses) of the memo since use_memo(True)."""
    counts = (ctypes.c_long * 2)()
    _ctypes_lib().cedra_heightmap_host_memo_counts(counts)
    return counts[0], counts[1]


def last_message() -> str:
    """Why the last evaluation of the active map failed (a point outside the grid), or ''."""
    return _ctypes_lib().cedra_heightmap_host_message().decode()


def external() -> ca.Function:
    """cedra_heightmap: (x[2] = [X, Y]) -> h, an external CasADi function on the active map (see load)."""
    _ctypes_lib()           # the same shared object: CasADi's dlopen returns the handle ctypes holds
    return ca.external(EXTERNAL_NAME, str(host_library()))


def rim_external(jacobian: bool = True) -> ca.Function:
    """cedra_rim_contact: (x[7] = [wheel center, unit axle, radius]) -> (e[6] = [p, h(p), h_X(p), h_Y(p)],
    J[6x7] = de/dx), the contact point by the rim search (docs/model.md, Contact; C: heightmap_rim) and its
    exact derivative (implicit function theorem), on the active map (see load). jacobian=False: cedra_rim_point,
    x -> e alone."""
    _ctypes_lib()
    return ca.external(RIM_EXTERNAL_NAME if jacobian else RIM_POINT_EXTERNAL_NAME, str(host_library()))


def bounds_external() -> ca.Function:
    """cedra_heightmap_bounds: (tin[8], unused) -> (bounds[2]): over the whole active map, |gradient| <= bounds[0]
    and the Hessian's largest eigenvalue <= bounds[1] (fmu_src/heightmap.c: derivative_bounds)."""
    _ctypes_lib()
    return ca.external(BOUNDS_EXTERNAL_NAME, str(host_library()))
