"""Whether a rover's closed chains assemble over its joints' whole range, for its parameter values: checked before
any code is generated (cedra.models.scene), so that a geometry whose links cannot meet fails with the key that
sets it, not as a run's status at the pose where the chain breaks.

A rover description's `closure` is a number with |closure| < 1 where its chains assemble (CEDRA's four-bar:
K / |d| of mechanism.four_bar, the cosine of the angle that closes the chain). For each jointed coordinate the
closure depends on and that has stops, the closure is evaluated over the stops' range (SAMPLES angles, both stops
and the design angle among them) with the other coordinates at the design pose; the first angle where it is not
finite or |closure| >= 1 - MARGIN fails.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from cedra.mechanics.rover_kind import RoverKind

SAMPLES = 1441          # angles over a joint's range (about 1 mrad apart over CEDRA's fork range)
MARGIN = 1e-6           # a chain this close to |closure| = 1 is at the edge of assembly (its links in line)

_FUNCTIONS: dict[str, tuple] = {}


@dataclass
class AssemblyFailure:
    rover: str
    joint: str                  # the coordinate at which the chain does not close
    angle: float                # rad: the first angle in its range where it does not
    limits: tuple               # (lo, hi) rad: the joint's stops
    closure: float              # the closure there (|closure| >= 1, or not finite)
    parameters: tuple           # the parameters the closure and the joint's stops depend on

    def reason(self) -> str:
        return (f"rover {self.rover}'s closed chain cannot be assembled at {self.joint} = {self.angle:.4f} rad, "
                f"within its stops [{self.limits[0]:.4f}, {self.limits[1]:.4f}] rad (closure {self.closure:.4g}; "
                f"the links meet only where |closure| < 1; set by {', '.join(self.parameters)})")


def _closure(kind: RoverKind):
    if kind.name not in _FUNCTIONS:
        names = kind.coordinates
        q, qd = ca.SX.sym("q", len(names)), ca.SX.sym("qd", len(names))
        psym = {x.name: ca.SX.sym(x.name) for x in kind.parameters}
        rover = kind.describe(q, lambda e: ca.jtimes(e, q, qd), psym, ca.SX.zeros(6), None)
        closure = ca.SX(rover.closure)
        par = ca.vertcat(*psym.values())
        f = ca.Function("closure", [q, par], [closure])
        joints = tuple(s for s in kind.stops if ca.depends_on(closure, q[names.index(s.coordinate)]))
        depends = tuple(n for n, s in psym.items() if ca.depends_on(closure, s))
        _FUNCTIONS[kind.name] = (f, joints, depends)
    return _FUNCTIONS[kind.name]


def assembly_failure(kind: RoverKind, values: dict | None = None) -> AssemblyFailure | None:
    """The first joint angle within the stops where `kind`'s closed chain cannot be assembled with the parameter
    values (the kind's defaults updated by `values`), or None where it assembles over every joint's range."""
    p = {x.name: float(x.start) for x in kind.parameters}
    p.update({k: float(v) for k, v in (values or {}).items() if k in p})
    f, joints, depends = _closure(kind)
    design = kind.design(p)
    q0 = np.array([float(design.get(n, 0.0)) for n in kind.coordinates])
    par = np.array([p[x.name] for x in kind.parameters])
    for stop in joints:
        lo, hi = (float(x) for x in stop.limits(p))
        j = kind.coordinates.index(stop.coordinate)
        angles = np.unique(np.concatenate([np.linspace(min(lo, hi), max(lo, hi), SAMPLES), [q0[j]]]))
        Q = np.repeat(q0[:, None], len(angles), axis=1)
        Q[j] = angles
        c = np.array(f.map(len(angles))(Q, np.repeat(par[:, None], len(angles), axis=1))).ravel()
        bad = ~np.isfinite(c) | (np.abs(np.nan_to_num(c, nan=np.inf)) >= 1 - MARGIN)
        if bad.any():
            k = int(np.argmax(bad))
            limits = tuple(n.lstrip("-") for n in (stop.lo, stop.hi))
            return AssemblyFailure(kind.name, stop.coordinate, float(angles[k]), (lo, hi), float(c[k]),
                                   depends + tuple(n for n in dict.fromkeys(limits) if n not in depends))
    return None
