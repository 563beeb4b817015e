"""The eq. (9) cost, the noise models built on it, and the log-posterior the sampler sees.

Eq. (9) is the normalised residual of one transient window,

    J(α_V, p_R) = ||F_C − F_E|| / ||F_E||,

with F_C the computed and F_E the measured force [N] at the window's samples. The likelihoods below are
written in terms of the residual r = F_C − F_E, and reduce to functions of J:

White Gaussian noise, unknown scale
    r_i ~ N(0, σ²) independent. With the Jeffreys prior p(σ) ∝ 1/σ integrated out,

        p(r) ∝ ∫ σ^(−N) exp(−Σ r_i² / 2σ²) σ^(−1) dσ ∝ (Σ r_i²)^(−N/2),

    so log L = −(N/2) log Σ r_i² + const = −(N/2) log J² + const, because ||F_E||² does not depend on
    the parameters. Maximising it is exactly the paper's least-squares tuning of eq. (9).

AR(1) residual, unknown scale (the default)
    Rig noise is coloured and model error is smooth, so neighbouring residuals are correlated. With
    r_i = φ r_{i−1} + e_i, e_i ~ N(0, σ²) and the stationary start r_0 ~ N(0, σ²/(1−φ²)),

        S_φ = (1−φ²) r_0² + Σ_{i≥1} (r_i − φ r_{i−1})²,
        log p(r | φ, σ) = −(N/2) log(2πσ²) + ½ log(1−φ²) − S_φ / (2σ²).

    Integrating σ out as above gives log L = ½ log(1−φ²) − (N/2) log S_φ + const, i.e. eq. (9) applied
    to the pre-whitened residual: S_φ = ||F_E||² J_φ². φ is sampled with the physical parameters; at
    φ = 0 it is the white model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from bayesdamper.inference.priors import PHI_BOUNDS, ParameterSpace, ParameterSpec
from bayesdamper.inference.problem import WindowProblem
from bayesdamper.physics.single_state import solve_eq7

#: Names of the noise models accepted by :func:`make_noise_model` and the CLI. ``"plateau"`` (the default of
#: triangular tests): AR(1) with φ and σ_e estimated from the plateaus and held fixed
#: (:mod:`bayesdamper.inference.joint`); where there are no plateaus (whole records, models with effects) it
#: falls back to ``"ar1"`` (φ sampled, scale marginalised), see :func:`conditional_noise_name`.
NOISE_MODELS = ("plateau", "ar1", "white")
DEFAULT_NOISE_MODEL = "ar1"


def conditional_noise_name(name: str) -> str:
    """The noise model of a likelihood that has no plateau estimate to hold fixed: ``"plateau"`` -> ``"ar1"``."""
    return "ar1" if name == "plateau" else name


def cost_j(computed: np.ndarray, measured: np.ndarray) -> float:
    """Eq. (9): normalised residual J = ||F_C − F_E|| / ||F_E|| [-].

    Parameters
    ----------
    computed, measured : ndarray, shape (n_times,)
        Computed and measured force [N].
    """
    r = np.asarray(computed, dtype=float) - np.asarray(measured, dtype=float)
    return float(np.sqrt(r @ r) / np.sqrt(np.asarray(measured) @ np.asarray(measured)))


def ar1_sum_of_squares(r: np.ndarray, phi: float) -> float:
    """S_φ, the sum of squares of the pre-whitened AR(1) residual [N^2]."""
    e = r[1:] - phi * r[:-1]
    return float((1.0 - phi * phi) * r[0] * r[0] + e @ e)


def ar1_loglike(r: np.ndarray, phi: float, sigma: float) -> float:
    """Exact log density of a stationary AR(1) residual with innovation scale ``sigma`` [N]."""
    n = r.size
    s = ar1_sum_of_squares(r, phi)
    return float(-0.5 * n * np.log(2 * np.pi * sigma**2) + 0.5 * np.log1p(-phi * phi) - s / (2 * sigma**2))


#: Noise-model codes of the compiled log-posteriors: white (scale marginalised), AR(1) with φ sampled (scale
#: marginalised), AR(1) with φ fixed (estimated where the model holds no error) and the window's scale marginalised
#: (σ_e known before the window's start).
WHITE, AR1, PLATEAU = 0, 1, 2



@njit(cache=True)
def _log_posterior_batch(thetas, lower, upper, noise_code, t_out, brk, coef, restart, dp0, area, v01, v02, b0,
                         flow4, force, rtol, atol):
    """Compiled log-posterior of many parameter vectors (the sampler's hot path).

    ``thetas`` has shape (n, ndim): (log α_V, log p_R[, φ]). Returns shape (n,); -inf outside the
    prior box (checked before solving), for a failed solve and for a degenerate residual; never NaN.
    """
    n, ndim = thetas.shape
    out = np.empty(n)
    n_t = force.shape[0]
    for k in range(n):
        inside = True
        for j in range(ndim):
            v = thetas[k, j]
            if not (v >= lower[j] and v <= upper[j]):  # also false for NaN
                inside = False
        if not inside:
            out[k] = -np.inf
            continue
        dp, status, _ = solve_eq7(t_out, brk, coef, restart, dp0, area, v01, v02, b0, flow4,
                                  np.exp(thetas[k, 0]), np.exp(thetas[k, 1]), np.int64(0), 0.0, rtol, atol)
        if status != 0:
            out[k] = -np.inf
            continue
        if noise_code == WHITE:
            s = 0.0
            for i in range(n_t):
                r = area * dp[i] - force[i]
                s += r * r
            ll = -0.5 * n_t * np.log(s) if s > 0.0 else -np.inf
        else:
            phi = thetas[k, 2]
            r_prev = area * dp[0] - force[0]
            s = (1.0 - phi * phi) * r_prev * r_prev
            for i in range(1, n_t):
                r = area * dp[i] - force[i]
                e = r - phi * r_prev
                s += e * e
                r_prev = r
            ll = 0.5 * np.log1p(-phi * phi) - 0.5 * n_t * np.log(s) if s > 0.0 else -np.inf
        out[k] = ll if np.isfinite(ll) else -np.inf
    return out


@dataclass(frozen=True)
class WhiteNoise:
    """Independent Gaussian residuals with unknown scale, marginalised (no sampled parameters)."""

    name: str = "white"
    params: tuple[ParameterSpec, ...] = ()
    code: int = WHITE

    def loglike(self, r: np.ndarray, noise_theta: np.ndarray) -> float:
        return float(-0.5 * r.size * np.log(r @ r))


@dataclass(frozen=True)
class AR1Noise:
    """AR(1) residuals with unknown innovation scale (marginalised) and sampled coefficient φ."""

    name: str = "ar1"
    params: tuple[ParameterSpec, ...] = (ParameterSpec("phi", "-", *PHI_BOUNDS, log=False),)
    code: int = AR1

    def loglike(self, r: np.ndarray, noise_theta: np.ndarray) -> float:
        phi = float(noise_theta[0])
        return float(0.5 * np.log1p(-phi * phi) - 0.5 * r.size * np.log(ar1_sum_of_squares(r, phi)))


def make_noise_model(name: str) -> WhiteNoise | AR1Noise:
    """The noise model called ``name`` (one of :data:`NOISE_MODELS`)."""
    from bayesdamper.core.errors import SettingsError

    if name == "white":
        return WhiteNoise()
    if name in ("ar1", "plateau"):  # "plateau" without plateaus: the AR(1) of the residual itself
        return AR1Noise()
    raise SettingsError(f"--noise-model: unknown noise model {name!r}, choose from {', '.join(NOISE_MODELS)}")


class LogPosterior:
    """Log-posterior of one transient: prior box, forward solve, noise model.

    Callable on the transformed vector ``theta`` (order fixed by :class:`ParameterSpace`); returns
    ``-inf`` outside the prior *before* solving, and ``-inf`` for a failed or non-physical solve.
    Never returns NaN. Picklable (it holds only arrays and frozen dataclasses).
    """

    def __init__(self, problem: WindowProblem, noise=None, space: ParameterSpace | None = None):
        self.problem = problem
        self.noise = noise if noise is not None else make_noise_model(DEFAULT_NOISE_MODEL)
        self.space = space if space is not None else ParameterSpace.default(self.noise.params)
        if self.space.ndim != 2 + len(self.noise.params):
            raise ValueError("parameter space does not match the noise model")
        self._lower = self.space.lower
        self._upper = self.space.upper

    def batch(self, thetas: np.ndarray) -> np.ndarray:
        """Log-posterior of each row of ``thetas``, shape (n, ndim) -> (n,) (emcee ``vectorize=True``).

        Compiled for the plain eq. (7) :class:`WindowProblem`; any other problem (a model with
        effects) goes through its own ``simulate_force`` row by row.
        """
        p = self.problem
        if not isinstance(p, WindowProblem):
            return np.array([self.reference(t) for t in np.atleast_2d(thetas)])
        d = p.damper
        thetas = np.ascontiguousarray(np.atleast_2d(thetas), dtype=np.float64)
        w = p.drive
        return _log_posterior_batch(thetas, self._lower, self._upper, self.noise.code, p.time, w.breaks, w.coefs,
                                    w.restart, float(p.dp0), d.piston_area, d.chamber_volume_1,
                                    d.chamber_volume_2, d.liquid_bulk_modulus, p.flow_array, p.force,
                                    p.rtol, p.atol)

    def residual(self, theta: np.ndarray) -> np.ndarray | None:
        """Residual F_C − F_E [N] at ``theta``, or None if the solve failed."""
        alpha_v, p_r = np.exp(theta[0]), np.exp(theta[1])
        force, ok = self.problem.simulate_force(alpha_v, p_r)
        if not ok:
            return None
        return force - self.problem.force

    def __call__(self, theta: np.ndarray) -> float:
        return float(self.batch(np.asarray(theta, dtype=float)[None, :])[0])

    def reference(self, theta: np.ndarray) -> float:
        """The same log-posterior computed step by step in NumPy (slow; for tests)."""
        theta = np.asarray(theta, dtype=float)
        lp = self.space.log_prior(theta)
        if not np.isfinite(lp):
            return -np.inf
        r = self.residual(theta)
        if r is None or not np.all(np.isfinite(r)) or not np.any(r):
            return -np.inf
        ll = self.noise.loglike(r, theta[2:])
        return float(lp + ll) if np.isfinite(ll) else -np.inf

    def cost(self, theta: np.ndarray) -> float:
        """Eq. (9) J at ``theta`` (inf if the solve fails)."""
        r = self.residual(np.asarray(theta, dtype=float))
        if r is None:
            return np.inf
        f = self.problem.force
        return float(np.sqrt(r @ r) / np.sqrt(f @ f))


# ----------------------------------------------------------------------------- the window likelihood
@njit(cache=True)
def _flow_log_prior(theta, prior_mean, prior_prec):
    """Gaussian log density of the flow coefficients ``theta[3:7]`` (up to a constant; 0 for zero precision)."""
    lp = 0.0
    for d in range(2):
        x0 = theta[3 + 2 * d] - prior_mean[2 * d]
        x1 = theta[4 + 2 * d] - prior_mean[2 * d + 1]
        lp -= 0.5 * (prior_prec[d, 0, 0] * x0 * x0 + 2.0 * prior_prec[d, 0, 1] * x0 * x1
                     + prior_prec[d, 1, 1] * x1 * x1)
    return lp


@njit(cache=True)
def window_loglike(model, force, f0, pre_force, noise_code, phi, inv_var_e):
    """Log-likelihood of a window (module docstring): the model force ``model`` [N] at the window's samples and
    the constant ``f0`` [N] over the settled samples before its start, against the measured ``force`` and
    ``pre_force``. ``phi``: the AR(1) coefficient (sampled for :data:`AR1`, fixed for :data:`PLATEAU`);
    ``inv_var_e``: 1/σ_e² of the innovations before the start (:data:`PLATEAU`). -inf for a degenerate residual.
    """
    n_pre = pre_force.shape[0]
    n_w = force.shape[0]
    n_all = n_pre + n_w
    if noise_code == WHITE:
        s = 0.0
        for i in range(n_all):
            r = (f0 - pre_force[i]) if i < n_pre else (model[i - n_pre] - force[i - n_pre])
            s += r * r
        return -0.5 * n_all * np.log(s) if s > 0.0 else -np.inf
    r_prev = (f0 - pre_force[0]) if n_pre > 0 else (model[0] - force[0])
    s_pre = (1.0 - phi * phi) * r_prev * r_prev
    s_w = 0.0
    if n_pre == 0:
        s_w, s_pre = s_pre, 0.0
    for i in range(1, n_all):
        r = (f0 - pre_force[i]) if i < n_pre else (model[i - n_pre] - force[i - n_pre])
        e = r - phi * r_prev
        if i < n_pre:
            s_pre += e * e
        else:
            s_w += e * e
        r_prev = r
    if noise_code == AR1:
        s = s_pre + s_w
        return 0.5 * np.log1p(-phi * phi) - 0.5 * n_all * np.log(s) if s > 0.0 else -np.inf
    return -0.5 * s_pre * inv_var_e - 0.5 * n_w * np.log(s_w) if s_w > 0.0 else -np.inf


@njit(cache=True)
def _inside(theta, lower, upper):
    for j in range(theta.shape[0]):
        if not (theta[j] >= lower[j] and theta[j] <= upper[j]):  # also false for NaN
            return False
    return True


@njit(cache=True)
def _joint_batch(thetas, lower, upper, noise_code, t_out, brk, coef, restart, area, v01, v02, b0, force, pre_force,
                 prior_mean, prior_prec, phi_fixed, inv_var_e, rtol, atol):
    """Compiled log-posterior of eq. (7) at rows (log α_V, log p_R, F0/A_P, C_L12, C_Q12, C_L21, C_Q21[, φ]).

    -inf outside the box (checked before solving), for a failed solve and a degenerate residual; never NaN.
    """
    n, ndim = thetas.shape
    out = np.empty(n)
    flow4 = np.empty(4)
    for k in range(n):
        if not _inside(thetas[k], lower, upper):
            out[k] = -np.inf
            continue
        lp = _flow_log_prior(thetas[k], prior_mean, prior_prec)
        for j in range(4):
            flow4[j] = thetas[k, 3 + j]
        dp0 = thetas[k, 2]
        dp, status, _ = solve_eq7(t_out, brk, coef, restart, dp0, area, v01, v02, b0, flow4,
                                  np.exp(thetas[k, 0]), np.exp(thetas[k, 1]), np.int64(0), 0.0, rtol, atol)
        if status != 0:
            out[k] = -np.inf
            continue
        phi = thetas[k, 7] if noise_code == AR1 else phi_fixed
        v = lp + window_loglike(area * dp, force, area * dp0, pre_force, noise_code, phi, inv_var_e)
        out[k] = v if np.isfinite(v) else -np.inf
    return out
