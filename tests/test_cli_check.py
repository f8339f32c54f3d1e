"""`python -m cedra check FMU ...` (cedra.fmu.compliance): one verdict line per FMU and checker, then a summary; exit
status 1 on any error or warning, 2 (before any check runs) when a path is not an FMU. The FMU is the shipped
drive2d.fmu, and copies of it broken in one way each: every copy is reported by the checker that can see it, with
that checker's own message, and by no other (a VDMCheck2 warning alone fails the command too). docs/fmu.md's sample
output is this command's (times aside)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from cedra.fmu import compliance
from fmu_harness import rewrite_md, shipped_fmu

REPO = Path(__file__).resolve().parents[1]
CHECKERS = compliance.CHECKERS
LINE = re.compile(r"^(?P<fmu>\S+)\s+(?P<checker>[\w-]+)\s+(?P<verdict>ok|FAIL|WARN|skipped|unavailable:)\s*(?P<rest>.*)$")
TIME = re.compile(r"\(\d+\.\d s\)")


def _cedra(*args: str, cwd: Path = REPO, env: dict | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """`python -m cedra ARGS` of this checkout."""
    env = dict(env or os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "python"), os.environ.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "cedra", *args], capture_output=True, text=True, cwd=cwd, env=env,
                          timeout=timeout)


def _verdicts(out: str) -> dict[tuple[str, str], tuple[str, str]]:
    """(FMU, checker) -> (verdict, the rest of the line) of every verdict line."""
    found = {}
    for ln in out.splitlines():
        m = LINE.match(ln)
        if m:
            found[(m["fmu"], m["checker"])] = (m["verdict"], m["rest"])
    return found


@pytest.fixture(scope="module")
def drive2d(tmp_path_factory) -> Path:
    return shipped_fmu("drive2d", tmp_path_factory)


# ------------------------------------------------------------------------------------------------- broken copies

def _wrong_guid(root):
    root.set("guid", "{00000000-0000-0000-0000-000000000000}")


def _wrong_identifier(root):
    root.find("CoSimulation").set("modelIdentifier", "no_such_model")


def _unknown_attribute(root):
    root.set("colour", "red")


def _output_dropped(root):
    outputs = root.find("ModelStructure/Outputs")
    outputs.remove(outputs[-1])


def _without_binary(fmu: Path, out: Path) -> Path:
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            if not item.filename.startswith("binaries/"):
                zout.writestr(item, zin.read(item.filename))
    return out


def _alias_variability(root):
    # tau[2] made an alias of tau[1] (discrete) with another variability: VDMCheck2 warns, nothing else sees it
    variables = root.find("ModelVariables")
    tau1 = variables.find("ScalarVariable[@name='tau[1]']")
    tau2 = variables.find("ScalarVariable[@name='tau[2]']")
    tau2.set("valueReference", tau1.get("valueReference"))
    tau2.set("variability", "continuous")


# (name, how it is broken, {checker: (its verdict, a fragment of its first message)} for the checkers that must
# report it; every other checker must pass)
BROKEN = [
    # the binary refuses a GUID that is not its own; no checker of the XML can know
    ("wrong_guid", _wrong_guid, {"roundtrip": ("FAIL", "fmi2Instantiate failed"),
                                 "libcosim": ("FAIL", "does not match the FMU's GUID")}),
    # a modelIdentifier that names no library in binaries/
    ("wrong_identifier", _wrong_identifier, {"roundtrip": ("FAIL", "no_such_model"),
                                             "libcosim": ("FAIL", "no_such_model")}),
    # no binaries/ at all
    ("no_binary", None, {"roundtrip": ("FAIL", "Cannot find shared library"),
                         "libcosim": ("FAIL", "[FMI Library: FMILIB]")}),
    # a schema error: an attribute the schema does not have
    ("unknown_attribute", _unknown_attribute, {"fmpy-validate": ("FAIL", "colour"), "vdmcheck2": ("FAIL", "colour")}),
    # ModelStructure/Outputs misses an output
    ("output_dropped", _output_dropped, {"fmpy-validate": ("FAIL", "Outputs"),
                                         "vdmcheck2": ("FAIL", "validOutputs")}),
    # a warning alone fails the command too
    ("alias_variability", _alias_variability, {"vdmcheck2": ("WARN", "Warning: aliases of reference")}),
]


def test_each_broken_fmu_fails_on_the_checker_that_sees_it(drive2d, tmp_path):
    paths = {}
    for name, edit, _ in BROKEN:
        out = tmp_path / f"{name}.fmu"
        paths[name] = rewrite_md(drive2d, out, edit) if edit else _without_binary(drive2d, out)
    r = _cedra("check", str(drive2d), *map(str, paths.values()))
    assert r.returncode == 1, r.stdout + r.stderr
    got = _verdicts(r.stdout)
    assert len(got) == len(CHECKERS) * (1 + len(BROKEN)), r.stdout
    for checker in CHECKERS:
        assert got[(str(drive2d), checker)][0] == "ok", r.stdout
    for name, _, failing in BROKEN:
        for checker in CHECKERS:
            verdict, rest = got[(str(paths[name]), checker)]
            want, fragment = failing.get(checker, ("ok", ""))
            assert verdict == want and fragment in rest, (name, checker, r.stdout)
    summary = r.stdout.splitlines()[-1]
    n = 1 + len(BROKEN)
    reported = [verdict for _, _, f in BROKEN for verdict, _ in f.values()]
    assert summary.startswith(f"{n} FMUs, {len(CHECKERS)} checkers: {n * len(CHECKERS) - len(reported)} passed, "
                              f"{reported.count('WARN')} with warnings, {reported.count('FAIL')} with errors ("), \
        summary


def test_a_shipped_fmu_passes_with_one_line_per_checker(drive2d):
    r = _cedra("check", str(drive2d))
    assert r.returncode == 0, r.stdout + r.stderr
    lines = r.stdout.splitlines()
    assert [LINE.match(ln)["checker"] for ln in lines[:-1]] == list(CHECKERS), r.stdout
    assert all(LINE.match(ln)["verdict"] == "ok" for ln in lines[:-1]), r.stdout
    assert lines[-1].startswith(f"1 FMU, {len(CHECKERS)} checkers: {len(CHECKERS)} passed, 0 with warnings, "
                                "0 with errors ("), r.stdout


def test_verbose_prints_every_problem(drive2d, tmp_path):
    dropped = rewrite_md(drive2d, tmp_path / "output_dropped.fmu", _output_dropped)
    r = _cedra("check", "-v", "--skip", "roundtrip", "--skip", "libcosim", str(dropped))
    assert r.returncode == 1
    detail = [ln.strip() for ln in r.stdout.splitlines() if ln.startswith("    ")]
    assert any(d.startswith("error: ") and "Outputs" in d for d in detail), r.stdout
    assert any(d.startswith("error: validOutputs") for d in detail), r.stdout


def test_a_warning_alone_fails_the_command(drive2d, tmp_path):
    warned = rewrite_md(drive2d, tmp_path / "alias_variability.fmu", _alias_variability)
    r = _cedra("check", "--skip", "fmpy-validate", "--skip", "roundtrip", "--skip", "libcosim", str(warned))
    assert r.returncode == 1, r.stdout + r.stderr
    assert _verdicts(r.stdout)[(str(warned), "vdmcheck2")][0] == "WARN", r.stdout
    assert ": 0 passed, 1 with warnings, 0 with errors, 3 skipped (" in r.stdout.splitlines()[-1], r.stdout


def test_a_checker_that_cannot_run_is_an_error_unless_skipped(drive2d, tmp_path):
    """No java on the PATH and an empty tools cache: VDMCheck2 cannot be set up."""
    env = dict(os.environ, PATH=str(tmp_path / "empty"), CEDRA_TOOLS_CACHE=str(tmp_path / "tools"))
    r = _cedra("check", "--skip", "roundtrip", "--skip", "libcosim", str(drive2d), env=env)
    assert r.returncode == 1, r.stdout + r.stderr
    got = _verdicts(r.stdout)
    verdict, rest = got[(str(drive2d), "vdmcheck2")]
    assert verdict == "unavailable:" and "java" in rest, r.stdout
    assert got[(str(drive2d), "roundtrip")][0] == "skipped"
    r = _cedra("check", "--skip", "vdmcheck2", "--skip", "roundtrip", "--skip", "libcosim", str(drive2d), env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.splitlines()[-1].startswith("1 FMU, 1 checker: 1 passed, 0 with warnings, 0 with errors, "
                                                "3 skipped ("), r.stdout


def test_a_path_that_is_not_an_fmu_fails_before_any_check(drive2d, tmp_path):
    not_zip = tmp_path / "notes.fmu"
    not_zip.write_text("not an archive")
    no_md = tmp_path / "empty.fmu"
    with zipfile.ZipFile(no_md, "w") as z:
        z.writestr("binaries/readme.txt", "no model description")
    missing = tmp_path / "missing.fmu"
    r = _cedra("check", str(drive2d), str(missing), str(not_zip), str(no_md), timeout=120)
    assert r.returncode == 2
    assert r.stdout == ""                                # not even the good FMU was checked
    assert r.stderr.splitlines() == [f"error: {missing}: no such file",
                                     f"error: {not_zip}: not an FMU (not a zip archive)",
                                     f"error: {no_md}: not an FMU (no modelDescription.xml in the archive)"]


# ------------------------------------------------------------------------------------------ docs/fmu.md's samples

def _doc_samples() -> list[tuple[list[str], list[str]]]:
    """(command's arguments, output lines) of every console block in docs/fmu.md's "Checking an FMU"."""
    text = (REPO / "docs" / "fmu.md").read_text()
    section = text.split("## Checking an FMU", 1)[1].split("\n## ", 1)[0]
    samples = []
    for block in re.findall(r"```console\n(.*?)```", section, re.S):
        cmd, *out = block.rstrip("\n").splitlines()
        assert cmd.startswith("$ .venv/bin/python -m cedra check "), cmd
        samples.append((cmd.split()[4:], out))
    return samples


def test_the_docs_samples_are_the_commands_output(drive2d, tmp_path):
    """Each sample runs as shown: build/ paths from the repository root, a broken copy (named as in BROKEN) from the
    folder that holds it; its lines are the command's, every time shown as (… s)."""
    samples = _doc_samples()
    assert len(samples) == 2
    edits = {name: edit for name, edit, _ in BROKEN if edit}
    for args, want in samples:
        cwd = REPO
        for a in args:
            if a.endswith(".fmu") and not a.startswith("build/"):
                cwd = tmp_path
                rewrite_md(drive2d, tmp_path / a, edits[a.removesuffix(".fmu")])
        r = _cedra(*args, cwd=cwd)
        got = [TIME.sub("(… s)", ln) for ln in r.stdout.splitlines()]
        assert got == want, "\n".join(got) + r.stderr
