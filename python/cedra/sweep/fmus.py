"""The FMUs a sweep runs: a shipped scene's (build/<scene>.fmu), a scene file's (<build>/scenes/) and a scene
variant's under [options] (<build>/variants/), each built unless its build stamp says it is up to date.
"""
from __future__ import annotations

from pathlib import Path

from cedra.sweep.definition import Sweep, SweepError, scene_named, sweep_options, variant


def sweep_fmu(sw: Sweep, build_dir) -> Path:
    """The FMU a scene sweep's runs run: the shipped scene's, or a variant's or a scene file's, built unless up to
    date."""
    from cedra.models.scene import shipped
    from cedra.run.scenario import fmu
    if sw.target.variant:
        return _variant_fmu(sw.target.scene, Path(build_dir) / "variants")
    if sw.target.name in shipped():
        return fmu(sw.target.name, build_dir)
    return _variant_fmu(sw.target.scene, Path(build_dir) / "scenes")


def variant_fmu(name: str, options: dict, build_dir="build") -> Path:
    """The FMU of scene `name` (shipped, or a scene file's path) with these [options] (a scenario's plant):
    <build_dir>/variants/<variant>.fmu, built unless up to date; where the options change nothing, the shipped
    scene's own FMU, or a scene file's in <build_dir>/scenes/."""
    from cedra.run.scenario import ScenarioError, fmu
    where = Path(f"<scene {name}>")
    try:
        scene = scene_named(where, name)
        var = variant(where, scene, sweep_options(where, options))
    except SweepError as e:
        raise ScenarioError(str(e)) from e
    if var is not scene:
        return _variant_fmu(var, Path(build_dir) / "variants")
    from cedra.models.scene import shipped
    return fmu(name, build_dir) if name in shipped() else _variant_fmu(scene, Path(build_dir) / "scenes")


def _variant_fmu(scene, build_dir: Path) -> Path:
    """<build_dir>/<variant>.fmu, built unless its build stamp says it is this scene's (its content, its heightmap's
    grid) from today's sources and flags (cedra.fmu.packaging.ensure_fmu)."""
    from cedra.fmu.packaging import ensure_fmu
    return ensure_fmu(scene, build_dir)
