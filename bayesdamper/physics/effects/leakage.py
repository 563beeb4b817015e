"""Leakage past the piston: a laminar flow G_l Δp in parallel with the orifice path.

``Q = Q_O(Δp) + G_l Δp``. On plateaus it adds to the laminar coefficients of eq. (8) (stage 1 absorbs
part of it); in transients it bleeds the pressure build-up at small |Δp| where the orifice is stiff.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import DP, Q

__all__ = ["EFFECT", "flow"]

EFFECT = Effect(
    name="leakage",
    description="leakage past the piston seal: a laminar flow in parallel with the orifice",
    params=(
        EffectParam("conductance_m3_per_s_Pa", "m^3/(s Pa)", 1.0e-15, 1.0e-9, 1.0e-12, True,
                    "leakage conductance G_l"),
    ),
)


@njit(cache=True, error_model="numpy")
def flow(sig, z, p, dz):
    """Q_O + G_l Δp [m^3/s]."""
    return sig[Q] + p[0] * sig[DP]
