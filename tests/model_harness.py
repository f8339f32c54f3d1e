"""Test harness for the symbolic model: a scene's contract functions evaluated numerically, by name."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import CedraModel


class Built:
    """A model with its numeric functions (built once per module)."""

    def __init__(self, opt):
        self.m = CedraModel(opt)
        self.fns = self.m.functions()
        self.names = self.m.q_names
        self.n = len(self.names)
        self.spec = self.m.spec("test")
        self.out_names = [o.name for o in self.spec.outputs]

    def M(self, q, par):
        return np.array(self.fns["cedra_M"](q, par))

    def f(self, q, u, inp, par):
        """M udot = f: every force, the collision points' too (cedra_fc, kept apart in the FMU)."""
        f, g = self.fns["cedra_f"](q, u, inp, par)
        if "cedra_fc" in self.fns:
            f = f + self.fns["cedra_fc"](q, u, inp, par)
        return np.array(f).ravel(), float(g)

    def out(self, q, u, inp, par):
        y = np.array(self.fns["cedra_out"](q, u, 0, inp, par)).ravel()
        return dict(zip(self.out_names, y))

    def settle(self, inp, par, q=None):
        """cedra_guess, then Newton on cedra_settle (as the FMU's initialization does)."""
        q = np.array(self.spec.q_start if q is None else q, dtype=float)
        q = np.array(self.fns["cedra_guess"](q, inp, par)).ravel()
        idx = self.m.settle_idx
        for _ in range(40):
            r, J = self.fns["cedra_settle"](q, inp, par)
            dq = np.linalg.solve(np.array(J), np.array(r).ravel())
            q[idx] -= dq
            if np.max(np.abs(dq)) < 1e-15:
                break
        r, _ = self.fns["cedra_settle"](q, inp, par)
        assert np.max(np.abs(np.array(r))) < 1e-9
        return q

    def integrate(self, q0, u0, inp, par, t_end, n_out):
        """x = [q, u], xdot = [u, solve(M, f)] by CasADi's cvodes at rtol = atol = 1e-10; returns (t, X)."""
        x = ca.MX.sym("x", 2 * self.n)
        q, u = x[:self.n], x[self.n:]
        M = self.fns["cedra_M"](q, par)
        f = self.fns["cedra_f"](q, u, inp, par)[0]
        if "cedra_fc" in self.fns:
            f = f + self.fns["cedra_fc"](q, u, inp, par)
        ode = ca.vertcat(u, ca.solve(M, f))
        t = np.linspace(0, t_end, n_out + 1)
        I = ca.integrator("I", "cvodes", {"x": x, "ode": ode}, 0, t[1:],
                          {"reltol": 1e-10, "abstol": 1e-10, "max_num_steps": 200000})
        X = np.array(I(x0=np.concatenate([q0, u0]))["xf"])
        return t, np.hstack([np.concatenate([q0, u0])[:, None], X])


# the FMU outputs that give a scene's coordinates (CEDRA's and the rocker-bogie's)
OUTPUTS = {"x": "body.x", "y": "body.y", "z": "body.z", "yaw": "body.yaw", "pitch": "body.pitch",
           "roll": "body.roll", "theta1": "bogie.theta[1]", "theta2": "bogie.theta[2]", "theta4": "fork.theta4",
           "theta3": "steer.theta[1]", "theta6": "steer.theta[2]", "rho": "rocker.rho", "beta_L": "bogie.beta[1]",
           "beta_R": "bogie.beta[2]"}


def run_coordinates(scene, model, seconds, every=50):
    """The coordinates (spin angles 0: a wheel is round) every `every` samples of the scene's main run through its
    shipped FMU (build/; the test skips where it is not built)."""
    from cedra.run.simulate import run_bump
    fmu = Path(__file__).resolve().parents[1] / "build" / f"{scene}.fmu"
    if not fmu.exists():
        pytest.skip(f"{fmu} is not built (./build.sh)")
    names, data, _, info = run_bump(fmu, seconds, {}, extra=list(OUTPUTS.values()))
    assert info["ok"], info["messages"][-2:]
    col = {n: k for k, n in enumerate(names)}
    qs = []
    for row in data[::every]:
        q = np.zeros(len(model.q_names))
        for k, nm in enumerate(model.q_names):
            if nm in OUTPUTS and OUTPUTS[nm] in col:
                q[k] = row[col[OUTPUTS[nm]]]
        qs.append(q)
    return qs


def central_differences(g, z, rel: float = 1e-6) -> np.ndarray:
    """The Jacobian of g (a vector function of the vector z) by central differences, the step rel * max(1, |z_j|)
    in each direction."""
    z = np.asarray(z, dtype=float)
    cols = []
    for j in range(z.size):
        h = rel * max(1.0, abs(z[j]))
        up, down = z.copy(), z.copy()
        up[j] += h
        down[j] -= h
        cols.append((np.asarray(g(up), dtype=float).ravel() - np.asarray(g(down), dtype=float).ravel()) / (2 * h))
    return np.column_stack(cols)
