"""The calibrated model on every window: its residuals, the noise it is judged against, where re-fits start.

The diagnosis starts from the calibrated baseline (eq. (7), or eq. (7) with the effects already selected) of every
window (:class:`bayesdamper.io.windows.Window`), whatever its kind: a transient whose flow coefficients come from
stage 1 and whose start force from the samples before the step, or a window of whole cycles with its own flow
coefficients and start. The residual reported is taken at the posterior medians of each window's parameters; the
noise is the plateaus' where there are plateaus, else each window's own estimate (:mod:`bayesdamper.inference.noise`),
in the form the structure test needs (:func:`bayesdamper.diagnosis.residual.structure_test`).

What the candidate search starts from (the residual whose dynamics it reads, the gain scales of the generic effect,
every window's warm start and the start force of a window that starts in motion) is taken at each window's
least-squares optimum instead (:func:`least_squares_optima`): a posterior median carries the sampler's Monte Carlo
error, and a search of local optima started from it can end in another optimum when that error moves by a fraction
of a percent; the optimum, found from the window's deterministic point fit, does not move with it.
"""

from __future__ import annotations

import math

import numpy as np

from bayesdamper.core.params import FlowCoefficients
from bayesdamper.diagnosis.residual import SMOOTH_S, plateau_noise

__all__ = ["baseline_residuals", "least_squares_optima", "pooled_noise", "search_problems", "stage_one_for",
           "window_noise_dict"]

#: Largest number of samples of a window in the candidate search: every q-th sample above it (the search compares
#: sums of squares; the final model's posterior uses every sample). 2000 samples hold 10 s at 200 Hz.
MAX_SEARCH_SAMPLES = 2000
#: A window of whole cycles enters the candidate search by its first stretch of this many cycles, but at least
#: :data:`SEARCH_MIN_S`: an effect of the damper or the rig repeats every cycle, so a few cycles of every window
#: judge it, and the search's cost is its solves', which grows with the duration (the final model's posterior uses
#: every sample of every window).
SEARCH_CYCLES, SEARCH_MIN_S = 3.0, 3.0
#: ... and the search's grid stage (which only picks where each refinement starts) by its first cycle, but at least
#: :data:`SCREEN_MIN_S`, with its flow coefficients held at the baseline's (only α_V and p_R re-fitted).
SCREEN_CYCLES, SCREEN_MIN_S = 1.0, 1.0

#: Effects whose force changes the plateaus (so stage 1 is fitted again with them): their parameter giving the
#: constant force [N] along the motion, signed with the velocity (friction) or not (an offset).
PLATEAU_FORCES = {"friction": ("coulomb_N", True), "load_cell_offset": ("offset_N", False)}


def _flow_of(entry: dict, flow0: FlowCoefficients | None) -> FlowCoefficients:
    """The window's flow coefficients: the posterior medians of its own, else stage 1's."""
    f = entry.get("flow") or {}
    if flow0 is None or entry.get("flow_prior", "").startswith("flat"):
        vals = [f[n]["median"] for n in ("CL12", "CQ12", "CL21", "CQ21")]
        return FlowCoefficients(*[max(float(v), 0.0) for v in vals])
    return flow0


def baseline_residuals(windows, results, damper, flow0: FlowCoefficients | None, effects=None):
    """Residual (model − measured) [N] of every window at its posterior medians, and each window's flow.

    ``results``: the windows' :class:`~bayesdamper.inference.stage2.WindowResult`; ``effects``: the model's
    effects (None: eq. (7)). A failed solve leaves the measured force as the residual.
    """
    from bayesdamper.inference.joint import JointProblem, StageOnePrior
    from bayesdamper.inference.plateau_noise import PlateauNoise

    out, flows = [], []
    dummy = StageOnePrior.flat(PlateauNoise(0.0, 1.0, 1, 0))
    for w, res in zip(windows, results, strict=True):
        e = res.entry
        flow = _flow_of(e, flow0)
        jp = JointProblem.from_window(w, damper, dummy, effects=effects)
        start = e["dp0_Pa"]["median"] if "dp0_Pa" in e else w.dp0
        theta = np.r_[math.log(e["alpha_V"]["median"]), math.log(e["p_R_Pa"]["median"]), start, flow.as_array()]
        f, ok = jp.simulate_window(theta)
        out.append(f - w.force if ok else w.force.copy())
        flows.append(flow)
    return out, flows


def _ar1_smoothed(phi: float, sigma: float, n: int) -> float:
    """Mean square of an n-sample moving average of AR(1) noise of coefficient φ and marginal sd σ [N^2]."""
    k = np.arange(1, n)
    return float(sigma * sigma / (n * n) * (n + 2.0 * np.sum((n - k) * phi ** k)))


def window_noise_dict(window, entry: dict, segs) -> dict:
    """The noise a window's residual is judged against, as :func:`~bayesdamper.diagnosis.residual.plateau_noise`
    gives it: the plateaus' where the data set has plateaus, else the window's own AR(1) estimate (its entry's
    ``noise``) with the moving average's mean square in closed form and the estimate's degrees of freedom (half
    the samples it was made from: one per periodogram bin pair)."""
    plateaus = [p for s in segs for p in s.plateaus]
    if plateaus:
        return plateau_noise(segs)
    nz = entry.get("noise") or {}
    phi, sigma = float(nz.get("phi", 0.0)), float(nz.get("sigma_N", np.std(window.force)))
    rate = 1.0 / float(np.median(np.diff(window.time)))
    n_avg = max(1, int(round(SMOOTH_S * rate)))
    return {"sigma_N": sigma, "rho": phi, "n": int(nz.get("n_samples", window.time.size)),
            "smoothed_ms": _ar1_smoothed(phi, sigma, n_avg),
            "smoothed_dof": float(max(0.5 * nz.get("n_samples", window.time.size), 1.0)),
            "source": nz.get("source", "window")}


def pooled_noise(noises: list[dict]) -> dict:
    """One noise summary for the report: the plateaus' (identical in every window) or the windows' median."""
    if all(n is noises[0] or n == noises[0] for n in noises):
        return noises[0]
    return {"sigma_N": float(np.median([n["sigma_N"] for n in noises])),
            "rho": float(np.median([n["rho"] for n in noises])), "n": int(sum(n["n"] for n in noises)),
            "source": "each window's own estimate (median shown)"}


def _point_start(problem, entry: dict, area: float) -> np.ndarray:
    """A window's own parameters at its baseline's deterministic point fit (the entry's ``ls``: the paper's
    Nelder-Mead point, or the least squares of all seven parameters of a window without plateaus), the posterior
    median where the point fit has no value; the start force of a window in motion from its first samples where
    the point fit has none."""
    ls = entry.get("ls") or {}
    names = ("CL12", "CQ12", "CL21", "CQ21")
    flow = entry.get("flow") or {}
    f4 = (np.array([ls[n] for n in names]) if all(n in ls for n in names)
          else np.array([flow[n]["median"] for n in names]) if flow else None)
    start = ls["dp0_Pa"] * area if "dp0_Pa" in ls else None
    return problem.inner_start(ls.get("alpha_V", entry["alpha_V"]["median"]),
                               ls.get("p_R_Pa", entry["p_R_Pa"]["median"]), start, f4)


def least_squares_optima(windows, results, damper, flow0: FlowCoefficients | None, max_steps_per_sample: int,
                         workers: int = 1):
    """Every window's own parameters at the least-squares optimum of the calibrated baseline (eq. (7)), on all its
    samples: re-fitted from its point fit (:func:`_point_start`) and from the best of a spread over the (α_V, p_R)
    box, the better optimum kept (:meth:`~bayesdamper.diagnosis.engine.ProfileEngine.evaluate` with ``keep``).

    Returns ``(optima, residuals, flows)``: per window the optimum's physical values
    (:meth:`~bayesdamper.inference.problem.EffectsProblem.unpack_inner`), its residual (model − measured) [N] (the
    measured force where no solve succeeds) and its flow coefficients.
    """
    from bayesdamper.diagnosis.engine import ProfileEngine
    from bayesdamper.inference.problem import EffectsProblem
    from bayesdamper.physics.with_effects import effect_argument

    area = damper.piston_area
    problems = [EffectsProblem.from_window(w, damper, flow0, max_steps=max_steps_per_sample * w.time.size)
                for w in windows]
    starts = [_point_start(p, r.entry, area) for p, r in zip(problems, results, strict=True)]
    engine = ProfileEngine(problems, starts, workers)
    try:
        _, xs, resid = engine.evaluate(effect_argument({}), None, keep=True)
    finally:
        engine.close()
    optima = [p.unpack_inner(x) for p, x in zip(problems, xs, strict=True)]
    flows = [FlowCoefficients(*o["flow"]) if "flow" in o else flow0 for o in optima]
    resid = [r if r is not None else w.force.copy() for w, r in zip(windows, resid, strict=True)]
    return optima, resid, flows


def _warm(problem, optimum: dict) -> np.ndarray:
    """x of a search problem at a window's least-squares optimum (:func:`least_squares_optima`)."""
    return problem.inner_start(optimum["alpha_V"], optimum["p_R_Pa"], optimum.get("start_force_N"),
                               optimum.get("flow"))


def stage_one_for(plateaus, area: float, source: str):
    """``flow_for(effects)``: stage 1 fitted again on the plateaus with the effects' constant forces removed
    (:data:`PLATEAU_FORCES`), or None when no selected effect moves the plateaus."""
    from types import SimpleNamespace

    from bayesdamper.inference.stage1 import fit_static

    def flow_for(effects: dict):
        shift = {1: 0.0, -1: 0.0}
        for name, (param, signed) in PLATEAU_FORCES.items():
            value = float((effects.get(name) or {}).get(param, 0.0))
            for d in (1, -1):
                shift[d] += value * (d if signed else 1.0)
        if shift[1] == 0.0 and shift[-1] == 0.0:
            return None
        # a plateau's pressure drop is direction * mean force / A_P: remove the effect's force first
        corr = [SimpleNamespace(direction=p.direction, flow_rate=p.flow_rate,
                                pressure_drop=p.pressure_drop - p.direction * shift[p.direction] / area)
                for p in plateaus]
        return fit_static(corr, source=source)

    return flow_for


def _subsampled(window, q: int, t_end: float | None = None):
    """The window's times and forces, every ``q``-th sample, up to ``t_end`` [s]."""
    keep = np.ones(window.time.size, dtype=bool) if t_end is None else window.time <= t_end
    return window.time[keep][::q], window.force[keep][::q]


def search_problems(windows, optima, damper, flow0, max_steps_per_sample: int):
    """The candidate search's problems (:class:`~bayesdamper.inference.problem.EffectsProblem`) of the windows, their
    warm starts at the windows' least-squares ``optima`` (:func:`least_squares_optima`), and the screening stretches
    of windows of whole cycles with theirs.

    A window of whole cycles enters by its first stretch (:data:`SEARCH_CYCLES`); a window that starts in motion
    starts from the force its optimum put there (data, not a parameter of the search); more than
    :data:`MAX_SEARCH_SAMPLES` samples are thinned. Returns ``(problems, warm, screen,
    screen_warm)``; the screening lists are None when no window is of whole cycles.
    """
    from bayesdamper.inference.problem import EffectsProblem

    problems, warm, screen, screen_warm = [], [], [], []
    for w, opt in zip(windows, optima, strict=True):
        start = None if w.starts_settled else opt.get("start_force_N")
        cyc = float(w.info.get("cycle_s", 0.0)) if w.kind == "cycles" else 0.0
        t_search = w.t_step + max(SEARCH_CYCLES * cyc, SEARCH_MIN_S) if w.kind == "cycles" else None
        n_search = int(np.count_nonzero(w.time <= t_search)) if t_search is not None else w.time.size
        q = max(1, int(np.ceil(n_search / MAX_SEARCH_SAMPLES)))
        t, f = _subsampled(w, q, t_search)
        prob = EffectsProblem.from_window(w, damper, flow0, time=t, force=f, start_force=start,
                                          max_steps=max_steps_per_sample * t.size)
        problems.append(prob)
        warm.append(_warm(prob, opt))
        if w.kind == "cycles":
            span = max(SCREEN_CYCLES * cyc, SCREEN_MIN_S)
            t, f = _subsampled(w, q, w.t_step + span)
            if t.size < problems[-1].time.size or flow0 is None:
                flow = flow0 or FlowCoefficients(*opt["flow"])
                sp = EffectsProblem.from_window(w, damper, flow, time=t, force=f,
                                                start_force=start, max_steps=max_steps_per_sample * t.size)
                screen.append(sp)
                screen_warm.append(_warm(sp, opt))
    if not screen:
        return problems, warm, None, None
    if len(screen) < len(problems):  # transients beside the cycles: the screen keeps them whole
        return problems, warm, None, None
    return problems, warm, screen, screen_warm
