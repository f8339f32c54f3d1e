"""Rigid contact (the paper's decision tree) through the FMU: equilibrium against the stiff compliant ground,
Coulomb sliding on a steep ramp, sticking on a shallow one, the friction cone and slip law at every output,
lift-off and touch-down (a drop), constraint drift over the bump run."""
import math

import numpy as np
import pytest

from cedra.driver import RoverFMU
from cedra.fmu import build_fmu
from cedra.scene import load_shipped, parse
from cedra.simulate import SpeedController

WHEELS = range(1, 7)


def build(tmp_path_factory, data):
    scene = parse(data)
    return build_fmu(scene.spec(), tmp_path_factory.mktemp(scene.name))


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    ramp = dict(dims="2d", terrain="slope", contact="rigid", locked_wheels=True)
    return {
        "rigid": build_fmu(load_shipped("bump2d_rigid").spec(), tmp_path_factory.mktemp("r")),
        "compliant": build_fmu(load_shipped("bump2d").spec(), tmp_path_factory.mktemp("c")),
        "ramp": build(tmp_path_factory, dict(name="ramp_rigid", **ramp)),
    }


def names(q):
    return [f"wheel[{i}].{q}" for i in WHEELS]


def loads(path, values=None):
    f = RoverFMU(path)
    f.start(values or {})
    out = f.get(names("Fn"))
    f.close()
    return out


def test_static_equilibrium_matches_stiff_compliant_ground(fmus):
    weight = (20 + 1 + 6 * 0.5) * 9.81
    rigid = loads(fmus["rigid"])
    stiff = loads(fmus["compliant"], {"ground_k": 1e7, "ground_d": 6e3})
    assert abs(rigid.sum() - weight) < 1e-6 * weight
    assert abs(stiff.sum() - weight) < 1e-9 * weight
    assert np.all(np.abs(rigid - stiff) <= 0.01 * stiff), (rigid, stiff)


def slide(path, slope, mu, t_end=1.0):
    f = RoverFMU(path)
    f.start({"terrain_slope": slope, "mu": mu})
    x, v, modes = [], [], []
    for k in range(1, int(round(t_end / 0.01)) + 1):
        assert f.step(k * 0.01), f.messages
        x.append(f.get(["body.x"])[0])
        v.append(f.get(["body.vx"])[0])
        modes.append(f.get(names("mode")))
    f.close()
    return np.array(x), np.array(v), np.array(modes)


def test_locked_wheels_slide_with_coulomb_deceleration_on_a_steep_ramp(fmus):
    slope, mu = 0.3, 0.2                       # tan(0.3) = 0.309 > mu
    x, v, modes = slide(fmus["ramp"], slope, mu)
    # every wheel on the ground slips (the rear one lifts: friction at ground level pitches the body forward)
    assert np.all(modes[5:] != 1) and np.all((modes[5:] == 2).sum(axis=1) >= 5)
    # along the ramp: a = g (sin s - mu cos s); body.vx is the horizontal component (after the 0.1 s start)
    a_expected = 9.81 * (math.sin(slope) - mu * math.cos(slope)) * math.cos(slope)
    t = (np.arange(len(v)) + 1) * 0.01
    a = np.polyfit(t[10:], v[10:], 1)[0]
    assert abs(a - a_expected) < 1e-3 * a_expected, (a, a_expected)


def test_locked_wheels_stick_on_a_shallow_ramp(fmus):
    x, v, modes = slide(fmus["ramp"], 0.1, 0.5)   # tan(0.1) = 0.100 < mu
    # the bogie wheels stick; the light rear and front wheels (5, 6) may sit at their cone with zero speed
    # (the holding force is statically indeterminate; the solver takes the near minimum-norm split)
    assert np.all(modes[:, :4] == 1)
    assert abs(x[-1] - x[0]) < 1e-9 and np.max(np.abs(v)) < 1e-9


def bump_run(path, stop=8.0):
    f = RoverFMU(path)
    f.start()
    ctrl = SpeedController()
    rows = []
    want = names("Fn") + names("Fx") + names("Fy") + names("mode") + names("slip") + names("gap")
    for k in range(1, int(round(stop / 0.01)) + 1):
        tau = ctrl(f.get(["body.vx"])[0])
        f.set({f"tau[{i}]": tau for i in WHEELS})
        assert f.step(k * 0.01), f.messages
        rows.append(f.get(want))
    out = f.get(["body.x"])[0]
    f.close()
    r = np.array(rows).reshape(len(rows), 6, 6)
    return out, {q: r[:, j, :] for j, q in enumerate(("Fn", "Fx", "Fy", "mode", "slip", "gap"))}


def test_bump_run_cone_slip_law_and_drift(fmus):
    x_end, d = bump_run(fmus["rigid"])
    # the run reaches the bump (front wheels on it from X ~ 0.6). Whether the rigid rover then gets over it in
    # 8 s is NOT asserted: at the bump the outcome is hypersensitive (the rear wheel chatters between slip and
    # airborne under saturated torque; round-off-level changes decide between passing and getting stuck), the
    # open problem of issue 4 (README, "Rigid contact")
    assert x_end > 0.7
    mu = 0.8
    Fn, Ft = d["Fn"], np.hypot(d["Fx"], d["Fy"])
    mode = d["mode"]
    assert np.all(Fn >= 0)
    stick, slip, air = mode == 1, mode == 2, mode == 0
    assert np.all(Ft[stick] <= mu * Fn[stick] * (1 + 1e-9) + 1e-9)
    assert np.all(np.abs(Ft[slip] - mu * Fn[slip]) <= 1e-9 * np.maximum(1, Fn[slip]))
    assert np.all(Fn[air] == 0)
    assert air.any() and slip.any() and stick.any()     # the run exercises every mode
    drift = np.max(np.abs(d["gap"][~air]))
    # penetrations are projected out after every step (Gauss-Newton); a wheel counts as touching up to
    # gap_tol = 1 um above the ground, so that bounds the drift on that side by construction
    assert drift < 1e-6, drift


def test_drop_touches_down_and_settles(fmus):
    f = RoverFMU(fmus["rigid"])
    f.start({"start.settle": False, "start.z": 0.3, "start.theta4": -0.1418970546})
    first = f.get(names("mode"))
    assert np.all(first == 0)                            # airborne at the start
    for k in range(1, 201):
        assert f.step(k * 0.01), f.messages
    end = f.get(names("mode") + names("Fn") + ["body.vz"])
    f.close()
    assert np.all(end[:6] > 0)                           # all wheels down
    assert abs(end[6:12].sum() - 24 * 9.81) < 1e-3 * 24 * 9.81
    assert abs(end[-1]) < 1e-6
