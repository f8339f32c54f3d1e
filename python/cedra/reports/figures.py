"""The documentation's figures that no other report prints, each measured by one function here:

    python -m cedra report figures [--figure NAME ...] [--build build] [--out out/report] [--quiet]

Each figure prints its lines and a table; all of them together write <out>/figures.md with the command, the date,
the code's version, the CPU and the load (`cedra.pages.provenance`). A figure that needs a variant of an
FMU (no switch location, other compiler flags) builds it from this tree's sources under <out>/figures/ with
`cedra.fmu.packaging.build_fmu(..., extra_cflags)`; the rest run the FMUs in <build>.

    NAME        page                 what it measures
    fmpy        docs/fmu.md          FMPy's checked wrappers against FastIO: the cost of the Python glue per sample
    masters     docs/fmu.md          FMPy's SSP simulator against libcosim on the SSP packages, with and without
                                     the command ramp
    location    docs/solvers.md      force-law switch location on and off (-DCEDRA_LOCATE_FN=NULL) on the paper's
                                     run and step2d: steps, rejections, evaluations, how the forces converge
    flags       docs/solvers.md      -fno-math-errno and -O3: CPU of the paper's run and hills3d, compile time,
                                     results bit for bit
    switch      docs/solvers.md      the cost of one cedra_switch and one cedra_f evaluation (step2d, bump3d)
    ros34pw2    docs/solvers.md      bump3d's closed loop: ros34pw2 and rodas4 at tol 1e-6 against tol 1e-9
    rigid       docs/rigid-contact.md  Moreau-Jean's energy balance; the held-mode integration of the rigid run
    compare     docs/rigid-contact.md  `python -m cedra compare`'s runs: what the page reads from compare.csv
    chassis     docs/equations.md    CPU and steps of step2d's and stairs3d's runs (the chassis points gated)
    bench       docs/benchmarks.md   the first two parts of `python -m cedra bench`, the contact search linked in
    mujoco      docs/benchmarks.md   MuJoCo's force spikes on height fields where the ground is flat
    sizes       docs/scenes.md       the generated functions' sizes of every shipped scene, time to derive them
    mass        docs/solvers.md      the mass matrix's Cholesky work in the generator's order against dense

Figures are printed and written, never asserted on. CPU times are time.process_time, the least of REPEAT runs
where a figure says so.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cedra.pages import load_average, md_table, provenance
from cedra.reports.common import FN, SOLVER_CODES, Loop, closed_loop, fmu_path

REPEAT = 3
WIDE_OPEN = {"solver.max_wall_time": 1e3}          # no run stops on the per-call wall-clock budget under load


# ------------------------------------------------------------------ helpers
def least_cpu(path, stop_time, settings=None, n=REPEAT) -> tuple[Loop, list[float]]:
    runs = [closed_loop(path, stop_time, WIDE_OPEN | dict(settings or {})) for _ in range(n)]
    return min(runs, key=lambda r: r.cpu), [r.cpu for r in runs]


def variant(scene_name: str, out: Path, tag: str, cflags=()) -> tuple[Path, float]:
    """Build a shipped scene's FMU with extra C flags into out/<tag>/; (path, seconds for C code and compile)."""
    from cedra.fmu.packaging import build_fmu
    from cedra.models.scene import load_shipped
    spec = load_shipped(scene_name).spec()
    t0 = time.perf_counter()
    path = build_fmu(spec, out / tag, extra_cflags=tuple(cflags))
    return path, time.perf_counter() - t0


def e(v):
    return f"{v:.2g}" if v != 0 else "0"


def end_of(r: Loop) -> str:
    return "finished" if r.ok else f"stops at t = {r.t_end + 0.01:.2f} s: {r.message.split('terminated: ')[-1]}"


# ------------------------------------------------------------------ docs/fmu.md
def fig_fmpy(ctx) -> str:
    """The Python glue of one 0.01 s sample: FMPy's checked wrappers (FMU2Slave.getReal / setReal, which build the
    argument arrays on every call) against FastIO (the same fmi2 calls through ctypes with buffers made once),
    reading body.x, body.vx and the six wheel[i].Fn and setting the six torques, timed without stepping on a settled
    flat3d; and what a whole sample (FastIO's calls and the doStep) of flat3d's 15 s run at its defaults costs."""
    from cedra.run.driver import FastIO, RoverFMU
    path = fmu_path(ctx.build, "flat3d")
    read = ["body.x", "body.vx"] + FN
    write = [f"tau[{i}]" for i in range(1, 7)]
    calls, samples = 20000, 1500
    f = RoverFMU(path)
    f.start(dict(WIDE_OPEN))
    io = FastIO(f, read, write)
    rvr = [f.vars[v].valueReference for v in read]
    wvr = [f.vars[v].valueReference for v in write]

    def glue(fast: bool) -> float:
        cpu = time.process_time()
        for _ in range(calls):
            if fast:
                io.read()
                io.write([0.5] * 6)
            else:
                f.fmu.getReal(rvr)
                f.fmu.setReal(wvr, [0.5] * 6)
        return (time.process_time() - cpu) / calls

    fmpy = min(glue(False) for _ in range(REPEAT))
    fast = min(glue(True) for _ in range(REPEAT))
    f.close()

    def sample() -> float:
        g = RoverFMU(path)
        g.start(dict(WIDE_OPEN))
        gio = FastIO(g, read, write)
        cpu = time.process_time()
        for k in range(samples):
            gio.read()
            gio.write([0.5] * 6)
            gio.step((k + 1) * 0.01)
        cpu = time.process_time() - cpu
        g.close()
        return cpu / samples

    whole = min(sample() for _ in range(REPEAT))
    rows = [["FMPy FMU2Slave getReal (8) + setReal (6)", f"{fmpy * 1e6:.1f}"],
            ["FastIO read + write (ctypes, buffers made once)", f"{fast * 1e6:.1f}"],
            ["a whole flat3d sample through FastIO (read, write, doStep; 15 s at 0.5 N.m)", f"{whole * 1e6:.1f}"]]
    ctx.log(f"fmpy: FMPy's getReal + setReal {fmpy * 1e6:.1f} us, FastIO's {fast * 1e6:.1f} us, a flat3d sample "
            f"{whole * 1e6:.1f} us")
    return (f"CPU per sample, the least of {REPEAT} loops each ({calls} calls without stepping; {samples} samples "
            "of the run).\n\n" + md_table(["calls", "CPU per sample (us)"], rows))


def fig_masters(ctx) -> str:
    """FMPy's SSP simulator against libcosim on the two SSP systems (4 s, step 0.01 s): the largest distance between
    the body's paths, as shipped (1 s command ramp) and with ctrl.ramp_time = 0."""
    import tempfile
    from cedra.run import scenario, ssp
    stop, step = 4.0, 0.01
    rows = []
    with tempfile.TemporaryDirectory(prefix="cedra-figures-") as tmp:
        for system, (plant, ctrl, pv, cv) in ssp.SYSTEMS.items():
            for ramp in (cv.get("ctrl.ramp_time", 0.0), 0.0):
                values = dict(cv) | {"ctrl.ramp_time": ramp}
                path = ssp.write_ssp(Path(tmp) / f"{system}_{ramp:g}.ssp", scenario.fmu(plant, ctx.build),
                                     scenario.fmu(ctrl, ctx.build), pv, values, stop_time=stop)
                a, b = ssp.run_fmpy(path, stop, step), ssp.run_libcosim(path, stop, step)
                n = min(len(a["plant.body.x"]), len(b["plant.body.x"]))
                pa = np.c_[a["plant.body.x"][:n], a.get("plant.body.y", np.zeros(n))[:n]]
                pb = np.c_[b["plant.body.x"][:n], b.get("plant.body.y", np.zeros(n))[:n]]
                d = _path_distance(pa, pb)
                rows.append([system, f"{ramp:g} s", f"{d:.2g}"])
                ctx.log(f"masters: {system}, ramp {ramp:g} s: body paths within {d:.2g} m")
    return (f"Each SSP package ({stop:g} s, step {step:g} s) in FMPy's SSP simulator and in libcosim; the largest "
            "distance from a point of one body path (x, y) to the other path, both ways.\n\n"
            + md_table(["system", "ctrl.ramp_time", "paths within (m)"], rows))


def _path_distance(p, q):
    def one_way(a, b):
        d = np.full(len(a), np.inf)
        for i in range(len(b) - 1):
            s = b[i + 1] - b[i]
            ss = s @ s
            t = np.clip(((a - b[i]) @ s) / ss, 0, 1) if ss > 0 else np.zeros(len(a))
            d = np.minimum(d, np.linalg.norm(a - (b[i] + t[:, None] * s), axis=1))
        return d.max()
    return max(one_way(p, q), one_way(q, p))


# ------------------------------------------------------------------ docs/solvers.md
NO_LOCATION = ("-DCEDRA_LOCATE_FN=NULL",)
COMPARE_UNTIL = 8.0     # s: step2d's rover is stuck at the step by then, and its rocking there parts any two runs


def _force_diff(a: Loop, b: Loop, t_max: float = math.inf) -> dict:
    """a against b (the tighter run) at their common samples up to t_max: max |dFn| (N), relative to the sample's
    force with 1 N and 10 N floors, max |d body.x|, b's peak Fn; over the whole run, the first sample where body.x
    differs by more than 0.1 mm (parts, nan: never)."""
    n = min(len(a.t), len(b.t))
    dx_all = np.abs(a.col("body.x")[:n] - b.col("body.x")[:n])
    far = np.nonzero(dx_all > 1e-4)[0]
    n_cmp = int(np.sum(a.t[:n] <= t_max + 1e-9))
    fa, fb = a.fn[:n_cmp], b.fn[:n_cmp]
    d = np.abs(fa - fb)
    return dict(dF=float(d.max()), rel1=float((d / np.maximum(np.abs(fb), 1.0)).max()),
                rel10=float((d / np.maximum(np.abs(fb), 10.0)).max()), peak=float(fb.max()),
                dx=float(dx_all[:n_cmp].max()), parts=float(a.t[far[0]]) if len(far) else math.nan)


def fig_location(ctx) -> str:
    """The paper's run (15 s, the main job's controller, rodas4) on bump2d and step2d with switch location (the
    shipped sources) and without (-DCEDRA_LOCATE_FN=NULL, built here)."""
    out = ctx.out / "figures"
    fmus = {}
    for scene in ("bump2d", "step2d"):
        fmus[(scene, True)] = fmu_path(ctx.build, scene)
        fmus[(scene, False)], _ = variant(scene, out, "no_location", NO_LOCATION)
    runs = {}
    plan = [("bump2d", 1e-6), ("bump2d", 1e-10), ("step2d", 1e-6), ("step2d", 1e-8), ("step2d", 1e-9),
            ("step2d", 1e-10)]
    for scene, tol in plan:
        for located in (True, False):
            r = closed_loop(fmus[(scene, located)], 15.0, WIDE_OPEN | {"solver.tol": tol})
            runs[(scene, tol, located)] = r
            c = r.counters
            ctx.log(f"location: {scene} tol {tol:g} {'located' if located else 'not located'}: {c['steps']} steps "
                    f"({c['rejected']} rejected), {c['rhs_evals']} rhs evals, CPU {r.cpu:.2f} s, {end_of(r)}")

    def cell(r: Loop):
        c = r.counters
        pct = f" = {100 * c['rejected'] / c['steps']:.1f} %" if c["steps"] else ""
        s = f"{c['steps']} ({c['rejected']}{pct}), {c['rhs_evals']}, {r.cpu:.2f} s"
        return s if r.ok else f"{end_of(r)} [{s}]"

    rows = [[f"{scene} tol {tol:g}", cell(runs[(scene, tol, True)]), cell(runs[(scene, tol, False)])]
            for scene, tol in plan]
    text = ("The paper's run, 15 s, the main job's controller, rodas4 at the scene's h_max; steps (rejected), rhs "
            "evaluations, CPU; a run that stops gives its time and the FMU's message.\n\n"
            + md_table(["run", "with switch location", "without (-DCEDRA_LOCATE_FN=NULL)"], rows))
    lines = []
    step = [(f"step2d located, tol {tol:g} against tol 1e-10", runs[("step2d", tol, True)],
             runs[("step2d", 1e-10, True)]) for tol in (1e-6, 1e-8, 1e-9)]
    pairs = step + [("step2d not located, tol 1e-6 against tol 1e-8", runs[("step2d", 1e-6, False)],
                     runs[("step2d", 1e-8, False)]),
                    ("bump2d located against not located, both tol 1e-6", runs[("bump2d", 1e-6, True)],
                     runs[("bump2d", 1e-6, False)])]
    for label, a, b in pairs:
        if a.ok and b.ok:
            d = _force_diff(a, b, COMPARE_UNTIL)
            lines.append([label, f"{d['dF']:.2g}", f"{100 * d['rel1']:.2g} %", f"{100 * d['rel10']:.2g} %",
                          f"{d['peak']:.1f}", f"{d['dx']:.2g}", f"{d['parts']:.2f}"])
            ctx.log(f"location: {label}: up to {COMPARE_UNTIL:g} s max |dFn| {d['dF']:.2g} N ({100 * d['rel1']:.2g} "
                    f"% with a 1 N floor, {100 * d['rel10']:.2g} % with 10 N), peak {d['peak']:.1f} N, max |dx| "
                    f"{d['dx']:.2g} m; body.x parts by 0.1 mm at t = {d['parts']:.2f} s")
    text += (f"\n\nThe normal forces at every sample up to t = {COMPARE_UNTIL:g} s (largest difference, relative to "
             "the tighter run's force at that sample with a 1 N and a 10 N floor) and body.x; the last column: the "
             "first sample of the whole run where body.x differs by more than 0.1 mm (nan: never).\n\n"
             + md_table(["runs", "max dFn (N)", "rel., 1 N floor", "rel., 10 N floor", "peak Fn (N)",
                         "max d body.x (m)", "parts at t (s)"], lines))
    a, b = runs[("bump2d", 1e-6, True)], runs[("bump2d", 1e-6, False)]
    more = a.counters["rhs_evals"] / b.counters["rhs_evals"] - 1
    xa, xb = np.interp(6.0, a.t, a.col("body.x")), np.interp(6.0, b.t, b.col("body.x"))
    text += (f"\n\nbump2d at tol 1e-6, with location against without: {a.counters['rhs_evals']} against "
             f"{b.counters['rhs_evals']} rhs evaluations ({100 * more:+.1f} %); CPU {a.cpu:.3f} s against "
             f"{b.cpu:.3f} s (single runs); peak Fn {a.fn.max():.2f} N against {b.fn.max():.2f} N; body.x at 6 s "
             f"{xa:.6f} m against {xb:.6f} m.")
    ctx.log(f"location: bump2d tol 1e-6: rhs evals {100 * more:+.1f} % with location; CPU {a.cpu:.3f} vs {b.cpu:.3f} s;"
            f" peak {a.fn.max():.2f} vs {b.fn.max():.2f} N; x(6 s) {xa:.6f} vs {xb:.6f} m")
    return text


FLAG_VARIANTS = {            # tag: (C flags after the shipped ones, what it is)
    "shipped": ((), "as shipped: -O2 -fno-math-errno, the hand-written C at -O3"),
    "math_errno": (("-fmath-errno",), "-fmath-errno"),
    "hand_O2": (("-O2",), "everything at -O2 (the hand-written C too)"),
    "all_O3": (("-O3",), "everything at -O3 (the generated model too)"),
}


def fig_flags(ctx) -> str:
    """The compiler flags of cedra.fmu.packaging: bump2d (the paper's run) and hills3d built as shipped and with
    one flag changed; the time to generate and compile each, the CPU of the paper's 15 s run through it (the
    least of REPEAT), and whether its samples equal the shipped build's bit for bit."""
    out = ctx.out / "figures" / "flags"
    builds = {"bump2d": ("shipped", "math_errno"), "hills3d": ("shipped", "math_errno", "hand_O2", "all_O3")}
    rows = []
    for scene, tags in builds.items():
        ref = None
        for tag in tags:
            flags, what = FLAG_VARIANTS[tag]
            path, t_build = variant(scene, out, tag, flags)
            best, cpus = least_cpu(path, 15.0)
            same = "-" if ref is None else ("yes" if np.array_equal(best.y, ref.y) else "no")
            ref = ref or best
            rows.append([scene, what, f"{t_build:.1f}", f"{best.cpu:.3f}", " / ".join(f"{c:.3f}" for c in cpus),
                         same])
            ctx.log(f"flags: {scene} {what}: C code and compile {t_build:.1f} s, CPU {best.cpu:.3f} s "
                    f"(runs {', '.join(f'{c:.3f}' for c in cpus)}), same samples: {same}")
    return (f"Each build made here with `build_fmu(..., extra_cflags)` (the flags go after the shipped ones), then "
            f"the paper's 15 s run through it {REPEAT} times (CPU, time.process_time).\n\n"
            + md_table(["scene", "build", "C code and compile (s)", "CPU, least (s)", "CPU of each run (s)",
                        "samples equal the shipped build's"], rows))


def fig_switch(ctx) -> str:
    """One evaluation of cedra_switch and of cedra_f (CasADi's C of the scene's functions, gcc -O2, evaluated many
    times in one mapped call: cedra.reports.bench.time_per_call), at the settled start moving at 0.2 m/s."""
    import tempfile
    from cedra.models.scene import load_shipped
    from cedra.reports.bench import compile_functions, time_per_call
    from cedra.reports.common import Problem
    rows = []
    for scene in ("step2d", "bump3d"):
        prob = Problem(load_shipped(scene))
        q0 = prob.settle()
        u = np.zeros(prob.nq)
        u[prob.q_names.index("x")] = 0.2
        inp = prob.inp0
        nh = prob.spec.n_hold
        with tempfile.TemporaryDirectory() as d:
            ext = compile_functions(prob.fns, ["cedra_switch", "cedra_f"], Path(d), prob.spec.rim_refine)
            t_sw = time_per_call(ext["cedra_switch"], [q0, u, inp, prob.par, np.zeros(nh)])
            t_f = time_per_call(ext["cedra_f"], [q0, u, inp, prob.par])
        rows.append([scene, str(len(prob.spec.switch_names)), f"{t_sw * 1e6:.2f}", f"{t_f * 1e6:.2f}"])
        ctx.log(f"switch: {scene}: cedra_switch {t_sw * 1e6:.2f} us ({len(prob.spec.switch_names)} switching "
                f"functions), cedra_f {t_f * 1e6:.2f} us")
    return md_table(["scene", "switching functions", "cedra_switch (us per call)", "cedra_f (us per call)"], rows)


def fig_ros34pw2(ctx) -> str:
    """bump3d under the paper's closed loop, 15 s: body.x of ros34pw2 and rodas4 at tol 1e-6 against rodas4 at
    tol 1e-9."""
    path = fmu_path(ctx.build, "bump3d")
    ref = closed_loop(path, 15.0, WIDE_OPEN | {"solver.method": SOLVER_CODES["rodas4"], "solver.tol": 1e-9})
    rows = []
    for method in ("rodas4", "ros34pw2"):
        r = closed_loop(path, 15.0, WIDE_OPEN | {"solver.method": SOLVER_CODES[method], "solver.tol": 1e-6})
        n = min(len(r.t), len(ref.t))
        dx = float(np.abs(r.col("body.x")[:n] - ref.col("body.x")[:n]).max())
        d = _force_diff(r, ref)
        rows.append([f"{method} 1e-6", f"{dx:.2g}", f"{d['dF']:.3g}", f"{r.counters['steps']}", end_of(r)])
        ctx.log(f"ros34pw2: bump3d {method} tol 1e-6: max |d body.x| {dx:.2g} m, max |dFn| {d['dF']:.3g} N "
                f"against rodas4 tol 1e-9")
    return ("bump3d, the paper's closed loop, 15 s, every 0.01 s sample against rodas4 at tol 1e-9.\n\n"
            + md_table(["run", "max d body.x (m)", "max dFn (N)", "steps", "end"], rows))


def fig_bench(ctx) -> str:
    """The first two parts of `python -m cedra bench` (cedra.reports.bench.bench_scene, bench_contact: 10 s of
    bump2d and flat3d against scipy Radau, the per-call cost of the generated C; the bump run with both contact
    models)."""
    from cedra.reports import bench
    stop = 10.0
    rows = []
    for name in bench.SCENES:
        o = bench.bench_scene(name, ctx.build, stop)
        rtf = o["fmu_reached"] / o["fmu_wall"] if o.get("fmu_ok") else math.nan
        rows.append([name, f"{o['t_M'] * 1e6:.2f} us", f"{o['t_f'] * 1e6:.2f} us", f"{o['t_jac'] * 1e6:.2f} us",
                     f"{o['fmu_wall']:.3f} s", f"{rtf:.1f}",
                     f"{o['fmu_steps']} / {o['fmu_rejected']} / {o['fmu_evals']}",
                     f"{o['peer_wall']:.2f} s" + ("" if o["peer_ok"] else " (failed)"),
                     f"x{o['peer_wall'] / o['fmu_wall']:.1f}"])
        ctx.log(f"bench: {name}: {rows[-1]}")
    text = (f"{stop:g} s simulated, communication step 0.01 s, the scene's default solver, the precision report's "
            "input schedule; one evaluation of the generated C (gcc -O2, mapped calls); the peer on the same "
            "equations: scipy Radau with the exact Jacobian, rtol = atol = the FMU's tol.\n\n"
            + md_table(["scene", "cedra_M", "cedra_f", "Jacobian (cedra_rjac)", "FMU wall", "real-time factor",
                        "steps / rejected / rhs evals", "Radau wall", "Radau / FMU"], rows))
    contact = bench.bench_contact(ctx.build, stop)
    crow = []
    for label, r in contact.items():
        if r is None:
            crow.append([label, "not built", "", "", ""])
            continue
        ratio = r["wall"] / contact["bump2d"]["wall"] if contact.get("bump2d") else math.nan
        crow.append([label, f"{r['wall']:.3f} s", f"{r['reached'] / r['wall']:.1f}",
                     f"{r['steps']} / {r['rejected']} / {r['evals']}", f"x{ratio:.2f}"])
        ctx.log(f"bench: contact {label}: {crow[-1]}")
    return text + (f"\n\nContact models: the bump run ({stop:g} s, the main job's speed controller), each scene at its "
                   "defaults (bump2d_rigid: Moreau-Jean) and bump2d_rigid with dopri5 on held modes:\n\n"
                   + md_table(["run", "wall", "real-time factor", "steps / rejected / rhs evals",
                               "wall / compliant"], crow))


# ------------------------------------------------------------------ docs/rigid-contact.md
def fig_rigid(ctx) -> str:
    """bump2d_rigid under the paper's closed loop. Moreau-Jean (15 s): the largest rise of kinetic + potential -
    work over one 0.01 s sample at h = 1e-4 and at the default h. The held-mode integration (8 s, h_max 0.01, the
    scene's tol 1e-6): the sampled peak normal force, the mode switches (changes of wheel[i].mode between samples,
    summed over wheels 1-6 as output; in 2D wheels 3, 4 repeat 1, 2), the last switch, CPU against the compliant
    bump2d."""
    path = fmu_path(ctx.build, "bump2d_rigid")
    energy = ["energy.kinetic", "energy.potential", "energy.work"]
    modes = [f"wheel[{i}].mode" for i in range(1, 7)]
    rows = []
    for h in (1e-4, 5e-5):
        r = closed_loop(path, 15.0, WIDE_OPEN | {"solver.h_max": h}, extra=energy)
        E = r.col("energy.kinetic") + r.col("energy.potential") - r.col("energy.work")
        rise = float(np.max(np.diff(E)))
        rows.append([f"moreau h = {h:g}", end_of(r), f"{rise:.2g}", f"{r.cpu:.2f}"])
        ctx.log(f"rigid: moreau h {h:g}: largest rise of K + P - W over a sample {rise:.2g} J, CPU {r.cpu:.2f} s")
    text = ("Moreau-Jean, 15 s: the largest rise of `energy.kinetic + energy.potential - energy.work` from one "
            "0.01 s sample to the next.\n\n" + md_table(["run", "end", "largest rise (J)", "CPU (s)"], rows))
    rows = []
    comp = closed_loop(fmu_path(ctx.build, "bump2d"), 8.0, WIDE_OPEN)
    rows.append(["bump2d (compliant, rodas4)", f"{comp.cpu:.2f}", "", "", f"{comp.fn.max():.1f}", ""])
    for method in ("rodas4", "dopri5"):
        r = closed_loop(path, 8.0, WIDE_OPEN | {"solver.method": SOLVER_CODES[method], "solver.h_max": 0.01},
                        extra=modes)
        m = r.y[:, [r.names.index(n) for n in modes]]
        changes = np.diff(m, axis=0) != 0
        n_sw = int(changes.sum())
        last = float(r.t[1:][changes.any(axis=1)][-1]) if n_sw else float("nan")
        peak_wheel = int(np.unravel_index(np.argmax(r.fn), r.fn.shape)[1]) + 1
        rows.append([f"bump2d_rigid held modes, {method}", f"{r.cpu:.2f}", f"{r.cpu / comp.cpu:.2f}", str(n_sw),
                     f"{r.fn.max():.1f} (wheel {peak_wheel})", f"{last:.2f}"])
        ctx.log(f"rigid: held modes {method}: CPU {r.cpu:.2f} s (x{r.cpu / comp.cpu:.2f} the compliant run's), "
                f"{n_sw} mode switches, last at {last:.2f} s, peak Fn {r.fn.max():.1f} N (wheel {peak_wheel}), "
                f"{end_of(r)}")
    return text + ("\n\nThe held-mode integration, 8 s (h_max 0.01 s, tol 1e-6), against the compliant bump2d at its "
                   "defaults (single runs):\n\n"
                   + md_table(["run", "CPU (s)", "CPU / compliant", "mode switches", "sampled peak Fn (N)",
                               "last switch (s)"], rows))


def fig_compare(ctx) -> str:
    """`python -m cedra compare`'s two runs (cedra.run.simulate.run_bump, the paper's 15 s run, bump2d and
    bump2d_rigid at their defaults) and what docs/rigid-contact.md reads from them: body.x and torques against each
    other, the rigid modes' switches (changes of wheel[i].mode between samples, wheels 1, 2, 5, 6: the 2D wheels
    3, 4 repeat 1, 2), the wheel loads at the end, the drift of touching wheels, the peaks of the sampled and the
    mean normal forces, the rigid run's wall time."""
    from cedra.run.compare import SHOWN, drift
    from cedra.run.simulate import run_bump
    nc, rc, tc, ic = run_bump(fmu_path(ctx.build, "bump2d"), 15.0)
    nr, rr, tr, ir = run_bump(fmu_path(ctx.build, "bump2d_rigid"), 15.0, extra=[f"wheel[{i}].gap" for i in range(1, 7)])
    n = min(len(rc), len(rr))
    rc, rr, tc, tr = rc[:n], rr[:n], tc[:n], tr[:n]
    t = rc[:, 0]

    def col(names, rows, name):
        return rows[:, names.index(name)]

    dx = np.abs(col(nr, rr, "body.x") - col(nc, rc, "body.x"))
    modes = np.stack([col(nr, rr, f"wheel[{i}].mode") for i in SHOWN], axis=1)
    changed = np.diff(modes, axis=0) != 0
    n_sw = int(changed.sum())
    last = float(t[1:][changed.any(axis=1)][-1]) if n_sw else math.nan
    fn_r = np.stack([col(nr, rr, f"wheel[{i}].Fn") for i in SHOWN], axis=1)
    fn_c = np.stack([col(nc, rc, f"wheel[{i}].Fn") for i in SHOWN], axis=1)
    mean_r = np.stack([col(nr, rr, f"wheel[{i}].Fn_mean") for i in SHOWN], axis=1)
    kr, wr = np.unravel_index(np.argmax(fn_r), fn_r.shape)
    km, wm = np.unravel_index(np.argmax(mean_r), mean_r.shape)
    rows = [["body.x: largest difference over the run", f"{dx.max() * 1e3:.1f} mm"],
            ["body.x at the end, rigid / compliant",
             f"{col(nr, rr, 'body.x')[-1]:.4f} / {col(nc, rc, 'body.x')[-1]:.4f} m"],
            ["torques: largest difference; peak |tau| rigid / compliant",
             f"{np.abs(tr - tc).max():.2f} N.m; {np.abs(tr).max():.2f} / {np.abs(tc).max():.2f} N.m"],
            ["rigid modes: switches (wheels 1, 2, 5, 6), the last at", f"{n_sw}, t = {last:.2f} s"],
            ["rigid modes at the end (wheels 1, 2, 5, 6; 1 stick, 2 slip)", " / ".join(f"{m:g}" for m in modes[-1])],
            ["loads at the end, rigid (wheels 1, 2, 5, 6)", " / ".join(f"{v:.1f}" for v in fn_r[-1]) + " N"],
            ["loads at the end, compliant", " / ".join(f"{v:.1f}" for v in fn_c[-1]) + " N"],
            ["rigid: largest drift |gap| of touching wheels", f"{drift(nr, rr):.3g} m"],
            ["rigid: peak sampled wheel[i].Fn", f"{fn_r[kr, wr]:.1f} N (wheel {SHOWN[wr]} at t = {t[kr]:.2f} s)"],
            ["compliant: peak sampled wheel[i].Fn", f"{fn_c.max():.1f} N"],
            ["rigid: peak wheel[i].Fn_mean", f"{mean_r[km, wm]:.1f} N (wheel {SHOWN[wm]} over the 0.01 s to t = "
                                              f"{t[km]:.2f} s; its sampled Fn there {fn_r[km, wm]:.1f} N)"],
            ["compliant: that wheel's Fn at that sample and the next",
             " / ".join(f"{v:.1f}" for v in fn_c[km:km + 2, wm]) + " N"],
            ["wall time, rigid / compliant (perf_counter of run_bump)", f"{ir['wall']:.2f} / {ic['wall']:.2f} s"]]
    for what, v in rows:
        ctx.log(f"compare: {what}: {v}")
    return md_table(["what", "measured"], rows)


# ------------------------------------------------------------------ docs/equations.md
def fig_chassis(ctx) -> str:
    """The runs that have chassis contact: step2d's paper's run (15 s, least of REPEAT) and stairs3d as
    `python -m cedra simulate stairs` runs it (the drive controller, 25 s, one run)."""
    best, cpus = least_cpu(fmu_path(ctx.build, "step2d"), 15.0)
    rows = [["step2d, the paper's run, 15 s", str(best.counters["steps"]), f"{best.cpu:.2f}",
             " / ".join(f"{c:.2f}" for c in cpus), end_of(best)]]
    ctx.log(f"chassis: step2d {best.counters['steps']} steps, CPU {best.cpu:.2f} s (runs {cpus})")
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "examples"))
    import stairs
    from cedra.run.cosim import DriveLoop
    from cedra.run.scenario import fmu
    loop = DriveLoop(fmu("stairs3d", ctx.build), fmu("drive3d", ctx.build), controller_values={"ctrl.mode": 1})

    def commands(t):
        return {"cmd.v": stairs.SPEED, "cmd.yaw_rate": -stairs.HEADING_GAIN * loop.plant.get(["body.yaw"])[0]}
    try:
        cpu = time.process_time()
        r = loop.run(stairs.STOP_TIME, stairs.STEP, commands, stairs.RECORD)
        cpu = time.process_time() - cpu
        steps = int(loop.plant.get(["solver.steps"])[0])
    finally:
        loop.close()
    v, _ = stairs.verdict(stairs.stairs_geometry("stairs3d"), r)
    rows.append([f"stairs3d, examples/stairs.py, {stairs.STOP_TIME:g} s", str(steps), f"{cpu:.2f}", "",
                 "finished, " + v if r.ok else "stopped, " + v])
    ctx.log(f"chassis: stairs3d {steps} steps, CPU {cpu:.2f} s (controller included), verdict {v}")
    return md_table(["run", "steps", "CPU (s)", "CPU of each run (s)", "end"], rows)


# ------------------------------------------------------------------ docs/benchmarks.md
def fig_mujoco(ctx) -> str:
    """MuJoCo (cedra.reports.mujoco_model, 1 ms) on height fields: the bump field's peak normal force while every
    wheel is still on the flat cells before the bump, and where the hills field's peak is."""
    from cedra.models.scene import load_shipped
    from cedra.reports import mujoco_model as mm
    from cedra.run.driver import RoverFMU
    sc = load_shipped("bump3d")
    f = RoverFMU(fmu_path(ctx.build, "bump3d"))
    f.start({})
    x, cx6, cx5, R, x0, w = f.get(["body.x", "wheel[6].cx", "wheel[5].cx", "R_w", "terrain_x0", "terrain_w"])
    f.close()
    front, rear = cx6 - x + R, cx5 - x - R               # the front and rear rims from the body's origin
    r = mm.run(sc, "hfield", 1e-3, 15.0)
    # the Gaussian bump is below 1e-4 of its height more than 3 w from its center
    parts = {"before the bump (the front rim more than 3 w before its center)": r.x + front < x0 - 3 * w,
             "after the bump (the rear rim more than 3 w past its center)": r.x + rear > x0 + 3 * w}
    rows = []
    for label, flat in parts.items():
        if not flat.any():
            rows.append([f"bump field, {label}", "-", "-", f"{r.Fn.max():.1f}"])
            continue
        k = int(np.argmax(np.where(flat[:, None], r.Fn, -np.inf)) // 6)
        rows.append([f"bump field, {label}", f"{r.Fn[flat].max():.1f}", f"{r.t[k]:.2f}", f"{r.Fn.max():.1f}"])
        ctx.log(f"mujoco: bump field {label}: peak {r.Fn[flat].max():.1f} N at t = {r.t[k]:.2f} s (whole run "
                f"{r.Fn.max():.1f} N)")
    rh = mm.run(load_shipped("hills3d"), "hfield", 1e-3, 15.0)
    kh = int(np.argmax(rh.Fn) // 6)
    rows.append(["hills field, whole run", f"{rh.Fn.max():.1f}", f"{rh.t[kh]:.2f}", f"{rh.Fn.max():.1f}"])
    ctx.log(f"mujoco: hills peak {rh.Fn.max():.1f} N at t = {rh.t[kh]:.2f} s")
    return ("MuJoCo at 1 ms, the paper's 15 s run (`cedra.reports.mujoco_model.run`), the largest wheel normal "
            "force at the 0.01 s samples.\n\n" + md_table(["where", "peak Fn (N)", "at t (s)", "whole run (N)"], rows))


# ------------------------------------------------------------------ docs/scenes.md
def _size(fn) -> tuple[int, int]:
    """CasADi instructions of one evaluation of a generated function: an SX function's n_instructions; a function
    that first runs the contact searches and then one of two forms (several contacts per wheel: CedraModel._contract)
    sums the SX functions it calls, its Switch counted as (the one-maximum form, the full form). External calls (the
    rim searches' C) count as one instruction."""
    if not fn.is_a("MXFunction"):
        return fn.n_instructions(), fn.n_instructions()
    one = full = 0
    for k in range(fn.n_instructions()):
        m = fn.instruction_MX(k)
        if not m.is_call():
            continue
        sub = m.which_function()
        if sub.class_name() == "Switch":
            info = sub.info()
            one += info["f_def"].n_instructions()
            full += max(c.n_instructions() for c in info["f"])
        else:
            a, b = _size(sub)
            one, full = one + a, full + b
    return one, full


def fig_sizes(ctx) -> str:
    """CasADi instruction counts of every shipped scene's generated functions (`_size`: where a wheel can have
    several contacts, "one-maximum form / full form"), and the time to derive the model and form its functions
    (Scene.spec())."""
    from cedra.models.scene import load_shipped, shipped
    rows = []
    for name in shipped():
        sc = load_shipped(name)
        t0 = time.perf_counter()
        spec = sc.spec()
        dt = time.perf_counter() - t0
        fns = spec.functions
        cells = []
        for k in ("cedra_M", "cedra_f", "cedra_rjac", "cedra_switch", "cedra_fc"):
            if k not in fns:
                cells.append("-")
                continue
            one, full = _size(fns[k])
            cells.append(str(one) if one == full else f"{one} / {full}")
        rows.append([f"`{name}`", sc.options.dims, str(len(spec.q_names))] + cells + [f"{dt:.2f} s"])
        ctx.log(f"sizes: {name}: {cells}, {dt:.2f} s")
    return md_table(["scene", "dims", "coordinates", "M", "f", "Jacobian of M udot - f", "switches",
                     "chassis forces", "derive + functions"], rows)


def _cholesky_work(pattern: np.ndarray, order: list[int]) -> int:
    """Multiply-adds of a Cholesky factor of a matrix with this nonzero pattern eliminated in this order that skips
    the entries that stay zero: L[i, j] -= L[i, k] L[j, k] for k < j <= i where both are nonzero (fill included)."""
    g = pattern[np.ix_(order, order)].copy()
    n = len(g)
    L = np.zeros_like(g)
    for j in range(n):                        # the factor's pattern, column by column (symbolic factorization)
        col = g[j:, j].copy()
        for k in range(j):
            if L[j, k]:
                col |= L[j:, k]
        L[j:, j] = col
    return int(sum(np.count_nonzero(L[i, :j] & L[j, :j]) for j in range(n) for i in range(j, n)))


def fig_mass(ctx) -> str:
    """The mass matrix's Cholesky work (fmu_src/linalg.c skips the entries that stay zero) in the generator's
    minimum-degree order (cedra.fmu.mass_order, CEDRA_M_ORDER) against the dense factor, per shipped 3D scene and
    bump2d."""
    from cedra.fmu import mass_order
    from cedra.models.scene import load_shipped
    rows = []
    for name in ("bump2d", "flat3d", "hills3d", "stairs3d"):
        spec = load_shipped(name).spec()
        pattern = mass_order.nonzero_pattern(spec)
        n = len(pattern)
        order = mass_order.elimination_order(spec)
        work, natural = _cholesky_work(pattern, order), _cholesky_work(pattern, list(range(n)))
        dense = _cholesky_work(np.ones_like(pattern), list(range(n)))
        zeros = int(n * n - np.count_nonzero(pattern))
        rows.append([name, str(n), f"{zeros} of {n * n}", str(work), str(natural), str(dense)])
        ctx.log(f"mass: {name}: {work} multiply-adds in the generator's order, {natural} in the coordinates' order, "
                f"{dense} dense ({zeros} of {n * n} entries zero)")
    return md_table(["scene", "coordinates", "zeros of M (pattern)", "multiply-adds, CEDRA_M_ORDER",
                     "in the coordinates' order", "dense"], rows)


FIGURES = {    # name: (function, the page that quotes it, expected time on two cores)
    "fmpy": (fig_fmpy, "fmu.md", "5 s"),
    "masters": (fig_masters, "fmu.md", "5 s"),
    "location": (fig_location, "solvers.md", "80 s"),
    "flags": (fig_flags, "solvers.md", "9 min"),
    "switch": (fig_switch, "solvers.md", "30 s"),
    "ros34pw2": (fig_ros34pw2, "solvers.md", "5 s"),
    "rigid": (fig_rigid, "rigid-contact.md", "10 s"),
    "compare": (fig_compare, "rigid-contact.md", "10 s"),
    "chassis": (fig_chassis, "equations.md", "15 s"),
    "mujoco": (fig_mujoco, "benchmarks.md", "10 s"),
    "sizes": (fig_sizes, "scenes.md", "15 s"),
    "mass": (fig_mass, "solvers.md", "10 s"),
    "bench": (fig_bench, "benchmarks.md", "1 min"),
}


@dataclass
class Context:
    build: Path
    out: Path
    quiet: bool

    def log(self, line):
        if not self.quiet:
            print(line, flush=True)


def main(args) -> int:
    names = getattr(args, "figure", None) or list(FIGURES)
    unknown = [n for n in names if n not in FIGURES]
    if unknown:
        print(f"error: unknown figure(s) {unknown} (figures: {', '.join(FIGURES)})", file=sys.stderr)
        return 2
    ctx = Context(Path(getattr(args, "build", "build")), Path(getattr(args, "out", "out/report")),
                  getattr(args, "quiet", False))
    if not getattr(args, "quiet", False):
        print("report figures: expect " + ", ".join(f"{n} {FIGURES[n][2]}" for n in names), file=sys.stderr)
    load0, t0 = load_average(), time.perf_counter()
    sections = []
    for name in names:
        fn, page, _ = FIGURES[name]
        t1 = time.perf_counter()
        body = fn(ctx)
        sections.append(f"## {name} ({page})\n\n{(fn.__doc__ or '').strip()}\n\n{body}\n\n"
                        f"({time.perf_counter() - t1:.0f} s)\n")
        print(f"\n## {name}\n\n{body}\n", flush=True)
    cmd = "python -m cedra report figures" + "".join(f" --figure {n}" for n in getattr(args, "figure", None) or [])
    made_by = provenance(cmd, time.perf_counter() - t0, load0)
    ctx.out.mkdir(parents=True, exist_ok=True)
    suffix = "" if not getattr(args, "figure", None) else "-" + "-".join(names)
    path = ctx.out / f"figures{suffix}.md"
    title = "Figures of the documentation" + (f": {', '.join(names)}" if getattr(args, "figure", None) else "")
    path.write_text(f"# {title}\n\n" + made_by + "\n\n" + "\n".join(sections))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(prog="python -m cedra.reports.figures")
    ap.add_argument("--figure", action="append", choices=list(FIGURES))
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="out/report")
    ap.add_argument("--quiet", action="store_true")
    sys.exit(main(ap.parse_args()))
