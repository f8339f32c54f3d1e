"""A small mechanical model following the ModelSpec contract, for testing the FMU machinery without the rover.

A point mass in the vertical plane: q = [x, z] (horizontal, vertical; the ground is z = 0), u = [vx, vz], on a
compliant ground (spring-damper normal force, Coulomb friction regularized by v_eps), pushed horizontally by the
input force F. Integral state: the work of F. Outputs include a copy of a parameter (`mass`) and of an input
(`force`) for round trips, and one Integer output (`contact`). cedra_check refuses |x| >= x_max (a workspace
limit), which the tests use to force a failure.
"""
from __future__ import annotations

import casadi as ca

from cedra.contract import ModelSpec, Quantity
from cedra.mechanics.contact import terrain_functions
from cedra.mechanics.terrain import Terrain


def toy_spec(name: str = "toy") -> ModelSpec:
    q = ca.SX.sym("q", 2)
    u = ca.SX.sym("u", 2)
    a = ca.SX.sym("a", 2)
    zs = ca.SX.sym("zs", 1)
    inp = ca.SX.sym("inp", 1)
    par = ca.SX.sym("par", 7)
    params = [
        Quantity("m", 1.0, "kg", "mass", min=1e-9),
        Quantity("g", 9.81, "m/s2", "gravitational acceleration", min=0.0),
        Quantity("ground_k", 1e4, "N/m", "ground stiffness", min=1e-9),
        Quantity("ground_d", 100.0, "N.s/m", "ground damping", min=0.0),
        Quantity("mu", 0.5, "1", "friction coefficient", min=0.0),
        Quantity("v_eps", 0.01, "m/s", "friction regularization speed", min=1e-12),
        Quantity("x_max", 100.0, "m", "workspace limit: states with |x| >= x_max cannot be evaluated", min=0.0),
    ]
    inputs = [Quantity("F", 0.0, "N", "horizontal force on the mass", min=-1e4, max=1e4)]
    m, g, k, d, mu, veps, xmax = (par[i] for i in range(7))
    x, z = q[0], q[1]
    vx, vz = u[0], u[1]
    F = inp[0]

    def forces(z_, vz_, vx_):
        pen = -z_
        fn = ca.if_else(pen > 0, ca.fmax(0, k * pen - d * vz_), 0)
        ft = -mu * fn * vx_ / ca.sqrt(vx_ ** 2 + veps ** 2)
        return pen, fn, ft

    pen, fn, ft = forces(z, vz, vx)
    M = ca.diag(ca.vertcat(m, m))
    f = ca.vertcat(F + ft, fn - m * g)
    gz = F * vx
    r = ca.mtimes(M, a) - f
    fns = {
        "cedra_M": ca.Function("cedra_M", [q, par], [M]),
        "cedra_f": ca.Function("cedra_f", [q, u, inp, par], [f, gz]),
        "cedra_rjac": ca.Function("cedra_rjac", [q, u, a, inp, par],
                                  [ca.jacobian(r, q), ca.jacobian(r, u), ca.jacobian(gz, q), ca.jacobian(gz, u)]),
    }
    energy = 0.5 * m * (vx ** 2 + vz ** 2) + m * g * z + ca.if_else(pen > 0, 0.5 * k * pen ** 2, 0)
    outs = [
        (Quantity("pos.x", unit="m", description="horizontal position"), x),
        (Quantity("pos.z", unit="m", description="vertical position (ground at 0)"), z),
        (Quantity("vel.x", unit="m/s", description="horizontal speed"), vx),
        (Quantity("vel.z", unit="m/s", description="vertical speed"), vz),
        (Quantity("Fn", unit="N", description="normal contact force"), fn),
        (Quantity("Ft", unit="N", description="friction force"), ft),
        (Quantity("energy.total", unit="J", description="kinetic + potential (gravity, ground spring) energy"),
         energy),
        (Quantity("energy.work", unit="J", description="work of the input force since the start"), zs[0]),
        (Quantity("mass", unit="kg", description="the parameter m (round trip)"), m),
        (Quantity("force", unit="N", description="the input F (round trip)"), F),
        (Quantity("contact", unit="1", description="1 in contact with the ground, 0 airborne", type="Integer"),
         ca.if_else(pen > 0, 1, 0)),
    ]
    fns["cedra_out"] = ca.Function("cedra_out", [q, u, zs, inp, par], [ca.vertcat(*[e for _, e in outs])])
    # static equilibrium in z (u = 0)
    _, fn0, _ = forces(z, 0, 0)
    res = fn0 - m * g
    fns["cedra_settle"] = ca.Function("cedra_settle", [q, inp, par], [res, ca.jacobian(res, z)])
    fns["cedra_guess"] = ca.Function("cedra_guess", [q, inp, par], [ca.vertcat(x, -0.5 * m * g / k)])
    fns["cedra_check"] = ca.Function("cedra_check", [q, u, inp, par], [ca.if_else(ca.fabs(x) < xmax, 1, 0)])
    fns |= terrain_functions(Terrain("flat", {}))       # the contract's; the toy's own ground is in its forces
    spec = ModelSpec(
        name=name, description="toy: a point mass on a compliant ground with regularized Coulomb friction",
        q_names=["x", "z"], z_names=["work"], params=params, inputs=inputs, outputs=[o for o, _ in outs],
        q_start=[0.0, 0.05], settle_idx=[1], start_params={"start.x": 0, "start.z": 1}, functions=fns,
        stop_time=2.0, output_interval=0.01, solver=dict(method="dopri5", tol=1e-8, h_max=0.002))
    spec.check()
    return spec
