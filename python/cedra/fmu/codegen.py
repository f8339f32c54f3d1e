"""C code of a ModelSpec's CasADi functions: one translation unit per function (<name>.c and <name>.h, the
contract's fixed names, as acados generates one file per function), and cedra_model.h, which includes every
function's header, for the glue.

One file per function lets the compiler see small units, compiles them in parallel, lets each file get the
optimization level its function is worth (cedra.fmu.packaging.compile_flags), and lets the object cache
(cedra.fmu.compiler) keep every function whose C did not change.

The generated files are compiled with the hand-written glue's flags relaxed only for them
(GENERATED_CFLAGS_RELAX): CasADi's code has unused parameters/variables in some functions.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca

from cedra.contract import ModelSpec
from cedra.fmu import part_stubs

CODEGEN_OPTIONS = {"with_header": True, "casadi_real": "double", "casadi_int": "long long int",
                   "with_mem": False, "verbose": False, "mex": False, "cpp": False, "main": False}
# warnings CasADi's generated code triggers under -Wall -Wextra (never used for the hand-written files)
GENERATED_CFLAGS_RELAX = ["-Wno-unused-parameter", "-Wno-unused-variable", "-Wno-unused-function",
                          "-Wno-unused-but-set-variable", "-Wno-sign-compare"]


def dense(fn: ca.Function) -> ca.Function:
    """fn with every input and output dense (the C glue passes plain column-major arrays; CasADi's generated code
    reads and writes only the structural nonzeros of a sparse argument)."""
    if all(fn.sparsity_in(i).is_dense() for i in range(fn.n_in())) and \
            all(fn.sparsity_out(i).is_dense() for i in range(fn.n_out())):
        return fn
    args = fn.sx_in() if fn.is_a("SXFunction") else fn.mx_in()
    args = [type(a).sym(fn.name_in(i), a.size1(), a.size2()) for i, a in enumerate(args)]
    outs = fn.call(args)
    return ca.Function(fn.name(), args, [ca.densify(o) for o in outs], fn.name_in(), fn.name_out())


MODEL_HEADER = "cedra_model.h"


def generated_files(spec: ModelSpec) -> list[str]:
    """The C files generate_c writes for spec: the contract's functions in its order, then the parts'."""
    return [f"{name}.c" for name in spec.function_names() + list(spec.part_names)]


def is_generated(file_name: str) -> bool:
    """Whether a C file of an FMU's sources/ is generated (a contract function's: cedra_*.c); the hand-written
    files (fmu_src/) have other names."""
    return file_name.startswith("cedra_") and file_name.endswith(".c")


def _generate(fn: ca.Function, out_dir: Path) -> None:
    cg = ca.CodeGenerator(f"{fn.name()}.c", CODEGEN_OPTIONS)
    cg.add(fn)
    cg.generate(str(out_dir) + "/")


def generate_c(spec: ModelSpec, out_dir) -> list[Path]:
    """Write out_dir/<name>.c and <name>.h for every contract function and every part, and out_dir/cedra_model.h
    including the contract functions' headers; returns the C files.

    A part is written once, into its own file. The contract functions formed from parts (spec.compose) are
    generated with each part replaced by an external function of the same name, so that their C calls the part's
    file instead of holding a copy of it: a part's text depends only on what it computes, so the object cache
    keeps it across the functions that call it and across scenes whose part is the same."""
    spec.check()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = spec.function_names()
    fns = dict(spec.functions) if not spec.part_names else {n: spec.functions[n] for n in names}
    if spec.part_names:
        externals = {}
        for part in spec.part_names:
            fn = spec.parts[part]
            _generate(fn, out_dir)
            externals[part] = part_stubs.external(fn, out_dir / f"{part}.c")
        fns |= dict(spec.compose(externals))
    for name in names:
        _generate(dense(fns[name]), out_dir)
    guard = "CEDRA_MODEL_H"
    (out_dir / MODEL_HEADER).write_text(
        f"/* The model's generated functions, one file each (cedra.fmu.codegen). */\n#ifndef {guard}\n"
        f"#define {guard}\n" + "".join(f'#include "{n}.h"\n' for n in names) + f"#endif /* {guard} */\n")
    return [out_dir / f"{n}.c" for n in names]
