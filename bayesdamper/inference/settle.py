"""Which plateaus of a triangular test are points of eq. (4), and at what force.

A plateau is the last 30 % of a ramp. Its mean is a point of the static characteristic only where the force has
settled; where it still approaches the steady force (soft gas after a start from rest, a compliant mount in
series), the settled force is extrapolated from the approach or the plateau is left out of stage 1
(:func:`settled_plateaus`).
"""

from __future__ import annotations

import math

import numpy as np

from bayesdamper.inference.noise import rest_noise
from bayesdamper.inference.plateau_noise import PlateauNoise

__all__ = ["APPROACH_TAU_MAX", "MIN_PLATEAUS_PER_DIRECTION", "SETTLED_T", "approach_fit", "plateau_trend_t",
           "settled_plateaus"]


#: |t| of a plateau's linear trend above which it is not settled (two-sided p = 0.0027 for a settled plateau:
#: over 18 plateaus a 5 % chance of losing one good plateau, which costs only its data).
SETTLED_T = 3.0
#: Plateaus kept per direction whatever their trend (stage 1 needs three for one residual degree of freedom).
MIN_PLATEAUS_PER_DIRECTION = 3
#: Longest time constant of a plateau's approach to its settled force, in plateau lengths, from which the settled
#: force is extrapolated (:func:`approach_fit`). At τ = 1 a third of the approach's amplitude is left at the
#: plateau's end and the curvature over the plateau (1 − e^-1 of the slope lost) still pins the end; slower
#: approaches are nearly lines there, and their plateau is left out.
APPROACH_TAU_MAX = 1.0


def plateau_trend_t(t: np.ndarray, f: np.ndarray, noise: PlateauNoise) -> float:
    """t-statistic of the least-squares slope of force ``f`` [N] over times ``t`` [s], its standard error that of
    AR(1) noise (large-sample: the white-noise error × sqrt((1 + φ)/(1 − φ)))."""
    x = t - t.mean()
    sxx = float(x @ x)
    if sxx <= 0.0:
        return 0.0
    slope = float(x @ (f - f.mean())) / sxx
    phi = noise.phi
    se = noise.sigma * math.sqrt((1.0 + phi) / (1.0 - phi) / sxx)
    return slope / se if se > 0 else 0.0


def approach_fit(t: np.ndarray, f: np.ndarray) -> tuple[float, float, np.ndarray] | None:
    """The settled force of a plateau whose force still approaches it: least squares of
    F(t) = F_inf + b exp(-(t - t_0) / τ) over the plateau's times ``t`` [s] and forces ``f`` [N], τ profiled on a
    log grid from 1/100 of the plateau's length to :data:`APPROACH_TAU_MAX` of it, then refined between the grid's
    neighbours. Returns (F_inf [N], τ [s], the residual [N]), or None when the best τ is the longest: an approach
    no faster than that is close to a line within the plateau and does not say where it ends."""
    from scipy.optimize import minimize_scalar

    x = np.asarray(t, float) - float(t[0])
    f = np.asarray(f, float)
    span = float(x[-1]) if x.size else 0.0
    if x.size < 10 or span <= 0.0:
        return None

    def fit(log_tau: float) -> tuple[float, float, np.ndarray]:
        design = np.column_stack([np.ones_like(x), np.exp(-x / (span * math.exp(log_tau)))])
        coef, *_ = np.linalg.lstsq(design, f, rcond=None)
        r = f - design @ coef
        return float(r @ r), float(coef[0]), r

    grid = np.linspace(math.log(0.01), math.log(APPROACH_TAU_MAX), 41)
    sse = [fit(g)[0] for g in grid]
    i = int(np.argmin(sse))
    if i == grid.size - 1:
        return None
    lo, hi = grid[max(i - 1, 0)], grid[i + 1]
    best = minimize_scalar(lambda g: fit(g)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-3})
    g = float(best.x) if best.fun <= sse[i] else float(grid[i])
    _, settled, resid = fit(g)
    return settled, span * math.exp(g), resid


def settled_plateaus(segmented_records) -> tuple[list, list[tuple[str, int, float]]]:
    """Give each plateau its settled force: its mean where the force has settled, else the value its approach
    extrapolates to, else leave it out.

    A plateau is the last 30 % of a ramp; after a start from rest with soft gas (low α_V, low p_R), or with a
    compliant mount in series, eq. (7)'s approach to the steady force can outlast it (measured on independent
    two-state data with a 2e7 N/m mount: plateau means up to 2.5 kN below the steady force at 2 mm/s, and the
    approach's time constant 0.5-1.3 plateau lengths). Its mean is then not a point of eq. (4). The test: the
    linear trend of the plateau's force, its standard error from the AR(1) noise of all plateaus each about its
    own line (:func:`bayesdamper.inference.noise.rest_noise`: about their means, the drifts would pass for noise
    with φ near 1, whose wide standard error hides them); |t| > :data:`SETTLED_T` says the force still moves. Such
    a plateau keeps the settled force of an exponential approach fitted to it (:func:`approach_fit`, its
    ``approach_tau`` set) when that approach pins it: a time constant of at most :data:`APPROACH_TAU_MAX` plateau
    lengths and no trend left in its residual (|t| ≤ :data:`SETTLED_T` again; a valve's ringing or a second,
    slower mode leaves one). Otherwise it is left out, the largest |t| first, keeping at least
    :data:`MIN_PLATEAUS_PER_DIRECTION` per direction.

    Returns
    -------
    records : list of SegmentedRecord
        The records with their settled forces, the plateaus left out moved from ``plateaus`` to ``unsettled``.
    dropped : list of (test, plateau index, t)
        The plateaus left out.

    Raises
    ------
    ValueError
        No plateau has any scatter.
    """
    from dataclasses import replace

    segmented_records = list(segmented_records)
    samples = {}
    for s in segmented_records:
        t, f = s.record.time, s.record.force
        for p in s.plateaus:
            sel = (t >= p.t_start) & (t <= p.t_end)
            samples[(p.test, p.index)] = (t[sel], f[sel])
    noise = rest_noise([f for _, f in samples.values()], detrend="linear")
    if noise is None:
        raise ValueError("no plateau stretch of at least 5 samples with any scatter")
    scored = [(abs(plateau_trend_t(*samples[(p.test, p.index)], noise)), p)
              for s in segmented_records for p in s.plateaus]
    left = {d: sum(1 for _, p in scored if p.direction == d) for d in (1, -1)}
    drop, settled = set(), {}
    for tval, p in sorted(scored, key=lambda x: -x[0]):
        if tval <= SETTLED_T:
            break
        t, f = samples[(p.test, p.index)]
        approach = approach_fit(t, f)
        if approach is not None and abs(plateau_trend_t(t, approach[2], noise)) <= SETTLED_T:
            area = p.flow_rate / p.velocity
            settled[(p.test, p.index)] = replace(
                p, pressure_drop=p.pressure_drop + p.direction * (approach[0] - float(f.mean())) / area,
                approach_tau=approach[1])
        elif left[p.direction] > MIN_PLATEAUS_PER_DIRECTION:
            drop.add((p.test, p.index))
            left[p.direction] -= 1
    out = [replace(s, plateaus=tuple(settled.get((p.test, p.index), p) for p in s.plateaus
                                     if (p.test, p.index) not in drop),
                   unsettled=tuple(p for p in s.plateaus if (p.test, p.index) in drop))
           for s in segmented_records]
    dropped = [(p.test, p.index, float(tv)) for tv, p in scored if (p.test, p.index) in drop]
    return out, dropped
