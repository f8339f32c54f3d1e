"""Rigid contact with several contacts per wheel and chassis contact, through the FMU: a wheel at a steep bump's foot
carries force at two contacts, the wheels' totals (along n_eff) balance the weight wherever the rover stands still,
no energy is gained that the motors did not supply; the chassis touching a narrow bump carries the load without
penetrating it (hung up). The paper's run itself (one maximum per wheel everywhere) is the rest of test_rigid.py."""
from pathlib import Path

import numpy as np
import pytest

from cedra.fmu.packaging import build_fmu
from cedra.models.scene import load, load_shipped
from cedra.run.simulate import run_bump
from cedra.sweep import variant

ROOT = Path(__file__).resolve().parents[1]
WEIGHT = (20 + 1 + 6 * 0.5) * 9.81          # the rover's weight (N): body, fork, six wheels
WHEELS = range(1, 7)
PER_WHEEL = ("Fn", "Fx", "psi", "contacts")


@pytest.fixture(scope="module")
def bump_fmu(tmp_path_factory):
    """bump2d_rigid with drives and chassis contact: the rigid climbing map's model"""
    scene = variant(Path("test.toml"), load_shipped("bump2d_rigid"), {"drives": True, "chassis": True})
    return build_fmu(scene.spec(), tmp_path_factory.mktemp("bump2d_rigid_cd"))


def run(fmu, stop, **values):
    extra = ["body.vx", "body.vz", "chassis.Fn", "chassis.clearance", "energy.kinetic", "energy.potential",
             "energy.work"] + [f"wheel[{k}].{q}" for k in WHEELS for q in PER_WHEEL] + \
        [f"wheel[{k}].contact[{j}].Fn" for k in WHEELS for j in (1, 2, 3)]
    names, rows, _, info = run_bump(fmu, stop_time=stop, settings=values, extra=extra)
    assert info["ok"], info["messages"]
    return {n: rows[:, i] for i, n in enumerate(names)}


def wheel_forces(r):
    """the wheels' total contact force in the world X-Z plane, from each wheel's Fn, Fx along the frame of n_eff
    (n_eff = (-sin psi, cos psi), x = (cos psi, sin psi))"""
    F = np.zeros((len(r["time"]), 2))
    for k in WHEELS:
        fn, fx, psi = r[f"wheel[{k}].Fn"], r[f"wheel[{k}].Fx"], r[f"wheel[{k}].psi"]
        F[:, 0] += -fn * np.sin(psi) + fx * np.cos(psi)
        F[:, 1] += fn * np.cos(psi) + fx * np.sin(psi)
    return F


def unpaid_energy(r):
    """the largest rise of K + P - motor work over any interval (J)"""
    E = r["energy.kinetic"] + r["energy.potential"] - r["energy.work"]
    return float(np.max(E - np.minimum.accumulate(E)))


def test_corner_has_two_contacts_and_the_totals_balance(bump_fmu):
    """A steep bump (w = R_w / 2, h = R_w, mu 0.8, drives): the bogie's wheel 2 meets its flank while on the ground
    (measured: from t = 6.2 s, 65 N on the flank at psi = 59 deg and 3.5 N on the ground) and the rover stops there.
    Wherever it stands still the wheels' totals (along n_eff) carry its weight (measured within 0.06 N of 235 N: the
    Baumgarte terms' share)."""
    r = run(bump_fmu, 8.0, terrain_w=0.0325, terrain_h=0.065, mu=0.8)
    two = r["wheel[2].contacts"] >= 2
    assert two.any()
    i = np.argmax(two)
    parts = [r[f"wheel[2].contact[{j}].Fn"][i] for j in (1, 2, 3)]
    assert sum(p > 1 for p in parts) == 2, parts
    still = (np.abs(r["body.vx"]) < 1e-6) & (np.abs(r["body.vz"]) < 1e-6) & (r["time"] > 1)
    assert still.sum() > 10
    F = wheel_forces(r)
    assert np.max(np.abs(F[still, 0])) < 1e-3 * WEIGHT
    assert np.max(np.abs(F[still, 1] - WEIGHT)) < 1e-3 * WEIGHT
    assert r["chassis.clearance"].min() > 0          # the chassis stays clear of this bump
    assert unpaid_energy(r) < 1e-3


def test_the_rigid_example_scenes_have_chassis_contact():
    """the rigid step and stairs maps' scenes (examples/scenes): rigid contact with chassis points and drives"""
    for name in ("step2d_rigid", "stairs2d_rigid"):
        scene = load(ROOT / "examples" / "scenes" / f"{name}.toml")
        assert scene.name == name and scene.solver["method"] == "moreau"
        assert scene.options.contact == "rigid" and scene.options.chassis and scene.options.drives


def test_chassis_hangs_up_on_a_narrow_bump(bump_fmu):
    """A Gaussian bump as narrow as the wheel (w = R_w) and 1.5 R_w high, mu 0.8, drives: the bogie's segment rides
    on it (as on compliant ground, docs/scenarios.md) and the rover stops with the chassis carrying most of its
    weight (measured: 178 N normal force of 235 N, the wheels 14 N), the points held on the terrain (clearance >=
    -1e-6 m), no energy gained."""
    r = run(bump_fmu, 12.0, terrain_w=0.065, terrain_h=0.0975, mu=0.8)
    last = r["time"] > 9
    assert np.all(np.abs(r["body.vx"][last]) < 1e-3)
    assert r["chassis.Fn"][last].mean() > 100
    assert r["chassis.clearance"].min() > -1e-6
    # the wheels carry the rest: less than the weight, the chassis' points sit on the bump's flank where their
    # friction holds part of the load (chassis.Fn is the normal forces alone)
    F = wheel_forces(r)
    assert np.all(F[last, 1] + r["chassis.Fn"][last] < WEIGHT)
    assert unpaid_energy(r) < 1e-3
