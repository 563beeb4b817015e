"""Valve dynamics: the check valves of the flow path open with a delay.

The effective opening x in (0, 1] of the flow path scales the static orifice flow of eq. (8),
``Q = x Q_O(Δp)``, and relaxes to a pressure-dependent steady opening::

    dx/dt = (x_ss(Δp) - x) / τ_v,      x_ss(Δp) = max(1 - exp(-|Δp| / p_v), MIN_OPENING)

with valve time constant τ_v [s] and opening-pressure scale p_v [Pa]; the floor ``MIN_OPENING``
keeps a little flow at Δp = 0. At a velocity step from steady state x starts at x_ss(Δp0). The
system becomes two-state: after a step the pressure overshoots while the valve is still closing or
opening, and may ring (valve chatter, the measured pressure pulses). τ_v = 0 with p_v > 0 is the
quasi-static valve ``x = x_ss(Δp)``; p_v = 0 means a fully open path (eq. (7)).
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import DP, Q

__all__ = ["EFFECT", "MIN_OPENING", "STATES", "flow", "initial", "state_atol", "steady_opening"]

#: Floor of the steady opening x_ss [-], so that flow never stops.
MIN_OPENING = 1.0e-3

EFFECT = Effect(
    name="valve_dynamics",
    description="the check valves open and close with a delay, so the flow lags the pressure "
                "difference (overshoot, pressure pulses)",
    params=(
        EffectParam("time_constant_s", "s", 1.0e-4, 3.0, 0.1, True,
                    "time constant τ_v of the valve opening"),
        EffectParam("opening_pressure_Pa", "Pa", 1.0e3, 1.0e6, 5.0e4, True,
                    "pressure-difference scale p_v over which the valves open"),
    ),
)


@njit(cache=True)
def steady_opening(dp: float, p_v: float) -> tuple[float, float]:
    """Steady opening x_ss(Δp) [-] and its slope dx_ss/dΔp [Pa^-1] (module docstring).

    ``dp`` is Δp [Pa]; ``p_v`` > 0 the opening-pressure scale [Pa]. The slope is 0 on the floor.
    """
    e = math.exp(-abs(dp) / p_v)
    x = 1.0 - e
    if x < MIN_OPENING:
        return MIN_OPENING, 0.0
    return x, (e / p_v if dp >= 0.0 else -e / p_v)


# ----------------------------------------------------------------------------- composed-kernel hooks
#: State of the composed kernel: the opening x [-].
STATES = ("opening",)


@njit(cache=True, error_model="numpy")
def flow(sig, z, p, dz):
    """Q = x Q_O (τ_v > 0) or x_ss Q_O (τ_v = 0); dx/dt (hook of :mod:`bayesdamper.physics.effects.signals`)."""
    tau, p_v = p[0], p[1]
    if p_v <= 0.0:
        return sig[Q]
    xs = steady_opening(sig[DP], p_v)[0]
    if tau > 0.0:
        dz[0] = (xs - z[0]) / tau
        return sig[Q] * z[0]
    return sig[Q] * xs


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """x = x_ss(Δp0)."""
    z[0] = steady_opening(sig[DP], p[1])[0] if p[1] > 0.0 else 1.0


@njit(cache=True, error_model="numpy")
def state_atol(p, atol, out):
    """Tolerance of x: that of Δp over p_v."""
    out[0] = atol / p[1] if p[1] > 0.0 else 1.0
