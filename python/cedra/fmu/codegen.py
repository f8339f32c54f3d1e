"""C code of a ModelSpec's CasADi functions: one file cedra_model.c (+ cedra_model.h) in the build tree.

The generated file is compiled with the hand-written glue's flags relaxed only for it (GENERATED_CFLAGS_RELAX):
CasADi's code has unused parameters/variables in some functions.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca

from cedra.contract import ModelSpec

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


def generate_c(spec: ModelSpec, out_dir) -> tuple[Path, Path]:
    """Write out_dir/cedra_model.c and out_dir/cedra_model.h with every contract function; returns both paths."""
    spec.check()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cg = ca.CodeGenerator("cedra_model.c", CODEGEN_OPTIONS)
    for name in spec.function_names():
        cg.add(dense(spec.functions[name]))
    cg.generate(str(out_dir) + "/")
    return out_dir / "cedra_model.c", out_dir / "cedra_model.h"
