"""The drive system as an SSP package: the SSD validates against FMPy's SSP schemas, the
package runs unchanged in FMPy's SSP simulator and in libcosim, the project's master set to either master's
convention reproduces that master's run, and the two masters agree on the body's path."""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from cedra.run import scenario
from cedra.run import ssp
from cedra.run.cosim import DriveLoop

BUILD = Path(__file__).resolve().parents[1] / "build"
STOP, STEP = 4.0, 0.01


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    """turn_flat: flat3d + drive3d turning at 0.2 m/s, 0.3 rad/s."""
    plant_name, ctrl_name, pv, cv = ssp.SYSTEMS["turn_flat"]
    paths = {name: scenario.fmu(name, BUILD) for name in (plant_name, ctrl_name)}
    out = tmp_path_factory.mktemp("ssp") / "turn_flat.ssp"
    return ssp.write_ssp(out, paths[plant_name], paths[ctrl_name], pv, cv, stop_time=STOP), paths, pv, cv


def test_the_ssd_validates_and_connects_name_to_name(system):
    path, paths, _, _ = system
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        data = z.read("SystemStructure.ssd")
    assert {"SystemStructure.ssd", "resources/flat3d.fmu", "resources/drive3d.fmu"} <= names
    assert ssp.validate_ssd(data) == []
    links = ssp.connections(ssp._variables(paths["flat3d"]), ssp._variables(paths["drive3d"]))
    assert all(a == b for _, a, _, b in links)
    assert {"tau[1]", "steer[2]", "wheel[6].psi_R", "body.wz"} <= {a for _, a, _, _ in links}
    # a broken SSD is caught by the same check
    assert ssp.validate_ssd(data.replace(b"startConnector", b"beginConnector"))


def _path_distance(p, q):
    """Largest distance from a point of one polyline to the other polyline (both ways)."""
    def one_way(a, b):
        d = np.full(len(a), np.inf)
        for i in range(len(b) - 1):
            s = b[i + 1] - b[i]
            t = np.clip(((a - b[i]) @ s) / (s @ s), 0, 1)
            d = np.minimum(d, np.linalg.norm(a - (b[i] + t[:, None] * s), axis=1))
        return d.max()
    return max(one_way(p, q), one_way(q, p))


def test_masters_run_the_package_and_the_project_master_reproduces_each(system):
    path, paths, pv, cv = system
    runs = {"fmpy-ssp": ssp.run_fmpy(path, STOP, STEP), "libcosim": ssp.run_libcosim(path, STOP, STEP)}
    xy = {}
    for convention, ref in runs.items():
        loop = DriveLoop(paths["flat3d"], paths["drive3d"], pv, cv, convention=convention)
        try:
            r = loop.run(STOP, STEP, record=["body.x", "body.y"])
        finally:
            loop.close()
        assert r.ok, r.messages[-3:]
        for name in ("body.x", "body.y"):
            ours, theirs = r.column(name)[1:], ref[f"plant.{name}"]
            assert len(ours) == len(theirs), convention
            assert np.max(np.abs(ours - theirs)) <= 1e-9, (convention, name)
        xy[convention] = np.c_[ref["plant.body.x"], ref["plant.body.y"]]
        assert np.hypot(*(xy[convention][-1] - xy[convention][0])) > 0.3     # the rover went somewhere
    n = min(len(v) for v in xy.values())
    dist = _path_distance(xy["fmpy-ssp"][:n], xy["libcosim"][:n])
    print(f"FMPy vs libcosim: body path within {dist:.2e} m")
    assert dist <= 1e-4
