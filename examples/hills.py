"""The rolling hills of the shipped scene hills3d (terrain = "heightmap"): how its grid file was made, and a
drive across it through the FMU.

    python examples/hills.py     # rewrites python/cedra/models/scenes/hills3d.txt, then drives (prints a summary)

tests/test_heightmap.py checks that the shipped grid is exactly what heights() gives, and runs drive().
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

GRID = dict(x0=-1.0, y0=-1.0, dx=0.05, dy=0.05, nx=101, ny=41)    # X in [-1, 4] m, Y in [-1, 1] m
# (X, Y, height, width) of each hill, m: low and broad enough for 0.065 m wheels; under the start pose (wheels at
# X = -0.3 .. 0.3) the hills add less than 1e-8 m, so the start is the flat ground's
HILLS = [(1.3, 0.15, 0.05, 0.25), (1.9, -0.25, 0.06, 0.3), (2.5, 0.3, 0.04, 0.2), (3.0, -0.1, 0.05, 0.3)]
SHIPPED = Path(__file__).resolve().parents[1] / "python" / "cedra" / "models" / "scenes" / "hills3d.txt"


def heights(X, Y):
    Z = np.zeros(np.broadcast(X, Y).shape)
    for x, y, h, w in HILLS:
        Z += h * np.exp(-((X - x) ** 2 + (Y - y) ** 2) / w ** 2)
    return Z


def grid():
    g = GRID
    X = g["x0"] + g["dx"] * np.arange(g["nx"])
    Y = g["y0"] + g["dy"] * np.arange(g["ny"])
    return X, Y, heights(X[None, :], Y[:, None])


def write_heightmap(path=SHIPPED) -> Path:
    from cedra.mechanics import heightmap
    _, _, Z = grid()
    return heightmap.write(path, np.round(Z, 9), GRID["x0"], GRID["y0"], GRID["dx"], GRID["dy"],
                           "cedra scene hills3d: rolling hills, made by examples/hills.py")


def drive(build_dir="build", stop_time=None):
    """Run the shipped hills3d FMU under the main job's closed loop (cedra.run.simulate.run_bump: the sampled speed
    controller, the same torque on every wheel); returns (names, rows), names[0] = "time"."""
    from cedra.models import scene as scn
    from cedra.fmu.packaging import build_fmu
    from cedra.run.simulate import run_bump
    sc = scn.load_shipped("hills3d")
    fmu = Path(build_dir) / "hills3d.fmu"
    if not fmu.exists():
        fmu = build_fmu(sc.spec(), build_dir)
    extra = [f"body.{n}" for n in ("y", "yaw", "roll")] + ["energy.kinetic"]
    names, rows, _, info = run_bump(fmu, stop_time or sc.stop_time, extra=extra)
    if not info["ok"]:
        raise RuntimeError(f"hills3d stopped at t={info['simulated']}: " + "; ".join(info["messages"][-3:]))
    return names, rows


if __name__ == "__main__":
    print(write_heightmap())
    names, rows = drive(stop_time=float(sys.argv[1]) if len(sys.argv) > 1 else None)
    last = dict(zip(names, rows[-1]))
    print(", ".join(f"{k}={v:.4g}" for k, v in last.items()))
