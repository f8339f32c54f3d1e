"""The model as parts: the rover's contact-free dynamics, the wheels' kinematics, ONE wheel-contact part formed once
and called for each wheel, and ONE point-contact part for the body's and links' collision points; cedra_f,
cedra_rjac, cedra_fc and cedra_fcjac composed from them (docs/model.md, The model as parts).

A wheel's contact with the terrain depends on the rover only through the wheel's state

    x_k = [c_k, a_k, v_k, w_k]      (center, axle, center velocity, angular velocity; world, 12 numbers)

and on the contact search's result s_k for that wheel (cedra.mechanics.rim; derivatives never go through the
search). So the contact part is one function of (x, s, inp, par) giving the wrench at the wheel's center,
W = [F; T] with F the sum of the slots' forces and T = sum (p_j - c) x F_j, and its Jacobian dW/dx. The rover's
generalized force from wheel k is J_k' W_k with J_k = d[v_k; w_k]/du (the velocities are linear in u, so J_k is a
function of q), which equals the sum of the slots' point forces through their partial velocities (the contact
point's material velocity is v + w x (p - c)). With f0 the contact-free right-hand side,

    f            = f0 + sum_k J_k' W_k
    d(M a - f)/dq = d(M a - f0 - sum_k J_k' W)/dq |W fixed - sum_k J_k' (dW_k/dx_k) (dx_k/dq)
    d(M a - f)/du = d(M a - f0)/du                     - sum_k J_k' (dW_k/dx_k) (dx_k/du)

the exact Jacobian by the chain rule. Each wheel picks its own form: with one maximum on its rim (the search says
so) the one-slot form, else the three-slot form; CasADi's conditional call evaluates only the branch taken. The
monolithic form (CedraModel.functions(parts=False)) stays as the reference the tests hold the parts to.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from cedra.mechanics import rim
from cedra.mechanics.contact import (compliant_force, compliant_law, contact_geometry, point_penetration,
                                     rim_contacts)
from cedra.contract import TERRAIN_TIN
from cedra.mechanics.kane import KaneSystem

WHEEL_STATE = 12      # x_k = [center, axle, center velocity, angular velocity]
WRENCH = 6            # W_k = [force, torque about the center]
POINT_STATE = 6       # a collision point's x = [position, velocity]
SEARCH_INPUT = 7 + TERRAIN_TIN    # the contact search's x = [center, axle, radius, terrain inputs] (fmu_src/rim.c)


def part_names(multi_contact: bool, chassis_groups: list[str] = ()) -> list[str]:
    """The fixed names of a model's parts, in the order the build writes their C files: the wheels' kinematics,
    the contact-free dynamics, the wheel-contact part (with its one-maximum forms where a wheel can touch at several
    points), and with collision points the point-contact part and, per group of points (point_groups: the points
    fixed in one body, or a point of its own), the group's generalized force cedra_part_chassis_<group> (and
    _jac)."""
    names = ["cedra_part_kin", "cedra_part_dyn", "cedra_part_dyn_jac", "cedra_part_wheel", "cedra_part_wheel_jac"]
    if multi_contact:
        names += ["cedra_part_wheel_one", "cedra_part_wheel_one_jac", "cedra_part_wheel_flag"]
    if chassis_groups:
        names += ["cedra_part_point", "cedra_part_point_jac", "cedra_part_point_none", "cedra_part_point_depth",
                  "cedra_part_point_kin"]
        for g in chassis_groups:
            names += [f"cedra_part_chassis_{g}", f"cedra_part_chassis_{g}_jac"]
    return names


@dataclass
class PointGroup:
    """Collision points that share one generalized-force part: the points fixed in one of the rover's bodies (body:
    their local coordinates R' (p - o) in its frame, an expression of the parameters, local), or one point of its
    own (body None: a point on a massless link, e.g. a bogie, whose frame the description does not give)."""
    name: str
    points: list[int]            # indices into the model's collision points (those of nonzero weight)
    body: object | None = None
    local: ca.SX | None = None   # 3 x len(points)


def point_groups(model) -> list[PointGroup]:
    """The model's collision points (those of nonzero planar weight, in order) grouped by the body they are fixed
    in. A point is fixed in a body where R' (p - o) (o the body's position, R its inertia frame) is the same at every
    pose and its velocity is do/dt + omega x (p - o): both checked at random poses, speeds and parameters, to 1e-12,
    against r = R' (p - o) at q = 0; where no body holds it, it is a group of its own (its index, from 1)."""
    m = model
    planar = m.opt.dims == "2d"
    points = [pt for pt in m.rover.collision_points if (pt.planar_weight if planar else 1) != 0]
    n = m.q.numel()
    par0 = m.default_par()
    rng = np.random.default_rng(20261202)
    # poses, speeds and parameter values: a point that coincides with a body's frame only at some parameters' values
    # (the fork's joint with its mass point where fork_mass_at = 0) is not fixed in it for a user who sets others
    poses = [(rng.uniform(-0.6, 0.6, n), rng.normal(0, 1, n), par0 + 0.05 * rng.normal(size=par0.size) *
              (np.abs(par0) + 0.01)) for _ in range(3)]
    groups: dict[str, PointGroup] = {}
    singles = []
    for j, pt in enumerate(points):
        home = None
        for body in m.rover.bodies:
            if body.omega is None or body.inertia_frame is None or body.name.startswith("wheel"):
                continue          # a wheel spins: its points are not the chassis'
            local = body.inertia_frame.T @ (pt.position - body.position)
            arm = body.inertia_frame @ ca.substitute(local, m.q, ca.SX.zeros(n))
            # the body's frame moves with its omega where the point's velocity is do/dt + omega x R r
            slip = ca.vertcat(local - ca.substitute(local, m.q, ca.SX.zeros(n)),
                              m.rate(pt.position) - m.rate(body.position) - ca.cross(body.omega, arm))
            at = ca.Function("fixed", [m.q, m.u, m.par], [slip])
            if all(np.max(np.abs(np.array(at(qq, uu, pp)))) <= 1e-12 for qq, uu, pp in poses):
                home = body, ca.substitute(local, m.q, ca.SX.zeros(n))
                break
        if home is None:
            singles.append(PointGroup(str(j + 1), [j]))
            continue
        body, local = home
        g = groups.setdefault(body.name, PointGroup(body.name, [], body, ca.SX(3, 0)))
        g.points.append(j)
        g.local = ca.horzcat(g.local, local)
    return list(groups.values()) + singles


def _function(name, ins, outs, names_in=None, names_out=None) -> ca.Function:
    opts = {"cse": True}
    if names_in:
        return ca.Function(name, ins, outs, names_in, names_out, opts)
    return ca.Function(name, ins, outs, opts)


@dataclass
class WheelContactPart:
    """The wheel-contact part in its forms: (x, s, inp, par) -> W and -> dW/dx; `one` the one-maximum forms
    (None where the terrain has one contact per wheel), flag(s) -> 1 where the one-maximum form holds."""
    wrench: ca.Function
    wrench_jac: ca.Function
    one_wrench: ca.Function | None
    one_wrench_jac: ca.Function | None
    flag: ca.Function | None


class ModelParts:
    """The parts of a compliant CedraModel and the contract's cedra_f, cedra_rjac (and, with chassis points,
    cedra_fc, cedra_fcjac) composed from them. It reads the model's symbols and its contact search (the same
    package's CedraModel); the monolithic forms stay CedraModel's."""

    def __init__(self, model):
        if model.rigid:
            raise ValueError("the parts form is the compliant model's (rigid contact keeps the monolithic form)")
        self.m = model
        self.part_functions: dict[str, ca.Function] = {}     # every part, by its fixed name
        self.compact: dict[str, dict[int, list[int]]] = {}  # a compact part's argument -> the entries it reads
        q, u, par, inp = model.q, model.u, model.par, model.inp
        self.n = q.numel()
        wheels = model.rover.wheels
        self.K = len(wheels)
        # the wheels' states and the search's inputs, functions of the rover's coordinates
        X = ca.vertcat(*[ca.vertcat(w.center, w.axle, w.velocity, w.omega) for w in wheels])
        self.kin = self._part("cedra_part_kin", [q, u, inp, par], [X] + (
            [ca.vertcat(*[rim.search_input(w.center, w.axle, model.p["R_w"], model.terrain) for w in wheels])]
            if model.multi_contact else []))
        # the contact-free dynamics: Kane's equations without the wheels' contact forces, the wrenches as inputs
        free = KaneSystem(q, u, model.kane.bodies, model.kane.generalized_forces,
                          model.kane.point_forces[:model.n_free_point_forces])
        M, f0 = free.equations()
        W = ca.SX.sym("W", WRENCH * self.K)
        J = [ca.jacobian(ca.vertcat(w.velocity, w.omega), u) for w in wheels]
        fW = f0 + sum((J[k].T @ W[WRENCH * k:WRENCH * (k + 1)] for k in range(self.K)), ca.SX.zeros(self.n, 1))
        a = ca.SX.sym("a", self.n)
        r = M @ a - fW
        self.contact = self._wheel_part()
        # the chain rule inside the dynamics' own Jacobian, on the structural nonzeros of every factor: dW/dx enters
        # as an input with the wheel part's sparsity, so the products are straight-line code that shares the
        # rover's kinematics (its sines and cosines) with the dynamics
        pattern = self.contact.wrench_jac.sparsity_out(1)
        dW = [ca.SX.sym(f"dW{k}", pattern) for k in range(self.K)]
        Xq, Xu = ca.jacobian(X, q), ca.jacobian(X, u)
        dr_dq, dr_du = ca.jacobian(r, q), ca.jacobian(r, u)
        for k in range(self.K):
            rows = slice(WHEEL_STATE * k, WHEEL_STATE * (k + 1))
            dr_dq -= J[k].T @ (dW[k] @ Xq[rows, :])
            dr_du -= J[k].T @ (dW[k] @ Xu[rows, :])
        if model.chassis:
            self._chassis_parts()
        self.dyn_f = self._part("cedra_part_dyn", [q, u, inp, par, W], [fW, model.power], compact=True)
        self.dyn_jac = self._part("cedra_part_dyn_jac", [q, u, a, inp, par, W, ca.horzcat(*dW)], [
            dr_dq, dr_du, ca.jacobian(model.power, q), ca.jacobian(model.power, u)], compact=True)
        expected = part_names(model.multi_contact, [g.name for g in model.chassis_groups] if model.chassis else [])
        if sorted(self.part_functions) != sorted(expected):
            raise RuntimeError(f"the parts formed {sorted(self.part_functions)}, part_names says {sorted(expected)}")

    def _wheel_part(self) -> WheelContactPart:
        """The wheel-contact part, formed once from a symbolic wheel state (the contact law of
        CedraModel._wheel_contact, summed into the wrench at the center)."""
        m, p, i_ = self.m, self.m.p, self.m.i
        x = ca.SX.sym("x", WHEEL_STATE)
        c, a, v, w = x[0:3], x[3:6], x[6:9], x[9:12]
        s = ca.SX.sym("s", rim.N_RESULT)
        if m.multi_contact:
            geos, _ = rim_contacts(c, a, m.terrain, p["R_w"], s)
        else:
            geos = [contact_geometry(c, a, m.terrain, p["R_w"])]
        F, T = ca.SX.zeros(3, 1), ca.SX.zeros(3, 1)
        for geo in geos:
            arm = geo.point - c
            force = compliant_force(geo, v + ca.cross(w, arm), p["ground_k"], p["ground_d"], i_["mu"], p["v_eps"])[0]
            F += force
            T += ca.cross(arm, force)
        Wk = ca.vertcat(F, T)
        dW = ca.jacobian(Wk, x)
        ins = [x, s, m.inp, m.par]
        res = m.terrain.resolve
        wrench = self._part("cedra_part_wheel", ins, res([Wk], False))
        # the Jacobian's form gives the wrench too: one call per wheel forms the contact geometry once for both
        wrench_jac = self._part("cedra_part_wheel_jac", ins, res([Wk, dW]))
        if not m.multi_contact:
            return WheelContactPart(wrench, wrench_jac, None, None, None)
        ones = rim.ONE_MAXIMUM
        fixed = [s[k] for k in ones], [ca.SX(v_) for v_ in ones.values()]
        one = self._part("cedra_part_wheel_one", ins, res(ca.substitute([Wk], *fixed), False))
        # the same sparsity as the full form's (the forms are a conditional call; dW enters the dynamics with it)
        one_W, one_dW = ca.substitute([Wk, dW], *fixed)
        one_jac = self._part("cedra_part_wheel_one_jac", ins,
                            [e if k == 0 else ca.project(e, dW.sparsity()) for k, e in enumerate(res([one_W, one_dW]))])
        flag = 1
        for k, v_ in ones.items():
            flag = ca.logic_and(flag, s[k] == v_)
        return WheelContactPart(wrench, wrench_jac, one, one_jac, self._part("cedra_part_wheel_flag", [s], [flag]))

    def _part(self, name, ins, outs, compact: bool = False) -> ca.Function:
        """The part `name`; compact: its inputs and parameters reduced to the entries it reads (self.compact keeps
        which), so that the part's C is the same in every scene whose rover is the same, whatever the terrain's
        inputs and the scene's parameters around them (the object cache then keeps one object for all of them)."""
        if compact:
            every = ca.vertcat(*[ca.vec(o) for o in outs])
            picks = {}
            for k, arg in enumerate(ins):
                if arg is self.m.inp or arg is self.m.par:
                    idx = [i for i, used in enumerate(ca.which_depends(every, arg, 1, False)) if used]
                    picks[k] = idx
                    sub = ca.SX.sym("inp" if arg is self.m.inp else "par", len(idx))
                    outs = ca.substitute(outs, [arg[idx]], [sub]) if idx else outs
                    ins = ins[:k] + [sub] + ins[k + 1:]
            self.compact[name] = picks
        fn = _function(name, ins, outs)
        self.part_functions[name] = fn
        return fn

    # ---------------- the composition (MX: each part a call, each wheel's form a conditional call) ----------------
    def _wheels(self, q, u, inp, par, jac: bool, use):
        """Per wheel: its wrench W_k (jac: also dW_k/dx_k), the search run once per wheel (a 2D
        wheel and its planar twin meet the terrain alike: one search and one wrench for the pair)."""
        m = self.m
        out = use("cedra_part_kin")(q, u, inp, par)
        X = out[0] if isinstance(out, (list, tuple)) else out
        S = out[1] if m.multi_contact else None
        Ws, dWs = [], []
        forms = None
        if m.multi_contact:
            forms = (ca.Function.if_else("cedra_part_wheel_forms", use("cedra_part_wheel_one"), use("cedra_part_wheel")),
                     ca.Function.if_else("cedra_part_wheel_jac_forms", use("cedra_part_wheel_one_jac"),
                                         use("cedra_part_wheel_jac")))
        done = {}
        for k, wh in enumerate(m.rover.wheels):
            x = X[WHEEL_STATE * k:WHEEL_STATE * (k + 1)]
            twin = m.planar_twins.get(wh.index) if m.opt.dims == "2d" else None
            if twin in done:
                # 2D: a wheel and its planar twin differ only in their center's Y, and the terrain is constant in Y:
                # the same wrench about their centers and the same derivative (zero along Y), so it is formed once
                Ws.append(Ws[done[twin]])
                if jac:
                    dWs.append(dWs[done[twin]])
                continue
            done[wh.index] = k
            if m.multi_contact:
                s = m._rim_search(S[SEARCH_INPUT * k:SEARCH_INPUT * (k + 1)])
                flag = use("cedra_part_wheel_flag")(s)
                if jac:
                    Wk, dWk = forms[1](flag, x, s, inp, par)
                    Ws.append(Wk)
                    dWs.append(dWk)
                else:
                    Ws.append(forms[0](flag, x, s, inp, par))
            else:
                s = ca.MX.zeros(rim.N_RESULT, 1)
                if jac:
                    Wk, dWk = use("cedra_part_wheel_jac")(x, s, inp, par)
                    Ws.append(Wk)
                    dWs.append(dWk)
                else:
                    Ws.append(use("cedra_part_wheel")(x, s, inp, par))
        return Ws, dWs

    def _user(self, parts):
        """name -> the part the compositions call: parts[name] where given (the same name and signature: the FMU's
        build passes the parts as external functions, so that the compositions' C calls each part's own file),
        else the part itself."""
        parts = parts or {}
        unknown = set(parts) - set(self.part_functions)
        if unknown:
            raise KeyError(f"no parts named {sorted(unknown)}")

        def use(name):
            fn, picks = parts.get(name, self.part_functions[name]), self.compact.get(name)
            if not picks:
                return fn
            return lambda *args: fn(*[a[picks[k]] if k in picks else a for k, a in enumerate(args)])
        return use

    def functions(self, parts=None) -> dict[str, ca.Function]:
        """cedra_f and cedra_rjac (and, with collision points, cedra_fc and cedra_fcjac) under the contract's names
        and arguments (cedra.contract); parts: replacements of some parts by name (_user)."""
        use = self._user(parts)
        n = self.n
        q, u, a = ca.MX.sym("q", n), ca.MX.sym("u", n), ca.MX.sym("a", n)
        inp, par = ca.MX.sym("inp", self.m.inp.numel()), ca.MX.sym("par", self.m.par.numel())
        Ws, _ = self._wheels(q, u, inp, par, False, use)
        f, power = use("cedra_part_dyn")(q, u, inp, par, ca.vertcat(*Ws))
        cedra_f = ca.Function("cedra_f", [q, u, inp, par], [f, power])
        Ws, dWs = self._wheels(q, u, inp, par, True, use)
        dr_dq, dr_du, dp_dq, dp_du = use("cedra_part_dyn_jac")(q, u, a, inp, par, ca.vertcat(*Ws), ca.horzcat(*dWs))
        cedra_rjac = ca.Function("cedra_rjac", [q, u, a, inp, par], [dr_dq, dr_du, dp_dq, dp_du])
        fns = {"cedra_f": cedra_f, "cedra_rjac": cedra_rjac} | (self.chassis_functions(parts) if self.m.chassis else {})
        return fns | {"cedra_settle": self._settle(fns)}

    def _settle(self, fns) -> ca.Function:
        """cedra_settle from the composed functions: the static residual f(q, 0) (+ the chassis' force) on the settle
        coordinates and its Jacobian, which at a = 0 is -d(M a - f)/dq (+ dQc/dq), rows and columns those
        coordinates."""
        n, sidx = self.n, self.m.settle_idx
        q, zero = ca.MX.sym("q", n), ca.MX.zeros(n, 1)
        inp, par = ca.MX.sym("inp", self.m.inp.numel()), ca.MX.sym("par", self.m.par.numel())
        res = fns["cedra_f"](q, zero, inp, par)[0]
        jac = -fns["cedra_rjac"](q, zero, zero, inp, par)[0]
        if "cedra_fc" in fns:
            res += fns["cedra_fc"](q, zero, inp, par)
            jac += fns["cedra_fcjac"](q, zero, inp, par)[0]
        return ca.Function("cedra_settle", [q, inp, par], [res[sidx], jac[sidx, sidx]])

    # ---------------- the body's and links' collision points (docs/model.md, Chassis and links) ----------------
    def _chassis_parts(self):
        """One point-contact part for every collision point: (x = [p, v], inputs, parameters) -> the compliant
        law's force on the point F = F_n n + F_t (and dF/dx), the terrain's normal under the point; the points'
        kinematics with their depths; and per point j its generalized force w_j J_j' F_j (J_j = dv_j/du, w_j the
        point's planar weight) with its Jacobian by the chain rule, cedra_part_chassis_<j> (and _jac). Only the
        points that touch (depth > 0) call the law and their own generalized-force part: elsewhere both are exactly
        zero, as they are in the monolithic form, and a point that does not touch costs its depth alone."""
        m, p, i_ = self.m, self.m.p, self.m.i
        q, u, inp, par = m.q, m.u, m.inp, m.par
        planar = m.opt.dims == "2d"
        points = [pt for pt in m.rover.collision_points if (pt.planar_weight if planar else 1) != 0]
        weights = [pt.planar_weight if planar else 1 for pt in points]
        self.n_points = len(points)
        x = ca.SX.sym("x", POINT_STATE)
        pos, vel = x[0:3], x[3:6]
        n, depth = point_penetration(m.terrain, pos)
        Fn, Ft, _, _ = compliant_law(depth, n, vel, p["ground_k"], p["ground_d"], i_["mu"], p["v_eps"])
        F = Fn * n + Ft
        res = m.terrain.resolve
        self.point_jac = self._part("cedra_part_point_jac", [x, inp, par], res([F, ca.jacobian(F, x)]))
        self.point = self._part("cedra_part_point", [x, inp, par], res([F], False))
        zero = [ca.SX.zeros(self.point_jac.sparsity_out(k)) for k in range(2)]
        self.point_none = self._part("cedra_part_point_none", [x, inp, par], zero)
        self.point_depth = self._part("cedra_part_point_depth", [x, inp, par], res([depth], False))
        P = ca.vertcat(*[ca.vertcat(pt.position, m.rate(pt.position)) for pt in points])
        self.point_kin = self._part("cedra_part_point_kin", [q, u, par], [P], compact=True)
        # per group, its points' generalized force w J' F and d(w J' F)/dq at fixed F + w J' (dF/dx)(dx/dq): the
        # velocity is J u, so dx/du = [0; J]. A body's part takes the point's local coordinates r as an input
        # (p = o + R r, v = do/dt + omega x R r): one part serves every point fixed in the body.
        self.groups = m.chassis_groups
        Fj, wj = ca.SX.sym("F", 3), ca.SX.sym("w")
        dFj = ca.SX.sym("dF", self.point_jac.sparsity_out(1))
        for g in self.groups:
            if g.body is not None:
                r = ca.SX.sym("r", 3)
                arm = g.body.inertia_frame @ r
                xj = ca.vertcat(g.body.position + arm, m.rate(g.body.position) + ca.cross(g.body.omega, arm))
                extra = [r]
            else:
                pt = points[g.points[0]]
                xj = ca.vertcat(pt.position, m.rate(pt.position))
                extra = []
            Jj = ca.jacobian(xj[3:6], u)
            Q = wj * (Jj.T @ Fj)
            dQ_dq = ca.jacobian(Q, q) + wj * (Jj.T @ (dFj @ ca.jacobian(xj, q)))
            dQ_du = wj * (Jj.T @ (dFj @ ca.jacobian(xj, u)))
            self._part(f"cedra_part_chassis_{g.name}", [q, par] + extra + [wj, Fj], [Q], compact=True)
            self._part(f"cedra_part_chassis_{g.name}_jac", [q, u, par] + extra + [wj, Fj, dFj], [dQ_dq, dQ_du],
                       compact=True)
        self.weights = weights

    def _points(self, q, u, inp, par, jac: bool, use):
        """The collision points' generalized force (jac: its Jacobian), each point's law and its group's part one
        conditional call, taken only where the point touches."""
        n = self.n
        P = use("cedra_part_point_kin")(q, u, par)
        law = ca.Function.if_else("cedra_part_point_touch", use("cedra_part_point_jac"), use("cedra_part_point_none"))
        Q, dQ_dq, dQ_du = ca.MX.zeros(n, 1), ca.MX.zeros(n, n), ca.MX.zeros(n, n)
        qs, us, ps = ca.MX.sym("q", n), ca.MX.sym("u", n), ca.MX.sym("par", par.numel())
        xs, inps = ca.MX.sym("x", POINT_STATE), ca.MX.sym("inp", inp.numel())
        rs, ws = ca.MX.sym("r", 3), ca.MX.sym("w")
        Fs, dFs = ca.MX.sym("F", 3), ca.MX.sym("dF", self.point_jac.sparsity_out(1))
        for g in self.groups:
            extra_s = [rs] if g.body is not None else []
            if jac:
                name = f"cedra_part_chassis_{g.name}_jac"
                part = self.part_functions[name]
                force = ca.Function(f"cedra_point_{g.name}_jac", [qs, us, ps] + extra_s + [ws, Fs, dFs],
                                    use(name)(qs, us, ps, *extra_s, ws, Fs, dFs))
                none = ca.Function(f"cedra_point_{g.name}_jac_none", [qs, us, ps] + extra_s + [ws, Fs, dFs],
                                   [ca.MX(part.sparsity_out(0), 0), ca.MX(part.sparsity_out(1), 0)])
            else:
                name = f"cedra_part_chassis_{g.name}"
                force = ca.Function(f"cedra_point_{g.name}", [qs, ps] + extra_s + [ws, xs, inps],
                                    [use(name)(qs, ps, *extra_s, ws, use("cedra_part_point")(xs, inps, ps))])
                # both branches with the part's sparsity (a conditional call's derivatives need them equal)
                none = ca.Function(f"cedra_point_{g.name}_none", [qs, ps] + extra_s + [ws, xs, inps],
                                   [ca.MX(self.part_functions[name].sparsity_out(0), 0)])
            touch = ca.Function.if_else(force.name() + "_touch", force, none)
            local = ca.Function(f"cedra_point_{g.name}_local", [self.m.par], [g.local])(par) \
                if g.body is not None else None
            for k, j in enumerate(g.points):
                x = P[POINT_STATE * j:POINT_STATE * (j + 1)]
                flag = use("cedra_part_point_depth")(x, inp, par) > 0
                extra = [local[:, k]] if g.body is not None else []
                if jac:
                    F, dF = law(flag, x, inp, par)
                    dq, du = touch(flag, q, u, par, *extra, self.weights[j], F, dF)
                    dQ_dq += dq
                    dQ_du += du
                else:
                    Q += touch(flag, q, par, *extra, self.weights[j], x, inp)
        return Q, dQ_dq, dQ_du

    def chassis_functions(self, parts=None) -> dict[str, ca.Function]:
        """cedra_fc and cedra_fcjac under the contract's names and arguments (cedra.contract); parts as in
        functions."""
        use = self._user(parts)
        n = self.n
        q, u = ca.MX.sym("q", n), ca.MX.sym("u", n)
        inp, par = ca.MX.sym("inp", self.m.inp.numel()), ca.MX.sym("par", self.m.par.numel())
        fc = ca.Function("cedra_fc", [q, u, inp, par], [self._points(q, u, inp, par, False, use)[0]])
        _, dq, du = self._points(q, u, inp, par, True, use)
        fcjac = ca.Function("cedra_fcjac", [q, u, inp, par], [dq, du])
        return {"cedra_fc": fc, "cedra_fcjac": fcjac}
