"""Command displacement: the displacement channel records the servo command, not the piston.

The piston follows the recorded command y_A through the servo loop, a second-order system of
bandwidth f_s [Hz] and damping ratio ζ_s::

    d²y_D/dt² + 2 ζ_s ω_s dy_D/dt + ω_s² y_D = ω_s² y_A,    ω_s = 2π f_s

On a steady ramp of speed v the piston trails by 2 ζ_s v / ω_s at the same speed (plateaus unchanged);
after a velocity step it overshoots and rings at the servo's frequency when ζ_s < 1.
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import VP, YP

__all__ = ["EFFECT", "STATES", "STATE_ATOL", "displacement", "initial"]

#: States: piston displacement y_D [m] and velocity [m/s]; their absolute tolerances.
STATES = ("piston_m", "piston_velocity_m_s")
STATE_ATOL = (1.0e-12, 1.0e-10)

EFFECT = Effect(
    name="command_displacement",
    description="the displacement channel records the servo command; the piston follows it through the servo "
                "loop (second order)",
    params=(
        EffectParam("bandwidth_Hz", "Hz", 0.5, 500.0, 20.0, True, "servo bandwidth f_s (off: inf)", off=math.inf,
                    inf_ok=True),
        EffectParam("damping_ratio", "-", 0.1, 3.0, 0.7, True, "servo damping ratio ζ_s"),
    ),
)


@njit(cache=True, error_model="numpy")
def displacement(sig, z, p, dz):
    """(y_D, v_D) of the servo and their derivatives (the command itself for an infinite bandwidth)."""
    if p[0] == math.inf:
        return sig[YP], sig[VP]
    w = 2.0 * math.pi * p[0]
    dz[0] = z[1]
    dz[1] = w * w * (sig[YP] - z[0]) - 2.0 * p[1] * w * z[1]
    return z[0], z[1]


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """Steady tracking of the velocity before the start: trail 2 ζ_s v / ω_s."""
    w = 2.0 * math.pi * p[0]
    z[0] = sig[YP] - 2.0 * p[1] * sig[VP] / w
    z[1] = sig[VP]
