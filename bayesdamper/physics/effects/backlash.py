"""Backlash: free play between the actuator (whose displacement is measured) and the piston.

A play operator of total width ``gap`` (half-width r = gap / 2): the piston stays still while the
actuator moves inside the play; once the actuator reaches a side of the play it drags the piston
along, ``y_P = y_A - r`` when pushing forward and ``y_A + r`` when pulling back. After each reversal
the piston therefore rests until the actuator has moved ``gap``; from rest with the piston centred
in the play (the default) until it has moved ``gap / 2``.

The play operator is applied to the input itself, never as an ODE state. On a piecewise-linear actuator
displacement it is exactly piecewise linear: each linear segment adds at most one knot (where the actuator
takes up the play), :func:`backlash_knots`. On polynomial pieces of higher degree (a smoothed measured
record) the piston rests at a constant until the actuator reaches a side of the play (a root of a piece,
where the piston's velocity jumps: a restart break) and follows the actuator until its velocity changes sign
(a root of the piece's derivative), :func:`play_polynomial`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from bayesdamper.core.errors import SettingsError
from bayesdamper.physics.effects.base import Effect, EffectParam
from bayesdamper.physics.excitation import PiecewisePolynomial

__all__ = ["EFFECT", "backlash_knots", "play_polynomial", "transform_input"]

#: Engagement points closer than this to a knot are merged into it [s] (keeps knot times strictly
#: increasing by far more than the kernel's step-size floor).
MERGE_TIME_S = 1e-9
#: Distance from a side of the play within which the actuator counts as in contact [m] (far below any sensor's
#: resolution, far above the round-off of the piece arithmetic on displacements of millimetres).
CONTACT_M = 1e-12
#: Speed below which the actuator counts as not moving [m/s] (round-off of the pieces' derivative at a reversal is
#: ~1e-18 m/s; any real motion is many orders above).
MOVING_M_S = 1e-12

EFFECT = Effect(
    name="backlash",
    description="free play between actuator and piston: after each reversal the piston rests until the "
                "actuator has taken up the gap",
    params=(
        EffectParam("gap_m", "m", 1.0e-7, 1.0e-3, 1.0e-5, True,
                    "total free play between the measured actuator displacement and the piston"),
    ),
)


@njit(cache=True)
def _play_knots(kt, ky, r, yp):
    """Knots of the play operator of half-width ``r`` [m] from piston position ``yp`` [m] (compiled core)."""
    n = kt.shape[0]
    times = np.empty(2 * n - 1)
    ys = np.empty(2 * n - 1)
    times[0] = kt[0]
    ys[0] = yp
    m = 1
    for k in range(n - 1):
        ta, tb, ya, yb = kt[k], kt[k + 1], ky[k], ky[k + 1]
        s = (yb - ya) / (tb - ta)
        if s != 0.0:
            side = -r if s > 0.0 else r  # the contact: y_P = y_A + side while the actuator drags
            te = ta + (yp - side - ya) / s  # the actuator reaches the contact
            if te < tb - MERGE_TIME_S:
                if te > ta + MERGE_TIME_S:
                    times[m] = te
                    ys[m] = yp
                    m += 1
                yp = yb + side
        times[m] = tb
        ys[m] = yp
        m += 1
    return times[:m].copy(), ys[:m].copy()


def backlash_knots(knot_t: np.ndarray, knot_y: np.ndarray, gap: float,
                   y_piston0: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Piston displacement knots behind a play of total width ``gap``, exactly (module docstring).

    Parameters
    ----------
    knot_t, knot_y : ndarray, shape (n_knots,)
        Strictly increasing knot times [s] and actuator displacement there [m].
    gap : float
        Total free play [m], >= 0 (0 returns copies of the knots).
    y_piston0 : float, optional
        Piston displacement at ``knot_t[0]`` [m]; default ``knot_y[0]`` (centred in the play).
        Clipped into ``[knot_y[0] - gap/2, knot_y[0] + gap/2]``.

    Returns
    -------
    knot_t, knot_y : ndarray, shape (n_out,)
        Knots of the piston displacement, ``n_knots <= n_out <= 2 n_knots - 1``: every input knot
        plus at most one engagement knot per segment.
    """
    kt = np.ascontiguousarray(knot_t, dtype=np.float64)
    ky = np.ascontiguousarray(knot_y, dtype=np.float64)
    if not (np.isfinite(gap) and gap >= 0):
        raise SettingsError(f"backlash gap must be finite and >= 0 m, got {gap!r}")
    if gap == 0:
        return kt.copy(), ky.copy()
    r = 0.5 * float(gap)
    y0 = float(ky[0])
    yp = y0 if y_piston0 is None else min(max(float(y_piston0), y0 - r), y0 + r)
    return _play_knots(kt, ky, r, yp)


#: Sub-intervals of a piece in which a root is bracketed by a sign change and then bisected: two roots closer than
#: a 32nd of a piece (a touch of a side of the play, or a velocity that grazes zero, shorter than a 32nd of a sample
#: interval of a smoothed record) are not seen, and the piston then neither takes nor leaves contact there.
ROOT_SUBINTERVALS = 32


@njit(cache=True)
def _poly(c, s):
    out = 0.0
    for j in range(c.shape[0] - 1, -1, -1):
        out = out * s + c[j]
    return out


@njit(cache=True)
def _first_root(c, h):
    """Smallest real root in (MERGE_TIME_S, h - MERGE_TIME_S) of sum_j c[j] s^j where it changes sign, or -1.0."""
    lo = MERGE_TIME_S
    hi = h - MERGE_TIME_S
    if hi <= lo:
        return -1.0
    step = (hi - lo) / ROOT_SUBINTERVALS
    a = lo
    fa = _poly(c, a)
    for i in range(1, ROOT_SUBINTERVALS + 1):
        b = lo + i * step if i < ROOT_SUBINTERVALS else hi
        fb = _poly(c, b)
        if fa == 0.0:
            return a
        if (fa < 0.0) != (fb < 0.0):
            for _ in range(200):  # bisection to the last bit
                m = 0.5 * (a + b)
                if m <= a or m >= b:
                    break
                fm = _poly(c, m)
                if (fm < 0.0) == (fa < 0.0):
                    a, fa = m, fm
                else:
                    b = m
            return 0.5 * (a + b)
        a, fa = b, fb
    return -1.0


@njit(cache=True)
def _shift_coefs(c, d):
    """Coefficients of p(s + d) in powers of s, for p(s) = sum_j c[j] s^j (synthetic division)."""
    out = c.copy()
    n = out.shape[0]
    for i in range(n - 1):
        for j in range(n - 2, i - 1, -1):
            out[j] += d * out[j + 1]
    return out


@njit(cache=True)
def _play_pieces(breaks, coefs, restart_in, r, yp):
    """The play operator on polynomial pieces (compiled core of :func:`play_polynomial`)."""
    m, k_deg = coefs.shape
    cap = 3 * k_deg * m + 2  # each piece holds fewer than 3 k_deg contacts and reversals
    b_out = np.empty(cap + 1)
    c_out = np.zeros((cap, k_deg))
    f_out = np.zeros(cap + 1, dtype=np.bool_)
    b_out[0] = breaks[0]
    f_out[0] = True
    n = 0  # pieces written
    side = 0.0  # 0: free (piston at rest at yp); -r: dragged forward (y_P = y_A - r); +r: dragged back
    for k in range(m):
        ta, tb = breaks[k], breaks[k + 1]
        c = coefs[k]
        dc = np.zeros(k_deg - 1)
        for j in range(1, k_deg):
            dc[j - 1] = c[j] * j
        s0 = 0.0
        while s0 < tb - ta:
            if n >= cap - 2:
                raise ValueError("play operator: more contacts in a piece than its degree allows")
            h = tb - ta - s0
            cs = _shift_coefs(c, s0)
            dcs = _shift_coefs(dc, s0)
            if side == 0.0:  # free: the first contact with either side of the play
                best, best_side = -1.0, 0.0
                for sd, level in ((-r, yp + r), (r, yp - r)):
                    cl = cs.copy()
                    cl[0] -= level
                    root = _first_root(cl, h)
                    if root >= 0.0 and (best < 0.0 or root < best):
                        best, best_side = root, sd
                if abs(cs[0] - yp) >= r - CONTACT_M and (dcs[0] > 0) == (cs[0] > yp) and abs(dcs[0]) > MOVING_M_S:
                    best, best_side = 0.0, (-r if dcs[0] > 0 else r)  # at a side and moving out: taken along now
                if best < 0.0:
                    t_end = ta + s0 + h
                    if t_end - b_out[n] > MERGE_TIME_S:
                        c_out[n, :] = 0.0
                        c_out[n, 0] = yp
                        b_out[n + 1] = t_end
                        f_out[n + 1] = False
                        n += 1
                    s0 += h
                    continue
                if best > 0.0:
                    t_end = ta + s0 + best
                    if t_end - b_out[n] > MERGE_TIME_S:
                        c_out[n, :] = 0.0
                        c_out[n, 0] = yp
                        b_out[n + 1] = t_end
                        n += 1
                    f_out[n] = True  # the piston's velocity jumps from 0 where it is taken along
                    s0 += best
                side = best_side
                continue
            # dragged: follow the actuator until its velocity changes sign (at once if it no longer moves out)
            outward = -side * dcs[0] > 0.0 and abs(dcs[0]) > MOVING_M_S
            root = 0.0 if not outward else _first_root(dcs, h)
            end = h if root < 0.0 else root
            t_end = ta + s0 + end
            if t_end - b_out[n] > MERGE_TIME_S:
                c_out[n, :] = cs
                c_out[n, 0] += side
                b_out[n + 1] = t_end
                f_out[n + 1] = False
                n += 1
            s0 += end
            if root >= 0.0:
                yp = _poly(cs, end) + side
                side = 0.0
        f_out[n] = f_out[n] or restart_in[k + 1]
    return b_out[:n + 1].copy(), c_out[:n].copy(), f_out[:n + 1].copy()


def play_polynomial(drive: PiecewisePolynomial, gap: float, y_piston0: float | None = None) -> PiecewisePolynomial:
    """The piston displacement behind a play of total width ``gap`` [m] for an actuator displacement of any
    degree (module docstring); degree-1 inputs go through :func:`backlash_knots` (exact and faster).

    Parameters
    ----------
    drive : PiecewisePolynomial
        Actuator displacement [m].
    gap : float
        Total free play [m], >= 0.
    y_piston0 : float, optional
        Piston displacement at the first break [m]; default centred in the play.
    """
    if not (np.isfinite(gap) and gap >= 0):
        raise SettingsError(f"backlash gap must be finite and >= 0 m, got {gap!r}")
    if gap == 0:
        return drive
    if drive.degree == 1 and bool(np.all(drive.restart)):
        kt, ky = backlash_knots(drive.breaks, drive.displacement(drive.breaks), gap, y_piston0)
        return PiecewisePolynomial.from_knots(kt, ky)
    r = 0.5 * float(gap)
    y0 = float(drive.coefs[0, 0])
    yp = y0 if y_piston0 is None else min(max(float(y_piston0), y0 - r), y0 + r)
    b, c, f = _play_pieces(np.ascontiguousarray(drive.breaks, dtype=float),
                           np.ascontiguousarray(drive.coefs, dtype=float), np.asarray(drive.restart, dtype=np.bool_),
                           r, yp)
    return PiecewisePolynomial(b, c, f)


# ----------------------------------------------------------------------------- composed-kernel hooks
def transform_input(drive: PiecewisePolynomial, p: np.ndarray) -> PiecewisePolynomial:
    """The piston displacement behind the play ``p[0]`` [m] (input hook of :mod:`bayesdamper.physics.compose`)."""
    return play_polynomial(drive, float(p[0]))
