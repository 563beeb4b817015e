"""Physical parameter sets, in SI units.

One frozen dataclass per group of parameters that travels together. Field metadata carry the unit
and the paper's symbol, so tables and reports never guess them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from bayesdamper.core.errors import SettingsError

#: Atmospheric pressure p_0 [Pa].
ATMOSPHERIC_PRESSURE = 101_325.0


def _f(unit: str, symbol: str) -> dict:
    return field(metadata={"unit": unit, "symbol": symbol})


@dataclass(frozen=True)
class DamperConstants:
    """Constants of a symmetric liquid damper, known from its drawings.

    Attributes
    ----------
    piston_area : float
        Piston area A_P [m^2].
    chamber_volume_1, chamber_volume_2 : float
        Initial fluid volumes V_{0,1}, V_{0,2} of chambers CH1 and CH2 [m^3].
    liquid_bulk_modulus : float
        Bulk modulus of the gas-free liquid B_0 [Pa].
    name : str
        Free-text name of the damper or rig.
    """

    piston_area: float = _f("m^2", "A_P")
    chamber_volume_1: float = _f("m^3", "V_{0,1}")
    chamber_volume_2: float = _f("m^3", "V_{0,2}")
    liquid_bulk_modulus: float = _f("Pa", "B_0")
    name: str = field(default="", metadata={"unit": "", "symbol": ""})

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "name":
                continue
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise SettingsError(f"damper constant {f.name} must be a positive finite number, got {v!r}")


@dataclass(frozen=True)
class FlowCoefficients:
    """Series laminar-turbulent pressure-flow coefficients, eq. (4), one pair per direction.

    Attributes
    ----------
    laminar_12, quadratic_12 : float
        C_{L,12} [kg m^-4 s^-1] and C_{Q,12} [kg m^-7] for flow CH1 -> CH2 (Δp > 0).
    laminar_21, quadratic_21 : float
        C_{L,21} [kg m^-4 s^-1] and C_{Q,21} [kg m^-7] for flow CH2 -> CH1 (Δp < 0).
    """

    laminar_12: float = _f("kg m^-4 s^-1", "C_{L,12}")
    quadratic_12: float = _f("kg m^-7", "C_{Q,12}")
    laminar_21: float = _f("kg m^-4 s^-1", "C_{L,21}")
    quadratic_21: float = _f("kg m^-7", "C_{Q,21}")

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (np.isfinite(v) and v >= 0):
                raise SettingsError(f"flow coefficient {f.name} must be finite and >= 0, got {v!r}")
        if self.laminar_12 == 0 and self.quadratic_12 == 0 or self.laminar_21 == 0 and self.quadratic_21 == 0:
            raise SettingsError("flow coefficients: C_L and C_Q cannot both be zero in one direction")

    def as_array(self) -> np.ndarray:
        """Return ``[C_L12, C_Q12, C_L21, C_Q21]``, the order every kernel uses."""
        return np.array([self.laminar_12, self.quadratic_12, self.laminar_21, self.quadratic_21], dtype=float)


@dataclass(frozen=True)
class DynamicParameters:
    """The two parameters stage 2 identifies from transients, eq. (6).

    Attributes
    ----------
    liquid_gas_ratio : float
        Liquid-gas volume ratio α_V = V_L / V_G at the reference pressure [-].
    reference_pressure : float
        Reference (pressurisation) pressure p_R [Pa].
    """

    liquid_gas_ratio: float = _f("-", "α_V")
    reference_pressure: float = _f("Pa", "p_R")

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (np.isfinite(v) and v > 0):
                raise SettingsError(f"{f.name} must be a positive finite number, got {v!r}")


#: The paper's Figure 3 flow coefficients (its helicopter damper).
PAPER_FLOW = FlowCoefficients(2.4255e10, 4.3126e16, 0.8572e10, 5.0805e16)

#: rig-A's damper constants, also used by the simulator.
RIG_A_DAMPER = DamperConstants(4.2e-3, 1.5e-4, 1.5e-4, 1.5e9, "rig-A")
