"""Drives (docs/model.md, Drives): each wheel's torque command clipped to a DC motor's torque-speed envelope at the
wheel, minus the gear's viscous loss. The law itself against numpy at points inside, on and outside the
envelope; drives off leaves the model as it was; the scene option is validated like the other keys; through the
shipped bump2d_drives FMU: the energy balance with the applied torques' work, and a lifted rover whose wheels
cannot spin past the no-load speed (without drives they run away).

Uses build/<scene>.fmu when `./build.sh` has built it (CI does), else builds into pytest's tmp dir."""
import sys
from pathlib import Path

import numpy as np
import pytest

from cedra.models import scene as sc
from cedra.run.driver import RoverFMU
from cedra.models.plant import ModelOptions
from cedra.rover.mechanism import IDX
from model_harness import Built

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
import drives_paper  # noqa: E402
from fmu_harness import shipped_fmu

DRIVE_PARAMS = ("drive_stall_torque", "drive_noload_speed", "drive_viscous")


def applied_torque(cmd, omega, stall, noload, viscous):
    """The drive law (docs/model.md, Drives) in numpy: the reference the model is checked against."""
    return np.clip(cmd, -stall * (1 + omega / noload), stall * (1 - omega / noload)) - viscous * omega


class Functions(Built):
    """A model's numeric contract functions with named access to outputs, and the wheels' spin rates."""

    def spin_rates(self, u):
        """The six wheels' spin rates relative to their carriers for scene speeds u (2D: 1 = 3, 2 = 4)."""
        uf = self.m.P @ u
        return np.array([uf[IDX[f"gamma{i}"]] for i in range(1, 7)])


OPTIONS = {"2d": dict(dims="2d", terrain="bump"), "3d": dict(dims="3d", terrain="flat", steering=True)}


@pytest.fixture(scope="module", params=list(OPTIONS))
def pair(request):
    """(drives on, drives off) for the same scene options."""
    opt = OPTIONS[request.param]
    return Functions(ModelOptions(**opt, drives=True)), Functions(ModelOptions(**opt))


def random_point(fn, rng):
    """A state near the ground (some wheels in contact) with spin rates up to 3 no-load speeds."""
    names = fn.m.q_names
    q = np.zeros(len(names))
    q[names.index("z")] = 0.197
    q[names.index("theta4")] = fn.m.default_par()[[p.name for p in fn.m.params].index("fork_theta4_ref")]
    u = rng.uniform(-0.5, 0.5, len(names))
    for k, nm in enumerate(names):
        if nm.startswith("gamma"):
            u[k] = rng.uniform(-30, 30)
    return q, u


def commands(rng, omega, stall, noload):
    """One command per wheel: inside the envelope, exactly on its upper or lower edge, or beyond it."""
    upper, lower = stall * (1 - omega / noload), -stall * (1 + omega / noload)
    where = rng.integers(0, 4, 6)
    inside = rng.uniform(lower, upper)
    beyond = np.where(rng.random(6) < 0.5, upper + rng.uniform(0, 3 * stall, 6), lower - rng.uniform(0, 3 * stall, 6))
    return np.choose(where, [inside, upper, lower, beyond]), where


def test_applied_torque_is_the_envelope_law(pair):
    on, off = pair
    rng = np.random.default_rng(11)
    names = [p.name for p in on.m.params]
    seen = set()
    for _ in range(40):
        q, u = random_point(on, rng)
        stall, noload, viscous = rng.uniform(1, 10), rng.uniform(2, 20), rng.uniform(0, 0.1)
        par = on.m.default_par(drive_stall_torque=stall, drive_noload_speed=noload, drive_viscous=viscous)
        omega = on.spin_rates(u)
        cmd, where = commands(rng, omega, stall, noload)
        seen |= set(where)
        inp = on.m.default_inp(**{f"tau[{i}]": cmd[i - 1] for i in range(1, 7)})
        expected = applied_torque(cmd, omega, stall, noload, viscous)
        y = on.out(q, u, inp, par)
        got = np.array([y[f"wheel[{i}].tau"] for i in range(1, 7)])
        assert np.max(np.abs(got - expected)) <= 1e-12 * max(1.0, np.max(np.abs(expected))), (got, expected)
        # the equations are the plain model's driven by the applied torques (each wheel's own torque on its own
        # spin coordinate; in 2D the pair 1, 3 and the pair 2, 4 add on their shared coordinate) ...
        plain_par = np.array([par[names.index(p.name)] for p in off.m.params])
        plain_inp = off.m.default_inp(**{f"tau[{i}]": expected[i - 1] for i in range(1, 7)})
        f_on, work_rate = on.f(q, u, inp, par)
        f_off, _ = off.f(q, u, plain_inp, plain_par)
        assert np.max(np.abs(f_on - f_off)) <= 1e-12 * np.max(np.abs(f_off)), f_on - f_off
        # ... and the work integral's rate is the applied torques' power, gear loss included
        assert abs(work_rate - expected @ omega) <= 1e-12 * max(1.0, np.abs(expected * omega).sum())
    assert seen == {0, 1, 2, 3}          # inside, on the upper edge, on the lower edge, beyond


def test_drives_off_is_the_plain_model():
    bump2d = sc.load_shipped("bump2d")
    assert bump2d.options.drives is False and ModelOptions().drives is False
    plain = Functions(bump2d.options)
    assert not {p.name for p in plain.m.params} & set(DRIVE_PARAMS)
    assert not [n for n in plain.out_names if n.endswith(".tau")]
    assert plain.m.spec("t").outputs[-1].description == "work done by the motor torques since the start"
    # drives whose envelope never binds (huge stall torque and no-load speed, no gear loss) give exactly the plain
    # model: so the plain model applies tau[i] as it is, while default drives do change it at the same points
    drives = Functions(ModelOptions(dims="2d", terrain="bump", drives=True))
    unbound = drives.m.default_par(drive_stall_torque=1e9, drive_noload_speed=1e9, drive_viscous=0.0)
    rng = np.random.default_rng(5)
    changed = 0
    for _ in range(20):
        q, u = random_point(plain, rng)
        tau = {f"tau[{i}]": rng.uniform(-20, 20) for i in range(1, 7)}
        f_plain, g_plain = plain.f(q, u, plain.m.default_inp(**tau), plain.m.default_par())
        f_unbound, g_unbound = drives.f(q, u, drives.m.default_inp(**tau), unbound)
        assert np.max(np.abs(f_plain - f_unbound)) <= 1e-12 * np.max(np.abs(f_plain))
        assert abs(g_plain - g_unbound) <= 1e-12 * max(1.0, abs(g_plain))
        f_default, _ = drives.f(q, u, drives.m.default_inp(**tau), drives.m.default_par())
        changed += np.max(np.abs(f_default - f_plain)) > 1e-3 * np.max(np.abs(f_plain))
    assert changed == 20


# ---------------------------------------------------------------- scene option
SCENE = """\
name = "t2d"
dims = "2d"
terrain = "flat"
"""


@pytest.mark.parametrize("text, key, reason", [
    ('drives = "yes"\n', "drives", "expected true or false"),
    ("drives = 1\n", "drives", "expected true or false"),
    ("drives = true\nlocked_wheels = true\n", "drives", "locked wheels have no motors"),
    ("drives = true\n[parameters]\ndrive_stall_torque = 0.0\n", "parameters.drive_stall_torque", "must be > 0.0"),
    ("drives = true\n[parameters]\ndrive_noload_speed = -10.0\n", "parameters.drive_noload_speed",
     "must be > 0.0"),
    ("drives = true\n[parameters]\ndrive_viscous = -0.01\n", "parameters.drive_viscous", "must be >= 0.0"),
    ("[parameters]\ndrive_viscous = 0.01\n", "parameters.drive_viscous", "not a parameter of this scene"),
])
def test_bad_drives_scene(tmp_path, text, key, reason):
    path = tmp_path / "drives.toml"
    path.write_text(SCENE + text)
    with pytest.raises(sc.SceneError) as e:
        sc.load(path)
    msg = str(e.value)
    assert str(path) in msg and f"'{key}'" in msg and reason in msg, msg


def test_drives_scene_options_reach_the_spec(tmp_path):
    path = tmp_path / "drives.toml"
    path.write_text(SCENE + "drives = true\n[parameters]\ndrive_stall_torque = 3.5\ndrive_viscous = 0.0\n")
    spec = sc.load(path).spec()
    spec.check()
    par = {p.name: p for p in spec.params}
    assert par["drive_stall_torque"].start == 3.5 and par["drive_viscous"].start == 0.0
    assert par["drive_noload_speed"].start == 10.0
    assert [(par[n].unit, par[n].min, par[n].min_exclusive) for n in DRIVE_PARAMS] == [
        ("N.m", 0.0, True), ("rad/s", 0.0, True), ("N.m.s/rad", 0.0, False)]
    assert [o.name for o in spec.outputs if o.name.endswith(".tau")] == [f"wheel[{i}].tau" for i in range(1, 7)]
    assert "applied torques" in spec.outputs[-1].description


# ---------------------------------------------------------------- the FMU
@pytest.fixture(scope="module")
def fmu_paths(tmp_path_factory):
    paths = {}
    for name in ("bump2d", "bump2d_drives"):
        paths[name] = shipped_fmu(name, tmp_path_factory)
    return paths


WHEELS = range(1, 7)
OMEGA = [f"wheel[{i}].omega" for i in WHEELS]
TAU = [f"wheel[{i}].tau" for i in WHEELS]


def test_fmu_variables(fmu_paths):
    plain = RoverFMU(fmu_paths["bump2d"])
    assert not [n for n in plain.vars if n.startswith("drive_") or n.endswith(".tau")]
    plain.close()
    f = RoverFMU(fmu_paths["bump2d_drives"])
    v = f.vars
    assert [(v[n].causality, v[n].unit, v[n].start) for n in DRIVE_PARAMS] == [
        ("parameter", "N.m", "6.0"), ("parameter", "rad/s", "10.0"), ("parameter", "N.m.s/rad", "0.01")]
    assert all(v[n].causality == "output" and v[n].unit == "N.m" for n in TAU)
    # the glue refuses a zero no-load speed (the envelope divides by it) and a negative gear loss, by name
    from fmpy.fmi1 import FMICallException
    f.fmu.instantiate(callbacks=f._callbacks)
    f.fmu.setupExperiment(startTime=0.0)
    f.fmu.enterInitializationMode()
    for name, bad in (("drive_noload_speed", 0.0), ("drive_stall_torque", 0.0), ("drive_viscous", -1e-3)):
        with pytest.raises(FMICallException):
            f.fmu.setReal([v[name].valueReference], [bad])
        assert name in f.messages[-1], f.messages[-1]
    f.fmu.exitInitializationMode()
    f.close()


def fmu_law_error(f, y, commands):
    """Largest difference between the FMU's wheel[i].tau and the numpy law at its own outputs wheel[i].omega."""
    par = f.get(list(DRIVE_PARAMS))
    omega, tau = y[:6], y[6:12]
    return np.max(np.abs(tau - applied_torque(np.asarray(commands), omega, *par)))


def test_energy_balance_with_drives(fmu_paths):
    """K + P - W is constant when nothing but the drives dissipates (no ground, joint or stop damping, mu = 0:
    the torques only spin the wheels and rock the rover on its springs by their reactions): the work integral is
    the applied torques' (envelope and gear loss included), at the solver's tolerance. Commands of +-8 N.m
    sweep every wheel across both edges of its envelope."""
    f = RoverFMU(fmu_paths["bump2d_drives"])
    f.start({"ground_d": 0.0, "fork_d": 0.0, "stop_d": 0.0, "mu": 0.0, "solver.tol": 1e-8})
    names = OMEGA + TAU + ["energy.kinetic", "energy.potential", "energy.work"]
    balance, work, law_error = [], [], 0.0
    held = [0.0] * 6                   # the commands of the last step (the outputs are the step end's)
    for k in range(201):
        y = f.get(names)
        law_error = max(law_error, fmu_law_error(f, y, held))
        kinetic, potential, w = y[12:]
        balance.append(kinetic + potential - w)
        work.append(w)
        if k == 200:
            break
        held = [8.0 * np.sin(2 * np.pi * (0.5 + 0.3 * i) * 0.01 * k) for i in WHEELS]
        f.set({f"tau[{i}]": c for i, c in zip(WHEELS, held)})
        assert f.step(0.01 * (k + 1)), f.messages
    f.close()
    moved = np.sum(np.abs(np.diff(work)))          # energy that went through the drives, in and out
    drift = np.max(np.abs(np.array(balance) - balance[0]))
    print(f"energy through the drives {moved:.4f} J, balance drift {drift:.2e} J")
    assert moved > 1.0
    assert drift < 1e-6 * moved                    # measured 1.8e-8 J of 2.85 J at solver.tol 1e-8
    assert law_error < 1e-12


def spin_lifted(path, commands, stop):
    """The rover in free space (g = 0, body at 1 m, no settle) with constant commands; the sampled spin rates
    relative to the carriers and the largest deviation of wheel[i].tau from the law (nan without drives)."""
    f = RoverFMU(path)
    f.start({"g": 0.0, "start.settle": False, "start.z": 1.0})
    f.set({f"tau[{i}]": c for i, c in zip(WHEELS, commands)})
    drives = f.has(TAU[0])
    spins, law_error = [], 0.0 if drives else np.nan
    for k in range(1, int(round(stop / 0.01)) + 1):
        assert f.step(0.01 * k), f.messages
        y = f.get(OMEGA + (TAU if drives else []))
        spins.append(y[:6])
        if drives:
            law_error = max(law_error, fmu_law_error(f, y, commands))
    f.close()
    return np.array(spins), law_error


def test_lifted_wheels_cannot_outrun_the_motor(fmu_paths):
    # any positive command, each 2D pair (1, 3) and (2, 4) with different commands on its shared spin
    commands = [4.0, 6.0, 1000.0, 0.5, 50.0, 0.2]
    spins, law_error = spin_lifted(fmu_paths["bump2d_drives"], commands, 2.0)
    print("peak spin with drives", np.max(np.abs(spins), axis=0))
    assert np.max(np.abs(spins)) <= 10.0           # drive_noload_speed
    # free-running: the upper edge minus the gear loss is 0 at w = T_s / (T_s / w_0 + b) = 9.836 rad/s
    assert np.allclose(spins[-1], 6.0 / (0.6 + 0.01), rtol=1e-3), spins[-1]
    assert law_error < 1e-12
    # without drives the controller's largest torque spins them far beyond within a quarter second (longer, the
    # reaction tips the floating body over, which stops the FMU)
    plain, _ = spin_lifted(fmu_paths["bump2d"], [4.0] * 6, 0.25)
    print("peak spin without drives", np.max(np.abs(plain), axis=0))
    assert np.min(np.max(np.abs(plain), axis=0)) > 50 * 10.0


def test_drives_paper_example(tmp_path):
    """The example's two bump runs up to 5 s: the rover has reached the bump and stalls at it for a while, its
    bogie wheels off the ground; plain torques spin them to ~830 rad/s there, the drives hold every wheel under
    the no-load speed (later, rolling down the bump faster than 0.65 m/s, the ground spins the wheels past it
    while the drives brake: the full-run figures of docs/scenarios.md)."""
    built = REPO / "build"          # else the example builds both FMUs into tmp_path itself
    both_built = all((built / f"{s}.fmu").exists() for s in drives_paper.SCENES)
    figures = drives_paper.run(build_dir=built if both_built else tmp_path, out_dir=tmp_path / "out",
                                   stop_time=5.0)
    for name in ("bump2d.csv", "bump2d_drives.csv", "spin_and_load.png"):
        assert (tmp_path / "out" / name).stat().st_size > 1000, name
    plain, drives = figures["bump2d"], figures["bump2d_drives"]
    assert drives["peak spin [rad/s]"] <= 10.0 + 1e-9
    assert drives["peak spin airborne [rad/s]"] > 9.0             # the bogie wheels did spin in the air
    assert plain["peak spin airborne [rad/s]"] > 50 * 10.0
    assert drives["slip work [J]"] < plain["slip work [J]"] / 10
    assert plain["gear loss [J]"] == 0 < drives["gear loss [J]"]
    for f in (plain, drives):                        # the sampled slip work fits in the exact dissipation
        assert 0 < f["slip work [J]"] < f["dissipated W - d(K+P) [J]"]
