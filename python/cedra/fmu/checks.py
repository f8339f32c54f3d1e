"""Independent checks of an FMI 2.0 Co-Simulation FMU: other people's checkers and importers, plus our own
runtime check that no checker does.

    fmpy_validate(fmu)            FMPy's modelDescription validation (schema, names, ModelStructure, units)
    vdmcheck(fmu)                 VDMCheck2 1.1.3 (INTO-CPS, VDM-SL model of the FMI 2.0 rules), from Maven Central
    libcosim_run(fmu, ...)        simulate with OSP libcosim (libcosimpy), in a subprocess
    fmpy_run(fmu, ...)            simulate with FMPy
    recompile_from_sources(fmu)   rebuild binaries/<platform> from sources/ with FMPy's CMake project
    start_value_roundtrip(fmu)    XML start values == what the binary returns for the same value reference
    not_an_fmu(path)              why a path cannot be checked as an FMU, or None

`python -m cedra check FMU ...` (cedra.fmu.compliance) runs fmpy validate, VDMCheck2, the round trip and a short
libcosim run against FMPy on any FMUs.

Every function raises CheckerUnavailable when its tool cannot be run at all (no java/mvn, Maven Central not
reachable, no cmake, libcosimpy not installed): callers (the tests) must treat that as a failure, never a
skip, because CI reaches the registries the tools come from.

Gaps of the checkers: swapped value references, a wrong GUID or a modelIdentifier that is not the .so name
are invisible to fmpy validate and VDMCheck2; the start value round trip catches swapped value references as
long as the swapped variables have different start values, and a wrong GUID (fmi2Instantiate refuses it).

Step sizes and agreement between libcosim and FMPy (measured, see tests/test_fmu_checkers.py):
libcosim keeps time in integer nanoseconds and passes t_k = k*step_ns*1e-9 and h = step_ns*1e-9 (h is the
same double every step); FMPy passes t_k = k*interval and h = t_{k+1} - t_k computed in doubles, which differs
from `interval` by round-off unless the step is a power of two seconds. With a power-of-two step
(e.g. 2**-7 s = 7812500 ns) both hand the FMU identical (t, h) and results are bit-identical; with 0.01 s
they differ by the FMU's sensitivity to ~1e-18 s perturbations of h (for a toy Euler model: ~1e-16 relative).

Run `python python/cedra/fmu/checks.py vdmcheck|validate|roundtrip FMU` for a quick look from the shell.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[3]
VDMCHECK_VERSION = "1.1.3"
VDMCHECK_POM = REPO_ROOT / "tools" / "vdmcheck" / "pom.xml"

# measured durations of the last calls in this process (seconds), for reports: name -> seconds
TIMINGS: dict[str, float] = {}


class CheckerUnavailable(RuntimeError):
    """The checker could not be run at all (missing tool, download failed). Not a verdict on the FMU."""


class CheckerFailed(RuntimeError):
    """The checker ran but crashed or produced output we cannot interpret."""


@contextlib.contextmanager
def _timed(name: str):
    t0 = time.perf_counter()
    try:
        yield
    finally:
        TIMINGS[name] = time.perf_counter() - t0


# ----------------------------------------------------------------------------------------------- caches, lock

def tools_cache() -> Path:
    """Root of the downloaded tools: $CEDRA_TOOLS_CACHE or <repo>/tools/cache (git-ignored)."""
    return Path(os.environ.get("CEDRA_TOOLS_CACHE") or REPO_ROOT / "tools" / "cache").resolve()


@contextlib.contextmanager
def file_lock(path: Path, timeout: float = 900.0):
    """Exclusive advisory lock (fcntl.flock) on `path`, shared by processes (pytest-xdist workers)."""
    import fcntl
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"could not lock {path} within {timeout} s")
                time.sleep(0.1)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


# ------------------------------------------------------------------------------------------------ fmpy validate

def fmpy_validate(fmu_path) -> list[str]:
    """Problems FMPy finds in the FMU (schema, variable names, ModelStructure, start values, units); [] = fine."""
    try:
        from fmpy.validation import validate_fmu
    except ImportError as e:  # pragma: no cover
        raise CheckerUnavailable(f"fmpy is not installed: {e}") from e
    with _timed("fmpy_validate"):
        return list(validate_fmu(str(fmu_path)))


# ---------------------------------------------------------------------------------------------------- VDMCheck2

_VDM_JARS = {  # name in dist/ -> artifact file prefix in lib/
    "vdmcheck2.jar": "vdmcheck2-",
    "vdmj.jar": "vdmj-",
    "annotations.jar": "annotations-",
    "xsd2vdm.jar": "xsd2vdm-",
    "fmuReader.jar": "fmuReader-",
}


def _vdm_dir() -> Path:
    return tools_cache() / "vdmcheck"


def _run_quiet(cmd: list[str], what: str, timeout: float, **kw) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)
    except FileNotFoundError as e:
        raise CheckerUnavailable(f"{what}: {cmd[0]} not found ({e})") from e
    except subprocess.TimeoutExpired as e:
        raise CheckerUnavailable(f"{what}: timed out after {timeout} s: {' '.join(cmd)}") from e


def _setup_vdmcheck_locked(root: Path) -> Path:
    """Fetch VDMCheck2 with Maven and lay out root/dist. Caller holds the lock. Returns dist/."""
    dist = root / "dist"
    marker = dist / ".cedra-complete"
    if marker.exists() and marker.read_text().split()[0] == VDMCHECK_VERSION:
        return dist
    for tool in ("java", "mvn"):
        if shutil.which(tool) is None:
            raise CheckerUnavailable(f"VDMCheck2 needs `{tool}` on PATH (Java 17 + Maven)")
    t0 = time.perf_counter()
    lib = root / "lib"
    shutil.rmtree(lib, ignore_errors=True)
    cmd = ["mvn", "-B", "-q", "-Dstyle.color=never", "-f", str(VDMCHECK_POM),
           f"-Dvdmcheck2.version={VDMCHECK_VERSION}",
           "dependency:copy-dependencies", f"-DoutputDirectory={lib}"]
    if os.environ.get("CEDRA_MAVEN_REPO"):     # optional separate local repository (e.g. a cold-cache test)
        cmd.insert(1, f"-Dmaven.repo.local={os.environ['CEDRA_MAVEN_REPO']}")
    r = _run_quiet(cmd, "VDMCheck2 download", timeout=900)
    if r.returncode != 0:
        raise CheckerUnavailable(f"mvn failed (rc {r.returncode}) fetching VDMCheck2:\n{r.stdout}\n{r.stderr}")
    tmp = root / "dist.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    jars = {p.name: p for p in lib.glob("*.jar")}

    def find(prefix: str) -> Path:
        hits = [p for n, p in jars.items() if n.startswith(prefix)]
        if len(hits) != 1:
            raise CheckerUnavailable(f"expected one {prefix}*.jar in {lib}, found {sorted(jars)}")
        return hits[0]

    for name, prefix in _VDM_JARS.items():
        shutil.copy2(find(prefix), tmp / name)
    for prefix in ("rule-model-", "static-model-"):
        with zipfile.ZipFile(find(prefix)) as z:
            z.extractall(tmp, [m for m in z.namelist() if not m.startswith("META-INF/")])
    with zipfile.ZipFile(tmp / "vdmcheck2.jar") as z:
        z.extractall(tmp, [m for m in z.namelist() if m.startswith("fmi2schema/")])
    seconds = time.perf_counter() - t0
    (tmp / ".cedra-complete").write_text(f"{VDMCHECK_VERSION} setup_seconds={seconds:.1f}\n")
    shutil.rmtree(dist, ignore_errors=True)
    tmp.rename(dist)
    TIMINGS["vdmcheck_setup"] = seconds
    return dist


def ensure_vdmcheck() -> Path:
    """Set VDMCheck2 up in the tools cache on first use (under the lock); return its dist/ folder."""
    root = _vdm_dir()
    with file_lock(tools_cache() / "vdmcheck.lock"):
        return _setup_vdmcheck_locked(root)


_VDM_RULE = re.compile(r"^\w[\w-]*: .* at \S+:\d+\s*$")
_VDM_WARNING = re.compile(r"^\w[\w-]*: Warning: ")
# a file VDMCheck2 refuses to read: not well-formed XML, or (`Internal 0000: Cannot read file: ... XML validation`)
# not valid against the FMI 2.0 schema
_VDM_REFUSED = re.compile(r"^(XML errors found|Internal \d+: )")
# VDMCheck2's two JVMs (its own, then VDMJ on the generated VDM-SL) run a few seconds of parsing and evaluation each:
# the client compiler alone and the serial collector take about half the CPU time of the defaults for the same
# output (VDMCheck2 starts the second JVM itself, so the flags go through JAVA_TOOL_OPTIONS, which both read).
_VDM_JAVA_OPTIONS = "-XX:TieredStopAtLevel=1 -XX:+UseSerialGC"


def vdmcheck(fmu_path, timeout: float = 300.0) -> tuple[bool, list[str]]:
    """Run VDMCheck2 on an .fmu (or a modelDescription.xml). Returns (ok, lines): ok is True when VDMCheck2
    says "No errors found."; lines is its whole output (rule lines look like
    `validOutputs: Outputs section does not match output variables at modelDescription.xml:37`, followed by a
    link to the standard; warnings, which leave ok True, like `rule: Warning: ...`). Raises CheckerUnavailable if
    it cannot be set up, CheckerFailed if it crashed. Several runs may go at once: each writes the VDM-SL it
    generates (by default a file `null` in VDMCheck2's folder) into a folder of its own (-v)."""
    fmu_path = Path(fmu_path).resolve()
    if not fmu_path.exists():
        raise FileNotFoundError(fmu_path)
    dist = ensure_vdmcheck()
    env = dict(os.environ, JAVA_TOOL_OPTIONS=" ".join(filter(None, [os.environ.get("JAVA_TOOL_OPTIONS"),
                                                                    _VDM_JAVA_OPTIONS])))
    with tempfile.TemporaryDirectory(prefix="cedra-vdmcheck-") as scratch, _timed("vdmcheck"):
        r = _run_quiet(["java", "-jar", str(dist / "vdmcheck2.jar"), "-v", str(Path(scratch) / "model.vdmsl"),
                        str(fmu_path)], "VDMCheck2", timeout=timeout, cwd=dist, env=env)
    lines = [ln.rstrip() for ln in (r.stdout + "\n" + r.stderr).splitlines()
             if ln.strip() and not ln.startswith(("Picked up JAVA_TOOL_OPTIONS", "VDM source written to"))]
    if "No errors found." in lines and r.returncode == 0:
        return True, lines
    if "Errors found." in lines or any(_VDM_RULE.match(ln) or _VDM_REFUSED.match(ln) for ln in lines):
        return False, lines
    raise CheckerFailed(f"VDMCheck2 gave no verdict (rc {r.returncode}):\n" + "\n".join(lines))


def vdmcheck_errors(lines: list[str]) -> list[str]:
    """The rule violations (`rule: message at file:line`) and the refusals of the file (XML errors, schema
    errors) out of vdmcheck()'s lines, warnings left out."""
    return [ln for ln in lines if (_VDM_RULE.match(ln) or _VDM_REFUSED.match(ln)) and not _VDM_WARNING.match(ln)]


def vdmcheck_warnings(lines: list[str]) -> list[str]:
    """VDMCheck2's warnings (`rule: Warning: message at file:line`) out of vdmcheck()'s lines."""
    return [ln for ln in lines if _VDM_WARNING.match(ln)]


# ---------------------------------------------------------------------------------------------- model description

def read_md(fmu_path):
    """The FMU's model description (FMPy's reader, not validated)."""
    from fmpy import read_model_description
    return read_model_description(str(fmu_path), validate=False)


def _variables(fmu_path) -> dict:
    return {v.name: v for v in read_md(fmu_path).modelVariables}


def _default_outputs(md) -> list[str]:
    return [v.name for v in md.modelVariables if v.causality == "output"]


# -------------------------------------------------------------------------------------------------------- libcosim

def _n_steps(step: float, stop: float) -> int:
    n = round(stop / step)
    if n < 1 or abs(n * step - stop) > 1e-9 * max(1.0, stop):
        raise ValueError(f"stop={stop} is not a whole number of steps of {step}")
    return n


def libcosim_run(fmu_path, step: float, stop: float, inputs: dict | None = None,
                 outputs: list[str] | None = None, timeout: float = 600.0) -> dict:
    """Simulate the FMU alone with OSP libcosim (fixed step `step` s until `stop` s) in a subprocess.

    inputs: name -> value, set as initial values (by value reference, Real/Integer/Boolean) before init.
    outputs: names to record (default: every causality="output" variable), Real or Integer.
    Returns {"time": t[0..N] (s), "time_ns": int ns, name: values[0..N]} with the sample at t=0 after
    initialization. Raises CheckerFailed with the subprocess's stderr if libcosim fails or aborts."""
    import numpy as np
    import importlib
    try:
        importlib.import_module("libcosimpy")       # only to fail early and clearly in this process
    except ImportError as e:
        raise CheckerUnavailable(f"libcosimpy is not installed: {e}") from e
    md = read_md(fmu_path)
    byname = {v.name: v for v in md.modelVariables}
    outputs = list(outputs) if outputs is not None else _default_outputs(md)
    step_ns = round(step * 1e9)
    if abs(step_ns - step * 1e9) > 1e-3:
        raise ValueError(f"step {step} s is not a whole number of nanoseconds")
    n = _n_steps(step, stop)
    req = {"fmu": str(Path(fmu_path).resolve()), "step_ns": step_ns, "n": n,
           "inputs": [], "outputs": []}
    for name, value in (inputs or {}).items():
        v = byname[name]
        req["inputs"].append([v.valueReference, v.type, value])
    for name in outputs:
        v = byname[name]
        if v.type not in ("Real", "Integer"):
            raise ValueError(f"libcosim_run records Real/Integer only, {name} is {v.type}")
        req["outputs"].append([name, v.valueReference, v.type])
    with tempfile.TemporaryDirectory(prefix="cedra-libcosim-") as tmp:
        req_path, res_path = Path(tmp) / "req.json", Path(tmp) / "res.npz"
        req["result"] = str(res_path)
        req_path.write_text(json.dumps(req))
        with _timed("libcosim_run"):
            try:
                r = subprocess.run([sys.executable, str(Path(__file__).resolve()), "_libcosim_worker",
                                    str(req_path)], capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired as e:
                raise CheckerFailed(f"libcosim run timed out after {timeout} s") from e
        if r.returncode != 0 or not res_path.exists():
            how = f"rc {r.returncode}"
            if r.returncode < 0:
                import signal
                with contextlib.suppress(ValueError):
                    how += f", killed by {signal.Signals(-r.returncode).name}"
            raise CheckerFailed(f"libcosim run failed ({how}):\n{r.stderr[-6000:]}\n{r.stdout[-2000:]}")
        with np.load(res_path) as z:
            out = {k: z[k] for k in z.files}
    out["time"] = out["time_ns"] * 1e-9
    return out


def _libcosim_worker(req_path: str) -> None:
    """Runs in the subprocess: libcosim may abort() the process (e.g. instantiate returning NULL)."""
    import numpy as np
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    req = json.loads(Path(req_path).read_text())
    log_output_level(CosimLogLevel.WARNING)
    n, step_ns = req["n"], req["step_ns"]
    ex = CosimExecution.from_step_size(step_ns)
    slave = CosimLocalSlave(fmu_path=req["fmu"], instance_name="fmu")
    idx = ex.add_local_slave(slave)
    if idx < 0:
        sys.exit(f"add_local_slave failed for {req['fmu']}")
    for vr, typ, value in req["inputs"]:
        ok = {"Real": lambda: ex.real_initial_value(idx, vr, float(value)),
              "Integer": lambda: ex.integer_initial_value(idx, vr, int(value)),
              "Boolean": lambda: ex.boolean_initial_value(idx, vr, bool(value))}[typ]()
        if not ok:
            sys.exit(f"setting initial value vr={vr} ({typ}) = {value} failed")
    obs = CosimObserver.create_time_series(buffer_size=n + 16)
    ex.add_observer(obs)
    vtype = {"Real": CosimVariableType.REAL, "Integer": CosimVariableType.INTEGER}
    for _, vr, typ in req["outputs"]:
        if not obs.start_time_series(idx, vr, vtype[typ]):
            sys.exit(f"cannot observe vr={vr}")
    if not ex.simulate_until(n * step_ns):
        sys.exit(f"simulate_until failed: {ex.status()}")
    result = {}
    time_ns = None
    for name, vr, typ in req["outputs"]:
        get = obs.time_series_real_samples if typ == "Real" else obs.time_series_integer_samples
        # libcosimpy 0.0.6 trims the returned lists by counting step numbers == 0, which also drops a real
        # sample at step 0: read step 0.. and step 1.. separately and merge by step number.
        samples = {}
        for start, count in ((0, n + 1), (1, n)):
            t, s, v = get(idx, vr, start, count)
            for ti, si, vi in zip(t, s, v):
                samples[si] = (ti, vi)
        if sorted(samples) != list(range(n + 1)):
            sys.exit(f"{name}: got steps {sorted(samples)[:5]}..{sorted(samples)[-5:]}, expected 0..{n}")
        tt = np.array([samples[k][0] for k in range(n + 1)], dtype=np.int64)
        if time_ns is None:
            time_ns = tt
        result[name] = np.array([samples[k][1] for k in range(n + 1)],
                                dtype=float if typ == "Real" else np.int64)
    if time_ns is None:
        time_ns = np.arange(n + 1, dtype=np.int64) * step_ns
    np.savez(req["result"], time_ns=time_ns, **result)


# ------------------------------------------------------------------------------------------------------------ FMPy

def fmpy_run(fmu_path, step: float, stop: float, start_values: dict | None = None,
             outputs: list[str] | None = None, use_source: bool = False) -> dict:
    """Simulate with FMPy (Co-Simulation) with communication step = output_interval = `step` (always passed:
    FMPy otherwise uses the default experiment's stepSize, doubled until <= 1000 steps).
    use_source=True: rebuild the binary from sources/ first (recompile_from_sources) and run that.
    Returns {"time": t[0..N], name: values}."""
    import numpy as np
    from fmpy import simulate_fmu
    _n_steps(step, stop)
    with contextlib.ExitStack() as stack:
        path = Path(fmu_path)
        if use_source:
            tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="cedra-src-")))
            path = recompile_from_sources(fmu_path, tmp / Path(fmu_path).name)
        md = read_md(path)
        outputs = list(outputs) if outputs is not None else _default_outputs(md)
        with _timed("fmpy_run"):
            res = simulate_fmu(str(path), fmi_type="CoSimulation", start_time=0.0, stop_time=stop,
                               output_interval=step, start_values=dict(start_values or {}), output=outputs,
                               model_description=md)
    return {"time": np.asarray(res["time"], dtype=float),
            **{name: np.asarray(res[name]) for name in outputs}}


def recompile_from_sources(fmu_path, out_path) -> Path:
    """Copy the FMU without binaries/, compile binaries/<platform>/<modelIdentifier>.so from sources/ with
    FMPy's CMake project (fmpy.build.create_cmake_settings + fmpy/c-code/CMakeLists.txt, Release = -O3; FMPy
    0.3.32 has no fmpy.util.compile_platform_binary, its build_platform_binary prints to our stdout, so the two
    cmake calls are made here with their output captured), and zip it to out_path."""
    import fmpy
    from fmpy.build import create_cmake_settings
    out_path = Path(out_path)
    if shutil.which("cmake") is None:
        raise CheckerUnavailable("recompiling from sources needs cmake on PATH")
    with tempfile.TemporaryDirectory(prefix="cedra-recompile-") as tmp:
        unzip, build = Path(tmp) / "fmu", Path(tmp) / "build"
        build.mkdir()
        with zipfile.ZipFile(fmu_path) as z:
            z.extractall(unzip)
        shutil.rmtree(unzip / "binaries", ignore_errors=True)
        md = read_md(unzip)
        if not md.buildConfigurations or not md.buildConfigurations[0].sourceFileSets:
            raise CheckerFailed(f"{fmu_path}: modelDescription lists no <SourceFiles>")
        create_cmake_settings(unzip, build)
        src = Path(fmpy.__file__).parent / "c-code"
        with _timed("recompile"):
            for cmd in (["cmake", "-S", str(src), "-B", str(build)],
                        ["cmake", "--build", str(build), "--target", "install", "--config", "Release"]):
                r = _run_quiet(cmd, "recompile", timeout=900)
                if r.returncode != 0:
                    raise CheckerFailed(f"{' '.join(cmd)} failed:\n{r.stdout[-6000:]}\n{r.stderr[-6000:]}")
        out_path.parent.mkdir(parents=True, exist_ok=True)
        if out_path.exists():
            out_path.unlink()
        with zipfile.ZipFile(out_path, "w", zipfile.ZIP_DEFLATED) as z:
            for p in sorted(unzip.rglob("*")):
                if p.is_file():
                    z.write(p, p.relative_to(unzip).as_posix())
    return out_path


# ---------------------------------------------------------------------------------------- start value round trip

def _xml_start(v):
    if v.type == "Real":
        return float(v.start)
    if v.type in ("Integer", "Enumeration"):
        return int(v.start)
    if v.type == "Boolean":
        return v.start in (True, "true", "1", 1)
    return v.start


def start_value_roundtrip(fmu_path, rtol: float = 1e-14, include_approx: bool = False) -> list[str]:
    """Instantiate the FMU (FMPy FMU2Slave), setupExperiment + enterInitializationMode, then read every variable
    that has a start value back through the binary by its value reference and compare with the XML start.
    Returns the mismatches ([] = all agree). Catches swapped or wrong value references (when the start values
    differ), wrong start values in the XML and types read through the wrong getter; no checker sees these.
    Variables with initial="approx" are skipped unless include_approx (the FMU may iterate on them during
    initialization). Reals compare with relative tolerance rtol (XML printed with %.17g round-trips exactly;
    1e-14 allows a shorter printing); Integer, Boolean, String compare exactly. An FMU that cannot be instantiated
    or initialized (e.g. a GUID that is not the binary's) gives one problem quoting the FMU's log."""
    from fmpy import extract
    from fmpy.fmi1 import calloc, free
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
    md = read_md(fmu_path)
    if md.coSimulation is None:
        raise CheckerFailed("not a Co-Simulation FMU")
    log: list[str] = []           # the FMU's log messages (unformatted), quoted when a call fails

    def logger(env, name, status, category, message):
        log.append((message or b"").decode(errors="replace"))

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)

    def failed(call: str, e: Exception) -> str:
        return f"{call} failed: " + ("; ".join(log) if log else str(e))

    with tempfile.TemporaryDirectory(prefix="cedra-roundtrip-") as tmp, _timed("start_value_roundtrip"):
        unzipdir = extract(str(fmu_path), unzipdir=tmp)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="roundtrip")
        try:
            fmu.instantiate(callbacks=callbacks)
        except Exception as e:   # fmi2Instantiate returned NULL (e.g. a GUID that is not the binary's)
            fmu.freeLibrary()
            return [failed("fmi2Instantiate", e)]
        problems: list[str] = []
        try:
            try:
                fmu.setupExperiment(startTime=0.0)
                fmu.enterInitializationMode()
            except Exception as e:
                return [failed("fmi2SetupExperiment/fmi2EnterInitializationMode", e)]
            for v in md.modelVariables:
                if v.start is None or (v.initial == "approx" and not include_approx):
                    continue
                want = _xml_start(v)
                vr = [v.valueReference]
                try:
                    got = {"Real": fmu.getReal, "Integer": fmu.getInteger, "Enumeration": fmu.getInteger,
                           "Boolean": fmu.getBoolean, "String": fmu.getString}[v.type](vr)[0]
                except Exception as e:   # an fmi2Error for a value reference the binary does not know
                    problems.append(f"{v.name} (vr {v.valueReference}, {v.type}): get failed: {e}")
                    continue
                if v.type == "Real":
                    bad = not (math.isfinite(got) and abs(got - want) <= rtol * max(abs(want), abs(got))) \
                        and not (got == want)
                elif v.type == "Boolean":
                    bad = bool(got) != want
                elif v.type == "String":
                    bad = (got.decode() if isinstance(got, bytes) else got) != want
                else:
                    bad = int(got) != want
                if bad:
                    problems.append(f"{v.name} (vr {v.valueReference}, {v.type}, {v.causality}): "
                                    f"XML start {want!r}, binary {got!r}")
        finally:        # fmi2Terminate is not allowed in initialization mode, fmi2FreeInstance is
            fmu.freeInstance()
    return problems


# ------------------------------------------------------------------------------------------------------ not an FMU

def not_an_fmu(path) -> str | None:
    """Why `path` cannot be checked as an FMU (no such file, not a zip archive, no modelDescription.xml in it),
    or None when it can."""
    path = Path(path)
    if not path.exists():
        return f"{path}: no such file"
    if not path.is_file():
        return f"{path}: not a file"
    if not zipfile.is_zipfile(path):
        return f"{path}: not an FMU (not a zip archive)"
    with zipfile.ZipFile(path) as z:
        if "modelDescription.xml" not in z.namelist():
            return f"{path}: not an FMU (no modelDescription.xml in the archive)"
    return None


# ------------------------------------------------------------------------------------------------------ compare

def compare_runs(a: dict, b: dict, names: list[str] | None = None) -> dict:
    """Max |a-b| and max |a-b|/max(|a|,|b|,1e-300) per output at the common times (matched to 1e-9 s).
    Returns {name: (max_abs, max_rel, n_common)}."""
    import numpy as np
    ta, tb = np.asarray(a["time"]), np.asarray(b["time"])
    ia = {round(t * 1e9): i for i, t in enumerate(ta)}
    pairs = [(ia[round(t * 1e9)], j) for j, t in enumerate(tb) if round(t * 1e9) in ia]
    if not pairs:
        raise ValueError("no common times")
    ja, jb = (np.array(x) for x in zip(*pairs))
    out = {}
    for name in names or [k for k in a if k in b and k not in ("time", "time_ns")]:
        xa, xb = np.asarray(a[name], float)[ja], np.asarray(b[name], float)[jb]
        d = np.abs(xa - xb)
        rel = d / np.maximum(np.maximum(np.abs(xa), np.abs(xb)), 1e-300)
        out[name] = (float(d.max()), float(rel.max()), len(pairs))
    return out


def _main(argv: list[str]) -> int:
    if len(argv) >= 2 and argv[0] == "_libcosim_worker":
        _libcosim_worker(argv[1])
        return 0
    if len(argv) == 2 and argv[0] == "vdmcheck":
        ok, lines = vdmcheck(argv[1])
        print("\n".join(lines))
        return 0 if ok else 1
    if len(argv) == 2 and argv[0] == "validate":
        problems = fmpy_validate(argv[1])
        print("\n".join(problems) or "No problems found.")
        return 1 if problems else 0
    if len(argv) == 2 and argv[0] == "roundtrip":
        problems = start_value_roundtrip(argv[1])
        print("\n".join(problems) or "All start values round-trip.")
        return 1 if problems else 0
    if argv == ["setup-vdmcheck"]:
        print(ensure_vdmcheck())
        return 0
    print(__doc__)
    return 2


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
