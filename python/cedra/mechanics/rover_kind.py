"""What a rover description gives the equations (docs/model.md, Mechanism): the interface between a rover's own
package (its transform chains, masses, joints; CEDRA's is cedra.rover) and the machinery that forms a scene's
equations from it (cedra.models.plant: Kane's method, terrain, contact, drives, outputs).

A rover is a `RoverKind`: static facts (its full 3D coordinates, which of them a planar scene keeps, which it
steers with, which the static settle solves for, its parameters) and functions of symbols: `describe` (bodies,
wheels, joint torques, potential, collision points), `stops` (its joints' compliant stops, for the force-law
switches), `design` (the pose the settle starts from) and `joint_outputs` (the FMU outputs of its joints).

Fixed names, so that the machinery is the same for every rover (as the contract's function names are): the body
pose coordinates are x, y, z, yaw, pitch, roll (the body's mass center, ZYX Euler angles) and the six wheels spin
with gamma1..gamma6 relative to their carriers, wheel i's motor torque acting on gamma{i}.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import casadi as ca

from cedra.contract import Quantity
from cedra.mechanics.kane import Body

POSE = ("x", "y", "z", "yaw", "pitch", "roll")
SPINS = tuple(f"gamma{i}" for i in range(1, 7))


@dataclass
class Wheel:
    index: int          # the wheel's number, 1..6
    center: ca.SX       # world
    axle: ca.SX         # world unit vector
    omega: ca.SX        # world angular velocity of the wheel
    velocity: ca.SX     # world velocity of the center
    up: ca.SX           # world unit vector: the contact frame's normal at psi = 0 in the kinematics' convention
    #                     (the carrier's own rotation undone, so psi is measured from the rover frame R)


@dataclass
class CollisionPoint:
    """A point of the body or a link that can touch the terrain (docs/model.md, Chassis and links); no mass.
    position: world, an expression of the coordinates (a material point of its link, so its velocity is the
    position's time derivative). planar_weight: in 2D, where the terrain is constant in Y, points that differ
    only in y act as one: the point on the center line carries the count of its twins, the others 0."""
    link: str
    position: ca.SX
    planar_weight: int


@dataclass
class RoverDescription:
    bodies: list[Body]
    wheels: list[Wheel]         # in wheel order 1..6
    coordinate_torques: ca.SX   # torque on each full coordinate (joint springs, stops, motors, servos)
    potential: ca.SX            # gravity (datum Z = 0) + springs + stops + servo springs
    closure: ca.SX              # |closure| < 1 where the mechanism can be assembled (a closed chain's; else 0)
    body_omega: ca.SX
    body_velocity: ca.SX
    collision_points: list[CollisionPoint]
    # a rover's description may carry more (its own dataclass deriving from this one) for its joint_outputs


@dataclass(frozen=True)
class Stop:
    """A joint's compliant stops: lo <= coordinate <= hi (names of parameters, or a sign and a name: "-bogie_stop")."""
    coordinate: str
    lo: str
    hi: str

    def limits(self, p) -> tuple:
        def value(name):
            return -p[name[1:]] if name.startswith("-") else p[name]
        return value(self.lo), value(self.hi)


@dataclass(frozen=True)
class RoverKind:
    name: str
    coordinates: tuple[str, ...]            # the full 3D coordinates: POSE, the joints, SPINS (any order)
    planar: dict                            # 2D: coordinate -> the coordinate it equals there, or None (held at 0)
    steering: tuple[str, ...]               # steering joints (held at 0 in a scene without steering); () = none
    settle: tuple[str, ...]                 # what the static settle solves for
    parameters: list[Quantity]              # the rover's own parameters (FMU parameters, in this order)
    servo_parameters: list[Quantity]        # the steering servo's, in a scene with steering
    steer_inputs: list[Quantity]            # the steering commands, in a scene with steering
    describe: Callable                      # (qf, rate, p, tau, steer_cmd or None, stop_width=None)
    #                                         -> RoverDescription
    stops: tuple[Stop, ...]                 # the joints' compliant stops (force-law switches)
    design: Callable                        # p -> {coordinate: value}: body height z over flat ground and the
    #                                         joint angles of the design pose (the rest 0)
    joint_outputs: Callable                 # (qf, qd, idx, description, steering: bool) -> [(Quantity, expr)]

    @property
    def index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.coordinates)}

    def check(self) -> None:
        missing = [n for n in POSE + SPINS if n not in self.coordinates]
        if missing:
            raise ValueError(f"rover {self.name}: coordinates without the fixed names {missing}")
