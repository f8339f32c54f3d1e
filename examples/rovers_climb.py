"""CEDRA and the rocker-bogie over one obstacle, each with its drive controller in its three modes: equal torques
from the speed loop (ctrl.mode 0, the paper's run), the inverse kinematics with a rate loop per wheel (ctrl.mode 1)
and traction control (ctrl.mode 2: the speed loop's summed torque at one friction ratio on every wheel).

    python examples/rovers_climb.py          (or: python -m cedra simulate rovers_climb)

The obstacle is the paper's bump (obstacle = 0: plants bump2d and rb_bump2d), step2d's sharp step (obstacle = 1:
step2d and rb_step2d) or stairs2d's 4 stairs (obstacle = 2: stairs2d and rb_stairs2d), its
height terrain_h (the stairs' rise), the ground's mu; each plant with its own controller FMU (drive2d,
rb_drive2d) at the commanded speed for 15 s. The plants have their drives (the motors' torque-speed envelope clips
the commands, within +-4 N.m) and chassis contact: the sweeps' variant <scene>_drives_chassis, built into
build/variants/ on first use. Prints and returns, per rover and mode, whether every wheel center got past the
obstacle, when, whether the rover tipped over (the plant stops there: an outcome, not a failure), the peak wheel
load, the mean slip speed, the motors' work per metre and the largest forward speed. Sweep it over the
obstacle's height and mu: examples/sweeps/rovers/climb_controllers_{bump,step,stairs}.toml (`python -m cedra
report rovers` runs them).
"""
from __future__ import annotations


SPEED = 0.2                 # m/s
STOP_TIME = 15.0
ROVERS = {"CEDRA": ("drive2d", {0: "bump2d", 1: "step2d", 2: "stairs2d"}),
          "rocker-bogie": ("rb_drive2d", {0: "rb_bump2d", 1: "rb_step2d", 2: "rb_stairs2d"})}
MODES = {"equal torques": 0, "inverse kinematics": 1, "traction control": 2}
KINDS = {0: "bump", 1: "step", 2: "stairs"}
STAIRS_STEPS = 4            # stairs2d's and rb_stairs2d's
# the plants' variant: the drives' torque-speed envelope (a wheel's torque falls to 0 at the no-load speed: without
# it a wheel in the air or stalled against the step spins up without bound) and the body and links touching
PLANT_OPTIONS = {"drives": True, "chassis": True}
FMUS = tuple((plant, PLANT_OPTIONS) for _, plants in ROVERS.values() for plant in plants.values()) + \
    tuple(controller for controller, _ in ROVERS.values())                             # what run() opens
PARAMETERS = {"obstacle": (0, 0, 2, "0: the paper's bump (width 2.25 R_w), 1: step2d's sharp step, 2: stairs2d's "
                           "4 stairs (run 4 R_w)"),
              "terrain_h": (0.14625, 0.0, 0.3, "m, the obstacle's height"),
              "mu": (0.8, 0.05, 2.0, "friction coefficient of the ground"),
              "speed_cmd": (SPEED, 0.05, 0.4, "m/s, commanded speed")}
QUANTITIES = {"climbed": "1 if every wheel center got past the obstacle's end, else 0",
              "t_over": "s, when the last wheel center got past it (NaN: never)",
              "peak_Fn": "N, largest wheel load", "mean_slip": "m/s, mean |wheel slip|",
              "work_per_m": "J/m, the motors' work per metre travelled", "x_end": "m, body.x at the end",
              "peak_speed": "m/s, largest body.vx (the commanded speed is speed_cmd)",
              "tipped": "1 if the rover tipped over (the plant stops there), else 0"}
SUMMARY = {f"{rover}.{mode}.{q}": f"{what} ({rover}, {mode})" for rover in ROVERS for mode in MODES
           for q, what in QUANTITIES.items()}


def run(out_dir="out/rovers_climb", build_dir="build", stop_time=None, quiet=False, watch=True, params=None) -> dict:
    """params: values of PARAMETERS (a sweep's run); watch: unused (the 3D view draws CEDRA only)."""
    from cedra.reports.rovers import drive
    from cedra.run.scenario import ScenarioError, parameters
    p = parameters(PARAMETERS, params)
    obstacle = int(round(p["obstacle"]))
    if obstacle not in KINDS:
        raise ScenarioError(f"rovers_climb: obstacle must be 0 (bump), 1 (step) or 2 (stairs), got {p['obstacle']}")
    summary = {}
    for rover, (controller, plants) in ROVERS.items():
        summary[rover] = {}
        for mode_name, mode in MODES.items():
            m = drive(plants[obstacle], controller, mode, p["terrain_h"], build_dir, stop_time or STOP_TIME,
                      kind=KINDS[obstacle], mu=p["mu"], speed=p["speed_cmd"], options=PLANT_OPTIONS,
                      steps=STAIRS_STEPS if KINDS[obstacle] == "stairs" else 1)
            summary[rover][mode_name] = {q: m[q] for q in QUANTITIES}
            if not quiet:
                ended = f"over at {m['t_over']:.2f} s" if m["climbed"] else "tipped" if m["tipped"] else "not over"
                print(f"rovers_climb ({KINDS[obstacle]} {p['terrain_h']:.3f} m, mu {p['mu']}), {rover}, {mode_name}: "
                      f"{ended}, peak Fn {m['peak_Fn']:.1f} N, slip {m['mean_slip']:.4f} m/s, work "
                      f"{m['work_per_m']:.2f} J/m")
    return summary


if __name__ == "__main__":
    run()
