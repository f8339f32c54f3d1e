"""The main job (docs/model.md): the paper's bump run through the FMU with a sampled PI speed controller."""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cedra.run.driver import FastIO, RoverFMU
from cedra.run.watch import plus_watched

SAMPLE = 0.01          # controller period = communication step, s
V_REF, KP, KI, TAU_MAX = 0.2, 3.0, 6.0, 4.0


@dataclass
class SpeedController:
    """u = Kp e + Ki (I + e dt), all six torques = clip(u, -tau_max, tau_max) (the paper: 4 N.m); no integration
    while clipped (anti-windup). v_ref and tau_max are what a sweep may vary."""
    integral: float = 0.0
    v_ref: float = V_REF
    tau_max: float = TAU_MAX

    def __call__(self, v):
        e = self.v_ref - v
        u = KP * e + KI * (self.integral + e * SAMPLE)
        if abs(u) <= self.tau_max:
            self.integral += e * SAMPLE
        return float(np.clip(u, -self.tau_max, self.tau_max))


def wheel_names(quantity):
    return [f"wheel[{i}].{quantity}" for i in range(1, 7)]


def recorded(fmu: RoverFMU) -> list[str]:
    names = ["body.x", "body.z", "body.pitch", "body.vx", "bogie.theta[1]", "fork.theta4"]
    for q in ("Fn", "Fx", "mode", "omega", "cx", "cz", "px", "pz", "Fn_mean", "Fx_mean"):     # *_mean: rigid
        names += wheel_names(q)
    names += ["energy.kinetic", "energy.potential", "energy.work", "solver.steps", "solver.rejected",
              "solver.rhs_evals"]
    names = plus_watched(names)         # what the animation and the 3D view draw
    return [n for n in names if fmu.has(n)]


def speed_loop(fmu: RoverFMU, stop_time, names: list[str], on_sample,
               controller: SpeedController | None = None) -> bool:
    """The main job's closed loop on a started FMU (docs/model.md): every SAMPLE s read `names` (body.vx among
    them), compute the torque, hand (k, t, y, tau) to on_sample, which may return True to stop here, then set all
    six tau[i] and step. The calls go through FastIO. Returns False if the FMU refused a call (fmu.status and
    fmu.messages say why), True when the run stopped at stop_time or where on_sample said."""
    ctrl = controller or SpeedController()
    io = FastIO(fmu, names, [f"tau[{i}]" for i in range(1, 7)])
    vx = names.index("body.vx")
    n = int(round(stop_time / SAMPLE))
    for k in range(n + 1):
        y = io.read()
        if y is None:
            return False
        tau = ctrl(y[vx])
        if on_sample(k, k * SAMPLE, y, tau) or k == n:
            return True
        if not (io.write([tau] * 6) and io.step((k + 1) * SAMPLE)):
            return False
    return True


def run_bump(fmu_path, stop_time=15.0, settings: dict | None = None, extra=()):
    """Run the paper's bump scene; returns (names, data rows, torques, info)."""
    fmu = RoverFMU(fmu_path)
    names = recorded(fmu) + [n for n in extra if fmu.has(n)]
    rows, torques = [], []

    def record(k, t, y, tau):
        if not np.all(np.isfinite(y)):
            raise RuntimeError(f"non-finite output at t = {t}")
        rows.append(np.concatenate([[t], y]))
        torques.append(tau)

    wall = time.perf_counter()
    fmu.start(settings or {})
    ok = speed_loop(fmu, stop_time, names, record)
    wall = time.perf_counter() - wall
    info = dict(simulated=rows[-1][0], wall=wall, ok=ok, status=fmu.status, messages=list(fmu.messages))
    fmu.close()
    return ["time"] + names, np.array(rows), np.array(torques), info


def write_outputs(out_dir, names, rows, torques, terrain):
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "bump2d.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names + ["tau"])
        for r, t in zip(rows, torques):
            w.writerow([f"{v:.10g}" for v in r] + [f"{t:.10g}"])
    plot(out_dir, names, rows, torques, terrain)


def plot(out_dir, names, rows, torques, terrain):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    col = {n: rows[:, k] for k, n in enumerate(names)}
    t = col["time"]
    shown = [1, 2, 5, 6]          # in 2D wheels 3 and 4 carry the same forces as 1 and 2
    labels = {1: "bogie front (1, 3)", 2: "bogie rear (2, 4)", 5: "rear (5)", 6: "front fork (6)"}
    fig, ax = plt.subplots(4, 1, figsize=(9, 11), sharex=True)
    for i in shown:
        Fn, Fx = col[f"wheel[{i}].Fn"], col[f"wheel[{i}].Fx"]
        ax[0].plot(t, Fn, label=labels[i])
        ax[1].plot(t, Fx, label=labels[i])
        ratio = np.where(Fn > 1e-6, Fx / np.where(Fn > 1e-6, Fn, 1), np.nan)
        ax[2].plot(t, ratio, label=labels[i])
    ax[3].plot(t, torques, "k")
    for a, lab in zip(ax, ["normal force [N]", "friction force Fx [N]", "Fx / Fn [-]", "motor torque [N.m]"]):
        a.set_ylabel(lab)
        a.grid(True)
    ax[0].legend(fontsize=8)
    ax[3].set_xlabel("time [s]")
    fig.suptitle("CEDRA over the bump (compliant ground): ground forces and motor torques (cf. the paper's Fig. 8)")
    fig.tight_layout()
    fig.savefig(Path(out_dir) / "forces.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(10, 3.2))
    X = np.linspace(col["body.x"].min() - 0.5, col["body.x"].max() + 0.5, 600)
    ax.fill_between(X, terrain(X), -0.05, color="0.8", label="terrain")
    ax.plot(col["body.x"], col["body.z"], "k", label="body mass center")
    for i in shown:
        ax.plot(col[f"wheel[{i}].cx"], col[f"wheel[{i}].cz"], lw=0.8, label=f"wheel {labels[i]} center")
    ax.set_aspect("equal")
    ax.set_xlabel("X [m]")
    ax.set_ylabel("Z [m]")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("path over the bump")
    fig.tight_layout()
    fig.savefig(Path(out_dir) / "path.png", dpi=110)
    plt.close(fig)


def bump_terrain(fmu_path):
    """Z(X) of the FMU's bump terrain at its start values (for the plots), and the bump's position."""
    from fmpy import read_model_description
    start = {v.name: float(v.start) for v in read_model_description(str(fmu_path)).modelVariables
             if v.name in ("terrain_h", "terrain_w", "terrain_x0")}

    def terrain(X):
        return start["terrain_h"] * np.exp(-((X - start["terrain_x0"]) / start["terrain_w"]) ** 2)
    return terrain, start["terrain_x0"]


def main(fmu_path="build/bump2d.fmu", out_dir="out/bump2d", stop_time=15.0, video=True):
    """The main job; video: also the animation and the 3D page (cedra.run.watch)."""
    terrain, x0 = bump_terrain(fmu_path)
    names, rows, torques, info = run_bump(fmu_path, stop_time)
    write_outputs(out_dir, names, rows, torques, terrain)
    x_end = rows[-1][names.index("body.x")]
    rtf = info["simulated"] / info["wall"]
    print(f"bump2d: simulated {info['simulated']:.2f} s in {info['wall']:.2f} s wall (real-time factor {rtf:.1f}), "
          f"body.x {x_end:.3f} m (bump at {x0} m), status {info['status']}")
    print(f"wrote {out_dir}/bump2d.csv, {out_dir}/forces.png, {out_dir}/path.png")
    if video:
        from cedra.run.watch import watch
        w = watch(out_dir, names, rows, fmu_path, title="bump2d: the paper's run (compliant ground)")
        sec = w["seconds"]
        print(f"wrote {w['animation']} ({w['animation'].stat().st_size / 1e6:.1f} MB, {sec['animation']:.1f} s) and "
              f"{w['view']} ({w['view'].stat().st_size / 1e6:.2f} MB, {sec['view']:.1f} s)")
    if not info["ok"]:
        print("FMU stopped:", *info["messages"][-3:], sep="\n  ")
        return 1
    return 0
