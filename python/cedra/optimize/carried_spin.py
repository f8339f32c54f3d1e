"""Multiple shooting with the wheels' spin rates carried from interval to interval (solver.spin_rates = "carried"):
the nodes hold the body's and the joints' states only, and each interval starts with the
spin rates the previous interval ended with, their sensitivities chained through the intervals.

Why: a wheel's spin inertia is small (m_w R_w^2 / 2), so where a wheel lands its end rate is a steep function of
the instant it touches: at a saved iterate of the whole bump the interval Jacobians hold d omega / d z up to
8e3 rad/s per m (landing wheels), exact to 1e-7 relative against CVODES' error-controlled sensitivities. As
node decisions with shooting defects of their own those rates put that steepness into the constraints, and the
Gauss-Newton steps, which are linear in it, break them at every landing (docs/optimize.md). Carried, a rate is
an intermediate of the integration: what a landing's timing does to it reaches the constraints only through the
body, where a wheel's small momentum moves little. A slipping wheel's rate forgets where it started within
milliseconds (the friction law's ~1e4 1/s), so the chained sensitivities die out where wheels touch the ground and
single shooting in the rates is well conditioned; in the air a rate follows its torque (d omega = tau dt / J).
Measured (docs/optimize.md): the short bump problem converges with it as with the lifted rates, to IPOPT's
tolerance with "differenced"; on the whole bump the shipped stages reach far lower energies but keep larger
defects in the joints' rates, and the torques' own path does not reach the goal: not the default.

Decisions w = [vec(X) (nb x (n + 1), the body and joint states of every node, X_0 fixed at the start);
vec(U) (4 x n); dt; s], the same order as the lifted transcription's. Constraints g = [the body defects (nb n);
the goal; peak_friction: Fx - s Fn <= 0 and -Fx - s Fn <= 0 at the nodes 1..n (4 wheels each)]. The constraint
values and their Jacobian come from CasADi callbacks: the integrations run serially (each interval needs the
previous one's rates), the interval Jacobians, given every interval's start, on `threads` threads."""
from __future__ import annotations

import casadi as ca
import numpy as np

from cedra.optimize.numpy_function import NumpyFunction, hess_lag_io
from cedra.optimize.shooting import interval_jacobian, mapped


class CarriedSpinShooting:
    """The constraints of the carried-spin transcription for n intervals of the Dynamics `dyn`
    (cedra.optimize.dynamics) from the full shooting state x0, at the smoothing width dyn.width when the functions
    are formed."""

    def __init__(self, dyn, x0, n: int, dt: float, tol: float, goal_x: float, free_dt: bool, peak: bool,
                 threads: int = 1):
        names = [nm for k, nm in enumerate(dyn.model.q_names + ["d" + nm for nm in dyn.model.q_names])
                 if k in dyn.kept]
        self.spin = [k for k, nm in enumerate(names) if nm.startswith("dgamma")]
        self.body = [k for k in range(len(names)) if k not in self.spin]
        self.nr, self.nb, self.ns, self.nu = len(names), len(self.body), len(self.spin), 4
        self.n, self.goal_x, self.free_dt, self.peak = n, goal_x, free_dt, peak
        self.x0 = np.asarray(dyn.reduced(x0), dtype=float).ravel()
        self.u_at = self.nb * (n + 1)                     # where the torques start in w
        self.nw = self.u_at + self.nu * n + 2             # ... then dt, s
        self.ng = self.nb * n + 1 + (8 * n if peak else 0)
        self.F = dyn.integrator(tol, dt=None if free_dt else dt)
        npar = self.nu + (1 if free_dt else 0)
        jac = interval_jacobian(self.F, self.nr, npar)
        self.jacobians = mapped(jac, n, threads)
        # constraint_curvature's differences: every interval's Jacobian at each of its nr + nu perturbed inputs
        self._differences = mapped(jac, n * (self.nr + self.nu), threads) if not free_dt else None
        if peak:
            xr = ca.MX.sym("x", self.nr)
            fn, fx = dyn.forces(xr)
            forces = ca.vertcat(fn, fx)
            self.forces = ca.Function("node_forces", [xr], [forces, ca.jacobian(forces, xr)])
        self._key = None
        self.sparsity = self._pattern()
        self.callbacks = (_Constraints(self), _ConstraintJacobian(self))

    # ---------------- the layout of w ----------------
    def _x_cols(self, k):
        return slice(self.nb * k, self.nb * (k + 1))

    def _u_cols(self, k):
        return slice(self.u_at + self.nu * k, self.u_at + self.nu * (k + 1))

    def split(self, w):
        """(X (nb x (n + 1)), U (4 x n), dt, s) of decisions w."""
        X = w[:self.u_at].reshape((self.nb, self.n + 1), order="F")
        U = w[self.u_at:self.u_at + self.nu * self.n].reshape((self.nu, self.n), order="F")
        return X, U, float(w[-2]), float(w[-1])

    def _pattern(self) -> ca.Sparsity:
        """Interval k's rows depend on the nodes 0..k + 1, the torques 0..k and dt; node k + 1's force rows also
        on s; the goal on node n's x."""
        rows, cols = [], []
        dt_col, s_col = self.nw - 2, self.nw - 1
        for k in range(self.n):
            past = list(range(self.nb * (k + 2))) + list(range(self.u_at, self.u_at + self.nu * (k + 1))) + [dt_col]
            for i in range(self.nb * k, self.nb * (k + 1)):
                rows += [i] * len(past)
                cols += past
            if self.peak:
                for i in self._force_rows(k):
                    rows += [i] * (len(past) + 1)
                    cols += past + [s_col]
        rows.append(self.nb * self.n)
        cols.append(self.nb * self.n)
        return ca.Sparsity.triplet(self.ng, self.nw, rows, cols)

    def _force_rows(self, k):
        start = self.nb * self.n + 1 + 8 * k
        return range(start, start + 8)

    # ---------------- evaluation ----------------
    def starts(self, w) -> np.ndarray:
        """Every interval's full start state (nr x n) and every interval's end state (nr x n); NaN from the first
        interval the integrator fails on."""
        if self._key is not None and np.array_equal(self._key, w):
            return self._starts, self._ends
        X, U, dt, _ = self.split(w)
        spin = self.x0[self.spin]
        starts, ends = np.full((self.nr, self.n), np.nan), np.full((self.nr, self.n), np.nan)
        for k in range(self.n):
            x = np.empty(self.nr)
            x[self.body], x[self.spin] = X[:, k], spin
            starts[:, k] = x
            if not np.all(np.isfinite(x)):
                break
            p = np.r_[U[:, k], dt] if self.free_dt else U[:, k]
            try:
                ends[:, k] = np.array(self.F(x0=x, p=p)["xf"]).ravel()
            except RuntimeError:           # the integrator could not integrate this trial point
                break
            spin = ends[self.spin, k]
        self._key, self._starts, self._ends = w.copy(), starts, ends
        return starts, ends

    def nodes(self, w) -> np.ndarray:
        """The full shooting states at the nodes (nr x (n + 1)): X with the carried spin rates."""
        X, _, _, _ = self.split(w)
        starts, ends = self.starts(w)
        full = np.empty((self.nr, self.n + 1))
        full[self.body] = X
        full[self.spin, 0] = self.x0[self.spin]
        full[self.spin, 1:] = ends[self.spin]
        return full

    def g(self, w) -> np.ndarray:
        X, _, _, s = self.split(w)
        starts, ends = self.starts(w)
        parts = [(ends[self.body] - X[:, 1:]).ravel(order="F"), [X[0, self.n] - self.goal_x]]
        if self.peak:
            full = self.nodes(w)
            for k in range(1, self.n + 1):
                f = np.array(self.forces(full[:, k])[0]).ravel() if np.all(np.isfinite(full[:, k])) \
                    else np.full(8, np.nan)
                fn, fx = f[:4], f[4:]
                parts.append(np.r_[fx - s * fn, -fx - s * fn])
        return np.concatenate(parts)

    def jacobian(self, w) -> np.ndarray:
        """d g / d w (dense): the interval Jacobians chained through the carried spin rates."""
        X, U, dt, s = self.split(w)
        starts, ends = self.starts(w)
        npar = self.nu + (1 if self.free_dt else 0)
        G = np.zeros((self.ng, self.nw))
        if not np.all(np.isfinite(starts)) or not np.all(np.isfinite(ends)):
            return np.full((self.ng, self.nw), np.nan)
        P = np.vstack([U, np.full((1, self.n), dt)]) if self.free_dt else U
        J = np.array(self.jacobians(starts, P))                   # nr x n (nr + npar), interval-major
        S = np.zeros((self.ns, self.nw))                          # d (the carried rates) / d w
        for k in range(self.n):
            Jk = J[:, k * (self.nr + npar):(k + 1) * (self.nr + npar)]
            D = Jk[:, self.spin] @ S
            D[:, self._x_cols(k)] += Jk[:, self.body]
            D[:, self._u_cols(k)] += Jk[:, self.nr:self.nr + self.nu]
            if self.free_dt:
                D[:, self.nw - 2] += Jk[:, -1]
            G[self.nb * k:self.nb * (k + 1)] = D[self.body]
            G[self.nb * k:self.nb * (k + 1), self._x_cols(k + 1)] -= np.eye(self.nb)
            S = D[self.spin]
            if self.peak:
                node = np.empty(self.nr)
                node[self.body], node[self.spin] = X[:, k + 1], ends[self.spin, k]
                f, df = (np.array(v) for v in self.forces(node))
                fn = f.ravel()[:4]
                dF = df[:, self.spin] @ S
                dF[:, self._x_cols(k + 1)] += df[:, self.body]
                dfn, dfx = dF[:4], dF[4:]
                rows = list(self._force_rows(k))
                G[rows[:4]] = dfx - s * dfn
                G[rows[4:]] = -dfx - s * dfn
                G[rows[:4], self.nw - 1] = -fn
                G[rows[4:], self.nw - 1] = -fn
        G[self.nb * self.n, self.nb * self.n] = 1.0
        return G

    def _chain(self, w):
        """Every interval's Jacobian J_k (nr x (nr + npar)) and the derivative of its inputs z_k = (start state,
        torques) in w, Z_k ((nr + nu) x nw); fixed horizon."""
        _, U, _, _ = self.split(w)
        starts, _ = self.starts(w)
        J = np.array(self.jacobians(starts, U))
        S = np.zeros((self.ns, self.nw))
        Js, Zs = [], []
        for k in range(self.n):
            Jk = J[:, k * (self.nr + self.nu):(k + 1) * (self.nr + self.nu)]
            Z = np.zeros((self.nr + self.nu, self.nw))
            Z[np.ix_(self.body, range(self._x_cols(k).start, self._x_cols(k).stop))] = np.eye(self.nb)
            Z[self.spin] = S
            Z[np.ix_(range(self.nr, self.nr + self.nu), range(self._u_cols(k).start, self._u_cols(k).stop))] = \
                np.eye(self.nu)
            S = Jk[self.spin] @ Z
            Js.append(Jk)
            Zs.append(Z)
        return Js, Zs

    STEP = 1e-5       # the Hessian's forward differences of the sensitivities, relative to max(1, |z|)

    def constraint_curvature(self, w, lam_g) -> np.ndarray:
        """sum_i lam_g[i] times the second derivative of g[i] in w (dense, symmetric), fixed horizon: the second-
        order adjoint of the interval chain. Each interval's output gets its whole multiplier mu_k (its body rows'
        own lam, its spin rates' the next interval's pulled back through that interval's Jacobian), its curvature
        in its own inputs z_k comes from forward differences of its sensitivities weighted by mu_k (as
        ShootingHessian), and sum_k Z_k^T H_k Z_k is the whole: the composite's second derivative. The energy
        objective's constraints only (no node forces)."""
        if self.peak or self.free_dt:
            raise ValueError("the carried transcription's constraint curvature is formed for a fixed horizon and "
                             "no node forces")
        X, U, dt, s = self.split(w)
        starts, _ = self.starts(w)
        Js, Zs = self._chain(w)
        nz = self.nr + self.nu
        mus = [None] * self.n
        carried = np.zeros(self.ns)           # the adjoint of interval k's end spin rates
        for k in reversed(range(self.n)):
            mu = np.zeros(self.nr)
            mu[self.body] = lam_g[self.nb * k:self.nb * (k + 1)]
            mu[self.spin] = carried
            mus[k] = mu
            carried = mu @ Js[k][:, self.spin]
        Z = np.vstack([starts, U])                                          # nz x n
        steps = self.STEP * np.maximum(1.0, np.abs(Z))
        points = np.concatenate([Z + np.eye(nz)[:, [c]] * steps[c] for c in range(nz)], axis=1)
        jac = np.array(self._differences(points[:self.nr], points[self.nr:])).reshape(self.nr, nz, self.n, nz)
        H = np.zeros((self.nw, self.nw))
        for k in range(self.n):
            base = mus[k] @ Js[k]
            block = np.stack([(mus[k] @ jac[:, c, k, :] - base) / steps[c, k] for c in range(nz)], axis=1)
            H += Zs[k].T @ (0.5 * (block + block.T)) @ Zs[k]
        return H

    # ---------------- for nlpsol ----------------
    def constraint(self, w: ca.MX) -> ca.MX:
        """g(w) as an expression for nlpsol's problem (evaluation only: its Jacobian is jac_g())."""
        return self.callbacks[0](w)

    def jac_g(self) -> ca.Function:
        """nlpsol's jac_g option: (x, p) -> (g, jac_g_x)."""
        return self.callbacks[1]


def carried_constraints(shooting: CarriedSpinShooting, n: int, peak: bool):
    """The decisions w, (w, U, dt, s, constraints, lower bounds, upper bounds) as shooting.lifted_constraints gives
    them, for the carried spin rates: the nodes hold the body and joint states."""
    w = ca.MX.sym("w", shooting.nw)
    U = ca.reshape(w[shooting.u_at:shooting.u_at + 4 * n], 4, n)
    lbg = [np.zeros(shooting.nb * n), [0.0]] + ([np.full(8 * n, -np.inf)] if peak else [])
    ubg = [np.zeros(shooting.nb * n), [np.inf]] + ([np.zeros(8 * n)] if peak else [])
    return w, U, w[-2], w[-1], [shooting.constraint(w)], lbg, ubg


class _Constraints(NumpyFunction):
    """w -> g. CasADi needs a Jacobian of it to build the solver (it forms the Lagrangian's gradient; without one
    that fails), the chained one; IPOPT's own Jacobian evaluations go through _ConstraintJacobian (a solve of the
    short problem evaluates this one never)."""

    def __init__(self, shooting: CarriedSpinShooting):
        self.shooting = shooting
        super().__init__("carried_spin_g", [("w", ca.Sparsity.dense(shooting.nw))],
                         [("g", ca.Sparsity.dense(shooting.ng))])

    def evaluate(self, w):
        return [self.shooting.g(w)]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jacobian = _Jacobian(self.shooting, name, inames, onames)   # kept: CasADi holds no Python reference
        return self._jacobian


class _Jacobian(NumpyFunction):
    """(w, g) -> d g / d w on the declared pattern: CasADi's form of a Jacobian takes the outputs as an input."""

    def __init__(self, shooting: CarriedSpinShooting, name: str, inames: list[str], onames: list[str]):
        self.shooting = shooting
        super().__init__(name, list(zip(inames, [ca.Sparsity.dense(shooting.nw), ca.Sparsity.dense(shooting.ng)])),
                         [(onames[0], shooting.sparsity)])

    def evaluate(self, w, g):
        return [self.shooting.jacobian(w)]


class _ConstraintJacobian(NumpyFunction):
    """nlpsol's jac_g: (x, p) -> (g, jac_g_x), one serial integration and one set of interval Jacobians."""

    def __init__(self, shooting: CarriedSpinShooting):
        self.shooting = shooting
        super().__init__("nlp_jac_g", [("x", ca.Sparsity.dense(shooting.nw)), ("p", ca.Sparsity(0, 1))],
                         [("g", ca.Sparsity.dense(shooting.ng)), ("jac_g_x", shooting.sparsity)])

    def evaluate(self, w, p):
        return [self.shooting.g(w), self.shooting.jacobian(w)]


class CarriedSpinHessian(NumpyFunction):
    """nlpsol's hess_lag for the carried transcription with solver.hessian = "differenced": lam_f times the
    objective's own Hessian (with the proximal term: `objective_part`, w -> matrix) plus the constraints'
    curvature (CarriedSpinShooting.constraint_curvature), upper triangle, dense (the chain couples every interval
    with the ones before it)."""

    def __init__(self, shooting: CarriedSpinShooting, objective_part: ca.Function):
        self.shooting, self.objective_part = shooting, objective_part
        super().__init__("nlp_hess_l", *hess_lag_io(shooting.nw, shooting.ng, ca.Sparsity.upper(shooting.nw)))

    def evaluate(self, w, p, lam_f, lam_g):
        return [np.triu(lam_f[0] * np.array(self.objective_part(w)) + self.shooting.constraint_curvature(w, lam_g))]
