"""The force noise of a triangular test, estimated where the model is exact: on the plateaus.

On a plateau the piston moves at constant speed and the force has settled, so the model force is a constant
and what scatters about the plateau's mean is noise alone, whatever the model misses in the transients. The
joint stage 2 (:mod:`bayesdamper.inference.joint`) takes its AR(1) coefficient from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayesdamper.inference.priors import PHI_BOUNDS


@dataclass(frozen=True)
class PlateauNoise:
    """AR(1) force noise estimated from the plateaus.

    Attributes
    ----------
    phi : float
        Lag-1 coefficient [-] (bias-corrected, see :func:`plateau_noise`).
    sigma_e : float
        Innovation standard deviation [N].
    n_samples, n_plateaus : int
    """

    phi: float
    sigma_e: float
    n_samples: int
    n_plateaus: int

    @property
    def sigma(self) -> float:
        """Marginal standard deviation of the noise [N]."""
        return self.sigma_e / math.sqrt(1.0 - self.phi * self.phi)

    def as_dict(self) -> dict:
        return {"phi": self.phi, "sigma_e_N": self.sigma_e, "sigma_N": self.sigma,
                "n_samples": self.n_samples, "n_plateaus": self.n_plateaus, "source": "plateaus"}


def _expected_lag_sums(phi: float, lengths: np.ndarray) -> tuple[float, float]:
    """E[Σ x_t x_{t-1}] and E[Σ x_{t-1}²] over stretches of unit-variance AR(1) noise of the given lengths,
    each about its own sample mean (x = y − ȳ), in closed form."""
    num = den = 0.0
    for n in lengths:
        k = np.arange(1, n)
        pk = phi ** k
        e_mean2 = (n + 2.0 * np.sum((n - k) * pk)) / n**2  # E[ȳ²]
        e_mean_end = (1.0 + np.sum(pk)) / n  # E[ȳ y_1] = E[ȳ y_n]
        num += (n - 1) * phi - (2 * n * e_mean2 - 2 * e_mean_end) + (n - 1) * e_mean2
        den += (n - 1) - 2 * (n * e_mean2 - e_mean_end) + (n - 1) * e_mean2
    return float(num), float(den)


def _lag_quadratic_forms(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lag-1 quadratic forms of :func:`_expected_lag_sums` applied to the columns of ``v``: A_num v with
    A_num the symmetric lag matrix ((v_{t-1} + v_{t+1}) / 2), and A_den v with A_den = diag(1, ..., 1, 0)."""
    a_num = np.zeros_like(v)
    a_num[1:] += 0.5 * v[:-1]
    a_num[:-1] += 0.5 * v[1:]
    a_den = v.copy()
    a_den[-1] = 0.0
    return a_num, a_den


def _expected_lag_sums_detrended(phi: float, lengths: np.ndarray) -> tuple[float, float]:
    """E[Σ x_t x_{t-1}] and E[Σ x_{t-1}²] as :func:`_expected_lag_sums`, each stretch about its own least-squares
    line: x = M y with M = I - Q Q' (Q an orthonormal basis of a constant and a linear trend), so
    E[x' A x] = tr(A Σ) - 2 tr(Q' A Σ Q) + tr(Q' A Q Q' Σ Q) for the unit-variance AR(1) covariance Σ = φ^|i-j|,
    with Σ Q by a forward and a backward first-order recursion (O(n) per stretch)."""
    from scipy.signal import lfilter

    num = den = 0.0
    for n in lengths:
        n = int(n)
        tt = np.arange(n, dtype=float)
        q, _ = np.linalg.qr(np.column_stack([np.ones(n), tt - tt.mean()]))
        fwd = lfilter([1.0], [1.0, -phi], q, axis=0)
        bwd = lfilter([1.0], [1.0, -phi], q[::-1], axis=0)[::-1]
        sq = fwd + bwd - q  # Σ Q
        qsq = q.T @ sq
        aq_num, aq_den = _lag_quadratic_forms(q)
        num += (n - 1) * phi - 2.0 * float(np.sum(aq_num * sq)) + float(np.trace((q.T @ aq_num) @ qsq))
        den += (n - 1) - 2.0 * float(np.sum(aq_den * sq)) + float(np.trace((q.T @ aq_den) @ qsq))
    return float(num), float(den)


def _detrended(s: np.ndarray) -> np.ndarray:
    """``s`` less its least-squares line in the sample index."""
    tt = np.arange(s.size, dtype=float) - 0.5 * (s.size - 1)
    return s - s.mean() - tt * float(tt @ s) / float(tt @ tt)


def ar1_from_segments(segments: list[np.ndarray], *, detrend: bool = False) -> PlateauNoise:
    """AR(1) φ and σ_e from several stretches of noise, each about its own unknown mean (``detrend``: about its
    own unknown line).

    The pooled least-squares lag-1 coefficient r = Σ x_t x_{t−1} / Σ x_{t−1}² of mean-removed stretches is
    biased low (by about (1 + 3φ)/n for a stretch of n samples, Marriott & Pope 1954, and by less near φ = 1,
    where that formula over-corrects two-fold at n = 300, φ = 0.97). Pooled over many stretches, numerator and
    denominator concentrate at their expectations, which are closed-form functions of φ and the stretch
    lengths (:func:`_expected_lag_sums`); φ is the root of E[num](φ)/E[den](φ) = r. σ_e² is the mean square of
    the innovations on N − 2m degrees of freedom (a mean and a lag per stretch). With ``detrend`` each stretch
    is taken about its least-squares line, the expectations are those of :func:`_expected_lag_sums_detrended`
    and the degrees of freedom N − 3m.
    """
    from scipy.optimize import brentq

    num = den = 0.0
    xs = []
    for s in segments:
        s = np.asarray(s, dtype=float)
        if s.size < 5:
            continue
        x = _detrended(s) if detrend else s - s.mean()
        xs.append(x)
        num += float(x[1:] @ x[:-1])
        den += float(x[:-1] @ x[:-1])
    if not xs or den <= 0.0:
        raise ValueError("no plateau stretch of at least 5 samples with any scatter")
    raw = num / den
    lengths = np.array([x.size for x in xs])

    def g(phi):
        a, b = (_expected_lag_sums_detrended if detrend else _expected_lag_sums)(phi, lengths)
        return a / b - raw

    lo, hi = PHI_BOUNDS[0], 0.995
    if g(lo) >= 0:
        phi = lo
    elif g(hi) <= 0:
        phi = hi
    else:
        phi = float(brentq(g, lo, hi, xtol=1e-10))
    n, m = int(lengths.sum()), len(xs)
    ss = sum(float(np.sum((x[1:] - phi * x[:-1]) ** 2)) for x in xs)
    sigma_e = math.sqrt(ss / max(n - (3 if detrend else 2) * m, 1))
    return PlateauNoise(phi, sigma_e, n, m)


def plateau_noise(segmented_records, *, detrend: bool = False) -> PlateauNoise:
    """:func:`ar1_from_segments` on the force samples of every plateau of a segmented data set (``detrend``: each
    plateau about its own least-squares line)."""
    segs = []
    for s in segmented_records:
        t, f = s.record.time, s.record.force
        for p in s.plateaus:
            segs.append(f[(t >= p.t_start) & (t <= p.t_end)])
    return ar1_from_segments(segs, detrend=detrend)


#: |t| of a plateau's linear trend above which it is not settled (two-sided p = 0.0027 for a settled plateau:
#: over 18 plateaus a 5 % chance of losing one good plateau, which costs only its data).
SETTLED_T = 3.0
#: Plateaus kept per direction whatever their trend (stage 1 needs three for one residual degree of freedom).
MIN_PLATEAUS_PER_DIRECTION = 3


def plateau_trend_t(t: np.ndarray, f: np.ndarray, noise: PlateauNoise) -> float:
    """t-statistic of the least-squares slope of force ``f`` [N] over times ``t`` [s], its standard error that of
    AR(1) noise (large-sample: the white-noise error × sqrt((1 + φ)/(1 − φ)))."""
    x = t - t.mean()
    sxx = float(x @ x)
    if sxx <= 0.0:
        return 0.0
    slope = float(x @ (f - f.mean())) / sxx
    phi = noise.phi
    se = noise.sigma * math.sqrt((1.0 + phi) / (1.0 - phi) / sxx)
    return slope / se if se > 0 else 0.0


def _with_leads(segmented, drop: set) -> tuple:
    """The record's transients, each reversal that starts at the end of a plateau in ``drop`` (its ramp ended with
    the force still drifting) given the step time and step force of the last earlier transient whose start is
    settled (a start from rest, or a reversal after a settled plateau) as its lead
    (:attr:`~bayesdamper.io.windows.Window.lead_time`)."""
    from dataclasses import replace

    ends = sorted((p.t_end, (p.test, p.index)) for p in segmented.plateaus)
    out, last = [], None
    for w in segmented.transients:  # in time order
        before = [key for t_end, key in ends if t_end <= w.t_step]
        settled = w.kind != "reversal" or not before or before[-1] not in drop
        if settled or last is None or not w.starts_settled:
            out.append(replace(w, lead_time=None, lead_force=None))
        else:
            out.append(replace(w, lead_time=float(last.t_step), lead_force=float(np.mean(last.pre_force))))
        if settled and w.starts_settled:
            last = w
    return tuple(out)


def settled_plateaus(segmented_records) -> tuple[list, list[tuple[str, int, float]]]:
    """Drop the plateaus whose force still drifts: the transient has not died out within them.

    A plateau is the last 30 % of a ramp; after a start from rest with soft gas (low α_V, low p_R) eq. (7)'s
    approach to the steady force can outlast that (measured on independent data, α_V 25 at 1.5 mm/s: the first
    plateau 28 N below the steady force, 14 of its standard errors, which moved stage 1's coefficients up to 6
    of their sds). Its mean is then not a point of eq. (4). The test: the linear trend of the plateau's force
    with an AR(1) standard error from the noise of all plateaus; |t| > :data:`SETTLED_T` drops it, the
    largest |t| first, keeping at least :data:`MIN_PLATEAUS_PER_DIRECTION` per direction. That noise is the
    scatter of each plateau about its own line: taken about each plateau's mean instead, the drifts of unsettled
    plateaus pass for strongly correlated noise (an AR(1) φ near 1), whose wide standard error then hides the
    very drifts the test looks for. A drift that is not a line still leaves structure about it, so the noise is
    taken again from the plateaus kept so far and every plateau tested again, until none more is dropped.

    Returns
    -------
    records : list of SegmentedRecord
        The records with their unsettled plateaus moved from ``plateaus`` to ``unsettled``, and a lead on every
        transient that starts at the end of an unsettled plateau (:func:`_with_leads`).
    dropped : list of (test, plateau index, t)
    """
    from dataclasses import replace

    segmented_records = list(segmented_records)
    plateaus = [(p, s.record) for s in segmented_records for p in s.plateaus]
    drop: set = set()
    while True:  # the noise of the plateaus kept so far, until no further plateau is dropped
        kept = [replace(s, plateaus=tuple(p for p in s.plateaus if (p.test, p.index) not in drop))
                for s in segmented_records]
        noise = plateau_noise(kept, detrend=True)
        scored = []
        for p, rec in plateaus:
            sel = (rec.time >= p.t_start) & (rec.time <= p.t_end)
            scored.append((abs(plateau_trend_t(rec.time[sel], rec.force[sel], noise)), p))
        left = {d: sum(1 for _, p in scored if p.direction == d and (p.test, p.index) not in drop) for d in (1, -1)}
        grown = set(drop)
        for tval, p in sorted(scored, key=lambda x: -x[0]):
            if (p.test, p.index) not in grown and tval > SETTLED_T and left[p.direction] > MIN_PLATEAUS_PER_DIRECTION:
                grown.add((p.test, p.index))
                left[p.direction] -= 1
        if grown == drop:
            break
        drop = grown
    out = [replace(s, plateaus=tuple(p for p in s.plateaus if (p.test, p.index) not in drop),
                   unsettled=tuple(p for p in s.plateaus if (p.test, p.index) in drop),
                   transients=_with_leads(s, drop))
           for s in segmented_records]
    dropped = [(p.test, p.index, float(tv)) for tv, p in scored if (p.test, p.index) in drop]
    return out, dropped
