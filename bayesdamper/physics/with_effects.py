"""Eq. (7) with effects driven by any displacement history: the Python side of the composed kernel.

:func:`simulate_effects` drives the compiled kernel of :mod:`bayesdamper.physics.compose` (the right-hand side
of eq. (7) with every named effect's hooks) from a measured or synthetic displacement, piecewise linear (a
triangular test) or polynomial (a smoothed measured record). The two-state model eq. (1) is the composition
with the ``two_state`` effect (absolute chamber pressures refilled from an accumulator at p_R):
:func:`two_state_effects`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.core.params import DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.physics.compose import ComposedEffects, compose, solve_composed
from bayesdamper.physics.excitation import PiecewiseLinear, PiecewisePolynomial, as_drive
from bayesdamper.physics.rodas import DEFAULT_ATOL, DEFAULT_RTOL, STATUS_MESSAGES, STATUS_OK

__all__ = ["effect_argument", "simulate_effects", "two_state_effects"]


def _times(t_out) -> np.ndarray:
    t_out = np.ascontiguousarray(t_out, dtype=float)
    if t_out.ndim != 1 or t_out.size == 0 or not np.all(np.isfinite(t_out)):
        raise SettingsError("output times must be a non-empty 1-D array of finite numbers")
    if np.any(np.diff(t_out) < 0):
        raise SettingsError("output times must be non-decreasing")
    return t_out


def effect_argument(effects: Mapping[str, Mapping[str, float] | None] | None) -> ComposedEffects:
    """The composed kernel's argument for ``{effect: {param: value}}`` (defaults fill the rest)."""
    return compose(effects)


def two_state_effects(dynamic: DynamicParameters, effects: Mapping[str, Mapping[str, float] | None] | None,
                      accumulator_conductance: float, kappa: float = 1.0) -> dict:
    """Effects that make eq. (7) the two-state model eq. (1): ``two_state`` (accumulator at p_R, check-valve
    conductance G [m^3 s^-1 Pa^-1], polytropic exponent ``kappa``), plus ``effects``. ``dynamic`` is accepted for
    the call sites' symmetry with :func:`~bayesdamper.physics.reference.simulate_two_state` (p_R is the window's)."""
    g = float(accumulator_conductance)
    if not (math.isfinite(g) and g > 0):
        raise SettingsError(f"accumulator conductance must be finite and > 0, got {accumulator_conductance}")
    out = {k: dict(v or {}) for k, v in (effects or {}).items()}
    out["two_state"] = {"polytropic_exponent": float(kappa), "refill_conductance_m3_per_s_Pa": g}
    return out


def simulate_effects(
    t_out: np.ndarray,
    excitation: PiecewiseLinear | PiecewisePolynomial,
    damper: DamperConstants,
    flow: FlowCoefficients,
    dynamic: DynamicParameters,
    effects: Mapping[str, Mapping[str, float] | None] | ComposedEffects | None,
    *,
    dp0: float = 0.0,
    t0: float | None = None,
    from_force: bool = False,
    rtol: float = DEFAULT_RTOL,
    atol: float = DEFAULT_ATOL,
) -> np.ndarray:
    """Measured force of eq. (7) with effects at the sample times (:mod:`bayesdamper.physics.compose`).

    Parameters
    ----------
    t_out : ndarray, shape (n_t,)
        Non-decreasing sample times [s], all >= ``t0``.
    excitation : PiecewiseLinear or PiecewisePolynomial
        Measured (actuator) displacement of the whole record from its start [m]; input transforms (backlash)
        apply to all of it, so their state at ``t0`` follows from the history.
    damper, flow, dynamic
        A_P, V_{0,1}, V_{0,2}, B_0; eq. (8) coefficients; α_V and p_R of eq. (6).
    effects : dict, ComposedEffects or None
        ``{effect: {param: value}}`` (:mod:`bayesdamper.physics.effects`; defaults fill the rest).
    dp0 : float
        Δp at ``t0`` [Pa], or with ``from_force`` the measured force there [N] (Δp0 then solved so that the
        model's force in the steady state before t0 equals it).
    t0 : float, optional
        Start of the solution [s]; default ``t_out[0]``. Effect states start in the steady state of the
        velocity just before t0.
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
    t0 = float(t_out[0]) if t0 is None else float(t0)
    if not (np.isfinite(t0) and t_out[0] >= t0):
        raise SettingsError(f"output times start at {t_out[0]!r} s, before the start t0={t0!r} s")
    comp = effects if isinstance(effects, ComposedEffects) else compose(effects)
    drive = comp.transform_input(as_drive(excitation)).cover(t0, float(t_out[-1]))
    force, status = solve_composed(comp, t_out, drive, t0, float(dp0), drive.velocity_before(t0), damper,
                                   flow.as_array(), float(dynamic.liquid_gas_ratio),
                                   float(dynamic.reference_pressure), float(rtol), float(atol),
                                   from_force=from_force)
    if status != STATUS_OK:
        raise BayesDamperError(f"composed solve failed (alpha_V={dynamic.liquid_gas_ratio!r}, "
                               f"p_R={dynamic.reference_pressure!r} Pa, effects={comp.as_dict()}): "
                               f"{STATUS_MESSAGES[int(status)]}")
    return force
