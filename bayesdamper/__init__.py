"""bayesdamper: Bayesian identification of single-state liquid-damper models from displacement-force tests.

The pipeline, one subpackage per step (each ``__init__`` says what it owns and what it may import)::

    core -> physics -> io -> inference -> diagnosis -> report -> run -> cli

The names below are the public API; all but the errors and parameter containers are imported on first
use, so ``import bayesdamper`` stays light (no numba compilation, no matplotlib).
"""

from importlib import import_module

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

#: Public name -> module that defines it (imported lazily by ``__getattr__``).
_LAZY = {
    "PiecewiseLinear": "bayesdamper.physics.excitation",
    "simulate_single_state": "bayesdamper.physics.single_state",
    "solve_single_state": "bayesdamper.physics.single_state",
    "reference_single_state": "bayesdamper.physics.reference",
    "simulate_two_state": "bayesdamper.physics.reference",
    "simulate_effects": "bayesdamper.physics.with_effects",
    "PiecewisePolynomial": "bayesdamper.physics.excitation",
    "EFFECTS": "bayesdamper.physics.effects",
    "load_dataset": "bayesdamper.io.dataset",
    "segment_dataset": "bayesdamper.io.segmentation",
    "segment_record": "bayesdamper.io.segmentation",
    "fit_static": "bayesdamper.inference.stage1",
    "identify_window": "bayesdamper.inference.identify",
    "StageTwoSettings": "bayesdamper.inference.stage2",
    "SamplerSettings": "bayesdamper.inference.sampling",
    "fit_drift": "bayesdamper.inference.drift",
    "prepare": "bayesdamper.run.stages",
    "identify_all": "bayesdamper.run.stages",
    "drift_summary": "bayesdamper.inference.drift",
    "Progress": "bayesdamper.run.progress",
    "run_check": "bayesdamper.run.check",
    "run_identify": "bayesdamper.run.identify",
    "run_diagnosis": "bayesdamper.run.diagnose",
    "run_conditions": "bayesdamper.run.conditions",
    "run_report": "bayesdamper.run.report",
    "predict": "bayesdamper.run.predict",
    "Calibration": "bayesdamper.inference.calibration",
    "fit_hierarchy": "bayesdamper.inference.hierarchy",
}

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
    *_LAZY,
]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'bayesdamper' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
