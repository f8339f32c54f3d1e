"""Command line: python -m cedra build|simulate|compare|bench|report|check|fuzz|sweep|watch|optimize ..."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from cedra.contract import SOLVER_METHODS


def _build_one(name: str, out: str, jobs: int) -> dict:
    """Generate, compile and package one scene (shipped name or .toml) or drive controller, in a worker process:
    what the build report shows of it (cedra.fmu.build_report)."""
    from cedra.fmu.compiler import CompileStats
    from cedra.fmu.packaging import build_fmu, fmu_state, resolve_target, write_stamp
    t0 = time.perf_counter()
    fmu, what, form = resolve_target(name)
    path, key, _ = fmu_state(what, out)
    spec = form()
    dict(spec.functions)                # the model's CasADi functions formed here, so "model" is what it costs
    t1 = time.perf_counter()
    stats = CompileStats()
    path = build_fmu(spec, Path(out), jobs=jobs, stats=stats)
    write_stamp(path, key)
    gen = sum(p.stat().st_size for p in (Path(out) / fmu / "sources").glob("cedra_*.c"))
    return dict(fmu=fmu, path=str(path), state="built", model_s=t1 - t0, code_s=time.perf_counter() - t1,
                compiled=len(stats.compiled), cached=len(stats.cached), compile_cpu_s=sum(stats.seconds.values()),
                generated_bytes=gen)


def cmd_build(args):
    import os
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from cedra.fmu import build_report
    from cedra.fmu.packaging import fmu_state
    from cedra.models.controller import CONTROLLERS
    from cedra.models.scene import SceneError, load, load_shipped, shipped
    t_start = time.perf_counter()
    names = list(dict.fromkeys(args.scenes or shipped() + list(CONTROLLERS)))
    dims, fmu_names = {}, {}
    for name in names:              # every scene file is checked before any code is generated
        if name in CONTROLLERS:
            fmu_names[name] = name
            continue
        try:
            scene = load(name) if name.endswith(".toml") else load_shipped(name)
        except SceneError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        dims[name] = scene.options.dims
        if scene.name in fmu_names.values():      # two processes would build into the same directory
            other = next(n for n, f in fmu_names.items() if f == scene.name)
            print(f"error: {name} and {other} both build the FMU {scene.name!r}", file=sys.stderr)
            return 2
        fmu_names[name] = scene.name
    rows, todo = [], []
    for name in names:              # an FMU whose stamp matches today's sources and scene is kept as it is
        path, _, state = fmu_state(name, args.out)
        if state == "up to date" and not args.force:
            rows.append(dict(fmu=fmu_names[name], path=str(path), state="up to date"))
            print(f"{fmu_names[name]}: up to date ({path})", flush=True)
        else:
            todo.append(name)
    # The scenes build in parallel (one process each, each compiling its files on the cores left to it): the 3D
    # ones first, so that the short ones fill in behind them.
    order = sorted(todo, key=lambda n: dims.get(n) != "3d")
    cores = os.cpu_count() or 1
    procs = max(1, min(args.jobs or cores, len(order) or 1))
    threads = max(1, cores // procs)
    if order:
        with ProcessPoolExecutor(max_workers=procs) as pool:
            futures = [pool.submit(_build_one, name, args.out, threads) for name in order]
            for f in as_completed(futures):          # a progress line per FMU as it is done
                r = f.result()
                rows.append(r)
                print(f"{r['fmu']}: {r['path']} (model {r['model_s']:.1f} s, C code and compile {r['code_s']:.1f} s: "
                      f"{r['compiled']} files compiled, {r['cached']} from the cache)", flush=True)
    if not args.scenes:
        from cedra.run.ssp import SYSTEMS, build_system
        for name in SYSTEMS:
            print(f"{name}: {build_system(name, Path(args.out))} (SSP: plant + drive controller)")
    page = build_report.write(Path(args.out), rows, time.perf_counter() - t_start, procs, threads,
                              " ".join(["python -m cedra build", *sys.argv[2:]]))
    print(f"build report: {page}")
    return 0


def cmd_simulate(args):
    from cedra.run import scenario, simulate
    if args.list:
        print(f"{scenario.MAIN_JOB:18s} the main job: the paper's bump run (cedra.run.simulate)")
        for name, line in scenario.scenarios().items():
            print(f"{name:18s} {line}")
        return 0
    if args.scene == scenario.MAIN_JOB:
        from cedra.fmu.packaging import ensure_fmu
        return simulate.main(ensure_fmu("bump2d", args.build), Path(args.out) / "bump2d", args.stop_time or 15.0,
                             video=not args.no_video)
    try:
        mod = scenario.load(args.scene)
        mod.run(out_dir=str(Path(args.out) / args.scene), build_dir=args.build, stop_time=args.stop_time,
                quiet=args.quiet, watch=not args.no_video)
    except scenario.ScenarioError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def cmd_compare(args):
    from cedra.run import compare
    return compare.main(args.build, args.out, args.stop_time)


def cmd_bench(args):
    from cedra.reports import bench
    return bench.main(args)


def cmd_report(args):
    if args.which == "precision":
        from cedra.reports import precision as r
    elif args.which == "defaults":
        from cedra.reports import defaults as r
    elif args.which == "figures":
        from cedra.reports import figures as r
    elif args.which == "rovers":
        from cedra.reports import rovers as r
    else:
        from cedra.reports import stability as r
    return r.main(args)


def cmd_watch(args):
    from cedra.run import watch
    return watch.main(args)


def cmd_sweep(args):
    from cedra import sweep
    return sweep.main(args)


def cmd_optimize(args):
    from cedra.optimize import command
    return command.main(args)


def cmd_check(args):
    from cedra.fmu import compliance
    return compliance.main(args)


def cmd_fuzz(args):
    from cedra.fmu import fuzz
    return fuzz.main(args)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m cedra")
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="generate, compile and package FMUs (default: every shipped scene and the "
                       "drive controllers drive2d, drive3d, rb_drive2d, rb_drive3d)")
    b.add_argument("scenes", nargs="*", help="shipped scene names, .toml files, or drive controllers "
                   "(drive2d, drive3d, rb_drive2d, rb_drive3d)")
    b.add_argument("--out", default="build")
    b.add_argument("--jobs", type=int, default=0, help="scenes built at once (default: one per CPU core)")
    b.add_argument("--force", action="store_true", help="build even the FMUs whose stamp says they are up to date "
                   "(their objects still come from the object cache where it holds them)")
    s = sub.add_parser("simulate", help="run the main job (bump2d: the paper's bump run) or a scenario script")
    s.add_argument("scene", nargs="?", default="bump2d", help="bump2d or a scenario in examples/ (see --list)")
    s.add_argument("--list", action="store_true", help="list the scenarios")
    s.add_argument("--build", default="build")
    s.add_argument("--out", default="out")
    s.add_argument("--stop-time", type=float, default=None, help="s (default: the scenario's own)")
    s.add_argument("--quiet", action="store_true", help="no progress, no summary")
    s.add_argument("--no-video", action="store_true",
                   help="no animation.gif / view.html (cedra.run.watch), only the CSV and plots")
    c = sub.add_parser("compare", help="compliant vs rigid contact on the bump (same torques)")
    c.add_argument("--build", default="build")
    c.add_argument("--out", default="out/compare")
    c.add_argument("--stop-time", type=float, default=15.0)
    be = sub.add_parser("bench", help="benchmark the shipped FMUs (prints figures)")
    be.add_argument("--build", default="build")
    be.add_argument("--quiet", action="store_true", help="no progress lines (the figures only)")
    be.add_argument("--stop-time", type=float, default=None,
                    help="simulated seconds (default: 10 per scene; --steps: 25; the side by side: 15)")
    be.add_argument("--quick", action="store_true",
                    help="only the MuJoCo side-by-side table, 1 s runs (what the tests run)")
    be.add_argument("--side-by-side", action="store_true",
                    help="only the MuJoCo side-by-side table (the paper's 15 s run)")
    be.add_argument("--steps", action="store_true",
                    help="only MuJoCo on the step and the stairs (boxes): CPU, verdicts, unpaid energy gains")
    be.add_argument("--controller", action="store_true",
                    help="only the drive controller's cost per sample over the bump run, each mode (worst sample)")
    be.add_argument("--step-cost", action="store_true",
                    help="only the cost of one implicit step: rodas4 dense against reduced (Schur) stage solve, "
                         "ros34pw2")
    r = sub.add_parser("report", help="work-precision, stability, defaults, rovers (CEDRA against the rocker-bogie) "
                       "report, or the docs' other figures")
    r.add_argument("which", choices=["precision", "stability", "defaults", "figures", "rovers"])
    r.add_argument("--build", default="build")
    r.add_argument("--out", default="out/report")
    r.add_argument("--quick", action="store_true", help="a small subset (what the tests run)")
    r.add_argument("--quiet", action="store_true", help="no per-run lines, no progress (the report and summary only)")
    r.add_argument("--scene", action="append", default=None,
                   help="precision, defaults: only this scene of the report (repeatable)")
    r.add_argument("--tol", type=float, help="defaults: compare rodas4 (or --method) at this tolerance instead of the "
                                            "scene's defaults")
    r.add_argument("--method", choices=list(SOLVER_METHODS),
                   help="defaults: compare this solver (at the scene's tolerance, or --tol) instead of the defaults")
    r.add_argument("--h-max", type=float, help="defaults: with this solver.h_max (rk4's and moreau's fixed step)")
    r.add_argument("--choose", action="store_true",
                   help="defaults: try every candidate setting and name the cheapest that keeps the guarantee")
    r.add_argument("--record", action="store_true",
                   help="defaults --choose: write the choice into the shipped scene files' [solver] tables")
    r.add_argument("--figure", action="append", default=None,
                   help="figures: only this figure (repeatable; cedra.reports.figures lists them)")
    ch = sub.add_parser("check", help="the FMU compliance checkers (fmpy validate, VDMCheck2, the start value round "
                        "trip through the binary, a short libcosim run against FMPy) on any FMI 2.0 Co-Simulation "
                        "FMUs: one verdict line per FMU and checker; exit status 1 on any error or warning")
    from cedra.fmu.compliance import add_arguments as add_check_arguments
    add_check_arguments(ch)
    from cedra.fmu.fuzz import add_parser as add_fuzz_parser
    from cedra.optimize.command import add_parser as add_optimize_parser
    from cedra.sweep import add_parser as add_sweep_parser
    from cedra.run.watch import add_parser as add_watch_parser
    add_fuzz_parser(sub)
    add_optimize_parser(sub)
    add_sweep_parser(sub)
    add_watch_parser(sub)
    args = ap.parse_args(argv)
    commands = {"build": cmd_build, "simulate": cmd_simulate, "compare": cmd_compare, "bench": cmd_bench,
                "report": cmd_report, "check": cmd_check, "fuzz": cmd_fuzz, "sweep": cmd_sweep, "watch": cmd_watch,
                "optimize": cmd_optimize}
    return commands[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
