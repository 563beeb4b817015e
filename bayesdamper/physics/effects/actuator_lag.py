"""Actuator lag: the piston follows the measured displacement through a first-order lag.

The displacement transducer sits on the actuator; the piston position y_P follows the measured
actuator displacement y_A through a first-order lag of time constant τ_a::

    dy_P/dt = (y_A - y_P) / τ_a

On a steady ramp of speed v the piston trails by v τ_a and moves at v, so plateaus are unchanged;
after a velocity step the transient is delayed and rounded over ~τ_a. A transient window starts
from the steady-ramp state of the preceding segment (trail ``v_prev τ_a``; 0 from rest).

The trail is an ODE state of the composed kernel, integrated with Δp.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import VP, YP

__all__ = ["EFFECT", "STATES", "STATE_ATOL", "displacement", "initial"]

EFFECT = Effect(
    name="actuator_lag",
    description="the piston follows the measured actuator displacement through a first-order lag",
    params=(
        EffectParam("time_constant_s", "s", 1.0e-4, 0.5, 0.01, True,
                    "time constant τ_a of the first-order lag from measured to piston displacement"),
    ),
)


# ----------------------------------------------------------------------------- composed-kernel hooks
#: State of the composed kernel: the trail e = y_A - y_D [m], and its absolute tolerance.
STATES = ("trail_m",)
STATE_ATOL = (1.0e-12,)


@njit(cache=True, error_model="numpy")
def displacement(sig, z, p, dz):
    """(y_D, v_D) behind the lag; de/dt = v_A - e/τ_a (hook of :mod:`bayesdamper.physics.effects.signals`)."""
    tau = p[0]
    if tau <= 0.0:
        return sig[YP], sig[VP]
    dz[0] = sig[VP] - z[0] / tau
    return sig[YP] - z[0], z[0] / tau


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """Steady trail v_prev τ_a."""
    z[0] = sig[VP] * p[0]
