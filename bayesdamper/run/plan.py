"""What a data set is and what will be done with it: the identification mode, chosen from the data.

Every record is classified from its displacement (:mod:`bayesdamper.io.recordkind`) and checked for
flat, clipped, too short or implausible channels. A data set whose records are all triangular tests is
identified by the paper's two stages (plateaus, then transients); any other (sine, sweep, multisine,
random, or a mix) is identified record by record as a whole (:mod:`bayesdamper.inference.whole`). The
mode can be forced; it is printed and stored with the results.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.io.dataset import check_duration, load_dataset
from bayesdamper.io.recordkind import inspect_record
from bayesdamper.io.wholerecord import record_window

#: Identification modes accepted by ``--mode``.
MODES = ("auto", "two-stage", "whole-record")
TWO_STAGE, WHOLE = "two-stage", "whole-record"


@dataclass
class DataPlan:
    """A validated data set, the kind of each record and the mode; nothing written yet.

    For the two-stage mode ``segs``, ``transients`` and ``static`` are those of
    :func:`bayesdamper.run.stages.prepare`; for the whole-record mode ``windows`` holds one
    :class:`~bayesdamper.io.wholerecord.RecordWindow` per record.
    """

    ds: object
    mode: str
    mode_reason: str
    kinds: list
    segs: tuple = ()
    transients: list = field(default_factory=list)
    static: object = None
    windows: list = field(default_factory=list)

    def describe(self) -> list[str]:
        """One line per record: its name, what it is and what will be done with it."""
        what = "segmented into transients (stage 1 + stage 2)" if self.mode == TWO_STAGE else \
            "identified as a whole record"
        return [f"{k.name}: {k.description} -> {what}" for k in self.kinds]

    def as_dict(self) -> dict:
        return {"mode": self.mode, "mode_reason": self.mode_reason,
                "records": [{"name": k.name, "kind": k.kind, "description": k.description,
                             "details": k.details} for k in self.kinds],
                "windows": [w.as_dict() for w in self.windows]}


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise SettingsError(f"--mode: unknown mode {mode!r}, choose from {', '.join(MODES)}")
    return mode


def choose_mode(kinds: list, forced: str) -> tuple[str, str]:
    """The mode and why: forced, or two-stage when most records are triangular tests (a data set of
    triangular tests with a stray record is refused by :func:`plan_dataset`, naming the record)."""
    if forced != "auto":
        return forced, "forced by --mode"
    other = [k for k in kinds if k.kind != "triangular"]
    if not other:
        return TWO_STAGE, "every record is a triangular test"
    if 2 * len(other) < len(kinds):
        return TWO_STAGE, "most records are triangular tests"
    names = ", ".join(f"{k.name} ({k.kind})" for k in other[:3]) + (" ..." if len(other) > 3 else "")
    return WHOLE, f"not every record is a triangular test: {names}"


def plan_dataset(data_dir: str | Path, tmax: float, mode: str = "auto") -> DataPlan:
    """Load, validate and classify a data set, choose the mode and prepare it. Raises on bad input."""
    from bayesdamper.run.stages import prepare_loaded

    check_mode(mode)
    ds = load_dataset(data_dir, tmax=None)
    kinds = [inspect_record(r) for r in ds.records]  # checked (raises on a bad record) and classified
    chosen, reason = choose_mode(kinds, mode)
    if chosen == TWO_STAGE:
        not_tri = [k for k in kinds if k.kind != "triangular"]
        if not_tri:
            k = not_tri[0]
            n_tri = len(kinds) - len(not_tri)
            if mode == "auto":
                raise DataError(f"{ds.record(k.name).path}: is not a triangular test like the other {n_tri} "
                                f"record(s) of the data set (it reads as: {k.description}; truncated?): remove it "
                                "or use --mode whole-record")
            raise DataError(f"{ds.record(k.name).path}: is not a triangular test (it reads as: {k.description}): "
                            "the two-stage method needs plateaus and velocity steps (use --mode auto or whole-record)")
        for r in ds.records:
            check_duration(r.path, r.duration, tmax)
        segs, transients, static = prepare_loaded(ds, tmax)
        return DataPlan(ds, chosen, reason, kinds, segs, transients, static)
    windows = [record_window(r, kind=k.kind, description=k.description)
               for r, k in zip(ds.records, kinds, strict=True)]
    return DataPlan(ds, chosen, reason, kinds, windows=windows)
