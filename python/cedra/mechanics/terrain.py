"""Terrain kinds Z = f(X, Y) (docs/model.md, Terrain). Terrain numbers are FMU inputs, so they are symbols here."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import casadi as ca

from cedra.mechanics import heightmap
from cedra.contract import TERRAIN_TIN, Quantity

TERRAIN_INPUTS = {
    "terrain_h": Quantity("terrain_h", 0.14625, "m", "terrain feature height (bump, step, waves)"),
    "terrain_w": Quantity("terrain_w", 0.14625, "m", "terrain feature width (bump) or wavelength (waves)",
                          min=1e-6),
    "terrain_x0": Quantity("terrain_x0", 1.0, "m", "terrain feature position, X"),
    "terrain_y0": Quantity("terrain_y0", 0.0, "m", "terrain feature position, Y (bump3d)"),
    "terrain_slope": Quantity("terrain_slope", 0.0, "rad",
                              "slope angle about Y (positive: the ground descends toward +X)", min=-1.2, max=1.2),
    "terrain_s": Quantity("terrain_s", 0.02, "m", "step smoothing length", min=1e-6),
    "terrain_yaw": Quantity("terrain_yaw", 0.0, "rad", "stairs turned about Z through (terrain_x0, terrain_y0): "
                            "the edges' normal makes this angle with X", min=-1.5, max=1.5),
}
STAIRS_STEPS = 4        # the stairs' default number of steps (a scene's stairs_steps)


@dataclass(frozen=True)
class TerrainKind:
    name: str
    inputs: tuple[str, ...]
    height: Callable       # (X, Y, t: dict name -> SX) -> SX
    planar: bool           # a plane: the rim search's start point (beta = 0) is already exact
    # (t) -> (G, U): over the whole plane, G >= |gradient| and U >= the Hessian's largest eigenvalue (the contact
    # search's test for one maximum, fmu_src/rim.c); None: no such bounds (the search always samples the rim)
    bounds: Callable | None = None


def terrain_inputs(kind: str, dims: str) -> tuple[str, ...]:
    """The inputs of a terrain kind in a scene of dims: 2D stairs are not turned (no terrain_y0, terrain_yaw)."""
    names = KINDS[kind].inputs
    if kind == "stairs" and dims == "2d":
        names = tuple(n for n in names if n not in ("terrain_y0", "terrain_yaw"))
    return names


def _bump(X, Y, t):
    return t["terrain_h"] * ca.exp(-((X - t["terrain_x0"]) / t["terrain_w"]) ** 2)


def _bump3d(X, Y, t):
    r2 = (X - t["terrain_x0"]) ** 2 + (Y - t["terrain_y0"]) ** 2
    return t["terrain_h"] * ca.exp(-r2 / t["terrain_w"] ** 2)


def _step(X, Y, t):
    return 0.5 * t["terrain_h"] * (1 + ca.tanh((X - t["terrain_x0"]) / t["terrain_s"]))


def _stairs(X, Y, t, steps=STAIRS_STEPS):
    """steps smoothed steps of rise terrain_h and run terrain_w, the first edge at terrain_x0; in 3D turned about
    Z through (terrain_x0, terrain_y0) by terrain_yaw (absent in 2D: 0)."""
    yaw = t.get("terrain_yaw", 0)
    x0, y0 = t["terrain_x0"], t.get("terrain_y0", 0)
    u = (X - x0) * ca.cos(yaw) + (Y - y0) * ca.sin(yaw)          # distance past the first edge, across the edges
    return sum(0.5 * t["terrain_h"] * (1 + ca.tanh((u - j * t["terrain_w"]) / t["terrain_s"])) for j in range(steps))


# Bounds of the Gaussian profile h exp(-s^2), s = d / w, along d: |slope| <= sqrt(2) e^(-1/2) |h| / w (at
# s^2 = 1/2); curvature (4 s^2 - 2) e^(-s^2) h / w^2 in [-2, 4 e^(-3/2)] h / w^2 (at s = 0 and s^2 = 3/2)
_GAUSS_SLOPE, _GAUSS_CURV = math.sqrt(2 / math.e), 4 * math.exp(-1.5)


def _gauss_bounds(t):
    """The bump (h exp(-((X - x0)/w)^2): Hessian diag(f'', 0)) and bump3d (radially the same profile; across
    the radius f'/r = -2 h/w^2 e^(-s^2), between 0 and -2 h/w^2): the largest eigenvalue is at most
    max(4 e^(-3/2) h, -2 h) / w^2 either way."""
    h, w = t["terrain_h"], t["terrain_w"]
    return _GAUSS_SLOPE * ca.fabs(h) / w, ca.fmax(_GAUSS_CURV * h, -2 * h) / w ** 2


def _step_bounds(t):
    """0.5 h (1 + tanh(u / s)): slope 0.5 h/s sech^2 <= |h| / (2 s); curvature -h/s^2 tanh sech^2, at most
    2 / (3 sqrt 3) |h| / s^2 in size."""
    h, s = t["terrain_h"], t["terrain_s"]
    return ca.fabs(h) / (2 * s), 2 / (3 * math.sqrt(3)) * ca.fabs(h) / s ** 2


def _waves_bounds(t):
    """h sin(kX) sin(kY): each gradient component at most |h| k; the Hessian's eigenvalues
    h k^2 (-sin sin +- |cos cos|), at most |h| k^2."""
    k = 2 * ca.pi / t["terrain_w"]
    return math.sqrt(2) * ca.fabs(t["terrain_h"]) * k, ca.fabs(t["terrain_h"]) * k ** 2


def _waves(X, Y, t):
    k = 2 * ca.pi / t["terrain_w"]
    return t["terrain_h"] * ca.sin(k * X) * ca.sin(k * Y)


KINDS = {
    "flat": TerrainKind("flat", (), lambda X, Y, t: 0 * X, True),
    "slope": TerrainKind("slope", ("terrain_slope",), lambda X, Y, t: -ca.tan(t["terrain_slope"]) * X, True),
    "bump": TerrainKind("bump", ("terrain_h", "terrain_w", "terrain_x0"), _bump, False, _gauss_bounds),
    "bump3d": TerrainKind("bump3d", ("terrain_h", "terrain_w", "terrain_x0", "terrain_y0"), _bump3d, False,
                          _gauss_bounds),
    "step": TerrainKind("step", ("terrain_h", "terrain_x0", "terrain_s"), _step, False, _step_bounds),
    "waves": TerrainKind("waves", ("terrain_h", "terrain_w"), _waves, False, _waves_bounds),
    # in 2D without terrain_y0, terrain_yaw (terrain_inputs); the number of steps is the scene's (Terrain's steps)
    "stairs": TerrainKind("stairs", ("terrain_h", "terrain_w", "terrain_x0", "terrain_s", "terrain_y0", "terrain_yaw"),
                          _stairs, False),
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

    def __init__(self, kind: str, inputs: dict[str, ca.SX], heightmap_file: str = "", symbolic_rim: bool = False,
                 steps: int = STAIRS_STEPS):
        """heightmap_file: the grid of kind "heightmap"; it is loaded as the process's active map.
        symbolic_rim: kind "heightmap" with the rim search formed symbolically (contact.rim_point through the
        point external cedra_heightmap), as before the C search: the reference the tests compare against."""
        self.kind = KINDS[kind]
        self.inputs = inputs
        self.external_rim = kind == "heightmap" and not symbolic_rim
        self._frozen = []           # (x0, e0, J0, x) per rim_contact call
        X, Y = ca.SX.sym("X"), ca.SX.sym("Y")
        t = [inputs[n] for n in self.kind.inputs if n in inputs]
        if kind == "heightmap":
            if not heightmap_file:
                raise ValueError("terrain 'heightmap' needs its heightmap file")
            heightmap.load(heightmap_file)
            h, grad, hess = heightmap.external()(ca.vertcat(X, Y))
        else:
            h = _stairs(X, Y, inputs, steps) if kind == "stairs" else self.kind.height(X, Y, inputs)
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

    @property
    def n_inputs(self) -> int:
        return len(self._t)

    @property
    def input_names(self) -> list[str]:
        """The names of the terrain's inputs in their order (tin's order)."""
        return [n for n in self.kind.inputs if n in self.inputs]

    def bound(self, inputs: dict[str, ca.SX]) -> "Terrain":
        """This terrain with other symbols for its inputs (the same kind, steps and grid)."""
        other = object.__new__(Terrain)
        other.__dict__.update(self.__dict__)
        other.inputs = inputs
        other._t = [inputs[n] for n in self.input_names]
        return other

    def function(self) -> ca.Function:
        """cedra_terrain: (xy[2], tin[TERRAIN_TIN]) -> (h, gradient, Hessian), the terrain for C (the contract)."""
        xy, tin = ca.SX.sym("xy", 2), ca.SX.sym("tin", TERRAIN_TIN)
        h, g, H = self._f(xy[0], xy[1], *[tin[k] for k in range(self.n_inputs)])
        # dense: C reads every entry (a terrain constant in Y has no structural h_Y, h_XY, h_YY)
        return ca.Function("cedra_terrain", [xy, tin], [ca.densify(h), ca.densify(g), ca.densify(H)], ["xy", "tin"],
                           ["h", "grad", "hess"])

    def bounds_function(self) -> ca.Function:
        """cedra_terrain_bounds: (tin[TERRAIN_TIN]) -> (bounds[2] = [G, U]): G >= |gradient| and U >= the Hessian's
        largest eigenvalue everywhere, at these inputs (TerrainKind.bounds); inf where the kind has none."""
        tin = ca.SX.sym("tin", TERRAIN_TIN)
        if self.kind.name == "heightmap":
            b = heightmap.bounds_external()(tin)
        elif self.kind.bounds is None:
            b = ca.SX([ca.inf, ca.inf])
        else:
            b = ca.vertcat(*self.kind.bounds({n: tin[k] for k, n in enumerate(self.input_names)}))
        return ca.Function("cedra_terrain_bounds", [tin], [ca.densify(b)], ["tin"], ["bounds"])

    def tin(self):
        """The terrain's inputs as cedra_terrain's tin (padded with zeros)."""
        return ca.vertcat(*self._t, ca.SX.zeros(TERRAIN_TIN - self.n_inputs))

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
