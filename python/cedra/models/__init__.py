"""Models the FMUs are built from: a scene (TOML) and the plant's equations, the drive controller's equations."""
