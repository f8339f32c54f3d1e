"""The toy FMU as built by cedra.fmu.packaging.build_fmu: validation, exported symbols, GUID, start values through the
binary, shipped sources, one variable table behind the XML and the C header."""
from __future__ import annotations

import re
import subprocess
import zipfile
from dataclasses import replace

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from cedra.fmu import packaging as fmu_mod
from cedra.fmu.variables import variables
from fmu_harness import Toy
from toy_model import toy_spec


def test_fmpy_validate_finds_no_problems(toy):
    assert list(validate_fmu(str(toy))) == []


def test_exactly_the_fmi2_functions_are_exported(toy, tmp_path):
    with zipfile.ZipFile(toy) as z:
        so = tmp_path / "toy.so"
        so.write_bytes(z.read("binaries/linux64/toy.so"))
    assert fmu_mod.exported_symbols(so) == fmu_mod.FMI2_CS_FUNCTIONS


def test_guid_is_a_hash_of_the_spec(toy):
    gen = fmu_mod._generator()
    a, b = gen.spec_guid(toy_spec()), gen.spec_guid(toy_spec())
    assert a == b == read_model_description(str(toy)).guid
    changed = toy_spec()
    changed.q_start = [0.0, 0.06]
    assert gen.spec_guid(changed) != a
    assert gen.spec_guid(toy_spec("other")) != a


def test_wrong_guid_instantiate_returns_null_and_logs(toy):
    t = Toy(toy, guid="{00000000-0000-0000-0000-000000000000}")
    with pytest.raises(Exception, match="Failed to instantiate"):
        t.instantiate()
    md = read_model_description(str(toy))
    assert t.messages("error") == [
        f"fmi2Instantiate: GUID {{00000000-0000-0000-0000-000000000000}} does not match the FMU's GUID {md.guid}"]
    t.slave.freeLibrary()


def test_every_start_value_reads_back_by_value_reference(toy):
    t = Toy(toy).start(exit_init=False)
    try:
        checked = 0
        for v in t.md.modelVariables:
            if v.start is None:
                continue
            got = t.get(v.name)
            want = {"Real": float, "Integer": int, "Boolean": lambda s: s in (True, "true", "1", 1)}[v.type](v.start)
            assert got == want, (v.name, v.valueReference, got, want)
            checked += 1
        assert checked == sum(v.start is not None for v in t.md.modelVariables) >= 15
    finally:
        t.close()


def test_variable_table_rows_and_start_params():
    spec = toy_spec()
    table = variables(spec)
    assert [v.vr for v in table] == list(range(len(table)))
    names = [v.name for v in table]
    assert len(set(names)) == len(names)
    assert {"start.x", "start.z", "start.speed.x", "start.settle", "solver.method", "solver.tol", "solver.h_max",
            "solver.steps", "solver.rejected", "solver.rhs_evals"} <= set(names)
    # a friendly start name replaces start.<q name> for its coordinate (no alias rows)
    spec2 = replace(spec, start_params={"start.pos": 0})
    names2 = [v.name for v in variables(spec2)]
    assert "start.pos" in names2 and "start.x" not in names2 and "start.z" in names2
    row = next(v for v in variables(spec2) if v.name == "start.pos")
    assert (row.kind, row.index, row.start, row.unit) == ("q_start", 0, 0.0, "m")
    for v in table:
        if v.type == "Real":
            assert v.unit, v.name


def test_header_and_xml_come_from_one_table(toy, tmp_path):
    with zipfile.ZipFile(toy) as z:
        header = z.read("sources/cedra_vars.h").decode()
    rows = re.findall(r'\{(\d+)u, "([^"]+)", CEDRA_(\w+), CEDRA_K_(\w+), (\d+),', header)
    md = read_model_description(str(toy))
    assert [(int(vr), name, typ.capitalize()) for vr, name, typ, _, _ in rows] == \
        [(v.valueReference, v.name, v.type) for v in md.modelVariables]
    assert f'#define CEDRA_GUID "{md.guid}"' in header


def test_sources_compile_on_their_own(toy, tmp_path):
    with zipfile.ZipFile(toy) as z:
        z.extractall(tmp_path)
    md = read_model_description(str(toy))
    files = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    assert files and all((tmp_path / "sources" / f).is_file() for f in files)
    so = tmp_path / "rebuilt.so"
    r = subprocess.run(["gcc", "-shared", "-fPIC", "-O1", "-I", str(tmp_path / "sources"),
                        *[str(tmp_path / "sources" / f) for f in files], "-o", str(so), "-lm"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert fmu_mod.FMI2_CS_FUNCTIONS <= fmu_mod.exported_symbols(so)


def test_documentation_lists_every_variable(toy):
    with zipfile.ZipFile(toy) as z:
        doc = z.read("documentation/index.html").decode()
    for v in read_model_description(str(toy)).modelVariables:
        assert f"<code>{v.name}</code>" in doc


def test_guid_does_not_depend_on_the_checkouts_location(tmp_path, monkeypatch):
    """A model calls the contact search through casadi.external, named by the host library's absolute path: the
    same model in another checkout (another build/host) gets the same GUID."""
    import shutil

    import casadi as ca

    from cedra.mechanics import rim
    from cedra.mechanics.terrain import Terrain, terrain_inputs
    from cedra.models import host as host_libraries
    gen = fmu_mod._generator()
    library = rim._host(Terrain("bump", {n: ca.SX.sym(n) for n in terrain_inputs("bump", "2d")}))
    hashes, serialized = [], []
    for checkout in ("one", "three"):                 # paths of different lengths
        host = tmp_path / checkout / "build" / "host"
        host.mkdir(parents=True)
        shutil.copy(library, host / library.name)
        monkeypatch.setattr(host_libraries, "HOST_DIR", host)
        x = ca.MX.sym("x", 15)
        search = ca.external(rim.EXTERNAL_NAME, str(host / library.name))
        spec = toy_spec()
        first = spec.function_names()[0]          # a function that calls the search, in place of the toy's
        spec.functions[first] = ca.Function(first, [x], [search(x)])
        serialized.append(spec.functions[first].serialize())
        hashes.append(gen.spec_guid(spec))
    assert serialized[0] != serialized[1]             # the path is in the serialization
    assert hashes[0] == hashes[1]
