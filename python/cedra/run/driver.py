"""Drive a cedra FMU by variable name through FMPy (used by the main job, the reports and the benchmark)."""
from __future__ import annotations

import shutil

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException, calloc, free
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2Terminated)

STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]


class RoverFMU:
    """One instance of a cedra FMU. Failed calls do not raise: `status` and `messages` say what happened."""

    def __init__(self, fmu_path, instance_name="cedra"):
        self.md = read_model_description(str(fmu_path))
        self.unzipdir = extract(str(fmu_path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.messages: list[str] = []
        self.status = "ok"
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)
        self._callbacks = fmi2CallbackFunctions()
        self._callbacks.logger = fmi2CallbackLoggerTYPE(self._log)
        self._callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        # No fmpy.logging.addLoggerProxy here: its native proxy keeps ONE process-wide target, so pointing it at
        # this instance's callback left every later proxied logger (fmpy's own default callbacks included)
        # calling freed memory once this instance was gone (a segfault in the next FMU that logged). cedra's
        # glue passes finished messages, so no printf formatting is needed.
        self.time = 0.0

    def _log(self, env, name, status, category, message):
        self.messages.append(f"[{STATUS[status] if status < 6 else status}] {category.decode()}: {message.decode()}")

    def has(self, name):
        return name in self.vars

    def start(self, values: dict | None = None, start_time=0.0):
        """Instantiate, set start values by name, initialize (the FMU settles the pose)."""
        self.fmu.instantiate(callbacks=self._callbacks)
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()
        self.set(values or {})
        self.fmu.exitInitializationMode()
        self.time = start_time

    def set(self, values: dict):
        """Set by name: one fmi2Set call per type (all or nothing, as the FMU's setters are)."""
        by_type: dict[str, tuple[list, list]] = {}
        for name, value in values.items():
            v = self.vars[name]
            vrs, vals = by_type.setdefault(v.type, ([], []))
            vrs.append(v.valueReference)
            vals.append(float(value) if v.type == "Real" else int(value) if v.type == "Integer" else bool(value))
        setters = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger, "Boolean": self.fmu.setBoolean}
        for t, (vrs, vals) in by_type.items():
            if t not in setters:
                raise ValueError(f"{vrs}: cannot set a {t}")
            setters[t](vrs, vals)

    def get(self, names) -> np.ndarray:
        """Values by name, one fmi2Get call per type."""
        out = np.empty(len(names))
        by_type: dict[str, tuple[list, list]] = {}
        for k, name in enumerate(names):
            v = self.vars[name]
            idx, vrs = by_type.setdefault(v.type, ([], []))
            idx.append(k)
            vrs.append(v.valueReference)
        getters = {"Real": self.fmu.getReal, "Integer": self.fmu.getInteger, "Boolean": self.fmu.getBoolean}
        for t, (idx, vrs) in by_type.items():
            out[idx] = np.asarray(getters[t](vrs), dtype=float)
        return out

    def step(self, t_next) -> bool:
        """Step to t_next; False (status 'discard'/'error', reason in messages) if the FMU refused. The step is
        t_next - time, so a master computing t_next = k dt does not accumulate round-off."""
        try:
            self.fmu.doStep(currentCommunicationPoint=self.time, communicationStepSize=t_next - self.time)
        except FMICallException as e:
            self.status = STATUS[e.status] if 0 <= e.status < 6 else str(e.status)
            return False
        self.time = t_next
        return True

    def terminated(self) -> bool:
        try:
            return bool(self.fmu.getBooleanStatus(fmi2Terminated))
        except FMICallException:
            return False

    def close(self):
        try:
            self.fmu.terminate()
        except FMICallException:
            pass
        self.fmu.freeInstance()
        shutil.rmtree(self.unzipdir, ignore_errors=True)


class FastIO:
    """The per-sample calls of a loop that reads the same variables and sets the same inputs every communication
    step, through the FMU's own fmi2GetReal/GetInteger/SetReal/DoStep with buffers made once (what a compiled
    master does; FMPy's checked wrappers build the arrays on every call: ~20 us per sample of a rover run). A call
    the FMU refuses sets fmu.status (its reason is in fmu.messages, as with RoverFMU) and returns None / False.
    Use on a started RoverFMU."""

    def __init__(self, fmu: RoverFMU, read: list[str], write: list[str]):
        import ctypes
        self.fmu = fmu
        self.dll, self.comp = fmu.fmu.dll, fmu.fmu.component
        types = [fmu.vars[n].type for n in read]
        bad = sorted({t for t in types if t not in ("Real", "Integer")})
        if bad or any(fmu.vars[n].type != "Real" for n in write):
            raise ValueError("FastIO reads Real and Integer and writes Real variables "
                             f"(got {bad or 'a non-Real input'})")
        self.real_idx = [k for k, t in enumerate(types) if t == "Real"]
        self.int_idx = [k for k, t in enumerate(types) if t == "Integer"]
        self.real_vr = (ctypes.c_uint * len(self.real_idx))(*[fmu.vars[read[k]].valueReference for k in self.real_idx])
        self.int_vr = (ctypes.c_uint * len(self.int_idx))(*[fmu.vars[read[k]].valueReference for k in self.int_idx])
        self.real_buf = (ctypes.c_double * len(self.real_idx))()
        self.int_buf = (ctypes.c_int * len(self.int_idx))()
        self.write_vr = (ctypes.c_uint * len(write))(*[fmu.vars[n].valueReference for n in write])
        self.write_buf = (ctypes.c_double * len(write))()
        # numpy views of the buffers (no copy per call); all-Real reads in order are one copy of the view
        self.real_view = np.ctypeslib.as_array(self.real_buf) if self.real_idx else np.empty(0)
        self.int_view = np.ctypeslib.as_array(self.int_buf) if self.int_idx else np.empty(0, dtype=np.intc)
        self.all_real = not self.int_idx
        self.n = len(read)

    def _ok(self, status: int) -> bool:
        if status > 1:                                      # worse than fmi2Warning
            self.fmu.status = STATUS[status] if 0 <= status < 6 else str(status)
            return False
        return True

    def read(self) -> np.ndarray | None:
        """The read variables' values (a new array), or None if the FMU refused."""
        if self.real_idx and not self._ok(self.dll.fmi2GetReal(self.comp, self.real_vr, len(self.real_idx),
                                                                self.real_buf)):
            return None
        if self.int_idx and not self._ok(self.dll.fmi2GetInteger(self.comp, self.int_vr, len(self.int_idx),
                                                                  self.int_buf)):
            return None
        if self.all_real:
            return self.real_view.copy()
        out = np.empty(self.n)
        out[self.real_idx] = self.real_view
        out[self.int_idx] = self.int_view
        return out

    def write(self, values) -> bool:
        self.write_buf[:] = values
        return self._ok(self.dll.fmi2SetReal(self.comp, self.write_vr, len(self.write_buf), self.write_buf))

    def step(self, t_next) -> bool:
        """As RoverFMU.step: to t_next from the instance's time."""
        if not self._ok(self.dll.fmi2DoStep(self.comp, self.fmu.time, t_next - self.fmu.time, 1)):
            return False
        self.fmu.time = t_next
        return True
