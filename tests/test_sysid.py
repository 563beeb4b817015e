"""Residual system identification (bayesdamper.diagnosis.sysid) on data with known dynamics.

Every data set is generated here with scipy.signal (``lsim`` of a known continuous system), never by the
module under test. Transients come in groups ("speeds") with different driver amplitudes and shapes;
each starts where a random input history left the system (a different initial state for each).

Seeds: every seed here lies in 2000-2099 and was fixed before the test first ran with it. The practical
floor of the selection rule was calibrated on seeds 1000-1099 (benchmarks/sysid_floor.py, which this file
does not import); seeds 0-31 and 100-109 were looked at while the module was written and are not used.
Interval coverage is judged over a fixed block of seeds against a binomial bound, never on one seed.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import signal, stats

from bayesdamper.core.errors import DataError, SettingsError
from bayesdamper.diagnosis.sysid import (
    PoleEstimate,
    TransientSignals,
    _summary,
    cross_correlation,
    identify_residual_dynamics,
)

#: Sampling rate of the synthetic records [Hz] (decimated by 10 to the module's default 50 Hz).
FS = 500.0
#: Length of a transient and of the input history before it that sets its initial state [s].
DURATION_S = 8.0
HISTORY_S = 2.0
#: Test speeds (driver amplitude factors) = leave-one-group-out groups, two transients each.
SPEEDS = (0.5, 1.0, 2.0, 4.0)
PER_GROUP = 2
#: Driver: random steps (6 per record) smoothed by a 2nd-order low-pass at this corner [Hz].
N_STEPS = 6
DRIVER_CORNER_HZ = 5.0
#: White measurement noise [N] as a fraction of the RMS noise-free response at speed 1.
NOISE_FRACTION = 1.0
#: Scale of the pressure driver [Pa per unit speed] and the true gain of the residual on it [N/Pa].
DP_SCALE = 2e5
DP_GAIN = 1e-4
#: Seeds of the single-data-set tests and the blocks of the interval-coverage tests (module docstring).
SEED_SECOND_ORDER, SEED_ABS_LAW, SEED_DISTRACTOR, SEED_NOISE, SEED_ERA, SEED_CC_BAND, SEED_CC_FAR = range(2000, 2007)
COVERAGE_SEEDS_SECOND_ORDER = range(2010, 2030)
COVERAGE_SEEDS_FIRST_ORDER = range(2030, 2050)
#: Nominal level of the module's intervals and the lower-tail probability of the coverage tests: a
#: block of N seeds fails only if its coverage count is below the 0.5 % quantile of Binomial(N, 0.9).
LEVEL = 0.90
COVERAGE_TAIL = 0.005


def second_order(f_hz: float, zeta: float, gain: float = 1.0) -> signal.lti:
    w = 2 * math.pi * f_hz
    return signal.lti([gain * w**2], [1.0, 2 * zeta * w, w**2])


def smooth_steps(rng: np.random.Generator, t: np.ndarray, amplitude: float) -> np.ndarray:
    u = np.zeros_like(t)
    for t_step, level in zip(rng.uniform(t[0], t[-1], N_STEPS), rng.normal(0.0, amplitude, N_STEPS), strict=True):
        u += level * (t >= t_step)
    return signal.filtfilt(*signal.butter(2, DRIVER_CORNER_HZ, fs=FS), u)


def make_transients(system: signal.lti, seed: int, law=lambda u: u, distractor=None) -> list[TransientSignals]:
    """Residual = system(law(u)) + white noise, driver ``u``, plus ``tau`` [s] and an independent ``w``."""
    rng = np.random.default_rng(seed)
    t = np.arange(int((HISTORY_S + DURATION_S) * FS)) / FS
    keep = t >= HISTORY_S
    records = []
    for speed in SPEEDS:
        for j in range(PER_GROUP):
            u = smooth_steps(rng, t, speed)
            y = signal.lsim(system, law(u), t)[1][keep]
            drivers = {"u": u[keep], "tau": t[keep] - HISTORY_S, "w": smooth_steps(rng, t, speed)[keep]}
            if distractor is not None:
                drivers["d"] = distractor(u[keep], speed, rng)
            records.append((f"{speed}-{j}", f"{speed}mm/s", y, drivers))
    noise = NOISE_FRACTION * np.sqrt(np.mean(np.concatenate([y for _, g, y, _ in records if g == "1.0mm/s"]) ** 2))
    return [TransientSignals(i, g, 1 / FS, y + rng.normal(0.0, noise, y.size), d) for i, g, y, d in records]


def dp_driver(data: list[TransientSignals]) -> list[TransientSignals]:
    """The driver ``u`` as a pressure difference ``dp`` [Pa] (the module must cope with its scale)."""
    return [TransientSignals(x.id, x.group, x.dt, x.residual,
                             {"dp": x.drivers["u"] * DP_SCALE, "tau": x.drivers["tau"], "w": x.drivers["w"]})
            for x in data]


def min_covered(n: int) -> int:
    """Smallest coverage count of n calibrated intervals not rejected: the 0.5 % quantile of Bin(n, 0.9)."""
    return int(stats.binom.ppf(COVERAGE_TAIL, n, LEVEL))


def covers(interval, truth) -> bool:
    return interval is not None and interval[0] <= truth <= interval[1]


def test_a_pole_whose_interval_reaches_zero_is_reported_as_not_resolved():
    """A pole whose frequency (pair) or time constant (real) interval reaches 0 cannot be told from no pole: the
    summary says so beside it. The unresolved poles are rig-A's, as measured: a well-damped pair at 40 Hz with a
    frequency interval of [-338, 418] Hz and a 0.026 s time constant with [-0.012, 0.063] s."""
    data = dp_driver(make_transients(second_order(1.7, 0.25, DP_GAIN * DP_SCALE), seed=SEED_SECOND_ORDER))
    res = identify_residual_dynamics(data)
    (pole,) = res.fit.poles
    assert pole.resolved
    loose = PoleEstimate("oscillatory", 39.96, (-338.4, 418.3), 0.78, (-3.97, 5.53))
    fast = PoleEstimate("real", time_constant_s=0.0256, time_constant_interval=(-0.0118, 0.0631))
    slow = PoleEstimate("real", time_constant_s=0.825, time_constant_interval=(0.255, 1.395))
    assert not loose.resolved and not fast.resolved and slow.resolved
    assert PoleEstimate("real", time_constant_s=0.5).resolved  # no interval: nothing claimed
    assert loose.as_dict()["resolved"] is False and slow.as_dict()["resolved"] is True  # diagnosis.json has it
    assert res.as_dict()["fit"]["poles"][0]["resolved"] is True
    text = _summary(dataclasses.replace(res.fit, poles=(pole, loose, slow, fast)), res.chosen, res.chosen)
    assert text.count("not resolved") == 2
    assert f"{pole.frequency_hz:.3g} Hz, damping {pole.damping:.2f}; 40 Hz, damping 0.78 (not resolved" in text
    assert "time constant 0.825 s; time constant 0.0256 s (not resolved: its 90 % interval reaches 0)," in text


def test_second_order_linear_driver_is_identified():
    f_true, zeta_true = 1.7, 0.25
    data = dp_driver(make_transients(second_order(f_true, zeta_true, DP_GAIN * DP_SCALE), seed=SEED_SECOND_ORDER))
    res = identify_residual_dynamics(data)
    assert res.verdict == "dynamics"
    assert (res.fit.driver, res.fit.law, res.fit.order) == ("dp", "linear", 2)
    (pole,) = res.fit.poles
    assert pole.kind == "oscillatory"
    # the estimate is within ~5 SE of the truth (3 half-widths of its 90 % interval); that the interval
    # covers it at its level is tested below over a block of seeds
    half = (pole.frequency_interval[1] - pole.frequency_interval[0]) / 2
    assert abs(pole.frequency_hz - f_true) < 3 * half
    assert res.summary.startswith(f"unnamed dynamics: {pole.frequency_hz:.3g} Hz, damping {pole.damping:.2f}")
    assert "driven by dp (linear), order 2" in res.summary
    assert res.runner_up is not None and (res.runner_up.driver, res.runner_up.law) != ("dp", "linear")
    assert len(res.candidates) == 3 * 4 * 4  # drivers x laws x orders, every one scored
    json.dumps(res.as_dict())  # plain types only


def test_second_order_intervals_cover_the_truth_at_their_level():
    # A 90 % interval misses the truth for one data set in ten, so one seed passes or fails by luck (and
    # replacing a seed after a miss tunes the test to its data). Instead: a fixed block of N seeds, the
    # structure given (its selection is tested above); with calibrated intervals each count is
    # Binomial(N, 0.9), rejected only below its 0.5 % quantile (N = 20: at least 14 covered; a correct
    # module fails one of the three counts with probability < 1 %). Measured on this block: frequency
    # 16/20, damping 17/20, DC gain 19/20.
    f_true, zeta_true = 1.7, 0.25
    counts = np.zeros(3, int)
    for seed in COVERAGE_SEEDS_SECOND_ORDER:
        data = dp_driver(make_transients(second_order(f_true, zeta_true, DP_GAIN * DP_SCALE), seed=seed))
        fit = identify_residual_dynamics(data, drivers=["dp"], laws=["linear"], orders=[2], level=LEVEL).fit
        pole = fit.poles[0] if fit is not None else None
        if pole is None or pole.kind != "oscillatory":
            continue
        counts += [covers(pole.frequency_interval, f_true), covers(pole.damping_interval, zeta_true),
                   covers(fit.dc_gain_interval, DP_GAIN)]
    assert np.all(counts >= min_covered(len(COVERAGE_SEEDS_SECOND_ORDER))), counts


def test_first_order_on_abs_law():
    tau_true = 0.3
    res = identify_residual_dynamics(make_transients(signal.lti([1.0], [tau_true, 1.0]), seed=SEED_ABS_LAW,
                                                     law=np.abs), drivers=["u", "w"])
    assert (res.fit.driver, res.fit.law, res.fit.order) == ("u", "abs", 1)
    (pole,) = res.fit.poles
    assert pole.kind == "real"


def test_first_order_intervals_cover_the_truth_at_their_level():
    # as for the second order: a fixed block of N = 20 seeds, structure given, count >= the 0.5 % quantile
    # of Binomial(20, 0.9) = 14. Measured on this block: time constant 15/20.
    tau_true = 0.3
    covered = 0
    for seed in COVERAGE_SEEDS_FIRST_ORDER:
        fit = identify_residual_dynamics(make_transients(signal.lti([1.0], [tau_true, 1.0]), seed=seed, law=np.abs),
                                         drivers=["u"], laws=["abs"], orders=[1], level=LEVEL).fit
        covered += fit is not None and fit.poles[0].kind == "real" and covers(fit.poles[0].time_constant_interval,
                                                                              tau_true)
    assert covered >= min_covered(len(COVERAGE_SEEDS_FIRST_ORDER)), covered


def test_correlated_distractor_is_rejected_out_of_sample():
    # "d" follows u within every transient (correlation > 0.95) but with a gain that changes with speed,
    # as a signal computed with a wrong speed law would: only held-out groups can tell it from the cause
    def distractor(u, speed, rng):
        return u * (1.0 + 0.5 * math.log2(speed)) + 0.05 * speed * smooth_steps(rng, np.arange(u.size) / FS, 1.0)

    data = make_transients(second_order(1.7, 0.25), seed=SEED_DISTRACTOR, distractor=distractor)
    assert min(np.corrcoef(x.drivers["u"], x.drivers["d"])[0, 1] for x in data) > 0.95
    res = identify_residual_dynamics(data, drivers=["d", "u"])
    assert (res.fit.driver, res.fit.law, res.fit.order) == ("u", "linear", 2)
    best_d = min(c.score for c in res.candidates if c.driver == "d")
    assert best_d > res.chosen.score + res.chosen.score_se


def test_pure_noise_gives_verdict_none():
    rng = np.random.default_rng(SEED_NOISE)
    data = [TransientSignals(x.id, x.group, x.dt, rng.normal(0.0, 1.0, x.residual.size), x.drivers)
            for x in make_transients(second_order(1.7, 0.25), seed=SEED_NOISE)]
    res = identify_residual_dynamics(data, drivers=["u", "tau"])
    assert res.verdict == "none" and res.fit is None and res.chosen is None
    assert res.runner_up.score >= 1 - res.runner_up.score_se
    assert res.summary.startswith("no dynamics found")


# --------------------------------------------------------------------------- independent method: ERA
def era_poles(markov: np.ndarray, order: int, dt: float, rows: int = 40) -> np.ndarray:
    """Eigensystem Realization Algorithm (Juang & Pappa 1985) for a single-input single-output system.

    ``markov[k]`` = h(k) (k >= 1) the impulse response samples; H0[i, j] = h(i + j + 1), H1 = h(i + j + 2);
    H0 = U Σ V', truncated to ``order``; A = Σ^-1/2 U' H1 V Σ^-1/2; continuous poles s = ln(eig A) / dt.
    """
    h = markov[1:]
    H0 = np.array([[h[i + j] for j in range(rows)] for i in range(rows)])
    H1 = np.array([[h[i + j + 1] for j in range(rows)] for i in range(rows)])
    U, s, Vt = np.linalg.svd(H0)
    root = np.diag(1 / np.sqrt(s[:order]))
    A = root @ U[:, :order].T @ H1 @ Vt[:order].T @ root
    return np.log(np.linalg.eigvals(A).astype(complex)) / dt


#: ERA and the module may differ by 0.5 % in frequency and 0.005 in damping. With noise of 0.5 % of the
#: step, averaged over 8 transients, ERA on the un-filtered, sub-sampled mean step response is off by
#: ~0.1 % / 0.001 (measured on its seed: 0.006 % / 1.4e-4) and the module's 90 % intervals are narrower
#: still (checked below): the tolerance is a 5x margin on the cruder of the two methods.
ERA_FREQ_RTOL = 0.005
ERA_DAMPING_ATOL = 0.005


def test_poles_agree_with_the_eigensystem_realization_algorithm():
    fs = 1234.5  # off-integer rate: the module decimates by 24 to 51.44 Hz
    f_true, zeta_true, step_at = 2.3, 0.15, 1.0
    sys_ = second_order(f_true, zeta_true)
    rng = np.random.default_rng(SEED_ERA)
    t = np.arange(int(6.0 * fs)) / fs
    data, steps = [], []
    for speed in SPEEDS:
        for j in range(PER_GROUP):
            amp = speed * rng.uniform(0.8, 1.2)
            u = amp * (t >= step_at)
            y = signal.lsim(sys_, u, t, interp=False)[1]  # zero-order hold: an exact step at a sample
            y += rng.normal(0.0, 0.005 * amp, t.size)
            data.append(TransientSignals(f"{speed}-{j}", f"{speed}", 1 / fs, y, {"u": u}))
            steps.append(y / amp)
    res = identify_residual_dynamics(data, laws=["linear"])
    assert res.fit.order == 2
    (pole,) = res.fit.poles

    # ERA on the step-aligned mean unit-step response, sampled every 24th sample from the step:
    # with a held input the differences of step-response samples are the Markov parameters
    k0, every = int(np.argmax(t >= step_at)), 24
    mean_step = np.mean(steps, axis=0)[k0::every]
    s_era = era_poles(np.diff(mean_step, prepend=0.0), 2, every / fs)
    w_era = np.sqrt((s_era[0] * s_era[1]).real)
    f_era, zeta_era = w_era / (2 * math.pi), -(s_era[0] + s_era[1]).real / (2 * w_era)

    assert f_era == pytest.approx(pole.frequency_hz, rel=ERA_FREQ_RTOL)
    assert zeta_era == pytest.approx(pole.damping, abs=ERA_DAMPING_ATOL)
    assert f_era == pytest.approx(f_true, rel=ERA_FREQ_RTOL)
    assert pole.frequency_interval[1] - pole.frequency_interval[0] < ERA_FREQ_RTOL * f_true
    assert pole.damping_interval[1] - pole.damping_interval[0] < ERA_DAMPING_ATOL


# ------------------------------------------------------------------------------------ cross-correlation
#: Largest lag of the band checks, the lags counted (50 apart: for two AR(1) series with phi = 0.9 the
#: correlation of ρ_ru at lags 50 apart is ~0.03, so the counts are close to independent), the number of
#: independent (residual, driver) pairs, and the two-sided probability of the binomial acceptance region.
MAX_LAG = 200
COUNTED_LAGS = (0, 50, 100, 150, 200)
REPLICATES = 100
BINOMIAL_CONFIDENCE = 0.999


@pytest.mark.parametrize("phi", [0.0, 0.9])
def test_cross_correlation_band_holds_about_5_percent_under_independence(phi):
    # independent residual and driver, white (phi = 0) or both AR(1) (phi = 0.9, where the uncorrected
    # band 1.96/sqrt(N) would be far too narrow). The count outside the band is Binomial(n, 0.05) only for
    # nearly independent ρ_ru values: neighbouring lags of one pair are not (for phi = 0.9 they move
    # together, and a count over all 201 lags of a few pairs is far more variable than binomial, so
    # whether it passed depended on the seed). Hence few, widely spaced lags of many independent pairs.
    rng = np.random.default_rng(SEED_CC_BAND)
    outside = 0
    for _ in range(REPLICATES):
        r, u = (signal.lfilter([1.0], [1.0, -phi], rng.normal(size=4000)) for _ in range(2))
        cc = cross_correlation(r, u, MAX_LAG)
        outside += int(np.sum(np.abs(np.take(cc.ccf, COUNTED_LAGS)) > cc.band))
    lo, hi = stats.binom.interval(BINOMIAL_CONFIDENCE, REPLICATES * len(COUNTED_LAGS), 0.05)
    assert lo <= outside <= hi, outside
    if phi:
        assert cc.n_eff < 0.2 * cc.n  # Bartlett: N_eff = N (1 - phi^2) / (1 + phi^2) ~ 0.1 N


def test_cross_correlation_of_a_residual_made_from_the_driver_is_far_outside():
    rng = np.random.default_rng(SEED_CC_FAR)
    u = signal.lfilter([1.0], [1.0, -0.9], rng.normal(size=4000))
    r = signal.lfilter([0.0, 0.5], [1.0, -0.8], u) + rng.normal(0.0, 1.0, u.size)
    cc = cross_correlation([r[:2000], r[2000:]], [u[:2000], u[2000:]], 20)
    assert cc.max_ratio > 5 and cc.fraction_outside == 1.0


# ------------------------------------------------------------------------------------------ bad input
def _good(n=400, group="a"):
    return TransientSignals("x", group, 0.02, np.sin(np.arange(n) / 7.0), {"u": np.cos(np.arange(n) / 7.0)})


@pytest.mark.parametrize("case, error, words", [
    ([_good(), TransientSignals("y", "b", 0.02, np.ones(400), {"u": np.ones(399)})], DataError, "as long as"),
    ([_good(), TransientSignals("y", "b", 0.02, np.r_[np.nan, np.ones(399)], {"u": np.ones(400)})], DataError,
     "finite"),
    ([_good(), _good()], DataError, "at least 2 groups"),
    ([_good(), TransientSignals("y", "b", 0.02, np.ones(400), {"v": np.ones(400)})], DataError, "common"),
    ([], DataError, "no transients"),
])
def test_bad_transients_raise_one_line_errors(case, error, words):
    with pytest.raises(error, match=words) as err:
        identify_residual_dynamics(case)
    assert "\n" not in str(err.value)


def test_bad_settings_raise_one_line_errors():
    data = [_good(), _good(group="b")]
    for kwargs in ({"orders": [5]}, {"laws": ["cubic"]}, {"rate_hz": 0.0}, {"level": 1.5}):
        with pytest.raises(SettingsError) as err:
            identify_residual_dynamics(data, **kwargs)
        assert "\n" not in str(err.value)
    with pytest.raises(DataError, match="matching lengths"):
        cross_correlation(np.ones(10), np.ones(9), 3)
    with pytest.raises(SettingsError, match="max_lag"):
        cross_correlation(np.arange(10.0), np.arange(10.0), 10)
