"""What kind of test a record is (triangular, sine, other) and whether it can be identified at all.

:func:`classify_record` looks at the displacement only:

* **sine**: the least-squares fit ``y = a cos(2 pi f t) + b sin(2 pi f t) + c + d t`` (slowly drifting
  mean) over the moving part (leading and trailing rest cut), at the FFT peak frequency refined by
  :func:`scipy.optimize.minimize_scalar`, explains ``SINE_R2`` of the variance over ``MIN_CYCLES`` cycles;
* **triangular**: ``TRIANGULAR_FRACTION`` of the moving part is at piecewise-constant velocity (the
  Savitzky-Golay velocity within ``VELOCITY_TOLERANCE`` of its run's level: zero acceleration except at
  isolated corners), with at least one start from rest or reversal;
* **other** otherwise (sweep, multisine, random): described by its band and rms velocity.

:func:`check_record_quality` raises :class:`~bayesdamper.core.errors.DataError` with one line
``"<path>: <problem>"`` for a record no whole-record identification can use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import savgol_filter
from scipy.signal.windows import tukey

from bayesdamper.core.errors import DataError
from bayesdamper.io.dataset import TestRecord

__all__ = ["RecordKind", "check_record_quality", "classify_record", "inspect_record"]

#: Smallest R^2 (of the variance about the best line) of the sine fit. Harmonic distortion d gives R^2 = 1 / (1 + d^2):
#: 1 % 0.9999, 5 % 0.9975, 7 % 0.995. A triangle fitted by its fundamental: (8/pi^2)^2 / 2 / (1/3) = 0.9855 (rig-A's
#: 1.25 cycles with rest: 0.9848). 0.995 lies between: up to 7 % distortion is a sine, a triangle never. The
#: five lab-MR sines (quantised, start-up transient, drifting mean) give 0.9972-0.9987.
SINE_R2 = 0.995
#: Fewest cycles of a sine identified as a whole [-] (less cannot separate stiffness from damping), less
#: ``CYCLE_TOLERANCE``: the frequency of a one-cycle record is fitted to about 1e-3 of itself (a cycle of n
#: samples at exactly one period must not be refused for it).
MIN_CYCLES, CYCLE_TOLERANCE = 1.0, 0.01
#: Below this many cycles a sine arc is not told from a ramp (no "less than one cycle" error) [-].
MIN_PARTIAL_CYCLES = 0.25
#: Zero padding of the FFT locating the frequency peak (peak error below 1/16 of a bin) [-].
FFT_PADDING = 8
#: Fewest samples of a record that is not a triangular test.
MIN_SAMPLES = 200
#: Smoothing window of the velocity [s], as in bayesdamper.io.segmentation ...
SMOOTHING_WINDOW = 0.2
#: ... at most this fraction of the dominant period (a 1 Hz sine at 100 Hz: 5 samples) [-].
SMOOTHING_PERIOD_FRACTION = 0.05
#: A noisy record's window is widened up to this fraction of the period [-] (a sine's velocity stays a sine).
MAX_SMOOTHING_PERIOD_FRACTION = 0.25
#: Fewest samples in the smoothing window [-] (a quadratic Savitzky-Golay fit needs 5).
MIN_SMOOTHING_SAMPLES = 5
#: Rest = smoothed speed below this fraction of the 95th-percentile speed [-] (3 % of a sine's time) ...
REST_FRACTION = 0.05
#: ... or below this many standard deviations of the smoothed-velocity noise [-].
NOISE_SIGMAS = 8.0
#: A sample is at its run's constant velocity within this fraction of the run's median [-] (a sine: 13 % of its time).
VELOCITY_TOLERANCE = 0.1
#: Fewest samples of the moving part at a constant velocity (rest included) for a triangular test [-].
#: Set by the synthetic signals of tests/test_recordkind.py: triangles (rest, noise 0-30 µm, rounded
#: corners, 100 Hz-1 kHz) 0.91-0.99; sines, random-phase multisines and a sweep 0-0.16. Real data:
#: rig-A 0.976-0.989, lab-MR 0.11-0.14.
TRIANGULAR_FRACTION = 0.6
#: Shortest motion or rest run counted as a ramp or a rest, in (unwidened) smoothing windows [-].
MIN_RUN_WINDOWS = 2.0
#: Speeds within this relative difference are reported as one level [-].
SPEED_MERGE = 0.05
#: The displacement is flat when its peak-to-peak (0.1-99.9 percentiles) is below this many noise
#: standard deviations (from the fourth differences; pure Gaussian noise spans 6.2) ...
FLAT_NOISE_FACTOR = 20.0
#: ... or below this [m] (two lab-MR quantisation steps of 5 µm).
FLAT_DISPLACEMENT = 1e-5
#: The force is flat below this many noise sigmas (a force of amplitude 5 sigma still carries a response) ...
FLAT_FORCE_NOISE_FACTOR = 10.0
#: ... or below this fraction of its largest |value| (a constant offset) [-].
FLAT_FORCE_RELATIVE = 1e-3
#: Clipped: at least CLIP_FRACTION of the samples (and CLIP_MIN_SAMPLES) exactly at the channel's max or
#: min, in CLIP_MIN_RUNS or more interior runs of CLIP_RUN samples or more (a saturated sensor or ADC).
CLIP_FRACTION, CLIP_MIN_SAMPLES, CLIP_MIN_RUNS, CLIP_RUN = 0.01, 5, 2, 2
#: ... and the limit holds more than this many times the samples of the next level: the extreme level of a
#: quantised, noisy channel is the tail of its noise and holds no more than the level next to it (a dry-friction
#: plateau read in 3 N steps); a saturated channel piles there every sample that would have passed the limit.
CLIP_SPIKE = 3.0
#: Largest plausible piston speed [m/s]; hydraulic damper rigs stay below 1-2 m/s.
MAX_VELOCITY = 10.0


@dataclass(frozen=True)
class RecordKind:
    """Kind of one record.

    Attributes
    ----------
    name : str
        Record name (file stem).
    kind : str
        ``"triangular"``, ``"sine"`` or ``"other"``.
    description : str
        One human-readable line.
    details : dict
        JSON-able: sine ``amplitude_m``, ``frequency_Hz``, ``offset_m``, ``n_cycles``, ``fit_r2``; triangular
        ``speeds_m_s``, ``n_reversals``, ``fraction_constant_velocity``; other ``rms_velocity_m_s``, ``band_Hz``.
    """

    name: str
    kind: str
    description: str
    details: dict = field(default_factory=dict)


@dataclass(frozen=True)
class _Analysis:
    start: int  # moving part: samples start:stop
    stop: int
    velocity: np.ndarray
    sine: tuple[float, float, float, float, float, bool]  # amplitude, frequency, offset, r2, cycles, interior
    fraction: float  # of the moving part at a constant velocity level
    speeds: list[float]
    n_reversals: int
    triangular: bool


def _noise(x: np.ndarray) -> float:
    """Robust noise standard deviation from the fourth differences (MAD) [unit of x]: a 3 Hz multisine at
    100 Hz has second differences of 4 % of its amplitude (they passed for noise), fourth ones of 0.1 %."""
    d4 = np.diff(x, 4)
    return 1.4826 * float(np.median(np.abs(d4 - np.median(d4)))) / math.sqrt(70.0)


def _peak_frequency(t: np.ndarray, y: np.ndarray, f_min: float) -> float:
    """Frequency of the largest zero-padded FFT peak above ``f_min`` [Hz]."""
    nfft = FFT_PADDING * int(2 ** math.ceil(math.log2(y.size)))
    spec, f = np.abs(np.fft.rfft(y - y.mean(), nfft)), np.fft.rfftfreq(nfft, float(np.median(np.diff(t))))
    return float(f[int(np.argmax(np.where(f < f_min, 0.0, spec)))])


def _fit_sine(t: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, float, bool]:
    """(amplitude [m], frequency [Hz], mid-span offset [m], R^2, cycles, optimum inside the search bounds).
    The offset may drift linearly (``+ d (t - t_mid)``): the lab-MR ensaio10 mean creeps 2 mm in 27 s."""
    tc = t - t[0]
    span = float(tc[-1])
    # R^2 relative to the best straight line: the sine, not the drift, must explain the motion
    var = float(np.sum((y - np.polyval(np.polyfit(tc, y, 1), tc)) ** 2)) if tc.size > 2 else 0.0
    if span <= 0 or var <= 1e-12 * float(np.sum((y - y.mean()) ** 2)):
        return 0.0, 0.0, float(np.mean(y)), 0.0, 0.0, False

    def solve(f: float) -> tuple[np.ndarray, float]:
        w = 2 * np.pi * f * tc
        x = np.column_stack((np.cos(w), np.sin(w), np.ones_like(tc), tc - 0.5 * span))
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        return coef, float(np.sum((y - x @ coef) ** 2))

    lo_bound, hi_bound = MIN_PARTIAL_CYCLES / span, 0.5 / float(np.median(np.diff(t)))
    f0 = _peak_frequency(t, y, lo_bound)
    # the R^2(f) peak of a sine is about one bin (1/span) wide: grid the neighbourhood, then refine
    grid = np.linspace(max(lo_bound, f0 - 1.5 / span), min(hi_bound, f0 + 1.5 / span), 31)
    k = int(np.argmin([solve(f)[1] for f in grid]))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    f = float(minimize_scalar(lambda f: solve(f)[1], bounds=(a, b), method="bounded",
                              options={"xatol": 1e-6 * (b - a + 1e-12)}).x)
    coef, sse = solve(f)
    interior = lo_bound * 1.01 < f < hi_bound * 0.99
    covered = span + float(np.median(np.diff(t)))  # n samples stand for n sample intervals of the motion
    return float(math.hypot(coef[0], coef[1])), f, float(coef[2]), 1.0 - sse / var, f * covered, interior


def _runs(state: np.ndarray) -> list[tuple[int, int, int]]:
    """Runs of equal values as (value, start, stop)."""
    edges = [0, *(np.flatnonzero(np.diff(state)) + 1).tolist(), state.size]
    return [(int(state[a]), a, b) for a, b in zip(edges, edges[1:], strict=False)]


def _analyse(record: TestRecord) -> _Analysis:
    """Smoothed velocity, its runs (rest / forward / backward), the moving part and the sine fit on it."""
    t, y = record.time, record.displacement
    dt = float(np.median(np.diff(t)))
    f_dom = _peak_frequency(t, y, 1.0 / max(record.duration, dt))
    period = 1.0 / f_dom if f_dom > 0 else record.duration
    sigma_y, n_max = _noise(y), y.size if y.size % 2 else y.size - 1
    n = min(n_max, max(MIN_SMOOTHING_SAMPLES, int(min(SMOOTHING_WINDOW, SMOOTHING_PERIOD_FRACTION * period) / dt) | 1))
    v = savgol_filter(y, n, 2, deriv=1, delta=dt, mode="interp")
    v_ref = float(np.percentile(np.abs(v), 95))
    min_run = max(3, int(MIN_RUN_WINDOWS * n))  # from the unwidened window: at most 0.1 period
    # widen the window until NOISE_SIGMAS of the velocity noise (~ sigma_y sqrt(12 / n^3) / dt) are below
    # half the rest threshold, up to MAX_SMOOTHING_PERIOD_FRACTION of the period
    n_quiet = math.ceil((12 * (2 * NOISE_SIGMAS * sigma_y / (dt * REST_FRACTION * max(v_ref, 1e-300))) ** 2) ** (1 / 3))
    if n_quiet > n:
        n = min(n_max, max(n, int(MAX_SMOOTHING_PERIOD_FRACTION * period / dt)), n_quiet) | 1  # n_max is odd
        v = savgol_filter(y, n, 2, deriv=1, delta=dt, mode="interp")
        v_ref = float(np.percentile(np.abs(v), 95))
    noise_v = NOISE_SIGMAS * sigma_y * math.sqrt(12.0 / (n * (n * n - 1.0))) / dt  # NOISE_SIGMAS velocity sigmas
    state = np.where(np.abs(v) > max(REST_FRACTION * v_ref, noise_v), np.sign(v), 0).astype(int)
    runs = _runs(state)
    moving = [r for r in runs if r[0] != 0 and r[2] - r[1] >= min_run]
    # the moving part: leading and trailing rest cut (short runs count: a sweep's last half-cycles)
    span = [r for r in runs if r[0] != 0 and r[2] - r[1] >= 3]
    start, stop = (span[0][1], span[-1][2]) if span else (0, y.size)
    steady = 0
    for s, a, b in ((s, max(a, start), min(b, stop)) for s, a, b in runs if b > start and a < stop):
        level = float(np.median(v[a:b])) if s else 0.0
        steady += int(np.count_nonzero(np.abs(v[a:b] - level) <= max(VELOCITY_TOLERANCE * abs(level), noise_v)))
    # a velocity too noisy to separate rest from motion shows no constant levels
    fraction = steady / max(stop - start, 1) if noise_v <= REST_FRACTION * v_ref else 0.0
    # runs long enough to be a ramp or a rest, in order: (+1, -1) is a reversal, (0, +-1) a start
    states = [s for s, a, b in runs if b - a >= min_run]
    n_reversals = sum(1 for p, q in zip(states, states[1:], strict=False) if p * q < 0)
    n_starts = sum(1 for p, q in zip(states, states[1:], strict=False) if p == 0 and q != 0)
    levels = np.sort([abs(float(np.median(v[a:b]))) for _, a, b in moving])  # ramp speeds, grouped by gaps
    groups = np.split(levels, np.flatnonzero(np.diff(levels) > SPEED_MERGE * levels[:-1]) + 1)
    speeds = [float(g.mean()) for g in groups if g.size]
    triangular = fraction >= TRIANGULAR_FRACTION and n_reversals + n_starts >= 1
    return _Analysis(start, stop, v, _fit_sine(t[start:stop], y[start:stop]), fraction, speeds, n_reversals, triangular)


def _band(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Frequencies holding the central 98 % of the displacement's power [Hz] (10 % Tukey window: a Hann
    window would hide the ends of a sweep, i.e. of its band)."""
    p = np.abs(np.fft.rfft((y - y.mean()) * tukey(y.size, 0.1))) ** 2
    f = np.fft.rfftfreq(y.size, float(np.median(np.diff(t))))
    lo, hi = np.minimum(np.searchsorted(np.cumsum(p) / max(float(np.sum(p)), 1e-300), [0.01, 0.99]), f.size - 1)
    return float(f[lo]), float(f[hi])


def classify_record(record: TestRecord) -> RecordKind:
    """Classify a record as ``"sine"``, ``"triangular"`` or ``"other"`` from its displacement.

    Parameters
    ----------
    record : TestRecord

    Returns
    -------
    RecordKind
        With a one-line description and the numbers behind it (see :class:`RecordKind`).
    """
    return _classify(record, _analyse(record))


def _classify(record: TestRecord, a: _Analysis) -> RecordKind:
    amp, freq, offset, r2, cycles, _ = a.sine
    if r2 >= SINE_R2 and cycles >= MIN_CYCLES - CYCLE_TOLERANCE:
        details = {"amplitude_m": amp, "frequency_Hz": freq, "offset_m": offset, "n_cycles": cycles, "fit_r2": r2}
        text = f"sine, amplitude {amp * 1e3:.3g} mm, {freq:.3g} Hz, mean {offset * 1e3:.3g} mm, {cycles:.1f} cycles"
        return RecordKind(record.name, "sine", text, details)
    if a.triangular:
        details = {"speeds_m_s": [float(s) for s in a.speeds], "n_reversals": a.n_reversals,
                   "fraction_constant_velocity": a.fraction}
        text = "triangular, speeds " + ", ".join(f"{s * 1e3:.2f}" for s in a.speeds) + " mm/s"
        return RecordKind(record.name, "triangular", text, details)
    rms = float(np.sqrt(np.mean(a.velocity[a.start:a.stop] ** 2)))
    lo, hi = _band(record.time[a.start:a.stop], record.displacement[a.start:a.stop])
    width = "broadband" if hi > 2 * max(lo, 1e-300) else "narrow-band"
    text = f"other ({width}: {lo:.2g}-{hi:.2g} Hz, rms velocity {rms * 1e3:.3g} mm/s)"
    return RecordKind(record.name, "other", text, {"rms_velocity_m_s": rms, "band_Hz": [lo, hi]})


def _clipped(x: np.ndarray) -> tuple[float, int, int] | None:
    """(limit, samples at it, runs) if ``x`` sits at its max or min in several interior runs, and the limit holds
    more than :data:`CLIP_SPIKE` times the samples of the level next to it (a quantised channel's extreme level is
    the tail of its noise, a saturated one's every sample that would have passed it)."""
    need = max(CLIP_MIN_SAMPLES, math.ceil(CLIP_FRACTION * x.size))
    levels = np.unique(x)
    for limit, side in ((float(np.max(x)), -1), (float(np.min(x)), 1)):
        runs = [(a, b) for s, a, b in _runs((x == limit).astype(int))
                if s and b - a >= CLIP_RUN and a > 0 and b < x.size]  # rest at an end is not clipping
        count = sum(b - a for a, b in runs)
        if len(runs) < CLIP_MIN_RUNS or count < need:
            continue
        nxt = levels[-2] if side < 0 else levels[1] if levels.size > 1 else limit
        if int(np.count_nonzero(x == limit)) > CLIP_SPIKE * max(int(np.count_nonzero(x == nxt)), 1):
            return limit, count, len(runs)
    return None


def check_record_quality(record: TestRecord) -> None:
    """Raise if a record cannot be identified as a whole.

    Parameters
    ----------
    record : TestRecord

    Raises
    ------
    DataError
        ``"<path>: <problem>"``: too few samples, a flat or clipped channel, implausible velocities, or a sine
        shorter than one cycle.
    """
    _check_basic(record)
    _check_analysed(record)


def _check_basic(record: TestRecord) -> None:
    """The checks that need no analysis of the displacement's shape."""
    path, t, y, force = record.path, record.time, record.displacement, record.force
    if y.size < MIN_SAMPLES:
        raise DataError(f"{path}: record has {y.size} samples, fewer than the {MIN_SAMPLES} needed for whole-record "
                        "identification")
    y_pp = float(np.percentile(y, 99.9) - np.percentile(y, 0.1))
    if y_pp < max(FLAT_NOISE_FACTOR * _noise(y), FLAT_DISPLACEMENT):
        raise DataError(f"{path}: displacement_m hardly moves (peak-to-peak {y_pp:.2g} m): "
                        "no excitation to identify from")
    f_pp = float(np.percentile(force, 99.9) - np.percentile(force, 0.1))
    level = float(np.max(np.abs(force)))
    if f_pp <= max(FLAT_FORCE_NOISE_FACTOR * _noise(force), FLAT_FORCE_RELATIVE * level):
        raise DataError(f"{path}: force_N is flat (peak-to-peak {f_pp:.2g} N at a level of {level:.3g} N): "
                        f"no response to identify from")
    for name, unit, x in (("displacement_m", "m", y), ("force_N", "N", force)):
        if clip := _clipped(x):
            raise DataError(f"{path}: {name} is clipped at {clip[0]:.6g} {unit} ({clip[1]} samples at the "
                            f"limit in {clip[2]} runs): saturated sensor")
    v_peak = float(np.percentile(np.abs(np.gradient(y, t)), 99))
    if v_peak > MAX_VELOCITY:
        raise DataError(f"{path}: displacement_m implies velocities up to {v_peak:.3g} m/s: wrong unit or time column?")


def _check_analysed(record: TestRecord) -> _Analysis:
    """The checks that need the displacement analysed; returns the analysis."""
    t, a = record.time, _analyse(record)
    _, freq, _, r2, cycles, interior = a.sine
    too_short = MIN_PARTIAL_CYCLES <= cycles < MIN_CYCLES - CYCLE_TOLERANCE
    if r2 >= SINE_R2 and interior and too_short and not a.triangular:
        span = float(t[a.stop - 1] - t[a.start])
        lasts = "lasts" if span >= 0.99 * record.duration else "moves for"
        raise DataError(f"{record.path}: record {lasts} {span:.2g} s, less than one cycle of its {freq:#.2g} Hz "
                        f"motion (need at least one)")
    return a


def inspect_record(record: TestRecord) -> RecordKind:
    """:func:`check_record_quality`, then :func:`classify_record`, analysing the displacement once."""
    _check_basic(record)
    return _classify(record, _check_analysed(record))
