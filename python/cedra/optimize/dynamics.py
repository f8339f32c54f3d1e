"""The optimizer's own equations: the scene's planar model as CasADi functions of the shooting state, the four
torque decisions and the problem's constant inputs and parameters.

The ODE [u; M^-1 f] is formed from the model's own symbolic M and f (with the collision points' force cedra_fc
where the scene has chassis contact), generated to C with its Jacobian, one file per function as the FMU's, and compiled once per model
(cedra.models.host.casadi_library: in parallel, through the object cache; the library under build/host/). The contact search (cedra_rim_search, the FMU's C search) makes discrete choices and
returns converged angles: the model never differentiates it (cedra.mechanics.contact.rim_contacts), and neither
does the optimizer (casadi.stop_diff on its results). Second derivatives of the equations are not formed. The
wheels' spin angles enter no force, so the shooting state leaves them out (14 of the model's 18 states).

Decisions: one torque per wheel pair and interval. The planar model's wheels 3 and 4 share the spin coordinates
of wheels 1 and 2 (the left and right bogie wheels roll on the same profile), so tau[1] + tau[3] is what drives
gamma1: the optimizer sets tau[1] = tau[3], tau[2] = tau[4] (the split that costs least energy), tau[5] and
tau[6] on their own (PAIRS).

Contact non-smoothness: the compliant law's normal force max(0, k delta - d v_n) and its onset at delta = 0 are
kinks and a jump in the state derivative; the friction law is already regularized by v_eps. The integrator
crosses them with error control (the FMU locates them; CVODES shortens its steps), and the sensitivities carry no
jump term at a switch. The problem's `solver.smoothing` replaces them, in these equations only, by the smoothed
law of contact.compliant_law (a softplus of the clip and a sigmoid of the onset over a depth width w, w = 0 the
FMU's law exactly), the joint stops' law likewise (mechanism.stop_torque, over w / R_w in radians: the same clip
and onset). The width is an input of the compiled equations (Dynamics.width), so one library serves every
continuation stage; the FMUs are generated without it. The replay integrates the FMU's own law, so with a last
width > 0 its deviation from the optimizer's path measures the smoothing too (docs/optimize.md)."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from cedra.models.host import casadi_library
from cedra.models.scene import load_shipped
from cedra.optimize.problem import REPLAY_STEP, Problem

PAIRS = (0, 1, 0, 1, 2, 3)   # tau[1..6] from the four decisions (wheel pairs 1/3, 2/4, then 5, 6)
WHEELS = (1, 2, 5, 6)        # the planar model's distinct wheels (3, 4 repeat 1, 2)
RATE_MAX = 200.0             # rad/s: bound of the wheels' spin rates at the nodes (state_bounds)
SPEED_MAX = 20.0             # m/s, rad/s: bound of the other rates at the nodes


def _compiled(functions: list[ca.Function], stem: str) -> Path:
    """The functions as C (CasADi's code generator, one file each) in one shared library, each file compiled once.
    -O1: bump2d's Jacobian is one 3.2 MB file, about 85 s of gcc at -O1 and 18 s at -O0, but the -O0 Jacobian takes
    twice as long per evaluation (620 against 320 us), and the integrator's sensitivities evaluate it at every
    step."""
    return casadi_library(functions, stem, ("-O1",))


class Dynamics:
    """The scene's planar equations as CasADi functions of the state x = [q; u], the four torque decisions and the
    problem's constant inputs and parameters."""

    def __init__(self, problem: Problem):
        from cedra.models.plant import CedraModel
        self.scene = load_shipped(problem.scene)
        # the scene's equations with the contact law's smoothing width a free input (0: the FMU's law exactly)
        self.model = m = CedraModel(self.scene.options, smooth_contact=True)
        self.width = 0.0            # m: the smoothing width the equations below are evaluated at
        self.par = m.default_par(**self.scene.parameters)
        self.inp = m.default_inp(**(self.scene.inputs | problem.inputs))
        self.nq = m.q.numel()
        self.nx = 2 * self.nq
        # the wheels' spin angles enter no force (a round wheel): the shooting state leaves them out, which spares
        # their sensitivities; full() puts zeros in their place for the equations
        self.kept = [k for k, n in enumerate(m.q_names) if not n.startswith("gamma")] + \
            list(range(self.nq, self.nx))
        self.nr = len(self.kept)
        self.select = ca.DM.zeros(self.nx, self.nr)
        for j, k in enumerate(self.kept):
            self.select[k, j] = 1
        # the contact search's stand-in symbols and their expressions (CedraModel._freeze): the compiled ODE takes
        # the search's results as an input, so its Jacobian does not go through the search (the model offers no
        # public accessor for them)
        frozen = ca.vertcat(*[s for s, _ in m._frozen]) if m._frozen else ca.SX(0, 1)
        searched = ca.vertcat(*[e for _, e in m._frozen]) if m._frozen else ca.SX(0, 1)
        x = ca.vertcat(m.q, m.u)
        f = m.f + (m.chassis_force if m.chassis else 0)
        ode = ca.vertcat(m.u, ca.solve(m.M, f))
        jac = ca.jacobian(ode, ca.vertcat(x, m.inp))
        width = m.contact_width
        body = ca.Function("opt_ode", [x, m.inp, m.par, frozen, width], [ode], {"cse": True})
        # CasADi's name for the derivative of an external: jac_<name>(inputs, outputs) -> d outputs / d inputs
        body_jac = ca.Function("jac_opt_ode", [x, m.inp, m.par, frozen, width, ca.SX.sym("out", self.nx)],
                               [jac[:, :self.nx], jac[:, self.nx:], ca.SX(self.nx, self.par.size),
                                ca.SX(self.nx, frozen.numel()), ca.SX(self.nx, 1)], {"cse": True})
        self.ode_c = ca.external("opt_ode", str(_compiled([body, body_jac], f"cedra_opt_{self.scene.name}")))
        self.search = ca.Function("opt_search", [m.q, m.inp, m.par], [searched])
        self.frozen = frozen
        forces = [(m.contacts[k - 1]["Fn"], m.contacts[k - 1]["Fx"]) for k in WHEELS]
        self.forces_sx = ca.Function("opt_forces", [x, m.inp, m.par, frozen, width],
                                     [ca.vertcat(*[a for a, _ in forces]), ca.vertcat(*[b for _, b in forces])])

    def full(self, xr):
        """The model state [q; u] of a shooting state (the spin angles set to zero)."""
        return ca.mtimes(self.select, xr)

    def reduced(self, x) -> np.ndarray:
        """The shooting state of model states (columns)."""
        return np.asarray(x)[self.kept]

    def inputs(self, tau4):
        """The scene's input vector with the four torque decisions put in as tau[1..6]."""
        rest = ca.DM(self.inp[6:])
        return ca.vertcat(*[tau4[k] for k in PAIRS], rest)

    def _searched(self, x, inp):
        # the contact search's results enter as constants of differentiation, as in the model's own Jacobians
        return ca.stop_diff(self.search(x[:self.nq], inp, ca.DM(self.par)), 1) if self.frozen.numel() else ca.MX(0, 1)

    def ode(self, x, tau4):
        inp = self.inputs(tau4)
        # second derivatives are declared zero: the compiled library holds first derivatives only
        return ca.stop_diff(self.ode_c(x, inp, ca.DM(self.par), self._searched(x, inp), self.width), 2)

    def forces(self, xr):
        """(Fn, Fx) of wheels 1, 2, 5, 6 at shooting state xr (the FMU's wheel[i].Fn, wheel[i].Fx)."""
        x = self.full(xr)
        inp = self.inputs([0, 0, 0, 0])
        return self.forces_sx(x, inp, ca.DM(self.par), self._searched(x, inp), self.width)

    def integrator(self, tol: float, n_out: int = 1, dt: float | None = None) -> ca.Function:
        """The shooting state at the end of one interval under dx/ds = dt ode(x, tau4) from x(0), p = [tau4; dt]
        (the time objective: dt is a decision) or p = tau4 with the interval's length fixed at `dt` (no
        sensitivity to it); n_out > 1: the states at n_out equally spaced points of the interval."""
        x, p = ca.MX.sym("x", self.nr), ca.MX.sym("p", 5 if dt is None else 4)
        length = p[4] if dt is None else dt
        grid = list(np.linspace(0, 1, n_out + 1)[1:])
        ode = length * self.ode(self.full(x), p[:4])[self.kept]
        # second_order_correction: CasADi's Newton matrix of the sensitivity-augmented system would carry the
        # equations' second derivatives, which are declared zero (first derivatives only): leaving the term out
        # gives the same sensitivities bit for bit at half the cost (the whole bump's interval Jacobians at 0.1 s,
        # measured: 4.8 -> 2.3 s for 14 of them)
        return ca.integrator("shoot", "cvodes", {"x": x, "p": p, "ode": ode}, 0, grid,
                             {"abstol": tol, "reltol": tol, "fsens_err_con": False, "max_num_steps": 100000,
                              "show_eval_warnings": False, "second_order_correction": False})


def state_bounds(dyn: Dynamics) -> tuple[np.ndarray, np.ndarray]:
    """Generous bounds on the nodes' states that keep IPOPT's trial points in the model's domain: the joints a
    little beyond their stops (the stops are springs), the pitch well inside the FMU's 80 deg tip-over limit, the
    rates beyond anything a climb at these torques reaches. Without them a long trial step puts the four-bar
    through its toggle, where the equations have no value."""
    p = dict(zip([q.name for q in dyn.model.params], dyn.par))
    span = {"pitch": (-1.0, 1.0), "theta1": (-p["bogie_stop"] - 0.2, p["bogie_stop"] + 0.2),
            "theta4": (p["fork_stop_lo"] - 0.2, p["fork_stop_hi"] + 0.2)}
    names = dyn.model.q_names
    inf = (-np.inf, np.inf)
    rate = [RATE_MAX if nm.startswith("gamma") else SPEED_MAX for nm in names]
    lo = [span.get(nm, inf)[0] for nm in names] + [-r for r in rate]
    hi = [span.get(nm, inf)[1] for nm in names] + rate
    return np.array(lo), np.array(hi)


def goal(problem: Problem, dyn: Dynamics) -> float:
    """The goal's body.x: the obstacle's terrain_x0 (the scene's input, or the problem's) plus the margin."""
    return float(dyn.inp[[q.name for q in dyn.model.inputs].index("terrain_x0")]) + problem.margin


def model_path(dyn: Dynamics, x0, torques, dt, tol) -> np.ndarray:
    """The optimizer's own trajectory at every REPLAY_STEP: its integrator from x0 over the optimal torques (the
    states at the replay's communication points)."""
    n_sub = int(round(dt / REPLAY_STEP))
    F = dyn.integrator(tol, n_sub, dt)
    xs, x = [dyn.reduced(x0)], dyn.reduced(x0)
    for tau in torques:
        r = np.array(F(x0=x, p=tau)["xf"])
        xs += list(r.T)
        x = r[:, -1]
    return np.array(xs).T
