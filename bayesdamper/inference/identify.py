"""The posterior of one window: the unit of work of every identification.

A window (:class:`bayesdamper.io.windows.Window`) has three parts, each with its own data where the record has
them (:mod:`bayesdamper.inference.cut`):

* the flow coefficients of eq. (4): stage 1 from the plateaus of triangular tests (a Gaussian prior); a record
  without plateaus has none, and they are sampled with the window's other parameters under a flat prior
  (:mod:`bayesdamper.inference.start` finds where the fit starts);
* Δp at the start: the mean force of the settled samples before a step (a start from rest or a reversal, or the
  rest before a record's motion); a window that starts in motion has none, and Δp0 is sampled;
* α_V and p_R: the window's eq. (9) residual.

One likelihood (:mod:`bayesdamper.inference.joint`): AR(1) noise with its coefficient φ estimated where the model
holds no error — the plateaus, or the window's least-squares residual away from the excitation's band and
harmonics (:mod:`bayesdamper.inference.noise`) — and held fixed, the window's scale marginalised, so smooth model
error cannot pass for noise colour. When every other part has its own data the posterior is the cut one
(their uncertainty carried in, the window unable to drag them); otherwise the parts without data are sampled
jointly with α_V and p_R. One sampler with its convergence rules (:mod:`bayesdamper.inference.sampling`).
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.inference import posterior as post
from bayesdamper.inference.likelihood import cost_j
from bayesdamper.inference.logscale import LogScaled
from bayesdamper.inference.pointfit import fit_point
from bayesdamper.inference.priors import ParameterSpace
from bayesdamper.inference.problem import WindowProblem
from bayesdamper.inference.sampling import sample_posterior
from bayesdamper.inference.stage2 import (
    N_PREDICTIVE,
    StageTwoSettings,
    WindowResult,
    identify_conditional,
    predictive_band,
    sampling_summary,
    shape_report,
    summarise,
    task_seed,
    thinned_chains,
)
from bayesdamper.inference.start import least_squares_start, residual_sse

__all__ = ["better_start", "identify_window", "window_noise"]

#: Sampler of the joint posterior: differential evolution with independence moves from the Gauss-Newton
#: approximation at the MAP (a window that determines its parameters has a posterior close to Gaussian in the
#: sampled variables), walkers 2 × ndim + 2, checks every 50 steps (τ of a few steps: the rule is met long before a
#: check 100 steps on).
JOINT_MOVE = "de+laplace"
JOINT_CHECK_EVERY = 50
#: Sampler of a window whose MAP lies near a prior bound (:data:`JOINT_BOUND_SDS`) or that has no Gauss-Newton
#: covariance: the Gaussian at the MAP is cut by the box, so the independence proposal comes from a discarded DE pilot
#: instead (exact: adapted in the warm-up only), checked every :data:`JOINT_CHECK_EVERY` steps. Where the pilot's
#: Gaussian misses the posterior (a slow reversal's long, thin, curved (α_V, p_R) ridge, whose optimiser start can lie
#: far down the ridge from the mass) the proposal follows the ridge's crest and the ensembles restart from it
#: (:func:`~bayesdamper.inference.proposals.choose_pilot_proposal`; the move's tests are in tests/test_sampling.py).
#: On four of rig-A's transients with a diagnosed model's effects: τ of 2-4 steps against plain DE's 12-14, and
#: 9 000-14 000 evaluations against 36 000-58 000, at the same intervals.
BOUND_MOVE = "de+pilot"
#: Distance [Gauss-Newton sd] from the MAP to a prior bound of log α_V or log p_R below which the Gaussian
#: approximation is cut by the box (a bound within 3 sd cuts >= 0.13 % of it; a ridge that runs into a bound far
#: more) and :data:`BOUND_MOVE` replaces the Laplace proposal: on rig-A's low-speed reversals (MAP at the 10 MPa
#: bound) its independence moves were accepted 8 % of the time and τ was 120 steps (plain DE: 26 % and 65 steps). On
#: an independent 33-window set with 14 such windows (τ up to 45 steps under plain DE, up to 14 with the pilot's
#: proposal) the pilot's proposal took a fifth of plain DE's evaluations, the 90 % intervals the same to Monte
#: Carlo error.
JOINT_BOUND_SDS = 3.0
#: Entries of the joint vector that are flow coefficients (after log α_V, log p_R and Δp0).
FLOW_DIMS = np.arange(3, 7)


def identify_window(window, damper: DamperConstants, flow: FlowCoefficients | None, settings: StageTwoSettings,
                    seed: int, out_nc: Path | None = None, provenance: dict | None = None, progress=None,
                    static_draws: np.ndarray | None = None, problem=None, prior=None,
                    effects=None, start: dict | None = None) -> WindowResult:
    """Point fit and posterior of one window (module docstring).

    Parameters
    ----------
    window : Window
    damper : DamperConstants
    flow : FlowCoefficients or None
        Stage 1's coefficients (None: the data set has no plateaus).
    settings : StageTwoSettings
    seed : int
        Run seed; the window's own seed derives from it and the window id.
    prior : StageOnePrior, optional
        Stage 1's flow posterior and the plateau noise. With it (and ``settings.propagate``) the posterior is
        the modular one (cut or joint, :data:`settings.coupling`); without it and without ``flow`` the flow
        coefficients are sampled under a flat prior with the noise estimated from the window.
    problem : optional
        A model with effects (it needs ``simulate_force(alpha_v, p_r)``, ``force``, ``time`` and ``dp0``): the
        posterior of (α_V, p_R) is then conditional on everything else.
    static_draws : ndarray, optional
        Stage-1 draws for the conditional posterior's sensitivity check.
    effects : ComposedEffects, optional
        Effects added to eq. (7), held at their values (the diagnosis's final model): the same likelihood, priors
        and sampler, on the composed kernel.
    start : dict, optional
        A further start of the point fit of a model with ``effects``: physical ``alpha_V``, ``p_R_Pa`` and, where
        known, ``start_force_N`` [N] and ``flow`` (4,) — the window's optimum in the diagnosis's search of the same
        model. The fit starts from whichever of it and its own start fits the window better (one solve more):
        with effects such as the two-state model, α_V and p_R mean other things than in eq. (7), and the eq. (7)
        optimum can lie in another basin of the model with effects. Recorded as the entry's ``start``.
    out_nc : Path, optional
        Where the posterior is written (atomically) with its provenance.
    """
    if problem is not None or (flow is not None and prior is None) or (prior is not None
                                                                        and not settings.propagate):
        return identify_conditional(window, damper, flow, settings, seed, out_nc, provenance, progress,
                                    static_draws, problem)
    return _identify_joint(window, damper, flow, settings, seed, out_nc, provenance, progress, prior, effects,
                           start if effects is not None else None)


def better_start(jp, own: list, hint: dict | None, space) -> tuple[list, str]:
    """``own`` (log α_V, log p_R, Δp0, flow...) or the same with the hint's (α_V, p_R) (clipped into ``space``),
    whichever has the smaller residual sum of squares (:func:`identify_window`'s ``start``), and which it is:
    ``"own"`` or ``"search optimum"``. A hint whose solve fails is not taken."""
    if hint is None:
        return own, "own"
    alt = list(own)
    alt[:2] = np.clip(np.log([hint["alpha_V"], hint["p_R_Pa"]]), space.lower[:2], space.upper[:2])
    return (alt, "search optimum") if residual_sse(jp, alt) < residual_sse(jp, own) else (own, "own")


def window_noise(window, residual: np.ndarray):
    """The noise of a window without plateaus, from its least-squares residual ``residual`` [N] away from the
    excitation's band and harmonics (:func:`bayesdamper.inference.noise.spectral_noise`)."""
    from bayesdamper.inference.noise import spectral_noise

    info = window.info or {}
    rate = float(1.0 / np.median(np.diff(window.time)))
    periodic = bool(info.get("periodic")) and info.get("cycle_s")
    band = info.get("band_Hz")
    return spectral_noise(residual, rate, fundamental_hz=1.0 / float(info["cycle_s"]) if periodic else None,
                          input_band_hz=tuple(band) if band else (None if periodic else
                                                                  (0.0, 1.0 / float(info.get("cycle_s", 1.0)))))


def input_error(jp, window, theta: np.ndarray, force: np.ndarray | None, noise) -> dict:
    """What the reconstruction's error of the input does to the force: the rms difference [N] between the force
    at ``theta`` driven by the input and by each of its bootstrap replicates, against the noise's sd. It is part
    of the window's residual, so its scale σ_w (marginalised) holds it: where it is a fraction of the noise it
    widens the intervals by less than that fraction squared; where it rivals the noise the intervals widen with
    σ_w/σ and say so."""
    if force is None:
        return {}
    diffs = []
    for rep in window.drive_replicates:
        local = rep.window(window.t_step, float(max(window.time[-1], window.t_step + 1e-9)))
        f, ok = replace(jp, drive=local, record_drive=rep if jp.effects is not None else None).simulate_window(theta)
        if ok:
            diffs.append(float(np.sqrt(np.mean((f - force) ** 2))))
    if not diffs:
        return {}
    rms = float(np.sqrt(np.mean(np.square(diffs))))
    return {"force_rms_N": rms, "relative_to_noise": rms / max(float(noise.sigma), 1e-300),
            "replicates": len(diffs)}


def _cut_by_zero(x: np.ndarray, lower: np.ndarray, cov: np.ndarray | None) -> np.ndarray:
    """The flow coefficients (entries of ``x``) whose Laplace approximation the bound 0 cuts: MAP within
    :data:`JOINT_BOUND_SDS` sd of it (all of them without a covariance).

    Those are sampled as their logs (:class:`LogScaled`): a posterior pressed against 0 over decades is a funnel on
    its own scale and smooth in its log. The others stay linear: a laminar and a quadratic coefficient that one
    speed per direction cannot separate lie on a straight ridge (C_L v + C_Q v² fixed, correlation -1.000 on
    triangular records), which the log bends into a curve that neither the independence moves nor DE follow.
    """
    if cov is None:
        return FLOW_DIMS
    sd = np.sqrt(np.diag(cov))[FLOW_DIMS]
    return FLOW_DIMS[x[FLOW_DIMS] - lower[FLOW_DIMS] < JOINT_BOUND_SDS * sd]


def _identify_joint(window, damper, flow, settings: StageTwoSettings, seed: int, out_nc, provenance, progress,
                    prior, effects=None, hint: dict | None = None) -> WindowResult:
    from bayesdamper.inference import cut, joint

    t0 = time.perf_counter()
    code = {"plateau": joint.PLATEAU, "ar1": joint.AR1, "white": joint.WHITE}[settings.noise_model]
    seed_t = task_seed(seed, window.id)
    if prior is None or not prior.gaussian:  # no stage 1: least squares of all seven, noise from its residual
        from bayesdamper.inference.noise import NoiseEstimate

        provisional = joint.StageOnePrior.flat(NoiseEstimate(0.0, 1.0, int(window.time.size), "provisional"))
        jp = joint.JointProblem.from_window(window, damper, provisional, code, effects=effects)
        space = jp.space(settings.alpha_v_bounds, settings.p_r_bounds)
        x_ls, j_ls, hinted = least_squares_start(jp, space, hint)
        origin = "search optimum" if hinted else "own"
        f_ls, _ = jp.simulate_window(x_ls)
        prior = joint.StageOnePrior.flat(window_noise(window, jp.force - f_ls) if prior is None else prior.noise)
        jp = replace(jp, prior=prior)
        ls = {"alpha_V": float(np.exp(x_ls[0])), "p_R_Pa": float(np.exp(x_ls[1])), "dp0_Pa": float(x_ls[2]),
              **{n: float(c) for n, c in zip(joint.FLOW_NAMES, x_ls[3:7], strict=True)}, "J": j_ls}
        start = list(x_ls)
        ls_force = f_ls
    else:
        jp = joint.JointProblem.from_window(window, damper, prior, code, effects=effects)
        space = jp.space(settings.alpha_v_bounds, settings.p_r_bounds)
        # the paper's point estimate (Nelder-Mead on α_V, p_R with stage-1 flow and the mean step force): reported
        # as "ls" and the start of the MAP fit
        cond = WindowProblem.from_window(window, damper, flow)
        pf = fit_point(cond, ParameterSpace.default((), settings.alpha_v_bounds, settings.p_r_bounds))
        start, origin = better_start(jp, [np.log(pf.alpha_v), np.log(pf.p_r), jp.dp0_estimate, *prior.mean], hint,
                                     space)
        ls = {"alpha_V": pf.alpha_v, "p_R_Pa": pf.p_r, "J": pf.cost}
        ls_force, _ = cond.simulate_force(pf.alpha_v, pf.p_r)
    space = jp.space(settings.alpha_v_bounds, settings.p_r_bounds)
    logpost = joint.JointLogPosterior(jp, space)
    if code == joint.AR1:
        start.append(float(np.clip(prior.noise.phi, space.lower[-1] + 0.01, space.upper[-1] - 0.01)))
    coupling = settings.coupling if (prior.gaussian and jp.settled_start) else "joint"
    if coupling == "cut":  # sample θ2 | θ̂1, then carry θ1's own uncertainty in (inference/cut.py)
        theta1 = np.r_[jp.dp0_estimate, prior.mean]
        fit = cut.fit_conditional(logpost, theta1, np.r_[start[:2], start[7:]])
        target = cut.ConditionalLogPosterior(logpost, theta1)
        lower, upper, cov = target.lower, target.upper, fit.cov2
        x_start = np.clip(fit.x2, lower + 1e-3 * (upper - lower), upper - 1e-3 * (upper - lower))
        x_map = target.full(x_start)[0]
        if effects is not None:  # the least-squares point of the model with its effects (the eq. (7) one above)
            ls_force, ok = jp.simulate_window(x_map)
            ls = {"alpha_V": float(np.exp(x_map[0])), "p_R_Pa": float(np.exp(x_map[1])),
                  "J": cost_j(ls_force, jp.force) if ok else float("inf")}
    else:
        x_map, cov = joint.fit_map(logpost, space.clip_inside(np.array(start), margin=1e-9))
        # just inside the box: a flat prior's box of a flow coefficient spans 100 times its scale, so a margin of a
        # thousandth of the box would move a small coefficient by more than its own value
        x_map = space.clip_inside(x_map, margin=1e-9)
        target, lower, upper, x_start = logpost, space.lower, space.upper, x_map
    gap = np.minimum(x_map[:2] - space.lower[:2], space.upper[:2] - x_map[:2])
    near_bound = cov is None or bool(np.any(gap < JOINT_BOUND_SDS * np.sqrt(np.diag(cov))[:2]))
    sampler = replace(settings.sampler, n_walkers=max(settings.sampler.n_walkers, 2 * x_start.size + 2),
                      move=BOUND_MOVE if near_bound else JOINT_MOVE, check_every=JOINT_CHECK_EVERY)
    logged = _cut_by_zero(x_start, lower, cov) if coupling == "joint" and not prior.gaussian else []
    if len(logged):  # flat flow priors on [0, bound] that the bound cuts: sampled as their logs
        logs = LogScaled(target, logged, lower, upper)
        res = sample_posterior(logs, logs.to_u(x_start), logs.lower, logs.upper, sampler, seed_t, progress,
                               scale=logs.covariance(x_start, cov))
        res.log_prob = res.log_prob - np.sum(res.chain[..., logs.dims], axis=-1)  # the density of θ, not of u
        res.chain = logs.to_theta(res.chain)
    else:
        res = sample_posterior(target, x_start, lower, upper, sampler, seed_t, progress, scale=cov)
    if coupling == "cut":
        res = cut.propagate(res, logpost, theta1, fit, int(np.random.SeedSequence([seed_t, 1]).generate_state(1)[0]))
    flat = res.flat()
    phys = space.to_physical(flat)
    rng = np.random.default_rng(seed_t)
    idx = rng.choice(len(flat), size=min(N_PREDICTIVE, len(flat)), replace=False)
    sims = [f for f, good in (jp.simulate_window(th) for th in flat[idx]) if good]
    band = predictive_band(sims, settings.credible_mass, jp.time.size)
    f_map, ok_map = jp.simulate_window(x_map)
    entry = {
        "id": window.id, "test": window.test, "kind": window.kind,
        "direction": int(window.direction), "velocity_m_s": float(window.velocity),
        "t_start_s": float(window.t_step), "window": window.as_dict() | {"t_end_s": float(window.time[-1])},
        "alpha_V": summarise(phys[:, 0], settings.credible_mass),
        "p_R_Pa": summarise(phys[:, 1], settings.credible_mass),
        "dp0_Pa": summarise(phys[:, 2], settings.credible_mass),
        "flow": {n: summarise(phys[:, 3 + k], settings.credible_mass) for k, n in enumerate(joint.FLOW_NAMES)},
        "ls": ls,
        # J of the posterior-predictive median force (the curve drawn through the data) and at the MAP
        "J": cost_j(band[1], jp.force) if sims else float("inf"),
        "J_map": cost_j(f_map, jp.force) if ok_map else float("inf"),
        **sampling_summary(res, space.names, phys),
        "shape": shape_report(flat, space.lower, space.upper),
        "seed": seed_t, "propagated": True, "coupling": coupling,
        # where the point fit started: its own start, or the diagnosis's search optimum of the same model
        "start": origin,
        "effects": effects.as_dict() if effects is not None else {},
        "flow_prior": "stage 1 (plateaus)" if prior.gaussian else "flat (no plateaus): sampled with the window",
        "noise": prior.noise.as_dict() | {"model": settings.noise_model},
        "dp0_estimate_Pa": jp.dp0_estimate, "n_pre_samples": int(jp.pre_force.size),
        # σ_w / σ_e at the MAP: how much wider than the noise alone the window's scale (noise + model error)
        # makes the intervals
        "window_scale_ratio": logpost.window_scale(x_map, prior.noise.phi) / prior.noise.sigma_e,
        "sampler": sampler.as_dict(),
        "sampled_as_log": [space.names[d] for d in logged],
    }
    if code == joint.AR1:
        entry["phi"] = summarise(phys[:, -1], settings.credible_mass)
    if window.drive_replicates:
        entry["input_error"] = input_error(jp, window, x_map, f_map if ok_map else None, prior.noise)
    phys_ch, lp, thin = thinned_chains(res, space)
    entry["wall_s"] = time.perf_counter() - t0
    if out_nc is not None:
        attrs = dict(provenance or {})
        attrs.update({"segment_id": window.id, "seed": seed_t, "run_seed": seed,
                      "settings": settings.as_dict(),
                      "static_flow": asdict(flow) if flow is not None else None,
                      "stage1_prior": ({"mean": prior.mean.tolist(), "cov": prior.cov.tolist(),
                                        "dof": prior.dof.tolist()} if prior.gaussian else None),
                      "summary": {k: entry[k] for k in ("alpha_V", "p_R_Pa", "J", "rhat_max",
                                                          "ess_bulk_min", "converged", "tau")},
                      "entry": entry, "thin": thin, "chains_are": "walkers, ensemble-major "
                      f"({sampler.n_ensembles} ensembles x {sampler.n_walkers} walkers)"})
        idata = post.to_inference_data(phys_ch, space.names, lp, {"force_N": jp.force},
                                       {"time_s": jp.time, "dp0_Pa": np.array([jp.dp0_estimate]),
                                        "band_N": band, "ls_force_N": ls_force,
                                        "displacement_m": np.asarray(window.displacement)}, attrs)
        post.write_netcdf(idata, out_nc)
    return WindowResult(entry, space.names, phys_ch, np.array(jp.time), np.array(jp.force), band, ls_force)
