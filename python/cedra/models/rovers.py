"""The rovers a scene may name (`rover = "..."` in a scene file): each a cedra.mechanics.rover.RoverKind from
its own package."""
from cedra.rover.mechanism import CEDRA

ROVERS = {CEDRA.name: CEDRA}
