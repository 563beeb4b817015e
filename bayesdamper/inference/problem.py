"""Binding of the forward model to one window of measured data (the model never sees data; this does).

A :class:`WindowProblem` keeps read-only copies of one window (sample times, measured force, the input from the
window's start, initial Δp) and the fixed damper constants and flow coefficients, and turns (α_V, p_R) into a
computed force history F_C = A_P Δp [N] by eq. (7). An :class:`EffectsProblem` does the same with effects added
(the composed kernel of :mod:`bayesdamper.physics.compose`), driven by the record's whole input so that effects
with a memory (backlash, lags) see the history before the window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.frozen import ReadOnlyArrays, frozen_copy
from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.physics.compose import ComposedEffects, solve_composed
from bayesdamper.physics.excitation import PiecewisePolynomial
from bayesdamper.physics.single_state import solve_eq7

__all__ = ["LIKELIHOOD_ATOL", "LIKELIHOOD_RTOL", "EffectsProblem", "WindowProblem", "freeze_arrays"]

#: Kernel tolerances used inside the likelihood. The kernel's relative L2 error at rtol 1e-5 is < 1e-5
#: over the prior box (benchmarks/forward.py): ~0.1 N on rig-A forces, two orders below the 12 N noise.
LIKELIHOOD_RTOL = 1e-5
LIKELIHOOD_ATOL = 1.0  # [Pa]: far below 1 N / A_P force resolution


def freeze_arrays(obj, names: tuple[str, ...]) -> None:
    """Replace the array attributes ``names`` of a frozen dataclass by read-only float64 copies."""
    for name in names:
        object.__setattr__(obj, name, frozen_copy(getattr(obj, name)))


def _local(drive: PiecewisePolynomial, t_step: float, time: np.ndarray, segment_id: str) -> PiecewisePolynomial:
    """The input from the window's start, covering its samples (a sample a rounding error past its end holds)."""
    t_end = float(time[-1])
    if not (drive.start <= t_step <= float(time[0])):
        raise SettingsError(f"{segment_id}: the input must start at or before the window, and the samples at or "
                            "after the window's start")
    return drive.window(t_step, max(t_end, t_step + 1e-9))


@dataclass(frozen=True)
class WindowProblem(ReadOnlyArrays):
    """One window bound to the damper and its flow coefficients: (α_V, p_R) -> force by eq. (7).

    Attributes
    ----------
    segment_id : str
        Identifier of the window.
    time : ndarray, shape (n_times,)
        Absolute sample times [s], the first at or after ``t_step``.
    force : ndarray, shape (n_times,)
        Measured force F_E [N].
    t_step : float
        Start of the window [s]; Δp(t_step) = ``dp0``.
    dp0 : float
        Initial pressure difference [Pa].
    drive : PiecewisePolynomial
        Piston displacement from ``t_step`` over the window [m].
    damper : DamperConstants
    flow : FlowCoefficients
    """

    segment_id: str
    time: np.ndarray
    force: np.ndarray
    t_step: float
    dp0: float
    drive: PiecewisePolynomial
    damper: DamperConstants
    flow: FlowCoefficients
    rtol: float = LIKELIHOOD_RTOL
    atol: float = LIKELIHOOD_ATOL

    def __post_init__(self) -> None:
        freeze_arrays(self, ("time", "force"))
        object.__setattr__(self, "drive", _local(self.drive, self.t_step, self.time, self.segment_id))
        object.__setattr__(self, "flow_array", self.flow.as_array())

    @classmethod
    def from_window(cls, window, damper: DamperConstants, flow: FlowCoefficients, **kw) -> WindowProblem:
        """Build from a :class:`bayesdamper.io.windows.Window`."""
        return cls(window.id, window.time, window.force, window.t_step, window.dp0, window.local_drive, damper,
                   flow, **kw)

    def with_flow(self, flow: FlowCoefficients) -> WindowProblem:
        """The same window with other flow coefficients."""
        return WindowProblem(self.segment_id, self.time, self.force, self.t_step, self.dp0, self.drive,
                             self.damper, flow, self.rtol, self.atol)

    def simulate_dp(self, alpha_v: float, p_r: float) -> tuple[np.ndarray, bool]:
        """Δp [Pa] at the sample times by eq. (7), and whether the solve succeeded."""
        d, w = self.damper, self.drive
        dp, status, _ = solve_eq7(self.time, w.breaks, w.coefs, w.restart, self.dp0, d.piston_area,
                                  d.chamber_volume_1, d.chamber_volume_2, d.liquid_bulk_modulus, self.flow_array,
                                  float(alpha_v), float(p_r), 0, 0.0, self.rtol, self.atol)
        return dp, status == 0

    def simulate_force(self, alpha_v: float, p_r: float) -> tuple[np.ndarray, bool]:
        """Computed force F_C = A_P Δp [N] and whether the solve succeeded."""
        dp, ok = self.simulate_dp(alpha_v, p_r)
        return self.damper.piston_area * dp, ok


#: Kernel tolerances of :class:`EffectsProblem` (the diagnosis's candidate search): the likelihood's. The search's
#: forward differences replay the steps of the solve they are differenced against
#: (:func:`~bayesdamper.physics.compose.solve_composed`), so their error is the discrete solution's, not the
#: tolerance's noise over the difference's step (error-controlled differences, even at rtol 1e-6, put a two-state +
#: valve window's Jacobian up to 41 % off on rig-A against rtol 1e-8; on replayed steps at this tolerance, 21 %).
EFFECTS_RTOL = 1e-5
EFFECTS_ATOL = 1.0  # [Pa]
#: Box of a window's (log α_V, log p_R) in its least-squares re-fits: the priors' boxes.
INNER_BOX = (np.log([2.0, 1e3]), np.log([5000.0, 1e7]))
#: Box of a window's own flow coefficients, in units of the coefficient that alone carries its largest force at
#: its largest flow (the flat prior's upper end; the lower end a thousandth of the scale, far below any effect
#: on the force, keeps the log finite).
FLOW_BOX = (1e-3, 100.0)


@dataclass(frozen=True, eq=False)
class EffectsProblem(ReadOnlyArrays):
    """One window bound to the damper and the record's whole input, for models with effects.

    ``simulate_force(alpha_v, p_r, effects)`` solves eq. (7) with any effects (the composed kernel) from the
    window's start. The start state: with ``step_force`` (a settled start: the measured force before the step),
    Δp0 is solved so that the model's force with every effect equals it (friction, offsets... included); without
    it, Δp0 = ``dp0`` [Pa] is given (a window that starts in motion; its value is a parameter of the fit).

    Attributes
    ----------
    segment_id : str
    time, force : ndarray, shape (n_times,)
        Absolute sample times [s] (the first at or after ``t_step``) and measured force [N]. Read-only.
    t_step : float
        Start of the window [s].
    step_force : float or None
        Measured force at the start [N] of a settled start, else None.
    dp0 : float
        Δp at the start [Pa] when there is no step force (ignored otherwise).
    drive : PiecewisePolynomial
        The record's measured displacement from its start [m].
    damper : DamperConstants
    flow : FlowCoefficients
    rtol, atol : float
        Kernel tolerances [-], [Pa].
    max_steps : int or None
        Accepted steps after which a solve fails (None: the kernel's default); the diagnosis caps its candidate
        search this way.
    free_flow : bool
        The flow coefficients are the window's own parameters (no stage 1), fitted with α_V and p_R.

    The window's own parameters x (:meth:`inner_box`, :meth:`simulate_inner`): (log α_V, log p_R); for a window
    that starts in motion also s0, the start force over A_P in units of :attr:`p_scale`; without stage 1 also the
    logs of the four flow coefficients.
    """

    segment_id: str
    time: np.ndarray
    force: np.ndarray
    t_step: float
    step_force: float | None
    dp0: float
    drive: PiecewisePolynomial
    damper: DamperConstants
    flow: FlowCoefficients
    rtol: float = EFFECTS_RTOL
    atol: float = EFFECTS_ATOL
    max_steps: int | None = None
    free_flow: bool = False
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        freeze_arrays(self, ("time", "force"))
        object.__setattr__(self, "_flow4", self.flow.as_array())
        if self.time.size == 0 or self.time.shape != self.force.shape:
            raise SettingsError(f"{self.segment_id}: time and force must be non-empty and of equal length")
        if not (self.drive.start <= self.t_step <= self.time[0]):
            raise SettingsError(f"{self.segment_id}: the input must start at or before the window, and the samples "
                                "at or after its start")
        area = self.damper.piston_area
        object.__setattr__(self, "p_scale", max(float(np.max(np.abs(self.force))) / area, 1.0))
        q = area * np.abs(self.drive.velocity(self.time))
        qmax = max(float(np.quantile(q, 0.99)), 1e-12)
        object.__setattr__(self, "flow_scales", np.array([self.p_scale / qmax, self.p_scale / qmax**2] * 2))

    @classmethod
    def from_window(cls, window, damper: DamperConstants, flow: FlowCoefficients | None, *, time=None, force=None,
                    start_force: float | None = None, **kw) -> EffectsProblem:
        """Build from a :class:`bayesdamper.io.windows.Window`: its step force when it starts settled, else
        ``start_force`` [N] if given (else the start force is a parameter); ``flow`` None: the flow coefficients
        are the window's own parameters; ``time``, ``force``: a subset of the window's samples."""
        step_force = float(window.dp0) * damper.piston_area if window.starts_settled else start_force
        free = flow is None
        flow = flow if flow is not None else FlowCoefficients(1.0, 1.0, 1.0, 1.0)
        return cls(window.id, window.time if time is None else time, window.force if force is None else force,
                   float(window.t_step), step_force, float(window.dp0), window.drive, damper, flow, free_flow=free,
                   **kw)

    # ------------------------------------------------------------------ the window's own parameters
    @property
    def free_start(self) -> bool:
        """The force at the start is a parameter of the window (it starts in motion)."""
        return self.step_force is None

    def inner_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Box of the window's own parameters x (class docstring)."""
        lo, hi = list(INNER_BOX[0]), list(INNER_BOX[1])
        if self.free_start:
            f_lo, f_hi = float(np.min(self.force)), float(np.max(self.force))
            span = max(f_hi - f_lo, 1e-6 * self.p_scale * self.damper.piston_area)
            scale = self.p_scale * self.damper.piston_area
            lo.append((f_lo - span) / scale)
            hi.append((f_hi + span) / scale)
        if self.free_flow:
            lo += list(np.log(FLOW_BOX[0] * self.flow_scales))
            hi += list(np.log(FLOW_BOX[1] * self.flow_scales))
        return np.array(lo), np.array(hi)

    def inner_start(self, alpha_v: float, p_r: float, start_force: float | None = None,
                    flow4: np.ndarray | None = None) -> np.ndarray:
        """x of given α_V [-], p_R [Pa], start force [N] and flow coefficients (clipped into the box)."""
        x = [math.log(alpha_v), math.log(p_r)]
        if self.free_start:
            f0 = float(np.mean(self.force[:3])) if start_force is None else float(start_force)
            x.append(f0 / (self.p_scale * self.damper.piston_area))
        if self.free_flow:
            c = np.asarray(flow4 if flow4 is not None else 0.5 * self.flow_scales, dtype=float)
            x += list(np.log(np.maximum(c, FLOW_BOX[0] * self.flow_scales)))
        lo, hi = self.inner_box()
        return np.clip(np.array(x), lo + 1e-9, hi - 1e-9)

    def unpack_inner(self, x: np.ndarray) -> dict:
        """The physical values of x: ``alpha_V`` [-], ``p_R_Pa`` [Pa], ``start_force_N`` [N] and ``flow`` (4,)."""
        k = 2
        out = {"alpha_V": math.exp(x[0]), "p_R_Pa": math.exp(x[1])}
        if self.free_start:
            out["start_force_N"] = float(x[k]) * self.p_scale * self.damper.piston_area
            k += 1
        if self.free_flow:
            out["flow"] = np.exp(np.asarray(x[k:k + 4], dtype=float))
        return out

    def simulate_inner(self, x: np.ndarray, effects: ComposedEffects, flow: FlowCoefficients | None = None, *,
                       record: bool = False, replay: np.ndarray | None = None) -> tuple:
        """Computed force [N] at the window's own parameters ``x`` with ``effects`` (``flow`` replaces the fixed
        flow coefficients of a window without its own), and whether the solve succeeded. ``record``: also the
        solve's steps (:func:`~bayesdamper.physics.compose.solve_composed`); ``replay``: a solve's steps to take
        (a finite difference against that solve)."""
        v = self.unpack_inner(x)
        if self.free_flow:
            flow4 = v["flow"]
        else:
            flow4 = (flow if flow is not None else self.flow).as_array()
        drive, v_prev = self._input(effects)
        start = v["start_force_N"] if self.free_start else self.step_force
        if not (math.isfinite(start) and np.all(np.isfinite(flow4))):
            return (np.full(self.time.shape, np.nan), False) + ((None,) if record else ())
        out = solve_composed(effects, self.time, drive, self.t_step, start, v_prev, self.damper,
                             np.ascontiguousarray(flow4, dtype=float), v["alpha_V"], v["p_R_Pa"], self.rtol, self.atol,
                             from_force=True, max_steps=self.max_steps, record=record, replay=replay)
        return (out[0], out[1] == 0) + tuple(out[2:])

    def _input(self, comp: ComposedEffects) -> tuple[PiecewisePolynomial, float]:
        key = (comp.names, comp.values.tobytes())
        hit = self._cache.get("input")
        if hit is not None and hit[0] == key:
            return hit[1]
        drive = comp.transform_input(self.drive).cover(self.t_step, float(self.time[-1]))
        out = (drive, drive.velocity_before(self.t_step) if self.step_force is not None
               else float(drive.velocity(self.t_step)))  # in motion: the steady state at the start's velocity
        self._cache["input"] = (key, out)
        return out

    def simulate_force(self, alpha_v: float, p_r: float, effects: ComposedEffects) -> tuple[np.ndarray, bool]:
        """Computed force F_C [N] at the sample times and whether the solve succeeded."""
        drive, v_prev = self._input(effects)
        settled = self.step_force is not None
        start = self.step_force if settled else self.dp0
        if not math.isfinite(start):
            return np.full(self.time.shape, np.nan), False
        force, status = solve_composed(effects, self.time, drive, self.t_step, start, v_prev, self.damper,
                                       self._flow4, float(alpha_v), float(p_r), self.rtol, self.atol,
                                       from_force=settled, max_steps=self.max_steps)
        return force, status == 0
