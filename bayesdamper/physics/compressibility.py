"""Bulk modulus of a liquid with entrained gas, eq. (2), (3) and the pressure-difference rule (6).

A fluid volume made of liquid V_L (bulk modulus B_0) and gas V_G (polytropic exponent κ,
``V_G ∝ p^(-1/κ)``) with liquid-gas ratio α_V = V_L / V_G at the reference pressure p_0 has the
effective bulk modulus ``B = -V dp/dV``::

    B(p) = B_0 [1 + (1/α_V)(p_0/p)^(1/κ)] / [1 + (1/α_V)(B_0/(κ p_0))(p_0/p)^((κ+1)/κ)]   (2)

The paper's simplified form (κ = 1, the total volume in the numerator held at its value at p_0)::

    B(p) = B_0 (1 + α_V) / (α_V + B_0 p_0 / p^2)                                          (3)

Exact relation between the two at κ = 1 (multiply (2) through by α_V)::

    B_(3)(p) / B_(2)(p) = (1 + α_V) / (α_V + p_0/p)

so they agree exactly at p = p_0 and differ by at most a factor ``1 + 1/α_V`` anywhere.

Eq. (6) applies (3) with p_0 -> p_R to the two chambers: the loaded chamber sits at p_R + |Δp|,
the other at p_R. The NumPy functions are the public API; the ``numba`` scalar twins are what the
forward-model kernel calls.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from bayesdamper.core.errors import SettingsError

__all__ = [
    "bulk_modulus",
    "bulk_modulus_and_slope",
    "bulk_modulus_general",
    "bulk_modulus_scalar",
    "chamber_bulk_moduli",
    "chamber_bulk_moduli_scalar",
]


def _check_positive(**values: float) -> None:
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise SettingsError(f"{name} must be a positive finite number, got {v!r}")


def _as_pressure(p: np.ndarray | float) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    if not np.all(np.isfinite(p) & (p > 0)):
        raise SettingsError("absolute pressure must be positive and finite for the bulk modulus")
    return p


def bulk_modulus_general(
    p: np.ndarray | float,
    liquid_bulk_modulus: float,
    liquid_gas_ratio: float,
    reference_pressure: float,
    kappa: float,
) -> np.ndarray:
    """General liquid-gas effective bulk modulus, eq. (2).

    Parameters
    ----------
    p : float or ndarray
        Absolute pressure [Pa], > 0.
    liquid_bulk_modulus : float
        Bulk modulus of the gas-free liquid B_0 [Pa].
    liquid_gas_ratio : float
        Liquid-gas volume ratio α_V = V_L / V_G at ``reference_pressure`` [-].
    reference_pressure : float
        Pressure p_0 at which α_V is defined [Pa].
    kappa : float
        Polytropic (isentropic) exponent of the gas κ [-]; 1 is isothermal.

    Returns
    -------
    ndarray, shape of ``p``
        Effective bulk modulus B(p) [Pa].
    """
    _check_positive(
        liquid_bulk_modulus=liquid_bulk_modulus,
        liquid_gas_ratio=liquid_gas_ratio,
        reference_pressure=reference_pressure,
        kappa=kappa,
    )
    p = _as_pressure(p)
    b0, a, p0 = liquid_bulk_modulus, liquid_gas_ratio, reference_pressure
    ratio = p0 / p
    num = 1.0 + ratio ** (1.0 / kappa) / a
    den = 1.0 + (b0 / (kappa * p0)) * ratio ** ((kappa + 1.0) / kappa) / a
    return b0 * num / den


def bulk_modulus(
    p: np.ndarray | float,
    liquid_bulk_modulus: float,
    liquid_gas_ratio: float,
    reference_pressure: float,
) -> np.ndarray:
    """Simplified liquid-gas effective bulk modulus (κ = 1), eq. (3).

    ``B(p) = B_0 (1 + α_V) / (α_V + B_0 p_0 / p^2)``.

    Parameters
    ----------
    p : float or ndarray
        Absolute pressure [Pa], > 0.
    liquid_bulk_modulus : float
        Bulk modulus of the gas-free liquid B_0 [Pa].
    liquid_gas_ratio : float
        Liquid-gas volume ratio α_V at ``reference_pressure`` [-].
    reference_pressure : float
        Pressure p_0 at which α_V is defined [Pa] (p_R when used through eq. (6)).

    Returns
    -------
    ndarray, shape of ``p``
        Effective bulk modulus B(p) [Pa].
    """
    _check_positive(
        liquid_bulk_modulus=liquid_bulk_modulus,
        liquid_gas_ratio=liquid_gas_ratio,
        reference_pressure=reference_pressure,
    )
    p = _as_pressure(p)
    b0, a = liquid_bulk_modulus, liquid_gas_ratio
    return b0 * (1.0 + a) / (a + b0 * reference_pressure / (p * p))


def chamber_bulk_moduli(
    dp: np.ndarray | float,
    liquid_bulk_modulus: float,
    liquid_gas_ratio: float,
    reference_pressure: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Chamber bulk moduli from the pressure difference alone, eq. (6).

    Δp >= 0: ``B_1 = B(p_R + Δp)``, ``B_2 = B(p_R)``; Δp < 0: ``B_1 = B(p_R)``,
    ``B_2 = B(p_R + |Δp|)``, with B from eq. (3) and p_0 -> p_R. Continuous at Δp = 0.

    Parameters
    ----------
    dp : float or ndarray
        Pressure difference Δp = p_1 - p_2 [Pa].
    liquid_bulk_modulus : float
        Bulk modulus of the gas-free liquid B_0 [Pa].
    liquid_gas_ratio : float
        Liquid-gas volume ratio α_V at p_R [-].
    reference_pressure : float
        Reference (pressurisation) pressure p_R [Pa].

    Returns
    -------
    b1, b2 : ndarray, shape of ``dp``
        Bulk moduli B_1 of CH1 and B_2 of CH2 [Pa].
    """
    dp = np.asarray(dp, dtype=float)
    if not np.all(np.isfinite(dp)):
        raise SettingsError("pressure difference must be finite for the chamber bulk moduli")
    args = (liquid_bulk_modulus, liquid_gas_ratio, reference_pressure)
    loaded = bulk_modulus(reference_pressure + np.abs(dp), *args)
    base = np.broadcast_to(bulk_modulus(reference_pressure, *args), dp.shape)
    positive = dp >= 0
    return np.where(positive, loaded, base), np.where(positive, base, loaded)


@njit(cache=True)
def bulk_modulus_scalar(p: float, b0: float, alpha_v: float, p_ref: float) -> float:
    """Scalar eq. (3): B(p) [Pa] at absolute pressure ``p`` [Pa]; B_0 ``b0`` [Pa], α_V [-], p_0 [Pa]."""
    return b0 * (1.0 + alpha_v) / (alpha_v + b0 * p_ref / (p * p))


@njit(cache=True)
def bulk_modulus_and_slope(p: float, b0: float, alpha_v: float, p_ref: float) -> tuple[float, float]:
    """Scalar eq. (3) and its slope: ``(B [Pa], dB/dp [-])`` at absolute pressure ``p`` [Pa].

    With ``g = B_0 p_0 / p^2``: ``dB/dp = B 2 g / (p (α_V + g))``.
    """
    g = b0 * p_ref / (p * p)
    den = alpha_v + g
    b = b0 * (1.0 + alpha_v) / den
    return b, b * 2.0 * g / (p * den)


@njit(cache=True)
def chamber_bulk_moduli_scalar(dp: float, b0: float, alpha_v: float, p_r: float) -> tuple[float, float]:
    """Scalar eq. (6): ``(B_1, B_2)`` [Pa] at pressure difference ``dp`` [Pa], reference p_R ``p_r`` [Pa]."""
    loaded = bulk_modulus_scalar(p_r + abs(dp), b0, alpha_v, p_r)
    base = bulk_modulus_scalar(p_r, b0, alpha_v, p_r)
    if dp >= 0.0:
        return loaded, base
    return base, loaded
