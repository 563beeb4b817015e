"""Inertia: the moving mass adds m a_P to the measured force.

A piecewise-linear displacement has zero acceleration between knots and infinite at them. The rig
controller rounds the corners: the piston velocity v_f follows the measured velocity v_A with its
acceleration a_A, and a velocity step through a first-order filter of fixed time constant
``CORNER_TIME_S`` = 0.05 s (a filter state)::

    dv_f/dt = a_P = a_A + (v_A - v_f) / CORNER_TIME_S,    F = A_P Δp + m a_P

So after a velocity step of size Δv the force carries ``m Δv / CORNER_TIME_S exp(-t / CORNER_TIME_S)``
and nothing on steady ramps; on a smooth input (a sine) v_f = v_A and the force is m a_A. The simulator
uses the same convention, so the effect is identifiable.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import AA, FORCE_READS_MOTION, VA

__all__ = ["CORNER_TIME_S", "EFFECT", "STATES", "STATE_ATOL", "derivatives", "force", "force_reads", "initial"]

#: Time constant of the rig controller's corner rounding of the piston velocity [s].
CORNER_TIME_S = 0.05

EFFECT = Effect(
    name="inertia",
    description="the moving mass of piston, rod and fixtures adds m times the acceleration at the corners",
    params=(
        EffectParam("mass_kg", "kg", 1.0, 1.0e4, 1000.0, True,
                    "moving mass m between the force transducer and the piston"),
    ),
)


# ----------------------------------------------------------------------------- composed-kernel hooks
#: State of the composed kernel: the corner-filtered velocity v_f [m/s].
STATES = ("filtered_velocity_m_s",)
STATE_ATOL = (1.0e-12,)


@njit(cache=True, error_model="numpy")
def derivatives(sig, z, p, dz):
    """dv_f/dt = a_A + (v_A - v_f) / CORNER_TIME_S."""
    dz[0] = sig[AA] + (sig[VA] - z[0]) / CORNER_TIME_S


@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """m a_P [N]."""
    return p[0] * (sig[AA] + (sig[VA] - z[0]) / CORNER_TIME_S)


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """Steady filter: v_f = v_prev."""
    z[0] = sig[VA]


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """The input's velocity and acceleration."""
    return FORCE_READS_MOTION
