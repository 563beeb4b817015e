"""The select-and-refit loop: which missing effect explains the residual, and the model calibrated with it.

Stated criterion: an effect is selected only when ΔBIC_eff ≤ ``SELECT_DELTA_BIC`` = −10 ("very strong"
evidence on the Kass & Raftery scale; ΔBIC_eff of :mod:`bayesdamper.diagnosis.candidates`) AND it lowers
the pooled eq. (9) error by at least ``MIN_J_REDUCTION`` (20 %): the base model is itself only an
approximation, and with thousands of samples a smooth, tiny improvement of its mismatch is "significant"
without being an effect worth adding. Otherwise the answer is "none". After selecting, the search repeats
with the selected effects fixed at their estimates, until no candidate passes (at most ``MAX_ROUNDS``).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor

import numpy as np

from bayesdamper.diagnosis.candidates import effective_sizes, fit_candidate, pooled_j
from bayesdamper.diagnosis.residual import STRUCTURE_ALPHA
from bayesdamper.physics.effect_vector import pack_effects

#: ΔBIC at or below which a candidate effect is selected (Kass & Raftery: |ΔBIC| > 10 very strong).
SELECT_DELTA_BIC = -10.0
#: Smallest relative reduction of the pooled eq. (9) error a selected effect must achieve (a fifth of
#: what is left): statistical support alone would let a smooth, small improvement of a slightly
#: mis-specified base model through (on two-state data the mis-specification looks partly like friction).
MIN_J_REDUCTION = 0.2
#: Rounds of the select-and-refit loop.
MAX_ROUNDS = 3


class FixedEffectsProblem:
    """An augmented transient problem with its effect vector fixed: looks like a TransientProblem."""

    def __init__(self, problem, eff: np.ndarray):
        self.problem = problem
        self.eff = np.asarray(eff, dtype=float)
        self.force = problem.force
        self.time = problem.time
        self.dp0 = getattr(problem, "dp0", 0.0)
        self.segment_id = getattr(problem, "segment_id", "")

    def simulate_force(self, alpha_v: float, p_r: float):
        return self.problem.simulate_force(alpha_v, p_r, self.eff)


def _friction_corrected_static(plateaus, area: float, coulomb: float, source: str):
    """Stage 1 refitted with the plateau forces reduced by the Coulomb friction [N]."""
    from types import SimpleNamespace

    from bayesdamper.inference.stage1 import fit_static

    corr = [SimpleNamespace(direction=p.direction, flow_rate=p.flow_rate,
                            pressure_drop=p.pressure_drop - coulomb / area) for p in plateaus]
    return fit_static(corr, source=source)


def _calibrate_task(args):
    from bayesdamper.inference.stage2 import identify_transient

    tr, prob, damper, flow, settings, seed = args
    return identify_transient(tr, damper, flow, settings, seed, problem=prob)


def calibrate_with(transients, problems, damper, flow, settings, seed: int, workers: int, progress) -> list:
    """Stage 2 (emcee, as for the baseline) of every transient with the given problem objects."""
    import multiprocessing as mp

    tasks = [(tr, pb, damper, flow, settings, seed) for tr, pb in zip(transients, problems, strict=True)]
    out = []
    if workers <= 1:
        for t in tasks:
            out.append(_calibrate_task(t))
            progress.advance()
        return out
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx) as ex:
        for r in ex.map(_calibrate_task, tasks):
            out.append(r)
            progress.advance()
    progress(f"calibrated {len(out)} transient(s): {sum(r.entry['converged'] for r in out)} converged")
    return out


def _residuals_at_medians(results, problems) -> list[np.ndarray]:
    out = []
    for res, prob in zip(results, problems, strict=True):
        e = res.entry
        f, ok = prob.simulate_force(e["alpha_V"]["median"], e["p_R_Pa"]["median"])
        out.append(f - prob.force if ok else prob.force.copy())
    return out


def report_text(d: dict) -> str:
    """A short plain-text account of what the diagnosis found."""
    from bayesdamper.physics.effects import EFFECTS

    s = d["structure_before"]["summary"]
    lines = [f"Diagnosis of {d['dataset']!r}: plateau noise {d['noise_N']:.1f} N.",
             f"Baseline eq. (7): pooled J = {d['baseline']['J_pooled']:.4f}; {s['n_structured']} of "
             f"{s['n_transients']} transient residuals are structured (F test, alpha {STRUCTURE_ALPHA}); "
             f"residual rms grows with speed as v^{s['rms_vs_speed_log_slope']:.2f}, centroid "
             f"{s['median_t_centroid_s']:.2f} s after the step, dominant frequency "
             f"{s['median_peak_frequency_Hz']:.2f} Hz."]
    sig = d.get("residual_dynamics") or {}
    if sig.get("summary"):
        lines.append(f"Residual dynamics (leave-one-speed-out, from the model's own signals): {sig['summary']}.")
        cb, ca = sig.get("cross_correlation_before"), sig.get("cross_correlation_after")
        if cb and ca:
            lines.append(f"Residual-{cb['driver']} cross-correlation outside its 95 % band at "
                         f"{cb['fraction_outside']:.0%} of lags before, {ca['fraction_outside']:.0%} after.")
    if d["candidates"]:
        ranked = ", ".join(f"{c['effect']} ({c['score']:+.0f})" for c in d["candidates"])
        lines.append(f"Candidates, first round, by delta-BIC_eff (select <= {SELECT_DELTA_BIC:g}): {ranked}.")
    if d["selected"]:
        for name in d["selected"]:
            vals = ", ".join(f"{k} = {v:.4g}" for k, v in d["selected_params"][name].items())
            lines.append(f"Selected: {name} ({vals}): {EFFECTS[name].description}")
    else:
        lines.append(f"Selected: none - no candidate passes both delta-BIC_eff <= {SELECT_DELTA_BIC:g} and a "
                     f"{MIN_J_REDUCTION:.0%} reduction of the pooled J.")
        if d["candidates"]:
            c = d["candidates"][0]
            lines.append(f"Best candidate: {c['effect']} (delta-BIC_eff {c['score']:+.0f}) lowers the pooled J by "
                         f"only {c.get('J_reduction', float('nan')):.0%}: the structure is real but none of the "
                         "library's effects reproduces it.")
    kinds = s.get("parameters_by_kind_median", {})
    if len(kinds) == 2:
        ini, rev = kinds["initial"], kinds["reversal"]
        lines.append(f"Median p_R: {ini['p_R_Pa'] / 1e6:.2f} MPa from starts at rest vs {rev['p_R_Pa'] / 1e6:.2f} MPa "
                     f"from reversals (alpha_V {ini['alpha_V']:.0f} vs {rev['alpha_V']:.0f}): one (alpha_V, p_R) "
                     "pair does not describe both kinds of step.")
    lines.append(f"Pooled J before {d['baseline']['J_pooled']:.4f} -> after {d['final']['J_pooled']:.4f}.")
    return "\n".join(lines)


def select_effects(engine, names: list[str], forces: list[np.ndarray], flow_for, progress) -> tuple[list, dict, list]:
    """The select-and-refit loop of the stated criterion (module docstring).

    ``engine``: a :class:`~bayesdamper.diagnosis.candidates.ProfileEngine` over the transients; ``names``:
    candidate effects; ``forces``: the measured forces; ``flow_for(fixed)``: flow coefficients to use with
    the effects ``fixed`` (None keeps stage 1's). Returns ``(selected, fixed, rounds)``: the selected effects
    in order, their parameter values, and every round's ranked candidates.
    """
    sse, xs, resid = engine.evaluate(pack_effects({}), None, keep=True)
    current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
    selected: list[str] = []
    fixed: dict = {}
    rounds = []
    remaining = list(names)
    for rnd in range(MAX_ROUNDS):
        if not remaining:
            break
        n_eff = effective_sizes(current["resid"])
        fits = []
        for name in remaining:
            progress(f"diagnose: round {rnd + 1}, fitting {name}")
            fits.append(fit_candidate(engine, name, fixed, current["sse"], n_eff, flow_for, pack_effects))
            progress.advance()
        fits.sort(key=lambda c: c.delta_bic)
        j_cur = pooled_j(current["resid"], forces)
        rounds.append({"current_J_pooled": j_cur, "current_effects": list(selected), "candidates": [
            {"effect": c.effect, "score": c.delta_bic, "criterion": "delta_BIC_eff", "J_pooled": c.j_pooled,
             "J_reduction": 1.0 - c.j_pooled / j_cur, "params": c.params,
             "supported": bool(c.delta_bic <= SELECT_DELTA_BIC and c.j_pooled <= (1 - MIN_J_REDUCTION) * j_cur),
             "n_profile_evaluations": c.n_evaluations} for c in fits]})
        best = next((c for c in rounds[-1]["candidates"] if c["supported"]), None)
        if best is None:
            break
        best = next(c for c in fits if c.effect == best["effect"])
        selected.append(best.effect)
        fixed[best.effect] = best.values
        remaining.remove(best.effect)
        engine.warm = best.warm
        sse, xs, resid = engine.evaluate(pack_effects(fixed), flow_for(fixed), keep=True)
        current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
    return selected, fixed, rounds
