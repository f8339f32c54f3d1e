"""Scene files (TOML): what one simulation needs. A bad scene fails here, with the file, the key and the reason,
before any code is generated.

    name = "bump2d"                 # FMU model identifier: letters, digits, underscore
    description = "..."
    rover = "cedra"                 # which rover (cedra.models.rovers.ROVERS; default cedra), a shipped variant
                                    # of one (cedra.models.rovers.VARIANTS: "cedra_shrimp"), or a rover variant
                                    # file (.toml, relative to the scene file; format: read_variant)
    dims = "2d"                     # "2d" (planar, 9 DOF) or "3d" (17 DOF, 15 without steering)
    terrain = "bump"                # flat | slope | bump | bump3d | step | stairs | waves | heightmap
    stairs_steps = 4                # terrain "stairs" only: its number of steps (1..50)
    heightmap = "hills.txt"         # terrain "heightmap" only: the grid file (format: fmu_src/heightmap.h), relative
                                    # to the scene file; shipped in the FMU as resources/heightmap.txt
    contact = "compliant"           # compliant | rigid (the paper's decision tree, docs/rigid-contact.md)
    steering = false                # 3d only: steering servo on wheels 5 and 6
    locked_wheels = false           # wheels welded to their carriers (a parking brake; no torque inputs)
    drives = false                  # motor-and-gear model between tau[i] and the wheel (docs/model.md, Drives)
    chassis = false                 # the body's and links' collision points touch the terrain (docs/model.md,
                                    # Chassis and links)
    stop_time = 15.0                # s, the FMU's DefaultExperiment
    output_interval = 0.01          # s, the DefaultExperiment's step size
    [solver]                        # defaults of the FMU's solver.* parameters
    method = "rodas4"               # rk4 | dopri5 | rodas4 | ros34pw2 | moreau (rigid scenes only)
    tol = 1e-6
    h_max = 0.01
    max_steps = 100000              # budget of one fmi2DoStep: attempted steps
    max_wall_time = 1.0             # budget of one fmi2DoStep: wall-clock seconds
    [parameters]                    # start values of model parameters (docs/model.md, Parameters; ground_k, ...)
    [inputs]                        # start values of inputs (tau[1], mu, terrain_h, ...)
    [start]                         # initial coordinates, e.g. x = 0.0 (the rest is settled by the FMU)
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

from cedra.mechanics import heightmap
from cedra.models.plant import CedraModel, ModelOptions, input_table, param_table, projection
from cedra.models.rovers import ROVERS, VARIANTS
from cedra.rover.assembly import assembly_failure
from cedra.rover.variants import RoverVariant
from cedra.contract import MAX_STEPS_LIMIT, MAX_WALL_LIMIT, SOLVER_METHODS, ModelSpec
from cedra.mechanics.terrain import KINDS, STAIRS_STEPS

SOLVERS = {name: k for k, name in enumerate(SOLVER_METHODS)}
TOP_KEYS = {"name", "description", "rover", "dims", "terrain", "heightmap", "stairs_steps", "contact", "steering", "locked_wheels",
            "drives", "chassis", "stop_time", "output_interval",
            "solver", "parameters", "inputs", "start"}


# The boolean scene keys (ModelOptions fields) a sweep file may set in its [options] table to run a variant of its
# scene (cedra.sweep): each builds a different model, so the variant FMU gets its own name.
SWEEP_OPTIONS = ("drives", "chassis")


class SceneError(ValueError):
    pass


@dataclass
class Scene:
    name: str
    description: str
    options: ModelOptions
    stop_time: float
    output_interval: float
    solver: dict
    parameters: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)
    start: dict = field(default_factory=dict)
    path: str = ""
    variant: RoverVariant | None = None     # the rover variant the scene names (its values are in parameters)

    def model(self) -> CedraModel:
        return CedraModel(self.options)

    def spec(self, model: CedraModel | None = None) -> ModelSpec:
        model = model or self.model()
        s = model.spec(self.name, self.description, stop_time=self.stop_time, output_interval=self.output_interval,
                       solver=dict(self.solver))
        s.params = [replace(p, start=float(self.parameters.get(p.name, p.start))) for p in s.params]
        s.inputs = [replace(p, start=float(self.inputs.get(p.name, p.start))) for p in s.inputs]
        if self.variant is not None:
            # the design pose of the variant's geometry (the base's is the default start)
            design = model.kind.design({p.name: p.start for p in s.params})
            for name, value in design.items():
                if name in s.q_names:
                    s.q_start[s.q_names.index(name)] = float(value)
        for name, value in self.start.items():
            s.q_start[s.q_names.index(name)] = float(value)
        return s


# The checks of a file's values (scene files here, optimization problem files in cedra.optimize.problem): each fails
# with `error` (SceneError by default) saying "<path>: key '<key>': <reason>".
def fail(path, key, reason, error=None):
    raise (error or SceneError)(f"{path}: key '{key}': {reason}")


def number(path, key, value, lo=None, hi=None, positive=False, lo_exclusive=False, error=None):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fail(path, key, f"expected a number, got {value!r}", error)
    value = float(value)
    if not math.isfinite(value):
        fail(path, key, f"must be finite, got {value}", error)
    if positive and value <= 0:
        fail(path, key, f"must be > 0, got {value}", error)
    if lo is not None and lo_exclusive and value <= lo:
        fail(path, key, f"must be > {lo}, got {value}", error)
    if lo is not None and value < lo:
        fail(path, key, f"must be >= {lo}, got {value}", error)
    if hi is not None and value > hi:
        fail(path, key, f"must be <= {hi}, got {value}", error)
    return value


def choice(path, key, value, choices, error=None):
    if value not in choices:
        fail(path, key, f"must be one of {', '.join(sorted(choices))}, got {value!r}", error)
    return value


def _table(path, data, key):
    t = data.get(key, {})
    if not isinstance(t, dict):
        fail(path, key, "must be a table")
    return t


def _heightmap_file(path, data, terrain) -> str:
    """The absolute path of a heightmap scene's grid, read once here (the FMU's own C reader) so that a bad file
    fails before any code is generated."""
    if terrain != "heightmap":
        if "heightmap" in data:
            fail(path, "heightmap", f"only for terrain = 'heightmap' (this scene's terrain is '{terrain}')")
        return ""
    if "heightmap" not in data:
        fail(path, "heightmap", "missing: terrain 'heightmap' needs its grid file")
    name = data["heightmap"]
    if not isinstance(name, str) or not name:
        fail(path, "heightmap", f"expected a file name, got {name!r}")
    base = Path(path).parent if path != "<scene>" else Path.cwd()
    file = (base / name).resolve()
    try:
        heightmap.load(file)
    except heightmap.HeightmapError as e:
        fail(path, "heightmap", str(e))
    return str(file)


def read_variant(file) -> RoverVariant:
    """A rover variant file (TOML): a shipped rover with other parameter values. A bad file fails with the variant
    file, the key and the reason.

        name = "my_cedra"               # letters, digits, underscore (default: the file's stem)
        description = "..."
        base = "cedra"                  # the rover it varies (cedra.models.rovers.ROVERS)
        [parameters]                    # its parameters' values (the base's defaults for the rest)
        bogie_half = 0.15
    """
    data = read_toml(file, SceneError)
    path = str(file)
    for key in data:
        if key not in ("name", "description", "base", "parameters"):
            fail(path, key, "unknown key (known: base, description, name, parameters)")
    if "base" not in data:
        fail(path, "base", f"missing: the rover the variant varies ({', '.join(sorted(ROVERS))})")
    base = choice(path, "base", data["base"], set(ROVERS))
    name = data.get("name", Path(file).stem)
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        fail(path, "name", f"must be an identifier (letters, digits, underscore), got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        fail(path, "description", "must be a string")
    known = {q.name: q for q in ROVERS[base].parameters}
    values = {}
    for key, value in _table(path, data, "parameters").items():
        if key not in known:
            fail(path, f"parameters.{key}", f"not a parameter of rover {base}")
        q = known[key]
        values[key] = number(path, f"parameters.{key}", value, q.min, q.max, lo_exclusive=q.min_exclusive)
    return RoverVariant(name, base, values, description, source=path)


def _rover(path, value) -> tuple[str, RoverVariant | None]:
    """The scene's rover key: (the rover kind's name, the variant or None)."""
    if not isinstance(value, str):
        fail(path, "rover", f"expected a rover's name or a variant file, got {value!r}")
    if value in ROVERS:
        return value, None
    if value in VARIANTS:
        return VARIANTS[value].base, VARIANTS[value]
    if value.endswith(".toml"):
        base = Path(path).parent if path != "<scene>" else Path.cwd()
        file = (base / value).resolve()
        if not file.is_file():
            fail(path, "rover", f"no rover variant file {str(file)!r}")
        variant = read_variant(file)
        return variant.base, variant
    fail(path, "rover", f"must be one of {', '.join(sorted(ROVERS | VARIANTS))} or a rover variant file (.toml), "
         f"got {value!r}")


def _check_assembly(path, scene: Scene, own: dict) -> None:
    """The rover's closed chains assemble over their joints' range with the scene's parameter values (the
    variant's, then the scene's own, `own`); else the file that sets the failing geometry fails, naming its keys:
    the scene's [parameters] where it sets any of them, else the variant's."""
    failure = assembly_failure(ROVERS[scene.options.rover], scene.parameters)
    if failure is None:
        return
    variant = scene.variant
    keys = [k for k in failure.parameters if k in own]
    if keys or variant is None:
        fail(path, ", ".join(f"parameters.{k}" for k in keys) or "rover", failure.reason())
    keys = [k for k in failure.parameters if k in variant.values]
    where = variant.source or f"{path} (rover variant {variant.name!r})"
    fail(where, ", ".join(f"parameters.{k}" for k in keys) or "base", failure.reason())


def parse(data: dict, path: str = "<scene>") -> Scene:
    for key in data:
        if key not in TOP_KEYS:
            fail(path, key, f"unknown key (known: {', '.join(sorted(TOP_KEYS))})")
    for key in ("name", "dims", "terrain"):
        if key not in data:
            fail(path, key, "missing")
    name = data["name"]
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        fail(path, "name", f"must be an identifier (letters, digits, underscore), got {name!r}")
    rover, variant = _rover(path, data.get("rover", "cedra"))
    dims = choice(path, "dims", data["dims"], {"2d", "3d"})
    terrain = choice(path, "terrain", data["terrain"], set(KINDS))
    if dims == "2d" and terrain in ("bump3d", "waves", "heightmap"):
        fail(path, "terrain", f"'{terrain}' varies along Y and needs dims = '3d'")
    heightmap_file = _heightmap_file(path, data, terrain)
    steps = data.get("stairs_steps", STAIRS_STEPS)
    if "stairs_steps" in data and terrain != "stairs":
        fail(path, "stairs_steps", f"only for terrain = 'stairs' (this scene's terrain is '{terrain}')")
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 50:
        fail(path, "stairs_steps", f"expected an integer in 1..50, got {steps!r}")
    contact = choice(path, "contact", data.get("contact", "compliant"), {"compliant", "rigid"})
    steering = data.get("steering", False)
    if not isinstance(steering, bool):
        fail(path, "steering", f"expected true or false, got {steering!r}")
    if dims == "2d" and steering:
        fail(path, "steering", "a 2d scene has no steering")
    if steering and not ROVERS[rover].steering:
        fail(path, "steering", f"rover '{rover}' has no steering joints (it turns by skid steering)")
    locked = data.get("locked_wheels", False)
    if not isinstance(locked, bool):
        fail(path, "locked_wheels", f"expected true or false, got {locked!r}")
    drives = data.get("drives", False)
    if not isinstance(drives, bool):
        fail(path, "drives", f"expected true or false, got {drives!r}")
    if drives and locked:
        fail(path, "drives", "locked wheels have no motors (locked_wheels = true)")
    chassis = data.get("chassis", False)
    if not isinstance(chassis, bool):
        fail(path, "chassis", f"expected true or false, got {chassis!r}")
    stop_time = number(path, "stop_time", data.get("stop_time", 10.0), positive=True)
    interval = number(path, "output_interval", data.get("output_interval", 0.01), positive=True)
    if interval > stop_time:
        fail(path, "output_interval", f"{interval} is longer than stop_time {stop_time}")
    description = data.get("description", "")
    if not isinstance(description, str):
        fail(path, "description", "must be a string")

    solver = dict(method="rodas4", tol=1e-6, h_max=0.01)
    st = _table(path, data, "solver")
    for key, value in st.items():
        k = f"solver.{key}"
        if key == "method":
            solver["method"] = choice(path, k, value, set(SOLVERS))
        elif key in ("tol", "h_max"):
            solver[key] = number(path, k, value, positive=True)
        elif key == "max_wall_time":
            solver[key] = number(path, k, value, positive=True)
            if solver[key] > MAX_WALL_LIMIT:
                fail(path, k, f"must be <= {MAX_WALL_LIMIT:g} s (a call always has a bound), got {solver[key]}")
        elif key == "max_steps":
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_STEPS_LIMIT:
                fail(path, k, f"expected an integer in 1..{MAX_STEPS_LIMIT}, got {value!r}")
            solver[key] = value
        else:
            fail(path, k, "unknown key (known: method, tol, h_max, max_steps, max_wall_time)")

    if solver["method"] == "moreau" and contact != "rigid":
        fail(path, "solver.method", "moreau is the rigid contact's own time stepping (contact = \"rigid\")")
    opt = ModelOptions(dims=dims, terrain=terrain, steering=steering, contact=contact, locked_wheels=locked,
                       heightmap=heightmap_file, drives=drives, stairs_steps=steps, chassis=chassis, rover=rover)
    scene = Scene(name, description, opt, stop_time, interval, solver, path=str(path), variant=variant)
    for section, table in (("parameters", param_table(opt)), ("inputs", input_table(opt))):
        known = {q.name: q for q in table}
        values = {}
        for key, value in _table(path, data, section).items():
            if key not in known:
                what = "an input" if section == "inputs" else "a parameter"
                fail(path, f"{section}.{key}", f"not {what} of this scene "
                      f"(dims={dims}, terrain={terrain}, steering={steering}, drives={drives})")
            q = known[key]
            values[key] = number(path, f"{section}.{key}", value, q.min, q.max, lo_exclusive=q.min_exclusive)
            if terrain == "stairs" and key == "terrain_h" and values[key] < 0:
                fail(path, f"{section}.{key}", f"the stairs' rise must be >= 0, got {values[key]}")
        setattr(scene, section, values)
    own = dict(scene.parameters)
    if variant is not None:
        scene.parameters = {**variant.values, **own}
    _check_assembly(path, scene, own)
    names, _ = projection(opt)
    for key, value in _table(path, data, "start").items():
        if key not in names:
            fail(path, f"start.{key}", f"not a coordinate of this scene (coordinates: {', '.join(names)})")
        scene.start[key] = number(path, f"start.{key}", value)
    return scene


def read_toml(path, error=ValueError) -> dict:
    """The TOML file's table; an unreadable file or bad TOML raises error naming the file (scene, problem files)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML: {e}") from None


def load(path) -> Scene:
    return parse(read_toml(path, SceneError), str(path))


def shipped() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("cedra.models.scenes").iterdir() if p.name.endswith(".toml"))


def load_shipped(name: str) -> Scene:
    if name not in shipped():
        raise SceneError(f"no shipped scene {name!r} (shipped: {', '.join(shipped())})")
    return load(Path(str(resources.files("cedra.models.scenes") / f"{name}.toml")))
