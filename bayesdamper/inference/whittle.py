"""The band-limited Whittle estimate of AR(1) noise behind :func:`bayesdamper.inference.noise.spectral_noise`.

Tapered periodograms of a residual (whole, or cycle against cycle), the masks of the bins model error reaches (the
low band, harmonics, lines, rings; the low-edge search), and the Whittle likelihood of the AR(1) spectrum
S = σ_e² / (1 − 2φ cos ω + φ²) on the bins left, with its standard errors. The rules and their derivations are in
the module docstring of :mod:`bayesdamper.inference.noise`; this module is their machinery.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize, signal, stats

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

    def __init__(self) -> None:
        self.m, self.a, self.b, self.log_a = 0, 0.0, 0.0, np.zeros(_PHI.size)

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


class _Grid:
    """The bins 0..n//2 of an n-sample stretch: cos ω_j, and log a_j on the φ grid summed along j (row j: the sum
    over the bins below j), computed once for all the sets of bins the fits of one call look at: a set's sum is
    one difference per run of consecutive bins."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.cos = np.cos(2.0 * np.pi * np.arange(n // 2 + 1) / n)
        self.cum = np.zeros((self.cos.size + 1, _PHI.size))
        for k in range(0, self.cos.size, 4096):  # in blocks: a cache-sized temporary
            block = np.log1p(self.cos[k:k + 4096, None] * (-2.0 * _PHI) + _PHI * _PHI)
            self.cum[k + 1:k + 1 + block.shape[0]] = np.cumsum(block, axis=0) + self.cum[k]
        self.coarse = np.ascontiguousarray(np.diff(self.cum[:, ::4], axis=0).T)  # log a_j, every 4th grid point

    def sums(self, i_h: np.ndarray, mask: np.ndarray) -> _Sums:
        """The :class:`_Sums` of the periodogram ``i_h`` [N²] over the bins of ``mask``."""
        idx, out = np.flatnonzero(mask), _Sums()
        out.m, out.a, out.b = idx.size, float(i_h[idx].sum()), float(i_h[idx] @ self.cos[idx])
        edges = np.flatnonzero(np.diff(np.concatenate([[False], mask, [False]]).astype(np.int8)))
        out.log_a = (self.cum[edges[1::2]] - self.cum[edges[::2]]).sum(axis=0)
        return out


def _robust_fit(i_u: np.ndarray, cos_u: np.ndarray, log_a_coarse: np.ndarray, k: int = 1) -> tuple[float, float]:
    """Least-absolute-deviation fit of AR(1) to log I = log S + log E (E the mean of ``k`` Exp(1), its median
    known: ln 2 for one periodogram): (φ, σ_e² [N²]). Lines move a median, unlike a mean, hardly at all, so this
    fit says which single bins stand out; ``log_a_coarse`` holds log a of the bins on every fourth point of the
    φ grid, where the search starts."""
    log_i = np.log(np.maximum(i_u, 1e-300))

    def resid(u: float, log_a: np.ndarray | None = None) -> np.ndarray:
        phi = 1.0 - math.exp(u)
        r = log_i + (np.log1p(phi * (phi - 2.0 * cos_u)) if log_a is None else log_a)
        return r - np.median(r)

    grid = _U[::4]
    j = int(np.argmin([np.abs(resid(u, la)).sum() for u, la in zip(grid, log_a_coarse, strict=True)]))
    bounds = (grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)])
    u = optimize.minimize_scalar(lambda v: np.abs(resid(v)).sum(), bounds=bounds, method="bounded",
                                 options={"xatol": 1e-3}).x
    phi = float(np.clip(1.0 - math.exp(u), *PHI_BOUNDS))
    return phi, math.exp(float(np.median(log_i + np.log1p(phi * (phi - 2.0 * cos_u))))) / _gamma_median(k)


def _gamma_median(k: int) -> float:
    """Median of the mean of k independent Exp(1) [-]."""
    return float(stats.gamma.median(k)) / k


def _noise_reach(k: int, p: float) -> float:
    """Level [S] the mean of k independent Exp(1) exceeds with probability p."""
    return float(stats.gamma.isf(p, k)) / k


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


def _edge_search(i_h: np.ndarray, grid: _Grid, use: np.ndarray, floor: int, lobe: int, c: float) -> int:
    """The low edge [bin] (step 4 of the module docstring), searched from the upper half of the band down to
    ``floor`` in blocks of a factor :data:`EDGE_STEP` (and at least a main lobe of ``lobe`` bins each side)."""
    j, b = np.arange(i_h.size), max(floor, i_h.size // 2)
    if (use & (j >= b)).sum() < MIN_BINS:
        return floor
    total = grid.sums(i_h, use & (j >= b))
    blocks: list[tuple[int, _Sums]] = []  # (upper bin, sums) of the accepted blocks, highest first
    scales = [k for k in (1, 2, 4, 8, 16) if k <= EDGE_SCALES]
    while b > floor:
        b_new = max(floor, min(int(b / EDGE_STEP), b - 2 * lobe - 1))
        sel = use & (j >= b_new) & (j < b)
        if sel.any():
            blocks.append((b, grid.sums(i_h, sel)))
            total = total.plus(blocks[-1][1])
            window = _Sums()
            for k in range(1, min(len(blocks), EDGE_SCALES) + 1):
                window = window.plus(blocks[-k][1])
                if k in scales and _excess(window, total.plus(window, -1.0), c, EXCESS_ALPHA / len(scales)):
                    return math.ceil(blocks[-k][0] * EDGE_GUARD)
        b = b_new
    return floor


@dataclass(frozen=True, eq=False)
class _Spectrum:
    """What a Whittle fit sees: the mean ``i_h`` [N²] (bins 0..n//2) of ``k`` independent tapered periodograms
    of ``n``-sample stretches (k = 1: the whole residual; k > 1: the contrasts between a window's cycles)."""

    i_h: np.ndarray
    grid: _Grid
    k: int
    taper: _Taper
    kind: str  # "whole", "harmonics", "excess" or "cycles"

    @property
    def c(self) -> float:
        """Variance factor of a bin of the mean: the Whittle LR of k periodograms is k times that of their mean."""
        return self.taper.c / self.k


def _whole_spectrum(x: np.ndarray, taper: _Taper, grid: _Grid, kind: str) -> _Spectrum:
    """The tapered periodogram of the whole residual ``x`` [N]."""
    return _Spectrum(np.abs(np.fft.rfft(taper.h * x)) ** 2 / x.size, grid, 1, taper, kind)


def _cycle_spectra(x: np.ndarray, period: float, n_c: int) -> list[_Spectrum]:
    """The spread of the window's ``n_c`` cycles (``period`` samples each) about their mean, bin by bin: a
    periodic error is the same in every cycle and drops out; the noise of cycles a period apart (≫ its
    correlation time) is independent, so the n_c − 1 orthonormal contrasts are n_c − 1 independent records of
    it. A cycle starting at round(i·period) is δ_i = i·period − round(i·period) samples early; its harmonics
    are turned back by e^(2πi j δ_i / L) in bin j (exact at the harmonic's own frequency, a phase error under
    π·lobe/period within its main lobe), which leaves the noise's distribution unchanged."""
    starts = np.round(np.arange(n_c) * period).astype(int)
    length = min(int(period), x.size - int(starts[-1]))
    cycles, grid, out = x[starts[:, None] + np.arange(length)], _Grid(length), []
    cycles = cycles - cycles.mean(axis=1, keepdims=True)  # a drift's offsets between cycles (0 Hz lobe only)
    turn = np.exp(2j * np.pi * np.outer(np.arange(n_c) * period - starts, np.arange(length // 2 + 1)) / length)
    for name in ("Hann", "Slepian"):
        taper = _taper(name, length)
        y = np.fft.rfft(taper.h * cycles, axis=1) * turn
        i_h = np.sum(np.abs(y - y.mean(axis=0)) ** 2, axis=0) / (length * (n_c - 1))
        out.append(_Spectrum(i_h, grid, n_c - 1, taper, "cycles"))
    return out


def _fit_spectrum(spec: _Spectrum, rate_hz: float, fundamental_hz: float | None, low_edge_hz: float) -> dict:
    """The masked Whittle fit of one spectrum (steps 1-5 of the module docstring): for ``spec.kind`` "harmonics"
    every harmonic of ``fundamental_hz`` is masked with its main lobe from the start, for "excess" only where it
    stands out (*Periodic records*, c)."""
    i_h, grid, taper, c, k = spec.i_h, spec.grid, spec.taper, spec.c, spec.k
    n, nh = grid.n, i_h.size  # bins 0..n//2
    j = np.arange(nh)
    freq, cos_w = j * rate_hz / n, grid.cos
    usable = (j >= 1) & (j < (n + 1) // 2)  # no 0 Hz, no Nyquist bin (a χ²₁)
    low = (freq < low_edge_hz) | (j <= taper.lobe)
    kf = fundamental_hz * n / rate_hz if fundamental_hz else 1.0  # harmonic spacing [bins]
    harm = (np.abs(j - np.round(j / kf) * kf) <= taper.lobe) & (fundamental_hz is not None)
    lines = harm.copy() if spec.kind == "harmonics" else np.zeros(nh, dtype=bool)
    leaky, hot_harm = np.zeros(nh, dtype=bool), np.zeros(nh, dtype=bool)
    n_hot, edge_done, top = 0, False, 0
    for _ in range(MAX_ROUNDS):
        use = ~(low | lines | leaky) & usable
        m = int(use.sum())
        if m < MIN_BINS:
            break
        phi, s2 = _robust_fit(i_h[use], cos_w[use], grid.coarse[:, use], k)
        spec_j = s2 / (1.0 + phi * (phi - 2.0 * cos_w))
        # 2. leakage of the masked excess over the level noise reaches once in m bins (its own spread is the bins'
        # correlation; counted, it would mask the neighbours of high bins and bias σ_e low)
        p = np.where(low | lines, np.maximum(i_h - _noise_reach(k, 1.0 / m) * spec_j, 0.0), 0.0)
        leak = _leakage(np.concatenate([p, p[1:(n + 1) // 2][::-1]]), taper.kernel)[:nh]
        new_leaky = use & (leak > LEAK_BIAS_SE * math.sqrt(c / m) * spec_j)
        hot = use & (i_h / spec_j > _noise_reach(k, EXCESS_ALPHA / m))  # 3. lines
        if spec.kind == "excess":  # hot harmonics: the error's series (4'), not unlisted lines
            hot_harm |= hot & harm
        if hot.any() or new_leaky.any():
            unlisted = hot & ~hot_harm
            n_hot += int(np.sum(np.diff(unlisted.astype(np.int8)) == 1) + unlisted[0])
            lines |= ndimage.binary_dilation(hot, iterations=taper.lobe) & usable
            leaky |= new_leaky
            continue
        if not edge_done:  # 4. the low edge, once the lines are out of the way
            edge_done = True
            free = np.flatnonzero(~(low | leaky | ~usable))
            top = _edge_search(i_h, grid, use, int(free[0]) if free.size else nh, taper.lobe, c)
        # 4'. a hot harmonic less than a guard factor above the band out is the series going on: out to a guard
        # factor above it
        while (chain := hot_harm & (j >= top) & (j < EDGE_GUARD * max(top, 1))).any():
            top = math.ceil(EDGE_GUARD * (int(np.flatnonzero(chain)[-1]) + 1))
        if (use & (j < top)).any():
            low |= j < top
            continue
        ring = ndimage.binary_dilation(lines, iterations=taper.lobe) & use  # 5. the rings round the lines
        if ring.any() and _excess(grid.sums(i_h, ring), grid.sums(i_h, use & ~ring), c, EXCESS_ALPHA):
            lines = ndimage.binary_dilation(lines, iterations=taper.lobe)
            continue
        break
    use = ~(low | lines | leaky) & usable
    out = {"spec": spec, "m": int(use.sum()), "n_bins": int(usable.sum()), "lines": n_hot}
    if out["m"] >= MIN_BINS:
        sums = grid.sums(i_h, use)
        phi = sums.fit()
        sigma_e = math.sqrt(sums.s2(phi))
        phi_se, s_se = _fisher_se(phi, sigma_e, cos_w[use], c)
        out.update(phi=phi, sigma_e=sigma_e, phi_se=max(phi_se, sums.profile_se(phi, c)), sigma_e_se=s_se,
                   band=(float(freq[use][0]), float(freq[use][-1])))
    return out
