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


def ar1_from_segments(segments: list[np.ndarray]) -> PlateauNoise:
    """AR(1) φ and σ_e from several stretches of noise, each about its own unknown mean.

    The pooled least-squares lag-1 coefficient r = Σ x_t x_{t−1} / Σ x_{t−1}² of mean-removed stretches is
    biased low (by about (1 + 3φ)/n for a stretch of n samples, Marriott & Pope 1954, and by less near φ = 1,
    where that formula over-corrects two-fold at n = 300, φ = 0.97). Pooled over many stretches, numerator and
    denominator concentrate at their expectations, which are closed-form functions of φ and the stretch
    lengths (:func:`_expected_lag_sums`); φ is the root of E[num](φ)/E[den](φ) = r. σ_e² is the mean square of
    the innovations on N − 2m degrees of freedom (a mean and a lag per stretch).
    """
    from scipy.optimize import brentq

    num = den = 0.0
    xs = []
    for s in segments:
        s = np.asarray(s, dtype=float)
        if s.size < 5:
            continue
        x = s - s.mean()
        xs.append(x)
        num += float(x[1:] @ x[:-1])
        den += float(x[:-1] @ x[:-1])
    if not xs or den <= 0.0:
        raise ValueError("no plateau stretch of at least 5 samples with any scatter")
    raw = num / den
    lengths = np.array([x.size for x in xs])

    def g(phi):
        a, b = _expected_lag_sums(phi, lengths)
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
    sigma_e = math.sqrt(ss / max(n - 2 * m, 1))
    return PlateauNoise(phi, sigma_e, n, m)


def plateau_noise(segmented_records) -> PlateauNoise:
    """:func:`ar1_from_segments` on the force samples of every plateau of a segmented data set."""
    segs = []
    for s in segmented_records:
        t, f = s.record.time, s.record.force
        for p in s.plateaus:
            segs.append(f[(t >= p.t_start) & (t <= p.t_end)])
    return ar1_from_segments(segs)


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


def settled_plateaus(segmented_records) -> tuple[list, list[tuple[str, int, float]]]:
    """Drop the plateaus whose force still drifts: the transient has not died out within them.

    A plateau is the last 30 % of a ramp; after a start from rest with soft gas (low α_V, low p_R) eq. (7)'s
    approach to the steady force can outlast that (measured on independent data, α_V 25 at 1.5 mm/s: the first
    plateau 28 N below the steady force, 14 of its standard errors, which moved stage 1's coefficients up to 6
    of their sds). Its mean is then not a point of eq. (4). The test: the linear trend of the plateau's force
    with an AR(1) standard error from the noise of all plateaus; |t| > :data:`SETTLED_T` drops it, the
    largest |t| first, keeping at least :data:`MIN_PLATEAUS_PER_DIRECTION` per direction.

    Returns
    -------
    records : list of SegmentedRecord
        The records with their unsettled plateaus moved from ``plateaus`` to ``unsettled``.
    dropped : list of (test, plateau index, t)
    """
    from dataclasses import replace

    segmented_records = list(segmented_records)
    noise = plateau_noise(segmented_records)
    scored = []
    for s in segmented_records:
        t, f = s.record.time, s.record.force
        for p in s.plateaus:
            sel = (t >= p.t_start) & (t <= p.t_end)
            scored.append((abs(plateau_trend_t(t[sel], f[sel], noise)), p))
    left = {d: sum(1 for _, p in scored if p.direction == d) for d in (1, -1)}
    drop = set()
    for tval, p in sorted(scored, key=lambda x: -x[0]):
        if tval > SETTLED_T and left[p.direction] > MIN_PLATEAUS_PER_DIRECTION:
            drop.add((p.test, p.index))
            left[p.direction] -= 1
    out = [replace(s, plateaus=tuple(p for p in s.plateaus if (p.test, p.index) not in drop),
                   unsettled=tuple(p for p in s.plateaus if (p.test, p.index) in drop))
           for s in segmented_records]
    dropped = [(p.test, p.index, float(tv)) for tv, p in scored if (p.test, p.index) in drop]
    return out, dropped
