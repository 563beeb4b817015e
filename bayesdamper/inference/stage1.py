"""Stage 1: static flow coefficients from the steady plateaus, eq. (4).

On a plateau the piston moves at constant speed |v| and the force has settled, so the flow through the
orifice equals the displaced flow, Q = A_P |v| [m^3/s], and Δp = |F| / A_P [Pa]. Eq. (4),
Δp = C_L Q + C_Q Q |Q|, is linear in (C_L, C_Q), so each flow direction is an ordinary linear
least-squares problem with design matrix ``[Q, Q^2]``. The covariance of the estimate is
``s^2 (X^T X)^-1`` with ``s^2`` the residual variance on ``n - 2`` degrees of freedom, so the standard
errors include the scatter of the plateaus about the curve (model error included), not only the
within-plateau noise.

Eq. (8) needs C_L, C_Q >= 0. Plateaus that eq. (4) cannot fit with both non-negative (a load cell that was not
zeroed shifts one direction's forces up and the other's down; a force that saturates with speed bends the curve
the wrong way) are fitted with the offending coefficient at 0 and the fit says so (``constrained``): a finding for
the diagnosis, which tests the effects that would explain it, not a reason to refuse the data.

One such explanation is checked here. A constant force offset F_0 of the force channel adds d F_0 / A_P to the
plateau pressure drops of direction d = ±1: Δp = C_L Q + C_Q Q^2 + d p_0 with p_0 = F_0 / A_P, up in one direction
and down in the other, so with plateaus in both directions p_0 is identifiable beside the four coefficients (one
linear least-squares problem in five unknowns, :func:`fit_with_offset`). Where eq. (4) alone holds a coefficient at
0, the fit with an offset is made, and it is reported (``StaticFit.offset``) when it has every coefficient positive
and its offset lies more than :data:`OFFSET_MIN_T` standard errors from 0. It is reported, not applied: the
coefficients stage 1 gives are eq. (4)'s alone, the ones that meet the measured plateaus with the model the
windows are identified with, which has no offset (the windows' data keep it); the diagnosis tests the offset with
the ``load_cell_offset`` effect and re-fits stage 1 on the plateaus with the offset removed. Plateaus that eq. (4)
fits with non-negative coefficients get exactly that fit and no offset.

The force channel's zero is also measured whatever eq. (4) alone gives (:func:`plateau_zero`): each direction's
signed pressure drops fitted with their own intercept, Δp_d = C_L Q + C_Q Q^2 + b_d. An offset F_0 adds d F_0 / A_P
to direction d and a Coulomb friction f adds f / A_P to both, so F_0 = A_P (b_+ - b_-) / 2 and f = A_P (b_+ + b_-) / 2
whatever the friction (the fit with an offset above has no friction term and takes part of a friction for an
offset). The diagnosis removes a zero measured there from the forces before it searches (:mod:`bayesdamper.run.plan`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

from bayesdamper.core.errors import DataError
from bayesdamper.core.params import FlowCoefficients

#: Names of the four static coefficients, in the order of :meth:`FlowCoefficients.as_array`.
STATIC_NAMES = ("CL12", "CQ12", "CL21", "CQ21")

#: Fewest plateaus per direction that leave at least one degree of freedom for the residual variance.
MIN_PLATEAUS_PER_DIRECTION = 3
#: Fewest plateaus per direction for the force channel's zero (:func:`plateau_zero`): three coefficients per direction
#: and one degree of freedom for the residual variance.
ZERO_MIN_PLATEAUS = 4
#: A force offset is reported only this many standard errors from 0 (the |t| > 3 of the plateau drift rule): below
#: it, the coefficient eq. (4) made negative is as well explained by noise about a small true value.
OFFSET_MIN_T = 3.0


@dataclass(frozen=True)
class DirectionFit:
    """Least-squares fit of eq. (4) for one flow direction.

    Attributes
    ----------
    direction : int
        +1 for flow CH1 -> CH2 (coefficients ``_12``), -1 for CH2 -> CH1 (``_21``).
    laminar : float
        C_L [kg m^-4 s^-1].
    quadratic : float
        C_Q [kg m^-7].
    covariance : ndarray, shape (2, 2)
        Covariance of (C_L, C_Q).
    residual_std : float
        Standard deviation of the plateau pressure drops about the fitted curve [Pa].
    flow_rate, pressure_drop : ndarray, shape (n,)
        The plateau points Q [m^3/s] and Δp [Pa] (both positive magnitudes).
    constrained : tuple of str
        Coefficients (``"C_L"``, ``"C_Q"``) the unconstrained least squares made negative, held at 0.
    """

    direction: int
    laminar: float
    quadratic: float
    covariance: np.ndarray
    residual_std: float
    flow_rate: np.ndarray
    pressure_drop: np.ndarray
    constrained: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        """Number of plateaus used."""
        return int(self.flow_rate.size)

    @property
    def standard_errors(self) -> np.ndarray:
        """Standard errors of (C_L, C_Q), shape (2,)."""
        return np.sqrt(np.diag(self.covariance))

    def predict(self, flow_rate: np.ndarray) -> np.ndarray:
        """Pressure drop [Pa] of eq. (4) at flow-rate magnitudes ``flow_rate`` [m^3/s]."""
        q = np.abs(np.asarray(flow_rate, dtype=float))
        return self.laminar * q + self.quadratic * q * q


@dataclass(frozen=True)
class OffsetFit:
    """Eq. (4) in both directions with a constant force offset: ``Δp = C_L Q + C_Q Q^2 + d p_0`` (d = +1 forward,
    -1 backward), one linear least-squares fit.

    Attributes
    ----------
    coefficients : ndarray, shape (4,)
        [C_L12, C_Q12, C_L21, C_Q21] of the fit with the offset.
    pressure : float
        p_0 = F_0 / A_P [Pa]: F_0 is positive when the force channel reads F_0 at zero pressure difference (the
        ``load_cell_offset`` effect's ``offset_N``).
    covariance : ndarray, shape (5, 5)
        s^2 (X^T X)^-1 of [C_L12, C_Q12, C_L21, C_Q21, p_0], s^2 the residual variance pooled over both directions.
    residual_std : float
        s [Pa].
    dof : int
        n - 5.
    """

    coefficients: np.ndarray
    pressure: float
    covariance: np.ndarray
    residual_std: float
    dof: int

    @property
    def standard_errors(self) -> np.ndarray:
        """Standard errors of [C_L12, C_Q12, C_L21, C_Q21, p_0], shape (5,)."""
        return np.sqrt(np.diag(self.covariance))

    def force(self, area: float) -> tuple[float, float]:
        """The offset F_0 and its standard error [N] for piston area ``area`` [m^2]."""
        return float(self.pressure * area), float(self.standard_errors[4] * area)

    @property
    def explains(self) -> bool:
        """Every coefficient positive and the offset more than :data:`OFFSET_MIN_T` standard errors from 0."""
        return bool(np.all(self.coefficients > 0) and abs(self.pressure) > OFFSET_MIN_T * self.standard_errors[4])


@dataclass(frozen=True)
class StaticFit:
    """Both directions of the stage-1 fit.

    Attributes
    ----------
    forward, backward : DirectionFit
        Direction +1 (coefficients ``_12``) and -1 (``_21``).
    offset : OffsetFit or None
        The constant force offset that explains the coefficients held at 0 (module docstring), reported and not
        applied; None when no coefficient is held or no offset explains it.
    """

    forward: DirectionFit
    backward: DirectionFit
    offset: OffsetFit | None = None

    def offset_force(self, area: float) -> tuple[float, float] | None:
        """The reported force offset F_0 and its standard error [N] for piston area ``area`` [m^2], or None."""
        return self.offset.force(area) if self.offset is not None else None

    @property
    def coefficients(self) -> FlowCoefficients:
        """Point estimate as :class:`FlowCoefficients`."""
        return FlowCoefficients(self.forward.laminar, self.forward.quadratic,
                                self.backward.laminar, self.backward.quadratic)

    @property
    def covariance(self) -> np.ndarray:
        """Block-diagonal covariance of ``[C_L12, C_Q12, C_L21, C_Q21]``, shape (4, 4)."""
        cov = np.zeros((4, 4))
        cov[:2, :2] = self.forward.covariance
        cov[2:, 2:] = self.backward.covariance
        return cov

    @property
    def constrained(self) -> list[str]:
        """Coefficients held at 0 because the plateaus made them negative (e.g. ``["C_L21"]``)."""
        return [f"{n}{lab}" for f, lab in ((self.forward, "12"), (self.backward, "21")) for n in f.constrained]

    def intervals(self, credible_mass: float = 0.9) -> dict[str, dict[str, float]]:
        """Equal-tailed intervals of each coefficient (Student-t on the residual degrees of freedom)."""
        out = {}
        est = self.coefficients.as_array()
        se = np.sqrt(np.diag(self.covariance))
        dofs = (self.forward.n - 2,) * 2 + (self.backward.n - 2,) * 2
        for name, m, s, dof in zip(STATIC_NAMES, est, se, dofs, strict=True):
            q = stats.t.ppf(0.5 + credible_mass / 2, max(dof, 1))
            out[name] = {"median": float(m), "lo": float(max(m - q * s, 0.0)), "hi": float(m + q * s)}
        return out

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draws of ``[C_L12, C_Q12, C_L21, C_Q21]`` from the Gaussian approximation, shape (n, 4)."""
        return rng.multivariate_normal(self.coefficients.as_array(), self.covariance, size=n)


def fit_direction(flow_rate: np.ndarray, pressure_drop: np.ndarray, direction: int,
                  source: str = "plateaus") -> DirectionFit:
    """Fit eq. (4) to one direction's plateau points by linear least squares.

    Parameters
    ----------
    flow_rate : ndarray, shape (n,)
        Flow-rate magnitudes Q = A_P |v| [m^3/s].
    pressure_drop : ndarray, shape (n,)
        Pressure-drop magnitudes |Δp| [Pa].
    direction : int
        +1 or -1, recorded in the result.
    source : str
        Named in the error message if the fit is impossible.
    """
    q = np.abs(np.asarray(flow_rate, dtype=float))
    dp = np.abs(np.asarray(pressure_drop, dtype=float))
    if q.size < MIN_PLATEAUS_PER_DIRECTION:
        raise DataError(f"{source}: {q.size} plateau(s) in direction {direction:+d}, "
                        f"need at least {MIN_PLATEAUS_PER_DIRECTION} to fit eq. (4) with an uncertainty")
    if np.unique(np.round(q / q.max(), 6)).size < 2:
        raise DataError(f"{source}: all plateaus in direction {direction:+d} share one velocity; "
                        "eq. (4) needs at least two distinct velocities")
    # Scale the columns so the normal equations are well conditioned (Q ~ 1e-6, Q^2 ~ 1e-12).
    x = np.column_stack([q, q * q])
    scale = np.abs(x).max(axis=0)
    xs = x / scale
    coef_s, *_ = np.linalg.lstsq(xs, dp, rcond=None)
    constrained: tuple[str, ...] = ()
    if np.any(coef_s < 0):  # eq. (8) needs both >= 0: the best one-term fit holds the other at 0 (NNLS)
        from scipy.optimize import nnls

        coef_s, _ = nnls(xs, dp)
        constrained = tuple(n for n, c in zip(("C_L", "C_Q"), coef_s, strict=True) if c == 0.0)
        if np.all(coef_s == 0.0):
            raise DataError(f"{source}: the plateau forces in direction {direction:+d} do not rise with speed: "
                            "eq. (4) cannot describe them (is the force channel's sign or unit right?)")
    resid = dp - xs @ coef_s
    dof = q.size - 2
    s2 = float(resid @ resid) / dof if dof > 0 else float("nan")
    cov_s = s2 * np.linalg.inv(xs.T @ xs)  # held coefficients keep the full fit's spread (conservative)
    coef = coef_s / scale
    cov = cov_s / np.outer(scale, scale)
    return DirectionFit(direction, float(coef[0]), float(coef[1]), cov, float(np.sqrt(s2)), q, dp, constrained)


def fit_with_offset(forward: tuple[np.ndarray, np.ndarray], backward: tuple[np.ndarray, np.ndarray]) -> OffsetFit:
    """Fit eq. (4) with a constant force offset to both directions' plateau points at once (:class:`OffsetFit`).

    ``forward``, ``backward``: each direction's flow-rate magnitudes Q [m^3/s] and pressure drops
    ``direction * mean(F) / A_P`` [Pa] as the plateaus give them (kept signed: an offset larger than a slow
    plateau's force makes its pressure drop negative), at least three points each, so n - 5 >= 1. Coefficients are
    returned as fitted, whatever their sign.
    """
    (q_f, dp_f), (q_b, dp_b) = ((np.abs(np.asarray(q, float)), np.asarray(dp, float)) for q, dp in (forward, backward))
    n_f = q_f.size
    x = np.zeros((n_f + q_b.size, 5))
    x[:n_f, 0], x[:n_f, 1], x[:n_f, 4] = q_f, q_f * q_f, 1.0
    x[n_f:, 2], x[n_f:, 3], x[n_f:, 4] = q_b, q_b * q_b, -1.0
    y = np.r_[dp_f, dp_b]
    scale = np.abs(x).max(axis=0)  # columns of order 1 (Q ~ 1e-6, Q^2 ~ 1e-12)
    xs = x / scale
    coef_s, *_ = np.linalg.lstsq(xs, y, rcond=None)
    resid = y - xs @ coef_s
    dof = y.size - 5
    s2 = float(resid @ resid) / dof
    coef = coef_s / scale
    cov = s2 * np.linalg.inv(xs.T @ xs) / np.outer(scale, scale)
    return OffsetFit(coef[:4].copy(), float(coef[4]), cov, float(np.sqrt(s2)), dof)


def _direction_points(plateaus: Sequence) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Each direction's (+1, -1) plateau flow rates [m^3/s] and pressure drops [Pa]."""
    out = {}
    for direction in (1, -1):
        sel = [p for p in plateaus if p.direction == direction]
        out[direction] = (np.array([p.flow_rate for p in sel]), np.array([p.pressure_drop for p in sel]))
    return out


def offset_estimate(plateaus: Sequence, area: float) -> float | None:
    """F_0 [N] of eq. (4) with a constant force offset fitted to the plateaus (:func:`fit_with_offset`), whatever its
    significance and its coefficients' signs, for piston area ``area`` [m^2]; None with fewer than three plateaus in
    a direction. A start for the diagnosis' ``load_cell_offset``, not a finding: where friction also acts on the
    plateaus, an offset can leave every coefficient of eq. (4) alone positive, and stage 1 then reports none."""
    pts = _direction_points(plateaus)
    if min(q.size for q, _ in pts.values()) < 3:
        return None
    try:
        value = fit_with_offset(pts[1], pts[-1]).force(area)[0]
    except np.linalg.LinAlgError:  # the plateaus' flow rates do not separate the coefficients
        return None
    return value if np.isfinite(value) else None


def fit_static(plateaus: Sequence, source: str = "plateaus") -> StaticFit:
    """Stage 1: fit eq. (4) per direction to the plateaus of a data set.

    Parameters
    ----------
    plateaus : sequence of :class:`bayesdamper.io.segments.Plateau`
        Each with ``direction``, ``flow_rate`` [m^3/s] and ``pressure_drop`` [Pa].
    source : str
        Data-set name used in error messages.

    Where a coefficient is held at 0, the fit with a constant force offset is made and reported in ``offset`` if it
    explains the held coefficient (:attr:`OffsetFit.explains`); the coefficients stay eq. (4)'s alone.
    """
    points = _direction_points(plateaus)
    fits = {direction: fit_direction(*points[direction], direction, source) for direction in (1, -1)}
    static = StaticFit(fits[1], fits[-1])
    if static.constrained:
        off = fit_with_offset(points[1], points[-1])
        if off.explains:
            return StaticFit(fits[1], fits[-1], off)
    return static


@dataclass(frozen=True)
class ZeroFit:
    """The force channel's zero and the Coulomb friction measured on the plateaus (:func:`plateau_zero`) [N].

    ``offset_N`` is the force the channel reads at zero force (the ``load_cell_offset`` effect's ``offset_N``);
    ``friction_N`` the direction-signed constant force common to both directions (friction opposing the motion is
    positive); each with its standard error from the two directions' least-squares covariances."""

    offset_N: float
    offset_se_N: float
    friction_N: float
    friction_se_N: float

    @property
    def measured(self) -> bool:
        """The offset lies more than :data:`OFFSET_MIN_T` standard errors from 0."""
        return bool(abs(self.offset_N) > OFFSET_MIN_T * self.offset_se_N)

    def as_dict(self) -> dict:
        return {"offset_N": self.offset_N, "offset_se_N": self.offset_se_N, "friction_N": self.friction_N,
                "friction_se_N": self.friction_se_N, "measured": self.measured}


def _intercept(q: np.ndarray, dp: np.ndarray) -> tuple[float, float]:
    """Intercept b of ``dp = C_L q + C_Q q^2 + b`` and its variance (columns scaled to unit norm for the solve)."""
    X = np.column_stack([q, q * q, np.ones_like(q)])
    scale = np.linalg.norm(X, axis=0)
    if not np.all(scale > 0):
        raise np.linalg.LinAlgError("a column of the plateaus' design is zero")
    Xs = X / scale
    theta, _, rank, _ = np.linalg.lstsq(Xs, dp, rcond=None)
    if rank < 3:
        raise np.linalg.LinAlgError("the plateaus' flow rates do not separate the coefficients")
    r = dp - Xs @ theta
    s2 = float(r @ r) / (q.size - 3)
    cov = s2 * np.linalg.inv(Xs.T @ Xs)
    return float(theta[2] / scale[2]), float(cov[2, 2] / scale[2] ** 2)


def plateau_zero(plateaus: Sequence, area: float) -> ZeroFit | None:
    """The force channel's zero and the Coulomb friction from both directions' plateau intercepts (module docstring)
    for piston area ``area`` [m^2]; None with fewer than :data:`ZERO_MIN_PLATEAUS` plateaus in a direction or flow
    rates that do not separate a direction's three coefficients."""
    pts = _direction_points(plateaus)
    if min(q.size for q, _ in pts.values()) < ZERO_MIN_PLATEAUS:
        return None
    try:
        (b_f, v_f), (b_b, v_b) = (_intercept(*pts[d]) for d in (1, -1))
    except np.linalg.LinAlgError:
        return None
    se = 0.5 * area * float(np.sqrt(v_f + v_b))
    out = ZeroFit(0.5 * area * (b_f - b_b), se, 0.5 * area * (b_f + b_b), se)
    return out if all(np.isfinite([out.offset_N, out.offset_se_N, out.friction_N])) else None
