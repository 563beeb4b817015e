"""Whole-record identification of one record: start, least-squares point, emcee posterior, stored NetCDF.

The counterpart of :mod:`bayesdamper.inference.stage2` for records that are not triangular tests
(:mod:`bayesdamper.inference.whole`). The same sampler, convergence rules, noise models, summaries and
NetCDF store are used; the unit of work is a record (or a stated window of one) instead of a transient.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesdamper.core.params import DamperConstants
from bayesdamper.inference import posterior as post
from bayesdamper.inference.likelihood import make_noise_model
from bayesdamper.inference.sampling import SamplerSettings, sample_posterior
from bayesdamper.inference.stage2 import (
    N_PREDICTIVE,
    StageTwoSettings,
    TransientResult,
    predictive_band,
    sampling_summary,
    summarise,
    task_seed,
    thinned_chains,
)
from bayesdamper.inference.whole import (
    STATIC_NAMES,
    WholeLogPosterior,
    WholeRecordProblem,
    WholeSpace,
    static_scales,
)
from bayesdamper.physics.effect_vector import pack_effects

#: Grid of (α_V, p_R) from which the least-squares point fit starts (the best of them on eq. (9)).
START_ALPHA_V = (10.0, 40.0, 150.0, 600.0)
START_P_R = (3e4, 1e5, 3e5, 1e6)
#: Samples with |v| above this fraction of the largest |v| enter the quasi-static start of the flow
#: coefficients (away from reversals, where compressibility dominates the force).
QUASI_STATIC_SPEED = 0.3
MODE = "whole-record"
#: Sampler move of whole records: differential evolution plus independence moves from the Laplace
#: approximation (:class:`~bayesdamper.inference.sampling.LaplaceIndependenceMove`). A record that
#: determines every parameter has a nearly Gaussian posterior, so the independence share cuts τ several
#: fold (benchmarks/whole_record.py); the chain stays exact when the approximation is poor.
WHOLE_MOVE = "de+laplace"
#: Steps between convergence checks of whole records: with the independence moves τ is a few steps, so
#: 100 steps are already some 25 τ; checking every 200 (the transients' value, τ of tens of steps) would
#: run up to twice as long as the rules need.
WHOLE_CHECK_EVERY = 100
#: Kernel rtol of the least-squares fit and of the Gauss-Newton covariance (the absolute tolerance scaled
#: alike). The adaptive solver's force moves by about its tolerance when a parameter change shifts its
#: steps; finite differences need that far below their step, or the fit stops near its start on the
#: (α_V, p_R) ridge. A few hundred solves, so the tighter tolerance costs little.
FIT_RTOL = 1e-7
#: Relative finite-difference step of the least-squares Jacobian and of the Gauss-Newton covariance:
#: solver noise 1e-4 of the difference, truncation error of central differences 1e-6.
FD_STEP = 1e-3


@dataclass
class WholeResult(TransientResult):
    """What one record's identification returns: a ``TransientResult`` of the whole window, plus the
    decimated displacement [m] that drove it (for the loop figures)."""

    displacement: np.ndarray


def quasi_static_start(problem: WholeRecordProblem, offset: bool) -> tuple[np.ndarray, float]:
    """Flow coefficients (and force offset [N]) from a non-negative least-squares fit of the force
    against eq. (4) at the quasi-static samples of the record."""
    from scipy.optimize import nnls

    area = problem.damper.piston_area
    v = problem.window.velocity()
    f = problem.force
    off = float(np.median(f)) if offset else 0.0
    fast = np.abs(v) >= QUASI_STATIC_SPEED * np.max(np.abs(v))
    flow4 = np.empty(4)
    scales = static_scales(problem.window, area)
    for k, sel in enumerate((fast & (v > 0), fast & (v < 0))):
        q, dp = area * np.abs(v[sel]), np.abs(f[sel] - off) / area
        if q.size < 3:
            flow4[2 * k:2 * k + 2] = 0.5 * scales[2 * k:2 * k + 2]
            continue
        # columns scaled to the pressure scale, so NNLS sees numbers of order one
        a = np.column_stack([q * scales[2 * k], q * q * scales[2 * k + 1]]) / np.max(dp)
        c, _ = nnls(a, dp / np.max(dp))
        c = np.maximum(c, 1e-3)  # strictly inside the box
        flow4[2 * k:2 * k + 2] = c * scales[2 * k:2 * k + 2]
    return flow4, off


def fine(logpost: WholeLogPosterior) -> WholeLogPosterior:
    """``logpost`` with its kernel at :data:`FIT_RTOL` (absolute tolerance scaled alike)."""
    p = logpost.problem
    if p.rtol <= FIT_RTOL:
        return logpost
    tight = WholeRecordProblem(p.window, p.damper, p.base_effects, FIT_RTOL, p.atol * FIT_RTOL / p.rtol)
    return WholeLogPosterior(tight, logpost.wspace)


def point_fit(logpost: WholeLogPosterior, offset_start: float, flow4: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares optimum of eq. (9) over the model part of θ (bounded, from the best grid start; the
    fit itself at :data:`FIT_RTOL`)."""
    from scipy.optimize import least_squares

    ws = logpost.wspace
    lo, hi = logpost.space.lower[:ws.n_model], logpost.space.upper[:ws.n_model]
    mid = [(lo[k] + hi[k]) / 2 for k in range(6, ws.n_model)]
    if ws.has_offset:
        mid[-1] = offset_start
    best, best_j = None, math.inf
    for a in START_ALPHA_V:
        for p in START_P_R:
            th = np.r_[flow4, math.log(a), math.log(p), mid]
            j = logpost.cost(np.r_[th, [0.0] * (logpost.space.ndim - ws.n_model)])
            if j < best_j:
                best, best_j = th, j
    if best is None:
        raise RuntimeError("no start of the whole-record fit gives a finite solution")
    scale = np.maximum(np.abs(best), 1e-3 * (hi - lo))
    fmag = float(np.sqrt(np.mean(logpost.problem.force**2)))
    pad = np.zeros(logpost.space.ndim - ws.n_model)

    tight = fine(logpost)

    def resid(x):
        r = tight.residual(np.r_[x, pad])
        return r if r is not None else np.full(logpost.problem.force.size, 10 * fmag)

    eps = 1e-9 * (hi - lo)
    x0 = np.clip(best, lo + eps, hi - eps)
    sol = least_squares(resid, x0, bounds=(lo, hi), x_scale=scale, diff_step=FD_STEP, max_nfev=400)
    x = sol.x if logpost.cost(np.r_[sol.x, pad]) <= best_j else best
    return x, logpost.cost(np.r_[x, pad])


def gauss_newton_covariance(logpost: WholeLogPosterior, x: np.ndarray) -> np.ndarray:
    """Covariance of the least-squares optimum ``x`` (model part of θ): σ² (JᵀJ)⁺ with J the Jacobian of the
    residual by central differences and σ² = SSE / (n − p); the pseudo-inverse keeps a ridge (α_V, p_R
    barely constrained by a slow record) from spoiling the flow coefficients' errors. Solves at
    :data:`FIT_RTOL`."""
    logpost = fine(logpost)
    pad = np.zeros(logpost.space.ndim - x.size)
    r0 = logpost.residual(np.r_[x, pad])
    h = FD_STEP * np.maximum(np.abs(x), 1e-3 * (logpost.space.upper[:x.size] - logpost.space.lower[:x.size]))
    jac = np.empty((r0.size, x.size))
    for k in range(x.size):
        e = np.zeros(x.size)
        e[k] = h[k]
        rp, rm = logpost.residual(np.r_[x + e, pad]), logpost.residual(np.r_[x - e, pad])
        jac[:, k] = (rp - rm) / (2 * h[k]) if rp is not None and rm is not None else 0.0
    sigma2 = float(r0 @ r0) / max(r0.size - x.size, 1)
    s = np.maximum(np.abs(x), 1.0)  # columns scaled to O(1) first: the coefficients span 10 decades
    js = jac * s
    return sigma2 * np.linalg.pinv(js.T @ js) * np.outer(s, s)


def proposal_covariance(logpost: WholeLogPosterior, x: np.ndarray, phi: float | None) -> np.ndarray | None:
    """Covariance of the posterior near the least-squares point ``x`` (transformed variables), for the
    sampler's starting balls and independence proposal: the Gauss-Newton covariance inflated by
    (1 + φ)/(1 − φ) for lag-1 correlated residuals, and for φ itself (AR(1) noise) its large-sample variance
    (1 − φ²)/n. None if it is not positive definite (the sampler then uses finite differences)."""
    phi_ = 0.0 if phi is None else float(phi)
    cov = gauss_newton_covariance(logpost, x) * (1 + phi_) / (1 - phi_)
    if phi is not None:
        n = logpost.problem.force.size
        cov = np.block([[cov, np.zeros((x.size, 1))], [np.zeros((1, x.size)), np.array([[(1 - phi_**2) / n]])]])
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return None
    return cov


def identify_record(window, damper: DamperConstants, settings: StageTwoSettings, seed: int,
                    out_nc: Path | None = None, provenance: dict | None = None, progress=None, *,
                    effects: tuple[str, ...] = (), offset: bool = False) -> WholeResult:
    """Point fit and joint posterior of every parameter of one record window."""
    t0 = time.perf_counter()
    noise = make_noise_model(settings.noise_model)
    base = pack_effects({e: {} for e in effects})
    problem = WholeRecordProblem(window, damper, base)
    scales = static_scales(window, damper.piston_area)
    wspace = WholeSpace.build(scales, float(np.max(np.abs(window.force))), effects=tuple(effects), offset=offset,
                              noise_params=noise.params, alpha_v_bounds=settings.alpha_v_bounds,
                              p_r_bounds=settings.p_r_bounds)
    space = wspace.space
    logpost = WholeLogPosterior(problem, wspace)
    flow4, off0 = quasi_static_start(problem, offset)
    x, j_ls = point_fit(logpost, off0, flow4)
    start = list(x)
    phi0 = None
    if wspace.has_phi:
        r = logpost.residual(np.r_[x, 0.0])
        phi0 = float(np.clip(r[1:] @ r[:-1] / (r @ r), space.lower[-1] + 0.01, space.upper[-1] - 0.01))
        start.append(phi0)
    start = space.clip_inside(np.array(start), margin=1e-4)
    cov = proposal_covariance(logpost, x, phi0)
    seed_t = task_seed(seed, window.id)
    s = settings.sampler
    sampler = SamplerSettings(**{**s.as_dict(), "n_walkers": max(s.n_walkers, 2 * space.ndim + 2),
                                 "move": WHOLE_MOVE, "check_every": min(s.check_every, WHOLE_CHECK_EVERY)})
    res = sample_posterior(logpost, start, space.lower, space.upper, sampler, seed_t, progress, scale=cov)
    flat = res.flat()
    phys = space.to_physical(flat)
    med_t = np.median(flat, axis=0)
    f_med, ok = logpost.simulate(med_t)
    vel = window.velocity()
    entry = {
        "id": window.id, "test": window.test, "kind": window.kind, "mode": MODE,
        "description": window.description, "direction": 0,
        "velocity_m_s": float(np.quantile(np.abs(vel), 0.99)), "t_start_s": float(window.time[0]),
        "window": window.as_dict(), "effects": list(effects), "offset": bool(offset),
        "J": float(np.sqrt(np.sum((f_med - problem.force) ** 2) / np.sum(problem.force**2))) if ok else math.inf,
        "ls": {**{n: float(v) for n, v in zip(space.names, space.to_physical(np.r_[x, [0.0] * (space.ndim - x.size)]),
                                                strict=True) if n != "phi"}, "J": float(j_ls)},
        **sampling_summary(res, space.names, phys),
        "n_walkers": sampler.n_walkers, "move": sampler.move,
        "prior_box": {n: [float(a), float(b)] for n, a, b in
                      zip(space.names, space.to_physical(space.lower), space.to_physical(space.upper), strict=True)},
        "seed": seed_t,
    }
    for i, n in enumerate(space.names):
        entry[n] = summarise(phys[:, i], settings.credible_mass)
    phys_ch, lp, thin = thinned_chains(res, space)
    rng = np.random.default_rng(seed_t)
    draws = flat[rng.choice(len(flat), size=min(N_PREDICTIVE, len(flat)), replace=False)]
    sims = [f for f, good in (logpost.simulate(th) for th in draws) if good]
    band = predictive_band(sims, settings.credible_mass, problem.time.size)
    ls_force, _ = logpost.simulate(np.r_[x, [0.0] * (space.ndim - x.size)])
    entry["wall_s"] = time.perf_counter() - t0
    if out_nc is not None:
        attrs = dict(provenance or {})
        attrs.update({"segment_id": window.id, "seed": seed_t, "run_seed": seed, "mode": MODE,
                      "settings": settings.as_dict(), "entry": entry, "thin": thin,
                      "static_names": list(STATIC_NAMES),
                      "chains_are": f"walkers, ensemble-major ({sampler.n_ensembles} ensembles x "
                                    f"{sampler.n_walkers} walkers)"})
        idata = post.to_inference_data(phys_ch, space.names, lp, {"force_N": problem.force},
                                       {"time_s": problem.time, "dp0_Pa": np.array([0.0]),
                                        "band_N": band, "ls_force_N": ls_force,
                                        "displacement_m": np.asarray(window.displacement)}, attrs)
        post.write_netcdf(idata, out_nc)
    return WholeResult(entry, space.names, phys_ch, np.array(problem.time), np.array(problem.force), band,
                       ls_force, np.array(window.displacement))
