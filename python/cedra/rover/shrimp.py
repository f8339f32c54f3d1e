"""A shrimp-faithful CEDRA geometry (docs/rovers.md, A shrimp-faithful CEDRA): the CEDRA mechanism with its
parameters chosen by the design rules of EPFL's Shrimp (Estier et al., *An innovative space rover with extended
climbing abilities*, 2000; Siegwart, Lamon, Estier, Lauria, Piguet, *Innovative design for wheeled locomotion in
rough terrain*, RAS 40, 2002), as the rover variant `cedra_shrimp` a scene names (`rover = "cedra_shrimp"`). The
default geometry (cedra.rover.parameters) stays what the shipped scenes use.

The rules, and how each sets the numbers (the wheel radius, the masses and the axle height stay the default's):

- **The front fork's virtual centre of rotation behind and below its wheel axle**, so that a step's face, pushing
  the wheel back at its axle's height, turns the fork up about that centre instead of pressing it down.
  `four_bar_about` builds the four-bar from that centre: the coupler upright at the design pose with its joints
  C and D above the wheel, the lower link on the line from the centre through C, the upper one on the line
  through D, both body pivots FORK_SPAN behind the coupler; the links converge toward the centre.
- **The bogies' virtual pivot at the wheel axles' height**: CEDRA's bogie is a beam through both axles, its pivot
  at their height (bogie_z = rear_z), as the default; the variant lengthens it and widens its stops so that
  with the rear bogie wheel on the ground the front one reaches over a step of two wheel diameters,
  2 bogie_half sin(bogie_stop) >= 4 R_w.
- **Loads balanced**: the bogie pivots' x (bogie_x) puts as much weight on the rear wheel as on a bogie wheel at
  rest (the spring holds the fork at its rest angle, so the fork wheel carries what the fork's own weight gives
  through the four-bar): bogie_x = -rear_x / 4 (balanced_bogie_x; tests/test_shrimp.py checks it on the rover's own
  statics).
"""
from __future__ import annotations

import math

from cedra.rover.variants import RoverVariant

R_W = 0.065
AXLE_Z = -0.135             # m: every wheel centre below the body's mass centre at the design pose (the default's)
FORK_WHEEL_X = 0.40         # m: the fork wheel's centre ahead of the body's mass centre (0.165 m ahead of the
#                             bogies' front wheels: 2 R_w and a 3.5 cm gap)
FORK_BEHIND = 0.40          # m: the fork's virtual centre behind its wheel's axle
FORK_BELOW = 0.10           # m: and below it (0.035 m under the ground at the design pose)
FORK_WHEEL = 0.08           # m: the coupler's lower joint C above the wheel's centre
FORK_COUPLER = 0.12         # m: C to the upper joint D
FORK_SPAN = 0.16            # m: the body pivots A, B behind the coupler


def four_bar_about(wheel, behind, below, c_above, coupler, span) -> dict:
    """The four-bar (CEDRA's fork parameters) whose virtual centre at the design pose is `behind` and `below`
    the wheel centre `wheel` (x, z in the body frame): the coupler upright (C `c_above` the wheel, D `coupler`
    above C), A on the line from the centre through C and B on the line through D, both `span` behind the
    coupler. The spring's rest angle is the design pose's lower link angle."""
    xw, zw = wheel
    px, pz = xw - behind, zw - below
    cx, cz = xw, zw + c_above
    dx, dz = cx, cz + coupler
    ax, az = cx + (px - cx) * span / behind, cz + (pz - cz) * span / behind
    bx, bz = dx + (px - dx) * span / behind, dz + (pz - dz) * span / behind
    return {"fork_ax": ax, "fork_az": az, "fork_bx": bx, "fork_bz": bz,
            "fork_a": math.hypot(cx - ax, cz - az), "fork_b": math.hypot(dx - bx, dz - bz), "fork_c": coupler,
            "fork_wheel": c_above, "fork_mass_at": 0.5 * coupler,
            "fork_theta4_ref": math.atan2(cz - az, cx - ax)}


REAR_X = -0.30              # m: the rear wheel (the default's)
BOGIE_HALF = 0.16           # m: the bogie's wheels 0.32 m apart
BOGIE_STOP = 1.0            # rad: 2 bogie_half sin(bogie_stop) = 0.269 m >= 4 R_w = 0.26 m
FORK_STOPS = (-0.6, 1.5)    # rad: the lower link's range (the chain closes over it; the wheel rises 0.12 m at 1.5)
FORK_K = 5.0                # N.m/rad: a soft spring (the default's 20): the fork wheel rises with little push

RULES = dict(axle_z=AXLE_Z, fork_wheel_x=FORK_WHEEL_X, fork_behind=FORK_BEHIND, fork_below=FORK_BELOW,
             fork_c_above=FORK_WHEEL, fork_coupler=FORK_COUPLER, fork_span=FORK_SPAN, fork_stops=FORK_STOPS,
             fork_k=FORK_K, bogie_half=BOGIE_HALF, bogie_stop=BOGIE_STOP, rear_x=REAR_X)


def balanced_bogie_x(rear_x: float) -> float:
    """The bogie pivots' x that gives the rear wheel a bogie wheel's load at rest: with the fork spring at rest the
    fork wheel carries the fork's and its own weight, each wheel its own, and the body's weight (its mass centre
    at x = 0) splits between the two bogie pivots and the rear wheel by their lever arms; the rear wheel gets a
    fifth of it (a bogie wheel's share, each pivot carrying two fifths) where bogie_x / (bogie_x - rear_x) = 1/5."""
    return -rear_x / 4


def values(**rules) -> dict:
    """The variant's parameter values from its rules (RULES, updated by `rules`)."""
    r = {**RULES, **rules}
    r.setdefault("bogie_x", balanced_bogie_x(r["rear_x"]))
    z = r["axle_z"]
    return {**four_bar_about((r["fork_wheel_x"], z), r["fork_behind"], r["fork_below"], r["fork_c_above"],
                             r["fork_coupler"], r["fork_span"]),
            "fork_stop_lo": r["fork_stops"][0], "fork_stop_hi": r["fork_stops"][1], "fork_k": r["fork_k"],
            "bogie_half": r["bogie_half"], "bogie_stop": r["bogie_stop"], "bogie_x": r["bogie_x"], "bogie_z": z,
            "rear_x": r["rear_x"], "rear_z": z}


VALUES = values()

SHRIMP = RoverVariant("cedra_shrimp", "cedra", VALUES,
                      "CEDRA with the Shrimp's design rules: the fork's virtual centre behind and below its axle, "
                      "long bogies, balanced loads (cedra.rover.shrimp)")
