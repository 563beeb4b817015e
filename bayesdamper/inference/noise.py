"""The force noise of a record, estimated where model error cannot reach it: AR(1) φ and scale.

A residual (measured − model force) holds model error as well as noise, and its lag-1 coefficient goes to 1 as
soon as the error is smooth. The error lives at known frequencies: a periodic motion of fundamental f₀ makes
lines at every k·f₀ (the flow law is asymmetric and not smooth at v = 0: harmonics decay only as k⁻³ for the
orifice law, k⁻¹ for dry friction); a motion of band [f_lo, f_hi] makes an error below f_hi and, through the
nonlinearity, at sums of its frequencies (v|v| is odd and nearly cubic: the harmonics of sin·|sin| are 20, 2.9,
1.0 % at k = 3, 5, 7), mostly below :data:`NONLINEAR_ORDER` · f_hi; drifts sit at 0 Hz. Noise fills the band.

:func:`spectral_noise` fits S(ω) = σ_e² / (1 − 2φ cos ω + φ²) to the tapered periodogram
I_j = |Σ h_t x_t e^(−iω_j t)|² / Σ h_t² by the Whittle likelihood −Σ_U [log S_j + I_j / S_j] over the usable
bins U, σ_e² profiled out; its information over the taper's variance factor c = n Σh⁴ / (Σh²)² gives the
standard errors. Left out of U:

1. *Known places*: 0 Hz and every k·f₀ with the taper's main lobe (but see *Periodic records*); below
   NONLINEAR_ORDER · f_hi.
2. *Leakage*: a bin is used only if the masked bins' excess power leaks into it, by the bound
   Σ_masked (I_i − S_i log m)₊ L(|i − j|) (L the spectral window's envelope for the worst bin-centring, log m the
   level noise reaches once in m bins), under ε·S_j. An excess ε moves φ and log σ_e² by at most ε·sqrt(m/c)
   standard errors (Cauchy–Schwarz on the linearised score over m bins): ε = :data:`LEAK_BIAS_SE` · sqrt(c/m)
   keeps that under 0.1 se. It sets each line's exclusion from its height and the window's decay, in bins of
   1/T: a main lobe to tens of bins.
3. *Lines*: a bin above the exponential's Bonferroni quantile log(m/α) of a robust fit (least absolute
   deviations on log I) is a line nobody listed (mains hum, a harmonic of something else). For a mean of k
   periodograms (below) both levels are the quantiles of a mean of k exponentials.
4. *Low edge*: from the upper half of the band, where a decaying error is smallest, the band grows downwards a
   block (:data:`EDGE_STEP`) at a time; windows of the last 1, 2, 4, 8 blocks are tested against the AR(1) of
   the other accepted bins (one-sided likelihood ratio, φ refitted under both: the noise's own knee is no
   excess). A window in excess ends the search, and :data:`EDGE_GUARD` more is left out above it.
5. *Rings*: if the bins next to the masked lines are in excess (sidebands), every exclusion widens a main lobe.

*Periodic records* (f₀ given) are read in up to three ways, in windows of whole cycles as the identification cuts
them (often 1-4 cycles of a slow sine, where the bins k/T = (k/n_c)·f₀ are all harmonics or next to one):

a. *Harmonics masked*: the whole record, every k·f₀ masked with its main lobe (step 1). It needs bins between
   the harmonics, n_c of them apart: more than 2·lobe + 1 cycles, 5 with Hann and 11 with the Slepian taper.
b. *Cycles compared*: with n_c ≥ 2 whole cycles of P samples a periodic error, whatever its harmonics' decay,
   is the same in every cycle; the spread of the cycles' tapered spectra about their mean holds none of it.
   Cycles P ≫ the noise's correlation time apart are independent records of the noise, so the n_c − 1
   orthonormal contrasts are k = n_c − 1 independent periodograms of P-sample records: their mean is fitted
   as above with c/k for c (the Whittle LR and information of k periodograms are k times their mean's). A
   cycle starting at round(i·P) is turned back in phase by its fractional offset (exact at each harmonic), and
   each cycle loses its mean (a drift's steps between cycles, which would leak from 0 Hz).
   It costs 1/n_c of the data and resolves only f₀: an AR(1) knee below f₀ is lost, so with many short cycles
   (a) does better; the smaller se decides, as between the tapers.
c. *Harmonics in excess*: only if neither gives :data:`MIN_BINS` bins (fewer than two cycles, or too short a
   cycle): the whole record with no harmonic masked up front. A harmonic is model error where it stands above
   the noise: a hot harmonic (step 3) or a low edge in excess (step 4) marks it, and a hot harmonic less than
   EDGE_GUARD above the band left out continues the series, which is then left out to EDGE_GUARD above that
   harmonic. One cycle cannot tell a harmonic series as slow as k⁻¹ (dry friction) that reaches the noise's
   knee from an AR(1) of larger φ: the periodogram of such a record is an AR(1) one to well within its
   scatter, so φ is read too high with a se that does not show it (one 20 s cycle at 100 Hz, square error 5 x
   the noise: at φ = 0.9, knee at bin 32, 79 of 100 seeds beyond 4 se; at φ = 0.97 3 of 100; φ = 0 and 0.5, and
   the orifice law's k⁻³ at any φ, are recovered). Two cycles (b) remove it whatever it is.

Steps 2-5 repeat until the mask stops growing, with a Hann taper (c = 1.94, sidelobes falling as d⁻⁶) and a
Slepian NW = 4 (c = 2.8, leakage ~1e-10 from 5 bins on: bins left between strong harmonics); the smaller se of φ
wins (the wider of the information's and the profile likelihood's). Above the AR(1) knee f_s (1 − φ)/2π the
spectrum is ≈ σ_e² / (2φ(1 − cos ω)) for any φ near 1: such a band hardly determines φ, and the se says so.
Broadband error (dry friction under a random motion: a 1/f² tail) cannot be told from noise by its spectrum.
ADC quantisation (step q) adds white noise of variance q²/12 to a moving signal, seen like any other noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize, signal, stats

from bayesdamper.inference.plateau_noise import PlateauNoise, ar1_from_segments
from bayesdamper.inference.priors import PHI_BOUNDS
from bayesdamper.inference.whittle import (
    MIN_BINS,
    NONLINEAR_ORDER,
    PHI_SE_UNDETERMINED,
    _cycle_spectra,
    _fit_spectrum,
    _Grid,
    _taper,
    _whole_spectrum,
)


@dataclass(frozen=True)
class NoiseEstimate:
    """AR(1) force noise of one sensor, with where it was measured.

    Attributes
    ----------
    phi, sigma_e : float
        Lag-1 coefficient [-] (within :data:`~bayesdamper.inference.priors.PHI_BOUNDS`), innovation sd [N].
    n_samples, source : int, str
        Samples used (the whole residual for a spectral estimate); one line saying where and how.
    band_hz : tuple of float or None
        Lowest and highest frequency used [Hz] (spectral estimates).
    phi_se, sigma_e_se, rate_hz : float or None
        Standard errors of φ [-] (inf when φ was assumed) and σ_e [N]; the sample rate φ refers to [Hz].
    """

    phi: float
    sigma_e: float
    n_samples: int
    source: str
    band_hz: tuple[float, float] | None = None
    phi_se: float | None = None
    sigma_e_se: float | None = None
    rate_hz: float | None = None

    @property
    def sigma(self) -> float:
        """Marginal standard deviation σ_e / sqrt(1 − φ²) [N]."""
        return self.sigma_e / math.sqrt(1.0 - self.phi * self.phi)

    def as_dict(self) -> dict:
        """JSON-safe dict: the keys of :meth:`PlateauNoise.as_dict` (but ``n_plateaus``), the band, the standard
        errors and the rate (None where unknown or not finite)."""
        extra = {"phi_se": self.phi_se, "sigma_e_se_N": self.sigma_e_se, "rate_Hz": self.rate_hz}
        return {"phi": float(self.phi), "sigma_e_N": float(self.sigma_e), "sigma_N": float(self.sigma),
                "n_samples": int(self.n_samples), "source": self.source,
                "band_Hz": None if self.band_hz is None else [float(b) for b in self.band_hz],
                **{k: float(v) if v is not None and math.isfinite(v) else None for k, v in extra.items()}}


def _ar1_se(phi: float, sigma_e: float, n: int) -> tuple[float, float]:
    """Large-sample standard errors of a least-squares AR(1) fit on n samples: φ [-] and σ_e [N]."""
    return math.sqrt(max(1.0 - phi * phi, 1e-6) / max(n, 2)), sigma_e / math.sqrt(2.0 * max(n, 2))


def from_plateaus(noise: PlateauNoise, rate_hz: float | None = None) -> NoiseEstimate:
    """A :class:`PlateauNoise` as a :class:`NoiseEstimate` (for :func:`combine`)."""
    se = _ar1_se(noise.phi, noise.sigma_e, noise.n_samples - 2 * noise.n_plateaus)
    return NoiseEstimate(noise.phi, noise.sigma_e, noise.n_samples, f"plateaus, {noise.n_plateaus} stretches",
                         None, *se, rate_hz=rate_hz)


def _difference_fallback(x: np.ndarray, rate_hz: float, why: str) -> NoiseEstimate:
    """White noise from the first differences (MAD), φ = 0 assumed: a smooth error changes little between samples
    and the median outvotes sparse jumps (friction); for AR(1) noise it gives σ sqrt(1 − φ), not σ."""
    s = 1.4826 * float(np.median(np.abs(np.diff(x) - np.median(np.diff(x))))) / math.sqrt(2.0)
    return NoiseEstimate(0.0, s, int(x.size), f"first differences of the residual (MAD), φ = 0 assumed: {why}",
                         phi_se=math.inf, sigma_e_se=1.65 * s / math.sqrt(2.0 * x.size), rate_hz=float(rate_hz))


def spectral_noise(residual: np.ndarray, rate_hz: float, *, fundamental_hz: float | None = None,
                   input_band_hz: tuple[float, float] | None = None) -> NoiseEstimate:
    """AR(1) noise of a residual from the part of its spectrum that model error does not reach (module docstring).

    Parameters
    ----------
    residual : ndarray, shape (n,)
        Measured − model force, or the measured force itself [N], at a constant sample rate.
    rate_hz : float
        Sample rate [Hz].
    fundamental_hz : float, optional
        Fundamental of a periodic test [Hz], to much better than 1/(k_max T) (T the length [s], k_max the highest
        harmonic below Nyquist), as a least-squares sine fit gives it. A residual of two whole cycles or more is
        also read cycle against cycle (*Periodic records* in the module docstring).
    input_band_hz : tuple of float, optional
        Band (low, high) of the excitation of a record that is not periodic [Hz].

    Returns
    -------
    NoiseEstimate
        With fewer than :data:`MIN_BINS` usable bins after the exclusions (too short a record), white noise from
        the first differences (``source`` says so).

    Raises
    ------
    ValueError
        Fewer than 3 samples, a non-finite one, a rate ≤ 0 or a fundamental beyond Nyquist.
    """
    x = np.asarray(residual, dtype=float).ravel()
    if x.size < 3 or not np.all(np.isfinite(x)) or not 0 < rate_hz < math.inf:
        raise ValueError(f"spectral_noise needs 3 finite samples and a positive rate, got {x.size} at {rate_hz} Hz")
    if fundamental_hz is not None and not 0 < fundamental_hz < 0.5 * rate_hz:
        raise ValueError(f"spectral_noise: fundamental {fundamental_hz} Hz is not inside (0, {rate_hz / 2:g}) Hz")
    t, scale = np.arange(x.size, dtype=float), float(np.max(np.abs(x)))
    x = x - np.polyval(np.polyfit(t, x, 1), t)  # a trend only feeds leakage; its bins are masked anyway
    if not np.any(np.abs(x) > 1e-12 * scale):  # a constant or a straight line, to rounding
        return NoiseEstimate(0.0, 0.0, int(x.size), "no scatter in the residual", rate_hz=float(rate_hz))
    low_edge = 0.0 if input_band_hz is None else NONLINEAR_ORDER * float(max(input_band_hz))
    if x.size < 2 * MIN_BINS + 3:
        return _difference_fallback(x, rate_hz, f"{x.size} samples give fewer than {MIN_BINS} bins")
    period = rate_hz / fundamental_hz if fundamental_hz is not None else math.inf
    n_c = int((x.size + 1) // period)  # whole cycles (a window cut to whole cycles may be a sample short)
    grid, tapers = _Grid(x.size), [_taper(name, x.size) for name in ("Hann", "Slepian")]
    whole = [_whole_spectrum(x, taper, grid, "whole" if fundamental_hz is None else "harmonics") for taper in tapers]
    fits = [_fit_spectrum(spec, rate_hz, fundamental_hz, low_edge) for spec in whole]
    if n_c >= 2 and int(period) >= 2 * MIN_BINS + 3:  # cycles long enough for a spectrum of their own
        fits += [_fit_spectrum(spec, rate_hz, None, low_edge) for spec in _cycle_spectra(x, period, n_c)]
    if fundamental_hz is not None and not any("phi" in f for f in fits):  # the harmonics where in excess only
        fits += [_fit_spectrum(replace(spec, kind="excess"), rate_hz, fundamental_hz, low_edge) for spec in whole]
    if not any("phi" in f for f in fits):
        f = max(fits, key=lambda f: f["m"])
        return _difference_fallback(x, rate_hz, f"{f['m']} usable bins of {f['n_bins']} (< {MIN_BINS}) after the "
                                                f"exclusions: too short a record for its spectrum")
    f = min((f for f in fits if "phi" in f), key=lambda f: f["phi_se"])
    spec = f["spec"]
    phi_se = min(f["phi_se"], PHI_BOUNDS[1] - PHI_BOUNDS[0])  # a flat likelihood: no more than the prior width
    what = [spec.kind == "harmonics" and f"harmonics of {fundamental_hz:.4g} Hz excluded",
            spec.kind == "excess" and f"harmonics of {fundamental_hz:.4g} Hz excluded where in excess of the "
                                      f"noise ({x.size / period:.3g} cycle(s): "
                                      + ("none to compare)" if n_c < 2 else "their comparison left too few bins)"),
            input_band_hz is not None and f"below {low_edge:.4g} Hz excluded ({NONLINEAR_ORDER} x the band top)",
            f["lines"] and f"{f['lines']} unlisted line(s) excluded",
            phi_se > PHI_SE_UNDETERMINED and f"φ poorly determined by this band (se {phi_se:.2f})"]
    of = f"the residual's {n_c} cycles about their mean" if spec.kind == "cycles" else "the residual"
    bins = f"{f['m']} of {f['n_bins']} bins" + (f" x {spec.k} contrasts" if spec.k > 1 else "")
    source = (f"spectrum {f['band'][0]:.4g}-{f['band'][1]:.4g} Hz of {of}, Whittle AR(1) on {bins} "
              f"({spec.taper.name} taper)" + "".join(", " + w for w in what if w))
    return NoiseEstimate(f["phi"], f["sigma_e"], int(x.size), source, band_hz=f["band"], phi_se=phi_se,
                         sigma_e_se=f["sigma_e_se"], rate_hz=float(rate_hz))


def _lag_sums(phi: float, lengths: list[int], deg: int) -> tuple[float, float]:
    """E[Σ x_t x_(t−1)] and E[Σ x_(t−1)²] over stretches of unit-variance AR(1) noise of the given lengths, each
    with a least-squares polynomial of degree ``deg`` removed: with M = I − QQ' (Q orthonormal, the polynomials)
    and Σ the AR(1) correlation, E[x'Ax] = tr(AΣ) − 2 tr(Q'ΣAQ) + tr(Q'AQ Q'ΣQ), ΣQ by a forward and a backward
    AR(1) filter (O(n) a stretch)."""
    num = den = 0.0
    for n in lengths:
        q = np.linalg.qr(np.vander(np.linspace(-1.0, 1.0, n), deg + 1))[0]
        sq = signal.lfilter([1.0], [1.0, -phi], q, axis=0)
        sq += signal.lfilter([1.0], [1.0, -phi], q[::-1], axis=0)[::-1] - q  # Σ Q
        aq = 0.5 * (np.pad(q[:-1], ((1, 0), (0, 0))) + np.pad(q[1:], ((0, 1), (0, 0))))  # A Q, A: ½ lag-1 both ways
        bq = np.pad(q[:-1], ((0, 1), (0, 0)))  # B Q, B = diag(1, ..., 1, 0)
        qsq = q.T @ sq
        num += (n - 1) * phi - 2.0 * float(np.sum(sq * aq)) + float(np.trace((q.T @ aq) @ qsq))
        den += (n - 1) - 2.0 * float(np.sum(sq * bq)) + float(np.trace((q.T @ bq) @ qsq))
    return num, den


def rest_noise(force_segments: list[np.ndarray], *, detrend: str = "mean") -> NoiseEstimate | None:
    """AR(1) noise from stretches where the piston is at rest (model force constant, or slowly relaxing).

    Each stretch loses its mean (then :func:`~bayesdamper.inference.plateau_noise.ar1_from_segments`, whose
    small-sample bias correction is exact for a mean) or, with ``detrend="linear"`` for a force still relaxing, a
    line (the pooled lag-1 ratio then solved against its expectation after a line, :func:`_lag_sums`). The
    correction undoes the shrinking by the slope h'(φ) of that expectation, so the se sqrt((1 − φ²)/N) is / h'(φ).

    Parameters
    ----------
    force_segments : list of ndarray
        Force samples of each stretch at rest [N], one sample rate; stretches under 5 samples are skipped.
    detrend : {"mean", "linear"}

    Returns
    -------
    NoiseEstimate or None
        None when no stretch has any scatter (a quantiser the noise does not dither reads a constant at rest).
    """
    if detrend not in ("mean", "linear"):
        raise ValueError(f"rest_noise: detrend must be 'mean' or 'linear', not {detrend!r}")
    deg = int(detrend == "linear")
    segs = []
    for s in force_segments:
        s = np.asarray(s, dtype=float).ravel()
        s, t = s[np.isfinite(s)], np.arange(np.count_nonzero(np.isfinite(s)), dtype=float)
        if s.size >= 5 and np.ptp(s) > 0:
            segs.append(s - np.polyval(np.polyfit(t, s, deg), t))
    if not segs:
        return None
    lengths, n = [s.size for s in segs], sum(s.size for s in segs)

    def h(phi: float) -> float:  # the expected lag-1 ratio
        return float(np.divide(*_lag_sums(phi, lengths, deg)))

    if deg == 0:
        phi = ar1_from_segments(segs).phi
    else:
        raw = sum(float(x[1:] @ x[:-1]) for x in segs) / sum(float(x[:-1] @ x[:-1]) for x in segs)
        lo, hi = PHI_BOUNDS[0], 0.995
        phi = lo if h(lo) >= raw else hi if h(hi) <= raw else optimize.brentq(lambda f: h(f) - raw, lo, hi)
    dof = n - (deg + 2) * len(segs)  # a polynomial and a lag per stretch
    sigma_e = math.sqrt(sum(float(np.sum((x[1:] - phi * x[:-1]) ** 2)) for x in segs) / max(dof, 1))
    phi_se, s_se = _ar1_se(phi, sigma_e, dof)
    lo, hi = max(phi - 1e-4, PHI_BOUNDS[0]), min(phi + 1e-4, 0.9999)
    phi_se /= max((h(hi) - h(lo)) / (hi - lo), 1e-3)
    return NoiseEstimate(float(phi), sigma_e, n, f"rest, {n} samples in {len(segs)} stretch(es), {detrend} removed",
                         phi_se=phi_se, sigma_e_se=s_se)


def combine(estimates: list[NoiseEstimate]) -> NoiseEstimate:
    """Pool estimates of one sensor's noise (windows, records, sources): φ and log σ_e averaged with inverse-
    variance weights (their standard errors, else the least-squares AR(1) ones of their sample counts). Estimates
    that assumed φ (``phi_se`` inf: the fallback) count only if nothing else is there. When the φ disagree beyond
    their errors (χ², p < 0.01) the source says so: model error the estimator did not catch is the likely cause.

    Raises
    ------
    ValueError
        No estimate with a positive scale, or estimates at different sample rates (φ is per sample).
    """
    rates = {e.rate_hz for e in estimates if e.rate_hz is not None}
    est = [e for e in estimates if e.sigma_e > 0]
    est = [e for e in est if e.phi_se is None or math.isfinite(e.phi_se)] or est
    if len(rates) > 1 or not est:
        raise ValueError(f"combine: {len(est)} estimates with a positive scale at rates {sorted(rates)} Hz")
    if len(est) == 1:
        return est[0]
    se = [_ar1_se(e.phi, e.sigma_e, e.n_samples) for e in est]
    w_phi = np.array([(e.phi_se if e.phi_se is not None else d[0]) ** -2.0 for e, d in zip(est, se, strict=True)])
    w_s = np.array([(e.sigma_e / (e.sigma_e_se or d[1])) ** 2 for e, d in zip(est, se, strict=True)])
    phis = np.array([e.phi for e in est])
    phi = float(np.clip(np.sum(w_phi * phis) / w_phi.sum(), *PHI_BOUNDS)) if w_phi.sum() > 0 else 0.0
    sigma_e = math.exp(float(np.sum(w_s * np.log([e.sigma_e for e in est])) / w_s.sum()))
    chi2 = float(np.sum(w_phi * (phis - phi) ** 2))
    bands = [e.band_hz for e in est if e.band_hz is not None]
    source = f"pooled from {len(est)} estimates ({', '.join(sorted({e.source.split()[0].strip(',') for e in est}))})"
    if stats.chi2.sf(chi2, len(est) - 1) < 0.01:
        source += f", φ disagree beyond their errors (χ² {chi2:.1f} on {len(est) - 1} dof)"
    return NoiseEstimate(phi, sigma_e, int(sum(e.n_samples for e in est)), source,
                         band_hz=(min(b[0] for b in bands), max(b[1] for b in bands)) if bands else None,
                         phi_se=float(w_phi.sum()) ** -0.5 if w_phi.sum() > 0 else math.inf,
                         sigma_e_se=sigma_e * float(w_s.sum()) ** -0.5,
                         rate_hz=rates.pop() if rates else None)
