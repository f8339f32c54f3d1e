"""The map's own report: <out>/<name>.md next to the map's PNG, written from the sweep's table.

It says how the map was made (the command, the date, the code's git revision, the machine), what turns the wheels,
the number of runs of each verdict, the verdicts as tables (rows: the map's y, columns: its x; one table per
panel), where the verdict is not monotonic in y (a run that does not get over above one that does, in the same
column: each such place with both runs' own outputs), the failed runs with their reasons, the slowest runs and,
after `--check-tol`, whether every run gives the same verdict at a tight solver tolerance.
"""
from __future__ import annotations

import math
import statistics
from pathlib import Path

from cedra.pages import md_table
from cedra.sweep.maps import cell, index


SLOW_S = 10.0          # s of wall time: a run slower than this is listed


def _num(v, digits=4) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "nan" if f != f else f"{f:.{digits}g}"


def _climbs(cat: str) -> bool:
    return cat in ("over", "yes")


class Axes:
    """The map's axes over a sweep's table: each row's place (panel, x, y) and category (maps.cell)."""

    def __init__(self, sw, rows):
        spec = sw.map
        self.spec = spec
        self.xs, self.ys = sw.grid[spec["x"]], sw.grid[spec["y"]]
        self.panels = sw.grid[spec["panels"]] if "panels" in spec else [None]
        self.places = {}                     # (panel index, x index, y index) -> row
        for r in rows:
            ip = index(self.panels, r[spec["panels"]]) if "panels" in spec else 0
            ix, iy = index(self.xs, r[spec["x"]]), index(self.ys, r[spec["y"]])
            if None not in (ip, ix, iy):
                self.places[ip, ix, iy] = r

    def category(self, r) -> str:
        return cell(r, self.spec["verdict"])

    def x_text(self, v) -> str:
        return f"{v / self.spec.get('x_scale', 1.0):.3g}"

    def panel_text(self, ip) -> str:
        pv = self.panels[ip]
        if pv is None:
            return ""
        return f"{self.spec.get('panel_label', self.spec['panels'])} = {pv / self.spec.get('panel_scale', 1.0):.3g}"

    def where(self, ip, ix) -> str:
        p = self.panel_text(ip)
        return (f"{p}, " if p else "") + f"{self.spec.get('x_label', self.spec['x'])} = {self.x_text(self.xs[ix])}"


def not_monotonic(ax: Axes) -> list[tuple]:
    """Every run that does not get over while a run lower in y in the same column (panel, x) does, with the
    nearest such run below it: [(panel index, x index, the run over, the run not over)]. Failed runs take no
    part: a failure to simulate is no verdict."""
    out = []
    for ip in range(len(ax.panels)):
        for ix in range(len(ax.xs)):
            below = None                     # the highest run so far that got over
            for iy in range(len(ax.ys)):
                r = ax.places.get((ip, ix, iy))
                if r is None:
                    continue
                c = ax.category(r)
                if c == "failed":
                    continue
                if _climbs(c):
                    below = r
                elif below is not None:
                    out.append((ip, ix, below, r))
    return out


def _run_text(ax: Axes, r, outputs) -> str:
    y = ax.spec["y"]
    parts = [f"{y} {_num(r[y])}: {ax.category(r)}"]
    parts += [f"{o} {_num(r[o])}" for o in ("final_x", "t_end") if o in outputs]
    if r.get("reason"):
        parts.append(f"reason: {r['reason']}")
    return ", ".join(parts)


def tolerance_differences(sw, rows, tight, tight_rows) -> tuple[int, list[tuple]]:
    """Runs compared and [(params, row at the sweep's tolerance, row at the tight one)] where the map's category
    differs (runs missing from either table are not compared)."""
    verdict = sw.map["verdict"]
    by_id = {r["id"]: r for r in rows}
    tight_by_id = {r["id"]: r for r in tight_rows}
    compared, diffs = 0, []
    for p, q in zip(sw.runs(), tight.runs()):
        a, b = by_id.get(sw.run_id(p)), tight_by_id.get(tight.run_id(q))
        if a is None or b is None:
            continue
        compared += 1
        if cell(a, verdict) != cell(b, verdict):
            diffs.append((p, a, b))
    return compared, diffs


def write(sw, rows: list[dict], command: str, wall: float, load_at_start: float, check=None) -> Path:
    """Write <out>/<name>.md; check = (the solver parameter, its value, the tight sweep, its rows) after --check-tol
    or --check-h."""
    from cedra.pages import provenance
    from cedra.sweep.verdicts import VERDICTS
    ax = Axes(sw, rows)
    spec = sw.map
    lines = [f"# {spec.get('title', sw.name)}", "", provenance(command, wall, load_at_start), ""]
    what = f"{len(rows)} runs of {sw.target.kind} {sw.target.name}"
    if sw.target.kind == "scene":
        what += f" (model {sw.target.scene.name}): {sw.actuation()}"
    opts = ", ".join(f"{k} = {str(v).lower()}" for k, v in sw.target.options.items())
    lines += [what + (f"; sweep options: {opts}" if opts else "") + f"; {sw.stop_time:g} s simulated at most per "
              f"run; table `{sw.table.name}`.", "", f"![the map]({sw.name}.png)", ""]

    # counts
    cats = [ax.category(r) for r in rows]
    lines += ["## Verdicts", ""]
    if spec["verdict"] == "verdict":
        order = list(VERDICTS)
        lines.append(md_table(["verdict", "runs", "meaning"],
                            [(c, cats.count(c), VERDICTS[c]) for c in order if cats.count(c)]))
        late = sum(c in ("stuck", "hung up") and r["reason"].startswith("not over") for c, r in zip(cats, rows))
        if late:
            lines += ["", f"Of the stuck and hung-up runs, {late} ran to the stop time without getting over and "
                          f"without stopping (reason \"not over the obstacle at the stop time\")."]
    else:
        lines.append(md_table([spec["verdict"], "runs"],
                            [(c, cats.count(c)) for c in ("yes", "no", "failed") if cats.count(c)]))
    lines.append("")

    # the verdict tables
    y = spec["y"]
    lines += [f"## The verdicts over {spec['x']} and {y}", ""]
    for ip in range(len(ax.panels)):
        head = ax.panel_text(ip)
        if head:
            lines += [f"### {head}", ""]
        header = [f"{y} \\ {spec.get('x_label', spec['x'])}"] + [ax.x_text(v) for v in ax.xs]
        body = []
        for iy, yv in enumerate(ax.ys):
            r_cells = []
            for ix in range(len(ax.xs)):
                r = ax.places.get((ip, ix, iy))
                r_cells.append("" if r is None else ax.category(r))
            body.append([f"{yv:.4g}"] + r_cells)
        lines += [md_table(header, body), ""]

    # monotonicity in y
    bad = not_monotonic(ax)
    lines += [f"## Monotonic in {y}?", ""]
    if bad:
        lines.append(f"Not everywhere: {len(bad)} place(s) where a run does not get over while the run at a lower "
                     f"{y} in the same column does (failed runs left out):")
        lines.append("")
        for ip, ix, over, stopped in bad:
            lines.append(f"- {ax.where(ip, ix)}: {_run_text(ax, over, sw.outputs)} / "
                         f"{_run_text(ax, stopped, sw.outputs)}")
    else:
        lines.append(f"Yes: in every column, once a run gets over, every run at a higher {y} does too "
                     f"(failed runs left out).")
    lines.append("")

    # failed runs
    failed = [r for r in rows if r["status"] != "ok"]
    lines += ["## Failed runs", ""]
    if failed:
        lines.append(md_table(sw.parameters + ["status", "t_end", "wall_s", "reason"],
                            [[_num(r[p]) for p in sw.parameters] + [r["status"], _num(r.get("t_end", "")),
                                                                    _num(r["wall_s"], 3), r["reason"]]
                             for r in failed]))
    else:
        lines.append("None.")
    lines.append("")

    # wall time
    walls = [float(r["wall_s"]) for r in rows if r["wall_s"] not in ("", "nan")]
    walls = [w for w in walls if math.isfinite(w)]
    lines += ["## Wall time", ""]
    if walls:
        slow = sorted((r for r in rows if _finite(r["wall_s"]) and float(r["wall_s"]) > SLOW_S),
                      key=lambda r: -float(r["wall_s"]))
        lines.append(f"Per run: median {statistics.median(walls):.2f} s, max {max(walls):.1f} s, sum "
                     f"{sum(walls):.1f} s over {len(walls)} runs; {len(slow)} run(s) over {SLOW_S:g} s" +
                     (":" if slow else "."))
        if slow:
            lines += ["", md_table(sw.parameters + ["wall_s", "t_end", ax.spec["verdict"], "reason"],
                                 [[_num(r[p]) for p in sw.parameters] +
                                  [_num(r["wall_s"], 3), _num(r.get("t_end", "")), ax.category(r), r["reason"]]
                                  for r in slow])]
    lines.append("")

    # the tolerance check
    if check is not None:
        key, tol, tight, tight_rows = check
        at = f"{key.split('.')[-1]} {tol:g}"
        compared, diffs = tolerance_differences(sw, rows, tight, tight_rows)
        tight_failed = sum(r["status"] != "ok" for r in tight_rows)
        tight_walls = [float(r["wall_s"]) for r in tight_rows if _finite(r["wall_s"])]
        walls_text = (f", wall time per run median {statistics.median(tight_walls):.2f} s, max "
                      f"{max(tight_walls):.1f} s" if tight_walls else "")
        lines += [f"## The same verdicts at {key} {tol:g}?", "",
                  f"Every run again at {key} = {tol:g} (table `{tight.table.name}`; {tight_failed} of its runs "
                  f"failed{walls_text}): {compared} runs compared, "
                  + ("every verdict the same." if not diffs else f"{len(diffs)} verdict(s) differ:"), ""]
        if diffs:
            lines.append(md_table(sw.parameters + ["verdict", f"at {at}", "final_x", f"at {at}", f"reason at {at}"],
                                [[_num(p[k]) for k in sw.parameters] + [ax.category(a), ax.category(b),
                                                                          _num(a.get("final_x", "")),
                                                                          _num(b.get("final_x", "")), b["reason"]]
                                 for p, a, b in diffs]))
            lines.append("")
    out = sw.out / f"{sw.name}.md"
    out.write_text("\n".join(lines))
    return out


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False
