"""Segmentation of a triangular-displacement record into velocity steps, transients and plateaus.

The commanded displacement is piecewise linear: rest, then ramps at constant velocity ``±|V_P|``
(``|V_P| = 4 Y_P / T``). Each velocity step (the start from rest, each reversal) is followed by a
transient of the force (stage 2 of the method fits eq. (7) to it over ``[t_step, t_step + T_max]``,
eq. (9), or up to the end of its ramp where that comes first) and then by a steady plateau (stage 1 fits eq. (4)
to the plateaus).

Method (robust to noise, sample rate and slightly rounded corners):

1. Smoothed velocity: local linear-regression slope (Savitzky-Golay, order 1, derivative) of the displacement
   over ``smoothing_window`` seconds.
2. Each sample is labelled rest (0), forward (+1) or backward (-1) by comparing the smoothed velocity
   with a threshold ``max(VELOCITY_THRESHOLD_FRACTION * v_ref, NOISE_THRESHOLD_SIGMAS * sigma_v)``,
   where ``v_ref`` is a high percentile of the smoothed speed and ``sigma_v`` the noise of the
   smoothed velocity estimated from the second differences of the displacement. Runs of one label
   shorter than ``min_segment`` seconds (the corner regions) are dropped; neighbouring runs with the
   same label are merged.
3. A straight line is fitted by least squares (one outlier-rejection pass) to the interior of each run,
   excluding ``max(corner_margin, smoothing_window, CORNER_FRACTION * run length)`` at both ends; rest
   runs are fitted with a constant ``y = const``.
4. The knots of the continuous piecewise-linear model are the intersections of adjacent fitted lines,
   plus the first and last sample times. Velocities are the fitted slopes.

A knot is a *velocity step* when motion starts from rest (``kind="initial"``) or the velocity changes
sign (``kind="reversal"``). Other knots (a stop, a change of speed without reversal) bound ramps but
start no transient.

Plateau rule: the plateau of a ramp that runs from knot ``t_a`` to knot ``t_b`` is the samples in
``[t_b - plateau_margin - plateau_fraction (t_b - t_a), t_b - plateau_margin]``, i.e. the last
``plateau_fraction`` (default 30 %) of the ramp, ending ``plateau_margin`` (default 0.2 s) before the
next corner (or the end of the record).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.core.frozen import frozen_copy
from bayesdamper.core.params import DamperConstants
from bayesdamper.io.dataset import Dataset, TestRecord
from bayesdamper.io.segments import Plateau, SegmentedRecord, StepKind, VelocityStep
from bayesdamper.io.windows import Window
from bayesdamper.physics.excitation import PiecewisePolynomial

__all__ = [
    "CORNER_MARGIN",
    "MIN_SEGMENT",
    "PLATEAU_FRACTION",
    "PLATEAU_MARGIN",
    "SMOOTHING_WINDOW",
    "STEP_FORCE_WINDOW",
    "Plateau",
    "SegmentedRecord",
    "Window",
    "VelocityStep",
    "segment_dataset",
    "segment_record",
]
#: Length of the local linear regression giving the smoothed velocity [s].
SMOOTHING_WINDOW = 0.2
#: Fewest samples in the smoothing window, whatever the sample rate [-].
MIN_SMOOTHING_SAMPLES = 5
#: Speed threshold as a fraction of the reference speed (95th percentile of |smoothed velocity|) [-].
VELOCITY_THRESHOLD_FRACTION = 0.25
#: Percentile of the smoothed speed taken as the reference speed [%].
REFERENCE_SPEED_PERCENTILE = 95.0
#: Speed threshold in standard deviations of the smoothed-velocity noise [-].
NOISE_THRESHOLD_SIGMAS = 8.0
#: Shortest run of one motion state kept as a segment; shorter runs are corner regions [s].
MIN_SEGMENT = 0.4
#: Data excluded from each line fit next to a corner, at least [s].
CORNER_MARGIN = 0.25
#: ... and at least this fraction of the run's length [-].
CORNER_FRACTION = 0.1
#: Residual beyond which a sample is rejected from a line fit, in robust standard deviations [-].
OUTLIER_SIGMAS = 5.0
#: Length of the force average just before a step giving the step force [s].
STEP_FORCE_WINDOW = 0.15
#: Plateau = this last fraction of a ramp [-] ...
PLATEAU_FRACTION = 0.3
#: ... ending this long before the next corner or the end of the record [s].
PLATEAU_MARGIN = 0.2
#: Fewest samples in a plateau [-].
MIN_PLATEAU_SAMPLES = 5


@dataclass(frozen=True)
class _Segment:
    state: int  # 0 rest, +1 / -1 moving
    start: int  # first sample of the run
    stop: int  # one past the last sample of the run
    fit_start: int  # first sample used by the line fit
    fit_stop: int  # one past the last sample used
    intercept: float  # line y = intercept + slope * (t - t_ref)
    slope: float
    t_ref: float

    def at(self, t: float | np.ndarray) -> float | np.ndarray:
        return self.intercept + self.slope * (t - self.t_ref)


def _odd(n: int) -> int:
    return n if n % 2 else n + 1


def _smoothed_velocity(t: np.ndarray, y: np.ndarray, window: float) -> tuple[np.ndarray, float]:
    """Local linear-regression slope of y [m/s] and its noise standard deviation [m/s]."""
    dt = float(np.median(np.diff(t)))
    n = _odd(max(MIN_SMOOTHING_SAMPLES, int(round(window / dt))))
    if n > y.size:
        n = y.size if y.size % 2 else y.size - 1
    h = n // 2
    j = np.arange(-h, h + 1, dtype=float)
    # slope of the least-squares line through n samples centred on each sample (Savitzky-Golay,
    # order 1); the h samples at each edge take the slope of the first / last full window
    inner = np.convolve(y, j[::-1] / (np.dot(j, j) * dt), mode="valid")
    v = np.concatenate((np.full(h, inner[0]), inner, np.full(h, inner[-1])))
    d2 = np.diff(y, 2)
    sigma_y = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    sigma_v = sigma_y * math.sqrt(12.0 / (n * (n * n - 1.0))) / dt
    return v, sigma_v


def _runs(state: np.ndarray) -> list[tuple[int, int, int]]:
    """Runs of equal values as (value, start, stop)."""
    edges = np.flatnonzero(np.diff(state)) + 1
    starts = np.concatenate(([0], edges))
    stops = np.concatenate((edges, [state.size]))
    return [(int(state[a]), int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def _fit_line(t: np.ndarray, y: np.ndarray, rest: bool) -> tuple[float, float, float]:
    """Least-squares line (or constant when ``rest``) with one outlier-rejection pass."""
    t_ref = float(t.mean())
    x = t - t_ref
    keep = np.ones(t.size, dtype=bool)
    for _ in range(2):
        xs, ys = x[keep], y[keep]
        if rest:
            slope, intercept = 0.0, float(ys.mean())
        else:
            xc = xs - xs.mean()
            slope = float(np.dot(xc, ys - ys.mean()) / np.dot(xc, xc))
            intercept = float(ys.mean() - slope * xs.mean())
        r = y - (intercept + slope * x)
        scale = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        if scale == 0:
            break
        new = np.abs(r) <= OUTLIER_SIGMAS * scale
        if new.sum() < max(3, keep.size // 2) or (new == keep).all():
            break
        keep = new
    return intercept, slope, t_ref


def _segments(
    record: TestRecord, smoothing_window: float, min_segment: float, corner_margin: float
) -> list[_Segment]:
    t, y = record.time, record.displacement
    dt = float(np.median(np.diff(t)))
    v, sigma_v = _smoothed_velocity(t, y, smoothing_window)
    v_ref = float(np.percentile(np.abs(v), REFERENCE_SPEED_PERCENTILE))
    threshold = max(VELOCITY_THRESHOLD_FRACTION * v_ref, NOISE_THRESHOLD_SIGMAS * sigma_v)
    state = np.where(v > threshold, 1, np.where(v < -threshold, -1, 0))

    min_len = max(3, int(math.ceil(min_segment / dt)))
    kept: list[list[int]] = []
    for s, a, b in _runs(state):
        if b - a < min_len:
            continue
        if kept and kept[-1][0] == s:
            kept[-1][2] = b  # merge across a dropped short run
        else:
            kept.append([s, a, b])

    if not kept:
        raise DataError(f"{record.path}: no segment of rest or constant velocity found")
    segments = []
    for s, a, b in kept:
        margin = max(corner_margin, smoothing_window, CORNER_FRACTION * (t[b - 1] - t[a]))
        lo = int(np.searchsorted(t, t[a] + margin))
        hi = int(np.searchsorted(t, t[b - 1] - margin, side="right"))
        if hi - lo < 3:  # short run: keep its middle
            mid = (a + b) // 2
            lo, hi = max(a, mid - 1), min(b, mid + 2)
        intercept, slope, t_ref = _fit_line(t[lo:hi], y[lo:hi], rest=(s == 0))
        segments.append(_Segment(s, a, b, lo, hi, intercept, slope, t_ref))
    return segments


def _knots(t: np.ndarray, segments: list[_Segment]) -> tuple[np.ndarray, np.ndarray]:
    """Knots of the continuous piecewise-linear model: intersections of adjacent lines."""
    times = [float(t[0])]
    values = [float(segments[0].at(t[0]))]
    for s1, s2 in zip(segments[:-1], segments[1:], strict=True):
        lo, hi = float(t[s1.fit_stop - 1]), float(t[s2.fit_start])
        ds = s1.slope - s2.slope
        # y1(tk) = y2(tk): a1 + b1 (tk - r1) = a2 + b2 (tk - r2)
        num = s2.intercept - s1.intercept + s1.slope * s1.t_ref - s2.slope * s2.t_ref
        tk = num / ds if ds != 0 else 0.5 * (lo + hi)
        if not (lo <= tk <= hi):  # nearly parallel lines: keep the knot between the fitted parts
            tk = min(max(tk, lo), hi)
        times.append(tk)
        values.append(0.5 * float(s1.at(tk) + s2.at(tk)))
    times.append(float(t[-1]))
    values.append(float(segments[-1].at(t[-1])))
    return np.asarray(times), np.asarray(values)


def _check_settings(tmax: float, plateau_fraction: float, plateau_margin: float, **positive: float) -> None:
    if not (math.isfinite(tmax) and tmax > 0):
        raise SettingsError(f"tmax must be a positive number of seconds, got {tmax!r}")
    if not (0 < plateau_fraction <= 1):
        raise SettingsError(f"plateau_fraction must be in (0, 1], got {plateau_fraction!r}")
    if not (math.isfinite(plateau_margin) and plateau_margin >= 0):
        raise SettingsError(f"plateau_margin must be >= 0 s, got {plateau_margin!r}")
    for name, value in positive.items():
        if not (math.isfinite(value) and value > 0):
            raise SettingsError(f"{name} must be a positive number of seconds, got {value!r}")


def segment_record(
    record: TestRecord,
    damper: DamperConstants,
    *,
    tmax: float = 3.0,
    plateau_fraction: float = PLATEAU_FRACTION,
    plateau_margin: float = PLATEAU_MARGIN,
    smoothing_window: float = SMOOTHING_WINDOW,
    min_segment: float = MIN_SEGMENT,
    corner_margin: float = CORNER_MARGIN,
) -> SegmentedRecord:
    """Find the velocity steps, transient windows and plateaus of one record.

    Parameters
    ----------
    record : TestRecord
        A validated record.
    damper : DamperConstants
        Damper constants; only the piston area A_P [m^2] is used (Δp = F_D / A_P).
    tmax : float
        Transient window length T_max of eq. (9) [s]. A window whose ramp ends sooner (a fast or short test: the
        next velocity change, or the end of the record, comes before T_max) ends with its ramp.
    plateau_fraction : float
        Fraction of each ramp, at its end, taken as the plateau [-].
    plateau_margin : float
        Gap between the plateau's end and the next corner (or the end of the record) [s].
    smoothing_window, min_segment, corner_margin : float
        Velocity smoothing length, shortest kept segment, and least data excluded from each line fit
        next to a corner [s]; see the module docstring.

    Returns
    -------
    SegmentedRecord

    Raises
    ------
    DataError
        The record has no velocity step, or a ramp is too short for a plateau.
    """
    _check_settings(
        tmax,
        plateau_fraction,
        plateau_margin,
        smoothing_window=smoothing_window,
        min_segment=min_segment,
        corner_margin=corner_margin,
    )
    path = record.path
    t, y, force = record.time, record.displacement, record.force
    area = damper.piston_area
    segments = _segments(record, smoothing_window, min_segment, corner_margin)
    knot_t, knot_y = _knots(t, segments)

    steps: list[VelocityStep] = []
    step_knots: list[int] = []  # knot index of each step
    pre_samples: list[tuple[np.ndarray, np.ndarray]] = []  # (times, forces) the step force is the mean of
    for k, (s1, s2) in enumerate(zip(segments[:-1], segments[1:], strict=True)):
        if s2.state == 0 or s1.state == s2.state:
            continue
        if s1.state == 0:
            kind: StepKind = "initial"
        elif s1.state == -s2.state:
            kind = "reversal"
        else:  # pragma: no cover - states are -1, 0, 1
            continue
        tk = float(knot_t[k + 1])
        before = (t >= tk - STEP_FORCE_WINDOW) & (t < tk)
        if not before.any():
            before = t < tk
        f_step = float(force[before].mean())
        pre_samples.append((t[before], force[before]))
        steps.append(
            VelocityStep(
                index=len(steps),
                time=tk,
                velocity_before=float(s1.slope),
                velocity_after=float(s2.slope),
                kind=kind,
                direction=1 if s2.slope > 0 else -1,
                force=f_step,
            )
        )
        step_knots.append(k + 1)
    if not steps:
        raise DataError(
            f"{path}: no velocity step found (no start from rest and no reversal of the displacement)"
        )

    transients = []
    eps = 1e-9 * float(t[1] - t[0])
    drive = PiecewisePolynomial.from_knots(knot_t, knot_y)
    for step, kk, (pre_t, pre_f) in zip(steps, step_knots, pre_samples, strict=True):
        # the window ends T_max after its step, or where its ramp ends first: at the next knot (a velocity change,
        # or the end of the record, the last knot)
        t_end = min(step.time + tmax, float(knot_t[kk + 1]))
        win = (t >= step.time) & (t <= t_end + eps)
        transients.append(
            Window(
                id=f"{record.name}_s{step.index}",
                test=record.name,
                index=step.index,
                kind=step.kind,
                direction=step.direction,
                velocity=abs(step.velocity_after),
                t_step=step.time,
                time=frozen_copy(t[win]),
                displacement=frozen_copy(y[win]),
                force=frozen_copy(force[win]),
                dp0=step.force / area,
                drive=drive,
                pre_time=frozen_copy(pre_t),
                pre_force=frozen_copy(pre_f),
            )
        )

    plateaus = []
    for k, seg in enumerate(segments):
        if seg.state == 0:
            continue
        ta, tb = float(knot_t[k]), float(knot_t[k + 1])
        p_end = tb - plateau_margin
        p_start = p_end - plateau_fraction * (tb - ta)
        sel = (t >= p_start) & (t <= p_end)
        n = int(sel.sum())
        if n < MIN_PLATEAU_SAMPLES:
            raise DataError(
                f"{path}: the ramp from {ta:.3f} s to {tb:.3f} s is too short for a plateau "
                f"({n} samples; need {MIN_PLATEAU_SAMPLES})"
            )
        direction = 1 if seg.slope > 0 else -1
        dp = force[sel] / area
        plateaus.append(
            Plateau(
                test=record.name,
                index=len(plateaus),
                direction=direction,
                velocity=abs(seg.slope),
                flow_rate=area * abs(seg.slope),
                pressure_drop=direction * float(dp.mean()),
                pressure_drop_std=float(dp.std(ddof=1)),
                n=n,
                t_start=float(t[sel][0]),
                t_end=float(t[sel][-1]),
            )
        )

    return SegmentedRecord(
        record=record,
        steps=tuple(steps),
        transients=tuple(transients),
        plateaus=tuple(plateaus),
        knot_times=frozen_copy(knot_t),
        knot_displacements=frozen_copy(knot_y),
    )


def segment_dataset(
    dataset: Dataset,
    *,
    tmax: float = 3.0,
    plateau_fraction: float = PLATEAU_FRACTION,
    plateau_margin: float = PLATEAU_MARGIN,
    smoothing_window: float = SMOOTHING_WINDOW,
    min_segment: float = MIN_SEGMENT,
    corner_margin: float = CORNER_MARGIN,
) -> tuple[SegmentedRecord, ...]:
    """Segment every record of a data set (see :func:`segment_record`), in the data set's order."""
    return tuple(
        segment_record(
            r,
            dataset.damper,
            tmax=tmax,
            plateau_fraction=plateau_fraction,
            plateau_margin=plateau_margin,
            smoothing_window=smoothing_window,
            min_segment=min_segment,
            corner_margin=corner_margin,
        )
        for r in dataset.records
    )
