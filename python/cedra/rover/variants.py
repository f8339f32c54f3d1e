"""Rover variants: a rover kind with other values of its own parameters (its geometry, masses, springs, stops),
which a scene file names like a rover (cedra.models.scene: `rover = "cedra_shrimp"`, or a variant file of the
user's). The FMU is the base rover's, its parameters' start values the variant's.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class RoverVariant:
    name: str
    base: str                   # the rover kind's name (cedra.models.rovers.ROVERS)
    values: dict = field(default_factory=dict)     # parameter values that differ from the base's defaults
    description: str = ""
    source: str = ""            # the variant file it was read from ("" for a shipped one)
