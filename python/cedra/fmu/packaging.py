"""Build an FMI 2.0 Co-Simulation FMU from a ModelSpec: generate C, the variable header and modelDescription.xml
(all from cedra.fmu.variables), compile the shared library, check its exported symbols, package.

    build_fmu(spec, build_dir) -> Path of <build_dir>/<spec.name>.fmu
    ensure_fmu(name_or_scene, build_dir) -> the FMU, built first if it is missing or stale

The build tree <build_dir>/<spec.name>/ (git-ignored) holds every file the FMU ships in sources/ plus the
objects. Hand-written C (fmu_src/) is compiled with CFLAGS (warnings are errors); the CasADi-generated files
(one per contract function, cedra.fmu.codegen) additionally with codegen.GENERATED_CFLAGS_RELAX. Every object comes
from the object cache when its translation unit, flags and compiler are the same (cedra.fmu.compiler).

An FMU built by ensure_fmu carries a build stamp beside it (<name>.fmu.stamp): the hash of what it was built from
(the model's sources, the scene, its heightmap, the flags) and of the FMU file itself. ensure_fmu builds again
only when the stamp does not match; a stamp is cheap to check (no model is formed), so an unchanged scene is
reused at once.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import shutil
import sys
import time
import zipfile
from dataclasses import fields
from functools import lru_cache
from pathlib import Path

import casadi as ca

from cedra.fmu.codegen import GENERATED_CFLAGS_RELAX, MODEL_HEADER, generate_c, is_generated
from cedra.fmu.compiler import CompileError, CompileJob, CompileStats, compile_objects, compiler_identity
from cedra.fmu.compiler import run as _compiler_run
from cedra.mechanics.heightmap import RESOURCE_NAME
from cedra.contract import ModelSpec
from cedra.fmu.reference import html_page

REPO_ROOT = Path(__file__).resolve().parents[3]
FMU_SRC = REPO_ROOT / "fmu_src"
CC = "gcc"
# -fno-math-errno (nothing reads errno after a math call): sqrt and friends inline, the same results bit for bit
# (`python -m cedra report figures --figure flags` measures this and the other flags' CPU).
CFLAGS = ["-std=c99", "-O2", "-fPIC", "-Wall", "-Wextra", "-Werror", "-fvisibility=hidden", "-fno-math-errno"]
# The hand-written C (the solvers, the heightmap's search, the linear algebra) at -O3: a few per cent less CPU on
# hills3d, the same results bit for bit (no fast-math: IEEE order kept). The generated model stays at -O2: -O3
# compiled it slower and gained nothing measurable.
HAND_WRITTEN_CFLAGS = ["-O3"]
# A generated function above LARGE_FUNCTION_BYTES of C (the 3D scenes' Jacobians with chassis points and several
# contacts per wheel) is compiled at -O1: GCC's -O2 passes grow worse than linearly in a function's size on
# CasADi's straight-line code (rubble3d's whole model at 9.8 MB: 188 s -> 97 s to build, +4 % CPU of its run).
LARGE_FUNCTION_BYTES = 3_000_000
LARGE_FUNCTION_FLAGS = ["-O1"]
# The generated functions a run evaluates rarely are compiled at -O1 whatever their size, where -O2 costs several
# times the compile (CPU seconds of gcc 12 on stairs3d's C):
# - cedra_settle, cedra_guess: only fmi2ExitInitializationMode (the settle's Newton, a few dozen evaluations);
#   cedra_settle 68.5 s at -O2, 13.4 s at -O1;
# - cedra_out: once per communication step (stairs3d: 100 a simulated second against ~5800 of cedra_f);
#   21.7 s -> 6.1 s;
# - cedra_fcjac: once per Jacobian, and only while a collision point touches; 22.6 s -> 11.5 s; likewise the parts
#   only it calls (cedra.models.parts: each point's generalized-force Jacobian and the point-contact part's).
# - cedra_sample, a drive controller's step: once per communication step, beside the plant's thousands of
#   evaluations; drive3d's 15.9 s at -O1 against 22.6 s at -O2 (a loaded machine).
# The CPU of stairs3d's 10 s and bump2d's 15 s main-job runs with cedra_out and cedra_fcjac at -O1: 0.985 and
# 0.987 of the runs at -O2 (the least of 3 each, the same machine; within its noise).
COLD_FUNCTIONS = ("cedra_settle.c", "cedra_guess.c", "cedra_out.c", "cedra_fcjac.c", "cedra_part_point_jac.c",
                  "cedra_sample.c")
# Of the hot functions, the Jacobians (every *jac.c: cedra_rjac and the parts it calls), cedra_switch and cedra_fc
# are at -O1 too: the dynamics' Jacobian part alone is 28.7 s of gcc at -O2 on rubble3d, 10.2 s at -O1 (user CPU,
# gcc 12, an idle machine), while the runs' CPU with them at -O1 is 1.019 (stairs3d, 10 s), 1.003 (bump2d, 15 s)
# and 0.995 (bump3d, 10 s) of the runs with them at -O2 (the least of 3 each, the speed loop of tools/profile;
# within the machine's noise). cedra_f and the parts it calls stay at -O2: they are evaluated several times per step.
LIGHT_HOT_FUNCTIONS = ("cedra_switch.c", "cedra_fc.c")


def light_optimization(file_name: str) -> bool:
    """Whether a generated C file is compiled at -O1 whatever its size (COLD_FUNCTIONS, the Jacobians,
    LIGHT_HOT_FUNCTIONS)."""
    return file_name in COLD_FUNCTIONS or file_name in LIGHT_HOT_FUNCTIONS or file_name.endswith("jac.c")
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
# the hand-written headers of each kind of block (the C files: modelDescription/generate.py HAND_WRITTEN_C)
HAND_WRITTEN_H = {
    "plant": ("cedra_var.h", "glue.h", "plant.h", "model_glue.h", "solver.h", "linalg.h", "rigid.h", "heightmap.h"),
    "controller": ("cedra_var.h", "glue.h", "controller.h"),
}

# the functions a Co-Simulation FMU exports: exactly these (nm -D)
FMI2_CS_FUNCTIONS = frozenset("""
fmi2GetTypesPlatform fmi2GetVersion fmi2SetDebugLogging fmi2Instantiate fmi2FreeInstance fmi2SetupExperiment
fmi2EnterInitializationMode fmi2ExitInitializationMode fmi2Terminate fmi2Reset fmi2GetReal fmi2GetInteger
fmi2GetBoolean fmi2GetString fmi2SetReal fmi2SetInteger fmi2SetBoolean fmi2SetString fmi2GetFMUstate
fmi2SetFMUstate fmi2FreeFMUstate fmi2SerializedFMUstateSize fmi2SerializeFMUstate fmi2DeSerializeFMUstate
fmi2GetDirectionalDerivative fmi2SetRealInputDerivatives fmi2GetRealOutputDerivatives fmi2DoStep fmi2CancelStep
fmi2GetStatus fmi2GetRealStatus fmi2GetIntegerStatus fmi2GetBooleanStatus fmi2GetStringStatus
""".split())


class BuildError(RuntimeError):
    pass


def _generator():
    """modelDescription/generate.py as a module (it is not part of the cedra package)."""
    path = REPO_ROOT / "modelDescription" / "generate.py"
    mod_spec = importlib.util.spec_from_file_location("cedra_md_generate", path)
    mod = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(mod)
    return mod


def fmi_headers_dir() -> Path:
    import fmpy
    return Path(fmpy.__file__).parent / "c-code"


def _run(cmd, cwd=None):
    try:
        return _compiler_run(cmd, cwd)
    except CompileError as e:
        raise BuildError(str(e)) from None


def exported_symbols(so_path) -> set[str]:
    """Names of the functions the shared library exports (nm -D --defined-only)."""
    out = _run(["nm", "-D", "--defined-only", str(so_path)], cwd=None)
    return {ln.split()[-1] for ln in out.splitlines() if len(ln.split()) >= 3 and ln.split()[1] in "TtWiV"}


def documentation(spec: ModelSpec) -> str:
    """The FMU's documentation/index.html: the reference generator's page (the site's reference has the same rows)."""
    return html_page(spec)


FLAGS_FILE = "build_flags.txt"      # sources/: each C file's compiler flags ("<file>: <flags>" per line)


def compile_flags(file_name: str, size: int, extra_cflags=()) -> list[str]:
    """The compiler flags of one C file of an FMU (size: its bytes; a generated function's size picks its level)."""
    own = HAND_WRITTEN_CFLAGS
    if is_generated(file_name):
        own = GENERATED_CFLAGS_RELAX + ["-DCASADI_SYMBOL_EXPORT="]
        if size > LARGE_FUNCTION_BYTES or light_optimization(file_name):
            own += LARGE_FUNCTION_FLAGS
    return CFLAGS + own + list(extra_cflags)


def flags_text(sizes: dict[str, int], extra_cflags=()) -> str:
    """The FLAGS_FILE text for C files of these sizes: what a build with these flags packages."""
    return "".join(f"{f}: {' '.join(compile_flags(f, n, extra_cflags))}\n" for f, n in sorted(sizes.items()))


def _jobs() -> int:
    """Compiles at once within one build: CEDRA_BUILD_JOBS, else every core."""
    return max(1, int(os.environ.get("CEDRA_BUILD_JOBS", 0)) or os.cpu_count() or 1)


def build_fmu(spec: ModelSpec, build_dir, extra_cflags=(), jobs: int | None = None,
              stats: CompileStats | None = None) -> Path:
    """Generate, compile and package the FMU; returns <build_dir>/<spec.name>.fmu. extra_cflags go after CFLAGS
    (e.g. the precision report's baseline build: -D switches of the plant's C). jobs: compiles at once (default:
    every core); stats, if given, gets which files came from the object cache and which were compiled."""
    spec.check()
    build_dir = Path(build_dir).resolve()
    tree = build_dir / spec.name
    src, obj = tree / "sources", tree / "obj"
    if tree.exists():
        shutil.rmtree(tree)
    src.mkdir(parents=True)
    obj.mkdir()
    gen = _generator()
    guid = gen.spec_guid(spec)
    # sources/: hand-written C, FMI headers, generated model, variable header
    c_files = gen.source_files(spec)
    for f in [f for f in c_files if not is_generated(f)] + list(HAND_WRITTEN_H[spec.block]):
        shutil.copy2(FMU_SRC / f, src / f)
    for f in FMI_HEADERS:
        shutil.copy2(fmi_headers_dir() / f, src / f)
    generate_c(spec, src)
    gen.write_vars_header(spec, src / "cedra_vars.h", guid)
    md = gen.write_model_description(spec, tree / "modelDescription.xml", guid)
    missing = set(c_files) - {p.name for p in src.glob("*.c")}
    if missing:
        raise BuildError(f"SourceFiles lists files that are not in sources/: {sorted(missing)}")
    if not (src / MODEL_HEADER).is_file():
        raise BuildError(f"the generated model's header {MODEL_HEADER} is missing from sources/")
    # compile: one translation unit per file, in parallel, each from the object cache where it holds it
    sizes = {f: (src / f).stat().st_size for f in c_files}
    work = [CompileJob(src / f, tuple(compile_flags(f, sizes[f], extra_cflags)), src) for f in c_files]
    try:
        objects = compile_objects(work, obj, workers=jobs or _jobs(), cc=CC, stats=stats)
    except CompileError as e:
        raise BuildError(str(e)) from None
    so = tree / f"{spec.name}.so"
    _run([CC, "-shared", "-fvisibility=hidden", "-o", str(so), *map(str, objects), "-lm"], cwd=tree)
    exported = exported_symbols(so)
    if exported != FMI2_CS_FUNCTIONS:
        raise BuildError(f"{so} exports {sorted(exported - FMI2_CS_FUNCTIONS)} beyond the fmi2 functions and "
                         f"misses {sorted(FMI2_CS_FUNCTIONS - exported)}")
    doc = tree / "index.html"
    doc.write_text(documentation(spec))
    # package: written next to the FMU, then renamed over it (a reader never sees half an FMU)
    fmu = build_dir / f"{spec.name}.fmu"
    part = build_dir / f".{spec.name}.fmu.part"
    with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        z.write(md, "modelDescription.xml")
        z.write(so, f"binaries/linux64/{spec.name}.so")
        for p in sorted(src.iterdir()):
            if p.suffix in (".c", ".h"):
                z.write(p, f"sources/{p.name}")
        # how each file was compiled, so that a kept build can be told from one with other flags (sweep variants)
        z.writestr(f"sources/{FLAGS_FILE}", flags_text(sizes, extra_cflags))
        z.write(doc, "documentation/index.html")
        if spec.heightmap_file:
            z.write(spec.heightmap_file, f"resources/{RESOURCE_NAME}")
    os.replace(part, fmu)
    return fmu


# ------------------------------------------------------------------------------------------------ build stamps

# what forms an FMU: the packages that form the model and write the FMU (not run/, reports/ or the CLI, whose
# changes leave every FMU as it was), the hand-written C and the model-description writer
_STAMP_SOURCES = ("python/cedra/contract.py", "python/cedra/compile.py", "python/cedra/__init__.py",
                  "python/cedra/mechanics", "python/cedra/rover", "python/cedra/models", "python/cedra/fmu", "fmu_src",
                  "modelDescription/generate.py", "pyproject.toml")
STAMP_SUFFIX = ".stamp"


@lru_cache(maxsize=None)
def sources_digest() -> str:
    """The hash of every file that forms an FMU, of the CasADi and FMPy versions and of the compiler."""
    import fmpy
    h = hashlib.sha256()
    for entry in _STAMP_SOURCES:
        root = REPO_ROOT / entry
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file()
                                                      and "__pycache__" not in p.parts and p.suffix != ".pyc")
        for f in files:
            h.update(str(f.relative_to(REPO_ROOT)).encode() + b"\0" + f.read_bytes() + b"\0")
    h.update(f"casadi {ca.__version__} fmpy {fmpy.__version__} python {sys.version_info[:2]}".encode())
    h.update(compiler_identity(CC).encode())
    return h.hexdigest()


def _scene_text(scene) -> str:
    """A scene's content, without where its file lives (the same scene from two paths is one build)."""
    from dataclasses import replace
    d = {f.name: getattr(scene, f.name) for f in fields(scene) if f.name != "path"}
    if scene.options.heightmap:           # the grid's bytes are in the key (build_key), its directory is not
        d["options"] = replace(scene.options, heightmap=Path(scene.options.heightmap).name)
    return repr(sorted(d.items()))


def build_key(target, extra_cflags=()) -> str:
    """The key an FMU of target (a controller's name or a Scene) is built under: sources_digest, the scene's
    content and its heightmap grid's bytes, the extra flags."""
    h = hashlib.sha256(sources_digest().encode())
    if isinstance(target, str):
        h.update(b"controller " + target.encode())
    else:
        h.update(_scene_text(target).encode())
        if target.options.heightmap:
            h.update(Path(target.options.heightmap).read_bytes())
    h.update(repr((CFLAGS, HAND_WRITTEN_CFLAGS, GENERATED_CFLAGS_RELAX, LARGE_FUNCTION_BYTES, LARGE_FUNCTION_FLAGS,
                   COLD_FUNCTIONS, tuple(extra_cflags))).encode())
    return h.hexdigest()


def _file_sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def stamp_matches(fmu: Path, key: str) -> bool:
    """Whether fmu exists and its stamp says it was built under key and is still that file."""
    stamp = Path(str(fmu) + STAMP_SUFFIX)
    try:
        data = json.loads(stamp.read_text())
        return data.get("key") == key and data.get("fmu_sha256") == _file_sha(fmu)
    except (OSError, ValueError, AttributeError):
        return False


def write_stamp(fmu: Path, key: str) -> None:
    stamp = Path(str(fmu) + STAMP_SUFFIX)
    tmp = stamp.with_name(stamp.name + ".part")
    tmp.write_text(json.dumps({"key": key, "fmu_sha256": _file_sha(fmu)}) + "\n")
    os.replace(tmp, stamp)


def resolve_target(target):
    """(the FMU's name, the Scene or controller name, a function forming its ModelSpec) of a shipped scene's or
    controller's name, a scene file's path or a Scene."""
    from cedra.models.controller import CONTROLLERS, shipped_controller
    from cedra.models.scene import Scene, load, load_shipped
    if isinstance(target, Scene):
        return target.name, target, target.spec
    target = str(target)
    if target in CONTROLLERS:
        return target, target, lambda: shipped_controller(target)
    scene = load(target) if target.endswith(".toml") else load_shipped(target)
    return scene.name, scene, scene.spec


def fmu_state(target, build_dir, extra_cflags=()) -> tuple[Path, str, str]:
    """(the FMU's path, its build key, "up to date" / "missing" / "stale") for target in build_dir."""
    name, what, _ = resolve_target(target)
    path = Path(build_dir) / f"{name}.fmu"
    key = build_key(what, extra_cflags)
    if not path.exists():
        return path, key, "missing"
    return path, key, "up to date" if stamp_matches(path, key) else "stale"


def ensure_fmu(target, build_dir, extra_cflags=(), log=None, jobs: int | None = None) -> Path:
    """<build_dir>/<name>.fmu of target (a shipped scene's or controller's name, a scene file's path, or a Scene),
    built first when it is missing or stale (its stamp does not match today's sources, scene and flags); log (a
    callable taking a line, default: print to stderr) is told when and why it builds. Processes that ask for the
    same FMU at once (test workers, sweeps) take turns on a lock file: one builds, the others find it up to date."""
    import fcntl
    name, what, form = resolve_target(target)
    path, key, state = fmu_state(what, build_dir, extra_cflags)
    if state == "up to date":
        return path
    Path(build_dir).mkdir(parents=True, exist_ok=True)
    with open(Path(build_dir) / f".{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path, key, state = fmu_state(what, build_dir, extra_cflags)
        if state == "up to date":
            return path
        say = log or (lambda line: print(line, file=sys.stderr, flush=True))
        say(f"{name}: building {path} ({state})")
        t0 = time.perf_counter()
        stats = CompileStats()
        out = build_fmu(form(), build_dir, extra_cflags, jobs=jobs, stats=stats)
        write_stamp(out, key)
        say(f"{name}: built in {time.perf_counter() - t0:.1f} s ({len(stats.compiled)} files compiled, "
            f"{len(stats.cached)} from the cache)")
    return out
