"""Stability campaign: stiff and extreme cases through the FMU, every embedded solver.

    python -m cedra report stability [--quick] [--build build] [--out out/report]

writes <out>/stability.md (one row per case and solver) and <out>/stability.csv, and prints a summary.
Every case starts from a state computed in Python (the settled pose with the case's parameters, plus the case's
offsets) given to the FMU as start.<q> / start.speed.<q> with start.settle = false.
"""
from __future__ import annotations

import csv
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cedra.contract import CHECK_REASONS
from cedra.models.scene import load_shipped
from cedra.pages import load_average, md_table, provenance
from cedra.run.progress import Progress
from cedra.reports.common import Problem, Schedule, announce, fmt, fmu_path, run_fmu, torques

ENERGY_REL_TOL = 1e-5      # allowed energy increase, relative to |E(0)|, in zero-torque dissipative cases
WALL_BUDGET = 60.0         # s of wall time per run; a run still going is stopped and reported as such

SOLVERS = {                 # name -> (method, tol, h_max): the scene defaults; rk4 at a step it can survive
    "rodas4": ("rodas4", 1e-6, 0.01),
    "dopri5": ("dopri5", 1e-6, 0.01),
    "rk4": ("rk4", 1e-6, 1e-4),
}


@dataclass
class Case:
    name: str
    scene: str = "bump2d"
    overrides: dict = field(default_factory=dict)       # parameters and inputs by name
    schedule: Schedule = field(default_factory=lambda: Schedule([0.0], [torques(0.0)]))
    t_end: float = 3.0
    comm: float = 0.01
    dz: float = 0.0                 # raise the settled pose by dz (a drop)
    speed: float = 0.0              # initial forward speed, wheels rolling without slip
    energy: bool = False            # zero torque, dissipative contact: the energy must not increase
    meaningful: bool = True         # the implicit solver must finish it
    note: str = ""


def _steps(t_end, dt, fn):
    n = int(round(t_end / dt))
    return Schedule([round(k * dt, 10) for k in range(n)], [fn(k * dt) for k in range(n)])


def cases(quick=False) -> list[Case]:
    R = 0.065
    coast = dict(terrain_x0=0.6)
    cs: list[Case] = []
    for k in (1e4, 1e5, 1e6, 1e7, 1e8):
        cs.append(Case(f"ground_k {k:g}, coast 1 m/s onto the bump", overrides=coast | {"ground_k": k}, speed=1.0,
                       energy=True))
    for v in (1e-2, 1e-3, 1e-4, 1e-5):
        cs.append(Case(f"v_eps {v:g}, coast 1 m/s onto the bump", overrides=coast | {"v_eps": v}, speed=1.0,
                       energy=True))
    for mu in (0.05, 0.3, 0.8, 1.5):
        cs.append(Case(f"mu {mu:g}, 2 N.m torque step at 0.5 s", overrides={"mu": mu},
                       schedule=Schedule([0.0, 0.5], [torques(0.0), torques(2.0)])))
    for hr in (0.0, 1.0, 2.0, 3.0):
        cs.append(Case(f"steep narrow bump h = {hr:g} R_w (w = 0.5 R_w), 1.5 N.m", t_end=6.0,
                       overrides={"terrain_h": hr * R, "terrain_w": 0.5 * R, "terrain_x0": 0.6},
                       schedule=Schedule([0.0], [torques(1.5)])))
    cs.append(Case("drop from 0.3 m, zero torque", dz=0.3, t_end=2.0, energy=True))
    cs.append(Case("drop from 0.3 m onto ground_k 1e7, zero torque", dz=0.3, t_end=2.0, energy=True,
                   overrides={"ground_k": 1e7}))
    for tau in (5.0, 10.0, 20.0, 50.0):      # where the rover's domain ends (it flips: a loud discard)
        cs.append(Case(f"torque step 0 -> {tau:g} N.m at 0.5 s", t_end=2.0,
                       schedule=Schedule([0.0, 0.5], [torques(0.0), torques(tau)])))
    cs.append(Case("torque spikes +-50 N.m for 0.1 s every 0.5 s", t_end=3.0,
                   schedule=_steps(3.0, 0.1, lambda t: torques(
                       (50.0 if int(round(t / 0.5)) % 2 == 0 else -50.0) if abs(t / 0.5 - round(t / 0.5)) < 1e-9
                       else 0.3))))
    for comm in (1e-4, 1e-3, 1e-2, 1e-1, 1.0):
        cs.append(Case(f"comm step {comm:g} s, 0.5 N.m", comm=comm, t_end=3.0,
                       schedule=Schedule([0.0], [torques(0.5)])))
    cs.append(Case("long run 60 s, bump2d, 0.4 N.m", t_end=60.0, schedule=Schedule([0.0], [torques(0.4)])))
    cs.append(Case("long run 60 s, flat3d, steering 0.3 rad, 0.3 N.m", scene="flat3d", t_end=60.0,
                   schedule=Schedule([0.0], [torques(0.3, **{"steer[1]": 0.3, "steer[2]": 0.3})])))
    cs.append(Case("long run 60 s, flat3d, coast 1 m/s, zero torque", scene="flat3d", t_end=60.0, speed=1.0,
                   energy=True))
    if quick:
        keep = ("ground_k 1e+08", "v_eps 1e-05", "drop from 0.3 m, zero torque")
        cs = [c for c in cs if c.name.startswith(keep)]
        for c in cs:
            c.t_end = min(c.t_end, 1.0)
    return cs


@dataclass
class Result:
    case: Case
    solver: str
    finished: bool
    status: str
    reason: str
    steps: int
    rejected: int
    wall: float
    reached: float
    e_increase: float | None
    e_tol: float | None
    e_ref: float | None       # the same measure on the Python reference (cvodes 1e-10): the equations' own
    nan: bool
    nan_at: float | None
    timeout: bool = False     # stopped by the report's wall budget (the FMU was still integrating)

    @property
    def energy_ok(self):
        return self.e_increase is None or self.e_increase <= self.e_tol + (self.e_ref or 0.0)

    @property
    def outside_domain(self):
        """Stopped loudly because the state left the model's domain (cedra_check: the rover tipped over, or the
        fork passed its toggle): the model, not the solver, ends there (contract.CHECK_REASONS)."""
        return self.status == "discard" and any(r in self.reason for r in DOMAIN_REASONS)

    @property
    def acceptable(self):
        """The issue's rule: never NaN; the energy never grows; the implicit solver finishes every meaningful
        case; an explicit solver may stop, but only with status discard and a message. A run that leaves the
        model's domain (tipped over) is not physically meaningful past that point: a loud discard is right."""
        if self.nan or not self.energy_ok:
            return False
        if self.finished or self.outside_domain:
            return True
        if self.solver == "rodas4" and self.case.meaningful:
            return False
        if self.timeout:          # explicit and still grinding: no NaN, no crash, but no loud failure either
            return True
        return self.status == "discard" and bool(self.reason)


DOMAIN_REASONS = [why for code, why in CHECK_REASONS.items() if code < 0]
_PROBLEMS: dict = {}


def start_state(case: Case):
    key = (case.scene, tuple(sorted(case.overrides.items())))
    if key not in _PROBLEMS:
        _PROBLEMS[key] = Problem(load_shipped(case.scene), case.overrides)
    prob = _PROBLEMS[key]
    q0 = prob.settle()
    q0[prob.q_names.index("z")] += case.dz
    u0 = np.zeros(prob.nq)
    if case.speed:
        R = prob.par[prob.pnames.index("R_w")]
        u0[prob.q_names.index("x")] = case.speed
        for k, n in enumerate(prob.q_names):
            if n.startswith("gamma"):
                u0[k] = case.speed / R
    return prob, q0, u0


_EREF: dict = {}


def reference_energy_increase(case: Case):
    """Max energy increase of the same case on the Python side (CasADi cvodes, tol 1e-10), sampled at the same
    communication points: what the equations themselves do (the compliant contact on a curved terrain is not
    exactly passive), so that the FMU is only charged with what its solver adds."""
    if case.name in _EREF:
        return _EREF[case.name]
    from cedra.reports.common import grid, python_run_outputs, run_casadi
    prob, q0, u0 = start_state(case)
    tg = grid(case.t_end, min(case.comm, 0.01))
    r = run_casadi(prob, case.schedule, prob.x0(q0, u0), tg, "cvodes", 1e-10)
    val = None
    if r.ok:
        Y = python_run_outputs(prob, case.schedule, r, ["energy.kinetic", "energy.potential"]) \
            if "energy.kinetic" in prob.out_names else None
        if Y is None:     # cedra_out appends kinetic, potential, work after the named outputs
            inps = np.array([prob.inp(case.schedule.at(t)) for t in r.t])
            Yall = prob.outputs_many(r.X, inps)
            E = Yall[:, len(prob.out_names)] + Yall[:, len(prob.out_names) + 1]
        else:
            E = Y[:, 0] + Y[:, 1]
        val = float(np.max(E - np.minimum.accumulate(E)))
    _EREF[case.name] = val
    return val


def run_case(case: Case, solver: str, build="build", budget=WALL_BUDGET) -> Result:
    """One case with one solver through the FMU."""
    prob, q0, u0 = start_state(case)
    method, tol, h_max = SOLVERS[solver]
    rec = ["energy.kinetic", "energy.potential"]
    r = run_fmu(fmu_path(build, case.scene), prob, case.schedule, q0, case.t_end, case.comm, method, tol, h_max,
                record=rec, u0=u0, check_all=True, wall_budget=budget)
    e_inc = e_tol = None
    if case.energy and len(r.Y):
        E = r.Y[:, 0] + r.Y[:, 1]
        E = E[np.isfinite(E)]
        if len(E):
            e_inc = float(np.max(E - np.minimum.accumulate(E)))
            e_tol = ENERGY_REL_TOL * abs(float(E[0]))
    e_ref = reference_energy_increase(case) if case.energy else None
    reason = r.message if not r.ok else ""
    if r.extra.get("timeout"):
        reason = f"stopped by the report after {budget:g} s wall (still running at t = {r.extra['reached']:g} s)"
    return Result(case, solver, r.ok, r.status, reason, r.steps, r.extra.get("rejected", -1), r.wall,
                  r.extra.get("reached", 0.0), e_inc, e_tol, e_ref, bool(r.extra.get("nan")), r.extra.get("nan_at"),
                  bool(r.extra.get("timeout")))


HEADER = ["case", "solver", "comm [s]", "t_end [s]", "finished", "reached [s]", "FMU status", "reason (FMU log)",
          "steps", "rejected", "wall [s]", "max energy increase [J]", "reference's [J]", "energy tol [J]",
          "NaN ever", "verdict"]


def write(results, out_dir: Path, command, wall_total, load_at_start=float("nan")):
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for r in results:
        c = r.case
        rows.append([c.name + (f" ({c.scene})" if c.scene != "bump2d" else ""), r.solver, fmt(c.comm), fmt(c.t_end),
                     fmt(r.finished), fmt(r.reached), r.status, r.reason[:160] or "-", fmt(r.steps),
                     fmt(r.rejected), fmt(r.wall), fmt(r.e_increase) if r.e_increase is not None else "-",
                     fmt(r.e_ref) if r.e_ref is not None else "-",
                     fmt(r.e_tol) if r.e_tol is not None else "-",
                     fmt(r.nan) + (f" at {r.nan_at:g} s" if r.nan else ""),
                     ("outside domain" if r.outside_domain else "slow" if r.timeout else "ok")
                     if r.acceptable else "**FAIL**"])
    bad = [r for r in results if not r.acceptable]
    md = ["# Stability report", "",
          provenance(command, wall_total, load_at_start) + " Every figure is measured in that run.", "",
          "Each case runs through the FMU (FMPy) from a start state computed in Python: the static equilibrium "
          "with the case's parameters (`cedra_guess`, then Newton on `cedra_settle`), raised by the drop height, "
          "with the initial forward speed and matching wheel spin for coasting cases; the FMU gets it as "
          "`start.<q>`, `start.speed.<q>`, `start.settle = false`. Parameters and inputs not named are the "
          "scene's (bump2d: Gaussian bump, ground_k 1e5 N/m, ground_d 600 N.s/m, v_eps 0.01 m/s, mu 0.8).", "",
          "Solvers: " + ", ".join(f"`{k}` (tol {v[1]:g}, h_max {v[2]:g} s)" if k != "rk4" else
                                  f"`rk4` (fixed step {v[2]:g} s)" for k, v in SOLVERS.items()) + ".", "",
          "Columns: **finished** = reached t_end; **reached** = last communication point reached; **FMU status** "
          "= the status of the failing fmi2DoStep (`ok` if none failed); **reason** = the last lines the FMU "
          "logged; **steps**, **rejected** = `solver.steps`, `solver.rejected` at the end; **wall** = wall time of "
          "the run; **max energy increase** (zero-torque cases with dissipative contact only) = max over t of "
          "E(t) - min over s <= t of E(s), E = energy.kinetic + energy.potential read at every communication "
          "point; **reference's** = the same measure on the Python reference (CasADi cvodes, tol 1e-10, same "
          "start and inputs): what the equations themselves do (the compliant contact rolling onto a curved "
          "terrain is not exactly passive, see the summary); the FMU passes when its increase <= the reference's + "
          f"**energy tol** = {ENERGY_REL_TOL:g} |E(0)|; **NaN ever** = any Real output non-finite at any "
          "communication point. **verdict**: ok when no NaN, no energy growth beyond the tolerance, and either "
          "finished or (explicit solvers only, or a case marked not physically meaningful) stopped with status "
          f"`discard` and a logged reason; **outside domain**: any solver stopped with `discard` because the state "
          "left the model's domain (the rover tipped over beyond 80 deg, or the fork passed its four-bar toggle: "
          "the model has no body-ground contact, so nothing after that point is physical). A run still going "
          f"after {WALL_BUDGET:g} s of wall time is stopped by the report (said in the reason column; verdict "
          "**slow**: an explicit solver on a stiff case that neither finishes nor stops. Every fmi2DoStep has its "
          "own budget, `solver.max_steps` attempted steps and `solver.max_wall_time` seconds, so such a run "
          "normally stops itself with a discard naming the spent budget before the report's limit).", "",
          md_table(HEADER, rows), "",
          "## Summary", "",
          f"- {len(results)} runs, {sum(r.finished for r in results)} finished, {len(bad)} failed the rule "
          f"(never NaN; rodas4 finishes every meaningful case; explicit solvers stop only with discard + message; "
          "no energy growth)."]
    for s in SOLVERS:
        rs = [r for r in results if r.solver == s]
        if rs:
            md.append(f"- {s}: finished {sum(r.finished for r in rs)}/{len(rs)}, "
                      f"discarded {sum(r.status == 'discard' for r in rs)}, stopped by the wall budget "
                      f"{sum(r.timeout for r in rs)}, NaN {sum(r.nan for r in rs)}")
    for r in bad:
        md.append(f"- FAIL: {r.case.name} / {r.solver}: status {r.status}, reason '{r.reason}', NaN {r.nan}, "
                  f"energy increase {r.e_increase}")
    (out_dir / "stability.md").write_text("\n".join(md) + "\n")
    with open(out_dir / "stability.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "scene", "solver", "comm", "t_end", "finished", "reached", "status", "reason", "steps",
                    "rejected", "wall", "energy_increase", "energy_tol", "nan", "acceptable"])
        for r in results:
            w.writerow([r.case.name, r.case.scene, r.solver, r.case.comm, r.case.t_end, r.finished, r.reached,
                        r.status, r.reason, r.steps, r.rejected, r.wall, r.e_increase, r.e_tol, r.nan, r.acceptable])
    return md[-(len(SOLVERS) + 1 + len(bad)):]


def main(args):
    quick = getattr(args, "quick", False)
    out = Path(getattr(args, "out", "out/report"))
    build = getattr(args, "build", "build")
    t0, load0 = time.perf_counter(), load_average()
    quiet = getattr(args, "quiet", False)
    results = []
    missing = set()
    todo = cases(quick)
    announce("report stability", "about a minute on two cores" if quick else
             "about 2-3 minutes on two cores (--quick: the hardest cases only, under a minute)", quiet)
    progress = Progress(len(todo) * len(SOLVERS), "report stability", unit="runs", quiet=quiet)
    for case in todo:
        if not fmu_path(build, case.scene).exists():
            missing.add(case.scene)
            continue
        for solver in SOLVERS:
            r = run_case(case, solver, build)
            results.append(r)
            if not quiet:
                print(f"{case.name[:60]:60s} {solver:7s} {'finished' if r.finished else r.status:9s} "
                      f"{r.wall:7.2f} s steps {r.steps}" + ("" if r.acceptable else "  FAIL") +
                      (f"  [{r.reason[:100]}]" if r.reason else ""), flush=True)
            progress(len(results), f"{sum(not r.acceptable for r in results)} not acceptable")
    progress.done()
    if missing:
        print(f"no FMU for {sorted(missing)} in {build}: build first (python -m cedra build)", file=sys.stderr)
    cmd = "python -m cedra report stability" + (" --quick" if quick else "")
    summary = write(results, out, cmd, time.perf_counter() - t0, load0)
    print(f"wrote {out / 'stability.md'}")
    for s in summary:
        print(s)
    return 1 if missing or any(not r.acceptable for r in results) else 0
