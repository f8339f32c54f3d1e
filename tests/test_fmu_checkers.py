"""Independent checkers and importers on a built FMU (see python/cedra/fmu/checks.py).

The FMU under test is the toy model built by the FMU builder (`cedra.fmu.packaging.build_fmu(toy_model.toy_spec())`),
once per test session (shared between pytest-xdist workers through a file lock), or any FMU given by the
environment variable CEDRA_CHECK_FMU (e.g. the rover FMU:
`CEDRA_CHECK_FMU=build/x.fmu pytest tests/test_fmu_checkers.py`).

A checker that cannot run (no java/mvn, no cmake, Maven Central unreachable) makes its test FAIL: CI reaches
the registries, so "unavailable" is a broken setup, not a reason to skip.

libcosim vs FMPy: libcosim passes t = k*step_ns*1e-9 and h = step_ns*1e-9; FMPy passes t = k*step and
h = t_{k+1} - t_k computed in doubles. With a power-of-two step (2**-7 s) both pass identical (t, h) and the
results must agree to 1e-12 (measured: bit-identical); with step 0.01 s FMPy's h carries round-off of
~1e-18 s, so the two are compared with a documented looser bound DECIMAL_STEP_TOL = 1e-10.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cedra.fmu import checks
from fmu_harness import rewrite_md

POW2_STEP = 2.0 ** -7        # 7 812 500 ns: libcosim and FMPy hand the FMU bit-identical t and h
DECIMAL_STEP = 0.01          # FMPy's h = t_{k+1} - t_k carries round-off here
TOL = 1e-12                  # relative + absolute, identical h
DECIMAL_STEP_TOL = 1e-10     # relative + absolute, h differing by round-off (measured ~1e-16 on toy models)
STOP = 1.0                   # simulated time of the comparison runs (a whole number of both steps)


# -------------------------------------------------------------------------------------------------- fixtures

def _build_toy(out_dir: Path) -> Path:
    from cedra.fmu.packaging import build_fmu
    from toy_model import toy_spec
    return Path(build_fmu(toy_spec(), out_dir))


@pytest.fixture(scope="session")
def fmu(tmp_path_factory) -> Path:
    """The FMU under test: $CEDRA_CHECK_FMU, or the toy FMU built once for all xdist workers."""
    given = os.environ.get("CEDRA_CHECK_FMU")
    if given:
        path = Path(given).resolve()
        assert path.is_file(), f"CEDRA_CHECK_FMU={given} does not exist"
        return path
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return _build_toy(tmp_path_factory.mktemp("toy_fmu"))
    shared = tmp_path_factory.getbasetemp().parent / "toy_fmu_shared"
    with checks.file_lock(shared.with_suffix(".lock")):
        done = shared / "fmu_path.txt"
        if done.exists():
            return Path(done.read_text())
        shared.mkdir(exist_ok=True)
        path = _build_toy(shared / "build")
        done.write_text(str(path))
        return path


@pytest.fixture(scope="session")
def md(fmu):
    from fmpy import read_model_description
    return read_model_description(str(fmu), validate=False)


def _agree(a: dict, b: dict, names: list[str], tol: float) -> list[str]:
    """Outputs that differ by more than tol*(1+|b|) at common times (times must match exactly)."""
    assert len(a["time"]) == len(b["time"]), (len(a["time"]), len(b["time"]))
    assert np.allclose(a["time"], b["time"], rtol=0, atol=1e-12)
    bad = []
    for n in names:
        xa, xb = np.asarray(a[n], float), np.asarray(b[n], float)
        err = np.abs(xa - xb) - tol * (1.0 + np.abs(xb))
        if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(xb))) or np.any(err > 0):
            k = int(np.nanargmax(err)) if np.any(np.isfinite(err)) else 0
            bad.append(f"{n}: at t={a['time'][k]:.9g} {xa[k]!r} vs {xb[k]!r} (|d|={abs(xa[k] - xb[k]):.3g})")
    return bad


def _outputs(md) -> list[str]:
    return [v.name for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Integer")]


def _perturbed_inputs(md) -> dict:
    """Every Real input set to a value near (but different from) its start, so setting by value reference is
    exercised in both importers."""
    out = {}
    for v in md.modelVariables:
        if v.causality == "input" and v.type == "Real" and v.start is not None:
            s = float(v.start)
            val = s + 0.01 * (abs(s) + 1.0)
            if v.max is not None and val > float(v.max):
                val = s - 0.01 * (abs(s) + 1.0)
            out[v.name] = val
    return out


# -------------------------------------------------------------------------------------------------- checkers

def test_fmpy_validate(fmu):
    problems = checks.fmpy_validate(fmu)
    assert problems == [], "\n".join(problems)


def test_vdmcheck(fmu):
    ok, lines = checks.vdmcheck(fmu)
    print(f"VDMCheck2: {checks.TIMINGS.get('vdmcheck', 0):.2f} s "
          f"(setup {checks.TIMINGS.get('vdmcheck_setup', 0):.1f} s if it ran here)")
    assert ok, "VDMCheck2 errors:\n" + "\n".join(lines)


def test_start_values_roundtrip(fmu):
    mismatches = checks.start_value_roundtrip(fmu)
    assert mismatches == [], "\n".join(mismatches)


@pytest.mark.parametrize("step,tol", [(POW2_STEP, TOL), (DECIMAL_STEP, DECIMAL_STEP_TOL)],
                         ids=["pow2-step", "decimal-step"])
def test_libcosim_agrees_with_fmpy(fmu, md, step, tol):
    outputs, inputs = _outputs(md), _perturbed_inputs(md)
    assert outputs, "the FMU has no Real/Integer outputs"
    a = checks.libcosim_run(fmu, step, STOP, inputs=inputs, outputs=outputs)
    b = checks.fmpy_run(fmu, step, STOP, start_values=inputs, outputs=outputs)
    diff = checks.compare_runs(a, b, outputs)
    print(f"step {step}: libcosim vs FMPy max abs/rel per output: {diff}")
    bad = _agree(a, b, outputs, tol)
    assert not bad, f"libcosim and FMPy disagree (step {step}, tol {tol}):\n" + "\n".join(bad)
    if step == POW2_STEP:
        # identical (t, h) go into the FMU: anything but bit-identical means state leaks between calls
        assert all(d[0] == 0.0 for d in diff.values()), diff


def test_recompiled_from_sources_matches_binary(fmu, md, tmp_path):
    rebuilt = checks.recompile_from_sources(fmu, tmp_path / Path(fmu).name)
    with zipfile.ZipFile(rebuilt) as z:
        assert any(n.startswith("binaries/linux64/") and n.endswith(".so") for n in z.namelist())
    outputs = _outputs(md)
    a = checks.fmpy_run(fmu, POW2_STEP, STOP, outputs=outputs)
    b = checks.fmpy_run(rebuilt, POW2_STEP, STOP, outputs=outputs)
    diff = checks.compare_runs(a, b, outputs)
    print(f"shipped vs recompiled (Release -O3) binary: {diff}")
    bad = _agree(a, b, outputs, TOL)
    assert not bad, "recompiled FMU differs:\n" + "\n".join(bad)


# ------------------------------------------------------------------------------------- negative: checks can fail

def _drop_one_output(root):
    outs = root.find("ModelStructure/Outputs")
    assert outs is not None and len(outs), "FMU has no Outputs to break"
    outs.remove(outs[-1])


def test_vdmcheck_and_fmpy_catch_broken_outputs(fmu, tmp_path):
    bad = rewrite_md(fmu, tmp_path / "broken_outputs.fmu", _drop_one_output)
    ok, lines = checks.vdmcheck(bad)
    assert not ok
    assert any(ln.startswith("validOutputs:") for ln in checks.vdmcheck_errors(lines)), lines
    problems = checks.fmpy_validate(bad)
    assert any("Outputs" in p for p in problems), problems


def test_roundtrip_catches_swapped_value_references(fmu, md, tmp_path):
    # two variables of one type whose start values differ: swap their value references in the XML only
    cands = [v for v in md.modelVariables
             if v.start is not None and v.initial != "approx" and v.type in ("Real", "Integer")]
    pair = next(((a, b) for i, a in enumerate(cands) for b in cands[i + 1:]
                 if a.type == b.type and float(a.start) != float(b.start)), None)
    if pair is None:     # fall back: a start value the binary does not have
        target = cands[0]

        def edit(root):
            sv = root.find(f"ModelVariables/ScalarVariable[@name='{target.name}']")
            el = sv[0]
            el.set("start", str(float(el.get("start")) * 2 + 1) if target.type == "Real"
                   else str(int(el.get("start")) * 2 + 1))
        names = {target.name}
    else:
        a, b = pair

        def edit(root):
            sa = root.find(f"ModelVariables/ScalarVariable[@name='{a.name}']")
            sb = root.find(f"ModelVariables/ScalarVariable[@name='{b.name}']")
            va, vb = sa.get("valueReference"), sb.get("valueReference")
            sa.set("valueReference", vb)
            sb.set("valueReference", va)
        names = {a.name, b.name}
    bad = rewrite_md(fmu, tmp_path / "swapped_vrs.fmu", edit)
    mismatches = checks.start_value_roundtrip(bad)
    assert {m.split(" ")[0] for m in mismatches} == names, mismatches
    # ... while neither checker sees anything wrong with the swapped table
    assert checks.fmpy_validate(bad) == []


def test_libcosim_failure_raises_with_stderr(fmu, tmp_path):
    # a modelIdentifier with no binaries/linux64/<id>.so: libcosim fails (or aborts) in the subprocess
    def edit(root):
        root.find("CoSimulation").set("modelIdentifier", "no_such_model")
    bad = rewrite_md(fmu, tmp_path / "wrong_identifier.fmu", edit)
    with pytest.raises(checks.CheckerFailed, match="libcosim run failed"):
        checks.libcosim_run(bad, POW2_STEP, POW2_STEP * 4)


def test_vdmcheck_is_set_up_in_the_cache():
    dist = checks.ensure_vdmcheck()
    assert dist.is_relative_to(checks.tools_cache())
    for jar in ("vdmcheck2.jar", "vdmj.jar", "annotations.jar", "xsd2vdm.jar", "fmuReader.jar"):
        assert (dist / jar).is_file(), jar
    for folder in ("fmi2-rule-model", "fmi2-static-model", "fmi2schema"):
        assert (dist / folder).is_dir(), folder
