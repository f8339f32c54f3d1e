"""Models the FMUs are built from: a scene (TOML) and the plant's equations, the drive controller's equations.

Importing the package hands cedra.mechanics the builders of its host libraries (cedra.models.host)."""
from cedra.models import host

__all__ = ["host"]
