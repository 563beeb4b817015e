"""Reparametrisation for the sampler: parameters bounded by 0 sampled as their logarithm.

The sampler (:mod:`bayesdamper.inference.sampling`) moves on whatever vector its target takes; a target wrapped
in :class:`LogScaled` is the same posterior in other coordinates, which suits ensemble moves where a parameter's
posterior spans decades. Imports: numpy.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["LOG_FLOOR_FRACTION", "LogScaled"]


#: Floor of a parameter sampled on the log scale (:class:`LogScaled`), as a fraction of its upper bound: a
#: uniform prior on [0, upper] has the mass floor/upper below it (left out); above it the density in the log is
#: the prior's Jacobian, falling off exponentially towards the floor where the data do not bound the parameter.
LOG_FLOOR_FRACTION = 1e-9


class LogScaled:
    """A posterior whose entries ``dims`` (uniform priors on [0, upper]) are sampled as their logarithm, from
    ``floor`` (default :data:`LOG_FLOOR_FRACTION` of the upper bound) up.

    A parameter whose posterior runs from near 0 over decades (a flow coefficient the data bound only from above:
    on a measured MR damper's windows of cycles one such coefficient spanned a factor 60 in its 90 % interval) is
    a funnel on its own scale, which the ensemble moves cross slowly (τ of 60-100 steps in every parameter); in
    its log, with the uniform prior's Jacobian u ↦ e^u, it is a smooth, light-tailed density. The target is the
    same posterior: rows u map to θ (θ_d = e^{u_d}), the log density gains Σ_d u_d. ``to_theta`` maps draws back.
    """

    def __init__(self, log_prob: Callable[[np.ndarray], float], dims, lower: np.ndarray, upper: np.ndarray,
                 floor: np.ndarray | float | None = None):
        self.log_prob = log_prob
        self.dims = np.asarray(dims, dtype=int)
        lower, upper = np.asarray(lower, float), np.asarray(upper, float)
        if np.any(upper[self.dims] <= 0) or np.any(lower[self.dims] < 0):
            raise ValueError("log scaling needs parameters bounded by 0 below and a positive upper bound")
        floor = LOG_FLOOR_FRACTION * upper[self.dims] if floor is None else np.broadcast_to(floor, self.dims.shape)
        self.lower, self.upper = lower.copy(), upper.copy()
        self.lower[self.dims] = np.log(np.maximum(lower[self.dims], floor))
        self.upper[self.dims] = np.log(upper[self.dims])
        if hasattr(log_prob, "batch"):
            self.batch = self._batch

    def to_theta(self, u: np.ndarray) -> np.ndarray:
        theta = np.array(u, dtype=float)
        theta[..., self.dims] = np.exp(theta[..., self.dims])
        return theta

    def to_u(self, theta: np.ndarray) -> np.ndarray:
        u = np.array(theta, dtype=float)
        u[..., self.dims] = np.log(np.maximum(u[..., self.dims], np.exp(self.lower[self.dims])))
        return u

    def covariance(self, theta: np.ndarray, cov: np.ndarray | None) -> np.ndarray | None:
        """``cov`` of θ near ``theta`` carried to u (delta method: the dims divided by their values)."""
        if cov is None:
            return None
        d = np.ones(theta.size)
        d[self.dims] = 1.0 / np.maximum(np.asarray(theta, float)[self.dims], np.exp(self.lower[self.dims]))
        return cov * np.outer(d, d)

    def __call__(self, u: np.ndarray) -> float:
        u = np.asarray(u, dtype=float)
        if not (np.all(u >= self.lower) and np.all(u <= self.upper)):
            return -np.inf
        return float(self.log_prob(self.to_theta(u))) + float(np.sum(u[self.dims]))

    def _batch(self, u: np.ndarray) -> np.ndarray:
        u = np.atleast_2d(np.asarray(u, dtype=float))
        out = np.full(len(u), -np.inf)
        inside = np.all((u >= self.lower) & (u <= self.upper), axis=1)
        if np.any(inside):
            out[inside] = (np.asarray(self.log_prob.batch(self.to_theta(u[inside])), dtype=float)
                           + np.sum(u[inside][:, self.dims], axis=1))
        return out
