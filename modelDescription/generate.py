"""modelDescription.xml (FMI 2.0 Co-Simulation) and cedra_vars.h (the C glue's sizes and value-reference table),
both from the one variable table of cedra.fmu.variables.

    spec_guid(spec) -> str                                  "{8-4-4-4-12}" from a SHA-256 of the spec
    write_model_description(spec, path, guid) -> Path
    write_vars_header(spec, path, guid) -> Path
"""
from __future__ import annotations

import hashlib
import json
import re
import sys
import uuid
from pathlib import Path

from lxml import etree

_PY = Path(__file__).resolve().parents[1] / "python"
if str(_PY) not in sys.path:                      # importable from a checkout without installing the package
    sys.path.insert(0, str(_PY))

from cedra import __version__  # noqa: E402
from cedra.contract import ModelSpec  # noqa: E402
from cedra.fmu.mass_order import elimination_order  # noqa: E402
from cedra.fmu.variables import DISPLAY_UNITS, Var, solver_defaults, units, variables  # noqa: E402

GENERATION_TOOL = f"cedra {__version__}"       # the package's version (pyproject.toml), also the FMU's version
LOG_CATEGORIES = [
    ("logEvents", "initialization, settle, steps refused"),
    ("logStatusWarning", "warnings"),
    ("logStatusDiscard", "steps discarded (state cannot be evaluated, solver failure)"),
    ("logStatusError", "errors (bad arguments, call order)"),
    ("logStatusFatal", "fatal errors"),
    ("logAll", "everything"),
]
# the hand-written C files of each kind of block's FMU (sources/ and the build): the generic glue, the block, what
# it uses; the generated model's files (one per contract function) follow them (source_files)
HAND_WRITTEN_C = {
    "plant": ["fmi2_glue.c", "plant.c", "model_glue.c", "solver.c", "linalg.c", "rigid.c", "heightmap.c", "rim.c"],
    "controller": ["fmi2_glue.c", "controller.c"],
}


def source_files(spec: ModelSpec) -> list[str]:
    """Every C file the FMU ships in sources/ and compiles: the hand-written ones, then the generated ones."""
    from cedra.fmu.codegen import generated_files
    return HAND_WRITTEN_C[spec.block] + generated_files(spec)


def _fmt(x: float) -> str:
    return repr(float(x))             # shortest round-trip representation


def spec_guid(spec: ModelSpec) -> str:
    """Same spec (variables, defaults, functions) -> same GUID."""
    h = hashlib.sha256()
    table = [[v.name, v.vr, v.causality, v.variability, v.initial, v.start, v.unit, v.type, v.kind, v.index,
              v.min, v.max, v.quantity, v.display_unit] for v in variables(spec)]
    h.update(json.dumps(dict(name=spec.name, description=spec.description, q=spec.q_names, z=spec.z_names,
                             q_start=spec.q_start, settle=spec.settle_idx, contact=spec.contact,
                             nc=spec.n_contacts, table=table, stop=spec.stop_time, dt=spec.output_interval),
                        sort_keys=True, default=str).encode())
    for name in spec.function_names():
        h.update(name.encode())
        h.update(_portable(spec.functions[name].serialize()))
    return "{" + str(uuid.UUID(bytes=h.digest()[:16])) + "}"


def _portable(serialized: str) -> bytes:
    """A function's serialization without the checkout's location, for the hash: the host libraries a model calls
    through casadi.external (the contact search) are named by their absolute path, and the same model built from
    another directory must get the same GUID. CasADi's serialization is its bytes written two letters a-p a byte,
    the low half first; a path is its 4-byte length followed by its bytes. The library's directory and the length
    go, its file name (a hash of its source) stays."""
    from cedra.models.host import HOST_DIR
    data = bytes(16 * (ord(hi) - 97) + ord(lo) - 97 for lo, hi in zip(serialized[::2], serialized[1::2]))
    for host in {str(HOST_DIR), str(HOST_DIR.resolve())}:
        data = re.sub(rb"(?s).{4}" + re.escape(host.encode()), b"<host>", data)
    return data


# ------------------------------------------------------------------------------------------------ units

_BASE = {  # SI base-unit exponents kg, m, s, A, K, mol, cd, rad
    "kg": dict(kg=1), "m": dict(m=1), "s": dict(s=1), "rad": dict(rad=1), "A": dict(A=1), "K": dict(K=1),
    "N": dict(kg=1, m=1, s=-2), "J": dict(kg=1, m=2, s=-2), "W": dict(kg=1, m=2, s=-3),
    "Pa": dict(kg=1, m=-1, s=-2), "g": None, "1": {},
}


def base_unit(unit: str) -> dict | None:
    """SI exponents of a unit like 'N.m/rad', 'm/s2', '1/s'; None if a factor is unknown."""
    parts = unit.split("/")
    if len(parts) > 2:
        return None
    exps: dict[str, int] = {}
    for sign, side in zip((1, -1), parts):
        for tok in side.split("."):
            m = re.fullmatch(r"([A-Za-z]+|1)(-?\d*)", tok)
            if not m or _BASE.get(m.group(1)) is None:
                return None
            e = int(m.group(2)) if m.group(2) else 1
            for k, v in _BASE[m.group(1)].items():
                exps[k] = exps.get(k, 0) + sign * e * v
    return {k: v for k, v in exps.items() if v}


# ------------------------------------------------------------------------------------------------ XML

def model_description(spec: ModelSpec, guid: str) -> etree._Element:
    table = variables(spec)
    root = etree.Element("fmiModelDescription", fmiVersion="2.0", modelName=spec.name, guid=guid,
                         description=spec.description, generationTool=GENERATION_TOOL, version=__version__,
                         variableNamingConvention="structured", numberOfEventIndicators="0")
    cs = etree.SubElement(root, "CoSimulation", modelIdentifier=spec.name,
                          needsExecutionTool="false", canHandleVariableCommunicationStepSize="true",
                          canInterpolateInputs="false", maxOutputDerivativeOrder="0",
                          canRunAsynchronuously="false", canBeInstantiatedOnlyOncePerProcess="false",
                          canNotUseMemoryManagementFunctions="false", canGetAndSetFMUstate="true",
                          canSerializeFMUstate="true", providesDirectionalDerivative="false")
    sf = etree.SubElement(cs, "SourceFiles")
    for f in source_files(spec):
        etree.SubElement(sf, "File", name=f)
    ud = etree.SubElement(root, "UnitDefinitions")
    for u in units(table):
        el = etree.SubElement(ud, "Unit", name=u)
        b = base_unit(u)
        if b is not None:
            etree.SubElement(el, "BaseUnit", **{k: str(v) for k, v in b.items()})
        if u in DISPLAY_UNITS and any(v.display_unit == DISPLAY_UNITS[u][0] for v in table if v.unit == u):
            name, factor = DISPLAY_UNITS[u]
            etree.SubElement(el, "DisplayUnit", name=name, factor=_fmt(factor))
    lc = etree.SubElement(root, "LogCategories")
    for name, desc in LOG_CATEGORIES:
        etree.SubElement(lc, "Category", name=name, description=desc)
    experiment = dict(startTime="0.0", stopTime=_fmt(spec.stop_time))
    if spec.block == "plant":       # a master passes it on to fmi2SetupExperiment: the solver's own default
        experiment["tolerance"] = _fmt(solver_defaults(spec)["tol"])
    etree.SubElement(root, "DefaultExperiment", **experiment, stepSize=_fmt(spec.output_interval))
    mv = etree.SubElement(root, "ModelVariables")
    for v in table:
        attrs = dict(name=v.name, valueReference=str(v.vr), description=v.description, causality=v.causality,
                     variability=v.variability)
        if v.initial is not None:
            attrs["initial"] = v.initial
        sv = etree.SubElement(mv, "ScalarVariable", **attrs)
        t = {}
        if v.type == "Real" and v.quantity:
            t["quantity"] = v.quantity
        if v.type == "Real" and v.unit:
            t["unit"] = v.unit
        if v.type == "Real" and v.display_unit:
            t["displayUnit"] = v.display_unit
        if v.min is not None and v.type in ("Real", "Integer"):
            t["min"] = _fmt(v.min) if v.type == "Real" else str(int(v.min))
        if v.max is not None and v.type in ("Real", "Integer"):
            t["max"] = _fmt(v.max) if v.type == "Real" else str(int(v.max))
        if v.start is not None:
            t["start"] = (_fmt(v.start) if v.type == "Real" else
                          ("true" if v.start else "false") if v.type == "Boolean" else str(int(v.start)))
        etree.SubElement(sv, v.type, **t)
    ms = etree.SubElement(root, "ModelStructure")
    index = {v.vr: k + 1 for k, v in enumerate(table)}     # 1-based ScalarVariable index
    outs = [v for v in table if v.causality == "output"]
    if outs:
        el = etree.SubElement(ms, "Outputs")
        for v in outs:
            etree.SubElement(el, "Unknown", index=str(index[v.vr]))
    init = [v for v in table if v.causality == "output" and v.initial in ("approx", "calculated")]
    if init:                       # an empty <InitialUnknowns/> is schema-invalid
        el = etree.SubElement(ms, "InitialUnknowns")
        for v in init:
            etree.SubElement(el, "Unknown", index=str(index[v.vr]))
    return root


def write_model_description(spec: ModelSpec, path, guid: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    root = model_description(spec, guid)
    path.write_bytes(etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True))
    return path


# ------------------------------------------------------------------------------------------------ C header

def _c_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def _c_real(x) -> str:
    if x is None:
        return "0.0"
    r = repr(float(x))
    if r == "inf":
        return "HUGE_VAL"
    if r == "-inf":
        return "-HUGE_VAL"
    return r if ("." in r or "e" in r or "n" in r) else r + ".0"


_C_TYPE = {"Real": "CEDRA_REAL", "Integer": "CEDRA_INTEGER", "Boolean": "CEDRA_BOOLEAN"}
_C_KIND = {k: "CEDRA_K_" + k.upper() for k in ("par", "inp", "out", "q_start", "u_start", "settle", "solver",
                                                "stat")}
_C_CAUS = {"parameter": "CEDRA_PARAMETER", "input": "CEDRA_INPUT", "output": "CEDRA_OUTPUT"}


def vars_header(spec: ModelSpec, guid: str) -> str:
    table = variables(spec)
    nq, nz, ni, npar, ny, ns = (spec.nq, len(spec.z_names), len(spec.inputs), len(spec.params),
                                len(spec.outputs), len(spec.settle_idx))

    def arr(name, ctype, values, fmt):
        vals = list(values) or [0]          # C99: no empty arrays (sizes say how many are used)
        return f"static const {ctype} {name}[] = {{{', '.join(fmt(v) for v in vals)}}};"

    lines = [
        f"/* Generated by modelDescription/generate.py for the model {spec.name}: do not edit. */",
        "#ifndef CEDRA_VARS_H", "#define CEDRA_VARS_H", "", "#include <math.h>", '#include "cedra_var.h"', "",
        f"#define CEDRA_MODEL_IDENTIFIER {_c_str(spec.name)}", f"#define CEDRA_GUID {_c_str(guid)}",
        f"#define CEDRA_NQ {nq}", f"#define CEDRA_NZ {nz}", f"#define CEDRA_NI {ni}", f"#define CEDRA_NP {npar}",
        f"#define CEDRA_NY {ny}", f"#define CEDRA_NS {ns}",
        # rigid contact: the contact impulses (Fx, Fy, Fn per contact) over the current communication step, the
        # glue's quadratures behind wheel[i].F*_mean (model_glue.c)
        f"#define CEDRA_NIMP {3 * spec.n_contacts if spec.contact == 'rigid' else 0}",
        "#define CEDRA_NX (2 * CEDRA_NQ + CEDRA_NZ + CEDRA_NIMP)",
        f"#define CEDRA_RIGID {1 if spec.contact == 'rigid' else 0}", f"#define CEDRA_NC {spec.n_contacts}",
        f"#define CEDRA_NCW {spec.contacts_per_wheel}",
        f"#define CEDRA_HEIGHTMAP {1 if spec.heightmap_file else 0}",
        f"#define CEDRA_RIM_REFINE {1 if spec.rim_refine else 0}",
        f"#define CEDRA_NSW {len(spec.switch_names)}", f"#define CEDRA_NH {spec.n_hold}",
        f"#define CEDRA_CHASSIS {1 if spec.chassis else 0}",
        f"#define CEDRA_CONTROLLER {1 if spec.block == 'controller' else 0}",
        f"#define CEDRA_ND {len(spec.d_names)}",
        "#define CEDRA_PERIOD_PAR "
        f"{[p.name for p in spec.params].index('ctrl.period') if spec.block == 'controller' else -1}",
        f"#define CEDRA_NVARS {len(table)}", "",
        arr("CEDRA_SETTLE_IDX", "int", spec.settle_idx, str),
        arr("CEDRA_M_ORDER", "int", elimination_order(spec), str),
        arr("CEDRA_Q_START", "double", spec.q_start, _c_real),
        arr("CEDRA_PAR_START", "double", [p.start for p in spec.params], _c_real),
        arr("CEDRA_INP_START", "double", [p.start for p in spec.inputs], _c_real),
        "static const char *const CEDRA_Q_NAMES[] = {" + ", ".join(_c_str(n) for n in spec.q_names) + "};",
        "static const char *const CEDRA_SW_NAMES[] = {" +
        (", ".join(_c_str(n) for n in spec.switch_names) or '""') + "};",
        "static const char *const CEDRA_Y_NAMES[] = {" +
        (", ".join(_c_str(o.name) for o in spec.outputs) or '""') + "};",
        "",
        "/* vr, name, type, kind, index, start, min, max, min_exclusive, causality */",
        "static const cedra_var CEDRA_VARS[CEDRA_NVARS] = {",
    ]
    for v in table:
        start = 0.0 if v.start is None else float(v.start)
        lines.append(f"    {{{v.vr}u, {_c_str(v.name)}, {_C_TYPE[v.type]}, {_C_KIND[v.kind]}, {v.index}, "
                     f"{_c_real(start)}, {_c_real(v.min if v.min is not None else float('-inf'))}, "
                     f"{_c_real(v.max if v.max is not None else float('inf'))}, {int(v.min_exclusive)}, "
                     f"{_C_CAUS[v.causality]}}},")
    lines += ["};", "", "#endif", ""]
    return "\n".join(lines)


def write_vars_header(spec: ModelSpec, path, guid: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(vars_header(spec, guid))
    return path
