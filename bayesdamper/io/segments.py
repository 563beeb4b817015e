"""What segmentation produces: velocity steps, transients, plateaus and the segmented record.

Immutable containers with read-only arrays; :mod:`bayesdamper.io.segmentation` builds them from a record. A
transient is a :class:`~bayesdamper.io.windows.Window` (the unit of identification of every record).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayesdamper.io.dataset import TestRecord
from bayesdamper.io.windows import Window

StepKind = Literal["initial", "reversal"]



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
    approach_tau : float or None
        Where the force was still approaching its settled value within the plateau: the time constant [s] of that
        approach, and ``pressure_drop`` is the settled value it extrapolates to
        (:func:`bayesdamper.inference.settle.settled_plateaus`). None: the force had settled and
        ``pressure_drop`` is the plateau's mean.
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
    approach_tau: float | None = None


@dataclass(frozen=True, eq=False)
class SegmentedRecord:
    """A record with its fitted piecewise-linear displacement, steps, transients and plateaus.

    Attributes
    ----------
    record : TestRecord
        The source record.
    steps : tuple of VelocityStep
    transients : tuple of Window
        One per step, same order (kind ``"initial"`` or ``"reversal"``).
    plateaus : tuple of Plateau
        One per ramp.
    knot_times : ndarray, shape (n_knots,)
        Knots of the whole record's fitted piecewise-linear displacement [s]; the first and last
        are the first and last sample times. Read-only.
    knot_displacements : ndarray, shape (n_knots,)
        Fitted displacement at the knots [m]. Read-only.
    unsettled : tuple of Plateau
        Plateaus taken out of ``plateaus`` because their force still drifts and its approach does not pin the
        settled force (:func:`bayesdamper.inference.settle.settled_plateaus`); empty until that check has run.
    """

    record: TestRecord
    steps: tuple[VelocityStep, ...]
    transients: tuple[Window, ...]
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
