"""The field's quasi-static metrics for the rovers of `report rovers` (docs/rovers.md, The friction a climb
requires): per rover, the friction a sharp step of height h requires (cedra.rover.required_friction) over h up to
two wheel diameters, the same for the stairs of the stairs map (4 risers, run 4 R_w), the torque each needs, the
virtual centres of rotation at the design pose (cedra.rover.virtual_centres), and, with the dynamic maps, every
cell where the two disagree with what each says there.

`section(out, quick, maps)` computes, draws (<out>/rovers_statics.png, <out>/rovers_centres.png) and returns the
report's lines.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from cedra.rover.climb_pose import PlanarRover, PoseError
from cedra.rover.mechanism import CEDRA
from cedra.rover.profile import Staircase
from cedra.rover.required_friction import required_friction
from cedra.rover.rocker_bogie import ROCKER_BOGIE
from cedra.rover.shrimp import SHRIMP
from cedra.rover.virtual_centres import virtual_centres

# each rover: its kind and its parameter values (a variant's; {}: the kind's defaults)
KINDS = {"CEDRA": (CEDRA, {}), "CEDRA shrimp": (CEDRA, SHRIMP.values), "rocker-bogie": (ROCKER_BOGIE, {})}
R_W = 0.065
STAIRS = dict(steps=4, run=0.26)                # the stairs map's (examples/sweeps/rovers/stairs_*.toml)
STEP_H = {False: [0.25 * k for k in range(1, 17)], True: [0.5, 1.0, 1.5, 2.0, 4.0]}     # h / R_w
STAIRS_H = {False: [0.5, 1.0, 1.5, 2.0, 2.5], True: [1.5]}
SPACING = {False: R_W / 8, True: R_W / 4}       # ds along each wheel's path
TAU_MAX = 4.0                                   # N.m: the maps' torque limit


def curve(kind, heights, quick, steps=1, run=math.inf, params=None) -> list[dict]:
    """Per height (in R_w): the climb's required friction, the worst pose, the torque; or why no pose forms."""
    rover = PlanarRover(kind, params)
    rows = []
    for f in heights:
        t0 = time.process_time()
        try:
            c = required_friction(kind, Staircase(f * R_W, steps, run), ds=SPACING[quick], rover=rover)
        except PoseError as e:
            rows.append(dict(h=f, ratio=math.inf, error=str(e), cpu=time.process_time() - t0))
            continue
        w = c.worst
        rows.append(dict(h=f, ratio=c.ratio, ratio_equal=c.ratio_equal, torque=c.torque, phase=w.phase, s=w.s,
                         label=w.label, hanging=w.hanging, clearance=c.clearance, error="", wedged=c.wedged,
                         cpu=time.process_time() - t0))
    return rows


def compute(quick: bool) -> dict:
    return {rover: {"step": curve(kind, STEP_H[quick], quick, params=params),
                    "stairs": curve(kind, STAIRS_H[quick], quick, params=params, **STAIRS),
                    "centres": virtual_centres(kind, params)} for rover, (kind, params) in KINDS.items()}


def _fmt(r) -> str:
    return "inf" if not math.isfinite(r) else f"{r:.3f}"


def table(results, terrain) -> list[str]:
    lines = [f"| rover | {'rise' if terrain == 'stairs' else 'h'} / R_w | required friction | worst pose | "
             "largest wheel torque (N.m) | with equal torques | chassis clearance (m) |", "|---|---|---|---|---|---|---|"]
    for rover, res in results.items():
        for row in res[terrain]:
            if row["error"]:
                # the pose solver's failure on this profile, not a property the rover is shown to have
                lines.append(f"| {rover} | {row['h']:g} | not solved | no pose found: "
                             f"{row['error'].split(': ', 1)[-1]} | | | |")
                continue
            wheel, riser = row["phase"]
            pose = f"wheel {wheel} at riser {riser}, {1000 * row['s']:.0f} mm past its lift-off"
            if row["hanging"]:
                pose += f" (wheel {', '.join(map(str, row['hanging']))} off the ground)"
            ratio = _fmt(row["ratio"])
            if row.get("wedged"):
                # the ratio is a limit approached with unbounded internal forces (required_friction: wedged)
                ratio += " (wedged)"
                pose += ": wedged between the risers, its least ratio needs unbounded internal forces"
            lines.append(f"| {rover} | {row['h']:g} | {ratio} | {pose} | {row['torque']:.2f} | "
                         f"{_fmt(row['ratio_equal'])} | {row['clearance']:.3f} |")
    return lines


def centres_table(results) -> list[str]:
    lines = ["| rover | joint | wheel | virtual centre x, z (m) | wheel centre x, z (m) | below the axle (m) |",
             "|---|---|---|---|---|---|"]
    for rover, res in results.items():
        for vc in res["centres"]:
            lines.append(f"| {rover} | {vc.joint} | {vc.wheel} | {vc.centre[0]:.3f}, {vc.centre[1]:.3f} | "
                         f"{vc.wheel_centre[0]:.3f}, {vc.wheel_centre[1]:.3f} | {vc.below_axle:.3f} |")
    return lines


def draw_curves(results, path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4))
    for (rover, res), colour in zip(results.items(), ("C0", "C2", "C1")):
        step = [r for r in res["step"] if not r["error"]]
        ax.plot([r["h"] for r in step], [min(r["ratio"], 3.0) for r in step], "o-", color=colour,
                label=f"{rover}: step")
        stairs = [r for r in res["stairs"] if not r["error"]]
        ax.plot([r["h"] for r in stairs], [min(r["ratio"], 3.0) for r in stairs], "s--", color=colour, mfc="none",
                label=f"{rover}: stairs (run 4 R_w)")
    for mu in (0.4, 0.6, 0.8, 1.0):
        ax.axhline(mu, color="0.8", lw=0.8, zorder=0)
    ax.set_xlabel("step height / stairs rise h / R_w")
    ax.set_ylabel("required friction (3 = 3 or more)")
    ax.set_ylim(0, 3.05)
    ax.legend(fontsize=8)
    ax.set_title("Quasi-static: the least largest friction ratio over the climb", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def draw_centres(results, path: Path) -> Path:
    """Each rover at its design pose (wheels, the body's and links' collision points) with its virtual centres."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 3.6), squeeze=False)
    for ax, (rover, res) in zip(axes[0], results.items()):
        model = PlanarRover(*KINDS[rover])
        centres, _, _, points = (np.array(e) for e in model.geometry(model.check_design(), model.par))
        for x, z in centres.T:
            ax.add_patch(plt.Circle((x, z), model.radius, fill=False, color="k"))
        if points.size:
            ax.plot(points[0], points[1], ".", color="0.5", ms=3, label="body and links")
        ax.axhline(0, color="0.6", lw=1)
        lo, hi = -0.45, 0.5
        for vc in res["centres"]:
            x, z = vc.centre
            label = f"{vc.joint}: ({x:.2f}, {z:.2f}) m"
            if lo < x < hi and -0.2 < z < 0.4:
                ax.plot(x, z, "x", ms=10, mew=2, label=label)
                ax.plot([x, vc.wheel_centre[0]], [z, vc.wheel_centre[1]], ":", lw=1)
            else:                           # off the figure: an arrow toward it
                d = np.array([x, z]) - np.array(vc.wheel_centre)
                d = 0.15 * d / np.linalg.norm(d)
                ax.annotate("", xy=(vc.wheel_centre[0] + d[0], vc.wheel_centre[1] + d[1]), xytext=vc.wheel_centre,
                            arrowprops=dict(arrowstyle="->", color="C3"))
                ax.plot([], [], "->", color="C3", label=label + " (off the figure)")
        ax.set_xlim(lo, hi)
        ax.set_ylim(-0.2, 0.4)
        ax.set_aspect("equal")
        ax.set_title(f"{rover}: virtual centres at the design pose", fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def disagreements(results, maps) -> list[str]:
    """The map cells where the quasi-static verdict (required friction <= mu) and the run's differ, with what each
    says there. maps: report rovers' {(terrain, rover): (Sweep, rows)}."""
    lines = []
    for terrain in ("step", "stairs"):
        for rover in KINDS:
            key = (terrain, rover)
            if key not in maps:
                continue
            by_h = {round(r["h"], 6): r for r in results[rover][terrain]}
            for run in maps[key][1]:
                h = round(float(run["terrain_h"]) / R_W, 6)
                if h == 0 or h not in by_h or run.get("status", "ok") != "ok":
                    continue
                qs, mu = by_h[h], float(run["mu"])
                if qs["error"]:
                    continue
                static_over = qs["ratio"] <= mu
                dynamic_over = run.get("verdict") == "over"
                if static_over == dynamic_over:
                    continue
                torque = "" if qs["error"] else f", largest wheel torque {qs['torque']:.2f} N.m " \
                    f"(the maps' limit {TAU_MAX:g}), with equal torques {_fmt(qs['ratio_equal'])}"
                lines.append(f"| {terrain} | {rover} | {h:g} | {mu:g} | {run.get('verdict')} "
                             f"(peak friction ratio {float(run.get('peak_ratio', 'nan')):.2f}, final x "
                             f"{float(run.get('final_x', 'nan')):.2f} m) | required {_fmt(qs['ratio'])}{torque} |")
    if not lines:
        return ["Every cell of the step and stairs maps at the curves' heights agrees with the quasi-static verdict."]
    return ["| terrain | rover | h / R_w | mu | the run | quasi-static |", "|---|---|---|---|---|---|"] + lines


def section(out: Path, quick: bool, maps=None) -> tuple[list[str], dict]:
    t0 = time.perf_counter()
    results = compute(quick)
    draw_curves(results, out / "rovers_statics.png")
    draw_centres(results, out / "rovers_centres.png")
    lines = ["## The friction a climb requires (quasi-static)", "",
             "Each rover's planar quasi-static balance up a sharp step and the stairs (cedra.rover.required_friction:"
             " every wheel's phase over every riser, the other wheels held down, the wheel torques distributed to "
             "minimize the largest friction ratio |T|/N over the wheels in contact, no acceleration); the worst "
             f"pose of the climb; poses every {1000 * SPACING[quick]:.1f} mm along each climbing wheel's path. "
             f"{time.perf_counter() - t0:.0f} s.", "", "### The step", ""]
    lines += table(results, "step")
    lines += ["", "### The stairs (4 risers, run 4 R_w)", ""]
    lines += table(results, "stairs")
    lines += ["", "![required friction](rovers_statics.png)", "", "### Virtual centres of rotation", ""]
    lines += centres_table(results)
    lines += ["", "![virtual centres](rovers_centres.png)", ""]
    if maps:
        lines += ["### Where the quasi-static verdict and the runs differ", "",
                  "A map cell's quasi-static verdict is `over` where the required friction is at most its mu. "
                  "The runs use equal torques from the speed loop at tau_max 4 N.m with drives; the quasi-static "
                  "balance distributes the torques freely and bounds none.", ""]
        lines += disagreements(results, maps)
        lines.append("")
    return lines, results
