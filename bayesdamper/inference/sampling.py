"""emcee sampling of one transient's posterior, with convergence checked rather than assumed.

emcee's walkers are not independent chains, so R-hat is computed across several *independently
started* ensembles, each with its own random generator and its own dispersed start. The stopping rule
is the integrated autocorrelation time τ: every ensemble runs until its post-burn-in chain is longer
than ``TAU_FACTOR`` τ for every parameter and the largest τ, which sets that length, has settled (changed
between checks by less than ``TAU_RTOL`` or than the estimate's own sampling noise, :func:`tau_settled`). Only
then are the rank-normalised R-hat (across ensembles) and the bulk ESS checked against ``GOOD_RHAT`` and
``MIN_ESS``. A run that exhausts its step budget first is reported as not converged. A two-parameter run of
``"de+laplace"`` whose τ keeps growing gives its steps up for the pilot route of ``"de+pilot"`` once that is the
cheaper way to the stopping rule (:func:`~bayesdamper.inference.stopping.pilot_pays`); the steps given up count
against the budget. The rules themselves are in :mod:`bayesdamper.inference.stopping`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from bayesdamper.inference.proposals import (
    INDEPENDENCE_SHARE,
    PILOT_BURN,
    PILOT_STEPS,
    LaplaceIndependenceMove,
    choose_pilot_proposal,
    independence_acceptance,
    pilot_proposal,
)
from bayesdamper.inference.stopping import TAU_FACTOR, TAU_RTOL, burn_in, pilot_pays, tau_estimate, tau_settled

__all__ = ["GOOD_RHAT", "LaplaceIndependenceMove", "SamplerSettings", "SamplingResult", "independence_acceptance",
           "initial_positions", "laplace_covariance", "pilot_proposal", "sample_posterior"]

#: Largest acceptable rank-normalised split R-hat across ensembles (Vehtari et al. 2021).
GOOD_RHAT = 1.01
#: Smallest acceptable bulk effective sample size per parameter.
MIN_ESS = 1000.0
#: R-hat above which ensembles are taken to sit in different modes once τ has settled: more steps do
#: not cure that, so the run stops and is reported as not converged (multimodal).
GROSS_RHAT = 1.1
#: Relative spread, in the transformed variables, between ensembles' independent starting balls.
START_SPREAD = 0.05


@dataclass(frozen=True)
class SamplerSettings:
    """Settings of :func:`sample_posterior` (stored with every posterior).

    Attributes
    ----------
    n_ensembles : int
        Independently started ensembles (the "chains" of R-hat).
    n_walkers : int
        Walkers per ensemble.
    check_every : int
        Steps between convergence checks.
    max_steps : int
        Step budget per ensemble; reaching it without convergence is reported, not accepted. 10 000: a chain of
        50 τ after a burn-in of 10 τ, for τ up to 150 steps (sine records whose α_V and p_R lie on a ridge:
        an independent 1 Hz sine at 500 Hz with AR(1) noise had τ 150, R-hat 1.002 and ESS 1490, but was only
        30 τ long at the earlier 6000).
    move : str
        ``"de"`` (default: differential evolution 80% + stretch 20%, which follows the long
        (log α_V, log p_R) ridges with τ about three times shorter than the stretch move on rig-A),
        ``"stretch"`` (emcee's default), ``"de+laplace"`` (``"de"`` with a share of independence
        moves from the Laplace approximation, :class:`LaplaceIndependenceMove`: for nearly Gaussian
        posteriors such as whole records; with two parameters it turns to the pilot route below when τ keeps
        growing, :func:`~bayesdamper.inference.stopping.pilot_pays`) or ``"de+pilot"`` (``"de+laplace"`` with
        the proposal's centre and covariance from a discarded pilot run of ``"de"``, :func:`pilot_proposal`:
        where no reliable covariance is known in advance; for two parameters whose posterior the Gaussian misses,
        the proposal follows the ridge's crest instead, :func:`~bayesdamper.inference.proposals.ridge_proposal`,
        and the ensembles restart from it).
    """

    n_ensembles: int = 3
    n_walkers: int = 12
    check_every: int = 200
    max_steps: int = 10_000
    move: str = "de"
    tau_factor: float = TAU_FACTOR
    tau_rtol: float = TAU_RTOL
    rhat_max: float = GOOD_RHAT
    ess_min: float = MIN_ESS

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class SamplingResult:
    """Post-burn-in samples and convergence diagnostics of one posterior.

    Attributes
    ----------
    chain : ndarray, shape (n_ensembles, n_steps, n_walkers, ndim)
        Transformed parameter samples after burn-in.
    log_prob : ndarray, shape (n_ensembles, n_steps, n_walkers)
    tau : ndarray, shape (ndim,)
        Integrated autocorrelation time [steps], worst ensemble per parameter.
    rhat, ess_bulk : ndarray, shape (ndim,)
    n_steps : int
        Steps run per ensemble (burn-in included), not counting a pilot's or those given up (``pilot_after``).
    burn_in : int
    converged : bool
    reason : str
        Why the run stopped ("converged", or what failed).
    acceptance : float
        Mean acceptance fraction.
    n_evaluations : int
        Log-posterior evaluations.
    pilot_after : int
        Steps of a ``"de+laplace"`` run given up for the pilot route of ``"de+pilot"`` (:func:`pilot_pays`); 0 where
        none was.
    """

    chain: np.ndarray
    log_prob: np.ndarray
    tau: np.ndarray
    rhat: np.ndarray
    ess_bulk: np.ndarray
    n_steps: int
    burn_in: int
    converged: bool
    reason: str
    acceptance: float
    n_evaluations: int
    pilot_after: int = 0

    def flat(self) -> np.ndarray:
        """All post-burn-in samples, shape (n_samples, ndim)."""
        return self.chain.reshape(-1, self.chain.shape[-1])


def _moves(name: str, independence: LaplaceIndependenceMove | None = None, share: float = INDEPENDENCE_SHARE):
    import emcee  # here, not at module level: the CLI reads SamplerSettings' defaults without emcee/arviz

    if name in ("de+laplace", "de+pilot"):
        de = _moves("de")
        if independence is None:  # no positive-definite Laplace covariance: plain DE
            return de
        return [(m, w * (1.0 - share)) for m, w in de] + [(emcee.moves.MHMove(independence.proposal), share)]
    if name == "stretch":
        return None
    if name == "de":
        # DE follows ridges; the stretch share pulls a walker that strayed into a low-probability
        # corner back to the others (DE alone moves it by the ensemble's own small differences).
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]
    if name == "de-snooker":
        return [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    raise ValueError(f"unknown move {name!r}")


def initial_positions(start: np.ndarray, lower: np.ndarray, upper: np.ndarray, n_walkers: int,
                      rng: np.random.Generator, scale: np.ndarray | None = None) -> np.ndarray:
    """A ball of ``n_walkers`` points around ``start``, inside the prior box.

    ``scale`` is a covariance of the posterior near ``start`` (a Laplace approximation): the ball's
    centre is drawn one standard deviation away from ``start`` and its walkers one more, so independent
    ensembles start overdispersed relative to the posterior, as R-hat needs. Without ``scale`` a
    diagonal ball of ``START_SPREAD`` of the prior box is used.
    """
    span = upper - lower
    if scale is None:
        scale = np.diag((START_SPREAD * 0.2 * span) ** 2)
    chol = np.linalg.cholesky(scale)
    centre = start + chol @ rng.standard_normal(start.size)
    pos = centre + rng.standard_normal((n_walkers, start.size)) @ chol.T
    # Reflect at the prior bounds rather than clip: clipped walkers would share a coordinate exactly,
    # and neither DE nor stretch moves can ever separate them again.
    pos = np.where(pos > upper, 2 * upper - pos, pos)
    pos = np.where(pos < lower, 2 * lower - pos, pos)
    bad = (pos <= lower) | (pos >= upper)
    pos[bad] = (lower + rng.uniform(0.25, 0.75, pos.shape) * span)[bad]
    return pos


def finite_difference_hessian(f: Callable[[np.ndarray], float], x0: np.ndarray, h: np.ndarray,
                              dims: np.ndarray | None = None) -> np.ndarray:
    """Hessian of the scalar ``f`` at ``x0`` over the entries ``dims`` (default: all) by central differences with
    per-entry steps ``h``: (f(x+h_i) − 2 f(x) + f(x−h_i)) / h_i² on the diagonal, the four-point formula off it."""
    dims = np.arange(x0.size) if dims is None else np.asarray(dims)
    f0 = f(x0)

    def at(*moves):
        x = np.array(x0, dtype=float)
        for j, sgn in moves:
            x[j] += sgn * h[j]
        return f(x)

    hess = np.empty((dims.size, dims.size))
    for a, i in enumerate(dims):
        hess[a, a] = (at((i, 1)) - 2 * f0 + at((i, -1))) / h[i] ** 2
        for b in range(a):
            j = dims[b]
            hess[a, b] = hess[b, a] = (at((i, 1), (j, 1)) - at((i, 1), (j, -1)) - at((i, -1), (j, 1))
                                       + at((i, -1), (j, -1))) / (4 * h[i] * h[j])
    return hess


def laplace_covariance(log_prob: Callable[[np.ndarray], float], x0: np.ndarray, lower: np.ndarray,
                       upper: np.ndarray) -> np.ndarray | None:
    """Covariance of the Laplace approximation at ``x0``: the inverse of minus the Hessian of the
    log-posterior by central finite differences. None if it is not positive definite (a ridge that
    runs into a prior bound, say): the caller then falls back to a fixed ball.
    """
    hess = finite_difference_hessian(log_prob, x0, 1e-4 * (upper - lower))
    if not np.all(np.isfinite(hess)):
        return None
    try:
        cov = np.linalg.inv(-hess)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return None
    # never start wider than a quarter of the prior box in any direction
    sd = np.sqrt(np.diag(cov))
    shrink = np.minimum(1.0, 0.25 * (upper - lower) / sd)
    return cov * np.outer(shrink, shrink)


def _log_prob_fn(log_prob):
    """emcee's ``compute_log_prob`` for ``log_prob`` without its per-walker Python: the same checks (no infinite or
    NaN coordinate, no NaN value) and the same float64 values, one call per half-ensemble (``log_prob.batch``
    where there is one, else row by row); no blobs."""
    batch = getattr(log_prob, "batch", None)

    def compute(coords):
        if not np.all(np.isfinite(coords)):
            raise ValueError("At least one parameter value was infinite or NaN")
        vals = np.array(batch(coords) if batch is not None else [float(log_prob(z)) for z in coords],
                        dtype=np.float64).reshape(-1)
        if np.any(np.isnan(vals)):
            raise ValueError("Probability function returned NaN")
        return vals, None

    return compute


def _advance(sampler, state, n: int, compute):
    """``sampler.run_mcmc(state, n, skip_initial_state_check=True)`` without the per-step bookkeeping that costs
    as much as a cheap posterior: each step draws its move from the sampler's own generator, proposes, and is stored
    in the sampler's backend, exactly as emcee's ``EnsembleSampler.sample`` does (the same random stream, chain,
    log-densities and acceptances), but the generator's state is not copied into every step's ``State`` (emcee only
    reports it there) and the log-density goes through ``compute`` (:func:`_log_prob_fn`). Returns the last state.
    """
    from emcee.model import Model
    from emcee.state import State

    state = State(state, copy=True)
    if state.random_state is not None:  # a State that carries a generator state resumes from it, as in emcee
        sampler.random_state = state.random_state
        state.random_state = None
    if state.log_prob is None:
        state.log_prob, state.blobs = compute(state.coords)
    if np.shape(state.log_prob) != (sampler.nwalkers,) or np.any(np.isnan(state.log_prob)):
        raise ValueError("The initial log_prob was NaN or of the wrong shape")
    backend, random = sampler.backend, sampler._random
    backend.grow(n, state.blobs)
    model = Model(sampler.log_prob_fn, compute, map, random)
    moves, weights = sampler._moves, sampler._weights
    for _ in range(n):
        move = random.choice(moves, p=weights)
        state, accepted = move.propose(model, state)
        backend.save_step(state, accepted)
    sampler._previous_state = state
    return state


def sample_posterior(log_prob: Callable[[np.ndarray], float], start: np.ndarray, lower: np.ndarray,
                     upper: np.ndarray, settings: SamplerSettings | None = None, seed: int = 0,
                     progress: Callable[[str], None] | None = None,
                     scale: np.ndarray | None = None) -> SamplingResult:
    """Sample one posterior with ``settings.n_ensembles`` independent emcee ensembles.

    Parameters
    ----------
    log_prob : callable
        Log-posterior of the transformed vector; returns a float, -inf where impossible. If it has a
        ``batch`` method (rows -> values), emcee calls that once per step for all walkers.
    start : ndarray, shape (ndim,)
        A high-posterior point (the Nelder-Mead optimum) in transformed variables.
    lower, upper : ndarray, shape (ndim,)
        Prior box in transformed variables.
    seed : int
        Seeds every ensemble's generator (through ``numpy.random.SeedSequence``).
    progress : callable, optional
        Receives a one-line status after every convergence check.
    scale : ndarray, shape (ndim, ndim), optional
        Covariance of the posterior near ``start`` known to the caller (a Gauss-Newton covariance, say):
        shapes the starting balls and the ``"de+laplace"`` proposal. Default: :func:`laplace_covariance`
        (finite differences of ``log_prob``; with strongly correlated parameters its marginal widths can be
        off by a factor of two, harmless for a starting ball but not for a proposal).
    """
    import emcee

    from bayesdamper.inference import posterior as post

    settings = settings or SamplerSettings()
    start = np.asarray(start, dtype=float)
    ndim = start.size
    seeds = np.random.SeedSequence(seed).spawn(settings.n_ensembles)
    if scale is not None:
        try:
            np.linalg.cholesky(scale)
        except np.linalg.LinAlgError:
            scale = None
    if scale is None:
        scale = laplace_covariance(log_prob, start, lower, upper)
    indep = LaplaceIndependenceMove(start, scale) if scale is not None and settings.move == "de+laplace" else None

    def ensemble(moves):
        if hasattr(log_prob, "batch"):  # one compiled call per ensemble step for all walkers
            return emcee.EnsembleSampler(settings.n_walkers, ndim, log_prob.batch, moves=moves, vectorize=True)
        return emcee.EnsembleSampler(settings.n_walkers, ndim, log_prob, moves=moves)

    def continued(old, name, indep=None, share=INDEPENDENCE_SHARE):
        fresh = []
        for s in old:
            f = ensemble(_moves(name, indep, share))
            f.random_state = s.random_state  # each ensemble's own stream continues
            fresh.append(f)
        return fresh

    def run_pilot(samplers, states):
        """The discarded pilot of DE (``samplers`` move by DE) from ``states``, then :func:`choose_pilot_proposal`:
        the samplers of the run that follows, their starts, the pilot's steps and the other evaluations it took."""
        n = min(PILOT_STEPS, settings.max_steps)
        states = [_advance(s, st, n, compute) for s, st in zip(samplers, states, strict=True)]
        chain = np.stack([s.get_chain() for s in samplers])
        kept_lp = np.stack([s.get_log_prob() for s in samplers])[:, int(PILOT_BURN * n):]
        indep, share, restart, n_trials, n_ridge = choose_pilot_proposal(
            log_prob, chain, kept_lp, float(np.mean([s.acceptance_fraction for s in samplers])), lower, upper,
            settings.n_walkers, seed)
        return (continued(samplers, "de+laplace", indep, share), restart if restart is not None else states, n,
                n_trials + n_ridge)

    pilot = settings.move == "de+pilot"
    compute = _log_prob_fn(log_prob)
    samplers, states = [], []
    for ss in seeds:
        rng = np.random.default_rng(ss)
        s = ensemble(_moves("de" if pilot else settings.move, indep))
        # emcee copies NumPy's global state at construction; give each ensemble its own instead.
        s.random_state = np.random.RandomState(rng.integers(2**32 - 1)).get_state()
        p0 = initial_positions(start, lower, upper, settings.n_walkers, rng, scale)
        samplers.append(s)
        states.append(p0)
    n_spent = n_other = pilot_after = 0  # steps outside the kept run (pilot, a given-up start); other evaluations
    # emcee refuses to start from an ensemble whose coordinates are badly conditioned (a performance heuristic, with
    # no bearing on correctness): the ball of initial_positions follows the Laplace covariance, which on a thin ridge
    # is nearly singular, and an ensemble sampling left on such a ridge is a valid state. The check is skipped; a
    # walker cloud that cannot move shows in τ and the convergence rules (:func:`_advance` makes no such check).
    if pilot:  # a discarded pilot run of DE gives the independence proposal, then held fixed
        samplers, states, n_spent, n_other = run_pilot(samplers, states)

    tau_prev = None
    reason = "step budget exhausted before τ settled"
    converged = False
    n_steps = 0
    tau = np.full(ndim, np.inf)
    rhat = np.full(ndim, np.inf)
    ess = np.zeros(ndim)
    burn = 0
    budget = settings.max_steps
    tau_low = math.inf  # the smallest finite largest-τ of the run's checks
    while n_steps < budget:
        n = min(settings.check_every, budget - n_steps)
        states = [_advance(s, st, n, compute) for s, st in zip(samplers, states, strict=True)]
        n_steps += n
        chains = np.stack([s.get_chain() for s in samplers])  # (E, T, W, D)
        burn = burn_in(burn, n_steps, tau)
        kept = chains[:, burn:]
        tau = np.max([tau_estimate(c) for c in kept], axis=0)
        tau_low = min(tau_low, float(np.max(tau)))
        long_enough = bool(np.all(kept.shape[1] > settings.tau_factor * tau))
        settled = tau_settled(tau, tau_prev, kept.shape[1], n, settings.n_walkers, settings.tau_rtol)
        tau_prev = tau
        # R-hat and ESS decide only once the chain is long enough and τ has settled; they are also reported at
        # the step budget and in the progress line (the same values a computation at every check gives there)
        if progress is not None or (long_enough and settled) or n_steps >= budget:
            rhat = post.rhat_across_ensembles(kept)
            ess = post.ess_bulk(kept)
        if progress is not None:
            progress(f"steps {n_steps}: τ_max {np.max(tau):.1f}, chain/τ {kept.shape[1] / np.max(tau):.0f}, "
                     f"R-hat {np.max(rhat):.3f}, ESS {np.min(ess):.0f}")
        if long_enough and settled:
            if np.all(rhat <= settings.rhat_max) and np.all(ess >= settings.ess_min):
                converged, reason = True, "converged"
                break
            reason = (f"τ settled but R-hat {np.max(rhat):.3f} (need ≤ {settings.rhat_max}) or "
                      f"ESS {np.min(ess):.0f} (need ≥ {settings.ess_min:.0f}) not met")
            if np.max(rhat) > GROSS_RHAT:
                reason = (f"ensembles disagree (R-hat {np.max(rhat):.2f} > {GROSS_RHAT}) after τ settled: "
                          "separate modes or a ridge the ensembles cannot cross")
                break
        elif long_enough:
            reason = "chain longer than 50 τ but τ still changing at the step budget"
        else:
            reason = f"chain only {kept.shape[1] / np.max(tau):.0f} τ long at the step budget"
        if (settings.move == "de+laplace" and ndim == 2 and not pilot_after and n_steps < budget
                and pilot_pays(float(np.max(tau)), tau_low, n_steps, settings.tau_factor)):
            # the walkers are leaving the Laplace proposal's reach: the pilot route from where they are
            pilot_after, budget = n_steps, budget - n_steps
            samplers, states, n_pilot, n_trials = run_pilot(continued(samplers, "de"), states)
            n_spent, n_other = n_spent + n_steps + n_pilot, n_other + n_trials
            n_steps, burn, tau_prev, tau = 0, 0, None, np.full(ndim, np.inf)

    chains = np.stack([s.get_chain() for s in samplers])[:, burn:]
    log_probs = np.stack([s.get_log_prob() for s in samplers])[:, burn:]
    acc = float(np.mean([s.acceptance_fraction for s in samplers]))
    return SamplingResult(chains, log_probs, tau, rhat, ess, n_steps, burn, converged, reason, acc,
                          (n_steps + n_spent) * settings.n_walkers * settings.n_ensembles + n_other, pilot_after)
