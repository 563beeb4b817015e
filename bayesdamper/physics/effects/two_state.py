"""The two-state model eq. (1): both chambers' absolute pressures, the liquid-gas law eq. (2), an accumulator.

Eq. (6) guesses the absolute pressures (the loaded chamber at p_R + |Δp|, the other at p_R) and eq. (3) holds the
gas isothermal. This effect replaces both by the physics eq. (7) was derived from. With the mean chamber pressure
p̄ as an extra state, p_1 = p̄ + Δp/2 and p_2 = p̄ - Δp/2; each chamber has its own bulk modulus of eq. (2) with
the gas following the polytropic law ``p V_G^κ = const`` written about the charge state (pressure p_R, liquid-gas
ratio α_V there)::

    B(p) = B_0 [1 + (1/α_V)(p_R/p)^(1/κ)] / [1 + (1/α_V)(B_0/(κ p_R))(p_R/p)^((κ+1)/κ)]

(the same law as eq. (2) about atmosphere: its ratio there is α_V,0 = α_V (p_0/p_R)^(1/κ), p_0 = 101325 Pa; at
κ = 1 and p = p_R it equals eq. (3)); an accumulator at the charge pressure p_R refills each chamber through a
check valve of conductance G (flow only into a chamber below the charge)::

    dp_1/dt = B(p_1)/V_1 (A_P v_P - Q + G max(p_R - p_1, 0))
    dp_2/dt = B(p_2)/V_2 (-A_P v_P + Q + G max(p_R - p_2, 0))

so dΔp/dt = dp_1/dt - dp_2/dt and dp̄/dt = (dp_1/dt + dp_2/dt)/2. A window starts from the steady state eq. (6)
assumes, the unloaded chamber at the charge: p̄ = p_R + |Δp0|/2. After a step the newly unloaded chamber falls
below the charge until the valve refills it and the loaded chamber rises from its own level: starts from rest and
reversals see different stiffness, which eq. (6) can only absorb in different p_R. α_V and p_R stay each window's
own parameters; κ and G are shared.
"""

from __future__ import annotations

import math

from numba import njit

from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.effects.signals import AV, BL, DP, DP1, DP2, P1, P2, PR, PRESSURE_FLOOR_PA

__all__ = ["ATMOSPHERE_PA", "EFFECT", "STATES", "atmospheric_ratio", "chamber_flows", "derivatives", "initial",
           "liquid_gas_modulus", "moduli", "pressures", "state_atol"]

#: State: the mean absolute chamber pressure p̄ [Pa].
STATES = ("mean_pressure_Pa",)
#: Standard atmosphere p_0 [Pa], the reference of the atmospheric form of the gas fraction.
ATMOSPHERE_PA = 101325.0

EFFECT = Effect(
    name="two_state",
    description="the two-state model eq. (1): both chambers' absolute pressures with a polytropic gas (eq. (2)) and "
                "an accumulator at p_R refilling each chamber through check valves; the paper's eq. (6) assumes "
                "these pressures instead",
    params=(
        EffectParam("polytropic_exponent", "-", 1.0, 1.4, 1.2, False,
                    "polytropic exponent κ of the entrained gas (1 isothermal, 1.4 adiabatic air)",
                    physical_limits=True),
        EffectParam("refill_conductance_m3_per_s_Pa", "m^3/(s Pa)", 1.0e-15, 1.0e-8, 1.0e-12, True,
                    "conductance G of the check valves from the accumulator into each chamber"),
    ),
)


@njit(cache=True, error_model="numpy")
def liquid_gas_modulus(p, b0, alpha_v, p_ref, kappa):
    """Eq. (2) at absolute pressure ``p`` [Pa]: B_0 [Pa], α_V [-] at ``p_ref`` [Pa], κ [-] (``p`` floored at
    :data:`~bayesdamper.physics.effects.signals.PRESSURE_FLOOR_PA`)."""
    r = p_ref / max(p, PRESSURE_FLOOR_PA)
    g = math.exp(math.log(r) / kappa)  # r^(1/κ), and r^((κ+1)/κ) = r g: one exp and one log where pow took two
    num = 1.0 + g / alpha_v
    den = 1.0 + (b0 / (kappa * p_ref)) * (r * g) / alpha_v
    return b0 * num / den


def atmospheric_ratio(alpha_v: float, p_r: float, kappa: float) -> float:
    """The liquid-gas ratio at atmosphere α_V,0 = α_V (p_0/p_R)^(1/κ) of the ratio α_V at the charge p_R [Pa]."""
    return float(alpha_v) * math.pow(ATMOSPHERE_PA / float(p_r), 1.0 / float(kappa))


@njit(cache=True, error_model="numpy")
def pressures(sig, z, p):
    """Absolute chamber pressures (p̄ + Δp/2, p̄ - Δp/2) [Pa]."""
    return z[0] + 0.5 * sig[DP], z[0] - 0.5 * sig[DP]


@njit(cache=True, error_model="numpy")
def moduli(sig, z, p):
    """Bulk moduli (B(p_1), B(p_2)) of eq. (2) about the charge state [Pa]."""
    return (liquid_gas_modulus(sig[P1], sig[BL], sig[AV], sig[PR], p[0]),
            liquid_gas_modulus(sig[P2], sig[BL], sig[AV], sig[PR], p[0]))


@njit(cache=True, error_model="numpy")
def chamber_flows(sig, z, p):
    """Refill flows through the check valves into chambers 1 and 2 [m^3/s]."""
    return p[1] * max(sig[PR] - sig[P1], 0.0), p[1] * max(sig[PR] - sig[P2], 0.0)


@njit(cache=True, error_model="numpy")
def derivatives(sig, z, p, dz):
    """dp̄/dt = (dp_1/dt + dp_2/dt) / 2."""
    dz[0] = 0.5 * (sig[DP1] + sig[DP2])


@njit(cache=True, error_model="numpy")
def initial(sig, p, z):
    """p̄ = p_R + |Δp0|/2: the unloaded chamber at the charge (eq. (6)'s own assumption)."""
    z[0] = sig[PR] + 0.5 * abs(sig[DP])


@njit(cache=True, error_model="numpy")
def state_atol(p, atol, out):
    """Tolerance of p̄: that of Δp [Pa]."""
    out[0] = atol
