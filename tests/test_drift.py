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


def _cycle_entries(test: str, n: int, value, sd: float, rng, converged: bool = True) -> list[dict]:
    """Entries of ``n`` windows of cycles of one 120 s record; ``value(t_mid)`` the true C_L12 at the window's
    middle, observed with posterior sd ``sd``; α_V constant."""
    out = []
    for k in range(n):
        t0, t1 = 120.0 * k / n, 120.0 * (k + 1) / n
        mid = 0.5 * (t0 + t1)
        out.append({"id": f"{test}_w{k}", "test": test, "kind": "cycles", "converged": converged,
                    "t_start_s": t0, "window": {"t_end_s": t1},
                    "posterior_mean": {"alpha_V": 40.0 + rng.normal(0.0, 1.0), "C_L12": value(mid) + rng.normal(0, sd)},
                    "posterior_sd": {"alpha_V": 1.0, "C_L12": sd}})
    return out


def test_slow_drift_within_a_record_is_found_against_time_and_temperature():
    """A flow coefficient falling 20 % over a 120 s record (the fluid warming from 30 to 50 °C), eight windows with
    posterior sds of 1 % of it: the change over the record is recovered within its interval against time and
    against temperature, and is credible; α_V, constant, is not credibly drifting; a record of two windows and
    unconverged windows give no trend."""
    from bayesdamper.inference.drift import record_drift

    rng = np.random.default_rng(5)
    c0 = 2.5e10
    entries = _cycle_entries("long", 8, lambda t: c0 * (1.0 - 0.2 * t / 120.0), 0.01 * c0, rng)
    entries += _cycle_entries("short", 2, lambda t: c0, 0.01 * c0, rng)
    entries += _cycle_entries("failed", 4, lambda t: c0, 0.01 * c0, rng, converged=False)
    temps = {e["id"]: 30.0 + 20.0 * (0.5 * (e["t_start_s"] + e["window"]["t_end_s"])) / 120.0 for e in entries}
    out = record_drift(entries, temps, 0.9, seed=0)
    assert set(out) == {"long"}
    for axis in ("time_s", "temperature_C"):
        t = out["long"]["trends"][axis]["C_L12"]
        truth = -0.2 * (7 / 8) / (1.0 - 0.1)  # change between the first and last mid-time over the mean
        assert t["credible_nonzero"] and t["change"]["lo"] < truth < t["change"]["hi"], (axis, t["change"])
    assert not out["long"]["trends"]["time_s"]["alpha_V"]["credible_nonzero"]
