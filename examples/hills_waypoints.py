"""Over the rolling hills (hills3d heightmap) through a list of waypoints: pure pursuit on top of the drive
controller's yaw-rate command.

    python examples/hills_waypoints.py      (or: python -m cedra simulate hills_waypoints)

Each communication step the script aims the rover at the current waypoint (yaw rate = 2 v sin(alpha) / L, alpha
the bearing error, L the distance), moving on to the next within REACHED m. Writes out/hills_waypoints/
(hills_waypoints.csv, path.png over the height map) and prints how close each waypoint was passed.
Edit WAYPOINTS (X, Y in m, inside the grid) and SPEED.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

WAYPOINTS = [(1.2, 0.15), (2.2, -0.1), (3.2, 0.05)]    # m
SPEED = 0.2                 # m/s (> 0)
REACHED = 0.15              # m: a waypoint counts as passed within this distance
LOOKAHEAD = 0.5             # m: the shortest distance the pursuit law divides by (gentler turns near a waypoint)
MAX_YAW_RATE = 0.5          # rad/s
STOP_TIME = 25.0
STEP = 0.01
MARGIN = 0.4                # m: waypoints must be this far inside the grid (the rover is ~0.7 m long)
RECORD = ["body.x", "body.y", "body.yaw", "body.z"] + [f"wheel[{i}].slip" for i in range(1, 7)]


def check_inputs(waypoints, speed, grid):
    """ScenarioError before any simulation: a negative speed, an empty list, a waypoint off the heightmap."""
    from cedra.run.scenario import ScenarioError
    if not speed > 0:
        raise ScenarioError(f"hills_waypoints: SPEED = {speed} m/s must be > 0")
    if not waypoints:
        raise ScenarioError("hills_waypoints: WAYPOINTS is empty")
    x0, y0, x1, y1 = grid
    for k, (x, y) in enumerate(waypoints):
        if not (x0 + MARGIN <= x <= x1 - MARGIN and y0 + MARGIN <= y <= y1 - MARGIN):
            raise ScenarioError(f"hills_waypoints: waypoint {k} ({x}, {y}) m is off the heightmap: it must lie in "
                                f"[{x0 + MARGIN:g}, {x1 - MARGIN:g}] x [{y0 + MARGIN:g}, {y1 - MARGIN:g}] m (the grid "
                                f"[{x0:g}, {x1:g}] x [{y0:g}, {y1:g}] m less {MARGIN} m for the rover)")


def grid_extent():
    """(x0, y0, x1, y1) of the shipped hills3d grid, from its header."""
    from cedra.models.scene import load_shipped
    path = Path(load_shipped("hills3d").options.heightmap)
    nums = [ln.split() for ln in path.read_text().splitlines() if ln and not ln.startswith("#")][1]
    nx, ny, x0, y0, dx, dy = int(nums[0]), int(nums[1]), *map(float, nums[2:6])
    return x0, y0, x0 + (nx - 1) * dx, y0 + (ny - 1) * dy


class PurePursuit:
    def __init__(self, loop, waypoints):
        self.loop, self.waypoints, self.k = loop, list(waypoints), 0
        self.closest = [np.inf] * len(self.waypoints)

    def __call__(self, t):
        x, y, yaw = self.loop.plant.get(["body.x", "body.y", "body.yaw"])
        if self.k >= len(self.waypoints):
            return {"cmd.v": 0.0, "cmd.yaw_rate": 0.0}
        wx, wy = self.waypoints[self.k]
        dist = np.hypot(wx - x, wy - y)
        self.closest[self.k] = min(self.closest[self.k], dist)
        if dist < REACHED:
            self.k += 1
            return self(t)
        alpha = np.angle(np.exp(1j * (np.arctan2(wy - y, wx - x) - yaw)))
        yaw_rate = float(np.clip(2 * SPEED * np.sin(alpha) / max(dist, LOOKAHEAD), -MAX_YAW_RATE, MAX_YAW_RATE))
        return {"cmd.v": SPEED, "cmd.yaw_rate": yaw_rate}


def run(out_dir="out/hills_waypoints", build_dir="build", stop_time=None, quiet=False, waypoints=None,
        speed=None, watch=True) -> dict:
    from cedra.run.cosim import DriveLoop
    from cedra.run.scenario import fmu, run_loop, watch_run, write_csv
    from cedra.run.watch import plus_watched
    global SPEED
    waypoints = WAYPOINTS if waypoints is None else waypoints
    SPEED = SPEED if speed is None else speed
    check_inputs(waypoints, SPEED, grid_extent())
    stop_time = stop_time or STOP_TIME
    loop = DriveLoop(fmu("hills3d", build_dir), fmu("drive3d", build_dir))
    pursuit = PurePursuit(loop, waypoints)
    r = run_loop(loop, "hills_waypoints", stop_time, STEP, pursuit, plus_watched(RECORD), quiet)
    out = Path(out_dir)
    write_csv(out / "hills_waypoints.csv", r.names, r.rows)
    watch_run(out, r.names, r.rows, fmu("hills3d", build_dir), "hills_waypoints: pure pursuit over the hills", watch)
    summary = dict(reached=pursuit.k, closest=[float(c) for c in pursuit.closest], wall=r.wall,
                   x_end=float(r.column("body.x")[-1]))
    _plot(out, r, waypoints)
    if not quiet:
        print(f"hills_waypoints: passed {pursuit.k} of {len(waypoints)} waypoints; closest approach "
              + ", ".join(f"{c:.3f}" if np.isfinite(c) else "-" for c in pursuit.closest)
              + f" m; {r.column('time')[-1]:g} s in {r.wall:.1f} s wall -> {out}")
    return summary


def _plot(out, r, waypoints):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import sys
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from hills import grid               # examples/hills.py made the shipped grid
    X, Y, Z = grid()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    cs = ax.contourf(X, Y, Z, levels=20, cmap="Greens")
    fig.colorbar(cs, ax=ax, label="height [m]")
    ax.plot(r.column("body.x"), r.column("body.y"), "k", label="body path")
    wx, wy = zip(*waypoints)
    ax.plot(wx, wy, "rx", ms=9, label="waypoints")
    ax.set_aspect("equal")
    ax.set_xlabel("X [m]")
    ax.set_ylabel("Y [m]")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "path.png", dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    run()
