"""The rover FMU leaves its domain loudly: torques that flip the rover end in fmi2Discard naming the reason."""
import numpy as np

from cedra.run.driver import RoverFMU
from cedra.models.scene import load_shipped
from fmu_harness import shipped_fmu


def test_flipping_torque_is_a_loud_discard(tmp_path_factory):
    fmu = RoverFMU(shipped_fmu("bump2d", tmp_path_factory))
    fmu.start()
    fmu.set({f"tau[{i}]": 50.0 for i in range(1, 7)})     # 300 N.m of reaction torque on a 24 kg rover
    ok = True
    for k in range(1, 201):
        ok = fmu.step(k * 0.01)
        if not ok:
            break
        assert np.all(np.isfinite(fmu.get(["body.x", "body.z", "body.pitch"])))
    assert not ok and fmu.status == "discard"
    assert fmu.terminated()
    # The domain reason: the body tips over, or the front four-bar is driven past its toggle first (50 N.m
    # slams the fork through its lower stop). Which comes first depends on resolving the stop impacts at
    # t = 0.03-0.04 s: rodas4 at tol 1e-6 unlocated integrates across them and reaches "tipped over" at t = 0.095 s,
    # at tol 1e-7, 1e-8 and 1e-9 (and with switch location at 1e-6) the run drives the fork
    # into its toggle at t = 0.041 s. Either is a loud discard with the model's reason.
    assert any("tipped over" in m or "fork beyond its toggle" in m for m in fmu.messages), fmu.messages
    fmu.close()


def test_a_discarded_ros34pw2_step_leaves_the_kept_jacobian_as_it_was(tmp_path_factory):
    """ros34pw2 keeps its Jacobian in the FMU state (the last field before the checksum). A discarded step
    restores x, and the kept Jacobian with it: the state read after the discard holds the Jacobian of before."""
    from cedra.reports.common import Problem
    scene = load_shipped("bump2d")
    prob = Problem(scene)
    keep_bytes = 8 * (prob.nx * prob.nx + prob.nq * prob.nq)
    fmu = RoverFMU(shipped_fmu("bump2d", tmp_path_factory))
    fmu.start({"solver.method": 3})
    fmu.set({f"tau[{i}]": 50.0 for i in range(1, 7)})

    def kept():
        st = fmu.fmu.getFMUState()
        blob = bytes(fmu.fmu.serializeFMUState(st))
        fmu.fmu.freeFMUState(st)
        return blob[-8 - keep_bytes:-8]

    before, ok, changed = kept(), True, 0
    for k in range(1, 201):
        ok = fmu.step(k * 0.01)
        if not ok:
            break
        now = kept()
        changed += now != before
        before = now
    assert not ok and fmu.status == "discard"
    assert changed > 0                                  # the Jacobian does move from call to call
    assert kept() == before
    fmu.close()
