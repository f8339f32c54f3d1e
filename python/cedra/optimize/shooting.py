"""Direct multiple shooting: one shooting interval per control interval, integrated by CVODES, and the lifted
transcription (solver.spin_rates = "nodes": every shooting state a node decision with a shooting defect of its
own), with what both transcriptions share (one interval's Jacobian, the intervals mapped over threads, the
objective's part of the Hessian of the Lagrangian).

Why shooting: the contact is stiff (a slipping wheel's spin relaxes at ~1e4 1/s: the friction law's slope
mu Fn / v_eps on the wheel's own small inertia), so a transcription has to integrate it with an implicit,
error-controlled method to follow the FMU to 1e-4 m. Collocation would need a grid fine enough for that accuracy
everywhere (thousands of intervals over a climb, each with its own contact switches); multiple shooting keeps a
coarse control grid (0.05-0.1 s) and lets CVODES (BDF, tolerances `solver.integrator_tol`) place its steps and
find each interval's end state and its sensitivities. With a fixed horizon the interval's length is a constant,
not a parameter the sensitivities are taken for.

The Hessian of the Lagrangian (`solver.hessian`): by default the objective's own (exact for the energy, a sum of
squares of the torques) without the shooting constraints' curvature, a generalized Gauss-Newton method
(objective_hessian); "differenced" adds that curvature, each interval's block from forward differences of its
sensitivities (ShootingHessian: Newton's method, at ten times an iteration's cost or more); "limited-memory" is
IPOPT's quasi-Newton approximation. CVODES' sensitivity Newton iteration uses the first-order Jacobian."""
from __future__ import annotations

import casadi as ca
import numpy as np

from cedra.optimize.dynamics import Dynamics
from cedra.optimize.numpy_function import NumpyFunction, hess_lag_io
from cedra.optimize.problem import Problem


def interval_jacobian(F: ca.Function, nx: int, npar: int) -> ca.Function:
    """d xf / d (x0, p) of one shooting interval F(x0, p) -> xf, as one nx x (nx + npar) matrix."""
    x, p = ca.MX.sym("x", nx), ca.MX.sym("p", npar)
    return ca.Function("interval_jacobian", [x, p], [ca.jacobian(F(x0=x, p=p)["xf"], ca.vertcat(x, p))])


def mapped(f: ca.Function, count: int, threads: int) -> ca.Function:
    """f evaluated at `count` points (columns) at once, on `threads` threads (serially with one)."""
    return f.map(count, "thread", threads) if threads > 1 else f.map(count, "serial")


def lifted_constraints(problem: Problem, dyn: Dynamics, n: int, dt_guess: float, goal_x: float):
    """The decisions w = [vec(X); vec(U); dt; s] with every shooting state a node decision, and (w, U, dt, s,
    constraints, lower bounds, upper bounds): the shooting defects, the goal, peak_friction's node forces."""
    free_dt = problem.objective == "time"
    X = ca.MX.sym("X", dyn.nr, n + 1)
    U = ca.MX.sym("U", 4, n)
    dt = ca.MX.sym("dt")
    s = ca.MX.sym("s")
    F = dyn.integrator(problem.integrator_tol, dt=None if free_dt else dt_guess)
    F = mapped(F, n, problem.threads)
    xf = F(x0=X[:, :n], p=ca.vertcat(U, ca.repmat(dt, 1, n)) if free_dt else U)["xf"]
    g = [ca.vec(xf - X[:, 1:]), X[0, n] - goal_x]
    lbg = [np.zeros(dyn.nr * n), [0.0]]
    ubg = [np.zeros(dyn.nr * n), [np.inf]]
    if problem.objective == "peak_friction":
        fn, fx = _node_forces(dyn, X[:, 1:])
        g += [ca.vec(fx - s * fn), ca.vec(-fx - s * fn)]
        lbg += [np.full(2 * 4 * n, -np.inf)]
        ubg += [np.zeros(2 * 4 * n)]
    return ca.vertcat(ca.vec(X), ca.vec(U), dt, s), U, dt, s, g, lbg, ubg


def _node_forces(dyn: Dynamics, X):
    fn, fx = [], []
    for k in range(X.shape[1]):
        a, b = dyn.forces(X[:, k])
        fn.append(a)
        fx.append(b)
    return ca.horzcat(*fn), ca.horzcat(*fx)




def objective_hessian(w, J, n_g: int, n_states: int, proximal: float) -> ca.Function:
    """The Hessian of the Lagrangian without the constraints' curvature: lam_f times the objective's own (the
    energy term is a sum of squares of the torques, so its Hessian is constant and exact). The shooting constraints'
    second derivatives are not available (the integrator's sensitivities are first order); left out, the steps
    are those of a generalized Gauss-Newton method, which the objective's curvature in the torques keeps short."""
    x = ca.MX.sym("x", w.numel())
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", n_g)
    return ca.Function("nlp_hess_l", [x, ca.MX(0, 1), lam_f, lam_g],
                       [ca.triu(lam_f * objective_part(w, J, n_states, proximal)(x))],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])


def objective_part(w, J, n_states: int, proximal: float) -> ca.Function:
    """w -> the objective's own Hessian plus `proximal` times the identity on the first n_states decisions (the
    node states): the Hessian of the Lagrangian without the constraints' curvature, per unit lam_f."""
    x = ca.MX.sym("x", w.numel())
    hess = ca.hessian(ca.Function("objective", [w], [J])(x), x)[0]
    return ca.Function("objective_part", [x], [hess + ca.diag(ca.vertcat(ca.DM.ones(n_states) * proximal,
                                                                          ca.DM.zeros(w.numel() - n_states)))])


class ShootingHessian(NumpyFunction):
    """The Hessian of the Lagrangian with the shooting constraints' curvature (solver.hessian = "differenced"):
    lam_f times the objective's own with the proximal term (objective_part, as the Gauss-Newton Hessian) plus,
    for every interval k, the second derivative of lam_k . F(X_k, U_k) in the interval's own decisions
    z_k = (X_k, U_k), from forward differences of its Jacobian (CVODES' first-order sensitivities, `jacobian`:
    z -> d F / d z) in each component of z_k, symmetrized. The equations' own second
    derivatives are not compiled, and differencing the sensitivities costs len(z_k) more Jacobians an interval (on
    `threads` threads): on the whole bump (53 intervals of 0.1 s, 2 threads) an iteration takes about 50 s
    instead of the Gauss-Newton iteration's 4 s. The shooting constraints are the first nx n entries of g
    (X_{k+1} = F(X_k, U_k)); any further constraints (peak_friction's node forces) keep their curvature out, as in
    the Gauss-Newton Hessian. The decisions are w = [vec(X) (nx x (n + 1)); vec(U) (nu x n); anything else]."""

    STEP = 1e-5           # the forward difference's step, relative to max(1, |z|): the sensitivities are accurate to
    # about 1e-5 relative (docs/optimize.md), so the difference carries about that over the step, 1e-5 x |H|

    def __init__(self, w, J, n_g: int, n: int, jacobian: ca.Function, threads: int = 1, proximal: float = 0.0):
        self.nx, self.nu = jacobian.size1_out(0), jacobian.size2_out(0) - jacobian.size1_out(0)
        self.nw, self.n_g, self.n = w.numel(), n_g, n
        nz, nx = self.nx + self.nu, self.nx
        self.objective_part = objective_part(w, J, nx * (n + 1), proximal)
        self.jacobians = mapped(jacobian, n * (nz + 1), threads)
        self.blocks = [np.r_[np.arange(k * nx, (k + 1) * nx), nx * (n + 1) + self.nu * k + np.arange(self.nu)]
                       for k in range(n)]
        # the pattern: every interval's block, the diagonal (proximal) and the objective's own Hessian
        own = self.objective_part.sparsity_out(0)
        rows = np.concatenate([np.repeat(idx, nz) for idx in self.blocks] + [np.arange(self.nw), own.row()])
        cols = np.concatenate([np.tile(idx, nz) for idx in self.blocks] + [np.arange(self.nw), own.get_col()])
        upper = rows <= cols
        self.sparsity = ca.Sparsity.triplet(self.nw, self.nw, rows[upper].tolist(), cols[upper].tolist())
        super().__init__("nlp_hess_l", *hess_lag_io(self.nw, n_g, self.sparsity))

    def evaluate(self, w, p, lam_f, lam_g):
        return [np.triu(self.matrix(w, lam_f[0], lam_g))]

    def matrix(self, w: np.ndarray, lam_f: float, lam_g: np.ndarray) -> np.ndarray:
        """The full (symmetric) Hessian of lam_f f + lam_g . g at w, as a dense array."""
        nx, n, nz = self.nx, self.n, self.nx + self.nu
        H = lam_f * np.array(self.objective_part(w))
        Z = np.stack([w[idx] for idx in self.blocks], axis=1)                 # nz x n: every interval's z_k
        steps = self.STEP * np.maximum(1.0, np.abs(Z))
        variants = [Z] + [Z + np.eye(nz)[:, [c]] * steps[c] for c in range(nz)]
        points = np.concatenate(variants, axis=1)                             # nz x n (nz + 1), variant-major
        jac = np.array(self.jacobians(points[:nx], points[nx:])).reshape(nx, nz + 1, n, nz)
        for k, idx in enumerate(self.blocks):
            lam = lam_g[k * nx:(k + 1) * nx]
            base = lam @ jac[:, 0, k, :]
            block = np.stack([(lam @ jac[:, 1 + c, k, :] - base) / steps[c, k] for c in range(nz)], axis=1)
            H[np.ix_(idx, idx)] += 0.5 * (block + block.T)
        return H
