"""emcee sampling of one transient's posterior, with convergence checked rather than assumed.

emcee's walkers are not independent chains, so R-hat is computed across several *independently
started* ensembles, each with its own random generator and its own dispersed start. The stopping rule
is the integrated autocorrelation time τ: every ensemble runs until its post-burn-in chain is longer
than ``TAU_FACTOR`` τ for every parameter and the largest τ, which sets that length, has settled (changed by
less than ``TAU_RTOL`` between checks). Only then are the rank-normalised R-hat (across ensembles) and the bulk
ESS checked against ``GOOD_RHAT`` and ``MIN_ESS``. A run that exhausts its step budget first is reported as not
converged.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

#: Chain length required, in integrated autocorrelation times (emcee's documented rule of thumb).
TAU_FACTOR = 50.0
#: Relative change of the largest τ between two checks below which τ counts as settled. The largest τ is what the
#: length rule uses; asking every parameter's τ to settle (each a noisy estimate from a chain of some 50 τ: on a
#: 7-parameter window of cycles they moved by 5-10 % between checks long after R-hat, ESS and the length were met)
#: ran chains half as long again as the rule asks.
TAU_RTOL = 0.05
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
        posteriors such as whole records) or ``"de+pilot"`` (``"de+laplace"`` with the proposal's centre and
        covariance from a discarded pilot run of ``"de"``, :func:`pilot_proposal`: where no reliable
        covariance is known in advance; for two parameters whose posterior the Gaussian misses, the proposal
        follows the ridge's crest instead, :func:`ridge_proposal`, and the ensembles restart from it).
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
        Steps run per ensemble (burn-in included).
    burn_in : int
    converged : bool
    reason : str
        Why the run stopped ("converged", or what failed).
    acceptance : float
        Mean acceptance fraction.
    n_evaluations : int
        Log-posterior evaluations.
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

    def flat(self) -> np.ndarray:
        """All post-burn-in samples, shape (n_samples, ndim)."""
        return self.chain.reshape(-1, self.chain.shape[-1])


#: Share of the independence move in ``"de+laplace"``; the rest is ``"de"`` in its own proportions (so that
#: a poor approximation still leaves a working ridge-following move). Chosen on a benchmark record (a 1 kHz
#: sine + multisine, not a test's data): 0.5 / inflation 1.3 and 0.75 / 1.15 gave the same intervals; the
#: latter halved τ.
INDEPENDENCE_SHARE = 0.75
#: Degrees of freedom of the independence proposal's multivariate t (heavy tails: a posterior wider than
#: its Laplace approximation in some direction is still proposed there, if rarely).
INDEPENDENCE_DOF = 5.0
#: Scale of the independence proposal relative to the Laplace covariance (wider than the target, so that
#: the importance ratio target/proposal stays bounded in the bulk; with t tails, 1.15 kept the importance
#: ESS fraction near 0.6 on the benchmark record, 1.0 gave 0.72 and 1.6 gave 0.31).
INDEPENDENCE_INFLATION = 1.15


class LaplaceIndependenceMove:
    """Independence Metropolis-Hastings move: every walker proposes a fresh draw from a multivariate t
    centred at the posterior optimum with the Laplace covariance (times ``INDEPENDENCE_INFLATION``²),
    whatever its current position, and accepts it with the ratio π(x') g(x) / (π(x) g(x')).

    The proposal is fixed before sampling (not adapted from the chain), so every move keeps the posterior
    invariant and the chain stays exact whether or not the approximation is good. Where the posterior is
    close to Gaussian (a whole record that determines every parameter) most proposals are accepted and
    consecutive samples are nearly independent: τ of a few steps instead of tens. Where it is not (a ridge,
    a bound, two modes) the proposals are mostly rejected and the differential-evolution share does the
    work, at the cost of the share's evaluations.
    """

    def __init__(self, centre: np.ndarray, cov: np.ndarray, dof: float = INDEPENDENCE_DOF,
                 inflation: float = INDEPENDENCE_INFLATION):
        self.centre = np.asarray(centre, dtype=float)
        self.chol = np.linalg.cholesky(np.asarray(cov, dtype=float)) * inflation
        self.dof = float(dof)
        self._inv = np.linalg.inv(self.chol)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """Log density of the proposal at the rows of ``x``, up to a constant."""
        z = (np.atleast_2d(x) - self.centre) @ self._inv.T
        return -0.5 * (self.dof + self.centre.size) * np.log1p(np.sum(z * z, axis=1) / self.dof)

    def draw(self, n: int, random) -> np.ndarray:
        """``n`` draws (``random``: a ``numpy.random.RandomState``, the ensemble's own)."""
        z = random.standard_normal((n, self.centre.size))
        w = random.chisquare(self.dof, n) / self.dof
        return self.centre + (z / np.sqrt(w)[:, None]) @ self.chol.T

    def proposal(self, coords: np.ndarray, random) -> tuple[np.ndarray, np.ndarray]:
        """emcee ``MHMove`` proposal: new positions and ln g(x) − ln g(x')."""
        q = self.draw(coords.shape[0], random)
        return q, self.log_density(coords) - self.log_density(q)


#: Steps of the discarded pilot run of ``"de+pilot"``, and the share of them discarded before its covariance is
#: estimated (its own burn-in).
PILOT_STEPS, PILOT_BURN = 100, 0.5


def pilot_proposal(chains: np.ndarray) -> LaplaceIndependenceMove | None:
    """The independence proposal of ``"de+pilot"`` from a pilot run, shape (n_ensembles, n_steps, n_walkers, ndim).

    Centre and covariance are the median and covariance of the pilot's second half over all ensembles and
    walkers. The pilot is discarded and the proposal then held fixed, so the chain that follows is exact
    (adaptation in the warm-up only, as Stan's); a poor estimate costs efficiency, not correctness. None if the
    covariance is not positive definite (the run continues with plain DE). :func:`sample_posterior` also drops it
    when its proposals are accepted less often than the pilot's DE moves (:func:`independence_acceptance`): on a
    curved ridge a Gaussian proposal is mostly rejected, and its share of the moves would slow DE down. Otherwise
    the independence moves are chosen with the probability that they are accepted (at most
    :data:`INDEPENDENCE_SHARE`), so a proposal that covers only part of the target leaves DE the other steps.
    """
    kept = chains[:, int(PILOT_BURN * chains.shape[1]):]
    flat = kept.reshape(-1, kept.shape[-1])
    cov = np.atleast_2d(np.cov(flat.T))
    try:
        return LaplaceIndependenceMove(np.median(flat, axis=0), cov)
    except np.linalg.LinAlgError:
        return None


#: Independence proposals drawn to estimate their acceptance after the pilot (evaluations of the target).
PILOT_TRIALS = 96


def independence_acceptance(log_prob, move: LaplaceIndependenceMove, current: np.ndarray, current_lp: np.ndarray,
                            rng: np.random.Generator) -> float:
    """Mean Metropolis-Hastings acceptance of ``move``'s independence proposals from states of the target.

    ``current`` (n, ndim) are draws of the target (the pilot's second half) with their log-densities
    ``current_lp``; :data:`PILOT_TRIALS` of them each get a fresh proposal x', accepted with
    min(1, π(x') g(x) / (π(x) g(x'))).
    """
    pick = rng.choice(current.shape[0], size=min(PILOT_TRIALS, current.shape[0]), replace=False)
    x, lp_x = current[pick], current_lp[pick]
    q = move.draw(pick.size, np.random.RandomState(rng.integers(2**32 - 1)))
    lp_q = np.asarray(log_prob.batch(q) if hasattr(log_prob, "batch") else [log_prob(z) for z in q], dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        log_r = lp_q - lp_x + move.log_density(x) - move.log_density(q)
    return float(np.mean(np.where(np.isfinite(log_r), np.exp(np.minimum(log_r, 0.0)), 0.0)))


#: The ridge proposal's walk along its axis stops where the crest's log-density has fallen this far below the best
#: crest point [nats] (a stretch of e^-20 of the peak's density holds nothing a chain of some thousand draws shows).
RIDGE_DROP = 20.0
#: Largest change of the Laplace log-weight (crest log-density plus log width) between neighbouring crest points
#: [nats]: a step that changes it more is halved and taken again, one that changes it by less than a fifth of this
#: makes the next step half as long again, so the log-linear interpolation between points is never off by much more.
RIDGE_STEP_NATS = 1.0
#: Crest points per direction of the walk (a bound on its cost: some 15-20 evaluations each).
RIDGE_MAX_POINTS = 150
#: Share of the ridge proposal's axis density that is uniform over the prior box's extent along the axis: every
#: point of the box is proposed with a density bounded away from zero, so the target-to-proposal ratio stays bounded
#: wherever the walk did not reach (a defensive mixture, Hesterberg 1995).
RIDGE_DEFENSIVE = 0.05


class RidgeIndependenceMove:
    """Independence Metropolis-Hastings move for a two-parameter posterior that is a long, thin, possibly curved
    and multi-lobed ridge (a transient's (log α_V, log p_R) where the data fix one combination of the two only).

    In the frame of the pilot's principal axes (a along the ridge, b across it; a rotation, so densities are the
    same in either frame) the proposal is

        g(a, b) = [(1 − ε) r(a) + ε / (A_hi − A_lo)] · t_ν(b; c(a), s(a) · inflation)

    with ``(a_k, c_k, s_k, L_k)`` crest points of the target found by :func:`ridge_proposal` (c_k the crest's b at
    a_k, L_k the log-density there, s_k the curvature width across it), r the density along the axis that is
    log-linear between crest points with log-weights L_k + log s_k (the Laplace marginal), c and s interpolated
    linearly (held at the ends' values beyond them), and [A_lo, A_hi] the prior box's extent along the axis
    (ε = :data:`RIDGE_DEFENSIVE`). Held fixed once built, so the chain is exact whatever the crest points' quality.
    """

    def __init__(self, centre, axes, a, crest, width, log_weight, a_range, dof: float = INDEPENDENCE_DOF,
                 inflation: float = INDEPENDENCE_INFLATION, defensive: float = RIDGE_DEFENSIVE):
        self.centre = np.asarray(centre, dtype=float)
        self.axes = np.asarray(axes, dtype=float)  # columns: along, across
        order = np.argsort(a)
        self.a = np.asarray(a, dtype=float)[order]
        self.crest = np.asarray(crest, dtype=float)[order]
        self.width = np.asarray(width, dtype=float)[order] * inflation
        lw = np.asarray(log_weight, dtype=float)[order]
        self.lw = lw - np.max(lw)
        self.a_range = (float(a_range[0]), float(a_range[1]))
        self.dof = float(dof)
        self.defensive = float(defensive)
        # masses of the log-linear pieces between crest points: ∫ exp(l0 + (l1 - l0) u) da over each piece
        da = np.diff(self.a)
        l0, l1 = self.lw[:-1], self.lw[1:]
        k = l1 - l0
        curved = np.abs(k) > 1e-9
        mass = np.where(curved, da * (np.exp(l1) - np.exp(l0)) / np.where(curved, k, 1.0), da * np.exp(l0))
        self._mass = mass / np.sum(mass)
        self._log_norm = float(np.log(np.sum(mass)))

    def _frame(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.atleast_2d(x) - self.centre
        return d @ self.axes[:, 0], d @ self.axes[:, 1]

    def _axis_log_density(self, a: np.ndarray) -> np.ndarray:
        lo, hi = self.a_range
        inside = (a >= self.a[0]) & (a <= self.a[-1])
        lr = np.interp(a, self.a, self.lw) - self._log_norm
        ridge = np.where(inside, (1.0 - self.defensive) * np.exp(lr), 0.0)
        dens = ridge + np.where((a >= lo) & (a <= hi), self.defensive / (hi - lo), 0.0)
        with np.errstate(divide="ignore"):
            return np.log(dens)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """Log density of the proposal at the rows of ``x`` (normalised)."""
        a, b = self._frame(x)
        s = np.interp(a, self.a, self.width)
        z = (b - np.interp(a, self.a, self.crest)) / s
        nu = self.dof
        log_t = math.lgamma(0.5 * (nu + 1.0)) - math.lgamma(0.5 * nu) - 0.5 * math.log(nu * math.pi)
        return self._axis_log_density(a) - np.log(s) + log_t - 0.5 * (nu + 1.0) * np.log1p(z * z / nu)

    def draw(self, n: int, random) -> np.ndarray:
        """``n`` draws (``random``: a ``numpy.random.RandomState``)."""
        lo, hi = self.a_range
        piece = random.choice(self._mass.size, size=n, p=self._mass)
        u = random.uniform(size=n)
        k = self.lw[piece + 1] - self.lw[piece]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            frac = np.where(np.abs(k) > 1e-9, np.log1p(u * np.expm1(k)) / np.where(np.abs(k) > 1e-9, k, 1.0), u)
        a = self.a[piece] + np.clip(frac, 0.0, 1.0) * (self.a[piece + 1] - self.a[piece])
        a = np.where(random.uniform(size=n) < self.defensive, random.uniform(lo, hi, size=n), a)
        t = random.standard_normal(n) / np.sqrt(random.chisquare(self.dof, n) / self.dof)
        b = np.interp(a, self.a, self.crest) + t * np.interp(a, self.a, self.width)
        return self.centre + np.outer(a, self.axes[:, 0]) + np.outer(b, self.axes[:, 1])

    def proposal(self, coords: np.ndarray, random) -> tuple[np.ndarray, np.ndarray]:
        """emcee ``MHMove`` proposal: new positions and ln g(x) − ln g(x')."""
        q = self.draw(coords.shape[0], random)
        return q, self.log_density(coords) - self.log_density(q)


def ridge_proposal(log_prob, chains: np.ndarray, chain_lp: np.ndarray, lower: np.ndarray,
                   upper: np.ndarray) -> tuple[RidgeIndependenceMove | None, int]:
    """The :class:`RidgeIndependenceMove` of a two-parameter target from a pilot run, and the evaluations it took.

    ``chains`` (n_ensembles, n_steps, n_walkers, 2) and their log-densities ``chain_lp`` are the pilot's second half.
    The pilot gives the ridge's axis (its principal axes) and its best point; from there the crest is followed
    along the axis in both directions: at each step the target is maximised across the axis (bounded Brent, from
    the crest's extrapolated position) and its curvature there gives the width. Steps adapt to the crest's change
    (:data:`RIDGE_STEP_NATS`); the walk ends :data:`RIDGE_DROP` nats below the best crest point, at the prior box or
    at a failed solve. Lobes along the ridge that the pilot never reached are found this way, and the proposal puts
    their Laplace mass there. None (and the evaluations spent) for another dimension, a degenerate pilot or a
    crest of fewer than three points.
    """
    from scipy.optimize import minimize_scalar

    flat = chains.reshape(-1, chains.shape[-1])
    if flat.shape[1] != 2:
        return None, 0
    lps = chain_lp.reshape(-1)
    cov = np.cov(flat.T)
    if not np.all(np.isfinite(cov)):
        return None, 0
    evals, vecs = np.linalg.eigh(cov)
    if evals[0] <= 0:
        return None, 0
    axes = vecs[:, ::-1]  # along (largest variance), across
    sd_along, sd_across = float(np.sqrt(evals[1])), float(np.sqrt(evals[0]))
    centre = np.median(flat, axis=0)
    corners = np.array([[lower[0], lower[1]], [lower[0], upper[1]], [upper[0], lower[1]], [upper[0], upper[1]]])
    proj = (corners - centre) @ axes[:, 0]
    a_range = (float(proj.min()), float(proj.max()))
    n_eval = 0

    def lp(a: float, b: float) -> float:
        nonlocal n_eval
        x = centre + a * axes[:, 0] + b * axes[:, 1]
        if np.any(x <= lower) or np.any(x >= upper):
            return -np.inf
        n_eval += 1
        v = float(log_prob(x))
        return v if np.isfinite(v) else -np.inf

    def crest(a: float, guess: float, width: float) -> tuple[float, float, float]:
        """(b, log-density, width) of the crest across the axis at ``a``."""
        lo, hi = guess - 4.0 * width, guess + 4.0 * width
        def cost(b: float) -> float:
            v = lp(a, b)
            return -v if np.isfinite(v) else 1e300

        for _ in range(3):  # re-centred while the maximum sits at the bracket's edge
            r = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 0.02 * width})
            b = float(r.x)
            if min(b - lo, hi - b) > 0.1 * (hi - lo):
                break
            lo, hi = b - 4.0 * width, b + 4.0 * width
        top = lp(a, b)
        if not np.isfinite(top):
            return b, -np.inf, width
        h = 0.5 * width
        curv = -(lp(a, b + h) - 2.0 * top + lp(a, b - h)) / (h * h)
        return b, top, (1.0 / np.sqrt(curv) if np.isfinite(curv) and curv > 0 else width)

    best = flat[int(np.argmax(lps))] - centre
    b0, top0, w0 = crest(float(best @ axes[:, 0]), float(best @ axes[:, 1]), sd_across)
    if not np.isfinite(top0):
        return None, n_eval
    points = [(float(best @ axes[:, 0]), b0, top0, w0)]
    min_step = 1e-3 * sd_along
    for direction in (1.0, -1.0):
        step = 0.5 * sd_along
        prev = [points[0]]
        while len(prev) <= RIDGE_MAX_POINTS:
            a_prev, b_prev, l_prev, w_prev = prev[-1]
            a_new = a_prev + direction * step
            if not a_range[0] < a_new < a_range[1]:
                break
            slope = (prev[-1][1] - prev[-2][1]) / (prev[-1][0] - prev[-2][0]) if len(prev) > 1 else 0.0
            b_new, l_new, w_new = crest(a_new, b_prev + slope * (a_new - a_prev), w_prev)
            if not np.isfinite(l_new):
                break
            change = abs((l_new + np.log(w_new)) - (l_prev + np.log(w_prev)))
            if change > RIDGE_STEP_NATS and step > min_step:  # too coarse for the interpolation: a shorter step
                step /= 2.0
                continue
            prev.append((a_new, b_new, l_new, w_new))
            if l_new < max(p[2] for p in points + prev) - RIDGE_DROP:
                break
            if change < 0.2 * RIDGE_STEP_NATS:
                step *= 1.5
        points += prev[1:]
    if len(points) < 3:
        return None, n_eval
    a, b, top, width = (np.array(v) for v in zip(*points, strict=True))
    move = RidgeIndependenceMove(centre, axes, a, b, width, top + np.log(width), a_range)
    return move, n_eval


#: Draws of the ridge proposal per ensemble from which the ensemble's walkers are resampled (:func:`ridge_restart`).
RIDGE_RESTART_DRAWS = 200


def ridge_restart(log_prob, move: RidgeIndependenceMove, n_ensembles: int, n_walkers: int,
                  rng: np.random.Generator) -> tuple[list, np.ndarray, np.ndarray, int] | None:
    """New starting walkers for every ensemble from the ridge proposal, resampled by importance weight.

    A pilot started at an optimiser's point on a long thin ridge can sit far down the ridge from its mass (a
    Nelder-Mead simplex stalls on a thin curved crest: rig-A's slowest reversals with the diagnosed model), and DE
    climbs such a ridge slowly. Each ensemble instead
    draws :data:`RIDGE_RESTART_DRAWS` points from ``move`` and keeps ``n_walkers`` distinct ones with probability
    proportional to target / proposal (sampling importance resampling, Rubin 1988): independent starts, each
    close to the target. Returns (starts per ensemble, the pooled resampled states and their log-densities for the
    acceptance check, evaluations), or None when fewer than ``n_walkers`` draws of an ensemble have a finite
    weight (the pilot's walkers are kept).
    """
    starts, cur, cur_lp = [], [], []
    for _ in range(n_ensembles):
        q = move.draw(RIDGE_RESTART_DRAWS, np.random.RandomState(rng.integers(2**32 - 1)))
        lq = np.asarray(log_prob.batch(q) if hasattr(log_prob, "batch") else [log_prob(z) for z in q], dtype=float)
        with np.errstate(invalid="ignore"):
            lw = np.where(np.isfinite(lq), lq - move.log_density(q), -np.inf)
        ok = np.isfinite(lw)
        if ok.sum() < n_walkers:
            return None
        w = np.where(ok, np.exp(lw - np.max(lw[ok])), 0.0)
        pick = rng.choice(q.shape[0], size=n_walkers, replace=False, p=w / w.sum())
        starts.append(q[pick])
        resampled = rng.choice(q.shape[0], size=PILOT_TRIALS // n_ensembles, replace=True, p=w / w.sum())
        cur.append(q[resampled])
        cur_lp.append(lq[resampled])
    return starts, np.concatenate(cur), np.concatenate(cur_lp), n_ensembles * RIDGE_RESTART_DRAWS


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


def _tau(chain: np.ndarray) -> np.ndarray:
    """τ per parameter of one ensemble's chain, shape (n_steps, n_walkers, ndim).

    A parameter whose walkers never moved has no defined τ; it is reported as infinite, so the run
    cannot pass as converged.
    """
    import emcee

    with np.errstate(invalid="ignore", divide="ignore"):
        tau = emcee.autocorr.integrated_time(chain, c=5, tol=0, quiet=True)
    return np.where(np.isfinite(tau), tau, np.inf)


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
    n_pilot = n_trials = n_ridge = 0
    # emcee refuses to start from an ensemble whose coordinates are badly conditioned (a performance heuristic, with
    # no bearing on correctness): the ball of initial_positions follows the Laplace covariance, which on a thin ridge
    # is nearly singular, and an ensemble sampling left on such a ridge is a valid state. The check is skipped; a
    # walker cloud that cannot move shows in τ and the convergence rules (:func:`_advance` makes no such check).
    if pilot:  # a discarded pilot run of DE gives the independence proposal, then held fixed
        n_pilot = min(PILOT_STEPS, settings.max_steps)
        states = [_advance(s, st, n_pilot, compute) for s, st in zip(samplers, states, strict=True)]
        pilot_chain = np.stack([s.get_chain() for s in samplers])
        half = int(PILOT_BURN * n_pilot)
        kept_lp = np.stack([s.get_log_prob() for s in samplers])[:, half:]
        de_rate = float(np.mean([s.acceptance_fraction for s in samplers]))
        indep = pilot_proposal(pilot_chain)
        trial_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(settings.n_ensembles + 1)[-1])
        rate = -1.0
        if indep is not None:
            rate = independence_acceptance(log_prob, indep, pilot_chain[:, half:].reshape(-1, ndim),
                                           kept_lp.reshape(-1), trial_rng)
            n_trials = min(PILOT_TRIALS, kept_lp.size)
        if ndim == 2 and rate < de_rate:  # the Gaussian misses the target's shape: follow its ridge instead
            ridge, n_ridge = ridge_proposal(log_prob, pilot_chain[:, half:], kept_lp, lower, upper)
            if ridge is not None:
                restart = ridge_restart(log_prob, ridge, settings.n_ensembles, settings.n_walkers,
                                        np.random.default_rng(np.random.SeedSequence(seed).spawn(
                                            settings.n_ensembles + 2)[-1]))
                if restart is not None:
                    states, current, current_lp, n_sir = restart
                    n_ridge += n_sir
                    indep = ridge
                    rate = independence_acceptance(log_prob, ridge, current, current_lp, trial_rng)
                    n_trials += min(PILOT_TRIALS, current_lp.size)
        share = INDEPENDENCE_SHARE
        if indep is not None:  # kept only if accepted at least as often as DE was in the pilot (else plain DE), and
            # chosen as often as it is accepted: a proposal that misses part of the target leaves DE more steps
            if rate < de_rate:
                indep = None
            share = min(rate, INDEPENDENCE_SHARE)
        fresh = []
        for s in samplers:
            f = ensemble(_moves("de+laplace", indep, share))
            f.random_state = s.random_state  # each ensemble's own stream continues
            fresh.append(f)
        samplers = fresh

    tau_prev = None
    reason = "step budget exhausted before τ settled"
    converged = False
    n_steps = 0
    tau = np.full(ndim, np.inf)
    rhat = np.full(ndim, np.inf)
    ess = np.zeros(ndim)
    burn = 0
    while n_steps < settings.max_steps:
        n = min(settings.check_every, settings.max_steps - n_steps)
        states = [_advance(s, st, n, compute) for s, st in zip(samplers, states, strict=True)]
        n_steps += n
        chains = np.stack([s.get_chain() for s in samplers])  # (E, T, W, D)
        burn = min(n_steps // 3, int(math.ceil(10 * np.max(tau)))) if np.all(np.isfinite(tau)) else n_steps // 3
        kept = chains[:, burn:]
        tau = np.max([_tau(c) for c in kept], axis=0)
        long_enough = bool(np.all(kept.shape[1] > settings.tau_factor * tau))
        with np.errstate(invalid="ignore"):
            settled = tau_prev is not None and bool(abs(np.max(tau) - np.max(tau_prev))
                                                    < settings.tau_rtol * np.max(tau))
        tau_prev = tau
        # R-hat and ESS decide only once the chain is long enough and τ has settled; they are also reported at
        # the step budget and in the progress line (the same values a computation at every check gives there)
        if progress is not None or (long_enough and settled) or n_steps >= settings.max_steps:
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

    chains = np.stack([s.get_chain() for s in samplers])[:, burn:]
    log_probs = np.stack([s.get_log_prob() for s in samplers])[:, burn:]
    acc = float(np.mean([s.acceptance_fraction for s in samplers]))
    return SamplingResult(chains, log_probs, tau, rhat, ess, n_steps, burn, converged, reason, acc,
                          (n_steps + n_pilot) * settings.n_walkers * settings.n_ensembles + n_trials + n_ridge)
