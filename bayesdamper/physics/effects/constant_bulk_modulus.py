"""The constant-bulk-modulus baseline: both chambers at one modulus, B(p_R) of eq. (3).

The paper's point of comparison for eq. (6): the fluid's compressibility does not depend on the pressure. Both
chambers get ``B = B_0 (1 + α_V) / (α_V + B_0 / p_R)``, eq. (3) at the reference pressure, so a window's (α_V, p_R)
act only through this one number. It is a variant of the base model, kept for the model comparison of the diagnosis
(:mod:`bayesdamper.diagnosis.comparison`), not a rig effect the loop offers.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.compressibility import bulk_modulus_scalar
from bayesdamper.physics.effects.base import Effect
from bayesdamper.physics.effects.signals import AV, BL, PR

__all__ = ["EFFECT", "moduli"]

EFFECT = Effect(
    name="constant_bulk_modulus",
    description="both chambers at the constant bulk modulus B(p_R) of eq. (3): no pressure dependence",
    params=(),
    candidate=False,
)


@njit(cache=True, error_model="numpy")
def moduli(sig, z, p):
    """(B, B) with B = eq. (3) at p = p_R [Pa]."""
    b = bulk_modulus_scalar(sig[PR], sig[BL], sig[AV], sig[PR])
    return b, b
