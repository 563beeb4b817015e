"""Binding of the forward model to one measured transient (model never sees data; this does).

A :class:`TransientProblem` keeps read-only copies of one transient window (sample times, measured
force, fitted piecewise-linear displacement, initial Δp) and the fixed damper constants and stage-1
flow coefficients, and turns (α_V, p_R) into a computed force history F_C = A_P Δp [N].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.physics import single_state as model

#: Kernel tolerances used inside the likelihood. The kernel's relative L2 error at rtol 1e-5 is < 1e-5
#: over the prior box (benchmarks/forward.py): ~0.1 N on rig-A forces, two orders below the 12 N noise.
LIKELIHOOD_RTOL = 1e-5
LIKELIHOOD_ATOL = 1.0  # [Pa]: far below 1 N / A_P force resolution


def freeze_window(problem, names: tuple[str, ...]) -> None:
    """Make a frozen window problem's arrays read-only float64 copies, and check its knots cover its samples.

    A sample at the window end that rounding put a hair (1e-9 relative) past the last knot extends that knot.
    ``problem`` needs ``segment_id``, ``time`` and ``knot_times`` among ``names``.
    """
    for name in names:
        arr = np.ascontiguousarray(getattr(problem, name), dtype=np.float64).copy()
        arr.flags.writeable = False
        object.__setattr__(problem, name, arr)
    kt, t = problem.knot_times, problem.time
    if t[-1] > kt[-1] and t[-1] - kt[-1] <= 1e-9 * max(1.0, abs(float(kt[-1]))):
        kt = kt.copy()
        kt[-1] = t[-1]
        kt.flags.writeable = False
        object.__setattr__(problem, "knot_times", kt)
    if not (problem.knot_times[0] <= t[0] and t[-1] <= problem.knot_times[-1]):
        raise ValueError(f"{problem.segment_id}: knots must cover the sample times")


@dataclass(frozen=True)
class TransientProblem:
    """One transient window bound to the damper and its static flow coefficients.

    Attributes
    ----------
    segment_id : str
        Identifier of the transient.
    time : ndarray, shape (n_times,)
        Absolute sample times [s], the first at or after ``t_step``.
    force : ndarray, shape (n_times,)
        Measured force F_E [N].
    t_step : float
        Time of the velocity step [s]; Δp(t_step) = ``dp0``.
    dp0 : float
        Initial pressure difference [Pa].
    knot_times, knot_displacements : ndarray
        Piecewise-linear piston displacement over the window [s], [m].
    damper : DamperConstants
    flow : FlowCoefficients
    """

    segment_id: str
    time: np.ndarray
    force: np.ndarray
    t_step: float
    dp0: float
    knot_times: np.ndarray
    knot_displacements: np.ndarray
    damper: DamperConstants
    flow: FlowCoefficients
    rtol: float = LIKELIHOOD_RTOL
    atol: float = LIKELIHOOD_ATOL

    def __post_init__(self) -> None:
        freeze_window(self, ("time", "force", "knot_times", "knot_displacements"))
        object.__setattr__(self, "flow_array", self.flow.as_array())

    @classmethod
    def from_transient(cls, transient, damper: DamperConstants, flow: FlowCoefficients,
                       **kw) -> TransientProblem:
        """Build from a :class:`bayesdamper.io.segments.Transient`."""
        return cls(transient.id, transient.time, transient.force, transient.t_step, transient.dp0,
                   transient.knot_times, transient.knot_displacements, damper, flow, **kw)

    def with_flow(self, flow: FlowCoefficients) -> TransientProblem:
        """The same window with other flow coefficients."""
        return TransientProblem(self.segment_id, self.time, self.force, self.t_step, self.dp0,
                                self.knot_times, self.knot_displacements, self.damper, flow,
                                self.rtol, self.atol)

    def simulate_dp(self, alpha_v: float, p_r: float) -> tuple[np.ndarray, bool]:
        """Δp [Pa] at the sample times by eq. (7), and whether the solve succeeded."""
        d = self.damper
        dp, status, _ = model.solve_single_state(
            self.time, self.knot_times, self.knot_displacements, self.dp0,
            d.piston_area, d.chamber_volume_1, d.chamber_volume_2, d.liquid_bulk_modulus,
            self.flow_array, float(alpha_v), float(p_r), 0, 0.0, self.rtol, self.atol)
        return dp, status == 0

    def simulate_force(self, alpha_v: float, p_r: float) -> tuple[np.ndarray, bool]:
        """Computed force F_C = A_P Δp [N] and whether the solve succeeded."""
        dp, ok = self.simulate_dp(alpha_v, p_r)
        return self.damper.piston_area * dp, ok
