"""Switch location and the reduced stage solve at the solver level (fmu_src/solver.c through tests/c/solver_harness.c):
- the RODAS4 stage system solved with the n2 x n2 Schur complement of the second-order structure x = [q, u, z]
  equals the dense n x n solve to 1e-12, on the rover's own Jacobians at random states (bump2d, flat3d);
- a touchdown inside a step is located to 1e-9 s or better by the adaptive solvers with a switch-location
  callback (solver_locate_switches): a ball dropped on the compliant contact law, whose force jumps by d |v| at
  touchdown; without location no accepted step is that short around it."""
import ctypes
import math

import numpy as np
import pytest
from solver_harness import compile_harness

DOPRI5, RODAS4 = 1, 2
_D = ctypes.POINTER(ctypes.c_double)


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    so = compile_harness(tmp_path_factory.mktemp("solver_events"))
    so.harness_stage_solve.restype = ctypes.c_int
    so.harness_stage_solve.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_double, _D, _D, _D, _D, _D, _D]
    so.harness_ball.restype = ctypes.c_int
    so.harness_ball.argtypes = [ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_double,
                                ctypes.c_int, ctypes.c_int, _D, ctypes.c_char_p, ctypes.c_int]
    return so


def _p(a):
    return a.ctypes.data_as(_D)


@pytest.mark.parametrize("mass_rows", [False, True], ids=["A,B rows", "mass rows"])
@pytest.mark.parametrize("scene", ["bump2d", "flat3d"])
def test_reduced_stage_solve_equals_full_solve(lib, scene, mass_rows):
    """mass rows: the reduced solve is handed what the FMU's Jacobian callback gives (solver.h mass_rows), the u rows
    as M A, M B with the rover's own mass matrix M at the state, and must still solve the true Jacobian's system."""
    from cedra.reports.common import Problem
    from cedra.models.scene import load_shipped
    prob = Problem(load_shipped(scene))
    q0 = prob.settle()
    rng = np.random.default_rng(13)
    nq, n = prob.nq, prob.nx
    worst = 0.0
    for k in range(8):
        x = prob.x0(q0 + rng.normal(0, 2e-3, nq), rng.normal(0, 0.3, nq))
        J = np.array(prob.jac(x, np.concatenate([prob.inp0, prob.par])))
        # the structure the reduced solve relies on: q' = u, nothing depends on the integral state
        assert np.array_equal(J[:nq, :], np.hstack([np.zeros((nq, nq)), np.eye(nq), np.zeros((nq, n - 2 * nq))]))
        assert not J[:, 2 * nq:].any()
        for h in (1e-6, 1e-4, 1e-2):
            fac = 1.0 / (h * 0.25)        # RODAS4's gamma
            b = rng.normal(0, 1, n)
            full, red = np.empty(n), np.empty(n)
            Jc = np.asfortranarray(J).ravel(order="F")
            if mass_rows:
                M = np.array(prob.fns["cedra_M"](x[:nq], prob.par))
                Jm = J.copy()
                Jm[nq:2 * nq, :] = M @ J[nq:2 * nq, :]
                Jm, Mf = np.asfortranarray(Jm).ravel(order="F"), np.asfortranarray(M).ravel(order="F")
                Mp = _p(Mf)              # (Mf keeps the buffer alive through the call)
            else:
                Jm, Mp = Jc, None
            rc = lib.harness_stage_solve(n, nq, fac, _p(Jc), _p(Jm), Mp, _p(b), _p(full), _p(red))
            assert rc == 0
            ref = np.linalg.solve(fac * np.eye(n) - J, b)
            err = np.max(np.abs(red - full)) / np.max(np.abs(full))
            assert np.max(np.abs(full - ref)) / np.max(np.abs(ref)) <= 1e-12
            assert err <= 1e-12, (scene, k, h, err)
            worst = max(worst, err)
    print(f"{scene}: reduced vs full stage solve, worst relative difference {worst:.2e}")


def ball(lib, method, with_locate, z0=0.1, tol=1e-6, n2=0):
    out = np.zeros(8)
    msg = ctypes.create_string_buffer(300)
    rc = lib.harness_ball(method, tol, 0.01, z0, 0.3, with_locate, n2, _p(out), msg, 300)
    assert rc == 0, msg.value.decode()
    return out


# n2: RODAS4's reduced (Schur) stage solve on the ball's [q, u] split; dopri5 has no linear solve to reduce
@pytest.mark.parametrize("method,n2", [(DOPRI5, 0), (RODAS4, 0), (RODAS4, 1)])
def test_touchdown_inside_a_step_is_located(lib, method, n2):
    z0 = 0.1
    t_touch = math.sqrt(2 * z0 / 9.81)          # free fall until z = 0
    out = ball(lib, method, 1, z0, n2=n2)
    located, t0, t1, cuts = out[0], out[1], out[2], out[3]
    assert located == 1
    assert t0 <= t_touch + 1e-12 and t_touch - 1e-12 <= t1, (t0, t_touch, t1)
    assert t1 - t0 <= 1e-9, f"the step across the touchdown is {t1 - t0:.3g} s long"
    assert cuts >= 1
    # the located run and one without location agree on where the ball ends up within their tolerance, and
    # the free fall before touchdown is exact up to the solver's error
    free = ball(lib, method, 0, z0, n2=n2)
    assert abs(out[6] - free[6]) < 1e-4
    print(f"method {method}: touchdown at {t_touch:.12f} s located in [{t0:.12f}, {t1:.12f}] "
          f"({t1 - t0:.2e} s), {int(cuts)} cuts, steps {int(out[4])} (rejected {int(out[5])}); without location: "
          f"steps {int(free[4])} (rejected {int(free[5])})")


def _locate(lib, s0, s1, t=0.0, t_new=1e-3, loc_tol=1e-10):
    f = lib.solver_locate_switches
    f.restype = ctypes.c_double
    f.argtypes = [ctypes.c_int, _D, _D, ctypes.c_double, ctypes.c_double, ctypes.c_double,
                  ctypes.POINTER(ctypes.c_int)]
    which = ctypes.c_int(-7)
    a, b = np.array([s0], float), np.array([s1], float)
    return f(1, _p(a), _p(b), t, t_new, loc_tol, ctypes.byref(which)), which.value


def test_a_cut_is_aimed_a_quarter_tolerance_short_of_the_linear_estimate(lib):
    len_, which = _locate(lib, -1.0, 3.0)
    assert which == 0 and abs(len_ - (0.25e-3 - 0.25e-10)) < 1e-18
    assert _locate(lib, 1.0, 2.0) == (1e-3, -1)                 # no crossing: the whole step
    assert _locate(lib, 1.0, -1.0, t_new=1e-10)[0] == math.inf  # a step within the tolerance: located


def test_an_estimate_at_the_end_of_the_step_is_no_cut(lib):
    """s jumping inside a step (a contact slot that begins to hold a newborn maximum: from its absent value
    -1e5 to a small positive one) puts the linear estimate at the step's end. A cut that shortens the step by no
    more than loc_tol would find the estimate at the end again at every retry: no cut, the step stands as it is
    (its error test decides). Estimates further from the end still cut; that a retried cut does not come nearer
    is the FMU glue's to see (model_locate_step: the switch is left to the error control for the call)."""
    len_, which = _locate(lib, -1e5, 0.001, t_new=1e-3)
    assert which == 0 and len_ == 1e-3
    len_, _ = _locate(lib, -1e5, 0.229, t_new=1e-3)
    assert len_ < 1e-3 - 1e-9
