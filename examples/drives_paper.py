"""The paper's bump run (docs/model.md) with plain torques (bump2d) and with drives (bump2d_drives, docs/model.md,
Drives), under the same speed controller (cedra.run.simulate.run_bump): how much of the motors' work goes into
spinning wheels and wheel slip when the torque command is not limited by a motor's torque-speed envelope.

    python examples/drives_paper.py [stop_time]     # writes out/drives_paper/, prints a summary

Writes out/drives_paper/<scene>.csv (one per run) and spin_and_load.png (wheel spin rates and normal forces of
both runs). tests/test_drives.py runs run() with a short stop time.
"""
from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

SCENES = ("bump2d", "bump2d_drives")
WHEELS = range(1, 7)
SHOWN = {1: "bogie front (1, 3)", 2: "bogie rear (2, 4)", 5: "rear (5)", 6: "front fork (6)"}   # 2D: 3 = 1, 4 = 2


def run_scene(scene, build_dir="build", stop_time=None) -> dict[str, np.ndarray]:
    """One closed-loop bump run of a shipped scene; its outputs by name, with "time" and "tau_cmd" (the
    controller's command to every wheel, held over the following sample)."""
    from cedra.models import scene as scn
    from cedra.fmu.packaging import build_fmu
    from cedra.run.simulate import run_bump
    sc = scn.load_shipped(scene)
    fmu = Path(build_dir) / f"{scene}.fmu"
    if not fmu.exists():
        fmu = build_fmu(sc.spec(), build_dir)
    extra = [f"wheel[{i}].{q}" for q in ("slip", "Fy", "tau") for i in WHEELS]
    names, rows, commands, info = run_bump(fmu, stop_time or sc.stop_time, extra=extra)
    if not info["ok"]:
        raise RuntimeError(f"{scene} stopped at t={info['simulated']}: " + "; ".join(info["messages"][-3:]))
    columns = {n: rows[:, k] for k, n in enumerate(names)}
    columns["tau_cmd"] = commands
    return columns


def slip_work(c) -> float:
    """Work of the friction forces against the slip, summed over the wheels: the integral of |F_t| times the slip
    speed (the regularized Coulomb force is opposite to the slip velocity), trapezoidal over the 0.01 s samples.
    A sampled estimate: the long spin-downs after a landing are resolved, contact spikes of a few ms are not."""
    total = 0.0
    for i in WHEELS:
        friction = np.hypot(c[f"wheel[{i}].Fx"], c.get(f"wheel[{i}].Fy", 0.0))
        total += np.trapezoid(friction * c[f"wheel[{i}].slip"], c["time"])
    return float(total)


def gear_loss(c, viscous) -> float:
    """Work lost in the gears, the integral of b omega^2 over the wheels, sampled like slip_work (0 without
    drives). The motors themselves gave W plus this."""
    if "wheel[1].tau" not in c:
        return 0.0
    return float(sum(np.trapezoid(viscous * c[f"wheel[{i}].omega"] ** 2, c["time"]) for i in WHEELS))


def summary(c, viscous) -> dict[str, float]:
    spin = np.abs(np.array([c[f"wheel[{i}].omega"] for i in WHEELS]))
    load = np.array([c[f"wheel[{i}].Fn"] for i in WHEELS])
    mechanical = c["energy.kinetic"] + c["energy.potential"]
    return {
        "peak spin [rad/s]": float(spin.max()),
        "peak spin airborne [rad/s]": float(spin[load == 0].max(initial=0.0)),
        "slip work [J]": slip_work(c),
        # exact (the FMU's work integral): everything the ground and the joints dissipated; the gear's loss is
        # not in it, the work integral W is of the applied torques (after the gear)
        "dissipated W - d(K+P) [J]": float(c["energy.work"][-1] - (mechanical[-1] - mechanical[0])),
        "motor work W [J]": float(c["energy.work"][-1]),
        "gear loss [J]": gear_loss(c, viscous),
        "peak Fn [N]": float(load.max()),
        "body.x end [m]": float(c["body.x"][-1]),
    }


def write_csv(path, c):
    names = list(c)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for row in zip(*(c[n] for n in names)):
            w.writerow([f"{v:.10g}" for v in row])


def plot(path, runs, noload_speed):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, len(runs), figsize=(12, 7), sharex=True, sharey="row", squeeze=False)
    for col, (scene, c) in enumerate(runs.items()):
        for i, label in SHOWN.items():
            ax[0, col].plot(c["time"], c[f"wheel[{i}].omega"], lw=0.9, label=label)
            ax[1, col].plot(c["time"], c[f"wheel[{i}].Fn"], lw=0.9, label=label)
        ax[0, col].axhline(noload_speed, color="k", ls=":", lw=0.8, label="drive no-load speed")
        ax[0, col].set_title(scene)
        ax[1, col].set_xlabel("time [s]")
    ax[0, 0].set_yscale("symlog", linthresh=2 * noload_speed)    # 830 rad/s beside 10 rad/s
    ax[0, 0].set_ylabel("wheel spin rate [rad/s]")
    ax[1, 0].set_ylabel("normal force [N]")
    for a in ax.flat:
        a.grid(True)
    ax[0, -1].legend(fontsize=8)
    fig.suptitle("The paper's bump run, same speed controller: plain torques vs drives")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(out_dir="out/drives_paper", build_dir="build", stop_time=None, quiet=False,
        watch=True) -> dict[str, dict[str, float]]:
    """Both runs: CSVs and the figure into out_dir, the summary printed (unless quiet) and returned (scene ->
    figures)."""
    from cedra.rover.parameters import DEFAULTS
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = {scene: run_scene(scene, build_dir, stop_time) for scene in SCENES}
    for scene, c in runs.items():
        write_csv(out / f"{scene}.csv", c)
        if watch:           # <scene>_animation.gif, <scene>_view.html
            from cedra.run.watch import watch as watch_run
            names = [n for n in c if n != "tau_cmd"]
            watch_run(out, names, np.array([c[n] for n in names]).T, Path(build_dir) / f"{scene}.fmu",
                      title=f"drives_paper: {scene}", stem=f"{scene}_")
    plot(out / "spin_and_load.png", runs, DEFAULTS["drive_noload_speed"])
    figures = {scene: summary(c, DEFAULTS["drive_viscous"]) for scene, c in runs.items()}
    if not quiet:
        width = max(map(len, next(iter(figures.values()))))
        print(f"{'':{width}}  " + "  ".join(f"{s:>14}" for s in SCENES))
        for key in figures[SCENES[0]]:
            print(f"{key:{width}}  " + "  ".join(f"{figures[s][key]:14.6g}" for s in SCENES))
        print(f"wrote {', '.join(str(out / f'{s}.csv') for s in SCENES)}, {out / 'spin_and_load.png'}")
    return figures


if __name__ == "__main__":
    run(stop_time=float(sys.argv[1]) if len(sys.argv) > 1 else None)
