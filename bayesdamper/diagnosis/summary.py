"""What a diagnosis reports: J before and after (per window, per speed, pooled), drift, the p_R split, the structure
before and after, and the settings and provenance — the content of ``diagnosis.json``.

Findings the report must state: a selected effect's parameter that ends on a bound of its search (the form does not
fit the data as parametrised: its value is not a result; :func:`bound_findings`), and every test speed (or kind of
step at a speed) whose J is worse with the selected effects than without (:func:`j_by_speed`). :func:`findings_text`
words both for the report; :func:`report_text` gives the whole diagnosis in a few lines of text.
"""

from __future__ import annotations

import math

import numpy as np

from bayesdamper.diagnosis.calibrated import (
    MAX_SEARCH_SAMPLES,
    SCREEN_CYCLES,
    SCREEN_MIN_S,
    SEARCH_CYCLES,
    SEARCH_MIN_S,
)
from bayesdamper.diagnosis.candidates import CandidateSpec, pooled_j, reset_search_cost, search_cost, spec_bound_flags
from bayesdamper.diagnosis.findings import FLAT_DEVIANCE, findings_text
from bayesdamper.diagnosis.global_stage import search_cost_by_step
from bayesdamper.diagnosis.loop import MIN_J_REDUCTION, SELECT_DELTA_BIC
from bayesdamper.diagnosis.residual import SMOOTH_S, STRUCTURE_ALPHA, describe_residual, structure_test
from bayesdamper.diagnosis.residual import summarise_structure as _summarise_structure
from bayesdamper.diagnosis.spec import GENERIC
from bayesdamper.diagnosis.unnamed import effect_reading
from bayesdamper.inference.drift import drift_summary
from bayesdamper.physics.effects import EFFECTS

__all__ = ["GENERIC", "annotate_bounds", "bound_findings", "findings_text", "j_by_speed", "p_r_split", "pooled_j_ls",
           "summarise_diagnosis", "test_speeds"]


def pooled_j_ls(entries: list[dict], forces: list[np.ndarray]) -> float:
    """Pooled eq. (9) J at each window's least-squares optimum (``entry["ls"]["J"]``).

    The reported J is at the posterior medians, which need not minimise eq. (9) (the likelihood weighs the
    residual's increments by the noise colour): this is the figure the candidate search compares.
    """
    num = sum((e["ls"]["J"] ** 2) * float(f @ f) for e, f in zip(entries, forces, strict=True))
    den = sum(float(f @ f) for f in forces)
    return math.sqrt(num / den)


def p_r_split(entries: list[dict]) -> dict:
    """Median p_R of starts from rest and of reversals, and whether they agree.

    They agree ("closes") when the medians differ by less than the median half-width of the per-window
    90 % intervals of log p_R: the split is then within what a single transient resolves.
    """
    kinds = {k: [e for e in entries if e["kind"] == k] for k in ("initial", "reversal")}
    if not all(kinds.values()):
        return {}
    med = {k: float(np.median([e["p_R_Pa"]["median"] for e in v])) for k, v in kinds.items()}
    half = float(np.median([0.5 * (np.log(e["p_R_Pa"]["hi"]) - np.log(e["p_R_Pa"]["lo"])) for e in entries]))
    gap = abs(math.log(med["initial"] / med["reversal"]))
    return {"initial_Pa": med["initial"], "reversal_Pa": med["reversal"], "log_ratio": gap,
            "median_half_width_log": half, "agrees": bool(gap < half)}


def test_speeds(windows) -> list[float]:
    """Each window's test speed [m/s]: the median |v| of the windows of its record (``window.test``)."""
    by_test: dict = {}
    for w in windows:
        by_test.setdefault(w.test, []).append(abs(float(w.velocity)))
    return [float(np.median(by_test[w.test])) for w in windows]


def j_by_speed(windows, base_resid: list[np.ndarray], final_resid: list[np.ndarray],
               base_entries: list[dict] | None = None, final_entries: list[dict] | None = None) -> list[dict]:
    """Pooled eq. (9) J of the baseline and of the final model per test speed and kind of step.

    One row per (speed, kind) present and one with kind ``"all"`` per speed, each ``{"speed_mm_s", "kind",
    "n_windows", "J_before", "J_after", "change", "worse"}``: J pooled over the windows of that speed (and kind)
    from the residuals at the posterior medians (the J the diagnosis reports), ``change`` J_after / J_before - 1,
    ``worse`` whether J_after exceeds J_before; with the windows' entries also ``J_before_ls`` and ``J_after_ls``, the
    same at each window's least-squares optimum (:func:`pooled_j_ls`).
    """
    speeds = [round(v * 1e3, 4) for v in test_speeds(windows)]
    forces = [w.force for w in windows]
    rows = []
    for sp in sorted(set(speeds)):
        at = [i for i, v in enumerate(speeds) if v == sp]
        kinds = sorted({windows[i].kind for i in at})
        for kind in kinds + ["all"]:
            idx = [i for i in at if kind == "all" or windows[i].kind == kind]
            jb = pooled_j([base_resid[i] for i in idx], [forces[i] for i in idx])
            ja = pooled_j([final_resid[i] for i in idx], [forces[i] for i in idx])
            row = {"speed_mm_s": float(sp), "kind": kind, "n_windows": len(idx), "J_before": jb, "J_after": ja,
                   "change": ja / jb - 1.0 if jb > 0 else float("nan"), "worse": bool(ja > jb)}
            if base_entries is not None and final_entries is not None:
                row["J_before_ls"] = pooled_j_ls([base_entries[i] for i in idx], [forces[i] for i in idx])
                row["J_after_ls"] = pooled_j_ls([final_entries[i] for i in idx], [forces[i] for i in idx])
            rows.append(row)
    return rows


def _specs_by_label(names: list) -> dict:
    return {getattr(n, "label", n): (n if isinstance(n, CandidateSpec) else CandidateSpec(n)) for n in names}


#: The sentence of a parameter on its bound (:func:`bound_findings`).
BOUND_TEXT = ("{effect}: {param} ends on its {side} bound ({value:.4g}): the form does not fit these data as "
              "parametrised; its value is not a result")
#: The sentences of a parameter on its bound that the data do not resolve there, or bound on one side only
#: (:func:`bayesdamper.diagnosis.findings.bound_resolution`).
UNRESOLVED_TEXT = ("{effect}: {param} ends on its {side} bound ({value:.4g}), and the fit is the same at {inside:.4g} "
                   "(deviance {delta_deviance:+.2f}, within the 90 % level {level:.2f}): the data do not resolve it "
                   "between these values; read it as a one-sided bound, not a value")
ONE_SIDED_TEXT = ("{effect}: {param} ends on its {side} bound ({value:.4g}); the fit is worse at {inside:.4g} "
                  "(deviance {delta_deviance:+.2f}) and no better at {past:.4g} past the bound (deviance "
                  "{delta_deviance_past:+.2f}, the 90 % level {level:.2f}): the data bound it on one side only; read "
                  "it as {relation} {inside:.4g}, not a value")


def bound_findings(selected: list[str], fixed: dict, names: list, resolution: list | None = None) -> list[dict]:
    """The selected effects' parameters that end on a bound of their search
    (:func:`bayesdamper.diagnosis.candidates.spec_bound_flags` of the final values ``fixed``), each
    ``{"effect", "param", "value", "bound", "side", "text"}`` (:data:`BOUND_TEXT`). ``resolution``: the checks of
    :func:`~bayesdamper.diagnosis.findings.bound_resolution` (of the same values); a parameter they find
    unresolved at its bound, or bound on one side only, gets :data:`UNRESOLVED_TEXT` or :data:`ONE_SIDED_TEXT`
    instead, and every checked one its check (``"resolution"``)."""
    specs = _specs_by_label(names)
    checks = {(c["effect"], c["param"]): c for c in resolution or []}
    out = []
    for label in selected:
        spec = specs.get(label) or CandidateSpec(label)
        for f in spec_bound_flags(spec, fixed.get(spec.effect) or {}):
            c = checks.get((label, f["param"]))
            if c is not None and not math.isclose(c["value"], f["value"], rel_tol=1e-9):
                c = None  # a check of other values
            verdict = c["verdict"] if c is not None else "misfit"
            more = {k: c[k] for k in ("inside", "delta_deviance", "past", "delta_deviance_past")} if c else {}
            if verdict == "unresolved":
                text = UNRESOLVED_TEXT.format(effect=label, level=FLAT_DEVIANCE, **more, **f)
            elif verdict == "one-sided":
                text = ONE_SIDED_TEXT.format(effect=label, level=FLAT_DEVIANCE, relation="at least" if f["side"] ==
                                             "upper" else "at most", **more, **f)
            else:
                text = BOUND_TEXT.format(effect=label, **f)
            row = {"effect": label, **f, "text": text}
            if c is not None:
                row["resolution"] = {**more, "verdict": verdict}
            out.append(row)
    return out


def annotate_bounds(rounds: list, names: list) -> None:
    """Add ``at_bound`` (:func:`bayesdamper.diagnosis.candidates.bound_flags`) to every candidate row of ``rounds``
    from its parameters' estimates (keys ``param`` of a single fit, ``label.param`` of a joint one)."""
    specs = _specs_by_label(names)
    for rnd in rounds:
        for row in rnd.get("candidates") or []:
            flags = []
            for key, est in (row.get("params") or {}).items():
                label, name = key.rsplit(".", 1) if "." in key else (row.get("effect", ""), key)
                spec = specs.get(label)
                value = (est or {}).get("median") if isinstance(est, dict) else None
                if spec is None or value is None:
                    continue
                flags += [{**f, "param": key} for f in spec_bound_flags(spec, {name: value})]
            row["at_bound"] = flags


def _take_search_cost() -> tuple[dict, dict]:
    """The profile searches' cost per stage so far (:func:`bayesdamper.diagnosis.candidates.search_cost`) and the
    select-and-refit loop's per step (:func:`bayesdamper.diagnosis.global_stage.search_cost_by_step`), the tallies
    then started afresh for the next diagnosis of the process."""
    out = search_cost(), search_cost_by_step()
    reset_search_cost()
    return out


def summarise_diagnosis(ds, windows, base, final, base_resid, final_resid, noise, noises, rows, structure,
                        signature, rounds, selected, fixed, names, settings, final_settings, credible_mass: float,
                        seed: int, prov: dict, bound_checks: list | None = None) -> dict:
    """The diagnosis as plain values (``diagnosis.json``): everything :func:`bayesdamper.run.diagnose.run_diagnosis`
    computed, with J before and after per window and per speed (and kind of step, :func:`j_by_speed`), drift before
    and after, the structure of the residual after, the selected effects' parameters on a bound (``findings``,
    :func:`bound_findings`, with the search's ``bound_checks`` of them; every candidate row of ``rounds`` gets its
    ``at_bound``) and the searches' cost per stage.
    """
    forces = [w.force for w in windows]
    base_entries = [r.entry for r in base]
    final_entries = [r.entry for r in final]
    after_rows = []
    for w, r, nz in zip(windows, final_resid, noises, strict=True):
        rate = 1.0 / float(np.median(np.diff(w.time)))
        after_rows.append(structure_test(r, rate, nz) | describe_residual(w.time - w.t_step, r, w.force, rate)
                          | {"id": w.id, "velocity_m_s": w.velocity, "direction": w.direction, "kind": w.kind})
    annotate_bounds(rounds, names)
    per_velocity = {}
    for v in sorted({round(w.velocity, 6) for w in windows}):
        idx = [i for i, w in enumerate(windows) if round(w.velocity, 6) == v]
        per_velocity[f"{v * 1e3:.2f}"] = {
            "before": pooled_j([base_resid[i] for i in idx], [forces[i] for i in idx]),
            "after": pooled_j([final_resid[i] for i in idx], [forces[i] for i in idx])}
    return {
        "dataset": ds.name,
        "noise_N": noise["sigma_N"],
        "noise": noise,
        "baseline": {"J_pooled": pooled_j(base_resid, forces), "J_pooled_ls": pooled_j_ls(base_entries, forces),
                     "J": {e["id"]: e["J"] for e in base_entries}},
        "candidates": rounds[0]["candidates"] if rounds else [],
        "rounds": rounds,
        "selected": selected,
        "selected_params": fixed,
        "final": {"J_pooled": pooled_j(final_resid, forces), "J_pooled_ls": pooled_j_ls(final_entries, forces),
                  "J": {e["id"]: e["J"] for e in final_entries},
                  # where each window's point fit started: its own start or the search's optimum of the model
                  "started_from": {e["id"]: e.get("start", "own") for e in final_entries}},
        "J_pooled_by_velocity_mm_s": per_velocity,
        "J_by_speed": j_by_speed(windows, base_resid, final_resid, base_entries, final_entries),
        "findings": bound_findings(selected, fixed, names, bound_checks),
        "p_R_split": {"before": p_r_split(base_entries), "after": p_r_split(final_entries)},
        "drift_before": drift_summary(base_entries, credible_mass, seed) if len(base_entries) >= 3 else {},
        "drift_after": drift_summary(final_entries, credible_mass, seed) if len(final_entries) >= 3 else {},
        "structure_before": {"summary": structure, "transients": rows},
        "residual_dynamics": signature,
        "structure_after": {"summary": _summarise_structure(after_rows), "transients": after_rows},
        "criterion": {"name": "delta_BIC_eff", "select_at_or_below": SELECT_DELTA_BIC,
                      "structure_test": f"F test of {SMOOTH_S} s moving-average residual vs the noise "
                                        f"(plateaus, else each window's own estimate), alpha {STRUCTURE_ALPHA}"},
        "windows": [w.as_dict() for w in windows],
        "search": {"cycle_windows": f"the first {SEARCH_CYCLES:g} cycles (at least {SEARCH_MIN_S:g} s) of each window "
                                    "of whole cycles, at most " f"{MAX_SEARCH_SAMPLES} samples; the grid stage on "
                                    f"the first {SCREEN_CYCLES:g} cycle(s) (at least {SCREEN_MIN_S:g} s) with the "
                                    "flow coefficients held at the baseline's",
                   "candidates_J": "the candidates' J are over the search's samples; J before and after are over "
                                   "every sample",
                   **dict(zip(("cost_by_stage", "cost_by_step"), _take_search_cost(), strict=True)),
                   "cost_note": "seconds and evaluations (re-fits of every window of a stage's objective) of the "
                                "profile searches per stage since the process's previous diagnosis was summarised "
                                "(a diagnose command: this run); per step of the select-and-refit loop its wall "
                                "time, the searches run in it and their evaluations"},
        "final_segments": final_entries,
        "settings": settings.as_dict(), "final_settings": final_settings.as_dict(), "seed": seed,
        "effects_considered": [getattr(n, "label", n) for n in names],
        "unnamed_candidates": [{"label": n.label, "structure": n.extra, "reading": n.reading,
                                "search": {k: [v.lower, v.upper] for k, v in n.overrides.items()}}
                               for n in names if not isinstance(n, str) and n.effect == GENERIC],
        "search_starts": {n.label: n.starts for n in names if not isinstance(n, str) and n.starts},
        "provenance": prov,
    }


def none_selected_lines(candidates: list[dict]) -> list[str]:
    """Why a round selected nothing, from its candidates (best first): which options pass the criterion in sample
    and why each is not selected (the held-out speeds, a generic option not named, or not scored out of sample),
    and what the best candidate lacks."""
    lines: list[str] = []
    passing = [c for c in candidates if c.get("supported")]
    if not passing:
        lines.append(f"Selected: none - no candidate passes both delta-BIC_eff <= {SELECT_DELTA_BIC:g} and a "
                     f"{MIN_J_REDUCTION:.0%} reduction of the pooled J.")
    else:
        why = {"not the held-out speeds": [c for c in passing if "lovo" in c and not c.get("not_named")],
               "not named: a physical explanation predicts the held-out speeds as well":
                   [c for c in passing if c.get("not_named")],
               "not scored out of sample (ranked below those scored)": [c for c in passing if "lovo" not in c]}
        parts = [f"{', '.join(c['effect'] for c in cs)}: {w}" for w, cs in why.items() if cs]
        lines.append(f"Selected: none - passing delta-BIC_eff <= {SELECT_DELTA_BIC:g} and a "
                     f"{MIN_J_REDUCTION:.0%} reduction of the pooled J in sample: {'; '.join(parts)}.")
    if candidates:
        c = candidates[0]
        inc = c.get("over_better_member")
        if not c.get("supported") and inc and c["score"] <= SELECT_DELTA_BIC and \
                c.get("J_reduction", 0.0) >= MIN_J_REDUCTION:
            lines.append(f"Best candidate: {c['effect']} (delta-BIC_eff {c['score']:+.0f}, J "
                         f"-{c['J_reduction']:.0%}) does not pass over its better member {inc['member']} "
                         f"(delta-BIC_eff {inc['delta_BIC_eff']:+.0f}, J -{inc['J_reduction']:.0%}; "
                         f"{MIN_J_REDUCTION:.0%} asked): the second effect does not earn its place.")
        elif c.get("supported") and "lovo" in c:
            folds = ", ".join(f"{g:+.0f}" for g in c["lovo"]["per_fold"])
            lines.append(f"Best candidate: {c['effect']} (delta-BIC_eff {c['score']:+.0f}, J "
                         f"-{c.get('J_reduction', float('nan')):.0%}) is supported in sample but does not "
                         f"predict every held-out speed better (folds {folds}).")
        else:
            lines.append(f"Best candidate: {c['effect']} (delta-BIC_eff {c['score']:+.0f}) lowers the pooled J "
                         f"by only {c.get('J_reduction', float('nan')):.0%}: the structure is real but none of "
                         "the library's effects reproduces it.")
    return lines


def zero_lines(d: dict) -> list[str]:
    """The report's line on the force channel's zero where the diagnosis removed one (``load_cell_zero_N``)."""
    zero = d.get("load_cell_zero_N")
    if not (zero and zero.get("removed")):
        return []
    return [f"Load cell zero: the plateaus' intercepts measure F_0 = {zero['offset_N']:.1f} ± "
            f"{zero['offset_se_N']:.1f} N (and a Coulomb friction of {zero['friction_N']:.1f} ± "
            f"{zero['friction_se_N']:.1f} N); F_0 was removed from every force before the diagnosis."]


def report_text(d: dict) -> str:
    """A short plain-text account of what the diagnosis found."""
    s = d["structure_before"]["summary"]
    lines = [f"Diagnosis of {d['dataset']!r}: plateau noise {d['noise_N']:.1f} N.",
             f"Baseline eq. (7): pooled J = {d['baseline']['J_pooled']:.4f}; {s['n_structured']} of "
             f"{s['n_transients']} transient residuals are structured (F test, alpha {STRUCTURE_ALPHA}); "
             f"residual rms grows with speed as v^{s['rms_vs_speed_log_slope']:.2f}, centroid "
             f"{s['median_t_centroid_s']:.2f} s after the step, dominant frequency "
             f"{s['median_peak_frequency_Hz']:.2f} Hz."]
    lines += zero_lines(d)
    off = d.get("stage1_offset_N")
    if off:
        lines.append(f"Stage 1: the plateaus hold a constant force offset F_0 = {off['value']:.1f} ± {off['se']:.1f} N "
                     f"(an unzeroed load cell or a preload; eq. (4) alone needed {', '.join(off['held_at_zero'])} "
                     "held at 0); the windows' baseline has no offset, the candidates test it (load_cell_offset).")
    sig = d.get("residual_dynamics") or {}
    if sig.get("summary"):
        lines.append(f"Residual dynamics (leave-one-speed-out, from the model's own signals): {sig['summary']}.")
        cb, ca = sig.get("cross_correlation_before"), sig.get("cross_correlation_after")
        if cb and ca:
            lines.append(f"Residual-{cb['driver']} cross-correlation outside its 95 % band at "
                         f"{cb['fraction_outside']:.0%} of lags before, {ca['fraction_outside']:.0%} after.")
    if d["candidates"]:
        ranked = ", ".join(f"{c['effect']} ({c['score']:+.0f})" for c in d["candidates"][:8])
        lines.append(f"Candidates, first round, by delta-BIC_eff (select <= {SELECT_DELTA_BIC:g}): {ranked}"
                     + (f" and {len(d['candidates']) - 8} more" if len(d["candidates"]) > 8 else "") + ".")
        if d.get("rounds"):
            lines.append(f"Rule: {d['rounds'][0].get('rule', '')}.")
    for r in d.get("rounds", []):
        for c in r["candidates"]:
            if "lovo" in c:
                name = (f"{c['effect']} (selected as {c['variant_of']}, whose held-out gain this is)"
                        if "variant_of" in c else c["effect"])
                lines.append(f"  round {d['rounds'].index(r) + 1}: {name}: leave-velocities-out gain "
                             f"{c['lovo']['gain']:+.1f} (se {c['lovo']['se']:.1f}), J {c['J_pooled']:.4f}"
                             + (" <- selected" if c["effect"] == r.get("selected") else ""))
            if "against_runner_up" in c:
                a = c["against_runner_up"]
                lines.append(f"    evidence against the runner-up {a['runner_up']}: {a['gain']:+.1f} "
                             f"(se {a['se']:.1f})")
    lines += last_resort_lines(d.get("rounds", []))
    lines += basins_lines(d.get("rounds", []))
    for r in (d.get("rounds") or [])[-1:]:
        for b in r.get("backward_check") or []:
            lines.append(f"Backward check: {b['effect']} dropped (against the model without it delta-BIC_eff "
                         f"{b['delta_BIC_eff']:+.0f}, J -{b['J_reduction']:.0%}): a later effect explains it.")
    if d["selected"]:
        for label in d["selected"]:
            name = label.split("@", 1)[0]
            values = d["selected_params"][name]
            shown = {k: v for k, v in values.items() if k not in ("driver", "law", "placement")}
            vals = ", ".join(f"{k} = {v:.4g}" for k, v in shown.items())
            lines.append(f"Selected: {label} ({vals}): {effect_reading(label, values, EFFECTS[name].description)}")
    else:
        lines += none_selected_lines(d["candidates"])
    lines += [f"Finding: {x}" for x in findings_text(d)]
    kinds = s.get("parameters_by_kind_median", {})
    if len(kinds) == 2:
        ini, rev = kinds["initial"], kinds["reversal"]
        lines.append(f"Median p_R: {ini['p_R_Pa'] / 1e6:.2f} MPa from starts at rest vs {rev['p_R_Pa'] / 1e6:.2f} MPa "
                     f"from reversals (alpha_V {ini['alpha_V']:.0f} vs {rev['alpha_V']:.0f}): one (alpha_V, p_R) "
                     "pair does not describe both kinds of step.")
    split = d.get("p_R_split", {})
    if split.get("before") and split.get("after") and d["selected"]:
        b, a = split["before"], split["after"]
        lines.append(f"p_R split (rest vs reversal): before {b['initial_Pa'] / 1e6:.2f} vs "
                     f"{b['reversal_Pa'] / 1e6:.2f} MPa, after {a['initial_Pa'] / 1e6:.2f} vs "
                     f"{a['reversal_Pa'] / 1e6:.2f} MPa: "
                     + ("closes" if a["agrees"] else "does not close") + ".")
    lines.append(f"Pooled J before {d['baseline']['J_pooled']:.4f} -> after {d['final']['J_pooled']:.4f} at the "
                 "posterior medians" + (f"; at the least-squares optima {d['baseline']['J_pooled_ls']:.4f} -> "
                                        f"{d['final']['J_pooled_ls']:.4f}" if "J_pooled_ls" in d["final"] else "")
                 + ".")
    return "\n".join(lines)


def last_resort_lines(rounds: list) -> list[str]:
    """The report's lines on each generic option set against the best physical explanations (a round's
    ``last_resort`` record of :func:`bayesdamper.diagnosis.loop.unnamed_last_resort`)."""
    lines = []
    for r in rounds:
        lr = r.get("last_resort")
        if lr:
            rivals = ", ".join(f"{x['effect']} ({x['gain_over']:+.1f}, se {x['se']:.1f}, {x['n_folds']} folds"
                               + ("" if x["beats"] else ": not beaten") + ")" if "gain_over" in x else x["effect"]
                               for x in lr["rivals"]) or "none fitted"
            first = lr.get("pairs_fitted_before_naming") or []
            afresh = "; ".join(f"{a['effect']} ({', '.join(_afresh_text(b) for b in a['searches'])})"
                               for a in lr.get("rivals_searched_afresh") or [])
            lines.append(f"  {lr['generic']} against the best physical explanations (leave-velocities-out gains over "
                         f"each, named only when they pass the held-out rule"
                         + (f"; before it was named, also fitted: {', '.join(first)}" if first else "")
                         + (f"; before it was named, the rivals' narrow-basin effects searched afresh: {afresh}"
                            if afresh else "")
                         + f"): {rivals}: "
                         + ("named" if lr["kept"] else "not named")
                         + (f"; indistinguishable from {', '.join(lr['indistinguishable_from'])}."
                            if lr["indistinguishable_from"] else "."))
    return lines


def _afresh_text(b: dict) -> str:
    """One search afresh of :func:`~bayesdamper.diagnosis.basins.research_basins` in a few words."""
    if not b.get("continued", True):
        return f"{b['candidate']}: no better on the screening windows, the fit stands"
    return (f"{b['candidate']}: delta-BIC_eff {b['delta_BIC_eff']:+.0f} -> {b['afresh_delta_BIC_eff']:+.0f}, J "
            f"{b['J_pooled']:.4f} -> {b['afresh_J_pooled']:.4f}, " + ("replaces the fit" if b["replaced"]
                                                                     else "the fit stands"))


def basins_lines(rounds: list) -> list[str]:
    """The report's lines on each selected option's searches afresh and variants
    (:mod:`bayesdamper.diagnosis.basins`): what each found and whether the option's fit stands."""
    lines = []
    for k, r in enumerate(rounds):
        for c in (c for c in r["candidates"] if c["effect"] == r.get("selected")):
            option = c.get("variant_of", c["effect"])
            for b in c.get("basins_afresh") or []:
                head = (f"  round {k + 1}: {b['candidate']} of {option} searched afresh from the data's starts, the "
                        "option's other effects at its optimum: ")
                if "subset_delta_BIC_eff" in b:
                    head += (f"on the screening windows delta-BIC_eff {b['subset_delta_BIC_eff']:+.0f} -> "
                             f"{b['subset_afresh_delta_BIC_eff']:+.0f}, ")
                if not b.get("continued", True):
                    lines.append(head + "no better there, not continued: the option's fit stands")
                    continue
                lines.append(head + f"J {b['J_pooled']:.4f} -> {b['afresh_J_pooled']:.4f} (delta-BIC_eff "
                             f"{b['delta_BIC_eff']:+.0f} -> {b['afresh_delta_BIC_eff']:+.0f}): "
                             + ("another basin, which replaces the option's fit" if b["replaced"]
                                else "the option's fit stands"))
            for v in c.get("variants") or []:
                lines.append(f"  round {k + 1}: {v['candidate']} of {option} searched as {v['variant']} in its "
                             f"place, the option's other effects at its optimum: J {v['J_pooled']:.4f} -> "
                             f"{v['variant_J_pooled']:.4f} (delta-BIC_eff {v['delta_BIC_eff']:+.0f} -> "
                             f"{v['variant_delta_BIC_eff']:+.0f}): " + (f"{v['variant']} replaces it" if v["replaced"]
                                                                       else "the option's fit stands"))
    return lines
