"""What an importer can rely on, checked on the toy FMU: no step that returns fmi2OK without integrating, a
bounded cost per fmi2DoStep, time that must advance, all-or-nothing setters, checked deserialized states, the
importer's tolerance. (tests/test_fmu_misuse.py runs the misuse matrix on every shipped FMU.)"""
from __future__ import annotations

import ctypes
import math
import struct

import pytest

from fmu_harness import Toy
from misuse_matrix import with_checksum

DRIVE = {"F": 8.0}


def serialized(inst) -> bytes:
    state = inst.slave.getFMUState()
    try:
        return bytes(inst.slave.serializeFMUState(state))
    finally:
        inst.slave.freeFMUState(state)


def replace_double(blob: bytes, old: float, new: float) -> bytes:
    """The first copy of `old` replaced (the state's fields come before their copies: time before last_good_time,
    x before the outputs y, inputs before y, solver settings before the counters' h_next)."""
    key = struct.pack("<d", old)
    assert key in blob, f"{old} is not in the state"
    return blob.replace(key, struct.pack("<d", new), 1)


# ------------------------------------------------------------------------------ 1. no silent no-op step

@pytest.mark.parametrize("h_max,step", [(1e-300, 0.5), (0.002, 1e300), (1e-8, 0.01)])
def test_rk4_step_that_cannot_fit_the_budget_is_refused_unchanged(inst, h_max, step):
    inst.start({"solver.method": 0, "solver.h_max": h_max, **DRIVE})
    before = serialized(inst)
    assert inst.step(step) == "error"
    msg = inst.messages("error")[-1]
    assert msg.startswith("fmi2DoStep: refused: rk4: the interval of") and "more than solver.max_steps = 100000" in msg
    assert serialized(inst) == before                       # time, state and counters as they were
    assert inst.get("solver.steps") == 0
    assert inst.step(0.01) == ("ok" if h_max >= 1e-3 else "error")   # refused again, or a sensible step works


def test_a_deserialized_state_with_a_tiny_rk4_step_is_refused_at_the_step(toy, inst):
    inst.start({"solver.method": 0, "solver.h_max": 1e-300, **DRIVE})
    blob = serialized(inst)
    other = Toy(toy, name="other")
    try:
        other.start(DRIVE)
        st = other.slave.deSerializeFMUstate(blob)
        other.slave.setFMUState(st)
        other.slave.freeFMUState(st)
        assert other.get("solver.h_max") == 1e-300
        assert other.step(0.5) == "error"
        assert "needs at least 5e+299 steps" in other.messages("error")[-1]
        assert other.get("solver.steps") == 0
    finally:
        other.close()


def test_every_ok_step_integrates_the_whole_interval(inst):
    inst.start({"solver.method": 0, "solver.h_max": 0.001, **DRIVE})
    for k in range(1, 6):
        steps = inst.get("solver.steps")
        assert inst.step(0.0105) == "ok"
        assert inst.get("solver.steps") - steps == 11          # ceil(0.0105 / 0.001)
        from fmpy.fmi2 import fmi2LastSuccessfulTime
        assert inst.slave.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(0.0105 * k, abs=1e-15)


# ------------------------------------------------------------------------------ 2. a bounded cost per call

def test_budget_parameters_are_in_the_interface(inst):
    assert inst.vars["solver.max_steps"].type == "Integer"
    assert inst.vars["solver.max_wall_time"].unit == "s"
    inst.start(exit_init=False)
    assert inst.get("solver.max_steps") == 100000 and inst.get("solver.max_wall_time") == 1.0
    for name, value, reason in (("solver.max_steps", 0, "= 0 must be >= 1"),
                                ("solver.max_wall_time", 0.0, "= 0 must be > 0"),
                                ("solver.max_wall_time", 1e7, "must be <= 1000000"),
                                ("solver.max_wall_time", math.inf, "= inf is not finite")):
        fn = "setInteger" if isinstance(value, int) else "setReal"
        assert inst.call(fn, [inst.vr(name)], [value]) == "error"
        assert reason in inst.messages("error")[-1]


STIFF_AND_TIGHT = {"solver.method": 1, "solver.h_max": 1.0, "solver.tol": 1e-12, "ground_k": 1e9, "ground_d": 1e2,
                   "F": 0.0, "start.speed.z": -1.0}   # DOPRI5 on a very stiff ground, hit at 1 m/s: many tiny steps


def test_a_step_that_spends_its_step_budget_is_discarded_with_the_reason(inst):
    from fmpy.fmi2 import fmi2Terminated
    inst.start({**STIFF_AND_TIGHT, "solver.max_steps": 500})
    before = {k: v for k, v in inst.outputs().items() if not k.startswith("solver.")}
    assert inst.step(1.0) == "discard"
    msg = inst.messages("discard")[-1]
    assert "too many steps (more than solver.max_steps = 500 in one call)" in msg, msg
    assert inst.slave.getBooleanStatus(fmi2Terminated) is True
    assert {k: v for k, v in inst.outputs().items() if not k.startswith("solver.")} == before


def test_a_step_that_spends_its_wall_clock_budget_is_discarded_with_the_reason(inst):
    inst.start({**STIFF_AND_TIGHT, "solver.max_steps": 2**31 - 1, "solver.max_wall_time": 1e-4})
    assert inst.step(100.0) == "discard"
    msg = inst.messages("discard")[-1]
    assert "the call's wall-clock budget of 0.0001 s is spent" in msg and "solver.max_wall_time" in msg, msg


# ------------------------------------------------------------------------------ 3. time that cannot advance

def test_a_start_time_where_steps_cannot_be_resolved_is_refused(inst):
    inst.instantiate()
    assert inst.call("setupExperiment", startTime=1e300) == "error"
    assert inst.messages("error")[-1].startswith("fmi2SetupExperiment: startTime = 1e+300 is beyond +-1e+09 s")
    assert inst.call("setupExperiment", startTime=1e9) == "ok"


def test_a_step_below_the_time_resolution_is_refused(inst):
    inst.instantiate()
    inst.slave.setupExperiment(startTime=1e6)
    inst.slave.enterInitializationMode()
    inst.slave.exitInitializationMode()
    inst.time = 1e6
    before = serialized(inst)
    assert inst.step(1e-7) == "error"               # resolution at 1e6 s: 1e-6 s
    assert "is below the time resolution 1e-06 s at t=1000000" in inst.messages("error")[-1]
    assert serialized(inst) == before
    assert inst.step(0.01) == "ok"


# ------------------------------------------------------------------------------ 4. all-or-nothing setters

def test_a_refused_vector_set_writes_nothing(inst):
    inst.start(DRIVE, exit_init=False)
    before = serialized(inst)
    assert inst.call("setReal", [inst.vr("F"), inst.vr("mu")], [3.0, float("nan")]) == "error"
    assert inst.messages("error")[-1] == f"fmi2SetReal: variable mu (vr {inst.vr('mu')}) = nan is not finite"
    assert inst.get("F") == 8.0
    assert serialized(inst) == before
    # an unknown reference later in the vector: nothing written either
    assert inst.call("setReal", [inst.vr("F"), 9999], [3.0, 1.0]) == "error"
    assert inst.get("F") == 8.0 and serialized(inst) == before


# ------------------------------------------------------------------------------ 5. checked deserialized states

def test_a_random_body_is_refused_by_its_checksum(inst):
    inst.start(DRIVE)
    inst.run(0.03, 0.01)
    blob = bytearray(serialized(inst))
    blob[100:140] = bytes(range(40))
    with pytest.raises(Exception):
        inst.slave.deSerializeFMUstate(bytes(blob))
    assert "the checksum does not match the bytes" in inst.messages("error")[-1]


@pytest.mark.parametrize("field,value,reason", [
    ("time", math.nan, "a time is not finite"),
    ("h_max", -1.0, "its solver.h_max = -1 must be > 0"),
    ("F", 2e4, "its F = 20000 must be <= 10000"),
    ("x", math.inf, "the state x or the outputs are not finite"),
])
def test_a_state_with_a_valid_checksum_but_impossible_contents_is_refused(inst, field, value, reason):
    inst.start({"solver.h_max": 0.00123456789, "F": 7.654321})
    inst.run(0.03, 0.01)
    blob = serialized(inst)
    old = {"time": inst.time, "h_max": 0.00123456789, "F": 7.654321, "x": inst.get("pos.x")}[field]
    bad = with_checksum(replace_double(blob, old, value))
    assert with_checksum(blob) == blob                  # the test's checksum is the FMU's
    with pytest.raises(Exception):
        inst.slave.deSerializeFMUstate(bad)
    assert inst.messages("error")[-1] == f"fmi2DeSerializeFMUstate: refused, {reason}"


def test_set_fmu_state_checks_the_contents_too(inst):
    inst.start(DRIVE)
    state = inst.slave.getFMUState()
    raw = ctypes.cast(state, ctypes.POINTER(ctypes.c_ubyte))
    phase_offset = 4 + 4 + 64                           # magic, size, guid[64]
    raw[phase_offset] = 0x60                            # two phases at once: not a phase of this FMU
    assert inst.call("setFMUState", state) == "error"
    assert inst.messages("error")[-1] == "fmi2SetFMUstate: refused, its phase is not one of this FMU's"
    inst.slave.freeFMUState(state)


# ------------------------------------------------------------------------------ 6. the importer's tolerance

def run_with(toy, setup_tol=None, explicit_tol=None, explicit_first=True):
    t = Toy(toy, name="tol")
    try:
        t.instantiate()
        if explicit_tol is not None and explicit_first:
            t.set({"solver.tol": explicit_tol})
        t.slave.setupExperiment(tolerance=setup_tol, startTime=0.0)
        if explicit_tol is not None and not explicit_first:
            t.set({"solver.tol": explicit_tol})
        t.slave.enterInitializationMode()
        t.set(DRIVE)
        t.slave.exitInitializationMode()
        return t.get("solver.tol"), t.run(0.2, 0.05)
    finally:
        t.close()


def test_the_importers_tolerance_is_the_solvers_unless_solver_tol_is_set(toy):
    default_tol, default = run_with(toy)
    assert default_tol == 1e-8
    tol, loose = run_with(toy, setup_tol=1e-3)
    assert tol == 1e-3
    assert loose != default                              # it changed the integration
    assert run_with(toy, explicit_tol=1e-3) == (tol, loose)   # the same as setting solver.tol = 1e-3
    for first in (True, False):                          # an explicit solver.tol wins in either order
        assert run_with(toy, setup_tol=1e-3, explicit_tol=1e-8, explicit_first=first) == (1e-8, default)


def test_a_bad_importer_tolerance_is_refused(inst):
    inst.instantiate()
    for tol in (0.0, -1e-6, math.nan):
        assert inst.call("setupExperiment", tolerance=tol, startTime=0.0) == "error"
        assert "tolerance" in inst.messages("error")[-1] and "must be > 0 and finite" in inst.messages("error")[-1]
    inst.slave.enterInitializationMode()
    assert inst.get("solver.tol") == 1e-8
