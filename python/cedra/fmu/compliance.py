"""`python -m cedra check FMU ...`: the FMU compliance checkers run over any FMI 2.0 Co-Simulation FMUs, one verdict
per FMU and checker, then a summary; the exit status is 1 on any error or warning.

    fmpy-validate   FMPy's validation of modelDescription.xml (schema, names, ModelStructure, start values, units)
    vdmcheck2       VDMCheck2 (INTO-CPS, a VDM-SL model of the FMI 2.0 rules): its errors, and its warnings
    roundtrip       every start value read back through the binary by value reference (cedra.fmu.checks)
    libcosim        a short run in OSP libcosim and the same run in FMPy: the outputs must agree

The checks of the binary (roundtrip, libcosim) run in a process of their own, so an FMU that crashes fails its
check and nothing else; the checks of the XML run in the command's process (FMPy) or in VDMCheck2's JVM. Up to
`--jobs` checks run at once, in any order; the verdicts print in the order of the command line.

VDMCheck2 takes one file per run (`vdmcheck2.jar [-v <VDM out>] -x <XML> | <file>.fmu | <file>.xml`), and a run
starts two JVMs (its own, then VDMJ on the generated VDM-SL), so each FMU pays for both; the runs of several FMUs
go in parallel, each with a scratch folder of its own. Putting several FMUs into one VDMJ evaluation would need a
Java launcher of our own around its classes: not done.

Other FMI 2.0 checkers looked at on the package registries:
- the FMI Standard's FMUComplianceChecker (fmuCheck): on no registry (GitHub release archives only), and
  discontinued;
- FMPy's `fmpy validate` is fmpy-validate here; VDMCheck2 (org.into-cps.vdmcheck.fmi2 on Maven Central) is vdmcheck2;
- fmu-manipulation-toolbox (PyPI, maintained, pure Python): its checker is an XSD validation (xmlschema) and a
  semantic check of names, value references, causality/variability/initial/start and ModelStructure, a subset
  of what fmpy-validate and VDMCheck2 check: not added;
- crates.io's rust-fmi (`fmi`, `fmi-schema`, `fmi-sim`): a reader and a simulator, no checker;
- OMSimulator (PyPI) and PyFMI: importers, not checkers (PyFMI's PyPI release is from 2018).
"""
from __future__ import annotations

import contextlib
import importlib.util
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from cedra.fmu import checks

CHECKERS = ("fmpy-validate", "vdmcheck2", "roundtrip", "libcosim")
IN_SUBPROCESS = ("roundtrip", "libcosim")           # the checks that load the FMU's binary
TASK_TIMEOUT = 600.0                                # s, one check of one FMU

# The libcosim run: the FMU's DefaultExperiment stepSize rounded down to a power of two seconds (libcosim counts
# time in integer nanoseconds, and 2**-k s for k <= 9 is a whole number of them, so both importers hand the FMU the
# same t and h and the outputs must agree to LIBCOSIM_TOL), at most LIBCOSIM_STEPS steps and not past the
# DefaultExperiment's stopTime. A step below 2**-9 s is taken as it is, to the nanosecond, with LIBCOSIM_TOL_ROUNDED
# (FMPy's h = t_(k+1) - t_k then carries round-off).
LIBCOSIM_STEPS = 32
LIBCOSIM_DEFAULT_STEP = 2.0 ** -7
LIBCOSIM_TOL = 1e-12                 # |libcosim - FMPy| <= tol (1 + |FMPy|), every output, every sample
LIBCOSIM_TOL_ROUNDED = 1e-9


@dataclass
class Verdict:
    """One checker's verdict on one FMU. status: ok, warn (warnings only), fail (errors), unavailable (the checker
    cannot run here: an error), skipped (--skip)."""
    fmu: str
    checker: str
    status: str
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    note: str = ""


# ------------------------------------------------------------------------------------------------ the checkers

def _fmpy_validate(fmu: str) -> dict:
    return {"errors": checks.fmpy_validate(fmu)}


def _vdmcheck2(fmu: str) -> dict:
    ok, lines = checks.vdmcheck(fmu)
    warnings = checks.vdmcheck_warnings(lines)
    if ok:
        return {"errors": [], "warnings": warnings}
    return {"errors": checks.vdmcheck_errors(lines) or [ln for ln in lines if ln not in warnings] or lines,
            "warnings": warnings}


def _roundtrip(fmu: str) -> dict:
    return {"errors": checks.start_value_roundtrip(fmu)}


def libcosim_experiment(md) -> tuple[float, int, float]:
    """(step, number of steps, tolerance) of the libcosim-against-FMPy run of an FMU (see LIBCOSIM_STEPS)."""
    de = md.defaultExperiment
    start = float(de.startTime) if de is not None and de.startTime is not None else 0.0
    stop = float(de.stopTime) - start if de is not None and de.stopTime is not None else None
    h = float(de.stepSize) if de is not None and de.stepSize is not None else None
    if not h or not math.isfinite(h) or h <= 0:
        h = min(LIBCOSIM_DEFAULT_STEP, stop / LIBCOSIM_STEPS) if stop and stop > 0 else LIBCOSIM_DEFAULT_STEP
    if h >= 2.0 ** -9:
        step, tol = 2.0 ** math.floor(math.log2(h)), LIBCOSIM_TOL
    else:
        step, tol = max(round(h * 1e9), 1) * 1e-9, LIBCOSIM_TOL_ROUNDED
    n = LIBCOSIM_STEPS
    if stop is not None and stop > 0:
        n = max(1, min(n, math.floor(stop / step + 1e-9)))
    return step, n, tol


def _perturbed_inputs(md) -> dict:
    """Every Real input with a start value set a little off its start (within its min and max), so that both
    importers set inputs by value reference before initialization."""
    out = {}
    for v in md.modelVariables:
        if v.causality != "input" or v.type != "Real" or v.start is None:
            continue
        s = float(v.start)
        d = 0.01 * (abs(s) + 1.0)
        lo = float(v.min) if v.min is not None else -math.inf
        hi = float(v.max) if v.max is not None else math.inf
        val = s + d if s + d <= hi else s - d
        if lo <= val <= hi:
            out[v.name] = val
    return out


def _first_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[0] if lines else text


def _libcosim(fmu: str) -> dict:
    import numpy as np
    md = checks.read_md(fmu)
    step, n, tol = libcosim_experiment(md)
    outputs = [v.name for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Integer")]
    inputs = _perturbed_inputs(md)
    note = f"{n} steps of {step:g} s, {len(outputs)} outputs"
    try:
        a = checks.libcosim_run(fmu, step, n * step, inputs=inputs, outputs=outputs)
    except checks.CheckerFailed as e:
        return {"errors": [f"libcosim: {line}" for line in _libcosim_reasons(str(e))], "note": note}
    try:
        b = checks.fmpy_run(fmu, step, n * step, start_values=inputs, outputs=outputs)
    except Exception as e:       # noqa: BLE001  (FMPy refusing the FMU is this check's failure)
        return {"errors": [f"FMPy: {type(e).__name__}: {_first_line(str(e))}"], "note": note}
    errors = []
    if len(a["time"]) != len(b["time"]) or not np.allclose(a["time"], b["time"], rtol=0, atol=1e-12):
        errors.append(f"libcosim gives {len(a['time'])} samples, FMPy {len(b['time'])}")
    else:
        for name in outputs:
            xa, xb = np.asarray(a[name], float), np.asarray(b[name], float)
            excess = np.abs(xa - xb) - tol * (1.0 + np.abs(xb))
            if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(xb))) or np.any(excess > 0):
                k = int(np.nanargmax(excess)) if np.any(np.isfinite(excess)) else 0
                errors.append(f"{name}: libcosim {xa[k]!r}, FMPy {xb[k]!r} at t = {a['time'][k]:.9g} s "
                              f"(tolerance {tol:g} (1 + |FMPy|))")
    return {"errors": errors, "note": note}


_LOG_PREFIX = re.compile(r"^\[[^\]]*\] \[0x[0-9a-f]+\] \[(\w+)\]\s*")     # libcosim's [time] [thread] [level]


def _libcosim_reasons(message: str) -> list[str]:
    """Why a libcosim run failed, out of its stderr: libcosim's error log lines (its own words and the FMU's,
    without the time stamp), then the rest that is not a traceback's frame."""
    errors, rest = [], []
    for ln in message.splitlines()[1:]:
        m = _LOG_PREFIX.match(ln)
        if m:
            if m[1] in ("error", "fatal"):
                errors.append(ln[m.end():].strip())
        elif ln.strip() and not ln.startswith((" ", "Traceback")):
            rest.append(ln.strip())
    return errors + rest or [_first_line(message)]


RUN = {"fmpy-validate": _fmpy_validate, "vdmcheck2": _vdmcheck2, "roundtrip": _roundtrip, "libcosim": _libcosim}


def unavailable(checker: str) -> str | None:
    """Why the checker cannot run on this machine, or None when it can (VDMCheck2 is set up here on first use)."""
    if checker in ("fmpy-validate", "roundtrip") and importlib.util.find_spec("fmpy") is None:
        return "fmpy is not installed"
    if checker == "libcosim" and importlib.util.find_spec("libcosimpy") is None:
        return "libcosimpy is not installed (pip install libcosimpy)"
    if checker == "vdmcheck2":
        try:
            checks.ensure_vdmcheck()
        except checks.CheckerUnavailable as e:
            lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
            cause = next((ln for ln in lines[1:] if "ERROR" in ln), None)      # Maven's first error, if any
            return lines[0] + (f" {cause}" if cause else "") if lines else str(e)
    return None


# --------------------------------------------------------------------------------------------------- running

def _run_here(checker: str, fmu: str) -> dict:
    """One check, in this process: {"errors", "warnings", "note"}. A crash of the checker is its error."""
    try:
        return RUN[checker](fmu)
    except checks.CheckerUnavailable as e:
        return {"unavailable": _first_line(str(e))}
    except Exception as e:       # noqa: BLE001  (any failure of the checker or the FMU is this check's failure)
        return {"errors": [f"{type(e).__name__}: {_first_line(str(e))}"]}


def _run_isolated(checker: str, fmu: str) -> dict:
    """One check in a Python process of its own (an FMU that crashes or hangs fails this check only)."""
    with tempfile.TemporaryDirectory(prefix="cedra-check-") as tmp:
        out = Path(tmp) / "verdict.json"
        cmd = [sys.executable, "-m", "cedra.fmu.compliance", "_task", checker, str(Path(fmu).resolve()), str(out)]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(Path(__file__).resolve().parents[2]), os.environ.get("PYTHONPATH", "")]))
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=TASK_TIMEOUT, env=env, cwd=tmp)
        except subprocess.TimeoutExpired:
            return {"errors": [f"no verdict within {TASK_TIMEOUT:g} s"]}
        if out.exists():
            return json.loads(out.read_text())
        how = f"exit status {r.returncode}"
        if r.returncode < 0:
            import signal
            with contextlib.suppress(ValueError):
                how = f"killed by {signal.Signals(-r.returncode).name}"
        tail = [ln for ln in r.stderr.splitlines() if ln.strip()][-1:]
        return {"errors": [f"the check's process ended without a verdict ({how})" + (f": {tail[0]}" if tail else "")]}


def run_one(checker: str, fmu: str) -> Verdict:
    t0 = time.perf_counter()
    res = _run_isolated(checker, fmu) if checker in IN_SUBPROCESS else _run_here(checker, fmu)
    seconds = time.perf_counter() - t0
    if "unavailable" in res:
        return Verdict(fmu, checker, "unavailable", errors=[res["unavailable"]], seconds=seconds)
    errors, warnings = list(res.get("errors", [])), list(res.get("warnings", []))
    status = "fail" if errors else "warn" if warnings else "ok"
    return Verdict(fmu, checker, status, errors, warnings, seconds, res.get("note", ""))


def run(fmus: list[str], skip: tuple[str, ...] = (), jobs: int = 2, on_verdicts=None) -> list[Verdict]:
    """Every checker not in `skip` on every FMU, `jobs` at once. on_verdicts(list of one FMU's verdicts) is called
    for each FMU in the order of `fmus`, as soon as its verdicts are in."""
    active = [c for c in CHECKERS if c not in skip]
    missing = {c: why for c in active if (why := unavailable(c))}
    out: list[Verdict] = []
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        # each FMU's longest checks first (VDMCheck2's two JVMs, then the two importers' runs), so that the short
        # ones fill in behind them
        order = sorted((c for c in active if c not in missing), key=("vdmcheck2", "libcosim").__contains__,
                       reverse=True)
        futures = {(f, c): pool.submit(run_one, c, f) for f in fmus for c in order}
        for f in fmus:
            verdicts = []
            for c in CHECKERS:
                if c in skip:
                    verdicts.append(Verdict(f, c, "skipped"))
                elif c in missing:
                    verdicts.append(Verdict(f, c, "unavailable", errors=[missing[c]]))
                else:
                    verdicts.append(futures[(f, c)].result())
            out.extend(verdicts)
            if on_verdicts:
                on_verdicts(verdicts)
    return out


# --------------------------------------------------------------------------------------------------- output

def verdict_line(v: Verdict, width: int, verbose: bool = False) -> str:
    """`<fmu>  <checker>  <verdict>`: ok (time), FAIL / WARN with the checker's first message, unavailable: why,
    skipped. Verbose: every error and warning on an indented line below."""
    head = f"{v.fmu:<{width}}  {v.checker:<{max(map(len, CHECKERS))}}"
    if v.status == "skipped":
        return f"{head}  skipped (--skip)"
    if v.status == "unavailable":
        return f"{head}  unavailable: {v.errors[0]}"
    took = f"({v.seconds:.1f} s)"
    if v.status == "ok":
        line = f"{head}  ok  {took}"
    else:
        problems = v.errors if v.status == "fail" else v.warnings
        more = len(v.errors) + len(v.warnings) - 1
        line = (f"{head}  {'FAIL' if v.status == 'fail' else 'WARN'}  {took}  {problems[0]}"
                + (f" (+{more} more, -v)" if more and not verbose else ""))
    if verbose:
        line += "".join(f"\n    error: {e}" for e in v.errors) + "".join(f"\n    warning: {w}" for w in v.warnings)
    return line


def summary_line(verdicts: list[Verdict], n_fmus: int, seconds: float) -> str:
    count = {s: sum(v.status == s for v in verdicts) for s in ("ok", "warn", "fail", "unavailable", "skipped")}
    checkers = len({v.checker for v in verdicts if v.status != "skipped"})
    return (f"{n_fmus} FMU{'s' * (n_fmus != 1)}, {checkers} checker{'s' * (checkers != 1)}: {count['ok']} passed, "
            f"{count['warn']} with warnings, {count['fail'] + count['unavailable']} with errors"
            + (f", {count['skipped']} skipped" if count["skipped"] else "") + f" ({seconds:.1f} s)")


def main(args) -> int:
    """The command: exit status 0 when every verdict is ok (or skipped), 1 on any error or warning, 2 when a path
    is not an FMU (every path is looked at before the first check runs)."""
    bad = [why for why in map(checks.not_an_fmu, args.fmus) if why]
    if bad:
        for why in bad:
            print(f"error: {why}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    width = max(map(len, args.fmus))

    def show(verdicts):
        for v in verdicts:
            print(verdict_line(v, width, args.verbose), flush=True)

    jobs = args.jobs or min(os.cpu_count() or 1, 8)
    verdicts = run(list(args.fmus), tuple(args.skip or ()), jobs, show)
    print(summary_line(verdicts, len(args.fmus), time.perf_counter() - t0))
    return 0 if all(v.status in ("ok", "skipped") for v in verdicts) else 1


def add_arguments(p) -> None:
    p.add_argument("fmus", nargs="+", metavar="FMU", help=".fmu files (any FMI 2.0 Co-Simulation FMU)")
    p.add_argument("-v", "--verbose", action="store_true", help="every error and warning of each check, not the "
                   "first")
    p.add_argument("--skip", action="append", choices=CHECKERS, metavar="CHECKER",
                   help=f"leave this checker out (repeatable): {', '.join(CHECKERS)}")
    p.add_argument("--jobs", type=int, default=0, help="checks run at once (default: one per CPU core, at most 8)")


def _task(checker: str, fmu: str, out: str) -> None:
    Path(out).write_text(json.dumps(_run_here(checker, fmu)))


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "_task":
        _task(*sys.argv[2:])
    else:
        sys.exit(__doc__)
