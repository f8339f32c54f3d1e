"""ROS34PW2, the Rosenbrock-W method (solver.method = 3), through tests/c/solver_harness.c:
- order 3 at fixed steps on a linear and a nonlinear problem with the exact Jacobian, and still order 3 with a wrong
  one (0.5x, 2x, zero): the W property that lets it keep a Jacobian over many steps and calls;
- with F declared autonomous the Jacobian is kept: far fewer Jacobians than steps, also across calls when the caller
  keeps it, and a fresh one every call when it does not;
- explicit time dependence (not autonomous): a fresh Jacobian and dF/dt every step, order 3;
- stiff problems: few steps where DOPRI5 needs thousands, and the tolerance is met."""
import ctypes
import math

import numpy as np
import pytest
from solver_harness import compile_harness

DECAY, OSC, STIFF, VDP, TIMEDEP, CYCLE = 0, 1, 2, 3, 6, 7
DOPRI5, ROS34PW2 = 1, 3
_D = ctypes.POINTER(ctypes.c_double)


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    so = compile_harness(tmp_path_factory.mktemp("solver_w"))
    so.harness_run_w.restype = ctypes.c_int
    so.harness_run_w.argtypes = [ctypes.c_int, _D, ctypes.c_double, ctypes.c_double, ctypes.c_int, _D,
                                 ctypes.c_double, ctypes.c_double, _D, _D, _D, ctypes.c_double, ctypes.c_int,
                                 ctypes.c_char_p, ctypes.c_int]
    so.harness_workspace.restype = ctypes.c_size_t
    so.harness_run.restype = ctypes.c_int
    so.harness_run.argtypes = [ctypes.c_int, _D, ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_long,
                               ctypes.c_double, ctypes.c_int, _D, ctypes.c_double, ctypes.c_double, _D, _D, _D,
                               ctypes.c_char_p, ctypes.c_int]
    return so


def _p(a):
    return a.ctypes.data_as(_D)


class W:
    """One ROS34PW2 integration; keep: the caller's kept-Jacobian buffer (None: not kept between calls)."""

    def __init__(self, lib, problem, x0, par=0.0, jac_scale=1.0, autonomous=1, keep=True):
        self.lib, self.problem, self.jac_scale, self.autonomous = lib, problem, jac_scale, autonomous
        self.x = np.array(x0, dtype=float)
        self.par = np.atleast_1d(np.array(par, dtype=float))
        n = self.x.size
        self.work = np.zeros(lib.harness_workspace(ROS34PW2, n))
        self.keep = np.zeros(n * n) if keep else None
        self.stats = np.zeros(6)

    def run(self, t0, t1, tol=1e-6, h_max=1.0, h_first=0.0):
        if h_first:
            self.stats[4] = h_first
        msg = ctypes.create_string_buffer(256)
        rc = self.lib.harness_run_w(self.problem, _p(self.par), tol, h_max, self.x.size, _p(self.x), t0, t1,
                                    _p(self.work), None if self.keep is None else _p(self.keep), _p(self.stats),
                                    self.jac_scale, self.autonomous, msg, 256)
        assert rc == 0, msg.value.decode()
        return self

    steps = property(lambda self: int(self.stats[0]))
    rejected = property(lambda self: int(self.stats[1]))
    rhs_evals = property(lambda self: int(self.stats[2]))
    jac_evals = property(lambda self: int(self.stats[3]))


def fixed(lib, problem, x0, T, h, **kw):
    """Fixed steps: a tolerance nothing fails (every step accepted), h_max = h and the first step h."""
    w = W(lib, problem, x0, **kw).run(0.0, T, tol=1e10, h_max=h, h_first=h)
    assert w.rejected == 0 and w.steps == round(T / h)
    return w


def orders(errs):
    return [math.log2(errs[i] / errs[i + 1]) for i in range(len(errs) - 1)]


def cycle_exact(T, r0=0.5):
    r = 1 / math.sqrt(1 + (1 / r0**2 - 1) * math.exp(-2 * T))
    return np.array([r * math.cos(T), r * math.sin(T)])


@pytest.mark.parametrize("jac_scale", [1.0, 0.5, 2.0, 0.0])
def test_order_3_with_the_exact_and_with_a_wrong_jacobian(lib, jac_scale):
    T = 10.0
    e = [np.linalg.norm(fixed(lib, OSC, [1, 0], T, h, jac_scale=jac_scale).x - [math.cos(T), -math.sin(T)])
         for h in (0.05, 0.025, 0.0125)]
    for p in orders(e):
        assert abs(p - 3) < 0.1, (jac_scale, e)
    # nonlinear, exact solution known: every order condition up to 3 matters. The leading error term is small on
    # this problem (with the exact Jacobian the measured order tends to 4; with 2x it changes sign once in the
    # range), so the order is the least-squares slope over a factor 32 in h, not pair by pair. A wrong
    # coefficient gives 1 or 2.
    hs = np.array([0.04, 0.02, 0.01, 0.005, 0.0025, 0.00125])
    e = [np.linalg.norm(fixed(lib, CYCLE, [0.5, 0], 3.0, h, jac_scale=jac_scale).x - cycle_exact(3.0)) for h in hs]
    slope = np.polyfit(np.log(hs), np.log(e), 1)[0]
    assert slope > 2.5 and e[-1] < 2e-9, (jac_scale, slope, e)


def test_time_dependence_fresh_jacobian_every_step_order_3(lib):
    ex = math.exp(math.sin(5.0))
    runs = [fixed(lib, TIMEDEP, [1.0], 5.0, h, autonomous=0) for h in (0.1, 0.05, 0.025)]
    for p in orders([abs(w.x[0] - ex) for w in runs]):
        assert p > 2.7
    for w in runs:
        assert w.jac_evals == w.steps                    # dF/dt and J belong to each step's start
        assert w.rhs_evals == 5 * w.steps               # 4 stages + the dF/dt difference


def test_autonomous_keeps_the_jacobian(lib):
    T = 10.0
    w = W(lib, CYCLE, [0.5, 0]).run(0.0, T, tol=1e-8, h_max=10)
    assert np.linalg.norm(w.x - cycle_exact(T)) < 1e-6
    assert w.rhs_evals == 4 * (w.steps + w.rejected) + 1        # 4 F per attempt, + the initial-step probe
    assert w.jac_evals <= w.steps / 10 + w.rejected + 1, (w.jac_evals, w.steps, w.rejected)


def test_the_kept_jacobian_crosses_calls_only_when_the_caller_keeps_it(lib):
    kept, fresh = W(lib, CYCLE, [0.5, 0]), W(lib, CYCLE, [0.5, 0], keep=False)
    for k in range(200):
        kept.run(k * 0.01, (k + 1) * 0.01, tol=1e-6, h_max=1.0)
        fresh.run(k * 0.01, (k + 1) * 0.01, tol=1e-6, h_max=1.0)
    assert fresh.jac_evals >= 200                     # each call starts with a fresh one
    assert kept.jac_evals <= 200 / 10, kept.jac_evals
    for w in (kept, fresh):
        assert np.linalg.norm(w.x - cycle_exact(2.0)) < 1e-5


def test_stiff_problems(lib):
    """Linear stiff (eigenvalues -1, -1e6) and Van der Pol mu = 1000: a few hundred steps where DOPRI5 needs
    thousands, and the results within the tolerance's reach of exact / Radau."""
    T, lam, tol = 1.0, 1e6, 1e-6
    w = W(lib, STIFF, [1, 2], par=lam).run(0.0, T, tol=tol, h_max=T)
    exact = math.exp(-T) + np.array([0.0, math.exp(-lam * T)])
    assert w.steps < 300
    assert np.max(np.abs(w.x - exact)) < 10 * tol * (1 + math.exp(-T))
    T, mu = 100.0, 1000.0
    w = W(lib, VDP, [2, 0], par=mu).run(0.0, T, tol=tol, h_max=T)
    d_steps = np.zeros(5)
    x = np.array([2.0, 0.0])
    work = np.zeros(lib.harness_workspace(DOPRI5, 2))
    msg = ctypes.create_string_buffer(256)
    assert lib.harness_run(VDP, _p(np.array([mu])), DOPRI5, tol, T, 10**7, 1e9, 2, _p(x), 0.0, T, _p(work),
                           _p(d_steps), _p(np.zeros(2)), msg, 256) == 0
    assert w.steps * 20 < d_steps[0], (w.steps, d_steps[0])
    solve_ivp = pytest.importorskip("scipy.integrate").solve_ivp
    ref = solve_ivp(lambda t, x: [x[1], mu * (1 - x[0] ** 2) * x[1] - x[0]], (0, T), [2.0, 0.0], method="Radau",
                    rtol=1e-11, atol=1e-11).y[:, -1]
    assert np.all(np.abs(w.x - ref) < 100 * tol * (1 + np.abs(ref))), (w.x, ref)


@pytest.mark.parametrize("tol", [1e-4, 1e-6, 1e-8])
def test_meets_the_tolerance_on_the_oscillator(lib, tol):
    T = 10.0
    w = W(lib, OSC, [1, 0]).run(0.0, T, tol=tol, h_max=10)
    assert np.linalg.norm(w.x - [math.cos(T), -math.sin(T)]) < 10 * tol
