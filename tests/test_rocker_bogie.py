"""The rocker-bogie (cedra.rover.rocker_bogie, through the rover interface) checked as CEDRA's equations are: the
design geometry, the mass matrix against the kinetic energy's Hessian, Kane's f against Lagrange's equations, the
planar model as the projection of the 3D one, energy conservation, static equilibrium with equal wheel loads, and
left/right symmetry."""
import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import ModelOptions, projection
from cedra.rover.rocker_bogie import COORDINATES, DEFAULTS as D, IDX
from model_harness import Built

WEIGHT = (D["m_B"] + 6 * D["m_w"]) * D["g"]
JOINTS = ("rho", "beta_L", "beta_R")


def rb(dims, **kw):
    return Built(ModelOptions(dims=dims, terrain="flat", rover="rocker_bogie", **kw))


@pytest.fixture(scope="module")
def r2():
    return rb("2d")


@pytest.fixture(scope="module")
def r3():
    return rb("3d")


def random_state(b, rng, z=1.0):
    """A random state with every wheel in the air (z = 1 m) and the joints inside their stops."""
    q = np.zeros(b.n)
    for k, nm in enumerate(b.names):
        if nm in ("x", "y"):
            q[k] = rng.uniform(-1, 1)
        elif nm == "yaw":
            q[k] = rng.uniform(-np.pi, np.pi)
        elif nm in ("pitch", "roll"):
            q[k] = rng.uniform(-0.5, 0.5)
        elif nm in JOINTS:
            q[k] = rng.uniform(-0.45, 0.45)
        elif nm.startswith("gamma"):
            q[k] = rng.uniform(-5, 5)
    q[b.names.index("z")] = z
    return q, rng.uniform(-1, 1, b.n)


def random_inp(b, rng):
    vals = {f"tau[{i}]": rng.uniform(-3, 3) for i in range(1, 7)} | {"mu": rng.uniform(0.3, 1)}
    return b.m.default_inp(**{q.name: vals[q.name] for q in b.m.inputs if q.name in vals})


def test_design_pose_puts_every_wheel_r_w_above_the_ground(r3):
    """docs/model.md, The rocker-bogie: in the design pose (all angles 0, body mass center at 0.20 m) every wheel center is R_w
    above flat ground; the wheel centers' x are 0.30 (front), 0 (middle), -0.30 (rear), both sides."""
    q = np.zeros(r3.n)
    q[r3.names.index("z")] = 0.20
    y = r3.out(q, np.zeros(r3.n), r3.m.default_inp(), r3.m.default_par())
    for i, x in zip(range(1, 7), (0.30, 0.0, -0.30) * 2):
        assert abs(y[f"wheel[{i}].cz"] - D["R_w"]) < 1e-12, i
        assert abs(y[f"wheel[{i}].cx"] - x) < 1e-12, i
        assert abs(abs(y[f"wheel[{i}].cy"]) - D["rocker_y"]) < 1e-12, i


def test_a_positive_rocker_angle_lifts_the_left_front_wheel_and_lowers_the_right(r3):
    q = np.zeros(r3.n)
    q[r3.names.index("z")] = 0.20
    q[r3.names.index("rho")] = 0.1
    y = r3.out(q, np.zeros(r3.n), r3.m.default_inp(), r3.m.default_par())
    assert y["wheel[1].cz"] > D["R_w"] + 0.02 and y["wheel[4].cz"] < D["R_w"] - 0.02
    assert y["rocker.rho"] == 0.1


@pytest.mark.parametrize("which", ["r2", "r3"])
def test_mass_matrix_is_the_hessian_of_the_kinetic_energy(which, request):
    b = request.getfixturevalue(which)
    m = b.m
    H = ca.Function("H", [m.q, m.u, m.par], [ca.hessian(m.kane.kinetic_energy(), m.u)[0]])
    rng = np.random.default_rng(2)
    par = m.default_par()
    for _ in range(5):
        q, u = random_state(b, rng)
        M = b.M(q, par)
        np.testing.assert_allclose(np.array(H(q, u, par)), M, rtol=0, atol=1e-12 * np.max(np.abs(M)))
        assert np.linalg.eigvalsh(M)[0] > 1e-5


@pytest.mark.parametrize("which", ["r2", "r3"])
def test_kane_vs_lagrange(which, request):
    """Lagrange's equations from T (the bodies' velocities) and V (gravity, stops), plus the motor torques on the
    spins: a second formulation of the same equations, in the air and with joints inside their stops."""
    b = request.getfixturevalue(which)
    m = b.m
    T, V = m.kane.kinetic_energy(), m.rover.potential
    lag = ca.Function("lag", [m.q, m.u, m.par], [-ca.jacobian(ca.gradient(T, m.u), m.q) @ m.u +
                                                 ca.gradient(T, m.q) - ca.gradient(V, m.q)])
    rng = np.random.default_rng(3)
    par = m.default_par()
    for _ in range(8):
        q, u = random_state(b, rng)
        inp = random_inp(b, rng)
        out = b.out(q, u, inp, par)
        assert all(out[f"wheel[{i}].Fn"] == 0 for i in range(1, 7))
        tau = dict(zip([p.name for p in m.inputs], inp))
        Qfull = np.zeros(len(COORDINATES))
        for i in range(1, 7):
            Qfull[IDX[f"gamma{i}"]] = tau[f"tau[{i}]"]
        f_kane, _ = b.f(q, u, inp, par)
        f_lag = np.array(lag(q, u, par)).ravel() + m.P.T @ Qfull
        np.testing.assert_allclose(f_kane, f_lag, rtol=0, atol=1e-9 * max(1.0, np.max(np.abs(f_kane))))


def test_the_planar_model_is_the_projection_of_the_3d_one(r2, r3):
    names, P = projection(r2.m.opt)
    assert names == r2.names == ["x", "z", "pitch", "beta_L", "gamma1", "gamma2", "gamma3"]
    assert len(r3.names) == 15
    rng = np.random.default_rng(5)
    for _ in range(6):
        par = r2.m.default_par() * (1 + rng.uniform(-0.05, 0.05, len(r2.m.params)))
        q, u = random_state(r2, rng, z=0.0)
        q[r2.names.index("z")] = 0.197 + rng.uniform(-0.003, 0.002)      # some wheels in contact
        q[r2.names.index("pitch")] = rng.uniform(-0.05, 0.05)
        q[r2.names.index("beta_L")] = rng.uniform(-0.1, 0.1)
        inp = random_inp(r2, rng)
        q3, u3 = P @ q, P @ u
        M, (f, _) = r2.M(q, par), r2.f(q, u, inp, par)
        M3, (f3, _) = r3.M(q3, par), r3.f(q3, u3, inp, par)
        np.testing.assert_allclose(M, P.T @ M3 @ P, rtol=0, atol=1e-10 * np.max(np.abs(M)))
        np.testing.assert_allclose(f, P.T @ f3, rtol=0, atol=1e-10 * max(1, np.max(np.abs(f))))


@pytest.mark.parametrize("which", ["r2", "r3"])
def test_energy_is_conserved_without_damping_and_friction(which, request):
    b = request.getfixturevalue(which)
    m = b.m
    par = m.default_par(ground_d=0.0, stop_d=0.0)
    inp = m.default_inp(mu=0.0)
    q = b.settle(inp, par)
    u = np.zeros(b.n)
    q[b.names.index("z")] += 0.01               # dropped 1 cm: wheels leave the ground and land again
    u[b.names.index("pitch")] = 0.3
    u[b.names.index("x")] = 0.05
    if "roll" in b.names:
        u[b.names.index("roll")] = 0.2
        u[b.names.index("rho")] = 0.3
    E = ca.Function("E", [m.q, m.u, m.inp, m.par], [m.kane.kinetic_energy(), m.potential])
    t, X = b.integrate(q, u, inp, par, 1.0, 100)
    TV = np.array([np.array(E(X[:b.n, k], X[b.n:, k], inp, par)).ravel() for k in range(X.shape[1])])
    Etot = TV.sum(axis=1)
    drift = np.max(np.abs(Etot - Etot[0]))
    assert TV[:, 0].max() > 1.0
    assert drift < 1e-6 * abs(Etot[0]) and drift < 1e-5 * TV[:, 0].max(), drift


@pytest.mark.parametrize("which", ["r2", "r3"])
def test_static_equilibrium_has_equal_wheel_loads(which, request):
    """The design (docs/model.md, The rocker-bogie): on flat ground the six wheels carry equal loads (the rocker's 0.30 / 0.15 m
    lever arms, the bogie's equal arms), their sum the weight."""
    b = request.getfixturevalue(which)
    par, inp = b.m.default_par(), b.m.default_inp()
    q = b.settle(inp, par)
    y = b.out(q, np.zeros(b.n), inp, par)
    Fn = np.array([y[f"wheel[{i}].Fn"] for i in range(1, 7)])
    assert abs(Fn.sum() - WEIGHT) <= 1e-9 * WEIGHT
    assert np.max(Fn) - np.min(Fn) <= 1e-6, Fn
    assert np.max(np.abs(b.m.udot(q, np.zeros(b.n), inp, par))) < 1e-8
    for nm in ("pitch",) + tuple(n for n in JOINTS if n in b.names):
        assert abs(q[b.names.index(nm)]) < 1e-9, nm


def test_a_symmetric_run_stays_symmetric(r3):
    par = r3.m.default_par()
    q = r3.settle(r3.m.default_inp(), par)
    inp = r3.m.default_inp(**{f"tau[{i}]": 1.0 for i in range(1, 7)})
    u = np.zeros(r3.n)
    u[r3.names.index("x")] = 0.1
    t, X = r3.integrate(q, u, inp, par, 1.0, 100)
    ix = {nm: k for k, nm in enumerate(r3.names)}
    assert X[ix["x"], -1] - X[ix["x"], 0] > 0.1
    for nm in ("y", "yaw", "roll", "rho"):
        assert np.max(np.abs(X[ix[nm]])) < 1e-9, nm
    for a, c in (("beta_L", "beta_R"), ("gamma1", "gamma4"), ("gamma2", "gamma5"), ("gamma3", "gamma6")):
        assert np.max(np.abs(X[ix[a]] - X[ix[c]])) < 1e-9, (a, c)


def test_the_rocker_bogie_cannot_steer():
    from cedra.models.plant import CedraModel
    with pytest.raises(ValueError, match="no steering joints"):
        CedraModel(ModelOptions(dims="3d", rover="rocker_bogie", steering=True))


# ---------------------------------------------------------------- the shipped FMUs: the paper's run
@pytest.fixture(scope="module")
def rb_fmus(tmp_path_factory):
    from fmu_harness import shipped_fmu
    return {n: shipped_fmu(n, tmp_path_factory) for n in ("rb_bump2d", "rb_bump3d")}


def test_symmetric_rb_bump3d_gives_rb_bump2d_and_climbs(rb_fmus):
    """The paper's run (its speed controller, equal torques) for the rocker-bogie: it gets over the bump, the 3D
    FMU started symmetric stays in the plane and gives the planar FMU's results to the solver's error scale
    (tests/test_bump3d.py's bounds at tol 1e-6), and at rest the six loads are equal."""
    from cedra.run.simulate import run_bump
    tol, stop = 1e-6, 8.0
    runs = {}
    for name, path in rb_fmus.items():
        names, rows, _, info = run_bump(path, stop, {"solver.tol": tol},
                                        extra=["body.y", "body.yaw", "body.roll", "rocker.rho"])
        assert info["ok"], info["messages"][-2:]
        runs[name] = {n: rows[:, k] for k, n in enumerate(names)}
    c2, c3 = runs["rb_bump2d"], runs["rb_bump3d"]
    assert c3["body.x"][-1] > 1.3                                    # past the bump at X = 1 m
    assert np.max(np.abs(c2["body.x"] - c3["body.x"])) <= tol * (1 + np.max(np.abs(c2["body.x"])))
    bound_f = 1e5 * tol * (1 + np.max(c2["body.z"])) + 600.0 * tol * (1 + 1.0)
    for i in range(1, 7):
        assert np.max(np.abs(c2[f"wheel[{i}].Fn"] - c3[f"wheel[{i}].Fn"])) <= bound_f, i
    for n in ("body.y", "body.yaw", "body.roll", "rocker.rho"):
        assert np.max(np.abs(c3[n])) < 1e-9, n
    rest = np.array([c3[f"wheel[{i}].Fn"][0] for i in range(1, 7)])
    assert np.max(rest) - np.min(rest) <= 1e-6 and abs(rest.sum() - WEIGHT) <= 1e-6 * WEIGHT
