"""What every window's posterior shares: the settings, the seeds, the summaries and shape report, the stored
result, and the conditional posterior of (α_V, p_R) (the paper's stage 2).

Windows are independent tasks; :func:`bayesdamper.inference.identify.identify_window` is the unit of work sent to
worker processes. Each task derives its seed from the run seed and the window id, so results do not depend
on the number of workers or the order tasks finish in.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.inference import posterior as post
from bayesdamper.inference.likelihood import LogPosterior, cost_j, make_noise_model
from bayesdamper.inference.pointfit import fit_point
from bayesdamper.inference.priors import ALPHA_V_BOUNDS, P_R_BOUNDS, ParameterSpace
from bayesdamper.inference.problem import WindowProblem
from bayesdamper.inference.sampling import SamplerSettings, sample_posterior

#: Posterior draws stored per chain are thinned to about this many per τ (half a τ apart).
THIN_PER_TAU = 2
#: Posterior draws pushed through the model for the predictive bands of Figure 8.
N_PREDICTIVE = 200
#: Draws of the stage-1 flow coefficients used to measure how much their uncertainty moves (α_V, p_R).
N_STATIC_DRAWS = 8
#: Ratio (sd of the optimum under static draws) / (posterior sd) below which the stage-1 uncertainty is
#: negligible: it would widen the interval by less than sqrt(1 + 0.3^2) - 1 = 4.4 %.
STATIC_NEGLIGIBLE_RATIO = 0.3


def static_sensitivity(problem: WindowProblem, space: ParameterSpace, static_draws: np.ndarray,
                       start: tuple[float, float], posterior_sd_log: np.ndarray) -> dict:
    """How far the eq. (9) optimum moves when the flow coefficients are redrawn from stage 1.

    Each row of ``static_draws`` ([C_L12, C_Q12, C_L21, C_Q21]) replaces the point estimate, the
    optimum is re-polished by Nelder-Mead from ``start``, and the spread of the optima (in log α_V and
    log p_R) is compared with the posterior sd of the same quantities.
    """
    from bayesdamper.core.params import FlowCoefficients

    optima = []
    for c in static_draws:
        try:
            flow = FlowCoefficients(*np.abs(c))
        except Exception:  # a draw with a zero pair: skip it
            continue
        pf = fit_point(problem.with_flow(flow), space, starts=(start,))
        optima.append(np.log([pf.alpha_v, pf.p_r]))
    if len(optima) < 2:
        return {"ratio": {"alpha_V": float("nan"), "p_R_Pa": float("nan")}, "negligible": False}
    ratio = np.std(np.array(optima), axis=0, ddof=1) / np.maximum(posterior_sd_log, 1e-300)
    return {"ratio": {"alpha_V": float(ratio[0]), "p_R_Pa": float(ratio[1])},
            "negligible": bool(np.all(ratio < STATIC_NEGLIGIBLE_RATIO))}


@dataclass
class WindowResult:
    """What one transient's stage 2 returns to the driver (plain arrays, picklable).

    Attributes
    ----------
    entry : dict
        Its ``summary.json`` entry.
    names : tuple of str
        Parameter names of the last axis of ``chains``.
    chains : ndarray, shape (n_chains, n_draws, ndim)
        Thinned posterior draws in physical units; chains are walkers, ensemble-major.
    time, force : ndarray, shape (n_times,)
        Window sample times [s] and measured force [N].
    band : ndarray, shape (3, n_times)
        Lower, median and upper quantile of the posterior predictive model force [N]
        (the credible mass of the settings).
    ls_force : ndarray, shape (n_times,)
        Force of the Nelder-Mead point estimate [N].
    """

    entry: dict
    names: tuple
    chains: np.ndarray
    time: np.ndarray
    force: np.ndarray
    band: np.ndarray
    ls_force: np.ndarray


@dataclass(frozen=True)
class StageTwoSettings:
    """Everything that changes a stage-2 result (stored with it; compared on resume)."""

    credible_mass: float = 0.9
    noise_model: str = "plateau"
    #: Sample the step's Δp and the flow coefficients with α_V and p_R (:mod:`~bayesdamper.inference.joint`);
    #: False: condition on their estimates (the paper's stage 2, kept for comparison).
    propagate: bool = True
    #: How the window couples to Δp0 and stage 1 when they are propagated: ``cut`` (their own data only,
    #: :mod:`~bayesdamper.inference.cut`) or ``joint`` (sampled with α_V and p_R, the window informs them).
    coupling: str = "cut"
    alpha_v_bounds: tuple[float, float] = ALPHA_V_BOUNDS
    p_r_bounds: tuple[float, float] = P_R_BOUNDS
    sampler: SamplerSettings = field(default_factory=SamplerSettings)

    def space(self) -> ParameterSpace:
        return ParameterSpace.default(make_noise_model(self.noise_model).params, self.alpha_v_bounds,
                                      self.p_r_bounds)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["sampler"] = self.sampler.as_dict()
        return d


def task_seed(seed: int, segment_id: str) -> int:
    """Seed of one transient's sampler, from the run seed and the segment id."""
    return int(np.random.SeedSequence([seed, zlib.crc32(segment_id.encode())]).generate_state(1)[0])


def summarise(samples: np.ndarray, credible_mass: float) -> dict[str, float]:
    """Median and equal-tailed interval of ``credible_mass`` of 1-D samples."""
    lo, hi = np.quantile(samples, [0.5 - credible_mass / 2, 0.5 + credible_mass / 2])
    return {"median": float(np.median(samples)), "lo": float(lo), "hi": float(hi)}


def sampling_summary(res, names: tuple[str, ...], phys: np.ndarray) -> dict:
    """The convergence diagnostics and posterior moments every stored entry carries (``res``: a
    :class:`~bayesdamper.inference.sampling.SamplingResult`; ``phys``: its flat draws in physical units)."""
    return {
        "rhat_max": float(np.max(res.rhat)), "ess_bulk_min": float(np.min(res.ess_bulk)),
        "converged": bool(res.converged), "convergence": res.reason,
        "tau": {n: float(t) for n, t in zip(names, res.tau, strict=True)},
        "n_steps": res.n_steps, "n_evaluations": res.n_evaluations, "acceptance": res.acceptance,
        "pilot_after_steps": res.pilot_after,
        "posterior_mean": {n: float(m) for n, m in zip(names, phys.mean(0), strict=True)},
        "posterior_sd": {n: float(s) for n, s in zip(names, phys.std(0), strict=True)},
    }


def thinned_chains(res, space: ParameterSpace) -> tuple[np.ndarray, np.ndarray, int]:
    """The stored chains: every walker a chain (ensemble-major), thinned to about ``THIN_PER_TAU`` draws per
    τ, in physical units, shape (chains, draws, ndim); their log-probabilities (chains, draws); the thinning."""
    tau_min = float(np.min(res.tau))
    thin = max(1, int(tau_min / THIN_PER_TAU)) if np.isfinite(tau_min) else 1
    ch = res.chain[:, ::thin]  # (E, T, W, D)
    e, t, w, d = ch.shape
    phys_ch = space.to_physical(ch.transpose(0, 2, 1, 3).reshape(e * w, t, d))
    lp = res.log_prob[:, ::thin].transpose(0, 2, 1).reshape(e * w, t)
    return phys_ch, lp, thin


def predictive_band(sims: list, credible_mass: float, n_times: int) -> np.ndarray:
    """Lower, median and upper quantile of simulated forces, shape (3, n_times) (NaN if none succeeded)."""
    q = [0.5 - credible_mass / 2, 0.5, 0.5 + credible_mass / 2]
    return np.quantile(np.array(sims), q, axis=0) if sims else np.full((3, n_times), np.nan)


#: |correlation| of (log α_V, log p_R) above which the posterior is reported as a ridge.
RIDGE_CORRELATION = 0.9
#: Ashman's D between the two parts of the best hard split along the principal axis above which the
#: posterior is called bimodal. A hard split of one Gaussian at its median already gives D = 2.65,
#: so the usual mixture threshold D > 2 is raised to 3.5 for hard splits.
BIMODAL_D = 3.5
#: Fraction of the prior box (in transformed units) within which a sample counts as "at a bound".
BOUND_FRACTION = 0.01


def shape_report(samples: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> dict:
    """Shape of a posterior in transformed variables: ridge, bimodality and prior-bound pile-up.

    Parameters
    ----------
    samples : ndarray, shape (n, ndim)
        Samples of (log α_V, log p_R, ...).
    lower, upper : ndarray, shape (ndim,)
        Prior box.
    """
    x = samples[:, :2]
    c = float(np.corrcoef(x.T)[0, 1]) if np.all(np.std(x, axis=0) > 0) else 0.0
    z = np.sort((x - x.mean(0)) @ np.linalg.eigh(np.cov(x.T))[1][:, -1])
    best = 0.0
    for cut in np.linspace(0.1, 0.9, 17):  # 2-means along the principal axis, clusters >= 10 %
        k = int(cut * z.size)
        a, b = z[:k], z[k:]
        sd = np.sqrt((a.var() + b.var()) / 2)
        if sd > 0:
            best = max(best, abs(a.mean() - b.mean()) / sd)
    span = upper - lower
    at_lo = np.mean(samples < lower + BOUND_FRACTION * span, axis=0)
    at_hi = np.mean(samples > upper - BOUND_FRACTION * span, axis=0)
    return {"log_correlation": c, "ridge": bool(abs(c) > RIDGE_CORRELATION),
            "multimodal": bool(best > BIMODAL_D), "ashman_d": float(best),
            "at_prior_bound": bool(np.any(at_lo[:2] > 0.05) or np.any(at_hi[:2] > 0.05))}


def identify_conditional(transient, damper: DamperConstants, flow: FlowCoefficients,
                         settings: StageTwoSettings, seed: int, out_nc: Path | None = None,
                         provenance: dict | None = None, progress=None,
                         static_draws: np.ndarray | None = None, problem=None) -> WindowResult:
    """Point fit and posterior of (α_V, p_R) of one window conditional on ``flow`` and the start's Δp (the
    paper's stage 2; :func:`bayesdamper.inference.identify.identify_window` is the entry point).

    ``problem`` replaces the default eq. (7) :class:`WindowProblem` (e.g. a model with effects; it
    needs ``simulate_force(alpha_v, p_r)``, ``force``, ``time`` and ``dp0``).

    If ``out_nc`` is given, the posterior is written there (atomically) with its provenance.
    """
    t0 = time.perf_counter()
    problem = problem if problem is not None else WindowProblem.from_window(transient, damper, flow)
    space = settings.space()
    noise = make_noise_model(settings.noise_model)
    logpost = LogPosterior(problem, noise, space)
    pf = fit_point(problem, space)
    start = [np.log(pf.alpha_v), np.log(pf.p_r)]
    if noise.params:
        force, _ = problem.simulate_force(pf.alpha_v, pf.p_r)
        r = force - problem.force
        phi0 = float(np.clip(r[1:] @ r[:-1] / (r @ r), space.lower[2] + 0.01, space.upper[2] - 0.01))
        start.append(phi0)
    start = space.clip_inside(np.array(start), margin=1e-3)
    seed_t = task_seed(seed, transient.id)
    res = sample_posterior(logpost, start, space.lower, space.upper, settings.sampler, seed_t, progress)
    flat = res.flat()
    phys = space.to_physical(flat)
    med = np.median(phys, axis=0)
    f_med, ok = problem.simulate_force(med[0], med[1])
    entry = {
        "id": transient.id, "test": transient.test, "kind": transient.kind,
        "direction": int(transient.direction), "velocity_m_s": float(transient.velocity),
        "t_start_s": float(transient.t_step),
        "alpha_V": summarise(phys[:, 0], settings.credible_mass),
        "p_R_Pa": summarise(phys[:, 1], settings.credible_mass),
        "ls": {"alpha_V": pf.alpha_v, "p_R_Pa": pf.p_r, "J": pf.cost},
        "J": cost_j(f_med, problem.force) if ok else float("inf"),
        **sampling_summary(res, space.names, phys),
        "shape": shape_report(flat, space.lower, space.upper),
        "seed": seed_t,
    }
    if "phi" in space.names:
        entry["phi"] = summarise(phys[:, 2], settings.credible_mass)
    if static_draws is not None:
        entry["static_sensitivity"] = static_sensitivity(
            problem, space, static_draws, (float(med[0]), float(med[1])), np.std(flat[:, :2], axis=0))
    phys_ch, lp, thin = thinned_chains(res, space)
    rng = np.random.default_rng(seed_t)
    draws = phys[rng.choice(len(phys), size=min(N_PREDICTIVE, len(phys)), replace=False)]
    sims = [f for f, good in (problem.simulate_force(a, p) for a, p in draws[:, :2]) if good]
    band = predictive_band(sims, settings.credible_mass, problem.time.size)
    ls_force, _ = problem.simulate_force(pf.alpha_v, pf.p_r)
    entry["wall_s"] = time.perf_counter() - t0
    if out_nc is not None:
        attrs = dict(provenance or {})
        attrs.update({"segment_id": transient.id, "seed": seed_t, "run_seed": seed,
                      "settings": settings.as_dict(), "static_flow": asdict(flow),
                      "summary": {k: entry[k] for k in ("alpha_V", "p_R_Pa", "J", "rhat_max",
                                                          "ess_bulk_min", "converged", "tau")},
                      "entry": entry, "thin": thin, "chains_are": "walkers, ensemble-major "
                      f"({settings.sampler.n_ensembles} ensembles x {settings.sampler.n_walkers} walkers)"})
        idata = post.to_inference_data(phys_ch, space.names, lp, {"force_N": problem.force},
                                       {"time_s": problem.time, "dp0_Pa": np.array([problem.dp0]),
                                        "band_N": band, "ls_force_N": ls_force}, attrs)
        post.write_netcdf(idata, out_nc)
    return WindowResult(entry, space.names, phys_ch, np.array(problem.time), np.array(problem.force),
                           band, ls_force)
