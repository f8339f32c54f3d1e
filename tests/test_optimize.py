"""python -m cedra optimize: bad problem files fail before anything runs, naming the file, the key and the reason;
the shipped problem files load; one short real solve converges and its open-loop replay through the FMU follows
the optimizer's body path."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cedra import optimize
from cedra.optimize import interval_jacobian
from model_harness import central_differences

REPO = Path(__file__).resolve().parents[1]
BUILD = REPO / "build"
GOOD = 'scene = "bump2d"\nobjective = "energy"\nmargin = 0.4\ninterval = 0.1\n'


@pytest.mark.parametrize("text, key, reason", [
    (GOOD + "horizn = 5.0\n", "horizn", "unknown key"),
    (GOOD.replace('"bump2d"', '"mars2d"'), "scene", "must be one of"),
    (GOOD.replace('"bump2d"', '"bump3d"'), "scene", "must be one of"),           # 3D: not the planar model
    (GOOD.replace('"bump2d"', '"bump2d_drives"'), "scene", "must be one of"),    # torques through the drives
    (GOOD.replace('"energy"', '"speed"'), "objective", "must be one of"),
    (GOOD.replace("margin = 0.4\n", ""), "margin", "missing"),
    (GOOD.replace("margin = 0.4", 'margin = "far"'), "margin", "expected a number"),
    (GOOD.replace("interval = 0.1", "interval = 0.055"), "interval", "whole number of the replay step"),
    (GOOD.replace("interval = 0.1", "interval = 0.0"), "interval", "must be >= 0.01"),
    (GOOD + "horizon = 0.1\n", "horizon", "at least two intervals"),
    (GOOD + "torque_max = -1.0\n", "torque_max", "must be > 0"),
    (GOOD + "guess = \"random\"\n", "guess", "must be one of"),
    (GOOD + "[inputs]\ntau1 = 2.0\n", "inputs.tau1", "not an input of scene bump2d"),
    (GOOD + "[inputs]\n\"tau[1]\" = 2.0\n", "inputs.tau[1]", "not an input of scene bump2d"),
    (GOOD + "[inputs]\nmu = -0.5\n", "inputs.mu", "must be >= 0"),
    (GOOD + "[solver]\nmax_iter = 2.5\n", "solver.max_iter", "expected an integer"),
    (GOOD + "[solver]\nintegrator_tol = 0.1\n", "solver.integrator_tol", "must be <="),
    (GOOD + "[solver]\nmethod = \"sqp\"\n", "solver.method", "unknown key"),
    (GOOD + "[solver]\nhessian = \"bfgs\"\n", "solver.hessian", "must be one of"),
    (GOOD + "[solver]\nthreads = 0\n", "solver.threads", "expected an integer"),
    (GOOD + "[solver]\nsmoothing = 1e-4\n", "solver.smoothing", "expected a non-empty list"),
    (GOOD + "[solver]\nsmoothing = []\n", "solver.smoothing", "expected a non-empty list"),
    (GOOD + "[solver]\nsmoothing = [1e-4, -1e-5]\n", "solver.smoothing", "must be >= 0"),
    (GOOD + "[solver]\nsmoothing = [0.1]\n", "solver.smoothing", "must be <="),
    (GOOD + "[solver]\nsmoothing = [1e-4, 1e-3]\n", "solver.smoothing", "must decrease"),
    (GOOD + "[solver]\nsmoothing = [1e-4, 1e-4]\n", "solver.smoothing", "must decrease"),
    (GOOD + "[solver]\nsmoothing = [1e-4, 0.0]\nproximal = [0.1, 0.01, 0.0]\n", "solver.proximal",
     "one weight per smoothing stage"),
    (GOOD + "[solver]\nproximal = [0.1, -1.0]\n", "solver.proximal", "must be >= 0"),
    (GOOD + "[solver]\nhessian = [\"objective\", \"bfgs\"]\n", "solver.hessian", "must be one of"),
    (GOOD + "[solver]\nsmoothing = [1e-4, 0.0]\nhessian = [\"objective\", \"objective\", \"differenced\"]\n",
     "solver.hessian", "one Hessian per smoothing stage"),
    (GOOD.replace('"energy"', '"time"') + "[solver]\nhessian = \"differenced\"\n", "solver.hessian",
     "needs a fixed horizon"),
    (GOOD.replace('"energy"', '"peak_friction"') + "[solver]\nhessian = \"differenced\"\nspin_rates = \"carried\"\n",
     "solver.hessian",
     "formed for the energy objective"),
    (GOOD + "[solver]\nspin_rates = \"lifted\"\n", "solver.spin_rates", "must be one of"),
])
def test_bad_problem_names_file_and_key(tmp_path, text, key, reason):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(optimize.ProblemError) as e:
        optimize.load(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: key '{key}': "), msg
    assert reason in msg, msg


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(optimize.ProblemError, match="cannot read"):
        optimize.load(tmp_path / "missing.toml")
    bad = tmp_path / "broken.toml"
    bad.write_text("scene = \n")
    with pytest.raises(optimize.ProblemError, match=f"{bad}: not valid TOML"):
        optimize.load(bad)


def test_cli_fails_before_running(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(GOOD.replace('"energy"', '"speed"'))
    r = subprocess.run([sys.executable, "-m", "cedra", "optimize", str(path), "--out", str(tmp_path / "out"),
                        "--build", str(tmp_path / "no_build")], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 2
    assert f"{path}: key 'objective'" in r.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "no_build").exists()


def test_shipped_problems_load():
    files = sorted((REPO / "examples" / "optimize").glob("*.toml"))
    assert files
    for f in files:
        p = optimize.load(f)
        assert p.objective in optimize.OBJECTIVES


def test_the_differenced_hessian_is_the_lagrangians_own():
    """ShootingHessian against CasADi's own second derivatives through the integrator, on a torque-driven pendulum
    (a small ODE CasADi can differentiate twice): 3 intervals, a random point and random multipliers."""
    import casadi as ca
    x, p = ca.SX.sym("x", 2), ca.SX.sym("p", 1)
    ode = ca.vertcat(x[1], -9.81 * ca.sin(x[0]) - 0.3 * x[1] * ca.fabs(x[1]) + p[0] * (1 + 0.5 * ca.cos(x[0])))
    F = ca.integrator("F", "cvodes", {"x": x, "p": p, "ode": ode}, 0, 0.3, {"abstol": 1e-12, "reltol": 1e-12})
    n, nx = 3, 2
    X, U = ca.MX.sym("X", nx, n + 1), ca.MX.sym("U", 1, n)
    g = ca.vec(F(x0=X[:, :n], p=U)["xf"] - X[:, 1:])
    J = ca.sumsqr(U) + 0.1 * ca.sumsqr(X[:, -1])
    w = ca.vertcat(ca.vec(X), ca.vec(U))
    rng = np.random.default_rng(1)
    wv, lam = rng.uniform(-1, 1, w.numel()), rng.uniform(-2, 2, g.numel())
    lam_f = 0.7
    exact = np.array(ca.Function("h", [w], [ca.hessian(lam_f * J + ca.dot(ca.DM(lam), g), w)[0]])(wv))
    hess = optimize.ShootingHessian(w, J, g.numel(), n, interval_jacobian(F, nx, 1), proximal=0.0)
    got = hess.matrix(wv, lam_f, lam)
    assert np.max(np.abs(got - exact)) < 1e-4 * np.max(np.abs(exact)), np.max(np.abs(got - exact))
    assert np.max(np.abs(exact - np.diag(np.diag(exact)))) > 0.1      # the intervals' own curvature is in it
    # what IPOPT gets: the upper triangle of the same matrix, on the declared block pattern
    triu = np.array(ca.densify(hess(wv, ca.DM(0, 1), lam_f, lam)))
    assert np.allclose(triu, np.triu(got), atol=0) and np.allclose(np.triu(got) + np.triu(got, 1).T, got)


@pytest.mark.parametrize("free_dt, peak", [(False, False), (True, False), (False, True)])
def test_the_carried_spin_rates_jacobian_is_the_chain_rules(free_dt, peak):
    """The carried-spin transcription's constraint Jacobian (the interval Jacobians chained through the spin rates
    by hand) against central differences of its own constraints, at a controller run's nodes toward the bump's
    foot (3 intervals of 0.2 s, the smoothed law): every entry, the time column (free horizon) and the node
    forces' rows (peak_friction) included, and nothing outside the declared pattern."""
    from cedra.optimize import CarriedSpinShooting
    problem = optimize.load(REPO / "examples" / "optimize" / "bump2d_short_energy.toml")
    dyn = optimize.Dynamics(problem)
    dyn.width = 2e-4
    r = optimize.controller_run(problem, dyn, "inverse_kinematics", 1.0, BUILD)
    n, dt = 3, 0.2
    X, U = optimize.initial_guess(r.names, r.rows, n, dt)
    shooting = CarriedSpinShooting(dyn, X[:, 0], n, dt, 1e-11, optimize.goal(problem, dyn), free_dt, peak)
    w = np.concatenate([dyn.reduced(X)[shooting.body].ravel(order="F"), U.T.ravel(order="F"), [dt], [0.3]])
    got = shooting.jacobian(w)
    differenced = central_differences(shooting.g, w)
    if not free_dt:
        differenced[:, -2] = 0.0                 # a constant of the problem: no column of the Jacobian
    assert np.max(np.abs(got - differenced)) < 1e-4 * np.max(np.abs(got))
    assert np.max(np.abs(got[:, shooting.nb:shooting.nb * 2])) > 1.0      # the intervals' own sensitivities
    inside = np.zeros(got.shape, dtype=bool)
    rows, cols = shooting.sparsity.get_triplet()
    inside[rows, cols] = True
    assert not np.any(got[~inside]) and not np.any(differenced[~inside])
    if free_dt:
        assert np.max(np.abs(got[:, -2])) > 1e-3


class _SpinningPendulum:
    """A small stand-in for optimize.Dynamics that CasADi can differentiate twice: a pendulum (x) whose wheel
    (gamma1) it is coupled to through a smooth slip law; torques p[0] on the wheel, p[1] on the pendulum."""

    class model:
        q_names = ["x", "gamma1"]

    kept = [0, 2, 3]                                  # x, dx, dgamma1: the wheel's angle left out

    def reduced(self, x):
        return np.asarray(x)[self.kept]

    def integrator(self, tol, dt=None):
        import casadi as ca
        r, p = ca.SX.sym("r", 3), ca.SX.sym("p", 4 if dt is not None else 5)
        length = dt if dt is not None else p[4]
        slip = ca.tanh(r[2] - r[1])
        ode = ca.vertcat(r[1], -9.81 * ca.sin(r[0]) + 2.0 * slip * (1 + 0.3 * ca.cos(r[0])) + p[1],
                         p[0] - 3.0 * slip - 0.2 * r[2] * r[1])
        return ca.integrator("F", "cvodes", {"x": r, "p": p, "ode": length * ode}, 0, 1.0,
                             {"abstol": tol, "reltol": tol})


def test_the_carried_spin_rates_curvature_is_the_lagrangians_own():
    """CarriedSpinShooting.constraint_curvature (the second-order adjoint of the interval chain: each interval's
    multiplier with the later intervals' pulled back through the carried rates) against CasADi's own second
    derivatives of lam . g(w), g formed symbolically through the same integrator (a stand-in it can differentiate
    twice: _SpinningPendulum), 4 intervals, a random point and random multipliers."""
    import casadi as ca
    from cedra.optimize import CarriedSpinShooting
    dyn = _SpinningPendulum()
    n, dt = 4, 0.3
    x0 = np.array([0.3, 0.0, 0.1, 2.0])
    shooting = CarriedSpinShooting(dyn, x0, n, dt, 1e-12, 0.2, False, False)
    assert (shooting.nb, shooting.ns) == (2, 1)
    rng = np.random.default_rng(2)
    w = np.concatenate([np.r_[0.3, 0.1], rng.uniform(-1, 1, 2 * n), rng.uniform(-2, 2, 4 * n), [dt, 0.0]])
    lam = rng.uniform(-1, 1, shooting.ng)
    # the same constraints, formed symbolically: the node states and the carried spin rate
    F = dyn.integrator(1e-12, dt)
    ws = ca.MX.sym("w", shooting.nw)
    X = ca.reshape(ws[:shooting.u_at], 2, n + 1)
    U = ca.reshape(ws[shooting.u_at:shooting.u_at + 4 * n], 4, n)
    spin, g = ca.MX(x0[3]), []
    for k in range(n):
        end = F(x0=ca.vertcat(X[:, k], spin), p=U[:, k])["xf"]
        g.append(end[:2] - X[:, k + 1])
        spin = end[2]
    g = ca.vertcat(*g, X[0, n] - 0.2)
    assert np.allclose(np.array(ca.Function("g", [ws], [g])(w)).ravel(), shooting.g(w), atol=1e-9)
    exact = np.array(ca.Function("h", [ws], [ca.hessian(ca.dot(ca.DM(lam), g), ws)[0]])(w))
    got = shooting.constraint_curvature(w, lam)
    assert np.max(np.abs(got - exact)) < 1e-4 * np.max(np.abs(exact)), np.max(np.abs(got - exact))
    # the carried rate couples node 1 with the torques of interval 0 (separate blocks in the lifted transcription)
    coupling = exact[np.ix_(range(2, 4), range(shooting.u_at, shooting.u_at + 4))]
    assert np.max(np.abs(coupling)) > 1e-2 * np.max(np.abs(exact))


def test_smoothed_contact_law_tends_to_the_fmus():
    """The optimizer's smoothed normal force (contact.compliant_law with a width) is the FMU's law exactly at width
    0, tends to it as the width goes to 0 away from its switches (the clip k delta = d v_n and the onset delta = 0),
    and is smooth across them: its slope in the depth changes by no more than the law's own over a width."""
    import casadi as ca
    from cedra.mechanics.contact import compliant_law
    k, d = 1e5, 600.0
    depth, v_n, width = ca.SX.sym("depth"), ca.SX.sym("v_n"), ca.SX.sym("width")
    n, v = ca.DM([0, 0, 1]), ca.vertcat(0.05, 0, v_n)
    law = ca.Function("law", [depth, v_n], [compliant_law(depth, n, v, k, d, 0.8, 0.01)[0]])
    fn = compliant_law(depth, n, v, k, d, 0.8, 0.01, width)[0]
    smooth = ca.Function("smooth", [depth, v_n, width], [fn, ca.jacobian(fn, depth)])
    D, V = (a.ravel() for a in np.meshgrid(np.linspace(-0.01, 0.01, 401), np.linspace(-0.5, 0.5, 201)))
    exact = np.array(law(D, V)).ravel()
    assert np.array_equal(np.array(smooth(D, V, 0.0)[0]).ravel(), exact)
    for w in (1e-4, 1e-5, 1e-6):
        far = (np.abs(D) > 30 * w) & (np.abs(k * D - d * V) > 30 * k * w)
        value = np.array(smooth(D, V, w)[0]).ravel()
        assert np.all(value >= 0) and np.all(np.isfinite(value))
        error = np.max(np.abs(value - exact)[far])
        assert error < 1e-9 * k * w + 1e-9, (w, error)      # e^-30 of the force width k w
        assert np.max(np.abs(value - exact)) <= k * w * np.log(2) + d * 0.5 / 2 + 1e-9
    # smooth: across the clip at v_n = 0.1 m/s (delta = d v_n / k) the slope in the depth rises from 0 to k over a
    # few widths, not at once
    w = 1e-4
    at = np.linspace(-5 * w, 5 * w, 11) + d * 0.1 / k
    slope = np.array(smooth(at, 0.1 + 0 * at, w)[1]).ravel()
    assert np.all(np.diff(slope) > 0) and slope[0] < 0.01 * k and slope[-1] > 0.99 * k
    assert np.max(np.diff(slope)) < 0.3 * k


def test_smoothed_joint_stop_tends_to_the_fmus():
    """The joint stops' smoothed law (mechanism.stop_torque with a width) is the FMU's law exactly at width 0 and
    within e^-30 of it away from its switches (the stop's angle and the clip k e = -d rate), on both stops."""
    import casadi as ca
    from cedra.rover.mechanism import stop_torque
    k, d, lo, hi = 500.0, 5.0, -0.6, 0.6
    angle, rate, width = ca.SX.sym("angle"), ca.SX.sym("rate"), ca.SX.sym("width")
    law = ca.Function("law", [angle, rate], [stop_torque(angle, rate, lo, hi, k, d)])
    smooth = ca.Function("smooth", [angle, rate, width], [stop_torque(angle, rate, lo, hi, k, d, width)])
    A, R = (a.ravel() for a in np.meshgrid(np.linspace(-0.7, 0.7, 701), np.linspace(-3, 3, 121)))
    exact = np.array(law(A, R)).ravel()
    assert np.array_equal(np.array(smooth(A, R, 0.0)).ravel(), exact)
    for w in (1e-3, 1e-4, 1e-6):
        switches = [np.abs(A - hi), np.abs(A - lo), np.abs(k * (A - hi) + d * R) / k, np.abs(k * (A - lo) + d * R) / k]
        far = np.min(switches, axis=0) > 30 * w
        value = np.array(smooth(A, R, w)).ravel()
        assert np.all(np.isfinite(value))
        assert np.max(np.abs(value - exact)[far]) < 1e-9 * k * w + 1e-12, w
        assert np.all(value[A > hi + 30 * w] <= 0) and np.all(value[A < lo - 30 * w] >= 0)   # pushes back only


def test_the_optimizers_equations_smooth_the_joint_stops():
    """The optimizer's equations (optimize.Dynamics) take the contact's width to the joint stops too, as that width
    over R_w in radians: with the bogie 1 mrad past its stop the bogie's acceleration differs from the one under the
    FMU's law (width 0); with the bogie well inside its range it is the same."""
    import casadi as ca
    from cedra.optimize import Dynamics, parse
    dyn = Dynamics(parse({"scene": "bump2d", "objective": "energy", "margin": -0.5, "interval": 0.2}))
    q_names = dyn.model.q_names
    p = {q.name: dyn.par[k] for k, q in enumerate(dyn.model.params)}

    def bogie_acceleration(theta1, width):
        x = np.zeros(dyn.nx)
        x[q_names.index("z")] = 0.5                         # in the air: no contact, only the stop acts
        x[q_names.index("theta1")] = theta1
        dyn.width = width
        return float(ca.evalf(dyn.ode(ca.DM(x), [0, 0, 0, 0]))[dyn.nq + q_names.index("theta1")])

    w = 2e-4
    past = -p["bogie_stop"] - 1e-3
    assert bogie_acceleration(past, 0.0) != bogie_acceleration(past, w)
    assert bogie_acceleration(-0.2, 0.0) == bogie_acceleration(-0.2, w)


def test_the_optimizers_contact_forces_are_finite_above_the_ground():
    """The optimizer's wheel forces (optimize.Dynamics.forces: the FMU's wheel[i].Fn, Fx, what the peak-friction
    objective constrains) on the smoothed law, the rover held at heights from the ground up to 0.6 m: finite
    everywhere. A lifted wheel's smoothed normal force is positive but can be so small that its square underflows
    (depths of -0.07 to -0.15 m at a width of 2e-4 m); a wheel with several contact slots normalizes the sum of
    their forces, which must not divide by that zero norm."""
    import casadi as ca
    from cedra.optimize import Dynamics, parse
    dyn = Dynamics(parse({"scene": "bump2d", "objective": "energy", "margin": -0.5, "interval": 0.2}))
    z = dyn.model.q_names.index("z")
    for width in (2e-4, 5e-5):
        dyn.width = width
        for height in np.arange(0.0, 0.6, 0.0025):
            x = np.zeros(dyn.nx)
            x[z] = height
            fn, fx = (np.array(ca.evalf(f)).ravel() for f in dyn.forces(ca.DM(dyn.reduced(x))))
            assert np.all(np.isfinite(fn)) and np.all(np.isfinite(fx)), (width, height, fn, fx)


def test_smoothed_model_forms_no_fmu():
    from cedra.models.plant import CedraModel
    from cedra.models.scene import load_shipped
    with pytest.raises(ValueError, match="smoothed contact law"):
        CedraModel(load_shipped("bump2d").options, smooth_contact=True).spec("bump2d")


@pytest.mark.parametrize("spin_rates", ["nodes", "carried"])
def test_short_solve_converges_and_replays(tmp_path, spin_rates):
    """Toward the bump's foot: 0.4 s, 2 intervals of 0.2 s (the shipped short problem's first half, a test of
    seconds), from the IK controller's run, both transcriptions. The replay and the comparison are checked first,
    convergence last."""
    path = tmp_path / "short.toml"
    path.write_text('scene = "bump2d"\nobjective = "energy"\nmargin = -0.55\ninterval = 0.2\nstart_x = 0.4\n'
                    f'horizon = 0.4\n[solver]\nmax_iter = 60\nspin_rates = "{spin_rates}"\n')
    s = optimize.run(optimize.load(path), tmp_path / "out", BUILD, quiet=True)
    assert s["intervals"] == 2
    assert s["replay_ok"]
    assert s["replay_deviation"] < 1e-4
    assert s["node_deviation"] < 1e-4           # converged: the nodes are on the path the FMU replays
    for f in ("report.md", "climb.png", "result.json", "torques.csv"):
        assert (tmp_path / "out" / f).exists()
    tau = np.loadtxt(tmp_path / "out" / "torques.csv", delimiter=",", skiprows=1)
    assert tau.shape == (2, 5)
    assert np.abs(tau[:, 1:]).max() <= 6.0 + 1e-6
    # the controller's own run is feasible for the same problem, so the optimum spends no more energy than it
    assert s["optimum"]["energy"] <= s["controllers"]["inverse_kinematics"]["energy"]
    assert s["final_x_optimizer"] >= s["goal_x"] - 1e-5
    assert s["optimum"]["arrived"]
    assert s["success"], s["status"]


def test_the_report_does_not_call_a_node_path_closed_that_is_not():
    """A solve that ends where its constraints read as met but whose node states are off the replayed path (an
    aborted solve) is reported as not closed: the text goes by the node states against the FMU replay too."""
    problem = optimize.load(REPO / "examples" / "optimize" / "bump2d_short_energy.toml")
    run = dict(arrived=False, time=5.0, energy=1.0, peak_friction=0.8, work=1.0, peak_torque=1.0)
    summary = dict(problem="p", scene="bump2d", objective="energy", goal_x=1.4, torque_max=6.0, intervals=4,
                   horizon=0.8, guess="inverse_kinematics", status="Invalid_Number_Detected", iterations=21,
                   solve_time=1.0, wall=2.0, nlp_objective=0.0, violation=0.0, smoothing=1e-6, integrator_tol=1e-8,
                   replay_ok=True, replay_deviation=2e-6, node_deviation=0.388, stages=[], optimum=run,
                   controllers={"equal_torques": run})
    text = optimize.report_text(problem, summary)
    assert "NOT closed" in text
    assert "NOT closed" not in optimize.report_text(problem, summary | {"node_deviation": 1e-6})
