"""Accumulator: absolute chamber pressures, replenished through a line from a gas-charged accumulator.

The paper's stated limitation: eq. (6) guesses the absolute pressures (loaded chamber p_R + |Δp|, the
other p_R). This effect restores the absolute-pressure state of the two-state model eq. (1) as an
augmentation of eq. (7). With the mean chamber pressure p̄ as an extra state, p_1 = p̄ + Δp/2 and
p_2 = p̄ - Δp/2, each chamber has its own bulk modulus B(p_i) of eq. (3) (reference p_R, floor
:data:`~bayesdamper.physics.effects.signals.PRESSURE_FLOOR_PA`), and an accumulator at the charge
pressure p_a refills each chamber through a check valve of conductance G (flow only into a chamber
below the charge)::

    dp_1/dt = B(p_1)/V_1 (A_P v_P - Q + G max(p_a - p_1, 0))
    dp_2/dt = B(p_2)/V_2 (-A_P v_P + Q + G max(p_a - p_2, 0))

so dΔp/dt = dp_1/dt - dp_2/dt and dp̄/dt = (dp_1/dt + dp_2/dt)/2. A transient starts from the steady
state eq. (6) assumes, the unloaded chamber at the charge: p̄ = p_a + |Δp0|/2. After a step the newly
unloaded chamber falls below the charge until the valve refills it, and the loaded chamber starts from
its own level: starts from rest and reversals see different stiffness, which eq. (6) can only absorb in
different p_R.
"""

from __future__ import annotations

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import DP, DP1, DP2, P1, P2

__all__ = ["EFFECT", "STATES", "chamber_flows", "derivatives", "initial", "pressures", "state_atol"]

#: State: the mean absolute chamber pressure p̄ [Pa].
STATES = ("mean_pressure_Pa",)

EFFECT = Effect(
    name="accumulator",
    description="absolute chamber pressures with an accumulator: the unloaded chamber's pressure falls and is "
                "refilled through check valves, so each chamber has its own stiffness",
    params=(
        EffectParam("charge_pressure_Pa", "Pa", 1.0e4, 1.0e7, 5.0e5, True, "accumulator charge pressure p_a"),
        EffectParam("conductance_m3_per_s_Pa", "m^3/(s Pa)", 1.0e-15, 1.0e-8, 1.0e-12, True,
                    "conductance G of the refill check valve from the accumulator into each chamber"),
    ),
)


@njit(cache=True, error_model="numpy")
def pressures(sig, z, p):
    """Absolute chamber pressures (p̄ + Δp/2, p̄ - Δp/2) [Pa]."""
    return z[0] + 0.5 * sig[DP], z[0] - 0.5 * sig[DP]


@njit(cache=True, error_model="numpy")
def chamber_flows(sig, z, p):
    """Refill flows through the check valves into chambers 1 and 2 [m^3/s]."""
    return p[1] * max(p[0] - sig[P1], 0.0), p[1] * max(p[0] - sig[P2], 0.0)


@njit(cache=True, error_model="numpy")
def derivatives(sig, z, p, dz):
    """dp̄/dt = (dp_1/dt + dp_2/dt) / 2."""
    dz[0] = 0.5 * (sig[DP1] + sig[DP2])


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """p̄ = p_a + |Δp0|/2: the unloaded chamber at the charge (eq. (6)'s own assumption)."""
    z[0] = p[0] + 0.5 * abs(sig[DP])


@njit(cache=True, error_model="numpy")
def state_atol(p, atol, out):
    """Tolerance of p̄: that of Δp [Pa]."""
    out[0] = atol
