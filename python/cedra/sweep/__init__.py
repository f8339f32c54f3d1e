"""Scenario sweeps on Dask: `python -m cedra sweep <sweep.toml> [--scheduler tcp://host:port] [--workers N]
[--resume | --overwrite] [--quiet] [--check-tol TOL]`.

A sweep file names what one run runs, the parameters to vary (a grid and/or seeded random samples), the summary
outputs to keep per run and where to write them:

    scene = "bump2d"                 # a shipped scene, or a scene file (relative to the sweep file); or instead
    # scenario = "turn_flat"         # a scenario script of examples/ that declares PARAMETERS, SUMMARY and FMUS
    #                                  (names, or (scene, {options}) for a variant: variant_fmu)
    stop_time = 15.0                 # s simulated per run (default: the scene's)
    outputs = ["climbed", "t_over", "peak_Fn", "final_x"]     # default: all of OUTPUTS
    out = "out/climb"                # the table: <out>/<name>.csv (relative to the working directory)
    run_timeout = 120.0              # s of wall time per run; a run past it is recorded as failed (default 300)
    [options]                        # scene runs only: the scene's boolean build options (SWEEP_OPTIONS of
    drives = true                    # cedra.models.scene); the sweep builds and runs that variant of the scene
    [fixed]                          # the same value in every run
    tau_max = 4.0
    [grid]                           # every combination: a list, or {from, to, num} (num points, both ends in)
    terrain_h = {from = 0.0, to = 0.195, num = 14}
    mu = [0.2, 0.6, 1.0]
    [random]                         # `samples` draws, uniform in [lo, hi], numpy's default_rng(seed)
    samples = 50
    seed = 1
    ground_k = [5e4, 2e5]

With both [grid] and [random], every grid point is combined with every draw. For a scene, the parameters are the
scene FMU's inputs and parameters (mu, terrain_h, terrain_w, ground_k, start.yaw, ...) and the main job's
controller settings (CONTROLLER: tau_max, v_ref); each run is the main job's run (docs/model.md: a PI speed loop,
equal torques clipped at tau_max) on that scene, summarized as OUTPUTS. For a scenario script, the parameters and
outputs are its own PARAMETERS and SUMMARY, and each run is its run(params=...). A bad sweep file fails before
any run (and before any build) naming the file, the key and the reason.

[options] makes a variant of the scene: its file parsed again with those keys set (the scene's own checks apply:
drives with locked_wheels fails, for instance), under its own model name (<scene>_drives; <scene>_nodrives for
drives = false on a scene that has them), built into <build>/variants/ and rebuilt only when its model or the FMU
sources changed. The options are part of every run's id, so the runs of two variants never mix in a table. A
scene file's FMU is kept the same way, in <build>/scenes/ (a heightmap scene's is built every time: its grid file
is not in the FMU's GUID).

Runs execute on Dask: a LocalCluster with one single-threaded worker process per core by default, or an existing
cluster with --scheduler (the same code; the workers need this package installed, e.g. `pip install -e .` in a
clone of the same commit; a scene's FMU is sent to them, no shared disk is needed; a scenario script reads its
FMUs from the build directory, which the workers then need at the same path). Results are appended to the CSV as
runs finish, so an interrupted sweep loses nothing, and --resume runs only the runs missing from the table (a run
is identified by a hash of its scene, its [options], stop time and parameter values). A run that fails (the FMU
refuses a step, the run times out, or its worker process dies) is recorded with its status and reason and the
sweep goes on.

A sweep with a [map] draws it (<out>/<name>.png, cedra.sweep.maps) and writes its report next to it
(<out>/<name>.md, cedra.sweep.report). --check-tol TOL runs every run again at solver.tol = TOL (the table
<out>/<name>_tol<TOL>.csv) and the report says whether every verdict is the same.

The modules, from the bottom up:

  verdicts    what a scene run ended as, the criteria that stop a run that will not climb
  maps        the [map]: its keys, each run's cell, the drawing
  definition  the sweep file: its keys and checks, the runs and their ids, a scene's variant, the tightened check
  worker      one run on a worker: the main job's run on a scene's FMU, or a scenario script's
  fmus        the FMUs a sweep runs: shipped, a scene file's, a variant's
  client      the sweep on Dask, from the client: each result appended to the table as it arrives
  report      the map's report
  command     the command: all of the above in order
"""
from cedra.sweep.client import columns, execute, read_table
from cedra.sweep.command import add_parser, main
from cedra.sweep.definition import CHECKS, CONTROLLER, OUTPUTS, Sweep, SweepError, Target, load, resolve, settable, \
    tightened, variant
from cedra.sweep.fmus import sweep_fmu, variant_fmu
from cedra.sweep.worker import obstacle_end, run_one, run_scenario

__all__ = ["CHECKS", "CONTROLLER", "OUTPUTS", "Sweep", "SweepError", "Target", "add_parser", "columns", "execute",
           "load", "main", "obstacle_end", "read_table", "resolve", "run_one", "run_scenario", "settable",
           "sweep_fmu", "tightened", "variant", "variant_fmu"]
