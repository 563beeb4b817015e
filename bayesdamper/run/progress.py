"""Progress display of long runs: a tqdm bar on a terminal, one summary line per phase otherwise.

A job is a sequence of phases (``with progress.phase("stage 2: sampling", total=n, unit="transient")``).
On a terminal (stderr is a tty) a phase with a known total shows a tqdm bar with its count, rate and time
left, and the detailed messages of the run (``progress("...")``) are printed above the bar. When stderr is
not a terminal (a log file, CI, a batch system) the detailed messages are dropped and each phase prints one
line when it ends, e.g. ``stage 2: sampling: 12/12 transients in 130.2 s (12 converged)``.
``Progress(False)`` prints nothing at all.
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import TextIO


class Phase:
    """One phase of a job: counts what is done and, on a terminal, drives a progress bar."""

    def __init__(self, name: str, total: int | None, unit: str, bar):
        self.name, self.total, self.unit, self.bar = name, total, unit, bar
        self.done = 0
        self.note = ""
        self.t0 = time.perf_counter()

    def advance(self, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)

    def summary(self) -> str:
        wall = time.perf_counter() - self.t0
        if self.total is None:
            count = f"{self.done} {self.unit}{'s' * (self.done != 1)} " if self.done else ""
        else:
            count = f"{self.done}/{self.total} {self.unit}{'s' * (self.total != 1)} "
        return f"{self.name}: {count}in {wall:.1f} s" + (f" ({self.note})" if self.note else "")


class Progress:
    """Progress of a job on ``stream`` (default stderr).

    ``enabled``: None (default) shows bars and messages on a terminal and phase summaries otherwise;
    False shows nothing; True forces the terminal display.
    """

    def __init__(self, enabled: bool | None = None, stream: TextIO | None = None):
        self.stream = stream if stream is not None else sys.stderr
        self.silent = enabled is False
        self.terminal = bool(enabled) or (enabled is None and self.stream.isatty())
        self.current: Phase | None = None
        #: Every finished phase: ``{"phase", "s", "done", "note"}`` (wall seconds), in order.
        self.times: list[dict] = []

    @property
    def enabled(self) -> bool:
        """Whether detailed messages are shown (on a terminal only)."""
        return self.terminal and not self.silent

    def __call__(self, msg: str) -> None:
        """A detailed message: printed above the bar on a terminal, dropped otherwise."""
        if not self.enabled:
            return
        if self.current is not None and self.current.bar is not None:
            self.current.bar.write(msg, file=self.stream)
        else:
            print(msg, file=self.stream, flush=True)

    def advance(self, n: int = 1) -> None:
        """One more item of the current phase done."""
        if self.current is not None:
            self.current.advance(n)

    def note(self, text: str) -> None:
        """Text appended to the current phase's summary line (e.g. how many converged)."""
        if self.current is not None:
            self.current.note = text

    @contextmanager
    def phase(self, name: str, total: int | None = None, unit: str = "item"):
        bar = None
        if self.enabled and total:
            from tqdm import tqdm

            bar = tqdm(total=total, desc=name, unit=f" {unit}", file=self.stream, leave=False, dynamic_ncols=True,
                       bar_format="{desc}: {bar} {n_fmt}/{total_fmt}{unit}s [{elapsed}<{remaining}]")
        outer, self.current = self.current, Phase(name, total, unit, bar)
        phase = self.current
        try:
            yield phase
        finally:  # a failed phase prints no summary: its error is the one line the user sees
            if bar is not None:
                bar.close()
            self.current = outer
        self.times.append({"phase": phase.name, "s": time.perf_counter() - phase.t0, "done": phase.done,
                           "note": phase.note})
        if not self.silent:
            print(phase.summary(), file=self.stream, flush=True)


def count_files(tree) -> int:
    """Number of file paths in a (nested) dict/list of figure paths."""
    if isinstance(tree, dict):
        return sum(count_files(v) for v in tree.values())
    if isinstance(tree, list | tuple):
        return sum(count_files(v) for v in tree)
    return 1 if isinstance(tree, str) else 0
