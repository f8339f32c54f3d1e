"""A planar staircase with sharp edges, the terrain of the quasi-static climb (cedra.rover.required_friction).

Flat ground Z = 0 up to the first edge at x0, then `steps` risers of height `rise`, each tread `run` long; the top
tread goes on without end. One riser is the sharp step, four with the scenes' run are their stairs. The edges are
sharp (the scenes' terrain smooths them over terrain_s): the field's static analysis takes the obstacle's corner as
the point a wheel climbs over, and a wheel's contact there is the circle's tangency with the corner.

The solid below the profile is a union of quadrants (`blocks`); a wheel of radius R rolls on it with its centre at
distance R from the nearest. At each riser a wheel leaves its tread where it touches the tread and the
riser at once (`lift_off`): against the corner when the riser is lower than R, against the riser's face when it
is as high as R or higher.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Staircase:
    rise: float                 # m: each riser's height (0: flat ground)
    steps: int = 1              # risers
    run: float = math.inf       # m: each tread between two risers (one riser: not used)
    x0: float = 0.0             # m: the first riser's x

    def check(self, radius: float) -> None:
        """A wheel of this radius must fit each tread: it touches a tread between two risers only when the tread
        is longer than the radius (it meets the next riser's face while its centre is still above the last
        corner's arc otherwise)."""
        if not (self.rise >= 0 and math.isfinite(self.rise)):
            raise ValueError(f"the profile's rise must be a finite number >= 0, got {self.rise}")
        if self.steps < 1:
            raise ValueError(f"the profile needs at least one riser, got steps = {self.steps}")
        if self.steps > 1 and not self.run > radius:
            raise ValueError(f"the stairs' run {self.run} m must exceed the wheel radius {radius} m, so that a "
                             "wheel stands on each tread")

    def edges(self) -> list[float]:
        """The risers' x, in order."""
        return [self.x0 + k * self.run for k in range(self.steps)] if self.steps > 1 else [self.x0]

    @property
    def top(self) -> float:
        return self.rise * self.steps

    def blocks(self) -> np.ndarray:
        """The solid below the profile as a union of quadrants {x >= e, z <= H}: (n, 2) rows (e, H), the ground's
        first (e = -inf), then the one above each riser. Each is convex, so a point's distance to it is
        continuously differentiable outside it and zero inside: a wheel's centre at least R from every block
        stays above the profile."""
        rows = [(-math.inf, 0.0)] + [(xe, (k + 1) * self.rise) for k, xe in enumerate(self.edges())]
        return np.array(rows if self.rise > 0 else rows[:1], dtype=float)

    def height(self, x) -> np.ndarray:
        """The terrain's height at x (the upper tread at a riser's own x)."""
        x = np.asarray(x, dtype=float)
        return self.rise * sum((x >= xe).astype(float) for xe in self.edges())

    def lift_off(self, radius: float) -> list[tuple[int, np.ndarray]]:
        """Per riser k: (k, the wheel centre where it touches riser k and the tread below it at once); none on
        flat ground."""
        if self.rise == 0:
            return []
        h, R = self.rise, radius
        back = math.sqrt(R * R - (R - h) ** 2) if h < R else R
        return [(k, np.array([xe - back, k * h + R])) for k, xe in enumerate(self.edges())]

    def path(self, riser: int, radius: float, ds: float) -> list[tuple[float, np.ndarray]]:
        """The centre of a wheel climbing riser `riser` (0-based), from its lift-off: up the face while the riser
        is higher than the wheel's centre, then around the edge to above it; points at most ds apart along the
        path, as (distance along the path from the lift-off, centre)."""
        h, R = self.rise, radius
        xe, low, high = self.edges()[riser], riser * h, (riser + 1) * h
        points = []
        face = max(0.0, h - R)          # the face's part the centre climbs straight up
        if face > 0:
            for z in np.linspace(low + R, high, max(2, int(math.ceil(face / ds)) + 1)):
                points.append((z - low - R, np.array([xe - R, z])))
            start = math.pi
        else:
            start = math.atan2(R - h, -math.sqrt(R * R - (R - h) ** 2))
        arc = (start - math.pi / 2) * R
        for a in np.linspace(start, math.pi / 2, max(2, int(math.ceil(arc / ds)) + 1)):
            s = face + (start - a) * R
            if not points or s > points[-1][0] + 1e-12:
                points.append((s, np.array([xe + R * math.cos(a), high + R * math.sin(a)])))
        return points
