"""The FMPy driver leaves the process safe for other FMPy users after it is gone (regression: it once re-pointed
fmpy's process-wide native logger proxy at its own callback, and the next FMU that logged crashed)."""
import subprocess
import sys
import textwrap
from pathlib import Path

from fmu_harness import shipped_fmu

REPO = Path(__file__).resolve().parents[1]


def test_fmpy_logging_still_works_after_a_driver_is_gone(tmp_path_factory):
    fmu = shipped_fmu("bump2d", tmp_path_factory)
    script = textwrap.dedent(f"""
        import gc
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        from cedra.run.driver import RoverFMU
        f = RoverFMU({str(fmu)!r})
        f.start()
        assert f.step(0.01)
        f.close()
        del f
        gc.collect()
        md = read_model_description({str(fmu)!r})
        s = FMU2Slave(guid=md.guid, unzipDirectory=extract({str(fmu)!r}),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        s.instantiate()                     # fmpy's default (proxied) callbacks
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        try:
            s.terminate()                   # not allowed in initialization mode: the FMU logs an error
        except Exception:
            pass
        s.freeInstance()
        print("alive")
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       env={"PYTHONPATH": str(REPO / "python"), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0 and "alive" in r.stdout, (r.returncode, r.stderr[-2000:])
