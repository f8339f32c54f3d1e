"""The generated C of a model formed from parts (cedra.fmu.codegen): each part in a file of its own, the functions
composed of parts calling them by name, and the same part's file the same bytes in two scenes whose rover is the
same (bump3d and slope3d: CEDRA in 3D without steering or drives, on a bump and on a slope), so that the object
cache compiles it once for both."""
from __future__ import annotations

import re
import subprocess

import casadi as ca
import pytest

from cedra.fmu import part_stubs
from cedra.fmu.codegen import generate_c, generated_files
from cedra.models.scene import load_shipped


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    out = {}
    for scene in ("bump3d", "slope3d"):
        sc = load_shipped(scene)
        spec = sc.spec(sc.model())
        d = tmp_path_factory.mktemp(scene)
        generate_c(spec, d)
        out[scene] = (spec, d)
    return out


def test_each_part_in_its_own_file_called_by_name(generated):
    spec, d = generated["bump3d"]
    assert spec.part_names and set(generated_files(spec)) == {p.name for p in d.glob("*.c")}
    for name in ("cedra_f", "cedra_rjac", "cedra_settle"):
        text = (d / f"{name}.c").read_text()
        # the composition declares the part and calls it; the part's body (its name's definition) is not in it
        assert re.search(r"^int cedra_part_dyn(_jac)?\(const casadi_real\*\* arg", text, re.M), name
        assert "CASADI_SYMBOL_EXPORT int cedra_part_dyn" not in text, name
    dyn = (d / "cedra_part_dyn_jac.c").read_text()
    assert "CASADI_SYMBOL_EXPORT int cedra_part_dyn_jac(" in dyn
    # the composed Jacobian is small beside the dynamics' Jacobian part it calls
    assert (d / "cedra_rjac.c").stat().st_size < (d / "cedra_part_dyn_jac.c").stat().st_size / 5


def test_the_same_rover_gives_the_same_part_files(generated):
    (_, a), (_, b) = generated["bump3d"], generated["slope3d"]
    for part in ("cedra_part_dyn", "cedra_part_dyn_jac"):
        assert (a / f"{part}.c").read_bytes() == (b / f"{part}.c").read_bytes(), part
    # the terrain's parts are the scene's own
    assert (a / "cedra_part_wheel.c").read_bytes() != (b / "cedra_part_wheel.c").read_bytes()


def test_a_composition_generated_on_a_stub_runs_on_the_part(tmp_path):
    """A function composed of a part, generated with the part's stub in its place and compiled with the part's own
    C, gives what the composition of the part itself gives (the stub's signature and work sizes are the part's)."""
    x = ca.SX.sym("x", 3)
    fn = ca.Function("cedra_part_probe", [x], [ca.sin(x) * x[0], ca.jacobian(ca.sin(x) * x[0], x)])
    opts = {"with_header": True, "casadi_int": "long long int"}
    cg = ca.CodeGenerator("cedra_part_probe.c", opts)
    cg.add(fn)
    cg.generate(str(tmp_path) + "/")
    ext = part_stubs.external(fn, tmp_path / "cedra_part_probe.c")
    assert ext.name() == fn.name() and ext.sparsity_out(1) == fn.sparsity_out(1)
    with pytest.raises(RuntimeError):
        ext(ca.DM([1, 2, 3]))          # the stub is never evaluated: it fails

    def composed(part):
        X = ca.MX.sym("X", 3)
        a, J = part(X)
        b, _ = part(2 * X + 1)
        return ca.Function("cedra_probe_sum", [X], [a + b, J @ b])
    cg = ca.CodeGenerator("cedra_probe_sum.c", opts)
    cg.add(composed(ext))
    cg.generate(str(tmp_path) + "/")
    lib = tmp_path / "probe.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O1", "-o", str(lib), str(tmp_path / "cedra_probe_sum.c"),
                    str(tmp_path / "cedra_part_probe.c"), "-lm"], check=True)
    got = ca.external("cedra_probe_sum", str(lib))(ca.DM([0.3, -1.2, 2.0]))
    want = composed(fn)(ca.DM([0.3, -1.2, 2.0]))
    for g, w in zip(got, want):
        assert float(ca.norm_inf(g - w)) <= 1e-15 * max(1.0, float(ca.norm_inf(w)))
    with pytest.raises(ValueError, match="no cedra_part_other_work"):
        part_stubs.work_sizes((tmp_path / "cedra_part_probe.c").read_text(), "cedra_part_other")
