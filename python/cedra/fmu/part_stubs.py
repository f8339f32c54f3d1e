"""A part of the model as an external function for code generation only (cedra.fmu.codegen).

CasADi generates a call of an external function as a call by name, where it generates any other function it calls
as a copy in the caller's file. So the contract functions formed from parts are generated with each part replaced
by an external function of the part's name: their C then calls the part's own file. Forming that external needs a
library CasADi can load, but CasADi reads only the function's signature from it (its inputs' and outputs'
sparsity and its work sizes): the library here is a stub with the part's signature whose evaluation fails, so
that forming it costs a compile of a few lines instead of the part's own. The work sizes are read back from the
part's generated C (a caller's C sizes the part's work from them; the C's own differ from the CasADi function's,
which counts its virtual machine's registers).
"""
from __future__ import annotations

import re
import tempfile
from pathlib import Path

import casadi as ca

from cedra.fmu.compiler import cache_dir, shared_library

_WORK = re.compile(r"\bint (\w+)_work\(casadi_int \*sz_arg.*?\{(.*?)\n\}", re.S)
_SIZE = re.compile(r"if \((sz_\w+)\) \*\1 = (\d+);")


def _array(name: str, values) -> str:
    return f"static const casadi_int {name}[{len(values)}] = {{{', '.join(str(int(v)) for v in values)}}};\n"


def stub_c(fn: ca.Function, sizes: dict[str, int]) -> str:
    """C of a library with fn's signature (name, sparsity, the work sizes its generated C reports: sizes) whose
    evaluation returns 1 (fails)."""
    name = fn.name()
    ins = [fn.sparsity_in(i).compress() for i in range(fn.n_in())]
    outs = [fn.sparsity_out(i).compress() for i in range(fn.n_out())]
    c = [f"/* the signature of {name} for code generation (cedra.fmu.part_stubs): never evaluated */\n",
         "typedef long long int casadi_int;\n"]
    c += [_array(f"sp_in{i}", sp) for i, sp in enumerate(ins)]
    c += [_array(f"sp_out{i}", sp) for i, sp in enumerate(outs)]

    def table(kind, n):
        cases = "".join(f"    case {i}: return sp_{kind}{i};\n" for i in range(n))
        return (f"const casadi_int *{name}_sparsity_{kind}(casadi_int i) {{\n  switch (i) {{\n{cases}"
                f"    default: return 0;\n  }}\n}}\n")

    c += [f"int {name}(const double **arg, double **res, casadi_int *iw, double *w, int mem) {{ return 1; }}\n",
          f"casadi_int {name}_n_in(void) {{ return {fn.n_in()}; }}\n",
          f"casadi_int {name}_n_out(void) {{ return {fn.n_out()}; }}\n",
          table("in", fn.n_in()), table("out", fn.n_out()),
          f"int {name}_work(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w) {{\n"
          f"  if (sz_arg) *sz_arg = {sizes['sz_arg']};\n  if (sz_res) *sz_res = {sizes['sz_res']};\n"
          f"  if (sz_iw) *sz_iw = {sizes['sz_iw']};\n  if (sz_w) *sz_w = {sizes['sz_w']};\n  return 0;\n}}\n",
          # the calls a caller's generated code makes around every evaluation, as the part's own file defines them
          f"int {name}_checkout(void) {{ return 0; }}\n",
          f"void {name}_release(int mem) {{ (void)mem; }}\n",
          f"void {name}_incref(void) {{}}\n",
          f"void {name}_decref(void) {{}}\n"]
    return "".join(c)


def work_sizes(c_text: str, name: str) -> dict[str, int]:
    """The work sizes a generated file's <name>_work reports."""
    for m in _WORK.finditer(c_text):
        if m.group(1) == name:
            return {k: int(v) for k, v in _SIZE.findall(m.group(2))}
    raise ValueError(f"no {name}_work in the generated C")


def external(fn: ca.Function, part_c: Path) -> ca.Function:
    """An external function with fn's name and signature, for generating the C of a function that calls fn
    (part_c: fn's generated C, whose work sizes the stub must report)."""
    sizes = work_sizes(Path(part_c).read_text(), fn.name())
    if sorted(sizes) != ["sz_arg", "sz_iw", "sz_res", "sz_w"]:
        raise RuntimeError(f"{part_c}: {fn.name()}_work reports {sizes}")
    with tempfile.TemporaryDirectory(prefix="cedra-stub-") as tmp:
        src = Path(tmp) / f"{fn.name()}_stub.c"
        src.write_text(stub_c(fn, sizes))
        lib = shared_library(src, ("-std=c99", "-O0", "-w"), cache_dir().parent / "stubs")
    return ca.external(fn.name(), str(lib))
