"""What `python -m cedra optimize` writes: the summary (result.json), the optimal torques (torques.csv), the
figure (climb.png: the torques, the body paths against the controllers', the replay's deviation) and the report
page (report.md), which states both agreements (the replay against the optimizer's integration of the torques,
and the NLP's node states against the replay at the node times) so that a run that is not converged cannot be
read as one."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from cedra.optimize.fmu_runs import FN_MIN
from cedra.optimize.problem import Problem

def arrival(m: dict) -> str:
    """A run's arrival as the report and the progress lines write it."""
    return f"t = {m['time']:.2f} s" if m["arrived"] else "never"


def write(out: Path, problem: Problem, summary: dict, result: dict, path, replayed, runs):
    """The command's outputs in `out`: result.json (the summary), torques.csv (the optimal torques per
    interval), climb.png (_figure) and report.md (report_text)."""
    import json
    out.mkdir(parents=True, exist_ok=True)
    (out / "result.json").write_text(json.dumps(summary, indent=2) + "\n")
    t = np.arange(result["U"].shape[0]) * result["dt"]
    np.savetxt(out / "torques.csv", np.column_stack([t, result["U"]]), delimiter=",", fmt="%.10g",
               header="t_start,tau1_tau3,tau2_tau4,tau5,tau6", comments="")
    _figure(out / "climb.png", summary, result, path, replayed, runs)
    (out / "report.md").write_text(report_text(problem, summary))


def _figure(file: Path, summary, result, path, replayed, runs):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axs = plt.subplots(3, 1, figsize=(9, 9))
    n, dt = result["U"].shape[0], result["dt"]
    tt = np.arange(n + 1) * dt
    for j, label in enumerate(["tau[1] = tau[3]", "tau[2] = tau[4]", "tau[5]", "tau[6]"]):
        axs[0].step(tt, np.r_[result["U"][:, j], result["U"][-1, j]], where="post", label=label)
    axs[0].set_ylabel("optimal torque [N.m]")
    axs[0].set_xlabel("time [s]")
    axs[0].legend(fontsize=8, ncol=4)
    axs[0].set_title(f"{summary['problem']}: {summary['objective']}, {summary['status']}, "
                     f"{summary['iterations']} iterations")
    names, rows = replayed
    col = {nm: rows[:, j] for j, nm in enumerate(names)}
    for mode, (nm, rw, _) in runs.items():
        c = {a: rw[:, j] for j, a in enumerate(nm)}
        axs[1].plot(c["body.x"], c["body.z"], lw=1, label=mode.replace("_", " "))
    axs[1].plot(path[0], path[1], "k", lw=2, label="optimum (optimizer)")
    axs[1].plot(col["body.x"], col["body.z"], "r--", lw=1, label="optimum (FMU replay)")
    axs[1].axvline(summary["goal_x"], color="gray", ls=":", label="goal")
    axs[1].set_xlim(min(path[0]) - 0.1, summary["goal_x"] + 0.2)
    axs[1].set_xlabel("body.x [m]")
    axs[1].set_ylabel("body.z [m]")
    axs[1].legend(fontsize=8)
    k = min(path.shape[1], rows.shape[0])
    axs[2].semilogy(col["time"][:k], np.maximum(np.hypot(col["body.x"][:k] - path[0, :k],
                                                          col["body.z"][:k] - path[1, :k]), 1e-12))
    axs[2].set_ylabel("|FMU - optimizer| body (x, z) [m]")
    axs[2].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(file, dpi=90)
    plt.close(fig)


def report_text(problem: Problem, s: dict) -> str:
    rows = [("optimum (FMU replay)", s["optimum"])] + [(f"{m.replace('_', ' ')} controller", v)
                                                        for m, v in s["controllers"].items()]
    lines = [f"# Optimal climb: {s['problem']}", "",
             f"Scene {s['scene']}, objective `{s['objective']}`, goal body.x >= {s['goal_x']:.3f} m, "
             f"|tau| <= {s['torque_max']:g} N.m, {s['intervals']} intervals of {s['horizon'] / s['intervals']:.4g} s "
             f"(horizon {s['horizon']:.3f} s), initial guess: the {s['guess'].replace('_', ' ')} run.", "",
             "## Solve", "",
             f"- IPOPT: **{s['status']}** after {s['iterations']} iterations, {s['solve_time']:.1f} s "
             f"(whole command {s['wall']:.1f} s); NLP objective {s['nlp_objective']:.6g}, constraint violation "
             f"{s['violation']:.1e}",
             "- contact law of the optimizer's equations: "
             + ("the FMU's (no smoothing)" if s["smoothing"] == 0 else
                f"smoothed over {s['smoothing']:g} m (the FMU replay integrates the unsmoothed law)"),
             f"- shooting integrator: CVODES, abstol = reltol = {s['integrator_tol']:g}",
             f"- replay through the FMU (open loop, the scene's own solver settings): "
             f"{'completed' if s['replay_ok'] else 'STOPPED EARLY'}; the body path (x, z) stays within "
             f"**{s['replay_deviation']:.2e} m** of the optimizer's "
             f"({'holds' if s['replay_deviation'] <= 1e-4 else 'DOES NOT hold'} the 1e-4 m agreement)",
             f"- the NLP's node states against the replay at the node times: within **{s['node_deviation']:.2e} m** "
             + ("(the shooting defects are closed: the nodes are on the integrated path)"
                if s["violation"] <= 1e-5 and s["node_deviation"] <= 1e-4 else
                "(the shooting defects are NOT closed: the nodes are not on the torques' integrated path, and "
                "the solve is no certified optimum)"), "",
             *_stage_lines(s["stages"]),
             "## Against the controllers (same FMU, same measures)", "",
             "Measured on the FMU runs recorded every 0.01 s, up to the arrival (body.x first at the goal). "
             "energy: the integral of sum tau_i^2 over the six wheels; peak |Fx|/Fn: over wheels carrying more "
             f"than {FN_MIN:g} N; work: the motors' mechanical work (energy.work).", "",
             "| run | arrives | energy [N^2.m^2.s] | peak abs(Fx)/Fn | work [J] | peak torque [N.m] |",
             "|---|---|---|---|---|---|"]
    for label, m in rows:
        lines.append(f"| {label} | {arrival(m)} | {m['energy']:.3f} | {m['peak_friction']:.3f} | {m['work']:.3f} "
                     f"| {m['peak_torque']:.2f} |")
    lines += ["", "![optimal torques and trajectory](climb.png)", "",
              f"Reproduce: `python -m cedra optimize {problem.path}`", ""]
    return "\n".join(lines)


def _stage_lines(stages) -> list[str]:
    if stages and "round" in stages[0]:
        lines = ["Hybrid multiple shooting, the contact-mode sequence fixed; each round after the first solved on the "
                 "mode sequence of the previous round's FMU replay, from its solution:", "",
                 "| round | events | phases | IPOPT | iterations | time [s] | constraint violation (largest) "
                 "| objective | the replay's events |", "|---|---|---|---|---|---|---|---|---|"]
        for st in stages:
            lines.append(f"| {st['round']} | {st['events']} | {st['phases']} | {st['status']} | {st['iterations']} "
                         f"| {st['wall']:.1f} | {st['violation']:.1e} ({st['worst']}) | {st['objective']:.6g} "
                         f"| {st['replay_events']}{'' if st['same_sequence'] else ', another sequence'}"
                         f"{'; on a bound: ' + ', '.join(st['at_bound']) if st['at_bound'] else ''} |")
        return lines + [""]
    if len(stages) < 2:
        return []
    lines = ["Continuation (each stage started from the previous one's solution and multipliers):", "",
             "| stage | smoothing width [m] | Hessian | proximal | IPOPT | iterations | time [s] "
             "| constraint violation | objective |", "|---|---|---|---|---|---|---|---|---|"]
    for k, st in enumerate(stages):
        lines.append(f"| {k + 1} | {st['width']:g} | {st['hessian']} | {st['proximal']:g} "
                     f"| {st['status']} | {st['iterations']} | {st['wall']:.1f} | {st['violation']:.1e} "
                     f"| {st['objective']:.6g} |")
    return lines + [""]
