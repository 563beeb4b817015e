"""The sampled parameter vector: its order, bounds, priors and transforms, in one place.

Nothing else in the package knows the order of the vector the sampler moves. The physical parameters
α_V [-] and p_R [Pa] are sampled as natural logarithms under uniform priors on the log (log-uniform,
the scale-free choice for quantities known only to within decades); noise-model parameters, when the
noise model has any, follow them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayesdamper.core.errors import SettingsError

#: Default prior box of the liquid-gas volume ratio α_V [-]: a few to a few thousand (paper: 33 to 90).
ALPHA_V_BOUNDS = (2.0, 5000.0)
#: Default prior box of the reference pressure p_R [Pa]: 1 kPa to 10 MPa (paper: 27 kPa to 0.3 MPa).
P_R_BOUNDS = (1.0e3, 1.0e7)
#: Prior box of the AR(1) coefficient of the residual [-]; 0.999 keeps the stationary variance finite.
PHI_BOUNDS = (-0.5, 0.999)


@dataclass(frozen=True)
class ParameterSpec:
    """One sampled parameter.

    Attributes
    ----------
    name : str
        Name used in outputs (``alpha_V``, ``p_R_Pa``, ``phi``).
    unit : str
        Physical unit of the parameter (not of its transform).
    lower, upper : float
        Prior bounds in physical units.
    log : bool
        Sampled as ``log(value)`` under a uniform prior on the log if true, else uniform on the value.
    """

    name: str
    unit: str
    lower: float
    upper: float
    log: bool = True

    def __post_init__(self) -> None:
        if not (np.isfinite(self.lower) and np.isfinite(self.upper) and self.lower < self.upper):
            raise SettingsError(f"prior of {self.name}: need finite lower < upper, got "
                                f"[{self.lower}, {self.upper}]")
        if self.log and self.lower <= 0:
            raise SettingsError(f"prior of {self.name}: a log-uniform prior needs a positive lower bound")

    @property
    def bounds_transformed(self) -> tuple[float, float]:
        """Bounds of the sampled (transformed) variable."""
        if self.log:
            return float(np.log(self.lower)), float(np.log(self.upper))
        return float(self.lower), float(self.upper)


@dataclass(frozen=True)
class ParameterSpace:
    """The ordered sampled vector ``theta`` and its prior (uniform in the transformed variables)."""

    specs: tuple[ParameterSpec, ...] = field(default_factory=tuple)

    @classmethod
    def default(cls, noise_params: tuple[ParameterSpec, ...] = (),
                alpha_v_bounds: tuple[float, float] = ALPHA_V_BOUNDS,
                p_r_bounds: tuple[float, float] = P_R_BOUNDS) -> ParameterSpace:
        """α_V and p_R with log-uniform priors, then the noise model's parameters."""
        return cls((ParameterSpec("alpha_V", "-", *alpha_v_bounds),
                    ParameterSpec("p_R_Pa", "Pa", *p_r_bounds)) + tuple(noise_params))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.specs)

    @property
    def ndim(self) -> int:
        return len(self.specs)

    @property
    def lower(self) -> np.ndarray:
        return np.array([s.bounds_transformed[0] for s in self.specs])

    @property
    def upper(self) -> np.ndarray:
        return np.array([s.bounds_transformed[1] for s in self.specs])

    def log_prior(self, theta: np.ndarray) -> float:
        """Log prior density of the transformed vector (0 inside the box up to a constant, else -inf)."""
        theta = np.asarray(theta, dtype=float)
        if not np.all(np.isfinite(theta)) or np.any(theta < self.lower) or np.any(theta > self.upper):
            return -np.inf
        return 0.0

    def to_physical(self, theta: np.ndarray) -> np.ndarray:
        """Map transformed values (last axis = parameters) to physical units."""
        theta = np.asarray(theta, dtype=float)
        out = theta.copy()
        for i, s in enumerate(self.specs):
            if s.log:
                out[..., i] = np.exp(theta[..., i])
        return out

    def to_transformed(self, values: np.ndarray) -> np.ndarray:
        """Map physical values (last axis = parameters) to the sampled variables."""
        values = np.asarray(values, dtype=float)
        out = values.copy()
        for i, s in enumerate(self.specs):
            if s.log:
                out[..., i] = np.log(values[..., i])
        return out

    def clip_inside(self, theta: np.ndarray, margin: float = 1e-6) -> np.ndarray:
        """Move points just inside the prior box (for starting walkers at an optimum on a bound)."""
        span = self.upper - self.lower
        return np.clip(theta, self.lower + margin * span, self.upper - margin * span)
