"""bayesdamper: Bayesian identification of single-state liquid-damper models from triangular tests."""

from .errors import BayesDamperError, DataError, SettingsError
from .params import (
    ATMOSPHERIC_PRESSURE,
    PAPER_FLOW,
    RIG_A_DAMPER,
    DamperConstants,
    DynamicParameters,
    FlowCoefficients,
)

__version__ = "0.1.0"

__all__ = [
    "ATMOSPHERIC_PRESSURE",
    "PAPER_FLOW",
    "RIG_A_DAMPER",
    "BayesDamperError",
    "DamperConstants",
    "DataError",
    "DynamicParameters",
    "FlowCoefficients",
    "SettingsError",
    "__version__",
]
