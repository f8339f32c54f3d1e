"""CEDRA against the rocker-bogie on the paper's run: both planar rovers over the bump under the same speed loop.

    python examples/rovers_bump.py          (or: python -m cedra simulate rovers_bump)

Runs bump2d and rb_bump2d with the main job's loop (cedra.run.simulate.run_bump: the paper's equal torques from
a PI speed loop) and writes out/rovers_bump/: rovers.csv (one row per rover), loads.png (every wheel's normal force
over time, both rovers) and prints the table: the CPU of the run (best of three), when the body passes X = 1.5 m,
the peak wheel load, the loads at rest and their spread on the flat ground before the bump (max / min over the
first 2 s), the mean slip speed over wheels and samples, the fastest wheel spin, and the motors' work per
metre.
"""
from __future__ import annotations

import csv
import time
from pathlib import Path

STOP_TIME = 15.0
ROVERS = {"CEDRA": "bump2d", "rocker-bogie": "rb_bump2d"}


def measure(path, stop_time):
    import numpy as np
    from cedra.run.simulate import run_bump
    best = None
    for _ in range(3):
        cpu = time.process_time()
        names, rows, _, info = run_bump(path, stop_time, extra=[f"wheel[{i}].slip" for i in range(1, 7)])
        cpu = time.process_time() - cpu
        if not info["ok"]:
            raise RuntimeError(f"{path.name} stopped early: " + "; ".join(info["messages"][-2:]))
        best = cpu if best is None else min(best, cpu)
    col = {n: rows[:, k] for k, n in enumerate(names)}
    fn = np.column_stack([col[f"wheel[{i}].Fn"] for i in range(1, 7)])
    slip = np.column_stack([col[f"wheel[{i}].slip"] for i in range(1, 7)])
    spin = np.column_stack([col[f"wheel[{i}].omega"] for i in range(1, 7)])
    flat = fn[col["time"] <= min(2.0, stop_time)]
    past = col["time"][col["body.x"] > 1.5]
    travelled = col["body.x"][-1] - col["body.x"][0]
    return dict(cpu=best, t_over=float(past[0]) if len(past) else float("nan"), peak_Fn=float(fn.max()),
                rest=[float(v) for v in fn[0]], flat_spread=float(flat.max() / max(flat.min(), 1e-9)),
                work_per_m=float(col["energy.work"][-1] / travelled) if travelled > 0 else float("nan"),
                mean_slip=float(slip.mean()), max_spin=float(np.abs(spin).max()),
                t=col["time"], fn=fn)


def run(out_dir="out/rovers_bump", build_dir="build", stop_time=None, quiet=False, watch=True) -> dict:
    """watch: unused (the 3D view draws CEDRA only)."""
    from cedra.run.scenario import fmu
    stop_time = stop_time or STOP_TIME
    out = Path(out_dir)
    results = {label: measure(fmu(scene, build_dir), stop_time) for label, scene in ROVERS.items()}
    out.mkdir(parents=True, exist_ok=True)
    keys = ["cpu", "t_over", "peak_Fn", "flat_spread", "mean_slip", "max_spin", "work_per_m"]
    with open(out / "rovers.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["rover", "scene"] + keys + [f"rest_Fn{i}" for i in range(1, 7)])
        for label, r in results.items():
            w.writerow([label, ROVERS[label]] + [f"{r[k]:.6g}" for k in keys] + [f"{v:.6g}" for v in r["rest"]])
    _plot(results, out / "loads.png")
    if not quiet:
        print("| rover | CPU s | body past X = 1.5 m | peak Fn | loads at rest (wheels 1-6) | flat max/min | "
              "mean slip | fastest spin | work per m |\n|---|---|---|---|---|---|---|---|---|")
        for label, r in results.items():
            rest = " / ".join(f"{v:.1f}" for v in r["rest"])
            print(f"| {label} | {r['cpu']:.3f} | {r['t_over']:.2f} s | {r['peak_Fn']:.1f} N | {rest} N | "
                  f"{r['flat_spread']:.2f} | {r['mean_slip']:.3f} m/s | {r['max_spin']:.0f} rad/s | "
                  f"{r['work_per_m']:.2f} J/m |")
        print(f"wrote {out}/rovers.csv, loads.png")
    return {label: {k: r[k] for k in keys} for label, r in results.items()}


def _plot(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(results), 1, figsize=(9, 5), sharex=True)
    for ax, (label, r) in zip(axes, results.items()):
        for i in range(6):
            ax.plot(r["t"], r["fn"][:, i], lw=0.8, label=f"wheel {i + 1}")
        ax.set_ylabel("Fn [N]")
        ax.set_title(f"{label}: peak {r['peak_Fn']:.0f} N", fontsize=9)
        ax.legend(fontsize=7, ncol=6, loc="upper left")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    run()
