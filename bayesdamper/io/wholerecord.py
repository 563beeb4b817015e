"""A whole measured record prepared for identification: decimated, with its displacement as the input.

Records that are not triangular tests (sine, sweep, multisine, random) have no plateaus and no clean
transients; they are identified as a whole. :func:`record_window` turns a :class:`TestRecord` into a
:class:`RecordWindow`: the force and the displacement decimated by an integer factor with a zero-phase
FIR anti-alias filter (so the likelihood sees at most ``MAX_SAMPLES`` samples), the decimated
displacement becoming the input of eq. (7) (the quintic spline through the decimated samples:
:mod:`bayesdamper.physics.spline_input`). A record longer than ``MAX_WINDOW_S`` is identified on its central
``MAX_WINDOW_S`` seconds. The factor, the rate, the window and the rules that chose them are stored with
every result (:meth:`RecordWindow.as_dict`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesdamper.core.errors import DataError

#: Largest number of samples of one record the likelihood sees (above it the record is decimated).
MAX_SAMPLES = 2000
#: Lowest sample rate a record is decimated to [Hz]: the compressibility transients of eq. (7) last
#: tenths of a second (rig-A, the paper's Fig. 8), so 100 Hz keeps ≥ 10 samples on their rise.
MIN_RATE_HZ = 100.0
#: Fewest samples a record needs to be identified as a whole (seven parameters, a noise model).
MIN_WHOLE_SAMPLES = 200
#: Longest stretch of a record identified [s]; a longer record is identified on its central MAX_WINDOW_S.
#: The forward solve steps with the record's dynamics, not its samples, so its cost grows with the
#: duration whatever the decimation: about 0.14 ms per second of a 0.3-4 Hz multisine on one core
#: (benchmarks/whole_record.py), and an identification needs ~1e5 solves. 12 s hold 12 cycles of a 1 Hz
#: test (posterior widths grow as sqrt(T / 12 s)); 12 s records are identified whole.
MAX_WINDOW_S = 12.0
DECIMATION_RULE = (f"smallest integer factor giving at most {MAX_SAMPLES} samples, not below {MIN_RATE_HZ:g} Hz; "
                   "zero-phase FIR anti-alias filter")


@dataclass(frozen=True)
class RecordWindow:
    """One record (or a stated part of it) ready for whole-record identification.

    Attributes
    ----------
    id : str
        Identifier (the record name, or ``name_w<k>`` for a window).
    test : str
        Record name.
    time, force : ndarray, shape (n,)
        Decimated sample times [s] and measured force [N].
    displacement : ndarray, shape (n,)
        Decimated measured displacement [m]: the input (a quintic spline through these samples).
    decimation : int
        Integer decimation factor applied to the record.
    rate_hz : float
        Sample rate after decimation [Hz].
    kind : str
        Record kind of :mod:`bayesdamper.io.recordkind` ("sine", "triangular", "other").
    description : str
        One line describing the record.
    record_span : (float, float) or None
        First and last sample time of the whole record [s].
    window_rule : str
        Why only part of the record is used ("" when all of it is).
    """

    id: str
    test: str
    time: np.ndarray
    force: np.ndarray
    displacement: np.ndarray
    decimation: int
    rate_hz: float
    kind: str = "other"
    description: str = ""
    record_span: tuple[float, float] | None = None  # (first, last) sample time of the whole record [s]
    window_rule: str = ""  # why only part of the record is used ("" when it all is)

    def velocity(self) -> np.ndarray:
        """Piston velocity at the samples (centred differences) [m/s]."""
        return np.gradient(self.displacement, self.time)

    def as_dict(self) -> dict:
        d = {"id": self.id, "test": self.test, "n_samples": int(self.time.size),
             "decimation": int(self.decimation), "rate_Hz": float(self.rate_hz), "kind": self.kind,
             "description": self.description, "t_start_s": float(self.time[0]),
             "t_end_s": float(self.time[-1]), "decimation_rule": DECIMATION_RULE,
             "input": "quintic interpolating spline through the decimated displacement samples"}
        if self.record_span is not None:
            d["record_span_s"] = [float(self.record_span[0]), float(self.record_span[1])]
        d["windowed"] = bool(self.window_rule)
        if self.window_rule:
            d["window_rule"] = self.window_rule
        return d


def decimation_factor(n_samples: int, rate_hz: float, max_samples: int = MAX_SAMPLES,
                      min_rate_hz: float = MIN_RATE_HZ) -> int:
    """Smallest integer factor that brings ``n_samples`` to at most ``max_samples``, without going
    below ``min_rate_hz`` (a record that long is identified at ``min_rate_hz`` with more samples)."""
    q = int(np.ceil(n_samples / max_samples))
    q_max = max(1, int(np.floor(rate_hz / min_rate_hz)))
    return max(1, min(q, q_max))


def _decimate(x: np.ndarray, q: int) -> np.ndarray:
    from scipy.signal import decimate

    if q == 1:
        return np.array(x, dtype=float)
    # zero-phase FIR (Hamming, 20 q + 1 taps): no phase shift between force and displacement
    return decimate(np.asarray(x, dtype=float), q, ftype="fir", zero_phase=True)


def record_window(record, *, kind: str = "other", description: str = "", max_samples: int = MAX_SAMPLES,
                  t_range: tuple[float, float] | None = None, window_id: str | None = None,
                  max_window_s: float = MAX_WINDOW_S) -> RecordWindow:
    """Decimate ``record`` (only the samples in ``t_range`` [s] if given, else at most its central
    ``max_window_s`` seconds) for whole-record identification.

    Raises
    ------
    DataError
        If fewer than :data:`MIN_WHOLE_SAMPLES` samples remain.
    """
    t, y, f = record.time, record.displacement, record.force
    span = (float(t[0]), float(t[-1]))
    rule = ""
    if t_range is None and span[1] - span[0] > max_window_s:
        mid = 0.5 * (span[0] + span[1])
        t_range = (mid - 0.5 * max_window_s, mid + 0.5 * max_window_s)
        rule = f"the central {max_window_s:g} s of a longer record"
    elif t_range is not None:
        rule = f"samples in [{t_range[0]:g}, {t_range[1]:g}] s as requested"
    if t_range is not None:
        sel = (t >= t_range[0]) & (t <= t_range[1])
        t, y, f = t[sel], y[sel], f[sel]
    rate = float(record.sample_rate)
    q = decimation_factor(t.size, rate, max_samples)
    td = t[::q]
    yd = _decimate(y, q)[: td.size]
    fd = _decimate(f, q)[: td.size]
    # the filter's edge transients: drop the first and last filter half-lengths (10 decimated samples)
    edge = 10 if q > 1 else 0
    if edge:
        td, yd, fd = td[edge:-edge], yd[edge:-edge], fd[edge:-edge]
    if td.size < MIN_WHOLE_SAMPLES:
        raise DataError(f"{record.path}: only {td.size} samples after decimation by {q}; whole-record "
                        f"identification needs at least {MIN_WHOLE_SAMPLES}")
    return RecordWindow(window_id or record.name, record.name, td, fd, yd, q, rate / q, kind, description, span,
                        rule)
