"""Contact modes for hybrid multiple shooting (`method = "hybrid"`, docs/optimize.md): the force laws that switch,
each law's mode (on or off), the equations of a mode, and the events of a run.

Every switching law of the planar compliant scene is a unilateral compliant law with a penetration delta and a
rate v (the material point's normal velocity: delta' = -v in contact), stiffness k and damping d:

    force  = max(0, k delta - d v) where delta > 0, else 0          (the FMU's law, cedra.mechanics.contact)
    on     <=> delta >= 0 and delta - (d / k) v >= 0                (the model's switch min(k delta - d v, k delta))
    mode law: force = k delta - d v when on, 0 when off             (no clip, no onset: smooth in the state)

A wheel's contact slot is one such law (the contact's depth and its point's normal velocity), and so is each side
of a joint stop (delta the angle beyond the stop, v minus its rate towards it; the torque k delta - d v pushing
back). In a mode whose on-set holds, the mode law is the FMU's law exactly; beyond it the mode law continues
smoothly, so a phase's map and its sensitivities are smooth in the decisions even where a trial point crosses a
guard. A law's two branches, in metres (a stop's times R_w, as the smoothed law's width is), are its guards: the
depth branch delta is zero at a touch-down, the force branch delta - (d / k) v at a clip (a lift-off that leaves
the point still inside the ground, the usual way a damped contact opens). At an event the law's indicator
min(depth, force) crosses zero on one of its branches.

HybridSystem holds what the transcription needs from any such system (the rover's, or a test's dropped wheel):
the mode equations as CasADi expressions, the branches, and from them the time-scaled phase integrators, the
guards' rates and a hybrid simulation that locates every event (simulate). RoverHybrid is the planar rover's."""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from cedra.models.scene import load_shipped
from cedra.optimize.dynamics import PAIRS, _compiled
from cedra.optimize.problem import Problem, ProblemError

DEPTH, FORCE = 0, 1          # a law's branches: its penetration, its normal law / k (both in m)
BRANCH_NAMES = ("penetration", "normal law")
LOCATE_TOL = 1e-12           # s: an event's time from the bisection on its indicator


@dataclass(frozen=True)
class Event:
    """A law switching at `time`: it turns `on` (or off) on `branch`; rate: the branch's time derivative there
    (m/s; its sign is the crossing's), interval: the control interval it falls in."""
    law: int
    branch: int
    on: bool
    time: float
    rate: float
    interval: int

    def key(self) -> tuple:
        """What the mode sequence depends on (not the time inside the interval)."""
        return (self.interval, self.law, self.branch, self.on)


@dataclass
class Run:
    """A hybrid simulation: the events in order, the state at each event (columns, model states of the system),
    each interval's end state, and the mode at the start."""
    events: list[Event]
    event_states: list[np.ndarray]
    ends: np.ndarray
    start_mode: tuple
    laws: list[str] = field(default_factory=list)

    def describe(self, e: Event) -> str:
        return (f"{self.laws[e.law]} {'on' if e.on else 'off'} at t = {e.time:.6f} s ({BRANCH_NAMES[e.branch]} "
                f"zero, rate {e.rate:.3g} m/s)")


class HybridSystem:
    """A system with switching unilateral laws. A subclass sets nx, nu, laws (names) and implements ode(x, u, on)
    (on: a DM of 0/1, one per law) and branches(x) -> (depth, force) as CasADi expressions (MX) of x."""

    nx: int
    nu: int
    laws: list[str]
    tol: float = 1e-8

    def ode(self, x, u, on):
        raise NotImplementedError

    def branches(self, x):
        raise NotImplementedError

    # ---------------- from the above ----------------
    def _sym(self):
        return ca.MX.sym("x", self.nx), ca.MX.sym("u", self.nu), ca.MX.sym("h")

    def integrator(self, on, n_out: int = 1, tol: float | None = None) -> ca.Function:
        """One phase in mode `on`: dx/ds = h ode(x, u, on) over s in [0, 1] from x0, p = [u; h] (the phase's
        duration h a decision: time-scaled), the states at n_out equally spaced points of the phase."""
        key = (tuple(int(b) for b in on), n_out, tol)
        cache = self.__dict__.setdefault("_integrators", {})
        if key not in cache:
            x, u, h = self._sym()
            tol = tol or self.tol
            ode = h * self.ode(x, u, ca.DM(list(key[0])))
            cache[key] = ca.integrator(f"phase_{len(cache)}", "cvodes", {"x": x, "p": ca.vertcat(u, h), "ode": ode},
                                       0, list(np.linspace(0, 1, n_out + 1)[1:]),
                                       {"abstol": tol, "reltol": tol, "max_num_steps": 200000,
                                        "fsens_err_con": False, "show_eval_warnings": False,
                                        "second_order_correction": False})
        return cache[key]

    def branch_function(self) -> ca.Function:
        """x -> (depth, force) branches of every law (m)."""
        if "_branch_fn" not in self.__dict__:
            x = ca.MX.sym("x", self.nx)
            dep, frc = self.branches(x)
            self._branch_fn = ca.Function("branches", [x], [dep, frc])
        return self._branch_fn

    def rate(self, x, u, on, law: int, branch: int):
        """The time derivative of law `law`'s `branch` at (x, u) in mode `on` (m/s)."""
        g = self.branches(x)[branch][law]
        return ca.jtimes(g, x, self.ode(x, u, ca.DM(list(on))))

    def rate_function(self, on, law: int, branch: int) -> ca.Function:
        key = (tuple(int(b) for b in on), law, branch)
        cache = self.__dict__.setdefault("_rates", {})
        if key not in cache:
            x, u = ca.MX.sym("x", self.nx), ca.MX.sym("u", self.nu)
            cache[key] = ca.Function("guard_rate", [x, u], [self.rate(x, u, on, law, branch)])
        return cache[key]

    def indicators(self, xs) -> tuple[np.ndarray, np.ndarray]:
        """(min(depth, force), argmin) of every law at states xs (columns): >= 0 where the law is on."""
        dep, frc = (np.array(v) for v in self.branch_function()(xs))
        return np.minimum(dep, frc), np.where(dep <= frc, DEPTH, FORCE)

    def mode_at(self, x) -> tuple:
        c, _ = self.indicators(np.asarray(x).reshape(-1, 1))
        return tuple(int(v >= 0) for v in c[:, 0])

    def simulate(self, starts: np.ndarray, U: np.ndarray, dt: float, resync: bool = True, n_fine: int = 100,
                 start_mode: tuple | None = None) -> Run:
        """The FMU's law integrated mode by mode over the control grid, every event located on its indicator.
        starts: the state at each node (columns; with resync every interval starts there, as a multiple-shooting
        guess does, else only the first); U: the torques (rows per interval). Inside an interval the phase is
        checked at n_fine points; an indicator whose sign leaves the mode's is bisected to LOCATE_TOL."""
        n = U.shape[0]
        x = np.asarray(starts[:, 0], float)
        on = start_mode or self.mode_at(x)
        first = on
        events, states, ends = [], [], []
        for k in range(n):
            if resync and k > 0:
                x = np.asarray(starts[:, k], float)
                # the node's own mode, except for a law exactly at its guard (where the previous interval's
                # ending mode holds)
                c, _ = self.indicators(x.reshape(-1, 1))
                on = tuple(int(c[i, 0] >= 0) if abs(c[i, 0]) > 1e-12 else on[i] for i in range(len(on)))
            t, left = k * dt, dt
            while True:
                F = self.integrator(on, n_fine)
                xs = np.array(F(x0=x, p=np.r_[U[k], left])["xf"])
                c, _ = self.indicators(xs)
                bad = np.array([[(c[i, j] >= 0) != bool(on[i]) for j in range(xs.shape[1])]
                                for i in range(len(on))])
                if not bad.any():
                    x = xs[:, -1]
                    break
                j = int(np.nonzero(bad.any(axis=0))[0][0])
                s_lo, s_hi = j / n_fine, (j + 1) / n_fine
                laws = [i for i in range(len(on)) if bad[i, j]]
                # the earliest of the laws that flip in this sub-step
                best = None
                for i in laws:
                    s = self._locate(x, U[k], left, on, i, s_lo, s_hi)
                    if best is None or s < best[0]:
                        best = (s, i)
                s, i = best
                F1 = self.integrator(on, 1)
                xe = np.array(F1(x0=x, p=np.r_[U[k], s * left])["xf"])[:, 0]
                dep, frc = (np.array(v)[i, 0] for v in self.branch_function()(xe))
                branch = DEPTH if abs(dep) <= abs(frc) else FORCE
                rate = float(self.rate_function(on, i, branch)(xe, U[k]))
                t += s * left
                left -= s * left
                new = list(on)
                new[i] = 1 - on[i]
                on = tuple(new)
                events.append(Event(i, branch, bool(on[i]), t, rate, k))
                states.append(xe)
                x = xe
            ends.append(x)
        return Run(events, states, np.array(ends).T, first, list(self.laws))

    def _locate(self, x, u, left, on, law, s_lo, s_hi) -> float:
        """The phase fraction where law `law`'s indicator leaves the mode `on`, between s_lo and s_hi."""
        F1 = self.integrator(on, 1)
        want = bool(on[law])

        def inside(s):
            if s <= 0:
                return True
            xe = np.array(F1(x0=x, p=np.r_[u, s * left])["xf"])
            return (self.indicators(xe)[0][law, 0] >= 0) == want
        while (s_hi - s_lo) * left > LOCATE_TOL:
            mid = 0.5 * (s_lo + s_hi)
            if inside(mid):
                s_lo = mid
            else:
                s_hi = mid
        return s_hi


class RoverHybrid(HybridSystem):
    """The planar compliant rover's mode equations on the shooting state of cedra.optimize.dynamics (the wheels'
    spin angles left out) and the four torque decisions. Laws: every distinct wheel's contact slots (the planar
    twins 3 and 4 share 1's and 2's modes, as they share their coordinates) and both sides of every joint stop of
    the scene's coordinates (CEDRA's theta2 shares theta1's).

    The mode's right-hand side is the model's own f with each switching law's FMU form replaced by its mode law:
    f_mode = f + sum_slots J' (F_mode - F) + P' (Q_mode - Q), J the slot point's partial velocity, P the
    coordinates' projection; the contact search's results enter as constants of differentiation, as in the
    model's Jacobians. It is generated to C with its first derivatives (cached under build/host/)."""

    def __init__(self, problem: Problem):
        from cedra.models.plant import CedraModel
        from cedra.rover.mechanism import stop_torque
        self.problem = problem
        self.scene = load_shipped(problem.scene)
        if self.scene.options.chassis:
            raise ProblemError(f"{problem.path}: key 'method': 'hybrid' is formed for scenes without chassis "
                               f"contact (scene {problem.scene} has collision points)")
        self.model = m = CedraModel(self.scene.options)
        self.tol = problem.integrator_tol
        self.par = m.default_par(**self.scene.parameters)
        self.inp = m.default_inp(**(self.scene.inputs | problem.inputs))
        self.nq = m.q.numel()
        self.kept = [k for k, nm in enumerate(m.q_names) if not nm.startswith("gamma")] + \
            list(range(self.nq, 2 * self.nq))
        self.nx, self.nu = len(self.kept), 4
        self.select = ca.DM.zeros(2 * self.nq, self.nx)
        for j, k in enumerate(self.kept):
            self.select[k, j] = 1
        p, u = m.p, m.u
        twins = m.planar_twins
        laws, slot = [], {}
        dep, vel, kk, dd, scale = [], [], [], [], []
        for c in m.contacts:
            w = c["wheel"].index
            if w in twins:
                continue
            for j, part in enumerate(c["parts"]):
                slot[(w, j)] = len(laws)
                laws.append(f"wheel[{w}] contact[{j + 1}]")
                dep.append(part["geo"].depth)
                vel.append(part["v_n"])
                kk.append(p["ground_k"])
                dd.append(p["ground_d"])
                scale.append(1.0)
        qf, qd = m.qf, m.rate(m.qf)
        stop_law = {}
        for stop in m.kind.stops:
            if stop.coordinate not in m.q_names:
                continue
            lo, hi = stop.limits(p)
            a, r = qf[m.idx[stop.coordinate]], qd[m.idx[stop.coordinate]]
            for side, delta, v in (("upper", a - hi, -r), ("lower", lo - a, r)):
                stop_law[(stop.coordinate, side)] = len(laws)
                laws.append(f"{stop.coordinate} {side} stop")
                dep.append(delta)
                vel.append(v)
                kk.append(p["stop_k"])
                dd.append(p["stop_d"])
                scale.append(p["R_w"])
        self.laws = laws
        L = len(laws)
        on = ca.SX.sym("on", L)
        df = ca.SX.zeros(self.nq)
        for c in m.contacts:
            base = twins.get(c["wheel"].index, c["wheel"].index)
            for j, part in enumerate(c["parts"]):
                i = slot[(base, j)]
                geo, vp = part["geo"], part["v_point"]
                vn = ca.dot(vp, geo.normal)
                vt = vp - vn * geo.normal
                fn = on[i] * (p["ground_k"] * geo.depth - p["ground_d"] * vn)
                force = fn * geo.normal - m.i["mu"] * fn * vt / ca.sqrt(ca.dot(vt, vt) + p["v_eps"] ** 2)
                df += ca.jacobian(vp, u).T @ (force - part["force"])
        dq = ca.SX.zeros(qf.numel())
        for stop in m.kind.stops:
            row = m.idx[stop.coordinate]
            base = m.q_names[int(np.argmax(m.P[row]))]     # the scene coordinate this joint moves with
            lo, hi = stop.limits(p)
            a, r = qf[row], qd[row]
            up, low = stop_law[(base, "upper")], stop_law[(base, "lower")]
            mode = on[up] * (-p["stop_k"] * (a - hi) - p["stop_d"] * r) + \
                on[low] * (-p["stop_k"] * (a - lo) - p["stop_d"] * r)
            dq[row] = mode - stop_torque(a, r, lo, hi, p["stop_k"], p["stop_d"])
        df += ca.DM(m.P).T @ dq
        x = ca.vertcat(m.q, m.u)
        ode = ca.vertcat(m.u, ca.solve(m.M, m.f + df))
        jac = ca.jacobian(ode, ca.vertcat(x, m.inp))
        # the contact search's stand-in symbols (CedraModel._freeze): the compiled ODE takes the search's results
        # as an input, so its Jacobian does not go through the search (the model offers no public accessor)
        frozen = ca.vertcat(*[s for s, _ in m._frozen]) if m._frozen else ca.SX(0, 1)
        searched = ca.vertcat(*[e for _, e in m._frozen]) if m._frozen else ca.SX(0, 1)
        nx = 2 * self.nq
        body = ca.Function("hyb_ode", [x, m.inp, m.par, frozen, on], [ode], {"cse": True})
        body_jac = ca.Function("jac_hyb_ode", [x, m.inp, m.par, frozen, on, ca.SX.sym("out", nx)],
                               [jac[:, :nx], jac[:, nx:], ca.SX(nx, self.par.size), ca.SX(nx, frozen.numel()),
                                ca.SX(nx, L)], {"cse": True})
        self.ode_c = ca.external("hyb_ode", str(_compiled([body, body_jac], f"cedra_hyb_{self.scene.name}")))
        self.search = ca.Function("hyb_search", [m.q, m.inp, m.par], [searched])
        self.n_frozen = frozen.numel()
        sc = ca.vertcat(*scale)
        br = ca.Function("hyb_branches", [x, m.inp, m.par, frozen],
                         [ca.vertcat(*dep) * sc, (ca.vertcat(*dep) - ca.vertcat(*dd) / ca.vertcat(*kk) *
                                                  ca.vertcat(*vel)) * sc])
        self.branches_sx = br
        self.q_names = m.q_names

    def full(self, xr):
        return ca.mtimes(self.select, xr)

    def reduced(self, x) -> np.ndarray:
        return np.asarray(x)[self.kept]

    def inputs(self, tau4):
        return ca.vertcat(*[tau4[k] for k in PAIRS], ca.DM(self.inp[6:]))

    def _searched(self, x, inp):
        if not self.n_frozen:
            return ca.MX(0, 1)
        return ca.stop_diff(self.search(x[:self.nq], inp, ca.DM(self.par)), 1)

    def ode(self, x, u, on):
        xf = self.full(x)
        inp = self.inputs(u)
        # second derivatives are declared zero: the compiled library holds first derivatives only
        out = ca.stop_diff(self.ode_c(xf, inp, ca.DM(self.par), self._searched(xf, inp), on), 2)
        return out[self.kept]

    def branches(self, x):
        xf = self.full(x)
        inp = self.inputs(ca.DM.zeros(4))
        return self.branches_sx(xf, inp, ca.DM(self.par), self._searched(xf, inp))
