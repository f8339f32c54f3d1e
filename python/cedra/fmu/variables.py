"""The FMU's variable table, built from a ModelSpec: the ONE source of modelDescription.xml and of the C glue's
value-reference table (cedra_vars.h), see modelDescription/generate.py.

Each row (`Var`) says what the variable is in FMI terms (name, value reference, causality, variability, initial,
start, unit, min/max, type) and where the C glue finds it (`kind`, `index`):

    kind        index               C location
    "par"       i                   model parameter par[i]           (causality parameter, fixed)
    "inp"       i                   input inp[i]                     (causality input, continuous)
    "out"       i                   output y[i] of cedra_out         (causality output; Integer: y[i] rounded)
    "q_start"   i                   start value of q[i]              (parameter start.<q name> or a start_params name)
    "u_start"   i                   start value of u[i]              (parameter start.speed.<q name>)
    "settle"    0                   Boolean start.settle
    "solver"    0 method, 1 tol, 2 h_max, 3 max_steps, 4 max_wall_time   (parameters solver.*)
    "stat"      0 steps, 1 rejected, 2 rhs_evals, 3 jac_evals        (Integer outputs solver.*)

Value references are the row numbers (0, 1, 2, ...), unique across types, so the C glue indexes its table
directly with the value reference.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cedra.contract import MAX_STEPS_LIMIT, MAX_WALL_LIMIT, SOLVER_METHODS, ModelSpec

KINDS = ("par", "inp", "out", "q_start", "u_start", "settle", "solver", "stat")
# max_steps and max_wall_time bound the cost of one fmi2DoStep (no call runs without a bound): 1 s of wall time
# answers about as fast as a user waits for one call; 100000 attempted steps is ~1-4 s of the 2D/3D models on
# this machine and makes the bound reproducible when the clock would not be (a loaded machine)
SOLVER_DEFAULTS = dict(method="dopri5", tol=1e-6, h_max=0.01, max_steps=100000, max_wall_time=1.0)


@dataclass(frozen=True)
class Var:
    name: str
    vr: int
    causality: str            # "parameter", "input", "output"
    variability: str          # "fixed", "continuous", "discrete"
    initial: str | None       # "exact", "calculated" or None (not given: inputs)
    start: float | int | bool | None
    unit: str | None          # Real only
    description: str
    type: str                 # "Real", "Integer", "Boolean"
    kind: str                 # see KINDS
    index: int
    min: float | None = None
    max: float | None = None
    min_exclusive: bool = False   # the glue refuses value == min (XML min is inclusive: it only gives min)
    quantity: str | None = None   # Real only: the physical quantity (Angle, Force, ...), see quantity_of
    display_unit: str | None = None   # Real only: the unit an importer shows (deg, rpm), see DISPLAY_UNITS


def solver_method_index(method) -> int:
    if isinstance(method, str):
        if method not in SOLVER_METHODS:
            raise ValueError(f"unknown solver method {method!r} (one of {', '.join(SOLVER_METHODS)})")
        return SOLVER_METHODS.index(method)
    m = int(method)
    if not 0 <= m < len(SOLVER_METHODS):
        raise ValueError(f"solver method {method} is not in 0..{len(SOLVER_METHODS) - 1}")
    return m


def solver_methods(spec: ModelSpec) -> int:
    """how many of SOLVER_METHODS the model's FMU offers: moreau (the last) is rigid contact's own"""
    return len(SOLVER_METHODS) - (spec.contact != "rigid")


def solver_defaults(spec: ModelSpec) -> dict:
    s = dict(SOLVER_DEFAULTS)
    s.update(spec.solver or {})
    unknown = set(s) - set(SOLVER_DEFAULTS)
    if unknown:
        raise ValueError(f"model {spec.name}: unknown solver settings {sorted(unknown)}")
    if solver_method_index(s["method"]) >= solver_methods(spec):
        raise ValueError(f"model {spec.name}: solver method {s['method']!r} is for rigid contact only")
    return dict(method=solver_method_index(s["method"]), tol=float(s["tol"]), h_max=float(s["h_max"]),
                max_steps=int(s["max_steps"]), max_wall_time=float(s["max_wall_time"]))


def _finite(x, what):
    if x is not None and not math.isfinite(float(x)):
        raise ValueError(f"{what} is not finite: {x}")
    return x


def variables(spec: ModelSpec) -> list[Var]:
    """The FMU's variables in value-reference order (vr == position in the list)."""
    rows: list[dict] = []

    def add(**kw):
        kw.setdefault("min", None)
        kw.setdefault("max", None)
        rows.append(kw)

    for i, p in enumerate(spec.params):
        if p.type not in ("Real", "Integer"):
            raise ValueError(f"parameter {p.name}: type {p.type} (Real or Integer)")
        add(name=p.name, causality="parameter", variability="fixed", initial="exact",
            start=float(p.start) if p.type == "Real" else int(p.start), unit=p.unit, description=p.description,
            type=p.type, kind="par", index=i, min=p.min, max=p.max, min_exclusive=p.min_exclusive)
    for i, p in enumerate(spec.inputs):
        add(name=p.name, causality="input", variability="continuous", initial=None, start=float(p.start),
            unit=p.unit, description=p.description, type="Real", kind="inp", index=i, min=p.min, max=p.max,
            min_exclusive=p.min_exclusive)
    for i, p in enumerate(spec.outputs):
        if p.type not in ("Real", "Integer"):
            raise ValueError(f"output {p.name}: type {p.type} (Real or Integer)")
        # a sampled block's outputs change only at samples: discrete
        add(name=p.name, causality="output",
            variability="continuous" if p.type == "Real" and spec.block == "plant" else "discrete",
            initial="calculated", start=None, unit=p.unit if p.type == "Real" else None,
            description=p.description, type=p.type, kind="out", index=i, min=p.min, max=p.max)
    if spec.block == "plant":
        _plant_rows(spec, add)
    names = [r["name"] for r in rows]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"model {spec.name}: duplicate variable names {sorted(dup)}")
    out = []
    for vr, r in enumerate(rows):
        if r["type"] == "Real" and r["unit"] is None:
            r["unit"] = _q_unit(spec.q_names[r["index"]], speed=r["kind"] == "u_start")
        if r["type"] != "Real":
            r["unit"] = None
        else:
            r["quantity"] = quantity_of(r["name"], r["unit"])
            r["display_unit"] = display_unit_of(r["name"], r["unit"])
        _finite(r["start"], f"start value of {r['name']}")
        out.append(Var(vr=vr, **r))
    return out


def _plant_rows(spec: ModelSpec, add) -> None:
    """What a plant has beyond parameters, inputs and outputs: start values, start.settle, the solver."""
    # start values of the coordinates: a start_params name replaces start.<q name> for its coordinate
    q_param = {i: f"start.{n}" for i, n in enumerate(spec.q_names)}
    seen: dict[int, str] = {}
    for pname, i in spec.start_params.items():
        if not 0 <= i < spec.nq:
            raise ValueError(f"model {spec.name}: start parameter {pname} names coordinate {i} of {spec.nq}")
        if i in seen and seen[i] != pname:
            raise ValueError(f"model {spec.name}: start parameters {seen[i]} and {pname} both set q[{i}]")
        seen[i] = pname
        q_param[i] = pname
    for i, n in enumerate(spec.q_names):
        add(name=q_param[i], causality="parameter", variability="fixed", initial="exact",
            start=float(spec.q_start[i]), unit=None, description=f"start value of the coordinate {n}"
            + (" (then settled in static equilibrium if start.settle)" if i in spec.settle_idx else ""),
            type="Real", kind="q_start", index=i)
    for i, n in enumerate(spec.q_names):
        add(name=f"start.speed.{n}", causality="parameter", variability="fixed", initial="exact", start=0.0,
            unit=None, description=f"start value of the rate of {n}", type="Real", kind="u_start", index=i)
    add(name="start.settle", causality="parameter", variability="fixed", initial="exact", start=True, unit=None,
        description="solve the static equilibrium of the coordinates " +
        ", ".join(spec.q_names[i] for i in spec.settle_idx) + " during initialization", type="Boolean",
        kind="settle", index=0)
    sd = solver_defaults(spec)
    add(name="solver.method", causality="parameter", variability="fixed", initial="exact", start=sd["method"],
        unit=None, description="embedded solver: 0 RK4 (fixed step h_max), 1 DOPRI5, 2 RODAS4, 3 ROS34PW2 "
                                 "(Rosenbrock-W: keeps its Jacobian over steps)" +
                                 (", 4 MOREAU (Moreau-Jean time stepping of the rigid contact, fixed step h_max: "
                                  "forces and impacts as impulses over a step)" if spec.contact == "rigid" else ""),
        type="Integer", kind="solver", index=0, min=0, max=solver_methods(spec) - 1)
    add(name="solver.tol", causality="parameter", variability="fixed", initial="exact", start=sd["tol"],
        unit="1", description="relative and absolute tolerance of the adaptive solvers (> 0); the importer's "
        "fmi2SetupExperiment tolerance replaces the default unless this parameter is set", type="Real",
        kind="solver", index=1, min=0.0, min_exclusive=True)
    add(name="solver.h_max", causality="parameter", variability="fixed", initial="exact", start=sd["h_max"],
        unit="s", description="largest step of the solvers, RK4's and MOREAU's fixed step (> 0)", type="Real",
        kind="solver", index=2, min=0.0, min_exclusive=True)
    add(name="solver.max_steps", causality="parameter", variability="fixed", initial="exact",
        start=sd["max_steps"], unit=None, description="budget of one fmi2DoStep: attempted steps (accepted and "
        "rejected); a communication step that needs more than max_steps steps of h_max is refused, one that "
        "uses them up is discarded", type="Integer", kind="solver", index=3, min=1, max=MAX_STEPS_LIMIT)
    add(name="solver.max_wall_time", causality="parameter", variability="fixed", initial="exact",
        start=sd["max_wall_time"], unit="s", description="budget of one fmi2DoStep: wall-clock seconds; a step "
        "that spends them is discarded", type="Real", kind="solver", index=4, min=0.0, min_exclusive=True,
        max=MAX_WALL_LIMIT)
    for j, (n, d) in enumerate((("steps", "accepted steps since the start"),
                                ("rejected", "rejected steps since the start"),
                                ("rhs_evals", "right-hand side evaluations since the start"),
                                ("jac_evals", "Jacobian evaluations since the start (rodas4: one per accepted "
                                              "step; ros34pw2 keeps one over many steps)"))):
        add(name=f"solver.{n}", causality="output", variability="discrete", initial="calculated", start=None,
            unit=None, description=f"embedded solver: {d}", type="Integer", kind="stat", index=j)


_ANGLE_PREFIXES = ("theta", "gamma", "pitch", "roll", "yaw", "phi", "psi", "angle", "beta", "alpha")


def _q_unit(qname: str, speed: bool) -> str:
    base = "rad" if qname.lower().startswith(_ANGLE_PREFIXES) else "m"
    return f"{base}/s" if speed else base


# The quantity of every Real variable (modelDescription's `quantity` attribute, as Modelica names them), by unit;
# QUANTITY_BY_NAME first for variables whose unit alone does not say it.
QUANTITY_BY_UNIT = {
    "1": "Dimensionless", "1/s": "Frequency", "J": "Energy", "N": "Force", "N.m": "Torque", "kg": "Mass",
    "kg.m2": "MomentOfInertia", "m": "Length", "m/s": "Velocity", "m/s2": "Acceleration", "rad": "Angle",
    "rad/s": "AngularVelocity", "s": "Time", "N/m": "TranslationalSpringConstant",
    "N.s/m": "TranslationalDampingConstant", "N.m/rad": "RotationalSpringConstant",
    "N.m.s/rad": "RotationalDampingConstant", "N.m.s/m": "TorquePerVelocity", "N.m/m": "TorquePerLength",
}
QUANTITY_BY_NAME = {"mu": "CoefficientOfFriction", "solver.tol": "Tolerance", "rigid_alpha": "Frequency",
                    "ctrl.trim_ki": "Gain"}
# Display units an importer may show instead of the variable's unit: value in display unit = factor * value.
DISPLAY_UNITS = {"rad": ("deg", 180.0 / math.pi), "rad/s": ("rpm", 30.0 / math.pi)}
# rad/s variables shown in rpm: the wheels' spin rates (the others, body and joint rates, stay in rad/s)
_RPM_PREFIXES = ("wheel[", "ctrl.omega_ref[", "start.speed.gamma", "drive_noload_speed")


def quantity_of(name: str, unit: str) -> str:
    """The quantity attribute of a Real variable with this name and unit."""
    if name in QUANTITY_BY_NAME:
        return QUANTITY_BY_NAME[name]
    if unit not in QUANTITY_BY_UNIT:
        raise ValueError(f"variable {name}: no quantity known for the unit {unit!r} (add it to QUANTITY_BY_UNIT)")
    return QUANTITY_BY_UNIT[unit]


def display_unit_of(name: str, unit: str) -> str | None:
    """deg for every angle, rpm for the wheels' spin rates, None (the unit itself) otherwise."""
    if unit == "rad":
        return "deg"
    if unit == "rad/s" and name.startswith(_RPM_PREFIXES):
        return "rpm"
    return None


def units(table: list[Var]) -> list[str]:
    """Every unit the table uses, sorted."""
    return sorted({v.unit for v in table if v.unit})
