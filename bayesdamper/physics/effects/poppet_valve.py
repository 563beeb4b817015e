"""Poppet valve: a mass-spring check valve with a cracking pressure on the flow path.

The valve lift x [-] (0 closed, 1 fully open) is a damped oscillator driven towards the steady opening
of the pressure difference::

    d²x/dt² + 2 ζ_v ω_v dx/dt + ω_v² x = ω_v² s(Δp),    s(Δp) = clip((|Δp| - p_c) / p_s, 0, 1)

with natural frequency f_v = ω_v / 2π [Hz], damping ratio ζ_v, cracking pressure p_c [Pa] and the span
p_s [Pa] over which the valve goes from closed to fully open. The path's flow is

    Q = Q_O(Δp) (ε + clip(x, 0, 1)) / (ε + s(Δp))

with ε the bleed: the flow that passes the closed valve, as a fraction of the flow the fully open valve adds.
On every steady plateau (x = s) it is exactly eq. (8), so the static coefficients keep their meaning; after a
step the lift lags and may ring (pressure pulses at the valve's frequency whose size grows with |Δp| beyond
p_c). A small ε makes the valve carry nearly all the flow, a large one makes it a small addition to a
bleed orifice.

At a fixed lift the flow falls as Δp opens s, so a plateau inside the span is statically stable only while
the orifice flow grows faster than the opening, d ln Q_O/dΔp > d ln(ε + s)/dΔp; for a quadratic orifice this
is ε p_s > |Δp| + p_c. Beyond it (and with little damping) the valve chatters in a limit cycle, as real check
valves with a high opening gain do, and the plateaus never settle. A plateau above the span (the valve fully
open, s = 1) is stable at any ε.
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import DP, Q

__all__ = ["EFFECT", "STATES", "flow", "initial", "state_atol", "steady_lift"]

#: States: lift x [-] and its rate [1/s].
STATES = ("lift", "lift_rate_per_s")

EFFECT = Effect(
    name="poppet_valve",
    description="a mass-spring check valve with a cracking pressure: the flow lags the pressure and the valve "
                "rings at its own frequency once |Δp| exceeds the cracking pressure",
    params=(
        EffectParam("natural_frequency_Hz", "Hz", 0.2, 200.0, 20.0, True, "natural frequency f_v of the poppet"),
        EffectParam("damping_ratio", "-", 0.02, 3.0, 0.5, True, "damping ratio ζ_v of the poppet"),
        EffectParam("cracking_pressure_Pa", "Pa", 1.0e3, 3.0e6, 2.0e5, True,
                    "pressure difference p_c at which the valve starts to open"),
        # searched with the others: at a fixed span the search would mostly try chattering valves (at the default
        # bleed a span of 1 MPa chatters for |Δp| + p_c > 0.1 MPa, i.e. on every rig-A plateau)
        EffectParam("span_Pa", "Pa", 1.0e5, 1.0e8, 3.0e7, True,
                    "pressure span p_s from cracking to fully open (off: inf, the valve never opens beyond the "
                    "bleed, so Q = Q_O); the defaults keep rig-A's plateaus stable (ε p_s = 3 MPa)",
                    off=math.inf, inf_ok=True),
        EffectParam("bleed_fraction", "-", 1.0e-2, 10.0, 0.1, True,
                    "bleed ε: the flow that passes the closed valve as a fraction of the flow the valve adds fully "
                    "open (with the span off any ε > 0 gives Q = Q_O)", off=1.0),
    ),
)


@njit(cache=True, error_model="numpy")
def steady_lift(dp: float, p_c: float, p_s: float) -> float:
    """Steady lift s(Δp) [-] (module docstring)."""
    return min(max((abs(dp) - p_c) / p_s, 0.0), 1.0)


@njit(cache=True, error_model="numpy")
def flow(sig, z, p, dz):
    """Flow through the valve and the lift's derivatives (hook of :mod:`bayesdamper.physics.effects.signals`)."""
    w = 2.0 * math.pi * p[0]
    s = steady_lift(sig[DP], p[2], p[3])
    dz[0] = z[1]
    dz[1] = w * w * (s - z[0]) - 2.0 * p[1] * w * z[1]
    x = min(max(z[0], 0.0), 1.0)
    return sig[Q] * (p[4] + x) / (p[4] + s)


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """Valve at rest at its steady lift."""
    z[0] = steady_lift(sig[DP], p[2], p[3])
    z[1] = 0.0


@njit(cache=True, error_model="numpy")
def state_atol(p, atol, out):
    """Tolerances of the lift [-] and its rate [1/s]."""
    out[0] = 1.0e-7
    out[1] = 1.0e-7 * max(2.0 * math.pi * p[0], 1.0)
