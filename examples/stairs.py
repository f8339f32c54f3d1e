"""CEDRA up a flight of stairs, in 2D (stairs2d) and in 3D with the stairs turned by 20 degrees (stairs3d), with
drives on and the drive controller in the loop.

    python examples/stairs.py               (or: python -m cedra simulate stairs)

Each run drives at SPEED with the drive controller (ctrl.mode 1: the paper's inverse kinematics, one rate loop per
wheel); in 3D the commanded yaw rate holds the heading (yaw rate = -HEADING_GAIN * yaw), so the wheels of each side
meet every edge at different times. The verdict of each run, with its reason:

    over       the body's mass center is past the top step's edge plus half a run
    stuck      the run ended below that (the last edge the rover's front wheel passed is printed)
    tipped     the FMU stopped the run: the body tipped over (|pitch| or |roll| > 80 deg)
    failed     the FMU stopped the run for any other reason (its message is printed)

Writes out/stairs/ (<scene>.csv, path.png: the body's climb over the stairs' profile) and prints the verdicts.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

SPEED = 0.15                # m/s
HEADING_GAIN = 2.0          # 1/s: yaw rate command per radian of heading error (3D)
STOP_TIME = 25.0
STEP = 0.01
SCENES = {"stairs2d": "drive2d", "stairs3d": "drive3d"}
FMUS = tuple(SCENES) + tuple(SCENES.values())
RECORD = ["body.x", "body.y", "body.z", "body.yaw", "body.pitch", "body.roll", "wheel[6].cx", "wheel[6].cz"]


def stairs_geometry(scene) -> dict:
    """The scene's stairs: steps, rise, run, first edge, yaw (the scene file's values)."""
    from cedra.models.scene import load_shipped
    sc = load_shipped(scene)
    values = {q.name: q.start for q in sc.spec().inputs} | sc.inputs
    return dict(steps=sc.options.stairs_steps, rise=values["terrain_h"], run=values["terrain_w"],
                x0=values["terrain_x0"], y0=values.get("terrain_y0", 0.0), yaw=values.get("terrain_yaw", 0.0))


def across(geo, x, y):
    """Distance past the first edge, measured across the edges."""
    return (x - geo["x0"]) * np.cos(geo["yaw"]) + (y - geo["y0"]) * np.sin(geo["yaw"])


def verdict(geo, result) -> tuple[str, str]:
    """(verdict, reason) of a run from its own outputs."""
    x, y = result.column("body.x"), result.column("body.y") if "body.y" in result.names else 0 * result.column("body.x")
    u_end = float(across(geo, x[-1], y[-1]))
    top = (geo["steps"] - 1) * geo["run"] + 0.5 * geo["run"]
    if not result.ok:
        msg = "; ".join(result.messages[-1:])
        if "tipped" in msg:
            return "tipped", msg
        return "failed", msg
    if u_end > top:
        return "over", f"{u_end:.3f} m past the first edge (the top step begins at {top - 0.5 * geo['run']:.3f} m)"
    front = across(geo, result.column("wheel[6].cx"), 0 * x)
    passed = int(np.sum(np.max(front) > np.arange(geo["steps"]) * geo["run"]))
    return "stuck", f"the body ended {u_end:.3f} m past the first edge; the front wheel passed {passed} edge(s)"


def run(out_dir="out/stairs", build_dir="build", stop_time=None, quiet=False, watch=True, params=None) -> dict:
    from cedra.run.cosim import DriveLoop
    from cedra.run.scenario import fmu, write_csv
    stop_time = stop_time or STOP_TIME
    out = Path(out_dir)
    summary, results = {}, {}
    for scene, controller in SCENES.items():
        geo = stairs_geometry(scene)
        loop = DriveLoop(fmu(scene, build_dir), fmu(controller, build_dir), controller_values={"ctrl.mode": 1})
        three_d = scene.endswith("3d")

        def commands(t, loop=loop, three_d=three_d):
            c = {"cmd.v": SPEED}
            if three_d:
                c["cmd.yaw_rate"] = -HEADING_GAIN * loop.plant.get(["body.yaw"])[0]
            return c
        try:
            r = loop.run(stop_time, STEP, commands, RECORD)
        finally:
            loop.close()
        write_csv(out / f"{scene}.csv", r.names, r.rows)
        v, why = verdict(geo, r)
        summary[scene] = dict(verdict=v, reason=why, t_end=float(r.rows[-1, 0]), wall=r.wall)
        results[scene] = (geo, r)
        if not quiet:
            print(f"{scene}: {v}: {why} (t = {r.rows[-1, 0]:.2f} s of {stop_time:g}, {r.wall:.1f} s wall)")
    _plot(out, results)
    if not quiet:
        print(f"-> {out}")
    return summary


def _plot(out, results):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 4))
    for scene, (geo, r) in results.items():
        y = r.column("body.y") if "body.y" in r.names else 0 * r.column("body.x")
        ax.plot(across(geo, r.column("body.x"), y), r.column("body.z"), label=f"{scene}: body mass center")
    geo = next(iter(results.values()))[0]
    u = np.linspace(-1.0, geo["steps"] * geo["run"] + 0.5, 800)
    profile = sum(0.5 * geo["rise"] * (1 + np.tanh((u - j * geo["run"]) / 0.01)) for j in range(geo["steps"]))
    ax.plot(u, profile, "k", lw=1, label="stairs (across the edges)")
    ax.set_xlabel("distance past the first edge, across the edges [m]")
    ax.set_ylabel("Z [m]")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "path.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    run()
