"""Mains interference: a sinusoid at the mains frequency picked up by the force channel.

``F += a_c cos(2π f_m t) + a_s sin(2π f_m t)`` with t the absolute record time, so the phase is one
across the transients of a record; amplitude sqrt(a_c² + a_s²) [N]. The frequency f_m is 50 Hz unless
given (60 Hz grids); on records sampled below 2 f_m it appears aliased, as on the rig.
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import FORCE_READS_STATE, T

__all__ = ["EFFECT", "force", "force_reads"]

EFFECT = Effect(
    name="mains_interference",
    description="periodic interference at the mains frequency on the force channel",
    params=(
        EffectParam("cos_amplitude_N", "N", -1000.0, 1000.0, 10.0, False, "cosine amplitude a_c"),
        EffectParam("sin_amplitude_N", "N", -1000.0, 1000.0, 0.0, False, "sine amplitude a_s"),
        EffectParam("frequency_Hz", "Hz", 40.0, 70.0, 50.0, False, "mains frequency f_m", optional=True),
    ),
)


@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """a_c cos(2π f_m t) + a_s sin(2π f_m t) [N]."""
    ph = 2.0 * math.pi * p[2] * sig[T]
    return p[0] * math.cos(ph) + p[1] * math.sin(ph)


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """t alone."""
    return FORCE_READS_STATE
