"""Series compliance: the damper is mounted through a spring of stiffness k_s.

The measured (actuator) displacement y_A drives the piston through a mount of stiffness k_s, which
deflects under the damper force: ``y_P = y_A - A_P Δp / k_s``. Substituted in eq. (7)::

    d(Δp)/dt = K (A_P dy_A/dt - Q_O(Δp)) / (1 + K A_P^2 / k_s),    K = B_1/V_1 + B_2/V_2

so the mount stiffness is in series with the hydraulic stiffness K A_P^2: the rise after a step is
slower, the steady state unchanged. The ``compliance`` hook gives the kernel 1/k_s, so k_s = inf is a rigid
mount (eq. (7)).
"""

from __future__ import annotations

import math

from bayesdamper.physics.effects.base import Effect, EffectParam

__all__ = ["EFFECT", "compliance"]

EFFECT = Effect(
    name="series_compliance",
    description="the damper is mounted through a finite stiffness in series, which slows the force rise",
    params=(
        EffectParam("stiffness_N_per_m", "N/m", 1.0e6, 1.0e10, 1.0e8, True,
                    "stiffness k_s of the mount and rod in series with the damper", off=math.inf, reciprocal=True),
    ),
)


# ----------------------------------------------------------------------------- composed-kernel hooks
def compliance(p) -> float:
    """Series compliance 1/k_s [m/N] (0 for an infinite stiffness)."""
    return 0.0 if math.isinf(p[0]) else 1.0 / float(p[0])
