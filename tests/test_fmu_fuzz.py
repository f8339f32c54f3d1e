"""Sanitizer fuzzing of the shipped FMUs' C (python -m cedra fuzz, tools/fuzz/fmu_fuzz.c): random fmi2 call
sequences, valid and invalid mixed, against bump2d (2D) and flat3d (3D) compiled with AddressSanitizer and
UndefinedBehaviorSanitizer, a short wall-time budget each; any finding fails with its seed (replay:
`python -m cedra fuzz <scene> --seed S --sequences 1 --trace`). And bugs planted in the fuzzer's calls, which it
must report, so a green run means something.

The classes of glue bugs these runs guard against: setters that are not all-or-nothing, a DoStep that returns OK
without advancing, calls that do not return; a finding is a failure, never a skip.

Environment: CEDRA_FUZZ_SECONDS (default 20) per scene, CEDRA_FUZZ_SEED (default 1)."""
from __future__ import annotations

import os

import pytest

from cedra.fmu import fuzz

SECONDS = float(os.environ.get("CEDRA_FUZZ_SECONDS", "20"))
SEED = int(os.environ.get("CEDRA_FUZZ_SEED", "1"))


@pytest.fixture(scope="module")
def bump2d():
    fmu = fuzz.resolve_fmu("bump2d")
    fuzz.build(fmu)             # the compile is not part of the budget
    return fmu


@pytest.mark.parametrize("scene", ["bump2d", "flat3d"])
def test_fuzz_finds_nothing(scene):
    fmu = fuzz.resolve_fmu(scene)
    fuzz.build(fmu)
    res = fuzz.fuzz(fmu, scene, seed=SEED, seconds=SECONDS, call_limit=10.0)
    print(res.report())
    assert not res.findings, res.report()
    assert res.sequences >= 100 and res.steps_ok >= 100, res.summary()   # the budget ran sequences that stepped


def test_planted_step_that_does_not_advance_is_found_and_replays(bump2d):
    """fmi2DoStep returning OK without stepping (the fuzzer's call is replaced): invariant (d); the finding's seed
    alone reproduces it."""
    res = fuzz.fuzz(bump2d, "bump2d", seed=1, sequences=40, call_limit=2.0, defines=("FUZZ_PLANT_NOOP_STEP",))
    planted = [f for f in res.findings if f.text.startswith("(d)") and "fmi2LastSuccessfulTime" in f.text]
    assert planted, res.report()
    again = fuzz.fuzz(bump2d, "bump2d", seed=planted[0].seed, sequences=1, defines=("FUZZ_PLANT_NOOP_STEP",))
    assert any(f.call == planted[0].call and f.text == planted[0].text for f in again.findings), again.report()


def test_planted_buffer_overflow_is_a_sanitizer_finding(bump2d):
    """fmi2GetReal writing one value past the caller's array: AddressSanitizer aborts, the runner names the
    sequence and the call, and goes on with the next seed."""
    res = fuzz.fuzz(bump2d, "bump2d", seed=1, sequences=10, defines=("FUZZ_PLANT_OVERFLOW",))
    hits = [f for f in res.findings if "heap-buffer-overflow" in f.text]
    assert hits and hits[0].call is not None and "fmi2GetReal" in hits[0].text, res.report()
    assert res.processes > 1 and res.sequences == 10, res.summary()


def test_planted_partial_set_is_found(bump2d):
    """fmi2SetReal applying a vector up to its bad entry and then refusing it: invariant (e) names the changed
    variable."""
    res = fuzz.fuzz(bump2d, "bump2d", seed=1, sequences=60, call_limit=2.0, defines=("FUZZ_PLANT_PARTIAL_SET",))
    assert any(f.text.startswith("(e)") and "[in fmi2SetReal" in f.text and "(tau[" in f.text
               for f in res.findings), res.report()
