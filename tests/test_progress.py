"""Progress on long work: a bar redrawn in place on a terminal, a plain line per quarter
otherwise, nothing when quiet; the CLI's long commands take --quiet."""
from __future__ import annotations

import io

import pytest

from cedra.run.progress import Progress


class Stream(io.StringIO):
    def __init__(self, tty):
        super().__init__()
        self.tty = tty

    def isatty(self):
        return self.tty


def run(tty, quiet=False, total=8):
    s = Stream(tty)
    p = Progress(total, "sweep x", unit="runs", quiet=quiet, after=0.0, stream=s)
    for k in range(1, total + 1):
        p(k, f"{k // 4} failed")
    p.done()
    return s.getvalue()


def test_plain_lines_when_not_a_terminal():
    lines = run(tty=False).splitlines()
    assert len(lines) == 4                                      # one per quarter
    assert lines[0].startswith("sweep x: 2/8 runs, 0 failed, ") and "left" in lines[0]
    assert lines[-1].startswith("sweep x: 8/8 runs, 2 failed, ") and "left" not in lines[-1]
    assert "\r" not in "".join(lines)


def test_bar_redrawn_in_place_on_a_terminal():
    out = run(tty=True)
    assert out.count("\r") == 8 and out.endswith("\n")
    assert "[" + "#" * 30 + "]" in out                          # full at the end


def test_quiet_prints_nothing():
    assert run(tty=True, quiet=True) == "" and run(tty=False, quiet=True) == ""


def test_short_work_stays_silent():
    s = Stream(False)
    p = Progress(100, "x", unit="runs", after=60.0, stream=s)
    for k in range(1, 50):
        p(k)
    assert s.getvalue() == ""
    p(100)                                                      # but the end is always reported
    assert "100/100" in s.getvalue()


@pytest.mark.parametrize("argv", [["sweep", "x", "--quiet"], ["bench", "--quiet"], ["report", "precision", "--quiet"],
                                  ["report", "stability", "--quiet"], ["report", "defaults", "--quiet"],
                                  ["simulate", "bump2d", "--quiet"]])
def test_long_commands_take_quiet(argv, monkeypatch):
    import cedra.__main__ as cli
    seen = {}
    for name in ("cmd_sweep", "cmd_bench", "cmd_report", "cmd_simulate"):
        monkeypatch.setattr(cli, name, lambda args, n=name: seen.setdefault("quiet", args.quiet) or 0)
    cli.main(argv)
    assert seen["quiet"] is True
