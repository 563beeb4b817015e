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

import math

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


def _first_root(c: np.ndarray, h: float) -> float | None:
    """Smallest real root in (0, h) of the polynomial sum_j c[j] s^j, or None."""
    cc = np.trim_zeros(np.asarray(c, dtype=float)[::-1], "f")
    if cc.size < 2:
        return None
    roots = np.roots(cc)
    real = roots[np.abs(roots.imag) <= 1e-9 * max(1.0, h)].real
    real = real[(real > MERGE_TIME_S) & (real < h - MERGE_TIME_S)]
    return float(real.min()) if real.size else None


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
    side = 0.0  # 0: free (piston at rest at yp); -r: dragged forward (y_P = y_A - r); +r: dragged back
    k_deg = drive.coefs.shape[1]
    breaks, coefs, restart = [drive.start], [], [True]
    for k in range(drive.coefs.shape[0]):
        ta, tb = float(drive.breaks[k]), float(drive.breaks[k + 1])
        c = drive.coefs[k]
        dc = c[1:] * np.arange(1, k_deg)
        s0 = 0.0
        while s0 < tb - ta:
            h = tb - ta - s0
            cs = _shift_coefs(c, s0)
            dcs = _shift_coefs(dc, s0)
            if side == 0.0:  # free: the first contact with either side of the play
                hits = [(s, sd) for sd, level in ((-r, yp + r), (r, yp - r))
                        if (s := _first_root(cs - np.r_[level, np.zeros(k_deg - 1)], h)) is not None]
                if abs(cs[0] - yp) >= r - CONTACT_M and (dcs[0] > 0) == (cs[0] > yp) and abs(dcs[0]) > MOVING_M_S:
                    hits.append((0.0, -r if dcs[0] > 0 else r))  # at a side and moving out: taken along now
                if not hits:
                    _append(breaks, coefs, restart, ta + s0 + h, np.r_[yp, np.zeros(k_deg - 1)], False)
                    s0 += h
                    continue
                s, sd = min(hits)
                if s > 0.0:
                    _append(breaks, coefs, restart, ta + s0 + s, np.r_[yp, np.zeros(k_deg - 1)], False)
                    restart[-1] = True  # the piston's velocity jumps from 0 where it is taken along
                    s0 += s
                side = sd
                continue
            # dragged: follow the actuator until its velocity changes sign (at once if it no longer moves out)
            outward = -side * dcs[0] > 0.0 and abs(dcs[0]) > MOVING_M_S
            s = 0.0 if not outward else _first_root(dcs, h)
            end = h if s is None else s
            _append(breaks, coefs, restart, ta + s0 + end, cs + np.r_[side, np.zeros(k_deg - 1)], False)
            s0 += end
            if s is not None:
                yp = float(np.polyval(cs[::-1], end)) + side
                side = 0.0
        restart[-1] = restart[-1] or bool(drive.restart[k + 1])
    return PiecewisePolynomial(np.array(breaks), np.array(coefs), np.array(restart))


def _shift_coefs(c: np.ndarray, d: float) -> np.ndarray:
    """Coefficients of p(s + d) in powers of s, for p(s) = sum_j c[j] s^j."""
    n = c.size
    return np.array([sum(c[j] * math.comb(j, i) * d ** (j - i) for j in range(i, n)) for i in range(n)])


def _append(breaks: list, coefs: list, restart: list, t_end: float, c: np.ndarray, flag: bool) -> None:
    """Append the piece [breaks[-1], t_end] with coefficients ``c`` (merging a vanishing piece)."""
    if t_end - breaks[-1] <= MERGE_TIME_S:
        return
    coefs.append(np.asarray(c, dtype=float))
    breaks.append(t_end)
    restart.append(flag)


# ----------------------------------------------------------------------------- composed-kernel hooks
def transform_input(drive: PiecewisePolynomial, p: np.ndarray) -> PiecewisePolynomial:
    """The piston displacement behind the play ``p[0]`` [m] (input hook of :mod:`bayesdamper.physics.compose`)."""
    return play_polynomial(drive, float(p[0]))
