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
    """Posterior of the slope of a parameter against piston speed.

    Parameters
    ----------
    speed : ndarray, shape (n,)
        Piston speed |v_k| [m/s].
    mean, sd : ndarray, shape (n,)
        Posterior mean and standard deviation of the parameter for each transient.
    credible_mass : float
        Mass of the equal-tailed interval.
    seed : int
        Seed of the mixture draws.

    Returns
    -------
    dict
        ``{"slope_per_m_s": {"median", "lo", "hi"}, "intercept": {...}, "credible_nonzero": bool,
        "intrinsic_scatter": float}``; slope in parameter units per (m/s).
    """
    v = np.asarray(speed, float)
    m = np.asarray(mean, float)
    s = np.asarray(sd, float)
    if v.size < 3 or np.ptp(v) == 0:
        raise ValueError("a drift trend needs at least three transients at two or more speeds")
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
    return {"slope_per_m_s": sl, "intercept": summ(intercept),
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
