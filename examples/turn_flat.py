"""Turn on flat ground: 3D, constant commanded speed and yaw rate through the drive controller; the path is a circle.

    python examples/turn_flat.py            (or: python -m cedra simulate turn_flat)
    python examples/turn_flat.py --rover rocker_bogie      (the rocker-bogie, skid-steered: rb_flat3d + rb_drive3d)

Writes out/turn_flat/: turn_flat.csv, path.png (the body's path and the commanded circle), tracking.png
(commanded vs measured yaw rate and speed, steering angles, wheel slips), and prints a summary.
Edit SPEED, YAW_RATE, STOP_TIME to try other turns, or sweep them: examples/sweeps/turn_flat.toml
(`python -m cedra sweep turn_flat`; PARAMETERS and SUMMARY below are what a sweep may vary and keep).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

SPEED, YAW_RATE = 0.2, 0.3         # m/s, rad/s (positive turns left): a circle of radius SPEED / YAW_RATE
STOP_TIME = 20.0                   # s
STEP = 0.01                        # s, communication step = the controller's period
ROVERS = {"cedra": ("flat3d", "drive3d"), "rocker_bogie": ("rb_flat3d", "rb_drive3d")}   # rover -> plant, controller
FMUS = ROVERS["cedra"]             # the FMUs run() opens by default (a sweep builds them first)
# what a sweep may vary: name -> (default, min, max, meaning)
PARAMETERS = {"speed_cmd": (SPEED, 0.0, 0.5, "m/s, commanded speed"),
              "yaw_rate_cmd": (YAW_RATE, 0.05, 1.0,
                               "rad/s, commanded yaw rate (a left turn: the scenario fits a circle)"),
              "mu": (0.8, 0.05, 2.0, "friction coefficient of the ground")}
# what run() returns (besides the wall time): name -> meaning
SUMMARY = {"yaw_rate": "rad/s, mean measured yaw rate after the start", "speed": "m/s, mean measured speed",
           "radius": "m, mean turn radius speed / yaw rate", "commanded_radius": "m, speed / yaw rate commanded"}
RECORD = (["body.x", "body.y", "body.yaw", "body.vx", "body.vy", "body.wz"] +
          [f"wheel[{i}].slip" for i in range(1, 7)] + [f"tau[{i}]" for i in range(1, 7)])
STEERING = ["steer.theta[1]", "steer.theta[2]", "steer[1]", "steer[2]"]     # CEDRA's steered wheels


def run(out_dir="out/turn_flat", build_dir="build", stop_time=None, quiet=False, params=None, watch=None,
        rover="cedra") -> dict:
    """params: values of PARAMETERS (a sweep's run); the others keep their defaults. watch: view.html (default: yes,
    except for a sweep's run, i.e. with params; CEDRA only). rover: a key of ROVERS (the rocker-bogie turns by skid
    steering)."""
    from cedra.run.cosim import DriveLoop
    from cedra.run.scenario import ScenarioError, fmu, parameters, run_loop, watch_run, write_csv
    from cedra.run.watch import plus_watched
    stop_time = stop_time or STOP_TIME
    watch = params is None if watch is None else watch
    p = parameters(PARAMETERS, params)
    if rover not in ROVERS:
        raise ScenarioError(f"turn_flat: unknown rover {rover!r} ({', '.join(ROVERS)})")
    plant, controller = ROVERS[rover]
    steering = rover == "cedra"
    watch = watch and rover == "cedra"          # the view (cedra.run.watch) draws CEDRA only
    record = RECORD + (STEERING if steering else [])
    loop = DriveLoop(fmu(plant, build_dir), fmu(controller, build_dir), plant_values={"mu": p["mu"]})
    commands = {"cmd.v": p["speed_cmd"], "cmd.yaw_rate": p["yaw_rate_cmd"]}
    r = run_loop(loop, "turn_flat", stop_time, STEP, lambda t: commands, plus_watched(record) if watch else record,
                 quiet)
    out = Path(out_dir)
    write_csv(out / "turn_flat.csv", r.names, r.rows)
    watch_run(out, r.names, r.rows, fmu(plant, build_dir),
              f"turn_flat: {p['speed_cmd']:g} m/s, {p['yaw_rate_cmd']:g} rad/s", watch)
    t = r.column("time")
    late = t >= min(8.0, 0.5 * stop_time)
    speed = np.hypot(r.column("body.vx"), r.column("body.vy"))
    wz = r.column("body.wz")
    summary = dict(yaw_rate=float(wz[late].mean()), speed=float(speed[late].mean()),
                   radius=float((speed[late] / wz[late]).mean()), commanded_radius=p["speed_cmd"] / p["yaw_rate_cmd"],
                   wall=r.wall)
    _plots(out, r, t, speed, wz, p["speed_cmd"], p["yaw_rate_cmd"], steering)
    if not quiet:
        print(f"turn_flat ({rover}): yaw rate {summary['yaw_rate']:.4f} rad/s (commanded {p['yaw_rate_cmd']}), speed "
              f"{summary['speed']:.4f} m/s ({p['speed_cmd']}), radius {summary['radius']:.4f} m "
              f"({summary['commanded_radius']:.4f}), {stop_time:g} s in {r.wall:.1f} s wall -> {out}")
    return summary


def _plots(out, r, t, speed, wz, v_cmd, wz_cmd, steering):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 5))
    x, y = r.column("body.x"), r.column("body.y")
    radius = v_cmd / wz_cmd
    late = t >= 0.5 * t[-1]           # the circle of the commanded radius about the turn center after the start
    cx = np.mean(x[late] - r.column("body.vy")[late] / wz[late])
    cy = np.mean(y[late] + r.column("body.vx")[late] / wz[late])
    a = np.linspace(0, 2 * np.pi, 200)
    ax.plot(cx + radius * np.cos(a), cy + radius * np.sin(a), "k--", lw=0.8,
            label=f"radius v/yaw rate = {radius:.3f} m")
    ax.plot(x, y, label="body path")
    ax.set_aspect("equal")
    ax.set_xlabel("X, m")
    ax.set_ylabel("Y, m")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "path.png", dpi=110)
    plt.close(fig)
    fig, axs = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    axs[0].plot(t, wz, label="measured")
    axs[0].axhline(wz_cmd, color="k", ls="--", lw=0.8, label="commanded")
    axs[0].set_ylabel("yaw rate, rad/s")
    axs[1].plot(t, speed, label="measured")
    axs[1].axhline(v_cmd, color="k", ls="--", lw=0.8, label="commanded")
    axs[1].set_ylabel("speed, m/s")
    if steering:
        for k, n in ((1, "rear wheel 5"), (2, "front wheel 6")):
            axs[2].plot(t, np.degrees(r.column(f"steer.theta[{k}]")), label=f"{n}")
            axs[2].plot(t, np.degrees(r.column(f"steer[{k}]")), ls=":", label=f"{n} command")
        axs[2].set_ylabel("steering, deg")
    else:                           # skid steering: the torques turn it
        for i in range(1, 7):
            axs[2].plot(t, r.column(f"tau[{i}]"), label=f"wheel {i}")
        axs[2].set_ylabel("torque, N.m")
    for i in range(1, 7):
        axs[3].plot(t, r.column(f"wheel[{i}].slip"), label=f"wheel {i}")
    axs[3].set_ylabel("slip speed, m/s")
    axs[3].set_xlabel("time, s")
    for a_ in axs:
        a_.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(out / "tracking.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rover", default="cedra", choices=list(ROVERS))
    args = ap.parse_args()
    run(out_dir="out/turn_flat" if args.rover == "cedra" else f"out/turn_flat_{args.rover}", rover=args.rover)
