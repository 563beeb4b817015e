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

1. *Known places*: 0 Hz and every k·f₀ with the taper's main lobe; below NONLINEAR_ORDER · f_hi.
2. *Leakage*: a bin is used only if the masked bins' excess power leaks into it, by the bound
   Σ_masked (I_i − S_i log m)₊ L(|i − j|) (L the spectral window's envelope for the worst bin-centring), under
   ε·S_j. An excess ε moves φ and log σ_e² by at most ε·sqrt(m/c) standard errors (Cauchy–Schwarz on the
   linearised score over m bins): ε = :data:`LEAK_BIAS_SE` · sqrt(c/m) keeps that under 0.1 se. It sets each
   line's exclusion from its height and the window's decay, in bins of 1/T: a main lobe to tens of bins.
3. *Lines*: a bin above the exponential's Bonferroni quantile log(m/α) of a robust fit (least absolute
   deviations on log I) is a line nobody listed (mains hum, a harmonic of something else).
4. *Low edge*: from the upper half of the band, where a decaying error is smallest, the band grows downwards a
   block (:data:`EDGE_STEP`) at a time; windows of the last 1, 2, 4, 8 blocks are tested against the AR(1) of
   the other accepted bins (one-sided likelihood ratio, φ refitted under both: the noise's own knee is no
   excess). A window in excess ends the search, and :data:`EDGE_GUARD` more is left out above it.
5. *Rings*: if the bins next to the masked lines are in excess (sidebands), every exclusion widens a main lobe.

Steps 2-5 repeat until the mask stops growing, with a Hann taper (c = 1.94, sidelobes falling as d⁻⁶) and a
Slepian NW = 4 (c = 2.8, leakage ~1e-10 from 5 bins on: bins left between strong harmonics); the smaller se of φ
wins (the wider of the information's and the profile likelihood's). Above the AR(1) knee f_s (1 − φ)/2π the
spectrum is ≈ σ_e² / (2φ(1 − cos ω)) for any φ near 1: such a band hardly determines φ, and the se says so.
Broadband error (dry friction under a random motion: a 1/f² tail) cannot be told from noise by its spectrum.
ADC quantisation (step q) adds white noise of variance q²/12 to a moving signal, seen like any other noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize, signal, stats

from bayesdamper.inference.plateau_noise import PlateauNoise, ar1_from_segments
from bayesdamper.inference.priors import PHI_BOUNDS

#: Largest bias from leakage allowed in φ and log σ_e² [standard errors]: intervals keep their coverage to ~1 %.
LEAK_BIAS_SE = 0.1
#: One-sided level of each excess test. A false alarm costs bins, a miss costs bias, so it is per test (a minute
#: at 1 kHz makes ~50 edge steps: ~5 % chance of a false stop, which only widens the standard error).
EXCESS_ALPHA = 1e-3
#: Order of the nonlinearity whose products the initial low mask covers: the orifice law is odd and nearly cubic,
#: its fifth-order content 30 dB below its in-band level; the low-edge search finds the rest.
NONLINEAR_ORDER = 3
#: Block of the low-edge search, a factor in frequency (a quarter octave: little noise lost at the edge).
EDGE_STEP = 2.0**0.25
#: Largest window of the low-edge search [blocks] (two octaves): the error's excess grows at least as f⁻⁴
#: downwards, so a wider window adds mostly clean bins.
EDGE_SCALES = 8
#: Factor of frequency left out above a window in excess: the error's power falls at least as f⁻⁴ above its band
#: (a second-order roll-off of the motion), so an octave up it is 1/16 of what the test just misses.
EDGE_GUARD = 2.0
#: Fewest usable bins for the Whittle fit: σ_e² from m tapered bins has a relative sd sqrt(c/m), 25 % at 32.
MIN_BINS = 32
#: Oversampling of the spectral window for its envelope (resolves the sidelobe peaks to < 0.1 dB).
WINDOW_PAD = 16
#: Bins of the leakage envelope convolved directly (rounding relative to each term); the tail, < 1e-13, by FFT.
NEAR_BINS = 256
#: Slepian taper's time-bandwidth product: leakage ~1e-10 from NW + 1 bins on.
SLEPIAN_NW = 4.0
#: Iterations of the mask (each only adds bins; 1-6 are used in practice).
MAX_ROUNDS = 40
#: Standard error of φ above which the source says that the band does not determine φ.
PHI_SE_UNDETERMINED = 0.1
_RULE = 'all'


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


@dataclass(frozen=True)
class _Taper:
    name: str
    h: np.ndarray  # the taper, Σh² = n [-]
    c: float  # variance factor n Σh⁴ / (Σh²)² [-]
    lobe: int  # main-lobe half-width [bins]
    kernel: np.ndarray  # leakage envelope L at circular bin distance 0..n-1 [-]


def _taper(name: str, n: int) -> _Taper:
    """The taper and its leakage envelope L(d) = sup_(|ν| ≥ d − ½) W(ν) / W(½), W the spectral window: a line seen
    in bin i (at least W(½) of it) puts at most I_i L(|i − j|) into bin j."""
    h = signal.windows.hann(n, sym=False) if name == "Hann" else signal.windows.dpss(n, SLEPIAN_NW, sym=False)
    h = h * math.sqrt(n / float(h @ h))
    w = np.abs(np.fft.rfft(h, WINDOW_PAD * n)) ** 2
    env = np.maximum.accumulate(w[::-1])[::-1]
    idx = np.clip((np.arange(n // 2 + 1) - 0.5) * WINDOW_PAD, 0, w.size - 1).astype(int)
    half = env[idx] / w[WINDOW_PAD // 2]
    rising = np.diff(w[: WINDOW_PAD * 8]) > 0  # the first null ends the main lobe
    lobe = max(1, math.ceil((int(np.argmax(rising)) if rising.any() else WINDOW_PAD) / WINDOW_PAD))
    return _Taper(name, h, float(np.sum(h**4)) / n, lobe, np.concatenate([half, half[1:(n + 1) // 2][::-1]]))


def _leakage(p: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Circular convolution of the masked excess power ``p`` [N²] with the leakage envelope, near part direct."""
    n, near = p.size, min(NEAR_BINS, (p.size - 1) // 2)
    out = np.convolve(np.concatenate([p[n - near:], p, p[:near]]),
                      np.concatenate([kernel[near:0:-1], kernel[: near + 1]]), mode="valid")
    far = np.where((np.arange(n) > near) & (np.arange(n) < n - near), kernel, 0.0)
    if far.any():
        out = out + np.fft.irfft(np.fft.rfft(p) * np.fft.rfft(far), n)
    return np.maximum(out, 0.0)


#: The φ grid of the Whittle fits, uniform in u = log(1 − φ) over PHI_BOUNDS: 160 points put neighbours 5 % apart
#: in 1 − φ, and a parabola through the best three finds the optimum far inside any standard error.
_U = np.linspace(math.log(1.0 - PHI_BOUNDS[1]), math.log(1.0 - PHI_BOUNDS[0]), 160)
_PHI = 1.0 - np.exp(_U)


class _Sums:
    """Additive sufficient statistics of the profile Whittle likelihood over a set of bins: m, ΣI, ΣI cos ω, and
    Σ log a on the φ grid, a = 1 − 2φ cos ω + φ² (σ_e² = (ΣI (1 + φ²) − 2φ ΣI cos ω)/m,
    −log L = m log σ_e² − Σ log a)."""

    def __init__(self, i_b: np.ndarray | None = None, cos_b: np.ndarray | None = None) -> None:
        self.m, self.a, self.b, self.log_a = 0, 0.0, 0.0, np.zeros(_PHI.size)
        if i_b is not None:
            self.m, self.a, self.b = i_b.size, float(i_b.sum()), float(i_b @ cos_b)
            for k in range(0, cos_b.size, 2048):
                self.log_a += np.log1p(_PHI[:, None] * (_PHI[:, None] - 2.0 * cos_b[None, k:k + 2048])).sum(axis=1)

    def plus(self, other: _Sums, sign: float = 1.0) -> _Sums:
        out = _Sums()
        out.m, out.a, out.b = self.m + int(sign) * other.m, self.a + sign * other.a, self.b + sign * other.b
        out.log_a = self.log_a + sign * other.log_a
        return out

    def s2(self, phi: float | np.ndarray = _PHI) -> float | np.ndarray:
        """Profiled σ_e² [N²] at φ (default: the grid); for a block, its level."""
        return np.maximum((self.a * (1.0 + phi * phi) - 2.0 * phi * self.b) / self.m, 1e-300)

    def fit(self) -> float:
        """φ at the optimum: the best grid point, then the vertex of the parabola through three."""
        nll = self.m * np.log(self.s2()) - self.log_a
        k = int(np.clip(np.argmin(nll), 1, _U.size - 2))
        y0, y1, y2 = nll[k - 1:k + 2]
        step = 0.5 * (y0 - y2) / (y0 - 2.0 * y1 + y2) if y0 - 2.0 * y1 + y2 > 0 else 0.0
        return float(np.clip(1.0 - math.exp(_U[k] + float(np.clip(step, -1, 1)) * (_U[1] - _U[0])), *PHI_BOUNDS))

    def profile_se(self, phi: float, c: float) -> float:
        """Wider half of the profile-likelihood interval of φ at one se (Whittle deviance / c = 1, crossings
        interpolated on the grid): unlike the information it sees a likelihood flat towards φ = 1."""
        nll = self.m * np.log(self.s2()) - self.log_a
        dev = 2.0 * (nll - (self.m * math.log(self.s2(phi)) - np.interp(math.log(1 - phi), _U, self.log_a))) / c
        k, ends = int(np.argmin(np.abs(_PHI - phi))), []
        for side in (np.arange(k, -1, -1), np.arange(k, _PHI.size)):  # towards φ = 0.999, towards −0.5
            o = side[np.argmax(dev[side] > 1.0)] if np.any(dev[side] > 1.0) else side[-1]
            i = o - np.sign(o - k) if o != k else o  # the last grid point inside
            w = (1.0 - dev[i]) / (dev[o] - dev[i]) if dev[o] > 1.0 and dev[o] > dev[i] else 1.0
            ends.append(_PHI[i] + float(np.clip(w, 0.0, 1.0)) * (_PHI[o] - _PHI[i]))
        return max(ends[0] - phi, phi - ends[1], 0.0)


def _robust_fit(i_u: np.ndarray, cos_u: np.ndarray) -> tuple[float, float]:
    """Least-absolute-deviation fit of AR(1) to log I = log S + log E (median log E = log ln 2): (φ, σ_e² [N²]).
    Lines move a median, unlike a mean, hardly at all, so this fit says which single bins stand out."""
    log_i = np.log(np.maximum(i_u, 1e-300))

    def resid(u: float) -> np.ndarray:
        phi = 1.0 - math.exp(u)
        r = log_i + np.log1p(phi * (phi - 2.0 * cos_u))
        return r - np.median(r)

    grid = _U[::4]
    k = int(np.argmin([np.abs(resid(u)).sum() for u in grid]))
    bounds = (grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)])
    u = optimize.minimize_scalar(lambda v: np.abs(resid(v)).sum(), bounds=bounds, method="bounded",
                                 options={"xatol": 1e-3}).x
    phi = float(np.clip(1.0 - math.exp(u), *PHI_BOUNDS))
    return phi, math.exp(float(np.median(log_i + np.log1p(phi * (phi - 2.0 * cos_u))))) / math.log(2.0)


def _fisher_se(phi: float, sigma_e: float, cos_u: np.ndarray, c: float) -> tuple[float, float]:
    """Standard errors of φ [-] and σ_e [N]: the inverse Whittle information of (φ, log σ_e²), times c."""
    d = 2.0 * (cos_u - phi) / (1.0 + phi * (phi - 2.0 * cos_u))  # ∂ log S / ∂φ
    info = np.array([[d @ d, d.sum()], [d.sum(), float(d.size)]]) / c
    det = float(np.linalg.det(info))
    if det <= 0:
        return math.inf, math.inf
    return math.sqrt(info[1, 1] / det), sigma_e * math.sqrt(info[0, 0] / det) / 2.0


def _excess(window: _Sums, ref: _Sums, c: float, alpha: float) -> bool:
    """One-sided likelihood-ratio test that the ``window`` bins stand above the AR(1) of the ``ref`` bins (under
    the alternative the window has a higher level of its own; φ refitted under both, so a φ the reference pins
    loosely makes no false excess). The Whittle LR of tapered bins is c·χ²₁ under the null."""
    if window.m == 0 or ref.m < MIN_BINS:
        return False
    both = ref.plus(window)
    nll0 = np.min(both.m * np.log(both.s2()) - both.log_a)
    nll1 = ref.m * np.log(ref.s2()) + window.m * np.log(window.s2()) - both.log_a
    k = int(np.argmin(nll1))
    return bool(window.s2()[k] > ref.s2()[k] and 2.0 * (nll0 - nll1[k]) / c > stats.chi2.isf(2.0 * alpha, 1))


def _edge_search(i_h: np.ndarray, cos_w: np.ndarray, use: np.ndarray, floor: int, taper: _Taper) -> int:
    """The low edge [bin] (step 4 of the module docstring), searched from the upper half of the band down to
    ``floor`` in blocks of a factor :data:`EDGE_STEP` (and at least a main lobe)."""
    j, b = np.arange(i_h.size), max(floor, i_h.size // 2)
    if (use & (j >= b)).sum() < MIN_BINS:
        return floor
    total = _Sums(i_h[use & (j >= b)], cos_w[use & (j >= b)])
    blocks: list[tuple[int, _Sums]] = []  # (upper bin, sums) of the accepted blocks, highest first
    scales = [k for k in (1, 2, 4, 8, 16) if k <= EDGE_SCALES]
    while b > floor:
        b_new = max(floor, min(int(b / EDGE_STEP), b - 2 * taper.lobe - 1))
        sel = use & (j >= b_new) & (j < b)
        if sel.any():
            blocks.append((b, _Sums(i_h[sel], cos_w[sel])))
            total = total.plus(blocks[-1][1])
            window = _Sums()
            for k in range(1, min(len(blocks), EDGE_SCALES) + 1):
                window = window.plus(blocks[-k][1])
                if k in scales and _excess(window, total.plus(window, -1.0), taper.c, EXCESS_ALPHA / len(scales)):
                    return math.ceil(blocks[-k][0] * EDGE_GUARD)
        b = b_new
    return floor


def _fit_taper(x: np.ndarray, rate_hz: float, taper: _Taper, fundamental_hz: float | None,
               low_edge_hz: float, every_harmonic: bool = True) -> dict:
    """The masked Whittle fit of the residual ``x`` [N] with one taper (steps 1-5 of the module docstring)."""
    n, nh = x.size, x.size // 2 + 1  # bins 0..n//2
    i_h = np.abs(np.fft.rfft(taper.h * x)) ** 2 / n
    j = np.arange(nh)
    freq, cos_w = j * rate_hz / n, np.cos(2.0 * np.pi * j / n)
    usable = (j >= 1) & (j < (n + 1) // 2)  # no 0 Hz, no Nyquist bin (a χ²₁)
    low = (freq < low_edge_hz) | (j <= taper.lobe)
    kf = fundamental_hz * n / rate_hz if fundamental_hz else 1.0  # harmonic spacing [bins]
    lines = (np.abs(j - np.round(j / kf) * kf) <= taper.lobe) & (fundamental_hz is not None) & every_harmonic
    leaky = np.zeros(nh, dtype=bool)
    n_hot, edge_done = 0, False
    for _ in range(MAX_ROUNDS):
        use = ~(low | lines | leaky) & usable
        m = int(use.sum())
        if m < MIN_BINS:
            break
        phi, s2 = _robust_fit(i_h[use], cos_w[use])
        spec = s2 / (1.0 + phi * (phi - 2.0 * cos_w))
        # 2. leakage of the masked excess over log(m)·S, which noise reaches once a record (its own spread is the
        # bins' correlation; counted, it would mask the neighbours of high bins and bias σ_e low)
        p = np.where(low | lines, np.maximum(i_h - math.log(m) * spec, 0.0), 0.0)
        leak = _leakage(np.concatenate([p, p[1:(n + 1) // 2][::-1]]), taper.kernel)[:nh]
        new_leaky = use & (leak > LEAK_BIAS_SE * math.sqrt(taper.c / m) * spec)
        hot = use & (i_h / spec > math.log(m / EXCESS_ALPHA))  # 3. lines
        if hot.any() or new_leaky.any():
            n_hot += int(np.sum(np.diff(hot.astype(np.int8)) == 1) + hot[0])
            lines |= ndimage.binary_dilation(hot, iterations=taper.lobe) & usable
            leaky |= new_leaky
            continue
        if not edge_done:  # 4. the low edge, once the lines are out of the way
            edge_done = True
            free = np.flatnonzero(~(low | leaky | ~usable))
            top = _edge_search(i_h, cos_w, use, int(free[0]) if free.size else nh, taper)
            if (use & (j < top)).any():
                low |= j < top
                continue
        ring = ndimage.binary_dilation(lines, iterations=taper.lobe) & use  # 5. the rings round the lines
        if ring.any() and _excess(_Sums(i_h[ring], cos_w[ring]), _Sums(i_h[use & ~ring], cos_w[use & ~ring]),
                                  taper.c, EXCESS_ALPHA):
            lines = ndimage.binary_dilation(lines, iterations=taper.lobe)
            continue
        break
    use = ~(low | lines | leaky) & usable
    out = {"taper": taper, "m": int(use.sum()), "n_bins": int(usable.sum()), "lines": n_hot}
    if out["m"] >= MIN_BINS:
        sums = _Sums(i_h[use], cos_w[use])
        phi = sums.fit()
        sigma_e = math.sqrt(sums.s2(phi))
        phi_se, s_se = _fisher_se(phi, sigma_e, cos_w[use], taper.c)
        out.update(phi=phi, sigma_e=sigma_e, phi_se=max(phi_se, sums.profile_se(phi, taper.c)), sigma_e_se=s_se,
                   band=(float(freq[use][0]), float(freq[use][-1])))
    return out


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
        harmonic below Nyquist), as a least-squares sine fit gives it.
    input_band_hz : tuple of float, optional
        Band (low, high) of the excitation of a record that is not periodic [Hz].

    Returns
    -------
    NoiseEstimate
        With fewer than :data:`MIN_BINS` usable bins, white noise from the first differences (``source`` says so).

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
    fits = [_fit_taper(x, rate_hz, _taper(name, x.size), fundamental_hz, low_edge, _RULE == "all") for name in ("Hann", "Slepian")]
    if not any("phi" in f for f in fits):
        m = max(f["m"] for f in fits)
        return _difference_fallback(x, rate_hz, f"{m} usable bins of {fits[0]['n_bins']} (< {MIN_BINS})")
    f = min((f for f in fits if "phi" in f), key=lambda f: f["phi_se"])
    phi_se = min(f["phi_se"], PHI_BOUNDS[1] - PHI_BOUNDS[0])  # a flat likelihood: no more than the prior width
    what = [fundamental_hz is not None and f"harmonics of {fundamental_hz:.4g} Hz excluded",
            input_band_hz is not None and f"below {low_edge:.4g} Hz excluded ({NONLINEAR_ORDER} x the band top)",
            f["lines"] and f"{f['lines']} unlisted line(s) excluded",
            phi_se > PHI_SE_UNDETERMINED and f"φ poorly determined by this band (se {phi_se:.2f})"]
    source = (f"spectrum {f['band'][0]:.4g}-{f['band'][1]:.4g} Hz of the residual, Whittle AR(1) on {f['m']} of "
              f"{f['n_bins']} bins ({f['taper'].name} taper)" + "".join(", " + w for w in what if w))
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
