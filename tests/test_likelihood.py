"""Eq. (9), the noise models and the compiled log-posterior."""

import pickle

import numpy as np
import pytest
from scipy import integrate, linalg, stats

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.inference.likelihood import (
    AR1Noise,
    LogPosterior,
    WhiteNoise,
    ar1_loglike,
    cost_j,
    make_noise_model,
)
from bayesdamper.inference.problem import WindowProblem
from bayesdamper.physics.excitation import PiecewiseLinear, PiecewisePolynomial
from bayesdamper.physics.single_state import simulate_single_state

#: Agreement of two float64 evaluations of the same log density (sums of ~750 terms).
LOGPDF_RTOL = 1e-9


def make_problem(noise=20.0, seed=0, v=1.0e-3, alpha_v=33.0, p_r=3e5):
    exc = PiecewiseLinear(np.array([0.0, 3.0]), np.array([0.0, 3.0 * v]))
    t = np.arange(0.0, 3.0, 1 / 250)
    dp = simulate_single_state(t, exc, RIG_A_DAMPER, PAPER_FLOW, DynamicParameters(alpha_v, p_r), dp0=0.0)
    f = RIG_A_DAMPER.piston_area * dp + noise * np.random.default_rng(seed).standard_normal(t.size)
    return WindowProblem("synthetic_s0", t, f, 0.0, 0.0, exc.as_polynomial(), RIG_A_DAMPER, PAPER_FLOW)


def test_cost_j_is_eq9():
    f_e = np.array([1.0, 2.0, 2.0])
    f_c = np.array([1.0, 2.0, 3.0])
    assert cost_j(f_c, f_e) == pytest.approx(1.0 / 3.0)
    assert cost_j(f_e, f_e) == 0.0


def test_ar1_fixed_scale_matches_multivariate_normal():
    rng = np.random.default_rng(1)
    n, phi, sigma = 60, 0.7, 2.5
    r = rng.standard_normal(n)
    cov = sigma**2 / (1 - phi**2) * linalg.toeplitz(phi ** np.arange(n))
    ref = stats.multivariate_normal(np.zeros(n), cov).logpdf(r)
    assert ar1_loglike(r, phi, sigma) == pytest.approx(ref, rel=LOGPDF_RTOL)


@pytest.mark.parametrize("noise", [WhiteNoise(), AR1Noise()])
def test_marginal_likelihood_matches_numerical_integral(noise):
    """log L(r1) - log L(r2) equals the ratio of the σ-integrals with the Jeffreys prior."""
    rng = np.random.default_rng(2)
    r1, r2 = rng.standard_normal(40), 1.3 * rng.standard_normal(40)
    theta = np.array([0.4]) if noise.params else np.array([])
    phi = theta[0] if noise.params else 0.0

    def marginal(r):
        f = lambda ls: np.exp(ar1_loglike(r, phi, np.exp(ls)) + 60)  # noqa: E731  (d log σ = dσ/σ)
        return np.log(integrate.quad(f, -5, 5, limit=200)[0]) - 60

    expected = marginal(r1) - marginal(r2)
    got = noise.loglike(r1, theta) - noise.loglike(r2, theta)
    assert got == pytest.approx(expected, rel=1e-6)


def test_white_is_ar1_at_zero_phi():
    r = np.random.default_rng(3).standard_normal(50)
    assert AR1Noise().loglike(r, np.array([0.0])) == pytest.approx(WhiteNoise().loglike(r, np.array([])))


def test_white_loglike_is_function_of_j():
    prob = make_problem()
    lp = LogPosterior(prob, WhiteNoise())
    th = np.log([40.0, 2e5])
    f, _ = prob.simulate_force(40.0, 2e5)
    j = cost_j(f, prob.force)
    n = prob.force.size
    const = -0.5 * n * np.log(prob.force @ prob.force)
    assert lp(th) == pytest.approx(-0.5 * n * np.log(j**2) + const, rel=LOGPDF_RTOL)


@pytest.mark.parametrize("name", ["white", "ar1"])
def test_compiled_equals_reference(name):
    lp = LogPosterior(make_problem(), make_noise_model(name))
    rng = np.random.default_rng(4)
    for _ in range(5):
        th = lp.space.lower + rng.uniform(size=lp.space.ndim) * (lp.space.upper - lp.space.lower)
        assert lp(th) == pytest.approx(lp.reference(th), rel=LOGPDF_RTOL)


def test_batch_equals_single():
    lp = LogPosterior(make_problem())
    rng = np.random.default_rng(5)
    ths = lp.space.lower + rng.uniform(size=(8, 3)) * (lp.space.upper - lp.space.lower)
    np.testing.assert_allclose(lp.batch(ths), [lp(t) for t in ths], rtol=1e-12)


def test_minus_inf_outside_prior_and_never_nan():
    lp = LogPosterior(make_problem())
    for th in ([np.log(1.0), np.log(1e5), 0.2], [np.log(30), np.log(1e8), 0.2], [np.log(30), np.log(1e5), 1.0],
               [np.nan, np.log(1e5), 0.2], [np.inf, 0.0, 0.0], [np.log(30), np.log(1e5), np.nan]):
        v = lp(np.array(th))
        assert v == -np.inf


def test_failed_solve_is_minus_inf():
    """A displacement history that empties chamber 1 makes the solve fail: -inf, not NaN."""
    t = np.arange(0.0, 3.0, 1 / 250)
    knots = np.array([0.0, 3.0])
    y = np.array([0.0, 0.2])  # 0.2 m * 4.2e-3 m^2 > V01 = 1.5e-4 m^3
    prob = WindowProblem("bad", t, np.ones_like(t), 0.0, 0.0, PiecewisePolynomial.from_knots(knots, y), RIG_A_DAMPER,
                         PAPER_FLOW)
    lp = LogPosterior(prob)
    assert lp(np.array([np.log(30), np.log(1e5), 0.2])) == -np.inf


def test_maximum_near_truth_on_noise_free_data():
    lp = LogPosterior(make_problem(noise=1e-3), WhiteNoise())
    truth = np.log([33.0, 3e5])
    assert lp(truth) > lp(truth + [0.05, 0.0]) and lp(truth) > lp(truth + [0.0, 0.05])


def test_pickles():
    lp = LogPosterior(make_problem())
    th = np.array([np.log(30), np.log(1e5), 0.3])
    lp2 = pickle.loads(pickle.dumps(lp))
    assert lp2(th) == lp(th)


def test_unknown_noise_model_is_settings_error():
    with pytest.raises(SettingsError, match="unknown noise model"):
        make_noise_model("pink")
