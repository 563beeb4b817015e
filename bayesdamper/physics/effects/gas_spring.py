"""Gas spring: a force proportional to the piston position (accumulator or rod-volume gas).

The gas that takes up the rod volume is compressed as the rod goes in, so the measured force carries
a position-dependent part ``F += k_g y_P`` with the gas-spring stiffness k_g [N/m] (y_P from the
record's zero). On triangle tests it tilts every plateau with the displacement.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import FORCE_READS_MOTION, YP

__all__ = ["EFFECT", "force", "force_reads"]

EFFECT = Effect(
    name="gas_spring",
    description="a position-dependent force: the gas of the accumulator or rod volume acts as a spring",
    params=(
        EffectParam("stiffness_N_per_m", "N/m", 1.0e2, 1.0e8, 1.0e5, True, "gas-spring stiffness k_g"),
    ),
)


@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """k_g y_P [N]."""
    return p[0] * sig[YP]


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """The piston position."""
    return FORCE_READS_MOTION
