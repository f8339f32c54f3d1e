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

Each rover has its drawing (`DRAWINGS`: its points, links, the outputs it reads and the parameters it needs); a
run is drawn with the first whose outputs it recorded. The rocker-bogie's (cedra.rover.rocker_bogie's chains):
its body box (the collision box's floor to its top face), the rocker pivots Q, the bogie pivots P, the wheels; the
rockers drawn front wheel - Q - P, the bogies middle wheel - P - rear wheel.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import casadi as ca
import numpy as np

from cedra.mechanics.transforms import rot_x, rot_y, rot_z
from cedra.rover import rocker_bogie
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
    points: np.ndarray      # (frames, len(names), 3), world
    axles: np.ndarray       # (frames, 6, 3) unit axle of wheel i (left-pointing for straight wheels)
    spokes: np.ndarray      # (frames, 6, 3) unit vector from the center to a rim mark turning with the wheel
    R: np.ndarray           # (frames, 3, 3) body rotation
    R_w: float
    names: list = None      # the points' names (default: CEDRA's POINTS)
    links: list = None      # polylines through named points (default: CEDRA's LINKS)
    rover: str = "CEDRA"

    def __post_init__(self):
        self.names = POINTS if self.names is None else self.names
        self.links = LINKS if self.links is None else self.links

    def point(self, name) -> np.ndarray:
        return self.points[:, self.names.index(name)]

    def centers(self) -> np.ndarray:
        return np.stack([self.point(f"c{i}") for i in range(1, 7)], axis=1)


def _symbols(coords, params):
    """A drawing's symbols: the coordinates and parameters by name, the wheels' spin angles, the body's rotation R
    and world(v), a body-frame point in the world."""
    q = {n: ca.SX.sym(n) for n in coords}
    gam = ca.SX.sym("gamma", 6)
    p = {n: ca.SX.sym(n) for n in params}
    R = rot_z(q["body.yaw"]) @ rot_y(q["body.pitch"]) @ rot_x(q["body.roll"])
    origin = ca.vertcat(q["body.x"], q["body.y"], q["body.z"])
    return q, gam, p, R, lambda v: origin + R @ v


def _box(world, x, y, z) -> dict:
    """The body's box corners box0..box7 from its (low, high) extents along the body's x, y and z."""
    return {f"box{k}": world(ca.vertcat(x[k & 1], y[(k >> 1) & 1], z[(k >> 2) & 1])) for k in range(8)}


def _skeleton(name, q, gam, p, R, pts, wheels, frames, names) -> ca.Function:
    """(coordinates, spin angles, parameters) -> (the points `names`, the wheel centres c1..c6 among them; the
    wheels' axles; their spokes; R), each wheel's frame in `frames` (its axle the frame's y axis)."""
    for i in range(1, 7):
        pts[f"c{i}"] = wheels[i]
    points = ca.horzcat(*[pts[n] for n in names])
    axles = ca.horzcat(*[frames[i] @ ca.DM([0, 1, 0]) for i in range(1, 7)])
    spokes = ca.horzcat(*[frames[i] @ rot_y(gam[i - 1]) @ ca.DM([1, 0, 0]) for i in range(1, 7)])
    return ca.Function(name, [ca.vertcat(*q.values()), gam, ca.vertcat(*p.values())], [points, axles, spokes, R])


def _function() -> ca.Function:
    q, gam, p, R, world = _symbols(COORDS, PARAMS)
    zmin = p["fork_az"]
    half = 0.6 * p["bogie_y"]
    pts = _box(world, (p["rear_x"], p["fork_bx"]), (-half, half), (zmin, p["fork_bz"] + 0.03))
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
    return _skeleton("skeleton", q, gam, p, R, pts, wheels, frames, POINTS)


# ---------------------------------------------------------------- the rocker-bogie's drawing
RB_POINTS = [f"box{k}" for k in range(8)] + ["Q_L", "Q_R", "P_L", "P_R"] + [f"c{i}" for i in range(1, 7)]
RB_LINKS = [["c1", "Q_L", "P_L"], ["c2", "P_L", "c3"], ["c4", "Q_R", "P_R"], ["c5", "P_R", "c6"]]
RB_COORDS = ["body.x", "body.y", "body.z", "body.yaw", "body.pitch", "body.roll", "rocker.rho", "bogie.beta[1]",
             "bogie.beta[2]"]
RB_PARAMS = ["R_w", "rocker_x", "rocker_y", "rocker_z", "front_x", "front_z", "bogie_x", "bogie_z", "bogie_half",
             "bogie_drop"]
RB_NEEDED = ["body.x", "body.z", "body.pitch", "rocker.rho", "bogie.beta[1]"] + \
    [f"wheel[{i}].omega" for i in range(1, 7)]


def _rb_function() -> ca.Function:
    q, gam, p, R, world = _symbols(RB_COORDS, RB_PARAMS)
    xs, ys = rocker_bogie.BODY_BOX_X, rocker_bogie.BODY_BOX_Y
    pts = _box(world, (xs[0], xs[-1]), (ys[0], ys[-1]), (rocker_bogie.BODY_FLOOR_Z, rocker_bogie.BODY_FACE_Z[-1]))
    wheels, frames = {}, {}
    lift = rocker_bogie.lift
    for side, r, b, first, name in ((1, q["rocker.rho"], q["bogie.beta[1]"], 1, "L"),
                                    (-1, -q["rocker.rho"], q["bogie.beta[2]"], 4, "R")):
        Qp = ca.vertcat(p["rocker_x"], side * p["rocker_y"], p["rocker_z"])
        front = ca.vertcat(p["front_x"], side * p["rocker_y"], p["front_z"])
        pivot = ca.vertcat(p["bogie_x"], side * p["rocker_y"], p["bogie_z"])
        P = Qp + lift(r) @ (pivot - Qp)
        pts[f"Q_{name}"], pts[f"P_{name}"] = world(Qp), world(P)
        wheels[first] = world(Qp + lift(r) @ (front - Qp))
        wheels[first + 1] = world(P + lift(r + b) @ ca.vertcat(p["bogie_half"], 0, -p["bogie_drop"]))
        wheels[first + 2] = world(P + lift(r + b) @ ca.vertcat(-p["bogie_half"], 0, -p["bogie_drop"]))
        frames[first] = R @ lift(r)                         # a wheel spins relative to its carrier
        frames[first + 1] = frames[first + 2] = R @ lift(r + b)
    return _skeleton("rb_skeleton", q, gam, p, R, pts, wheels, frames, RB_POINTS)


@dataclass(frozen=True)
class Drawing:
    rover: str              # the rover's name, for messages
    points: list
    links: list
    coords: list            # the recorded outputs the drawing takes as its coordinates (missing 3D ones are 0)
    params: list
    needed: list            # what a run must record for it (besides time)
    twins: dict             # a missing output taken from another (2D: the right side as the left)
    build: Callable


DRAWINGS = [Drawing("CEDRA", POINTS, LINKS, COORDS, PARAMS, NEEDED, {"bogie.theta[2]": "bogie.theta[1]"}, _function),
            Drawing("the rocker-bogie", RB_POINTS, RB_LINKS, RB_COORDS, RB_PARAMS, RB_NEEDED,
                    {"bogie.beta[2]": "bogie.beta[1]"}, _rb_function)]
_FUNCTIONS: dict = {}


def drawing(cols) -> Drawing:
    """The drawing of the first rover in DRAWINGS whose outputs the run recorded; else ValueError naming, for each,
    what the run lacks."""
    lacks = []
    for d in DRAWINGS:
        missing = [n for n in d.needed + ["time"] if n not in cols]
        if not missing:
            return d
        lacks.append(f"{d.rover}: {missing}")
    raise ValueError("the run did not record what a rover's drawing needs (" + "; ".join(lacks) +
                     "; cedra.run.watch.WATCHED lists what the views need)")


def spin_angles(t: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """gamma(t) = integral of omega from t[0] (trapezoids); omega (frames, 6) -> (frames, 6)."""
    inc = 0.5 * (omega[1:] + omega[:-1]) * np.diff(t)[:, None]
    return np.vstack([np.zeros((1, omega.shape[1])), np.cumsum(inc, axis=0)])


def skeleton(cols: dict, p: dict, frames=None) -> Skeleton:
    """The drawing points of a run. cols: recorded outputs by name (arrays over the run's samples, with "time" and
    its rover's `needed` outputs (`drawing`); missing 3D coordinates are 0, a missing right bogie angle is the left
    one's as in 2D); p: the run's parameters (the drawing's params at least); frames: the sample indices to draw
    (default all; the spin is integrated over every sample regardless)."""
    d = drawing(cols)
    n = len(cols["time"])
    idx = np.arange(n) if frames is None else np.asarray(frames)
    default = {twin: cols[src] for twin, src in d.twins.items()}
    Q = np.array([np.asarray(cols.get(c, default.get(c, np.zeros(n))), dtype=float)[idx] for c in d.coords])
    omega = np.array([cols[f"wheel[{i}].omega"] for i in range(1, 7)], dtype=float).T
    gam = spin_angles(np.asarray(cols["time"], dtype=float), omega)[idx].T
    missing = [k for k in d.params if k not in p]
    if missing:
        raise ValueError(f"the run's parameters lack {missing} ({d.rover}'s drawing needs them)")
    P = np.array([float(p[k]) for k in d.params])
    if d.rover not in _FUNCTIONS:
        _FUNCTIONS[d.rover] = d.build()
    m = len(idx)
    pts, ax, sp, R = _FUNCTIONS[d.rover].map(m)(Q, gam, np.tile(P[:, None], (1, m)))
    npt = len(d.points)
    pts = np.array(pts).reshape(3, m, npt).transpose(1, 2, 0)
    ax = np.array(ax).reshape(3, m, 6).transpose(1, 2, 0)
    sp = np.array(sp).reshape(3, m, 6).transpose(1, 2, 0)
    R = np.array(R).reshape(3, m, 3).transpose(1, 0, 2)
    return Skeleton(pts, ax, sp, R, float(p["R_w"]), list(d.points), list(d.links), d.rover)
