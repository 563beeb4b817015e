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


def noise_plateaus(segmented_records) -> list:
    """The plateaus whose samples are noise about a constant: those whose force had settled (no ``approach_tau``),
    or all of them where none had."""
    plateaus = [(s.record, p) for s in segmented_records for p in s.plateaus]
    return [(r, p) for r, p in plateaus if getattr(p, "approach_tau", None) is None] or plateaus


def plateau_noise(segmented_records) -> PlateauNoise:
    """:func:`ar1_from_segments` on the force samples of every plateau of a segmented data set whose force had
    settled (all plateaus where none had)."""
    return ar1_from_segments([r.force[(r.time >= p.t_start) & (r.time <= p.t_end)]
                              for r, p in noise_plateaus(segmented_records)])
