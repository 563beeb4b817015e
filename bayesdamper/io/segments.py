"""What segmentation produces: velocity steps, transients, plateaus and the segmented record.

Immutable containers with read-only arrays; :mod:`bayesdamper.io.segmentation` builds them from a record.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from bayesdamper.io.dataset import TestRecord

StepKind = Literal["initial", "reversal"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class VelocityStep:
    """A velocity step of the piston: the start from rest or a reversal.

    Attributes
    ----------
    index : int
        Position among the record's steps, from 0.
    time : float
        Step time t_step [s], intersection of the fitted lines before and after.
    velocity_before, velocity_after : float
        Fitted piston velocity dy_P/dt before and after the step [m/s] (0 at rest).
    kind : {"initial", "reversal"}
        ``"initial"``: start from rest; ``"reversal"``: the velocity changes sign.
    direction : {1, -1}
        Sign of ``velocity_after``. +1: the piston compresses chamber 1, Δp > 0, flow CH1 -> CH2.
    force : float
        Damper force at the step [N]: mean over the last ``STEP_FORCE_WINDOW`` before it.
    """

    index: int
    time: float
    velocity_before: float
    velocity_after: float
    kind: StepKind
    direction: int
    force: float


@dataclass(frozen=True, eq=False)
class Transient:
    """The force transient after one velocity step: the data of eq. (9).

    Attributes
    ----------
    id : str
        File-name-safe identifier ``f"{test}_s{index}"``.
    test : str
        Name of the record.
    index : int
        Index of the step in the record.
    kind : {"initial", "reversal"}
        Kind of the step.
    direction : {1, -1}
        Sign of the velocity after the step (+1: Δp > 0, flow CH1 -> CH2).
    velocity : float
        Piston speed |V_P| after the step [m/s].
    t_step : float
        Step time [s]; the window is ``[t_step, t_step + tmax]``.
    time : ndarray, shape (n_times,)
        Absolute sample times in the window [s]; ``time[0] >= t_step``. Read-only.
    displacement : ndarray, shape (n_times,)
        Measured displacement y_P [m]. Read-only.
    force : ndarray, shape (n_times,)
        Measured damper force F_D,E [N]. Read-only.
    dp0 : float
        Pressure difference at the step, step force / A_P [Pa]; the initial condition Δp(t_step).
    knot_times : ndarray, shape (n_knots,)
        Knots of the fitted piecewise-linear displacement inside the window, absolute times [s];
        the first is ``t_step``, the last ``t_step + tmax``. Read-only.
    knot_displacements : ndarray, shape (n_knots,)
        Fitted displacement at the knots [m]. Read-only.
    pre_time, pre_force : ndarray, shape (n_pre,)
        The samples of the last ``STEP_FORCE_WINDOW`` before the step (those ``dp0`` is the mean of):
        times [s] and measured force [N]. Read-only; empty if not given.
    """

    id: str
    test: str
    index: int
    kind: StepKind
    direction: int
    velocity: float
    t_step: float
    time: np.ndarray
    displacement: np.ndarray
    force: np.ndarray
    dp0: float
    knot_times: np.ndarray
    knot_displacements: np.ndarray
    pre_time: np.ndarray = field(default_factory=lambda: _readonly([]))
    pre_force: np.ndarray = field(default_factory=lambda: _readonly([]))

    @property
    def duration(self) -> float:
        """Window length ``knot_times[-1] - t_step`` [s]."""
        return float(self.knot_times[-1] - self.t_step)


@dataclass(frozen=True)
class Plateau:
    """The settled end of one ramp: one point of the static characteristic, eq. (4).

    Attributes
    ----------
    test : str
        Name of the record.
    index : int
        Position of the ramp in the record, from 0 (equals the index of the step that starts it
        when the record starts from rest).
    direction : {1, -1}
        Sign of the ramp's velocity (+1: Δp > 0, flow CH1 -> CH2).
    velocity : float
        Piston speed |V_P| [m/s].
    flow_rate : float
        Flow magnitude |Q_O| = A_P |V_P| [m^3/s].
    pressure_drop : float
        Pressure-drop magnitude ``direction * mean(F) / A_P`` [Pa]; positive when the force has
        the sign the direction implies (then equal to mean |F| / A_P).
    pressure_drop_std : float
        Sample standard deviation of F / A_P over the plateau [Pa] (scatter, not the standard error;
        divide by sqrt(n) for that).
    n : int
        Number of samples.
    t_start, t_end : float
        Plateau time span [s].
    """

    test: str
    index: int
    direction: int
    velocity: float
    flow_rate: float
    pressure_drop: float
    pressure_drop_std: float
    n: int
    t_start: float
    t_end: float


@dataclass(frozen=True, eq=False)
class SegmentedRecord:
    """A record with its fitted piecewise-linear displacement, steps, transients and plateaus.

    Attributes
    ----------
    record : TestRecord
        The source record.
    steps : tuple of VelocityStep
    transients : tuple of Transient
        One per step, same order.
    plateaus : tuple of Plateau
        One per ramp.
    knot_times : ndarray, shape (n_knots,)
        Knots of the whole record's fitted piecewise-linear displacement [s]; the first and last
        are the first and last sample times. Read-only.
    knot_displacements : ndarray, shape (n_knots,)
        Fitted displacement at the knots [m]. Read-only.
    unsettled : tuple of Plateau
        Plateaus taken out of ``plateaus`` because their force still drifts
        (:func:`bayesdamper.inference.plateau_noise.settled_plateaus`); empty until that check has run.
    """

    record: TestRecord
    steps: tuple[VelocityStep, ...]
    transients: tuple[Transient, ...]
    plateaus: tuple[Plateau, ...]
    knot_times: np.ndarray
    knot_displacements: np.ndarray
    unsettled: tuple[Plateau, ...] = ()

    @property
    def name(self) -> str:
        """Name of the record."""
        return self.record.name

    def fitted_displacement(self, t: np.ndarray | float) -> np.ndarray:
        """Evaluate the fitted piecewise-linear displacement at times ``t`` [s] -> [m]."""
        return np.interp(t, self.knot_times, self.knot_displacements)
