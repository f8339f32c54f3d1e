"""The contract between a symbolic model and the FMU machinery (code generation, C glue, XML).

A model (the CEDRA rover for one scene, or a toy model in the tests) is handed to the FMU builder as a
`ModelSpec`: a few CasADi functions with FIXED names and argument order (acados style), so that the
hand-written C glue in `fmu_src/` is the same for every model, plus the tables of named quantities those
functions read and write. Nothing here knows about FMI; `variables.py` turns a ModelSpec into the FMU's
variable table.

State of the ODE integrated by the FMU:  x = [q (nq), u (nq), z (nz)] with
    qdot = u                         (generalized speeds are the coordinate rates)
    M(q, par) udot = f(q, u, inp, par)
    zdot = g(q, u, inp, par)         (integral states, e.g. the motor work)

Generated functions (CasADi names = C names; every argument and result is a dense column vector/matrix,
matrices column-major):
    cedra_M      (q, par)               -> (M[nq x nq])
    cedra_f      (q, u, inp, par)       -> (f[nq], g[nz])
    cedra_rjac   (q, u, a, inp, par)    -> (dr_dq[nq x nq], dr_du[nq x nq], dg_dq[nz x nq], dg_du[nz x nq])
                  where r = M(q) a - f(q, u): the implicit solver's Jacobian is
                  d(udot)/dq = -M^-1 dr_dq, d(udot)/du = -M^-1 dr_du, evaluated at a = udot.
    cedra_out    (q, u, z, inp, par)    -> (y[ny])      every output variable, in `outputs` order
    cedra_settle (q, inp, par)          -> (res[ns], jac[ns x ns])
                  static-equilibrium residual f(q, 0) restricted to the coordinates `settle_idx`, and its
                  Jacobian with respect to those coordinates (Newton solve in fmi2ExitInitializationMode).
    cedra_guess  (q, inp, par)          -> (q0[nq])
                  the Newton solve's starting point: q with the settle_idx coordinates replaced by a guess that
                  puts the model in contact with its terrain (e.g. z from the terrain height under the rover).
                  Used only when the Boolean parameter start.settle is true (then: q = cedra_guess(q_start),
                  then Newton on cedra_settle).
    cedra_check  (q, u, inp, par)       -> (ok[1])  1 where the state is inside the model's domain; otherwise a
                  code <= 0 that names the reason (CHECK_REASONS below); the glue refuses such states with it.
    cedra_terrain (xy[2], tin[8])       -> (h[1], gradient[2], Hessian[2 x 2])
                  the scene's terrain at (X, Y) with its inputs tin (the scene's terrain inputs in their order,
                  padded with zeros to TERRAIN_TIN); the hand-written contact search (fmu_src/rim.c) calls it.
    cedra_rim_samples (x[7 + TERRAIN_TIN]) -> (g[13], frame[6], d1[2])
                  the contact search's start for a wheel x = [center, axle, radius, tin]: g at the rim's 13 samples,
                  the rim's frame (r1, r2) and g' at both ends of the lower half rim (fmu_src/rim.c).
    cedra_terrain_bounds (tin[8])       -> (bounds[2])
                  G >= |gradient| and U >= the Hessian's largest eigenvalue over the whole terrain at these inputs
                  (inf where the kind has none): the contact search's test for a rim with one maximum (fmu_src/rim.c).

Rigid contact (contact == "rigid", the paper's decision tree) adds one function; cedra_f then holds every force
except the contact forces, and the glue solves for accelerations and contact forces together:
    cedra_contact (q, u, inp, par)      -> (W[3nc x nq], bias[3nc], vc[3nc], gap[nc])
                  per contact (wheel) k, rows 3k..3k+2 = the contact frame's x (rolling), y (lateral), z (normal):
                  vc = W u is the velocity of the wheel's material point at the contact in that frame, and
                  d(vc)/dt = W udot + bias. gap = -penetration (gap <= 0: touching). A contact force
                  lambda_k (same frame) enters as M udot = f + W' lambda. The contacts are the wheels' contact
                  slots, contacts_per_wheel for each wheel in wheel order, then the collision points (if any).
    cedra_out     (q, u, z, inp, par, lam[3nc]) -> (y[ny])   the glue's solution lam goes into the outputs (the
                  wheels' totals, the per-contact outputs); the outputs wheel[i].mode and wheel[i].F*_mean are the
                  glue's (from the contacts' modes and impulses: cedra_out gives 0 there).

Chassis and link contact (chassis == True) keeps the collision points' forces out of cedra_f and adds:
    cedra_cgap    (q, inp, par)         -> (depth[1])   the deepest collision point's penetration (> 0: touching)
    cedra_fc      (q, u, inp, par)      -> (Qc[nq])     their generalized force: M udot = f + Qc
    cedra_fcjac   (q, u, inp, par)      -> (dQc_dq[nq x nq], dQc_du[nq x nq])
                  Qc and its Jacobian are exactly zero while depth <= 0, so the glue evaluates them only then
                  (cedra_settle and cedra_out include the points themselves).

Force-law switches (generated only when the model has switches, len(switch_names) > 0):
    cedra_switch  (q, u, inp, par, hold[nh]) -> (s[nsw], hold_now[nh])
                  switching functions: each s_i is continuous in the state and changes sign exactly where a force
                  law switches (contact onset, a clip, a joint stop, ...), so the glue cuts an adaptive step whose
                  s changes sign at the crossing. `hold` are discrete choices the model makes (e.g. which rim
                  sample the contact search starts from), held over one step: the glue evaluates hold_now at the
                  step's start and passes it for every evaluation inside the step; s is measured relative to them
                  (nh may be 0).

A controller (block == "controller", fmu_src/controller.c) is sampled instead of integrated: no q, u, z, no
start values, no solver. Its discrete state xd (d_names) and outputs change only at samples:
    cedra_sample  (inp, par, xd)        -> (y[ny], xd_next[nd])
                  one sample from the inputs set at that moment; the parameter `ctrl.period` is the period.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import casadi as ca

# the largest solver budgets of one fmi2DoStep a scene or a user may set (the FMU's variables say the same)
# solver.method = index: the embedded solvers (enum solver_method in fmu_src/solver.h)
# (moreau: rigid contact's own Moreau-Jean time stepping, fixed step h_max; rigid scenes only)
SOLVER_METHODS = ("rk4", "dopri5", "rodas4", "ros34pw2", "moreau")

MAX_STEPS_LIMIT = 2**31 - 1       # an fmi2Integer
MAX_WALL_LIMIT = 1e6              # s: finite, so a call always has a bound

# cedra_check's codes (the C glue has the same table in model_glue.c)
CHECK_REASONS = {
    0: "the state is outside the model's domain",
    -1: "the front four-bar cannot be assembled (fork beyond its toggle)",
    -2: "the body has tipped over (|pitch| or |roll| > 80 deg): the model has no body-ground contact",
}

FUNCTION_NAMES = ("cedra_M", "cedra_f", "cedra_rjac", "cedra_out", "cedra_settle", "cedra_guess", "cedra_check",
                  "cedra_terrain", "cedra_rim_samples", "cedra_terrain_bounds")
TERRAIN_TIN = 8         # cedra_terrain's input vector (fmu_src/rim.c: the search's x = [c, a, R, tin])
CONTROLLER_FUNCTION_NAMES = ("cedra_sample",)


@dataclass(frozen=True)
class Quantity:
    """One named scalar of the model's interface (a parameter, an input, an output or a start value)."""
    name: str
    start: float = 0.0
    unit: str = "1"
    description: str = ""
    min: float | None = None
    max: float | None = None
    type: str = "Real"          # "Real" or "Integer" (Integer outputs are computed as reals and rounded)
    min_exclusive: bool = False  # value == min is refused too (XML can only say min; the glue and scenes refuse it)


class LazyFunctions(Mapping):
    """A ModelSpec's functions, formed on first use: forming a 3D scene's CasADi functions takes seconds, and the
    variable table (the FMU reference, the scene checks) needs none of them."""

    def __init__(self, form: Callable[[], dict]):
        self._form, self._fns = form, None

    def _all(self) -> dict:
        if self._fns is None:
            self._fns = dict(self._form())
        return self._fns

    def __getitem__(self, name):
        return self._all()[name]

    def __iter__(self):
        return iter(self._all())

    def __len__(self):
        return len(self._all())


@dataclass
class ModelSpec:
    name: str                               # the scene name: modelIdentifier, .so and .fmu name
    description: str
    q_names: list[str]                      # generalized coordinates, in state order
    z_names: list[str]                      # integral states
    params: list[Quantity]                  # `par` vector, in order
    inputs: list[Quantity]                  # `inp` vector, in order
    outputs: list[Quantity]                 # `y` vector of cedra_out, in order
    q_start: list[float]                    # default initial coordinates (design pose)
    settle_idx: list[int]                   # coordinates solved for by the static-equilibrium Newton solve
    start_params: dict[str, int] = field(default_factory=dict)   # FMU parameter name -> q index it sets
    functions: Mapping[str, ca.Function] = field(default_factory=dict)   # a dict or LazyFunctions
    stop_time: float = 10.0
    output_interval: float = 0.01
    solver: dict = field(default_factory=dict)   # default solver settings: method, tol, h_max
    contact: str = "compliant"              # "rigid": cedra_contact exists and the glue solves the contact forces
    n_contacts: int = 0                     # rigid: number of contacts (cedra_contact's nc)
    contacts_per_wheel: int = 0             # rigid: contacts 0 .. 6 * contacts_per_wheel - 1 are the wheels', in
    #                                         wheel order; the rest are the collision points
    block: str = "plant"                    # "plant": the ODE above in an embedded solver (fmu_src/plant.c);
    #                                         "controller": a sampled block (fmu_src/controller.c, see below)
    d_names: list[str] = field(default_factory=list)   # controller: discrete states, in xd order
    switch_names: list[str] = field(default_factory=list)   # cedra_switch's entries (none: no cedra_switch)
    n_hold: int = 0                         # cedra_switch's held discrete choices
    chassis: bool = False                   # collision points on the body and links: cedra_cgap, cedra_fc, cedra_fcjac
    heightmap_file: str = ""                # terrain "heightmap": the grid file, shipped as resources/heightmap.txt;
    #                                         the generated functions call the external cedra_heightmap (its C
    #                                         implementation is fmu_src/heightmap.c)
    rim_refine: bool = False                # the rim search samples the arcs near touching again (fmu_src/rim.c,
    #                                         CEDRA_RIM_REFINE): 3D scenes and heightmaps
    part_names: list[str] = field(default_factory=list)   # the model's parts (cedra_part_*), one C file each
    parts: Mapping[str, ca.Function] = field(default_factory=dict)  # part name -> its function (a dict or lazy)
    compose: Callable[[Mapping[str, ca.Function]], Mapping[str, ca.Function]] | None = None
    #                                         compose(replacements) -> the contract functions formed from the parts,
    #                                         each part named in replacements called through its replacement (the
    #                                         same name and signature): the build passes external functions, so
    #                                         that a composition's C calls each part in the part's own file

    @property
    def nq(self) -> int:
        return len(self.q_names)

    def function_names(self) -> list[str]:
        if self.block == "controller":
            return list(CONTROLLER_FUNCTION_NAMES)
        return list(FUNCTION_NAMES) + (["cedra_contact"] if self.contact == "rigid" else []) + \
            (["cedra_switch"] if self.switch_names else []) + \
            (["cedra_cgap", "cedra_fc", "cedra_fcjac"] if self.chassis else [])

    def check(self) -> None:
        """Raise ValueError if the functions do not follow the contract above."""
        nq, nz, ni, npar, ny = self.nq, len(self.z_names), len(self.inputs), len(self.params), len(self.outputs)
        ns = len(self.settle_idx)
        if self.block not in ("plant", "controller"):
            raise ValueError(f"model {self.name}: block {self.block!r} (plant or controller)")
        if self.block == "controller":
            if "ctrl.period" not in [p.name for p in self.params]:
                raise ValueError(f"model {self.name}: a controller needs the parameter ctrl.period")
            nd = len(self.d_names)
            return self._check_functions({"cedra_sample": ([ni, npar, nd], [(ny, 1), (nd, 1)])})
        expected = {
            "cedra_M": ([nq, npar], [(nq, nq)]),
            "cedra_f": ([nq, nq, ni, npar], [(nq, 1), (nz, 1)]),
            "cedra_rjac": ([nq, nq, nq, ni, npar], [(nq, nq), (nq, nq), (nz, nq), (nz, nq)]),
            "cedra_out": ([nq, nq, nz, ni, npar], [(ny, 1)]),
            "cedra_settle": ([nq, ni, npar], [(ns, 1), (ns, ns)]),
            "cedra_guess": ([nq, ni, npar], [(nq, 1)]),
            "cedra_check": ([nq, nq, ni, npar], [(1, 1)]),
            "cedra_terrain": ([2, TERRAIN_TIN], [(1, 1), (2, 1), (2, 2)]),
            "cedra_rim_samples": ([7 + TERRAIN_TIN], [(13, 1), (6, 1), (2, 1)]),
            "cedra_terrain_bounds": ([TERRAIN_TIN], [(2, 1)]),
        }
        if self.contact == "rigid":
            nc = self.n_contacts
            if not 0 <= 6 * self.contacts_per_wheel <= nc:      # the glue reads the six wheels' contacts first
                raise ValueError(f"model {self.name}: {self.contacts_per_wheel} contacts per wheel, {nc} contacts")
            expected["cedra_contact"] = ([nq, nq, ni, npar], [(3 * nc, nq), (3 * nc, 1), (3 * nc, 1), (nc, 1)])
            expected["cedra_out"] = ([nq, nq, nz, ni, npar, 3 * nc], [(ny, 1)])
        if self.chassis:
            expected["cedra_cgap"] = ([nq, ni, npar], [(1, 1)])
            expected["cedra_fc"] = ([nq, nq, ni, npar], [(nq, 1)])
            expected["cedra_fcjac"] = ([nq, nq, ni, npar], [(nq, nq), (nq, nq)])
        if self.switch_names:
            nsw, nh = len(self.switch_names), self.n_hold
            expected["cedra_switch"] = ([nq, nq, ni, npar, nh], [(nsw, 1), (nh, 1)])
        self._check_functions(expected)

    def _check_functions(self, expected: dict) -> None:
        for name, (ins, outs) in expected.items():
            fn = self.functions.get(name)
            if fn is None:
                raise ValueError(f"model {self.name}: function {name} missing")
            if fn.name() != name:
                raise ValueError(f"model {self.name}: function {name} is named {fn.name()}")
            got_in = [fn.size1_in(i) for i in range(fn.n_in())]
            got_out = [fn.size_out(i) for i in range(fn.n_out())]
            if got_in != ins or [tuple(s) for s in got_out] != outs:
                raise ValueError(f"model {self.name}: {name} has inputs {got_in} outputs {got_out}, "
                                 f"expected {ins} {outs}")
