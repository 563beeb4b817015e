"""Seal friction of Stribeck and viscous form (no Coulomb level): breakaway excess plus a viscous part.

``F += tanh(v_P / v_s) F_S exp(-(v_P / v_St)²) + c_v v_P`` with the Stribeck excess F_S [N], Stribeck
velocity v_St [m/s], viscous coefficient c_v [N s/m] and the smoothing speed v_s of
:data:`bayesdamper.physics.effects.friction.SIGN_VELOCITY_M_S`. The Coulomb level is the ``friction``
effect; this one describes seals whose force grows with speed and peaks at breakaway.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.friction import friction_force_scalar
from bayesdamper.physics.effects.signals import FORCE_READS_MOTION, VP

__all__ = ["EFFECT", "force", "force_reads"]

EFFECT = Effect(
    name="seal_friction",
    description="seal friction with a Stribeck (breakaway) peak and a viscous part growing with speed",
    params=(
        EffectParam("stribeck_N", "N", 1.0, 3000.0, 100.0, True, "Stribeck excess F_S at zero speed"),
        EffectParam("stribeck_velocity_m_s", "m/s", 1.0e-6, 1.0e-2, 1.0e-4, True, "Stribeck velocity v_St"),
        EffectParam("viscous_Ns_per_m", "N s/m", 10.0, 1.0e6, 1.0e3, True, "viscous coefficient c_v"),
    ),
)


@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """Stribeck and viscous friction at the piston velocity [N]."""
    return friction_force_scalar(sig[VP], 0.0, p[2], p[0], p[1])


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """The piston velocity."""
    return FORCE_READS_MOTION
