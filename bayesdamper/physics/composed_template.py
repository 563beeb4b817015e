# ruff: noqa: F821
"""The solver half of a composed kernel: :mod:`bayesdamper.physics.compose` appends the model half.

This file is never imported on its own. :func:`bayesdamper.physics.compose.kernel` writes its text,
followed by generated definitions of ``_n_states``, ``_force_mode``, ``_motion_at``, ``_rhs_at``, ``_force``,
``_init`` and ``_atol`` calling the hooks of every registered effect, each only when the runtime layout
``lay`` marks it active, into a module of the kernel cache and imports that: numba compiles (and caches on
disk) one kernel for every combination of effects, once per machine.

Method: RODAS4 (Hairer & Wanner; the coefficients, step control and dense output of
:mod:`bayesdamper.physics.rodas`) on the state vector (Δp, effect states...) with a forward-difference
Jacobian and time derivative, LU with partial pivoting once per step; no step across a knot of the
piecewise-linear displacement, and a fresh initial step at every knot. The force at an output time is
the model evaluated at the dense-output state, so every signal (v_P, dΔp/dt) is consistent with it (or A_P
times the dense Δp when no active effect adds a force; from the dense states and the signals of the motion alone when
every active force reads no other, ``force_reads``). The accepted steps can be recorded and replayed (internal
numerical differentiation, :func:`solve_composed`'s ``rec`` and ``rep``).
"""

import math

import numpy as np
from numba import njit
from numba.core.cpu import CPUTargetOptions

from bayesdamper.physics.effects.signals import FORCE_READS_ANY, FORCE_READS_MOTION, FORCE_READS_STATE, N_SIGNALS
from bayesdamper.physics.rodas import (
    _GAMMA,
    STATUS_BAD_INPUT,
    STATUS_MAX_STEPS,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_REPLAY,
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
from bayesdamper.physics.single_state import drive as _drive
from bayesdamper.physics.single_state import next_restart as _next_restart
from bayesdamper.physics.single_state import solve_eq7 as _solve_eq7

#: Compile options of the functions called at every stage and output time that only read, write and slice arrays
#: their caller owns (the right-hand side, the force, the motion's signals): no reference counting (numba's
#: ``_nrt`` option, where this numba has it). Each slice an effect's hook is handed would otherwise take an atomic
#: increment and decrement of its array's count, more than most hooks' own arithmetic; these functions allocate
#: nothing and hand back only scalars, so no count is ever needed. Effect hooks must return scalars.
NO_REFCOUNT = {"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}
#: Default largest number of accepted steps of one call (the ``max_steps`` argument).
MAX_STEPS = 100_000
#: A replayed step whose error estimate exceeds this many times the tolerance ends the replay (the solve is done
#: again with error control): the perturbed solution has left the one whose steps are replayed (a valve that
#: chatters, opens or closes at another step), and its difference against it would be the replay's error.
REPLAY_ERR_MAX = 10.0
# layout of the ``base`` vector
B_AREA, B_V01, B_V02, B_B0, B_ALPHA, B_PR, B_FL0, B_FL1, B_FL2, B_FL3, B_COMP = range(11)
N_BASE = 11
#: How the force at an output time is evaluated (``_force_mode``): A_P Δp (no active effect adds a force); from the
#: states, t and Δp; from those and the motion's signals (``_motion_at``: the input and the displacement path, the
#: series compliance's only when it is off); from every signal (a right-hand side there). The levels of the effects'
#: ``force_reads`` hooks (:mod:`bayesdamper.physics.effects.signals`) but the first.
FORCE_DP, FORCE_STATES, FORCE_MOTION, FORCE_SIGNALS = 0, FORCE_READS_STATE, FORCE_READS_MOTION, FORCE_READS_ANY


@njit(cache=True, error_model="numpy")
def _lu(m, piv):
    """In-place LU factorisation with partial pivoting; False if singular."""
    n = m.shape[0]
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(m[i, k]) > abs(m[p, k]):
                p = i
        piv[k] = p
        if m[p, k] == 0.0 or not math.isfinite(m[p, k]):
            return False
        if p != k:
            for j in range(n):
                tmp = m[k, j]
                m[k, j] = m[p, j]
                m[p, j] = tmp
        for i in range(k + 1, n):
            m[i, k] /= m[k, k]
            for j in range(k + 1, n):
                m[i, j] -= m[i, k] * m[k, j]
    return True


@njit(cache=True, error_model="numpy")
def _lu_solve(m, piv, b):
    """Solve in place with the factors of :func:`_lu`."""
    n = m.shape[0]
    for k in range(n):
        p = piv[k]
        if p != k:
            tmp = b[k]
            b[k] = b[p]
            b[p] = tmp
    for i in range(n):
        for j in range(i):
            b[i] -= m[i, j] * b[j]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            b[i] -= m[i, j] * b[j]
        b[i] /= m[i, i]


@njit(cache=True, error_model="numpy")
def _err_norm(v, x, xn, sc_a, rtol):
    acc = 0.0
    n = v.shape[0]
    for i in range(n):
        e = v[i] / (sc_a[i] + rtol * max(abs(x[i]), abs(xn[i])))
        acc += e * e
    return math.sqrt(acc / n)


@njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _rhs(t, s, ds, sig, prm, base, brk, coef, seg, lay):
    """The model's right-hand side at ``t`` with the input's polynomial pieces (``seg``: the restart interval's
    first and end piece and the piece last used, updated)."""
    ya, va, aa, j = _drive(t, brk, coef, seg[0], seg[1], seg[2])
    seg[2] = j
    return _rhs_at(t, s, ds, sig, prm, base, ya, va, aa, lay)


@njit(cache=True, error_model="numpy")
def _output_mode(lay, prm, base):
    """How the force is evaluated at the output times (:data:`FORCE_DP`...): the effects' ``_force_mode``, every
    signal where the motion's would need the series compliance's rate (v_P depends on dΔp/dt then)."""
    mode = _force_mode(lay, prm)
    if mode == FORCE_MOTION and base[B_COMP] != 0.0:
        return FORCE_SIGNALS
    return mode


@njit(cache=True, error_model="numpy")
def solve_force_only(t_out, brk, coef, restart, dp0, v_prev, base, prm, rtol, atol, from_force, lay):
    """Force at ``t_out`` of eq. (7) with effects that only add a force (no state, nothing in the ODE): Δp by the
    eq. (7) kernel (:func:`~bayesdamper.physics.single_state.solve_eq7`, its analytic Jacobian), the effects'
    forces at the samples. The input starts at the solution's start ``brk[0]``; other arguments as
    :func:`solve_composed`.
    """
    n_t = t_out.shape[0]
    out = np.full(n_t, np.nan)
    sig = np.full(N_SIGNALS, np.nan)
    x = np.zeros(1)
    f0 = np.zeros(1)
    seg = np.zeros(3, dtype=np.int64)
    m = brk.shape[0] - 1
    if n_t == 0:
        return out, STATUS_OK
    if m < 1 or coef.shape[0] != m or not math.isfinite(dp0):
        return out, STATUS_BAD_INPUT
    t0 = brk[0]
    ya0 = coef[0, 0]
    if from_force:  # the effects' force in the steady state before t0 does not depend on Δp: one step
        f_target = dp0
        dp0 = f_target / base[B_AREA]
        if not (_init(t0, ya0, v_prev, dp0, sig, x, prm, base, lay)
                and _rhs_at(t0, x, f0, sig, prm, base, ya0, v_prev, 0.0, lay)):
            return out, STATUS_NONFINITE
        dp0 -= (_force(sig, x, prm, base, lay) - f_target) / base[B_AREA]
    fl = base[B_FL0:B_FL3 + 1].copy()
    # eq. (6)'s bulk modulus as an int64, not a literal 0: the signature Python's calls compiled (and cached)
    dp, status, _ = _solve_eq7(t_out, brk, coef, restart, dp0, base[B_AREA], base[B_V01], base[B_V02], base[B_B0], fl,
                               base[B_ALPHA], base[B_PR], np.int64(0), 0.0, rtol, atol)
    if status != STATUS_OK:
        return out, status
    seg[1] = _next_restart(restart, 0)
    mode = _output_mode(lay, prm, base)
    for i in range(n_t):  # the effects' forces at the samples, from the same hooks as the full kernel
        x[0] = dp[i]
        if mode >= FORCE_MOTION:
            while seg[1] < m and t_out[i] > brk[seg[1]]:  # a sample on a velocity step takes the piece ending there
                seg[0] = seg[1]
                seg[2] = seg[1]
                seg[1] = _next_restart(restart, seg[0])
        if mode == FORCE_STATES:  # the signals inline: a call with the arrays costs more than the force itself
            sig[T] = t_out[i]
            sig[DP] = x[0]
        elif mode == FORCE_MOTION:
            ya, va, aa, j = _drive(t_out[i], brk, coef, seg[0], seg[1], seg[2])
            seg[2] = j
            _motion_at(t_out[i], x, f0, sig, prm, base, ya, va, aa, lay)
        elif mode == FORCE_SIGNALS and not _rhs(t_out[i], x, f0, sig, prm, base, brk, coef, seg, lay):
            return out, STATUS_NONFINITE
        out[i] = _force(sig, x, prm, base, lay)
    return out, STATUS_OK


@njit(cache=True, error_model="numpy")
def solve_composed(t_out, brk, coef, restart, t0, dp0, v_prev, base, prm, rtol, atol, from_force, lay, max_steps,
                   rec, rep):
    """Force of the composed model at the sample times (module docstring).

    Parameters
    ----------
    t_out : ndarray (n_t,)
        Non-decreasing output times [s] within ``[t0, brk[-1]]``.
    brk, coef, restart : ndarray (m + 1,), (m, K), (m + 1,) of bool
        The measured displacement as polynomial pieces
        (:class:`~bayesdamper.physics.excitation.PiecewisePolynomial`: breaks [s], local power-basis
        coefficients [m s^-j], breaks where the velocity may jump). Steps never cross a restart break.
    t0, dp0, v_prev : float
        Start time [s], Δp there [Pa] and the velocity just before it [m/s].
    from_force : bool
        ``dp0`` is the measured force at t0 [N] instead: Δp0 is solved so that the model's force in the
        steady state before t0 (velocity ``v_prev``) equals it (friction, offsets... included).
    base : ndarray (11,)
        A_P, V_01, V_02, B_0, α_V, p_R, C_L12, C_Q12, C_L21, C_Q21, total series compliance [m/N].
    prm : ndarray
        The named effects' parameters, concatenated in the kernel's order.
    rtol, atol : float
        Relative tolerance [-] and absolute tolerance of Δp [Pa] (effect states: their ``_atol``).
    lay : ndarray (n_effects, 4) of int64
        Which registered effects are active, their first state and their parameters' slice in ``prm``
        (:func:`bayesdamper.physics.compose.layout`).
    max_steps : int
        Accepted steps after which the solve fails with ``STATUS_MAX_STEPS``.
    rec : ndarray
        Where the end time of every accepted step is written, in order, while it has room (size 0: nothing is
        recorded); their number is returned.
    rep : ndarray
        Step end times to replay (size 0: the steps are chosen by the error control): the solve takes exactly
        these steps, no error estimate, no rejection (internal numerical differentiation: a solve at perturbed
        parameters on the steps of the solve it is differenced against differs from it smoothly, where two
        error-controlled solves differ by their tolerance's noise). ``STATUS_REPLAY`` when they do not fit this
        solve's restart intervals or a step fails.

    Returns
    -------
    (force [N] at t_out, status, steps recorded) with the status codes of :mod:`bayesdamper.physics.rodas`.
    """
    n_t = t_out.shape[0]
    out = np.full(n_t, np.nan)
    m = brk.shape[0] - 1
    n_rec = 0
    replaying = rep.shape[0] > 0
    i_rep = 0
    t_next = 0.0
    if n_t == 0:
        return out, STATUS_OK, n_rec
    if (m < 1 or coef.shape[0] != m or restart.shape[0] != m + 1
            or not (math.isfinite(t0) and brk[0] <= t0 <= t_out[0] and t_out[n_t - 1] <= brk[m])):
        return out, STATUS_BAD_INPUT, n_rec
    for j in range(prm.shape[0]):
        if not math.isfinite(prm[j]) and not prm[j] == math.inf:
            return out, STATUS_BAD_INPUT, n_rec
    ns = _n_states(lay)
    force_mode = _output_mode(lay, prm, base)
    sig = np.full(N_SIGNALS, np.nan)
    x = np.zeros(ns)
    x_new = np.zeros(ns)
    f0 = np.zeros(ns)
    f1 = np.zeros(ns)
    ft = np.zeros(ns)
    xp = np.zeros(ns)
    jac = np.zeros((ns, ns))
    mat = np.zeros((ns, ns))
    piv = np.zeros(ns, dtype=np.int64)
    ks = np.zeros((6, ns))
    r = np.zeros(ns)
    sc_a = np.zeros(ns)
    xd = np.zeros(ns)
    sc_a[0] = atol
    _atol(prm, atol, sc_a, lay)
    t_end = t_out[n_t - 1]
    # chamber volumes must stay positive on the input: checked at the breaks (exact for linear pieces; the
    # right-hand side rejects a non-positive volume between the breaks of higher-degree pieces)
    for k in range(m + 1):
        tk = min(max(brk[k], t0), t_end)
        yk, _, _, _ = _drive(tk, brk, coef, 0, m, min(k, m - 1))
        if base[B_V01] - base[B_AREA] * yk <= 0.0 or base[B_V02] + base[B_AREA] * yk <= 0.0:
            return out, STATUS_VOLUME, n_rec
        if brk[k] >= t_end:
            break
    # the restart interval [brk[a], brk[b]] holding t0
    a = 0
    while a < m - 1 and brk[a + 1] <= t0:
        a += 1
    while not restart[a]:
        a -= 1
    seg = np.zeros(3, dtype=np.int64)
    seg[0] = a
    seg[1] = _next_restart(restart, a)
    seg[2] = a
    ya0, _, _, j0 = _drive(t0, brk, coef, seg[0], seg[1], seg[2])
    seg[2] = j0
    if from_force:  # Newton on Δp0 with the slope A_P of the hydraulic force
        f_target = dp0
        dp0 = f_target / base[B_AREA]
        for _ in range(6):  # the steady state before t0: velocity v_prev, no acceleration
            if not (_init(t0, ya0, v_prev, dp0, sig, x, prm, base, lay)
                    and _rhs_at(t0, x, f0, sig, prm, base, ya0, v_prev, 0.0, lay)):
                return out, STATUS_NONFINITE, n_rec
            dp0 -= (_force(sig, x, prm, base, lay) - f_target) / base[B_AREA]
    if not (math.isfinite(dp0) and _init(t0, ya0, v_prev, dp0, sig, x, prm, base, lay)):
        return out, STATUS_NONFINITE, n_rec
    i_out = 0
    n_steps = 0
    cd3 = cd4 = 0.0
    while a < m:
        b = _next_restart(restart, a)
        seg[0] = a
        seg[1] = b
        seg[2] = a
        ts = max(brk[a], t0)
        tk1 = brk[b]
        while i_out < n_t and t_out[i_out] <= ts:
            if not _rhs(ts, x, f0, sig, prm, base, brk, coef, seg, lay):
                return out, STATUS_NONFINITE, n_rec
            out[i_out] = _force(sig, x, prm, base, lay)
            i_out += 1
        if i_out >= n_t:
            break
        tb = min(tk1, t_end)
        t = ts
        # Hairer-Wanner initial step
        if not _rhs(t, x, f0, sig, prm, base, brk, coef, seg, lay):
            return out, STATUS_NONFINITE, n_rec
        d0 = 0.0
        d1 = 0.0
        for i in range(ns):
            sc = sc_a[i] + rtol * abs(x[i])
            d0 += (x[i] / sc) ** 2
            d1 += (f0[i] / sc) ** 2
        d0 = math.sqrt(d0 / ns)
        d1 = math.sqrt(d1 / ns)
        h0 = min(tb - t, 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1)
        for i in range(ns):
            xp[i] = x[i] + h0 * f0[i]
        ok = _rhs(t + h0, xp, f1, sig, prm, base, brk, coef, seg, lay)
        d2 = 0.0
        for i in range(ns):
            d2 += ((f1[i] - f0[i]) / (sc_a[i] + rtol * abs(x[i]))) ** 2
        dmax = max(d1, math.sqrt(d2 / ns) / h0)
        if not ok or not math.isfinite(dmax):
            h = h0
        else:
            h = min(100.0 * h0, max(1e-6, h0 * 1e-3) if dmax <= 1e-15 else (0.01 / dmax) ** 0.2, tb - t)
        n_acc_seg = 0
        h_acc = 0.0
        err_acc = 1.0
        reject = False
        while t < tb:
            if replaying:  # the recorded step ending at rep[i_rep]; it must end inside this interval
                if i_rep >= rep.shape[0] or not (t < rep[i_rep] <= tb):
                    return out, STATUS_REPLAY, n_rec
                t_next = rep[i_rep]
                i_rep += 1
                last = t_next == tb
                h = t_next - t
            else:
                if n_steps >= max_steps:
                    return out, STATUS_MAX_STEPS, n_rec
                last = False
                if t + 1.0001 * h >= tb:
                    h = tb - t
                    last = True
            # f, forward-difference Jacobian and time derivative at (t, x); the input at t once for f and the columns
            ya, va, aa, jd = _drive(t, brk, coef, seg[0], seg[1], seg[2])
            seg[2] = jd
            if not _rhs_at(t, x, f0, sig, prm, base, ya, va, aa, lay):
                return out, STATUS_NONFINITE, n_rec
            for j in range(ns):
                dj = 1.49e-8 * max(abs(x[j]), sc_a[j] * 1e3)
                for i in range(ns):
                    xp[i] = x[i]
                xp[j] = x[j] + dj
                if not _rhs_at(t, xp, f1, sig, prm, base, ya, va, aa, lay):
                    return out, STATUS_NONFINITE, n_rec
                for i in range(ns):
                    jac[i, j] = (f1[i] - f0[i]) / dj
            dt = 1.49e-8 * max(abs(t), 1.0)
            if not _rhs(t + dt, x, f1, sig, prm, base, brk, coef, seg, lay):
                return out, STATUS_NONFINITE, n_rec
            for i in range(ns):
                ft[i] = (f1[i] - f0[i]) / dt
                if not (math.isfinite(f0[i]) and math.isfinite(ft[i])):
                    return out, STATUS_NONFINITE, n_rec
            while True:  # attempts from (t, x)
                if h <= 1e-14 * max(1.0, abs(t)):
                    return out, STATUS_STEP_UNDERFLOW, n_rec
                g = 1.0 / (h * _GAMMA)
                for i in range(ns):
                    for j in range(ns):
                        mat[i, j] = -jac[i, j]
                    mat[i, i] += g
                if not _lu(mat, piv):
                    if replaying:
                        return out, STATUS_REPLAY, n_rec
                    h *= 0.5
                    last = False
                    continue
                good = True
                for st in range(1, 7):
                    if st == 1:
                        for i in range(ns):
                            r[i] = stage_rhs(1, f0[i], h, ft[i], 0.0, 0.0, 0.0, 0.0, 0.0)
                    else:
                        ti = stage_time(st, t, h)
                        for i in range(ns):
                            if st <= 5:
                                xp[i] = stage_point(st, x[i], ks[0, i], ks[1, i] if st > 2 else 0.0,
                                                    ks[2, i] if st > 3 else 0.0, ks[3, i] if st > 4 else 0.0)
                            else:
                                xp[i] = x_new[i]
                        if not _rhs(ti, xp, f1, sig, prm, base, brk, coef, seg, lay):
                            good = False
                            break
                        for i in range(ns):
                            r[i] = stage_rhs(st, f1[i], h, ft[i], ks[0, i], ks[1, i], ks[2, i], ks[3, i],
                                             ks[4, i])
                    _lu_solve(mat, piv, r)
                    for i in range(ns):
                        ks[st - 1, i] = r[i]
                    if st == 5:
                        for i in range(ns):
                            x_new[i] = xp[i] + ks[4, i]
                if good:
                    for i in range(ns):
                        x_new[i] = x_new[i] + ks[5, i]
                    err = _err_norm(ks[5], x, x_new, sc_a, rtol)
                    for i in range(ns):
                        if not math.isfinite(x_new[i]):
                            good = False
                    good = good and math.isfinite(err)
                if not good:
                    if replaying:
                        return out, STATUS_REPLAY, n_rec
                    h *= 0.2
                    last = False
                    reject = True
                    continue
                if replaying and err > REPLAY_ERR_MAX:  # the recorded step is too long for this solution here
                    return out, STATUS_REPLAY, n_rec
                fac = step_factor(err)
                h_new = h / fac
                if err > 1.0 and not replaying:
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
                t_new = tb if last else (t_next if replaying else t + h)
                if n_rec < rec.shape[0]:
                    rec[n_rec] = t_new
                    n_rec += 1
                if force_mode == FORCE_DP:  # F = A_P Δp: the dense output of Δp alone, its coefficients once a step
                    cd3, cd4 = dense_coefficients(ks[0, 0], ks[1, 0], ks[2, 0], ks[3, 0], ks[4, 0])
                while i_out < n_t and t_out[i_out] <= t_new:
                    s = (t_out[i_out] - t) / h
                    if force_mode != FORCE_DP:
                        for i in range(ns):
                            cd3, cd4 = dense_coefficients(ks[0, i], ks[1, i], ks[2, i], ks[3, i], ks[4, i])
                            xd[i] = dense_value(x[i], x_new[i], cd3, cd4, s)
                        if force_mode == FORCE_STATES:  # inline, as in solve_force_only
                            sig[T] = t_out[i_out]
                            sig[DP] = xd[0]
                        elif force_mode == FORCE_MOTION:
                            ya, va, aa, jd = _drive(t_out[i_out], brk, coef, seg[0], seg[1], seg[2])
                            seg[2] = jd
                            _motion_at(t_out[i_out], xd, f1, sig, prm, base, ya, va, aa, lay)
                        elif not _rhs(t_out[i_out], xd, f1, sig, prm, base, brk, coef, seg, lay):
                            return out, STATUS_NONFINITE, n_rec
                        out[i_out] = _force(sig, xd, prm, base, lay)
                    else:
                        out[i_out] = base[B_AREA] * dense_value(x[0], x_new[0], cd3, cd4, s)
                    i_out += 1
                for i in range(ns):
                    x[i] = x_new[i]
                t = t_new
                if reject:
                    h_new = min(h_new, h)
                reject = False
                h = h_new
                break
        a = b
        if i_out >= n_t:
            break
    for i in range(n_t):
        if not math.isfinite(out[i]):
            return out, STATUS_NONFINITE, n_rec
    return out, STATUS_OK, n_rec
