"""MuJoCo on steps and stairs: `python -m cedra bench --steps [--build build] [--stop-time 25]`.

The scenes step2d, stairs2d and stairs3d under the paper's speed controller (equal torques clipped to 4 N.m,
cedra.run.simulate.SpeedController; the scene's drives where it has them), for stop_time s:

- MuJoCo (cedra.reports.mujoco_model) with the step or stairs as sharp boxes on a plane (`scene_boxes`), dt 1 ms,
  with its multi-point convex collision on (MuJoCo's default) and off (`multiccd`). With drives, the peer clips
  the command to the drive's torque-speed envelope every 1 ms in Python (a cost the FMU does not have in its
  column, counted in MuJoCo's CPU): MuJoCo has no speed-dependent torque limit of its own.
- each FMU at its scene defaults.

Columns: CPU (time.process_time of the controlled part), where the body ended across the edges, the verdict (over:
past the top step's edge plus half a run, or 0.5 m past a single step; stuck; unstable: MuJoCo met non-finite or
huge accelerations and reset its state), peak wheel normal force, and the **largest unpaid energy gain**: the
largest rise of E - W over any interval of the run, E the kinetic plus potential energy (gravity, springs; the
FMU's also holds its ground springs), W the motors' work. Motors, gravity and springs are the only sources; contact
and joints only dissipate, so a correct model's E - W never rises (up to its integration error): a rise is energy
the contact made. MuJoCo's is measured in a second, untimed run that steps 1 ms at a time (the same trajectory:
MuJoCo is deterministic); the FMU's from its energy.kinetic, energy.potential and energy.work outputs at the 0.01 s
samples of the timed run. Figures are printed, never asserted on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

STOP = 25.0
SCENES = ("step2d", "stairs2d", "stairs3d")
MUJOCO_DT = 1e-3
STEP_PAST = 0.5         # m past a single step's edge: "over"
ENERGY = ["energy.kinetic", "energy.potential", "energy.work"]
TARGET = {"stairs3d": 2.0}      # MuJoCo CPU / FMU CPU at the FMU's defaults, multiccd off: the FMU at least twice as cheap


@dataclass
class Row:
    label: str
    cpu: float
    simulated: float
    across: float           # m past the first edge, measured across the edges, at the end
    verdict: str
    peak_fn: float
    unpaid: float           # J, the largest rise of E - W
    unpaid_at: float        # s, where that rise ends
    note: str = ""


def largest_rise(t, b) -> tuple[float, float]:
    """max over t1 <= t2 of b(t2) - b(t1), and the t2 where it is reached."""
    b = np.asarray(b, dtype=float)
    rise = b - np.minimum.accumulate(b)
    i = int(np.argmax(rise))
    return float(rise[i]), float(t[i])


def geometry(scene) -> dict:
    """The first edge, the direction across the edges and the distance past the first edge that is "over"."""
    from cedra.reports.mujoco_model import numbers
    p = numbers(scene)
    stairs = scene.options.terrain == "stairs"
    yaw = p.get("terrain_yaw", 0.0) if stairs else 0.0
    y0 = p.get("terrain_y0", 0.0) if stairs else 0.0
    over = (scene.options.stairs_steps - 0.5) * p["terrain_w"] if stairs else STEP_PAST
    return dict(x0=p["terrain_x0"], y0=y0, yaw=yaw, over=over)


def across(geo, x, y) -> float:
    return (x - geo["x0"]) * math.cos(geo["yaw"]) + (y - geo["y0"]) * math.sin(geo["yaw"])


def verdict(geo, ok: bool, u_end: float) -> str:
    if not ok:
        return "unstable"
    return "over" if u_end > geo["over"] else "stuck"


def mujoco_energy(scene, multiccd: bool, stop_time: float, dt=MUJOCO_DT) -> tuple[float, float]:
    """(largest unpaid gain J, at s) of MuJoCo's run, stepped 1 ms at a time with the motors' work integrated by the
    trapezoidal rule; stops where MuJoCo reports instability (the rise up to there)."""
    from cedra.reports import mujoco_model as mm
    from cedra.run.simulate import SAMPLE, SpeedController
    rover = mm.Rover(scene, "boxes", dt, multiccd=multiccd, energy=True)
    mm.settle(rover)
    ctrl, nsub = SpeedController(), int(round(SAMPLE / dt))
    e0, work, low, best, best_t = rover.energy(), 0.0, 0.0, 0.0, 0.0
    for _ in range(int(round(stop_time / SAMPLE))):
        rover.set_torques(np.full(6, ctrl(rover.vx())))
        for _ in range(nsub):
            p0 = rover.motor_power()
            rover.step(1)
            work += 0.5 * (p0 + rover.motor_power()) * dt
            b = rover.energy() - e0 - work
            low = min(low, b)
            if b - low > best:
                best, best_t = b - low, rover.time
        if rover.unstable():
            break
    return best, best_t


def mujoco_row(scene, multiccd: bool, stop_time: float) -> Row:
    from cedra.reports import mujoco_model as mm
    r = mm.run(scene, "boxes", MUJOCO_DT, stop_time, multiccd=multiccd)
    geo = geometry(scene)
    u = across(geo, r.x[-1], r.extra["y_end"])
    unpaid, at = mujoco_energy(scene, multiccd, stop_time)
    label = f"MuJoCo boxes 1 ms, multiccd {'on' if multiccd else 'off'}"
    return Row(label, r.cpu, r.simulated, u, verdict(geo, r.ok, u), r.peak_fn, unpaid, at, r.message)


def fmu_row(scene, build, stop_time: float) -> Row | None:
    from cedra.reports.common import fmu_closed_loop, fmu_path
    path = fmu_path(build, scene.name)
    if not path.exists():
        return None
    planar = scene.options.dims == "2d"
    r = fmu_closed_loop(path, stop_time, label=f"FMU {scene.name}", record=ENERGY + ([] if planar else ["body.y"]))
    s = r.extra["series"]
    geo = geometry(scene)
    u = across(geo, r.x[-1], 0.0 if planar else s["body.y"][-1])
    unpaid, at = largest_rise(r.t, s["energy.kinetic"] + s["energy.potential"] - s["energy.work"])
    v = verdict(geo, True, u) if r.ok else "failed"
    note = f"{r.steps} steps ({r.extra['rejected']} rejected)" + ("" if r.ok else f"; {r.message}")
    return Row(r.label, r.cpu, r.simulated, u, v, r.peak_fn, unpaid, at, note)


def table(rows: dict[str, list[Row | None]], stop_time: float) -> list[str]:
    out = ["| scene | run | CPU s | ended past the first edge (m) | verdict | peak Fn (N) | largest unpaid energy "
           "gain (J) | notes |", "|---|---|---|---|---|---|---|---|"]
    for name, rs in rows.items():
        for r in rs:
            if r is None:
                out.append(f"| {name} | FMU not built (python -m cedra build {name}) | | | | | | |")
                continue
            sim = "" if r.simulated >= stop_time - 1e-9 else f"stopped at {r.simulated:g} s; "
            out.append(f"| {name} | {r.label} | {r.cpu:.2f} | {r.across:.3f} | {r.verdict} | {r.peak_fn:.0f} | "
                       f"{r.unpaid:.3g} (at {r.unpaid_at:.2f} s) | {sim}{r.note} |")
    out.append("")
    for name, rs in rows.items():
        fmu = rs[-1]
        if fmu is None:
            continue
        for mj in rs[:-1]:
            if mj.verdict == "unstable":
                continue
            target = TARGET.get(name) if "off" in mj.label else None
            ratio = mj.cpu / fmu.cpu
            verdict_ = "" if target is None else f"; target x{target:g}: " + ("met" if ratio >= target else "NOT met")
            out.append(f"- {name}: {mj.label} CPU / FMU CPU at its defaults: x{ratio:.2f}{verdict_}")
    return out


def print_steps(build, stop_time: float = STOP, scenes=SCENES) -> int:
    from cedra.reports import mujoco_model as mm
    from cedra.models.scene import load_shipped
    if not mm.available():
        print("\nMuJoCo on steps and stairs: skipped, mujoco is not installed (pip install -e '.[bench]')")
        return 0
    import mujoco
    print(f"\nMuJoCo on steps and stairs: {stop_time:g} s of the paper's speed controller (equal torques, 4 N.m clip; "
          f"the scene's drives), MuJoCo {mujoco.__version__} on sharp boxes at 1 ms, each FMU at its scene defaults; "
          f"largest unpaid energy gain = the largest rise of (kinetic + potential energy - motor work) over any "
          f"interval (cedra.reports.bench_steps)")
    rows = {}
    for name in scenes:
        sc = load_shipped(name)
        rows[name] = [mujoco_row(sc, True, stop_time), mujoco_row(sc, False, stop_time), fmu_row(sc, build, stop_time)]
    print("\n".join(table(rows, stop_time)))
    return 0 if all(r is not None for rs in rows.values() for r in rs) else 1
