"""`python -m cedra sweep <sweep.toml> [--scheduler tcp://host:port] [--workers N] [--resume | --overwrite]
[--quiet] [--check-tol TOL | --check-h H]`: the sweep file read and checked, its runs (and those of the tightened
check) executed, the map drawn and its report written (cedra.sweep).
"""
from __future__ import annotations

import time

from cedra.sweep.definition import CHECKS, SweepError, load, resolve, tightened
from cedra.sweep.client import execute, read_table
from cedra.sweep.maps import draw


def add_parser(sub):
    p = sub.add_parser("sweep", help="run a sweep file on Dask (local cluster by default)")
    p.add_argument("file", help="a sweep .toml, or a shipped sweep in examples/sweeps/ (climb, climb_rigid)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786 "
                   "(default: a local cluster)")
    p.add_argument("--workers", type=int, help="local cluster: worker processes (default: one per core)")
    p.add_argument("--build", default="build")
    p.add_argument("--resume", action="store_true", help="run only the runs missing from the table")
    p.add_argument("--overwrite", action="store_true", help="start the table again")
    p.add_argument("--quiet", action="store_true", help="no progress")
    check = p.add_mutually_exclusive_group()
    check.add_argument("--check-tol", type=float, metavar="TOL",
                       help="run every run again at solver.tol = TOL; the map's report says whether every verdict is "
                       "the same (e.g. 1e-9)")
    check.add_argument("--check-h", type=float, metavar="H",
                       help="for scenes stepped by Moreau-Jean (rigid contact): run every run again at solver.h_max = "
                       "H; the map's report says whether every verdict is the same (e.g. a quarter of the scene's)")


def command(args) -> str:
    """The command line of these arguments, for the report."""
    words = ["python -m cedra sweep", args.file]
    for flag in ("scheduler", "workers", "check_tol", "check_h"):
        if getattr(args, flag, None) is not None:
            words.append(f"--{flag.replace('_', '-')} {getattr(args, flag)}")
    if args.build != "build":
        words.append(f"--build {args.build}")
    words += [f"--{flag}" for flag in ("resume", "overwrite", "quiet") if getattr(args, flag)]
    return " ".join(words)


def main(args) -> int:
    import sys
    from cedra.pages import load_average
    from cedra.sweep import report
    load_at_start = load_average()
    check_h = getattr(args, "check_h", None)         # argparse makes --check-tol and --check-h exclusive
    flag, check = ("--check-h", check_h) if check_h is not None else ("--check-tol", getattr(args, "check_tol", None))
    try:
        sw = load(resolve(args.file))
        if args.workers is not None and args.workers < 1:
            raise SweepError(f"--workers: expected >= 1, got {args.workers}")
        tight = tightened(sw, check, flag) if check is not None else None
        if tight is not None and not sw.map:
            raise SweepError(f"{sw.path}: {flag}: the sweep has no [map], whose report it goes into")
        t0 = t_all = time.perf_counter()
        sweeps = [sw] + ([tight] if tight else [])
        for s in sweeps:
            c = execute(s, args.build, args.scheduler, args.workers, args.resume, args.overwrite, args.quiet)
            wall = time.perf_counter() - t0
            rate = f", {60 * c['ran'] / wall:.1f} runs/min" if c["ran"] else ""
            print(f"sweep {s.name}: {c['total']} runs, {c['skipped']} already in the table, {c['ran']} run "
                  f"({c['failed']} failed) in {wall:.1f} s{rate}; table {s.table}")
            t0 = time.perf_counter()
    except SweepError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if sw.map:
        rows = read_table(sw.table)
        print(f"map {draw(sw, rows)}")
        checked = (CHECKS[flag][0], check, tight, read_table(tight.table)) if tight else None
        elapsed = time.perf_counter() - t_all
        print(f"report {report.write(sw, rows, command(args), elapsed, load_at_start, checked)}")
    return 0
