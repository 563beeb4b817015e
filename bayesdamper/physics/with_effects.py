"""Simulators of eq. (7) and of the two-state model with effects: the Python side of the augmented kernel.

:func:`simulate_augmented` drives the compiled kernel (:mod:`bayesdamper.physics.augmented`) from a
measured or synthetic displacement history; :class:`AugmentedProblem` is its counterpart of
:class:`~bayesdamper.inference.problem.TransientProblem` for fits with effects;
:func:`simulate_two_state_augmented` adds the same effects to the two-state reference eq. (1).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.core.params import DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.physics.augmented import (
    _COMPLIANCE,
    _COULOMB,
    _GAP,
    _LAG_TAU,
    _MASS,
    _MESSAGES,
    _STRIBECK,
    _STRIBECK_V,
    _VALVE_P,
    _VALVE_TAU,
    _VISCOUS,
    solve_augmented,
)
from bayesdamper.physics.compose import ComposedEffects, compose, solve_composed
from bayesdamper.physics.effect_vector import EFFECT_SLOTS, VECTOR_EFFECTS, pack_effects, unpack_effects
from bayesdamper.physics.effects import EFFECTS, complete_effects
from bayesdamper.physics.effects.backlash import backlash_knots
from bayesdamper.physics.effects.friction import friction_force, friction_force_scalar
from bayesdamper.physics.effects.inertia import CORNER_TIME_S
from bayesdamper.physics.effects.valve_dynamics import MIN_OPENING
from bayesdamper.physics.excitation import PiecewiseLinear
from bayesdamper.physics.rodas import (
    DEFAULT_ATOL,
    DEFAULT_RTOL,
    STATUS_OK,
)


# ----------------------------------------------------------------------------- Python wrappers
def _times(t_out) -> np.ndarray:
    t_out = np.ascontiguousarray(t_out, dtype=float)
    if t_out.ndim != 1 or t_out.size == 0 or not np.all(np.isfinite(t_out)):
        raise SettingsError("output times must be a non-empty 1-D array of finite numbers")
    if np.any(np.diff(t_out) < 0):
        raise SettingsError("output times must be non-decreasing")
    return t_out


def _held_knots(kt: np.ndarray, ky: np.ndarray, t_lo: float, t_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Knots extended to cover ``[t_lo, t_hi]`` [s] with the end displacements held."""
    if t_lo < kt[0]:
        kt, ky = np.concatenate(([t_lo], kt)), np.concatenate(([ky[0]], ky))
    if t_hi > kt[-1]:
        kt, ky = np.concatenate((kt, [t_hi])), np.concatenate((ky, [ky[-1]]))
    return np.ascontiguousarray(kt), np.ascontiguousarray(ky)


def _velocity_before(kt: np.ndarray, ky: np.ndarray, t0: float) -> float:
    """Left-limit velocity [m/s] of the piecewise-linear displacement at ``t0`` [s] (0 before the knots)."""
    j = int(np.searchsorted(kt, t0, side="left"))
    if j == 0 or j >= kt.size:
        return 0.0
    return float((ky[j] - ky[j - 1]) / (kt[j] - kt[j - 1]))


def _piston_knots(excitation: PiecewiseLinear, gap: float, t_lo: float, t_hi: float):
    """Backlash-transformed knots of the whole excitation, held to cover ``[t_lo, t_hi]``."""
    kt, ky = backlash_knots(excitation.knot_times, excitation.knot_displacements, gap)
    return _held_knots(kt, ky, t_lo, t_hi)


def _start(t_out: np.ndarray, t0: float | None) -> float:
    t0 = float(t_out[0]) if t0 is None else float(t0)
    if not (np.isfinite(t0) and t_out[0] >= t0):
        raise SettingsError(f"output times start at {t_out[0]!r} s, before the transient start t0={t0!r} s")
    return t0


def simulate_augmented(
    t_out: np.ndarray,
    excitation: PiecewiseLinear,
    damper: DamperConstants,
    flow: FlowCoefficients,
    dynamic: DynamicParameters,
    effects: Mapping[str, Mapping[str, float] | None] | None,
    *,
    dp0: float = 0.0,
    t0: float | None = None,
    rtol: float = DEFAULT_RTOL,
    atol: float = DEFAULT_ATOL,
) -> np.ndarray:
    """Measured force of eq. (7) with effects at the sample times (:func:`solve_augmented`).

    Parameters
    ----------
    t_out : ndarray, shape (n_t,)
        Non-decreasing sample times [s], all >= ``t0``.
    excitation : PiecewiseLinear
        Measured (actuator) displacement of the whole record from its start [m]; backlash is applied
        to all of it (piston centred in the play at the first knot), so the play state at ``t0``
        follows from the history.
    damper, flow, dynamic
        A_P, V_{0,1}, V_{0,2}, B_0; eq. (8) coefficients; α_V and p_R of eq. (6).
    effects : dict or None
        ``{effect: {param: value}}`` (:mod:`bayesdamper.physics.effects`; defaults fill the rest).
    dp0 : float
        Δp at ``t0`` [Pa] (hydraulic part; the force at t0 adds friction).
    t0 : float, optional
        Start of the solution [s]; default ``t_out[0]``. Lag and corner filter start in the steady
        state of the velocity just before t0.
    rtol, atol : float
        Kernel tolerances: relative [-] and absolute [Pa].

    Returns
    -------
    ndarray, shape (n_t,)
        Measured force F [N].

    Raises
    ------
    BayesDamperError
        If the solve fails (one line naming the reason).
    """
    t_out = _times(t_out)
    t0 = _start(t_out, t0)
    arg = effect_argument(effects)
    if isinstance(arg, ComposedEffects):
        kt, ky = arg.transform_knots(excitation.knot_times, excitation.knot_displacements)
        kt, ky = _held_knots(kt, ky, t0, float(t_out[-1]))
        force, status = solve_composed(arg, t_out, kt, ky, t0, float(dp0), _velocity_before(kt, ky, t0), damper,
                                       flow.as_array(), float(dynamic.liquid_gas_ratio),
                                       float(dynamic.reference_pressure), float(rtol), float(atol))
        if status != STATUS_OK:
            raise BayesDamperError(f"composed solve failed (alpha_V={dynamic.liquid_gas_ratio!r}, "
                                   f"p_R={dynamic.reference_pressure!r} Pa, effects={arg.as_dict()}): "
                                   f"{_MESSAGES[int(status)]}")
        return force
    eff = arg
    kt, ky = _piston_knots(excitation, eff[_GAP], t0, float(t_out[-1]))
    force, status = solve_augmented(
        t_out, kt, ky, t0, float(dp0), _velocity_before(kt, ky, t0), damper.piston_area,
        damper.chamber_volume_1, damper.chamber_volume_2, damper.liquid_bulk_modulus, flow.as_array(),
        float(dynamic.liquid_gas_ratio), float(dynamic.reference_pressure), eff, float(rtol), float(atol))
    if status != STATUS_OK:
        raise BayesDamperError(f"augmented solve failed (alpha_V={dynamic.liquid_gas_ratio!r}, "
                               f"p_R={dynamic.reference_pressure!r} Pa, effects={unpack_effects(eff)}): "
                               f"{_MESSAGES[int(status)]}")
    return force


def effect_argument(effects: Mapping[str, Mapping[str, float] | None] | None) -> np.ndarray | ComposedEffects:
    """What the simulators take for an effect set: the fixed effect vector when every named effect has
    slots in it (the hand-written kernel), else a :class:`~bayesdamper.physics.compose.ComposedEffects`."""
    full = complete_effects(effects)
    if all(name in VECTOR_EFFECTS for name in full):
        return pack_effects(full)
    return compose(full)


# ----------------------------------------------------------------------------- problem binding
#: Kernel tolerances inside the likelihood: those of :class:`bayesdamper.inference.problem.TransientProblem`.
PROBLEM_RTOL = 1e-6
PROBLEM_ATOL = 1.0  # [Pa]
#: Step cap of the diagnosis's candidate search, per output sample: a solve needing more resolves motion
#: faster than the sampling can show (RODAS4 takes some 20-30 steps per period of an undamped oscillation at
#: rtol 1e-6, so 3 per sample is about a tenth of the sample rate; a chattering valve at an extreme trial
#: value, say); it counts as a failed solve there instead of taking up to 100 000 steps (stiff, decaying
#: modes cost few steps: the solver is L-stable). rig-A's final model takes 0.23 steps per sample.
STEPS_PER_SAMPLE = 3


@dataclass(frozen=True, eq=False)
class AugmentedProblem:
    """One transient window bound to the damper, its flow coefficients and the whole record's knots.

    The diagnosis calls :meth:`simulate_force` with (α_V, p_R) and an effect vector. The whole
    record's displacement knots let backlash and actuator lag see the history before the step.

    Attributes
    ----------
    segment_id : str
        Identifier of the transient.
    time : ndarray, shape (n_times,)
        Absolute sample times [s], the first at or after ``t_step``. Read-only.
    force : ndarray, shape (n_times,)
        Measured force F_E [N]. Read-only.
    t_step : float
        Time of the velocity step [s].
    step_force : float
        Measured force at the step [N] (friction included).
    record_knot_times, record_knot_displacements : ndarray, shape (n_knots,)
        Knots of the whole record's measured displacement [s], [m]. Read-only.
    damper : DamperConstants
    flow : FlowCoefficients
    rtol, atol : float
        Kernel tolerances [-], [Pa].
    max_steps : int or None
        Accepted steps after which a composed-kernel solve fails (None: the kernel's default). The diagnosis
        caps its candidate search at :data:`STEPS_PER_SAMPLE` per sample.
    """

    segment_id: str
    time: np.ndarray
    force: np.ndarray
    t_step: float
    step_force: float
    record_knot_times: np.ndarray
    record_knot_displacements: np.ndarray
    damper: DamperConstants
    flow: FlowCoefficients
    rtol: float = PROBLEM_RTOL
    atol: float = PROBLEM_ATOL
    max_steps: int | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("time", "force", "record_knot_times", "record_knot_displacements"):
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float64).copy()
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "_flow4", self.flow.as_array())
        if self.time.size == 0 or self.time.shape != self.force.shape:
            raise SettingsError(f"{self.segment_id}: time and force must be non-empty and of equal length")
        if not (self.record_knot_times[0] <= self.t_step <= self.time[0]):
            raise SettingsError(f"{self.segment_id}: the record knots must start at or before the step, "
                                "and the samples at or after it")

    @classmethod
    def from_transient(cls, transient, record_knot_times: np.ndarray, record_knot_displacements: np.ndarray,
                       damper: DamperConstants, flow: FlowCoefficients, **kw) -> AugmentedProblem:
        """Build from a :class:`bayesdamper.io.segments.Transient` and its record's knots
        (``SegmentedRecord.knot_times``, ``.knot_displacements``)."""
        return cls(transient.id, transient.time, transient.force, float(transient.t_step),
                   float(transient.dp0) * damper.piston_area, record_knot_times, record_knot_displacements,
                   damper, flow, **kw)

    @classmethod
    def from_segmented(cls, record, transient, damper: DamperConstants, flow: FlowCoefficients,
                       **kw) -> AugmentedProblem:
        """Build from a :class:`bayesdamper.io.segments.SegmentedRecord` and one of its transients."""
        return cls.from_transient(transient, record.knot_times, record.knot_displacements, damper, flow, **kw)

    def knots(self, gap: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Piston knots behind a play ``gap`` [m] covering the window, and the velocity before the step.

        Returns ``(knot_t [s], knot_y [m], v_prev [m/s])``; the last gap's result is cached.
        """
        hit = self._cache.get("knots")
        if hit is not None and hit[0] == gap:
            return hit[1]
        kt, ky = backlash_knots(self.record_knot_times, self.record_knot_displacements, gap)
        kt, ky = _held_knots(kt, ky, self.t_step, float(self.time[-1]))
        result = (kt, ky, _velocity_before(kt, ky, self.t_step))
        self._cache["knots"] = (gap, result)
        return result

    def initial_dp(self, eff: np.ndarray, v_prev: float) -> float:
        """Δp at the step [Pa]: ``(F_step - F_f(v_prev)) / A_P`` (the step force includes friction)."""
        f = self.step_force
        if eff[_COULOMB] > 0.0 or eff[_VISCOUS] > 0.0 or eff[_STRIBECK] > 0.0:  # plain Python: no dispatch
            f -= friction_force_scalar.py_func(v_prev, float(eff[_COULOMB]), float(eff[_VISCOUS]),
                                               float(eff[_STRIBECK]), float(eff[_STRIBECK_V]))
        return f / self.damper.piston_area

    def simulate_force(self, alpha_v: float, p_r: float,
                       eff: np.ndarray | ComposedEffects) -> tuple[np.ndarray, bool]:
        """Computed force F_C [N] at the sample times and whether the solve succeeded.

        Parameters
        ----------
        alpha_v, p_r : float
            α_V [-] and p_R [Pa] of eq. (6).
        eff : ndarray, shape (len(EFFECT_SLOTS),), or ComposedEffects
            Effect vector (:func:`pack_effects`) or any combination of effects (:func:`effect_argument`);
            with the latter Δp at the step is solved from the step force with every effect's force.
        """
        if isinstance(eff, ComposedEffects):
            return self._simulate_composed(float(alpha_v), float(p_r), eff)
        eff = np.asarray(eff, dtype=np.float64)
        gap = float(eff[_GAP]) if eff.shape == (len(EFFECT_SLOTS),) else math.nan
        if not 0.0 <= gap < math.inf:  # the kernel checks the other slots
            return np.full(self.time.shape, np.nan), False
        kt, ky, v_prev = self.knots(gap)
        d = self.damper
        force, status = solve_augmented(self.time, kt, ky, self.t_step, self.initial_dp(eff, v_prev), v_prev,
                                        d.piston_area, d.chamber_volume_1, d.chamber_volume_2,
                                        d.liquid_bulk_modulus, self._flow4, float(alpha_v), float(p_r), eff,
                                        self.rtol, self.atol)
        return force, status == STATUS_OK

    def _simulate_composed(self, alpha_v: float, p_r: float, comp: ComposedEffects) -> tuple[np.ndarray, bool]:
        key = ("composed_knots", comp.names, comp.values.tobytes())
        hit = self._cache.get("composed_knots")
        if hit is not None and hit[0] == key:
            kt, ky, v_prev = hit[1]
        else:
            kt, ky = comp.transform_knots(self.record_knot_times, self.record_knot_displacements)
            kt, ky = _held_knots(kt, ky, self.t_step, float(self.time[-1]))
            v_prev = _velocity_before(kt, ky, self.t_step)
            self._cache["composed_knots"] = (key, (kt, ky, v_prev))
        force, status = solve_composed(comp, self.time, kt, ky, self.t_step, self.step_force, v_prev, self.damper,
                                       self._flow4, alpha_v, p_r, self.rtol, self.atol, from_force=True,
                                       max_steps=self.max_steps)
        return force, status == STATUS_OK


# ----------------------------------------------------------------------------- two-state with effects
def simulate_two_state_augmented(
    t_out: np.ndarray,
    excitation: PiecewiseLinear,
    damper: DamperConstants,
    flow: FlowCoefficients,
    dynamic: DynamicParameters,
    effects: Mapping[str, Mapping[str, float] | None] | None,
    *,
    dp0: float = 0.0,
    t0: float | None = None,
    accumulator_conductance: float = 1e-8,
    rtol: float = 1e-8,
    atol: float = 1e-3,
) -> np.ndarray:
    """Measured force of the two-state model eq. (1) with effects, by scipy ``Radau`` (slow reference).

    States: absolute pressures p_1, p_2 [Pa] (eq. (3) bulk modulus per chamber with reference p_R,
    accumulator refill ``G max(p_R - p_i, 0)`` as in :func:`bayesdamper.physics.reference.simulate_two_state`),
    valve opening x [-], lag trail e = y_A - y_D [m] and corner-filtered velocity v_f [m/s] as ODE
    states; series compliance by eliminating d(p_1 - p_2)/dt from ``v_P = v_D - c A_P d(p_1 - p_2)/dt``;
    backlash on the knots; friction and inertia added to the force. Start: ``p_1 = p_R + max(dp0, 0)``,
    ``p_2 = p_R + max(-dp0, 0)``, x = x_ss(dp0), steady lag and filter.

    Parameters
    ----------
    t_out, excitation, damper, flow, dynamic, effects, dp0, t0
        As for :func:`simulate_augmented`.
    accumulator_conductance : float
        Check-valve conductance G [m^3 s^-1 Pa^-1]; 0 disables the accumulator.
    rtol, atol : float
        ``solve_ivp`` tolerances: relative [-], absolute for the pressures [Pa].

    Returns
    -------
    ndarray, shape (n_t,)
        Measured force F [N].
    """
    g_acc = float(accumulator_conductance)
    if not (np.isfinite(g_acc) and g_acc >= 0):
        raise SettingsError(f"accumulator conductance must be finite and >= 0, got {accumulator_conductance}")
    t_out = _times(t_out)
    t0 = _start(t_out, t0)
    eff = pack_effects(effects)
    kt, ky = _piston_knots(excitation, eff[_GAP], t0, float(t_out[-1]))
    v_prev = _velocity_before(kt, ky, t0)
    area, v01, v02 = damper.piston_area, damper.chamber_volume_1, damper.chamber_volume_2
    b0, alpha_v, p_r = damper.liquid_bulk_modulus, dynamic.liquid_gas_ratio, dynamic.reference_pressure
    cl12, cq12, cl21, cq21 = flow.as_array().tolist()
    comp, tau_a, tau_v, p_v, mass = (float(eff[i])
                                     for i in (_COMPLIANCE, _LAG_TAU, _VALVE_TAU, _VALVE_P, _MASS))
    vmode = 0 if p_v == 0.0 else (2 if tau_v > 0.0 else 1)
    fric = {p.name: float(eff[EFFECT_SLOTS.index(p.slot)]) for p in EFFECTS["friction"].params}

    def bulk(p):
        return b0 * (1.0 + alpha_v) * p * p / (alpha_v * p * p + b0 * p_r)

    def x_ss(dp):
        return max(1.0 - math.exp(-abs(dp) / p_v), MIN_OPENING)

    def parts(t, z, ta, ya, va):
        p1, p2, xv, e, vf = z
        vd, de = (e / tau_a, va - e / tau_a) if tau_a > 0 else (va, 0.0)
        dp = p1 - p2
        y = ya + va * (t - ta) - e - comp * area * dp
        a1, a2 = bulk(p1) / (v01 - area * y), bulk(p2) / (v02 + area * y)
        c_l, c_q = (cl12, cq12) if dp >= 0 else (cl21, cq21)
        q = 2.0 * dp / (c_l + math.sqrt(c_l * c_l + 4.0 * c_q * abs(dp))) if dp else 0.0
        dx = 0.0
        if vmode == 2:
            dx = (x_ss(dp) - xv) / tau_v
            q *= xv
        elif vmode == 1:
            q *= x_ss(dp)
        qa1, qa2 = g_acc * max(p_r - p1, 0.0), g_acc * max(p_r - p2, 0.0)
        u = ((a1 + a2) * (area * vd - q) + a1 * qa1 - a2 * qa2) / (1.0 + (a1 + a2) * comp * area * area)
        vp = vd - comp * area * u
        rates = [a1 * (area * vp - q + qa1), a2 * (-area * vp + q + qa2), dx, de, (va - vf) / CORNER_TIME_S]
        return rates, vp

    def force_at(t, z, ta, ya, va):
        vp = parts(t, z, ta, ya, va)[1]
        return (area * (z[0] - z[1]) + float(friction_force(vp, **fric))
                + mass * (va - z[4]) / CORNER_TIME_S)

    z = np.array([p_r + max(dp0, 0.0), p_r + max(-dp0, 0.0), x_ss(dp0) if vmode == 2 else 1.0,
                  v_prev * tau_a, v_prev])
    atols = np.array([atol, atol, 1e-9, 1e-12, 1e-12])
    out = np.full(t_out.size, np.nan)
    k0 = max(int(np.searchsorted(kt, t0, side="right")) - 1, 0)
    for k in range(k0, kt.size - 1):
        ta, tb = max(kt[k], t0), min(kt[k + 1], float(t_out[-1]))
        va = (ky[k + 1] - ky[k]) / (kt[k + 1] - kt[k])
        ya = ky[k] + va * (ta - kt[k])
        if k == k0:
            for i in np.flatnonzero(t_out <= ta):
                out[i] = force_at(ta, z, ta, ya, va)
        if ta >= tb:
            break
        sel = np.flatnonzero((t_out > ta) & (t_out <= tb))
        t_eval = np.append(t_out[sel], tb) if sel.size == 0 or t_out[sel[-1]] < tb else t_out[sel]
        sol = solve_ivp(lambda t, zz, ta, ya, va: parts(t, zz, ta, ya, va)[0], (ta, tb), z, method="Radau",
                        t_eval=t_eval, args=(ta, ya, va), rtol=rtol, atol=atols)
        if sol.status != 0:
            raise BayesDamperError(f"two-state augmented solve failed: {sol.message}")
        for j, i in enumerate(sel):
            out[i] = force_at(t_out[i], sol.y[:, j], ta, ya, va)
        z = sol.y[:, -1]
    if not np.all(np.isfinite(out)):
        raise BayesDamperError("two-state augmented solve failed: non-finite force")
    return out
