"""How far the contact law is from conservative at a step (docs/model.md, Force laws): with mu = 0 and no damping
anywhere, the rover rolled into a step of 4 cm (0.6 R_w) by its own momentum gains energy where the edge is sharp.

The law's force k delta n with delta = g n_Z is the gradient of 0.5 k delta^2 only where n_Z does not change along
the motion: by the envelope theorem at a maximum of g, -dV/dq = k delta n.dp/dq - (k delta^2 / n_Z) dn_Z/dq, and
the second term grows with the edge's curvature (1/terrain_s). So the balance is exact on planes (the energy tests
of test_model_dynamics and test_chassis), close on smooth terrain and off on sharp edges. Measured here, with
the wheel carrying 4.32 J of kinetic energy into the step (cvodes, tolerance 1e-10); the figures are quoted in
docs/model.md."""
import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import ModelOptions
from model_harness import Built


@pytest.fixture(scope="module")
def b():
    return Built(ModelOptions(dims="2d", terrain="step"))


def _energy_gain(b, s):
    m = b.m
    par = m.default_par(ground_d=0.0, fork_d=0.0, stop_d=0.0)
    inp = m.default_inp(mu=0.0, terrain_h=0.04, terrain_x0=0.6, terrain_s=s)
    q = b.settle(inp, par)
    u = np.zeros(b.n)
    u[b.names.index("x")] = 0.6
    E = ca.Function("E", [m.q, m.u, m.inp, m.par],
                    m.resolve([m.kane.kinetic_energy(), m.potential], derivatives=False))
    t, X = b.integrate(q, u, inp, par, 1.0, 400)
    TV = np.array([np.array(E(X[:b.n, k], X[b.n:, k], inp, par)).ravel() for k in range(X.shape[1])])
    Et = TV.sum(axis=1)
    front = [b.out(X[:b.n, k], X[b.n:, k], inp, par)["wheel[6].cx"] for k in (0, -1)]
    assert front[0] < 0.6 - 0.065 < 0.6 + 0.065 < front[1]          # the front wheel went over the edge
    return float(np.max(np.abs(Et - Et[0]))) / TV[0, 0]


def test_energy_balance_at_a_step_against_the_edges_sharpness(b):
    gains = {s: _energy_gain(b, s) for s in (0.1, 0.03, 0.01)}
    print("largest |E - E0| / K0 by terrain_s:", {s: f"{g:.2e}" for s, g in gains.items()})
    assert gains[0.1] < 2e-4                 # smooth edge: nearly conservative
    assert gains[0.1] < gains[0.03] < gains[0.01]
    assert gains[0.01] < 0.1                 # the sharpest shipped edge (step2d, stairs): within 10 % of K0
