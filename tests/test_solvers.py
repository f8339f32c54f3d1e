"""The embedded solvers (fmu_src/solver.c) and dense LU (fmu_src/linalg.c), through the C harness
tests/c/solver_harness.c compiled with the FMU's strict flags and called with ctypes."""
import ctypes
import math
import re

import numpy as np
import pytest
from solver_harness import compile_harness


RK4, DOPRI5, RODAS4 = 0, 1, 2
NAMES = {RK4: "rk4", DOPRI5: "dopri5", RODAS4: "rodas4"}
# harness problems
DECAY, OSC, STIFF, VDP, FAILING, NAN, TIMEDEP, CYCLE = range(8)

_D = ctypes.POINTER(ctypes.c_double)
GUARD = 16
SENTINEL = 12345.678


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    so = compile_harness(tmp_path_factory.mktemp("solver"))
    so.harness_workspace.restype = ctypes.c_size_t
    so.harness_workspace.argtypes = [ctypes.c_int, ctypes.c_int]
    so.harness_run.restype = ctypes.c_int
    so.harness_run.argtypes = [ctypes.c_int, _D, ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_long,
                               ctypes.c_double, ctypes.c_int, _D, ctypes.c_double, ctypes.c_double, _D, _D, _D,
                               ctypes.c_char_p, ctypes.c_int]
    so.harness_lu_solve.restype = ctypes.c_int
    so.harness_lu_solve.argtypes = [ctypes.c_int, _D, _D]
    so.harness_chol_solve.restype = ctypes.c_int
    so.harness_chol_solve.argtypes = [ctypes.c_int, _D, _D]
    so.harness_chol_solve_perm.restype = ctypes.c_int
    so.harness_chol_solve_perm.argtypes = [ctypes.c_int, _D, ctypes.POINTER(ctypes.c_int), _D, _D]
    return so


def _p(a):
    return a.ctypes.data_as(_D)


class Run:
    def __init__(self, rc, x, stats, t_max_seen, msg):
        self.rc, self.x, self.msg, self.t_max_seen = rc, x, msg, t_max_seen
        self.steps, self.rejected, self.rhs_evals, self.jac_evals = (int(v) for v in stats[:4])
        self.h_next = stats[4]
        self.stats = stats


def run(lib, problem, method, x0, t0, t1, tol=1e-6, h_max=1.0, par=0.0, stats=None, max_steps=500000,
        max_wall=1e9):
    """Integrate; `stats` (steps, rejected, rhs_evals, jac_evals, h_next) is updated in place if given.
    max_steps and max_wall are the call's budget (attempted steps, wall-clock seconds).
    The workspace is exactly solver_workspace_size() long plus a guard that must stay untouched."""
    x = np.array(x0, dtype=float)
    n = x.size
    size = lib.harness_workspace(method, n)
    work = np.full(size + GUARD, SENTINEL)
    st = np.zeros(5) if stats is None else stats
    info = np.zeros(2)
    msg = ctypes.create_string_buffer(256)
    parr = np.atleast_1d(np.array(par, dtype=float))
    rc = lib.harness_run(problem, _p(parr), method, tol, h_max, max_steps, max_wall, n, _p(x), t0, t1, _p(work),
                         _p(st), _p(info), msg, 256)
    assert np.all(work[size:] == SENTINEL), "solver wrote past its workspace"
    return Run(rc, x, st.copy(), info[0], msg.value.decode())


def fixed(lib, problem, method, x0, T, h, par=0.0):
    """Adaptive methods forced to fixed steps: huge tol (every step accepted), h_max = h, and h_next = h so the
    first step is not the initial-step heuristic's."""
    st = np.array([0, 0, 0, 0, h], dtype=float)
    r = run(lib, problem, method, x0, 0.0, T, tol=1e10, h_max=h, par=par, stats=st)
    assert r.rc == 0, r.msg
    assert r.rejected == 0 and r.steps == round(T / h)
    return r.x


def osc_exact(T):
    return np.array([math.cos(T), -math.sin(T)])


def cycle_exact(T, r0=0.5):
    r = 1 / math.sqrt(1 + (1 / r0**2 - 1) * math.exp(-2 * T))
    return np.array([r * math.cos(T), r * math.sin(T)])


def orders(errs):
    return [math.log2(errs[i] / errs[i + 1]) for i in range(len(errs) - 1)]


# ---------------------------------------------------------------------------------------------------------------
# convergence orders


def test_rk4_order_4(lib):
    T = 10.0
    e_osc = [np.linalg.norm(run(lib, OSC, RK4, [1, 0], 0, T, h_max=h).x - osc_exact(T)) for h in (0.1, 0.05, 0.025)]
    e_cyc = [np.linalg.norm(run(lib, CYCLE, RK4, [0.5, 0], 0, 3.0, h_max=h).x - cycle_exact(3.0))
             for h in (0.05, 0.025, 0.0125)]
    for p in orders(e_osc) + orders(e_cyc):
        assert abs(p - 4) < 0.3, (e_osc, e_cyc)


def test_dopri5_order_5_fixed_steps(lib):
    T = 10.0
    e = [np.linalg.norm(fixed(lib, OSC, DOPRI5, [1, 0], T, h) - osc_exact(T)) for h in (0.1, 0.05, 0.025)]
    for p in orders(e):
        assert abs(p - 5) < 0.3, e
    # nonlinear: the linear oscillator only sees the stability polynomial; a wrong coupling coefficient would
    # show here as order <= 4 (the measured ratio is pre-asymptotic, ~2^5.8)
    e = [np.linalg.norm(fixed(lib, CYCLE, DOPRI5, [0.5, 0], 3.0, h) - cycle_exact(3.0)) for h in (0.1, 0.05, 0.025)]
    for p in orders(e):
        assert 4.7 < p < 6.5, e


def test_rodas4_order_4_fixed_steps(lib):
    T = 10.0
    e = [np.linalg.norm(fixed(lib, OSC, RODAS4, [1, 0], T, h) - osc_exact(T)) for h in (0.1, 0.05, 0.025)]
    for p in orders(e):
        assert abs(p - 4) < 0.3, e
    # nonlinear problem with exact solution: all the order conditions up to 4 matter
    e = [np.linalg.norm(fixed(lib, CYCLE, RODAS4, [0.5, 0], 3.0, h) - cycle_exact(3.0)) for h in (0.05, 0.025, 0.0125)]
    for p in orders(e):
        assert abs(p - 4) < 0.3, e
    # explicit time dependence goes through the d_i * h * F_t terms (F_t by a finite difference): still order >= 4
    ex = math.exp(math.sin(5.0))
    e = [abs(fixed(lib, TIMEDEP, RODAS4, [1.0], 5.0, h)[0] - ex) for h in (0.2, 0.1, 0.05)]
    for p in orders(e):
        assert p > 3.7, e


def test_rodas4_tolerance_sweep(lib):
    T = 10.0
    tols = [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]
    errs = [np.linalg.norm(run(lib, CYCLE, RODAS4, [0.5, 0], 0, T, tol=tol, h_max=10).x - cycle_exact(T))
            for tol in tols]
    assert all(a > b for a, b in zip(errs, errs[1:])), errs
    slope = np.polyfit(np.log(tols), np.log(errs), 1)[0]
    assert 0.75 < slope < 1.25, (slope, errs)
    assert all(e < 10 * tol for e, tol in zip(errs, tols)), errs


@pytest.mark.parametrize("method", [DOPRI5, RODAS4])
@pytest.mark.parametrize("tol", [1e-4, 1e-6, 1e-8, 1e-10])
def test_adaptive_meets_tolerance_on_oscillator(lib, method, tol):
    T = 10.0
    r = run(lib, OSC, method, [1, 0], 0, T, tol=tol, h_max=10)
    assert r.rc == 0, r.msg
    err = np.linalg.norm(r.x - osc_exact(T))
    assert err < 10 * tol, (err, tol)
    assert r.steps > 5


# ---------------------------------------------------------------------------------------------------------------
# stiffness


def test_stiff_linear_rodas4_few_steps_and_accurate(lib):
    T, lam, tol = 1.0, 1e6, 1e-6
    d = run(lib, STIFF, DOPRI5, [1, 2], 0, T, tol=tol, h_max=T, par=lam)
    r = run(lib, STIFF, RODAS4, [1, 2], 0, T, tol=tol, h_max=T, par=lam)
    assert d.rc == 0 and r.rc == 0, (d.msg, r.msg)
    assert r.steps * 20 < d.steps, (r.steps, d.steps)
    assert r.steps < 200
    exact = math.exp(-T) + np.array([0.0, math.exp(-lam * T)])
    assert np.max(np.abs(r.x - exact)) < 10 * tol * (1 + math.exp(-T))
    assert r.jac_evals == r.steps   # one Jacobian per accepted step: error-test rejections reuse it


def test_van_der_pol_mu_1000(lib):
    T, mu, tol = 100.0, 1000.0, 1e-6
    d = run(lib, VDP, DOPRI5, [2, 0], 0, T, tol=tol, h_max=T, par=mu)
    r = run(lib, VDP, RODAS4, [2, 0], 0, T, tol=tol, h_max=T, par=mu)
    assert d.rc == 0 and r.rc == 0, (d.msg, r.msg)
    assert r.steps * 20 < d.steps, (r.steps, d.steps)
    # independent reference: scipy's Radau at a tight tolerance
    solve_ivp = pytest.importorskip("scipy.integrate").solve_ivp
    ref = solve_ivp(lambda t, x: [x[1], mu * (1 - x[0] ** 2) * x[1] - x[0]], (0, T), [2.0, 0.0], method="Radau",
                    rtol=1e-11, atol=1e-11).y[:, -1]
    scale = tol * (1 + np.abs(ref))
    assert np.all(np.abs(r.x - ref) < 100 * scale), (r.x, ref)
    assert np.all(np.abs(d.x - ref) < 100 * scale), (d.x, ref)


# ---------------------------------------------------------------------------------------------------------------
# the interval is covered exactly


@pytest.mark.parametrize("method", [RK4, DOPRI5, RODAS4])
@pytest.mark.parametrize("t0,span,h_max,rk4_steps", [
    (0.0, 0.010000000000000009, 0.001, 10),   # a multiple of h_max up to rounding: no sliver step
    (1.0, 0.010000000000000009, 0.001, 10),
    (0.3, 0.0004, 0.001, 1),                  # shorter than h_max
    (0.1, 0.0105, 0.001, 11),                 # a genuine remainder: shortened last step, never dropped
])
def test_last_step_lands_on_t1(lib, method, t0, span, h_max, rk4_steps):
    t1 = t0 + span
    # FAILING with a threshold out of reach is x0' = 1, x1' = -x1: x0 - x0(t0) measures the covered interval
    r = run(lib, FAILING, method, [0.0, 1.0], t0, t1, tol=1e-8, h_max=h_max, par=1e9)
    assert r.rc == 0, r.msg
    assert r.t_max_seen == t1          # last stage at t1 exactly, never beyond
    assert r.x[0] == pytest.approx(t1 - t0, rel=1e-13, abs=1e-17)
    assert r.x[1] == pytest.approx(math.exp(-(t1 - t0)), rel=1e-8)
    if method == RK4:
        assert r.steps == rk4_steps
        assert r.rhs_evals == 4 * rk4_steps


# ---------------------------------------------------------------------------------------------------------------
# failures


@pytest.mark.parametrize("problem,reason", [(FAILING, "right-hand side failed"), (NAN, "non-finite")])
@pytest.mark.parametrize("method", [RK4, DOPRI5, RODAS4])
def test_failing_rhs(lib, problem, reason, method):
    thr = 0.53
    r = run(lib, problem, method, [0.0, 1.0], 0.0, 1.0, tol=1e-6, h_max=0.1, par=thr)
    assert r.rc != 0
    assert r.msg.startswith(NAMES[method] + ":"), r.msg
    assert reason in r.msg, r.msg
    assert np.all(np.isfinite(r.x))
    m = re.search(r"at t = ([-0-9.eE+]+)", r.msg)
    assert m, r.msg
    t_fail = float(m.group(1))
    # the state is the last accepted one: x0 = t there (x0' = 1 is integrated exactly), below the threshold,
    # and x1 = exp(-t) to the tolerance
    assert r.x[0] <= thr
    assert r.x[0] == pytest.approx(t_fail, abs=1e-12)
    assert r.x[1] == pytest.approx(math.exp(-t_fail), rel=1e-5)
    if method == RK4:
        assert r.x[0] == pytest.approx(0.5, abs=1e-15)   # failed in the step from 0.5 to 0.6
        assert r.steps == 5
    else:
        assert "step size underflow" in r.msg and "h = " in r.msg
        assert r.x[0] > thr - 1e-6   # it got as close as the step size allows
        assert r.rejected > 0


def test_too_many_steps(lib):
    r = run(lib, STIFF, DOPRI5, [1, 2], 0, 10.0, tol=1e-6, h_max=10, par=1e6)
    assert r.rc != 0
    assert r.msg.startswith("dopri5: too many steps"), r.msg
    assert "at t = " in r.msg and "h = " in r.msg
    assert r.steps + r.rejected == 500000
    assert np.all(np.isfinite(r.x))
    assert 0 < r.x[0] < 1


@pytest.mark.parametrize("method", [RK4, DOPRI5, RODAS4])
@pytest.mark.parametrize("h_max,t1", [(1e-300, 0.5), (0.01, 1e300), (1e-3, 101.0)])
def test_an_interval_beyond_the_step_budget_is_refused_before_any_work(lib, method, h_max, t1):
    """Every method needs at least (t1 - t0) / h_max steps; past max_steps the call fails at once, x untouched
    (RK4 used to convert the step count to a long out of range and return success having done nothing)."""
    r = run(lib, DECAY, method, [1.0], 0, t1, h_max=h_max, max_steps=100000)
    assert r.rc != 0
    assert "needs at least" in r.msg and "more than solver.max_steps = 100000" in r.msg, r.msg
    assert r.steps == r.rejected == r.rhs_evals == 0
    assert r.x[0] == 1.0


@pytest.mark.parametrize("method", [RK4, DOPRI5, RODAS4])
def test_exactly_the_step_budget_is_enough(lib, method):
    r = run(lib, DECAY, method, [1.0], 0, 1.0, h_max=0.01, par=1.0, max_steps=100)
    assert r.rc == 0, r.msg
    assert r.x[0] == pytest.approx(math.exp(-1), rel=1e-6)


def test_the_attempted_step_budget_stops_the_call(lib):
    r = run(lib, STIFF, DOPRI5, [1, 2], 0, 10.0, tol=1e-6, h_max=10, par=1e6, max_steps=250)
    assert r.rc != 0
    assert r.msg.startswith("dopri5: too many steps (more than solver.max_steps = 250 in one call)"), r.msg
    assert r.steps + r.rejected == 250


@pytest.mark.parametrize("method", [RK4, DOPRI5, RODAS4])
def test_the_wall_clock_budget_stops_the_call(lib, method):
    """A budget far below the work the call needs: the call fails with the budget named, having taken steps,
    and x is the last accepted state (finite). No time is asserted: the reason is."""
    r = run(lib, VDP, method, [2.0, 0.0], 0, 3000.0, tol=1e-10, h_max=1e-4 if method == RK4 else 1.0, par=1000.0,
            max_steps=10**8, max_wall=1e-3)
    assert r.rc != 0
    assert "wall-clock budget of 0.001 s is spent" in r.msg, r.msg
    assert r.steps > 0 and np.all(np.isfinite(r.x))


def test_budget_settings_are_checked(lib):
    r = run(lib, DECAY, DOPRI5, [1.0], 0, 1, max_steps=0)
    assert r.rc != 0 and "max_steps must be >= 1" in r.msg
    r = run(lib, DECAY, DOPRI5, [1.0], 0, 1, max_wall=float("nan"))
    assert r.rc != 0 and "max_wall must be positive and finite" in r.msg


def test_invalid_settings(lib):
    r = run(lib, DECAY, 7, [1.0], 0, 1)
    assert r.rc != 0 and "unknown method" in r.msg
    r = run(lib, DECAY, RK4, [1.0], 0, 1, h_max=0.0)
    assert r.rc != 0 and r.msg.startswith("rk4:")
    r = run(lib, DECAY, RODAS4, [1.0], 0, 1, tol=0.0)
    assert r.rc != 0 and r.msg.startswith("rodas4:")
    r = run(lib, DECAY, DOPRI5, [1.0], 1, 0)
    assert r.rc != 0 and "interval" in r.msg


# ---------------------------------------------------------------------------------------------------------------
# statistics and the carried step size


@pytest.mark.parametrize("method", [RK4, DOPRI5, RODAS4])
def test_stats_cumulative_and_h_next(lib, method):
    st = np.array([100, 7, 1000, 50, 0.0])   # counts from earlier calls must be kept, never reset
    x = np.array([1.0, 0.0])
    prev = st.copy()
    dt = 0.01
    for k in range(50):
        r = run(lib, OSC, method, x, k * dt, (k + 1) * dt, tol=1e-8, h_max=1.0 if method else 0.004, stats=st)
        assert r.rc == 0, r.msg
        x = r.x
        assert st[0] > prev[0] and st[2] > prev[2] and st[1] >= prev[1]
        if method == RODAS4:
            assert st[3] > prev[3]
        else:
            assert st[3] == prev[3]
        if method != RK4:
            assert 0 < st[4] <= 1.0
        prev = st.copy()
    assert np.linalg.norm(x - osc_exact(50 * dt)) < 1e-6
    if method != RK4:
        # h_next is carried across the communication steps: one step each once it exceeds dt
        assert st[0] - 100 <= 50 + 10
        assert st[4] > dt


def test_initial_step_from_h_next(lib):
    # a given h_next is the first step (here the whole interval: one step, 1 + 6 evaluations); without one the
    # initial guess costs a probe evaluation and is more careful
    st = np.array([0, 0, 0, 0, 0.5])
    r = run(lib, DECAY, DOPRI5, [1.0], 0, 0.5, tol=1e-3, h_max=1.0, par=1.0, stats=st)
    assert r.rc == 0 and (r.steps, r.rejected, r.rhs_evals) == (1, 0, 7)
    assert r.x[0] == pytest.approx(math.exp(-0.5), rel=1e-4)
    assert r.h_next >= 0.5
    r2 = run(lib, DECAY, DOPRI5, [1.0], 0, 0.5, tol=1e-3, h_max=1.0, par=1.0)
    assert r2.rc == 0 and r2.h_next > 0
    assert r2.steps > 1 and r2.rhs_evals == 1 + 1 + 6 * (r2.steps + r2.rejected)


# ---------------------------------------------------------------------------------------------------------------
# LU


def test_lu_random_17(lib):
    rng = np.random.default_rng(17)
    n = 17
    a = rng.standard_normal((n, n))
    x_true = rng.standard_normal(n)
    b = a @ x_true
    acol = np.asfortranarray(a).ravel(order="F").copy()
    bb = b.copy()
    assert lib.harness_lu_solve(n, _p(acol), _p(bb)) == 0
    assert np.linalg.norm(bb - x_true) / np.linalg.norm(x_true) < 1e-12
    assert np.linalg.norm(a @ bb - b) / np.linalg.norm(b) < 1e-13
    # pivoting is needed: a zero (1,1) element must not matter
    a2 = a.copy()
    a2[0, 0] = 0.0
    b2 = a2 @ x_true
    acol = a2.ravel(order="F").copy()
    assert lib.harness_lu_solve(n, _p(acol), _p(b2)) == 0
    assert np.linalg.norm(b2 - x_true) / np.linalg.norm(x_true) < 1e-12


def test_lu_reports_singular(lib):
    rng = np.random.default_rng(3)
    n = 17
    a = rng.standard_normal((n, n))
    a[5, :] = a[2, :]               # two equal rows: rank n-1, the elimination produces an exact zero pivot
    acol = a.ravel(order="F").copy()
    b = np.ones(n)
    assert lib.harness_lu_solve(n, _p(acol), _p(b)) == 1
    z = np.zeros((4, 4)).ravel(order="F")
    assert lib.harness_lu_solve(4, _p(z), _p(np.ones(4))) == 1
    m = np.eye(3)
    m[1, 1] = np.nan
    assert lib.harness_lu_solve(3, _p(m.ravel(order="F").copy()), _p(np.ones(3))) == 1


def test_cholesky_solves_the_rovers_mass_matrix_and_refuses_what_is_not_positive_definite(lib):
    """linalg_chol_factor_perm/solve in the natural order (the FMU's mass-matrix solve): equal to numpy on
    the 3D rover's own mass matrix at random poses (only the lower triangle read), and 1, not a wrong answer, for an
    indefinite, a singular or a NaN matrix (the glue then falls back to the pivoting LU)."""
    from cedra.models.scene import load_shipped
    from cedra.reports.common import Problem
    prob = Problem(load_shipped("flat3d"))
    q0 = prob.settle()
    rng = np.random.default_rng(17)
    for _ in range(10):
        m = np.array(prob.fns["cedra_M"](q0 + rng.normal(0, 0.05, prob.nq), prob.par))
        x_true = rng.standard_normal(prob.nq)
        b = m @ x_true
        upper_garbage = m + np.triu(rng.standard_normal(m.shape), 1)     # the upper triangle is never read
        bb = b.copy()
        assert lib.harness_chol_solve(prob.nq, _p(upper_garbage.ravel(order="F").copy()), _p(bb)) == 0
        assert np.linalg.norm(bb - np.linalg.solve(m, b)) / np.linalg.norm(x_true) < 1e-12
    indefinite = np.diag([2.0, 1.0, -1e-3, 4.0])
    singular = np.array([[1.0, 1.0], [1.0, 1.0]])
    nan = np.eye(3)
    nan[2, 2] = np.nan
    for a in (indefinite, singular, nan):
        assert lib.harness_chol_solve(a.shape[0], _p(a.ravel(order="F").copy()), _p(np.ones(a.shape[0]))) == 1


def test_the_mass_matrix_factor_in_its_elimination_order_solves_and_keeps_the_zeros(lib):
    """linalg_chol_factor_perm/solve_perm in cedra.fmu.mass_order's order (the FMU's mass-matrix solve): equal to
    numpy on the 3D rover's own M at random poses, refusing what is not positive definite; and the order does what it
    is for: the factor keeps M's zeros (little fill), where the natural order fills them in."""
    from cedra.fmu.mass_order import elimination_order
    from cedra.models.scene import load_shipped
    from cedra.reports.common import Problem
    sc = load_shipped("hills3d")
    prob = Problem(sc)
    order = elimination_order(sc.spec())
    assert sorted(order) == list(range(prob.nq))
    q0 = prob.settle()
    rng = np.random.default_rng(23)
    n = prob.nq
    fill = {}
    for name, perm in (("natural", list(range(n))), ("mass_order", order)):
        p = (ctypes.c_int * n)(*perm)
        nz_m = nz_l = 0
        for _ in range(10):
            m = np.array(prob.fns["cedra_M"](q0 + rng.normal(0, 0.2, n), prob.par))
            x_true = rng.standard_normal(n)
            b, l = m @ x_true, np.zeros(n * n)
            assert lib.harness_chol_solve_perm(n, _p(m.ravel(order="F").copy()), p, _p(b), _p(l)) == 0
            assert np.linalg.norm(b - x_true) / np.linalg.norm(x_true) < 1e-12
            L = np.tril(l.reshape(n, n, order="F"))
            mp = m[np.ix_(perm, perm)]
            assert np.allclose(L @ L.T, mp, rtol=0, atol=1e-12 * np.abs(m).max())
            nz_m += np.count_nonzero(np.tril(mp))
            nz_l += np.count_nonzero(L)
        fill[name] = nz_l / nz_m
    assert fill["mass_order"] < 1.15 and fill["natural"] > 1.3, fill
    for a in (np.diag([2.0, 1.0, -1e-3, 4.0]), np.array([[1.0, 1.0], [1.0, 1.0]])):
        p = (ctypes.c_int * a.shape[0])(*range(a.shape[0])[::-1])
        assert lib.harness_chol_solve_perm(a.shape[0], _p(a.ravel(order="F").copy()), p, _p(np.ones(a.shape[0])),
                                           _p(np.zeros(a.size))) == 1
