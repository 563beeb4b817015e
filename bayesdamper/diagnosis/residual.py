"""The residual of a calibrated model: plateau noise, the structure test and the residual's features.

Noise level
    Estimated from the data alone: on every plateau the force is steady, so after removing a straight
    line the remainder is measurement noise. The pooled standard deviation is ``noise_N`` and the
    pooled lag-1 autocorrelation its colour.

Is a residual structured?  (stated test)
    The residual of a transient and the detrended plateau noise are both passed through the same
    low-pass filter (a moving average over ``SMOOTH_S``); under "residual = noise" the ratio of their
    mean squares follows an F distribution with the effective degrees of freedom of the filtered
    signals (N_eff = N (1 - ρ) / (1 + ρ) with ρ the filtered lag-1 autocorrelation). A transient is
    structured when p < ``STRUCTURE_ALPHA``.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

#: Largest lag-1 autocorrelation used in the effective sample size (keeps N_eff >= N / 400).
MAX_RHO = 0.995
#: Window of the moving-average low-pass used by the structure test [s] (keeps < ~5 Hz content).
SMOOTH_S = 0.1
#: Significance level of the structure test.
STRUCTURE_ALPHA = 1e-3


def _detrend(t: np.ndarray, f: np.ndarray) -> np.ndarray:
    a = np.polyfit(t - t.mean(), f, 1)
    return f - np.polyval(a, t - t.mean())


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    k = np.ones(n) / n
    return np.convolve(x, k, mode="valid")


def _lag1(x: np.ndarray) -> float:
    x = x - x.mean()
    d = x @ x
    return float(np.clip(x[1:] @ x[:-1] / d, -0.99, MAX_RHO)) if d > 0 else 0.0


def plateau_noise(segs) -> dict:
    """Measurement noise estimated from the plateaus of every record whose force had settled (all plateaus where
    none had: :func:`bayesdamper.inference.plateau_noise.noise_plateaus`).

    Returns
    -------
    dict
        ``sigma_N`` (pooled sd [N]), ``rho`` (pooled lag-1 autocorrelation [-]), ``n`` (samples) and
        ``smoothed_ms`` (mean square of the low-passed noise [N^2]) with its effective dof.
    """
    from bayesdamper.inference.plateau_noise import noise_plateaus

    res, smooth, rhos, n_eff_s = [], [], [], 0.0
    for rec, p in noise_plateaus(segs):
        t, f = rec.time, rec.force
        n_avg = max(1, int(round(SMOOTH_S * rec.sample_rate)))
        m = (t >= p.t_start) & (t <= p.t_end)
        if m.sum() < 3 * n_avg:
            continue
        r = _detrend(t[m], f[m])
        res.append(r)
        rhos.append(_lag1(r))
        sm = _moving_average(r, n_avg)
        smooth.append(sm)
        rho_s = _lag1(sm)
        n_eff_s += sm.size * (1 - rho_s) / (1 + rho_s)
    allr = np.concatenate(res)
    alls = np.concatenate(smooth)
    return {"sigma_N": float(np.std(allr)), "rho": float(np.median(rhos)), "n": int(allr.size),
            "smoothed_ms": float(np.mean(alls**2)), "smoothed_dof": float(max(n_eff_s, 1.0))}


def structure_test(residual: np.ndarray, sample_rate: float, noise: dict) -> dict:
    """F test of a transient's low-passed residual against the low-passed plateau noise."""
    n_avg = max(1, int(round(SMOOTH_S * sample_rate)))
    sm = _moving_average(residual - 0.0, n_avg)
    rho = _lag1(sm)
    dof1 = max(sm.size * (1 - rho) / (1 + rho), 1.0)
    ratio = float(np.mean(sm**2) / noise["smoothed_ms"])
    p = float(stats.f.sf(ratio, dof1, noise["smoothed_dof"]))
    return {"ms_ratio": ratio, "p_value": p, "structured": bool(p < STRUCTURE_ALPHA), "dof": dof1}


def describe_residual(time_since_step: np.ndarray, residual: np.ndarray, force: np.ndarray,
                      sample_rate: float) -> dict:
    """Where and how a transient's residual sits: timing, frequency, relation to the force level."""
    r2 = residual**2
    tot = float(r2.sum()) or 1.0
    cum = np.cumsum(r2) / tot
    spec = np.abs(np.fft.rfft(residual - residual.mean())) ** 2
    freq = np.fft.rfftfreq(residual.size, 1.0 / sample_rate)
    band = freq > 0.2
    f_peak = float(freq[band][np.argmax(spec[band])]) if band.any() else 0.0
    level = np.abs(force) / max(np.max(np.abs(force)), 1e-12)
    return {
        "rms_N": float(np.sqrt(np.mean(r2))),
        "t_centroid_s": float((time_since_step * r2).sum() / tot),
        "t_50_percent_s": float(time_since_step[np.searchsorted(cum, 0.5)]),
        "early_fraction": float(r2[time_since_step < 0.5].sum() / tot),
        "peak_frequency_Hz": f_peak,
        "corr_with_force_level": float(np.corrcoef(np.abs(residual), level)[0, 1]) if residual.std() > 0 else 0.0,
        "lag1": _lag1(residual),
    }


def summarise_structure(rows: list[dict]) -> dict:
    """How the residual follows the quantities a physical effect would follow (across transients)."""
    v = np.array([r["velocity_m_s"] for r in rows])
    rms = np.array([r["rms_N"] for r in rows])
    d = np.array([r["direction"] for r in rows])
    kind = np.array([r["kind"] for r in rows])
    out = {
        "n_structured": int(sum(r["structured"] for r in rows)),
        "n_transients": len(rows),
        "rms_vs_speed_log_slope": float(np.polyfit(np.log(v), np.log(np.maximum(rms, 1e-9)), 1)[0]),
        "rms_by_direction_N": {str(k): float(np.sqrt(np.mean(rms[d == k] ** 2))) for k in (1, -1) if np.any(d == k)},
        "rms_by_kind_N": {k: float(np.sqrt(np.mean(rms[kind == k] ** 2))) for k in ("initial", "reversal")
                          if np.any(kind == k)},
        "median_t_centroid_s": float(np.median([r["t_centroid_s"] for r in rows])),
        "median_peak_frequency_Hz": float(np.median([r["peak_frequency_Hz"] for r in rows])),
        "median_early_fraction": float(np.median([r["early_fraction"] for r in rows])),
    }
    return out
