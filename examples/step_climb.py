"""The paper's obstacle climbed three times: equal torques (the paper's run), the inverse-kinematics controller and
traction control.

    python examples/step_climb.py           (or: python -m cedra simulate step_climb)

Every run uses the 2D plant over the paper's bump and the drive controller FMU (ctrl.mode 0: the paper's run's
speed loop with equal torques; ctrl.mode 1: Eq. 13 wheel rates with a PI loop per wheel; ctrl.mode 2: the speed
loop's summed torque distributed for the least largest friction ratio, docs/model.md, Traction control). Writes
out/step_climb/ (one CSV per run, compare.png: wheel slip, friction/normal ratios, torques) and prints slip,
friction ratio and peak torque for each.
Sweep it over bump height, friction and speed: examples/sweeps/step_climb.toml (`python -m cedra sweep step_climb`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

SPEED = 0.2                 # m/s
STOP_TIME = 15.0
STEP = 0.01
MODES = {"equal torques": 0, "inverse kinematics": 1, "traction control": 2}
FMUS = ("bump2d", "drive2d")       # the FMUs run() opens (a sweep builds them first)
# what a sweep may vary: name -> (default, min, max, meaning); the bump is the plant's, so is mu
PARAMETERS = {"speed_cmd": (SPEED, 0.05, 0.4, "m/s, commanded speed"),
              "terrain_h": (0.14625, 0.0, 0.2, "m, bump height (the paper: 2.25 R_w)"),
              "mu": (0.8, 0.05, 2.0, "friction coefficient of the ground")}
# what a sweep may keep: run() returns {mode: {quantity: value}}; a sweep names them "<mode>.<quantity>"
SUMMARY = {f"{mode}.{q}": f"{what} ({mode})" for mode in MODES for q, what in (
    ("mean_slip", "m/s, mean |wheel slip|"), ("peak_friction_ratio", "largest |Fx|/Fn while Fn > 1 N"),
    ("peak_torque", "N.m, largest |torque|"), ("peak_spin", "rad/s, largest |wheel rate|"),
    ("x_end", "m, body.x at the end"),
    ("climbed", "1 if every wheel center is past the bump's end (x0 + 2.5 w) at the end, else 0"))}
WHEELS = (1, 2, 5, 6)       # in 2D wheels 3, 4 repeat 1, 2
RECORD = (["body.x"] + [f"wheel[{i}].{q}" for i in WHEELS for q in ("slip", "Fn", "Fx", "omega", "cx")] +
          [f"tau[{i}]" for i in WHEELS])


def run(out_dir="out/step_climb", build_dir="build", stop_time=None, quiet=False, watch=True, params=None) -> dict:
    """params: values of PARAMETERS (a sweep's run); the others keep their defaults."""
    from cedra.run.cosim import DriveLoop
    from cedra.run.scenario import fmu, parameters, run_loop, watch_run, write_csv
    from cedra.run.watch import plus_watched
    from cedra.models.scene import load_shipped
    from cedra.sweep import obstacle_end
    stop_time = stop_time or STOP_TIME
    p = parameters(PARAMETERS, params)
    goal = obstacle_end("bump", load_shipped(FMUS[0]).inputs)       # the sweeps' goal line for the bump
    out = Path(out_dir)
    runs, summary = {}, {}
    for label, mode in MODES.items():
        loop = DriveLoop(*(fmu(n, build_dir) for n in FMUS), plant_values={"terrain_h": p["terrain_h"], "mu": p["mu"]},
                         controller_values={"ctrl.mode": mode})
        r = run_loop(loop, f"step_climb ({label})", stop_time, STEP, lambda t: {"cmd.v": p["speed_cmd"]},
                     plus_watched(RECORD), quiet)
        write_csv(out / f"{label.replace(' ', '_')}.csv", r.names, r.rows)
        # <label>_animation.gif, <label>_view.html
        watch_run(out, r.names, r.rows, fmu("bump2d", build_dir), f"step_climb ({label})", watch,
                  stem=label.replace(" ", "_") + "_")
        runs[label] = r
        fn = np.array([r.column(f"wheel[{i}].Fn") for i in WHEELS])
        fx = np.array([r.column(f"wheel[{i}].Fx") for i in WHEELS])
        ratio = np.abs(fx)[fn > 1.0] / fn[fn > 1.0]
        summary[label] = dict(
            mean_slip=float(np.mean(np.abs([r.column(f"wheel[{i}].slip") for i in WHEELS]))),
            peak_friction_ratio=float(ratio.max()), mean_friction_ratio=float(ratio.mean()),
            peak_torque=float(np.max(np.abs([r.column(f"tau[{i}]") for i in WHEELS]))),
            peak_spin=float(np.max(np.abs([r.column(f"wheel[{i}].omega") for i in WHEELS]))),
            x_end=float(r.column("body.x")[-1]),
            climbed=int(min(r.column(f"wheel[{i}].cx")[-1] for i in WHEELS) > goal))
    _plot(out, runs)
    if not quiet:
        for label, s in summary.items():
            print(f"step_climb, {label}: mean |slip| {s['mean_slip']:.4f} m/s, |Fx|/Fn mean "
                  f"{s['mean_friction_ratio']:.3f}"
                  f" peak {s['peak_friction_ratio']:.3f}, peak torque {s['peak_torque']:.2f} N.m, peak spin "
                  f"{s['peak_spin']:.1f} rad/s, body.x {s['x_end']:.3f} m")
        print(f"-> {out}")
    return summary


def _plot(out, runs):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axs = plt.subplots(3, len(runs), figsize=(5.5 * len(runs), 8), sharex=True, sharey="row")
    for col, (label, r) in enumerate(runs.items()):
        t = r.column("time")
        for i in WHEELS:
            fn, fx = r.column(f"wheel[{i}].Fn"), r.column(f"wheel[{i}].Fx")
            axs[0, col].plot(t, np.abs(r.column(f"wheel[{i}].slip")), label=f"wheel {i}")
            axs[1, col].plot(t, np.where(fn > 1.0, np.abs(fx) / np.where(fn > 1.0, fn, 1), np.nan), label=f"wheel {i}")
            axs[2, col].plot(t, r.column(f"tau[{i}]"), label=f"wheel {i}")
        axs[0, col].set_title(label)
        axs[0, col].set_yscale("log")
    for row, lab in enumerate(["|slip| [m/s]", "|Fx| / Fn [-]", "torque [N.m]"]):
        axs[row, 0].set_ylabel(lab)
    for a in axs[-1]:
        a.set_xlabel("time [s]")
    axs[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    run()
