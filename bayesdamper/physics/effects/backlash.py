"""Backlash: free play between the actuator (whose displacement is measured) and the piston.

A play operator of total width ``gap`` (half-width r = gap / 2): the piston stays still while the
actuator moves inside the play; once the actuator reaches a side of the play it drags the piston
along, ``y_P = y_A - r`` when pushing forward and ``y_A + r`` when pulling back. After each reversal
the piston therefore rests until the actuator has moved ``gap``; from rest with the piston centred
in the play (the default) until it has moved ``gap / 2``.

On a piecewise-linear actuator displacement the play operator is exactly piecewise linear: each
linear segment adds at most one knot (where the actuator takes up the play), so it is applied as a
transform of the knots (:func:`backlash_knots`), never as an ODE state.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from bayesdamper.core.errors import SettingsError
from bayesdamper.physics.effects.base import Effect, EffectParam

__all__ = ["EFFECT", "backlash_knots", "knots"]

#: Engagement points closer than this to a knot are merged into it [s] (keeps knot times strictly
#: increasing by far more than the kernel's step-size floor).
MERGE_TIME_S = 1e-9

EFFECT = Effect(
    name="backlash",
    description="free play between actuator and piston: after each reversal the piston rests until the "
                "actuator has taken up the gap",
    params=(
        EffectParam("gap_m", "m", 1.0e-7, 1.0e-3, 1.0e-5, True,
                    "total free play between the measured actuator displacement and the piston", slot="gap"),
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


# ----------------------------------------------------------------------------- composed-kernel hooks
def knots(kt: np.ndarray, ky: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The piston knots behind the play ``p[0]`` [m] (knot hook of :mod:`bayesdamper.physics.compose`)."""
    return backlash_knots(kt, ky, float(p[0]))
