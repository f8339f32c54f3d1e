"""The host libraries: C the Python side loads into this process (ctypes, casadi.external), built with the package's
compile helper (cedra.compile: the object cache, parallel compiles) and linked under build/host/.

    heightmap_library()                      fmu_src/heightmap.c for the heightmap's external functions
    rim_library(terrain C, on_heightmap, refine)   fmu_src/rim.c with a terrain's generated C: the contact search
    casadi_library(functions, stem, flags)   CasADi functions generated to C, one file each, in one library

cedra.mechanics calls the first two (the heightmap terrain, the contact search) and sits below the build: it
compiles nothing and takes its libraries from the builders this module hands it at the import of cedra.models
(rim.set_library_builder, heightmap.set_library_builder). A library's name is a hash of what it holds
(cedra.compile.source_key: the units with their local headers and the flags, no path), so the same model formed in
two checkouts names the same library file and gets the same GUID; an object compiled once, in any checkout or build
tree, comes from the cache after.
"""
from __future__ import annotations

import tempfile
from functools import lru_cache
from pathlib import Path

import casadi as ca

from cedra.compile import CompileError, CompileJob, link_library, source_key
from cedra.mechanics import heightmap, rim

REPO_ROOT = Path(__file__).resolve().parents[3]
FMU_SRC = REPO_ROOT / "fmu_src"
HOST_DIR = REPO_ROOT / "build" / "host"
HEIGHTMAP_FLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-DCEDRA_HEIGHTMAP_HOST")
RIM_FLAGS = ("-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
             "-Wno-unused-variable", "-Wno-unused-function", "-Wno-unused-but-set-variable", "-Wno-sign-compare",
             "-DRIM_HOST")
TERRAIN_SOURCE = "cedra_terrain_host.c"


@lru_cache(maxsize=None)
def heightmap_library() -> Path:
    """fmu_src/heightmap.c as a shared library with CEDRA_HEIGHTMAP_HOST (its loader and message functions)."""
    job = CompileJob(FMU_SRC / "heightmap.c", HEIGHTMAP_FLAGS)
    lib = HOST_DIR / f"libcedra_heightmap_{source_key([job])[:16]}.so"
    try:
        return link_library([job], lib)
    except CompileError as e:
        raise heightmap.HeightmapError(str(e)) from None


@lru_cache(maxsize=None)
def rim_library(code: str, on_heightmap: bool = False, refine: bool = False) -> Path:
    """fmu_src/rim.c and a terrain's generated C (code) in one shared library; on_heightmap: the terrain calls the
    heightmap's external functions, taken from heightmap_library (linked by its path, found again by an rpath)."""
    flags = RIM_FLAGS + (f"-DCEDRA_HEIGHTMAP={int(on_heightmap)}", f"-DCEDRA_RIM_REFINE={int(refine)}")
    # -Bsymbolic: rim.c calls this library's own cedra_terrain, whatever other library is loaded
    link = ["-Wl,-Bsymbolic"]
    named = []
    if on_heightmap:
        hm = heightmap.host_library()
        link += [str(hm), f"-Wl,-rpath,{hm.parent}"]
        named.append(hm.name)           # by its file name (a hash of its source), not its directory
    with tempfile.TemporaryDirectory() as d:
        src = Path(d) / TERRAIN_SOURCE
        src.write_text(code)
        jobs = [CompileJob(FMU_SRC / "rim.c", flags), CompileJob(src, flags)]
        lib = HOST_DIR / f"libcedra_rim_{source_key(jobs, *named)[:16]}.so"
        try:
            return link_library(jobs, lib, (*link, "-lm"))
        except CompileError as e:
            raise rim.RimBuildError(str(e)) from None


def casadi_library(functions: list[ca.Function], stem: str, flags=("-O1",), extra: list[CompileJob] = (),
                   link_args=("-lm",), out_dir: Path | None = None) -> Path:
    """The functions generated to C by CasADi's code generator, one file per function (compiled in parallel, each
    through the object cache), with the extra jobs' objects, in one shared library out_dir/lib<stem>_<key>.so
    (out_dir: build/host/)."""
    with tempfile.TemporaryDirectory() as d:
        jobs = []
        for fn in functions:
            cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False})
            cg.add(fn)
            cg.generate(d + "/")
            jobs.append(CompileJob(Path(d) / f"{fn.name()}.c", tuple(flags) + ("-fPIC",) * ("-fPIC" not in flags)))
        jobs += list(extra)
        lib = Path(out_dir or HOST_DIR) / f"lib{stem}_{source_key(jobs, *link_args)[:16]}.so"
        return link_library(jobs, lib, link_args)


rim.set_library_builder(rim_library)
heightmap.set_library_builder(heightmap_library)
