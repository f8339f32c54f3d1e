"""Each joint's virtual centre of rotation at the design pose, for any rover description (Siegwart et al., RAS 40,
2002: the Shrimp's front fork and its parallel bogies put "a virtual center of rotation at the level of or below the
wheel axis").

For a joint (a coordinate that is neither the body's pose, a spin nor a steering joint), with every other rate
zero, the link carrying a wheel it moves turns relative to the body about its instantaneous centre
P = c + (omega x v) / |omega|^2 (c the wheel centre, v its velocity, omega the link's angular velocity, from the
description's own kinematics): a rocker's or a bogie's pivot, a four-bar's intersection of its two links. Taken
for the lowest-numbered wheel on the left (y >= 0) that the joint moves, in the x-z plane, at the design pose over
flat ground (the body's mass centre at x = 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from cedra.mechanics.rover_kind import POSE, SPINS, RoverKind


@dataclass
class VirtualCentre:
    joint: str
    wheel: int
    centre: tuple               # (x, z) m, world at the design pose (inf: the link translates)
    wheel_centre: tuple         # (x, z) m

    @property
    def below_axle(self) -> float:
        """m: how far the centre lies below the wheel's axle (negative: above)."""
        return self.wheel_centre[1] - self.centre[1]


def virtual_centres(kind: RoverKind, params: dict | None = None) -> list[VirtualCentre]:
    values = {q.name: q.start for q in kind.parameters}
    values.update(params or {})
    names = kind.coordinates
    q, qd = ca.SX.sym("q", len(names)), ca.SX.sym("qd", len(names))
    p = {n: float(v) for n, v in values.items()}
    rover = kind.describe(q, lambda e: ca.jtimes(e, q, qd), p, ca.SX.zeros(6), None)
    design = kind.design(values)
    q0 = np.array([float(design.get(n, 0.0)) for n in names])
    joints = [n for n in names if n not in POSE and n not in SPINS and n not in kind.steering]
    f = ca.Function("vc", [q, qd], [ca.horzcat(*[ca.vertcat(w.center, ca.substitute(w.velocity, qd, qd),
                                                            w.omega) for w in rover.wheels])])
    out = []
    for j in joints:
        rate = np.zeros(len(names))
        rate[names.index(j)] = 1.0
        cols = np.array(f(q0, rate))
        for k, w in enumerate(rover.wheels):
            c, v, om = cols[0:3, k], cols[3:6, k], cols[6:9, k]
            if c[1] < 0 or np.linalg.norm(v) < 1e-12:
                continue
            wy = om[1]
            if abs(wy) < 1e-12:
                centre = (math.inf, math.inf)
            else:
                # planar: omega = (0, wy, 0), P = c + (omega x v) / wy^2
                centre = (c[0] + v[2] / wy, c[2] - v[0] / wy)
            out.append(VirtualCentre(j, w.index, centre, (float(c[0]), float(c[2]))))
            break
    return out
