"""`python -m cedra check FMU ...`: every check of cedra.fmu.checks.CHECKS on each FMU, one verdict line per FMU,
the first problem of a failed check, exit status 1 when a check fails and 2 (before any check runs) when a path is
not an FMU. The FMUs are the toy FMU (tests/toy_model.py) and copies of it with a broken modelDescription.xml."""
from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

from cedra.__main__ import main
from cedra.fmu import checks
from fmu_harness import rewrite_md

REPO = Path(__file__).resolve().parents[1]


def _cedra(*args: str, timeout: float) -> subprocess.CompletedProcess:
    """`python -m cedra ARGS` of this checkout."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "python"), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "cedra", *args], capture_output=True, text=True, cwd=REPO,
                          env=env, timeout=timeout)


def _wrong_guid(root):
    root.set("guid", "{00000000-0000-0000-0000-000000000000}")


def _output_dropped(root):
    outputs = root.find("ModelStructure/Outputs")
    outputs.remove(outputs[-1])


def _verdicts(out: str) -> dict[str, str]:
    """FMU path -> its verdict line (after 'path: ')."""
    return {ln.split(": ", 1)[0]: ln.split(": ", 1)[1] for ln in out.splitlines() if not ln.startswith(" ")}


def test_a_good_fmu_passes_every_check(toy):
    r = _cedra("check", str(toy), timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.splitlines() == [f"{toy}: " + ", ".join(f"{name} ok" for name in checks.CHECKS)]


def test_broken_fmus_fail_and_name_the_check(toy, tmp_path, capsys):
    guid = rewrite_md(toy, tmp_path / "wrong_guid.fmu", _wrong_guid)
    dropped = rewrite_md(toy, tmp_path / "output_dropped.fmu", _output_dropped)
    assert main(["check", str(guid), str(toy), str(dropped)]) == 1
    out = capsys.readouterr().out
    assert _verdicts(out) == {
        # the binary refuses a GUID that is not its own; neither checker of the XML can know
        str(guid): "validate ok, vdmcheck ok, roundtrip FAILED",
        str(toy): "validate ok, vdmcheck ok, roundtrip ok",
        # a ModelStructure/Outputs list that misses an output
        str(dropped): "validate FAILED, vdmcheck FAILED, roundtrip ok",
    }
    problems = [ln.strip() for ln in out.splitlines() if ln.startswith(" ")]
    assert len(problems) == 3, out                       # the first problem of each failed check
    assert problems[0].startswith("roundtrip: "), out
    assert problems[1].startswith("validate: ") and "Outputs" in problems[1], out
    assert problems[2].startswith("vdmcheck: validOutputs:"), out


def test_a_path_that_is_not_an_fmu_fails_before_any_check(toy, tmp_path):
    not_zip = tmp_path / "notes.fmu"
    not_zip.write_text("not an archive")
    no_md = tmp_path / "empty.fmu"
    with zipfile.ZipFile(no_md, "w") as z:
        z.writestr("binaries/readme.txt", "no model description")
    missing = tmp_path / "missing.fmu"
    r = _cedra("check", str(toy), str(missing), str(not_zip), str(no_md), timeout=120)
    assert r.returncode == 2
    assert r.stdout == ""                                # not even the good FMU was checked
    assert r.stderr.splitlines() == [f"error: {missing}: no such file",
                                     f"error: {not_zip}: not an FMU (not a zip archive)",
                                     f"error: {no_md}: not an FMU (no modelDescription.xml in the archive)"]
