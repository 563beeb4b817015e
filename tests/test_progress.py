"""Progress display: a bar with counts and time left on a terminal, one summary line per phase otherwise."""

from __future__ import annotations

import io
import re

import pytest

from bayesdamper.run.progress import Progress, count_files


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_not_a_terminal_one_summary_line_per_phase():
    out = io.StringIO()
    progress = Progress(stream=out)
    with progress.phase("stage 2: sampling", total=3, unit="transient"):
        for _ in range(3):
            progress("a detailed message")
            progress.advance()
        progress.note("3 converged")
    with progress.phase("figures", unit="file") as ph:
        ph.done = 5
    lines = out.getvalue().splitlines()
    assert len(lines) == 2, lines
    assert re.fullmatch(r"stage 2: sampling: 3/3 transients in \d+\.\d s \(3 converged\)", lines[0]), lines[0]
    assert re.fullmatch(r"figures: 5 files in \d+\.\d s", lines[1]), lines[1]
    assert "detailed" not in out.getvalue()
    # the phases' wall times are kept for the job's record (diagnosis.json: phase_times_s)
    assert [(t["phase"], t["done"], t["note"]) for t in progress.times] == [("stage 2: sampling", 3, "3 converged"),
                                                                            ("figures", 5, "")]
    assert all(t["s"] >= 0 for t in progress.times)


def test_terminal_shows_a_bar_with_counts_and_time_left_and_the_messages():
    out = _Terminal()
    progress = Progress(stream=out)
    with progress.phase("stage 2: sampling", total=4, unit="transient"):
        for i in range(4):
            progress(f"transient {i} converged")
            progress.advance()
    text = out.getvalue()
    assert "transient 3 converged" in text
    assert "4/4" in text and "<" in text  # count, and elapsed<remaining
    assert "stage 2: sampling: 4/4 transients in" in text


def test_silent():
    out = _Terminal()
    progress = Progress(False, stream=out)
    with progress.phase("x", total=2):
        progress("message")
        progress.advance(2)
    assert out.getvalue() == ""


def test_a_failed_phase_prints_no_summary():
    out = io.StringIO()
    progress = Progress(stream=out)
    with pytest.raises(ValueError), progress.phase("load", unit="data set"):
        raise ValueError("bad input")
    assert out.getvalue() == ""
    assert progress.current is None


def test_count_files():
    assert count_files({"a": ["x.png", "y.pdf"], "b": {"c": "z.png"}, "n": None}) == 3
