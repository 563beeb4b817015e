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
    return [(r, p) for r, p in plateaus if p.approach_tau is None] or plateaus


def plateau_noise(segmented_records) -> PlateauNoise:
    """:func:`ar1_from_segments` on the force samples of every plateau of a segmented data set whose force had
    settled (all plateaus where none had)."""
    return ar1_from_segments([r.force[(r.time >= p.t_start) & (r.time <= p.t_end)]
                              for r, p in noise_plateaus(segmented_records)])


#: |t| of a plateau's linear trend above which it is not settled (two-sided p = 0.0027 for a settled plateau:
#: over 18 plateaus a 5 % chance of losing one good plateau, which costs only its data).
SETTLED_T = 3.0
#: Plateaus kept per direction whatever their trend (stage 1 needs three for one residual degree of freedom).
MIN_PLATEAUS_PER_DIRECTION = 3
#: Longest time constant of a plateau's approach to its settled force, in plateau lengths, from which the settled
#: force is extrapolated (:func:`approach_fit`). At τ = 1 a third of the approach's amplitude is left at the
#: plateau's end and the curvature over the plateau (1 − e^-1 of the slope lost) still pins the end; slower
#: approaches are nearly lines there, and their plateau is left out.
APPROACH_TAU_MAX = 1.0


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


def approach_fit(t: np.ndarray, f: np.ndarray) -> tuple[float, float, np.ndarray] | None:
    """The settled force of a plateau whose force still approaches it: least squares of
    F(t) = F_inf + b exp(-(t - t_0) / τ) over the plateau's times ``t`` [s] and forces ``f`` [N], τ profiled on a
    log grid from 1/100 of the plateau's length to :data:`APPROACH_TAU_MAX` of it, then refined between the grid's
    neighbours. Returns (F_inf [N], τ [s], the residual [N]), or None when the best τ is the longest: an approach
    no faster than that is close to a line within the plateau and does not say where it ends."""
    from scipy.optimize import minimize_scalar

    x = np.asarray(t, float) - float(t[0])
    f = np.asarray(f, float)
    span = float(x[-1]) if x.size else 0.0
    if x.size < 10 or span <= 0.0:
        return None

    def fit(log_tau: float) -> tuple[float, float, np.ndarray]:
        design = np.column_stack([np.ones_like(x), np.exp(-x / (span * math.exp(log_tau)))])
        coef, *_ = np.linalg.lstsq(design, f, rcond=None)
        r = f - design @ coef
        return float(r @ r), float(coef[0]), r

    grid = np.linspace(math.log(0.01), math.log(APPROACH_TAU_MAX), 41)
    sse = [fit(g)[0] for g in grid]
    i = int(np.argmin(sse))
    if i == grid.size - 1:
        return None
    lo, hi = grid[max(i - 1, 0)], grid[i + 1]
    best = minimize_scalar(lambda g: fit(g)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    g = float(best.x) if best.fun <= sse[i] else float(grid[i])
    _, settled, resid = fit(g)
    return settled, span * math.exp(g), resid


def settled_plateaus(segmented_records) -> tuple[list, list[tuple[str, int, float]]]:
    """Give each plateau its settled force: its mean where the force has settled, else the value its approach
    extrapolates to, else leave it out.

    A plateau is the last 30 % of a ramp; after a start from rest with soft gas (low α_V, low p_R), or with a
    compliant mount in series, eq. (7)'s approach to the steady force can outlast it (measured on independent
    two-state data with a 2e7 N/m mount: plateau means up to 2.5 kN below the steady force at 2 mm/s, and the
    approach's time constant 0.5-1.3 plateau lengths). Its mean is then not a point of eq. (4). The test: the
    linear trend of the plateau's force, its standard error from the AR(1) noise of all plateaus each about its
    own line (:func:`bayesdamper.inference.noise.rest_noise`: about their means, the drifts would pass for noise
    with φ near 1, whose wide standard error hides them); |t| > :data:`SETTLED_T` says the force still moves. Such
    a plateau keeps the settled force of an exponential approach fitted to it (:func:`approach_fit`, its
    ``approach_tau`` set) when that approach is determined, and is otherwise left out, the largest |t| first,
    keeping at least :data:`MIN_PLATEAUS_PER_DIRECTION` per direction.

    Returns
    -------
    records : list of SegmentedRecord
        The records with their settled forces, the plateaus left out moved from ``plateaus`` to ``unsettled``.
    dropped : list of (test, plateau index, t)
        The plateaus left out.

    Raises
    ------
    ValueError
        No plateau has any scatter.
    """
    from dataclasses import replace

    from bayesdamper.inference.noise import rest_noise

    segmented_records = list(segmented_records)
    samples = {}
    for s in segmented_records:
        t, f = s.record.time, s.record.force
        for p in s.plateaus:
            sel = (t >= p.t_start) & (t <= p.t_end)
            samples[(p.test, p.index)] = (t[sel], f[sel])
    noise = rest_noise([f for _, f in samples.values()], detrend="linear")
    if noise is None:
        raise ValueError("no plateau stretch of at least 5 samples with any scatter")
    scored = [(abs(plateau_trend_t(*samples[(p.test, p.index)], noise)), p)
              for s in segmented_records for p in s.plateaus]
    left = {d: sum(1 for _, p in scored if p.direction == d) for d in (1, -1)}
    drop, settled = set(), {}
    for tval, p in sorted(scored, key=lambda x: -x[0]):
        if tval <= SETTLED_T:
            break
        t, f = samples[(p.test, p.index)]
        approach = approach_fit(t, f)
        if approach is not None and abs(plateau_trend_t(t, approach[2], noise)) <= SETTLED_T:
            area = p.flow_rate / p.velocity
            settled[(p.test, p.index)] = replace(
                p, pressure_drop=p.pressure_drop + p.direction * (approach[0] - float(f.mean())) / area,
                approach_tau=approach[1])
        elif left[p.direction] > MIN_PLATEAUS_PER_DIRECTION:
            drop.add((p.test, p.index))
            left[p.direction] -= 1
    out = [replace(s, plateaus=tuple(settled.get((p.test, p.index), p) for p in s.plateaus
                                     if (p.test, p.index) not in drop),
                   unsettled=tuple(p for p in s.plateaus if (p.test, p.index) in drop))
           for s in segmented_records]
    dropped = [(p.test, p.index, float(tv)) for tv, p in scored if (p.test, p.index) in drop]
    return out, dropped
