"""Stage 2 as a *cut* (modular) posterior: the step's Δp and stage 1 propagate into α_V and p_R, not back.

A transient's parameters come from three parts of a triangular test, each with its own data:

* the four flow coefficients θ_c from the plateaus (stage 1; its posterior is the Gaussian of
  :class:`~bayesdamper.inference.joint.StageOnePrior`, restricted to θ_c >= 0 as eq. (8) needs: this matters
  only for a coefficient near 0, such as one stage 1 held at 0, and the joint coupling's box ends there too),
* the pressure difference at the step Δp0 from the samples just before the step (mean of AR(1) noise of the
  plateaus' colour: :meth:`~bayesdamper.inference.joint.JointProblem.dp0_sd`),
* α_V and p_R from the transient window (eq. (9) residual, AR(1) innovations with φ from the plateaus, the
  window's scale marginalised: the likelihood of :mod:`bayesdamper.inference.joint`).

The joint posterior (``--coupling joint``) lets the window re-estimate θ1 = (Δp0, θ_c). Where eq. (7) is
exact that only sharpens them a little; under model error it lets the misfit of the dynamics drag the static
coefficients and the step force away from what their own data say (two-state data: C_L12 moved by
up to 4.6 stage-1 sds in starts from rest, and Δp0 by 4.5 sds of the pre-step mean), and α_V, p_R move with
them, away from the eq. (9) optimum. The *cut distribution* (Liu, Bayarri & Berger 2009, "Modularization in
Bayesian analysis, with emphasis on analysis of computer models"; Plummer 2015, "Cuts in Bayesian graphical
models") keeps each module's parameters where its own data put them and propagates their uncertainty
downstream only:

    p_cut(θ2) = ∫ p(θ2 | θ1, window) p(θ1 | plateaus, pre-step samples) dθ1,   θ2 = (log α_V, log p_R).

Computed here (:func:`propagate`) as the conditional posterior of θ2 at the estimate θ̂1, sampled by emcee,
with every draw moved along the path of the conditional optimum, θ2 + S (θ1 − θ̂1), θ1 drawn from its own
posterior, S = −(J2ᵀJ2)⁻¹ J2ᵀJ1 the Gauss-Newton sensitivity of the window's optimum to θ1 (implicit function
theorem; J the Jacobian of the whitened window residual). The linearisation is over θ1's own spread (stage-1
coefficients ~1 %, Δp0 a few hundred Pa), where the optimum path is straight to the accuracy that matters: the
test compares with re-optimising at drawn θ1 (tests/test_cut.py).

What the intervals mean: on eq. (7) data they hold the truth at their nominal rate; under model error they
aim at the eq. (9) optimum of the noise-free record (residual weighted by the noise colour) at the true step
force and flow coefficients, the pseudo-true value, and they widen by σ_w/σ_e where
the window's misfit exceeds the noise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bayesdamper.inference.joint import BOX_SDS, FIT_ATOL, FIT_RTOL, JointLogPosterior, central_jacobian

__all__ = ["COUPLINGS", "ConditionalLogPosterior", "CutFit", "fit_conditional", "module_covariance", "propagate"]

#: Stage-2 couplings of the window to Δp0 and stage 1: ``cut`` (default, this module), ``joint``
#: (:mod:`~bayesdamper.inference.joint`: sampled together, the window informs them).
COUPLINGS = ("cut", "joint")
#: Indices of θ1 = (Δp0, C_L12, C_Q12, C_L21, C_Q21) in the joint vector.
THETA1 = np.arange(2, 7)
#: Redraws of θ1 for a draw whose moved (α_V, p_R) leaves the prior box (the prior truncates the cut
#: distribution there) or whose flow coefficients are not all >= 0; a draw still outside after these is clipped to
#: the box and to 0.
MAX_REDRAWS = 20


def theta2_index(ndim: int) -> np.ndarray:
    """Indices of θ2 in the joint vector: log α_V, log p_R[, φ when it is sampled (8 entries)]."""
    return np.array([0, 1] + ([7] if ndim == 8 else []))


class ConditionalLogPosterior:
    """Log-posterior of θ2 given θ1 = ``theta1`` (picklable; -inf outside the box, never NaN).

    The joint log-posterior at (θ2, θ1): its pre-step and flow-prior terms are constant in θ2, so this is the
    conditional posterior p(θ2 | θ1, window) up to a constant (the window's first innovation conditioned on the
    last pre-step residual, as the AR(1) noise runs across the step).
    """

    def __init__(self, joint: JointLogPosterior, theta1: np.ndarray):
        self.joint = joint
        self.theta1 = np.asarray(theta1, dtype=float)
        self.index = theta2_index(joint.space.ndim)
        self.lower, self.upper = joint.space.lower[self.index], joint.space.upper[self.index]

    def full(self, thetas2: np.ndarray) -> np.ndarray:
        """Joint rows from θ2 rows, shape (n, joint ndim)."""
        thetas2 = np.atleast_2d(np.asarray(thetas2, dtype=float))
        rows = np.empty((thetas2.shape[0], self.joint.space.ndim))
        rows[:, THETA1] = self.theta1
        rows[:, self.index] = thetas2
        return rows

    def batch(self, thetas2: np.ndarray) -> np.ndarray:
        return self.joint.batch(self.full(thetas2))

    def __call__(self, theta2: np.ndarray) -> float:
        return float(self.batch(theta2)[0])


@dataclass(frozen=True)
class CutFit:
    """The conditional optimum and what the cut needs of it.

    Attributes
    ----------
    x2 : ndarray, shape (n2,)
        Conditional MAP of θ2 (transformed units).
    cov2 : ndarray, shape (n2, n2) or None
        Gauss-Newton covariance of θ2 at θ̂1 (None if singular).
    sensitivity : ndarray, shape (n2, 5)
        d θ2* / d θ1 (rows: θ2; columns: Δp0 [Pa], the four flow coefficients [SI]).
    sigma_w : float
        Window innovation scale at the optimum [N].
    """

    x2: np.ndarray
    cov2: np.ndarray | None
    sensitivity: np.ndarray
    sigma_w: float


def module_covariance(joint: JointLogPosterior) -> np.ndarray:
    """Covariance of θ1 under its own data, shape (5, 5): Δp0 from the pre-step samples (AR(1) mean of the
    plateaus' noise), independent of the flow coefficients' stage-1 Gaussian."""
    p = joint.problem
    cov = np.zeros((5, 5))
    cov[0, 0] = p.dp0_sd() ** 2
    cov[1:, 1:] = p.prior.prior_cov
    return cov


def _window_residual(joint: JointLogPosterior, theta: np.ndarray, phi: float, sigma_w: float) -> np.ndarray | None:
    """Whitened window innovations at a joint ``theta`` (the pre-step and prior rows dropped)."""
    w = joint.whitened(theta, phi, sigma_w, FIT_RTOL, FIT_ATOL)
    if w is None:
        return None
    n_pre, n_w = joint.problem.pre_force.size, joint.problem.force.size
    return w[n_pre:n_pre + n_w]


def fit_conditional(joint: JointLogPosterior, theta1: np.ndarray, start2: np.ndarray) -> CutFit:
    """Least-squares conditional MAP of θ2 at θ1, its Gauss-Newton covariance and the sensitivity S.

    (log α_V, log p_R) are fitted at a fixed window scale re-set twice (as :func:`joint.fit_map`); a sampled φ
    (``--noise-model ar1``) keeps its start and gets a small independent variance. S by central differences of
    the whitened window residual in all seven model entries.
    """
    from scipy.optimize import least_squares

    space = joint.space
    idx = theta2_index(space.ndim)
    phi = float(start2[2]) if idx.size == 3 else joint._phi
    lo, hi = space.lower[:2], space.upper[:2]
    x = np.clip(np.asarray(start2[:2], dtype=float), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    cond = ConditionalLogPosterior(joint, theta1)

    def full(x2):
        return cond.full(np.r_[x2, start2[2:]])[0]

    def fun(x2):
        r = _window_residual(joint, full(x2), phi, sigma_w)
        return np.full(n_rows, 1e6) if r is None else r

    n_rows = joint.problem.force.size
    sigma_w = joint.window_scale(full(x), phi)
    for _ in range(2):
        try:
            res = least_squares(fun, x, bounds=(lo, hi), x_scale=[0.1, 0.1], diff_step=1e-6, max_nfev=200)
        except Exception:  # a failed fit leaves the start (the sampler still starts there)
            break
        x = res.x
        sigma_w = joint.window_scale(full(x), phi)
    x_full = full(x)
    steps = np.r_[1e-4, 1e-4, (space.upper[2:7] - space.lower[2:7]) / (2 * BOX_SDS) * 1e-2]
    jac = central_jacobian(lambda th: _window_residual(joint, th, phi, sigma_w), x_full, steps)
    if jac is None:
        return CutFit(np.r_[x, start2[2:]], None, np.zeros((idx.size, 5)), sigma_w)
    j2, j1 = jac[:, :2], jac[:, 2:7]
    info = j2.T @ j2
    try:
        cov = np.linalg.inv(info)
        np.linalg.cholesky(cov)
        sens = -np.linalg.solve(info, j2.T @ j1)
    except np.linalg.LinAlgError:
        return CutFit(np.r_[x, start2[2:]], None, np.zeros((idx.size, 5)), sigma_w)
    if idx.size == 3:  # φ: its own small variance, not moved by θ1
        full_cov = np.zeros((3, 3))
        full_cov[:2, :2] = cov
        full_cov[2, 2] = (1.0 - phi * phi) / max(n_rows, 1)
        cov, sens = full_cov, np.vstack([sens, np.zeros((1, 5))])
    return CutFit(np.r_[x, start2[2:]], cov, sens, sigma_w)


def propagate(res, joint: JointLogPosterior, theta1: np.ndarray, fit: CutFit, seed: int):
    """The cut posterior from the conditional one: a :class:`~bayesdamper.inference.sampling.SamplingResult`
    over the joint vector whose θ1 entries are draws from θ1's own posterior and whose θ2 entries are moved
    by S (θ1 − θ̂1); R-hat, ESS and τ recomputed on the moved chains (those of θ1 draws are those of
    independent draws)."""
    from bayesdamper.inference import posterior as post
    from bayesdamper.inference.stopping import tau_estimate

    space = joint.space
    idx = theta2_index(space.ndim)
    chain2 = res.chain  # (E, T, W, n2)
    e, t, w, _ = chain2.shape
    rng = np.random.default_rng(seed)
    cov1 = module_covariance(joint)
    chol = np.linalg.cholesky(cov1)
    lo2, hi2 = space.lower[idx], space.upper[idx]
    flat2 = chain2.reshape(-1, idx.size)
    n = flat2.shape[0]
    d1 = rng.standard_normal((n, 5)) @ chol.T
    moved = flat2 + d1 @ fit.sensitivity.T
    for _ in range(MAX_REDRAWS):
        out = np.any((moved < lo2) | (moved > hi2), axis=1) | np.any(theta1[1:] + d1[:, 1:] < 0, axis=1)
        if not out.any():
            break
        d1[out] = rng.standard_normal((int(out.sum()), 5)) @ chol.T
        moved[out] = flat2[out] + d1[out] @ fit.sensitivity.T
    moved = np.clip(moved, lo2, hi2)
    full = np.empty((n, space.ndim))
    full[:, idx] = moved
    full[:, THETA1] = theta1 + d1
    full[:, THETA1[1:]] = np.maximum(full[:, THETA1[1:]], 0.0)
    chain = full.reshape(e, t, w, space.ndim)
    tau = np.max([tau_estimate(chain[k]) for k in range(e)], axis=0)
    return replace(res, chain=chain, tau=tau, rhat=post.rhat_across_ensembles(chain), ess_bulk=post.ess_bulk(chain))
