"""The FMI 2.0 CS glue on the toy FMU: FMU state, serialization, reset, argument and call-order checks with
their logged messages, discarded steps."""
from __future__ import annotations

import ctypes
import math

import pytest

from fmu_harness import Toy


DRIVE = {"F": 8.0}          # above the friction limit mu m g = 4.9 N: the mass slides


def test_outputs_at_init_are_settled_and_finite(inst):
    inst.start(exit_init=False)
    z_init = inst.get("pos.z")                     # computed on demand in initialization mode
    inst.slave.exitInitializationMode()
    out = inst.outputs()
    assert all(math.isfinite(v) for v in out.values())
    assert out["pos.z"] == z_init
    assert out["Fn"] == pytest.approx(9.81, rel=1e-10)          # static equilibrium: ground_k * pen = m g
    assert out["pos.z"] == pytest.approx(-9.81 / 1e4, rel=1e-10)
    assert out["contact"] == 1 and out["mass"] == 1.0 and out["force"] == 0.0
    assert out["solver.steps"] == 0


def test_no_settle_keeps_the_start_pose(inst):
    inst.start({"start.settle": False, "start.z": 0.2, "start.speed.x": 1.5, "m": 2.0})
    assert inst.get("pos.z") == 0.2 and inst.get("vel.x") == 1.5 and inst.get("contact") == 0
    assert inst.get("mass") == 2.0


def test_get_set_fmu_state_is_bit_identical(inst):
    inst.start(DRIVE)
    inst.run(0.2, 0.01)
    st = inst.slave.getFMUstate()
    t0 = inst.time
    a = inst.run(0.5, 0.01)
    inst.slave.setFMUstate(st)
    inst.time = t0
    assert inst.get("solver.steps") == inst.slave.getInteger([inst.vr("solver.steps")])[0]
    b = inst.run(0.5, 0.01)
    assert a == b
    inst.slave.freeFMUstate(st)


def test_serialized_state_restores_in_another_instance(toy, inst):
    inst.start(DRIVE)
    inst.run(0.1, 0.01)
    st = inst.slave.getFMUstate()
    data = inst.slave.serializeFMUstate(st)
    inst.slave.freeFMUstate(st)
    a = inst.run(0.3, 0.01)
    other = Toy(toy, name="toy2")
    try:
        other.start()
        st2 = other.slave.deSerializeFMUstate(data)
        other.slave.setFMUstate(st2)
        other.slave.freeFMUstate(st2)
        other.time = 0.1
        assert other.get("force") == 8.0
        assert other.run(0.3, 0.01) == a
        # a truncated buffer is refused
        with pytest.raises(Exception):
            other.slave.deSerializeFMUstate(data[:-1])
        assert any("size" in m for m in other.messages("error"))
    finally:
        other.close()


def test_reset_equals_a_fresh_instance(toy, inst):
    inst.start({"F": 3.0, "mu": 0.1, "solver.method": 2})
    inst.run(0.1, 0.01)
    inst.slave.reset()
    inst.slave.setupExperiment(startTime=0.0)
    inst.slave.enterInitializationMode()
    inst.set(DRIVE)
    inst.slave.exitInitializationMode()
    inst.time = 0.0
    a = inst.run(0.2, 0.01)
    fresh = Toy(toy, name="fresh")
    try:
        fresh.start(DRIVE)
        assert fresh.run(0.2, 0.01) == a
    finally:
        fresh.close()


@pytest.mark.parametrize("name,value,message", [
    ("F", float("nan"), "fmi2SetReal: variable F (vr 7) = nan is not finite"),
    ("F", float("inf"), "fmi2SetReal: variable F (vr 7) = inf is not finite"),
    ("m", -1.0, "fmi2SetReal: variable m (vr 0) = -1 must be >= 1.0000000000000001e-09"),
    ("solver.tol", -1e-6, "fmi2SetReal: variable solver.tol (vr 25) = -9.9999999999999995e-07 must be > 0"),
    ("solver.tol", 0.0, "fmi2SetReal: variable solver.tol (vr 25) = 0 must be > 0"),
    ("solver.h_max", 0.0, "fmi2SetReal: variable solver.h_max (vr 26) = 0 must be > 0"),
    ("solver.method", 7, "fmi2SetInteger: variable solver.method (vr 24) = 7 must be <= 3"),
    ("F", 2e4, "fmi2SetReal: variable F (vr 7) = 20000 must be <= 10000"),
])
def test_bad_values_are_refused_with_a_message(inst, name, value, message):
    inst.start(exit_init=False)
    before = inst.get(name)
    fn = "setInteger" if isinstance(value, int) else "setReal"
    assert inst.call(fn, [inst.vr(name)], [value]) == "error"
    assert inst.messages("error") == [message]
    assert inst.get(name) == before                     # no effect
    inst.slave.exitInitializationMode()
    assert inst.step(0.01) == "ok"


def test_call_order_is_checked(inst):
    inst.start(exit_init=False)
    assert inst.call("doStep", currentCommunicationPoint=0.0, communicationStepSize=0.01) == "error"
    assert inst.messages("error")[-1] == "fmi2DoStep: not allowed in state initialization mode"
    inst.slave.exitInitializationMode()
    assert inst.call("setReal", [inst.vr("m")], [2.0]) == "error"
    assert inst.messages("error")[-1] == ("fmi2SetReal: parameter m (vr 0) is fixed: it can be set only before "
                                          "fmi2ExitInitializationMode")
    assert inst.call("exitInitializationMode") == "error"
    assert inst.messages("error")[-1] == "fmi2ExitInitializationMode: not allowed in state step complete"
    assert inst.call("setReal", [inst.vr("pos.x")], [1.0]) == "error"
    assert inst.messages("error")[-1] == ("fmi2SetReal: variable pos.x (vr 8) is an output (calculated), "
                                          "it cannot be set")
    assert inst.call("doStep", currentCommunicationPoint=0.0, communicationStepSize=0.0) == "error"
    assert inst.messages("error")[-1] == "fmi2DoStep: communicationStepSize = 0 must be > 0"
    assert inst.call("doStep", currentCommunicationPoint=0.5, communicationStepSize=0.01) == "error"
    assert inst.messages("error")[-1].startswith("fmi2DoStep: currentCommunicationPoint = 0.5, but the FMU is at t=0")
    inst.set({"F": 1.0})                                # inputs stay settable
    assert inst.step(0.01) == "ok"
    inst.slave.terminate()
    assert inst.call("doStep", currentCommunicationPoint=0.01, communicationStepSize=0.01) == "error"
    assert inst.messages("error")[-1] == "fmi2DoStep: not allowed in state terminated"


def test_unknown_value_references_and_wrong_types(inst):
    inst.start()
    for fn, args in (("getReal", ([123],)), ("setReal", ([123], [1.0])), ("getInteger", ([123],)),
                     ("getBoolean", ([123],))):
        assert inst.call(fn, *args) == "error"
        assert inst.messages("error")[-1] == f"fmi2{fn[0].upper()}{fn[1:]}: unknown value reference 123"
    assert inst.call("getReal", [inst.vr("contact")]) == "error"
    assert inst.messages("error")[-1] == "fmi2GetReal: variable contact (vr 18) is an Integer"
    assert inst.call("getInteger", [inst.vr("pos.x")]) == "error"
    assert inst.messages("error")[-1] == "fmi2GetInteger: variable pos.x (vr 8) is a Real"
    assert inst.call("getString", [inst.vr("pos.x")]) == "error"
    assert inst.messages("error")[-1] == "fmi2GetString: variable pos.x (vr 8) is not a String"


def test_unsupported_functions_return_error(inst):
    inst.start()
    vr = (ctypes.c_uint * 1)(inst.vr("pos.x"))
    dv = (ctypes.c_double * 1)(1.0)
    out = (ctypes.c_double * 1)()
    fn = inst.slave.dll.fmi2GetDirectionalDerivative
    assert fn(inst.slave.component, vr, 1, vr, 1, dv, out) == 3
    assert inst.messages("error")[-1] == ("fmi2GetDirectionalDerivative: not supported "
                                          "(providesDirectionalDerivative=false)")
    assert inst.call("cancelStep") == "error"
    assert inst.call("getRealOutputDerivatives", [inst.vr("pos.x")], [1]) == "error"


def test_a_state_the_model_refuses_discards_and_terminates(inst):
    from fmpy.fmi2 import fmi2LastSuccessfulTime, fmi2Terminated
    inst.start({"x_max": 0.05, "F": 100.0})      # pushed out of the workspace |x| < x_max within ~0.05 s
    t_good, last = 0.0, None
    for _ in range(100):
        before = inst.outputs()
        st = inst.step(0.01)
        if st != "ok":
            break
        t_good, last = inst.time, inst.outputs()
    assert st == "discard"
    assert 0 < t_good < 0.2
    assert inst.slave.getBooleanStatus(fmi2Terminated) is True
    assert inst.slave.getRealStatus(fmi2LastSuccessfulTime) == t_good
    msg = inst.messages("discard")
    assert len(msg) == 1 and msg[0].startswith("fmi2DoStep: step discarded at t=")
    assert float(msg[0].split("t=")[1].split(",")[0]) == t_good
    assert "cedra_check" in msg[0]
    # outputs are those of the last good step, never NaN (the solver counters include the failed attempt)
    model_outputs = lambda d: {k: v for k, v in d.items() if not k.startswith("solver.")}  # noqa: E731
    assert model_outputs(inst.outputs()) == model_outputs(before) == model_outputs(last)
    assert abs(inst.get("pos.x")) < 0.05
    # no further steps
    assert inst.call("doStep", currentCommunicationPoint=inst.time, communicationStepSize=0.01) == "error"
    assert "terminated" in inst.messages("error")[-1]
    inst.slave.terminate()


def test_solver_blow_up_discards(inst):
    from fmpy.fmi2 import fmi2Terminated
    # RK4 with a step far beyond its stability limit on a very stiff, damped ground: the state explodes
    inst.start({"solver.method": 0, "solver.h_max": 0.05, "ground_k": 1e8, "ground_d": 1e5, "start.speed.z": -0.1,
                "F": 8.0})
    statuses = [inst.step(0.05) for _ in range(10)]
    assert statuses[:2] == ["ok", "discard"] and set(statuses[2:]) == {"error"}, statuses
    assert "rk4: the right-hand side failed" in inst.messages("discard")[0], inst.messages("discard")
    assert inst.slave.getBooleanStatus(fmi2Terminated) is True
    assert all(math.isfinite(v) for v in inst.outputs().values())
