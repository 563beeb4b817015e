"""What a data set is and how it will be cut into windows: one plan for every kind of record.

Every record is classified from its displacement (:mod:`bayesdamper.io.recordkind`) and checked for flat,
clipped, too short or implausible channels. Each then becomes windows (:class:`bayesdamper.io.windows.Window`):

* a triangular test is segmented (:mod:`bayesdamper.io.segmentation`): one transient after every velocity step,
  and its plateaus, which give stage 1 (the flow coefficients of eq. (4)) for every window of the data set;
* any other record (sine, sweep, multisine, random) has its displacement reconstructed into a smooth input
  (:mod:`bayesdamper.io.reconstruct`) and is cut into windows of whole cycles (:func:`~bayesdamper.io.windows.
  cycle_windows`); with no plateaus in the data set, the flow coefficients are estimated in each window.

``--mode two-stage`` insists that every record be a triangular test; ``--mode whole-record`` cuts every record,
triangular tests included, into cycle windows (no stage 1); ``auto`` (default) does each record as its kind
says. The plan is printed and stored with the results.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.inference.settle import settled_plateaus
from bayesdamper.inference.stage1 import fit_static
from bayesdamper.io.dataset import load_dataset
from bayesdamper.io.recordkind import inspect_record
from bayesdamper.io.segmentation import segment_dataset

#: Bootstrap replicates of a reconstructed input whose force, at every window's fitted parameters, measures what
#: the input's error does to the force (four give its rms to about ±35 %, enough to tell it from the noise).
INPUT_REPLICATES = 4
#: Identification modes accepted by ``--mode``.
MODES = ("auto", "two-stage", "whole-record")
AUTO, TWO_STAGE, WHOLE = "auto", "two-stage", "whole-record"


@dataclass
class DataPlan:
    """A validated data set cut into windows; nothing written yet.

    Attributes
    ----------
    ds : Dataset
    mode : str
        ``--mode`` as given.
    mode_reason : str
        One line: how the records were windowed.
    kinds : list of RecordKind
    segs : tuple of SegmentedRecord
        The segmented triangular tests (their plateaus give stage 1).
    windows : list of Window
        Every window, in record order.
    static : StaticFit or None
        Stage 1 from the plateaus (None without triangular tests).
    inputs : dict
        Per cycle-windowed record: how its input was reconstructed (JSON-safe).
    zero : ZeroFit or None
        The force channel's zero measured on the plateaus (:func:`zeroed`; None where not measured).
    zero_removed : bool
        The records' forces are the measured ones minus ``zero.offset_N``.
    """

    ds: object
    mode: str
    mode_reason: str
    kinds: list
    segs: tuple = ()
    windows: list = field(default_factory=list)
    static: object = None
    inputs: dict = field(default_factory=dict)
    zero: object = None
    zero_removed: bool = False

    @property
    def zero_record(self) -> dict | None:
        """The zero as results store it: :meth:`ZeroFit.as_dict` and whether it was removed (None: not measured)."""
        return {**self.zero.as_dict(), "removed": self.zero_removed} if self.zero is not None else None

    @property
    def transients(self) -> list:
        """Every window (the name the stage-2 code uses for its units of work)."""
        return self.windows

    def describe(self) -> list[str]:
        """One line per record: its name, what it is and what will be done with it."""
        n = {}
        for w in self.windows:
            n[w.test] = n.get(w.test, 0) + 1
        seg = {s.record.name for s in self.segs}
        out = []
        for k in self.kinds:
            what = (f"segmented: {n.get(k.name, 0)} transient(s) and plateaus (stage 1)" if k.name in seg else
                    f"{n.get(k.name, 0)} window(s) of whole cycles")
            out.append(f"{k.name}: {k.description} -> {what}")
        return out

    def as_dict(self) -> dict:
        return {"mode": self.mode, "mode_reason": self.mode_reason,
                "records": [{"name": k.name, "kind": k.kind, "description": k.description,
                             "details": k.details} for k in self.kinds],
                "windows": [w.as_dict() for w in self.windows],
                "stage1": self.static is not None, "inputs": self.inputs,
                "load_cell_zero": self.zero_record}


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise SettingsError(f"--mode: unknown mode {mode!r}, choose from {', '.join(MODES)}")
    return mode


def _cycle_windows(ds, record, kind) -> tuple[list, dict]:
    from bayesdamper.io.reconstruct import bootstrap_inputs, reconstruct_input
    from bayesdamper.io.windows import cycle_windows, reconstructed_drive

    try:
        rec = reconstruct_input(record.time, record.displacement, velocity=getattr(record, "velocity", None))
    except DataError as err:
        raise DataError(f"{record.path}: {err}") from None
    reps = bootstrap_inputs(record.time, record.displacement, velocity=getattr(record, "velocity", None),
                            n_replicates=INPUT_REPLICATES)
    summary = rec.as_dict()
    windows = cycle_windows(record, kind.kind, kind.details, reconstructed_drive(rec),
                            float(rec.velocity_error_m_s), ds.damper.piston_area, summary,
                            tuple(reconstructed_drive(r) for r in reps))
    return windows, summary


def segment_and_fit(ds, records, tmax: float):
    """Segment the triangular tests ``records`` of a data set and fit stage 1 on their settled plateaus:
    ``(segs, static)``."""
    import dataclasses

    sub = dataclasses.replace(ds, records=tuple(records)) if len(records) != len(ds.records) else ds
    segs = segment_dataset(sub, tmax=tmax)
    try:  # stage 1 and the noise take only plateaus whose force has settled
        segs, _ = settled_plateaus(segs)
    except ValueError:  # no plateau with scatter: fit_static says what is wrong
        pass
    plateaus = [p for s in segs for p in s.plateaus]
    static = fit_static(plateaus, source=str(ds.path))
    try:  # validated here, before any job writes
        static.coefficients  # noqa: B018
    except SettingsError as err:
        raise DataError(f"{ds.path}: stage 1 from the plateaus gives {err}") from None
    return segs, static


def plan_dataset(data_dir: str | Path, tmax: float, mode: str = AUTO) -> DataPlan:
    """Load, validate and classify a data set and cut every record into windows. Raises on bad input."""
    check_mode(mode)
    return _plan_of(load_dataset(data_dir, tmax=None), tmax, mode)


def zeroed(plan: DataPlan, tmax: float) -> DataPlan:
    """The plan with the force channel's zero removed where its plateaus measure one.

    An unzeroed load cell adds a constant to every force. Searched for as the ``load_cell_offset`` effect it has to
    lower the pooled error by a fifth like any rig effect, and a modest offset does not, while it hides the effects
    behind it (a compliant mount, a check valve). The plateaus measure it directly, friction or not
    (:func:`~bayesdamper.inference.stage1.plateau_zero`): where the offset lies more than
    :data:`~bayesdamper.inference.stage1.OFFSET_MIN_T` standard errors from 0 it is subtracted from every record's
    force and the data set planned again (the plateaus, stage 1 and the windows from the corrected forces); the
    ``load_cell_offset`` effect stays a candidate for what is left. Otherwise the plan is returned with the zero
    recorded and nothing removed."""
    import dataclasses

    from bayesdamper.core.frozen import frozen_copy
    from bayesdamper.inference.stage1 import plateau_zero

    if not plan.segs:
        return plan
    zero = plateau_zero([p for s in plan.segs for p in s.plateaus], plan.ds.damper.piston_area)
    if zero is None or not zero.measured:
        return dataclasses.replace(plan, zero=zero)
    records = tuple(dataclasses.replace(r, force=frozen_copy(r.force - zero.offset_N)) for r in plan.ds.records)
    out = _plan_of(dataclasses.replace(plan.ds, records=records), tmax, plan.mode)
    return dataclasses.replace(out, zero=zero, zero_removed=True)


def _plan_of(ds, tmax: float, mode: str) -> DataPlan:
    kinds = [inspect_record(r) for r in ds.records]  # checked (raises on a bad record) and classified
    triangular = [k.kind == "triangular" for k in kinds]
    if mode == TWO_STAGE and not all(triangular):
        k = kinds[triangular.index(False)]
        raise DataError(f"{ds.record(k.name).path}: is not a triangular test (it reads as: {k.description}): "
                        "the two-stage method needs plateaus and velocity steps (use --mode auto or whole-record)")
    segment = [t and mode != WHOLE for t in triangular]
    seg_records = [r for r, s in zip(ds.records, segment, strict=True) if s]
    segs, static = segment_and_fit(ds, seg_records, tmax) if seg_records else ((), None)
    by_name = {s.record.name: s for s in segs}
    windows, inputs = [], {}
    for r, k, s in zip(ds.records, kinds, segment, strict=True):
        if s:
            windows += list(by_name[r.name].transients)
        else:
            w, summary = _cycle_windows(ds, r, k)
            windows += w
            inputs[r.name] = summary
    n_seg, n_cyc = len(seg_records), len(ds.records) - len(seg_records)
    if mode == WHOLE:
        reason = "forced by --mode whole-record: every record cut into windows of whole cycles, no stage 1"
    elif n_cyc == 0:
        reason = "every record is a triangular test: transients after the velocity steps, stage 1 from the plateaus"
    elif n_seg == 0:
        reason = "no triangular test: every record cut into windows of whole cycles, flow coefficients per window"
    else:
        reason = (f"{n_seg} triangular test(s) segmented (stage 1 from their plateaus for every window), "
                  f"{n_cyc} other record(s) cut into windows of whole cycles")
    return DataPlan(ds, mode, reason, kinds, tuple(segs), windows, static, inputs)
