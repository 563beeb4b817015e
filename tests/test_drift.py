"""Drift of a parameter with speed: slope posterior with per-transient uncertainty propagated."""

import numpy as np
import pytest

from bayesdamper.inference.drift import fit_drift

SPEEDS = np.repeat(np.linspace(0.5e-3, 1.5e-3, 11), 3)


def test_recovers_known_slope_within_interval():
    rng = np.random.default_rng(0)
    sd = np.full(SPEEDS.size, 2.0)
    m = 50.0 - 2.0e4 * SPEEDS + sd * rng.standard_normal(SPEEDS.size)
    res = fit_drift(SPEEDS, m, sd, 0.9, seed=1)
    s = res["slope_per_m_s"]
    assert s["lo"] < -2.0e4 < s["hi"]
    assert res["credible_nonzero"]


def test_flat_trend_is_not_credibly_nonzero_in_most_replicates():
    """With no trend, a 90 % interval excludes 0 in ~10 % of data sets; allow up to 25 % of 40."""
    rng = np.random.default_rng(2)
    flags = []
    for _ in range(40):
        sd = rng.uniform(1.0, 3.0, SPEEDS.size)
        m = 30.0 + sd * rng.standard_normal(SPEEDS.size)
        flags.append(fit_drift(SPEEDS, m, sd, 0.9, seed=3)["credible_nonzero"])
    assert np.mean(flags) <= 0.25


def test_intrinsic_scatter_widens_the_interval():
    """Points scattered far beyond their error bars must not give an overconfident slope."""
    rng = np.random.default_rng(4)
    sd = np.full(SPEEDS.size, 0.1)
    m_tight = 30.0 + sd * rng.standard_normal(SPEEDS.size)
    m_wide = 30.0 + 5.0 * rng.standard_normal(SPEEDS.size)
    w_tight = np.diff([fit_drift(SPEEDS, m_tight, sd)["slope_per_m_s"][k] for k in ("lo", "hi")])[0]
    w_wide = np.diff([fit_drift(SPEEDS, m_wide, sd)["slope_per_m_s"][k] for k in ("lo", "hi")])[0]
    assert w_wide > 10 * w_tight
    assert fit_drift(SPEEDS, m_wide, sd)["intrinsic_scatter"] == pytest.approx(5.0, rel=0.5)


def test_needs_three_points_at_two_speeds():
    with pytest.raises(ValueError):
        fit_drift(np.array([1e-3, 1e-3, 1e-3]), np.ones(3), np.ones(3))


def test_drift_summary_leaves_out_posteriors_at_a_prior_bound_when_enough_remain():
    """A posterior piled against a prior bound has a mean set by the box: left out of the trend, unless that
    leaves fewer than three transients at two speeds (then the converged ones are used, as before)."""
    from bayesdamper.inference.drift import drift_summary

    def entry(v, at_bound):
        mean = 1e9 if at_bound else 40.0 + 1e4 * v  # an at-bound mean far off the trend
        return {"velocity_m_s": v, "converged": True, "shape": {"at_prior_bound": at_bound}, "direction": 1,
                "posterior_mean": {"alpha_V": mean, "p_R_Pa": 3e5}, "posterior_sd": {"alpha_V": 1.0, "p_R_Pa": 1e4}}

    four = [entry(1.0e-3, False), entry(1.2e-3, False), entry(1.4e-3, True), entry(1.5e-3, False)]
    d = drift_summary(four, 0.9, 0)["alpha_V"]
    assert d["n_transients"] == 3
    assert abs(d["slope_per_m_s"]["median"] - 1e4) < 0.05 * 1e4
    two_left = [entry(1.0e-3, False), entry(1.2e-3, True), entry(1.4e-3, True), entry(1.5e-3, False)]
    assert drift_summary(two_left, 0.9, 0)["alpha_V"]["n_transients"] == 4
