"""The periodic part of a displacement record: a drifting mean plus a Fourier series of its fundamental.

A smoothing spline must pass every frequency up to the highest it follows, and with it the noise of that whole
band: σ √(2 f_c³ / (3 f_s)) × 2π of velocity noise for white displacement noise σ [m] at sample rate f_s [Hz].
A periodic test repeats its motion, so its noise can be averaged over every cycle instead. :func:`fit_harmonic`
fits, by least squares over the moving part t_a ≤ t ≤ t_b of a record,

    h(t) = c₀ + c₁ (t - t_m) / T + Σ_{k=1..K} [a_k cos(2πkf (t - t_m)) + b_k sin(2πkf (t - t_m))]

(t [s], t_m the middle and T the length of the moving part [s], f the fundamental [Hz], c₀, c₁, a_k, b_k [m]).
Each coefficient then carries noise σ √(2/N) over N samples, the velocity ḣ an rms error of 2πf σ √(2/N) √(Σ k²)
[m/s] and the fitted f half as much again in mean square (ωσ √(3/N) for a sine), against the spline's band-wide
noise.

* **Periodic or not**: the fundamental alone (K = 1, f refined by least squares from the periodogram's peak) must
  explain ``MIN_R2`` of the noise-free variance about the best straight line, the classifier's rule for a sine
  (:mod:`bayesdamper.io.recordkind`) with the noise's share taken out (σ² per residual degree of freedom), over at
  least ``MIN_CYCLES`` cycles. A sweep or a random record fails it: it gets no harmonic part.
* **K** minimises the information criterion χ² + s² ln(N) (2K + 2) (BIC with the noise known) over 1 ≤ K ≤ the
  caller's band / f (harmonics the displacement's own smoothing spline resolves, below the Nyquist frequency); f is
  then refined with all K harmonics. Under C_p's 2 s² per coefficient a harmonic of pure noise enters with
  probability e⁻² = 14 %, and it enters for being large: a 2 µm second harmonic, 3.5 of its sds, on a 0.05 Hz
  sine with 30 µm noise at 100 Hz doubled the velocity error, which a bootstrap at that K does not see. With
  ln N per coefficient the probability is 1/N.
* **ADC steps** q: the quantisation error of a periodic motion is a function of its phase, so it repeats every
  cycle and no averaging removes it; within ±q/2, none of its Fourier amplitudes exceeds q. Harmonics of amplitude
  ≤ q after the last larger one are left to the spline.
* A measured **velocity channel** v [m/s] enters with weight w [s²]: χ² = Σ (y - h)² + w Σ (v - ḣ)².

The reconstruction (:mod:`bayesdamper.io.reconstruct`) smooths the record minus h, so what does not repeat
(amplitude wander, drift) is still followed, and keeps the spline alone where h would continue into a rest before
or after the motion (the rest would then hold a full sine to follow). :func:`piecewise` writes h plus a quintic
B-spline in the local power basis of :class:`bayesdamper.physics.excitation.PiecewisePolynomial` (h as its clamped
quintic interpolant at the sample times, subdivided where a harmonic turns faster than ``NODE_PHASE`` per node).

Imports: numpy, scipy and :mod:`bayesdamper.core` only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.linalg import LinAlgError, cho_factor, cho_solve, cholesky, solve_triangular

__all__ = ["HarmonicFit", "fit_harmonic", "moving_span", "piecewise", "refit"]

#: Smallest share of the noise-free variance (about the best line) that the fundamental explains: the
#: classifier's SINE_R2 (bayesdamper.io.recordkind: harmonic distortion up to 7 % is a sine, a triangle never).
MIN_R2 = 0.995
#: Fewest cycles over the moving part, less a tolerance for a one-cycle record's fitted frequency (the
#: classifier's MIN_CYCLES and CYCLE_TOLERANCE).
MIN_CYCLES, CYCLE_TOLERANCE = 1.0, 0.01
#: The moving part: from the first to the last sample whose reconstructed speed exceeds this fraction of its 95th
#: percentile (the classifier's REST_FRACTION).
REST_FRACTION = 0.05
#: Zero padding of the FFT locating the fundamental (peak error below 1/16 of a bin) [-]; the least-squares
#: search then spans ±1.5 bins on a grid of FREQUENCY_GRID points (the fit's R²(f) peak is about a bin wide, the
#: grid's step 0.1 bin), from whose best point Gauss-Newton converges.
FFT_PADDING, FREQUENCY_GRID = 8, 31
#: Gauss-Newton on f: at most NEWTON_STEPS steps (from the grid's best point it took 3-4), stopped when a step is below
#: FREQUENCY_TOL of f (a phase error of 1e-10 × 2π × cycles at the record's end); the Jacobian by central
#: differences of FREQUENCY_STEP × f (round-off 1e-16 / 1e-6 of a term, truncation 1e-12).
NEWTON_STEPS, FREQUENCY_TOL, FREQUENCY_STEP = 8, 1e-10, 1e-6
#: Most harmonics tried: a bound on the cost (a Gram matrix of 60 000 samples × 66 columns takes 12 ms on one core,
#: and the frequency's refinement a dozen of them); harmonics above it are left to the spline, which follows them as
#: it would without a harmonic part.
MAX_HARMONICS = 32
#: Largest phase of the fastest harmonic between interpolation nodes [rad]: the clamped quintic interpolant of a
#: sine has a relative rms velocity error ≈ (phase)⁵ / 3000: 4e-6 at 0.5 rad (measured on analytic sines, 400
#: nodes, phases 0.05-2 rad), far below the coefficients' noise.
NODE_PHASE = 0.5


@dataclass(frozen=True)
class HarmonicFit:
    """h(t) of the module docstring.

    Attributes
    ----------
    frequency_hz : float
        Fundamental f [Hz].
    coef : ndarray, shape (2 + 2K,)
        c₀ [m], c₁ [m], then a_k, b_k [m] for k = 1..K.
    t_mid, span : float
        Middle t_m and length T of the fitted (moving) part [s].
    fit_range : tuple of int
        Samples ``a:b`` fitted (the moving part).
    r2, cycles : float
        The fundamental's share of the noise-free variance [-]; cycles in the fitted part [-].
    """

    frequency_hz: float
    coef: np.ndarray
    t_mid: float
    span: float
    fit_range: tuple[int, int]
    r2: float
    cycles: float

    @property
    def n_harmonics(self) -> int:
        """K."""
        return (self.coef.size - 2) // 2

    def derivative(self, t, nu: int = 0) -> np.ndarray:
        """The ``nu``-th time derivative of h at times ``t`` [s] ([m s⁻ⁿᵘ])."""
        s = np.asarray(t, dtype=float) - self.t_mid
        out = np.full(s.shape, self.coef[0]) + self.coef[1] * s / self.span if nu == 0 else np.zeros(s.shape)
        if nu == 1:
            out += self.coef[1] / self.span
        w = 2.0 * math.pi * self.frequency_hz
        for k in range(1, self.n_harmonics + 1):
            ph = k * w * s + nu * math.pi / 2.0
            out += (k * w) ** nu * (self.coef[2 * k] * np.cos(ph) + self.coef[2 * k + 1] * np.sin(ph))
        return out

    def describe(self) -> str:
        """One line: the fundamental, K, the fitted part."""
        return (f"harmonic part: {self.frequency_hz:.6g} Hz with {self.n_harmonics} harmonic(s) (K by BIC) over "
                f"{self.cycles:.2f} cycles of the moving part (the fundamental's R² {self.r2:.5f}, noise removed)")


def moving_span(velocity) -> tuple[int, int]:
    """Samples ``a:b`` from the first to the last whose |``velocity``| exceeds ``REST_FRACTION`` of its 95th
    percentile (the whole record if none)."""
    v = np.abs(np.asarray(velocity, dtype=float))
    idx = np.flatnonzero(v > REST_FRACTION * float(np.percentile(v, 95)))
    return (int(idx[0]), int(idx[-1]) + 1) if idx.size > 1 else (0, v.size)


def _columns(s: np.ndarray, w: float, k_max: int, span: float, nu: int) -> np.ndarray:
    """Design columns (1, s/T, cos kws, sin kws, k ≤ k_max) or their time derivative (``nu`` = 1) at ``s`` [s]."""
    cols = [np.ones_like(s), s / span] if nu == 0 else [np.zeros_like(s), np.full(s.shape, 1.0 / span)]
    for k in range(1, k_max + 1):
        ph = k * w * s + nu * math.pi / 2.0
        cols += [(k * w) ** nu * np.cos(ph), (k * w) ** nu * np.sin(ph)]
    return np.column_stack(cols)


class _Problem:
    """The weighted least squares of h over samples ``a:b``: rows y and √w v (normal equations: the columns are
    near-orthogonal over whole cycles)."""

    def __init__(self, t, y, fit_range, velocity=None, weight=0.0):
        a, b = fit_range
        self.t, self.y = t[a:b], y[a:b]
        self.v = None if velocity is None or weight <= 0.0 else velocity[a:b]
        self.rw = math.sqrt(weight) if self.v is not None else 0.0
        self.t_mid, self.span = 0.5 * (self.t[0] + self.t[-1]), float(self.t[-1] - self.t[0])
        self.target = self.y if self.v is None else np.r_[self.y, self.rw * self.v]

    def design(self, f: float, k: int) -> np.ndarray:
        s, w = self.t - self.t_mid, 2.0 * math.pi * f
        x = _columns(s, w, k, self.span, 0)
        return x if self.v is None else np.vstack([x, self.rw * _columns(s, w, k, self.span, 1)])

    def solve(self, f: float, k: int, extra: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """(coefficients, χ² [m²]) with ``k`` harmonics of ``f`` [Hz] (and an ``extra`` column, last)."""
        x = self.design(f, k) if extra is None else np.column_stack([self.design(f, k), extra])
        c = cho_solve(cho_factor(x.T @ x), x.T @ self.target)
        r = self.target - x @ c
        return c, float(r @ r)

    def refine(self, f: float, k: int) -> float:
        """f [Hz] minimising χ² with ``k`` harmonics, by Gauss-Newton steps on (coefficients, f) from ``f``
        (a step that raises χ² is halved)."""
        c, chi2 = self.solve(f, k)
        for _ in range(NEWTON_STEPS):
            eps = FREQUENCY_STEP * f
            jac = (self.design(f + eps, k) @ c - self.design(f - eps, k) @ c) / (2.0 * eps)
            step = self.solve(f, k, jac)[0][-1]
            for _ in range(NEWTON_STEPS):
                c_new, chi2_new = self.solve(f + step, k)
                if chi2_new <= chi2:
                    break
                step *= 0.5
            else:
                return f
            f, c, chi2 = f + step, c_new, chi2_new
            if abs(step) <= FREQUENCY_TOL * f:
                break
        return f


def _peak(t: np.ndarray, y: np.ndarray, f_min: float) -> float:
    """Frequency [Hz] of the largest zero-padded periodogram peak above ``f_min`` of ``y`` less its best line."""
    s = t - t[0]
    nfft = FFT_PADDING * int(2 ** math.ceil(math.log2(y.size)))
    spec = np.abs(np.fft.rfft(y - np.polyval(np.polyfit(s, y, 1), s), nfft))
    f = np.fft.rfftfreq(nfft, float(np.median(np.diff(t))))
    return float(f[int(np.argmax(np.where(f < f_min, 0.0, spec)))])


def fit_harmonic(t, y, sigma: float, s2: float, band_hz: float, fit_range: tuple[int, int], *, adc_step: float = 0.0,
                 velocity=None, velocity_weight: float = 0.0) -> HarmonicFit | None:
    """The harmonic part of a periodic record, or None if the moving part is not periodic (module docstring) or
    too short for its harmonics (a singular least-squares problem).

    Parameters
    ----------
    t, y : ndarray, shape (n,)
        Sample times [s] (uniform) and measured displacement [m].
    sigma, s2 : float
        Displacement noise sd [m] (the periodicity test) and the variance the criterion charges per coefficient
        and unit of ln N [m²].
    band_hz : float
        Highest frequency a harmonic may have [Hz] (capped below the Nyquist frequency).
    fit_range : tuple of int
        Samples ``a:b`` of the moving part.
    adc_step : float
        The displacement's ADC step q [m] (0: none): harmonics of amplitude at most q after the last larger one are
        left to the spline (module docstring).
    velocity, velocity_weight
        A measured velocity channel [m/s] and its weight w [s²] (module docstring), or None.
    """
    p = _Problem(np.asarray(t, float), np.asarray(y, float), fit_range, velocity, velocity_weight)
    n, dt = p.t.size, float(np.median(np.diff(p.t))) if p.t.size > 1 else 0.0
    if n < 8 or p.span <= 0.0:
        return None
    try:
        return _fit(p, n, dt, sigma, s2, band_hz, tuple(fit_range), adc_step)
    except LinAlgError:
        return None


def _fit(p: _Problem, n: int, dt: float, sigma: float, s2: float, band_hz: float, fit_range: tuple[int, int],
         adc_step: float) -> HarmonicFit | None:
    f0 = _peak(p.t, p.y, 0.25 / p.span)
    if f0 * (p.span + dt) < MIN_CYCLES - CYCLE_TOLERANCE:
        return None
    grid = np.linspace(max(0.25 / p.span, f0 - 1.5 / p.span), f0 + 1.5 / p.span, FREQUENCY_GRID)
    f = p.refine(float(grid[int(np.argmin([p.solve(f, 1)[1] for f in grid]))]), 1)
    line = np.polyval(np.polyfit(p.t - p.t_mid, p.y, 1), p.t - p.t_mid)
    sse = float(np.sum((p.y - p.design(f, 1)[:n] @ p.solve(f, 1)[0]) ** 2))
    total = float(np.sum((p.y - line) ** 2)) - (n - 2) * sigma**2
    r2 = 1.0 - max(sse - (n - 4) * sigma**2, 0.0) / total if total > 0.0 else 0.0
    cycles = f * (p.span + dt)
    if r2 < MIN_R2 or cycles < MIN_CYCLES - CYCLE_TOLERANCE:
        return None
    # harmonics below the band and Nyquist, with at least two samples per coefficient (2 + 2K ≤ n/2)
    k_cap = max(1, min(MAX_HARMONICS, int(band_hz / f), int(math.ceil(0.5 / (dt * f))) - 1, (n // 2 - 2) // 2))
    x = p.design(f, k_cap)
    z = solve_triangular(cholesky(x.T @ x, lower=True), x.T @ p.target, lower=True)  # RSS of nested models
    bic = float(p.target @ p.target) - np.cumsum(z * z)[3::2] + s2 * math.log(n) * (2.0 * np.arange(1, k_cap + 1) + 2)
    k = 1 + int(np.argmin(bic))
    if adc_step > 0.0:  # a quantisation error bounded by q/2 has no harmonic of amplitude above q
        amp = np.hypot(*p.solve(f, k)[0][2:].reshape(-1, 2).T)
        k = 1 + int(np.flatnonzero(amp > adc_step)[-1]) if np.any(amp[1:] > adc_step) else 1
    f = p.refine(f, k) if k > 1 else f
    return HarmonicFit(f, p.solve(f, k)[0], p.t_mid, p.span, fit_range, r2, cycles)


def refit(h: HarmonicFit, t, y, *, velocity=None, velocity_weight: float = 0.0) -> HarmonicFit:
    """``h`` refitted to other data ``y`` [m] (and velocity [m/s]) over the same samples with the same K, its
    frequency refined again (a bootstrap replicate of the fit)."""
    p = _Problem(np.asarray(t, float), np.asarray(y, float), h.fit_range, velocity, velocity_weight)
    f = p.refine(h.frequency_hz, h.n_harmonics)
    return replace(h, frequency_hz=f, coef=p.solve(f, h.n_harmonics)[0])


def piecewise(h: HarmonicFit, spline: BSpline, t) -> tuple[np.ndarray, np.ndarray]:
    """(breaks [s], coefs) in the local power basis of h plus ``spline`` (a quintic B-spline whose knots are sample
    times of ``t``): h interpolated by a quintic spline with its own first and second derivatives at both ends, at
    the samples and, where a harmonic turns by more than ``NODE_PHASE`` per sample, between them."""
    t = np.asarray(t, dtype=float)
    dt = float(np.max(np.diff(t)))
    m = max(1, math.ceil(2.0 * math.pi * h.frequency_hz * h.n_harmonics * dt / NODE_PHASE))
    nodes = np.r_[(t[:-1, None] + np.diff(t)[:, None] * (np.arange(m) / m)).ravel(), t[-1]]
    ends = [[(1, float(h.derivative(x, 1))), (2, float(h.derivative(x, 2)))] for x in (t[0], t[-1])]
    hi = make_interp_spline(nodes, h.derivative(nodes), k=5, bc_type=(ends[0], ends[1]))
    left = nodes[:-1]
    coefs = np.column_stack([(hi(left, j) + spline(left, j)) / math.factorial(j) for j in range(6)])
    return np.ascontiguousarray(nodes), np.ascontiguousarray(coefs)
