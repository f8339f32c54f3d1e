"""CEDRA against the rocker-bogie (docs/rovers.md): `python -m cedra report rovers [--build build] [--out DIR]
[--quick] [--quiet]`.

1. **The paper's run for both rovers and the three controllers**: each planar rover (bump2d, rb_bump2d) with its
   drive controller FMU (drive2d, rb_drive2d) in the project's co-simulation master, ctrl.mode 0 (equal torques from
   the speed loop, the paper's run), 1 (the inverse kinematics with a rate loop per wheel) and 2 (traction control:
   the speed loop's summed torque at one friction ratio on every wheel), 0.2 m/s, 15 s, on the
   paper's bump and on flat ground (the same scene with terrain_h = 0). Per run: when the last wheel center
   passes the bump's end, the peak wheel load, the wheel load spread (max / min of the six wheels' loads, on flat
   ground in the steady run; over the bump the largest load against the rover's weight share), the mean slip
   speed, the largest friction ratio of a loaded wheel and the motors' work per metre travelled.
2. **The maps** (not with --quick): the six sweeps examples/sweeps/rovers/{bump,step,stairs}_{cedra,rb}.toml
   and the shrimp-faithful CEDRA's step (examples/sweeps/rovers/step_shrimp.toml, VARIANT_MAPS; in the table),
   a terrain's height (and the bump's width) against mu for one rover (drives, chassis contact, the main job's
   equal torques), and the three of examples/sweeps/rovers/climb_controllers_{bump,step,stairs}.toml
   (examples/rovers_climb.py: both rovers with their drive controller FMUs in the three modes, on the plants with
   drives and chassis contact), run afresh
   (cedra.sweep.execute, tables in out/rovers/) and drawn side by side (<out>/rovers_maps.png,
   <out>/rovers_controllers.png) with, per terrain and mu, the highest obstacle each rover gets over. The seven
   equal-torque maps run again at solver.tol = 1e-8, and the report says whether every verdict is the same.
3. **The field's quasi-static metrics** (cedra.reports.rovers_statics; with --quick on fewer heights): the friction
   a sharp step and the stairs require over their height, the torque it needs, the virtual centres of rotation,
   and where the maps' verdicts differ from the quasi-static one.

Writes <out>/rovers.md (and the figures); prints the tables.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from cedra.pages import load_average, provenance
from cedra.run.cosim import DriveLoop
from cedra.run.scenario import EXAMPLES, fmu
from cedra.sweep import obstacle_end, variant_fmu

ROVERS = {"CEDRA": ("bump2d", "drive2d", "cedra"), "rocker-bogie": ("rb_bump2d", "rb_drive2d", "rb")}
CONTROLLERS = {"equal torques": 0, "inverse kinematics": 1, "traction control": 2}
TERRAINS = {"bump": "the paper's bump (widths 1 to 6 R_w)", "step": "a sharp step", "stairs": "4 stairs (run 4 R_w)"}
OBSTACLES = ("bump", "step", "stairs")     # the controllers' maps (examples/rovers_climb.py)
# the rover variants' equal-torque maps: {(terrain, rover label): sweep file of examples/sweeps/rovers/}
VARIANT_MAPS = {("step", "CEDRA shrimp"): "step_shrimp.toml"}
SPEED, STOP_TIME, STEP = 0.2, 15.0, 0.01
BUMP_H = 0.14625                 # the paper's bump height (2.25 R_w)
LOADED = 5.0                     # N: a wheel's friction ratio counts while it carries more than this
STEADY = (5.0, 15.0)             # s: on flat ground, the loads' spread is taken over this window
R_W = 0.065
CHECK_TOL = 1e-8                 # the equal-torque maps' verdicts are checked again at this solver.tol


def drive(scene, controller, mode, terrain_h, build_dir, stop_time=STOP_TIME, kind="bump", mu=None,
          speed=SPEED, options=None, steps=1) -> dict:
    """One run of the rover's plant (terrain `kind`, its height terrain_h, mu: the scene's unless given; options:
    the scene's variant, cedra.sweep.variant_fmu; steps: the stairs' number of steps) with its controller in
    ctrl.mode `mode`; the measures of the module's docstring."""
    values = {"terrain_h": terrain_h} | ({"mu": mu} if mu is not None else {})
    plant = variant_fmu(scene, options, build_dir) if options else fmu(scene, build_dir)
    loop = DriveLoop(plant, fmu(controller, build_dir), plant_values=values,
                     controller_values={"ctrl.mode": mode})
    wheels = range(1, 7)        # in 2D each wheel's twin on the other side has its own outputs, the same values
    record = (["body.x", "body.vx", "energy.work"]
              + [f"wheel[{i}].{q}" for i in wheels for q in ("Fn", "Fx", "slip", "cx")])
    cpu = time.process_time()
    try:
        r = loop.run(stop_time, STEP, lambda t: {"cmd.v": speed}, record=record)
        names = [n for n in ("terrain_x0", "terrain_w", "terrain_s") if loop.plant.has(n)]
        inputs = {n: float(v) for n, v in zip(names, loop.plant.get(names))}
    finally:
        loop.close()
    cpu = time.process_time() - cpu
    # a rover that has tipped over (the FMU stops there: fmi2Discard naming it) did not climb: an outcome
    tipped = not r.ok and any("tipped over" in m for m in r.messages)
    if not r.ok and not tipped:
        raise RuntimeError(f"{scene} + {controller} (mode {mode}) stopped early: {r.messages[-2:]}")
    t = r.column("time")
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in wheels])
    fx = np.array([r.column(f"wheel[{i}].Fx") for i in wheels])
    slip = np.array([r.column(f"wheel[{i}].slip") for i in wheels])
    cx = np.array([r.column(f"wheel[{i}].cx") for i in wheels])
    goal = obstacle_end(kind, inputs, steps)
    past = np.nonzero(cx.min(axis=0) > goal)[0]
    x = r.column("body.x")
    travelled = x[-1] - x[0]
    loaded = fn > LOADED
    steady = (t >= STEADY[0]) & (t <= STEADY[1])
    mean_loads = fn[:, steady].mean(axis=1) if steady.any() else np.full(6, np.nan)
    weight_share = fn[:, 0].sum() / 6          # the six wheels' loads at rest share the weight
    return dict(cpu=cpu, t_over=float(t[past[0]]) if terrain_h > 0 and len(past) else float("nan"),
                climbed=int(len(past) > 0 and not tipped), tipped=int(tipped),
                peak_Fn=float(fn.max()), peak_factor=float(fn.max() / weight_share),
                spread=float(mean_loads.max() / max(mean_loads.min(), 1e-9)),
                mean_slip=float(np.abs(slip).mean()),
                peak_ratio=float((np.abs(fx)[loaded] / fn[loaded]).max()) if loaded.any() else float("nan"),
                work_per_m=float(r.column("energy.work")[-1] / travelled) if travelled > 0 else float("nan"),
                x_end=float(x[-1]), peak_speed=float(r.column("body.vx").max()), rest=[float(v) for v in fn[:, 0]])


def measures(build_dir="build", stop_time=STOP_TIME, log=print) -> list[dict]:
    rows = []
    for rover, (scene, controller, _) in ROVERS.items():
        for label, mode in CONTROLLERS.items():
            for terrain, h in (("flat", 0.0), ("bump", BUMP_H)):
                m = drive(scene, controller, mode, h, build_dir, stop_time)
                rows.append(dict(rover=rover, controller=label, terrain=terrain, **m))
                log(f"  {rover}, {label}, {terrain}: x {m['x_end']:.3f} m, peak Fn {m['peak_Fn']:.1f} N, "
                    f"slip {m['mean_slip']:.4f} m/s ({m['cpu']:.2f} s CPU)")
    return rows


def measures_table(rows) -> list[str]:
    lines = ["| rover | controller | terrain | last wheel past the bump | peak Fn (N) | peak Fn / weight share | "
             "load spread max/min (5-15 s) | mean slip (m/s) | peak friction ratio | work per m (J/m) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        over = "" if r["terrain"] == "flat" else (f"{r['t_over']:.2f} s" if np.isfinite(r["t_over"]) else "no")
        spread = f"{r['spread']:.2f}" if r["terrain"] == "flat" else ""
        lines.append(f"| {r['rover']} | {r['controller']} | {r['terrain']} | {over} | {r['peak_Fn']:.1f} | "
                     f"{r['peak_factor']:.2f} | {spread} | {r['mean_slip']:.4f} | {r['peak_ratio']:.3f} | "
                     f"{r['work_per_m']:.2f} |")
    return lines


# ------------------------------------------------------------------------------------------------ the maps

def map_sweeps():
    """The seven sweeps of the equal-torque maps with drives (the rovers' and VARIANT_MAPS), {(terrain, rover
    label): Sweep}, and the three of the controllers' maps, {("controllers", obstacle): Sweep}."""
    from cedra.sweep import load
    here = EXAMPLES / "sweeps" / "rovers"
    maps = {(terrain, rover): load(here / f"{terrain}_{short}.toml")
            for terrain in TERRAINS for rover, (_, _, short) in ROVERS.items()}
    maps.update({key: load(here / name) for key, name in VARIANT_MAPS.items()})
    maps.update({("controllers", kind): load(here / f"climb_controllers_{kind}.toml") for kind in OBSTACLES})
    return maps


def run_maps(build_dir="build", workers=None, quiet=False, log=print) -> tuple[dict, dict]:
    """Every map's sweep run afresh, the equal-torque maps again at solver.tol = CHECK_TOL: ({key of map_sweeps:
    (Sweep, rows)}, {key: (runs compared, verdicts that differ)})."""
    from cedra.sweep import execute, read_table, tightened
    from cedra.sweep.report import tolerance_differences
    out, checks = {}, {}
    for key, sw in map_sweeps().items():
        t0 = time.perf_counter()
        c = execute(sw, build_dir, workers=workers, overwrite=True, quiet=quiet)
        rows = read_table(sw.table)
        out[key] = (sw, rows)
        if key[0] in TERRAINS:          # a scene's sweep: its verdicts at a tight tolerance
            tight = tightened(sw, CHECK_TOL)
            execute(tight, build_dir, workers=workers, overwrite=True, quiet=quiet)
            compared, differ = tolerance_differences(sw, rows, tight, read_table(tight.table))
            checks[key] = (compared, len(differ))
        log(f"  {key[1]}, {key[0]}: {c['total']} runs ({c['failed']} failed) in {time.perf_counter() - t0:.0f} s")
    return out, checks



def _is_over(value) -> bool:
    """A run's verdict "over", or a climbed output of 1."""
    try:
        return value == "over" or float(value) == 1.0
    except (TypeError, ValueError):
        return False


def highest_over(rows, column="verdict") -> dict:
    """Per mu, the highest obstacle (terrain_h) the rover gets over (`column`: a verdict, or a 1/0 climbed output),
    and whether every lower one is over too."""
    by_mu = {}
    for r in rows:
        ok = r.get("status", "ok") == "ok"
        by_mu.setdefault(float(r["mu"]), []).append((float(r["terrain_h"]), ok and _is_over(r.get(column))))
    out = {}
    for mu, runs in sorted(by_mu.items()):
        runs.sort()
        over = [h for h, v in runs if v]
        top = max(over) if over else float("nan")
        gaps = [h for h, v in runs if not v and over and h < top]
        out[mu] = (top, not gaps)
    return out


def _cells(best, mus) -> list[str]:
    cells = []
    for mu in mus:
        top, clean = best.get(mu, (float("nan"), True))
        cells.append("none" if not np.isfinite(top) else f"{top / R_W:.1f} R_w" + ("" if clean else "*"))
    return cells


def panels(sw, rows) -> list[tuple[str, list]]:
    """A map's rows per bump width (a sweep with terrain_w in its grid), else all in one: [(label, rows)]."""
    if "terrain_w" not in sw.grid:
        return [("", rows)]
    return [(f"width {w / R_W:g} R_w", [r for r in rows if abs(float(r["terrain_w"]) - w) < 1e-12])
            for w in sw.grid["terrain_w"]]


def maps_table(maps, checks=None) -> list[str]:
    """The equal-torque maps with drives: per terrain and rover, the highest obstacle got over per mu (and, with
    checks, whether every verdict is the same at solver.tol = CHECK_TOL)."""
    checks = checks or {}
    mus = sorted({float(r["mu"]) for key, (_, rows) in maps.items() if key[0] in TERRAINS for r in rows})
    tail = f" verdicts at tol {CHECK_TOL:g} |" if checks else ""
    lines = ["| terrain | rover | " + " | ".join(f"mu {mu:g}" for mu in mus) + " |" + tail,
             "|---|---|" + "---|" * len(mus) + ("---|" if checks else "")]
    for terrain in TERRAINS:
        for rover in list(ROVERS) + [k[1] for k in maps if k[0] == terrain and k[1] not in ROVERS]:
            key = (terrain, rover)
            if key not in maps:
                continue
            check = ""
            if checks:
                n, differ = checks.get(key, (0, 0))
                check = f" {'all ' + str(n) + ' the same' if not differ else f'{differ} of {n} differ'} |"
            for label, rows in panels(*maps[key]):
                what = f"{terrain} ({label})" if label else terrain
                lines.append(f"| {what} | {rover} | " + " | ".join(_cells(highest_over(rows), mus)) + " |" + check)
    return lines


def controllers_table(maps) -> list[str]:
    """The controllers' maps: per obstacle, rover and mode, the highest obstacle climbed per mu."""
    keys = [("controllers", kind) for kind in OBSTACLES if ("controllers", kind) in maps]
    mus = sorted({float(r["mu"]) for key in keys for r in maps[key][1]})
    lines = ["| obstacle | rover | controller | " + " | ".join(f"mu {mu:g}" for mu in mus) + " |",
             "|---|---|---|" + "---|" * len(mus)]
    for key in keys:
        for rover in ROVERS:
            for mode in CONTROLLERS:
                best = highest_over(maps[key][1], f"{rover}.{mode}.climbed")
                lines.append(f"| {key[1]} | {rover} | {mode} | " + " | ".join(_cells(best, mus)) + " |")
    return lines


def draw_maps(maps, path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch
    from cedra.sweep.maps import VERDICT_COLOURS
    layout = [(terrain, k) for terrain in TERRAINS for k in range(len(panels(*maps[(terrain, "CEDRA")])))]
    fig, axes = plt.subplots(len(layout), len(ROVERS), figsize=(10, 2.6 * len(layout)), squeeze=False)
    seen = set()
    for row, (terrain, k) in enumerate(layout):
        for col, rover in enumerate(ROVERS):
            ax = axes[row][col]
            sw = maps[(terrain, rover)][0]
            label, rows = panels(*maps[(terrain, rover)])[k]
            for r in rows:
                v = r.get("verdict") if r.get("status") == "ok" else "failed"
                v = v if v in VERDICT_COLOURS else "failed"
                seen.add(v)
                ax.scatter(float(r["terrain_h"]) / R_W, float(r["mu"]), s=200, marker="s",
                           color=VERDICT_COLOURS[v], edgecolor="k", lw=0.4)
            what = {"bump": "the bump", "step": "a sharp step", "stairs": "4 stairs (run 4 R_w)"}[terrain]
            ax.set_title(f"{rover}: {what}" + (f", {label}" if label else ""), fontsize=9)
            ax.set_xlabel(sw.map.get("x_label", "h / R_w"), fontsize=8)
            ax.set_ylabel("mu", fontsize=8)
            ax.margins(0.12)
    fig.legend(handles=[Patch(color=VERDICT_COLOURS[v], label=v) for v in VERDICT_COLOURS if v in seen],
               loc="lower center", ncol=len(seen), fontsize=8)
    fig.suptitle("How each run ends: equal torques, drives, chassis contact, compliant ground, tau_max 4 N.m",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def draw_controllers(maps, path: Path) -> Path:
    """The controllers' maps: one row per obstacle, one panel per rover and mode, climbed yes / no."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch
    from cedra.sweep.maps import YES_NO_COLOURS
    keys = [("controllers", kind) for kind in OBSTACLES if ("controllers", kind) in maps]
    panels = [(rover, mode) for rover in ROVERS for mode in CONTROLLERS]
    fig, axes = plt.subplots(len(keys), len(panels), figsize=(2.7 * len(panels), 2.8 * len(keys)), squeeze=False,
                             sharey=True)
    for row, key in enumerate(keys):
        for col, (rover, mode) in enumerate(panels):
            ax = axes[row][col]
            for r in maps[key][1]:
                v = r.get(f"{rover}.{mode}.climbed")
                c = "failed" if r.get("status") != "ok" else ("yes" if _is_over(v) else "no")
                ax.scatter(float(r["terrain_h"]) / R_W, float(r["mu"]), s=200, marker="s", color=YES_NO_COLOURS[c],
                           edgecolor="k", lw=0.4)
            ax.set_title(f"{rover}, {mode}: {key[1]}", fontsize=8)
            ax.set_xlabel(f"{key[1]} {'rise' if key[1] == 'stairs' else 'height'} h / R_w", fontsize=8)
            if col == 0:
                ax.set_ylabel("mu", fontsize=8)
            ax.margins(0.12)
    fig.legend(handles=[Patch(color=YES_NO_COLOURS[v], label=f"climbed: {v}") for v in ("yes", "no")],
               loc="lower center", ncol=2, fontsize=8)
    fig.suptitle("Each rover with its drive controller in its three modes (drives, chassis contact, 0.2 m/s, 15 s, "
                 "compliant ground)", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 0.95))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# ------------------------------------------------------------------------------------------------ the report

def write(out: Path, rows, maps, command, wall, load_at_start, checks=None, statics=None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# CEDRA and the rocker-bogie", "", provenance(command, wall, load_at_start), "",
             "## The paper's run, both rovers, three controllers", "",
             f"Each planar rover's shipped scene (bump2d, rb_bump2d: no drives, no chassis contact, as the paper's "
             f"run) with its drive controller FMU at {SPEED} m/s for {STOP_TIME:g} s on the paper's "
             "bump and on flat ground (the same scene, terrain_h = 0); the loads' spread on flat ground is max / "
             "min of the six wheels' mean loads over 5-15 s; the weight share is the loads' sum at rest / 6.", ""]
    lines += measures_table(rows)
    rest = {r["rover"]: r["rest"] for r in rows}
    lines += ["", "Loads at rest (wheels 1-6): " + "; ".join(
        f"{rover} " + " / ".join(f"{v:.1f}" for v in loads) + " N" for rover, loads in rest.items()), ""]
    if maps:
        draw_maps(maps, out / "rovers_maps.png")
        lines += ["## Climbing maps", "",
                  "The highest obstacle each rover gets over (`over`), per friction coefficient (* : some lower "
                  "obstacle is not got over at that mu), and whether every run's verdict is the same when the "
                  f"whole map runs again at solver.tol = {CHECK_TOL:g}. The sweeps: examples/sweeps/rovers/.", ""]
        lines += maps_table(maps, checks)
        lines += ["", "![the maps](rovers_maps.png)", ""]
        draw_controllers(maps, out / "rovers_controllers.png")
        lines += ["## The controller as a dimension", "",
                  "Each rover with its drive controller FMU (drive2d, rb_drive2d) in its three modes, the plants with "
                  "drives and chassis contact, 0.2 m/s, 15 s (examples/rovers_climb.py; the sweeps "
                  "examples/sweeps/rovers/climb_controllers_*.toml): the highest obstacle climbed per mu.", ""]
        lines += controllers_table(maps)
        lines += ["", "![the controllers' maps](rovers_controllers.png)", ""]
    else:
        lines += ["The climbing maps were not run (--quick).", ""]
    lines += statics or []
    path = out / "rovers.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def main(args) -> int:
    load_at_start = load_average()
    t0 = time.perf_counter()
    log = (lambda *a, **k: None) if args.quiet else print
    build = getattr(args, "build", "build")
    log("the paper's run, both rovers, three controllers:")
    rows = measures(build, log=log)
    maps = checks = None
    if not args.quick:
        log("the climbing maps (ten sweeps; the seven equal-torque maps again at a tight tolerance):")
        maps, checks = run_maps(build, quiet=args.quiet, log=log)
    log("the quasi-static climbs (both rovers, the step over its height, the stairs):")
    from cedra.reports.rovers_statics import section, table
    statics, results = section(Path(args.out), args.quick, maps)
    command = "python -m cedra report rovers" + (" --quick" if args.quick else "")
    path = write(Path(args.out), rows, maps, command, time.perf_counter() - t0, load_at_start, checks, statics)
    print("\n".join(table(results, "step") + table(results, "stairs")))
    print("\n".join(measures_table(rows)))
    if maps:
        print("\n".join(maps_table(maps, checks)))
        print("\n".join(controllers_table(maps)))
    print(f"wrote {path}")
    return 0
