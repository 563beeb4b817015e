"""The single-state model eq. (7): its compiled RODAS4 kernel and the simulator built on it.

Single-state model, eq. (7) (eq. (5) with the bulk moduli of eq. (6))::

    d(Δp)/dt = (B_1/(V_{0,1} - A_P y_P) + B_2/(V_{0,2} + A_P y_P)) (A_P dy_P/dt - Q_O(Δp))

with Q_O from eq. (8) and y_P piecewise linear (dy_P/dt piecewise constant).

Time origin
-----------
The kernel :func:`solve_single_state` starts the transient at the FIRST KNOT ``knot_t[0]``
(the velocity step t_step) with Δp(t_step) = dp0, and returns Δp at the sample times ``t_out``,
which must lie in ``[knot_t[0], knot_t[-1]]`` and be non-decreasing. A caller with measured
samples windows the excitation at the step (``excitation.window(t_step, t_last)``) once and
passes those knots on every solve. :func:`simulate_single_state` does that for you.

Method
------
RODAS4 (Hairer & Wanner, Solving ODEs II, sec. IV.7; coefficients of rodas.f, METH=1): six
stages, order 4(3), L-stable and stiffly accurate, with the analytic dF/dΔp and dF/dt, the
order-3 dense output of rodas.f at the sample times, the Gustafsson step predictor, a fresh
initial step at every knot and no step crossing a knot. For a scalar ODE each linear solve is a
division. Stiffness (eigenvalues to ~ -2e3 s^-1 for large α_V, p_R) is confined to small |Δp|,
where the laminar term dominates eq. (8). A Dormand-Prince 5(4) twin measured in development was
as fast at equal cost but ~10x less accurate at equal rtol; RODAS4 is stable at any step size.
``benchmarks/forward.py`` gives the speed and accuracy against scipy.

Status codes and tolerances: :mod:`bayesdamper.physics.rodas`. The two-state model eq. (1) and the scipy
reference of eq. (7): :mod:`bayesdamper.physics.reference`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.core.frozen import readonly
from bayesdamper.core.params import DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.physics.compressibility import bulk_modulus_and_slope, bulk_modulus_scalar
from bayesdamper.physics.excitation import PiecewiseLinear, PiecewisePolynomial, as_drive
from bayesdamper.physics.orifice import orifice_flow, orifice_flow_and_slope
from bayesdamper.physics.rodas import (
    _GAMMA,
    DEFAULT_ATOL,
    DEFAULT_RTOL,
    MAX_STEPS,
    STATUS_BAD_INPUT,
    STATUS_MAX_STEPS,
    STATUS_MESSAGES,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_STEP_UNDERFLOW,
    STATUS_VOLUME,
    dense_coefficients,
    dense_value,
    predictive_step,
    stage_point,
    stage_rhs,
    stage_time,
    step_factor,
)

__all__ = ["simulate_single_state", "solve_single_state", "solve_single_state_batch"]


# ----------------------------------------------------------------------------- kernel internals
@njit(cache=True)
def drive(t, brk, coef, a, b, j):
    """Input at ``t`` on the pieces ``a .. b - 1``: (y [m], v [m/s], dv/dt [m/s^2], piece index).

    ``j`` is where the search for the piece holding ``t`` starts (the last one used); the pieces are
    :class:`~bayesdamper.physics.excitation.PiecewisePolynomial`'s local power basis.
    """
    while j < b - 1 and t >= brk[j + 1]:
        j += 1
    while j > a and t < brk[j]:
        j -= 1
    s = t - brk[j]
    k = coef.shape[1] - 1
    y = coef[j, k]
    v = 0.0
    acc = 0.0
    for i in range(k - 1, -1, -1):  # Horner with the first two derivatives
        acc = acc * s + 2.0 * v
        v = v * s + y
        y = y * s + coef[j, i]
    return y, v, acc, j


@njit(cache=True)
def next_restart(restart, k):
    """Index of the first restart break after break ``k``."""
    b = k + 1
    while not restart[b]:
        b += 1
    return b


@njit(cache=True)
def _rhs(dp, yp, vel, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base):
    """Right-hand side of eq. (7) at piston displacement ``yp`` [m] and velocity ``vel`` [m/s] [Pa s^-1]."""
    vol1 = v01 - area * yp
    vol2 = v02 + area * yp
    if not (vol1 > 0.0 and vol2 > 0.0):
        return math.nan
    b1 = b2 = b_base
    if bulk_mode == 0:  # eq. (6): the loaded chamber at p_R + |Δp|, the other at p_R
        loaded = bulk_modulus_scalar(p_r + abs(dp), b0, alpha_v, p_r)
        if dp >= 0.0:
            b1 = loaded
        else:
            b2 = loaded
    q = orifice_flow(dp, fl[0], fl[1], fl[2], fl[3])
    return (b1 / vol1 + b2 / vol2) * (area * vel - q)


@njit(cache=True)
def _rhs_jac(dp, yp, vel, acc, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base, atol):
    """Eq. (7) right-hand side F, dF/dΔp [s^-1] and dF/dt [Pa s^-2] at (y_P, v_P, a_P)."""
    vol1 = v01 - area * yp
    vol2 = v02 + area * yp
    if not (vol1 > 0.0 and vol2 > 0.0):
        return math.nan, math.nan, math.nan
    ds_ddp = 0.0
    b1 = b2 = b_base
    if bulk_mode == 0:
        loaded, slope = bulk_modulus_and_slope(p_r + abs(dp), b0, alpha_v, p_r)
        if dp >= 0.0:
            b1 = loaded
            ds_ddp = slope / vol1
        else:
            b2 = loaded
            ds_ddp = -slope / vol2
    q, dq = orifice_flow_and_slope(dp, fl[0], fl[1], fl[2], fl[3])
    if not math.isfinite(dq):  # purely quadratic orifice at Δp = 0: use the slope at |Δp| = atol
        dq = orifice_flow_and_slope(atol, fl[0], fl[1], fl[2], fl[3])[1]
    s = b1 / vol1 + b2 / vol2
    r = area * vel - q
    ds_dt = area * vel * (b1 / (vol1 * vol1) - b2 / (vol2 * vol2))
    return s * r, ds_ddp * r - s * dq, ds_dt * r + s * area * acc


@njit(cache=True)
def _pos(x):
    return math.isfinite(x) and x > 0.0


@njit(cache=True)
def _inputs_valid(t_out, brk, coef, restart, dp0, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode,
                  b_const, rtol, atol):
    n_b = brk.shape[0]
    if n_b < 2 or coef.shape[0] != n_b - 1 or coef.shape[1] < 2 or restart.shape[0] != n_b or fl.shape[0] != 4:
        return False
    if not (restart[0] and restart[n_b - 1]):
        return False
    for k in range(n_b):
        if not math.isfinite(brk[k]) or (k > 0 and not brk[k] > brk[k - 1]):
            return False
    for k in range(n_b - 1):
        for i in range(coef.shape[1]):
            if not math.isfinite(coef[k, i]):
                return False
    for i in range(t_out.shape[0]):
        if not math.isfinite(t_out[i]) or (i > 0 and t_out[i] < t_out[i - 1]):
            return False
    if t_out[0] < brk[0] or t_out[t_out.shape[0] - 1] > brk[n_b - 1]:
        return False
    if not (_pos(area) and _pos(v01) and _pos(v02) and _pos(rtol) and _pos(atol) and rtol < 1.0
            and math.isfinite(dp0) and fl[0] + fl[1] > 0.0 and fl[2] + fl[3] > 0.0):
        return False
    for j in range(4):
        if not (math.isfinite(fl[j]) and fl[j] >= 0.0):
            return False
    if bulk_mode == 0:
        return _pos(b0) and _pos(alpha_v) and _pos(p_r)
    return bulk_mode == 1 and _pos(b_const)


@njit(cache=True)
def _initial_step(t, x, f0, tb, brk, coef, a, b, j, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode,
                  b_base, rtol, atol):
    """Hairer-Wanner initial step heuristic (one extra F evaluation) [s]."""
    sc = atol + rtol * abs(x)
    d0, d1, span = abs(x) / sc, abs(f0) / sc, tb - t
    h0 = min(span, 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1)
    y, v, _, j = drive(t + h0, brk, coef, a, b, j)
    f1 = _rhs(x + h0 * f0, y, v, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base)
    d2 = abs(f1 - f0) / sc / h0
    dmax = max(d1, d2)
    if not math.isfinite(dmax):
        return h0
    h1 = max(1e-6, h0 * 1e-3) if dmax <= 1e-15 else (0.01 / dmax) ** 0.2
    return min(100.0 * h0, h1, span)


# ----------------------------------------------------------------------------- public kernel
@njit(cache=True)
def solve_eq7(t_out, brk, coef, restart, dp0, area, v01, v02, b0, flow4, alpha_v, p_r, bulk_mode, b_const,
              rtol, atol):
    """Solve eq. (7) at the sample times: the compiled hot path (RODAS4, see the module docstring).

    The solution starts at ``brk[0]`` with Δp = ``dp0``; the input is the displacement of
    :class:`~bayesdamper.physics.excitation.PiecewisePolynomial` (``brk``, ``coef``, ``restart``). Steps never
    cross a restart break (a velocity step), where the step control starts afresh; they cross the other breaks.

    Parameters
    ----------
    t_out : ndarray, shape (n_t,)
        Non-decreasing output times [s] within ``[brk[0], brk[-1]]``.
    brk : ndarray, shape (m + 1,)
        Strictly increasing break times [s].
    coef : ndarray, shape (m, K)
        Local power-basis coefficients of the piston displacement y_P [m s^-j].
    restart : ndarray of bool, shape (m + 1,)
        Breaks where the velocity may jump (the first and last are True).
    dp0 : float
        Δp at ``brk[0]`` [Pa].
    area, v01, v02 : float
        Piston area A_P [m^2]; chamber volumes V_{0,1}, V_{0,2} at y_P = 0 [m^3].
    b0, alpha_v, p_r : float
        Liquid bulk modulus B_0 [Pa], liquid-gas ratio α_V [-], reference pressure p_R [Pa] of
        eq. (6) (bulk_mode 0; ignored for bulk_mode 1).
    flow4 : ndarray, shape (4,)
        ``[C_L12, C_Q12, C_L21, C_Q21]`` ([kg m^-4 s^-1], [kg m^-7]) of eq. (8).
    bulk_mode : int
        0: eq. (6) pressure-difference bulk moduli; 1: constant ``b_const`` [Pa] in both chambers.
    b_const : float
        Constant bulk modulus [Pa] (bulk_mode 1; ignored otherwise).
    rtol, atol : float
        Relative [-] and absolute [Pa] tolerance of the local error.

    Returns
    -------
    dp : ndarray, shape (n_t,)
        Δp at ``t_out`` [Pa]; finite when status is 0, unspecified otherwise.
    status : int
        0 on success; see ``STATUS_MESSAGES``.
    n_rhs : int
        Number of evaluations of the right-hand side (each Jacobian evaluation counts one).
    """
    n_t = t_out.shape[0]
    out = np.full(n_t, np.nan)
    if n_t == 0:
        return out, STATUS_OK, 0
    if not _inputs_valid(t_out, brk, coef, restart, dp0, area, v01, v02, b0, flow4, alpha_v, p_r,
                         bulk_mode, b_const, rtol, atol):
        return out, STATUS_BAD_INPUT, 0
    fl = flow4
    m = brk.shape[0] - 1
    t_start = brk[0]
    t_end = t_out[n_t - 1]
    # Chamber volumes must stay positive: checked at the breaks (exact for linear pieces; the right-hand side
    # rejects a non-positive volume between breaks of higher-degree pieces)
    for k in range(m + 1):
        tk = min(brk[k], t_end)
        yk, _, _, _ = drive(tk, brk, coef, 0, m, max(k - 1, 0) if tk < brk[k] else min(k, m - 1))
        if v01 - area * yk <= 0.0 or v02 + area * yk <= 0.0:
            return out, STATUS_VOLUME, 0
        if brk[k] >= t_end:
            break
    b_base = b_const if bulk_mode == 1 else bulk_modulus_scalar(p_r, b0, alpha_v, p_r)

    i_out = 0
    while i_out < n_t and t_out[i_out] <= t_start:
        out[i_out] = dp0
        i_out += 1
    x = dp0
    n_rhs = 0
    n_steps = 0
    a = 0
    while a < m and i_out < n_t:
        b = next_restart(restart, a)
        tb = min(brk[b], t_end)
        t = brk[a]
        j = a
        yp, vel, acc, j = drive(t, brk, coef, a, b, j)
        f0 = _rhs(x, yp, vel, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base)
        h = _initial_step(t, x, f0, tb, brk, coef, a, b, j, area, v01, v02, b0, fl, alpha_v, p_r,
                          bulk_mode, b_base, rtol, atol)
        n_rhs += 2
        n_acc_seg = 0
        h_acc = 0.0
        err_acc = 1.0
        reject = False
        while t < tb:
            if n_steps >= MAX_STEPS:
                return out, STATUS_MAX_STEPS, n_rhs
            last = False
            if t + 1.0001 * h >= tb:
                h = tb - t
                last = True
            yp, vel, acc, j = drive(t, brk, coef, a, b, j)
            f0, jac, ft = _rhs_jac(x, yp, vel, acc, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base, atol)
            n_rhs += 1
            if not (math.isfinite(f0) and math.isfinite(jac) and math.isfinite(ft)):
                return out, STATUS_NONFINITE, n_rhs
            while True:  # attempts from (t, x)
                if h <= 1e-14 * max(1.0, abs(t)):
                    return out, STATUS_STEP_UNDERFLOW, n_rhs
                e = 1.0 / (h * _GAMMA) - jac
                if e == 0.0:
                    h *= 0.5
                    last = False
                    continue
                inv = 1.0 / e
                k1 = stage_rhs(1, f0, h, ft, 0.0, 0.0, 0.0, 0.0, 0.0) * inv
                yp, vel, _, j = drive(stage_time(2, t, h), brk, coef, a, b, j)
                f = _rhs(stage_point(2, x, k1, 0.0, 0.0, 0.0), yp, vel, area, v01, v02, b0, fl, alpha_v, p_r,
                         bulk_mode, b_base)
                k2 = stage_rhs(2, f, h, ft, k1, 0.0, 0.0, 0.0, 0.0) * inv
                yp, vel, _, j = drive(stage_time(3, t, h), brk, coef, a, b, j)
                f = _rhs(stage_point(3, x, k1, k2, 0.0, 0.0), yp, vel, area, v01, v02, b0, fl, alpha_v, p_r,
                         bulk_mode, b_base)
                k3 = stage_rhs(3, f, h, ft, k1, k2, 0.0, 0.0, 0.0) * inv
                yp, vel, _, j = drive(stage_time(4, t, h), brk, coef, a, b, j)
                f = _rhs(stage_point(4, x, k1, k2, k3, 0.0), yp, vel, area, v01, v02, b0, fl, alpha_v, p_r,
                         bulk_mode, b_base)
                k4 = stage_rhs(4, f, h, ft, k1, k2, k3, 0.0, 0.0) * inv
                xs = stage_point(5, x, k1, k2, k3, k4)
                yp, vel, _, j = drive(t + h, brk, coef, a, b, j)
                f = _rhs(xs, yp, vel, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base)
                k5 = stage_rhs(5, f, h, ft, k1, k2, k3, k4, 0.0) * inv
                xs += k5
                f = _rhs(xs, yp, vel, area, v01, v02, b0, fl, alpha_v, p_r, bulk_mode, b_base)
                k6 = stage_rhs(6, f, h, ft, k1, k2, k3, k4, k5) * inv
                x_new = xs + k6
                n_rhs += 5
                err = abs(k6) / (atol + rtol * max(abs(x), abs(x_new)))
                if not (math.isfinite(x_new) and math.isfinite(err)):
                    h *= 0.2
                    last = False
                    reject = True
                    continue
                fac = step_factor(err)
                h_new = h / fac
                if err > 1.0:
                    reject = True
                    last = False
                    h = h_new
                    continue
                # accepted step
                n_steps += 1
                n_acc_seg += 1
                if n_acc_seg > 1:
                    h_new = predictive_step(h, fac, err, h_acc, err_acc)
                h_acc = h
                err_acc = max(0.01, err)
                t_new = tb if last else t + h
                # dense output of rodas.f (order 3) on [t, t_new]
                cd3, cd4 = dense_coefficients(k1, k2, k3, k4, k5)
                while i_out < n_t and t_out[i_out] <= t_new:
                    out[i_out] = dense_value(x, x_new, cd3, cd4, (t_out[i_out] - t) / h)
                    i_out += 1
                x = x_new
                t = t_new
                if reject:
                    h_new = min(h_new, h)
                reject = False
                h = h_new
                break
        a = b
    for i in range(n_t):
        if not math.isfinite(out[i]):
            return out, STATUS_NONFINITE, n_rhs
    return out, STATUS_OK, n_rhs


@njit(cache=True)
def linear_pieces(knot_t, knot_y):
    """Degree-1 input arrays (breaks, coefficients, restart flags) through piecewise-linear knots."""
    n = knot_t.shape[0]
    coef = np.empty((max(n - 1, 0), 2))
    for k in range(n - 1):
        coef[k, 0] = knot_y[k]
        coef[k, 1] = (knot_y[k + 1] - knot_y[k]) / (knot_t[k + 1] - knot_t[k])
    restart = np.ones(n, dtype=np.bool_)
    return coef, restart


@njit(cache=True)
def solve_single_state(t_out, knot_t, knot_y, dp0, area, v01, v02, b0, flow4, alpha_v, p_r,
                       bulk_mode, b_const, rtol, atol):
    """:func:`solve_eq7` with a piecewise-linear input through knots (a triangular test's transient).

    The transient starts at ``knot_t[0]`` (the velocity step) with Δp = ``dp0``; every knot is a velocity
    step. Parameters and returns are those of :func:`solve_eq7` with ``knot_t`` [s], ``knot_y`` [m] (strictly
    increasing knot times and the piston displacement there) for the input.
    """
    if knot_t.shape[0] < 2 or knot_y.shape[0] != knot_t.shape[0]:
        return np.full(t_out.shape[0], np.nan), STATUS_BAD_INPUT, 0
    for k in range(knot_t.shape[0] - 1):
        if not knot_t[k + 1] > knot_t[k]:
            return np.full(t_out.shape[0], np.nan), STATUS_BAD_INPUT, 0
    coef, restart = linear_pieces(knot_t, knot_y)
    return solve_eq7(t_out, knot_t, coef, restart, dp0, area, v01, v02, b0, flow4, alpha_v, p_r, bulk_mode,
                     b_const, rtol, atol)


@njit(cache=True)
def solve_single_state_batch(t_out, knot_t, knot_y, dp0, area, v01, v02, b0, flow4, alpha_v, p_r,
                             bulk_mode, b_const, rtol, atol):
    """:func:`solve_single_state` for many (α_V, p_R) pairs on one excitation (a plain loop): ``alpha_v`` [-] and
    ``p_r`` [Pa] are arrays of shape (n,); returns Δp [Pa], shape (n, n_t), and the status per pair, shape (n,)."""
    n = alpha_v.shape[0]
    dp = np.empty((n, t_out.shape[0]))
    status = np.empty(n, dtype=np.int64)
    for i in range(n):
        row, st, _ = solve_single_state(t_out, knot_t, knot_y, dp0, area, v01, v02, b0, flow4,
                                        alpha_v[i], p_r[i], bulk_mode, b_const, rtol, atol)
        dp[i] = row
        status[i] = st
    return dp, status


# ----------------------------------------------------------------------------- Python wrappers
def _prepare(t_out, excitation: PiecewiseLinear | PiecewisePolynomial,
             t0: float | None) -> tuple[np.ndarray, PiecewisePolynomial]:
    t_out = np.ascontiguousarray(t_out, dtype=float)
    if t_out.ndim != 1 or t_out.size == 0 or not np.all(np.isfinite(t_out)):
        raise SettingsError("output times must be a non-empty 1-D array of finite numbers")
    if np.any(np.diff(t_out) < 0):
        raise SettingsError("output times must be non-decreasing")
    t0 = float(t_out[0]) if t0 is None else float(t0)
    if t_out[0] < t0:
        raise SettingsError(f"output times start at {t_out[0]!r} s, before the transient start t0={t0!r} s")
    t1 = float(t_out[-1]) if t_out[-1] > t0 else t0 + 1.0
    return readonly(t_out), as_drive(excitation).window(t0, t1)  # read-only, as a window's: one kernel signature


def simulate_single_state(
    t_out: np.ndarray,
    excitation: PiecewiseLinear | PiecewisePolynomial,
    damper: DamperConstants,
    flow: FlowCoefficients,
    dynamic: DynamicParameters | None,
    *,
    dp0: float = 0.0,
    t0: float | None = None,
    constant_bulk_modulus: float | None = None,
    rtol: float = DEFAULT_RTOL,
    atol: float = DEFAULT_ATOL,
) -> np.ndarray:
    """Pressure difference of the single-state model eq. (7) at the sample times.

    Parameters
    ----------
    t_out : ndarray, shape (n_t,)
        Non-decreasing sample times [s], all >= ``t0``.
    excitation : PiecewiseLinear or PiecewisePolynomial
        Piston displacement y_P(t) [m].
    damper : DamperConstants
        A_P [m^2], V_{0,1}, V_{0,2} [m^3], B_0 [Pa].
    flow : FlowCoefficients
        Eq. (4)/(8) coefficients per direction.
    dynamic : DynamicParameters or None
        α_V [-] and p_R [Pa] of eq. (6); may be None when ``constant_bulk_modulus`` is given.
    dp0 : float
        Δp at ``t0`` [Pa].
    t0 : float, optional
        Start of the transient [s] (the velocity step); default ``t_out[0]``.
    constant_bulk_modulus : float, optional
        If given, both chambers use this constant bulk modulus [Pa] instead of eq. (6) (baseline).
    rtol, atol : float
        Relative [-] and absolute [Pa] tolerance of the kernel.

    Returns
    -------
    ndarray, shape (n_t,)
        Δp = p_1 - p_2 at ``t_out`` [Pa]; damper force is A_P Δp.

    Raises
    ------
    BayesDamperError
        If the solve fails (message is one line naming the reason and the parameters).
    """
    t_out, window = _prepare(t_out, excitation, t0)
    if constant_bulk_modulus is None:
        if dynamic is None:
            raise SettingsError("single-state model needs DynamicParameters or a constant bulk modulus")
        mode, b_const, alpha_v, p_r = 0, 0.0, dynamic.liquid_gas_ratio, dynamic.reference_pressure
    else:
        mode, b_const, alpha_v, p_r = 1, float(constant_bulk_modulus), 1.0, 1.0
    dp, status, _ = solve_eq7(
        t_out, window.breaks, window.coefs, window.restart, float(dp0), damper.piston_area,
        damper.chamber_volume_1, damper.chamber_volume_2, damper.liquid_bulk_modulus, flow.as_array(),
        float(alpha_v), float(p_r), mode, b_const, float(rtol), float(atol),
    )
    if status != STATUS_OK:
        what = f"B={b_const!r} Pa" if mode == 1 else f"alpha_V={alpha_v!r}, p_R={p_r!r} Pa"
        raise BayesDamperError(f"single-state solve failed ({what}): {STATUS_MESSAGES[int(status)]}")
    return dp
