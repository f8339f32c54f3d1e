"""Running FMUs: the FMPy driver, the main job, the co-simulation master, SSP packages, scenario scripts."""
