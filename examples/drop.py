"""The rover dropped from 0.3 m onto flat ground (3D plant alone, zero torques).

    python examples/drop.py                 (or: python -m cedra simulate drop)

Starts from the design pose raised by DROP_HEIGHT with start.settle off, lands on the compliant ground and comes
to rest. Writes out/drop/ (drop.csv, drop.png: height, normal forces, energy) and prints the peak normal force,
the energy the landing dissipated, and the rest height.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

DROP_HEIGHT = 0.3           # m above the design pose (wheels resting on the ground)
STOP_TIME = 2.0
STEP = 0.005


def run(out_dir="out/drop", build_dir="build", stop_time=None, quiet=False, watch=True) -> dict:
    from cedra.run.driver import RoverFMU
    from cedra.rover.parameters import DEFAULTS
    from cedra.run.progress import Progress
    from cedra.run.scenario import fmu, watch_run, write_csv
    from cedra.run.watch import WATCHED
    stop_time = stop_time or STOP_TIME
    plant = RoverFMU(fmu("flat3d", build_dir))
    names = ["body.z", "body.vz", "energy.kinetic", "energy.potential"] + [f"wheel[{i}].Fn" for i in range(1, 7)]
    names += [n for n in WATCHED if n not in names and plant.has(n)]
    z0 = DEFAULTS["R_w"] - DEFAULTS["rear_z"] + DROP_HEIGHT       # body.z of the design pose, raised
    progress = Progress(stop_time, "drop", quiet=quiet)
    rows, ok = [], True
    try:
        plant.start({"start.settle": False, "start.z": z0, "start.theta4": DEFAULTS["fork_theta4_ref"]})
        n = int(round(stop_time / STEP))
        for k in range(n + 1):
            rows.append(np.concatenate([[k * STEP], plant.get(names)]))
            if k == n or not (ok := plant.step((k + 1) * STEP)):
                break
            progress((k + 1) * STEP)
    finally:
        progress.done()
        messages = plant.messages
        plant.close()
    if not ok:
        raise RuntimeError("drop stopped early: " + "; ".join(messages[-2:]))
    rows = np.array(rows)
    out = Path(out_dir)
    write_csv(out / "drop.csv", ["time"] + names, rows)
    watch_run(out, ["time"] + names, rows, fmu("flat3d", build_dir), f"drop: from {DROP_HEIGHT} m", watch)
    col = {n: rows[:, k + 1] for k, n in enumerate(names)}
    energy = col["energy.kinetic"] + col["energy.potential"]
    fn = np.array([col[f"wheel[{i}].Fn"] for i in range(1, 7)])
    summary = dict(peak_Fn=float(fn.max()), dissipated=float(energy[0] - energy[-1]), z_rest=float(col["body.z"][-1]),
                   drop=DROP_HEIGHT)
    _plot(out, rows[:, 0], col, fn, energy)
    if not quiet:
        print(f"drop: from {DROP_HEIGHT} m, peak normal force {summary['peak_Fn']:.0f} N, landing dissipated "
              f"{summary['dissipated']:.2f} J, rest height {summary['z_rest']:.4f} m -> {out}")
    return summary


def _plot(out, t, col, fn, energy):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    axs[0].plot(t, col["body.z"])
    axs[0].set_ylabel("body.z [m]")
    for i in range(6):
        axs[1].plot(t, fn[i], label=f"wheel {i + 1}")
    axs[1].set_ylabel("normal force [N]")
    axs[1].legend(fontsize=7, ncol=3)
    axs[2].plot(t, energy)
    axs[2].set_ylabel("kinetic + potential [J]")
    axs[2].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(out / "drop.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    run()
