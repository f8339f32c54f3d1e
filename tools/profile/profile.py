"""Instruction counts of one evaluation of a scene's generated functions (cedra_f, cedra_rjac, cedra_switch where
the scene has force-law switches, cedra_out, cedra_M) under callgrind, at a state on the scene's terrain:

    .venv/bin/python tools/profile/profile.py hills3d [--build build] [--reps 20] [--time 6.0]

The state: the FMU's pose at --time s of the paper's closed-loop run (cedra.simulate's speed controller) with
the wheels' spin angles 0 and speeds from the body's velocity, moved by 1e-9 m in x at each repetition (a new pose
each time, as in a run, so the FMU's memo of contact searches is not hit). eval_model.c is compiled with the FMU's sources/
(the generated C, heightmap.c and rim.c) at -O2 (the FMU's flags); callgrind counts the instructions of --reps
evaluations and of 0 (startup, the heightmap fit), and the difference / reps is printed per function, with the
inclusive counts of the most expensive callees (callgrind_annotate)."""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO / "python"))


def state_on_the_run(fmu, t_end):
    from cedra.run.driver import RoverFMU
    from cedra.run.simulate import SAMPLE, SpeedController
    f = RoverFMU(fmu)
    ctrl = SpeedController()
    f.start()
    for k in range(int(round(t_end / SAMPLE))):
        tau = ctrl(f.get(["body.vx"])[0])
        f.set({f"tau[{i}]": tau for i in range(1, 7)})
        assert f.step((k + 1) * SAMPLE), f.messages
    names = {"x": "body.x", "y": "body.y", "z": "body.z", "yaw": "body.yaw", "pitch": "body.pitch",
             "roll": "body.roll", "theta1": "bogie.theta[1]", "theta2": "bogie.theta[2]", "theta4": "fork.theta4"}
    vals = {k: f.get([v])[0] for k, v in names.items()}
    vx, vy, vz = f.get(["body.vx", "body.vy", "body.vz"])
    omega = [f.get([f"wheel[{i}].omega"])[0] for i in range(1, 7)]
    f.close()
    return vals, (vx, vy, vz), omega


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("--build", default=str(REPO / "build"))
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--time", type=float, default=6.0)
    ap.add_argument("--keep", help="a directory to keep the state file, the driver and callgrind's outputs in")
    args = ap.parse_args()
    from cedra.compile import CompileJob, link_program
    from cedra.models.scene import load_shipped
    sc = load_shipped(args.scene)
    spec = sc.spec()
    src = Path(args.build) / args.scene / "sources"
    vals, v, omega = state_on_the_run(Path(args.build) / f"{args.scene}.fmu", args.time)
    qn = spec.q_names
    q = np.array(spec.q_start, float)
    u = np.zeros(len(qn))
    for k, n in enumerate(qn):
        if n in vals:
            q[k] = vals[n]
        if n.startswith("gamma"):
            u[k] = omega[int(n[5:]) - 1]
    for n, vv in zip("xyz", v):
        if n in qn:
            u[qn.index(n)] = vv
    par = np.array([p.start for p in spec.params])
    inp = np.array([p.start for p in spec.inputs])
    for k, p in enumerate(spec.inputs):
        if p.name.startswith("tau["):
            inp[k] = 1.0
    a = np.array(spec.functions["cedra_M"](q, par)).dot(np.zeros(len(qn)))
    with tempfile.TemporaryDirectory() as d:
        d = Path(args.keep or d)
        d.mkdir(parents=True, exist_ok=True)
        state = d / "state.txt"
        state.write_text(f"{len(qn)} {len(inp)} {len(par)}\n" + "\n".join(
            " ".join(repr(float(x)) for x in vec) for vec in (q, u, a, inp, par)) + "\n")
        exe = d / "eval_model"
        # the contact search of several contacts per wheel (rim.c) where the model calls it, as the FMU links it
        units = [HERE / "eval_model.c", *sorted(src.glob("cedra_*.c")), src / "heightmap.c"]
        units += [src / "rim.c"] if (src / "rim.c").exists() else []
        has_switch = (src / "cedra_switch.c").exists()
        flags = ("-std=c99", "-O2", "-Wno-unused-parameter") + (("-DHAS_SWITCH",) if has_switch else ())
        exe.unlink(missing_ok=True)                 # a kept directory's driver is linked again
        link_program([CompileJob(u, flags, src) for u in units], exe)      # in parallel, through the object cache
        grid = str(sc.options.heightmap) if sc.options.heightmap else "-"
        print(f"{args.scene}: state at t = {args.time} s: " + ", ".join(f"{k} {x:.4g}" for k, x in vals.items()))
        for fn in ("f", "rjac") + (("switch",) if has_switch else ()) + ("out", "M"):
            counts = {}
            for reps in (0, args.reps):
                out = d / f"cg.{fn}.{reps}"
                subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", str(exe), str(state),
                                grid, fn, str(reps)], check=True, capture_output=True)
                ann = subprocess.run(["callgrind_annotate", "--inclusive=yes", str(out)], capture_output=True,
                                     text=True).stdout
                total = int(re.search(r"([\d,]+) \(100.0%\)\s+PROGRAM TOTALS", ann).group(1).replace(",", ""))
                counts[reps] = (total, ann)
            per = (counts[args.reps][0] - counts[0][0]) / args.reps
            print(f"\ncedra_{fn}: {per:,.0f} instructions per evaluation")
            skip = ("below main", "libc", "ld-linux", "heightmap_read", "read_number", "strtod", "main [", "fit",
                    "fgetc", "____strtod")
            lines = [ln for ln in counts[args.reps][1].splitlines() if re.match(r"\s*[\d,]+ \(", ln)
                     and not any(s in ln for s in skip)]
            for ln in lines[:8]:
                n = int(ln.split()[0].replace(",", ""))
                print(f"    {n / args.reps:12,.0f} per evaluation  {ln.split(None, 2)[2][:110]}")


if __name__ == "__main__":
    main()
