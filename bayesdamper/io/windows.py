"""The unit of identification: a window of a record with its initial state, and how records are cut into windows.

Every record, of any kind, is identified window by window. A :class:`Window` holds the samples it is judged on,
the input that drives the model there (the record's displacement as polynomial pieces, history included, so that
effects with a memory see what came before), and what is known of the state at its start:

* the transient after a velocity step of a triangular test (:mod:`bayesdamper.io.segmentation`): the step force,
  measured on the settled samples just before the step, gives Δp at the start;
* a stretch of whole cycles of a sine, sweep or random record (:func:`cycle_windows`): the input is the smoothed
  measured displacement (:mod:`bayesdamper.io.reconstruct`); a window that starts at rest (the record's start
  before the motion) has its rest samples as the step force's data, like a start from rest; a window that starts
  in motion has no such data, and Δp at its start is estimated with the other parameters.

Windows of a record are chosen by the record's own time scale, in whole cycles (:func:`cycle_windows`), and the
choice is stored with every result (:attr:`Window.info`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from bayesdamper.core.errors import DataError
from bayesdamper.core.frozen import ReadOnlyArrays, frozen_copy
from bayesdamper.physics.excitation import PiecewisePolynomial

__all__ = ["Window", "cycle_windows", "WINDOW_TARGET_S"]

#: A window holds the fewest whole cycles that last at least this long [s] (one cycle if that is longer). Each
#: window is sampled on its own and its posteriors are pooled: the sampling cost grows with the number of windows
#: (each needs about the same number of evaluations, each costing in proportion to its length), so windows are
#: long; a slow drift over a record (temperature over minutes) is resolved by windows shorter than it.
WINDOW_TARGET_S = 10.0
#: Largest number of samples a window keeps; above it the force is decimated by an integer factor (zero-phase
#: FIR) — the input stays the full-rate reconstruction. 12 s at 1 kHz.
MAX_WINDOW_SAMPLES = 12_000
#: The piston rests where the reconstructed speed is below this fraction of the record's peak speed (99th
#: percentile) and below :data:`REST_NOISE_SIGMAS` times the reconstruction's velocity error.
REST_FRACTION = 0.01
REST_NOISE_SIGMAS = 3.0
#: A reversal of the motion is a turning point the displacement then leaves by more than this fraction of its range
#: (1st to 99th percentile): a rest's noise and a corner's ringing cannot make one, and a random record's wiggles
#: smaller than a tenth of its range are not cycles.
REVERSAL_FRACTION = 0.1
#: Fewest rest samples at a record's start that make its first window a start from rest (their mean force is
#: the step force; the triangular tests' step force is the mean of 0.15 s, 30 samples at 200 Hz).
MIN_REST_SAMPLES = 20
#: Fewest samples of a window.
MIN_WINDOW_SAMPLES = 50
WINDOW_RULE = (f"whole cycles of the record's own period: the fewest that last at least {WINDOW_TARGET_S:g} s, "
               "from the start of the motion (or the record's start in motion), the last window running to the "
               "record's end")



@dataclass(frozen=True, eq=False)
class Window(ReadOnlyArrays):
    """A window of a record with its initial state: the data of one eq. (9) residual.

    Attributes
    ----------
    id : str
        File-name-safe identifier: ``f"{test}_s{index}"`` for a transient, ``f"{test}_w{index}"`` for cycles.
    test : str
        Name of the record.
    index : int
        Index of the window (step) in the record.
    kind : {"initial", "reversal", "cycles"}
        Start from rest, reversal (the transients of a triangular test) or a stretch of cycles.
    direction : {1, -1, 0}
        Sign of the velocity after the step (+1: Δp > 0, flow CH1 -> CH2); 0 for cycles.
    velocity : float
        Operating speed [m/s]: the piston speed after the step, or the peak speed (99th percentile) of the cycles.
    t_step : float
        Start of the window [s]: the velocity step, the start of the motion or the first sample.
    time : ndarray, shape (n_times,)
        Sample times in the window [s]; ``time[0] >= t_step``. Read-only.
    displacement : ndarray, shape (n_times,)
        Measured displacement [m]. Read-only.
    force : ndarray, shape (n_times,)
        Measured damper force F_D,E [N]. Read-only.
    dp0 : float
        Estimate of Δp at ``t_step`` [Pa]: the step force / A_P (mean of ``pre_force``), or for a window starting
        in motion the force of its first samples / A_P (a start value; its own data are the window's).
    drive : PiecewisePolynomial
        The record's displacement as the model's input [m], from the record's start (history included).
    pre_time, pre_force : ndarray, shape (n_pre,)
        The settled samples just before ``t_step`` whose mean is the step force: times [s] and force [N].
        Read-only; empty when the window starts in motion.
    info : dict
        How the window was chosen (JSON-safe): rule, cycles, decimation, the input's reconstruction.
    drive_replicates : tuple of PiecewisePolynomial
        Bootstrap replicates of a reconstructed input (:func:`bayesdamper.io.reconstruct.bootstrap_inputs`): the
        force they move at the fitted parameters is the reconstruction's error in the force. Empty for the
        piecewise-linear fit of a triangular test.
    """

    id: str
    test: str
    index: int
    kind: str
    direction: int
    velocity: float
    t_step: float
    time: np.ndarray
    displacement: np.ndarray
    force: np.ndarray
    dp0: float
    drive: PiecewisePolynomial
    pre_time: np.ndarray = field(default_factory=lambda: frozen_copy([]))
    pre_force: np.ndarray = field(default_factory=lambda: frozen_copy([]))
    info: dict = field(default_factory=dict)
    drive_replicates: tuple = ()

    @property
    def duration(self) -> float:
        """Window length ``time[-1] - t_step`` [s]."""
        return float(self.time[-1] - self.t_step)

    @property
    def starts_settled(self) -> bool:
        """The window starts from a settled state with its own data (the samples before the step)."""
        return self.pre_force.size > 0

    @functools.cached_property
    def local_drive(self) -> PiecewisePolynomial:
        """The input on ``[t_step, time[-1]]`` (what eq. (7) alone needs; effects with memory use :attr:`drive`)."""
        return self.drive.window(self.t_step, float(max(self.time[-1], self.t_step + 1e-9)))

    def as_dict(self) -> dict:
        """The window's description for the stored results (JSON-safe; no arrays)."""
        return {"id": self.id, "test": self.test, "kind": self.kind, "t_start_s": float(self.t_step),
                "t_end_s": float(self.time[-1]), "n_samples": int(self.time.size),
                "starts_settled": self.starts_settled, **self.info}


def reconstructed_drive(rec) -> PiecewisePolynomial:
    """The model's input from an :class:`~bayesdamper.io.reconstruct.InputReconstruction`: its pieces, with the
    solver restarting at both ends only."""
    return PiecewisePolynomial(rec.breaks, rec.coefs, [True] + [False] * (rec.breaks.size - 2) + [True])


def _decimate(x: np.ndarray, q: int) -> np.ndarray:
    from scipy.signal import decimate

    if q == 1:
        return np.array(x, dtype=float)
    return decimate(np.asarray(x, dtype=float), q, ftype="fir", zero_phase=True)


def cycle_period(kind: str, details: dict, time: np.ndarray, turns: list[int], moving: np.ndarray) -> float:
    """The record's own time scale [s]: a sine's period, else twice the median interval between the motion's
    reversals ``turns`` (:func:`_reversals`: a triangular or random record's mean half-cycle), else the moving
    duration."""
    if kind == "sine" and details.get("frequency_Hz", 0) > 0:
        return 1.0 / float(details["frequency_Hz"])
    if len(turns) >= 2:
        return float(2.0 * np.median(np.diff(time[turns])))
    idx = np.flatnonzero(moving)
    span = float(time[idx[-1]] - time[idx[0]]) if idx.size > 1 else float(time[-1] - time[0])
    return max(span, float(time[1] - time[0]))


def _reversals(y: np.ndarray, h: float) -> list[int]:
    """Indices of the turning points of ``y`` that it then leaves by more than ``h`` (each the extreme sample);
    the start is none. Peak picking with hysteresis: with ``h`` = :data:`REVERSAL_FRACTION` of the range, the
    noise of a rest and the ringing of a reconstructed velocity at a corner or a stop make no reversal."""
    turns, i_lo, i_hi, direction, i_ext = [], 0, 0, 0, 0
    for i in range(1, y.size):
        if direction == 0:  # until the first move by more than h
            i_lo = i if y[i] < y[i_lo] else i_lo
            i_hi = i if y[i] > y[i_hi] else i_hi
            if y[i] - y[i_lo] > h or y[i_hi] - y[i] > h:
                direction, i_ext = (1 if y[i] - y[i_lo] > h else -1), i
        elif direction * (y[i] - y[i_ext]) > 0:
            i_ext = i
        elif direction * (y[i_ext] - y[i]) > h:
            turns.append(i_ext)
            direction, i_ext = -direction, i
    return turns


def cycle_windows(record, kind: str, details: dict, drive: PiecewisePolynomial, velocity_error: float,
                  area: float, reconstruction: dict | None = None, replicates: tuple = ()) -> list[Window]:
    """Cut a sine, sweep or random record into windows of whole cycles (module docstring, :data:`WINDOW_RULE`).

    Parameters
    ----------
    record : TestRecord
    kind, details
        The record's kind and its numbers (:class:`~bayesdamper.io.recordkind.RecordKind`).
    drive : PiecewisePolynomial
        The reconstructed displacement of the whole record [m].
    velocity_error : float
        Estimated rms error of the reconstructed velocity [m/s] (the rest threshold's noise floor).
    area : float
        Piston area A_P [m^2] (Δp from the force).
    reconstruction : dict, optional
        How the input was reconstructed, stored in every window's ``info``.
    replicates : tuple of PiecewisePolynomial
        Bootstrap replicates of the reconstructed input (:attr:`Window.drive_replicates`).

    Raises
    ------
    DataError
        ``"<path>: <problem>"`` when a window would hold too few samples.
    """
    t, f, y = record.time, record.force, record.displacement
    v = drive.velocity(t)
    v_peak = float(np.quantile(np.abs(v), 0.99))
    rest = np.abs(v) <= max(REST_FRACTION * v_peak, REST_NOISE_SIGMAS * velocity_error)
    moving = ~rest
    y_drive = drive.displacement(t)
    turns = _reversals(y_drive, REVERSAL_FRACTION * float(np.ptp(np.quantile(y_drive, (0.01, 0.99)))))
    if kind != "sine" and not turns:
        raise DataError(f"{record.path}: the motion never reverses ({float(t[-1] - t[0]):.3g} s): not a triangular "
                        "test, and no cycle to identify")
    period = cycle_period(kind, details, t, turns, moving)
    i0 = 0
    pre = np.zeros(0, dtype=int)
    if rest[:MIN_REST_SAMPLES].all():  # starts at rest: the rest samples give the step force
        i_on = int(np.argmax(moving)) if moving.any() else t.size
        pre = np.arange(0, i_on)
        i0 = i_on
    if t.size - i0 < MIN_WINDOW_SAMPLES:
        raise DataError(f"{record.path}: the piston hardly moves ({t.size - i0} samples in motion)")
    t_start = float(t[i0])
    n_cyc = max(1, math.ceil(WINDOW_TARGET_S / period - 1e-9))
    width = n_cyc * period
    dt = float(np.median(np.diff(t)))
    n_win = max(1, int(math.floor((float(t[-1]) - t_start + dt) / width + 1e-6)))  # the last sample ends a cycle
    edges = [i0] + [int(np.searchsorted(t, t_start + k * width)) for k in range(1, n_win)] + [t.size]
    windows = []
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        if b - a < MIN_WINDOW_SAMPLES:
            raise DataError(f"{record.path}: window {k} of the record would hold {b - a} samples "
                            f"(fewer than {MIN_WINDOW_SAMPLES})")
        q = max(1, math.ceil((b - a) / MAX_WINDOW_SAMPLES))
        tw = t[a:b][::q]
        fw = _decimate(f[a:b], q)[:tw.size]
        yw = _decimate(y[a:b], q)[:tw.size]
        pre_idx = pre if k == 0 else np.zeros(0, dtype=int)
        t_step = float(t[a])
        if pre_idx.size:
            dp0 = float(np.mean(f[pre_idx])) / area
        else:
            dp0 = float(np.mean(f[a:min(a + 3, b)])) / area
        vw = np.abs(v[a:b])
        info = {"rule": WINDOW_RULE, "cycle_s": float(period), "cycles": float(n_cyc) if k < n_win - 1 else
                float((t[b - 1] - t_step) / period), "periodic": kind == "sine", "decimation": int(q),
                "rate_Hz": float(1.0 / np.median(np.diff(tw))) if tw.size > 1 else float(record.sample_rate),
                "starts": "rest" if pre_idx.size else ("motion" if k == 0 else "previous window"),
                "ends_at_rest": bool(k == n_win - 1 and rest[-1]), "record_kind": kind}
        if reconstruction is not None:
            info["input"] = reconstruction
        windows.append(Window(
            id=f"{record.name}_w{k}", test=record.name, index=k, kind="cycles", direction=0,
            velocity=float(np.quantile(vw, 0.99)) if vw.size else 0.0, t_step=t_step,
            time=frozen_copy(tw), displacement=frozen_copy(yw), force=frozen_copy(fw), dp0=dp0, drive=drive,
            pre_time=frozen_copy(t[pre_idx]), pre_force=frozen_copy(f[pre_idx]), info=info,
            drive_replicates=tuple(replicates)))
    return windows
