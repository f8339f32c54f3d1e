"""Scene files: shipped scenes load and give valid specs; bad files fail with the file, the key and the reason;
overrides end up as start values of the ModelSpec."""
import pytest

from cedra.models import scene as sc
from cedra.rover.parameters import DEFAULTS

BASE = """\
name = "t3d"
description = "test scene"
dims = "3d"
terrain = "bump"
contact = "compliant"
steering = true
stop_time = 2.0
output_interval = 0.01

[solver]
method = "rk4"
tol = 1e-5
h_max = 0.002
"""


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("name", sc.shipped())
def test_shipped_scene_loads_and_checks(name):
    s = sc.load_shipped(name)
    assert s.name == name
    spec = s.spec()
    spec.check()
    assert spec.name == name
    assert spec.stop_time == s.stop_time and spec.solver == s.solver


def test_shipped_scenes_present():
    assert {"bump2d", "flat3d", "slope3d"} <= set(sc.shipped())
    with pytest.raises(sc.SceneError, match="no_such_scene"):
        sc.load_shipped("no_such_scene")


def test_base_scene_is_valid(tmp_path):
    s = sc.load(write(tmp_path, BASE))
    assert s.options.dims == "3d" and s.options.terrain == "bump" and s.options.steering
    assert s.options.rover == "cedra"                               # the default rover
    assert sc.load(write(tmp_path, 'rover = "cedra"\n' + BASE, "named.toml")).options == s.options
    assert s.solver == dict(method="rk4", tol=1e-5, h_max=0.002)


def _replace(key, line):
    """BASE with the top-level `key = ...` line replaced by `line` (or appended if not present)."""
    lines = BASE.splitlines()
    for k, ln in enumerate(lines):
        if ln.split("=")[0].strip() == key and k < lines.index("[solver]"):
            lines[k] = line
            return "\n".join(lines) + "\n"
    return line + "\n" + BASE


BAD = [
    # (id, scene text, key named in the message, words of the reason)
    ("unknown_top", "colour = 'red'\n" + BASE, "colour", "unknown key"),
    ("dims_4d", _replace("dims", 'dims = "4d"'), "dims", "must be one of"),
    ("terrain_moon", _replace("terrain", 'terrain = "moon"'), "terrain", "must be one of"),
    ("steering_2d", _replace("dims", 'dims = "2d"'), "steering", "2d scene has no steering"),
    ("stop_time_neg", _replace("stop_time", "stop_time = -1.0"), "stop_time", "must be > 0"),
    ("solver_euler", BASE.replace('method = "rk4"', 'method = "euler"'), "solver.method", "must be one of"),
    ("solver_tol", BASE.replace("tol = 1e-5", "tol = -1"), "solver.tol", "must be > 0"),
    ("R_w_neg", BASE + "[parameters]\nR_w = -0.1\n", "parameters.R_w", "must be >= 0.0001"),
    ("param_unknown", BASE + "[parameters]\nno_such = 1.0\n", "parameters.no_such", "not a parameter"),
    ("mu_string", BASE + '[inputs]\nmu = "high"\n', "inputs.mu", "expected a number"),
    ("start_unknown", BASE + "[start]\nno_such = 1.0\n", "start.no_such", "not a coordinate"),
    ("input_2d_y0", _replace("steering", "steering = false").replace('"3d"', '"2d"')
     + "[inputs]\nterrain_y0 = 1.0\n", "inputs.terrain_y0", "of this scene"),
    ("start_2d_yaw", _replace("steering", "steering = false").replace('"3d"', '"2d"') + "[start]\nyaw = 1.0\n",
     "start.yaw", "not a coordinate"),
    ("solver_unknown", BASE.replace("tol = 1e-5", "tol = 1e-5\norder = 4"), "solver.order", "unknown key"),
    ("missing_name", BASE.replace('name = "t3d"\n', ""), "name", "missing"),
    ("rover_unknown", 'rover = "curiosity"\n' + BASE, "rover", "must be one of"),
]


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_scene(tmp_path, case):
    _, text, key, reason = case
    p = write(tmp_path, text, f"bad_{case[0]}.toml")
    with pytest.raises(sc.SceneError) as e:
        sc.load(p)
    msg = str(e.value)
    assert str(p) in msg, msg
    assert f"'{key}'" in msg, msg
    assert reason in msg, msg


def test_invalid_toml(tmp_path):
    p = write(tmp_path, BASE + "[parameters\nR_w = 0.1\n", "broken.toml")
    with pytest.raises(sc.SceneError) as e:
        sc.load(p)
    assert str(p) in str(e.value) and "not valid TOML" in str(e.value)


def test_missing_file(tmp_path):
    p = tmp_path / "nowhere.toml"
    with pytest.raises(sc.SceneError) as e:
        sc.load(p)
    assert str(p) in str(e.value) and "cannot read" in str(e.value)


def test_overrides_become_start_values(tmp_path):
    text = BASE + """
[parameters]
m_B = 25.0
ground_k = 2e5
steer_k = 40

[inputs]
mu = 0.5
"tau[2]" = 1.5
"steer[1]" = 0.25
terrain_h = 0.1

[start]
x = 1.5
yaw = 0.3
theta4 = -0.2
"""
    s = sc.load(write(tmp_path, text))
    spec = s.spec()
    spec.check()
    par = {p.name: p.start for p in spec.params}
    inp = {p.name: p.start for p in spec.inputs}
    q0 = dict(zip(spec.q_names, spec.q_start))
    assert par["m_B"] == 25.0 and par["ground_k"] == 2e5 and par["steer_k"] == 40.0
    assert par["R_w"] == DEFAULTS["R_w"] and par["I_F"] == DEFAULTS["I_F"]          # the rest untouched
    assert inp["mu"] == 0.5 and inp["tau[2]"] == 1.5 and inp["steer[1]"] == 0.25 and inp["terrain_h"] == 0.1
    assert inp["tau[1]"] == 0.0 and inp["terrain_x0"] == 1.0
    assert q0["x"] == 1.5 and q0["yaw"] == 0.3 and q0["theta4"] == -0.2
    assert q0["z"] == pytest.approx(0.2, abs=1e-15) and q0["y"] == 0.0
    assert spec.stop_time == 2.0 and spec.output_interval == 0.01
    assert spec.solver == dict(method="rk4", tol=1e-5, h_max=0.002)


def test_the_build_command_checks_every_scene_before_it_builds_any(tmp_path):
    """`python -m cedra build` builds scenes in parallel, so every file is checked first: a bad one among good
    ones fails with its file, key and reason, and nothing is generated"""
    import subprocess
    import sys
    bad = write(tmp_path, BASE.replace('dims = "3d"', 'dims = "4d"'), "bad.toml")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "cedra", "build", "bump2d", str(bad), "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert str(bad) in r.stderr and "'dims'" in r.stderr and "4d" in r.stderr
    assert not out.exists()


def test_the_build_command_refuses_two_scenes_of_one_name(tmp_path):
    """two files naming the same scene would build into the same directory at once"""
    import subprocess
    import sys
    a = write(tmp_path, BASE, "a.toml")
    b = write(tmp_path, BASE, "b.toml")
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "cedra", "build", str(a), str(b), "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "both build the FMU 't3d'" in r.stderr, r.stderr
    assert not out.exists()


def test_moreau_is_for_rigid_contact_only(tmp_path):
    p = write(tmp_path, BASE.replace('method = "rk4"', 'method = "moreau"'))
    with pytest.raises(sc.SceneError) as e:
        sc.load(p)
    assert str(e.value).startswith(f"{p}: key 'solver.method': moreau is the rigid contact's own"), str(e.value)
    rigid = write(tmp_path, BASE.replace('method = "rk4"', 'method = "moreau"').replace(
        'contact = "compliant"', 'contact = "rigid"').replace("steering = true", "steering = false"), "r.toml")
    assert sc.load(rigid).solver["method"] == "moreau"


VARIANT = """\
base = "cedra"
description = "a variant for the tests"
[parameters]
bogie_half = 0.13
"""


def test_a_scene_names_a_shipped_variant_and_gets_its_values(tmp_path):
    """`rover = "cedra_shrimp"`: CEDRA's model with the variant's values as start values (the scene's own
    [parameters] over them) and the variant's design pose as the start."""
    from cedra.models.rovers import VARIANTS
    from cedra.rover.mechanism import design
    text = 'rover = "cedra_shrimp"\n' + _replace("steering", "steering = false") + "[parameters]\nm_B = 21.0\n"
    s = sc.load(write(tmp_path, text))
    assert s.options.rover == "cedra" and s.variant is VARIANTS["cedra_shrimp"]
    spec = s.spec()
    spec.check()
    par = {p.name: p.start for p in spec.params}
    values = VARIANTS["cedra_shrimp"].values
    assert values and all(par[k] == v for k, v in values.items() if k != "m_B")
    assert par["m_B"] == 21.0
    q0 = dict(zip(spec.q_names, spec.q_start))
    assert q0["z"] == pytest.approx(design(par)["z"]) and q0["theta4"] == pytest.approx(par["fork_theta4_ref"])


def test_a_scene_names_a_variant_file(tmp_path):
    write(tmp_path, VARIANT, "long_bogies.toml")
    s = sc.load(write(tmp_path, 'rover = "long_bogies.toml"\n' + BASE))
    assert s.variant.name == "long_bogies" and s.parameters["bogie_half"] == 0.13
    assert {p.name: p.start for p in s.spec().params}["bogie_half"] == 0.13


BROKEN = [
    # (id, variant file text, key, words of the reason): the four-bar cannot close at its design angle, or only
    # beyond a stop the variant moves
    ("short_upper_link", VARIANT + "fork_b = 0.01\n", "parameters.fork_b", "cannot be assembled at theta4"),
    ("stop_past_toggle", VARIANT + "fork_stop_lo = -1.2\n", "parameters.fork_stop_lo", "within its stops"),
    ("unknown_parameter", VARIANT + "no_such = 1.0\n", "parameters.no_such", "not a parameter of rover cedra"),
    ("no_base", VARIANT.replace('base = "cedra"\n', ""), "base", "missing"),
    ("fork_a_negative", VARIANT + "fork_a = -0.1\n", "parameters.fork_a", "must be >="),
]


@pytest.mark.parametrize("case", BROKEN, ids=[c[0] for c in BROKEN])
def test_a_broken_variant_fails_before_code_generation(tmp_path, case):
    """A scene naming a variant file whose four-bar cannot close over its joint range (or is otherwise bad) fails
    when it is loaded, naming the variant file, its key and the reason."""
    _, text, key, reason = case
    variant = write(tmp_path, text, f"{case[0]}.toml")
    scene = write(tmp_path, f'rover = "{variant.name}"\n' + BASE)
    with pytest.raises(sc.SceneError) as e:
        sc.load(scene)
    msg = str(e.value)
    assert msg.startswith(f"{variant}: key '{key}': "), msg
    assert reason in msg, msg


def test_a_scene_that_breaks_the_four_bar_itself_is_named(tmp_path):
    """The scene's own [parameters] break the variant's four-bar: the scene file and its key are named."""
    write(tmp_path, VARIANT, "long_bogies.toml")
    p = write(tmp_path, 'rover = "long_bogies.toml"\n' + BASE + "[parameters]\nfork_b = 0.01\n")
    with pytest.raises(sc.SceneError, match=f"^{p}: key 'parameters.fork_b': .*cannot be assembled"):
        sc.load(p)
    with pytest.raises(sc.SceneError, match="no rover variant file"):
        sc.load(write(tmp_path, 'rover = "nowhere.toml"\n' + BASE))
