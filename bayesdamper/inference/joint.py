"""Stage 2 with every real uncertainty in the posterior: the transient's own start and stage 1 sampled jointly.

The plain stage 2 (:mod:`bayesdamper.inference.likelihood`) conditions each transient on three estimates
and treats them as exact: the initial Δp (the mean force of the 0.15 s before the step), the four flow
coefficients of stage 1, and - through the AR(1) model of the window's own residual - a noise colour that
smooth model error can masquerade as. On independent data those three cost the intervals their
coverage. Here

* Δp(t_step) is a sampled parameter, and the samples before the step enter the likelihood (the model force
  there is the constant A_P Δp(t_step) of a settled damper), so the step force is estimated from the
  same data and noise model as everything else, with its correlation to the window's first samples;
* the flow coefficients are sampled under the stage-1 posterior as prior: per direction, the posterior of
  the eq. (4) regression under a flat prior is a bivariate Student-t with ν = n − 2 degrees of freedom,
  location the least-squares estimate and scale s² (XᵀX)⁻¹ (Gelman et al., BDA3, sec. 14.2); it is used in
  its moment-matched Gaussian form, covariance s² (XᵀX)⁻¹ ν/(ν − 2) (×3 for ν ≤ 2). Plateau means are
  separate stretches of the record, so their errors are independent whatever the noise colour, and their
  scatter about eq. (4) sets s. Not the t itself: its logarithmic tails let a transient with model error
  drag the coefficients 70 scales from stage 1 (measured on rig-A's tri_1p50mm_s_s0: a second mode 6 nats
  above the one at stage 1, which the sampler crossed only rarely);
* the noise is an AR(1) process whose coefficient φ is estimated from the plateaus (:func:`plateau_noise`),
  where the model is a constant and the residual is noise alone, and then held fixed. Before the step the
  innovations have the plateaus' sd σ_e too (the damper is settled, the model exact); in the window their
  scale σ_w is unknown and marginalised (Jeffreys prior), because the window is where model error lives.
  The residual of the window then cannot talk the noise model into calling smooth model error "colour"
  (with φ sampled from the window, as the plain stage 2 does, rig-A's posterior moved to J = 0.054 where
  Nelder-Mead has 0.033), and the posterior stays centred on the eq. (9) optimum weighted by the noise's
  colour.

Under model error this joint posterior misbehaves in a way the cut does not (:mod:`bayesdamper.inference.cut`,
the default; this posterior is ``--coupling joint``): the window's misfit drags Δp0
and the flow coefficients away from what their own data say (two-state data: C_L12 by up to 4.6 stage-1 sds in
starts from rest), and α_V and p_R move with them, away from the eq. (9) optimum (13/18 and 15/18 of the CI
seed's intervals held the eq. (9) optimum's White counterpart). This module keeps the likelihood both use
(:func:`_joint_batch`, :class:`JointLogPosterior`), the MAP fit of the joint and the noise estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayesdamper.core.frozen import ReadOnlyArrays
from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.inference.likelihood import (
    AR1,
    PLATEAU,
    WHITE,
    _flow_log_prior,
    _inside,
    _joint_batch,
    window_loglike,
)
from bayesdamper.inference.plateau_noise import PlateauNoise, ar1_from_segments, plateau_noise
from bayesdamper.inference.priors import ALPHA_V_BOUNDS, P_R_BOUNDS, PHI_BOUNDS, ParameterSpace, ParameterSpec
from bayesdamper.inference.problem import freeze_arrays
from bayesdamper.physics.excitation import PiecewisePolynomial
from bayesdamper.physics.single_state import solve_eq7

__all__ = ["AR1", "PLATEAU", "WHITE", "JointLogPosterior", "JointProblem", "PlateauNoise", "StageOnePrior",
           "ar1_from_segments", "central_jacobian", "fit_map", "plateau_noise"]

#: Names of the flow coefficients in the sampled vector.
FLOW_NAMES = ("CL12", "CQ12", "CL21", "CQ21")
FLOW_UNITS = ("kg m^-4 s^-1", "kg m^-7") * 2
#: Half-width of the box of Δp(t_step) and of each flow coefficient, in standard deviations of its estimate:
#: wide enough that the box never cuts the posterior (a Gaussian has 4e-33 beyond 12 sd).
BOX_SDS = 12.0
#: Kernel tolerances of the MAP fit and its Gauss-Newton covariance: the adaptive solver's force moves by about its
#: tolerance when a parameter change shifts its steps, and finite differences need that far below their step
#: (1e-3 of the parameters' scale, moving the force by ~1e-3 of itself); 1e-7 keeps a 30 s window of a 5 Hz sine
#: within the kernel's step budget.
FIT_RTOL = 1e-7
FIT_ATOL = 1e-2  # [Pa]


@dataclass(frozen=True)
class StageOnePrior:
    """What the parts of a data set other than a window tell its likelihood: the flow coefficients' posterior
    from stage 1 (or nothing, a flat box, when there are no plateaus) and the noise.

    Attributes
    ----------
    mean : ndarray, shape (4,), or None
        Least-squares [C_L12, C_Q12, C_L21, C_Q21]; None: no stage 1 (flat prior on the window's box).
    cov : ndarray, shape (4, 4), or None
        Block-diagonal scale matrix s² (XᵀX)⁻¹ per direction.
    dof : ndarray, shape (2,), or None
        n − 2 per direction (forward, backward).
    noise : PlateauNoise or NoiseEstimate
        AR(1) noise (``phi``, ``sigma_e``, ``sigma``) estimated where the model holds no error.
    """

    mean: np.ndarray | None
    cov: np.ndarray | None
    dof: np.ndarray | None
    noise: PlateauNoise

    @classmethod
    def from_fit(cls, static, noise: PlateauNoise) -> StageOnePrior:
        """From a :class:`bayesdamper.inference.stage1.StaticFit`."""
        return cls(np.asarray(static.coefficients.as_array(), dtype=float), np.asarray(static.covariance, float),
                   np.array([static.forward.n - 2, static.backward.n - 2], dtype=float), noise)

    @classmethod
    def flat(cls, noise) -> StageOnePrior:
        """No stage 1: the flow coefficients are sampled with the window's parameters under a flat prior."""
        return cls(None, None, None, noise)

    @property
    def gaussian(self) -> bool:
        """The flow coefficients have stage 1's Gaussian prior (else a flat box)."""
        return self.mean is not None

    @property
    def prior_cov(self) -> np.ndarray:
        """Covariance of the Gaussian prior: each direction's scale matrix × ν/(ν − 2) (×3 for ν ≤ 2, ×1 for
        ν = ∞, a prior given as Gaussian)."""
        out = self.cov.copy()
        for d, nu in enumerate(self.dof):
            factor = 1.0 if not np.isfinite(nu) else (nu / (nu - 2.0) if nu > 2 else 3.0)
            out[2 * d:2 * d + 2, 2 * d:2 * d + 2] *= factor
        return out

    def precision_blocks(self) -> np.ndarray:
        """Inverse of each direction's 2×2 prior covariance, shape (2, 2, 2) (zeros for a flat prior)."""
        if not self.gaussian:
            return np.zeros((2, 2, 2))
        c = self.prior_cov
        return np.stack([np.linalg.inv(c[2 * d:2 * d + 2, 2 * d:2 * d + 2]) for d in (0, 1)])

    def log_prior(self, flow4: np.ndarray) -> float:
        """Log density of the flow coefficients (up to a constant; 0 for a flat prior)."""
        if not self.gaussian:
            return 0.0
        prec = self.precision_blocks()
        out = 0.0
        for d in (0, 1):
            dx = flow4[2 * d:2 * d + 2] - self.mean[2 * d:2 * d + 2]
            out += -0.5 * float(dx @ prec[d] @ dx)
        return out


#: Upper end of a flat prior's box of a flow coefficient (no stage 1), in units of the coefficient that alone
#: carries the window's largest force at its largest flow: 100x leaves two decades above anything the window can
#: support while keeping the prior proper; 0 (a purely laminar or purely quadratic path) is inside.
STATIC_BOX = 100.0
#: Half-width of a flat prior's box of Δp at the start of a window that starts in motion, in units of the
#: window's force range / A_P (about the force range's centre).
DP0_BOX = 1.0


def flow_scales(time: np.ndarray, force: np.ndarray, drive, area: float) -> np.ndarray:
    """[C_L, C_Q, C_L, C_Q] that alone carry the window's largest |force| (99th percentile) at its largest flow."""
    q = area * np.abs(drive.velocity(time))
    qmax = max(float(np.quantile(q, 0.99)), 1e-12)
    dpmax = max(float(np.quantile(np.abs(force), 0.99)) / area, 1.0)
    return np.array([dpmax / qmax, dpmax / qmax**2] * 2)


@dataclass(frozen=True)
class JointProblem(ReadOnlyArrays):
    """One window with its pre-step samples, bound to the damper, the flow prior and a noise model.

    Attributes
    ----------
    segment_id : str
    time, force : ndarray
        Window sample times [s] (from t_step) and measured force [N].
    pre_time, pre_force : ndarray
        Samples of the settled stretch just before the step [s], [N]; model force A_P Δp0 there. Empty for a
        window that starts in motion (Δp0 then has a flat prior on a box about the window's force).
    t_step : float
        Start of the window [s].
    drive : PiecewisePolynomial
        The input from ``t_step`` over the window [m].
    dp0_start : float
        Estimate of Δp0 [Pa]: the mean of ``pre_force`` / A_P, else the window's start value.
    damper : DamperConstants
    prior : StageOnePrior
    noise_code : int
        :data:`WHITE`, :data:`AR1` or :data:`PLATEAU`.
    effects : ComposedEffects or None
        Effects added to eq. (7) (the composed kernel), held at their values; None: eq. (7) alone.
    record_drive : PiecewisePolynomial or None
        The record's whole input (effects with a memory see the history before the window); needed with effects.

    The third sampled entry is the force at the start over A_P [Pa]: Δp0 for eq. (7) alone; with effects the
    kernel solves Δp0 so that the model's force in the steady state before the start equals it (a friction or
    offset force included), the settled samples before the start measuring that force.
    """

    segment_id: str
    time: np.ndarray
    force: np.ndarray
    pre_time: np.ndarray
    pre_force: np.ndarray
    t_step: float
    drive: PiecewisePolynomial
    dp0_start: float
    damper: DamperConstants
    prior: StageOnePrior
    noise_code: int = PLATEAU
    rtol: float = 1e-5
    atol: float = 1.0
    effects: object = None
    record_drive: PiecewisePolynomial | None = None

    def __post_init__(self) -> None:
        freeze_arrays(self, ("time", "force", "pre_time", "pre_force"))
        if self.effects is not None:
            drive = self.effects.transform_input(self.record_drive).cover(self.t_step, float(self.time[-1]))
            v0 = drive.velocity_before(self.t_step) if self.settled_start else float(drive.velocity(self.t_step))
            object.__setattr__(self, "_effects_input", (drive, v0))

    @classmethod
    def from_window(cls, window, damper: DamperConstants, prior: StageOnePrior, noise_code: int = PLATEAU,
                    effects=None, **kw) -> JointProblem:
        return cls(window.id, window.time, window.force, window.pre_time, window.pre_force, window.t_step,
                   window.local_drive, float(window.dp0), damper, prior, noise_code, effects=effects,
                   record_drive=window.drive if effects is not None else None, **kw)

    @property
    def settled_start(self) -> bool:
        """Δp0 has its own data (the samples before the step)."""
        return self.pre_force.size > 0

    @property
    def dp0_estimate(self) -> float:
        if self.settled_start:
            return float(np.mean(self.pre_force)) / self.damper.piston_area
        return float(self.dp0_start)

    @property
    def dp0(self) -> float:
        """The start's Δp estimate [Pa] (for stores and figures)."""
        return self.dp0_estimate

    def dp0_sd(self) -> float:
        """Standard deviation of :attr:`dp0_estimate` under the noise [Pa] (AR(1) mean variance)."""
        nz = self.prior.noise
        n = max(self.pre_force.size, 1)
        phi = nz.phi
        # variance of the mean of n AR(1) samples: σ²/n [1 + 2 Σ_k (1 − k/n) φ^k]
        k = np.arange(1, n)
        factor = 1.0 + 2.0 * float(np.sum((1.0 - k / n) * phi ** k))
        return nz.sigma * math.sqrt(max(factor, 1e-12) / n) / self.damper.piston_area

    def space(self, alpha_v_bounds=ALPHA_V_BOUNDS, p_r_bounds=P_R_BOUNDS) -> ParameterSpace:
        """The sampled vector: log α_V, log p_R, Δp0, the four flow coefficients[, φ for :data:`AR1`]."""
        area = self.damper.piston_area
        d0 = self.dp0_estimate
        if self.settled_start:
            half = BOX_SDS * self.dp0_sd() + 1e-3 * abs(d0) + 10.0
            dp0_box = (d0 - half, d0 + half)
        else:
            lo, hi = float(np.min(self.force)) / area, float(np.max(self.force)) / area
            half = DP0_BOX * max(hi - lo, 10.0)
            dp0_box = (0.5 * (lo + hi) - half, 0.5 * (lo + hi) + half)
        specs = [ParameterSpec("alpha_V", "-", *alpha_v_bounds), ParameterSpec("p_R_Pa", "Pa", *p_r_bounds),
                 ParameterSpec("dp0_Pa", "Pa", *dp0_box, log=False)]
        if self.prior.gaussian:
            sd = np.sqrt(np.diag(self.prior.prior_cov))
            for name, unit, m, s in zip(FLOW_NAMES, FLOW_UNITS, self.prior.mean, sd, strict=True):
                specs.append(ParameterSpec(name, unit, max(m - BOX_SDS * s, 1e-6 * abs(m)), m + BOX_SDS * s,
                                           log=False))
        else:
            scales = flow_scales(self.time, self.force, self.drive, area)
            for name, unit, sc in zip(FLOW_NAMES, FLOW_UNITS, scales, strict=True):
                specs.append(ParameterSpec(name, unit, 0.0, float(STATIC_BOX * sc), log=False))
        if self.noise_code == AR1:
            specs.append(ParameterSpec("phi", "-", *PHI_BOUNDS, log=False))
        return ParameterSpace(tuple(specs))

    def flow_of(self, theta: np.ndarray) -> FlowCoefficients:
        return FlowCoefficients(*[float(c) for c in theta[3:7]])

    def simulate_window(self, theta: np.ndarray, rtol: float | None = None,
                        atol: float | None = None) -> tuple[np.ndarray, bool]:
        """Model force [N] at the window samples for a transformed ``theta``, and whether the solve succeeded."""
        d, w = self.damper, self.drive
        if self.effects is not None:
            from bayesdamper.physics.compose import solve_composed

            drive, v0 = self._effects_input
            force, status = solve_composed(self.effects, self.time, drive, self.t_step, float(theta[2]) * d.piston_area,
                                           v0, d, np.ascontiguousarray(theta[3:7], dtype=float), math.exp(theta[0]),
                                           math.exp(theta[1]), self.rtol if rtol is None else rtol,
                                           self.atol if atol is None else atol, from_force=True)
            return force, status == 0
        dp, status, _ = solve_eq7(self.time, w.breaks, w.coefs, w.restart, float(theta[2]), d.piston_area,
                                  d.chamber_volume_1, d.chamber_volume_2, d.liquid_bulk_modulus,
                                  np.ascontiguousarray(theta[3:7], dtype=float), math.exp(theta[0]),
                                  math.exp(theta[1]), 0, 0.0, self.rtol if rtol is None else rtol,
                                  self.atol if atol is None else atol)
        return d.piston_area * dp, status == 0

    def residual(self, theta: np.ndarray, rtol=None, atol=None) -> np.ndarray | None:
        """Residual model − measured [N] over the pre-step samples and the window, or None if the solve failed."""
        f, ok = self.simulate_window(theta, rtol, atol)
        if not ok or not np.all(np.isfinite(f)):
            return None
        pre = self.damper.piston_area * float(theta[2]) - self.pre_force
        return np.concatenate([pre, f - self.force])


class JointLogPosterior:
    """Log-posterior of a :class:`JointProblem` on its :meth:`JointProblem.space` (picklable; never NaN)."""

    def __init__(self, problem: JointProblem, space: ParameterSpace):
        self.problem = problem
        self.space = space
        self._lower, self._upper = space.lower, space.upper
        self._prec = problem.prior.precision_blocks()
        # the flow prior's pseudo-residuals in whitened() (none for a flat prior)
        self._prec_chol = np.linalg.cholesky(self._prec) if problem.prior.gaussian else None
        nz = problem.prior.noise
        self._phi, self._inv_var = float(nz.phi), 1.0 / float(nz.sigma_e) ** 2

    def batch(self, thetas: np.ndarray) -> np.ndarray:
        p = self.problem
        d = p.damper
        thetas = np.ascontiguousarray(np.atleast_2d(thetas), dtype=np.float64)
        w = p.drive
        mean = p.prior.mean if p.prior.gaussian else np.zeros(4)
        if p.effects is not None:  # the composed kernel row by row, the same likelihood
            out = np.full(thetas.shape[0], -np.inf)
            for k, th in enumerate(thetas):
                if not _inside(th, self._lower, self._upper):
                    continue
                f, ok = p.simulate_window(th)
                if not ok:
                    continue
                phi = th[7] if p.noise_code == AR1 else self._phi
                v = _flow_log_prior(th, mean, self._prec) + window_loglike(
                    f, p.force, d.piston_area * th[2], p.pre_force, p.noise_code, phi, self._inv_var)
                out[k] = v if np.isfinite(v) else -np.inf
            return out
        return _joint_batch(thetas, self._lower, self._upper, p.noise_code, p.time, w.breaks, w.coefs, w.restart,
                            d.piston_area, d.chamber_volume_1, d.chamber_volume_2,
                            d.liquid_bulk_modulus, p.force, p.pre_force, mean, self._prec,
                            self._phi, self._inv_var, p.rtol, p.atol)

    def __call__(self, theta: np.ndarray) -> float:
        return float(self.batch(np.asarray(theta, dtype=float)[None, :])[0])

    def reference(self, theta: np.ndarray) -> float:
        """The same log-posterior step by step in NumPy (slow; for tests)."""
        theta = np.asarray(theta, dtype=float)
        if not np.isfinite(self.space.log_prior(theta)):
            return -np.inf
        r = self.problem.residual(theta)
        if r is None or not np.any(r):
            return -np.inf
        lp = self.problem.prior.log_prior(theta[3:7])
        code = self.problem.noise_code
        if code == WHITE:
            return lp - 0.5 * r.size * math.log(r @ r)
        phi = theta[7] if code == AR1 else self._phi
        e = np.r_[math.sqrt(1 - phi * phi) * r[0], r[1:] - phi * r[:-1]]
        if code == AR1:
            return lp + 0.5 * math.log1p(-phi * phi) - 0.5 * r.size * math.log(e @ e)
        n_pre = self.problem.pre_force.size
        s_pre = float(e[:n_pre] @ e[:n_pre]) if n_pre else 0.0
        e_w = e[n_pre:] if n_pre else np.r_[r[0], e[1:]]
        return lp - 0.5 * s_pre * self._inv_var - 0.5 * e_w.size * math.log(e_w @ e_w)

    def innovations(self, theta: np.ndarray, phi: float, rtol=None, atol=None) -> np.ndarray | None:
        """Pre-whitened residual (AR(1) innovations) over the pre-step samples and the window [N]."""
        r = self.problem.residual(theta, rtol, atol)
        if r is None:
            return None
        e = np.empty_like(r)
        e[0] = math.sqrt(1.0 - phi * phi) * r[0]
        e[1:] = r[1:] - phi * r[:-1]
        return e

    def whitened(self, theta: np.ndarray, phi: float, sigma_w: float, rtol=None,
                 atol=None) -> np.ndarray | None:
        """Innovations scaled by their sd (the plateau σ_e before the step, ``sigma_w`` in the window) with the
        Gaussian pseudo-residuals of the flow prior appended: the least-squares form of the log-posterior at
        a fixed window scale, for the MAP fit and its Gauss-Newton covariance."""
        e = self.innovations(theta, phi, rtol, atol)
        if e is None:
            return None
        n_pre = self.problem.pre_force.size
        e = e.copy()
        e[:n_pre] /= self.problem.prior.noise.sigma_e
        e[n_pre:] /= sigma_w
        if self._prec_chol is None:
            return e
        prior = [self._prec_chol[d].T @ (theta[3 + 2 * d:5 + 2 * d] - self.problem.prior.mean[2 * d:2 * d + 2])
                 for d in (0, 1)]
        return np.concatenate([e, *prior])

    def window_scale(self, theta: np.ndarray, phi: float) -> float:
        """RMS of the window's innovations at ``theta`` [N] (the marginalised σ_w at its mode)."""
        e = self.innovations(theta, phi, FIT_RTOL, FIT_ATOL)
        n_pre = self.problem.pre_force.size
        if e is None:
            return self.problem.prior.noise.sigma_e
        return float(max(np.sqrt(np.mean(e[n_pre:] ** 2)), 1e-9))


def central_jacobian(fun, x: np.ndarray, steps: np.ndarray) -> np.ndarray | None:
    """Jacobian of the vector function ``fun`` at ``x`` by central differences with per-entry ``steps``, shape
    (len(fun(x)), len(x)); None if ``fun`` returns None (a failed solve) at any point. For the Gauss-Newton
    covariances of :func:`fit_map` and :func:`bayesdamper.inference.cut.fit_conditional` (a least-squares
    solver's own Jacobian is one-sided)."""
    cols = []
    for j, h in enumerate(steps):
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        fp, fm = fun(xp), fun(xm)
        if fp is None or fm is None:
            return None
        cols.append((fp - fm) / (2 * h))
    return np.column_stack(cols)


def fit_map(logpost: JointLogPosterior, start: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Least-squares MAP of the joint posterior (Gaussian form of the flow prior, φ held at the plateau value)
    and the Gauss-Newton covariance of the transformed vector there (None if singular).

    The model part (the first seven entries) is fitted; a trailing φ keeps its start.
    """
    from scipy.optimize import least_squares

    space = logpost.space
    n_model = 7
    lo, hi = space.lower[:n_model], space.upper[:n_model]
    phi = logpost._phi
    tail = np.asarray(start[n_model:], dtype=float)
    x0 = np.clip(np.asarray(start[:n_model], dtype=float), lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    big = 1e6

    def fun(x):
        w = logpost.whitened(np.r_[x, tail], phi, sigma_w, FIT_RTOL, FIT_ATOL)
        if w is None:
            return np.full(n_rows, big)
        return w

    sigma_w = logpost.window_scale(np.r_[x0, tail], phi)
    w0 = logpost.whitened(np.r_[x0, tail], phi, sigma_w, FIT_RTOL, FIT_ATOL)
    if w0 is None:
        return np.r_[x0, tail], None
    n_rows = w0.size
    x_scale = np.r_[0.1, 0.1, (hi[2:] - lo[2:]) / (2 * BOX_SDS)]
    x = x0
    for _ in range(2):  # the window scale at the start, then at the first optimum
        try:
            res = least_squares(fun, x, bounds=(lo, hi), x_scale=x_scale, diff_step=1e-6, max_nfev=200,
                                method="trf")
        except Exception:  # a fit that fails leaves the start: the sampler still starts there
            return np.r_[x0, tail], None
        x = res.x
        sigma_w = logpost.window_scale(np.r_[x, tail], phi)
    # Gauss-Newton covariance by central differences (the solver's own Jacobian is one-sided)
    f0 = fun(x)
    jac = central_jacobian(fun, x, 1e-3 * x_scale)
    try:
        cov = np.linalg.inv(jac.T @ jac)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        cov = None
    if cov is not None and tail.size:  # φ: its own small independent variance
        full = np.zeros((space.ndim, space.ndim))
        full[:n_model, :n_model] = cov
        full[n_model:, n_model:] = np.eye(tail.size) * (1.0 - phi * phi) / max(f0.size, 1)
        cov = full
    return np.r_[x, tail], cov
