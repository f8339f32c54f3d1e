"""Test harness for the FMU machinery: the toy FMU built once per session, an FMPy FMU2Slave wrapper that
records the FMU's log messages and turns fmpy's exceptions into statuses, and copies of an FMU with an edited
modelDescription.xml."""
from __future__ import annotations

import zipfile
from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException, calloc, free
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]
_BUILT: dict[str, Path] = {}


REPO = Path(__file__).resolve().parents[1]


def shipped_fmu(name: str, tmp_path_factory) -> Path:
    """build/<name>.fmu of a shipped scene or drive controller: ./build.sh makes them before the tests (CI); built
    here (once per process) when missing."""
    built = REPO / "build" / f"{name}.fmu"
    if built.exists():
        return built
    if name not in _BUILT:
        from cedra.fmu.packaging import build_fmu
        from cedra.models.controller import CONTROLLERS, shipped_controller
        from cedra.models.scene import load_shipped
        spec = shipped_controller(name) if name in CONTROLLERS else load_shipped(name).spec()
        _BUILT[name] = Path(build_fmu(spec, tmp_path_factory.mktemp(name)))
    return _BUILT[name]


def rewrite_md(fmu: Path, out: Path, edit) -> Path:
    """Copy the FMU to `out` with its modelDescription.xml passed through edit(root) (lxml, in place)."""
    from lxml import etree
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                root = etree.fromstring(data)
                edit(root)
                data = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
            zout.writestr(item, data)
    return out


def toy_fmu(tmp_path_factory) -> Path:
    """<tmp>/toy.fmu built from toy_model.toy_spec(), once per session (process)."""
    if "toy" not in _BUILT:
        from cedra.fmu.packaging import build_fmu
        from toy_model import toy_spec
        _BUILT["toy"] = Path(build_fmu(toy_spec(), tmp_path_factory.mktemp("toy_build")))
        _BUILT["unzip"] = Path(extract(str(_BUILT["toy"]), unzipdir=str(tmp_path_factory.mktemp("toy_unzip"))))
    return _BUILT["toy"]


class Toy:
    """One instance of the toy FMU. `call(name, *args)` returns the status name instead of raising."""

    def __init__(self, fmu_path: Path, name: str = "toy1", guid: str | None = None):
        self.md = read_model_description(str(fmu_path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.log: list[tuple[str, str, str]] = []         # (status, category, message)
        self.slave = FMU2Slave(guid=guid or self.md.guid, unzipDirectory=str(_BUILT["unzip"]),
                               modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.callbacks = cb
        self.time = 0.0

    def _logger(self, env, name, status, category, message):
        self.log.append((STATUS[status], category.decode(), message.decode().replace("%%", "%")))

    def messages(self, status=None) -> list[str]:
        return [m for s, _, m in self.log if status is None or s == status]

    def instantiate(self):
        self.slave.instantiate(callbacks=self.callbacks)

    def call(self, fn: str, *args, **kw) -> str:
        try:
            getattr(self.slave, fn)(*args, **kw)
            return "ok"
        except FMICallException as e:
            return STATUS[e.status]

    def start(self, values: dict | None = None, exit_init: bool = True):
        self.instantiate()
        self.slave.setupExperiment(startTime=0.0)
        self.slave.enterInitializationMode()
        self.set(values or {})
        if exit_init:
            self.slave.exitInitializationMode()
        self.time = 0.0
        return self

    def vr(self, name) -> int:
        return self.vars[name].valueReference

    def set(self, values: dict):
        for name, value in values.items():
            v = self.vars[name]
            {"Real": self.slave.setReal, "Integer": self.slave.setInteger,
             "Boolean": self.slave.setBoolean}[v.type]([v.valueReference], [value])

    def get(self, name):
        v = self.vars[name]
        return {"Real": self.slave.getReal, "Integer": self.slave.getInteger,
                "Boolean": self.slave.getBoolean}[v.type]([v.valueReference])[0]

    def outputs(self) -> dict:
        return {n: self.get(n) for n, v in self.vars.items() if v.causality == "output"}

    def step(self, h: float) -> str:
        st = self.call("doStep", currentCommunicationPoint=self.time, communicationStepSize=h)
        if st == "ok":
            self.time += h
        return st

    def run(self, t_end: float, h: float) -> list[dict]:
        out = []
        n = round((t_end - self.time) / h)
        t0 = self.time
        for k in range(1, n + 1):
            st = self.call("doStep", currentCommunicationPoint=self.time,
                           communicationStepSize=t0 + k * h - self.time)
            assert st == "ok", (st, self.log[-3:])
            self.time = t0 + k * h
            out.append(self.outputs())
        return out

    def close(self):
        self.call("terminate")
        self.slave.freeInstance()
