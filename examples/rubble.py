"""CEDRA across a field of rubble (the shipped scene rubble3d: a heightmap of random blocks with smoothed edges),
drives on, chassis contact on, the drive controller holding the heading; how the grid was made, and the run's
verdict.

    python examples/rubble.py               (or: python -m cedra simulate rubble)
    python examples/rubble.py --write-grid  rewrites python/cedra/models/scenes/rubble3d.txt from BLOCKS

The blocks are boxes turned about Z, their edges smoothed over EDGE m (each a product of tanh steps across its
two axes), laid on flat ground and added where they overlap (a block lying on another). Their heights are
0.4 to 1.2 R_w, so the wheels meet faces they must climb, several at once, with the body and the bogies over
them. The run drives at SPEED with the drive controller (ctrl.mode 1: the inverse kinematics) and a heading
hold (yaw rate = -HEADING_GAIN * yaw); it stops driving once over, or once the body has gained less than
STALL_GAIN in X over STALL_TIME (as an operator would: a stalled rover on rubble pivots on what holds it and
wanders). The verdict, from the run's own outputs:

    over       the body's mass center passed the end of the field (FIELD_END + 0.3 m)
    hung up    it did not, and the chassis (body, bogies or fork) carried load over the last second
    stuck      it did not, with only the wheels on the ground
    tipped     the FMU stopped the run: the body tipped over
    failed     the FMU stopped the run for any other reason (its message is printed)

Writes out/rubble/ (rubble.csv, path.png: the path over the blocks, view.html) and prints the verdict.
tests/test_heightmap.py checks that the shipped grid is exactly what heights() gives.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

R_W = 0.065
# X in [-1, 4] m, Y in [-1, 1] m: room for a rover that turns on the blocks
GRID = dict(x0=-1.0, y0=-1.0, dx=0.01, dy=0.01, nx=501, ny=201)
FIELD = dict(x=(0.9, 2.6), y=(-0.35, 0.35))      # where the blocks' centers lie, m
FIELD_END = FIELD["x"][1]
N_BLOCKS = 16
EDGE = 0.012                # m: the smoothing length of the blocks' edges
SEED = 20261127
SHIPPED = Path(__file__).resolve().parents[1] / "python" / "cedra" / "models" / "scenes" / "rubble3d.txt"

SPEED = 0.15                # m/s
HEADING_GAIN = 2.0          # 1/s
STALL_TIME = 4.0            # s
STALL_GAIN = 0.02           # m
STOP_TIME = 25.0
STEP = 0.01
RECORD = ["body.x", "body.y", "body.z", "body.yaw", "body.pitch", "body.roll", "chassis.Fn", "chassis.clearance"] + \
    [f"wheel[{i}].contacts" for i in range(1, 7)] + [f"wheel[{i}].Fn" for i in range(1, 7)]


def blocks():
    """(x, y, yaw, half length, half width, height) of each block, m and rad, from SEED."""
    rng = np.random.default_rng(SEED)
    out = []
    for _ in range(N_BLOCKS):
        out.append((rng.uniform(*FIELD["x"]), rng.uniform(*FIELD["y"]), rng.uniform(-np.pi, np.pi),
                    rng.uniform(0.04, 0.10), rng.uniform(0.03, 0.07), rng.uniform(0.4, 1.2) * R_W))
    return out


def heights(X, Y):
    X, Y = np.broadcast_arrays(np.asarray(X, float), np.asarray(Y, float))
    Z = np.zeros(X.shape)
    for x, y, yaw, a, b, h in blocks():
        u = (X - x) * np.cos(yaw) + (Y - y) * np.sin(yaw)
        v = -(X - x) * np.sin(yaw) + (Y - y) * np.cos(yaw)
        Z += h * 0.25 * (1 + np.tanh((a - np.abs(u)) / EDGE)) * (1 + np.tanh((b - np.abs(v)) / EDGE))
    return Z


def grid():
    g = GRID
    X = g["x0"] + g["dx"] * np.arange(g["nx"])
    Y = g["y0"] + g["dy"] * np.arange(g["ny"])
    return X, Y, heights(X[None, :], Y[:, None])


def write_heightmap(path=SHIPPED) -> Path:
    from cedra.mechanics import heightmap
    _, _, Z = grid()
    return heightmap.write(path, np.round(Z, 6), GRID["x0"], GRID["y0"], GRID["dx"], GRID["dy"],
                           "cedra scene rubble3d: random blocks with smoothed edges, made by examples/rubble.py")


def verdict(result) -> tuple[str, str]:
    """(verdict, reason) of a run from its own outputs (see the module's docstring)."""
    if not result.ok:
        msg = "; ".join(result.messages[-1:])
        return ("tipped" if "tipped" in msg else "failed"), msg
    t, x = result.column("time"), result.column("body.x")
    if x.max() > FIELD_END + 0.3:
        k = int(np.argmax(x > FIELD_END + 0.3))
        return "over", f"body.x = {x[k]:.3f} m at t = {t[k]:.2f} s, past the field's end at {FIELD_END} m"
    last = t >= t[-1] - 1.0
    load = float(np.mean(result.column("chassis.Fn")[last]))
    where = f"body.x = {x[-1]:.3f} m (the field ends at {FIELD_END} m)"
    if load > 0:
        return "hung up", f"{where}; the chassis carried {load:.1f} N on average over the last second"
    return "stuck", f"{where}; only the wheels touch"


def run(out_dir="out/rubble", build_dir="build", stop_time=None, quiet=False, watch=True) -> dict:
    from cedra.run.cosim import DriveLoop
    from cedra.run.progress import Progress
    from cedra.run.scenario import fmu, watch_run, write_csv
    from cedra.run.watch import plus_watched
    stop_time = stop_time or STOP_TIME
    loop = DriveLoop(fmu("rubble3d", build_dir), fmu("drive3d", build_dir), controller_values={"ctrl.mode": 1})

    history = []             # (t, body.x) at each communication point
    stopped = []

    def commands(t):
        x, yaw = loop.plant.get(["body.x", "body.yaw"])
        history.append((t, x))
        before = [xb for tb, xb in history if tb <= t - STALL_TIME]
        if not stopped and (x > FIELD_END + 0.3 or (before and x - before[-1] < STALL_GAIN)):
            stopped.append(t)
        if stopped:
            return {"cmd.v": 0.0, "cmd.yaw_rate": 0.0}
        return {"cmd.v": SPEED, "cmd.yaw_rate": -HEADING_GAIN * yaw}
    progress = Progress(stop_time, "rubble", quiet=quiet)
    try:                     # a run the FMU stops (tipped, failed) is a verdict, not an error: loop.run, not run_loop
        r = loop.run(stop_time, STEP, commands, plus_watched(RECORD), progress)
    finally:
        progress.done()
        loop.close()
    out = Path(out_dir)
    write_csv(out / "rubble.csv", r.names, r.rows)
    watch_run(out, r.names, r.rows, fmu("rubble3d", build_dir), "rubble: across the blocks", watch)
    v, why = verdict(r)
    contacts = np.array([r.column(f"wheel[{i}].contacts") for i in range(1, 7)])
    summary = dict(verdict=v, reason=why, t_end=float(r.rows[-1, 0]), wall=r.wall, t_stop=(stopped or [None])[0],
                   x_end=float(r.column("body.x")[-1]), max_contacts=int(contacts.max()),
                   several=float(np.mean(contacts > 1)), chassis_peak=float(np.max(r.column("chassis.Fn"))))
    _plot(out, r)
    if not quiet:
        print(f"rubble3d: {v}: {why} (t = {summary['t_end']:.2f} s of {stop_time:g}, {r.wall:.1f} s wall); "
              f"a wheel had {summary['max_contacts']} contacts at most, several in {100 * summary['several']:.1f} % "
              f"of the wheel samples; chassis load peak {summary['chassis_peak']:.1f} N -> {out}")
    return summary


def _plot(out, r):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    X, Y, Z = grid()
    fig, ax = plt.subplots(figsize=(10, 3.8))
    cs = ax.contourf(X, Y, Z, levels=20, cmap="Greys")
    fig.colorbar(cs, ax=ax, label="height [m]")
    ax.plot(r.column("body.x"), r.column("body.y"), "r", label="body path")
    ax.set_xlim(-0.5, 3.3)
    ax.set_ylim(-0.7, 0.7)
    ax.set_aspect("equal")
    ax.set_xlabel("X [m]")
    ax.set_ylabel("Y [m]")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "path.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    if "--write-grid" in sys.argv[1:]:
        print(write_heightmap())
    else:
        run()
