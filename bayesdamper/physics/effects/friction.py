"""Seal friction: a force on the piston opposing its motion, added to the measured force.

The piston velocity v_P is imposed (displacement-driven test), so friction does not change Δp; it
adds to the measured force ``F = A_P Δp + F_f(v_P)`` with::

    F_f(v) = tanh(v / v_s) [F_C + F_S exp(-(v / v_St)^2)] + c_v v

Coulomb force F_C [N], Stribeck excess F_S [N] with Stribeck velocity v_St [m/s], viscous
coefficient c_v [N s/m]; the smoothed sign uses the fixed velocity scale ``SIGN_VELOCITY_M_S``.
Positive F_f has the sign of v (positive force compresses CH1, like Δp > 0).

At a velocity step the measured step force includes F_f(v_before), so the initial Δp of a transient
is ``(F_step - F_f(v_before)) / A_P`` (the composed kernel's start from the measured force does this).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import FORCE_READS_MOTION, VP

__all__ = ["EFFECT", "SIGN_VELOCITY_M_S", "force", "force_reads", "friction_force", "friction_force_scalar"]

#: Velocity scale v_s of the smoothed sign tanh(v / v_s) [m/s]: 1 % of the slowest test speed.
SIGN_VELOCITY_M_S = 1.0e-5

EFFECT = Effect(
    name="friction",
    description="seal friction: a force of constant magnitude opposing the piston motion (plus optional "
                "viscous and Stribeck parts)",
    params=(
        EffectParam("coulomb_N", "N", 1.0, 3000.0, 100.0, True,
                    "Coulomb friction force F_C of the piston and rod seals"),
        EffectParam("viscous_Ns_per_m", "N s/m", 10.0, 1.0e6, 0.0, True,
                    "viscous friction coefficient c_v (indistinguishable from C_L on plateaus)",
                    optional=True),
        EffectParam("stribeck_N", "N", 1.0, 3000.0, 0.0, True,
                    "Stribeck (breakaway) excess force F_S at zero speed", optional=True),
        EffectParam("stribeck_velocity_m_s", "m/s", 1.0e-6, 1.0e-2, 1.0e-4, True,
                    "Stribeck velocity v_St over which the breakaway excess decays", optional=True),
    ),
)


@njit(cache=True)
def friction_force_scalar(v: float, coulomb: float, viscous: float, stribeck: float,
                          stribeck_v: float) -> float:
    """Friction force F_f(v) [N] at piston velocity ``v`` [m/s] (module docstring; 0 if all are 0).

    ``coulomb`` F_C [N], ``viscous`` c_v [N s/m], ``stribeck`` F_S [N], ``stribeck_v`` v_St [m/s]
    (the Stribeck part is off when F_S or v_St is 0).
    """
    level = coulomb
    if stribeck > 0.0 and stribeck_v > 0.0:
        r = v / stribeck_v
        level += stribeck * math.exp(-r * r)
    return level * math.tanh(v / SIGN_VELOCITY_M_S) + viscous * v


def friction_force(v: np.ndarray | float, coulomb_N: float = 0.0, viscous_Ns_per_m: float = 0.0,
                   stribeck_N: float = 0.0, stribeck_velocity_m_s: float = 0.0) -> np.ndarray:
    """Vectorised friction force F_f(v) [N] at piston velocities ``v`` [m/s] (module docstring).

    Keyword names are the effect's parameter names, so ``friction_force(v, **params)`` works.
    """
    v = np.asarray(v, dtype=float)
    level = np.full(v.shape, float(coulomb_N))
    if stribeck_N > 0 and stribeck_velocity_m_s > 0:
        level = level + stribeck_N * np.exp(-(v / stribeck_velocity_m_s) ** 2)
    return level * np.tanh(v / SIGN_VELOCITY_M_S) + viscous_Ns_per_m * v


# ----------------------------------------------------------------------------- composed-kernel hooks
@njit(cache=True, error_model="numpy")
def force(sig, z, p):
    """Friction force [N] at the piston velocity (hook of :mod:`bayesdamper.physics.effects.signals`)."""
    return friction_force_scalar(sig[VP], p[0], p[1], p[2], p[3])


@njit(cache=True, error_model="numpy")
def force_reads(p):
    """The piston velocity."""
    return FORCE_READS_MOTION
