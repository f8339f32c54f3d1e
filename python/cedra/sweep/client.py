"""A sweep on Dask (on the client): its missing runs submitted to a local or an existing cluster, each result
appended to the table (<out>/<name>.csv) as it arrives, so an interrupted sweep loses nothing.
"""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path

from cedra.sweep.definition import Sweep, SweepError
from cedra.sweep.fmus import sweep_fmu, variant_fmu
from cedra.sweep.worker import run_one, run_scenario


def columns(sw: Sweep) -> list[str]:
    return ["id"] + sw.parameters + sw.outputs + ["status", "reason", "wall_s"]


def read_table(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if v != v else f"{v:.10g}"
    return str(v)


def execute(sw: Sweep, build_dir="build", scheduler: str | None = None, workers: int | None = None,
            resume: bool = False, overwrite: bool = False, quiet: bool = False, on_result=None) -> dict:
    """Run the sweep's missing runs on Dask and append each result to the table as it arrives. Returns counts.
    on_result(k, row), if given, is called in the client after each row is written (the tests use it to kill a
    worker mid-sweep or to interrupt)."""
    from distributed import Client, LocalCluster, as_completed
    from cedra.run.progress import Progress

    table = sw.table
    cols = columns(sw)
    done_rows = read_table(table)
    if done_rows and not (resume or overwrite):
        raise SweepError(f"{table} exists ({len(done_rows)} runs): pass --resume to run only the missing runs or "
                         f"--overwrite to start again")
    if done_rows and resume:
        header = list(done_rows[0].keys())
        if header != cols:
            raise SweepError(f"{table}: its columns are not this sweep's (was the sweep file changed?); "
                             f"use --overwrite")
    if overwrite:
        done_rows = []
    done = {r["id"] for r in done_rows}
    runs = [(sw.run_id(p), p) for p in sw.runs()]
    todo = [(i, p) for i, p in runs if i not in done]
    counts = dict(total=len(runs), skipped=len(runs) - len(todo), ran=0, failed=0)
    if not todo:
        return counts

    fmu_bytes = Path(sweep_fmu(sw, build_dir)).read_bytes() if sw.target.kind == "scene" else None
    table.parent.mkdir(parents=True, exist_ok=True)
    fresh = not done_rows
    fh = open(table, "w" if fresh else "a", newline="")
    writer = csv.writer(fh)
    if fresh:
        writer.writerow(cols)
        fh.flush()
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=":0")   # the HTTP server on a free port: several may run
        client = Client(cluster)
    progress = Progress(len(todo), f"sweep {sw.name}", unit="runs", quiet=quiet, after=0.0)
    try:
        if sw.target.kind == "scene":
            data = client.scatter(fmu_bytes, broadcast=True, hash=False)
            kind, steps = sw.target.scene.options.terrain, sw.target.scene.options.stairs_steps
            futures = {client.submit(run_one, data, kind, p, sw.stop_time, sw.run_timeout, steps, key=f"run-{i}",
                                     pure=False): (i, p) for i, p in todo}
        else:
            from cedra.run.scenario import fmu
            for entry in sw.target.fmus:         # built here, once, not by several workers at a time
                if isinstance(entry, tuple):
                    variant_fmu(*entry, build_dir)
                else:
                    fmu(entry, build_dir)
            build = str(Path(build_dir).resolve())
            futures = {client.submit(run_scenario, sw.target.name, build, p, sw.stop_time, sw.outputs,
                                     key=f"run-{i}", pure=False): (i, p) for i, p in todo}
        for fut in as_completed(futures):
            i, p = futures[fut]
            try:
                r = fut.result()
            except Exception as e:       # the worker died running it (KilledWorker) or the task could not run
                r = {o: math.nan for o in sw.outputs}
                r.update(verdict="failed", status="failed", reason=f"{type(e).__name__}: {e}"[:300], wall_s=math.nan)
            row = {"id": i, **p, **r}
            writer.writerow([_fmt(row.get(c, "")) for c in cols])
            fh.flush()
            counts["ran"] += 1
            counts["failed"] += row["status"] != "ok"
            progress(counts["ran"], f"{counts['failed']} failed")
            if on_result:
                on_result(counts["ran"], row)
    finally:
        progress.done()
        fh.close()
        client.close()
        if cluster is not None:
            cluster.close()
    return counts
