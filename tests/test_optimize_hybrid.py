"""Hybrid multiple shooting (method = "hybrid"): the events of a run located on their laws, a mode sequence that
cannot be formed failing with file, key and reason, a phase's sensitivities against finite differences (CVODES
Jacobians in several parameter directions at once are reported wrong: github.com/casadi/casadi/issues/4383), and
a wheel dropped onto compliant ground whose touch-down time is a decision: its optimum against a brute-force search over that time, each candidate solved in
closed form (the phases are linear, so the torques of a fixed touch-down time are a least-squares solution)."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import minimize_scalar

from cedra import optimize
from cedra.optimize import hybrid
from cedra.optimize.modes import DEPTH, FORCE, HybridSystem
from model_harness import central_differences

REPO = Path(__file__).resolve().parents[1]
MASS, K, G = 1.0, 1000.0, 9.81          # kg, N/m, m/s^2: the wheel's mass and the ground's stiffness
Z0 = 0.02                                 # m: the wheel's bottom above the ground at the start, at rest
N, DT = 4, 0.1                            # the control grid


class DroppedWheel(HybridSystem):
    """A wheel of mass MASS dropped onto the FMU's compliant law (stiffness K, damping d), a vertical force u its
    control: x = [z, z'] with z the height of its bottom (the penetration is -z)."""
    nx, nu, laws, tol = 2, 1, ["wheel contact"], 1e-10

    def __init__(self, damping: float):
        self.d = damping

    def ode(self, x, u, on):
        return ca.vertcat(x[1], -G + u[0] / MASS + on[0] * (K * -x[0] - self.d * x[1]) / MASS)

    def branches(self, x):
        return -x[0], -x[0] - self.d / K * x[1]


def open_loop(system, U):
    x0 = np.array([[Z0], [0.0]])
    return np.c_[x0, system.simulate(x0, U, DT, resync=False).ends]


def closed_form(damping: float, z_end: float, tau: float):
    """The least energy dt sum u_k^2 with the touch-down at tau and the wheel at rest at z_end at N DT: every
    phase's map is affine in u (its matrix exponential), so the guard and the end condition are linear in u and
    the optimum is the least-norm solution."""
    def phase(on, h):
        Z = np.zeros((4, 4))
        Z[:2, :2] = [[0, 1], [-on * K / MASS, -on * damping / MASS]]
        Z[:2, 2], Z[:2, 3] = [0, 1 / MASS], [0, -G]
        E = expm(Z * h)
        return E[:2, :2], E[:2, 2], E[:2, 3]
    ke = int(tau // DT)
    S, s, guard = np.zeros((2, N)), np.array([Z0, 0.0]), None
    for k in range(N):
        for j, (on, h) in enumerate([(int(k > ke), DT)] if k != ke else [(0, tau - k * DT), (1, (k + 1) * DT - tau)]):
            Phi, Gam, c = phase(on, h)
            S = Phi @ S
            S[:, k] += Gam
            s = Phi @ s + c
            if k == ke and j == 0:
                guard = (S[0].copy(), s[0])
    A = np.vstack([guard[0], S])
    b = -np.r_[guard[1], s[0] - z_end, s[1]]
    u = A.T @ np.linalg.solve(A @ A.T, b)
    return DT * u @ u, u


def solve_dropped(damping, z_end, rounds=5):
    system = DroppedWheel(damping)
    U0 = np.zeros((N, 1))
    starts = open_loop(system, U0)
    run = system.simulate(starts, U0, DT)

    def terminal(xe):
        return ca.vertcat(xe[0] - z_end, xe[1]), 0.0, 0.0, "at rest at the end"
    return hybrid.outer(system, run, starts, U0, DT, np.array([Z0, 0.0]), terminal,
                        lambda U: open_loop(system, U), 100.0, [1.0], 1e-3, 1e-4, rounds=rounds, say=lambda *a: None,
                        tol=1e-10), run


def test_the_events_of_a_run_are_located_on_their_law():
    """Free fall from Z0: the touch-down at sqrt(2 Z0 / g) with the penetration's rate sqrt(2 g Z0); then, with
    little damping, the wheel bounces: its lift-off on the normal law (the point still inside the ground)."""
    system = DroppedWheel(2.0)
    run = system.simulate(open_loop(system, np.zeros((N, 1))), np.zeros((N, 1)), DT)
    first = run.events[0]
    assert (first.on, first.branch, first.interval) == (True, DEPTH, 0)
    assert first.time == pytest.approx(np.sqrt(2 * Z0 / G), abs=1e-9)
    assert first.rate == pytest.approx(np.sqrt(2 * G * Z0), rel=1e-6)
    lift = run.events[1]
    assert (lift.on, lift.branch) == (False, FORCE)
    z, v = run.event_states[1]
    assert K * -z - system.d * v == pytest.approx(0.0, abs=1e-6)       # the normal law is zero there
    assert -z > 0                                                      # inside the ground still
    # the schedule bins them into the grid and alternates the mode
    schedule = hybrid.schedule_of(run, N, DT, 1e-3, 1e-4)
    modes = [ph.mode[0] for ph in schedule.phases()]
    assert modes[0] == 0 and modes[1] == 1 and modes[2] == 1 and 0 in modes[2:]


def test_a_grazing_event_cannot_form_a_mode_sequence(tmp_path):
    """A wheel that touches the ground at a guard rate below solver.guard_rate: the error names the file, the key
    and the event."""
    system = DroppedWheel(40.0)
    x0 = np.array([[1e-8], [0.0]])
    run = system.simulate(np.c_[x0, x0], np.zeros((1, 1)), DT)
    assert len(run.events) == 1 and run.events[0].rate < 1e-3
    with pytest.raises(optimize.ProblemError, match=r"p\.toml: key 'guess': no mode sequence: wheel contact on at "
                                                    r"t = 0\.0000\d+ s .* grazes"):
        hybrid.schedule_of(run, 1, DT, 1e-3, 1e-4, path="p.toml")


def test_the_touch_down_time_is_the_brute_force_optimum():
    """The wheel dropped from Z0 onto ground with damping 40 N.s/m, to rest 1 mm inside it at 0.4 s at the least
    energy: the touch-down time (a decision, its phase split out of the first interval) against the best of a
    brute-force search over that time, each time's torques in closed form."""
    damping, z_end = 40.0, -0.001
    (result, history), run = solve_dropped(damping, z_end)
    assert len(history) == 1 and history[0]["same_sequence"]         # one touch-down, the replay agrees
    assert result["success"], result["status"]
    assert result["violation"] <= 1e-8
    tau = result["event_times"][0]
    assert abs(tau - run.events[0].time) > 5e-4                       # it moved from the free fall's
    scan = np.linspace(1e-3, DT - 1e-3, 400)
    j = int(np.argmin([closed_form(damping, z_end, t)[0] for t in scan]))
    best = minimize_scalar(lambda t: closed_form(damping, z_end, t)[0], bounds=(scan[max(j - 1, 0)], scan[j + 1]),
                           method="bounded", options={"xatol": 1e-10})
    assert tau == pytest.approx(best.x, abs=1e-6)
    assert result["objective"] == pytest.approx(best.fun, rel=1e-7)
    assert np.allclose(result["U"][:, 0], closed_form(damping, z_end, best.x)[1], atol=1e-4)


def test_the_outer_loop_solves_again_on_the_replays_sequence():
    """With little damping the one-touch-down optimum ends a phase with the normal law at zero at a node (the
    sign condition active): its replay lifts off there and lands again, another sequence, so the outer loop
    solves again on it from the solution, and ends where the replay's sequence is the schedule's."""
    (result, history), _ = solve_dropped(20.0, -0.005)
    assert len(history) >= 2
    assert not history[0]["same_sequence"]
    assert history[-1]["same_sequence"] and history[-1]["events"] > history[0]["events"]
    assert result["success"] and result["violation"] <= 1e-8
    assert history[-1]["objective"] < history[0]["objective"]        # the new sequence is cheaper
    # the solution's own replay reaches the end condition
    end = open_loop(DroppedWheel(20.0), result["U"])[:, -1]
    assert end == pytest.approx([-0.005, 0.0], abs=1e-6)


def test_the_phase_jacobian_is_the_finite_differences():
    """One phase of the rover (bump2d, every wheel on the ground: 14 states, the four torques and the phase's
    duration) integrated with its sensitivities in every direction at once, against central differences
    (github.com/casadi/casadi/issues/4383 reports wrong CVODES Jacobians in three or more parameter directions)."""
    problem = optimize.parse({"scene": "bump2d", "objective": "energy", "margin": -0.5, "interval": 0.1,
                              "method": "hybrid", "solver": {"integrator_tol": 1e-10}}, "jac.toml")
    from cedra.optimize.modes import RoverHybrid
    system = RoverHybrid(problem)
    # a state resting on the flat ground before the bump: every wheel's first contact slot on
    x = settled_state(system)
    on = system.mode_at(x)
    assert sum(on) == 4
    F = system.integrator(on)
    xs, ps = ca.MX.sym("x", system.nx), ca.MX.sym("p", 5)
    jac = ca.Function("j", [xs, ps], [ca.jacobian(F(x0=xs, p=ps)["xf"], ca.vertcat(xs, ps))])
    p = np.array([1.0, 0.5, -0.5, 1.0, 0.05])
    J = np.array(jac(x, p))
    z = np.r_[x, p]
    fd = central_differences(lambda zz: np.array(F(x0=zz[:system.nx], p=zz[system.nx:])["xf"]), z)
    scale = np.maximum(1.0, np.abs(fd).max(axis=0))
    assert np.abs(J - fd).max(axis=0) / scale == pytest.approx(np.zeros(z.size), abs=1e-4)


def settled_state(system) -> np.ndarray:
    """The rover at rest on the ground at x = 0.3 m: the model's static equilibrium (cedra_settle's Newton)."""
    fns = system.model.functions()
    m = system.model
    q = np.array(ca.DM(fns["cedra_guess"](np.r_[0.3, np.zeros(m.q.numel() - 1)], system.inp, system.par))).ravel()
    idx = m.settle_idx
    for _ in range(50):
        res, jac = (np.array(v) for v in fns["cedra_settle"](q, system.inp, system.par))
        step = np.linalg.solve(jac, res.ravel())
        q[idx] -= step
        if np.abs(step).max() < 1e-13:
            break
    return system.reduced(np.r_[q, np.zeros(m.q.numel())])


@pytest.mark.parametrize("text, key, reason", [
    ('method = "collocation"\n', "method", "must be one of"),
    ('method = "hybrid"\n[solver]\nsmoothing = [1e-4]\n', "solver.smoothing", "no smoothing"),
    ('method = "hybrid"\n[solver]\nspin_rates = "carried"\n', "solver.spin_rates", "node decision"),
    ('method = "hybrid"\n[solver]\nhessian = "differenced"\n', "solver.hessian", "one Hessian"),
    ('[solver]\nguard_rate = 1e-4\n', "solver.guard_rate", "method = \"hybrid\""),
    ('method = "hybrid"\n[solver]\nmin_phase = 0.5\n', "solver.min_phase", ""),
    ('method = "hybrid"\n[solver]\nrounds = 0\n', "solver.rounds", "1..50"),
])
def test_bad_hybrid_problem_names_file_and_key(tmp_path, text, key, reason):
    path = tmp_path / "bad.toml"
    path.write_text('scene = "bump2d"\nobjective = "energy"\nmargin = 0.4\ninterval = 0.1\n' + text)
    with pytest.raises(optimize.ProblemError) as err:
        optimize.load(path)
    assert f"bad.toml: key '{key}'" in str(err.value) and reason in str(err.value)


def test_hybrid_needs_the_energy_objective_and_no_chassis(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('scene = "bump2d"\nobjective = "time"\nmargin = 0.4\ninterval = 0.1\nmethod = "hybrid"\n')
    with pytest.raises(optimize.ProblemError, match="bad.toml: key 'objective'"):
        optimize.load(path)
    path.write_text('scene = "step2d"\nobjective = "energy"\nmargin = 0.4\ninterval = 0.1\nmethod = "hybrid"\n')
    with pytest.raises(optimize.ProblemError, match="bad.toml: key 'method': .*chassis"):
        optimize.load(path)
