"""Load-cell offset: the force transducer reads a constant F_0 [N] at zero load (zeroing error, drift)."""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import FORCE_READS_STATE

__all__ = ["EFFECT", "force", "force_reads"]

EFFECT = Effect(
    name="load_cell_offset",
    description="a constant offset of the force transducer (zeroing error)",
    params=(EffectParam("offset_N", "N", -5000.0, 5000.0, 50.0, False, "force read at zero load F_0"),),
)


@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """F_0 [N]."""
    return p[0]


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """A constant: no signal."""
    return FORCE_READS_STATE
