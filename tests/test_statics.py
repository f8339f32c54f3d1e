"""The quasi-static balance and rolling rates of any rover (cedra.mechanics.statics, docs/model.md, Controller,
traction control): formed from CEDRA's description it is CEDRA's own balance (cedra.rover.statics); formed from the
rocker-bogie's it gives the plant's settled loads on flat ground, and at a tilted pose its forces hold the whole
rover, each bogie about its pivot and the two rockers through their differential, computed from the description's
bodies and wheel centers alone."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from cedra.mechanics.statics import loads_given_tractions, rover_statics
from cedra.mechanics.transforms import rot_x, rot_y
from cedra.rover import statics as cedra_statics
from cedra.rover.mechanism import CEDRA
from cedra.rover.parameters import DEFAULTS as CEDRA_DEFAULTS
from cedra.rover.rocker_bogie import DEFAULTS, IDX, ROCKER_BOGIE
from cedra.run.driver import RoverFMU
from cedra.run.scenario import fmu as scenario_fmu

BUILD = Path(__file__).resolve().parents[1] / "build"
WEIGHT = (DEFAULTS["m_B"] + 6 * DEFAULTS["m_w"]) * DEFAULTS["g"]


def _cedra_pose(rng, dims):
    """A random CEDRA pose: pitch, roll, (theta1, theta2, theta4), steering, psi; 2D: no roll, no steering,
    the bogies together."""
    three = dims == "3d"
    theta = [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), CEDRA_DEFAULTS["fork_theta4_ref"] + rng.uniform(-0.2, 0.2)]
    if not three:
        theta[1] = theta[0]
    steer = rng.uniform(-0.4, 0.4, 2) if three else np.zeros(2)
    return rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2) if three else 0.0, theta, steer, rng.uniform(-0.6, 0.6, 6)


@pytest.mark.parametrize("dims", ["2d", "3d"])
def test_formed_from_cedras_description_it_is_cedras_balance(dims):
    """Random poses, motions and joint rates: A, b and the rolling rates of the generic form applied to CEDRA's
    RoverKind are rover.statics' (its contact frames from the paper's kinematics, its own free directions and
    wheel pairs) within 1e-9 (relative to the largest entry; measured about 1e-16)."""
    st = rover_statics(CEDRA, dims)
    assert st.groups == cedra_statics.GROUPS[dims] and st.multiplicity == cedra_statics.multiplicity(dims)
    par = [CEDRA_DEFAULTS[n] for n in st.params]
    own = [CEDRA_DEFAULTS[n] for n in cedra_statics.STATICS_PARAMS]
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(10):
        pitch, roll, theta, steer, psi = _cedra_pose(rng, dims)
        joints = [theta[0], theta[2]] if dims == "2d" else [*theta, *steer]
        velocity, omega, rates = rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.5, 0.5, 3), rng.uniform(-0.5, 0.5, 3)
        if dims == "2d":
            velocity[1], omega[0], omega[2], rates[1] = 0.0, 0.0, 0.0, rates[0]
        joint_rates = [rates[0], rates[2]] if dims == "2d" else [*rates, 0.0, 0.0]
        generic = [np.array(m) for m in st.balance(pitch, roll, joints, psi, par)]
        generic.append(np.array(st.rolling(pitch, roll, joints, psi, par, velocity, omega, joint_rates)))
        own_ = [np.array(m) for m in cedra_statics.balance(dims, pitch, roll, theta, steer, psi, own)]
        own_.append(np.array(cedra_statics.rolling_rates(dims, pitch, roll, theta, steer, psi, own, velocity, omega,
                                                         rates)))
        for g, o in zip(generic, own_):
            assert g.shape == o.shape
            worst = max(worst, float(np.abs(g - o).max() / np.abs(o).max()))
    print(f"{dims}: largest relative difference to rover.statics {worst:.1e}")
    assert worst < 1e-9


def _settled(plant):
    f = RoverFMU(scenario_fmu(plant, BUILD), "plant")
    try:
        f.start({})
        names = ["body.pitch", "body.roll", "rocker.rho", "bogie.beta[1]", "bogie.beta[2]"] + \
            [f"wheel[{i}].{q}" for i in range(1, 7) for q in ("psi_R", "Fn")]
        names = [n for n in names if f.has(n)]
        return {n: float(v) for n, v in zip(names, f.get(names))}
    finally:
        f.close()


@pytest.mark.parametrize("plant,dims", [("rb_bump2d", "2d"), ("rb_flat3d", "3d")])
def test_the_rocker_bogies_flat_ground_loads_are_the_plants_settled_loads(plant, dims):
    """At rest on flat ground (no traction) the rocker-bogie's balance gives the plant's settled wheel[i].Fn
    within 1 % and the loads sum to its weight."""
    v = _settled(plant)
    st = rover_statics(ROCKER_BOGIE, dims)
    joints = [v["bogie.beta[1]"]] if dims == "2d" else [v["rocker.rho"], v["bogie.beta[1]"], v["bogie.beta[2]"]]
    A, b = st.balance(v["body.pitch"], v.get("body.roll", 0.0), joints, [v[f"wheel[{i}].psi_R"] for i in range(1, 7)],
                      [DEFAULTS[n] for n in st.params])
    n0, _, a0, _ = (ca.evalf(x) for x in loads_given_tractions(ca.SX(A), ca.SX(b), len(st.groups), dims == "3d"))
    normal = np.array(n0).ravel()
    true = np.array([v[f"wheel[{i}].Fn"] for i in st.groups])
    print(f"{plant}: estimate {np.round(normal, 3)} N, plant {np.round(true, 3)} N, largest relative difference "
          f"{np.abs(normal / true - 1).max():.1e}")
    assert np.all(np.abs(normal / true - 1) < 0.01)
    assert abs(np.dot(st.multiplicity, normal) / WEIGHT - 1) < 1e-9
    assert abs(float(a0)) < 1e-6                           # m/s2: at rest, no traction, no acceleration


def _moment_about(pivot, axis, points, forces):
    return float(np.dot(axis, sum(np.cross(x - pivot, f) for x, f in zip(points, forces))))


def test_the_rocker_bogies_balance_holds_the_rover_its_bogies_and_rockers_at_a_tilted_pose():
    """Any forces that satisfy the 3D balance at a tilted pose within the joints' stops (pitch, roll, rocker,
    bogies, every wheel on its own contact angle) hold the whole rover (the contact forces, weights and d'Alembert
    forces -m a x sum to zero force and moment), each bogie with its two wheels about its pivot's axis, and the
    two rockers through the differential (rho turns the left rocker one way and the right one the other: their
    moments about the pivots' common axis are equal). The
    contact forces are formed here from the wheel centers, the body's axes and psi; nothing from the virtual
    work the balance is formed with."""
    st = rover_statics(ROCKER_BOGIE, "3d")
    p = {n: float(v) for n, v in DEFAULTS.items()}
    rng = np.random.default_rng(5)
    for _ in range(5):
        pitch, roll, rho, beta_l, beta_r = rng.uniform(-0.3, 0.3), *rng.uniform(-0.2, 0.2, 2), \
            *rng.uniform(-0.4, 0.4, 2)
        psi = rng.uniform(-0.6, 0.6, 6)
        A, b = (np.array(m) for m in st.balance(pitch, roll, [rho, beta_l, beta_r], psi, [p[n] for n in st.params]))
        u = np.linalg.lstsq(A, b.ravel(), rcond=None)[0] + np.linalg.svd(A)[2][-1] * 10.0
        assert np.allclose(A @ u, b.ravel(), atol=1e-9)
        N, T, L, a = u[0:6], u[6:12], u[12:18], u[18]
        q = np.zeros(len(IDX))
        for name, value in (("pitch", pitch), ("roll", roll), ("rho", rho), ("beta_L", beta_l), ("beta_R", beta_r)):
            q[IDX[name]] = value
        rover = ROCKER_BOGIE.describe(ca.DM(q), lambda e: ca.DM.zeros(e.shape), p, ca.DM.zeros(6))
        R = np.array(rot_y(pitch) @ rot_x(roll), dtype=float)
        up, axle = R[:, 2], R[:, 1]
        centers = [np.array(w.center, dtype=float).ravel() for w in rover.wheels]
        points, forces = [], []
        for i in range(6):
            n = np.cos(psi[i]) * up + np.sin(psi[i]) * np.cross(axle, up)
            points.append(centers[i] - p["R_w"] * n)
            forces.append(N[i] * n + T[i] * np.cross(axle, n) + L[i] * axle)
        per_mass = np.array([-a, 0.0, -p["g"]])               # weight and d'Alembert force per unit mass
        masses = [(float(bd.mass), np.array(bd.position, dtype=float).ravel()) for bd in rover.bodies]
        force = sum(forces) + sum(m * per_mass for m, _ in masses)
        moment = sum(np.cross(x, f) for x, f in zip(points, forces)) + sum(np.cross(c, m * per_mass) for m, c in masses)
        # each side's wheels (1-3 left, 4-6 right) with their contact forces and their wheels' own weights
        side = {s: ([points[k] for k in ks] + [centers[k] for k in ks],
                    [forces[k] for k in ks] + [p["m_w"] * per_mass] * 3) for s, ks in (("L", (0, 1, 2)),
                                                                                     ("R", (3, 4, 5)))}
        world = R @ np.array([p["rocker_x"], p["rocker_y"], p["rocker_z"]])
        pivots = {"L": world, "R": R @ np.array([p["rocker_x"], -p["rocker_y"], p["rocker_z"]])}
        bogie = {}
        for s, r in (("L", rho), ("R", -rho)):
            qp = np.array([p["rocker_x"], p["rocker_y"] * (1 if s == "L" else -1), p["rocker_z"]])
            pivot = np.array([p["bogie_x"], qp[1], p["bogie_z"]])
            at = R @ (qp + np.array(rot_y(-r), dtype=float) @ (pivot - qp))
            pts, fs = side[s]
            bogie[s] = _moment_about(at, axle, pts[1:3] + pts[4:6], fs[1:3] + fs[4:6])
        rockers = {s: _moment_about(pivots[s], axle, *side[s]) for s in side}
        print(f"residual force {np.abs(force).max():.1e} N, moment {np.abs(moment).max():.1e} N.m, bogies "
              f"{bogie['L']:.1e}, {bogie['R']:.1e} N.m, differential {rockers['L'] - rockers['R']:.1e} N.m "
              f"(rocker moment {rockers['L']:.2f} N.m)")
        tol = 1e-9 * WEIGHT
        assert np.abs(force).max() < tol and np.abs(moment).max() < tol
        assert abs(bogie["L"]) < tol and abs(bogie["R"]) < tol
        assert abs(rockers["L"] - rockers["R"]) < tol
