"""The rovers a scene may name (`rover = "..."` in a scene file): each a cedra.mechanics.rover_kind.RoverKind from
its own description."""
from cedra.rover.mechanism import CEDRA
from cedra.rover.rocker_bogie import ROCKER_BOGIE

ROVERS = {kind.name: kind for kind in (CEDRA, ROCKER_BOGIE)}
