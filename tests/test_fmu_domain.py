"""The rover FMU leaves its domain loudly: torques that flip the rover end in fmi2Discard naming the reason."""
import numpy as np

from cedra.run.driver import RoverFMU
from cedra.fmu.packaging import build_fmu
from cedra.models.scene import load_shipped


def test_flipping_torque_is_a_loud_discard(tmp_path):
    fmu = RoverFMU(build_fmu(load_shipped("bump2d").spec(), tmp_path))
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
    assert any("tipped over" in m for m in fmu.messages), fmu.messages
    fmu.close()
