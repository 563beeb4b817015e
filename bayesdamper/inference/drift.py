"""Drift of identified parameters with piston speed, per-transient uncertainty propagated.

Trend model (stated in the README): for transient k at piston speed v_k with posterior mean m_k and
posterior standard deviation s_k of a parameter θ,

    m_k ~ N(a + b v_k, s_k^2 + σ_int^2),

a straight line in speed whose residual scatter is each transient's own posterior uncertainty plus an
intrinsic scatter σ_int shared by all transients (for what the line does not explain: direction,
unmodelled effects). Flat priors on a and b, a scale-invariant prior on σ_int over a grid spanning
1e-4 to 10 times the spread of the m_k (plus σ_int = 0). For fixed σ_int the posterior of (a, b) is
Gaussian (weighted least squares); σ_int is integrated out on the grid with its marginal likelihood,
so the posterior of the slope b is a Gaussian mixture, sampled here. "Credibly non-zero" means the
equal-tailed credible interval of b excludes 0.
"""

from __future__ import annotations

import numpy as np

#: Grid points for the intrinsic scatter σ_int.
N_SCATTER_GRID = 200
#: Draws taken from the slope's posterior mixture to form its interval.
N_SLOPE_DRAWS = 20000


def fit_drift(speed: np.ndarray, mean: np.ndarray, sd: np.ndarray, credible_mass: float = 0.9,
              seed: int = 0) -> dict:
    """Posterior of the slope of a parameter against piston speed (:func:`fit_trend` with ``x`` the speed [m/s];
    the slope is returned as ``slope_per_m_s``)."""
    res = fit_trend(speed, mean, sd, credible_mass, seed)
    res["slope_per_m_s"] = res.pop("slope")
    return res


def fit_trend(x: np.ndarray, mean: np.ndarray, sd: np.ndarray, credible_mass: float = 0.9,
              seed: int = 0) -> dict:
    """Posterior of the slope of a parameter against a covariate x (the trend model of the module docstring with
    x in place of the speed).

    Parameters
    ----------
    x : ndarray, shape (n,)
        The covariate of each estimate (piston speed [m/s], time [s], temperature [°C], ...).
    mean, sd : ndarray, shape (n,)
        Posterior mean and standard deviation of the parameter for each transient.
    credible_mass : float
        Mass of the equal-tailed interval.
    seed : int
        Seed of the mixture draws.

    Returns
    -------
    dict
        ``{"slope": {"median", "lo", "hi"}, "intercept": {...}, "credible_nonzero": bool,
        "intrinsic_scatter": float}``; slope in parameter units per unit of x.
    """
    v = np.asarray(x, float)
    m = np.asarray(mean, float)
    s = np.asarray(sd, float)
    if v.size < 3 or np.ptp(v) == 0:
        raise ValueError("a trend needs at least three estimates at two or more values of its covariate")
    x = np.column_stack([np.ones_like(v), v - v.mean()])
    spread = max(float(np.std(m)), float(np.median(s)), 1e-300)
    grid = np.concatenate([[0.0], np.geomspace(1e-4 * spread, 10 * spread, N_SCATTER_GRID)])
    logw, means, covs = [], [], []
    for tau in grid:
        w = 1.0 / (s * s + tau * tau)
        a = x.T @ (w[:, None] * x)
        cov = np.linalg.inv(a)
        beta = cov @ (x.T @ (w * m))
        r = m - x @ beta
        # log marginal likelihood of σ_int with (a, b) integrated out under flat priors
        ll = 0.5 * np.sum(np.log(w)) - 0.5 * np.sum(w * r * r) - 0.5 * np.linalg.slogdet(a)[1]
        # p(σ_int) ∝ 1/σ_int gives every cell of the log-spaced grid the same prior mass;
        # σ_int = 0 counts as one more such cell.
        logw.append(ll)
        means.append(beta)
        covs.append(cov)
    logw = np.array(logw)
    p = np.exp(logw - logw.max())
    p /= p.sum()
    rng = np.random.default_rng(seed)
    idx = rng.choice(grid.size, size=N_SLOPE_DRAWS, p=p)
    means = np.array(means)
    covs = np.array(covs)
    draws = means[idx] + np.einsum("nij,nj->ni", np.linalg.cholesky(covs[idx]),
                                   rng.standard_normal((N_SLOPE_DRAWS, 2)))
    lo_q, hi_q = 0.5 - credible_mass / 2, 0.5 + credible_mass / 2
    slope = draws[:, 1]
    intercept = draws[:, 0] - draws[:, 1] * v.mean()

    def summ(d):
        return {"median": float(np.median(d)), "lo": float(np.quantile(d, lo_q)),
                "hi": float(np.quantile(d, hi_q))}

    sl = summ(slope)
    return {"slope": sl, "intercept": summ(intercept),
            "credible_nonzero": bool(sl["lo"] > 0 or sl["hi"] < 0),
            "intrinsic_scatter": float(np.sum(p * grid))}


def drift_summary(entries: list[dict], credible_mass: float, seed: int) -> dict:
    """Slope of α_V and p_R against piston speed over the converged transients not piled against a prior bound
    (and per direction)."""
    out = {}
    # converged posteriors that the data determine: one piled against a prior bound (rig-A's slow reversals, whose
    # α_V-p_R ridge runs into the 10 MPa bound) has a mean set by the prior box, not by the test
    # (each choice only if it leaves the three transients at two speeds a trend needs)
    choices = ([e for e in entries if e["converged"] and not (e.get("shape") or {}).get("at_prior_bound")],
               [e for e in entries if e["converged"]], entries)
    ok = next(c for c in choices if len(c) >= 3 and len({e["velocity_m_s"] for e in c}) >= 2 or c is entries)
    for name in ("alpha_V", "p_R_Pa"):
        v = np.array([e["velocity_m_s"] for e in ok])
        m = np.array([e["posterior_mean"][name] for e in ok])
        s = np.array([e["posterior_sd"][name] for e in ok])
        res = fit_drift(v, m, s, credible_mass, seed)
        res["by_direction"] = {}
        for d in (1, -1):
            sel = np.array([e["direction"] == d for e in ok])
            if sel.sum() >= 3 and np.ptp(v[sel]) > 0:
                res["by_direction"][str(d)] = fit_drift(v[sel], m[sel], s[sel], credible_mass, seed)
        res["n_transients"] = int(len(ok))
        out[name] = res
    return out


#: Fewest converged windows of one record for a trend within it.
MIN_RECORD_WINDOWS = 3


def record_drift(entries: list[dict], covariates: dict[str, np.ndarray] | None = None, credible_mass: float = 0.9,
                 seed: int = 0) -> dict:
    """Slow drift within long records: for every record with at least :data:`MIN_RECORD_WINDOWS` converged
    windows of cycles, the trend of each sampled parameter (α_V, p_R, the flow coefficients) against the windows'
    mid-times [s] and, where ``covariates`` maps a window id to its mean temperature [°C], against it too.

    The windows of one record share its speed, so a trend among them is the record's own drift (the fluid warming
    over minutes, say), not the speed's. Each trend is :func:`fit_trend`'s, reported with the change it makes over
    the record relative to the parameter's mean (``change``, a fraction).
    """
    out = {}
    by_test: dict[str, list[dict]] = {}
    for e in entries:
        if e.get("kind") == "cycles" and e.get("converged"):
            by_test.setdefault(str(e.get("test") or e["id"]), []).append(e)
    for test, es in by_test.items():
        if len(es) < MIN_RECORD_WINDOWS:
            continue
        t_mid = np.array([0.5 * (e["t_start_s"] + e["window"]["t_end_s"]) for e in es])
        axes = {"time_s": t_mid}
        temp = [covariates.get(e["id"]) for e in es] if covariates else []
        if temp and all(v is not None for v in temp) and np.ptp(temp) > 0:
            axes["temperature_C"] = np.array(temp, float)
        names = [n for n in es[0]["posterior_mean"] if all(n in e["posterior_mean"] for e in es)]
        rec = {"n_windows": len(es), "t_mid_s": t_mid.tolist(), "trends": {}}
        if "temperature_C" in axes:
            rec["temperature_C"] = axes["temperature_C"].tolist()
        for axis, x in axes.items():
            rec["trends"][axis] = {}
            for name in names:
                m = np.array([e["posterior_mean"][name] for e in es])
                s = np.array([e["posterior_sd"][name] for e in es])
                res = fit_trend(x, m, s, credible_mass, seed)
                scale = abs(float(np.mean(m))) or 1.0
                res["change"] = {k: float(v * np.ptp(x) / scale) for k, v in res["slope"].items()}
                rec["trends"][axis][name] = res
        out[test] = rec
    return out
