"""The force noise estimated where model error cannot reach it (:mod:`bayesdamper.inference.noise`).

Every record is seeded AR(1) noise (white and φ = 0.5, 0.9, 0.97; marginal sd 5-30 N; 100 Hz to 1 kHz) plus a model
error much larger than the noise: (a) a slow sine, 10 × the noise sd, given no hint; (b) a saturated square wave
at 1 Hz, 5 × the noise sd (dry friction of an MR damper: harmonics decaying as 1/k up to Nyquist), with the
fundamental given; (c) band-limited random error, 10 × the noise sd, 0.3-2 Hz, with the excitation band given.
Windows of 1, 2 and 4 whole cycles of a slow sine (0.05-0.12 Hz, 2000-5000 samples, test_windows_of_whole_cycles)
hold pure noise, or an orifice law's error 10 × the noise, or friction 5 × the noise, with the fundamental given.

Tolerances: φ and σ_e within :data:`K_SE` of their standard errors. The se are the estimator's own (the Whittle
information or the profile likelihood, whichever is wider, for the spectrum; the bias-corrected lag-1 fit at
rest); over 40-60 seeds per case (white and AR(1), the three errors, 100 Hz to 1 kHz) the z-scores of φ had sd
0.74-1.12 and mean within ±0.16, those of σ_e sd 0.85-1.10 and mean -0.07 to -0.36 (the masks drop a few bins for
being high). |z| ≤ 4 fails a correct estimator with probability ~1e-4 per assertion; 640 reseeded runs of the
parametrised test below and 15 reseedings of the others all passed. Beside that, σ_e within :data:`SIGMA_TOL` and
φ's se below :data:`MAX_PHI_SE`, so a band too narrow to say anything cannot pass by a wide se. The naive estimate
(lag-1 AR(1) of the same residual) is checked to fail the same tolerance, so each case can fail.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from scipy import signal

from bayesdamper.inference.noise import NoiseEstimate, combine, from_plateaus, rest_noise, spectral_noise
from bayesdamper.inference.plateau_noise import PlateauNoise, ar1_from_segments
from bayesdamper.inference.priors import PHI_BOUNDS

#: Tolerance in standard errors (false failure ~1e-4 per assertion for a calibrated se; measured sd 0.9-1.14).
K_SE = 4.0
#: σ_e within 8 %: 4 se for the shortest records here (se ≤ 2 %).
SIGMA_TOL = 0.08
#: The cases' records are long enough for se(φ) below this; a larger one means the band lost φ's information.
MAX_PHI_SE = 0.05


def ar1(rng: np.random.Generator, n: int, phi: float, sd: float) -> np.ndarray:
    """Stationary AR(1) noise of marginal sd ``sd`` [N]."""
    e = rng.normal(0.0, sd * math.sqrt(1.0 - phi * phi), n)
    return signal.lfilter([1.0], [1.0, -phi], e, zi=[phi * rng.normal(0.0, sd)])[0]


def naive(x: np.ndarray) -> tuple[float, float]:
    """Lag-1 AR(1) of the residual itself: (φ, σ_e [N])."""
    x = x - x.mean()
    r = float(x[1:] @ x[:-1] / (x @ x))
    return r, float(np.std(x)) * math.sqrt(1.0 - r * r)


def within(phi: float, sigma_e: float, phi_true: float, sigma_e_true: float, phi_se: float) -> bool:
    """φ within K_SE se, on its own scale and on log(1 − φ) (near 1 the scale that matters: 0.9997 is not 0.97,
    the marginal sd differs ten-fold), and σ_e within SIGMA_TOL."""
    log_ratio = abs(math.log((1.0 - phi) / (1.0 - phi_true)))
    return (abs(phi - phi_true) <= K_SE * phi_se and log_ratio <= K_SE * phi_se / (1.0 - phi_true)
            and abs(sigma_e / sigma_e_true - 1.0) <= SIGMA_TOL)


def slow_sine(rng, t, sd, fs):
    return 10.0 * sd * math.sqrt(2.0) * np.sin(2 * np.pi * 0.13 * t + rng.uniform(0, 2 * np.pi)), {}


def square(rng, t, sd, fs):
    return 5.0 * sd * np.tanh(np.sin(2 * np.pi * 1.0 * t + rng.uniform(0, 2 * np.pi)) / 0.05), {"fundamental_hz": 1.0}


def band_random(rng, t, sd, fs):
    sos = signal.butter(4, [0.3, 2.0], btype="band", fs=fs, output="sos")
    w = signal.sosfiltfilt(sos, rng.normal(size=t.size))
    return 10.0 * sd * w / w.std(), {"input_band_hz": (0.3, 2.0)}


CASES = [(slow_sine, 250.0, 40.0), (square, 100.0, 60.0), (square, 1000.0, 20.0), (band_random, 1000.0, 20.0)]


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.9, 0.97])
@pytest.mark.parametrize(("error", "fs", "seconds"), CASES, ids=lambda c: getattr(c, "__name__", str(c)))
def test_spectral_noise_sees_through_model_error(error, fs, seconds, phi):
    rng = np.random.default_rng(int(1000 * phi) + int(fs))
    sd = 5.0 if phi in (0.0, 0.9) else 30.0
    t = np.arange(int(fs * seconds)) / fs
    err, hints = error(rng, t, sd, fs)
    residual = ar1(rng, t.size, phi, sd) + err
    est = spectral_noise(residual, fs, **hints)
    sigma_e = sd * math.sqrt(1.0 - phi * phi)
    assert PHI_BOUNDS[0] <= est.phi <= PHI_BOUNDS[1]
    assert est.phi_se < MAX_PHI_SE, est.source
    assert within(est.phi, est.sigma_e, phi, sigma_e, est.phi_se), (est.phi, est.phi_se, est.sigma_e, est.source)
    assert abs(est.sigma_e / sigma_e - 1.0) <= K_SE * est.sigma_e_se / sigma_e
    phi_naive, sigma_e_naive = naive(residual)
    assert phi_naive > 0.93
    assert not within(phi_naive, sigma_e_naive, phi, sigma_e, est.phi_se)
    assert est.source.startswith("spectrum") and est.band_hz is not None and est.rate_hz == fs


def test_the_band_says_when_it_cannot_see_phi():
    """Band-limited error at 100 Hz, 3 x its 2 Hz top masked: φ = 0.97 has its knee at 0.5 Hz, below the usable
    band, so φ is barely determined there (its likelihood is flat towards 1 and the estimate lands anywhere from
    0.75 to the bound): the standard error must say so rather than pass a number for a measurement."""
    rng = np.random.default_rng(7)
    t = np.arange(4000) / 100.0
    err, hints = band_random(rng, t, 10.0, 100.0)
    est = spectral_noise(ar1(rng, t.size, 0.97, 10.0) + err, 100.0, **hints)
    assert est.band_hz[0] >= 6.0
    assert est.phi_se > 0.05  # the whole band would give 0.006
    assert abs(est.phi - 0.97) <= K_SE * est.phi_se
    assert abs(est.sigma_e / (10.0 * math.sqrt(1 - 0.97**2)) - 1.0) <= K_SE * est.sigma_e_se / est.sigma_e


def test_unlisted_line_and_phi_near_the_bounds():
    fs, n = 1000.0, 20000
    rng = np.random.default_rng(3)
    t = np.arange(n) / fs
    hum = 40.0 * np.sin(2 * np.pi * 50.0 * t)  # mains hum, 8 x the noise sd, nobody said
    est = spectral_noise(ar1(rng, n, 0.5, 5.0) + hum, fs)
    assert "unlisted line" in est.source and abs(est.phi - 0.5) <= K_SE * est.phi_se
    for phi in (0.995, -0.4):
        est = spectral_noise(ar1(rng, n, phi, 10.0), fs)
        assert abs(est.phi - phi) <= K_SE * est.phi_se, (phi, est.phi, est.phi_se)
    walk = np.cumsum(rng.normal(size=n))  # φ = 1: outside the prior, the estimate stays inside
    est = spectral_noise(walk, fs)
    assert PHI_BOUNDS[0] <= est.phi <= PHI_BOUNDS[1] and est.phi > 0.99 and math.isfinite(est.sigma)


def test_quantisation_shows_up_as_white_noise():
    """ADC steps of q on a moving signal add q²/12: σ is sqrt(σ_n² + q²/12), not σ_n."""
    fs, n, q = 250.0, 10000, 10.0
    rng = np.random.default_rng(5)
    t = np.arange(n) / fs
    force = 300.0 * np.sin(2 * np.pi * 0.7 * t)
    measured = q * np.round((force + rng.normal(0.0, 5.0, n)) / q)
    est = spectral_noise(measured - force, fs, fundamental_hz=0.7)
    rel_se = K_SE * est.sigma_e_se / est.sigma_e
    assert abs(est.sigma / math.sqrt(25.0 + q * q / 12.0) - 1.0) <= rel_se
    assert abs(est.sigma / 5.0 - 1.0) > rel_se


def test_fallbacks_are_stated():
    rng = np.random.default_rng(11)
    short = spectral_noise(rng.normal(0.0, 10.0, 60), 100.0)  # 60 samples: under MIN_BINS bins
    assert short.phi == 0.0 and math.isinf(short.phi_se) and "first differences" in short.source
    assert abs(short.sigma_e - 10.0) <= K_SE * short.sigma_e_se
    t = np.arange(200) / 100.0  # two cycles of a 1 Hz test: every bin is a harmonic or next to one, but the
    # cycles differ only by the noise (this record fell back to the differences while every harmonic was masked)
    few = spectral_noise(rng.normal(0.0, 5.0, 200) + 25.0 * np.tanh(np.sin(2 * np.pi * t) / 0.05), 100.0,
                         fundamental_hz=1.0)
    assert "2 cycles about their mean" in few.source and math.isfinite(few.phi_se)
    assert abs(few.phi) <= K_SE * few.phi_se and abs(few.sigma_e - 5.0) <= K_SE * few.sigma_e_se
    wide = spectral_noise(rng.normal(0.0, 5.0, 2000), 100.0, input_band_hz=(1.0, 20.0))  # 3 x 20 Hz > Nyquist
    assert "first differences" in wide.source and "usable bins" in wide.source and "too short" in wide.source
    flat = spectral_noise(np.full(500, 3.0), 100.0)
    assert flat.sigma_e == 0.0 and "no scatter" in flat.source
    with pytest.raises(ValueError):
        spectral_noise(np.array([1.0, np.nan, 2.0, 3.0]), 100.0)
    with pytest.raises(ValueError):
        spectral_noise(rng.normal(size=500), 100.0, fundamental_hz=60.0)


def v_abs_v(rng, theta, sd):
    """Smooth periodic model error: an orifice law's v|v| with a linear and a second-harmonic part (harmonics at
    k = 1, 2, 3, 5, 7 ..., the odd ones falling as k⁻³), rms 10 x the noise sd."""
    f = np.sin(theta) * np.abs(np.sin(theta)) + 0.4 * np.cos(theta + 0.7) + 0.15 * np.sin(2.0 * theta)
    return 10.0 * sd * f / f.std()


def friction(rng, theta, sd):
    """Dry friction under a sine: a square wave 5 x the noise sd, harmonics falling as 1/k up to k ~ 20."""
    return 5.0 * sd * np.tanh(np.sin(theta) / 0.05)


#: Windows of whole cycles as the identification cuts them: (cycles, fundamental [Hz], rate [Hz]); the last has a
#: period of 1041.67 samples, so its cycles start up to half a sample off the grid (turned back in phase).
WINDOWS = [(1, 0.05, 100.0), (2, 0.1, 250.0), (4, 0.12, 125.0)]
#: Every window with pure noise, the smooth and the friction error, at every φ; but one cycle of friction over the
#: noise's AR(1) knee (φ ≥ 0.9 here), which cannot be read (test_one_cycle_of_friction_looks_like_a_larger_phi).
CYCLE_CASES = [pytest.param(*w, e, phi, id=f"{w[0]} cycle(s)-{getattr(e, '__name__', 'noise')}-{phi}")
               for w in WINDOWS for e in (None, v_abs_v, friction) for phi in (0.0, 0.5, 0.9, 0.97)
               if not (w[0] == 1 and e is friction and phi >= 0.9)]


@pytest.mark.parametrize(("cycles", "f0", "fs", "error", "phi"), CYCLE_CASES)
def test_windows_of_whole_cycles(cycles, f0, fs, error, phi):
    """Windows of 1, 2 and 4 whole cycles of a slow sine (every periodogram bin a harmonic or next to one): the
    pure-noise residual of an exact model, and one with periodic model error, the fundamental given. One cycle
    is read with the harmonics excluded where in excess of the noise, two or more cycle against cycle; none
    falls back to the differences (φ = 0 assumed). Reseeded 40 times per case (1360 runs): z of φ mean -0.31 to
    +0.33, sd 0.75-1.18; z of σ_e mean -0.51 to +0.33, sd 0.71-1.33. 12 runs failed an assertion: 8 by a false
    stop of the low-edge search tens of Hz up (step 4 tests each block at its own level: 1-3 % of records of this
    length stop falsely, whole records as well, and φ is then undetermined), 1 where that left the two cycles no
    bins (the excess rule then recovered φ), 3 by |z| = 3.4-3.6 read on log(1 − φ)."""
    rng = np.random.default_rng([cycles, int(1000 * phi), 0 if error is None else 1 + (error is friction)])
    sd = 5.0 if phi in (0.0, 0.9) else 30.0
    n = int(round(cycles * fs / f0))
    theta = 2.0 * np.pi * f0 * np.arange(n) / fs + rng.uniform(0.0, 2.0 * np.pi)
    residual = ar1(rng, n, phi, sd) + (0.0 if error is None else error(rng, theta, sd))
    est = spectral_noise(residual, fs, fundamental_hz=f0)
    sigma_e = sd * math.sqrt(1.0 - phi * phi)
    assert est.source.startswith("spectrum") and math.isfinite(est.phi_se), est.source
    assert ("cycles about their mean" in est.source) == (cycles >= 2), est.source
    assert est.phi_se < MAX_PHI_SE, est.source
    assert within(est.phi, est.sigma_e, phi, sigma_e, est.phi_se), (est.phi, est.phi_se, est.sigma_e, est.source)
    assert abs(est.sigma_e / sigma_e - 1.0) <= K_SE * est.sigma_e_se / sigma_e
    if error is not None:
        phi_naive, sigma_e_naive = naive(residual)
        assert phi_naive > 0.93
        assert not within(phi_naive, sigma_e_naive, phi, sigma_e, est.phi_se)


@pytest.mark.xfail(strict=True, reason="one cycle cannot tell a 1/k harmonic series over the AR(1) knee from a "
                                       "larger φ (module docstring, Periodic records c)")
def test_one_cycle_of_friction_looks_like_a_larger_phi():
    """One 20 s cycle at 100 Hz, φ = 0.9 (knee at bin 32 of 1000), friction's harmonics above the noise to bin ~25:
    the periodogram is that of an AR(1) with φ ~ 0.99 to within its scatter (79 of 100 seeds outside the
    tolerance, mean z +5.7). At φ = 0.97 (knee at bin 10) 3 of 100 are, and the se exceeds MAX_PHI_SE in 1 of
    10, so neither is in test_windows_of_whole_cycles; two cycles of the same test: 0 of 100."""
    rng = np.random.default_rng(9)
    n, sd = 2000, 5.0
    theta = 2.0 * np.pi * 0.05 * np.arange(n) / 100.0 + rng.uniform(0.0, 2.0 * np.pi)
    est = spectral_noise(ar1(rng, n, 0.9, sd) + friction(rng, theta, sd), 100.0, fundamental_hz=0.05)
    assert within(est.phi, est.sigma_e, 0.9, sd * math.sqrt(1.0 - 0.81), est.phi_se), (est.phi, est.phi_se)


@pytest.mark.parametrize(("phi", "length", "count"), [(0.0, 400, 6), (0.5, 400, 6), (0.9, 400, 6), (0.97, 1500, 4)])
def test_rest_noise_recovers_phi(phi, length, count):
    rng = np.random.default_rng(int(100 * phi))
    segs = [ar1(rng, length, phi, 10.0) + rng.normal(0.0, 200.0) for _ in range(count)]
    est = rest_noise(segs)
    sigma_e = 10.0 * math.sqrt(1.0 - phi * phi)
    assert est.source == f"rest, {length * count} samples in {count} stretch(es), mean removed"
    assert within(est.phi, est.sigma_e, phi, sigma_e, est.phi_se), (est.phi, est.phi_se, est.sigma_e)
    assert est.phi == pytest.approx(ar1_from_segments(segs).phi, abs=1e-9)


def test_rest_noise_with_a_relaxing_force():
    """A force still relaxing at rest: a line per stretch. Removing only the mean reads the drift as colour;
    removing the line, with the bias of its removal corrected, recovers φ."""
    rng = np.random.default_rng(21)
    phi, sd, n = 0.5, 10.0, 400
    segs = [ar1(rng, n, phi, sd) + 100.0 + np.linspace(0.0, rng.choice([-1, 1]) * 25.0, n) for _ in range(6)]
    lin, mean = rest_noise(segs, detrend="linear"), rest_noise(segs)
    assert within(lin.phi, lin.sigma_e, phi, sd * math.sqrt(1 - phi**2), lin.phi_se)
    assert mean.phi - phi > K_SE * mean.phi_se
    # the line's bias correction: over 50 seeds of short, coloured stretches the mean z is ~0 (uncorrected: -1.6)
    z = []
    for seed in range(50):
        r = np.random.default_rng(seed)
        e = rest_noise([ar1(r, 100, 0.9, sd) for _ in range(8)], detrend="linear")
        z.append((e.phi - 0.9) / e.phi_se)
    assert abs(np.mean(z)) < 0.6  # sd of the mean 0.18


def test_rest_noise_without_information():
    assert rest_noise([np.full(300, 120.0), np.full(200, 80.0)]) is None  # the quantiser reads a constant
    assert rest_noise([np.arange(4.0)]) is None
    with pytest.raises(ValueError):
        rest_noise([np.zeros(10)], detrend="quadratic")


def test_combine_pools_windows_of_one_sensor():
    fs, rng = 250.0, np.random.default_rng(31)
    t = np.arange(5000) / fs
    parts = []
    for _ in range(4):
        err, hints = square(rng, t, 8.0, fs)
        parts.append(spectral_noise(ar1(rng, t.size, 0.9, 8.0) + err, fs, **hints))
    pooled = combine(parts)
    w = np.array([p.phi_se for p in parts]) ** -2.0
    assert pooled.phi == pytest.approx(float(np.sum(w * [p.phi for p in parts]) / w.sum()))
    assert pooled.phi_se == pytest.approx(w.sum() ** -0.5)
    assert pooled.phi_se < min(p.phi_se for p in parts)
    assert within(pooled.phi, pooled.sigma_e, 0.9, 8.0 * math.sqrt(1 - 0.81), pooled.phi_se)
    assert pooled.n_samples == 4 * t.size and pooled.rate_hz == fs and "pooled from 4" in pooled.source
    assert "disagree" not in pooled.source
    assert combine([parts[0]]) is parts[0]
    fallback = spectral_noise(rng.normal(0.0, 50.0, 60), fs)
    assert combine([parts[0], fallback]) is parts[0]  # an assumed φ adds nothing
    other = NoiseEstimate(0.2, 3.0, 5000, "spectrum", phi_se=0.01, sigma_e_se=0.03, rate_hz=fs)
    assert "disagree" in combine([parts[0], other]).source
    with pytest.raises(ValueError):
        combine([parts[0], NoiseEstimate(0.9, 3.0, 100, "spectrum", rate_hz=500.0)])
    plateau = from_plateaus(PlateauNoise(0.9, 3.5, 2000, 10), rate_hz=fs)
    assert "plateaus" in combine([parts[0], plateau]).source


def test_as_dict_is_json_with_the_plateau_keys():
    est = spectral_noise(np.random.default_rng(2).normal(0.0, 4.0, 3000), 200.0)
    d = est.as_dict()
    json.dumps(d, allow_nan=False)
    plateau_keys = set(PlateauNoise(0.5, 1.0, 100, 2).as_dict()) - {"n_plateaus"}
    assert plateau_keys <= set(d) and d["band_Hz"] == list(est.band_hz)
    assert d["sigma_N"] == pytest.approx(est.sigma_e / math.sqrt(1 - est.phi**2))
    json.dumps(spectral_noise(np.arange(50.0) % 7, 100.0).as_dict(), allow_nan=False)  # phi_se inf -> None


def test_speed_of_a_long_record():
    """60 000 samples at 1 kHz (the longest record the whole-record path keeps) in well under a second or two."""
    rng = np.random.default_rng(4)
    t = np.arange(60000) / 1000.0
    err, hints = square(rng, t, 10.0, 1000.0)
    start = time.perf_counter()
    est = spectral_noise(ar1(rng, t.size, 0.9, 10.0) + err, 1000.0, **hints)
    assert time.perf_counter() - start < 3.0
    assert abs(est.phi - 0.9) <= K_SE * est.phi_se
