"""Reference solutions that the compiled kernels are checked against: eq. (7) by scipy, and the two-state model eq. (1).

:func:`reference_single_state` integrates eq. (7) with scipy's Radau, piecewise between the input's velocity
steps (no step crosses a velocity discontinuity). :func:`simulate_two_state` integrates the two-state model
eq. (1) (both chamber pressures, optionally with an accumulator on the low-pressure side), the paper's
higher-fidelity reference from which the single-state model is derived.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.core.params import DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.physics.excitation import PiecewiseLinear, PiecewisePolynomial
from bayesdamper.physics.single_state import _prepare


def _solve_ivp_segments(rhs, x0, t_out, window: PiecewisePolynomial, what: str, **kw) -> np.ndarray:
    """``solve_ivp`` between the restart breaks of the input (velocity steps are breakpoints): states at ``t_out``.

    ``rhs(t, x, y, v)`` gets the piston displacement [m] and velocity [m s^-1] at t. Returns an array of shape
    (n_states, n_t).
    """
    x = np.atleast_1d(np.asarray(x0, dtype=float))
    out = np.full((x.size, t_out.size), np.nan)
    out[:, t_out <= window.start] = x[:, None]
    edges = window.breaks[window.restart]
    for k in range(edges.size - 1):
        ta, tb = float(edges[k]), min(float(edges[k + 1]), float(t_out[-1]))
        if ta >= t_out[-1]:
            break
        sel = (t_out > ta) & (t_out <= tb)
        t_eval = t_out[sel]
        n_sel = t_eval.size
        if n_sel == 0 or t_eval[-1] < tb:
            t_eval = np.append(t_eval, tb)
        pieces = np.flatnonzero((window.breaks[:-1] >= ta) & (window.breaks[1:] <= float(edges[k + 1])))

        def y_v(t, k_lo=int(pieces[0]), k_hi=int(pieces[-1])):  # the interval's pieces only: at a velocity
            k_ = int(np.clip(np.searchsorted(window.breaks, t, side="right") - 1, k_lo, k_hi))  # step, its own
            c = window.coefs[k_]
            s_ = t - window.breaks[k_]
            y = float(np.polyval(c[::-1], s_))
            v = float(np.polyval((c[1:] * np.arange(1, c.size))[::-1], s_))
            return y, v

        sol = solve_ivp(lambda t, xx: rhs(t, xx, *y_v(t)), (ta, tb), x, t_eval=t_eval, **kw)
        if sol.status != 0:
            raise BayesDamperError(f"{what} solve failed: {sol.message}")
        out[:, sel] = sol.y[:, :n_sel]
        x = sol.y[:, -1]
    return out


def _python_rhs(t, x, yp, vel, area, v01, v02, b0, fl, alpha_v, p_r, b_const):
    """Plain-Python eq. (7) right-hand side at displacement ``yp`` [m] and velocity ``vel`` [m/s], written
    independently of the kernel [Pa s^-1]."""
    dp = x[0]
    if b_const is None:
        p_hi = p_r + abs(dp)
        b_hi = b0 * (1.0 + alpha_v) / (alpha_v + b0 * p_r / (p_hi * p_hi))
        b_lo = b0 * (1.0 + alpha_v) / (alpha_v + b0 / p_r)
        b1, b2 = (b_hi, b_lo) if dp >= 0 else (b_lo, b_hi)
    else:
        b1 = b2 = b_const
    c_l, c_q = (fl[0], fl[1]) if dp >= 0 else (fl[2], fl[3])
    if c_q > 0:
        q = math.copysign((-c_l + math.sqrt(c_l * c_l + 4.0 * c_q * abs(dp))) / (2.0 * c_q), dp)
    else:
        q = dp / c_l
    return [(b1 / (v01 - area * yp) + b2 / (v02 + area * yp)) * (area * vel - q)]


def reference_single_state(
    t_out: np.ndarray,
    excitation: PiecewiseLinear | PiecewisePolynomial,
    damper: DamperConstants,
    flow: FlowCoefficients,
    dynamic: DynamicParameters | None,
    *,
    dp0: float = 0.0,
    t0: float | None = None,
    constant_bulk_modulus: float | None = None,
    method: str = "Radau",
    rtol: float = 1e-10,
    atol: float = 1e-6,
) -> np.ndarray:
    """Eq. (7) by ``scipy.integrate.solve_ivp``: the slow independent reference.

    Same arguments and time convention as :func:`simulate_single_state`; integrates knot segment by
    knot segment (knots are breakpoints), eq. (8) in the paper's textbook form. ``method``,
    ``rtol`` [-] and ``atol`` [Pa] go to ``solve_ivp``.

    Returns
    -------
    ndarray, shape (n_t,)
        Δp at ``t_out`` [Pa].
    """
    t_out, window = _prepare(t_out, excitation, t0)
    if constant_bulk_modulus is None and dynamic is None:
        raise SettingsError("single-state model needs DynamicParameters or a constant bulk modulus")
    d = damper
    alpha_v = dynamic.liquid_gas_ratio if dynamic is not None else 1.0
    p_r = dynamic.reference_pressure if dynamic is not None else 1.0
    consts = (d.piston_area, d.chamber_volume_1, d.chamber_volume_2, d.liquid_bulk_modulus,
              flow.as_array().tolist(), alpha_v, p_r, constant_bulk_modulus)

    def rhs(t, x, yp, vel):
        return _python_rhs(t, x, yp, vel, *consts)

    return _solve_ivp_segments(rhs, dp0, t_out, window, "reference single-state", method=method,
                               rtol=rtol, atol=atol)[0]


# ----------------------------------------------------------------------------- two-state reference
@dataclass(frozen=True)
class TwoStateSolution:
    """Solution of the two-state model eq. (1) at the sample times.

    Attributes
    ----------
    dp : ndarray, shape (n_t,)
        Pressure difference Δp = p_1 - p_2 [Pa].
    p1, p2 : ndarray, shape (n_t,)
        Absolute pressures of CH1 and CH2 [Pa].
    """

    dp: np.ndarray
    p1: np.ndarray
    p2: np.ndarray


def simulate_two_state(
    t_out: np.ndarray,
    excitation: PiecewiseLinear | PiecewisePolynomial,
    damper: DamperConstants,
    flow: FlowCoefficients,
    dynamic: DynamicParameters,
    *,
    dp0: float = 0.0,
    t0: float | None = None,
    accumulator_conductance: float = 1e-8,
    kappa: float = 1.0,
    rtol: float = 1e-8,
    atol: float = 1e-3,
) -> TwoStateSolution:
    """Two-state reference model eq. (1) with an optional accumulator, by scipy ``Radau``.

    ``dp_i/dt = (B(p_i)/V_i) (±(A_P dy_P/dt - Q_O) + Q_A,i)`` with B from eq. (2) written about the charge
    state (ratio α_V at p_R, polytropic exponent κ:
    ``B_0 [1 + (p_R/p)^(1/κ)/α_V] / [1 + (B_0/(κ p_R)) (p_R/p)^((κ+1)/κ)/α_V]``, p floored at 1e4 Pa),
    Q_O from eq. (8) and the accumulator refill ``Q_A,i = G max(p_R - p_i, 0)`` through a check
    valve of conductance G. The pressures start at ``p_1 = p_R + max(dp0, 0)``,
    ``p_2 = p_R + max(-dp0, 0)`` (loaded chamber above p_R, the other at p_R, as eq. (6) assumes).

    Parameters
    ----------
    t_out, excitation, damper, flow, dp0, t0
        As for :func:`simulate_single_state`.
    dynamic : DynamicParameters
        α_V [-] and p_R [Pa]; p_R is also the accumulator pressure.
    accumulator_conductance : float
        Check-valve conductance G [m^3 s^-1 Pa^-1]; 0 disables the accumulator (pure eq. (1)).
    kappa : float
        Polytropic exponent κ of the gas [-], 1 to 1.4.
    rtol, atol : float
        Relative [-] and absolute [Pa] tolerance of ``solve_ivp``.

    Returns
    -------
    TwoStateSolution
    """
    if not (np.isfinite(accumulator_conductance) and accumulator_conductance >= 0):
        raise SettingsError(f"accumulator conductance must be finite and >= 0, got {accumulator_conductance}")
    t_out, window = _prepare(t_out, excitation, t0)
    area, v01, v02 = damper.piston_area, damper.chamber_volume_1, damper.chamber_volume_2
    b0, alpha_v, p_r = damper.liquid_bulk_modulus, dynamic.liquid_gas_ratio, dynamic.reference_pressure
    if not (np.isfinite(kappa) and 1.0 <= kappa <= 1.4):
        raise SettingsError(f"polytropic exponent must be in [1, 1.4], got {kappa}")
    g = float(accumulator_conductance)
    fl = flow.as_array().tolist()

    def bulk(p):
        r = p_r / max(p, 1.0e4)
        return b0 * (1.0 + r ** (1.0 / kappa) / alpha_v) / (1.0 + b0 / (kappa * p_r) * r ** ((kappa + 1.0) / kappa)
                                                             / alpha_v)

    def rhs(t, x, yp, vel):
        p1, p2 = x
        dp = p1 - p2
        c_l, c_q = (fl[0], fl[1]) if dp >= 0 else (fl[2], fl[3])
        q = 2.0 * dp / (c_l + math.sqrt(c_l * c_l + 4.0 * c_q * abs(dp))) if dp else 0.0
        net = area * vel - q
        return [bulk(p1) / (v01 - area * yp) * (net + g * max(p_r - p1, 0.0)),
                bulk(p2) / (v02 + area * yp) * (-net + g * max(p_r - p2, 0.0))]

    y_knots = window.displacement(window.breaks)  # ends at t_out[-1]
    if np.any(v01 - area * y_knots <= 0) or np.any(v02 + area * y_knots <= 0):
        raise BayesDamperError("two-state solve failed: a chamber volume is <= 0 on the excitation")
    x0 = [p_r + max(dp0, 0.0), p_r + max(-dp0, 0.0)]
    out = _solve_ivp_segments(rhs, x0, t_out, window, "two-state", method="Radau", rtol=rtol, atol=atol)
    return TwoStateSolution(dp=out[0] - out[1], p1=out[0], p2=out[1])
