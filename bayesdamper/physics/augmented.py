"""The compiled kernel of eq. (7) with candidate effects (:mod:`bayesdamper.physics.effects`).

Chain from the measured (actuator) displacement y_A to the measured force F::

    y_A --backlash (knot transform)--> --actuator lag τ_a--> y_D --series compliance 1/k_s--> y_P
    y_P = y_D - c A_P Δp,   c = 1/k_s
    d(Δp)/dt = K (A_P v_D - x Q_O(Δp)) / (1 + K A_P^2 c)
    K        = B_1/(V_{0,1} - A_P y_P) + B_2/(V_{0,2} + A_P y_P)
    dx/dt    = (x_ss(Δp) - x) / τ_v                          (valve dynamics; x = 1 when off)
    F        = A_P Δp + F_f(v_P) + m a_P,   v_P = v_D - c A_P d(Δp)/dt

with B_1, B_2 from eq. (6), Q_O from eq. (8), v_D = dy_D/dt, friction F_f and the corner-filtered
acceleration a_P of :mod:`bayesdamper.physics.effects.inertia`. With every effect off this is eq. (7).

Effect vector
-------------
The effect parameters travel as one float64 vector of fixed layout (:mod:`bayesdamper.physics.effect_vector`).
A slot at 0 switches its part off (the stiffness is stored as the compliance 1/k_s), except that τ_v = 0
with p_v > 0 is the quasi-static valve x = x_ss(Δp). The Python simulators that drive this kernel live in
:mod:`bayesdamper.physics.with_effects`.

Method of :func:`solve_augmented`
---------------------------------
The RODAS4 of :mod:`bayesdamper.physics.rodas` (same coefficients, step control, dense output, a fresh
initial step at every knot, no step across a knot) on the states (Δp, x) with the analytic 2x2
Jacobian; x is integrated only when the valve dynamics are on (otherwise its stage increments are
exactly 0). The actuator-lag and corner-filter states obey linear ODEs driven by the piecewise-linear
input, so they are integrated exactly in closed form on each knot segment and carried across knots.
Friction and inertia only add to the output force. Status codes are those of
:data:`bayesdamper.physics.rodas.STATUS_MESSAGES`.

numba caching: the kernel calls njit functions of :mod:`bayesdamper.physics.effects` and reads their constants
at compile time; after changing those, delete ``bayesdamper/physics/__pycache__/augmented*.nb[ic]``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bayesdamper.physics.compressibility import bulk_modulus_and_slope, bulk_modulus_scalar
from bayesdamper.physics.effect_vector import _SLOT_PARAM, EFFECT_SLOTS
from bayesdamper.physics.effects.friction import friction_force_scalar
from bayesdamper.physics.effects.inertia import CORNER_TIME_S
from bayesdamper.physics.effects.valve_dynamics import steady_opening
from bayesdamper.physics.orifice import orifice_flow, orifice_flow_and_slope
from bayesdamper.physics.rodas import (
    _GAMMA,
    STATUS_BAD_INPUT,
    STATUS_MAX_STEPS,
    STATUS_MESSAGES,
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

__all__ = ["MAX_STEPS", "solve_augmented"]

(_COULOMB, _VISCOUS, _STRIBECK, _STRIBECK_V, _GAP, _LAG_TAU, _VALVE_TAU, _VALVE_P, _COMPLIANCE,
 _MASS) = range(len(EFFECT_SLOTS))


#: Maximum number of accepted steps of one :func:`solve_augmented` call (whole records included).
MAX_STEPS = 100_000
_MESSAGES = {**STATUS_MESSAGES, STATUS_MAX_STEPS: f"more than {MAX_STEPS} steps were needed"}


if set(_SLOT_PARAM) != set(EFFECT_SLOTS) or len(_SLOT_PARAM) != len(EFFECT_SLOTS):  # pragma: no cover
    raise ImportError("bayesdamper.physics.augmented: EFFECT_SLOTS and the effect registry disagree")


# ----------------------------------------------------------------------------- kernel internals
@njit(cache=True)
def _drive(t, ts, ys, va, lag_tau, es):
    """Lag-filtered drive (y_D [m], v_D [m/s], dv_D/dt [m/s^2]) at ``t`` on a segment from ``ts``.

    ``ys``, ``va``: actuator displacement at ts and its velocity; ``es = y_A - y_D`` at ts. Exact
    solution of de/dt = v_A - e/τ_a.
    """
    ya = ys + va * (t - ts)
    if lag_tau > 0.0:
        w = va * lag_tau
        e = w + (es - w) * math.exp(-(t - ts) / lag_tau)
        vd = e / lag_tau
        return ya - e, vd, (va - vd) / lag_tau
    return ya, va, 0.0


@njit(cache=True)
def _rhs(t, dp, xv, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp, lag_tau,
         vmode, vtau, vp):
    """(d(Δp)/dt [Pa/s], dx/dt [1/s]) of the augmented single-state model (module docstring)."""
    yd, vd, _ = _drive(t, ts, ys, va, lag_tau, es)
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


@njit(cache=True)
def _rhs_jac(t, dp, xv, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp, lag_tau,
             vmode, vtau, vp, atol):
    """Right-hand side (f0, f1), Jacobian (j00, j01, j10, j11) and ∂f0/∂t of the augmented model."""
    yd, vd, dvd = _drive(t, ts, ys, va, lag_tau, es)
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
    dk = db1 * i1 + db2 * i2 - b1 * a2c * i1 * i1 + b2 * a2c * i2 * i2  # dV1/dΔp = A^2 c = -dV2/dΔp
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


@njit(cache=True)
def _force_out(dp, ddp, t, ts, ys, va, es, vfs, area, comp, lag_tau, eff):
    """Measured force [N]: A_P Δp + friction at v_P + m a_P (a_P from the corner filter)."""
    f = area * dp
    if eff[_COULOMB] > 0.0 or eff[_VISCOUS] > 0.0 or eff[_STRIBECK] > 0.0:
        vp = _drive(t, ts, ys, va, lag_tau, es)[1] - comp * area * ddp
        f += friction_force_scalar(vp, eff[_COULOMB], eff[_VISCOUS], eff[_STRIBECK], eff[_STRIBECK_V])
    if eff[_MASS] > 0.0:
        f += eff[_MASS] * (va - vfs) * math.exp(-(t - ts) / CORNER_TIME_S) / CORNER_TIME_S
    return f


@njit(cache=True)
def _nonneg(x):
    return math.isfinite(x) and x >= 0.0


@njit(cache=True)
def _valid(t_out, knot_t, knot_y, t0, dp0, v_prev, area, v01, v02, b0, fl, alpha_v, p_r, eff, rtol, atol):
    n_k = knot_t.shape[0]
    if n_k < 2 or knot_y.shape[0] != n_k or fl.shape[0] != 4 or eff.shape[0] != len(EFFECT_SLOTS):
        return False
    for k in range(n_k):
        if not (math.isfinite(knot_t[k]) and math.isfinite(knot_y[k])):
            return False
        if k > 0 and not knot_t[k] > knot_t[k - 1]:
            return False
    n_t = t_out.shape[0]
    for i in range(n_t):
        if not math.isfinite(t_out[i]) or (i > 0 and t_out[i] < t_out[i - 1]):
            return False
    if not (math.isfinite(t0) and knot_t[0] <= t0 <= t_out[0] and t_out[n_t - 1] <= knot_t[n_k - 1]):
        return False
    for j in range(eff.shape[0]):
        if not _nonneg(eff[j]):
            return False
    for j in range(4):
        if not _nonneg(fl[j]):
            return False
    pos = area > 0.0 and v01 > 0.0 and v02 > 0.0 and b0 > 0.0 and alpha_v > 0.0 and p_r > 0.0
    return (pos and math.isfinite(area + v01 + v02 + b0 + alpha_v + p_r) and math.isfinite(dp0)
            and math.isfinite(v_prev) and 0.0 < rtol < 1.0 and 0.0 < atol < math.inf
            and fl[0] + fl[1] > 0.0 and fl[2] + fl[3] > 0.0)


@njit(cache=True)
def _norm2(e0, e1, n_act):
    return math.sqrt((e0 * e0 + e1 * e1) / n_act)


# ----------------------------------------------------------------------------- public kernel
@njit(cache=True)
def solve_augmented(t_out, knot_t, knot_y, t0, dp0, v_prev, area, v01, v02, b0, flow4, alpha_v, p_r, eff,
                    rtol, atol):
    """Force of the augmented model at the sample times: the compiled hot path (module docstring).

    The transient starts at ``t0`` with Δp = ``dp0``, the valve opening at x_ss(dp0), the actuator lag
    and the corner filter in their steady state for the velocity ``v_prev`` before ``t0``.

    Parameters
    ----------
    t_out : ndarray, shape (n_t,)
        Non-decreasing output times [s] within ``[t0, knot_t[-1]]``.
    knot_t, knot_y : ndarray, shape (n_knots,)
        Strictly increasing knot times [s] covering ``[t0, t_out[-1]]`` and the actuator displacement
        there [m], already transformed for backlash (:func:`backlash_knots`); knots before ``t0``
        are ignored.
    t0 : float
        Start time [s].
    dp0 : float
        Δp at ``t0`` [Pa] (the hydraulic part only: friction excluded).
    v_prev : float
        Actuator velocity just before ``t0`` [m/s] (0 from rest).
    area, v01, v02, b0 : float
        A_P [m^2], V_{0,1}, V_{0,2} [m^3], B_0 [Pa].
    flow4 : ndarray, shape (4,)
        ``[C_L12, C_Q12, C_L21, C_Q21]`` of eq. (8).
    alpha_v, p_r : float
        α_V [-] and p_R [Pa] of eq. (6).
    eff : ndarray, shape (len(EFFECT_SLOTS),)
        Effect vector (:data:`EFFECT_SLOTS`), all entries finite and >= 0; the gap slot is ignored.
    rtol, atol : float
        Relative [-] and absolute [Pa] tolerance of the local error of Δp (valve opening:
        ``atol / p_v``).

    Returns
    -------
    force : ndarray, shape (n_t,)
        Measured force F [N] at ``t_out``; finite when status is 0, unspecified otherwise.
    status : int
        0 on success; the codes of :data:`bayesdamper.physics.rodas.STATUS_MESSAGES` (3: more than
        :data:`MAX_STEPS` steps).
    """
    n_t = t_out.shape[0]
    out = np.full(n_t, np.nan)
    if n_t == 0:
        return out, STATUS_OK
    if not _valid(t_out, knot_t, knot_y, t0, dp0, v_prev, area, v01, v02, b0, flow4, alpha_v, p_r, eff,
                  rtol, atol):
        return out, STATUS_BAD_INPUT
    fl = flow4
    n_k = knot_t.shape[0]
    t_end = t_out[n_t - 1]
    comp = eff[_COMPLIANCE]
    lag_tau = eff[_LAG_TAU]
    vtau = eff[_VALVE_TAU]
    vp = eff[_VALVE_P]
    vmode = 0 if vp == 0.0 else (2 if vtau > 0.0 else 1)
    n_act = 2.0 if vmode == 2 else 1.0
    atol_x = atol / vp if vmode == 2 else 1.0
    # chamber volumes on the actuator displacement over [t0, t_end] (linear between knots)
    y_lo = y_hi = np.interp(t0, knot_t, knot_y)
    y_end = np.interp(t_end, knot_t, knot_y)
    y_lo, y_hi = min(y_lo, y_end), max(y_hi, y_end)
    for k in range(n_k):
        if t0 < knot_t[k] < t_end:
            y_lo, y_hi = min(y_lo, knot_y[k]), max(y_hi, knot_y[k])
    if v01 - area * y_hi <= 0.0 or v02 + area * y_lo <= 0.0:
        return out, STATUS_VOLUME
    b_base = bulk_modulus_scalar(p_r, b0, alpha_v, p_r)
    k0 = 0
    while k0 < n_k - 2 and knot_t[k0 + 1] <= t0:
        k0 += 1
    # states at t0
    x = dp0
    xv = steady_opening(dp0, vp)[0] if vmode == 2 else 1.0
    es = v_prev * lag_tau  # steady trail of the lag
    vfs = v_prev  # corner filter
    i_out = 0
    n_steps = 0
    for k in range(k0, n_k - 1):
        ts = max(knot_t[k], t0)
        tk1 = knot_t[k + 1]
        va = (knot_y[k + 1] - knot_y[k]) / (tk1 - knot_t[k])
        ys = knot_y[k] + va * (ts - knot_t[k])
        if k == k0:  # samples at t0 itself: exact derivative
            f0, f1 = _rhs(ts, x, xv, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp,
                          lag_tau, vmode, vtau, vp)
            while i_out < n_t and t_out[i_out] <= ts:
                out[i_out] = _force_out(x, f0, ts, ts, ys, va, es, vfs, area, comp, lag_tau, eff)
                i_out += 1
        if i_out >= n_t:
            break
        tb = min(tk1, t_end)
        t = ts
        # Hairer-Wanner initial step (RMS norms over the integrated states)
        f0, f1 = _rhs(t, x, xv, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v, p_r, b_base, comp,
                      lag_tau, vmode, vtau, vp)
        sc0 = atol + rtol * abs(x)
        sc1 = atol_x + rtol * abs(xv)
        d0 = _norm2(x / sc0, (xv / sc1) if vmode == 2 else 0.0, n_act)
        d1 = _norm2(f0 / sc0, f1 / sc1, n_act)
        h0 = min(tb - t, 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1)
        g0, g1 = _rhs(t + h0, x + h0 * f0, xv + h0 * f1, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v,
                      p_r, b_base, comp, lag_tau, vmode, vtau, vp)
        dmax = max(d1, _norm2((g0 - f0) / sc0, (g1 - f1) / sc1, n_act) / h0)
        if not math.isfinite(dmax):
            h = h0
        else:
            h = min(100.0 * h0, max(1e-6, h0 * 1e-3) if dmax <= 1e-15 else (0.01 / dmax) ** 0.2, tb - t)
        n_acc_seg = 0
        h_acc = 0.0
        err_acc = 1.0
        reject = False
        while t < tb:
            if n_steps >= MAX_STEPS:
                return out, STATUS_MAX_STEPS
            last = False
            if t + 1.0001 * h >= tb:
                h = tb - t
                last = True
            f0, f1, j00, j01, j10, j11, ft = _rhs_jac(t, x, xv, ts, ys, va, es, area, v01, v02, b0, fl,
                                                      alpha_v, p_r, b_base, comp, lag_tau, vmode, vtau,
                                                      vp, atol)
            if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(j00) and math.isfinite(j01)
                    and math.isfinite(j10) and math.isfinite(j11) and math.isfinite(ft)):
                return out, STATUS_NONFINITE
            while True:  # attempts from (t, x, xv)
                if h <= 1e-14 * max(1.0, abs(t)):
                    return out, STATUS_STEP_UNDERFLOW
                g = 1.0 / (h * _GAMMA)
                m00 = g - j00
                m11 = g - j11
                det = m00 * m11 - j01 * j10
                if det == 0.0 or not math.isfinite(det):
                    h *= 0.5
                    last = False
                    continue
                idet = 1.0 / det
                # stage i: solve [[m00, -j01], [-j10, m11]] k = r (the valve state has no explicit t-dependence)
                r0 = stage_rhs(1, f0, h, ft, 0.0, 0.0, 0.0, 0.0, 0.0)
                r1 = stage_rhs(1, f1, h, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                k10 = (m11 * r0 + j01 * r1) * idet
                k11 = (j10 * r0 + m00 * r1) * idet
                a0, a1 = _rhs(stage_time(2, t, h), stage_point(2, x, k10, 0.0, 0.0, 0.0),
                              stage_point(2, xv, k11, 0.0, 0.0, 0.0), ts, ys, va, es, area, v01, v02,
                              b0, fl, alpha_v, p_r, b_base, comp, lag_tau, vmode, vtau, vp)
                r0 = stage_rhs(2, a0, h, ft, k10, 0.0, 0.0, 0.0, 0.0)
                r1 = stage_rhs(2, a1, h, 0.0, k11, 0.0, 0.0, 0.0, 0.0)
                k20 = (m11 * r0 + j01 * r1) * idet
                k21 = (j10 * r0 + m00 * r1) * idet
                a0, a1 = _rhs(stage_time(3, t, h), stage_point(3, x, k10, k20, 0.0, 0.0),
                              stage_point(3, xv, k11, k21, 0.0, 0.0), ts, ys, va, es, area, v01, v02,
                              b0, fl, alpha_v, p_r, b_base, comp, lag_tau, vmode, vtau, vp)
                r0 = stage_rhs(3, a0, h, ft, k10, k20, 0.0, 0.0, 0.0)
                r1 = stage_rhs(3, a1, h, 0.0, k11, k21, 0.0, 0.0, 0.0)
                k30 = (m11 * r0 + j01 * r1) * idet
                k31 = (j10 * r0 + m00 * r1) * idet
                a0, a1 = _rhs(stage_time(4, t, h), stage_point(4, x, k10, k20, k30, 0.0),
                              stage_point(4, xv, k11, k21, k31, 0.0), ts, ys, va, es, area, v01, v02,
                              b0, fl, alpha_v, p_r, b_base, comp, lag_tau, vmode, vtau, vp)
                r0 = stage_rhs(4, a0, h, ft, k10, k20, k30, 0.0, 0.0)
                r1 = stage_rhs(4, a1, h, 0.0, k11, k21, k31, 0.0, 0.0)
                k40 = (m11 * r0 + j01 * r1) * idet
                k41 = (j10 * r0 + m00 * r1) * idet
                xs0 = stage_point(5, x, k10, k20, k30, k40)
                xs1 = stage_point(5, xv, k11, k21, k31, k41)
                a0, a1 = _rhs(t + h, xs0, xs1, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v, p_r, b_base,
                              comp, lag_tau, vmode, vtau, vp)
                r0 = stage_rhs(5, a0, h, ft, k10, k20, k30, k40, 0.0)
                r1 = stage_rhs(5, a1, h, 0.0, k11, k21, k31, k41, 0.0)
                k50 = (m11 * r0 + j01 * r1) * idet
                k51 = (j10 * r0 + m00 * r1) * idet
                xs0 += k50
                xs1 += k51
                a0, a1 = _rhs(t + h, xs0, xs1, ts, ys, va, es, area, v01, v02, b0, fl, alpha_v, p_r, b_base,
                              comp, lag_tau, vmode, vtau, vp)
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
                n_acc_seg += 1
                if n_acc_seg > 1:
                    h_new = predictive_step(h, fac, err, h_acc, err_acc)
                h_acc = h
                err_acc = max(0.01, err)
                t_new = tb if last else t + h
                # dense output of rodas.f (order 3) for Δp and its time derivative
                cd3, cd4 = dense_coefficients(k10, k20, k30, k40, k50)
                while i_out < n_t and t_out[i_out] <= t_new:
                    s = (t_out[i_out] - t) / h
                    dp_s = dense_value(x, x_new, cd3, cd4, s)
                    ddp_s = dense_slope(x, x_new, cd3, cd4, s, h)
                    out[i_out] = _force_out(dp_s, ddp_s, t_out[i_out], ts, ys, va, es, vfs, area, comp,
                                            lag_tau, eff)
                    i_out += 1
                x = x_new
                xv = xv_new
                t = t_new
                if reject:
                    h_new = min(h_new, h)
                reject = False
                h = h_new
                break
        # carry the exactly integrated linear states to the next knot
        if lag_tau > 0.0:
            w = va * lag_tau
            es = w + (es - w) * math.exp(-(tb - ts) / lag_tau)
        vfs = va + (vfs - va) * math.exp(-(tb - ts) / CORNER_TIME_S)
        if i_out >= n_t:
            break
    for i in range(n_t):
        if not math.isfinite(out[i]):
            return out, STATUS_NONFINITE
    return out, STATUS_OK
