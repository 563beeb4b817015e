"""Pressure-flow characteristic of the damper's flow path, eq. (4) and its inverse eq. (8).

The flow path between the chambers has a series laminar-turbulent loss with one coefficient
pair per direction (check valves make the two directions differ)::

    Δp = C_L Q + C_Q Q |Q|                                           (4)

with the pair (C_{L,12}, C_{Q,12}) for flow CH1 -> CH2 (Q > 0, Δp > 0) and (C_{L,21}, C_{Q,21})
for flow CH2 -> CH1 (Q < 0, Δp < 0). Eq. (8) is its inverse. The paper writes it as
``(-C_L + sqrt(C_L^2 + 4 C_Q |Δp|)) / (2 C_Q)``, which cancels catastrophically when
``4 C_Q |Δp| << C_L^2`` and divides by zero for a linear orifice (C_Q = 0). Multiplying through by
the conjugate gives the equivalent form used everywhere here::

    Q = sign(Δp) 2|Δp| / (C_L + sqrt(C_L^2 + 4 C_Q |Δp|))           (8)

which is exact for C_Q = 0 (Q = Δp / C_L) and for C_L = 0 (Q = sign(Δp) sqrt(|Δp| / C_Q)).
Its slope is ``dQ/dΔp = 1 / sqrt(C_L^2 + 4 C_Q |Δp|) = 1 / (C_L + 2 C_Q |Q|)``.

The vectorised NumPy functions are the public API; the ``numba`` scalar twins are what the
forward-model kernel calls, with the coefficients in the order of
:meth:`bayesdamper.core.params.FlowCoefficients.as_array`: ``[C_L12, C_Q12, C_L21, C_Q21]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bayesdamper.core.params import FlowCoefficients

__all__ = ["flow_rate", "orifice_flow", "orifice_flow_and_slope", "pressure_drop"]


def _direction_pairs(x: np.ndarray, flow: FlowCoefficients) -> tuple[np.ndarray, np.ndarray]:
    """Per-element (C_L, C_Q): the 12 pair where ``x >= 0``, the 21 pair where ``x < 0``."""
    positive = x >= 0
    c_l = np.where(positive, flow.laminar_12, flow.laminar_21)
    c_q = np.where(positive, flow.quadratic_12, flow.quadratic_21)
    return c_l, c_q


def pressure_drop(q: np.ndarray | float, flow: FlowCoefficients) -> np.ndarray:
    """Static pressure drop across the flow path for a given flow, eq. (4).

    Parameters
    ----------
    q : float or ndarray
        Flow rate Q_O from CH1 to CH2 [m^3 s^-1]; positive uses the 12 pair, negative the 21 pair.
    flow : FlowCoefficients
        Laminar C_L [kg m^-4 s^-1] and quadratic C_Q [kg m^-7] coefficients per direction.

    Returns
    -------
    ndarray, shape of ``q``
        Signed pressure difference Δp = p_1 - p_2 [Pa], same sign as ``q``.
    """
    q = np.asarray(q, dtype=float)
    c_l, c_q = _direction_pairs(q, flow)
    return c_l * q + c_q * q * np.abs(q)


def flow_rate(dp: np.ndarray | float, flow: FlowCoefficients) -> np.ndarray:
    """Flow through the path for a given pressure difference, eq. (8) (inverse of eq. (4)).

    Uses the cancellation-free form ``Q = sign(Δp) 2|Δp| / (C_L + sqrt(C_L^2 + 4 C_Q |Δp|))``,
    exact for a linear (C_Q = 0) or purely quadratic (C_L = 0) orifice.

    Parameters
    ----------
    dp : float or ndarray
        Pressure difference Δp = p_1 - p_2 [Pa]; positive uses the 12 pair, negative the 21 pair.
    flow : FlowCoefficients
        Laminar C_L [kg m^-4 s^-1] and quadratic C_Q [kg m^-7] coefficients per direction.

    Returns
    -------
    ndarray, shape of ``dp``
        Flow rate Q_O from CH1 to CH2 [m^3 s^-1], same sign as ``dp``.
    """
    dp = np.asarray(dp, dtype=float)
    c_l, c_q = _direction_pairs(dp, flow)
    mag = np.abs(dp)
    denom = c_l + np.sqrt(c_l * c_l + 4.0 * c_q * mag)
    # denom == 0 only when C_L = 0 and Δp = 0, where Q = 0.
    safe = np.where(denom > 0, denom, 1.0)
    return np.where(denom > 0, np.sign(dp) * 2.0 * mag / safe, 0.0)


@njit(cache=True)
def orifice_flow(dp: float, cl12: float, cq12: float, cl21: float, cq21: float) -> float:
    """Scalar eq. (8) for the kernel: flow Q_O [m^3 s^-1] at pressure difference ``dp`` [Pa].

    ``cl12, cq12`` (used for Δp >= 0) and ``cl21, cq21`` (Δp < 0) are C_L [kg m^-4 s^-1] and
    C_Q [kg m^-7]. Cancellation-free form, exact for C_Q = 0.
    """
    if dp >= 0.0:
        c_l = cl12
        c_q = cq12
    else:
        c_l = cl21
        c_q = cq21
    mag = abs(dp)
    if mag == 0.0:
        return 0.0
    q = 2.0 * mag / (c_l + math.sqrt(c_l * c_l + 4.0 * c_q * mag))
    return q if dp > 0.0 else -q


@njit(cache=True)
def orifice_flow_and_slope(
    dp: float, cl12: float, cq12: float, cl21: float, cq21: float
) -> tuple[float, float]:
    """Scalar eq. (8) and its slope, for the kernel's Jacobian.

    Returns ``(Q, dQ/dΔp)``: flow [m^3 s^-1] and its derivative with respect to Δp
    [m^3 s^-1 Pa^-1], ``dQ/dΔp = 1 / sqrt(C_L^2 + 4 C_Q |Δp|)``. At Δp = 0 the 12 pair is used;
    for C_{L,12} = 0 the slope there is infinite (returned as ``inf``).
    """
    if dp >= 0.0:
        c_l = cl12
        c_q = cq12
    else:
        c_l = cl21
        c_q = cq21
    mag = abs(dp)
    root = math.sqrt(c_l * c_l + 4.0 * c_q * mag)
    slope = 1.0 / root if root > 0.0 else math.inf
    if mag == 0.0:
        return 0.0, slope
    q = 2.0 * mag / (c_l + root)
    if dp < 0.0:
        q = -q
    return q, slope
