"""The rover's drawing points (the animation and the 3D view of cedra.run.watch), from a run's recorded outputs.

A run records the body pose, the joint angles and the wheels' spin rates; the points to draw (body box corners,
bogie pivots, the four-bar's A, B, C, D, wheel centers, axles and a spoke per wheel) follow from them with the
chains of docs/model.md, Mechanism, written here once as a CasADi function of those outputs and the parameters (the
four-bar closed by `mechanism.four_bar`, rotations from `mechanics.transforms`) and evaluated for every frame at
once. The wheel centers it computes are the FMU's own `wheel[i].c*` outputs (tests/test_watch.py checks that),
so the drawing and the model cannot drift apart.

The spin angle gamma_i is not an FMU output (`wheel[i].psi` is the contact slope angle); it is the trapezoidal
integral of the recorded spin rate `wheel[i].omega` (relative to the wheel's carrier), enough to show a wheel
turning: a wheel spinning faster than pi per output interval aliases, as a filmed wheel does.

The body is drawn as a box (the model gives the body no shape): from the rear wheel's x to the upper four-bar pivot
B, from the lower pivot A's height to 3 cm above B, 0.6 bogie_y to each side.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from cedra.mechanics.transforms import rot_x, rot_y, rot_z
from cedra.rover.mechanism import four_bar

# the drawing points, in this order (rows of Skeleton.points)
POINTS = ([f"box{k}" for k in range(8)] + ["P_L", "P_R", "S_L", "S_R", "S_5", "A", "B", "C", "D"] +
          [f"c{i}" for i in range(1, 7)])
# polylines through named points: bogies, their struts from the box, the rear strut, the four-bar, the coupler
LINKS = [["c1", "P_L", "c2"], ["S_L", "P_L"], ["c3", "P_R", "c4"], ["S_R", "P_R"], ["S_5", "c5"],
         ["A", "C"], ["B", "D"], ["c6", "C", "D"]]
# box faces (corner indices; corner k has x bit 1, y bit 2, z bit 4)
BOX_FACES = [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]]
COORDS = ["body.x", "body.y", "body.z", "body.yaw", "body.pitch", "body.roll", "bogie.theta[1]", "bogie.theta[2]",
          "fork.theta4", "steer.theta[1]", "steer.theta[2]"]
PARAMS = ["R_w", "bogie_x", "bogie_y", "bogie_z", "bogie_half", "rear_x", "rear_z", "fork_ax", "fork_az", "fork_bx",
          "fork_bz", "fork_a", "fork_b", "fork_c", "fork_wheel"]
# what a run must record for the drawing (besides time); 2D runs lack y, yaw, roll and steering: they are 0
NEEDED = (["body.x", "body.z", "body.pitch", "bogie.theta[1]", "fork.theta4"] +
          [f"wheel[{i}].omega" for i in range(1, 7)])


@dataclass
class Skeleton:
    points: np.ndarray      # (frames, len(POINTS), 3), world
    axles: np.ndarray       # (frames, 6, 3) unit axle of wheel i (left-pointing for straight wheels)
    spokes: np.ndarray      # (frames, 6, 3) unit vector from the center to a rim mark turning with the wheel
    R: np.ndarray           # (frames, 3, 3) body rotation
    R_w: float

    def point(self, name) -> np.ndarray:
        return self.points[:, POINTS.index(name)]

    def centers(self) -> np.ndarray:
        return self.points[:, POINTS.index("c1"):POINTS.index("c6") + 1]


def _function() -> ca.Function:
    q = {n: ca.SX.sym(n) for n in COORDS}
    gam = ca.SX.sym("gamma", 6)
    p = {n: ca.SX.sym(n) for n in PARAMS}
    R = rot_z(q["body.yaw"]) @ rot_y(q["body.pitch"]) @ rot_x(q["body.roll"])
    origin = ca.vertcat(q["body.x"], q["body.y"], q["body.z"])

    def world(v):
        return origin + R @ v

    xmin, xmax = p["rear_x"], p["fork_bx"]
    zmin, zmax = p["fork_az"], p["fork_bz"] + 0.03
    half = 0.6 * p["bogie_y"]
    box = [world(ca.vertcat(xmax if k & 1 else xmin, half if k & 2 else -half, zmax if k & 4 else zmin))
           for k in range(8)]
    pts = {f"box{k}": b for k, b in enumerate(box)}
    wheels, frames = {}, {}
    bogies = ((1, q["bogie.theta[1]"], (1, 2), "L"), (-1, q["bogie.theta[2]"], (3, 4), "R"))
    for side, th, (front, rear), name in bogies:
        pivot = ca.vertcat(p["bogie_x"], side * p["bogie_y"], p["bogie_z"])
        Rb = rot_y(-th)
        pts[f"P_{name}"] = world(pivot)
        pts[f"S_{name}"] = world(ca.vertcat(p["bogie_x"], side * half, zmin))
        wheels[front] = world(pivot + Rb @ ca.vertcat(p["bogie_half"], 0, 0))
        wheels[rear] = world(pivot + Rb @ ca.vertcat(-p["bogie_half"], 0, 0))
        frames[front] = frames[rear] = R @ Rb
    pts["S_5"] = world(ca.vertcat(p["rear_x"], 0, zmin))
    wheels[5] = world(ca.vertcat(p["rear_x"], 0, p["rear_z"]))
    frames[5] = R @ rot_z(q["steer.theta[1]"])
    C, theta5, _ = four_bar(q["fork.theta4"], p)
    Rc = rot_y(-theta5)                      # the coupler frame: x axis e(theta5)
    s = Rc @ ca.DM([1, 0, 0])
    pts["A"] = world(ca.vertcat(p["fork_ax"], 0, p["fork_az"]))
    pts["B"] = world(ca.vertcat(p["fork_bx"], 0, p["fork_bz"]))
    pts["C"] = world(C)
    pts["D"] = world(C + p["fork_c"] * s)
    wheels[6] = world(C - p["fork_wheel"] * s)
    frames[6] = R @ Rc @ rot_x(q["steer.theta[2]"])
    for i in range(1, 7):
        pts[f"c{i}"] = wheels[i]
    points = ca.horzcat(*[pts[n] for n in POINTS])
    axles = ca.horzcat(*[frames[i] @ ca.DM([0, 1, 0]) for i in range(1, 7)])
    spokes = ca.horzcat(*[frames[i] @ rot_y(gam[i - 1]) @ ca.DM([1, 0, 0]) for i in range(1, 7)])
    return ca.Function("skeleton", [ca.vertcat(*q.values()), gam, ca.vertcat(*p.values())],
                       [points, axles, spokes, R])


_F = None


def spin_angles(t: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """gamma(t) = integral of omega from t[0] (trapezoids); omega (frames, 6) -> (frames, 6)."""
    inc = 0.5 * (omega[1:] + omega[:-1]) * np.diff(t)[:, None]
    return np.vstack([np.zeros((1, omega.shape[1])), np.cumsum(inc, axis=0)])


def skeleton(cols: dict, p: dict, frames=None) -> Skeleton:
    """The drawing points of a run. cols: recorded outputs by name (arrays over the run's samples, with "time" and
    NEEDED; missing 3D coordinates are 0, a missing bogie.theta[2] is bogie.theta[1] as in 2D); p: the run's
    parameters (PARAMS at least); frames: the sample indices to draw (default all; the spin is integrated over
    every sample regardless)."""
    global _F
    missing = [n for n in NEEDED + ["time"] if n not in cols]
    if missing:
        raise ValueError(f"the run did not record {missing} (cedra.run.watch.WATCHED lists what the views need)")
    n = len(cols["time"])
    idx = np.arange(n) if frames is None else np.asarray(frames)
    default = {"bogie.theta[2]": cols["bogie.theta[1]"]}
    Q = np.array([np.asarray(cols.get(c, default.get(c, np.zeros(n))), dtype=float)[idx] for c in COORDS])
    omega = np.array([cols[f"wheel[{i}].omega"] for i in range(1, 7)], dtype=float).T
    gam = spin_angles(np.asarray(cols["time"], dtype=float), omega)[idx].T
    P = np.array([float(p[k]) for k in PARAMS])
    if _F is None:
        _F = _function()
    m = len(idx)
    pts, ax, sp, R = _F.map(m)(Q, gam, np.tile(P[:, None], (1, m)))
    pts = np.array(pts).reshape(3, m, len(POINTS)).transpose(1, 2, 0)
    ax = np.array(ax).reshape(3, m, 6).transpose(1, 2, 0)
    sp = np.array(sp).reshape(3, m, 6).transpose(1, 2, 0)
    R = np.array(R).reshape(3, m, 3).transpose(1, 0, 2)
    return Skeleton(pts, ax, sp, R, float(p["R_w"]))
