"""The paper's run: the 2D rover over the Gaussian bump, equal torques from a speed loop (docs/model.md).

    python examples/bump_paper.py           (or: python -m cedra simulate bump_paper)

The main job (`./build.sh demo`) as a script: writes out/bump_paper/ (bump2d.csv, forces.png in the spirit of the
paper's Fig. 8, path.png) and prints a summary. The loop itself is cedra.run.simulate.run_bump (the controller in
Python, measuring at t and holding the torque over [t, t + 0.01 s]).
"""
from __future__ import annotations

from pathlib import Path

STOP_TIME = 15.0


def run(out_dir="out/bump_paper", build_dir="build", stop_time=None, quiet=False, watch=True) -> dict:
    from cedra.run.scenario import fmu, watch_run
    from cedra.run.simulate import bump_terrain, run_bump, write_outputs
    stop_time = stop_time or STOP_TIME
    path = fmu("bump2d", build_dir)
    names, rows, torques, info = run_bump(path, stop_time)
    if not info["ok"]:
        raise RuntimeError("bump_paper stopped early: " + "; ".join(info["messages"][-2:]))
    col = {n: rows[:, k] for k, n in enumerate(names)}
    write_outputs(Path(out_dir), names, rows, torques, bump_terrain(path)[0])
    watch_run(out_dir, names, rows, path, "bump_paper: the paper's run", watch)
    summary = dict(x_end=float(col["body.x"][-1]),
                   peak_Fn=float(max(col[f"wheel[{i}].Fn"].max() for i in (1, 2, 5, 6))),
                   peak_tau=float(abs(torques).max()), wall=info["wall"])
    if not quiet:
        print(f"bump_paper: body.x {summary['x_end']:.3f} m after {stop_time:g} s, peak normal force "
              f"{summary['peak_Fn']:.1f} N, peak torque {summary['peak_tau']:.2f} N.m, {info['wall']:.1f} s wall "
              f"-> {out_dir}")
    return summary


if __name__ == "__main__":
    run()
