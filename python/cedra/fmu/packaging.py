"""Build an FMI 2.0 Co-Simulation FMU from a ModelSpec: generate C, the variable header and modelDescription.xml
(all from cedra.fmu.variables), compile the shared library, check its exported symbols, package.

    build_fmu(spec, build_dir) -> Path of <build_dir>/<spec.name>.fmu

The build tree <build_dir>/<spec.name>/ (git-ignored) holds every file the FMU ships in sources/ plus the
objects. Hand-written C (fmu_src/) is compiled with CFLAGS (warnings are errors); the CasADi-generated
cedra_model.c additionally with codegen.GENERATED_CFLAGS_RELAX.
"""
from __future__ import annotations

import importlib.util
import shutil
import subprocess
import zipfile
from pathlib import Path

from cedra.fmu.codegen import GENERATED_CFLAGS_RELAX, generate_c
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
# A generated model above LARGE_MODEL_BYTES of C (the 3D scenes with chassis points and several contacts per wheel:
# ~10 MB) is compiled at -O1: GCC's -O2 passes grow worse than linearly in a function's size on CasADi's
# straight-line code. rubble3d (9.8 MB): `python -m cedra build rubble3d` 188 s -> 97 s, the CPU of 10 s of its
# main job (cedra.run.simulate.run_bump) 3.38 -> 3.52 s (best of 2 each).
LARGE_MODEL_BYTES = 8_000_000
LARGE_MODEL_FLAGS = ["-O1"]
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
GENERATED_C = "cedra_model.c"
# the hand-written headers of each kind of block (the C files: modelDescription/generate.py SOURCE_FILES)
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


def _run(cmd, cwd):
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        raise BuildError(f"{' '.join(map(str, cmd))} failed (rc {r.returncode}):\n{r.stdout}{r.stderr}")
    return r.stdout


def exported_symbols(so_path) -> set[str]:
    """Names of the functions the shared library exports (nm -D --defined-only)."""
    out = _run(["nm", "-D", "--defined-only", str(so_path)], cwd=None)
    return {ln.split()[-1] for ln in out.splitlines() if len(ln.split()) >= 3 and ln.split()[1] in "TtWiV"}


def documentation(spec: ModelSpec) -> str:
    """The FMU's documentation/index.html: the reference generator's page (the site's reference has the same rows)."""
    return html_page(spec)


FLAGS_FILE = "build_flags.txt"      # sources/: each C file's compiler flags ("<file>: <flags>" per line)


def compile_flags(file_name: str, size: int, extra_cflags=()) -> list[str]:
    """The compiler flags of one C file of an FMU (size: its bytes; the generated model's size picks its level)."""
    own = HAND_WRITTEN_CFLAGS
    if file_name == GENERATED_C:
        own = GENERATED_CFLAGS_RELAX + ["-DCASADI_SYMBOL_EXPORT="]
        if size > LARGE_MODEL_BYTES:
            own += LARGE_MODEL_FLAGS
    return CFLAGS + own + list(extra_cflags)


def flags_text(sizes: dict[str, int], extra_cflags=()) -> str:
    """The FLAGS_FILE text for C files of these sizes: what a build with these flags packages."""
    return "".join(f"{f}: {' '.join(compile_flags(f, n, extra_cflags))}\n" for f, n in sorted(sizes.items()))


def build_fmu(spec: ModelSpec, build_dir, extra_cflags=()) -> Path:
    """Generate, compile and package the FMU; returns <build_dir>/<spec.name>.fmu. extra_cflags go after CFLAGS
    (e.g. the precision report's baseline build: -D switches of the plant's C)."""
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
    c_files = gen.SOURCE_FILES[spec.block]
    for f in [f for f in c_files if f != GENERATED_C] + list(HAND_WRITTEN_H[spec.block]):
        shutil.copy2(FMU_SRC / f, src / f)
    for f in FMI_HEADERS:
        shutil.copy2(fmi_headers_dir() / f, src / f)
    generate_c(spec, src)
    gen.write_vars_header(spec, src / "cedra_vars.h", guid)
    md = gen.write_model_description(spec, tree / "modelDescription.xml", guid)
    missing = set(c_files) - {p.name for p in src.glob("*.c")}
    if missing:
        raise BuildError(f"SourceFiles lists files that are not in sources/: {sorted(missing)}")
    # compile
    objects = []
    sizes = {f: (src / f).stat().st_size for f in c_files}
    for f in c_files:
        flags = compile_flags(f, sizes[f], extra_cflags)
        o = obj / (Path(f).stem + ".o")
        _run([CC, *flags, "-I", str(src), "-c", str(src / f), "-o", str(o)], cwd=tree)
        objects.append(str(o))
    so = tree / f"{spec.name}.so"
    _run([CC, "-shared", "-fvisibility=hidden", "-o", str(so), *objects, "-lm"], cwd=tree)
    exported = exported_symbols(so)
    if exported != FMI2_CS_FUNCTIONS:
        raise BuildError(f"{so} exports {sorted(exported - FMI2_CS_FUNCTIONS)} beyond the fmi2 functions and "
                         f"misses {sorted(FMI2_CS_FUNCTIONS - exported)}")
    doc = tree / "index.html"
    doc.write_text(documentation(spec))
    # package
    fmu = build_dir / f"{spec.name}.fmu"
    if fmu.exists():
        fmu.unlink()
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as z:
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
    return fmu
