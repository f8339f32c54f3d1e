"""The project's own co-simulation master: a plant FMU and the drive controller FMU (cedra.controller) connected
name to name, stepped with a fixed communication step.

Order "plant-first" (Gauss-Seidel): at each communication point t the plant steps [t, t + h] with the controller's
held outputs, then the controller gets the plant's outputs at t + h and takes its sample there, so the torque
applied over [t, t + h] is computed from y(t): the spec section 10 loop, no delay. Order "jacobi": both FMUs step
from the outputs both had at t (the controller's sample at t + h then uses y(t)): one communication step of
delay, what masters that step every FMU from the same values do.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .driver import RoverFMU

ORDERS = ("plant-first", "jacobi")


@dataclass
class LoopResult:
    names: list[str]
    rows: np.ndarray             # one row per communication point: time, then `names[1:]`
    ok: bool
    wall: float
    messages: list[str] = field(default_factory=list)

    def column(self, name) -> np.ndarray:
        return self.rows[:, self.names.index(name)]


class DriveLoop:
    """plant + controller; `commands(t)` gives the controller's command inputs (cmd.v, cmd.yaw_rate) at t."""

    def __init__(self, plant_fmu, controller_fmu, plant_values: dict | None = None,
                 controller_values: dict | None = None, order: str = "plant-first"):
        if order not in ORDERS:
            raise ValueError(f"order {order!r}: one of {', '.join(ORDERS)}")
        self.plant, self.ctrl = RoverFMU(plant_fmu, "plant"), RoverFMU(controller_fmu, "controller")
        self.plant_values, self.controller_values = dict(plant_values or {}), dict(controller_values or {})
        self.order = order
        inputs = lambda f: {n for n, v in f.vars.items() if v.causality == "input"}      # noqa: E731
        outputs = lambda f: {n for n, v in f.vars.items() if v.causality == "output"}    # noqa: E731
        self.measured = sorted(outputs(self.plant) & inputs(self.ctrl))     # plant -> controller
        self.commanded = sorted(outputs(self.ctrl) & inputs(self.plant))    # controller -> plant
        missing = {n for n in inputs(self.ctrl) if not n.startswith("cmd.")} - set(self.measured)
        if missing:
            raise ValueError(f"the plant does not give the controller's inputs {sorted(missing)}")
        if "tau[1]" not in self.commanded:
            raise ValueError("the controller's torques have no plant inputs to go to")

    def _measure(self):
        self.ctrl.set(dict(zip(self.measured, self.plant.get(self.measured))))

    def _command(self):
        self.plant.set(dict(zip(self.commanded, self.ctrl.get(self.commanded))))

    def run(self, stop_time: float, dt: float, commands: Callable[[float], dict], record=(),
            progress: Callable[[float], None] | None = None) -> LoopResult:
        record = [n for n in record if self.plant.has(n) or self.ctrl.has(n)]
        wall = time.perf_counter()
        self.plant.start(self.plant_values)
        cmd = {k: v for k, v in commands(0.0).items() if self.ctrl.has(k)}
        self.ctrl.fmu.instantiate(callbacks=self.ctrl._callbacks)
        self.ctrl.fmu.setupExperiment(startTime=0.0)
        self.ctrl.fmu.enterInitializationMode()
        self.ctrl.set(self.controller_values | cmd)
        self._measure()                                   # sample 0 from the plant's settled start
        self.ctrl.fmu.exitInitializationMode()
        self._command()
        rows, ok = [], True
        n = int(round(stop_time / dt))
        for k in range(n + 1):
            t = k * dt
            rows.append(np.concatenate([[t], self._values(record)]))
            if k == n:
                break
            if self.order == "jacobi":
                self._measure()
                self.ctrl.set({kk: v for kk, v in commands(t).items() if self.ctrl.has(kk)})
                ok = self.plant.step((k + 1) * dt) and self.ctrl.step((k + 1) * dt)
                self._command()
            else:
                ok = self.plant.step((k + 1) * dt)
                if ok:
                    self._measure()
                    self.ctrl.set({kk: v for kk, v in commands((k + 1) * dt).items() if self.ctrl.has(kk)})
                    ok = self.ctrl.step((k + 1) * dt)
                    self._command()
            if not ok:
                break
            if progress:
                progress((k + 1) * dt)
        result = LoopResult(["time"] + record, np.array(rows), ok, time.perf_counter() - wall,
                            self.plant.messages + self.ctrl.messages)
        return result

    def _values(self, names) -> np.ndarray:
        """Plant outputs from the plant, everything else from the controller (one get per FMU)."""
        from_plant = [self.plant.has(n) and self.plant.vars[n].causality == "output" for n in names]
        out = np.empty(len(names))
        idx = [k for k, p in enumerate(from_plant) if p]
        out[idx] = self.plant.get([names[k] for k in idx])
        idx = [k for k, p in enumerate(from_plant) if not p]
        out[idx] = self.ctrl.get([names[k] for k in idx])
        return out

    def close(self):
        self.plant.close()
        self.ctrl.close()
