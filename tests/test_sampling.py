"""emcee posteriors on synthetic eq. (7) data with known truth: recovery, convergence, reproducibility."""

import numpy as np
import pytest
from independent import ar1_noise

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.inference.identify import identify_window
from bayesdamper.inference.priors import ParameterSpace
from bayesdamper.inference.sampling import SamplerSettings, sample_posterior
from bayesdamper.inference.stage2 import StageTwoSettings, shape_report
from bayesdamper.inference.stopping import (
    TAU_RTOL,
    TAU_WINDOW_C,
    burn_in,
    pilot_pays,
    tau_change_sd,
    tau_settled,
)
from bayesdamper.io.dataset import TestRecord
from bayesdamper.io.segmentation import segment_record
from bayesdamper.io.synthetic import simulate_record

TRUTH = DynamicParameters(1 / 0.03, 3.0e5)
#: Force noise of the synthetic records [N], about rig-A's plateau noise.
NOISE_N = 20.0


def synthetic_transients(velocity, seed, phi=0.0, truth=TRUTH):
    t, y, f = simulate_record(velocity, truth, sample_rate=250.0, noise_n=NOISE_N, noise_phi=phi,
                              rng=np.random.default_rng(seed))
    rec = TestRecord(f"v{velocity * 1e6:.0f}", None, t, y, f, "0" * 64)
    return segment_record(rec, RIG_A_DAMPER).transients


def test_gaussian_target_converges_and_matches_moments():
    """The sampler machinery alone, on a 2-D Gaussian with known moments."""
    cov = np.array([[1.0, 0.8], [0.8, 1.0]])
    icov = np.linalg.inv(cov)

    def logp(x):
        return -0.5 * x @ icov @ x if np.all(np.abs(x) < 10) else -np.inf

    res = sample_posterior(logp, np.zeros(2), np.full(2, -10.0), np.full(2, 10.0),
                           SamplerSettings(max_steps=4000), seed=3)
    assert res.converged, res.reason
    flat = res.flat()
    # ESS >= 1000 gives a Monte Carlo sd of the mean of ~0.03 and of the covariance of ~0.05
    np.testing.assert_allclose(flat.mean(0), 0.0, atol=0.15)
    np.testing.assert_allclose(np.cov(flat.T), cov, atol=0.2)
    assert np.all(res.rhat <= 1.01) and np.all(res.ess_bulk >= 1000)
    assert np.all(res.chain.shape[1] > 50 * res.tau)


def test_budget_exhaustion_is_reported_not_accepted():
    res = sample_posterior(lambda x: -0.5 * x @ x, np.zeros(2), np.full(2, -10.0), np.full(2, 10.0),
                           SamplerSettings(max_steps=200, check_every=100), seed=0)
    assert not res.converged
    assert "budget" in res.reason or "τ" in res.reason or "R-hat" in res.reason


def test_a_tau_that_depends_on_the_burn_in_settles():
    # the measured case, a chain of 3000 steps at its last check estimated at τ 20: τ comes out 27 with the end of the
    # starting transient kept (a burn-in below 250 steps), 20 without it
    def tau_of(burn):
        return np.array([27.0 if burn < 250 else 20.0])

    def checks_until_settled(rule):
        burn, prev = 0, np.array([20.0])
        for k, n in enumerate(range(3000, 10_001, 200)):
            burn = rule(burn, n, prev)
            tau = tau_of(burn)
            if abs(tau[0] - prev[0]) < TAU_RTOL * tau[0]:
                return k
            prev = tau
        return None

    def following(burn, n, tau):  # a burn-in that follows each estimate back and forth
        return burn_in(0, n, tau)

    assert checks_until_settled(following) is None  # 200, 270, 200, ... steps to the budget
    assert checks_until_settled(burn_in) == 2  # 200, 270, 270: settled
    assert [burn_in(b, n, np.array([t])) for b, n, t in ((270, 2000, 20.0), (0, 300, 50.0), (90, 600, np.inf))] == [
        270, 100, 200]


def _ar1_walkers(tau: float, n_steps: int, n_walkers: int, seed: int) -> np.ndarray:
    """Independent stationary AR(1) walkers (tests/independent.py) of integrated autocorrelation time ``tau``
    (φ = (τ - 1) / (τ + 1)): shape (n_steps, n_walkers, 1)."""
    phi = (tau - 1.0) / (tau + 1.0)
    return np.stack([ar1_noise(n_steps, 1.0, phi, (seed, w)) for w in range(n_walkers)], axis=1)[:, :, None]


@pytest.mark.parametrize("tau, kept, added, walkers", [(2.3, 150, 50, 8), (6.0, 350, 50, 8), (20.0, 1200, 200, 12)])
def test_the_noise_of_a_change_of_tau_between_checks_is_what_the_formula_says(tau, kept, added, walkers):
    """The sampling noise tau_settled allows for: the sd of the change of emcee's estimate from one check to the next,
    on stationary AR(1) walkers of known τ (the final model's 8 walkers every 50 steps at τ 2-6, the baseline's 12
    every 200 at τ 20). Sokal's formula is a large-sample one and emcee's window adapts to the estimate, so it holds
    to about 30 % here (measured 1.0-1.2x the empirical sd); the test asks for 0.8-1.5x, which a formula off by the
    factor 2 of its window term, or a change scaled as two independent estimates (sqrt(2) times the estimate's sd
    instead of sqrt(added / (kept - added)) of it), fails."""
    import emcee

    est, diffs = [], []
    for rep in range(300):
        ch = _ar1_walkers(tau, kept, walkers, 11 + 1000 * rep)
        a = emcee.autocorr.integrated_time(ch[:kept - added], c=TAU_WINDOW_C, tol=0, quiet=True)[0]
        b = emcee.autocorr.integrated_time(ch, c=TAU_WINDOW_C, tol=0, quiet=True)[0]
        est.append(b)
        diffs.append(b - a)
    predicted = tau_change_sd(float(np.mean(est)), kept, added, walkers)
    assert 0.8 < predicted / float(np.std(diffs)) < 1.5
    # and the rule passes a stationary chain at about 19 checks in 20 (2 sd), where 5 % of τ alone passes far fewer
    pairs = list(zip(est, diffs, strict=True))
    settled = [tau_settled(np.array([e]), np.array([e - d]), kept, added, walkers) for e, d in pairs]
    fixed = [abs(d) < TAU_RTOL * e for e, d in pairs]
    assert np.mean(settled) > 0.9
    if tau < 10:
        assert np.mean(fixed) < 0.7


def test_tau_settles_on_noise_but_not_on_a_jump_of_a_long_chain():
    # the measured final-model window: τ 2.2 -> 2.4 (9 %) with 150 steps kept of 8 walkers, 50 added
    assert tau_settled(np.array([2.4, 1.1]), np.array([2.2, 1.0]), 150, 50, 8)
    assert not abs(2.4 - 2.2) < TAU_RTOL * 2.4  # which 5 % alone calls unsettled
    # a long chain's 30 % jump (the burn-in's oscillation, τ 20 -> 27 at 2 800 steps of 12 walkers) is no noise
    assert not tau_settled(np.array([27.0]), np.array([20.0]), 2800, 200, 12)
    # a rising τ on a short chain: 2 -> 4 is far beyond the noise of 150 steps
    assert not tau_settled(np.array([4.0]), np.array([2.0]), 150, 50, 8)
    # unknown or first estimates never settle
    assert not tau_settled(np.array([2.0]), None, 150, 50, 8)
    assert not tau_settled(np.array([np.inf]), np.array([2.0]), 150, 50, 8)


def test_same_seed_same_samples():
    def logp(x):
        return -0.5 * x @ x if np.all(np.abs(x) < 10) else -np.inf

    a = sample_posterior(logp, np.zeros(2), np.full(2, -10.0), np.full(2, 10.0),
                         SamplerSettings(max_steps=400), seed=7)
    b = sample_posterior(logp, np.zeros(2), np.full(2, -10.0), np.full(2, 10.0),
                         SamplerSettings(max_steps=400), seed=7)
    np.testing.assert_array_equal(a.chain, b.chain)


@pytest.mark.parametrize("velocity", [0.5e-3, 1.5e-3])
def test_recovery_on_synthetic_eq7(velocity):
    """Truth inside the 99 % intervals of every transient, all converged (AR(1) default noise model).

    Six intervals per case (3 transients x 2 parameters): at 99 % each, a calibrated posterior misses
    at least one about 6 % of the time; calibration at 90 % itself is tested in
    test_transient_coverage.py (independent data, SBC).
    """
    settings = StageTwoSettings(credible_mass=0.99)
    for tr in synthetic_transients(velocity, seed=11):
        res = identify_window(tr, RIG_A_DAMPER, PAPER_FLOW, settings, seed=5)
        e = res.entry
        assert e["converged"], (tr.id, e["convergence"])
        assert e["alpha_V"]["lo"] <= TRUTH.liquid_gas_ratio <= e["alpha_V"]["hi"], (tr.id, e["alpha_V"])
        assert e["p_R_Pa"]["lo"] <= TRUTH.reference_pressure <= e["p_R_Pa"]["hi"], (tr.id, e["p_R_Pa"])
        assert e["rhat_max"] <= 1.01 and e["ess_bulk_min"] >= 1000
        # the posterior predictive band contains the noise-free force in most samples
        assert res.band.shape == (3, tr.time.size)


def test_shape_report_flags_ridge_and_bound():
    rng = np.random.default_rng(0)
    z = rng.standard_normal(4000)
    ridge = np.column_stack([z, -z + 0.01 * rng.standard_normal(4000), rng.uniform(size=4000)])
    space = ParameterSpace.default()
    rep = shape_report(ridge, np.array([-5.0, -5.0, 0.0]), np.array([5.0, 5.0, 1.0]))
    assert rep["ridge"] and not rep["multimodal"] and not rep["at_prior_bound"]
    two = np.concatenate([rng.normal(-3, 0.3, (2000, 2)), rng.normal(3, 0.3, (2000, 2))])
    rep2 = shape_report(two, np.array([-5.0, -5.0]), np.array([5.0, 5.0]))
    assert rep2["multimodal"]
    edge = np.column_stack([rng.uniform(4.97, 5.0, 1000), rng.normal(0, 1, 1000)])
    assert shape_report(edge, np.array([-5.0, -5.0]), np.array([5.0, 5.0]))["at_prior_bound"]
    assert space.ndim == 2


def test_initial_positions_near_a_bound_stay_distinct():
    """A start on a prior bound must not put walkers on one shared value (they would never separate)."""
    from bayesdamper.inference.sampling import initial_positions

    lower, upper = np.zeros(2), np.ones(2)
    pos = initial_positions(np.array([1.0, 0.5]), lower, upper, 12, np.random.default_rng(0))
    assert np.all((pos > lower) & (pos < upper))
    assert len(np.unique(pos[:, 0])) == 12


def _skewed_logp(x):
    """x1 ~ Gamma(3, 1), x2 | x1 ~ N(x1 / 2, 1): mean (3, 1.5), var (3, 1.75), cov 1.5 (not Gaussian)."""
    if not (0.0 < x[0] < 40.0 and abs(x[1]) < 40.0):
        return -np.inf
    return 2.0 * np.log(x[0]) - x[0] - 0.5 * (x[1] - 0.5 * x[0]) ** 2


@pytest.mark.parametrize("centre, scale", [((3.0, 1.5), 1.0), ((4.5, 0.0), 0.4), ((2.0, 2.5), 3.0)])
def test_independence_move_keeps_the_target(centre, scale):
    """'de+laplace' with a proposal that is right, too narrow and off-centre, or too wide: the chain still
    samples the target (a flipped proposal ratio or a proposal adapted from the chain would bias it).
    Tolerances: ESS >= 1000 gives a Monte Carlo sd of 0.055 for mean(x1), 0.19 for var(x1) (Gamma(3)'s
    fourth moment); the bounds are about 4.5 sd."""
    cov = scale * np.array([[3.0, 1.5], [1.5, 1.75]])
    # the proposal is centred at the start
    res = sample_posterior(_skewed_logp, np.asarray(centre), np.array([0.0, -40.0]), np.array([40.0, 40.0]),
                           SamplerSettings(max_steps=6000, check_every=100, move="de+laplace"), seed=5,
                           scale=cov)
    assert res.converged, res.reason
    flat = res.flat()
    np.testing.assert_allclose(flat.mean(0), [3.0, 1.5], atol=0.25)
    np.testing.assert_allclose(np.cov(flat.T), [[3.0, 1.5], [1.5, 1.75]], atol=0.8)


def test_independence_proposal_density_is_the_multivariate_t():
    from scipy.stats import multivariate_t

    from bayesdamper.inference.sampling import LaplaceIndependenceMove

    cov = np.array([[2.0, 0.3, 0.0], [0.3, 1.0, -0.2], [0.0, -0.2, 0.5]])
    m = LaplaceIndependenceMove(np.array([1.0, -1.0, 0.5]), cov, dof=5.0, inflation=1.2)
    x = np.random.default_rng(0).normal(size=(6, 3))
    ref = multivariate_t(loc=m.centre, shape=1.44 * cov, df=5.0).logpdf(x)
    d = m.log_density(x) - ref
    np.testing.assert_allclose(d, d[0], atol=1e-10)  # equal up to the normalising constant
    draws = m.draw(40_000, np.random.RandomState(1))
    # t with 5 dof: covariance shape * 5/3; sd of the sample covariance ~0.03 at 40k draws
    np.testing.assert_allclose(np.cov(draws.T), 1.44 * cov * 5 / 3, atol=0.15)


def test_pilot_move_keeps_the_target_and_shortens_tau():
    """'de+pilot': the independence proposal comes from a discarded DE pilot, then is held fixed. On the skewed
    target above (no covariance given) the chain still samples the target (tolerances as in the test above);
    on a 3-D Gaussian with correlations -0.99 (the transients' (log α_V, log p_R) ridge) its τ is at most half
    of plain DE's (seeds 11-13: 2.5 vs 12.5) and its moments are right: at ESS >= 1000 the Monte Carlo sd is 0.032
    for a mean (in sds), 0.022 for an sd ratio and 0.029 for a correlation of 0.3; the bounds are 4-5 of them."""
    res = sample_posterior(_skewed_logp, np.array([3.0, 1.5]), np.array([0.0, -40.0]), np.array([40.0, 40.0]),
                           SamplerSettings(max_steps=6000, check_every=100, move="de+pilot"), seed=5)
    assert res.converged, res.reason
    flat = res.flat()
    np.testing.assert_allclose(flat.mean(0), [3.0, 1.5], atol=0.25)
    np.testing.assert_allclose(np.cov(flat.T), [[3.0, 1.5], [1.5, 1.75]], atol=0.8)

    sd = np.array([0.05, 0.08, 0.02])
    corr = np.array([[1.0, -0.99, 0.3], [-0.99, 1.0, -0.3], [0.3, -0.3, 1.0]])
    cov = corr * np.outer(sd, sd)
    icov = np.linalg.inv(cov)
    mu = np.array([3.7, 12.8, 0.6])

    def logp(x):
        d = x - mu
        return -0.5 * d @ icov @ d if np.all(np.abs(d) < 1.0) else -np.inf

    out = {}
    for move in ("de", "de+pilot"):
        out[move] = sample_posterior(logp, mu + 0.5 * sd, mu - 1.0, mu + 1.0,
                                     SamplerSettings(max_steps=6000, check_every=100, move=move), seed=11)
        assert out[move].converged, out[move].reason
    pil = out["de+pilot"]
    assert np.max(pil.tau) <= 0.5 * np.max(out["de"].tau)
    flat = pil.flat()
    np.testing.assert_allclose((flat.mean(0) - mu) / sd, 0.0, atol=0.15)
    np.testing.assert_allclose(np.corrcoef(flat.T), corr, atol=0.12)
    np.testing.assert_allclose(flat.std(0) / sd, 1.0, atol=0.1)
    # the discarded pilot and the trials of its proposal are counted in the evaluations
    assert pil.n_evaluations == (pil.n_steps + 100) * 3 * 12 + 96


def test_pilot_proposal_is_the_pilots_second_half():
    from bayesdamper.inference.sampling import pilot_proposal

    rng = np.random.default_rng(0)
    chains = rng.normal(size=(3, 200, 12, 2)) * [1.0, 2.0] + [5.0, -1.0]
    chains[:, :100] += 50.0  # a first half far away: the pilot's own burn-in, not used
    m = pilot_proposal(chains)
    np.testing.assert_allclose(m.centre, [5.0, -1.0], atol=0.1)
    np.testing.assert_allclose(m.chol @ m.chol.T / 1.15**2, np.diag([1.0, 4.0]), atol=0.2)
    assert pilot_proposal(np.zeros((3, 20, 12, 2))) is None  # singular: plain DE instead


def test_independence_acceptance_of_a_good_and_a_poor_proposal():
    """The pilot's check of its proposal: from draws of a 3-D Gaussian, its own Laplace proposal (t, inflated 1.15)
    is accepted about 70 % of the time, one centred 4 sd away almost never (96 trials: sd of the estimate < 0.05)."""
    from bayesdamper.inference.sampling import LaplaceIndependenceMove, independence_acceptance

    cov = np.array([[1.0, -0.9, 0.2], [-0.9, 1.0, -0.2], [0.2, -0.2, 1.0]])
    icov = np.linalg.inv(cov)

    def logp(x):
        return -0.5 * x @ icov @ x

    rng = np.random.default_rng(4)
    x = rng.multivariate_normal(np.zeros(3), cov, size=500)
    lp = np.array([logp(z) for z in x])
    good = independence_acceptance(logp, LaplaceIndependenceMove(np.zeros(3), cov), x, lp, np.random.default_rng(1))
    off = independence_acceptance(logp, LaplaceIndependenceMove(np.array([4.0, 0.0, 0.0]), cov), x, lp,
                                  np.random.default_rng(1))
    assert 0.55 < good < 0.9
    assert off < 0.15


def _decades_logp(theta):
    """θ0 ~ Beta(1/2, 1) on [0, 1] (density ∝ θ^-1/2: its 5 % and 95 % quantiles 0.0025 and 0.9025, three decades
    apart), θ1 ~ N(0, 1) independent; uniform prior on the box."""
    t0, t1 = float(theta[0]), float(theta[1])
    return -0.5 * np.log(t0) - 0.5 * t1 * t1 if 0.0 < t0 <= 1.0 else -np.inf


def test_log_scaled_sampling_is_the_same_posterior_in_its_log():
    """A parameter bounded by 0 whose posterior spans decades, sampled as its log (LogScaled, Jacobian included):
    the draws mapped back follow the target. The quantiles of θ0 are F⁻¹(q) = q²; with ESS >= 1000 the Monte
    Carlo sd of an estimated quantile q is below sqrt(q(1-q)/1000)/f(θ_q) < 0.02 in q, so each q is checked to
    0.05 (2.5 sd); the mass below the floor (sqrt(1e-9)) is negligible."""
    from bayesdamper.inference.logscale import LogScaled

    lower, upper = np.array([0.0, -10.0]), np.array([1.0, 10.0])
    target = LogScaled(_decades_logp, [0], lower, upper)
    u = np.array([np.log(0.3), 0.2])
    assert target(u) == pytest.approx(_decades_logp(target.to_theta(u)) + u[0])
    np.testing.assert_allclose(target.to_u(target.to_theta(u)), u)
    res = sample_posterior(target, u, target.lower, target.upper,
                           SamplerSettings(max_steps=8000, check_every=100), seed=3)
    assert res.converged, res.reason
    theta = target.to_theta(res.flat())
    for q in (0.05, 0.25, 0.5, 0.75, 0.95):
        assert np.sqrt(np.quantile(theta[:, 0], q)) == pytest.approx(q, abs=0.05), q
    assert np.std(theta[:, 1]) == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("move", ["de", "stretch"])
@pytest.mark.parametrize("vectorised", [True, False])
def test_advance_is_emcees_run_mcmc(move, vectorised):
    """The sampler's own step loop gives emcee's chain, log-densities, acceptances and random stream exactly."""
    import emcee

    from bayesdamper.inference.sampling import _advance, _log_prob_fn, _moves

    class Target:
        def __call__(self, x):
            return float(-0.5 * (x[0] ** 2 + 10.0 * (x[1] - 0.3 * x[0] ** 2) ** 2)) if np.all(np.abs(x) < 8) \
                else -np.inf

    class Batched(Target):
        def batch(self, xs):
            return np.array([self(x) for x in xs])

    lp = Batched() if vectorised else Target()
    p0 = np.random.default_rng(3).normal(size=(8, 2)) * 0.1
    runs = []
    for own in (False, True):
        s = (emcee.EnsembleSampler(8, 2, lp.batch, moves=_moves(move), vectorize=True) if vectorised
             else emcee.EnsembleSampler(8, 2, lp, moves=_moves(move)))
        s.random_state = np.random.RandomState(11).get_state()
        st = p0
        for n in (30, 45):  # resumed from the state the first run returns, as sample_posterior does
            st = (_advance(s, st, n, _log_prob_fn(lp)) if own
                  else s.run_mcmc(st, n, progress=False, skip_initial_state_check=True))
        runs.append((s.get_chain(), s.get_log_prob(), s.acceptance_fraction, s._random.get_state()[1]))
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)


def _thin_ridge_logp(theta):
    """A long, thin, curved ridge whose mass sits at one end, like a slow reversal's (log α_V, log p_R) under the
    two-state model (tests written from that window's shape, not fitted to it): x has log-density 6 x up to 3.8 and
    falls as a Gaussian of sd 0.1 beyond; y | x ~ N(g(x), 0.005²), g(x) = 16.6 - 0.47 x - 0.106 x²."""
    x, y = float(theta[0]), float(theta[1])
    if not (0.5 < x < 8.5 and 6.9 < y < 16.1):
        return -np.inf
    g = 16.6 - 0.47 * x - 0.106 * x * x
    return 6.0 * x - 50.0 * max(x - 3.8, 0.0) ** 2 - 0.5 * ((y - g) / 0.005) ** 2


def _thin_ridge_x_quantiles(qs):
    x = np.linspace(0.5, 5.0, 200_001)
    d = np.exp(6.0 * x - 50.0 * np.maximum(x - 3.8, 0.0) ** 2 - 6.0 * 3.8)
    c = np.cumsum(d)
    return np.interp(qs, c / c[-1], x)


RIDGE_BOX = (np.array([0.5, 6.9]), np.array([8.5, 16.1]))


def _ridge_from_far_end(logp):
    """:func:`ridge_proposal` of ``logp`` from a pilot-like cloud on the thin ridge at its far end (x near 1.2)."""
    from bayesdamper.inference.proposals import ridge_proposal

    rng = np.random.default_rng(2)
    x = 1.2 + 0.05 * rng.standard_normal((3, 50, 12))
    y = 16.6 - 0.47 * x - 0.106 * x * x + 0.005 * rng.standard_normal(x.shape)
    chains = np.stack([x, y], axis=-1)
    lps = np.array([logp(z) for z in chains.reshape(-1, 2)]).reshape(x.shape)
    return ridge_proposal(logp, chains, lps, *RIDGE_BOX)


def test_ridge_proposal_is_a_normalised_density_and_draws_from_it():
    """The ridge proposal built on the thin ridge from a pilot-like cloud at its far end: its density integrates to
    one over the plane (a Riemann sum on a grid that resolves the 0.005-wide crest: error < 1 %; the t tails beyond
    the grid hold < 1 %), its draws follow its density along the axis (the draws' mean and quartiles of the axis
    coordinate against those of the density on the grid; 40 000 draws: Monte Carlo sd < 0.01), and its crest follows
    the ridge across the 3 units of x between the start and the mass (crest points within 0.005 of g inside
    the box)."""
    move, n_eval = _ridge_from_far_end(_thin_ridge_logp)
    assert move is not None and n_eval > 0
    pts = move.centre + np.outer(move.a, move.axes[:, 0]) + np.outer(move.crest, move.axes[:, 1])
    g = 16.6 - 0.47 * pts[:, 0] - 0.106 * pts[:, 0] ** 2
    inside = pts[:, 1] < 16.09  # below x = 0.9 the ridge leaves the box: its crest there is the box's edge
    assert np.max(np.abs(pts[inside, 1] - g[inside])) < 0.005
    assert pts[:, 0].min() < 1.3 and pts[:, 0].max() > 3.9  # from the pilot's end past the mass
    # normalised: integrate over (a, b) on a grid following the crest
    a = np.linspace(move.a_range[0], move.a_range[1], 20_001)
    c = np.interp(a, move.a, move.crest)
    s = np.interp(a, move.a, move.width)
    z = np.linspace(-60.0, 60.0, 2001)  # in crest widths
    total = 0.0
    for lo in range(0, a.size, 2000):
        aa, cc, ss = a[lo:lo + 2000, None], c[lo:lo + 2000, None], s[lo:lo + 2000, None]
        bb = cc + z[None, :] * ss
        pts = move.centre + aa[..., None] * move.axes[:, 0] + bb[..., None] * move.axes[:, 1]
        dens = np.exp(move.log_density(pts.reshape(-1, 2))).reshape(bb.shape)
        total += float(np.sum(dens * ss * (z[1] - z[0])) * (a[1] - a[0]))
    assert abs(total - 1.0) < 0.02
    draws = move.draw(40_000, np.random.RandomState(3))
    da = (draws - move.centre) @ move.axes[:, 0]
    dens_a = np.exp(move._axis_log_density(a))
    cdf = np.cumsum(dens_a) / np.sum(dens_a)
    np.testing.assert_allclose(np.percentile(da, [25, 50, 75]), np.interp([0.25, 0.5, 0.75], cdf, a), atol=0.03)


def test_ridge_move_samples_a_thin_ridge_from_its_far_end():
    """'de+pilot' on the thin ridge, started 16 nats down the ridge from its mass (an optimiser stopped on the
    ridge's slope): the Gaussian proposal misses the curved ridge, the ridge proposal is built, the ensembles
    restart from it and the run converges with x's 5/50/95 % quantiles at the exact ones (ESS >= 1000: the Monte
    Carlo sd of a quantile is below 0.02 here; bound 0.06) for under a tenth of plain DE's evaluations, which does
    not converge within its 10 000 steps (seed 7; on seeds 7-9 it never did)."""
    start = np.array([1.2, 16.6 - 0.47 * 1.2 - 0.106 * 1.44])
    scale = np.diag([0.05, 0.005]) ** 2
    pil = sample_posterior(_thin_ridge_logp, start, *RIDGE_BOX, SamplerSettings(move="de+pilot", check_every=50),
                           seed=7, scale=scale)
    assert pil.converged, pil.reason
    np.testing.assert_allclose(np.percentile(pil.flat()[:, 0], [5, 50, 95]),
                               _thin_ridge_x_quantiles([0.05, 0.5, 0.95]), atol=0.06)
    de = sample_posterior(_thin_ridge_logp, start, *RIDGE_BOX, SamplerSettings(move="de", check_every=200),
                          seed=7, scale=scale)
    assert not de.converged
    assert pil.n_evaluations < 0.1 * de.n_evaluations


def _noisy_ridge_logp(theta):
    """The thin ridge with a solver's noise: 0.2 nats of deterministic ripple on a scale of 1e-4 in y, far finer
    than the ridge's 0.005 width (a second difference at a step near the ripple's scale reads its curvature,
    some ten thousand times the ridge's; at the crest's own width it is a fraction of a nat)."""
    v = _thin_ridge_logp(theta)
    return v + 0.2 * np.sin(6.0e4 * float(theta[1])) if np.isfinite(v) else v


def test_ridge_crest_and_widths_survive_a_solvers_noise():
    """The crest's width is measured from a drop of a quarter to four nats, not from the curvature at a step below
    the noise: on the noisy ridge every crest point's width is within a factor 2 of the ridge's own (0.005 in y, seen
    across the walk's axis at its angle), and the crest stays within 0.005 of g from the pilot's end past the mass."""
    from bayesdamper.inference.proposals import INDEPENDENCE_INFLATION

    move, _ = _ridge_from_far_end(_noisy_ridge_logp)
    pts = move.centre + np.outer(move.a, move.axes[:, 0]) + np.outer(move.crest, move.axes[:, 1])
    inside = (pts[:, 1] < 16.09) & (pts[:, 0] < 3.8)
    g = 16.6 - 0.47 * pts[:, 0] - 0.106 * pts[:, 0] ** 2
    assert np.max(np.abs(pts[inside, 1] - g[inside])) < 0.005
    assert pts[:, 0].max() > 3.9
    # across the walk's axis the ridge is 0.005 / |cos| wide, cos the angle between the across-axis and y
    slope = -0.47 - 0.212 * pts[inside, 0]  # dg/dx: the ridge's direction (1, slope)
    t = np.stack([np.ones_like(slope), slope], axis=1) / np.hypot(1.0, slope)[:, None]
    across = move.axes[:, 1]
    # the cross-section along `across` of a ridge of normal width s is s / |n . across|, n the ridge's normal
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    true_w = 0.005 * np.hypot(1.0, slope) ** -1 / np.abs(n @ across)
    ratio = move.width[inside] / INDEPENDENCE_INFLATION / true_w  # move.a is sorted, as pts
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio


def _corner_ridge_logp(theta):
    """A thin ridge that runs into a corner of the box with its mass there, like a 100 Hz slow start's (log α_V,
    log p_R) under eq. (7), whose data ask for the stiffest fluid the box allows (α_V at its bottom, p_R at its top;
    written from that shape, not fitted to it): x falls as exp(-3 x) from the box's edge at 0.5, y | x ~ N(g(x),
    0.005²) with g(x) = 16.1 - 0.9 (x - 0.5), which meets the box's top at the corner (0.5, 16.1)."""
    x, y = float(theta[0]), float(theta[1])
    if not (0.5 < x < 8.5 and 6.9 < y < 16.1):
        return -np.inf
    return -3.0 * x - 0.5 * ((y - (16.1 - 0.9 * (x - 0.5))) / 0.005) ** 2


def _corner_ridge_x_quantiles(qs):
    """x's quantiles on the corner ridge: exp(-3 x) times the share of y's normal inside the box (y < 16.1)."""
    from scipy.stats import norm

    x = np.linspace(0.5, 4.0, 400_001)
    d = np.exp(-3.0 * (x - 0.5)) * norm.cdf(0.9 * (x - 0.5) / 0.005)
    c = np.cumsum(d)
    return np.interp(qs, c / c[-1], x)


def _corner_pilot(spread: float = 0.15, offset: float = 0.0):
    """A pilot-like cloud on the corner ridge (chains (3, 50, 12, 2) and their log-densities): x from ``0.5 +
    offset`` up the ridge, half-normal with sd ``spread``, y on the crest (inside the box)."""
    rng = np.random.default_rng(2)
    x = 0.5 + offset + np.abs(spread * rng.standard_normal((3, 50, 12)))
    y = np.minimum(16.1 - 0.9 * (x - 0.5) + 0.005 * rng.standard_normal(x.shape), 16.1 - 1e-6)
    chains = np.stack([x, y], axis=-1)
    return chains, np.array([_corner_ridge_logp(z) for z in chains.reshape(-1, 2)]).reshape(x.shape)


def test_ridge_proposal_follows_a_crest_into_a_corner_of_the_box():
    """A posterior whose mass lies in a corner of the box: every line across the ridge near the corner leaves the
    box on both sides within a fraction of the crest's bracket. The crest is searched inside the box, so the ridge
    proposal is built from a pilot cloud in the corner (a crest searched across the whole bracket finds none: the
    bracket lies outside the box), its crest follows g inside the box, and 'de+pilot' from the corner converges with
    x's 5/50/95 % quantiles at the exact ones
    within 2000 steps (within 4 Monte Carlo sds of a quantile at ESS 1000, sqrt(q (1 - q) / 1000) / f(x_q), f the
    density there, about 3 (1 - q); seed 7)."""
    from bayesdamper.inference.proposals import ridge_proposal

    move, n_eval = ridge_proposal(_corner_ridge_logp, *_corner_pilot(), *RIDGE_BOX)
    assert move is not None and n_eval > 0
    pts = move.centre + np.outer(move.a, move.axes[:, 0]) + np.outer(move.crest, move.axes[:, 1])
    assert np.all((pts > RIDGE_BOX[0]) & (pts < RIDGE_BOX[1]))
    inside = pts[:, 1] < 16.1 - 0.01  # near the corner the crest is the box's edge
    assert np.max(np.abs(pts[inside, 1] - (16.1 - 0.9 * (pts[inside, 0] - 0.5)))) < 0.005
    start = np.array([0.55, 16.1 - 0.9 * 0.05])
    scale = np.diag([0.1, 0.09]) ** 2
    pil = sample_posterior(_corner_ridge_logp, start, *RIDGE_BOX,
                           SamplerSettings(move="de+pilot", check_every=50, max_steps=2000), seed=7, scale=scale)
    assert pil.converged, pil.reason
    q = np.array([0.05, 0.5, 0.95])
    mc_sd = np.sqrt(q * (1.0 - q) / 1000.0) / (3.0 * (1.0 - q))  # a quantile's sd at ESS 1000: sqrt(q(1-q)/n) / f
    assert np.all(np.abs(np.percentile(pil.flat()[:, 0], 100 * q) - _corner_ridge_x_quantiles(q)) < 4.0 * mc_sd)


def test_ridge_proposal_walks_its_crest_to_the_edge_of_the_box():
    """The walk along the crest ends at the box's edge, not a step short of it: on the corner ridge, where the mass
    lies against the edge, a walk that stopped at its last whole step before the edge left the proposal without the
    stretch that holds the mass (only the defensive share covers it). Pilots of several spreads and offsets up the
    ridge (where the last step before the edge falls varies with them) all give a proposal whose importance
    weights (target / proposal over 4000 of its draws) keep most of their draws: an effective share above 0.5.
    A proposal that follows the Laplace marginal along the crest, with its t tails across, keeps about 0.87 here;
    one that misses the stretch by the edge keeps under 0.01, since nearly all the weight falls on the few
    defensive draws there."""
    from bayesdamper.inference.proposals import ridge_proposal

    for spread, offset in ((0.15, 0.3), (0.15, 1.0), (0.5, 1.0), (1.0, 0.3), (1.0, 1.0), (0.5, 0.0)):
        move, _ = ridge_proposal(_corner_ridge_logp, *_corner_pilot(spread, offset), *RIDGE_BOX)
        assert move is not None
        q = move.draw(4000, np.random.RandomState(1))
        lw = np.array([_corner_ridge_logp(z) for z in q]) - move.log_density(q)
        w = np.where(np.isfinite(lw), np.exp(lw - np.max(lw[np.isfinite(lw)])), 0.0)
        share = w.sum() ** 2 / (w * w).sum() / w.size
        assert share > 0.5, (spread, offset, share)


def test_tau_is_emcees_integrated_time():
    """The convergence checks' τ (every walker and parameter in one real FFT) is emcee's ``integrated_time`` with
    the same window constant: AR(1) chains of 1 to 3001 steps, 8 or 16 walkers; a parameter whose walkers never
    moved is infinite. Agreement to 1e-12 relative, and 1e-12 absolute for a τ of zero (two steps): the same sums,
    FFTs of other lengths, so rounding only."""
    import emcee

    from bayesdamper.inference.stopping import TAU_WINDOW_C, tau_estimate

    rng = np.random.default_rng(5)
    for n_t in (1, 2, 3, 64, 251, 3001):
        for n_w, n_d, phi in ((16, 6, 0.95), (8, 3, 0.5)):
            e = rng.standard_normal((n_t, n_w, n_d))
            x = np.zeros_like(e)
            for t in range(n_t):
                x[t] = (phi * x[t - 1] if t else 0.0) + e[t]
            if n_t > 1:
                x[:, :, 1] = 0.25  # frozen walkers
            with np.errstate(invalid="ignore", divide="ignore"):
                ref = emcee.autocorr.integrated_time(x, c=TAU_WINDOW_C, tol=0, quiet=True)
            ref = np.where(np.isfinite(ref), ref, np.inf)
            got = tau_estimate(x)
            assert np.array_equal(np.isinf(got), np.isinf(ref)), (n_t, got, ref)
            fin = np.isfinite(ref)
            np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-12, atol=1e-12)
            if n_t > 1:
                assert np.isinf(got[1])


def test_a_laplace_run_whose_walkers_leave_its_proposal_takes_the_pilot_route():
    """'de+laplace' with the Laplace approximation where an optimiser stopped (on the thin ridge 16 nats down from
    its mass; on the corner ridge half a unit up from its corner, the Laplace Gaussian's correlation -0.99 with no
    curvature): the walkers spread along the ridge, τ grows at every check, and once going on would cost more steps
    than the pilot route the run takes it from where the walkers are (:func:`pilot_pays`). Every run switches,
    converges and puts x's 5/50/95 % quantiles at the exact ones (the bounds of the 'de+pilot' tests above) for under
    a tenth of the step budget's evaluations (plain DE does not converge within the budget on the thin ridge)."""
    thin = (_thin_ridge_logp, np.array([1.2, 16.6 - 0.47 * 1.2 - 0.106 * 1.44]), np.diag([0.05, 0.005]) ** 2,
            _thin_ridge_x_quantiles, np.full(3, 0.06))
    q = np.array([0.05, 0.5, 0.95])
    corner = (_corner_ridge_logp, np.array([1.0, 16.1 - 0.9 * 0.5]),
              np.diag([0.3, 0.27]) ** 2 * np.array([[1.0, -0.99], [-0.99, 1.0]]), _corner_ridge_x_quantiles,
              4.0 * np.sqrt(q * (1.0 - q) / 1000.0) / (3.0 * (1.0 - q)))
    settings = SamplerSettings(move="de+laplace", check_every=50)
    budget = settings.max_steps * settings.n_walkers * settings.n_ensembles
    for logp, start, scale, exact, tol in (thin, corner):
        for seed in (7, 8, 9):
            res = sample_posterior(logp, start, *RIDGE_BOX, settings, seed=seed, scale=scale)
            assert res.pilot_after > 0 and res.converged, (seed, res.reason)
            assert np.all(np.abs(np.percentile(res.flat()[:, 0], 100 * q) - exact(q)) < tol), seed
            assert res.n_evaluations < 0.1 * budget


def test_a_laplace_run_on_a_gaussian_ridge_keeps_its_move():
    """On a Gaussian as thin as rig-A's (α_V, p_R) windows (correlation -0.999) with its exact Laplace approximation,
    τ does not grow and no run gives its steps up for the pilot route; the smallest τ is near its estimate's noise
    only, so a rule that switched on any rise of τ would switch here."""
    cov = np.array([[1.0, -0.999], [-0.999, 1.0]]) * 0.01
    icov = np.linalg.inv(cov)

    def logp(x):
        return -0.5 * x @ icov @ x if np.all(np.abs(x) < 1.0) else -np.inf

    for seed in range(5):
        res = sample_posterior(logp, np.zeros(2), np.full(2, -1.0), np.full(2, 1.0),
                               SamplerSettings(move="de+laplace", check_every=50), seed=seed, scale=cov)
        assert res.converged and res.pilot_after == 0, (seed, res.reason)


def test_pilot_pays_when_going_on_costs_more_than_the_pilot_route():
    """The break-even of :func:`pilot_pays`: (50 + 10) (τ_now - τ_low) against 100 pilot steps and the steps run."""
    assert not pilot_pays(2.5, 2.0, 150)  # a stationary chain's scatter
    assert pilot_pays(2.0 + 251.0 / 60.0, 2.0, 150) and not pilot_pays(2.0 + 249.0 / 60.0, 2.0, 150)
    assert not pilot_pays(np.inf, 2.0, 150) and not pilot_pays(9.0, np.inf, 150)


def test_a_switched_run_keeps_its_step_budget_and_reports_at_its_end():
    """The steps given up count against the budget, and a run that switched and then meets the budget reports the
    R-hat and ESS of its kept chain there (as one that did not switch does), not the values before the switch."""
    start = np.array([1.2, 16.6 - 0.47 * 1.2 - 0.106 * 1.44])
    res = sample_posterior(_thin_ridge_logp, start, *RIDGE_BOX,
                           SamplerSettings(move="de+laplace", check_every=50, max_steps=180), seed=7,
                           scale=np.diag([0.05, 0.005]) ** 2)
    assert res.pilot_after > 0 and not res.converged
    assert res.pilot_after + res.n_steps <= 180
    assert np.all(np.isfinite(res.rhat)) and np.all(res.ess_bulk > 0)
