"""The compiled kernel of eq. (7) with candidate effects, driven by a smooth (spline) displacement.

A whole measured record (sine, multisine, random: :mod:`bayesdamper.inference.whole`) is a smooth
displacement sampled densely. Used sample by sample as the knots of a piecewise-linear input
(:func:`bayesdamper.physics.augmented.solve_augmented`), its velocity is a staircase: the integrator must
restart at every sample (a velocity step is a discontinuity of the right-hand side), and the staircase
itself is a first-order approximation of the velocity (at 100 Hz and a compressibility time constant of a
few ms, errors of 1 % of the force near reversals). Here the displacement is the quintic interpolating
spline through the samples instead (velocity C³, its error O(Δt⁵)), and RODAS4 steps across the samples
with its own step-size control, evaluating the force at the sample times by its dense output.

Model: that of :mod:`bayesdamper.physics.augmented` (same states, same effect vector), with the drive

    y_A(t) = spline, v_A = y_A', a_A = y_A''
    actuator lag τ_a:  e = y_A - y_D,  de/dt = v_A - e/τ_a  (closed form on every spline piece: v_A is a
                       quartic there, so e = e_p + (e_k - e_p(t_k)) exp(-(t - t_k)/τ_a) with the
                       polynomial particular solution τ_a e_p' + e_p = τ_a v_A)
    inertia:           m a_P with a_P = dv_D/dt, the acceleration of the smooth history itself (the corner
                       filter of :mod:`bayesdamper.physics.effects.inertia` only exists to round the
                       corners of a piecewise-linear input, which a spline does not have)

The backlash slot is ignored (as by the piecewise-linear kernel). Status codes are those of
:data:`bayesdamper.physics.rodas.STATUS_MESSAGES`. The kernel releases the GIL, so the walkers of one
emcee step can be evaluated on several threads.

numba caching: after changing this module or the njit functions it calls, delete
``bayesdamper/physics/__pycache__/spline_input*.nb[ic]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bayesdamper.physics.compressibility import bulk_modulus_and_slope, bulk_modulus_scalar
from bayesdamper.physics.effect_vector import EFFECT_SLOTS
from bayesdamper.physics.effects.friction import friction_force_scalar
from bayesdamper.physics.effects.valve_dynamics import steady_opening
from bayesdamper.physics.orifice import orifice_flow, orifice_flow_and_slope
from bayesdamper.physics.rodas import (
    _GAMMA,
    STATUS_BAD_INPUT,
    STATUS_MAX_STEPS,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_STEP_UNDERFLOW,
    STATUS_VOLUME,
    dense_coefficients,
    dense_slope,
    dense_value,
    predictive_step,
    stage_point,
    stage_rhs,
    stage_time,
    step_factor,
)

__all__ = ["MAX_STEPS", "spline_coefficients", "solve_spline"]

(_COULOMB, _VISCOUS, _STRIBECK, _STRIBECK_V, _GAP, _LAG_TAU, _VALVE_TAU, _VALVE_P, _COMPLIANCE,
 _MASS) = range(len(EFFECT_SLOTS))

#: Maximum number of accepted steps of one :func:`solve_spline` call.
MAX_STEPS = 200_000
#: Degree of the interpolating spline: quintic, so the velocity is C³ and the right-hand side C³ in t. The
#: jumps at the breakpoints then enter a step's local error at O(h⁵), the order of RODAS4's own error,
#: and steps cross breakpoints freely (with a cubic spline the jerk jumps at every sample, which limits the
#: steps to a fraction of a sample interval at tight tolerances).
SPLINE_DEGREE = 5


def spline_coefficients(time: np.ndarray, displacement: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Breakpoints [s] and per-piece coefficients of the quintic interpolating spline through the samples.

    Returns ``(sp_t, sp_c)``: ``sp_t`` shape (m,), strictly increasing, from ``time[0]`` to ``time[-1]``;
    ``sp_c`` shape (m - 1, 6) with y(t) = sum_i c_i s^i, s = t - sp_t[k] on piece k (C-contiguous float64).
    """
    from scipy.interpolate import PPoly, make_interp_spline

    t = np.asarray(time, dtype=float)
    pp = PPoly.from_spline(make_interp_spline(t, np.asarray(displacement, dtype=float), k=SPLINE_DEGREE))
    keep = np.diff(pp.x) > 0.0  # the B-spline's repeated end knots are empty pieces
    sp_t = np.r_[pp.x[:-1][keep], pp.x[1:][keep][-1]]
    return np.ascontiguousarray(sp_t), np.ascontiguousarray(pp.c[::-1, keep].T)


# ----------------------------------------------------------------------------- drive
@njit(cache=True, nogil=True)
def _piece(t, sp_t, j):
    """Index of the spline piece holding ``t``, searching forward from ``j`` (clamped to the last piece)."""
    n = sp_t.shape[0] - 2
    while j < n and t >= sp_t[j + 1]:
        j += 1
    return j


@njit(cache=True, nogil=True)
def _lag_poly(sp_c, j, tau):
    """Coefficients (p0..p4) of the polynomial particular solution e_p of de/dt = v_A - e/τ on piece ``j``:
    τ e_p' + e_p = τ v_A, solved from the top degree down."""
    p4 = tau * 5.0 * sp_c[j, 5]
    p3 = tau * (4.0 * sp_c[j, 4] - 4.0 * p4)
    p2 = tau * (3.0 * sp_c[j, 3] - 3.0 * p3)
    p1 = tau * (2.0 * sp_c[j, 2] - 2.0 * p2)
    p0 = tau * (sp_c[j, 1] - p1)
    return p0, p1, p2, p3, p4


@njit(cache=True, nogil=True)
def _drive(t, j, sp_t, sp_c, lag_e, lag_tau):
    """(y_D [m], v_D [m/s], dv_D/dt [m/s²]) at ``t`` on piece ``j`` (module docstring)."""
    s = t - sp_t[j]
    c1, c2, c3, c4, c5 = sp_c[j, 1], sp_c[j, 2], sp_c[j, 3], sp_c[j, 4], sp_c[j, 5]
    ya = sp_c[j, 0] + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))
    va = c1 + s * (2.0 * c2 + s * (3.0 * c3 + s * (4.0 * c4 + s * 5.0 * c5)))
    if lag_tau > 0.0:
        p0, p1, p2, p3, p4 = _lag_poly(sp_c, j, lag_tau)
        e = p0 + s * (p1 + s * (p2 + s * (p3 + s * p4))) + (lag_e[j] - p0) * math.exp(-s / lag_tau)
        vd = e / lag_tau
        return ya - e, vd, (va - vd) / lag_tau
    return ya, va, 2.0 * c2 + s * (6.0 * c3 + s * (12.0 * c4 + s * 20.0 * c5))


@njit(cache=True, nogil=True)
def _lag_states(sp_t, sp_c, lag_tau, j0):
    """e = y_A - y_D at the start of every piece from ``j0``, in its steady polynomial trail on piece ``j0``
    (so e(t0) = e_p(t0) for any ``t0`` on that piece)."""
    n = sp_c.shape[0]
    e = np.zeros(n)
    if lag_tau <= 0.0:
        return e
    e[j0] = _lag_poly(sp_c, j0, lag_tau)[0]
    for k in range(j0, n - 1):
        h = sp_t[k + 1] - sp_t[k]
        p0, p1, p2, p3, p4 = _lag_poly(sp_c, k, lag_tau)
        e[k + 1] = p0 + h * (p1 + h * (p2 + h * (p3 + h * p4))) + (e[k] - p0) * math.exp(-h / lag_tau)
    return e


# ----------------------------------------------------------------------------- right-hand side
@njit(cache=True, nogil=True)
def _rhs(t, dp, xv, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp,
         vmode, vtau, vp):
    """(d(Δp)/dt [Pa/s], dx/dt [1/s]) at ``t`` (piece searched forward from ``j``)."""
    yd, vd, _ = _drive(t, _piece(t, sp_t, j), sp_t, sp_c, lag_e, lag_tau)
    y = yd - comp * area * dp
    vol1 = v01 - area * y
    vol2 = v02 + area * y
    if vol1 <= 0.0 or vol2 <= 0.0:
        return math.nan, math.nan
    loaded = bulk_modulus_scalar(p_r + abs(dp), b0, alpha_v, p_r)
    b1 = b2 = b_base
    if dp >= 0.0:
        b1 = loaded
    else:
        b2 = loaded
    k = b1 / vol1 + b2 / vol2
    q = orifice_flow(dp, fl[0], fl[1], fl[2], fl[3])
    fx = 0.0
    if vmode == 2:
        xs, _ = steady_opening(dp, vp)
        q *= xv
        fx = (xs - xv) / vtau
    elif vmode == 1:
        q *= steady_opening(dp, vp)[0]
    return k * (area * vd - q) / (1.0 + k * area * area * comp), fx


@njit(cache=True, nogil=True)
def _rhs_jac(t, dp, xv, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp,
             vmode, vtau, vp, atol):
    """Right-hand side (f0, f1), Jacobian (j00, j01, j10, j11) and ∂f0/∂t at ``t`` on piece ``j``."""
    yd, vd, dvd = _drive(t, j, sp_t, sp_c, lag_e, lag_tau)
    a2c = area * area * comp
    y = yd - comp * area * dp
    vol1 = v01 - area * y
    vol2 = v02 + area * y
    if vol1 <= 0.0 or vol2 <= 0.0:
        return math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan
    loaded, slope = bulk_modulus_and_slope(p_r + abs(dp), b0, alpha_v, p_r)
    b1 = b2 = b_base
    db1 = db2 = 0.0
    if dp >= 0.0:
        b1 = loaded
        db1 = slope
    else:
        b2 = loaded
        db2 = -slope
    i1 = 1.0 / vol1
    i2 = 1.0 / vol2
    k = b1 * i1 + b2 * i2
    dk = db1 * i1 + db2 * i2 - b1 * a2c * i1 * i1 + b2 * a2c * i2 * i2
    dkt = area * vd * (b1 * i1 * i1 - b2 * i2 * i2)
    qo, dqo = orifice_flow_and_slope(dp, fl[0], fl[1], fl[2], fl[3])
    if not math.isfinite(dqo):  # purely quadratic orifice at Δp = 0: the slope at |Δp| = atol
        dqo = orifice_flow_and_slope(atol, fl[0], fl[1], fl[2], fl[3])[1]
    f1 = j10 = j11 = dq_dx = 0.0
    q = qo
    dq = dqo
    if vmode == 2:
        xs, dxs = steady_opening(dp, vp)
        q = xv * qo
        dq = xv * dqo
        dq_dx = qo
        f1 = (xs - xv) / vtau
        j10 = dxs / vtau
        j11 = -1.0 / vtau
    elif vmode == 1:
        xs, dxs = steady_opening(dp, vp)
        q = xs * qo
        dq = dxs * qo + xs * dqo
    n = area * vd - q
    inv_d = 1.0 / (1.0 + k * a2c)
    f0 = k * n * inv_d
    j00 = dk * n * inv_d * inv_d - k * dq * inv_d
    j01 = -k * dq_dx * inv_d
    ft0 = dkt * n * inv_d * inv_d + k * area * dvd * inv_d
    return f0, f1, j00, j01, j10, j11, ft0


@njit(cache=True, nogil=True)
def _force_out(dp, ddp, t, j, sp_t, sp_c, lag_e, lag_tau, area, comp, eff):
    """Measured force [N]: A_P Δp + friction at v_P + m a_P."""
    f = area * dp
    fric = eff[_COULOMB] > 0.0 or eff[_VISCOUS] > 0.0 or eff[_STRIBECK] > 0.0
    if fric or eff[_MASS] > 0.0:
        _, vd, dvd = _drive(t, _piece(t, sp_t, j), sp_t, sp_c, lag_e, lag_tau)
        if fric:
            f += friction_force_scalar(vd - comp * area * ddp, eff[_COULOMB], eff[_VISCOUS], eff[_STRIBECK],
                                       eff[_STRIBECK_V])
        f += eff[_MASS] * dvd
    return f


@njit(cache=True, nogil=True)
def _norm2(e0, e1, n_act):
    return math.sqrt((e0 * e0 + e1 * e1) / n_act)


@njit(cache=True, nogil=True)
def _valid(t_out, sp_t, sp_c, t0, dp0, area, v01, v02, b0, fl, alpha_v, p_r, eff, rtol, atol):
    n = sp_t.shape[0]
    if (n < 2 or sp_c.shape[0] != n - 1 or sp_c.shape[1] != SPLINE_DEGREE + 1 or fl.shape[0] != 4
            or eff.shape[0] != len(EFFECT_SLOTS)):
        return False
    for k in range(n):
        if not math.isfinite(sp_t[k]) or (k > 0 and not sp_t[k] > sp_t[k - 1]):
            return False
    for k in range(n - 1):
        for m in range(SPLINE_DEGREE + 1):
            if not math.isfinite(sp_c[k, m]):
                return False
    n_t = t_out.shape[0]
    for i in range(n_t):
        if not math.isfinite(t_out[i]) or (i > 0 and t_out[i] < t_out[i - 1]):
            return False
    if not (math.isfinite(t0) and sp_t[0] <= t0 <= t_out[0] and t_out[n_t - 1] <= sp_t[n - 1]):
        return False
    for j in range(eff.shape[0]):
        if not (math.isfinite(eff[j]) and eff[j] >= 0.0):
            return False
    for j in range(4):
        if not (math.isfinite(fl[j]) and fl[j] >= 0.0):
            return False
    pos = area > 0.0 and v01 > 0.0 and v02 > 0.0 and b0 > 0.0 and alpha_v > 0.0 and p_r > 0.0
    return (pos and math.isfinite(area + v01 + v02 + b0 + alpha_v + p_r) and math.isfinite(dp0)
            and 0.0 < rtol < 1.0 and 0.0 < atol < math.inf and fl[0] + fl[1] > 0.0 and fl[2] + fl[3] > 0.0)


# ----------------------------------------------------------------------------- public kernel
@njit(cache=True, nogil=True)
def solve_spline(t_out, sp_t, sp_c, t0, dp0, area, v01, v02, b0, flow4, alpha_v, p_r, eff, rtol, atol):
    """Force of eq. (7) with effects, driven by a spline displacement, at the sample times.

    The solution starts at ``t0`` with Δp = ``dp0``, the valve opening at x_ss(dp0) and the actuator lag in
    its steady trail of the spline there.

    Parameters
    ----------
    t_out : ndarray, shape (n_t,)
        Non-decreasing output times [s] within ``[t0, sp_t[-1]]``.
    sp_t, sp_c : ndarray, shapes (n,), (n - 1, SPLINE_DEGREE + 1)
        The displacement spline (:func:`spline_coefficients`) [s], [m, m/s, m/s², m/s³].
    t0, dp0 : float
        Start time [s] and Δp there [Pa].
    area, v01, v02, b0, flow4, alpha_v, p_r, eff, rtol, atol
        As :func:`bayesdamper.physics.augmented.solve_augmented`.

    Returns
    -------
    force : ndarray, shape (n_t,)
        Measured force F [N] at ``t_out``; finite when status is 0.
    status : int
        0 on success, else a code of :data:`bayesdamper.physics.rodas.STATUS_MESSAGES`.
    n_steps : int
        Accepted steps.
    """
    n_t = t_out.shape[0]
    out = np.full(n_t, np.nan)
    if n_t == 0:
        return out, STATUS_OK, 0
    if not _valid(t_out, sp_t, sp_c, t0, dp0, area, v01, v02, b0, flow4, alpha_v, p_r, eff, rtol, atol):
        return out, STATUS_BAD_INPUT, 0
    fl = flow4
    t_end = t_out[n_t - 1]
    comp = eff[_COMPLIANCE]
    lag_tau = eff[_LAG_TAU]
    vtau = eff[_VALVE_TAU]
    vp = eff[_VALVE_P]
    vmode = 0 if vp == 0.0 else (2 if vtau > 0.0 else 1)
    n_act = 2.0 if vmode == 2 else 1.0
    atol_x = atol / vp if vmode == 2 else 1.0
    n_sp = sp_t.shape[0]
    for k in range(n_sp - 1):  # chamber volumes at the samples
        if t0 - (sp_t[k + 1] - sp_t[k]) <= sp_t[k] <= t_end:
            y = sp_c[k, 0]
            if v01 - area * y <= 0.0 or v02 + area * y <= 0.0:
                return out, STATUS_VOLUME, 0
    b_base = bulk_modulus_scalar(p_r, b0, alpha_v, p_r)
    j = _piece(t0, sp_t, 0)
    lag_e = _lag_states(sp_t, sp_c, lag_tau, j)
    x = dp0
    xv = steady_opening(dp0, vp)[0] if vmode == 2 else 1.0
    t = t0
    i_out = 0
    if t_out[0] <= t0:
        f0, _ = _rhs(t, x, xv, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp,
                     vmode, vtau, vp)
        while i_out < n_t and t_out[i_out] <= t0:
            out[i_out] = _force_out(x, f0, t0, j, sp_t, sp_c, lag_e, lag_tau, area, comp, eff)
            i_out += 1
    # Hairer-Wanner initial step (RMS norms over the integrated states)
    f0, f1 = _rhs(t, x, xv, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp,
                  vmode, vtau, vp)
    sc0 = atol + rtol * abs(x)
    sc1 = atol_x + rtol * abs(xv)
    d0 = _norm2(x / sc0, (xv / sc1) if vmode == 2 else 0.0, n_act)
    d1 = _norm2(f0 / sc0, f1 / sc1, n_act)
    h0 = max(1e-9, min(t_end - t, 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1))
    g0, g1 = _rhs(t + h0, x + h0 * f0, xv + h0 * f1, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl,
                  alpha_v, p_r, b_base, comp, vmode, vtau, vp)
    dmax = max(d1, _norm2((g0 - f0) / sc0, (g1 - f1) / sc1, n_act) / h0)
    if not math.isfinite(dmax):
        h = h0
    else:
        h = min(100.0 * h0, max(1e-6, h0 * 1e-3) if dmax <= 1e-15 else (0.01 / dmax) ** 0.2)
    n_steps = 0
    n_acc = 0
    h_acc = 0.0
    err_acc = 1.0
    reject = False
    while i_out < n_t:
        if n_steps >= MAX_STEPS:
            return out, STATUS_MAX_STEPS, n_steps
        last = False
        if t + 1.0001 * h >= t_end:
            h = t_end - t
            last = True
        j = _piece(t, sp_t, j)
        f0, f1, j00, j01, j10, j11, ft = _rhs_jac(t, x, xv, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl,
                                                  alpha_v, p_r, b_base, comp, vmode, vtau, vp, atol)
        if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(j00) and math.isfinite(j01)
                and math.isfinite(j10) and math.isfinite(j11) and math.isfinite(ft)):
            return out, STATUS_NONFINITE, n_steps
        while True:  # attempts from (t, x, xv)
            if h <= 1e-14 * max(1.0, abs(t)):
                return out, STATUS_STEP_UNDERFLOW, n_steps
            g = 1.0 / (h * _GAMMA)
            m00 = g - j00
            m11 = g - j11
            det = m00 * m11 - j01 * j10
            if det == 0.0 or not math.isfinite(det):
                h *= 0.5
                last = False
                continue
            idet = 1.0 / det
            r0 = stage_rhs(1, f0, h, ft, 0.0, 0.0, 0.0, 0.0, 0.0)
            r1 = stage_rhs(1, f1, h, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            k10 = (m11 * r0 + j01 * r1) * idet
            k11 = (j10 * r0 + m00 * r1) * idet
            a0, a1 = _rhs(stage_time(2, t, h), stage_point(2, x, k10, 0.0, 0.0, 0.0),
                          stage_point(2, xv, k11, 0.0, 0.0, 0.0), j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02,
                          b0, fl, alpha_v, p_r, b_base, comp, vmode, vtau, vp)
            r0 = stage_rhs(2, a0, h, ft, k10, 0.0, 0.0, 0.0, 0.0)
            r1 = stage_rhs(2, a1, h, 0.0, k11, 0.0, 0.0, 0.0, 0.0)
            k20 = (m11 * r0 + j01 * r1) * idet
            k21 = (j10 * r0 + m00 * r1) * idet
            a0, a1 = _rhs(stage_time(3, t, h), stage_point(3, x, k10, k20, 0.0, 0.0),
                          stage_point(3, xv, k11, k21, 0.0, 0.0), j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02,
                          b0, fl, alpha_v, p_r, b_base, comp, vmode, vtau, vp)
            r0 = stage_rhs(3, a0, h, ft, k10, k20, 0.0, 0.0, 0.0)
            r1 = stage_rhs(3, a1, h, 0.0, k11, k21, 0.0, 0.0, 0.0)
            k30 = (m11 * r0 + j01 * r1) * idet
            k31 = (j10 * r0 + m00 * r1) * idet
            a0, a1 = _rhs(stage_time(4, t, h), stage_point(4, x, k10, k20, k30, 0.0),
                          stage_point(4, xv, k11, k21, k31, 0.0), j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02,
                          b0, fl, alpha_v, p_r, b_base, comp, vmode, vtau, vp)
            r0 = stage_rhs(4, a0, h, ft, k10, k20, k30, 0.0, 0.0)
            r1 = stage_rhs(4, a1, h, 0.0, k11, k21, k31, 0.0, 0.0)
            k40 = (m11 * r0 + j01 * r1) * idet
            k41 = (j10 * r0 + m00 * r1) * idet
            xs0 = stage_point(5, x, k10, k20, k30, k40)
            xs1 = stage_point(5, xv, k11, k21, k31, k41)
            a0, a1 = _rhs(t + h, xs0, xs1, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl, alpha_v, p_r,
                          b_base, comp, vmode, vtau, vp)
            r0 = stage_rhs(5, a0, h, ft, k10, k20, k30, k40, 0.0)
            r1 = stage_rhs(5, a1, h, 0.0, k11, k21, k31, k41, 0.0)
            k50 = (m11 * r0 + j01 * r1) * idet
            k51 = (j10 * r0 + m00 * r1) * idet
            xs0 += k50
            xs1 += k51
            a0, a1 = _rhs(t + h, xs0, xs1, j, sp_t, sp_c, lag_e, lag_tau, area, v01, v02, b0, fl, alpha_v, p_r,
                          b_base, comp, vmode, vtau, vp)
            r0 = stage_rhs(6, a0, h, ft, k10, k20, k30, k40, k50)
            r1 = stage_rhs(6, a1, h, 0.0, k11, k21, k31, k41, k51)
            k60 = (m11 * r0 + j01 * r1) * idet
            k61 = (j10 * r0 + m00 * r1) * idet
            x_new = xs0 + k60
            xv_new = xs1 + k61
            err = _norm2(k60 / (atol + rtol * max(abs(x), abs(x_new))),
                         k61 / (atol_x + rtol * max(abs(xv), abs(xv_new))), n_act)
            if not (math.isfinite(x_new) and math.isfinite(xv_new) and math.isfinite(err)):
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
            n_steps += 1
            n_acc += 1
            if n_acc > 1:
                h_new = predictive_step(h, fac, err, h_acc, err_acc)
            h_acc = h
            err_acc = max(0.01, err)
            t_new = t_end if last else t + h
            cd3, cd4 = dense_coefficients(k10, k20, k30, k40, k50)
            while i_out < n_t and t_out[i_out] <= t_new:
                s = (t_out[i_out] - t) / h
                out[i_out] = _force_out(dense_value(x, x_new, cd3, cd4, s), dense_slope(x, x_new, cd3, cd4, s, h),
                                        t_out[i_out], j, sp_t, sp_c, lag_e, lag_tau, area, comp, eff)
                i_out += 1
            x = x_new
            xv = xv_new
            t = t_new
            if reject:
                h_new = min(h_new, h)
            reject = False
            h = h_new
            break
    for i in range(n_t):
        if not math.isfinite(out[i]):
            return out, STATUS_NONFINITE, n_steps
    return out, STATUS_OK, n_steps
