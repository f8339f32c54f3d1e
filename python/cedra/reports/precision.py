"""Work-precision report: error against wall time for the FMU's embedded solvers and for the peers a
user would pick instead (scipy solve_ivp, CasADi cvodes/idas) on the same equations, from the same start state,
with the same piecewise-constant inputs.

    python -m cedra report precision [--quick] [--build build] [--out out/report]

writes <out>/precision.md, <out>/precision_<scene>.png and <out>/precision_<scene>.csv and prints a summary.
"""
from __future__ import annotations

import csv
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cedra.models.scene import load_shipped
from cedra.pages import load_average, md_table, provenance
from cedra.run.progress import Progress
from cedra.reports.common import (Problem, Run, Schedule, announce, errors, fmt, fmu_path, grid, position_names,
                                  fn_names, python_run_outputs, reference_outputs, run_casadi, run_fmu, run_scipy,
                                  torques)

SAMPLE = 0.1            # input schedule period = the coarsest communication step
REF_TOL = 1e-12
OUT_DT = 0.01           # reference output grid; errors are taken at the runs' points on this grid
FMU_COMM = 0.01         # communication step of the solver-setting sweeps
LEVELS = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7]     # position errors (m) at which speed-ups are compared
BASELINE_FLAGS = ("-DCEDRA_LOCATE_FN=NULL", "-DCEDRA_SCHUR_N2=0")
BASELINE_LABEL = "rodas4 no switches, dense"   # not "FMU ...": a peer in the speed-up tables


# ------------------------------------------------------------------ scenes and their inputs
def pi_schedule(prob: Problem, t_end, v_ref=0.2, kp=3.0, ki=6.0, tau_max=4.0) -> Schedule:
    """The main job's PI speed controller sampled every SAMPLE s, run once on the Python model (cvodes 1e-8);
    its torque sequence is then replayed open-loop by every method, so all see identical inputs."""
    q0 = prob.settle()
    x = prob.x0(q0)
    ivx = prob.out_names.index("body.vx")
    integral, times, values = 0.0, [], []
    for k in range(int(round(t_end / SAMPLE))):
        v = prob.outputs(x, prob.inp0)[ivx]
        e = v_ref - v
        u = kp * e + ki * (integral + e * SAMPLE)
        if abs(u) <= tau_max:
            integral += e * SAMPLE
        u = round(float(np.clip(u, -tau_max, tau_max)), 3)
        times.append(round(k * SAMPLE, 10))
        values.append(torques(u))
        r = run_casadi(prob, Schedule([0.0], [values[-1]]), x, np.array([0.0, SAMPLE]), "cvodes", 1e-8)
        x = r.X[-1]
    return Schedule(times, values)


def flat3d_schedule(prob: Problem, t_end) -> Schedule:
    """Drive off, steer both steered wheels, a left/right torque difference, a one-sample torque spike."""
    table = [(0.0, torques(0.4)), (0.5, torques(0.1)), (1.0, torques(0.15, **{"steer[1]": 0.25, "steer[2]": 0.25})),
             (2.0, torques([0.3, 0.3, 0.05, 0.05, 0.3, 0.05], **{"steer[1]": 0.25, "steer[2]": 0.25})),
             (2.5, torques(2.0, **{"steer[1]": -0.1, "steer[2]": -0.1})),
             (2.6, torques(0.1, **{"steer[1]": -0.1, "steer[2]": -0.1}))]
    table = [(t, v) for t, v in table if t < t_end]
    return Schedule([t for t, _ in table], [v for _, v in table])


@dataclass
class Config:
    scenes: dict
    rodas4_tols: list
    dopri5_tols: list
    rk4_steps: list
    comm_steps: list
    comm_settings: dict           # method -> (tol, h_max) used in the communication-step sweep
    sundials_tols: list
    implicit_rtols: list          # scipy Radau, BDF, LSODA
    explicit_rtols: list          # scipy RK45, DOP853
    idas_check: bool = True       # integrate the reference a second time with idas
    # rodas4 from an FMU built without switch location and with the dense 2n+1 stage solve (the same
    # sources, C flags of fmu_src/plant.c), at these tolerances: their gain at equal error
    baseline_tols: list = field(default_factory=list)
    # ROS34PW2, the W-method that keeps its Jacobian (solver.method 3)
    ros34pw2_tols: list = field(default_factory=list)


FULL = Config(
    scenes={"bump2d": dict(t_end=8.0, schedule=pi_schedule), "flat3d": dict(t_end=4.0, schedule=flat3d_schedule),
            # the sharp step (the switches located) and the paper's run in 3D
            "step2d": dict(t_end=8.0, schedule=pi_schedule), "bump3d": dict(t_end=8.0, schedule=pi_schedule)},
    rodas4_tols=[1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10],
    dopri5_tols=[1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10],
    rk4_steps=[4e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5],
    comm_steps=[1e-4, 1e-3, 1e-2, 1e-1],
    comm_settings={"rodas4": (1e-6, 0.01), "dopri5": (1e-6, 0.01), "rk4": (1e-6, 1e-4)},
    sundials_tols=[1e-4, 1e-6, 1e-8, 1e-10],
    implicit_rtols=[1e-3, 1e-5, 1e-7, 1e-9],
    explicit_rtols=[1e-3, 1e-6, 1e-9],
    baseline_tols=[1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10],
    ros34pw2_tols=[1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
)

QUICK = Config(
    scenes={"bump2d": dict(t_end=1.0, schedule=pi_schedule)},
    rodas4_tols=[1e-4, 1e-6, 1e-8, 1e-10],
    dopri5_tols=[1e-4, 1e-6, 1e-8],
    rk4_steps=[2e-4, 1e-4, 5e-5],
    comm_steps=[1e-3, 1e-1],
    comm_settings={"rodas4": (1e-6, 0.01)},
    sundials_tols=[1e-6],
    implicit_rtols=[1e-6],
    explicit_rtols=[],
    idas_check=False,
    ros34pw2_tols=[1e-4, 1e-6],
)


# ------------------------------------------------------------------ one scene
@dataclass
class SceneResult:
    name: str
    t_end: float
    ref: Run
    ref_check: dict = field(default_factory=dict)     # reference vs idas and vs the FMU's tightest run
    rows: list = field(default_factory=list)          # dicts: method, setting, comm, wall, steps, evals, errors
    fmu_available: bool = True
    schedule: Schedule | None = None


def _row(run: Run, comm, err) -> dict:
    return dict(method=run.method, setting=run.setting, comm=comm, wall=run.wall, steps=run.steps,
                evals=run.rhs_evals, ok=run.ok, status=run.status, message=run.message, **err)


def run_scene(name, cfg: Config, build="build", log=print) -> SceneResult:
    sc = cfg.scenes[name]
    scene = load_shipped(name)
    prob = Problem(scene)
    t_end = sc["t_end"]
    sched = sc["schedule"](prob, t_end)
    q0 = prob.settle()
    x0 = prob.x0(q0)
    tg = grid(t_end, OUT_DT)
    ref = run_casadi(prob, sched, x0, tg, "cvodes", REF_TOL, label=f"reference tol {REF_TOL:g}")
    if not ref.ok:
        raise RuntimeError(f"{name}: the reference failed: {ref.message}")
    R = reference_outputs(prob, sched, ref)
    log(f"{name}: reference cvodes rtol=atol={REF_TOL:g}: {ref.wall:.1f} s wall, {ref.steps} steps")
    res = SceneResult(name, t_end, ref, schedule=sched)
    watch = position_names(prob) + fn_names(prob)

    def py_err(run):
        if len(run.t) == 0:
            return errors(R, [], np.empty((0, len(watch))), watch, prob)
        return errors(R, run.t, python_run_outputs(prob, sched, run, watch), watch, prob)

    if cfg.idas_check:
        chk = run_casadi(prob, sched, x0, tg, "idas", REF_TOL)
        res.ref_check["idas"] = py_err(chk) | dict(wall=chk.wall, ok=chk.ok)
        log(f"  idas {REF_TOL:g} vs reference: position {res.ref_check['idas']['pos_abs']:.2e} m, "
            f"Fn {res.ref_check['idas']['fn_abs']:.2e} N")

    path = fmu_path(build, name)
    res.fmu_available = path.exists()

    def fmu(method, tol, h_max, comm, fmu_file=path, label=None):
        r = run_fmu(fmu_file, prob, sched, q0, t_end, comm, method, tol, h_max, record=watch, record_every=OUT_DT,
                    check_all=False)
        if label:
            r.method = label
        e = errors(R, r.t, r.Y, watch, prob) if len(r.t) else dict(pos_abs=np.nan, pos_rel=np.nan,
                                                                     fn_abs=np.nan, fn_rel=np.nan, n=0)
        if not r.ok:
            e = e | dict(pos_abs=np.inf, fn_abs=np.inf, pos_rel=np.inf, fn_rel=np.inf)
        row = _row(r, comm, e)
        row["rejected"] = r.extra.get("rejected", -1)
        res.rows.append(row)
        log(f"  {r.method:12s} {r.setting:12s} comm {comm:g}: {r.wall:7.2f} s, steps {r.steps}, "
            f"pos err {e['pos_abs']:.2e} m, Fn err {e['fn_abs']:.2e} N" + ("" if r.ok else f"  [{r.status}: "
                                                                          f"{r.message}]"))
        return row

    if res.fmu_available:
        for tol in cfg.rodas4_tols:
            fmu("rodas4", tol, 0.01, FMU_COMM)
        for tol in cfg.dopri5_tols:
            fmu("dopri5", tol, 0.01, FMU_COMM)
        for tol in cfg.ros34pw2_tols:
            fmu("ros34pw2", tol, 0.01, FMU_COMM)
        if cfg.baseline_tols:
            import tempfile
            from cedra.fmu.packaging import build_fmu
            with tempfile.TemporaryDirectory() as d:
                base = build_fmu(scene.spec(), d, extra_cflags=BASELINE_FLAGS)
                for tol in cfg.baseline_tols:
                    fmu("rodas4", tol, 0.01, FMU_COMM, fmu_file=base, label=BASELINE_LABEL)
        for h in cfg.rk4_steps:
            fmu("rk4", 1e-6, h, FMU_COMM)
        for method, (tol, h) in cfg.comm_settings.items():
            for comm in cfg.comm_steps:
                if comm != FMU_COMM:
                    fmu(method, tol, h, comm)
        tight = [r for r in res.rows if r["method"] == "FMU rodas4" and r["comm"] == FMU_COMM and r["ok"]]
        if tight:
            best = min(tight, key=lambda r: float(r["setting"].split()[-1]))
            res.ref_check["fmu"] = dict(setting=best["setting"], pos_abs=best["pos_abs"], fn_abs=best["fn_abs"],
                                        pos_rel=best["pos_rel"], fn_rel=best["fn_rel"])
    else:
        log(f"  no FMU at {path}: FMU runs skipped (build it with `python -m cedra build {name}`)")

    def peer(run):
        e = py_err(run)
        if not run.ok:
            e = e | dict(pos_abs=np.inf, fn_abs=np.inf, pos_rel=np.inf, fn_rel=np.inf)
        res.rows.append(_row(run, OUT_DT, e))
        log(f"  {run.method:12s} {run.setting:12s}: {run.wall:7.2f} s, rhs evals {run.rhs_evals}, "
            f"pos err {e['pos_abs']:.2e} m, Fn err {e['fn_abs']:.2e} N" + ("" if run.ok else f" [{run.message}]"))

    for plugin in ("cvodes", "idas"):
        for tol in cfg.sundials_tols:
            peer(run_casadi(prob, sched, x0, tg, plugin, tol))
    for method in ("Radau", "BDF", "LSODA"):
        for rtol in cfg.implicit_rtols:
            peer(run_scipy(prob, sched, x0, tg, method, rtol))
    for method in ("RK45", "DOP853"):
        for rtol in cfg.explicit_rtols:
            peer(run_scipy(prob, sched, x0, tg, method, rtol))
    return res


# ------------------------------------------------------------------ analysis
def cost_at(rows, method, level, key="pos_abs"):
    """Least wall time among the method's runs (at the sweep's communication step for FMU runs) whose error
    is <= level; None if none reaches it."""
    ws = [r["wall"] for r in rows if r["method"] == method and r["ok"] and r[key] <= level
          and (not method.startswith("FMU") or r["comm"] == FMU_COMM)]
    return min(ws) if ws else None


def speedups(res: SceneResult, levels=LEVELS):
    methods = list(dict.fromkeys(r["method"] for r in res.rows))
    fmus = [m for m in methods if m.startswith("FMU")]
    peers = [m for m in methods if not m.startswith("FMU") and m != BASELINE_LABEL]
    table = []
    for lev in levels:
        fbest = [(cost_at(res.rows, m, lev), m) for m in fmus]
        fbest = [x for x in fbest if x[0] is not None]
        pbest = [(cost_at(res.rows, m, lev), m) for m in peers]
        pbest = [x for x in pbest if x[0] is not None]
        f = min(fbest) if fbest else None
        p = min(pbest) if pbest else None
        rodas = cost_at(res.rows, "FMU rodas4", lev)
        base = cost_at(res.rows, BASELINE_LABEL, lev)
        table.append(dict(level=lev, fmu=f, peer=p, per_peer={m: cost_at(res.rows, m, lev) for m in peers},
                          ratio=(p[0] / f[0]) if (f and p) else None, rodas4=rodas, baseline=base))
    return table


# ------------------------------------------------------------------ output
HEADER = ["method", "setting", "comm step [s]", "ok", "wall [s]", "steps", "rejected", "rhs evals",
          "pos err [m]", "pos err rel", "Fn err [N]", "Fn err rel"]


def plot(res: SceneResult, out: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    methods = list(dict.fromkeys(r["method"] for r in res.rows))
    for ax, key, lab in ((axes[0], "pos_abs", "max body-position error [m]"),
                         (axes[1], "fn_abs", "max normal-force error [N]")):
        for m in methods:
            pts = sorted((r["wall"], r[key]) for r in res.rows if r["method"] == m and r["ok"]
                         and np.isfinite(r[key]) and r[key] > 0
                         and (not m.startswith("FMU") or r["comm"] == FMU_COMM))
            if pts:
                w, e = zip(*pts)
                ax.loglog(w, e, "o-" if m.startswith("FMU") else "s--", label=m, lw=2 if m.startswith("FMU") else 1)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{res.name}: error against wall time over {res.t_end:g} s simulated "
                 f"(FMU: communication step {FMU_COMM:g} s)")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def write(results, out_dir: Path, command: str, wall_total: float, load_at_start: float = float("nan")):
    out_dir.mkdir(parents=True, exist_ok=True)
    md = ["# Work-precision report", "",
          provenance(command, wall_total, load_at_start) + " Every figure below is measured in that run.",
          "",
          "Each scene is integrated from the same settled start state (computed in Python: `cedra_guess` then Newton "
          "on `cedra_settle` to 1e-12; the FMU gets every coordinate as `start.<q>` with `start.settle = false`) with "
          f"the same torque/steering schedule, piecewise constant with changes only at multiples of {SAMPLE:g} s "
          "(so every communication step sees the same inputs; every method restarts at each change).",
          "",
          f"**Reference**: CasADi cvodes (BDF, Newton, exact Jacobian by AD) on the same CasADi functions, "
          f"rtol = atol = {REF_TOL:g}, outputs every {OUT_DT:g} s. Its convergence is checked by an independent "
          "integration (CasADi idas at the same tolerance) and against the FMU's tightest rodas4 run.",
          "",
          "Columns: **wall** = wall-clock time of the whole run as a user sees it (FMU: instantiate, initialize, all "
          "doStep calls through FMPy; peers: the Python calls). **steps**, **rejected**, **rhs evals**: the FMU's "
          "`solver.steps`, `solver.rejected`, `solver.rhs_evals` at the end; for peers, the integrator's own "
          "counters (scipy gives no step count: `-`). **pos err** = max over time of |r - r_ref| (body mass center, "
          "Euclidean, m), **pos err rel** = that / max over time |r_ref|; **Fn err** = max over time and wheels of "
          "|Fn - Fn_ref| (N), **Fn err rel** = that / max over time and wheels of Fn_ref. Errors are taken at the "
          f"run's communication points that lie on the reference's {OUT_DT:g} s grid. A run that stopped early has "
          "error inf and its FMU status/message in the last column. The FMU's adaptive solvers use the scene's "
          "`solver.h_max` = 0.01 s; `rk4` runs use `solver.h_max` as the fixed step. tol = rtol = atol for every "
          "adaptive method (FMU, scipy and SUNDIALS alike); the scipy implicit methods get the exact Jacobian.",
          ""]
    summary = []
    for res in results:
        md += [f"## {res.name} ({res.t_end:g} s simulated)", ""]
        md += [f"Reference: {res.ref.wall:.1f} s wall, {res.ref.steps} steps, {res.ref.rhs_evals} rhs evals."]
        if "idas" in res.ref_check:
            c = res.ref_check["idas"]
            md.append(f"idas at {REF_TOL:g} against the reference: position {fmt(c['pos_abs'])} m, "
                      f"normal force {fmt(c['fn_abs'])} N.")
        if "fmu" in res.ref_check:
            c = res.ref_check["fmu"]
            md.append(f"The FMU's tightest rodas4 run ({c['setting']}) against the reference: position "
                      f"{fmt(c['pos_abs'])} m ({fmt(c['pos_rel'])} relative), normal force {fmt(c['fn_abs'])} N "
                      f"({fmt(c['fn_rel'])} relative).")
        if not res.fmu_available:
            md.append("**The FMU was not found: FMU rows are missing.**")
        md.append("")
        rows = []
        for r in res.rows:
            rows.append([r["method"], r["setting"], fmt(r["comm"]), fmt(bool(r["ok"])), fmt(r["wall"]),
                         fmt(int(r["steps"])), fmt(int(r.get("rejected", -1))), fmt(int(r["evals"])),
                         fmt(r["pos_abs"]), fmt(r["pos_rel"]), fmt(r["fn_abs"]), fmt(r["fn_rel"])]
                        + ([f"{r['status']}: {r['message']}"] if not r["ok"] else [""]))
        md += [md_table(HEADER + ["why it stopped"], rows), ""]
        png = f"precision_{res.name}.png"
        plot(res, out_dir / png)
        md += [f"![error against wall time]({png})", ""]
        sp = speedups(res)
        md += ["Speed-up at equal error: for each position-error level, the least wall time of any FMU run "
               f"(communication step {FMU_COMM:g} s) and of any peer run reaching it; ratio = peer / FMU.", ""]
        srows = []
        for s in sp:
            f, p = s["fmu"], s["peer"]
            srows.append([fmt(s["level"]), f"{f[1]} {fmt(f[0])} s" if f else "not reached",
                          f"{p[1]} {fmt(p[0])} s" if p else "not reached", fmt(s["ratio"])]
                         + [fmt(v) for v in s["per_peer"].values()])
        peers = list(sp[0]["per_peer"].keys()) if sp else []
        md += [md_table(["pos err <= [m]", "fastest FMU", "fastest peer", "peer / FMU"]
                        + [f"{p} [s]" for p in peers], srows), ""]
        with open(out_dir / f"precision_{res.name}.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            keys = ["method", "setting", "comm", "ok", "wall", "steps", "rejected", "evals", "pos_abs", "pos_rel",
                    "fn_abs", "fn_rel", "status", "message"]
            w.writerow(keys)
            for r in res.rows:
                w.writerow([r.get(k, "") for k in keys])
        base = [s for s in sp if s.get("baseline") is not None or s.get("rodas4") is not None]
        if any(r["method"] == BASELINE_LABEL for r in res.rows):
            md += [f"Switch location and the reduced stage solve: least wall time of FMU rodas4 and of "
                   f"`{BASELINE_LABEL}` (the same FMU sources built with {' '.join(BASELINE_FLAGS)}: no switch "
                   "location, the dense 2n+1 stage solve) reaching each position error.", ""]
            md += [md_table(["pos err <= [m]", "FMU rodas4 [s]", f"{BASELINE_LABEL} [s]", "baseline / FMU"],
                            [[fmt(s["level"]), fmt(s["rodas4"]), fmt(s["baseline"]),
                              fmt(s["baseline"] / s["rodas4"]) if s["rodas4"] and s["baseline"] else "-"]
                             for s in base]), ""]
            pairs = [s for s in base if s["rodas4"] and s["baseline"]]
            summary.append(f"{res.name}: FMU rodas4 vs {BASELINE_LABEL}: " + (", ".join(
                f"x{s['baseline'] / s['rodas4']:.2f} at {s['level']:g} m" for s in pairs) or "no common level"))
        ratios = [s for s in sp if s["ratio"] is not None]
        if ratios:
            summary.append(f"{res.name}: FMU faster than the fastest peer by " + ", ".join(
                f"x{s['ratio']:.1f} at {s['level']:g} m ({s['fmu'][1]} vs {s['peer'][1]})" for s in ratios))
        elif not res.fmu_available:
            summary.append(f"{res.name}: no FMU, peers only")
        if "fmu" in res.ref_check:
            c = res.ref_check["fmu"]
            summary.append(f"{res.name}: reference vs FMU rodas4 {c['setting']}: {c['pos_abs']:.1e} m, "
                           f"{c['fn_abs']:.1e} N")
    md += ["## Summary", ""] + [f"- {s}" for s in summary] + [""]
    (out_dir / "precision.md").write_text("\n".join(md))
    return summary


def main(args):
    cfg = QUICK if getattr(args, "quick", False) else FULL
    out = Path(getattr(args, "out", "out/report"))
    build = getattr(args, "build", "build")
    t0, load0 = time.perf_counter(), load_average()
    only = getattr(args, "scene", None)
    unknown = set(only or []) - set(cfg.scenes)
    if unknown:
        print(f"error: not a scene of the report: {sorted(unknown)} (it has {list(cfg.scenes)})", file=sys.stderr)
        return 2
    quiet = getattr(args, "quiet", False)
    names = [name for name in cfg.scenes if not only or name in only]
    minutes = {"bump2d": 4, "flat3d": 2, "step2d": 11, "bump3d": 15}
    announce("report precision", "a few seconds" if cfg is QUICK else
             f"about {sum(minutes.get(n, 10) for n in names)} minutes on two cores "
             "(--quick: a small subset in seconds; --scene NAME: one scene)", quiet)
    progress = Progress(len(names), "report precision", unit="scenes", quiet=quiet, after=0.0)
    results = []
    for name in names:                      # per-run lines on stdout, the bar on stderr; --quiet: neither
        results.append(run_scene(name, cfg, build, log=(lambda *a, **k: None) if quiet else print))
        progress(len(results), f"{name} done")
    progress.done()
    cmd = "python -m cedra report precision" + (" --quick" if cfg is QUICK else "") + \
        "".join(f" --scene {n}" for n in only or [])
    summary = write(results, out, cmd, time.perf_counter() - t0, load0)
    print(f"wrote {out / 'precision.md'}")
    for s in summary:
        print(s)
    return 0 if all(r.fmu_available for r in results) else 1


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="out/report")
    sys.exit(main(ap.parse_args()))
