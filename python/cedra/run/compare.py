"""Compliant versus rigid contact on the paper's bump: both FMUs from the same start under the same
torque law (the main job's sampled speed controller, the paper's equal torques on all wheels). Replaying the
compliant run's torques open-loop was tried first: the two runs drift apart, and at the bump the replayed
braking rolled the rigid rover back, which compares torque schedules, not contact models. Writes
out/compare/compare.png and .csv and prints the rigid run's constraint drift."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from cedra.run.simulate import run_bump

SHOWN = [1, 2, 5, 6]


def drift(names, rows):
    """Largest |gap| (output wheel[i].gap of rigid scenes) of wheels in contact (mode 1 or 2) over the run."""
    worst = 0.0
    for i in range(1, 7):
        if f"wheel[{i}].gap" not in names:
            continue
        gap = rows[:, names.index(f"wheel[{i}].gap")]
        mode = rows[:, names.index(f"wheel[{i}].mode")]
        if np.any(mode > 0):
            worst = max(worst, float(np.max(np.abs(gap[mode > 0]))))
    return worst


def main(build="build", out="out/compare", stop_time=15.0):
    build, out = Path(build), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    from cedra.run.scenario import fmu
    names_c, rows_c, torques, info_c = run_bump(fmu("bump2d", build), stop_time)
    gaps = [f"wheel[{i}].gap" for i in range(1, 7)]
    names_r, rows_r, torques_r, info_r = run_bump(fmu("bump2d_rigid", build), stop_time, extra=gaps)
    d = drift(names_r, rows_r)
    with open(out / "compare.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "compliant.tau", "rigid.tau"] + [f"compliant.{n}" for n in names_c[1:]] +
                   [f"rigid.{n}" for n in names_r[1:]])
        for k in range(min(len(rows_c), len(rows_r))):
            w.writerow([f"{rows_c[k][0]:.4f}", f"{torques[k]:.10g}", f"{torques_r[k]:.10g}"] +
                       [f"{v:.10g}" for v in rows_c[k][1:]] + [f"{v:.10g}" for v in rows_r[k][1:]])
    _plot(out, names_c, rows_c, names_r, rows_r, torques, torques_r)
    print(f"compliant: {info_c['simulated']:.2f} s simulated in {info_c['wall']:.2f} s wall; "
          f"rigid: {info_r['simulated']:.2f} s in {info_r['wall']:.2f} s wall, status {info_r['status']}")
    print(f"rigid run: max constraint drift |gap| of wheels in contact = {d:.3e} m")
    print(f"wrote {out}/compare.png, {out}/compare.csv")
    return 0 if info_r["status"] == "ok" else 1


def _plot(out, names_c, rows_c, names_r, rows_r, torques, torques_r):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(4, 1, figsize=(10, 12), sharex=True)
    for i, color in zip(SHOWN, ["C0", "C1", "C2", "C3"]):
        for names, rows, style, lab in ((names_c, rows_c, "-", "compliant"), (names_r, rows_r, "--", "rigid")):
            col = {n: rows[:, k] for k, n in enumerate(names)}
            # rigid: the mean over each 0.01 s step (impulse / step), which carries the impacts the samples miss
            mean = "_mean" if f"wheel[{i}].Fn_mean" in col else ""
            ax[0].plot(col["time"], col[f"wheel[{i}].Fn{mean}"], style, color=color, label=f"wheel {i} {lab}")
            ax[1].plot(col["time"], col[f"wheel[{i}].Fx{mean}"], style, color=color)
            if lab == "rigid":
                ax[2].step(col["time"], col[f"wheel[{i}].mode"] + 0.05 * SHOWN.index(i), color=color,
                           where="post", label=f"wheel {i}")
    ax[3].plot(rows_c[:, 0], torques[:len(rows_c)], "k-", label="compliant")
    ax[3].plot(rows_r[:, 0], torques_r[:len(rows_r)], "k--", label="rigid")
    ax[3].legend(fontsize=7)
    for a, lab in zip(ax, ["normal force [N] (rigid: mean per step)", "friction force Fx [N] (rigid: mean per step)", "rigid mode (0 air, 1 stick, 2 slip)",
                           "motor torque [N.m]"]):
        a.set_ylabel(lab)
        a.grid(True)
    ax[0].legend(fontsize=7, ncol=2)
    ax[2].legend(fontsize=7)
    ax[3].set_xlabel("time [s]")
    fig.suptitle("bump run: compliant ground (solid) vs rigid decision tree (dashed), same speed controller")
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=110)
    plt.close(fig)
