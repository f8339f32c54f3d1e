"""Traction control on the paper's bump (docs/model-studies.md): the plant's friction ratios under the
inverse kinematics (mode 1) and traction control (mode 2), the controller's normal-force estimate against the
plant's wheel[i].Fn, and what a controller sample costs.

    python -m cedra.reports.traction [--build build] [--out docs] [--plant bump2d] [--speed 0.2] [--period 0.01]

Writes <out>/traction_<plant>.png (friction ratios and torques), <out>/traction_estimate_<plant>.png (estimate
against the plant's normal force per wheel, and the error) and prints the numbers the docs quote. A rocker-bogie
plant (--plant rb_bump2d) runs with the rocker-bogie's controller rb_drive2d.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from cedra.run.cosim import DriveLoop
from cedra.run.driver import RoverFMU
from cedra.run.scenario import fmu

WHEELS = (1, 2, 5, 6)          # 2D: wheels 3, 4 repeat 1, 2
# a plant's rover (its scene name's prefix) -> its 2D controller and the wheels with their own values in 2D
ROVERS = {"": ("drive2d", WHEELS), "rb_": ("rb_drive2d", (1, 2, 3))}
MODES = {1: "inverse kinematics (mode 1)", 2: "traction control (mode 2)"}
SPEED, STOP_TIME, STEP = 0.2, 15.0, 0.01
LOADED = 1.0                   # N: a wheel's friction ratio counts while the plant's Fn exceeds this


def rover_of(plant: str) -> tuple[str, tuple[int, ...]]:
    """The plant's controller and its wheels with their own values (ROVERS)."""
    return ROVERS["rb_" if plant.startswith("rb_") else ""]


def run_modes(build_dir="build", plant="bump2d", speed=SPEED, period=STEP):
    """The bump run in each mode at the commanded speed, the controller sampled and the loop stepped every
    `period`; every plant output the controller reads is recorded (for the cost replay)."""
    runs = {}
    controller, wheels = rover_of(plant)
    for mode in MODES:
        loop = DriveLoop(fmu(plant, build_dir), fmu(controller, build_dir),
                         controller_values={"ctrl.mode": mode, "ctrl.period": period})
        record = sorted(set(loop.measured) | {f"wheel[{i}].{q}" for i in wheels for q in ("Fn", "Fx")} |
                        {f"ctrl.Fn_est[{i}]" for i in wheels} | {f"tau[{i}]" for i in wheels} | {"body.x"})
        try:
            runs[mode] = loop.run(STOP_TIME, period, lambda t: {"cmd.v": speed}, record=record)
        finally:
            loop.close()
        if not runs[mode].ok:
            raise RuntimeError(f"mode {mode} stopped early: {runs[mode].messages[-2:]}")
    return runs


def friction_ratios(r, wheels=WHEELS) -> np.ndarray:
    """|Fx| / Fn per wheel (rows) and sample, NaN where the wheel carries less than LOADED."""
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in wheels])
    fx = np.array([r.column(f"wheel[{i}].Fx") for i in wheels])
    return np.where(fn > LOADED, np.abs(fx) / np.where(fn > LOADED, fn, 1.0), np.nan)


def summary(r, wheels=WHEELS) -> dict:
    ratio = friction_ratios(r, wheels)
    fn = np.array([r.column(f"wheel[{i}].Fn") for i in wheels])
    est = np.array([r.column(f"ctrl.Fn_est[{i}]") for i in wheels])
    err = est - fn
    k, j = np.unravel_index(np.nanargmax(ratio), ratio.shape)
    peak_at = f"wheel {wheels[k]} at t = {r.column('time')[j]:.2f} s, Fn {fn[k, j]:.1f} N"
    return dict(peak_ratio=float(np.nanmax(ratio)), peak_at=peak_at, q99_ratio=float(np.nanquantile(ratio, 0.99)),
                mean_ratio=float(np.nanmean(ratio)), at_limit=int(np.sum(ratio > 0.79)),
                x_end=float(r.column("body.x")[-1]),
                peak_tau=float(np.max(np.abs([r.column(f"tau[{i}]") for i in wheels]))),
                est_mean_abs=[float(v) for v in np.mean(np.abs(err), axis=1)],
                est_max_abs=[float(v) for v in np.max(np.abs(err), axis=1)],
                est_median_rel=float(np.median(np.abs(err)[fn > 10] / fn[fn > 10])))


def sample_cost(r, build_dir="build", mode=2, repeat=3, speed=SPEED, period=STEP, controller="drive2d") -> dict:
    """Wall time of one controller fmi2DoStep (one sample) replaying the run's measurements through FMPy: the
    generated function plus FMPy's call overhead, so an upper bound of the C's own cost."""
    ctrl = RoverFMU(fmu(controller, build_dir), "controller")
    names = [n for n in r.names[1:] if ctrl.has(n) and ctrl.vars[n].causality == "input"]
    ctrl.fmu.instantiate(callbacks=ctrl._callbacks)
    ctrl.fmu.setupExperiment(startTime=0.0)
    ctrl.set({"ctrl.mode": mode, "ctrl.period": period, "cmd.v": speed})
    ctrl.fmu.enterInitializationMode()
    ctrl.fmu.exitInitializationMode()
    refs = [ctrl.vars[n].valueReference for n in names]
    values = np.array([r.column(n) for n in names]).T
    times = []
    t = 0.0
    for _ in range(repeat):
        for row in values:
            ctrl.fmu.setReal(refs, list(row))
            start = time.perf_counter()
            ctrl.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=period)
            times.append(time.perf_counter() - start)
            t += period
    ctrl.close()
    times = np.array(times) * 1e6
    return dict(median_us=float(np.median(times)), p999_us=float(np.quantile(times, 0.999)),
                max_us=float(times.max()), samples=len(times))


def plot(runs, out: Path, plant: str):
    wheels = rover_of(plant)[1]
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axs = plt.subplots(2, 2, figsize=(11, 6), sharex=True, sharey="row")
    for col, (mode, r) in enumerate(runs.items()):
        t, ratio = r.column("time"), friction_ratios(r, wheels)
        for k, i in enumerate(wheels):
            axs[0, col].plot(t, ratio[k], lw=0.8, label=f"wheel {i}")
            axs[1, col].plot(t, r.column(f"tau[{i}]"), lw=0.8, label=f"wheel {i}")
        axs[0, col].set_title(MODES[mode])
    axs[0, 0].set_ylabel("plant |Fx| / Fn")
    axs[1, 0].set_ylabel("torque command [N.m]")
    for a in axs[1]:
        a.set_xlabel("time [s]")
    axs[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / f"traction_{plant}.png", dpi=90)
    plt.close(fig)

    r = runs[2]
    t = r.column("time")
    fig, axs = plt.subplots(2, len(wheels), figsize=(13, 5), sharex=True, sharey="row")
    for k, i in enumerate(wheels):
        fn, est = r.column(f"wheel[{i}].Fn"), r.column(f"ctrl.Fn_est[{i}]")
        axs[0, k].plot(t, fn, lw=0.8, label="plant wheel[i].Fn")
        axs[0, k].plot(t, est, lw=0.8, label="controller ctrl.Fn_est[i]")
        axs[0, k].set_title(f"wheel {i}")
        axs[1, k].plot(t, est - fn, lw=0.8, color="C3")
        axs[1, k].set_xlabel("time [s]")
    axs[0, 0].set_ylabel("normal force [N]")
    axs[0, 0].set_ylim(-10, 150)
    axs[1, 0].set_ylabel("estimate - plant [N]")
    axs[1, 0].set_ylim(-60, 60)
    axs[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / f"traction_estimate_{plant}.png", dpi=90)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m cedra.reports.traction")
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="docs")
    ap.add_argument("--plant", default="bump2d", help="a 2D plant scene with the bump (bump2d, bump2d_drives; "
                    "rb_bump2d: the rocker-bogie with rb_drive2d)")
    ap.add_argument("--speed", type=float, default=SPEED, help="commanded speed cmd.v, m/s")
    ap.add_argument("--period", type=float, default=STEP, help="controller sample period and the loop's step, s")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = run_modes(a.build, a.plant, a.speed, a.period)
    controller, wheels = rover_of(a.plant)
    for mode, r in runs.items():
        s = summary(r, wheels)
        print(f"{a.plant} at {a.speed:g} m/s, {MODES[mode]}: peak |Fx|/Fn {s['peak_ratio']:.3f} ({s['peak_at']}), "
              f"99th percentile {s['q99_ratio']:.3f}, mean {s['mean_ratio']:.3f}, samples x wheels above 0.79: "
              f"{s['at_limit']}, peak torque {s['peak_tau']:.2f} N.m, body.x {s['x_end']:.3f} m")
        print("    normal-force estimate - plant, per wheel " + ", ".join(
            f"{i}: mean |e| {m:.1f} N, max |e| {x:.1f} N" for i, m, x in
            zip(wheels, s["est_mean_abs"], s["est_max_abs"])) + f"; median relative error {s['est_median_rel']:.3f}")
    for mode in MODES:
        c = sample_cost(runs[mode], a.build, mode, speed=a.speed, period=a.period, controller=controller)
        print(f"controller sample, mode {mode} (fmi2DoStep through FMPy, {c['samples']} samples): median "
              f"{c['median_us']:.1f} us, 99.9 % {c['p999_us']:.1f} us, max {c['max_us']:.1f} us")
    plot(runs, out, a.plant)
    print(f"-> {out}/traction_{a.plant}.png, {out}/traction_estimate_{a.plant}.png")


if __name__ == "__main__":
    main()
