"""Sweeps on Dask: bad sweep files fail before any run; a 200-run sweep on a LocalCluster; the same
table with 1 and 2 workers; a worker killed mid-sweep loses nothing; --resume reruns nothing already done."""
from __future__ import annotations

import os
import signal
import tempfile
import textwrap
from dataclasses import replace
from pathlib import Path

import psutil
import pytest

from cedra import sweep as sw_mod
from cedra.sweep import verdicts, worker
from cedra.run.scenario import fmu
from cedra.sweep import SweepError, execute, load, read_table

BUILD = "build"


@pytest.fixture(scope="module")
def bump2d_fmu():
    return fmu("bump2d", BUILD)


def write(tmp_path, body, name="s.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(body).replace("OUT", str(tmp_path / "out")))
    return path


def results(table, drop=("wall_s",)):
    """The table's rows by id, without the columns that measure the machine rather than the model."""
    return {r["id"]: {k: v for k, v in r.items() if k not in drop} for r in read_table(table)}


# ------------------------------------------------------------------ bad files fail before any run

BAD = [
    ("[grid]\nterrain_hh = [0.1]\n", "grid.terrain_hh", "unknown parameter 'terrain_hh'"),
    ("[grid]\nmu = []\n", "grid.mu", "empty list"),
    ("[grid]\nmu = {from = 0.5, to = 0.5, num = 3}\n", "grid.mu", "empty range"),
    ("[grid]\nmu = {from = 0.2, to = 1.0, num = 0}\n", "grid.mu.num", "expected an integer >= 1"),
    ("[random]\nsamples = 3\nmu = [0.9, 0.2]\n", "random.mu", "empty range"),
    ("outputs = ['climbed', 'peak_Fz']\n[grid]\nmu = [0.5]\n", "outputs[1]", "no output 'peak_Fz'"),
    ("[grid]\nmu = [0.5, -1.0]\n", "grid.mu", "outside the range of mu"),
    ("[grid]\nmu = [0.5]\n[map]\nx = 'terrain_h'\ny = 'mu'\nverdict = 'climbed'\n", "map.x", "not a [grid] parameter"),
    ("stop_tim = 3\n[grid]\nmu = [0.5]\n", "stop_tim", "unknown key"),
    ("[fixed]\nmu = 0.5\n[grid]\nmu = [0.5]\n", "grid.mu", "already set in [fixed]"),
    ("", "grid", "nothing to vary"),
    ("scenario = 'turn_flat'\n[grid]\nmu = [0.5]\n", "scene", "not both"),
    ("[options]\nturbo = true\n[grid]\nmu = [0.5]\n", "options.turbo", "unknown option (options: drives"),
    ("[options]\ndrives = 1\n[grid]\nmu = [0.5]\n", "options.drives", "expected true or false, got 1"),
    ("options = ['drives']\n[grid]\nmu = [0.5]\n", "options", "expected a table"),
    # a parameter of the drives is a parameter of the variant only
    ("[grid]\ndrive_stall_torque = [6.0]\n", "grid.drive_stall_torque", "unknown parameter"),
]


@pytest.mark.parametrize("body,key,reason", BAD, ids=[b[1] + ":" + b[2][:20] for b in BAD])
def test_bad_sweep_file_fails_before_any_run(tmp_path, body, key, reason):
    path = write(tmp_path, "scene = 'bump2d'\nout = 'OUT'\n" + body)
    with pytest.raises(SweepError) as e:
        load(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: {key}: "), msg
    assert reason in msg, msg
    assert not (tmp_path / "out").exists()


def test_unknown_scene_and_cli_exit_code(tmp_path, capsys):
    path = write(tmp_path, "scene = 'bump9d'\n[grid]\nmu = [0.5]\n")
    from cedra.__main__ import main
    assert main(["sweep", str(path), "--build", BUILD]) == 2
    err = capsys.readouterr().err
    assert f"{path}: scene: 'bump9d' is neither a shipped scene" in err


def test_shipped_sweeps_load():
    drives = {"climb": True, "climb_plain": False, "climb_rigid": False, "climb_step": True, "climb_step_plain": False}
    for name, on in drives.items():
        sw = load(sw_mod.resolve(name))
        assert len(sw.runs()) >= (200 if "step" not in name else 78)
        assert sw.fixed == {"tau_max": 4.0}
        assert max(sw.grid["terrain_h"]) == pytest.approx(3 * 0.065)
        assert sw.target.scene.options.drives == on, name
        # chassis contact: the step maps' scene has it, the bump maps turn it on (a variant); rigid has none
        assert sw.target.scene.options.chassis == (name != "climb_rigid"), name
        assert sw.target.variant == (on or name in ("climb", "climb_plain")), name
        assert sw.map["verdict"] == "verdict" and "verdict" in sw.outputs
        assert sw.actuation().startswith("drives (stall 6 N.m, no-load 10 rad/s" if on else "plain torque")
        assert ("plain torque" in sw.map["title"]) != on and ("drives" in sw.map["title"]) == on, name
    for a, b in (("climb", "climb_plain"), ("climb_step", "climb_step_plain")):     # variants of the same map
        sa, sb = load(sw_mod.resolve(a)), load(sw_mod.resolve(b))
        assert sa.runs() == sb.runs() and sa.out != sb.out
        assert not {sa.run_id(p) for p in sa.runs()} & {sb.run_id(p) for p in sb.runs()}
    assert load(sw_mod.resolve("climb_step")).target.scene.name == "step2d_drives"
    assert load(sw_mod.resolve("climb")).target.scene.name == "bump2d_drives_chassis"
    stairs = load(sw_mod.resolve("climb_stairs"))
    assert stairs.target.scene.options.terrain == "stairs" and len(stairs.runs()) == 25
    assert load(sw_mod.resolve("turn_flat")).target.kind == "scenario"
    sc = load(sw_mod.resolve("step_climb"))
    assert sc.target.kind == "scenario" and "inverse kinematics.mean_slip" in sc.outputs


def test_nested_scenario_summaries_become_columns():
    assert worker._flat({"equal torques": {"mean_slip": 1.0, "x_end": 2.0}, "wall": 3.0}) == \
        {"equal torques.mean_slip": 1.0, "equal torques.x_end": 2.0, "wall": 3.0}


# ------------------------------------------------------------------ running on the local cluster

SHORT = """
scene = "bump2d"
stop_time = 0.3
out = "OUT"
[grid]
mu = {from = 0.2, to = 1.2, num = 10}
terrain_h = {from = 0.0, to = 0.19, num = 20}
"""


def test_200_runs_on_local_cluster_and_resume_after_interrupt(tmp_path, bump2d_fmu):
    sw = load(write(tmp_path, SHORT))
    assert len(sw.runs()) == 200

    class Interrupt(Exception):
        pass

    def stop_after_30(k, row):
        if k == 30:
            raise Interrupt
    with pytest.raises(Interrupt):
        execute(sw, BUILD, workers=2, quiet=True, on_result=stop_after_30)
    first = results(sw.table)
    assert len(first) == 30                      # every finished run was written before the interrupt
    with pytest.raises(SweepError, match="pass --resume"):
        execute(sw, BUILD, workers=2, quiet=True)
    counts = execute(sw, BUILD, workers=2, quiet=True, resume=True)
    assert counts == dict(total=200, skipped=30, ran=170, failed=0)
    full = results(sw.table)
    assert len(full) == 200 and len(read_table(sw.table)) == 200          # nothing ran twice
    assert all(full[i] == row for i, row in first.items())                # nothing written was lost
    assert all(r["status"] == "ok" for r in full.values())
    assert execute(sw, BUILD, workers=2, quiet=True, resume=True) == dict(total=200, skipped=200, ran=0, failed=0)


MIXED = """
scene = "bump2d"
stop_time = 2.0
out = "OUT"
[grid]
terrain_h = [0.05, 0.15]
[random]
samples = 6
seed = 7
mu = [0.2, 1.2]
ground_k = [5e4, 2e5]
"""


def test_one_and_two_workers_give_the_same_table(tmp_path, bump2d_fmu):
    sw = load(write(tmp_path, MIXED))
    assert len(sw.runs()) == 12
    execute(sw, BUILD, workers=1, quiet=True)
    one = results(sw.table)
    execute(sw, BUILD, workers=2, quiet=True, overwrite=True)
    two = results(sw.table)
    assert one == two
    assert len({r["mu"] for r in one.values()}) == 6                       # the draws differ from each other


def _worker_pids():
    """The LocalCluster's worker processes: this process's children started by multiprocessing's spawn (the
    nannies run in this process; the resource tracker is not a worker)."""
    return [p.pid for p in psutil.Process().children(recursive=True)
            if "spawn_main" in " ".join(p.cmdline())]


def test_killed_worker_loses_nothing(tmp_path, bump2d_fmu):
    sw = load(write(tmp_path, MIXED.replace("stop_time = 2.0", "stop_time = 3.0")))
    seen = {}
    leftovers = set(Path(tempfile.gettempdir()).glob("cedra-*.fmu"))

    def kill_one(k, row):
        if k == 3:
            seen["before"] = results(sw.table)
            pids = _worker_pids()
            assert pids, "no worker process found"
            os.kill(pids[0], signal.SIGKILL)
            seen["killed"] = pids[0]
    counts = execute(sw, BUILD, workers=2, quiet=True, on_result=kill_one)
    assert "killed" in seen
    after = results(sw.table)
    assert counts["ran"] == 12 and len(after) == 12
    assert all(after[i] == row for i, row in seen["before"].items())
    assert all(r["status"] == "ok" for r in after.values()), [r["reason"] for r in after.values()]
    # the killed worker's run was rescheduled: the table equals an undisturbed sweep's
    execute(sw, BUILD, workers=2, quiet=True, overwrite=True)
    assert results(sw.table) == after
    # a worker's copy of the FMU lives in the worker's own directory, which Dask removes even for a killed worker
    assert set(Path(tempfile.gettempdir()).glob("cedra-*.fmu")) <= leftovers


def _free_port():
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_external_scheduler_gives_the_local_table(tmp_path, bump2d_fmu):
    """`--scheduler tcp://host:port`: the documented `dask scheduler` / `dask worker` commands, here on loopback."""
    import subprocess
    import sys
    import time
    from pathlib import Path
    dask = str(Path(sys.executable).parent / "dask")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        time.sleep(2)
        procs.append(subprocess.Popen([dask, "worker", addr, "--nworkers", "2", "--nthreads", "1", "--no-dashboard"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path))
        from distributed import Client
        with Client(addr, timeout=30) as c:
            c.wait_for_workers(2, timeout=60)
        sw = load(write(tmp_path, MIXED))
        counts = execute(sw, BUILD, scheduler=addr, quiet=True)
        assert counts["ran"] == 12 and counts["failed"] == 0
        remote = results(sw.table)
        execute(sw, BUILD, workers=1, quiet=True, overwrite=True)
        assert results(sw.table) == remote
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=30)


# ------------------------------------------------------------------ [options]: a variant of the scene

STALL = """
scene = "bump2d"
stop_time = 6.0
out = "OUT"
[fixed]
tau_max = 4.0
[grid]
mu = [0.8]
terrain_h = [0.10, 0.14625]
"""


def test_drives_option_runs_the_drives_variant(tmp_path, bump2d_fmu):
    """[options] drives = true on bump2d: the variant bump2d_drives is built (into build/variants/) and run; its
    runs equal the shipped bump2d_drives FMU's (the same model), never share an id with the plain scene's, and show
    the drives: at the bump's foot (t = 3.5-5 s) the unloaded bogie wheels spin up to 26-54 m/s of slip with plain
    torques, to about the drives' free-running speed (10 rad/s, 0.65 m/s at the rim) with drives (0.6-0.9 m/s)."""
    import zipfile
    import xml.etree.ElementTree as ET
    from cedra.models.scene import SWEEP_OPTIONS
    assert "drives" in SWEEP_OPTIONS
    plain = load(write(tmp_path, STALL))
    drives = load(write(tmp_path, STALL + "[options]\ndrives = true\n", name="d.toml"))
    drives.name = plain.name                                  # the same table: a resumed sweep must rerun every run
    assert drives.target.variant and drives.target.scene.name == "bump2d_drives"
    assert "drive_stall_torque" in drives.target.limits and "drive_stall_torque" not in plain.target.limits
    assert plain.run_id(plain.runs()[0]) != drives.run_id(drives.runs()[0])
    assert plain.actuation() == "plain torque (tau_max 4 N.m)"
    assert drives.actuation() == "drives (stall 6 N.m, no-load 10 rad/s; tau_max 4 N.m commanded)"
    assert execute(plain, BUILD, workers=2, quiet=True)["ran"] == 2
    counts = execute(drives, BUILD, workers=2, quiet=True, resume=True)
    assert counts == dict(total=2, skipped=0, ran=2, failed=0)
    rows = read_table(drives.table)
    assert len(rows) == 4
    by_id = {r["id"]: r for r in rows}
    variant_fmu = Path(BUILD) / "variants" / "bump2d_drives.fmu"
    with zipfile.ZipFile(variant_fmu) as z:
        md = ET.fromstring(z.read("modelDescription.xml"))
    assert md.get("modelName") == "bump2d_drives"
    assert "drive_stall_torque" in {v.get("name") for v in md.iter("ScalarVariable")}
    shipped = fmu("bump2d_drives", BUILD).read_bytes()
    for p in drives.runs():
        d, q = by_id[drives.run_id(p)], by_id[plain.run_id(p)]
        assert d["status"] == q["status"] == "ok", (d, q)
        assert float(d["max_slip"]) < 1.5 < 20.0 < float(q["max_slip"]), (d["max_slip"], q["max_slip"])
        alone = sw_mod.run_one(shipped, "bump", p, drives.stop_time, 60.0)
        for o in drives.outputs:
            if o in ("verdict",):
                assert d[o] == alone[o]
            else:
                assert float(d[o]) == pytest.approx(alone[o], rel=1e-9, abs=1e-12, nan_ok=True), o
    # the built variant is kept while its stamp matches (the scene, today's sources and flags, the FMU file itself)
    # and rebuilt otherwise
    from cedra.fmu import packaging
    from cedra.models.scene import load_shipped
    scene = drives.target.scene
    assert packaging.fmu_state(scene, variant_fmu.parent)[2] == "up to date"
    assert packaging.build_key(scene) != packaging.build_key(load_shipped("bump2d_drives"))   # another scene
    changed = tmp_path / "variants"
    changed.mkdir()
    copy = changed / variant_fmu.name
    copy.write_bytes(variant_fmu.read_bytes() + b"\0")           # the FMU is not the file its stamp hashed
    copy.with_name(copy.name + packaging.STAMP_SUFFIX).write_bytes(
        variant_fmu.with_name(variant_fmu.name + packaging.STAMP_SUFFIX).read_bytes())
    assert packaging.fmu_state(scene, changed)[2] == "stale"
    flags = packaging.HAND_WRITTEN_CFLAGS                     # other compiler flags today: not the same build either
    try:
        packaging.HAND_WRITTEN_CFLAGS = ["-O2"]
        assert packaging.fmu_state(scene, variant_fmu.parent)[2] == "stale"
    finally:
        packaging.HAND_WRITTEN_CFLAGS = flags
    mtime = variant_fmu.stat().st_mtime_ns
    assert sw_mod.sweep_fmu(drives, BUILD) == variant_fmu and variant_fmu.stat().st_mtime_ns == mtime


# ------------------------------------------------------------------ the climbing map against single runs

R_W = 0.065
# three points of the shipped maps (examples/sweeps/climb.toml with drives, climb_plain.toml with plain torques):
# one that climbs (next to the paper's case), one that fails (a high bump with little friction: stuck), one at the
# edge (climbs, its next higher neighbour fails); the same points in both maps
MAP_POINTS = {"climbs": (7, 0.14625, 0.8), "fails": (9, 0.26, 0.2), "edge": (5, 0.26, 0.2)}


@pytest.mark.parametrize("name", ["climb_plain", "climb"])
def test_climbing_map_agrees_with_single_runs(tmp_path, name):
    """Single runs through the main job's own loop on the map's FMU (its variant of bump2d: chassis contact, and
    drives in climb)."""
    import numpy as np
    from cedra.run.simulate import run_bump
    shipped = load(sw_mod.resolve(name))
    heights = shipped.grid["terrain_h"]
    sw = load(sw_mod.resolve(name))
    sw.out = tmp_path / "out"
    points = {k: dict(tau_max=4.0, terrain_h=heights[i], terrain_w=w, mu=mu) for k, (i, w, mu) in MAP_POINTS.items()}
    # the four runs alone (a product grid over their values would run 16): the edge column, then the climbing point
    # appended to the same table
    sw.grid = {"terrain_h": sorted({heights[i] for i in (5, 6, 9)}), "terrain_w": [0.26], "mu": [0.2]}
    execute(sw, BUILD, workers=2, quiet=True)
    sw.grid = {"terrain_h": [points["climbs"]["terrain_h"]], "terrain_w": [0.14625], "mu": [0.8]}
    assert execute(sw, BUILD, workers=2, quiet=True, resume=True)["ran"] == 1
    table = {r["id"]: r for r in read_table(sw.table)}
    assert len(table) == 4
    map_ids = {shipped.run_id(p) for p in shipped.runs()}
    edge_above = dict(points["edge"], terrain_h=heights[6])
    verdicts = {}
    for name, p in list(points.items()) + [("edge_above", edge_above)]:
        assert sw.run_id(p) in map_ids                      # the same run as the shipped map's
        verdicts[name] = table[sw.run_id(p)]["climbed"]
        assert table[sw.run_id(p)]["verdict"] == ("over" if verdicts[name] == "1" else "stuck"), name
    assert verdicts == {"climbs": "1", "fails": "0", "edge": "1", "edge_above": "0"}
    # the map of these runs (the cells of the other runs of their grid empty): both verdicts' colours are in it
    from PIL import Image
    from cedra.sweep.maps import draw
    sw.grid = {"terrain_h": sorted({p["terrain_h"] for p in points.values()} | {heights[6]}),
               "terrain_w": [0.14625, 0.26], "mu": [0.2, 0.8]}
    png = draw(sw, read_table(sw.table))
    pixels = {rgb for _, rgb in Image.open(png).convert("RGB").getcolors(1 << 24)}
    assert (0x5c, 0xb8, 0x5c) in pixels and (0xd9, 0x53, 0x4f) in pixels         # climbs (green), fails (red)
    # alone, through the main job's own loop (no early stop, the full 20 s): past the bump's end or not
    for name, p in points.items():
        names, rows, _, info = run_bump(sw_mod.sweep_fmu(sw, BUILD), shipped.stop_time,
                                        {k: v for k, v in p.items() if k != "tau_max"})
        assert info["ok"], info["messages"][-2:]
        goal = 1.0 + 2.5 * p["terrain_w"]
        cx = rows[-1][[names.index(f"wheel[{i}].cx") for i in range(1, 7)]]
        assert int(np.min(cx) > goal) == int(verdicts[name]), (name, cx, goal)
    # on a bump narrower than a bogie and taller than the bogie's segment sits (w = R_w, h = 2.4 R_w) the rover
    # with chassis contact stops with its bogies on the bump: 'hung up', the chassis carrying load
    hung = sw_mod.run_one(Path(sw_mod.sweep_fmu(sw, BUILD)).read_bytes(), "bump",
                          dict(tau_max=4.0, terrain_h=2.4 * R_W, terrain_w=R_W, mu=1.0), shipped.stop_time, 60.0)
    assert hung["status"] == "ok" and hung["verdict"] == "hung up", hung


# ------------------------------------------------------------------ a scenario script as the run

def test_scenario_sweep(tmp_path):
    path = write(tmp_path, """
        scenario = "turn_flat"
        stop_time = 12.0
        out = "OUT"
        [grid]
        yaw_rate_cmd = [0.3, 0.5]
        """)
    sw = load(path)
    assert sw.outputs == ["yaw_rate", "speed", "radius", "commanded_radius"]
    counts = execute(sw, BUILD, workers=2, quiet=True)
    assert counts == dict(total=2, skipped=0, ran=2, failed=0)
    for r in read_table(sw.table):
        assert r["status"] == "ok", r["reason"]
        # each run got its own parameter: the turn holds that run's commanded yaw rate (within 5 % after 6 s)
        cmd = float(r["yaw_rate_cmd"])
        assert float(r["commanded_radius"]) == pytest.approx(0.2 / cmd, rel=1e-9)
        assert abs(float(r["yaw_rate"]) - cmd) < 0.05 * cmd, r


def test_options_the_scene_refuses_fail_before_any_run(tmp_path):
    """drives on a scene with locked wheels: the scene's own check, named by the sweep file's key."""
    (tmp_path / "locked.toml").write_text('name = "locked2d"\ndims = "2d"\nterrain = "flat"\nlocked_wheels = true\n')
    path = write(tmp_path, "scene = 'locked.toml'\nout = 'OUT'\n[options]\ndrives = true\n[grid]\nmu = [0.5]\n")
    with pytest.raises(SweepError) as e:
        load(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: options.drives: scene locked2d refuses it: "), msg
    assert "locked wheels have no motors" in msg, msg
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("body,key,reason", [
    ("scenario = 'turn_flat'\n[options]\ndrives = true\n[grid]\nmu = [0.5]\n", "options", "only for a scene"),
    ("scenario = 'turn_flat'\n[grid]\nterrain_h = [0.1]\n", "grid.terrain_h",
     "unknown parameter 'terrain_h' of scenario turn_flat"),
    ("scenario = 'turn_flat'\n[grid]\nyaw_rate_cmd = [0.0]\n", "grid.yaw_rate_cmd", "outside the range"),
    ("scenario = 'turn_flat'\noutputs = ['Fn']\n[grid]\nmu = [0.5]\n", "outputs[0]", "no output 'Fn'"),
    ("scenario = 'drop'\n[grid]\nmu = [0.5]\n", "scenario", "does not declare PARAMETERS"),
    ("scenario = 'nope'\n[grid]\nmu = [0.5]\n", "scenario", "unknown scenario 'nope'"),
])
def test_bad_scenario_sweep(tmp_path, body, key, reason):
    path = write(tmp_path, body)
    with pytest.raises(SweepError) as e:
        load(path)
    assert str(e.value).startswith(f"{path}: {key}: ") and reason in str(e.value), str(e.value)


# ------------------------------------------------------------------ failed runs are recorded, the sweep goes on

def test_failed_and_timed_out_runs_are_recorded(tmp_path, bump2d_fmu):
    path = write(tmp_path, """
        scene = "bump2d"
        stop_time = 1.0
        out = "OUT"
        [grid]
        "solver.h_max" = [1e-8, 0.01]
        mu = [0.5, 0.8]
        """)
    counts = execute(load(path), BUILD, workers=2, quiet=True)
    assert counts == dict(total=4, skipped=0, ran=4, failed=2)
    for r in read_table(load(path).table):
        if float(r["solver.h_max"]) == 0.01:
            assert r["status"] == "ok" and float(r["t_end"]) == 1.0, r
        else:              # 0.01 s in steps of 1e-8 s is more than solver.max_steps: refused before any work
            assert r["status"] in ("error", "discard") and "max_steps" in r["reason"], r
            assert float(r["t_end"]) == 0.0
    # tol 1e-10 makes the 15 s run take several seconds (it would finish within 0.5 s at the default), and 1 s
    # leaves the run's start (unzip, instantiate, settle: up to a few tenths of a second on a loaded machine) room
    # to reach its first samples before the timeout
    slow = write(tmp_path, """
        scene = "bump2d"
        stop_time = 15.0
        run_timeout = 1.0
        out = "OUT2"
        [fixed]
        "solver.tol" = 1e-10
        [grid]
        mu = [0.5, 0.8]
        """.replace("OUT2", str(tmp_path / "out2")), name="slow.toml")
    counts = execute(load(slow), BUILD, workers=2, quiet=True)
    assert counts["ran"] == 2 and counts["failed"] == 2
    for r in read_table(load(slow).table):
        assert r["status"] == "timeout" and "more than 1 s of wall time" in r["reason"], r
        assert 0 < float(r["t_end"]) < 15.0


def test_a_rigid_runs_peak_force_carries_the_impacts():
    """On rigid contact a sweep's peak_Fn is of the mean forces (impulse / communication step): the rear wheel's
    landing from the bump transmits ~607 N over its 0.01 s step, which the forces at the samples (at most ~220 N at
    any tolerance) miss."""
    path = fmu("bump2d_rigid", BUILD)
    row = sw_mod.run_one(path.read_bytes(), "bump", {}, 6.5, 60.0)
    assert row["status"] == "ok", row
    assert 550 < row["peak_Fn"] < 700, row
    # the ratio of the means: in the cone (mu = 0.8) up to the contact frame's turn within a step on the bump
    assert 0.5 < row["peak_ratio"] < 0.85, row


# ------------------------------------------------------------------ verdicts with the reason

def test_verdict_rule():
    v = verdicts.verdict
    assert v("ok", True, False, None) == "over"
    assert v("ok", True, False, 100.0) == "over"               # over is over, whatever the chassis carried
    assert v("ok", False, True, None) == "tipped"
    assert v("ok", False, True, 100.0) == "tipped"
    assert v("ok", False, False, None) == "stuck"              # no chassis.Fn output: a rover cannot hang up
    assert v("ok", False, False, verdicts.HUNG_FN) == "stuck"
    assert v("ok", False, False, verdicts.HUNG_FN + 1e-6) == "hung up"
    for status in ("timeout", "discard", "error", "failed"):
        assert v(status, True, False, None) == v(status, False, False, 50.0) == "failed"
    assert set(verdicts.VERDICTS) == {"over", "stuck", "hung up", "tipped", "failed"}


MAP = """
scene = "bump2d"
stop_time = 4.0
out = "OUT"
outputs = ["verdict", "climbed", "final_x", "t_end"]
[grid]
terrain_h = [0.0, 0.05, 0.1]
mu = [0.2, 0.5, 0.8, 1.1]
[map]
x = "terrain_h"
y = "mu"
verdict = "verdict"
x_scale = 0.065
x_label = "h / R_w"
"""


def _row(sw, params, verdict, status="ok", reason="", final_x=1.0):
    return {"id": sw.run_id(params), **{k: str(v) for k, v in params.items()}, "verdict": verdict,
            "climbed": "1" if verdict == "over" else "0", "final_x": str(final_x), "t_end": "4",
            "status": status, "reason": reason, "wall_s": "0.5"}


def _synthetic(sw, layout):
    """rows from a layout: {(h, mu): verdict or ("failed", status, reason)}"""
    rows = []
    for p in sw.runs():
        v = layout[p["terrain_h"], p["mu"]]
        if isinstance(v, tuple):
            rows.append(_row(sw, p, "failed", status=v[1], reason=v[2]))
        else:
            rows.append(_row(sw, p, v, reason="" if v == "over" else f"{v} here", final_x=3.0 if v == "over" else
                             0.7 + p["mu"]))
    return rows


def _colours(png):
    from PIL import Image
    return {rgb for _, rgb in Image.open(png).convert("RGB").getcolors(1 << 24)}


def _rgb(hex_colour):
    return tuple(int(hex_colour[k:k + 2], 16) for k in (1, 3, 5))


LAYOUT = {   # h = 0: over everywhere; 0.05: not monotonic at mu 0.8 (and a failed run); 0.1: each other verdict
    (0.0, 0.2): "over", (0.0, 0.5): "over", (0.0, 0.8): "over", (0.0, 1.1): "over",
    (0.05, 0.2): "stuck", (0.05, 0.5): "over", (0.05, 0.8): "stuck", (0.05, 1.1): ("failed", "discard", "refused"),
    (0.1, 0.2): "stuck", (0.1, 0.5): "hung up", (0.1, 0.8): "tipped", (0.1, 1.1): "over",
}


def test_map_draws_each_verdict_in_its_colour(tmp_path):
    from cedra.sweep.maps import VERDICT_COLOURS, draw
    sw = load(write(tmp_path, MAP))
    sw.out.mkdir(parents=True)
    pixels = _colours(draw(sw, _synthetic(sw, LAYOUT)))
    for name, colour in VERDICT_COLOURS.items():
        assert _rgb(colour) in pixels, name
    assert len(set(VERDICT_COLOURS.values())) == len(VERDICT_COLOURS)
    # only over: no other verdict's colour (grey, the failed runs', is in the antialiased text too)
    pixels = _colours(draw(sw, _synthetic(sw, dict.fromkeys(LAYOUT, "over"))))
    assert _rgb(VERDICT_COLOURS["over"]) in pixels
    assert not any(_rgb(VERDICT_COLOURS[c]) in pixels for c in ("stuck", "hung up", "tipped")), \
        [c for c in VERDICT_COLOURS if _rgb(VERDICT_COLOURS[c]) in pixels]


def test_report_counts_tables_monotonicity_and_failures(tmp_path):
    from cedra.sweep import report as sweep_report
    sw = load(write(tmp_path, MAP))
    sw.out.mkdir(parents=True)
    rows = _synthetic(sw, LAYOUT)
    md = sweep_report.write(sw, rows, "python -m cedra sweep s.toml", 12.0, 1.0).read_text()
    assert "Made by `python -m cedra sweep s.toml`" in md and "plain torque (tau_max 4 N.m)" in md
    counts = {"over": 6, "stuck": 3, "hung up": 1, "tipped": 1, "failed": 1}
    for verdict, n in counts.items():
        assert f"| {verdict} | {n} | " in md, verdict
    # the verdict table: rows mu, columns h / R_w
    assert "| mu \\ h / R_w | 0 | 0.769 | 1.54 |" in md
    assert "| 0.8 | over | stuck | tipped |" in md
    assert "| 1.1 | over | failed | over |" in md
    # the non-monotonic places: (0.05, 0.8) stuck above (0.05, 0.5) over; (0.1, 0.5) hung up and (0.1, 0.8)
    # tipped above nothing over: monotonic there
    bad = [line for line in md.splitlines() if line.startswith("- ")]
    assert len(bad) == 1, bad
    assert "h / R_w = 0.769: mu 0.5: over, final_x 3" in bad[0]
    assert "mu 0.8: stuck, final_x 1.5, t_end 4, reason: stuck here" in bad[0]
    assert "| discard | 4 | 0.5 | refused |" in md
    # monotonic everywhere
    rows = _synthetic(sw, {k: ("over" if k[1] >= 0.5 else "stuck") for k in LAYOUT})
    md = sweep_report.write(sw, rows, "c", 1.0, 1.0).read_text()
    assert "Yes: in every column" in md and "## Failed runs\n\nNone." in md
    # the tolerance check: the same runs at a tight tolerance, one verdict different
    tight = sw_mod.tightened(sw, 1e-9)
    assert tight.name == f"{sw.name}_tol1e-09" and tight.fixed["solver.tol"] == 1e-9 and tight.map is None
    tight_rows = [dict(r, id=tight.run_id({**p, "solver.tol": 1e-9})) for p, r in zip(sw.runs(), rows)]
    flip = next(r for r in tight_rows if r["terrain_h"] == "0.1" and r["mu"] == "0.8")
    flip.update(verdict="stuck", reason="stuck at tol", final_x="1.25")
    md = sweep_report.write(sw, rows, "c", 1.0, 1.0, ("solver.tol", 1e-9, tight, tight_rows)).read_text()
    assert "12 runs compared, 1 verdict(s) differ:" in md
    assert "| 0.1 | 0.8 | over | stuck | 3 | 1.25 | stuck at tol |" in md
    same = [dict(r, id=tight.run_id({**p, "solver.tol": 1e-9})) for p, r in zip(sw.runs(), rows)]
    md = sweep_report.write(sw, rows, "c", 1.0, 1.0, ("solver.tol", 1e-9, tight, same)).read_text()
    assert "12 runs compared, every verdict the same." in md
    # Moreau-Jean converges in its step, not in solver.tol: each check is refused where it means nothing
    with pytest.raises(SweepError, match="adaptive solver: use --check-tol"):
        sw_mod.tightened(sw, 1e-5, "--check-h")
    moreau = replace(sw, fixed={**sw.fixed, "solver.method": 4})
    with pytest.raises(SweepError, match="solver.tol does nothing there\\): use --check-h"):
        sw_mod.tightened(moreau, 1e-9)
    tight = sw_mod.tightened(moreau, 1.25e-5, "--check-h")
    assert tight.name == f"{sw.name}_h1.25e-05" and tight.fixed["solver.h_max"] == 1.25e-5
    md = sweep_report.write(moreau, rows, "c", 1.0, 1.0, ("solver.h_max", 1.25e-5, tight, [])).read_text()
    assert "## The same verdicts at solver.h_max 1.25e-05?" in md


def test_check_tol_cli_writes_the_report(tmp_path, bump2d_fmu, capsys):
    from cedra.__main__ import main
    path = write(tmp_path, MAP.replace("[0.0, 0.05, 0.1]", "[0.0]").replace("[0.2, 0.5, 0.8, 1.1]", "[0.5, 0.8]")
                 .replace("stop_time = 4.0", "stop_time = 1.0"))
    assert main(["sweep", str(path), "--build", BUILD, "--workers", "2", "--quiet", "--check-tol", "1e-9"]) == 0
    out = tmp_path / "out"
    assert len(read_table(out / "s_tol1e-09.csv")) == 2
    assert all(r["solver.tol"] == "1e-09" for r in read_table(out / "s_tol1e-09.csv"))
    md = (out / "s.md").read_text()
    assert f"Made by `python -m cedra sweep {path} --workers 2 --check-tol 1e-09 --quiet`" in md
    assert "## The same verdicts at solver.tol 1e-09?" in md
    assert "2 runs compared, every verdict the same." in md, md            # 1 s on flat ground: stuck twice
    assert "| stuck | 2 | " in md and "2 ran to the stop time without getting over and without stopping" in md
    bad = write(tmp_path, MAP.replace("[grid]", "[grid]\n\"solver.tol\" = [1e-6, 1e-8]"), name="b.toml")
    assert main(["sweep", str(bad), "--build", BUILD, "--check-tol", "1e-9"]) == 2
    assert "--check-tol: solver.tol is what this sweep varies" in capsys.readouterr().err


def test_the_stairs_goal_line_is_past_the_top_steps_edge():
    p = dict(terrain_x0=1.0, terrain_w=0.26, terrain_s=0.01)
    assert sw_mod.obstacle_end("stairs", p, 4) == pytest.approx(1.0 + 3 * 0.26 + 0.04)
    assert sw_mod.obstacle_end("stairs", p, 1) == pytest.approx(sw_mod.obstacle_end("step", p))
