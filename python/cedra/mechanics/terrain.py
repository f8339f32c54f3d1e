"""Terrain kinds Z = f(X, Y) (docs/model.md, Terrain). Terrain numbers are FMU inputs, so they are symbols here."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import casadi as ca

from cedra.mechanics import heightmap
from cedra.contract import Quantity

TERRAIN_INPUTS = {
    "terrain_h": Quantity("terrain_h", 0.14625, "m", "terrain feature height (bump, step, waves)"),
    "terrain_w": Quantity("terrain_w", 0.14625, "m", "terrain feature width (bump) or wavelength (waves)",
                          min=1e-6),
    "terrain_x0": Quantity("terrain_x0", 1.0, "m", "terrain feature position, X"),
    "terrain_y0": Quantity("terrain_y0", 0.0, "m", "terrain feature position, Y (bump3d)"),
    "terrain_slope": Quantity("terrain_slope", 0.0, "rad",
                              "slope angle about Y (positive: the ground descends toward +X)", min=-1.2, max=1.2),
    "terrain_s": Quantity("terrain_s", 0.02, "m", "step smoothing length", min=1e-6),
}


@dataclass(frozen=True)
class TerrainKind:
    name: str
    inputs: tuple[str, ...]
    height: Callable       # (X, Y, t: dict name -> SX) -> SX
    planar: bool           # a plane: the rim search's start point (beta = 0) is already exact


def _bump(X, Y, t):
    return t["terrain_h"] * ca.exp(-((X - t["terrain_x0"]) / t["terrain_w"]) ** 2)


def _bump3d(X, Y, t):
    r2 = (X - t["terrain_x0"]) ** 2 + (Y - t["terrain_y0"]) ** 2
    return t["terrain_h"] * ca.exp(-r2 / t["terrain_w"] ** 2)


def _step(X, Y, t):
    return 0.5 * t["terrain_h"] * (1 + ca.tanh((X - t["terrain_x0"]) / t["terrain_s"]))


def _waves(X, Y, t):
    k = 2 * ca.pi / t["terrain_w"]
    return t["terrain_h"] * ca.sin(k * X) * ca.sin(k * Y)


KINDS = {
    "flat": TerrainKind("flat", (), lambda X, Y, t: 0 * X, True),
    "slope": TerrainKind("slope", ("terrain_slope",), lambda X, Y, t: -ca.tan(t["terrain_slope"]) * X, True),
    "bump": TerrainKind("bump", ("terrain_h", "terrain_w", "terrain_x0"), _bump, False),
    "bump3d": TerrainKind("bump3d", ("terrain_h", "terrain_w", "terrain_x0", "terrain_y0"), _bump3d, False),
    "step": TerrainKind("step", ("terrain_h", "terrain_x0", "terrain_s"), _step, False),
    "waves": TerrainKind("waves", ("terrain_h", "terrain_w"), _waves, False),
    # a grid shipped in the FMU's resources (cedra.mechanics.heightmap): the height is an external function, no inputs
    "heightmap": TerrainKind("heightmap", (), None, False),
}


class Terrain:
    """A terrain kind bound to its symbolic inputs: height, gradient, Hessian and unit normal.

    Derivatives are outputs of one function, never taken by differentiating the terrain inside the model: the
    heightmap is an external C function (cedra.mechanics.heightmap) whose derivative chain is finite, so the model
    uses h, gradient and Hessian explicitly (one level of symbolic differentiation of the model remains possible).

    The heightmap's wheel contact (external_rim, the default for kind "heightmap"): the whole rim search of a
    wheel is one call of the C function cedra_rim_contact, which returns the contact point, the height and
    gradient there, and their Jacobian J with respect to the wheel's pose x = [center, axle, radius]. The model
    sees them through rim_contact() as  e = e0 + J0 (x - x0)  with e0, J0, x0 free symbols, so every derivative
    the model takes (Jacobians, rates) applies the chain rule through J0; resolve() then puts in x0 = x and
    (e0, J0) = cedra_rim_contact(x): one C call per wheel and function, and the contact point's dependence on the
    pose enters the derivatives exactly (implicit function theorem in C) instead of through the symbolic
    derivatives of 13 samples and 4 Newton steps."""

    def __init__(self, kind: str, inputs: dict[str, ca.SX], heightmap_file: str = "", symbolic_rim: bool = False):
        """heightmap_file: the grid of kind "heightmap"; it is loaded as the process's active map.
        symbolic_rim: kind "heightmap" with the rim search formed symbolically (contact.rim_point through the
        point external cedra_heightmap), as before the C search: the reference the tests compare against."""
        self.kind = KINDS[kind]
        self.inputs = inputs
        self.external_rim = kind == "heightmap" and not symbolic_rim
        self._frozen = []           # (x0, e0, J0, x) per rim_contact call
        X, Y = ca.SX.sym("X"), ca.SX.sym("Y")
        t = [inputs[n] for n in self.kind.inputs]
        if kind == "heightmap":
            if not heightmap_file:
                raise ValueError("terrain 'heightmap' needs its heightmap file")
            heightmap.load(heightmap_file)
            h, grad, hess = heightmap.external()(ca.vertcat(X, Y))
        else:
            h = self.kind.height(X, Y, inputs)
            grad = ca.gradient(h, ca.vertcat(X, Y))
            hess = ca.jacobian(grad, ca.vertcat(X, Y))
        self._f = ca.Function("terrain", [X, Y] + t, [h, grad, hess])
        self._t = t

    @property
    def planar(self):
        return self.kind.planar

    def local(self, X, Y):
        """(h, gradient [h_X, h_Y], Hessian 2x2) at (X, Y)."""
        return self._f(X, Y, *self._t)

    def height(self, X, Y):
        return self.local(X, Y)[0]

    def normal(self, X, Y):
        g = self.local(X, Y)[1]
        n = ca.vertcat(-g[0], -g[1], 1)
        return n / ca.norm_2(n)

    def rim_contact(self, center, axle, radius):
        """(p, h(p), gradient at p) of the wheel (external_rim only), linear in the wheel's pose about free
        symbols that resolve() replaces (see the class)."""
        x = ca.vertcat(center, axle, radius)
        x0, e0, J0 = ca.SX.sym("rim_x0", 7), ca.SX.sym("rim_e0", 6), ca.SX.sym("rim_J0", 6, 7)
        self._frozen.append((x0, e0, J0, x))
        e = e0 + J0 @ (x - x0)
        return e[0:3], e[3], e[4:6]

    def resolve(self, exprs: list, derivatives: bool = True) -> list:
        """exprs with the rim contacts' symbols put in: x0 = x, (e0, J0) = cedra_rim_contact(x). derivatives=False
        for expressions that hold no derivative of a contact: J0 = 0 there, e0 = cedra_rim_point(x) (no Jacobian
        computed)."""
        if not self._frozen:
            return list(exprs)
        ext = heightmap.rim_external(derivatives)
        syms, vals = [], []
        for x0, e0, J0, x in self._frozen:
            if derivatives:
                e, J = ext(x)
            else:
                e, J = ext(x), ca.SX.zeros(6, 7)
            syms += [x0, e0, J0]
            vals += [x, e, J]
        return ca.substitute(list(exprs), syms, vals)
