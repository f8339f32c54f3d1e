"""The drive system as an SSP package: build/<system>.ssp = SystemStructure.ssd + the plant FMU + the
drive controller FMU, connected name to name, with a scenario's parameter values bound to each component.

    write_ssp(path, plant_fmu, controller_fmu, plant_values, controller_values)
    validate_ssd(ssd_bytes)           -> [] or the schema's complaints (FMPy's SSP 1.0 schemas)
    run_fmpy(ssp, stop, step)         FMPy's SSP simulator (fmpy.ssp.simulation.simulate_ssp)
    run_libcosim(ssp, stop, step)     OSP libcosim (libcosimpy CosimExecution.from_ssp_file), in a subprocess

The SSD declares as connectors the connected variables and the recorded plant outputs (body.x, body.y, ...).
Scenario values (e.g. the controller's cmd.v, the plant's mu) are ParameterBindings with inline ParameterValues
on each component, and are NOT connectors: FMPy's simulator writes every input connector before every step, so a
command declared as an unconnected connector would be reset to 0.

The masters' conventions (both step every FMU from the values of the last communication point: Jacobi):
  FMPy   every connector starts at 0: the first step feeds the controller zeros and the plant zero torques;
         time advances by adding the step (t += h); it applies the bindings only when given a parameter set,
         which run_fmpy builds from the same file's bindings with fmpy's own SSD reader.
  libcosim  counts time in integer nanoseconds; after initialization it passes the initial outputs to the
         connected inputs, so the first step already uses the plant's settled start.
cedra.run.cosim.DriveLoop reproduces either with convention="fmpy-ssp" or "libcosim".
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from lxml import etree

NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues"}
RECORDED = ("body.x", "body.y", "body.z", "body.yaw", "body.vx")   # plant outputs every run records (if present)
FMU_TYPE = "application/x-fmu-sharedlibrary"

# The shipped systems (python -m cedra build writes build/<name>.ssp): plant scene, controller, the values bound
# to each. The 1 s command ramp lets every master start the same way (see the module's docstring).
SYSTEMS = {
    "turn_flat": ("flat3d", "drive3d", {}, {"cmd.v": 0.2, "cmd.yaw_rate": 0.3, "ctrl.ramp_time": 1.0}),
    "bump_ik": ("bump2d", "drive2d", {}, {"cmd.v": 0.2, "ctrl.ramp_time": 1.0}),
}


def build_system(name: str, build_dir) -> Path:
    """build/<name>.ssp from the FMUs already in build_dir."""
    plant, ctrl, pv, cv = SYSTEMS[name]
    build_dir = Path(build_dir)
    return write_ssp(build_dir / f"{name}.ssp", build_dir / f"{plant}.fmu", build_dir / f"{ctrl}.fmu", pv, cv)


def _q(prefix, tag):
    return f"{{{NS[prefix]}}}{tag}"


def _variables(fmu_path) -> dict:
    from fmpy import read_model_description
    return {v.name: v for v in read_model_description(str(fmu_path)).modelVariables}


def connections(plant_vars: dict, ctrl_vars: dict) -> list[tuple[str, str, str, str]]:
    """(start element, connector, end element, connector): plant outputs the controller reads, controller outputs
    the plant takes."""
    out = [("plant", n, "controller", n) for n, v in plant_vars.items()
           if v.causality == "output" and n in ctrl_vars and ctrl_vars[n].causality == "input"]
    out += [("controller", n, "plant", n) for n, v in ctrl_vars.items()
            if v.causality == "output" and n in plant_vars and plant_vars[n].causality == "input"]
    return out


def _component(system_elements, name, source, variables: dict, connector_names, values: dict):
    comp = etree.SubElement(system_elements, _q("ssd", "Component"), name=name, type=FMU_TYPE, source=source)
    conns = etree.SubElement(comp, _q("ssd", "Connectors"))
    for n in connector_names:
        v = variables[n]
        c = etree.SubElement(conns, _q("ssd", "Connector"), name=n, kind=v.causality)
        etree.SubElement(c, _q("ssc", v.type))
    if values:
        bindings = etree.SubElement(comp, _q("ssd", "ParameterBindings"))
        binding = etree.SubElement(bindings, _q("ssd", "ParameterBinding"))
        pv = etree.SubElement(binding, _q("ssd", "ParameterValues"))
        ps = etree.SubElement(pv, _q("ssv", "ParameterSet"), version="1.0", name=f"{name} scenario values")
        params = etree.SubElement(ps, _q("ssv", "Parameters"))
        for n, value in values.items():
            if n not in variables:
                raise ValueError(f"{name} has no variable {n}")
            v = variables[n]
            p = etree.SubElement(params, _q("ssv", "Parameter"), name=n)
            text = repr(float(value)) if v.type == "Real" else str(int(value)) if v.type == "Integer" else \
                ("true" if value else "false")
            etree.SubElement(p, _q("ssv", v.type), value=text)


def ssd(plant_fmu, controller_fmu, plant_values: dict, controller_values: dict, name: str,
        stop_time: float) -> bytes:
    """SystemStructure.ssd for the FMUs (referenced as resources/<file name>)."""
    pv, cv = _variables(plant_fmu), _variables(controller_fmu)
    links = connections(pv, cv)
    root = etree.Element(_q("ssd", "SystemStructureDescription"), nsmap=NS, version="1.0", name=name)
    system = etree.SubElement(root, _q("ssd", "System"), name=name)
    elements = etree.SubElement(system, _q("ssd", "Elements"))
    plant_conns = sorted({c[1] for c in links} | {n for n in RECORDED if n in pv and pv[n].causality == "output"},
                         key=lambda n: (pv[n].causality, n))
    ctrl_conns = sorted({c[1] for c in links}, key=lambda n: (cv[n].causality, n))
    _component(elements, "plant", f"resources/{Path(plant_fmu).name}", pv, plant_conns, plant_values)
    _component(elements, "controller", f"resources/{Path(controller_fmu).name}", cv, ctrl_conns, controller_values)
    conns = etree.SubElement(system, _q("ssd", "Connections"))
    for a, an, b, bn in links:
        etree.SubElement(conns, _q("ssd", "Connection"), startElement=a, startConnector=an, endElement=b,
                         endConnector=bn)
    etree.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0", stopTime=repr(float(stop_time)))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def schema_dir() -> Path:
    import fmpy
    return Path(fmpy.__file__).parent / "ssp" / "schema"


def validate_ssd(data: bytes) -> list[str]:
    """The complaints of FMPy's SSP 1.0 SystemStructureDescription schema ([] when valid)."""
    schema = etree.XMLSchema(etree.parse(str(schema_dir() / "SystemStructureDescription.xsd")))
    doc = etree.fromstring(data)
    return [] if schema.validate(doc) else [str(e) for e in schema.error_log]


def write_ssp(path, plant_fmu, controller_fmu, plant_values: dict | None = None,
              controller_values: dict | None = None, stop_time: float = 15.0) -> Path:
    """build/<system>.ssp: the SSD (checked against the schema first) and both FMUs under resources/."""
    path = Path(path)
    data = ssd(plant_fmu, controller_fmu, plant_values or {}, controller_values or {}, path.stem, stop_time)
    problems = validate_ssd(data)
    if problems:
        raise ValueError(f"{path.name}: the SSD does not validate: {problems[:3]}")
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", data)
        z.write(plant_fmu, f"resources/{Path(plant_fmu).name}")
        z.write(controller_fmu, f"resources/{Path(controller_fmu).name}")
    return path


# ------------------------------------------------------------------------------------------------ the masters

def run_fmpy(ssp_path, stop_time: float, step: float) -> dict:
    """FMPy's SSP simulator on the file as it is; the component bindings (read by fmpy's own SSD reader) are
    handed to it as its parameter set. Returns {"time": t at the END of each step, "plant.body.x": ..., ...}."""
    import numpy as np
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import ParameterSet, find_components, read_ssd
    system = read_ssd(str(ssp_path)).system
    values = ParameterSet(name="bindings")
    for comp in find_components(system):
        for binding in comp.parameterBindings:
            for pset in binding.parameterValues:
                for p in pset.parameters:
                    p.name = f"{comp.name}.{p.name}"
                    p.value = float(p.value) if p.type == "Real" else int(p.value) if p.type == "Integer" else \
                        p.value == "true"
                    values.parameters.append(p)
    rows = simulate_ssp(str(ssp_path), stop_time=stop_time, step_size=step, parameter_set=values)
    # FMPy labels each row with the time at the START of the step it just took
    out = {name: np.asarray(rows[name]) for name in rows.dtype.names}
    out["time"] = out["time"] + step
    return out


def run_libcosim(ssp_path, stop_time: float, step: float, record=RECORDED, timeout: float = 600.0) -> dict:
    """libcosim on the unzipped package (its SSP reader applies the bindings), in a subprocess (libcosim can
    abort the process). Returns {"time": t at each step's end, "plant.<name>": values}."""
    import numpy as np
    with tempfile.TemporaryDirectory(prefix="cedra-ssp-") as tmp:
        with zipfile.ZipFile(ssp_path) as z:
            z.extractall(tmp)
        plant = next(Path(tmp, "resources").glob("*.fmu"))
        ssd_root = etree.parse(str(Path(tmp, "SystemStructure.ssd")))
        src = ssd_root.find(".//ssd:Component[@name='plant']", NS).get("source")
        plant = Path(tmp, src)
        pv = _variables(plant)
        step_ns = round(step * 1e9)
        n = int(round(stop_time / step))
        req = dict(dir=tmp, step_ns=step_ns, n=n, result=str(Path(tmp, "res.npz")),
                   record=[[name, pv[name].valueReference] for name in record if name in pv])
        req_path = Path(tmp, "req.json")
        req_path.write_text(json.dumps(req))
        r = subprocess.run([sys.executable, "-m", "cedra.run.ssp", str(req_path)], capture_output=True, text=True,
                           timeout=timeout)
        if r.returncode != 0:
            raise RuntimeError(f"libcosim failed (rc {r.returncode}):\n{r.stderr[-4000:]}")
        with np.load(req["result"]) as z:
            out = {k: z[k] for k in z.files}
    out["time"] = out.pop("time_ns") * 1e-9
    return out


def _libcosim_worker(req_path: str) -> None:
    import numpy as np
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    req = json.loads(Path(req_path).read_text())
    log_output_level(CosimLogLevel.WARNING)
    ex = CosimExecution.from_ssp_file(req["dir"], req["step_ns"])
    idx = ex.slave_index_from_instance_name("plant")
    obs = CosimObserver.create_time_series(buffer_size=req["n"] + 16)
    ex.add_observer(obs)
    for _, vr in req["record"]:
        if not obs.start_time_series(idx, vr, CosimVariableType.REAL):
            sys.exit(f"cannot observe vr {vr}")
    if not ex.simulate_until(req["n"] * req["step_ns"]):
        sys.exit(f"simulate_until failed: {ex.status()}")
    result, time_ns = {}, None
    for name, vr in req["record"]:
        t, s, v = obs.time_series_real_samples(idx, vr, 1, req["n"])
        result["plant." + name] = np.asarray(v, dtype=float)
        time_ns = np.asarray(t, dtype=np.int64)
    np.savez(req["result"], time_ns=time_ns, **result)


if __name__ == "__main__":
    _libcosim_worker(sys.argv[1])
