"""Dynamics of the CEDRA model checked against independent derivations: mass matrix properties, Kane's f vs
Lagrange's equations, the scene restriction as a projection of the 3D equations, energy conservation, static
equilibrium on flat ground, and left/right symmetry of a 3D run."""
import time

import casadi as ca
import numpy as np
import pytest

from cedra.models.plant import CedraModel, ModelOptions, projection
from model_harness import Built
from cedra.rover.parameters import DEFAULTS
from cedra.rover.mechanism import FULL_Q, IDX

D = DEFAULTS
WEIGHT = (D["m_B"] + D["m_F"] + 6 * D["m_w"]) * D["g"]


@pytest.fixture(scope="module")
def b2():
    return Built(ModelOptions(dims="2d", terrain="flat"))


@pytest.fixture(scope="module")
def b3():
    return Built(ModelOptions(dims="3d", terrain="flat"))


@pytest.fixture(scope="module")
def b3s():
    return Built(ModelOptions(dims="3d", terrain="flat", steering=True))


def random_state(b, rng, z=None, joints_inside=True):
    """A random state; z None: near the ground so that some wheels are in contact."""
    names = b.names
    q = np.zeros(b.n)
    for k, nm in enumerate(names):
        if nm in ("x", "y"):
            q[k] = rng.uniform(-1, 1)
        elif nm == "yaw":
            q[k] = rng.uniform(-np.pi, np.pi)
        elif nm in ("pitch", "roll"):
            q[k] = rng.uniform(-0.05, 0.05) if z is None else rng.uniform(-0.5, 0.5)
        elif nm in ("theta1", "theta2"):
            q[k] = rng.uniform(-0.1, 0.1) if z is None else rng.uniform(-0.5, 0.5)
        elif nm == "theta4":
            q[k] = D["fork_theta4_ref"] + rng.uniform(-0.1, 0.1) if z is None else rng.uniform(-0.7, 0.5)
        elif nm in ("theta3", "theta6"):
            q[k] = rng.uniform(-0.5, 0.5)
        elif nm.startswith("gamma"):
            q[k] = rng.uniform(-5, 5)
    q[names.index("z")] = 0.197 + rng.uniform(-0.003, 0.002) if z is None else z
    return q, rng.uniform(-1, 1, b.n)


def random_inp(b, rng, **fixed):
    vals = {f"tau[{i}]": rng.uniform(-3, 3) for i in range(1, 7)}
    vals |= {"steer[1]": rng.uniform(-0.3, 0.3), "steer[2]": rng.uniform(-0.3, 0.3), "mu": rng.uniform(0.3, 1)}
    vals |= fixed
    return b.m.default_inp(**{q.name: vals[q.name] for q in b.m.inputs if q.name in vals})


# ---------------------------------------------------------------- mass matrix
@pytest.mark.parametrize("which", ["b2", "b3", "b3s"])
def test_mass_matrix_spd(which, request):
    b = request.getfixturevalue(which)
    rng = np.random.default_rng(1)
    par = b.m.default_par()
    for _ in range(10):
        q, _ = random_state(b, rng, z=0.5)
        M = b.M(q, par)
        assert np.max(np.abs(M - M.T)) <= 1e-14 * np.max(np.abs(M))
        ev = np.linalg.eigvalsh(M)
        assert ev[0] > 1e-5, ev       # the smallest inertia is a wheel's spin inertia 0.5 m_w R_w^2 ~ 1e-3


@pytest.mark.parametrize("which", ["b2", "b3s"])
def test_mass_matrix_is_hessian_of_kinetic_energy(which, request):
    b = request.getfixturevalue(which)
    m = b.m
    T = m.kane.kinetic_energy()
    H = ca.Function("H", [m.q, m.u, m.par], [ca.hessian(T, m.u)[0], T])
    rng = np.random.default_rng(2)
    par = m.default_par()
    for _ in range(5):
        q, u = random_state(b, rng, z=0.5)
        Hn, Tn = H(q, u, par)
        M = b.M(q, par)
        np.testing.assert_allclose(np.array(Hn), M, rtol=0, atol=1e-12 * np.max(np.abs(M)))
        assert abs(float(Tn) - 0.5 * u @ M @ u) <= 1e-12 * float(Tn)


# ---------------------------------------------------------------- Kane vs Lagrange
def lagrange_rhs(b):
    """Numeric function (q, u, inp, par) -> f from Lagrange's equations with T from the bodies' velocities and
    V = gravity + springs (conservative forces), without the nonconservative forces."""
    m = b.m
    T = m.kane.kinetic_energy()
    V = m.rover.potential
    dTdu = ca.gradient(T, m.u)
    rhs = -ca.jacobian(dTdu, m.q) @ m.u + ca.gradient(T, m.q) - ca.gradient(V, m.q)
    return ca.Function("lag", [m.q, m.u, m.inp, m.par], [rhs])


def nonconservative(b, q, u, inp, par, beyond_stops=()):
    """Q_nc = P' Q_full: motor torques on gamma_i, the fork damper, the servo dampers, and the stop dampers of
    the joints in beyond_stops."""
    P = b.m.P
    qfd = P @ u
    pv = dict(zip([p.name for p in b.m.params], par))
    iv = dict(zip([p.name for p in b.m.inputs], inp))
    Q = np.zeros(len(FULL_Q))
    for i in range(1, 7):
        Q[IDX[f"gamma{i}"]] = iv[f"tau[{i}]"]
    Q[IDX["theta4"]] = -pv["fork_d"] * qfd[IDX["theta4"]]
    if "steer_d" in pv:
        for nm in ("theta3", "theta6"):
            Q[IDX[nm]] = -pv["steer_d"] * qfd[IDX[nm]]
    for nm in beyond_stops:
        Q[IDX[nm]] += -pv["stop_d"] * qfd[IDX[nm]]
    return P.T @ Q


@pytest.mark.parametrize("which", ["b2", "b3", "b3s"])
def test_kane_vs_lagrange(which, request):
    b = request.getfixturevalue(which)
    lag = lagrange_rhs(b)
    rng = np.random.default_rng(3)
    par = b.m.default_par()
    cases = []
    for _ in range(8):
        q, u = random_state(b, rng, z=1.0)          # every wheel in the air, joints inside their stops
        cases.append((q, u, ()))
    # joints beyond their stops, moving so that the stop's spring-damper formula still pushes back out
    q, u = random_state(b, rng, z=1.0)
    q[b.names.index("theta1")] = D["bogie_stop"] + 0.05
    q[b.names.index("theta4")] = D["fork_stop_lo"] - 0.05
    u[b.names.index("theta1")] = 0.5
    u[b.names.index("theta4")] = -0.5
    beyond = ["theta1", "theta4"]
    if "theta2" in b.names:
        q[b.names.index("theta2")] = -D["bogie_stop"] - 0.02
        u[b.names.index("theta2")] = -0.3
        beyond.append("theta2")
    else:
        beyond.append("theta2")                     # 2D: theta2 = theta1
    cases.append((q, u, tuple(beyond)))
    for q, u, stops in cases:
        inp = random_inp(b, rng)
        out = b.out(q, u, inp, par)
        assert all(out[f"wheel[{i}].Fn"] == 0 and out[f"wheel[{i}].mode"] == 0 for i in range(1, 7))
        f_kane, _ = b.f(q, u, inp, par)
        f_lag = np.array(lag(q, u, inp, par)).ravel() + nonconservative(b, q, u, inp, par, stops)
        scale = max(1.0, np.max(np.abs(f_kane)))
        np.testing.assert_allclose(f_kane, f_lag, rtol=0, atol=1e-9 * scale)


def test_stop_torque_clipped(b3):
    """Beyond a stop, moving out fast: -k overshoot - d rate would pull the joint into the stop, so the stop
    acts with zero torque: f equals f of the same model without stops."""
    rng = np.random.default_rng(4)
    q, u = random_state(b3, rng, z=1.0)
    q[b3.names.index("theta1")] = D["bogie_stop"] + 0.05        # -k*0.05 = -25; -d*(-10) = +50
    u[b3.names.index("theta1")] = -10.0
    q[b3.names.index("theta4")] = D["fork_stop_hi"] + 0.05
    u[b3.names.index("theta4")] = -10.0
    inp = random_inp(b3, rng)
    f_stop, _ = b3.f(q, u, inp, b3.m.default_par())
    f_free, _ = b3.f(q, u, inp, b3.m.default_par(stop_k=0.0, stop_d=0.0))
    np.testing.assert_allclose(f_stop, f_free, rtol=0, atol=1e-12 * np.max(np.abs(f_free)))
    u[b3.names.index("theta1")] = 0.0                          # at rest beyond the stop: it pushes back
    f_stop, _ = b3.f(q, u, inp, b3.m.default_par())
    f_free, _ = b3.f(q, u, inp, b3.m.default_par(stop_k=0.0, stop_d=0.0))
    assert np.max(np.abs(f_stop - f_free)) > 1.0


# ---------------------------------------------------------------- restriction = projection
def _map_by_name(src_table, src_values, dst_table, dst_defaults):
    v = dict(zip([q.name for q in src_table], src_values))
    return np.array([v.get(q.name, d) for q, d in zip(dst_table, dst_defaults)])


@pytest.mark.parametrize("small", ["b2", "b3"])
def test_projection(small, b3s, request):
    b = request.getfixturevalue(small)
    names, P = projection(b.m.opt)
    assert names == b.names
    np.testing.assert_array_equal(P, b.m.P)
    rng = np.random.default_rng(5)
    for k in range(8):
        # perturbed parameters, so that a parameter mixed up by name would show
        par = b.m.default_par() * (1 + rng.uniform(-0.05, 0.05, len(b.m.params)))
        q, u = random_state(b, rng)
        inp = random_inp(b, rng)
        par3 = _map_by_name(b.m.params, par, b3s.m.params, b3s.m.default_par())
        inp3 = _map_by_name(b.m.inputs, inp, b3s.m.inputs, b3s.m.default_inp())   # steer commands 0
        q3, u3 = P @ q, P @ u
        assert float(b.fns["cedra_check"](q, u, inp, par)) == 1
        M, (f, g) = b.M(q, par), b.f(q, u, inp, par)
        M3, (f3, g3) = b3s.M(q3, par3), b3s.f(q3, u3, inp3, par3)
        np.testing.assert_allclose(M, P.T @ M3 @ P, rtol=0, atol=1e-10 * np.max(np.abs(M)))
        np.testing.assert_allclose(f, P.T @ f3, rtol=0, atol=1e-10 * max(1, np.max(np.abs(f))))
        assert abs(g - g3) <= 1e-10 * max(1, abs(g))
        # the outputs both models have agree
        y, y3 = b.out(q, u, inp, par), b3s.out(q3, u3, inp3, par3)
        common = set(y) & set(y3)
        assert len(common) > 80
        for nm in common:
            assert abs(y[nm] - y3[nm]) <= 1e-10 * max(1, abs(y[nm])), nm
        if k == 0:
            assert sum(y[f"wheel[{i}].Fn"] > 0 for i in range(1, 7)) >= 2     # contact forces are exercised


# ---------------------------------------------------------------- energy
@pytest.mark.parametrize("which", ["b2", "b3s"])
def test_energy_conservation(which, request):
    b = request.getfixturevalue(which)
    m = b.m
    over = dict(ground_d=0.0, fork_d=0.0, stop_d=0.0)
    if "steer_d" in [p.name for p in m.params]:
        over["steer_d"] = 0.0
    par = m.default_par(**over)
    inp = m.default_inp(mu=0.0)                 # torque-free; mu = 0: no tangential force
    q = b.settle(inp, par)
    u = np.zeros(b.n)
    q[b.names.index("z")] += 0.01               # dropped 1 cm: wheels leave the ground and land again
    u[b.names.index("pitch")] = 0.3
    u[b.names.index("x")] = 0.05
    if "roll" in b.names:
        u[b.names.index("roll")] = 0.2
        u[b.names.index("yaw")] = 0.1
        u[b.names.index("theta3")] = 0.5
    E = ca.Function("E", [m.q, m.u, m.inp, m.par], [m.kane.kinetic_energy(), m.potential])
    t_end = 2.0 if b.n < 10 else 1.0
    t, X = b.integrate(q, u, inp, par, t_end, 100)
    TV = np.array([np.array(E(X[:b.n, k], X[b.n:, k], inp, par)).ravel() for k in range(X.shape[1])])
    Etot = TV.sum(axis=1)
    drift = np.max(np.abs(Etot - Etot[0]))
    print(f"{which}: E0 = {Etot[0]:.6f} J, max T = {TV[:, 0].max():.4f} J, drift = {drift:.3e} J")
    assert TV[:, 0].max() > 1.0                 # energy really moved between kinetic and potential
    assert drift < 1e-6 * abs(Etot[0])
    assert drift < 1e-5 * TV[:, 0].max()
    # the outputs energy.kinetic / energy.potential are the same quantities
    y = b.out(X[:b.n, -1], X[b.n:, -1], inp, par)
    assert abs(y["energy.kinetic"] + y["energy.potential"] - Etot[-1]) < 1e-10 * abs(Etot[-1])


# ---------------------------------------------------------------- static equilibrium
@pytest.fixture(scope="module")
def settled(b2, b3s):
    res = {}
    for key, b in (("2d", b2), ("3d", b3s)):
        par, inp = b.m.default_par(), b.m.default_inp()
        q = b.settle(inp, par)
        res[key] = (b, q, b.out(q, np.zeros(b.n), inp, par), inp, par)
    return res


@pytest.mark.parametrize("key", ["2d", "3d"])
def test_static_equilibrium(settled, key):
    b, q, y, inp, par = settled[key]
    Fn = np.array([y[f"wheel[{i}].Fn"] for i in range(1, 7)])
    assert np.all(Fn > 0)
    assert abs(Fn.sum() - WEIGHT) <= 1e-9 * WEIGHT
    assert abs(Fn[0] - Fn[2]) <= 1e-9 * Fn[0] and abs(Fn[1] - Fn[3]) <= 1e-9 * Fn[1]
    for i in range(1, 7):
        assert abs(y[f"wheel[{i}].Fx"]) < 1e-9 and abs(y[f"wheel[{i}].Fy"]) < 1e-9
    udot = b.m.udot(q, np.zeros(b.n), inp, par)
    assert np.max(np.abs(udot)) < 1e-8, udot
    # the static pose differs from the design pose a little (docs/model.md, Parameters), but not much
    assert 0 < 0.2 - q[b.names.index("z")] < 0.005


def test_static_equilibrium_2d_equals_3d(settled):
    b2, q2, y2, _, _ = settled["2d"]
    b3, q3, y3, _, _ = settled["3d"]
    for nm in ("z", "pitch", "theta1", "theta4"):
        assert abs(q2[b2.names.index(nm)] - q3[b3.names.index(nm)]) < 1e-9, nm
    assert abs(q3[b3.names.index("roll")]) < 1e-12
    assert abs(q3[b3.names.index("theta1")] - q3[b3.names.index("theta2")]) < 1e-12
    for i in range(1, 7):
        assert abs(y2[f"wheel[{i}].Fn"] - y3[f"wheel[{i}].Fn"]) <= 1e-9 * WEIGHT, i


# ---------------------------------------------------------------- symmetry
def test_symmetric_run_stays_symmetric(b3):
    par = b3.m.default_par()
    q = b3.settle(b3.m.default_inp(), par)
    inp = b3.m.default_inp(**{f"tau[{i}]": 1.0 for i in range(1, 7)})
    u = np.zeros(b3.n)
    u[b3.names.index("x")] = 0.1
    t, X = b3.integrate(q, u, inp, par, 1.0, 100)
    ix = {nm: k for k, nm in enumerate(b3.names)}
    assert X[ix["x"], -1] - X[ix["x"], 0] > 0.1          # it did drive
    for nm in ("y", "yaw", "roll"):
        assert np.max(np.abs(X[ix[nm]])) < 1e-9, nm
    for a, c in (("theta1", "theta2"), ("gamma1", "gamma3"), ("gamma2", "gamma4")):
        assert np.max(np.abs(X[ix[a]] - X[ix[c]])) < 1e-9, (a, c)


# ---------------------------------------------------------------- sizes (printed with -s)
def test_function_sizes():
    from cedra.models.scene import load_shipped
    for scene in ("bump2d", "flat3d", "slope3d", "hills3d"):
        opt = load_shipped(scene).options
        t0 = time.perf_counter()
        fns = CedraModel(opt).functions()
        dt = time.perf_counter() - t0
        sizes = {k: fns[k].n_instructions() for k in ("cedra_M", "cedra_f", "cedra_rjac")}
        print(f"{scene}: build {dt:.3f} s, n_instructions {sizes}")
        assert dt < 30
        assert all(0 < v < 10 ** 6 for v in sizes.values())


def test_the_rover_kind_names_the_fixed_coordinates_and_its_2d_reduction():
    """CEDRA through the rover interface (cedra.mechanics.rover_kind): the fixed pose and spin names are its
    coordinates, its planar reduction keeps 9 of 17, its stops and steering joints are among them."""
    from cedra.mechanics.rover_kind import POSE, SPINS
    from cedra.models.plant import ModelOptions, projection
    from cedra.models.rovers import ROVERS
    kind = ROVERS["cedra"]
    kind.check()
    assert set(POSE + SPINS) <= set(kind.coordinates) and len(kind.coordinates) == 17
    assert {s.coordinate for s in kind.stops} | set(kind.steering) <= set(kind.coordinates)
    assert len(projection(ModelOptions(dims="2d"))[0]) == 9
    assert len(projection(ModelOptions(dims="3d", steering=True))[0]) == 17
    with pytest.raises(ValueError, match="unknown rover 'curiosity'"):
        projection(ModelOptions(rover="curiosity"))
