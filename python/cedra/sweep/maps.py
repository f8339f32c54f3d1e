"""The [map] of a sweep: a verdict (e.g. climbed yes/no) over two grid parameters, one panel per value of a third,
drawn from the sweep's table to <out>/<name>.png:

    [map]
    x = "terrain_h"              # grid parameters on the axes
    y = "mu"
    panels = "terrain_w"         # optional: one panel per grid value
    verdict = "verdict"          # the output "verdict" (over, stuck, hung up, tipped, failed: VERDICTS of
                                 # cedra.sweep.verdicts), or an output that is 1 (yes) or 0 (no), such as "climbed"
    x_scale = 0.065              # optional: show x / x_scale (e.g. in wheel radii) ...
    x_label = "h / R_w"          # ... under this label (likewise panel_scale, panel_label)
    mark = {terrain_h = 0.14625, terrain_w = 0.14625, mu = 0.8, label = "the paper's run"}

Each verdict has its own colour (VERDICT_COLOURS), and the legend counts the runs of each. Runs that failed (status
other than ok) are drawn grey: a failure to simulate is not a failure to climb. The title's second line says what
turns the wheels (drives and their envelope, or plain torque: cedra.sweep.Sweep.actuation).
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

VERDICT_COLOURS = {"over": "#5cb85c", "stuck": "#d9534f", "hung up": "#f0ad4e", "tipped": "#8e44ad",
                   "failed": "#bbbbbb"}
YES_NO_COLOURS = {"no": "#d9534f", "yes": "#5cb85c", "failed": "#bbbbbb"}      # a 1/0 verdict such as climbed
KEYS = {"x", "y", "panels", "verdict", "x_scale", "x_label", "panel_scale", "panel_label", "y_label", "mark", "title"}


def check_map(spec, sw) -> tuple[str, str] | None:
    """The first problem of a sweep's [map] table as (key under map, reason), or None."""
    if not isinstance(spec, dict):
        return "", "expected a table"
    for k in spec:
        if k not in KEYS:
            return k, f"unknown key (known: {', '.join(sorted(KEYS))})"
    for k in ("x", "y", "verdict"):
        if k not in spec:
            return k, "missing"
    for k in ("x", "y", "panels"):
        if k in spec and spec[k] not in sw.grid:
            return k, f"{spec[k]!r} is not a [grid] parameter of this sweep (grid: {', '.join(sw.grid)})"
    if spec["verdict"] not in sw.outputs:
        return "verdict", f"{spec['verdict']!r} is not one of this sweep's outputs ({', '.join(sw.outputs)})"
    for k in ("x_scale", "panel_scale"):
        if k in spec and not (isinstance(spec[k], (int, float)) and spec[k] > 0):
            return k, f"expected a number > 0, got {spec[k]!r}"
    mark = spec.get("mark", {})
    if mark and not (isinstance(mark, dict) and spec["x"] in mark and spec["y"] in mark):
        return "mark", f"expected a table with {spec['x']} and {spec['y']} (and optionally label)"
    for name in mark:
        if name != "label" and name not in sw.grid:
            return f"mark.{name}", f"not a [grid] parameter of this sweep (grid: {', '.join(sw.grid)})"
    return None


def _close(a, b) -> bool:
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


def cell(row: dict, verdict: str) -> str:
    """A table row's category on the map: one of VERDICT_COLOURS for the output "verdict", else one of
    YES_NO_COLOURS (a 1/0 output); "failed" for a run whose status is not ok, whatever its outputs."""
    if row["status"] != "ok":
        return "failed"
    if verdict == "verdict":
        return row["verdict"] if row["verdict"] in VERDICT_COLOURS else "failed"
    return "yes" if float(row[verdict]) >= 0.5 else "no"


def index(values, v) -> int | None:
    """The position of v among a grid's values, None if it is not one of them."""
    return next((k for k, g in enumerate(values) if _close(float(v), g)), None)


def draw(sw, rows: list[dict]) -> Path:
    """Draw the map from the sweep's table rows (as read from its CSV); returns the PNG's path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    spec = sw.map
    xs, ys = sw.grid[spec["x"]], sw.grid[spec["y"]]
    panels = sw.grid[spec["panels"]] if "panels" in spec else [None]
    xscale, pscale = spec.get("x_scale", 1.0), spec.get("panel_scale", 1.0)
    mark = spec.get("mark", {})
    # the mark goes in the panel nearest its value of the panel parameter (every panel's if it has none)
    mark_panel = (min(panels, key=lambda v: abs(v - mark[spec['panels']]))
                  if 'panels' in spec and spec['panels'] in mark else None)
    fig, axes = plt.subplots(1, len(panels), figsize=(max(7.0, 3.6 * len(panels) + 1), 4.6), sharey=True,
                             squeeze=False)
    colours = VERDICT_COLOURS if spec["verdict"] == "verdict" else YES_NO_COLOURS
    cats = list(colours)
    cmap = ListedColormap([colours[c] for c in cats])
    counts = dict.fromkeys(cats, 0)
    for ax, pv in zip(axes[0], panels):
        grid = np.full((len(ys), len(xs)), np.nan)
        for r in rows:
            if pv is not None and not _close(float(r[spec["panels"]]), pv):
                continue
            ix, iy = index(xs, r[spec["x"]]), index(ys, r[spec["y"]])
            if ix is None or iy is None:
                continue
            c = cell(r, spec["verdict"])
            grid[iy, ix] = cats.index(c)
            counts[c] += 1
        ax.pcolormesh(_edges(np.array(xs) / xscale), _edges(np.array(ys)), np.ma.masked_invalid(grid), cmap=cmap,
                      vmin=-0.5, vmax=len(cats) - 0.5, shading="flat", edgecolors="white", linewidth=0.3)
        if mark and (mark_panel is None or pv == mark_panel):      # in the figure's legend, not over the cells
            star = ax.plot(mark[spec["x"]] / xscale, mark[spec["y"]], marker="*", ms=16, mec="k", mfc="gold",
                           ls="none")[0]
        if pv is not None:
            ax.set_title(f"{spec.get('panel_label', spec['panels'])} = {pv / pscale:.3g}", fontsize=10)
        ax.set_xlabel(spec.get("x_label", spec["x"]))
    axes[0][0].set_ylabel(spec.get("y_label", spec["y"]))
    if spec["verdict"] == "verdict":           # the verdicts that occur, each with its count
        shown = [c for c in cats if counts[c]] or cats
        labels = [f"{c} ({counts[c]})" for c in shown]
    else:
        shown = cats
        labels = [f"{spec['verdict']}: no ({counts['no']})", f"{spec['verdict']}: yes ({counts['yes']})",
                  f"run failed ({counts['failed']})"]
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[c]) for c in shown]
    if mark:
        handles.append(star)
        labels.append(mark.get("label", "marked"))
    # one row while the labels fit the figure's width (about 16 characters of 8 pt per inch), else two columns
    fits = sum(len(lb) + 6 for lb in labels) <= 16 * fig.get_figwidth()
    fig.legend(handles, labels, loc="lower center", ncol=len(handles) if fits else 2, fontsize=8)
    default_title = f"{sw.name}: {spec['verdict']} ({len(rows)} runs of {sw.target.kind} {sw.target.name})"
    how = sw.actuation()
    lines = [spec.get("title", default_title)] + ([f"{sw.target.scene.name}: {how}"] if how else [])
    # wrapped to the figure's width (about 13 characters of 10 pt per inch), the plots below the lines it takes
    lines = [w for line in lines for w in textwrap.wrap(line, int(13 * fig.get_figwidth()))]
    fig.suptitle("\n".join(lines), x=0.02, ha="left", fontsize=10)
    fig.tight_layout(rect=(0, 0.06 if fits else 0.11, 1, max(0.7, 0.965 - 0.035 * len(lines))))
    out = sw.out / f"{sw.name}.png"
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _edges(v: np.ndarray) -> np.ndarray:
    """Cell edges around grid values (midpoints; the ends extended by half a cell)."""
    if len(v) == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5]) if v[0] != 0 else np.array([-0.5, 0.5])
    mid = (v[1:] + v[:-1]) / 2
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])
