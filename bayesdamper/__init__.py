"""bayesdamper: Bayesian identification of single-state liquid-damper models from triangular tests."""

from bayesdamper._version import __version__
from bayesdamper.core.errors import BayesDamperError, DataError, SettingsError
from bayesdamper.core.params import (
    ATMOSPHERIC_PRESSURE,
    PAPER_FLOW,
    RIG_A_DAMPER,
    DamperConstants,
    DynamicParameters,
    FlowCoefficients,
)

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
