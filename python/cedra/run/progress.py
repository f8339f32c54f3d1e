"""Progress on long work (scenario runs, sweeps, reports, the benchmark): a bar redrawn in place when stderr is a
terminal, a plain line every quarter otherwise (logs and CI), nothing when quiet. The bar appears only once the
work has taken `after` seconds, so short work stays silent."""
from __future__ import annotations

import sys
import time


def _clock(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


class Progress:
    """`done` of `total` units (simulated seconds, runs, cases): call it with the amount done so far and an optional
    note (e.g. "3 failed"); it shows the fraction, the wall time and the time left at the rate so far."""

    def __init__(self, total: float, label: str, unit: str = "s simulated", quiet: bool = False, after: float = 2.0,
                 stream=None):
        self.total, self.label, self.unit, self.quiet, self.after = total, label, unit, quiet, after
        self.stream = stream or sys.stderr
        self.start = time.perf_counter()
        self.tty = self.stream.isatty()
        self.shown = False
        self.next_quarter = 0.25

    def __call__(self, done: float, note: str = ""):
        if self.quiet:
            return
        wall = time.perf_counter() - self.start
        if wall < self.after and done < self.total:
            return
        frac = min(1.0, done / self.total) if self.total > 0 else 1.0
        left = wall * (1 - frac) / frac if frac > 0 else float("nan")
        amount = f"{done:g}/{self.total:g} {self.unit}" if self.unit != "s simulated" else \
            f"{done:.2f}/{self.total:g} {self.unit}"
        tail = f"{amount}{', ' + note if note else ''}, {_clock(wall)}" + \
            (f", ~{_clock(left)} left" if frac < 1 and left == left else "")
        if self.tty:
            bar = "#" * int(30 * frac)
            self.stream.write(f"\r{self.label} [{bar:<30}] {tail}\033[K")
            self.stream.flush()
            self.shown = True
        elif frac >= self.next_quarter or (frac >= 1 and self.next_quarter <= 1):
            self.stream.write(f"{self.label}: {tail}\n")
            self.stream.flush()
            while self.next_quarter <= frac:
                self.next_quarter += 0.25

    def done(self):
        if self.shown:
            self.stream.write("\n")
            self.shown = False
