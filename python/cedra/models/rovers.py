"""The rovers a scene may name (`rover = "..."` in a scene file): each a cedra.mechanics.rover_kind.RoverKind from
its own description, and the shipped variants of them (cedra.rover.variants: a rover with other parameter values,
built as its base rover's FMU with the variant's start values)."""
from cedra.rover.mechanism import CEDRA
from cedra.rover.rocker_bogie import ROCKER_BOGIE
from cedra.rover.shrimp import SHRIMP

ROVERS = {kind.name: kind for kind in (CEDRA, ROCKER_BOGIE)}
VARIANTS = {variant.name: variant for variant in (SHRIMP,)}
