"""Benchmark: `python -m cedra bench [--build build] [--stop-time 10]`.

For bump2d and flat3d over stop_time simulated: the FMU's wall time, real-time factor, steps and rhs
evaluations (scene default solver, communication step 0.01 s, from the Python-settled start state with the
report's input schedule), and the cost of one evaluation of the generated C functions cedra_M, cedra_f and
cedra_rjac (compiled here by CasADi's code generator + gcc into a shared library, loaded with casadi.external and
evaluated many times in one mapped call, so the per-call figure is the C code's, not Python's). A peer on the
same equations in the same run (scipy Radau with the exact Jacobian, rtol = atol = the FMU's tol) gives ratios.
Figures are printed, never asserted on.

Then, when the optional dependency mujoco is importable (`pip install -e '.[bench]'`, ./build.sh does it), the
MuJoCo side by side (`side_by_side`): the paper's 15 s run under its speed controller (docs/model.md)
on MuJoCo (cedra.reports.mujoco_model) on the bump as a height field (1 cm cells), on a plane and on the hills3d grid as
a height field, at dt 1, 0.5 and 0.2 ms, and through the FMUs bump2d, bump3d, flat3d and hills3d, each at its scene
defaults, at FMU_SETTINGS and at the REFERENCE settings: CPU time (time.process_time), real-time factor, x at 6 s,
peak normal force, steps, each FMU row's peak against its reference, and the ratios MuJoCo CPU / FMU CPU of the
matching pairs at the defaults and at the fastest setting whose forces converged (peak within CONVERGED).
`--quick`: only that table, 1 s runs (the tests); `--side-by-side`: only that table.

The drive controller's cost per sample (`--controller`: only that): the paper's bump run co-simulated with
drive2d in each control mode, then every sample's measurements replayed through the controller FMU three times;
the median, 99.9 % and worst wall time of one fmi2DoStep (through FMPy: an upper bound of the C's own cost).

Last, MuJoCo on the step and the stairs as boxes (cedra.reports.bench_steps; `--steps`: only that table): CPU,
where each run ended and its verdict, and the largest energy gain no motor paid for.
"""
from __future__ import annotations

import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from cedra.compile import CompileJob, link_library
from cedra.models.host import casadi_library
from cedra.reports.common import SOLVER_CODES, fmu_closed_loop, fmu_path

SCENES = ("bump2d", "flat3d")
CFLAGS = ("-O2", "-fPIC", "-fno-math-errno")
RIM_FUNCTIONS = ("cedra_terrain", "cedra_rim_samples", "cedra_terrain_bounds")    # what fmu_src/rim.c calls
RIM_SOURCE = Path(__file__).resolve().parents[3] / "fmu_src" / "rim.c"


def compile_functions(fns: dict, names, workdir: Path, rim_refine: bool = False) -> dict:
    """The named CasADi functions as C (CasADi's code generator, one file each), compiled (cedra.compile: in
    parallel, through the object cache) into one shared library, loaded back with casadi.external. A scene with
    an analytic terrain's contact search (the functions call cedra_rim_search) gets fmu_src/rim.c and the terrain
    functions it calls linked in, as its FMU does (without the FMU's memo of searches: RIM_HOST; rim_refine as in
    the scene's FMU). Heightmap scenes are not supported (their terrain is the FMU's)."""
    rim = [n for n in RIM_FUNCTIONS if n in fns]
    extra = [CompileJob(RIM_SOURCE, (*CFLAGS, "-DRIM_HOST", "-DCEDRA_HEIGHTMAP=0",
                                     f"-DCEDRA_RIM_REFINE={int(rim_refine)}"))] if rim else []
    lib = casadi_library([fns[n] for n in list(names) + rim], "bench_fns", CFLAGS, extra, out_dir=workdir)
    return {n: ca.external(n, str(lib)) for n in names}


def time_per_call(fn: ca.Function, args, min_time=0.3) -> float:
    """Seconds per evaluation: fn mapped serially over N copies of the same arguments, one call, N grown until
    the call takes min_time; the best of three."""
    n = 64
    while True:
        fm = fn.map(n, "serial")
        rep = [ca.repmat(ca.DM(a), 1, n) for a in args]
        t = time.perf_counter()
        fm(*rep)
        dt = time.perf_counter() - t
        if dt > min_time or n > 2 ** 22:
            break
        n *= 4
    best = dt
    for _ in range(2):
        t = time.perf_counter()
        fm(*rep)
        best = min(best, time.perf_counter() - t)
    return best / n


def time_python_call(fn: ca.Function, args, n=2000) -> float:
    """Seconds per call of a CasADi Function from Python (what the scipy peers pay per evaluation)."""
    t = time.perf_counter()
    for _ in range(n):
        fn(*args)
    return (time.perf_counter() - t) / n


def bench_scene(name, build, stop_time):
    from cedra.reports.common import Problem, fmu_path, grid, run_fmu, run_scipy
    from cedra.reports.precision import flat3d_schedule, pi_schedule
    from cedra.models.scene import load_shipped
    scene = load_shipped(name)
    prob = Problem(scene)
    sched = (pi_schedule if name == "bump2d" else flat3d_schedule)(prob, stop_time)
    q0 = prob.settle()
    x0 = prob.x0(q0)
    method, tol, h_max = scene.solver["method"], scene.solver["tol"], scene.solver["h_max"]
    out = dict(scene=name, method=method, tol=tol)

    # one evaluation of the generated C, at a state in contact with the ground, moving
    u = np.zeros(prob.nq)
    u[prob.q_names.index("x")] = 0.2
    inp = prob.inp(sched.at(0.0))
    with tempfile.TemporaryDirectory() as d:
        ext = compile_functions(prob.fns, ["cedra_M", "cedra_f", "cedra_rjac"], Path(d), prob.spec.rim_refine)
        a = np.array(prob.fns["cedra_M"](q0, prob.par)).dot(np.zeros(prob.nq))
        out["t_M"] = time_per_call(ext["cedra_M"], [q0, prob.par])
        out["t_f"] = time_per_call(ext["cedra_f"], [q0, u, inp, prob.par])
        out["t_jac"] = time_per_call(ext["cedra_rjac"], [q0, u, a, inp, prob.par])
    out["t_f_python"] = time_python_call(prob.fns["cedra_f"], [q0, u, inp, prob.par])
    out["t_rhs_python"] = time_python_call(prob.rhs, [x0, np.concatenate([inp, prob.par])])

    path = fmu_path(build, name)
    if path.exists():
        r = run_fmu(path, prob, sched, q0, stop_time, 0.01, method, tol, h_max, check_all=False)
        out |= dict(fmu_ok=r.ok, fmu_wall=r.wall, fmu_steps=r.steps, fmu_rejected=r.extra.get("rejected", -1),
                    fmu_evals=r.rhs_evals, fmu_status=r.status, fmu_message=r.message,
                    fmu_reached=r.extra.get("reached"))
    else:
        out["fmu_ok"] = None
    tg = grid(stop_time, 0.01)
    p = run_scipy(prob, sched, x0, tg, "Radau", tol)
    out |= dict(peer="scipy Radau", peer_ok=p.ok, peer_wall=p.wall, peer_evals=p.rhs_evals)
    return out


CONTACT_RUNS = {   # label: (scene, settings)
    "bump2d": ("bump2d", {}),
    "bump2d_rigid": ("bump2d_rigid", {}),
    "bump2d_rigid dopri5": ("bump2d_rigid", {"solver.method": SOLVER_CODES["dopri5"]}),
}


def bench_contact(build, stop_time):
    """The bump run (the main job's speed controller) with the compliant and the rigid contact model (the rigid
    one also with DOPRI5: its held-mode steps are not stiff)."""
    from cedra.run.simulate import run_bump
    rows = {}
    for label, (name, settings) in CONTACT_RUNS.items():
        path = fmu_path(build, name)
        if not path.exists():
            rows[label] = None
            continue
        names, data, _, info = run_bump(path, stop_time, settings)
        last = dict(zip(names, data[-1]))
        rows[label] = dict(wall=info["wall"], reached=info["simulated"], ok=info["ok"], steps=int(last["solver.steps"]),
                          rejected=int(last["solver.rejected"]), evals=int(last["solver.rhs_evals"]))
    return rows


# ------------------------------------------------------------------ cost of one implicit step
STEP_SCENES = ("bump2d", "bump3d")
STEP_VARIANTS = {        # label: (extra C flags of the FMU build (fmu_src/model_glue.c), solver settings)
    "rodas4, dense 2n+1 solve": (["-DCEDRA_SCHUR_N2=0"], {}),
    "rodas4, Schur n x n solve": ([], {}),
    "ros34pw2, Schur n x n solve": ([], {"solver.method": SOLVER_CODES["ros34pw2"]}),
}
STAGE_C = r"""
#include <time.h>
#include "solver.h"
/* seconds per RODAS4 step's linear algebra: one factorization and six stage solves of (fac I - J) k = r */
double stage_seconds(int n, int n2, const double *J, int reps) {
    double work[80 * 80 + 80], r[80];
    int piv[80];
    struct timespec a, b;
    volatile double sink = 0;
    clock_gettime(CLOCK_MONOTONIC, &a);
    for (int k = 0; k < reps; k++) {
        double fac = 1e3 * (1 + 1e-9 * k);
        solver_stage_factor(n, n2, fac, J, NULL, work, piv);
        for (int s = 0; s < 6; s++) {
            for (int i = 0; i < n; i++) r[i] = 1.0 + i + s;
            solver_stage_solve(n, n2, fac, J, NULL, work, piv, r);
            sink += r[0];
        }
    }
    clock_gettime(CLOCK_MONOTONIC, &b);
    (void)sink;
    return ((double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec)) / reps;
}
"""


def stage_cost(prob, workdir: Path) -> dict:
    """Microseconds of one RODAS4 step's linear algebra (1 factorization + 6 solves) at the rover's Jacobian,
    dense (n = 2 nq + 1) and reduced (nq x nq Schur complement), fmu_src/solver.c compiled with gcc -O2."""
    import ctypes
    root = Path(__file__).resolve().parents[3] / "fmu_src"
    src = workdir / "stage.c"
    src.write_text(STAGE_C)
    lib = link_library([CompileJob(s, ("-O2", "-fPIC"), root) for s in (src, root / "solver.c", root / "linalg.c")],
                       workdir / "stage.so")
    so = ctypes.CDLL(str(lib))
    so.stage_seconds.restype = ctypes.c_double
    so.stage_seconds.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_double), ctypes.c_int]
    q0 = prob.settle()
    u = np.zeros(prob.nq)
    u[prob.q_names.index("x")] = 0.2
    J = np.asfortranarray(np.array(prob.jac(prob.x0(q0, u), np.concatenate([prob.inp0, prob.par]))))
    Jp = J.ravel(order="F").ctypes.data_as(ctypes.POINTER(ctypes.c_double))
    n = prob.nx
    out = {}
    for label, n2 in (("dense", 0), ("schur", prob.nq)):
        so.stage_seconds(n, n2, Jp, 2000)
        out[label] = min(so.stage_seconds(n, n2, Jp, 20000) for _ in range(3))
    return out


def step_cost(build: Path, stop_time=8.0, log=print) -> list[dict]:
    """Per attempted step on the paper's run (the main job's controller, tol 1e-6): rhs evaluations, Jacobians
    (RODAS4: one per accepted step; ROS34PW2 keeps one over many) and CPU microseconds, for rodas4 in the FMU built
    with the dense and with the reduced stage solve (the same sources otherwise) and for ros34pw2, plus RODAS4's
    linear algebra alone (one factorization per attempt)."""
    from cedra.fmu.packaging import build_fmu
    from cedra.models.scene import load_shipped
    from cedra.reports.common import Problem
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name in STEP_SCENES:
            sc = load_shipped(name)
            la = stage_cost(Problem(sc), Path(d))
            builds = {}
            for label, (flags, settings) in STEP_VARIANTS.items():
                key = tuple(flags)
                if key not in builds:
                    builds[key] = build_fmu(sc.spec(), Path(d) / f"{name}_{len(builds)}", extra_cflags=flags)
                r = fmu_closed_loop(builds[key], stop_time, settings, label=f"{name} {label}")
                attempts = r.steps + r.extra["rejected"]
                rows.append(dict(scene=name, variant=label, ok=r.ok, cpu=r.cpu, steps=r.steps,
                                 rejected=r.extra["rejected"], evals=r.extra["rhs_evals"],
                                 us_per_attempt=1e6 * r.cpu / attempts,
                                 evals_per_attempt=r.extra["rhs_evals"] / attempts,
                                 jacs_per_attempt=r.extra["jac_evals"] / attempts,
                                 la_us=1e6 * la["schur" if "Schur" in label else "dense"] if "rodas4" in label
                                 else None))
                log(f"  ... {name} {label}: {r.cpu:.2f} s CPU")
    return rows


def print_step_cost(build: Path, stop_time=8.0) -> int:
    print(f"\ncost of one implicit step: the paper's run, {stop_time:g} s, tol 1e-6; per attempted "
          "step (accepted + rejected); 1 LU factorization per attempt; CPU = time.process_time of the run (the "
          "master's calls included); RODAS4's linear algebra = 1 factorization + 6 stage solves at the settled "
          "state's Jacobian, timed alone")
    rows = step_cost(build, stop_time)
    print("| scene | method, stage solve | CPU s | steps (rejected) | rhs evals per attempt | Jacobians per attempt | "
          "us per attempt | linear algebra us per attempt |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        la = "" if r["la_us"] is None else f"{r['la_us']:.2f}"
        print(f"| {r['scene']} | {r['variant']} | {r['cpu']:.3f} | {r['steps']} ({r['rejected']}) | "
              f"{r['evals_per_attempt']:.2f} | {r['jacs_per_attempt']:.3f} | {r['us_per_attempt']:.1f} | {la} |")
    return 0 if all(r["ok"] for r in rows) else 1


def print_controller_cost(build: Path) -> int:
    """The drive controllers' cost per sample over the bump run, in each mode (cedra.reports.traction): CEDRA's
    drive2d on bump2d and the rocker-bogie's rb_drive2d on rb_bump2d."""
    from cedra.reports.traction import MODES, rover_of, run_modes, sample_cost
    plants = ("bump2d", "rb_bump2d")
    missing = [n for plant in plants for n in (plant, rover_of(plant)[0]) if not fmu_path(build, n).exists()]
    if missing:
        print(f"\ncontroller cost: {', '.join(f'{build}/{n}.fmu' for n in missing)} not found (python -m cedra build)")
        return 1
    print("\nthe drive controllers' cost per sample: the bump run (bump2d + drive2d, rb_bump2d + rb_drive2d, 15 s, "
          "0.01 s samples) in each mode, every sample's measurements replayed 3 times through the controller "
          "(fmi2DoStep through FMPy)")
    print("| controller | mode | samples | median us | 99.9 % us | worst us |")
    print("|---|---|---|---|---|---|")
    for plant in plants:
        controller = rover_of(plant)[0]
        runs = run_modes(build, plant)
        for mode in MODES:
            c = sample_cost(runs[mode], build, mode, controller=controller)
            print(f"| {controller} | {MODES[mode]} | {c['samples']} | {c['median_us']:.1f} | {c['p999_us']:.1f} | "
                  f"{c['max_us']:.1f} |")
    return 0


def main(args):
    build = Path(getattr(args, "build", "build"))
    given = getattr(args, "stop_time", None)
    stop_time = 10.0 if given is None else float(given)
    if getattr(args, "step_cost", False):
        return print_step_cost(build)
    if getattr(args, "controller", False):
        return print_controller_cost(build)
    if getattr(args, "steps", False):
        from cedra.reports.bench_steps import STOP, print_steps
        return print_steps(build, STOP if given is None else float(given))
    if getattr(args, "quick", False):       # the MuJoCo side-by-side table only, short (what the tests run)
        return print_side_by_side(build, QUICK_STOP, quiet=getattr(args, "quiet", False))
    if getattr(args, "side_by_side", False):
        return print_side_by_side(build, SIDE_STOP, quiet=getattr(args, "quiet", False))
    if not shutil.which("gcc"):
        print("error: gcc not found (needed to time the generated C)", file=sys.stderr)
        return 2
    print(f"cedra bench: {stop_time:g} s simulated per scene, communication step 0.01 s, inputs: the precision "
          f"report's schedules; per-call times of the generated C compiled with gcc {' '.join(CFLAGS[:1])}")
    rc = 0
    for name in SCENES:
        o = bench_scene(name, build, stop_time)
        print(f"\n{name} (FMU solver {o['method']}, tol {o['tol']:g})")
        print(f"  one evaluation (generated C): cedra_M {o['t_M'] * 1e6:.2f} us, cedra_f {o['t_f'] * 1e6:.2f} us, "
              f"Jacobian cedra_rjac {o['t_jac'] * 1e6:.2f} us")
        print(f"  the same from Python (CasADi VM): cedra_f {o['t_f_python'] * 1e6:.1f} us, whole rhs with the "
              f"linear solve {o['t_rhs_python'] * 1e6:.1f} us  (x{o['t_f_python'] / o['t_f']:.0f} the C call)")
        if o["fmu_ok"] is None:
            print(f"  FMU: {build / (name + '.fmu')} not found (python -m cedra build {name})")
            rc = 1
        else:
            rtf = o["fmu_reached"] / o["fmu_wall"]
            state = "finished" if o["fmu_ok"] else f"STOPPED at {o['fmu_reached']:g} s: {o['fmu_status']} " \
                                                   f"{o['fmu_message']}"
            print(f"  FMU: wall {o['fmu_wall']:.3f} s, real-time factor {rtf:.1f}, steps {o['fmu_steps']}, "
                  f"rejected {o['fmu_rejected']}, rhs evals {o['fmu_evals']} ({state})")
            if not o["fmu_ok"]:
                rc = 1
        print(f"  peer {o['peer']} (rtol = atol = {o['tol']:g}, exact Jacobian): wall {o['peer_wall']:.2f} s, "
              f"rhs evals {o['peer_evals']}" + ("" if o["peer_ok"] else " (failed)"))
        if o["fmu_ok"]:
            print(f"  ratio peer / FMU wall time: x{o['peer_wall'] / o['fmu_wall']:.1f}")
    print(f"\ncontact models on the bump run ({stop_time:g} s, the main job's speed controller, tol 1e-6; rodas4 "
          f"unless named)")
    rows = bench_contact(build, stop_time)
    for name, r in rows.items():
        if r is None:
            print(f"  {name}: FMU not found (python -m cedra build {name})")
            rc = 1
            continue
        print(f"  {name:20s} wall {r['wall']:.3f} s, real-time factor {r['reached'] / r['wall']:.1f}, steps "
              f"{r['steps']}, rejected {r['rejected']}, rhs evals {r['evals']}" + ("" if r["ok"] else " (STOPPED)"))
    if all(rows.values()):
        for label in ("bump2d_rigid", "bump2d_rigid dopri5"):
            print(f"  ratio {label} / bump2d wall time: x{rows[label]['wall'] / rows['bump2d']['wall']:.2f}")
    rc = max(rc, print_step_cost(build))
    rc = max(rc, print_controller_cost(build))
    rc = max(rc, print_side_by_side(build, SIDE_STOP, quiet=getattr(args, "quiet", False)))
    from cedra.reports.bench_steps import STOP, print_steps
    return max(rc, print_steps(build, STOP))


# ------------------------------------------------------------------ MuJoCo side by side
SIDE_STOP = 15.0                     # the paper's run
QUICK_STOP = 1.0
X_AT = 6.0
MUJOCO_DTS = (1e-3, 5e-4, 2e-4)
MUJOCO_RUNS = {      # terrain label: (scene whose numbers and start it takes, MuJoCo terrain)
    "bump": ("bump3d", "hfield"),
    "plane": ("flat3d", "plane"),
    "hills": ("hills3d", "hfield"),
}
FMU_RUNS = ("bump2d", "bump3d", "flat3d", "hills3d")
PAIRS = (("bump3d", "MuJoCo bump 1 ms"), ("hills3d", "MuJoCo hills 1 ms"), ("flat3d", "MuJoCo plane 1 ms"),
         ("bump2d", "MuJoCo bump 1 ms"))
TARGETS = {"bump3d": 20.0, "hills3d": 10.0, "flat3d": 5.0}     # the targets: MuJoCo 1 ms CPU / FMU CPU, converged
DEFAULTS_TARGET = 10.0      # ... and at the scene defaults, for every 3D scene (what a user gets without tuning)


def solver_setting(method: str, tol: float) -> tuple[str, dict]:
    """("<method> <tol>" as in "ros34pw2 1e-4", the FMU's start values for it)."""
    mantissa, exponent = f"{tol:.0e}".split("e")
    return f"{method} {mantissa}e{int(exponent)}", {"solver.method": SOLVER_CODES[method], "solver.tol": tol}


# Each FMU also runs at these solver settings besides its scene defaults (rodas4, tol 1e-6): the faster ones a user
# may pick, each judged against the FMU's own tight run (REFERENCE) in the same table. ros34pw2 1e-3: where the
# communication step bounds the steps (hills3d) a looser tolerance still converges; where it does not, the table
# says so.
FMU_SETTINGS = dict(solver_setting(m, tol) for m, tol in
                    (("rodas4", 1e-4), ("ros34pw2", 1e-5), ("ros34pw2", 1e-4), ("ros34pw2", 1e-3)))
REFERENCE = solver_setting("rodas4", 1e-9)
CONVERGED = 1e-3         # peak Fn within this (relative) of the reference run: "forces converged"


def side_by_side(build: Path, stop_time=SIDE_STOP, dts=MUJOCO_DTS, log=print, quiet=False) -> dict:
    """Every row of the table: MuJoCo on the bump (height field), on a plane and on the hills grid (height field)
    at each dt, and each FMU at its defaults ("FMU <scene>"), at FMU_SETTINGS and at the REFERENCE settings;
    label -> Result (None: the FMU is not built). An FMU row's extra["peak_rel"] is its peak Fn's relative
    difference from the reference run's."""
    from cedra.reports import mujoco_model as mm
    from cedra.models.scene import load_shipped
    from cedra.run.progress import Progress
    rows = {}
    progress = Progress(len(MUJOCO_RUNS) * len(dts) + len(FMU_RUNS) * (len(FMU_SETTINGS) + 2),
                        "bench side by side", unit="runs", quiet=quiet)
    for name, (scene, terrain) in MUJOCO_RUNS.items():
        sc = load_shipped(scene)
        for dt in dts:
            label = f"MuJoCo {name} {dt * 1e3:g} ms"
            rows[label] = mm.run(sc, terrain, dt, stop_time, label=label)
            log(f"  ... {label}: {rows[label].cpu:.2f} s CPU")
            progress(len(rows))
    for name in FMU_RUNS:
        path = fmu_path(build, name)
        ref_label = f"FMU {name} {REFERENCE[0]} (reference)"
        runs = {f"FMU {name}": {}, **{f"FMU {name} {k}": v for k, v in FMU_SETTINGS.items()},
                ref_label: REFERENCE[1]}
        for label, settings in runs.items():
            rows[label] = fmu_closed_loop(path, stop_time, settings, label=label) if path.exists() else None
            if rows[label] is not None:
                log(f"  ... {label}: {rows[label].cpu:.2f} s CPU")
            progress(len(rows))
        ref = rows[ref_label]
        for label in runs:
            r = rows[label]
            if r is not None and ref is not None and ref.ok:
                r.extra["peak_rel"] = abs(r.peak_fn / ref.peak_fn - 1.0)
    progress.done()
    return rows


def converged(r) -> bool:
    return r is not None and r.ok and r.extra.get("peak_rel", math.inf) <= CONVERGED


def side_by_side_table(rows: dict, stop_time: float) -> list[str]:
    """The table (markdown) and the ratios MuJoCo CPU / FMU CPU of the matching pairs: at the FMU's defaults, and
    at its fastest converged setting (peak Fn within CONVERGED of its reference run)."""
    tx = min(X_AT, stop_time)
    out = [f"| run | CPU s | real-time factor | x at {tx:g} s (m) | peak Fn (N) | steps (rejected) | peak Fn vs "
           f"{REFERENCE[0]} |", "|---|---|---|---|---|---|---|"]
    for label, r in rows.items():
        if r is None:
            out.append(f"| {label} | not built (python -m cedra build {label.split()[1]}) | | | | | |")
            continue
        steps = f"{r.steps}" + (f" ({r.extra['rejected']})" if "rejected" in r.extra else "")
        note = "" if r.ok else f" STOPPED at {r.simulated:g} s: {r.message}"
        rel = f"{r.extra['peak_rel']:.1e}" if "peak_rel" in r.extra else ""
        out.append(f"| {label}{note} | {r.cpu:.3f} | {r.simulated / r.cpu:.1f} | {r.x_at(tx):.4f} | "
                   f"{r.peak_fn:.1f} | {steps} | {rel} |")
    out.append("")
    for fmu, mj in PAIRS:
        a, b = rows.get(f"FMU {fmu}"), rows.get(mj)
        if a is None or b is None:
            continue
        at_defaults = "" if not fmu.endswith("3d") else (f"; target x{DEFAULTS_TARGET:g}: " + (
            "met" if b.cpu / a.cpu >= DEFAULTS_TARGET else "NOT met"))
        out.append(f"- {mj} / FMU {fmu} CPU: x{b.cpu / a.cpu:.1f} at the scene defaults{at_defaults}")
        fast = [(rows[k].cpu, k) for k in rows if k.startswith(f"FMU {fmu} ") and "(reference)" not in k
                and converged(rows[k])] + ([(a.cpu, f"FMU {fmu}")] if converged(a) else [])
        if fast:
            cpu, k = min(fast)
            target = TARGETS.get(fmu)
            verdict = "" if target is None else (f"; target x{target:g}: " +
                                                 ("met" if b.cpu / cpu >= target else "NOT met"))
            setting = k[len(f"FMU {fmu}"):].strip() or "defaults"
            out.append(f"- {mj} / FMU {fmu} CPU: x{b.cpu / cpu:.1f} at the fastest converged setting ({setting}: "
                       f"peak Fn within {rows[k].extra['peak_rel']:.1e} of {REFERENCE[0]}){verdict}")
        else:
            out.append(f"- {mj} / FMU {fmu}: no setting converged (peak Fn within {CONVERGED:g} of "
                       f"{REFERENCE[0]})")
    return out


def print_side_by_side(build: Path, stop_time: float, dts=MUJOCO_DTS, quiet=False) -> int:
    from cedra.reports import mujoco_model as mm
    if not mm.available():
        print("\nMuJoCo side by side: skipped, mujoco is not installed (pip install -e '.[bench]'; ./build.sh "
              "installs it)")
        return 0
    import mujoco
    print(f"\nMuJoCo side by side: the paper's run, {stop_time:g} s, the paper's speed "
          f"controller every 0.01 s; MuJoCo {mujoco.__version__} (cedra.reports.mujoco_model, Euler, settled "
          f"{mm.SETTLE:g} s untimed), FMUs at their scene defaults (\"FMU <scene>\"), at faster settings and at "
          f"{REFERENCE[0]} (the reference each row's peak Fn is compared with); CPU = time.process_time; peak Fn = "
          f"the largest wheel normal force at the 0.01 s samples")
    rows = side_by_side(build, stop_time, dts, log=(lambda *a: None) if quiet else print, quiet=quiet)
    print("\n".join(side_by_side_table(rows, stop_time)))
    return 0 if all(r is not None and r.ok for r in rows.values()) else 1
