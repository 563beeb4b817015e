"""Independence proposals of the samplers' ``"de+laplace"`` and ``"de+pilot"`` moves.

An independence Metropolis-Hastings move proposes a fresh point from a fixed density g whatever the walker's
position and accepts it with π(x') g(x) / (π(x) g(x')): fixed before the kept chain begins, it leaves the chain
exact whatever g's quality (a poor g costs efficiency only). Two densities: the multivariate t about a Laplace or
pilot estimate (:class:`LaplaceIndependenceMove`, :func:`pilot_proposal`) for posteriors close to Gaussian, and, for
two parameters, one that follows a posterior's crest (:class:`RidgeIndependenceMove`, :func:`ridge_proposal`).

A transient whose data fix one combination of (log α_V, log p_R) only has a posterior that is a long, thin, often
curved ridge, with its mass where the ridge's crest is highest and its width largest. A Gaussian misses such a shape,
and an optimiser's start can lie far down the ridge from the mass, where differential evolution climbs slowly.
:func:`ridge_proposal` follows the crest from the pilot's best point in both directions,
:class:`RidgeIndependenceMove` proposes along it with the Laplace mass of every stretch, and :func:`ridge_restart`
starts the ensembles from it. :func:`choose_pilot_proposal` decides between them after the pilot.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["INDEPENDENCE_DOF", "INDEPENDENCE_INFLATION", "INDEPENDENCE_SHARE", "PILOT_BURN", "PILOT_STEPS",
           "PILOT_TRIALS", "RIDGE_DEFENSIVE", "RIDGE_DROP", "RIDGE_MAX_POINTS", "RIDGE_RESTART_DRAWS",
           "RIDGE_STEP_NATS", "RIDGE_WIDTH_DROP", "RIDGE_WIDTH_TRIES", "LaplaceIndependenceMove",
           "RidgeIndependenceMove", "choose_pilot_proposal", "evaluate", "independence_acceptance", "pilot_proposal",
           "ridge_proposal", "ridge_restart"]

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


def evaluate(log_prob, x: np.ndarray) -> np.ndarray:
    """``log_prob`` at the rows of ``x``: one ``log_prob.batch`` call where there is one, else row by row."""
    return np.asarray(log_prob.batch(x) if hasattr(log_prob, "batch") else [log_prob(z) for z in x], dtype=float)


#: Steps of the discarded pilot run of ``"de+pilot"``, and the share of them discarded before its covariance is
#: estimated (its own burn-in).
PILOT_STEPS, PILOT_BURN = 100, 0.5


def pilot_proposal(chains: np.ndarray) -> LaplaceIndependenceMove | None:
    """The independence proposal of ``"de+pilot"`` from a pilot run, shape (n_ensembles, n_steps, n_walkers, ndim).

    Centre and covariance are the median and covariance of the pilot's second half over all ensembles and
    walkers. The pilot is discarded and the proposal then held fixed, so the chain that follows is exact
    (adaptation in the warm-up only, as Stan's); a poor estimate costs efficiency, not correctness. None if the
    covariance is not positive definite (the run continues with plain DE). :func:`choose_pilot_proposal` also drops
    it when its proposals are accepted less often than the pilot's DE moves (:func:`independence_acceptance`): on a
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
    lp_q = evaluate(log_prob, q)
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
#: Mean drop of the log-density [nats] across the crest over which its width is measured (a quarter to four nats:
#: inside the Gaussian core, above a solver's noise), and the rescalings of the step tried to get there.
RIDGE_WIDTH_DROP, RIDGE_WIDTH_TRIES = (0.25, 4.0), 6
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
    a_k, L_k the log-density there, s_k the width across it), r the density along the axis that is
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
    the crest's extrapolated position) and the drop over a step across it gives the width (:data:`RIDGE_WIDTH_DROP`).
    Steps adapt to the crest's change
    (:data:`RIDGE_STEP_NATS`); the walk ends :data:`RIDGE_DROP` nats below the best crest point, at the prior box or
    at a failed solve, the last two reached by halving the step (down to a thousandth of the pilot's sd along the
    axis): a posterior whose mass lies against the box's edge keeps that stretch of its crest. Lobes along the ridge
    that the pilot never reached are found this way, and the proposal puts their Laplace mass there. None (and the
    evaluations spent) for another dimension, a degenerate pilot or a crest of fewer than three points.
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

    def inside(a: float) -> tuple[float, float]:
        """The b of the line across the axis at ``a`` that lie inside the box (an empty interval: lo >= hi)."""
        p = centre + a * axes[:, 0]
        v = axes[:, 1]
        lo, hi = -np.inf, np.inf
        for i in range(2):
            if v[i] != 0.0:
                e0, e1 = sorted(((lower[i] - p[i]) / v[i], (upper[i] - p[i]) / v[i]))
                lo, hi = max(lo, e0), min(hi, e1)
            elif not lower[i] < p[i] < upper[i]:
                return 0.0, 0.0
        return lo, hi

    def crest(a: float, guess: float, width: float) -> tuple[float, float, float]:
        """(b, log-density, width) of the crest across the axis at ``a``: searched in a bracket about ``guess``
        clipped to the box, so that a crest cut by the box (a posterior whose mass lies in one of its corners) ends
        on the box's edge instead of lost outside it."""
        box_lo, box_hi = inside(a)
        lo, hi = max(guess - 4.0 * width, box_lo), min(guess + 4.0 * width, box_hi)
        if lo >= hi:
            return guess, -np.inf, width

        def cost(b: float) -> float:
            v = lp(a, b)
            return -v if np.isfinite(v) else 1e300

        for _ in range(3):  # re-centred while the maximum sits at the bracket's edge (not the box's)
            r = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 0.02 * min(width, hi - lo)})
            b = float(r.x)
            edge = min(b - lo if lo > box_lo else np.inf, hi - b if hi < box_hi else np.inf)
            if edge > 0.1 * (hi - lo):
                break
            lo, hi = max(b - 4.0 * width, box_lo), min(b + 4.0 * width, box_hi)
        top = lp(a, b)
        if not np.isfinite(top):
            return b, -np.inf, width
        # the width from the mean drop d over ±h, w = h / sqrt(2 d) for a Gaussian cross-section, with h scaled by 4
        # until d lies in RIDGE_WIDTH_DROP: a step far inside the crest measures the solver's noise (widths that
        # collapse step by step and lose the crest), one far outside it the tails
        h, w = width, width
        for _ in range(RIDGE_WIDTH_TRIES):
            drop = top - 0.5 * (lp(a, b + h) + lp(a, b - h))
            if not np.isfinite(drop) or drop > RIDGE_WIDTH_DROP[1]:
                h /= 4.0
            elif drop < RIDGE_WIDTH_DROP[0]:
                h *= 4.0
            else:
                w = h / math.sqrt(2.0 * drop)
                break
        return b, top, w

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
            l_new = -np.inf
            if a_range[0] < a_new < a_range[1]:
                slope = (prev[-1][1] - prev[-2][1]) / (prev[-1][0] - prev[-2][0]) if len(prev) > 1 else 0.0
                b_new, l_new, w_new = crest(a_new, b_prev + slope * (a_new - a_prev), w_prev)
            if not np.isfinite(l_new):  # the box's edge (or where the crest leaves it, or the solves fail) is near
                if step > min_step:  # closer to it, in shorter steps
                    step /= 2.0
                    continue
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
        lq = evaluate(log_prob, q)
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


def choose_pilot_proposal(log_prob, pilot_chain: np.ndarray, kept_lp: np.ndarray, de_rate: float,
                          lower: np.ndarray, upper: np.ndarray, n_walkers: int, seed: int):
    """The independence proposal of ``"de+pilot"`` after its pilot, and what it changes.

    ``pilot_chain`` (n_ensembles, n_steps, n_walkers, ndim) is the whole pilot, ``kept_lp`` the log-densities of its
    second half and ``de_rate`` the pilot's DE acceptance. The pilot's Gaussian (:func:`pilot_proposal`) is measured
    from the pilot's second half (:func:`independence_acceptance`); for two parameters, where it is accepted less
    often than DE was, the ridge proposal is built instead, the ensembles restart from it (:func:`ridge_restart`) and
    its acceptance is measured from the restart's resampled states. The proposal is kept only if accepted at least
    as often as DE was in the pilot (else plain DE), and chosen as often as it is accepted (at most
    :data:`INDEPENDENCE_SHARE`): a proposal that misses part of the target leaves
    DE more steps. Returns (proposal or None, its share, new starting walkers per ensemble or None, evaluations of
    the acceptance trials, evaluations of the ridge and restart).
    """
    n_ensembles, n_pilot, _, ndim = pilot_chain.shape
    half = n_pilot - kept_lp.shape[1]
    indep = pilot_proposal(pilot_chain)
    trial_rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(n_ensembles + 1)[-1])
    rate, n_trials, n_ridge, states = -1.0, 0, 0, None
    if indep is not None:
        rate = independence_acceptance(log_prob, indep, pilot_chain[:, half:].reshape(-1, ndim), kept_lp.reshape(-1),
                                       trial_rng)
        n_trials = min(PILOT_TRIALS, kept_lp.size)
    if ndim == 2 and rate < de_rate:  # the Gaussian misses the target's shape: follow its ridge instead
        ridge, n_ridge = ridge_proposal(log_prob, pilot_chain[:, half:], kept_lp, lower, upper)
        if ridge is not None:
            restart = ridge_restart(log_prob, ridge, n_ensembles, n_walkers, np.random.default_rng(
                np.random.SeedSequence(seed).spawn(n_ensembles + 2)[-1]))
            if restart is not None:
                states, current, current_lp, n_sir = restart
                n_ridge += n_sir
                indep = ridge
                rate = independence_acceptance(log_prob, ridge, current, current_lp, trial_rng)
                n_trials += min(PILOT_TRIALS, current_lp.size)
    if indep is not None and rate < de_rate:
        indep = None
    return indep, min(rate, INDEPENDENCE_SHARE), states, n_trials, n_ridge
