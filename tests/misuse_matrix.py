"""The misuse matrix: how a cedra FMU answers an importer that calls it wrongly.

Each case puts a fresh instance into a phase (instantiated, initialization mode, step complete, terminated, or
failed after a discarded step), makes ONE wrong call through the raw C entry points (ctypes, so NULL pointers,
NaN and out-of-range values reach the FMU as an importer could send them), and checks what the FMI 2.0 standard and
the glue's contract say:
- the status (fmi2Error for a refused call, fmi2Discard for a step the FMU could not complete),
- that a message with that status reached the logger, containing the expected words,
- for a refused call: the instance is unchanged (its serialized state is byte for byte the same) and still gives
  the same results as an instance that never saw the call (two more steps, every output compared exactly);
  for a discarded step: fmi2Terminated is true and the outputs are those before the step, never NaN.

    python tests/misuse_matrix.py build/*.fmu      # the table: cases per class and result
    python tests/misuse_matrix.py --write docs/reports/misuse.md build/*.fmu    # and the page docs/reliability.md includes

tests/test_fmu_misuse.py runs every class on every shipped FMU.
"""
from __future__ import annotations

import ctypes as C
import math
import re
import struct
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from fmpy import extract, read_model_description
from fmpy.fmi1 import calloc, free
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

from cedra.contract import SOLVER_METHODS

OK, WARNING, DISCARD, ERROR, FATAL = range(5)
STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]
PHASES = ("instantiated", "init", "step", "terminated", "failed")
STEP = 0.01
NAN, INF = math.nan, math.inf

_UNZIPPED: dict[str, str] = {}


def unzipped(fmu_path) -> str:
    key = str(Path(fmu_path).resolve())
    if key not in _UNZIPPED:
        _UNZIPPED[key] = str(extract(key))
    return _UNZIPPED[key]


def fnv1a(data: bytes) -> int:
    h = 1469598103934665603
    for b in data:
        h = ((h ^ b) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def with_checksum(blob: bytes) -> bytes:
    """A serialized state with its checksum recomputed: the last member (uint64), FNV-1a over the bytes with it
    zero (fmu_src/fmi2_glue.c, state_checksum)."""
    return blob[:-8] + struct.pack("<Q", fnv1a(blob[:-8] + bytes(8)))


def _u(vals):
    return (C.c_uint * max(1, len(vals)))(*vals)


def _d(vals):
    return (C.c_double * max(1, len(vals)))(*vals)


def _i(vals):
    return (C.c_int * max(1, len(vals)))(*vals)


class Probe:
    """One instance of an FMU with a recording logger and raw access to its fmi2 functions."""

    def __init__(self, fmu_path, md=None):
        self.path = str(fmu_path)
        self.md = md or read_model_description(self.path)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.log: list[tuple[int, str]] = []
        self.slave = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipped(fmu_path),
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName="probe")
        # a second handle on the same library: its functions carry no argtypes (FMPy's handle has them), so
        # NULLs and raw arrays reach the FMU exactly as given
        self.dll = C.CDLL(self.slave.dll._name)
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.callbacks = cb
        self.c = None
        self.time = 0.0

    def _logger(self, env, name, status, category, message):
        self.log.append((status, message.decode()))

    # ------------------------------------------------------------------ raw calls
    def raw(self, fn: str, *args, restype=C.c_int):
        f = getattr(self.dll, fn)
        f.restype = restype
        return f(*args)

    def instantiate(self):
        self.slave.instantiate(callbacks=self.callbacks)
        self.c = C.c_void_p(self.slave.component)

    def vr(self, name) -> int:
        return self.vars[name].valueReference

    def set_real(self, names_values: dict) -> int:
        vrs = [self.vr(n) for n in names_values]
        return self.raw("fmi2SetReal", self.c, _u(vrs), C.c_size_t(len(vrs)), _d(list(names_values.values())))

    def set_any(self, values: dict):
        for name, value in values.items():
            v = self.vars[name]
            if v.type == "Real":
                st = self.raw("fmi2SetReal", self.c, _u([v.valueReference]), C.c_size_t(1), _d([value]))
            else:
                st = self.raw(f"fmi2Set{v.type}", self.c, _u([v.valueReference]), C.c_size_t(1), _i([int(value)]))
            assert st == OK, (name, value, self.log[-1:])

    def do_step(self, h, t=None) -> int:
        return self.raw("fmi2DoStep", self.c, C.c_double(self.time if t is None else t), C.c_double(h), C.c_int(1))

    def setup(self, start=0.0, tol=None, stop=None) -> int:
        return self.raw("fmi2SetupExperiment", self.c, C.c_int(tol is not None), C.c_double(tol or 0.0),
                        C.c_double(start), C.c_int(stop is not None), C.c_double(stop or 0.0))

    def serialized(self) -> bytes | None:
        """The instance's serialized state (None if the FMU refuses to give one)."""
        state = C.c_void_p()
        if self.raw("fmi2GetFMUstate", self.c, C.byref(state)) != OK:
            return None
        size = C.c_size_t()
        self.raw("fmi2SerializedFMUstateSize", self.c, state, C.byref(size))
        buf = C.create_string_buffer(size.value)
        self.raw("fmi2SerializeFMUstate", self.c, state, buf, size)
        self.raw("fmi2FreeFMUstate", self.c, C.byref(state))
        return buf.raw

    def real_outputs(self) -> list[float]:
        vrs = [v.valueReference for v in self.md.modelVariables if v.causality == "output" and v.type == "Real"]
        out = _d([0.0] * len(vrs))
        st = self.raw("fmi2GetReal", self.c, _u(vrs), C.c_size_t(len(vrs)), out)
        assert st == OK, self.log[-1:]
        return list(out)[:len(vrs)]

    def terminated(self) -> bool:
        b = C.c_int(0)
        st = self.raw("fmi2GetBooleanStatus", self.c, C.c_int(3), C.byref(b))   # fmi2Terminated
        return st == OK and b.value != 0

    def free(self):
        if self.c:
            self.raw("fmi2FreeInstance", self.c, restype=None)
            self.c = None
            self.slave.component = None

    # ------------------------------------------------------------------ phases
    def to_phase(self, phase: str):
        self.instantiate()
        if phase == "instantiated":
            assert self.setup() == OK
            return
        assert self.setup() == OK
        assert self.raw("fmi2EnterInitializationMode", self.c) == OK
        if phase == "init":
            return
        if phase == "failed":   # a budget far below one step's work: the next long step is discarded
            self.set_any({"solver.max_wall_time": 1e-9})
        assert self.raw("fmi2ExitInitializationMode", self.c) == OK, self.log[-1:]
        self.set_any(self.drive())
        if phase == "failed":
            assert self.do_step(0.5) == DISCARD, self.log[-1:]
            return
        assert self.do_step(STEP) == OK, self.log[-1:]
        self.time += STEP
        if phase == "terminated":
            assert self.raw("fmi2Terminate", self.c) == OK

    def drive(self) -> dict:
        """A torque on every wheel that has one (a plant), or a speed command (the controller): the continuation
        then changes the outputs."""
        return {n: 1.0 if n.startswith("tau[") else 0.3 for n in self.vars
                if (n.startswith("tau[") or n == "cmd.v") and self.vars[n].causality == "input"}

    def continuation(self, phase: str) -> list[float] | None:
        """Outputs after bringing the instance to two more steps from its phase (None where nothing can run)."""
        if phase in ("terminated", "failed"):
            return None
        if phase == "instantiated":
            assert self.raw("fmi2EnterInitializationMode", self.c) == OK, self.log[-1:]
            phase = "init"
        if phase == "init":
            assert self.raw("fmi2ExitInitializationMode", self.c) == OK, self.log[-1:]
            self.set_any(self.drive())
        out = []
        for _ in range(2):
            assert self.do_step(STEP) == OK, self.log[-2:]
            self.time += STEP
            out += self.real_outputs()
        return out


@dataclass(frozen=True)
class Case:
    cls: str                      # the class of misuse (the rows of docs/reliability.md's table)
    name: str
    phase: str                    # one of PHASES
    action: Callable[[Probe], int]
    status: int                   # the expected status
    message: str                  # a regular expression the logged message must match (search)
    logged: bool = True           # False: no logger can be reached (a NULL component)


def is_plant(md) -> bool:
    """A plant FMU (an embedded solver) rather than the sampled drive controller."""
    return any(v.name == "solver.method" for v in md.modelVariables)


def _getter_setter_cases(md) -> list[Case]:
    vs = {v.name: v for v in md.modelVariables}
    real_in = next(v for v in md.modelVariables if v.causality == "input" and v.type == "Real")
    real_out = next(v for v in md.modelVariables if v.causality == "output" and v.type == "Real")
    int_par = vs["solver.max_steps"] if is_plant(md) else vs["ctrl.mode"]
    bool_par = vs.get("start.settle")
    n = len(md.modelVariables)
    cases = []
    null = C.POINTER(C.c_uint)()
    for fn, arr in (("fmi2GetReal", _d), ("fmi2SetReal", _d), ("fmi2GetInteger", _i), ("fmi2SetInteger", _i),
                    ("fmi2GetBoolean", _i), ("fmi2SetBoolean", _i)):
        phase = "init"
        cases.append(Case("NULL arguments", f"{fn} vr NULL", phase,
                          lambda p, fn=fn, arr=arr: p.raw(fn, p.c, null, C.c_size_t(1), arr([0])),
                          ERROR, f"{fn}: vr is NULL"))
        cases.append(Case("NULL arguments", f"{fn} value NULL", phase,
                          lambda p, fn=fn: p.raw(fn, p.c, _u([0]), C.c_size_t(1), C.c_void_p()),
                          ERROR, f"{fn}: value is NULL"))
        cases.append(Case("NULL arguments", f"{fn} component NULL", phase,
                          lambda p, fn=fn, arr=arr: p.raw(fn, C.c_void_p(), _u([0]), C.c_size_t(1), arr([0])),
                          ERROR, "", logged=False))
        for bad in (n, n + 1000, 2**32 - 1):
            cases.append(Case("unknown references and wrong types", f"{fn} vr {bad}", phase,
                              lambda p, fn=fn, arr=arr, bad=bad: p.raw(fn, p.c, _u([bad]), C.c_size_t(1), arr([0])),
                              ERROR, f"{fn}: unknown value reference {bad}"))
    # an output read in initialization mode computes the start state: a vector that is refused must not
    cases.append(Case("unknown references and wrong types", "fmi2GetReal [an output, an unknown vr] (init)", "init",
                      lambda p: p.raw("fmi2GetReal", p.c, _u([real_out.valueReference, n + 7]), C.c_size_t(2),
                                      _d([0, 0])),
                      ERROR, f"fmi2GetReal: unknown value reference {n + 7}"))
    for fn in ("fmi2GetString", "fmi2SetString"):
        cases.append(Case("unknown references and wrong types", f"{fn} on a Real", "init",
                          lambda p, fn=fn, vr=real_in.valueReference: p.raw(
                              fn, p.c, _u([vr]), C.c_size_t(1), (C.c_char_p * 1)(b"x")),
                          ERROR, f"{fn}: variable .* is not a String"))
    wrong_type = (("fmi2GetInteger", real_out, _i), ("fmi2SetInteger", real_in, _i), ("fmi2GetBoolean", real_out, _i),
                  ("fmi2SetBoolean", real_in, _i), ("fmi2GetReal", int_par, _d), ("fmi2SetReal", int_par, _d),
                  ("fmi2GetReal", bool_par, _d), ("fmi2SetReal", bool_par, _d), ("fmi2SetInteger", bool_par, _i),
                  ("fmi2SetBoolean", int_par, _i))
    for fn, v, arr in wrong_type:
        if v is None:           # the controller has no Boolean variable
            continue
        cases.append(Case("unknown references and wrong types", f"{fn} on {v.name} ({v.type})", "init",
                          lambda p, fn=fn, vr=v.valueReference, arr=arr: p.raw(fn, p.c, _u([vr]), C.c_size_t(1),
                                                                                arr([1])),
                          ERROR, rf"{fn}: variable {re.escape(v.name)} \(vr {v.valueReference}\) is an? "))
    return cases


def _value_cases(md) -> list[Case]:
    """NaN, infinities and values outside [min, max] for every input, a sample of parameters and every solver
    setting; outputs set; parameters set after initialization; and vectors with one bad element (all or nothing)."""
    cases = []
    inputs = [v for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
    params = [v for v in md.modelVariables if v.causality == "parameter" and v.type == "Real"
              and not v.name.startswith(("start.", "solver."))]
    vs = {v.name: v for v in md.modelVariables}

    def set_real(name, value, phase="init", cls="NaN, infinite and out-of-range values"):
        return Case(cls, f"{name} = {value!r} ({phase})", phase,
                    lambda p: p.set_real({name: value}), ERROR,
                    rf"fmi2SetReal: variable {re.escape(name)} \(vr \d+\) = ")

    for v in inputs + params[:: max(1, len(params) // 8)]:
        for value in (NAN, INF, -INF):
            cases.append(set_real(v.name, value, "init" if v.causality == "parameter" else "step"))
        if v.min is not None:
            lo = float(v.min)
            cases.append(set_real(v.name, lo - max(1.0, abs(lo)), "init"))
        if v.max is not None:
            hi = float(v.max)
            cases.append(set_real(v.name, hi + max(1.0, abs(hi)), "init"))
    plant = is_plant(md)
    reals = (("solver.tol", 0.0), ("solver.tol", -1e-6), ("solver.tol", NAN), ("solver.h_max", 0.0),
             ("solver.h_max", -0.01), ("solver.h_max", INF), ("solver.max_wall_time", 0.0),
             ("solver.max_wall_time", 1e7), ("solver.max_wall_time", NAN)) if plant else \
        (("ctrl.period", 0.0), ("ctrl.period", -0.01), ("ctrl.period", INF), ("ctrl.tau_max", -1.0))
    for name, value in reals:
        cases.append(set_real(name, value))
    integers = (("solver.method", -1), ("solver.method", len(SOLVER_METHODS)), ("solver.max_steps", 0),
                ("solver.max_steps", -5)) \
        if plant else (("ctrl.mode", -1), ("ctrl.mode", int(vs["ctrl.mode"].max) + 1))
    for name, value in integers:
        vr = vs[name].valueReference
        cases.append(Case("NaN, infinite and out-of-range values", f"{name} = {value}", "init",
                          lambda p, vr=vr, value=value: p.raw("fmi2SetInteger", p.c, _u([vr]), C.c_size_t(1),
                                                               _i([value])),
                          ERROR, rf"fmi2SetInteger: variable {re.escape(name)} \(vr {vr}\) = "))
    out = next(v for v in md.modelVariables if v.causality == "output" and v.type == "Real")
    cases.append(Case("NaN, infinite and out-of-range values", f"set the output {out.name}", "step",
                      lambda p: p.set_real({out.name: 1.0}), ERROR, "is an output .*cannot be set"))
    par = params[0]
    cases.append(Case("call order", f"set the parameter {par.name} after initialization", "step",
                      lambda p: p.set_real({par.name: float(par.start)}), ERROR, "is fixed: it can be set only"))
    # all or nothing: a good value first, a bad one after it
    good = inputs[0].name
    setting = "solver.tol" if plant else "ctrl.period"
    for bad_name, bad_value in ((inputs[-1].name, NAN), (setting, -1.0), (out.name, 0.0)):
        phase = "init" if bad_name == setting else "step"
        cases.append(Case("all-or-nothing setters", f"[{good} = 0.5, {bad_name} = {bad_value}] ({phase})", phase,
                          lambda p, b=bad_name, bv=bad_value: p.set_real({good: 0.5, b: bv}), ERROR,
                          f"variable {re.escape(bad_name)}"))
    vr_good = vs[good].valueReference
    cases.append(Case("all-or-nothing setters", f"[{good} = 0.5, unknown vr]", "step",
                      lambda p: p.raw("fmi2SetReal", p.c, _u([vr_good, 10**6]), C.c_size_t(2), _d([0.5, 1.0])),
                      ERROR, "unknown value reference 1000000"))
    for name in ("solver.method", "solver.max_steps") if plant else ("ctrl.mode",):
        vr = vs[name].valueReference
        cases.append(Case("all-or-nothing setters", f"[{name} = 1, {name} = -7]", "init",
                          lambda p, vr=vr: p.raw("fmi2SetInteger", p.c, _u([vr, vr]), C.c_size_t(2), _i([1, -7])),
                          ERROR, rf"variable {re.escape(name)} \(vr {vr}\) = -7"))
    return cases


def _call_order_cases(md) -> list[Case]:
    cases = []
    not_allowed = {
        "fmi2SetupExperiment": (("init", "step", "terminated", "failed"),
                                lambda p: p.setup()),
        "fmi2EnterInitializationMode": (("init", "step", "terminated", "failed"),
                                        lambda p: p.raw("fmi2EnterInitializationMode", p.c)),
        "fmi2ExitInitializationMode": (("instantiated", "step", "terminated", "failed"),
                                       lambda p: p.raw("fmi2ExitInitializationMode", p.c)),
        "fmi2DoStep": (("instantiated", "init", "terminated", "failed"), lambda p: p.do_step(STEP)),
        "fmi2Terminate": (("instantiated", "init", "terminated"), lambda p: p.raw("fmi2Terminate", p.c)),
        "fmi2GetReal": (("instantiated",), lambda p: p.raw("fmi2GetReal", p.c, _u([0]), C.c_size_t(1), _d([0]))),
        "fmi2SetReal": (("terminated", "failed"),
                        lambda p: p.raw("fmi2SetReal", p.c, _u([0]), C.c_size_t(1), _d([0]))),
        "fmi2GetBooleanStatus": (("instantiated", "init"),
                                 lambda p: p.raw("fmi2GetBooleanStatus", p.c, C.c_int(3), C.byref(C.c_int()))),
        "fmi2GetRealStatus": (("instantiated", "init"),
                              lambda p: p.raw("fmi2GetRealStatus", p.c, C.c_int(2), C.byref(C.c_double()))),
        "fmi2CancelStep": (PHASES, lambda p: p.raw("fmi2CancelStep", p.c)),
    }
    for fn, (phases, action) in not_allowed.items():
        for phase in phases:
            if phase == "failed" and not is_plant(md):    # nothing makes the controller discard a step
                continue
            msg = ("terminated at t=.* after a discarded step" if fn == "fmi2DoStep" and phase == "failed"
                   else f"{fn}: not allowed in state")
            cases.append(Case("call order", f"{fn} in {phase}", phase, action, ERROR, msg))
    cases.append(Case("call order", "fmi2DoStep with NULL component", "step",
                      lambda p: p.raw("fmi2DoStep", C.c_void_p(), C.c_double(0), C.c_double(STEP), C.c_int(1)),
                      ERROR, "", logged=False))
    return cases


def _step_cases(md) -> list[Case]:
    cls = "step arguments and budgets"
    cases = [Case(cls, f"fmi2DoStep h = {h!r}", "step", lambda p, h=h: p.do_step(h), ERROR,
                  "communicationStepSize = .* must be > 0")
             for h in (0.0, -STEP, NAN, INF, -INF)]
    cases += [Case(cls, f"fmi2DoStep at t = {t}", "step", lambda p, t=t: p.do_step(STEP, t=t), ERROR,
                   "currentCommunicationPoint = .* but the FMU is at")
              for t in (NAN, -1.0, 1.0, 1e300)]
    cases.append(Case(cls, "fmi2DoStep h = 1e-300 (below the time resolution)", "step", lambda p: p.do_step(1e-300),
                      ERROR, "is below the time resolution"))
    if not is_plant(md):
        return cases + [Case(cls, f"fmi2DoStep h = {h:g} s (beyond 1e6 samples)", "step",
                             lambda p, h=h: p.do_step(h), ERROR, "refused: the communication step of .* samples")
                        for h in (1e300, 2e6 * 0.01)]
    cases += [Case(cls, "fmi2DoStep h = 1e300 (beyond the step budget)", "step", lambda p: p.do_step(1e300),
                   ERROR, r"refused: \w+: the interval of 1e\+300 s needs at least"),
              Case(cls, "fmi2DoStep h = 2e5 h_max (beyond 100000 steps of h_max)", "step",
                   lambda p: p.do_step(2e5 * float(p.vars["solver.h_max"].start)), ERROR,
                   "more than solver.max_steps = 100000")]

    def rk4(h_max, h):
        def action(p):
            return p.do_step(h)
        return Case(cls, f"RK4 h_max = {h_max:g}, fmi2DoStep h = {h:g}", "rk4:" + repr(h_max), action, ERROR,
                    r"refused: rk4: the interval of .* needs at least")
    cases += [rk4(1e-300, 0.5), rk4(1e-8, STEP), rk4(0.01, 1e300)]
    cases.append(Case(cls, "the attempted-step budget spent (max_steps = 3, h_max = 0.3, h = 0.5)", "budget:steps",
                      lambda p: p.do_step(0.5), DISCARD, r"too many steps \(more than solver.max_steps = 3"))
    cases.append(Case(cls, "the wall-clock budget spent (max_wall_time = 1e-9, h = 0.5)", "budget:wall",
                      lambda p: p.do_step(0.5), DISCARD, r"wall-clock budget of 1e-09 s is spent"))
    return cases


def _experiment_cases() -> list[Case]:
    cls = "setup experiment"
    return [Case(cls, f"startTime = {t!r}", "fresh", lambda p, t=t: p.setup(start=t), ERROR, "startTime = ")
            for t in (NAN, INF, 1e300, -1e300, 2e9)] + [
        Case(cls, "stopTime before startTime", "fresh", lambda p: p.setup(start=1.0, stop=0.5), ERROR,
             "stopTime = 0.5 is before startTime = 1"),
        Case(cls, "stopTime NaN", "fresh", lambda p: p.setup(stop=NAN), ERROR, "stopTime = nan")] + [
        Case(cls, f"tolerance = {tol!r}", "fresh", lambda p, tol=tol: p.setup(tol=tol), ERROR,
             "tolerance = .* must be > 0 and finite") for tol in (0.0, -1e-6, NAN, INF)]


def _state_cases() -> list[Case]:
    cls = "FMU states"

    def deserialize(mutate, size_delta=0):
        def action(p):
            blob = bytearray(p.serialized())
            mutate(blob)
            blob = bytes(blob)
            if size_delta < 0:
                blob = blob[:size_delta]
            elif size_delta > 0:
                blob = blob + bytes(size_delta)
            state = C.c_void_p()
            buf = C.create_string_buffer(blob, len(blob))
            st = p.raw("fmi2DeSerializeFMUstate", p.c, buf, C.c_size_t(len(blob)), C.byref(state))
            if state.value:
                p.raw("fmi2FreeFMUstate", p.c, C.byref(state))
            return st
        return action

    def flip(offset):
        def m(blob):
            blob[offset % len(blob)] ^= 0x5A
        return m

    def randomize(blob):
        import random
        rng = random.Random(11)
        for k in range(80, len(blob) - 8):
            blob[k] = rng.randrange(256)

    def nan_time_with_checksum(blob):
        off = 4 + 4 + 64 + 4 + 4     # magic, size, guid, phase, padding: the time
        blob[off:off + 8] = struct.pack("<d", math.nan)
        blob[:] = with_checksum(bytes(blob))

    def state_null(fn):
        if fn == "fmi2GetFMUstate":
            return lambda p: p.raw(fn, p.c, C.c_void_p())
        if fn == "fmi2SetFMUstate":
            return lambda p: p.raw(fn, p.c, C.c_void_p())
        if fn == "fmi2FreeFMUstate":
            return lambda p: p.raw(fn, p.c, C.c_void_p())
        if fn == "fmi2SerializedFMUstateSize":
            return lambda p: p.raw(fn, p.c, C.c_void_p(), C.byref(C.c_size_t()))
        if fn == "fmi2SerializeFMUstate":
            return lambda p: p.raw(fn, p.c, C.c_void_p(), C.create_string_buffer(8), C.c_size_t(8))
        return lambda p: p.raw(fn, p.c, C.c_void_p(), C.c_size_t(8), C.byref(C.c_void_p()))

    cases = []
    for fn in ("fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate", "fmi2SerializedFMUstateSize",
               "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate"):
        cases.append(Case("NULL arguments", f"{fn} with NULL", "step", state_null(fn), ERROR, f"{fn}: .*NULL"))
    for phase in ("step", "init"):
        cases += [
            Case(cls, f"deserialize a truncated state ({phase})", phase, deserialize(lambda b: None, -1), ERROR,
                 "fmi2DeSerializeFMUstate: size"),
            Case(cls, f"deserialize a longer state ({phase})", phase, deserialize(lambda b: None, 8), ERROR,
                 "fmi2DeSerializeFMUstate: size"),
            Case(cls, f"deserialize with a wrong magic number ({phase})", phase, deserialize(flip(0)), ERROR,
                 "not a state of this FMU"),
            Case(cls, f"deserialize with a damaged GUID ({phase})", phase, deserialize(flip(10)), ERROR,
                 "not a state of this FMU"),
            Case(cls, f"deserialize with one flipped byte ({phase})", phase, deserialize(flip(-20)), ERROR,
                 "the checksum does not match"),
            Case(cls, f"deserialize a random body ({phase})", phase, deserialize(randomize), ERROR,
                 "the checksum does not match"),
            Case(cls, f"deserialize a NaN time with a valid checksum ({phase})", phase,
                 deserialize(nan_time_with_checksum), ERROR, "refused, a time is not finite"),
        ]
    cases.append(Case(cls, "serialize with a wrong size", "step",
                      lambda p: _serialize_wrong_size(p), ERROR, "fmi2SerializeFMUstate: size"))
    cases.append(Case(cls, "set a state whose phase is garbage", "step", lambda p: _set_garbage_phase(p), ERROR,
                      "its phase is not one of this FMU's"))
    return cases


def _serialize_wrong_size(p):
    state = C.c_void_p()
    p.raw("fmi2GetFMUstate", p.c, C.byref(state))
    st = p.raw("fmi2SerializeFMUstate", p.c, state, C.create_string_buffer(16), C.c_size_t(16))
    p.raw("fmi2FreeFMUstate", p.c, C.byref(state))
    return st


def _set_garbage_phase(p):
    state = C.c_void_p()
    p.raw("fmi2GetFMUstate", p.c, C.byref(state))
    raw = C.cast(state, C.POINTER(C.c_ubyte))
    raw[4 + 4 + 64] = 0x60
    st = p.raw("fmi2SetFMUstate", p.c, state)
    p.raw("fmi2FreeFMUstate", p.c, C.byref(state))
    return st


def _unsupported_cases() -> list[Case]:
    cls = "unsupported functions and kinds"
    vr, d = _u([0]), _d([1.0])
    return [
        Case(cls, "fmi2GetDirectionalDerivative", "step",
             lambda p: p.raw("fmi2GetDirectionalDerivative", p.c, vr, C.c_size_t(1), vr, C.c_size_t(1), d, _d([0])),
             ERROR, "not supported"),
        Case(cls, "fmi2SetRealInputDerivatives", "step",
             lambda p: p.raw("fmi2SetRealInputDerivatives", p.c, vr, C.c_size_t(1), _i([1]), d), ERROR,
             "not supported"),
        Case(cls, "fmi2GetRealOutputDerivatives", "step",
             lambda p: p.raw("fmi2GetRealOutputDerivatives", p.c, vr, C.c_size_t(1), _i([1]), d), ERROR,
             "not supported"),
        Case(cls, "fmi2GetIntegerStatus", "step",
             lambda p: p.raw("fmi2GetIntegerStatus", p.c, C.c_int(0), C.byref(C.c_int())), ERROR, "not supported"),
        Case(cls, "fmi2GetStatus kind 2", "step",
             lambda p: p.raw("fmi2GetStatus", p.c, C.c_int(2), C.byref(C.c_int())), ERROR, "not supported"),
        Case(cls, "fmi2GetRealStatus kind 0", "step",
             lambda p: p.raw("fmi2GetRealStatus", p.c, C.c_int(0), C.byref(C.c_double())), ERROR, "not supported"),
        Case(cls, "fmi2GetBooleanStatus kind 0", "step",
             lambda p: p.raw("fmi2GetBooleanStatus", p.c, C.c_int(0), C.byref(C.c_int())), ERROR, "not supported"),
        Case(cls, "fmi2GetStringStatus kind 0", "step",
             lambda p: p.raw("fmi2GetStringStatus", p.c, C.c_int(0), C.byref(C.c_char_p())), ERROR, "not supported"),
        Case(cls, "fmi2SetDebugLogging unknown category", "step",
             lambda p: p.raw("fmi2SetDebugLogging", p.c, C.c_int(1), C.c_size_t(1), (C.c_char_p * 1)(b"logNope")),
             ERROR, "unknown log category logNope"),
        Case(cls, "fmi2SetDebugLogging NULL categories", "step",
             lambda p: p.raw("fmi2SetDebugLogging", p.c, C.c_int(1), C.c_size_t(2), C.c_void_p()), ERROR,
             "categories is NULL"),
        Case(cls, "fmi2GetStatus value NULL", "step",
             lambda p: p.raw("fmi2GetStatus", p.c, C.c_int(0), C.c_void_p()), ERROR, "value is NULL"),
        Case(cls, "fmi2GetRealStatus value NULL", "step",
             lambda p: p.raw("fmi2GetRealStatus", p.c, C.c_int(2), C.c_void_p()), ERROR, "value is NULL"),
    ]


def _instantiate_cases() -> list[Case]:
    """fmi2Instantiate refusals: NULL is returned (status ERROR here), a message where a logger exists."""
    cls = "instantiation"

    def inst(p, guid=None, kind=1, name=b"probe", callbacks=True, logger=True, alloc=True):
        cb = fmi2CallbackFunctions()
        if logger:
            cb.logger = p.callbacks.logger
        if alloc:
            cb.allocateMemory = p.callbacks.allocateMemory
            cb.freeMemory = p.callbacks.freeMemory
        guid = p.md.guid.encode() if guid is None else guid
        res = p.raw("fmi2Instantiate", C.c_char_p(name), C.c_int(kind), C.c_char_p(guid),
                    C.c_char_p(("file://" + unzipped(p.path) + "/resources").encode()),
                    C.byref(cb) if callbacks else C.c_void_p(), C.c_int(0), C.c_int(0), restype=C.c_void_p)
        if res:
            p.raw("fmi2FreeInstance", C.c_void_p(res), restype=None)
            return OK
        return ERROR

    return [
        Case(cls, "wrong GUID", "none", lambda p: inst(p, guid=b"{nope}"), ERROR, "GUID {nope} does not match"),
        Case(cls, "NULL GUID", "none", lambda p: inst(p, guid=b""), ERROR, "GUID  does not match"),
        Case(cls, "Model Exchange", "none", lambda p: inst(p, kind=0), ERROR, "supports Co-Simulation only"),
        Case(cls, "empty instance name", "none", lambda p: inst(p, name=b""), ERROR, "instanceName is NULL or empty"),
        Case(cls, "NULL instance name", "none", lambda p: inst(p, name=None), ERROR, "instanceName is NULL or empty"),
        Case(cls, "no allocateMemory/freeMemory", "none", lambda p: inst(p, alloc=False), ERROR,
             "allocateMemory and freeMemory are required"),
        Case(cls, "no logger", "none", lambda p: inst(p, logger=False), ERROR, "", logged=False),
        Case(cls, "NULL callbacks", "none", lambda p: inst(p, callbacks=False), ERROR, "", logged=False),
    ]


def cases(md) -> list[Case]:
    return (_call_order_cases(md) + _getter_setter_cases(md) + _value_cases(md) + _step_cases(md) +
            _experiment_cases() + _state_cases() + _unsupported_cases() + _instantiate_cases())


# ---------------------------------------------------------------------------------------------- running a case

def _prepare(p: Probe, phase: str):
    if phase == "none":
        return
    if phase == "fresh":
        p.instantiate()
        return
    if phase.startswith("rk4:"):
        p.instantiate()
        assert p.setup() == OK and p.raw("fmi2EnterInitializationMode", p.c) == OK
        p.set_any({"solver.method": 0, "solver.h_max": float(phase[4:])})
        assert p.raw("fmi2ExitInitializationMode", p.c) == OK, p.log[-1:]
        return
    if phase.startswith("budget:"):
        p.instantiate()
        assert p.setup() == OK and p.raw("fmi2EnterInitializationMode", p.c) == OK
        # the attempted-step budget of an adaptive solver (rodas4: a rigid scene's default moreau takes fixed steps)
        p.set_any({"solver.method": 2, "solver.max_steps": 3, "solver.h_max": 0.3} if phase == "budget:steps"
                  else {"solver.max_wall_time": 1e-9})
        assert p.raw("fmi2ExitInitializationMode", p.c) == OK, p.log[-1:]
        p.set_any(p.drive())
        return
    p.to_phase(phase)


def run_case(fmu_path, case: Case, md=None, reference: dict | None = None) -> str | None:
    """None if the FMU answered as it must, else what went wrong. `reference` caches the continuation of an
    untouched instance per phase."""
    p = Probe(fmu_path, md)
    try:
        _prepare(p, case.phase)
        before = p.serialized() if p.c else None
        outputs_before = p.real_outputs() if case.phase in ("step", "budget:steps", "budget:wall") else None
        n_log = len(p.log)
        status = case.action(p)
        if status != case.status:
            return f"status {STATUS[status] if 0 <= status < 6 else status}, expected {STATUS[case.status]}; " \
                   f"log: {p.log[n_log:][-2:]}"
        new = p.log[n_log:]
        if case.logged:
            hits = [m for s, m in new if s == case.status]
            if not hits:
                return f"no {STATUS[case.status]} message reached the logger (log: {new[-2:]})"
            if not any(re.search(case.message, m) for m in hits):
                return f"message {hits[-1]!r} does not match {case.message!r}"
        if p.c is None or case.phase == "none":
            return None
        if case.status == DISCARD:
            if not p.terminated():
                return "fmi2Terminated is false after a discarded step"
            after = p.real_outputs()
            if not all(math.isfinite(v) for v in after):
                return "an output is not finite after the discard"
            if outputs_before is not None and after != outputs_before:
                return "the outputs changed although the step was discarded"
            return None
        if p.serialized() != before:
            return "the refused call changed the instance (its serialized state differs)"
        phase = case.phase.split(":")[0]
        if phase in ("rk4", "fresh"):
            return None
        cont = p.continuation(phase)
        if cont is not None and reference is not None:
            if phase not in reference:
                q = Probe(fmu_path, md)
                try:
                    q.to_phase(phase)
                    reference[phase] = q.continuation(phase)
                finally:
                    q.free()
            if cont != reference[phase]:
                return "after the refused call the instance gives other results than one that never saw it"
        return None
    except AssertionError as e:
        return f"setup or continuation failed: {e}"
    finally:
        p.free()


def run_all(fmu_path, only_cls: str | None = None) -> list[tuple[Case, str | None]]:
    md = read_model_description(str(fmu_path))
    reference: dict = {}
    return [(c, run_case(fmu_path, c, md, reference)) for c in cases(md) if only_cls in (None, c.cls)]


def classes(fmu_path) -> list[str]:
    md = read_model_description(str(fmu_path))
    return list(dict.fromkeys(c.cls for c in cases(md)))


def table(fmu_paths) -> str:
    rows: dict[str, Counter] = {}
    failures = []
    names = []
    for path in fmu_paths:
        names.append(Path(path).stem)
        for case, problem in run_all(path):
            cnt = rows.setdefault(case.cls, Counter())
            cnt["cases"] += 1
            cnt["passed"] += problem is None
            if problem:
                failures.append(f"{Path(path).stem}: {case.cls}: {case.name}: {problem}")
    lines = [f"FMUs: {', '.join(names)}", "", "| class | cases (all FMUs) | answered as the standard says |",
             "|---|---|---|"]
    for cls, cnt in rows.items():
        lines.append(f"| {cls} | {cnt['cases']} | {cnt['passed']} |")
    total = sum(c["cases"] for c in rows.values())
    lines.append(f"| **all** | **{total}** | **{sum(c['passed'] for c in rows.values())}** |")
    return "\n".join(lines + [""] + failures)


def main(argv: list[str]) -> int:
    """python tests/misuse_matrix.py [--write PAGE] FMU ...: the table; --write: also as a report page with its
    provenance (docs/reports/misuse.md, which docs/reliability.md includes)."""
    import time
    from cedra.pages import load_average, provenance
    page = None
    if argv[:1] == ["--write"]:
        page, argv = Path(argv[1]), argv[2:]
    load, t0 = load_average(), time.time()
    text = table(argv)
    print(text)
    if page is not None:
        cmd = "python tests/misuse_matrix.py build/*.fmu"
        page.write_text(f"# The misuse matrix\n\n{provenance(cmd, time.time() - t0, load)}\n\n{text}\n")
    failed = any(line and not line.startswith(("|", "FMUs:")) for line in text.splitlines())   # a failure's line
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
