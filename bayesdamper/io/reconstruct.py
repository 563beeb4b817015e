"""The piston motion (the input of eq. (7)) reconstructed from a measured displacement record.

An interpolating spline through noisy samples turns displacement noise σ into velocity noise of about σ × sample
rate (1 µm at 200 Hz: 0.2 mm/s, the paper's slowest speeds). :func:`reconstruct_input` fits a penalised quintic
spline instead (:mod:`bayesdamper.io.pspline`), every setting taken from the record:

* **noise** σ̂: white noise gives Var(Δᵏy) = C(2k, k) σ² for the k-th differences at every k; a smooth signal
  sampled above its band adds (2 sin(ωΔt/2))ᵏ A, which falls with k: σ̂ is the smallest estimate over k;
* **ADC step** q: the values on a grid (:func:`detect_adc_step`). Moving faster than a step per sample, the
  quantisation error is white (in σ̂, at least q/√12); slower, it is a staircase (``_staircase``);
* **fit**: a quintic B-spline (velocity C³) minimising Σ (y_i - f(t_i))² + λ ∫ (f⁽ᴹ⁾)² dt, M = ``PENALTY_ORDER``;
* **λ** minimises Mallows' C_p = RSS + 2 σ² edf (an unbiased estimate of the displacement error given σ). C_p
  follows a staircase (not white): there λ is raised until RSS ≥ (n - edf)(q²/12 + σ_n²), the staircase's own
  residual;
* **a periodic record** (a sine, :mod:`bayesdamper.io.harmonic`): a spline passes the noise of its whole band; a
  test that repeats its motion lets the noise be averaged over every cycle. The record is fitted as a drifting
  mean plus a Fourier series of its fundamental (K harmonics by BIC, f by least squares, over the moving part)
  and the spline smooths the rest (measured minus harmonic part: what does not repeat), or the rest is its mean
  where C_p finds it noise. Kept where it describes the record with fewer edf than the spline alone: a record that
  starts or stops at rest keeps the spline alone (the harmonic part would continue into the rests). On an exact
  sine the velocity error is ωσ√(3/N) over N samples (tests/test_reconstruct.py).

Clean data (σ̂ below ``CLEAN_FRACTION`` of the stroke) are interpolated (quintic, not-a-knot). A measured velocity
channel is compared with the reconstruction (gain, lag, offset) and fitted jointly (weights 1/σ², 1/σ̂_v²) if
they agree. The velocity error is a seeded parametric bootstrap (the reconstruction plus noise, re-quantised on
the ADC grid at a random offset, refitted the same way: the harmonic part with its K, f refined, the spline at the
same knots and λ): it covers the noise and the smoothing bias of smooth motion but not all of the rounding of an
abrupt start or stop (tests/test_reconstruct.py).

``breaks``/``coefs`` are the local power basis of :class:`bayesdamper.physics.excitation.PiecewisePolynomial`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.linalg import cho_solve_banded

from bayesdamper.core.errors import DataError
from bayesdamper.io.harmonic import HarmonicFit, fit_harmonic, moving_span, piecewise, refit
from bayesdamper.io.pspline import PENALTY_ORDER, SPLINE_DEGREE, Smoother, power_basis, smooth

__all__ = ["InputReconstruction", "bootstrap_inputs", "detect_adc_step", "estimate_noise_sd", "reconstruct_input"]

#: Highest difference order of the noise estimate: (2 sin(ωΔt/2))ᵏ / √C(2k, k) ≈ 1e-7 at k = 10 for a 5 Hz sine
#: at 100 Hz (ωΔt = 0.31): even that signal adds < 1e-9 m per mm of amplitude to σ̂.
MAX_DIFFERENCE_ORDER = 10
#: The median of |x| is MAD_GAUSS sd for Gaussian x; differences beyond OUTLIER_MADS such sds are spikes, left
#: out (a Gaussian loses 6e-7 of its values). The rms of the rest estimates σ with a relative sd of 1.1/√n
#: (measured on white noise; the median instead: 1.4/√n, and 7 % low at n = 200 after the minimum over k).
MAD_GAUSS, OUTLIER_MADS = 0.6744897501960817, 5.0
#: C_p uses σ = σ̂ (1 + CP_NOISE_MARGIN/√n), σ̂ plus about two of its standard errors: a low σ̂ makes C_p
#: undersmooth far more than a high one oversmooths. On 40 records of 200 samples (5 Hz, 0.5 Hz, multisine) the
#: worst velocity error fell from 12-22x to 1.8-2.4x the median; on longer records it costs at most 5 %.
CP_NOISE_MARGIN = 2.0
#: Fewest samples (below 20 the differences are too few to tell noise from signal); noise below CLEAN_FRACTION of
#: the stroke is round-off (a CSV with 10 digits: 1e-10; a good LVDT: 1e-6 of its range): interpolated.
MIN_SAMPLES, CLEAN_FRACTION = 20, 1e-9
#: Grid test of the distinct values' spacings: within ADC_GRID_TOL of a step of an integer multiple (mm-to-m
#: round-off: 1e-10 of a step; a continuous record's spacing lands there with probability 0.04) for
#: ADC_GRID_FRACTION of them (glitches); the smallest spacing may be ADC_MAX_DIVISOR steps (lab-MR's fast sines
#: skip levels); spacings below ADC_SAME_LEVEL of the largest |value| are round-off of one level.
ADC_GRID_TOL, ADC_GRID_FRACTION, ADC_MAX_DIVISOR, ADC_SAME_LEVEL = 0.02, 0.99, 8, 1e-9
#: A quantised record is a staircase (slower than a step per sample: its error correlated over runs of equal
#: values) when this fraction of its sample steps repeat the value. C_p follows a staircase (100x the floor's
#: velocity error: 0.05 Hz sine, 10 µm ADC, 1 kHz); the floor over-smooths faster records (4x: 0.2 Hz, 5 µm, 200 Hz).
STAIRCASE_FRACTION = 0.5
#: The staircase floor's target is raised by STAIR_MARGIN/√N (N its level crossings), 2 sds of the scatter of a
#: staircase's own mean-square error: a target below it puts λ where the fit still follows the steps (0.05 Hz
#: sine, 10 µm ADC at 1 kHz, 0.2 s: 42 % of the peak speed without the margin, 2 % with it; 2 s: 24 %, 0.01 %).
STAIR_MARGIN = 0.5
#: Bootstrap replicates: their rms has a relative sd of 1/√(2 × 8 × smoothing lengths in the record), < 10 % on 20.
N_BOOTSTRAP = 8
#: A velocity channel is fitted jointly only if its gain is within 2 % of 1, its lag within 0.2 sample and its
#: offset within 2 % of its rms, or the deviation is below SIGNIFICANCE standard errors (too small to bias the
#: fit): a backward-difference channel (lag 0.5 sample) or a mis-scaled one is only reported.
VELOCITY_GAIN_TOL, VELOCITY_LAG_TOL, SIGNIFICANCE = 0.02, 0.2, 3.0


@dataclass(frozen=True)
class InputReconstruction:
    """A reconstructed piston displacement: a quintic spline in the local power basis.

    Attributes
    ----------
    breaks : ndarray, shape (m + 1,)
        Piece boundaries [s], strictly increasing, from the first to the last sample time.
    coefs : ndarray, shape (m, 6)
        C-contiguous float64: y(t) = Σ_j coefs[k, j] (t - breaks[k])ʲ [m] on [breaks[k], breaks[k + 1]].
    noise_sd_m, adc_step_m : float
        Estimated displacement noise sd [m] (sensor noise and quantisation, at least q/√12) and detected ADC step
        q [m] (0.0 if none).
    method : str
        One line: what was done and why.
    residual_rms_m, velocity_error_m_s : float
        Rms of measured minus reconstructed displacement at the samples [m]; bootstrap estimate of the rms error
        of the reconstructed velocity at the samples [m/s] (0.0 for an interpolation).
    n_samples, knot_step, n_bootstrap : int
        Samples, samples per knot interval (0: interpolation), bootstrap replicates behind the velocity error.
    log10_lambda, effective_dof : float
        Smoothing parameter (dimensionless; nan for an interpolation) and the fit's effective dof [-].
    harmonic_frequency_hz, n_harmonics : float, int
        Fundamental [Hz] and harmonics of the harmonic part (nan and 0: none).
    """

    breaks: np.ndarray
    coefs: np.ndarray
    noise_sd_m: float
    adc_step_m: float
    method: str
    residual_rms_m: float
    velocity_error_m_s: float
    n_samples: int = 0
    knot_step: int = 0
    n_bootstrap: int = 0
    log10_lambda: float = math.nan
    effective_dof: float = math.nan
    harmonic_frequency_hz: float = math.nan
    n_harmonics: int = 0

    def _evaluate(self, t, nu: int) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.breaks, t, side="right") - 1, 0, self.coefs.shape[0] - 1)
        s, c, out = t - self.breaks[k], self.coefs[k], np.zeros(t.shape)
        for j in range(self.coefs.shape[1] - 1, nu - 1, -1):  # Horner on the nu-th derivative
            out = out * s + c[..., j] * (math.factorial(j) // math.factorial(j - nu))
        return out

    def displacement(self, t) -> np.ndarray:
        """Displacement [m] at times ``t`` [s] (the end pieces extend beyond the record)."""
        return self._evaluate(t, 0)

    def velocity(self, t) -> np.ndarray:
        """Velocity [m/s] at times ``t`` [s]."""
        return self._evaluate(t, 1)

    def acceleration(self, t) -> np.ndarray:
        """Acceleration [m/s²] at times ``t`` [s]."""
        return self._evaluate(t, 2)

    def as_dict(self) -> dict:
        """The scalars and counts, JSON-safe (nan as None), no arrays."""
        out = {k: (float(x) if math.isfinite(x) else None) for k, x in vars(self).items() if isinstance(x, float)}
        return out | {"method": self.method, "n_samples": int(self.n_samples), "n_pieces": int(self.coefs.shape[0]),
                      "knot_step": int(self.knot_step), "n_bootstrap": int(self.n_bootstrap),
                      "n_harmonics": int(self.n_harmonics),
                      "t_start_s": float(self.breaks[0]), "t_end_s": float(self.breaks[-1])}


# ----------------------------------------------------------------------------- noise and ADC step
def estimate_noise_sd(displacement) -> float:
    """Sd [m] of the white part of the noise of uniformly sampled ``displacement`` [m], shape (n,): the smallest
    over k of the rms k-th difference / √C(2k, k), differences beyond ``OUTLIER_MADS`` robust sds left out
    (module docstring); 0 for a staircase whose differences are mostly 0."""
    y, best = np.asarray(displacement, dtype=float), math.inf
    for k in range(1, min(MAX_DIFFERENCE_ORDER, y.size // 4) + 1):
        d = np.diff(y, k)
        mad = float(np.median(np.abs(d))) / MAD_GAUSS
        d = d[np.abs(d) <= OUTLIER_MADS * mad] if mad > 0.0 else d  # mostly 0 (a staircase): no outliers to tell
        best = min(best, math.sqrt(float(np.mean(d * d)) / math.comb(2 * k, k)) if d.size else 0.0)
    return best if math.isfinite(best) else 0.0


def detect_adc_step(displacement) -> float:
    """Quantisation step [m] of a record whose values lie on a grid, else 0.0: the largest q = (smallest spacing
    of the distinct values) / j, j ≤ ``ADC_MAX_DIVISOR``, of which the spacings are integer multiples (module
    constants), refined as their total over the total of the multiples (the grid's offset does not matter)."""
    u = np.unique(np.asarray(displacement, dtype=float))
    d = np.diff(u)[np.diff(u) > ADC_SAME_LEVEL * float(np.max(np.abs(u), initial=0.0))]
    if d.size < 2 or d.max() / d.min() > 1.0 / ADC_SAME_LEVEL:
        return 0.0
    for j in range(1, ADC_MAX_DIVISOR + 1):
        ratio = d / (d.min() / j)
        mult, on_grid = np.round(ratio), np.abs(ratio - np.round(ratio)) <= ADC_GRID_TOL
        if on_grid.mean() >= ADC_GRID_FRACTION:
            return float(d[on_grid].sum() / mult[on_grid].sum())
    return 0.0


def _staircase(y: np.ndarray, q: float) -> tuple[int, float, float]:
    """(n_f, σ_n [m], margin [-]) of a staircase, (0, 0.0, 0.0) if ``y`` is not one. n_f: the samples from the
    first change of value to the last (rest before and after the motion, which the fit may follow exactly, left
    out); σ_n: the noise beneath the ADC, which flips the record between neighbouring levels (2 σ_n / (q √π) flips
    per sample at rest; c changes per level crossing, c² = 1 + (2 σ_n / (√π q × crossings per sample))²); margin:
    ``STAIR_MARGIN``/√crossings (a staircase's mean square scatters by 0.1-0.33/√crossings of q²/12 + σ_n²)."""
    d, change = np.diff(y), np.flatnonzero(np.diff(y) != 0.0)
    n_steps = int(change[-1] - change[0] + 1) if change.size else 0
    if q <= 0.0 or n_steps == 0 or 1.0 - change.size / n_steps < STAIRCASE_FRACTION:
        return 0, 0.0, 0.0
    sign = np.sign(d[change])
    crossings = max(change.size - np.count_nonzero(sign[1:] != sign[:-1]), 1)  # reversals are flips
    white = math.sqrt(max(change.size**2 - crossings**2, 0)) / n_steps * q * math.sqrt(math.pi) / 2.0
    return n_steps + 1, min(white, q / 2.0), STAIR_MARGIN / math.sqrt(crossings)


# ----------------------------------------------------------------------------- the reconstruction
def _validate(time, displacement, velocity):
    t, y = np.asarray(time, dtype=float), np.asarray(displacement, dtype=float)
    if t.ndim != 1 or y.shape != t.shape:
        raise DataError(f"time and displacement must be 1-D of one length (got shapes {t.shape}, {y.shape})")
    if t.size < MIN_SAMPLES:
        raise DataError(f"{t.size} samples: at least {MIN_SAMPLES} are needed to reconstruct the input")
    v = None if velocity is None else np.asarray(velocity, dtype=float)
    if v is not None and v.shape != t.shape:
        raise DataError(f"velocity must have the displacement's shape {t.shape} (got {v.shape})")
    for name, a in (("time", t), ("displacement", y), ("velocity", v)):
        bad = [] if a is None else np.flatnonzero(~np.isfinite(a))
        if len(bad):
            raise DataError(f"{name} sample {bad[0]} is not finite ({a[bad[0]]}); {len(bad)} such sample(s)")
    if np.any(np.diff(t) <= 0.0):
        i = int(np.flatnonzero(np.diff(t) <= 0.0)[0])
        raise DataError(f"time is not strictly increasing at sample {i + 1} ({t[i]!r} s, then {t[i + 1]!r} s)")
    return t, y, v


def _velocity_gate(t, vel, acc, v) -> tuple[bool, str]:
    """Whether the measured velocity ``v`` [m/s] agrees with the reconstruction's ``vel`` [m/s] and ``acc``
    [m/s²] (least squares v ≈ b + g (vel - τ acc)), and the comparison as text."""
    a = np.column_stack([np.ones_like(t), vel, acc])
    coef, *_ = np.linalg.lstsq(a, v, rcond=None)
    res = v - a @ coef
    cov = float(res @ res) / max(t.size - 3, 1) * np.linalg.pinv(a.T @ a)
    b, g, gt = (float(x) for x in coef)
    se_b, se_g, se_gt = np.sqrt(np.maximum(np.diag(cov), 0.0))
    lag, dt = -gt / g if g else math.inf, float(np.median(np.diff(t)))
    agrees = (abs(g - 1.0) <= max(VELOCITY_GAIN_TOL, SIGNIFICANCE * se_g)
              and abs(lag) <= max(VELOCITY_LAG_TOL * dt, SIGNIFICANCE * se_gt / abs(g or 1.0))
              and abs(b) <= max(VELOCITY_GAIN_TOL * float(np.sqrt(np.mean(v**2))), SIGNIFICANCE * se_b))
    return agrees, (f"gain {g:.4f}, lag {lag / dt:.2f} sample, offset {b * 1e3:.2g} mm/s, rms difference "
                    f"{float(np.sqrt(np.mean((v - vel) ** 2))) * 1e3:.3g} mm/s")


def _pieces(sm: Smoother, c: np.ndarray, offset: float, harmonic: HarmonicFit | None):
    """(breaks [s], coefs) of the spline ``c`` + ``offset`` [m] plus the harmonic part (if any)."""
    return sm.local_basis(c, offset) if harmonic is None else piecewise(harmonic, sm.spline(c, offset), sm.t)


@dataclass
class _Periodic:
    """A kept harmonic part and the smoothing of the rest (internal)."""

    harmonic: HarmonicFit
    sm: Smoother
    log_lam: float
    mean: float  # the rest's mean [m]
    rest: bool  # the rest smoothed (else its mean alone: C_p finds it noise)
    edf: float


def _periodic(t, y, v, sm: Smoother, log_lam: float, sigma: float, s2: float, floor, q: float):
    """(the harmonic part with the smoothing of the rest, or None; one line saying so) of a record whose plain
    smoothing is ``sm`` at ``log_lam`` (io/harmonic.py). Kept if it describes the record with fewer edf."""
    w = sm.v_weight if v is not None else 0.0
    harmonic = fit_harmonic(t, y, sigma, s2, sm.band(log_lam), moving_span(sm.dbasis @ sm.fit(log_lam)[0]),
                            adc_step=q, velocity=v, velocity_weight=w)
    if harmonic is None:
        return None, ""
    yr, vr = y - harmonic.derivative(t), None if v is None else v - harmonic.derivative(t, 1)
    mean = float(np.mean(yr))
    h_sm, h_lam = smooth(t, yr - mean, s2, floor, vr, w)
    _, _, chi2, edf = h_sm.fit(h_lam)
    chi2_mean = float(np.sum((yr - mean) ** 2)) + (w * float(vr @ vr) if vr is not None else 0.0)
    rest = chi2 + 2.0 * s2 * edf < chi2_mean + 2.0 * s2
    edf = (edf if rest else 1.0) + 2 * harmonic.n_harmonics + 3  # c₀, c₁, a_k, b_k and f
    edf_0 = sm.fit(log_lam)[3]
    note = f"; {harmonic.describe()}, edf {edf:.1f} against {edf_0:.1f} of the spline alone: "
    if edf >= edf_0:
        return None, note + "not kept"
    return (_Periodic(harmonic, h_sm, h_lam, mean, rest, edf),
            note + "kept" + ("" if rest else ", the rest is noise (C_p of its mean below the spline's)"))


@dataclass
class _Fit:
    """A reconstruction with what its bootstrap replicates need (internal)."""

    result: InputReconstruction
    sm: Smoother | None = None  # None: an interpolation
    coef: np.ndarray | None = None
    mean: float = 0.0
    white: float = 0.0  # the white noise the bootstrap adds before quantising [m]
    sigma_v: float = 0.0  # noise sd of a jointly fitted velocity channel [m/s]
    harmonic: HarmonicFit | None = None  # the periodic part (io/harmonic.py); the spline smooths the rest ...
    rest: bool = True  # ... unless the rest is noise about its mean (its spline coefficients 0)

    def velocity(self, c: np.ndarray, harmonic: HarmonicFit | None) -> np.ndarray:
        """Velocity [m/s] at the samples of the spline ``c`` plus ``harmonic``."""
        return self.sm.dbasis @ c + (harmonic.derivative(self.sm.t, 1) if harmonic is not None else 0.0)


def _fit(time, displacement, velocity) -> _Fit:
    t, y, v = _validate(time, displacement, velocity)
    q = detect_adc_step(y)
    n_f, white, margin = _staircase(y, q)
    # a staircase's error: q²/12 and the noise beneath the ADC (which its differences, mostly 0, do not show)
    sigma = math.sqrt(q * q / 12.0 + white**2) if n_f else max(estimate_noise_sd(y), q / math.sqrt(12.0))
    white = white if n_f else math.sqrt(max(sigma**2 - q**2 / 12.0, 0.0))
    stroke = float(np.ptp(y))
    if sigma <= CLEAN_FRACTION * stroke or stroke == 0.0:
        spline = make_interp_spline(t, y, k=SPLINE_DEGREE)
        method = (f"quintic interpolating spline (not-a-knot): displacement clean (σ̂ = {sigma * 1e6:.2g} µm "
                  f"≤ {CLEAN_FRACTION:g} of the {stroke * 1e3:.3g} mm stroke), nothing to smooth")
        if v is not None:
            method += "; measured velocity only compared: " + _velocity_gate(t, spline(t, 1), spline(t, 2), v)[1]
        breaks, coefs = power_basis(spline)
        return _Fit(InputReconstruction(breaks, coefs, sigma, q, method, float(np.sqrt(np.mean(
            (y - spline(t)) ** 2))), 0.0, t.size, 0, 0, math.nan, float(t.size)))
    mean = float(np.mean(y))  # constants are unpenalised: fitting about the mean only spares the solve's digits
    yc, floor = y - mean, (n_f, sigma**2 * (1.0 + margin) if n_f else 0.0)
    s2 = (sigma * (1.0 + CP_NOISE_MARGIN / math.sqrt(t.size))) ** 2
    sm, log_lam = smooth(t, yc, s2, floor)
    note, sigma_v = "", 0.0
    if v is not None:
        c = sm.fit(log_lam)[0]
        agrees, check = _velocity_gate(t, sm.dbasis @ c, sm.spline(c)(t, 2), v)
        sigma_v = max(estimate_noise_sd(v), detect_adc_step(v) / math.sqrt(12.0), CLEAN_FRACTION * float(np.ptp(v)))
        sigma_v = sigma_v if agrees else 0.0
        if sigma_v > 0.0:
            sm, log_lam = smooth(t, yc, s2, floor, v, sigma**2 / sigma_v**2)
        note = (f"; measured velocity fitted jointly (σ̂_v = {sigma_v * 1e3:.3g} mm/s; it agrees: {check})"
                if sigma_v > 0.0 else f"; measured velocity only compared, not fitted (it disagrees: {check})")
    per, h_note = _periodic(t, y, v if sigma_v > 0.0 else None, sm, log_lam, sigma, s2, floor, q)
    if per is not None:
        sm, log_lam, mean, yc = per.sm, per.log_lam, per.mean, y - per.harmonic.derivative(t) - per.mean
    coef, _, _, edf = sm.fit(log_lam)
    if per is not None:
        coef, edf = coef if per.rest else np.zeros_like(coef), per.edf
    harmonic, note = per.harmonic if per is not None else None, h_note + note
    noise = (f"σ = {sigma * 1e6:.3g} µm from the ADC step {q * 1e6:.3g} µm and the noise beneath it "
             f"({white * 1e6:.2g} µm, from level flips): a staircase, λ raised to RSS ≥ (n - edf) σ² (1 + {margin:.2g})"
             if n_f else f"σ̂ = {sigma * 1e6:.3g} µm from high-order differences"
             + (f", ADC step {q * 1e6:.3g} µm (moving > 1 step per sample: white)" if q else ""))
    method = (f"penalised quintic spline (∫(f⁽{PENALTY_ORDER}⁾)² penalty, knot every {sm.step} sample(s)), λ by "
              f"Mallows' C_p at σ (1 + {CP_NOISE_MARGIN:g}/√n), {noise}; edf {edf:.1f} of {t.size}{note}")
    breaks, coefs = _pieces(sm, coef, mean, harmonic)
    resid = float(np.sqrt(np.mean((yc - sm.basis @ coef) ** 2)))
    result = InputReconstruction(breaks, coefs, sigma, q, method, resid, math.nan, t.size, sm.step, 0,
                                 float(log_lam), edf, *((harmonic.frequency_hz, harmonic.n_harmonics)
                                                        if harmonic is not None else (math.nan, 0)))
    return _Fit(result, sm, coef, mean, white, sigma_v, harmonic, per is None or per.rest)


def _replicates(fit: _Fit, n_replicates: int, seed: int) -> list[tuple[np.ndarray, HarmonicFit | None]]:
    """(B-spline coefficients, harmonic part) of ``n_replicates`` refits (same knots and λ; the harmonic part with
    the same K, its frequency refined) of the reconstruction plus white noise, quantised on the ADC grid at a random
    offset (the staircase's phase is unknown) [m]."""
    sm, q, h, rng = fit.sm, fit.result.adc_step_m, fit.harmonic, np.random.default_rng(seed)
    chol = (sm.factor(fit.result.log10_lambda), False)
    y_hat = sm.basis @ fit.coef + fit.mean + (h.derivative(sm.t) if h is not None else 0.0)
    v_hat = fit.velocity(fit.coef, h)
    out = []
    for _ in range(n_replicates):
        ys = y_hat + fit.white * rng.standard_normal(y_hat.size)
        if q > 0.0:
            off = rng.uniform(0.0, q)
            ys = off + q * np.round((ys - off) / q)
        vs = v_hat + fit.sigma_v * rng.standard_normal(v_hat.size) if fit.sigma_v > 0.0 else None
        hb = None if h is None else refit(h, sm.t, ys, velocity=vs, velocity_weight=sm.v_weight)
        rhs = sm.basis.T @ (ys - fit.mean - (hb.derivative(sm.t) if hb is not None else 0.0))
        if vs is not None:
            rhs = rhs + sm.v_weight * (sm.dbasis.T @ (vs - (hb.derivative(sm.t, 1) if hb is not None else 0.0)))
        out.append((cho_solve_banded(chol, rhs) if fit.rest else np.zeros_like(fit.coef), hb))
    return out


def reconstruct_input(time, displacement, *, velocity=None, seed: int = 0) -> InputReconstruction:
    """Reconstruct the piston displacement (the input of eq. (7)) from a measured record.

    Parameters
    ----------
    time, displacement : ndarray, shape (n,)
        Sample times [s], strictly increasing (uniformly sampled for the noise estimate); measured displacement [m].
    velocity : ndarray, shape (n,), optional
        Measured velocity channel [m/s]: fitted jointly if it agrees with the displacement, else only compared
        (``method`` says which and why).
    seed : int
        Seed of the parametric bootstrap behind ``velocity_error_m_s``.

    Returns
    -------
    InputReconstruction

    Raises
    ------
    DataError
        Non-finite values, time not strictly increasing, fewer than ``MIN_SAMPLES`` samples, shape mismatch.
    """
    fit = _fit(time, displacement, velocity)
    if fit.sm is None:
        return fit.result
    v_hat = fit.velocity(fit.coef, fit.harmonic)
    err = [fit.velocity(c, hb) - v_hat for c, hb in _replicates(fit, N_BOOTSTRAP, seed)]
    return replace(fit.result, velocity_error_m_s=float(np.sqrt(np.mean(np.square(err)))), n_bootstrap=N_BOOTSTRAP,
                   method=fit.result.method + f"; velocity error by a {N_BOOTSTRAP}-replicate parametric bootstrap")


def bootstrap_inputs(time, displacement, *, velocity=None, n_replicates: int = N_BOOTSTRAP,
                     seed: int = 0) -> list[InputReconstruction]:
    """``n_replicates`` seeded bootstrap replicates of the reconstruction (InputReconstruction), to propagate the
    input's error into the force; the other parameters are :func:`reconstruct_input`'s.

    Each is the reconstruction refitted (same knots and λ) to itself plus noise of the estimated white sd,
    re-quantised on the ADC grid at a random offset (and a jointly fitted velocity channel plus its noise). With
    the same ``seed`` the first ``N_BOOTSTRAP`` are those behind :func:`reconstruct_input`'s velocity error; a
    clean (interpolated) record has no noise to resample: its replicates are the reconstruction itself.
    """
    fit = _fit(time, displacement, velocity)
    if fit.sm is None:
        return [fit.result] * n_replicates
    out = []
    for i, (c, hb) in enumerate(_replicates(fit, n_replicates, seed)):
        breaks, coefs = _pieces(fit.sm, c, fit.mean, hb)
        out.append(replace(fit.result, breaks=breaks, coefs=coefs, n_bootstrap=n_replicates, residual_rms_m=math.nan,
                           method=f"bootstrap replicate {i + 1}/{n_replicates} of: {fit.result.method}"))
    return out
