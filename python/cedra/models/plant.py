"""Forms a scene's equations: restricts the 3D rover to the scene's coordinates, adds terrain and contact, and
returns the ModelSpec (CasADi functions under the contract's fixed names, plus the named interface).

Restriction (docs/model.md, Scenes): every one of the 17 full coordinates is either one of the scene's coordinates or
the constant 0, so q_full = P q with a constant 0/1 matrix P. Forming Kane's equations with the scene's speeds
as generalized speeds is the projection P' M P, P' f of the 3D equations (tested in
tests/test_model_dynamics.py::test_projection): the planar model is the 3D model, not a second hand-written one.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from cedra.rover import parameters
from cedra.mechanics.contact import (ContactGeometry, compliant_force, compliant_law, contact_frame,
                                     contact_geometry, point_penetration, rim_contacts, slope_angle,
                                     terrain_functions)
from cedra.mechanics import rim
from cedra.mechanics.kane import KaneSystem
from cedra.rover.mechanism import drive_torque
from cedra.contract import LazyFunctions, ModelSpec, Quantity
from cedra.mechanics.rover_kind import RoverKind
from cedra.mechanics.terrain import STAIRS_STEPS, TERRAIN_INPUTS, Terrain, terrain_inputs
from cedra.models.rovers import ROVERS

XI_SPEED = 1e-3      # m/s: below it the rotational slip angle xi fades to 0 (its direction is undefined at rest)


@dataclass(frozen=True)
class ModelOptions:
    dims: str = "3d"              # "2d" or "3d"
    terrain: str = "flat"
    steering: bool = False
    contact: str = "compliant"
    locked_wheels: bool = False   # wheels welded to their carriers (a parking brake): no spin coordinates
    heightmap: str = ""           # terrain "heightmap": the grid file (shipped as the FMU's resources/heightmap.txt)
    drives: bool = False          # motor-and-gear model between tau[i] and the wheel (docs/model.md, Drives)
    stairs_steps: int = STAIRS_STEPS   # terrain "stairs": its number of steps
    chassis: bool = False         # the body's and links' collision points touch the terrain (docs/model.md,
    #                               Chassis and links)
    rover: str = "cedra"          # which rover (cedra.models.rovers.ROVERS)


def rover_kind(opt: ModelOptions) -> RoverKind:
    if opt.rover not in ROVERS:
        raise ValueError(f"unknown rover {opt.rover!r} ({', '.join(ROVERS)})")
    kind = ROVERS[opt.rover]
    kind.check()
    return kind


def coordinate_map(opt: ModelOptions) -> dict[str, str | None]:
    """For each full coordinate: the scene coordinate it equals, or None for the constant 0."""
    kind = rover_kind(opt)
    if opt.dims == "2d":
        m = kind.planar
    elif not opt.steering:
        m = {n: None for n in kind.steering}
    else:
        m = {}
    if opt.locked_wheels:
        m = m | {f"gamma{i}": None for i in range(1, 7)}
    return {n: m.get(n, n) for n in kind.coordinates}


def projection(opt: ModelOptions) -> tuple[list[str], np.ndarray]:
    """The scene's coordinate names and P with q_full = P q."""
    cmap = coordinate_map(opt)
    full = rover_kind(opt).coordinates
    names = [n for n in full if cmap[n] == n]
    P = np.zeros((len(full), len(names)))
    for i, n in enumerate(full):
        if cmap[n] is not None:
            P[i, names.index(cmap[n])] = 1.0
    return names, P


def param_table(opt: ModelOptions) -> list[Quantity]:
    kind = rover_kind(opt)
    ps = kind.parameters + (parameters.RIGID if opt.contact == "rigid" else parameters.GROUND)
    if opt.steering:
        ps = ps + kind.servo_parameters
    if opt.drives:
        ps = ps + parameters.DRIVES
    return ps


def input_table(opt: ModelOptions) -> list[Quantity]:
    ins = [] if opt.locked_wheels else [
        Quantity(f"tau[{i}]", 0.0, "N.m", f"motor torque of wheel {i} (about its axle, positive drives forward)")
        for i in range(1, 7)]
    if opt.steering:
        ins += rover_kind(opt).steer_inputs
    ins.append(Quantity("mu", 0.8, "1", "friction coefficient wheel-ground", 0.0, 10.0))
    ins += [TERRAIN_INPUTS[n] for n in terrain_inputs(opt.terrain, opt.dims)]
    return ins


def _function(name, ins, outs) -> ca.Function:
    """A contract function with common subexpressions eliminated: the same terrain point, frame or contact
    quantity formed twice (the contacts of a wheel share their frame, a 2D bogie pair its search) is computed
    once; bit for bit the same results, about half the instructions."""
    return ca.Function(name, ins, outs, {"cse": True})


def _out(name, unit, description, type="Real"):
    return Quantity(name, 0.0, unit, description, type=type)


class CedraModel:
    """The rover's equations for one set of scene options. Symbolic pieces are public for tests."""

    def __init__(self, opt: ModelOptions, symbolic_rim: bool = False, smooth_contact: bool = False):
        """symbolic_rim: a heightmap scene's rim search formed symbolically instead of the C search (the
        reference the tests compare the C search against; see terrain.Terrain). smooth_contact: the compliant law's
        smoothed form (contact.compliant_law) with its width the free symbol contact_width, for the optimizer's
        own equations (cedra.optimize); no FMU is formed with it."""
        if opt.contact not in ("compliant", "rigid"):
            raise ValueError(f"unknown contact model {opt.contact!r} (compliant or rigid)")
        if opt.drives and opt.locked_wheels:
            raise ValueError("drives need spinning wheels (locked_wheels is set)")
        self.kind = rover_kind(opt)
        if opt.steering and not self.kind.steering:
            raise ValueError(f"rover {opt.rover} has no steering joints (it turns by skid steering)")
        self.idx = self.kind.index
        self.rigid = opt.contact == "rigid"
        self.symbolic_rim = symbolic_rim
        self.contact_width = ca.SX.sym("contact_width") if smooth_contact else None
        self.opt = opt
        self.q_names, self.P = projection(opt)
        n = len(self.q_names)
        self.q = ca.SX.sym("q", n)
        self.u = ca.SX.sym("u", n)
        self.params = param_table(opt)
        self.inputs = input_table(opt)
        self.par = ca.SX.sym("par", len(self.params))
        self.inp = ca.SX.sym("inp", len(self.inputs))
        p = {q.name: self.par[i] for i, q in enumerate(self.params)}
        i_ = {q.name: self.inp[i] for i, q in enumerate(self.inputs)}
        self.p, self.i = p, i_
        self.qf = ca.SX(ca.DM(self.P)) @ self.q
        self.tau = self.applied_torques([i_.get(f"tau[{k}]", 0) for k in range(1, 7)])
        steer = tuple(i_[s.name] for s in self.kind.steer_inputs) if opt.steering else None
        # the smoothed law's joint stops: the contact's width measured along a wheel's rim, in radians
        stop_width = None if self.contact_width is None else self.contact_width / p["R_w"]
        self.rover = self.kind.describe(self.qf, self.rate, p, self.tau, steer, stop_width=stop_width)
        self.terrain = Terrain(opt.terrain, {n: i_[n] for n in terrain_inputs(opt.terrain, opt.dims)},
                               opt.heightmap, symbolic_rim, opt.stairs_steps)
        self.kane = KaneSystem(self.q, self.u, list(self.rover.bodies))
        self.kane.add_generalized_force(ca.jacobian(self.rate(self.qf), self.u).T @ self.rover.coordinate_torques)
        for b in self.rover.bodies:                                  # gravity: -m g Z at each mass center
            self.kane.add_point_force(self.rate(b.position), ca.vertcat(0, 0, -b.mass * p["g"]))
        self._frozen = []           # (symbol, expression) of the contact search (_freeze)
        self._searches = {}         # wheel index -> its contact search (cedra_rim_search's result)
        self._rim_search = None
        self._one = []              # (frozen search result, its value where the wheel has one maximum)
        # rigid contact: every contact the glue's constrained solve sees, in order (the wheels' contact slots, then
        # the collision points): its frame velocity vc, gap and force symbol lam (Fx, Fy, Fn in its frame)
        self.rigid_contacts = []
        self.n_free_point_forces = len(self.kane.point_forces)     # gravity's; the wheels' contact forces follow
        self.contacts = [self._wheel_contact(wh) for wh in self.rover.wheels]
        self.chassis = self._chassis_contacts() if opt.chassis else []
        # rigid: the contact forces, an input of cedra_out (the glue's solution), as the compliant law's are
        self.lam = ca.vertcat(*[c["lam"] for c in self.rigid_contacts]) if self.rigid else ca.SX(0, 1)
        self.M, self.f = self.kane.equations()
        qd = self.rate(self.qf)
        # the work integral is the APPLIED torques' (with drives: after the clip and the gear loss), so
        # K + P - work stays constant up to the contact's and the joints' dissipation
        self.power = sum(self.tau[k] * qd[self.idx[f"gamma{k + 1}"]] for k in range(6))
        self.kinetic = 0.5 * ca.dot(self.u, self.M @ self.u)
        self.potential = self.rover.potential
        if not self.rigid:
            self.potential += sum(ca.if_else(part["geo"].depth > 0, 0.5 * p["ground_k"] * part["geo"].depth ** 2, 0)
                                  for c in self.contacts for part in c["parts"])
            self.potential += sum(c["weight"] * ca.if_else(c["depth"] > 0, 0.5 * p["ground_k"] * c["depth"] ** 2, 0)
                                  for c in self.chassis)

    def _freeze(self, expr):
        """A free symbol standing for expr until resolve() (see contact.rim_contacts: derivatives do not go
        through the contact search)."""
        sym = ca.SX.sym(f"frozen{len(self._frozen)}", expr.shape[0], expr.shape[1])
        self._frozen.append((sym, expr))
        return sym

    def resolve(self, exprs: list, derivatives: bool = True) -> list:
        """exprs with the contact search's frozen symbols put back, then the heightmap's (terrain.resolve)."""
        if self._frozen:
            exprs = ca.substitute(list(exprs), [s for s, _ in self._frozen], [e for _, e in self._frozen])
        return self.terrain.resolve(exprs, derivatives)

    def _contract(self, name, ins, outs, derivatives=True, one=True) -> ca.Function:
        """The contract function name of ins -> outs, the contact search's frozen symbols put back (resolve).
        With several contacts per wheel it first runs the searches, then evaluates one of two forms of outs: where
        every wheel has one maximum, outs with the searches' other results put in as the constants they then are
        (rim.ONE_MAXIMUM: the absent contacts and the saddles fold away, the same arithmetic on what remains, a
        fraction of the work); otherwise the full form. one=False: the full form alone (the tests' reference)."""
        if not (self._frozen and one):
            return _function(name, ins, self.resolve(outs, derivatives))
        body = self.terrain.resolve(outs, derivatives)
        frozen = ca.vertcat(*[s for s, _ in self._frozen])
        full = _function(f"{name}_all", ins + [frozen], body)
        single = _function(f"{name}_one", ins + [frozen], ca.substitute(body, [s for s, _ in self._one],
                                                                        [ca.SX(v) for _, v in self._one]))
        value = {id(s): e for s, e in self._frozen}
        flag = 1
        for s, v in self._one:
            flag = ca.logic_and(flag, value[id(s)] == v)
        search = _function(f"{name}_search", [self.q, self.inp, self.par],
                           [ca.vertcat(*[e for _, e in self._frozen]), flag])
        mx = [ca.MX.sym(f"i{k}", x.sparsity()) for k, x in enumerate(ins)]
        arg = {id(x): m for x, m in zip(ins, mx)}
        r, flag = search(arg[id(self.q)], arg[id(self.inp)], arg[id(self.par)])
        out = ca.Function.if_else(f"{name}_forms", single, full)(flag, *mx, r)
        return ca.Function(name, mx, out if isinstance(out, (list, tuple)) else [out])

    def rate(self, expr):
        return ca.jtimes(expr, self.q, self.u)

    @cached_property
    def planar_twins(self) -> dict[int, int]:
        """2D: wheel -> the wheel whose spin it shares (the rover kind's planar map of the spins; CEDRA: 3 -> 1,
        4 -> 2): the two meet a terrain constant in Y alike."""
        return {int(a[5:]): int(b[5:]) for a, b in self.kind.planar.items() if a.startswith("gamma") and b}

    def _chassis_contacts(self) -> list[dict]:
        """The collision points of the body and links (docs/model.md, Chassis and links): each point below the
        terrain gets the compliant law with delta = g n_Z, the terrain's normal under it and the point's own
        velocity; in 2D one point stands for its twins across the rover (planar_weight). Rigid scenes: each point is
        a contact of the glue's constrained solve like a wheel's (its frame's x along the rover's heading), its
        force (the twins' together in 2D) the solve's."""
        p, i_ = self.p, self.i
        planar = self.opt.dims == "2d"
        yaw = self.qf[self.idx["yaw"]]
        lateral = ca.vertcat(-ca.sin(yaw), ca.cos(yaw), 0)     # the frame's "axle": x = unit(lateral x n), forward
        out = []
        for pt in self.rover.collision_points:
            weight = pt.planar_weight if planar else 1
            if weight == 0:
                continue
            pos = pt.position
            n, depth = point_penetration(self.terrain, pos)
            v = self.rate(pos)
            if self.rigid:
                lam = self._rigid_contact(contact_frame(lateral, n).T @ v, -depth)["lam"]
                out.append(dict(link=pt.link, weight=1, depth=depth, Fn=lam[2], v_n=ca.dot(v, n)))
                continue
            Fn, Ft, v_n, _ = compliant_law(depth, n, v, p["ground_k"], p["ground_d"], i_["mu"], p["v_eps"],
                                           self.contact_width)
            out.append(dict(link=pt.link, weight=weight, depth=depth, Fn=Fn, v_n=v_n,
                            Q=ca.jacobian(v, self.u).T @ (weight * (Fn * n + Ft))))
        return out

    @cached_property
    def chassis_force(self):
        """The collision points' generalized force (cedra_fc): kept out of Kane's f, so that the FMU evaluates it
        only while a point touches (cedra_cgap > 0); elsewhere it and its Jacobian are exactly zero."""
        n = self.q.numel()
        return sum((c["Q"] for c in self.chassis), ca.SX.zeros(n, 1))

    @cached_property
    def chassis_depth(self):
        """The deepest collision point's penetration g n_Z (cedra_cgap; > 0 while a point touches)."""
        return ca.mmax(ca.vertcat(*[c["depth"] for c in self.chassis]))

    @property
    def multi_contact(self) -> bool:
        """Several contacts per wheel (docs/model.md, Several contacts per wheel): a curved terrain, analytic or the
        heightmap, compliant or rigid (symbolic_rim aside: the tests' reference of the single-contact search).
        Planar terrain has one contact exactly."""
        return not self.terrain.planar and not self.symbolic_rim

    @property
    def rim_refine(self) -> bool:
        """The rim search samples every arc near touching again (fmu_src/rim.c, RIM_BAND): on a heightmap, whose
        spline has features narrower than an arc, and in 3D, where a wheel meets an edge obliquely and sees the
        edge and the tread as two maxima within one arc. A planar scene's wheel meets the terrain's features
        square on, where the 13 samples find every maximum (the exhaustive search agrees on the shipped runs)."""
        return self.opt.dims == "3d" or self.terrain.kind.name == "heightmap"

    def _rigid_contact(self, frame_velocity, gap) -> dict:
        """A contact of the rigid model: its force is a symbol the glue's solve fills (lam: Fx, Fy, Fn in the
        contact frame); vc, the contact frame's velocity components, and gap go to cedra_contact."""
        lam = ca.SX.sym(f"lam{len(self.rigid_contacts)}", 3)
        c = dict(vc=frame_velocity, gap=gap, lam=lam)
        self.rigid_contacts.append(c)
        return c

    def _wheel_contact(self, wh) -> dict:
        """A wheel's contacts, their forces added to Kane's equations (rigid: symbols the glue's solve fills, added
        by the glue as W' lambda), and the wheel's totals in the per-wheel
        outputs' meaning (docs/model.md, Several contacts per wheel, item 4): the total force along the frame of n_eff = unit(sum F_n,k n_k)
        (the deepest contact's normal while the wheel carries no force), the point the normal-force-weighted mean
        of the contact points (the deepest point while no force)."""
        p, i_ = self.p, self.i
        # velocity of the wheel's material point at a free point, then the contact point put in: the partial
        # velocities never differentiate through the contact search (the heightmap terrain's derivative chain is
        # finite, see terrain.Terrain)
        at = ca.SX.sym("p_contact", 3)
        v_at = wh.velocity + ca.cross(wh.omega, at - wh.center)
        if self.multi_contact:
            # 2D: the terrain is constant in Y and a wheel and its planar twin differ only in y (CEDRA's 3 and 4
            # are 1's and 2's), so they meet it exactly alike: one search for the pair
            search = self._searches.get(self.planar_twins.get(wh.index)) if self.opt.dims == "2d" else None
            if search is None:
                if self._rim_search is None:
                    self._rim_search = rim.search_external(self.terrain, self.rim_refine)
                search = self._rim_search(rim.search_input(wh.center, wh.axle, p["R_w"], self.terrain))
            self._searches[wh.index] = search
            geos, present = rim_contacts(wh.center, wh.axle, self.terrain, p["R_w"], search, self._freeze)
            # rim_contacts froze the search's results last, in their order
            self._one += [(self._frozen[k - rim.N_RESULT][0], v) for k, v in rim.ONE_MAXIMUM.items()]
        else:
            geos, present = [contact_geometry(wh.center, wh.axle, self.terrain, p["R_w"])], [1]
        parts = []
        for geo, pres in zip(geos, present):
            v_point = ca.substitute(v_at, at, geo.point)
            vc = geo.frame.T @ v_point                      # contact-frame components (x, y, n)
            part = dict(geo=geo, present=pres, v_point=v_point, vc=vc, v_n=ca.dot(v_point, geo.normal))
            if self.rigid:
                # a slot without a maximum is never in contact (gap 1 m); the glue's solve gives the force
                lam = self._rigid_contact(vc, ca.if_else(pres, -geo.depth, 1.0))["lam"]
                part |= dict(force=geo.frame @ lam, Fn=lam[2], Fx=lam[0], Fy=lam[1], slip=ca.norm_2(vc[0:2]))
            else:
                force, Fn, Fx, Fy, slip, _ = compliant_force(geo, v_point, p["ground_k"], p["ground_d"], i_["mu"],
                                                           p["v_eps"], self.contact_width)
                self.kane.add_point_force(v_point, force, ca.substitute(ca.jacobian(v_at, self.u), at, geo.point))
                part |= dict(force=force, Fn=Fn, Fx=Fx, Fy=Fy, slip=slip)
            parts.append(part)
        if len(parts) == 1:
            c = parts[0]
            geo = c["geo"]
            return dict(geo=geo, Fn=c["Fn"], Fx=c["Fx"], Fy=c["Fy"], slip=c["slip"], flag=geo.depth > 0,
                        force=c["force"], v_n=c["v_n"], parts=parts, wheel=wh)
        depths = [c["geo"].depth for c in parts]
        deepest = [1] + [0] * (len(parts) - 1)          # one-hot of the deepest contact (the first on ties)
        for k in range(1, len(parts)):
            deeper = depths[k] > ca.mmax(ca.vertcat(*depths[:k]))
            deepest = [ca.if_else(deeper, int(j == k), d) for j, d in enumerate(deepest)]

        def pick(vals):
            return sum(d * v for d, v in zip(deepest, vals))
        fn_sum = sum(c["Fn"] for c in parts)
        fn_vec = sum(c["Fn"] * c["geo"].normal for c in parts)
        fn_norm = ca.norm_2(fn_vec)
        # carried: the force has a direction. The forces are >= 0, so a nonzero norm means a positive sum; not the
        # sum's sign, because a smoothed law's lifted wheel has forces so small (1e-160 N) that their squares, and
        # the norm, underflow to 0 while their sum does not
        carried = fn_norm > 0
        n_eff = ca.if_else(carried, fn_vec / ca.if_else(carried, fn_norm, 1), pick([c["geo"].normal for c in parts]))
        weight = [ca.if_else(carried, c["Fn"] / ca.if_else(carried, fn_sum, 1), d) for c, d in zip(parts, deepest)]
        point = sum(w * c["geo"].point for w, c in zip(weight, parts))
        frame = contact_frame(wh.axle, n_eff)
        depth = ca.mmax(ca.vertcat(*depths))
        geo = ContactGeometry(point, n_eff, frame, depth, slope_angle(wh.axle, n_eff))
        force = sum(c["force"] for c in parts)
        return dict(geo=geo, Fn=ca.dot(force, n_eff), Fx=ca.dot(force, frame[:, 0]), Fy=ca.dot(force, frame[:, 1]),
                    slip=sum(w * c["slip"] for w, c in zip(weight, parts)), flag=depth > 0, force=force,
                    parts=parts, wheel=wh)

    def applied_torques(self, tau_cmd):
        """The torques on the six wheels: the commands themselves, or (drives) each command through its wheel's
        motor envelope at that wheel's own spin rate relative to its carrier. In 2D wheels 1, 3 (and 2, 4) share
        one spin coordinate, so they share omega, but each keeps its own command."""
        if not self.opt.drives:
            return tau_cmd
        omega = self.rate(self.qf)
        p = self.p
        return [drive_torque(tau_cmd[k], omega[self.idx[f"gamma{k + 1}"]], p["drive_stall_torque"],
                             p["drive_noload_speed"], p["drive_viscous"]) for k in range(6)]

    # ---------------- the contract's functions ----------------
    @cached_property
    def settle_idx(self) -> list[int]:
        return [self.q_names.index(n) for n in self.kind.settle if n in self.q_names]

    def outputs(self) -> list[tuple[Quantity, ca.SX]]:
        o, qf, qd = [], self.qf, self.rate(self.qf)
        planar = self.opt.dims == "2d"
        pose = [("x", "m"), ("y", "m"), ("z", "m"), ("yaw", "rad"), ("pitch", "rad"), ("roll", "rad")]
        for name, unit in pose:
            if not (planar and name in ("y", "yaw", "roll")):
                o.append((_out(f"body.{name}", unit, f"body pose: {name} (mass center, ZYX Euler)"),
                          qf[self.idx[name]]))
        v, w = self.rover.body_velocity, self.rover.body_omega
        for k, axis in enumerate("xyz"):
            if not (planar and axis == "y"):
                o.append((_out(f"body.v{axis}", "m/s", f"body velocity along world {axis.upper()}"), v[k]))
        for k, axis in enumerate("xyz"):
            if not (planar and axis in "xz"):
                o.append((_out(f"body.w{axis}", "rad/s", f"body angular velocity about world {axis.upper()}"), w[k]))
        o += self.kind.joint_outputs(qf, qd, self.idx, self.rover, self.opt.steering)
        for wh, c in zip(self.rover.wheels, self.contacts):
            k = wh.index
            geo = c["geo"]
            o += [
                (_out(f"wheel[{k}].omega", "rad/s", f"wheel {k} spin rate"), qd[self.idx[f"gamma{k}"]]),
            ]
            if self.opt.drives:     # without drives it would only repeat the input tau[k]
                o.append((_out(f"wheel[{k}].tau", "N.m", f"wheel {k} torque applied by its drive (tau[{k}] "
                                                         "clipped to the motor envelope, minus the gear loss)"),
                          self.tau[k - 1]))
            o += [
                (_out(f"wheel[{k}].Fn", "N", f"wheel {k} normal contact force"), c["Fn"]),
                (_out(f"wheel[{k}].Fx", "N", f"wheel {k} longitudinal contact force (contact frame x)"), c["Fx"]),
                (_out(f"wheel[{k}].Fy", "N", f"wheel {k} lateral contact force (contact frame y)"), c["Fy"]),
                (_out(f"wheel[{k}].mode", "1", f"wheel {k} contact mode: 0 airborne, 1 stick, 2 slip" if self.rigid
                  else f"wheel {k} contact mode: 0 airborne, 2 in contact", "Integer"),
                 ca.if_else(c["flag"], 2, 0)),
            ]
            if self.rigid:     # a rigid contact touches at delta = 0: the ones that carry force
                o.append((_out(f"wheel[{k}].contacts", "1", f"wheel {k} contacts carrying a normal force",
                               "Integer"), sum(ca.if_else(c2["Fn"] > 0, 1, 0) for c2 in c["parts"])))
            else:
                o.append((_out(f"wheel[{k}].contacts", "1", f"wheel {k} contacts touching the terrain (delta_k > 0)",
                               "Integer"), sum(ca.if_else(c2["geo"].depth > 0, 1, 0) for c2 in c["parts"])))
            if len(c["parts"]) > 1:
                o += self._contact_outputs(k, c["parts"])
            for j, axis in enumerate("xyz"):
                o.append((_out(f"wheel[{k}].c{axis}", "m", f"wheel {k} center, world {axis.upper()}"), wh.center[j]))
            for j, axis in enumerate("xyz"):
                o.append((_out(f"wheel[{k}].p{axis}", "m", f"wheel {k} contact point, world {axis.upper()}"),
                          geo.point[j]))
            o.append((_out(f"wheel[{k}].psi", "rad", f"wheel {k} contact slope angle"), geo.slope))
            o.append((_out(f"wheel[{k}].slip", "m/s", f"wheel {k} slip speed at the contact"), c["slip"]))
            o += self._kinematic_outputs(wh, geo)
            if self.rigid:
                o.append((_out(f"wheel[{k}].gap", "m", f"wheel {k} rim height above the terrain (negative: "
                                                         "penetration; in contact: the constraint drift)"),
                          -geo.depth))
                # an impact is an impulse: what a rigid contact transmits over an interval converges with the
                # motion, its force at one instant does not (the glue integrates the forces and adds the impacts)
                for comp, what in (("Fn", "normal"), ("Fx", "longitudinal"), ("Fy", "lateral")):
                    o.append((_out(f"wheel[{k}].{comp}_mean", "N",
                                   f"wheel {k} {what} contact force averaged over the last communication step "
                                   "(impulse / step, impacts included; at the start: the force there)"), 0))
        if self.chassis:
            o.append((_out("chassis.clearance", "m", "the body's and links' smallest height above the terrain over "
                           "their collision points (-g n_Z; negative while touching)"), -self.chassis_depth))
            o.append((_out("chassis.Fn", "N", "the sum of the normal forces on the body's and links' collision "
                           "points"), sum(c["weight"] * c["Fn"] for c in self.chassis)))
        return o

    def _contact_outputs(self, k, parts):
        """Per contact j = 1..3 of wheel k, ordered by beta (docs/model.md, Several contacts per wheel, item 4): its normal force, slope and
        point; 0 where the slot holds no maximum of g."""
        o = []
        for j, c in enumerate(parts, start=1):
            pres, geo = c["present"], c["geo"]
            o += [(_out(f"wheel[{k}].contact[{j}].Fn", "N", f"wheel {k} contact {j}: normal force"), c["Fn"]),
                  (_out(f"wheel[{k}].contact[{j}].psi", "rad", f"wheel {k} contact {j}: slope angle"),
                   ca.if_else(pres, geo.slope, 0)),
                  (_out(f"wheel[{k}].contact[{j}].px", "m", f"wheel {k} contact {j}: point, world X"),
                   ca.if_else(pres, geo.point[0], 0)),
                  (_out(f"wheel[{k}].contact[{j}].pz", "m", f"wheel {k} contact {j}: point, world Z"),
                   ca.if_else(pres, geo.point[2], 0))]
        return o

    def _kinematic_outputs(self, wh, geo):
        """What the paper's inverse kinematics and steering (kinematics.py, the controller FMU) measure at wheel k,
        in their conventions: the contact angle psi_i measured in the rover frame R (the contact normal's angle
        about the axle from the wheel's psi = 0 normal, positive by the right-hand rule about the axle), its rate,
        and the rotational slip angle xi_i (the direction of the wheel center's travel in the contact plane,
        from the wheel's heading x_C: atan(v_y / v_x), smoothly 0 below XI_SPEED so a wheel at rest reads 0)."""
        k, n = wh.index, geo.normal
        psi_r = ca.atan2(ca.dot(ca.cross(wh.up, n), wh.axle), ca.dot(wh.up, n))
        vc = geo.frame.T @ wh.velocity
        xi = ca.atan(vc[1] * vc[0] / (vc[0] ** 2 + XI_SPEED ** 2))
        return [(_out(f"wheel[{k}].psi_R", "rad", f"wheel {k} contact angle psi_{k} in the rover frame (the paper's "
                      "Eqs. 9-22)"), psi_r),
                (_out(f"wheel[{k}].psi_R_rate", "rad/s", f"wheel {k} rate of the contact angle psi_R"),
                 self.rate(psi_r)),
                (_out(f"wheel[{k}].xi", "rad", f"wheel {k} rotational slip angle xi_{k}: the center's direction of "
                      "travel in the contact plane from the wheel's heading"), xi)]

    # ---------------- force-law switches ----------------
    @cached_property
    def switches(self):
        """The switching functions of the compliant model's force laws: (s, hold, hold_now, names). Each s_i is
        continuous in the state and changes sign exactly where a force law switches; the FMU's adaptive solvers cut
        a step whose s changes sign at the crossing (model_glue.c), so no step integrates across a discontinuity.

        - contact onset / lift-off: delta_i (the law jumps by d |v_n| at touchdown);
        - the normal force's clip max(0, k delta - d v_n): min(k delta - d v_n, k delta), which has the clip's sign
          in contact and is negative off the ground (no false switches in the air);
        - joint stops: angle - limit for each stop, and the clip of the stop torque (it only pushes out):
          max(-k (a - hi) - d rate, k (hi - a)) above, min(-k (a - lo) - d rate, k (lo - a)) below, which again
          carry the clip's sign only beyond their stop;
        - drives (docs/model.md, Drives): the command against both edges of the motor envelope;
        - chassis and links: each collision point's penetration (its touchdown; docs/model.md, Chassis and links);
        - several contacts per wheel (docs/model.md, Several contacts per wheel): the contact switch is the
          wheel's deepest penetration, and each contact has its own clip. The contact search makes discrete
          choices (which samples start Newton), but the shared penetration keeps each wheel's force continuous
          through them: no switch there.
        Rigid scenes have none: their decision tree holds its modes over a step and locates touch-downs itself."""
        if self.rigid:
            return [], [], [], []
        p, qf, qd = self.p, self.qf, self.rate(self.qf)
        s, names, hold, hold_now = [], [], [], []
        for c in self.contacts:
            k = c["wheel"].index
            s.append(c["geo"].depth)                        # the wheel's deepest contact
            names.append(f"wheel[{k}] contact")
            several = len(c["parts"]) > 1
            for j, part in enumerate(c["parts"], start=1):
                d = part["geo"].depth
                s.append(ca.fmin(p["ground_k"] * d - p["ground_d"] * part["v_n"], p["ground_k"] * d))
                names.append(f"wheel[{k}] contact[{j}] normal-force clip" if several
                             else f"wheel[{k}] normal-force clip")
        for j, c in enumerate(self.chassis, start=1):        # a collision point's touchdown and its clip
            d = c["depth"]
            s += [d, ca.fmin(p["ground_k"] * d - p["ground_d"] * c["v_n"], p["ground_k"] * d)]
            names += [f"chassis point {j} ({c['link']}) contact", f"chassis point {j} ({c['link']}) normal-force clip"]
        for stop in self.kind.stops:
            name = stop.coordinate
            if name not in self.q_names:       # 2D: a joint that moves with another (CEDRA's theta2 is theta1)
                continue
            lo, hi = stop.limits(p)
            a, rate, k, dd = qf[self.idx[name]], qd[self.idx[name]], p["stop_k"], p["stop_d"]
            s += [a - hi, ca.fmax(-k * (a - hi) - dd * rate, k * (hi - a)),
                  a - lo, ca.fmin(-k * (a - lo) - dd * rate, k * (lo - a))]
            names += [f"{name} upper stop", f"{name} upper stop clip", f"{name} lower stop",
                      f"{name} lower stop clip"]
        if self.opt.drives:
            for k in range(6):
                w = qd[self.idx[f"gamma{k + 1}"]]
                cmd = self.i.get(f"tau[{k + 1}]", 0)
                T, w0 = p["drive_stall_torque"], p["drive_noload_speed"]
                s += [T * (1 - w / w0) - cmd, cmd + T * (1 + w / w0)]
                names += [f"wheel[{k + 1}] drive upper edge", f"wheel[{k + 1}] drive lower edge"]
        return s, hold, hold_now, names

    @property
    def has_parts(self) -> bool:
        """Whether cedra_f, cedra_rjac (and cedra_fc, cedra_fcjac) are composed from parts (cedra.models.parts): the
        FMU's compliant law (the rigid model's contact forces are the glue's; the optimizer's smoothed law and the
        symbolic search are reference forms)."""
        return not self.rigid and self.contact_width is None and not self.symbolic_rim

    def functions(self, one=True, parts=True) -> dict[str, ca.Function]:
        """The contract's functions; one=False: without the one-maximum form (_contract); parts=False: cedra_f,
        cedra_rjac, cedra_fc and cedra_fcjac in the monolithic form (the reference the parts are tested against).
        Where the parts serve, their monolithic forms are not formed at all (their Jacobians are the costly part
        of forming a scene)."""
        q, u, par, inp = self.q, self.u, self.par, self.inp
        composed = self.parts.functions() if parts and self.has_parts else {}
        n = q.numel()
        z = ca.SX.sym("z", 1)
        a = ca.SX.sym("a", n)
        outs = self.outputs()
        y = ca.vertcat(*[e for _, e in outs[:]],
                       self.kinetic, self.potential, z[0])
        sidx = self.settle_idx
        fns = {}
        if "cedra_settle" not in composed:      # the parts compose their own (ModelParts._settle)
            if self.rigid:
                # On rigid ground the pose is fixed by geometry alone: every wheel touches (gap = 0). As many
                # distinct wheels as settle unknowns (2D: wheels 3, 4 coincide with 1, 2); the glue's constrained
                # solve then gives the contact forces.
                wheels = [k for k in range(1, 7) if self.opt.dims == "3d" or k not in self.planar_twins]
                res = ca.vertcat(*[-self.contacts[k - 1]["geo"].depth for k in wheels])
            else:
                res = ca.substitute(self.f + self.chassis_force, u, ca.DM.zeros(n))[sidx]
            fns["cedra_settle"] = self._contract("cedra_settle", [q, inp, par], [res, ca.jacobian(res, q)[:, sidx]],
                                                 True, one)
        res_ = self.resolve      # the contact search's frozen symbols, a heightmap's contact points
        if self.rigid:
            vc = ca.vertcat(*[c["vc"] for c in self.rigid_contacts])
            W = ca.jacobian(vc, u)
            fns["cedra_contact"] = self._contract("cedra_contact", [q, u, inp, par], [
                W, ca.jtimes(vc, q, u), vc, ca.vertcat(*[c["gap"] for c in self.rigid_contacts])], True, one)
        sw, hold, hold_now, _ = self.switches
        if sw:
            hv = ca.vertcat(*hold) if hold else ca.SX(0, 1)
            fns["cedra_switch"] = self._contract("cedra_switch", [q, u, inp, par, hv], [
                ca.vertcat(*sw), ca.vertcat(*hold_now) if hold else ca.SX(0, 1)], False, one)
        if self.chassis and not self.rigid:
            Qc = self.chassis_force
            fns["cedra_cgap"] = _function("cedra_cgap", [q, inp, par], res_([self.chassis_depth], derivatives=False))
            if "cedra_fc" not in composed:
                fns["cedra_fc"] = _function("cedra_fc", [q, u, inp, par], res_([Qc], derivatives=False))
                fns["cedra_fcjac"] = _function("cedra_fcjac", [q, u, inp, par],
                                               res_([ca.jacobian(Qc, q), ca.jacobian(Qc, u)]))
        if "cedra_f" not in composed:
            r = self.M @ a - self.f
            fns["cedra_f"] = self._contract("cedra_f", [q, u, inp, par], [self.f, self.power], False, one)
            fns["cedra_rjac"] = self._contract("cedra_rjac", [q, u, a, inp, par],
                                               [ca.jacobian(r, q), ca.jacobian(r, u),
                                                ca.jacobian(self.power, q), ca.jacobian(self.power, u)], True, one)
        return fns | {
            "cedra_M": _function("cedra_M", [q, par], [self.M]),
            "cedra_out": self._contract("cedra_out", [q, u, z, inp, par] + ([self.lam] if self.rigid else []), [y],
                                        True, one),
            "cedra_guess": _function("cedra_guess", [q, inp, par], [self.guess()]),
            "cedra_check": _function("cedra_check", [q, u, inp, par], [self.check()]),
        } | terrain_functions(self.terrain) | composed

    @cached_property
    def parts(self):
        from cedra.models.parts import ModelParts
        return ModelParts(self)

    def work_description(self):
        if not self.opt.drives:
            return "work done by the motor torques since the start"
        return ("work done by the motor torques since the start: of the applied torques wheel[i].tau (after the "
                "envelope, so the gear's viscous loss is in it), times the wheels' spin rates relative to their "
                "carriers")

    def check(self):
        """cedra_check's code (contract.CHECK_REASONS): 1 inside the domain, -1 four-bar toggle, -2 tipped over.
        Beyond 80 deg of pitch or roll the body would be lying on the ground, which the model does not know (and
        3D pitch reaches the ZYX Euler singularity at 90 deg): the FMU stops there loudly instead of grinding."""
        tilt = ca.fmax(ca.fabs(self.qf[self.idx["pitch"]]), ca.fabs(self.qf[self.idx["roll"]]))
        return ca.if_else(ca.fabs(self.rover.closure) >= 1, -1, ca.if_else(tilt > 80 * ca.pi / 180, -2, 1))

    def guess(self):
        """A pose in contact with the terrain under (x, y) for the settle Newton: body level with the terrain's
        slope under it, bogies and fork at their design angles, every wheel at least 1 mm into the ground."""
        q, p, names = self.q, self.p, self.q_names
        x = q[names.index("x")]
        y = q[names.index("y")] if "y" in names else 0
        yaw = q[names.index("yaw")] if "yaw" in names else 0
        h = self.terrain.height(x, y)
        n = self.terrain.normal(x, y)
        fwd = ca.vertcat(ca.cos(yaw), ca.sin(yaw), 0)
        left = ca.vertcat(-ca.sin(yaw), ca.cos(yaw), 0)
        pitch = ca.atan2(ca.dot(n, fwd), n[2])          # positive pitch = nose down (the terrain descends ahead)
        roll = ca.atan2(-ca.dot(n, left), n[2])
        design = self.kind.design(p)
        height = design["z"] / ca.cos(pitch) / ca.cos(roll)
        values = {"z": h + height - 1e-3, "pitch": pitch, "roll": roll} | {n: v for n, v in design.items() if n != "z"}
        level = ca.vertcat(*[values[nm] if nm in values else q[k] for k, nm in enumerate(names)])
        if self.terrain.planar:
            return level
        # on curved ground some wheels of the level pose hang in the air, where the equilibrium Jacobian has no
        # stiffness (singular): lower the pose until the highest wheel is 1 mm into the ground too
        depths = self.resolve([ca.vertcat(*[c["geo"].depth for c in self.contacts])], derivatives=False)[0]
        depths = ca.substitute(depths, q, level)
        lower = ca.fmax(0, 1e-3 - ca.mmin(depths))
        return ca.vertcat(*[level[k] - lower if nm == "z" else level[k] for k, nm in enumerate(names)])

    def spec(self, name: str, description: str = "", **kw) -> ModelSpec:
        if self.contact_width is not None:
            raise ValueError("the smoothed contact law is the optimizer's; an FMU integrates the compliant law itself")
        outs = [qq for qq, _ in self.outputs()] + [
            _out("energy.kinetic", "J", "kinetic energy"),
            _out("energy.potential", "J",
                 "potential energy: gravity (datum Z = 0), fork spring, stops, servo springs, ground springs"),
            _out("energy.work", "J", self.work_description())]
        design = self.kind.design({q.name: q.start for q in self.kind.parameters})
        q_start = [float(design.get(n, 0.0)) for n in self.q_names]
        return ModelSpec(name=name, description=description or f"CEDRA rover, {self.opt}",
                         q_names=list(self.q_names), z_names=["work"], params=list(self.params),
                         inputs=list(self.inputs), outputs=outs, q_start=q_start, settle_idx=self.settle_idx,
                         start_params={f"start.{n}": k for k, n in enumerate(self.q_names)},
                         functions=LazyFunctions(lambda: self._num), contact=self.opt.contact,
                         n_contacts=len(self.rigid_contacts),
                         contacts_per_wheel=len(self.contacts[0]["parts"]) if self.rigid else 0,
                         heightmap_file=self.opt.heightmap, rim_refine=self.rim_refine,
                         switch_names=list(self.switches[3]), n_hold=len(self.switches[1]),
                         chassis=bool(self.chassis) and not self.rigid,   # rigid: contacts of cedra_contact
                         **self._parts_spec(), **kw)

    @cached_property
    def chassis_groups(self):
        """The collision points grouped by the body they are fixed in (cedra.models.parts.point_groups)."""
        from cedra.models.parts import point_groups
        return point_groups(self)

    def _parts_spec(self) -> dict:
        """ModelSpec's part_names, parts and compose where the parts serve (cedra.models.parts), formed on use."""
        if not self.has_parts:
            return {}
        from cedra.models.parts import part_names
        return dict(part_names=part_names(self.multi_contact, [g.name for g in self.chassis_groups] if self.chassis else []),
                    parts=LazyFunctions(lambda: self.parts.part_functions),
                    compose=lambda replacements: self.parts.functions(replacements))

    # ---------------- numeric helpers (tests, reference solutions) ----------------
    @cached_property
    def _num(self):
        """The contract's functions, built once per model (spec() and the numeric helpers share them)."""
        return self.functions()

    def default_par(self, **overrides) -> np.ndarray:
        unknown = set(overrides) - {p.name for p in self.params}
        if unknown:
            raise KeyError(f"unknown parameters {sorted(unknown)}")
        return np.array([overrides.get(p.name, p.start) for p in self.params])

    def default_inp(self, **overrides) -> np.ndarray:
        unknown = set(overrides) - {p.name for p in self.inputs}
        if unknown:
            raise KeyError(f"unknown inputs {sorted(unknown)}")
        return np.array([overrides.get(p.name, p.start) for p in self.inputs])

    def udot(self, q, u, inp, par) -> np.ndarray:
        M = np.array(self._num["cedra_M"](q, par))
        f = np.array(self._num["cedra_f"](q, u, inp, par)[0]).ravel()
        if self.rigid:
            raise ValueError("udot: rigid contact's accelerations come from the glue's constrained solve")
        if self.chassis:
            f = f + np.array(self._num["cedra_fc"](q, u, inp, par)).ravel()
        return np.linalg.solve(M, f)
