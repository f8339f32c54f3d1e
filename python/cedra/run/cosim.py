"""The project's own co-simulation master: a plant FMU and the drive controller FMU (cedra.models.controller) connected
name to name, stepped with a fixed communication step h. Conventions:

  "plant-first" (Gauss-Seidel, the default): the plant steps [t, t + h] with the controller's held outputs, then
                the controller gets the plant's outputs at t + h and takes its sample there, so the torque applied
                over [t, t + h] is computed from y(t): the paper's run's loop (docs/model.md), no delay.
  "jacobi"      both FMUs step from the values both had at t (the sample at t + h then uses y(t)): one step of
                delay; the controller's sample 0 sees the plant's settled start.
  "fmpy-ssp"    what FMPy's SSP simulator does (fmpy.ssp.simulation): Jacobi, every connection starts at 0 (the
                first step feeds the controller zeros and the plant zero torques; sample 0 sees the controller's
                own start values), time advances by t += h.
  "libcosim"    what OSP libcosim's fixed-step master does: Jacobi, time in integer nanoseconds (t_k = k h_ns
                / 1e9), the initial outputs passed to the connected inputs after initialization.
Set to a master's convention, this master reproduces that master's run of the same SSP package (cedra.run.ssp).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from cedra.run.driver import RoverFMU

CONVENTIONS = ("plant-first", "jacobi", "fmpy-ssp", "libcosim")


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
                 controller_values: dict | None = None, convention: str = "plant-first"):
        if convention not in CONVENTIONS:
            raise ValueError(f"convention {convention!r}: one of {', '.join(CONVENTIONS)}")
        self.plant, self.ctrl = RoverFMU(plant_fmu, "plant"), RoverFMU(controller_fmu, "controller")
        self.plant_values, self.controller_values = dict(plant_values or {}), dict(controller_values or {})
        self.convention = convention
        inputs = lambda f: {n for n, v in f.vars.items() if v.causality == "input"}      # noqa: E731
        outputs = lambda f: {n for n, v in f.vars.items() if v.causality == "output"}    # noqa: E731
        self.measured = sorted(outputs(self.plant) & inputs(self.ctrl))     # plant -> controller
        self.commanded = sorted(outputs(self.ctrl) & inputs(self.plant))    # controller -> plant
        optional = {"cmd.v", "cmd.yaw_rate"}
        if not self.plant.has("steer[1]"):     # a plant without steering: the controller reads straight wheels
            optional |= {"steer.theta[1]", "steer.theta[2]"}
        missing = inputs(self.ctrl) - optional - set(self.measured)
        if missing:
            raise ValueError(f"the plant does not give the controller's inputs {sorted(missing)}")
        if "tau[1]" not in self.commanded:
            raise ValueError("the controller's torques have no plant inputs to go to")

    def _measure(self):
        self.ctrl.set(dict(zip(self.measured, self.plant.get(self.measured))))

    def _command(self):
        self.plant.set(dict(zip(self.commanded, self.ctrl.get(self.commanded))))

    def _commands(self, t, commands):
        if commands is not None:
            self.ctrl.set({k: v for k, v in commands(t).items() if self.ctrl.has(k)})

    def _times(self, stop_time: float, dt: float) -> list[float]:
        """The communication points as the convention's master computes them."""
        if self.convention == "fmpy-ssp":      # `while time < stop_time: ... time += step_size`
            ts = [0.0]
            while ts[-1] < stop_time:
                ts.append(ts[-1] + dt)
            return ts
        n = int(round(stop_time / dt))
        if self.convention == "libcosim":
            ns = round(dt * 1e9)
            return [k * ns / 1e9 for k in range(n + 1)]
        return [k * dt for k in range(n + 1)]

    def _start(self, commands):
        self.plant.start(self.plant_values)
        self.ctrl.fmu.instantiate(callbacks=self.ctrl._callbacks)
        self.ctrl.fmu.setupExperiment(startTime=0.0)
        self.ctrl.set(self.controller_values)
        self._commands(0.0, commands)
        self.ctrl.fmu.enterInitializationMode()
        if self.convention != "fmpy-ssp":                      # sample 0 from the plant's settled start
            self._measure()
        self.ctrl.fmu.exitInitializationMode()
        self.ctrl.time = self.plant.time = 0.0
        if self.convention == "fmpy-ssp":                      # every connection starts at 0
            self.ctrl.set({n: 0.0 for n in self.measured})
            self.plant.set({n: 0.0 for n in self.commanded})
        else:
            self._command()

    def run(self, stop_time: float, dt: float, commands: Callable[[float], dict] | None = None, record=(),
            progress: Callable[[float], None] | None = None) -> LoopResult:
        """Run to stop_time with communication step dt; `commands(t)` (optional) sets the controller's command
        inputs (cmd.v, cmd.yaw_rate) at each communication point, else the controller's values stay."""
        record = [n for n in record if self.plant.has(n) or self.ctrl.has(n)]
        wall = time.perf_counter()
        self._start(commands)
        ts = self._times(stop_time, dt)
        n = len(ts) - 1
        rows, ok = [], True
        for k in range(n + 1):
            rows.append(np.concatenate([[ts[k]], self._values(record)]))
            if k == n:
                break
            h = ts[k + 1] - ts[k] if self.convention != "fmpy-ssp" else dt
            if self.convention == "plant-first":
                ok = self._step(self.plant, ts[k], h)
                if ok:
                    self._measure()
                    self._commands(ts[k + 1], commands)
                    ok = self._step(self.ctrl, ts[k], h)
                    self._command()
            else:
                self._commands(ts[k], commands)
                ok = self._step(self.plant, ts[k], h) and self._step(self.ctrl, ts[k], h)
                self._measure()
                self._command()
            if not ok:
                break
            if progress:
                progress(ts[k + 1])
        return LoopResult(["time"] + record, np.array(rows), ok, time.perf_counter() - wall,
                          self.plant.messages + self.ctrl.messages)

    @staticmethod
    def _step(fmu: RoverFMU, t: float, h: float) -> bool:
        """fmi2DoStep(t, h) exactly as given (the convention decides both numbers)."""
        from fmpy.fmi1 import FMICallException
        try:
            fmu.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        except FMICallException:
            fmu.status = "failed"
            return False
        fmu.time = t + h
        return True

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
