"""The select-and-refit loop: which missing effect explains the residual, and the model calibrated with it.

Stated criterion: an effect is selected only when ΔBIC_eff ≤ ``SELECT_DELTA_BIC`` = −10 ("very strong" evidence on
the Kass & Raftery scale; ΔBIC_eff of :mod:`bayesdamper.diagnosis.candidates`) AND it lowers the pooled eq. (9) error
by at least ``MIN_J_REDUCTION`` (20 %): the base model is itself only an approximation, and with thousands of samples a
smooth, tiny improvement of its mismatch is "significant" without being an effect worth adding. Out-of-sample
evidence is required too: the option's leave-velocities-out predictive gain over the current model must be positive
in every held-out fold and, with exactly ``LOVO_MIN_FOLDS_FOR_SE`` folds exceed its margin of standard errors
(Student's t: ``se_margin``; from ``LOVO_SIGN_TEST_FOLDS`` folds every fold better is itself the sign test at 3 %)
(:mod:`bayesdamper.diagnosis.attribution`), a fold whose gain is an outlier among the folds' (the Hampel identifier:
the shared parameters re-fitted without it extrapolate to its speeds out of all proportion) set aside and reported;
among the options that pass, the largest gain wins. Options are single candidates, pairs of the best ones and, in the
first round, pairs of the two-state model with the candidates that best explain what it leaves
(:func:`~bayesdamper.diagnosis.two_state_pairs.two_state_pairs`); every option re-fits the effects already selected
jointly with the new ones (in a later round the candidates are first screened with them held, :func:`screen_spec`,
and the best re-fitted jointly); a pair must also meet the criterion over its better member alone
(:func:`check_pairs`). Only the first round's singles that can still decide get the simplex that finishes a
refinement that did not converge (:func:`polish_contenders`). A generic option is set against the best physical
options out of sample (:func:`unnamed_last_resort`); where it would be named in the first round, the two-state
model's pairs with every library effect whose screen improved on the two-state model alone are fitted first
(:func:`~bayesdamper.diagnosis.two_state_pairs.physical_pairs_left`) and it is set against the physical options
again; before it is named in any round, the best physical rivals' narrow-basin effects are searched afresh as a selected
option's are (:func:`rivals_afresh`), and it is set against them again where that moved one to a better basin.
Otherwise the answer is "none". The options' searches stop at the looser tolerance that ranking needs
(:data:`~bayesdamper.diagnosis.engine.LM_DTOL_SEARCH`); the option selected has its narrow-basin effects searched
afresh and its effects' variants in their place (:mod:`bayesdamper.diagnosis.basins`), and is refined to the reported
tolerance (:data:`~bayesdamper.diagnosis.engine.LM_DTOL`), which the held-out folds keep, before its values and
intervals are taken. Rounds repeat until nothing passes (at most ``MAX_ROUNDS``); then every selected effect must meet
the criterion against the model without it (:func:`backward_check`: a later effect may explain an earlier one).
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import numpy as np

from bayesdamper.diagnosis.attribution import FOLD_ITER as LOVO_FOLD_ITER
from bayesdamper.diagnosis.attribution import (
    LOVO_LEVEL,
    LOVO_MIN_FOLDS_FOR_SE,
    LOVO_SIGN_TEST_FOLDS,
    lovo_passes,
    lovo_score,
    paired,
    runner_up,
    se_margin,
    velocity_folds,
)
from bayesdamper.diagnosis.basins import research_basins, search_variants, window_subset
from bayesdamper.diagnosis.candidates import (
    CandidateSpec,
    effective_sizes,
    fit_joint,
    pooled_j,
    search_params,
)
from bayesdamper.diagnosis.global_stage import search_step
from bayesdamper.diagnosis.spec import best_and_physical, holds_generic
from bayesdamper.diagnosis.two_state_pairs import (
    NO_INTERVALS,
    PAIR_FROM,
    TWO_STATE,
    physical_pairs_left,
    search_option,
    two_state_pairs,
)
from bayesdamper.physics.with_effects import effect_argument

#: ΔBIC at or below which a candidate effect is selected (Kass & Raftery: |ΔBIC| > 10 very strong).
SELECT_DELTA_BIC = -10.0
#: Smallest relative reduction of the pooled eq. (9) error a selected effect must achieve (a fifth of what is left):
#: statistical support alone would let a smooth, small improvement of a slightly mis-specified base model through (on
#: two-state data the mis-specification looks partly like friction).
MIN_J_REDUCTION = 0.2
MAX_ROUNDS = 3  # rounds of the select-and-refit loop
#: Physical options (by ΔBIC_eff) a generic option must beat out of sample to be named (:func:`unnamed_last_resort`).
PHYSICAL_RIVALS = 2
#: Options of a round (singles or pairs) whose leave-velocities-out gain is computed (best by ΔBIC_eff).
LOVO_OPTIONS = 3


def screen_spec(spec: CandidateSpec, earlier: dict, ts_screen: dict, sel_specs: list) -> tuple[CandidateSpec, bool]:
    """A candidate as a later round screens it: its optimum of the round before among its grid's points; and where the
    selected effects are the two-state model alone, the model the first round's two-state screen held as fitted
    alone (:func:`~bayesdamper.diagnosis.two_state_pairs.two_state_pairs`), the grid is that screen's best point and
    that optimum only (``points_only``): the grid was ranked on this model there, up to the selection's final
    refinement. Returns the spec and ``points_only``."""
    label = spec.label
    again = [ts_screen[label]] if label in ts_screen and [sp.effect for sp in sel_specs] == [TWO_STATE] else []
    points = again + ([earlier[label]] if label in earlier else [])
    return (dataclasses.replace(spec, points=tuple(points)) if points else spec), bool(again)


def polish_contenders(engine, fits: list, specs: dict, fixed: dict, current_sse, n_eff, flow_for, progress) -> None:
    """The deferred Nelder-Mead polishes of a round's single searches (``fit_joint`` with ``polish`` False), for the
    candidates whose score can still matter, in place in ``fits``.

    A candidate's score decides the round only while it is among the :data:`PAIR_FROM` best singles (the pairs'
    members; the options compared, those given out-of-sample evidence and the generic option's physical rivals are
    ranked among the best by ΔBIC_eff): a single whose refinement did not converge is polished, best first, while
    its score, an upper bound of its optimum's, lies within the largest gain any polish of the round has made of the
    :data:`PAIR_FROM`-th best single's score (with no polish made yet: within that score). Any other keeps its
    refinement's optimum, marked ``polish_pending`` in the report: polishing it could not, at the gains the round's
    polishes made, move it among the singles that decide."""
    gain = 0.0
    while True:
        singles = sorted((c for c in fits if len(c.labels) == 1), key=lambda c: c.delta_bic)
        bound = singles[PAIR_FROM - 1].delta_bic + gain if len(singles) >= PAIR_FROM else math.inf
        todo = [c for c in singles if c.polish_pending and c.delta_bic <= bound]
        if not todo:
            return
        c = todo[0]
        label = c.labels[0]
        progress(f"diagnose: polishing {label}")
        done = search_option(engine, [specs[label]], {label: c.effects[specs[label].effect]}, fixed, current_sse,
                             n_eff, flow_for, new=(label,), max_iter=0, polish=True)
        gain = max(gain, c.delta_bic - done.delta_bic)
        fits[fits.index(c)] = (dataclasses.replace(done, n_evaluations=c.n_evaluations + done.n_evaluations,
                                                   cost=c.cost) if done.delta_bic < c.delta_bic
                               else dataclasses.replace(c, polish_pending=False))


def _option_row(fit, j_cur: float) -> dict:
    return {"effect": fit.effect, "score": fit.delta_bic, "criterion": "delta_BIC_eff", "J_pooled": fit.j_pooled,
            "J_reduction": 1.0 - fit.j_pooled / j_cur, "params": fit.params,
            "supported": bool(fit.delta_bic <= SELECT_DELTA_BIC and fit.j_pooled <= (1 - MIN_J_REDUCTION) * j_cur),
            "n_profile_evaluations": fit.n_evaluations, "pair": "+" in fit.effect,
            **({"polish": "deferred: not among the singles that decide"} if fit.polish_pending else {})}


def check_pairs(rows: list[dict]) -> None:
    """A pair is supported only if it also meets the criterion over its better member alone (ΔBIC_eff of the
    pair minus the member's <= :data:`SELECT_DELTA_BIC` and a further :data:`MIN_J_REDUCTION` of the J): the
    second effect must earn its place as it would in the next round. Sets ``over_better_member``."""
    singles = {r["effect"]: r for r in rows if not r["pair"]}
    for row in rows:
        members = [singles[m] for m in row["effect"].split("+") if m in singles] if row["pair"] else []
        if len(members) == 2:
            m = min(members, key=lambda r: r["score"])
            inc = {"member": m["effect"], "delta_BIC_eff": row["score"] - m["score"],
                   "J_reduction": 1.0 - row["J_pooled"] / m["J_pooled"]}
            row["over_better_member"] = inc
            row["supported"] = bool(row["supported"] and inc["delta_BIC_eff"] <= SELECT_DELTA_BIC
                                    and inc["J_reduction"] >= MIN_J_REDUCTION)


def select_effects(engine, names: list, forces: list[np.ndarray], flow_for, progress,
                   velocities: list[float] | None = None) -> tuple[list, dict, list]:
    """The select-and-refit loop (module docstring of :mod:`bayesdamper.diagnosis.attribution` for the evidence).

    Each round: every remaining candidate is fitted (after the first round screened: its grid's best point with the
    effects already selected held at their values, the grid holding its optimum of the round before); the
    :data:`PAIR_FROM` best, and the :data:`PAIR_FROM` best library effects (generic filters can crowd them out),
    are re-fitted jointly with the selected effects (those re-fitted too), and pairs of the best are fitted jointly.
    Only joint fits are options. An option (single or pair) is *supported* by the present
    criterion when ΔBIC_eff <= :data:`SELECT_DELTA_BIC` and it lowers the pooled J by >= :data:`MIN_J_REDUCTION`.
    For the :data:`LOVO_OPTIONS` best supported options by ΔBIC_eff, and the best other option as the runner-up, the
    leave-velocities-out gain over the current model is computed (nothing when no option is supported); the rule
    selects, among the supported options that pass the out-of-sample rule (:func:`lovo_passes`), the one with the
    largest gain. Otherwise the round ends with "none".

    ``engine``: a :class:`~bayesdamper.diagnosis.candidates.ProfileEngine`; ``names``: effect names or specs;
    ``forces``: the measured forces; ``flow_for(fixed)``: flow coefficients for the effects ``fixed`` (None keeps
    stage 1's); ``velocities``: the test speeds (the folds; without them no out-of-sample evidence).
    Returns ``(selected labels, {effect: values}, rounds)``.
    """
    specs = {(n.label if isinstance(n, CandidateSpec) else n): (n if isinstance(n, CandidateSpec) else CandidateSpec(n))
             for n in names}
    search_step("current model")
    sse, xs, resid = engine.evaluate(effect_argument({}), None, keep=True)
    current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
    selected: list[str] = []
    sel_specs: list[CandidateSpec] = []
    fixed: dict = {}
    rounds = []
    # the paper's own simplification first: the two-state physics, then the library, the generic forms last
    remaining = sorted(specs, key=lambda lab: (specs[lab].effect != TWO_STATE, holds_generic(lab, specs)))
    folds = velocity_folds(list(velocities)) if velocities is not None and len(set(velocities)) > 1 else None
    earlier: dict = {}  # each candidate's optimum in the round before: a point of its next screen's grid
    ts_screen: dict = {}  # the first round's screen on the two-state model: each candidate's best point
    screens = None  # the first round's screens on the two-state model (two_state_pairs)
    for rnd in range(MAX_ROUNDS):
        if not remaining:
            break
        n_eff = effective_sizes(current["resid"])
        j_cur = pooled_j(current["resid"], forces)
        start = {sp.label: fixed[sp.effect] for sp in sel_specs}
        fits = []
        search_step("candidates screened with the selected effects held" if sel_specs else "candidates searched")
        for label in remaining:
            progress(f"diagnose: round {rnd + 1}, fitting {label}")
            # after the first round: screened with the selected effects held, by the grid (its last optimum in it) ...
            spec, again = screen_spec(specs[label], earlier, ts_screen, sel_specs)
            fits.append(search_option(engine, [spec], {}, fixed, current["sse"], n_eff, flow_for,
                                      grid_only=bool(sel_specs), polish=False, points_only=again))
            progress.advance()
        polish_contenders(engine, fits, specs, fixed, current["sse"], n_eff, flow_for, progress)
        held = set()
        if sel_specs:  # ... and the best re-fitted jointly with them (every option compared below is joint)
            held = {c.effect for c in fits}
            search_step("the best re-fitted with the selected effects")
            ranked = sorted((c for c in fits if c.delta_bic < 0), key=lambda c: c.delta_bic)
            for c in best_and_physical(ranked, specs, PAIR_FROM):
                progress(f"diagnose: round {rnd + 1}, re-fitting {c.effect} jointly with {', '.join(selected)}")
                st = dict(start)
                st[c.effect] = c.effects[specs[c.effect].effect]
                fits[fits.index(c)] = search_option(engine, sel_specs + [specs[c.effect]], st, {}, current["sse"],
                                                    n_eff, flow_for, new=(c.effect,))
                held.discard(c.effect)
        singles = sorted(fits, key=lambda c: c.delta_bic)
        seeds = [c for c in singles if c.delta_bic < 0][:PAIR_FROM]
        search_step("pairs")
        for i, a in enumerate(seeds):
            for b in seeds[i + 1:]:
                if specs[a.effect].effect == specs[b.effect].effect:
                    continue
                progress(f"diagnose: round {rnd + 1}, fitting the pair {a.effect} + {b.effect}")
                st = dict(start)
                st[a.effect] = a.effects[specs[a.effect].effect]
                st[b.effect] = b.effects[specs[b.effect].effect]
                fits.append(search_option(engine, sel_specs + [specs[a.effect], specs[b.effect]], st, {},
                                          current["sse"], n_eff, flow_for, new=(a.effect, b.effect)))
        if not sel_specs:
            search_step("two-state pairs")
            pairs, screens = two_state_pairs(engine, fits, specs, remaining, current["sse"], n_eff, flow_for,
                                             progress)
            ts_screen = screens.alone if screens is not None else {}
            fits += pairs
        fits.sort(key=lambda c: c.delta_bic)
        earlier = {c.labels[0]: dict(c.effects[specs[c.labels[0]].effect]) for c in fits
                   if len(c.labels) == 1 and c.labels[0] in specs and specs[c.labels[0]].effect in c.effects}
        rows = [_option_row(c, j_cur) for c in fits]
        check_pairs(rows)
        for row in rows:
            if row["effect"] in held:  # screened only: not an option (its fit held the selected effects)
                row["supported"] = False
                row["held_selected"] = True
        lovo_cache: dict = {}
        search_step("leave-velocities-out folds")
        for row in rows:
            row["passes"] = False
        if folds is not None and any(r["supported"] for r in rows):
            # the best supported options, and the best other option as the runner-up
            chosen = [i for i, r in enumerate(rows) if r["supported"]][:LOVO_OPTIONS]
            chosen += [next((i for i in range(len(rows)) if i not in chosen), None)]
            for c, row in [(fits[i], rows[i]) for i in chosen if i is not None]:
                progress(f"diagnose: round {rnd + 1}, leave-velocities-out evidence for {c.effect}")
                cand = sel_specs + [specs[lab] for lab in c.labels]
                sc = lovo_score(engine, folds, cand, c.effects, sel_specs, fixed, current["sse"], n_eff, flow_for,
                                effect_argument, lovo_cache)
                row["lovo"] = sc.as_dict()
                row["_lovo"] = sc
                row["passes"] = bool(row["supported"] and lovo_passes(sc))
        else:
            for row in rows:
                row["passes"] = row["supported"]
        passing = [r for r in rows if r["passes"]]
        best = max(passing, key=lambda r: r["lovo"]["gain"] if "lovo" in r else -r["score"]) if passing else None
        last_resort = None
        if best is not None and holds_generic(best["effect"], specs):
            progress(f"diagnose: round {rnd + 1}, {best['effect']} against the best physical explanations")
            search_step("generic option against the physical ones")
            generic = best
            best, last_resort = unnamed_last_resort(generic, rows, fits, specs, engine, folds, sel_specs, fixed,
                                                    current["sse"], n_eff, flow_for, lovo_cache)
            if last_resort["kept"] and not sel_specs and screens is not None:
                # before it is named in the first round: the two-state model's pairs the screens left, and again
                search_step("the two-state model's pairs left, before a generic option is named")
                more = physical_pairs_left(engine, screens, fits, specs, current["sse"], n_eff, flow_for, progress)
                if more:
                    fits += more
                    added = [_option_row(c, j_cur) for c in more]
                    rows += added
                    check_pairs(rows)
                    for row in added:  # out of sample, the last resort scores them; without folds supported passes
                        row["passes"] = bool(folds is None and row["supported"])
                    search_step("generic option against the physical ones")
                    best, last_resort = unnamed_last_resort(generic, rows, fits, specs, engine, folds, sel_specs,
                                                            fixed, current["sse"], n_eff, flow_for, lovo_cache)
                last_resort["pairs_fitted_before_naming"] = [c.effect for c in more]
            if last_resort["kept"]:  # before it is named: the physical rivals' narrow basins searched afresh
                search_step("the physical rivals' narrow-basin effects searched afresh")
                afresh = rivals_afresh(engine, rows, fits, specs, sel_specs, current["sse"], n_eff, flow_for, j_cur,
                                       folds)
                if any(a["replaced"] for r in afresh for a in r["searches"]):
                    search_step("generic option against the physical ones")
                    before = {k: v for k, v in last_resort.items() if k == "pairs_fitted_before_naming"}
                    best, last_resort = unnamed_last_resort(generic, rows, fits, specs, engine, folds, sel_specs,
                                                            fixed, current["sse"], n_eff, flow_for, lovo_cache)
                    last_resort.update(before)
                last_resort["rivals_searched_afresh"] = afresh
        rival = runner_up(rows, best)  # after the last resort: the option it selects, and every option it scored
        if best is not None and rival is not None and "_lovo" in best:
            best["against_runner_up"] = {"runner_up": rival["effect"], **paired(best["_lovo"], rival["_lovo"])}
        for r in rows:
            r.pop("_lovo", None)
        rows.sort(key=lambda r: r["score"])  # by ΔBIC_eff, with the options fitted or re-fitted after the ranking
        rounds.append({"current_J_pooled": j_cur, "current_effects": list(selected), "candidates": rows,
                       "selected": best["effect"] if best else None, "last_resort": last_resort,
                       "rule": f"supported (delta_BIC_eff <= {SELECT_DELTA_BIC:g}, J reduction >= "
                               f"{MIN_J_REDUCTION:.0%}; a pair also over its better member), every held-out speed "
                               f"fold better (from {LOVO_SIGN_TEST_FOLDS} folds: the sign test at <= 3 %) and with "
                               f"{LOVO_MIN_FOLDS_FOR_SE} folds a leave-velocities-out gain > "
                               f"{se_margin(LOVO_MIN_FOLDS_FOR_SE):.2f} se (Student's t at {LOVO_LEVEL:.1%}), a fold "
                               "whose gain is an outlier among the folds' set aside (Hampel, 3 MADs, at most a third "
                               "of them); the largest gain wins"})
        if best is None:
            break
        fit = next(c for c in fits if c.effect == best["effect"])
        search_step("the selection's narrow-basin effects searched afresh")
        search = partial(search_option, engine, fixed={}, current_sse=current["sse"], n_eff=n_eff, flow_for=flow_for,
                         new=fit.labels)
        cand = sel_specs + [specs[lab] for lab in fit.labels]
        if "basins_afresh" not in best:  # (a physical rival of a generic option has been searched afresh already)
            fit, best["basins_afresh"] = research_basins(search, fit, sel_specs, cand[len(sel_specs):],
                                                        subset=window_subset(engine))
        fit, best["variants"], added = search_variants(search, fit, sel_specs, cand[len(sel_specs):])
        if added:  # the option as selected is the rule's choice with a variant in an effect's place
            specs.update(added)
            best["variant_of"] = best["effect"]
            best["effect"] = rounds[-1]["selected"] = "+".join(fit.labels)
        cand = sel_specs + [specs[lab] for lab in fit.labels]
        # refined to LM_DTOL (the search stopped at LM_DTOL_SEARCH), intervals there (several: the others free)
        several = sum(len(search_params(sp)) for sp in cand) > 1
        progress(f"diagnose: round {rnd + 1}, intervals of {best['effect']}")
        search_step("the selection's intervals and re-fit")
        tight = fit_joint(engine, cand, {sp.label: fit.effects[sp.effect] for sp in cand}, {}, current["sse"], n_eff,
                          flow_for, effect_argument, new=fit.labels, max_iter=None if several else 0, marginal=several)
        fit = tight if tight.delta_bic <= fit.delta_bic else fit  # the refinement can only improve on the search
        best.update(score=fit.delta_bic, J_pooled=fit.j_pooled, J_reduction=1.0 - fit.j_pooled / j_cur)
        best["params"] = tight.params
        best["intervals"] = ("marginal: inverse of the profile likelihood's Gauss-Newton information" if several
                             else "the profile likelihood's Gauss-Newton information")
        for lab in fit.labels:
            selected.append(lab)
            sel_specs.append(specs[lab])
        fixed = {k: dict(v) for k, v in fit.effects.items()}
        chosen = {specs[lab].effect for lab in fit.labels} | {specs[v["candidate"]].effect for v in best["variants"]}
        remaining = [n for n in remaining if specs[n].effect not in chosen]
        engine.set_warm(fit.warm)
        sse, xs, resid = engine.evaluate(effect_argument(fixed), flow_for(fixed), keep=True)
        current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
    if len(selected) > 1:
        search_step("backward check")
        selected, sel_specs, fixed, dropped = backward_check(engine, selected, sel_specs, fixed, current, forces,
                                                             flow_for, progress)
        if rounds:
            rounds[-1]["backward_check"] = dropped
    search_step(None)
    return selected, fixed, rounds


def unnamed_last_resort(best: dict, rows: list[dict], fits: list, specs: dict, engine, folds, sel_specs: list,
                        fixed: dict, current_sse, n_eff, flow_for, cache: dict) -> tuple[dict | None, dict]:
    """The generic option ``best`` against the best physical explanations (library effects and the two-state model,
    alone or in pairs): it stays selected only if it beats each of the :data:`PHYSICAL_RIVALS` best physical options
    (by ΔBIC_eff) out of sample: its per-fold gains over the rival pass the same rule as an option's gains over the
    current model (:func:`~bayesdamper.diagnosis.attribution.paired`: every fold better, and with 4 folds a sum
    above Student's t at 2.3 %). Otherwise the physical option that
    passes the rule with the largest gain is selected instead; when no rival passes (the rivals need not pass the
    rule themselves: a pair that fails its check over its better member), the :data:`LOVO_OPTIONS` best supported
    physical options are scored out of sample and the one of them that passes with the largest gain is selected,
    or none. Without speed folds there is no out-of-sample comparison: a physical option that passes wins. Returns
    the option selected and a record (``generic``, ``level``, each rival's paired gain, se and folds,
    ``indistinguishable_from``, ``kept``, and ``fallback``: the supported physical options scored besides)."""
    def score(r):  # the option's leave-velocities-out score, computed once
        if "_lovo" not in r:
            fit = next(c for c in fits if c.effect == r["effect"])
            r["_lovo"] = lovo_score(engine, folds, sel_specs + [specs[lab] for lab in fit.labels], fit.effects,
                                    sel_specs, fixed, current_sse, n_eff, flow_for, effect_argument, cache)
            r["lovo"] = r["_lovo"].as_dict()
            r["passes"] = bool(r["supported"] and lovo_passes(r["_lovo"]))

    mine = [r for r in rows if not holds_generic(r["effect"], specs) and not r.get("held_selected")]
    physical = sorted(mine, key=lambda r: r["score"])[:PHYSICAL_RIVALS]
    record = {"generic": best["effect"], "level": LOVO_LEVEL, "rivals": [], "indistinguishable_from": []}
    kept = True
    for r in physical:
        if folds is None or "_lovo" not in best:
            kept = kept and not r["passes"]
            record["rivals"].append({"effect": r["effect"], "passes": r["passes"]})
            continue
        score(r)
        pr = paired(best["_lovo"], r["_lovo"])
        beats = pr["beats"]
        record["rivals"].append({"effect": r["effect"], "passes": r["passes"], "gain_over": pr["gain"],
                                 "se": pr["se"], "n_folds": pr["n"], "beats": beats})
        if not beats:
            record["indistinguishable_from"].append(r["effect"])
        kept = kept and beats
    record["kept"] = kept
    if kept:
        return best, record
    best["passes"] = False
    best["not_named"] = "a physical explanation predicts the held-out speeds as well"
    passing = [r for r in physical if r["passes"]]
    if not passing:  # rivals that cannot be selected (pairs failing their check over their better member): the
        # best supported physical options are scored, so that an explanation the rule accepts is not lost behind them
        fallback = sorted((r for r in mine if r["supported"] and r not in physical), key=lambda r: r["score"])
        fallback = fallback[:LOVO_OPTIONS]
        for r in fallback:
            if folds is not None:
                score(r)
        record["fallback"] = [{"effect": r["effect"], "passes": r["passes"]} for r in fallback]
        passing = [r for r in fallback if r["passes"]]
    return (max(passing, key=lambda r: r["lovo"]["gain"] if "lovo" in r else -r["score"]) if passing else None), record


def rivals_afresh(engine, rows: list[dict], fits: list, specs: dict, sel_specs: list, current_sse, n_eff, flow_for,
                  j_cur: float, folds) -> list[dict]:
    """The :data:`PHYSICAL_RIVALS` best physical options of a round whose generic option is about to be named, each
    with its narrow-basin effects searched afresh (:func:`~bayesdamper.diagnosis.basins.research_basins`, first on the
    screening windows) as the option a round selects is: the generic option is named only over physical explanations
    that reached their form's best basin, not over a valve whose refinement ended a basin away. A rival whose search
    afresh replaces its fit (ΔBIC_eff lower by more than 10) gets the new fit in ``fits`` and its row re-made (its
    out-of-sample score dropped, for the last resort to compute again; without speed folds it passes when supported);
    the pairs' check over their better member is re-applied. Each rival searched keeps the searches in its row
    (``basins_afresh``): selected, it is not searched afresh again.
    Returns a record per rival searched: ``{"effect", "searches": research_basins' rows}``."""
    mine = [r for r in rows if not holds_generic(r["effect"], specs) and not r.get("held_selected")]
    out, remade = [], []
    for row in sorted(mine, key=lambda r: r["score"])[:PHYSICAL_RIVALS]:
        i = next(k for k, c in enumerate(fits) if c.effect == row["effect"])
        fit = fits[i]
        new = [specs[lab] for lab in fit.labels]
        search = partial(search_option, engine, fixed={}, current_sse=current_sse, n_eff=n_eff, flow_for=flow_for,
                         new=fit.labels)
        again, searches = research_basins(search, fit, sel_specs, new, subset=window_subset(engine))
        if not searches:  # no narrow-basin effect in the option
            continue
        out.append({"effect": row["effect"], "searches": searches})
        if again is not fit:
            fits[i] = again
            for key in ("_lovo", "lovo", "passes", "over_better_member"):
                row.pop(key, None)
            row.update(_option_row(again, j_cur))
            remade.append(row)
        row["basins_afresh"] = searches  # selected, it is not searched afresh again
    check_pairs(rows)
    for row in remade:
        row["passes"] = bool(folds is None and row["supported"])
    return out


def backward_check(engine, selected: list, sel_specs: list, fixed: dict, current: dict, forces, flow_for,
                   progress) -> tuple[list, list, dict, list]:
    """Drop a selected effect that a later selection made redundant: for each, the model without it (the others
    re-fitted jointly) against the full model by the present criterion (ΔBIC_eff of adding it back <=
    :data:`SELECT_DELTA_BIC` and a further :data:`MIN_J_REDUCTION` of the pooled J, as a pair's second member must
    earn its place); the weakest that fails is dropped and the check repeats. Returns the kept labels, their specs,
    their values and a row per effect dropped."""
    dropped = []
    while len(selected) > 1:
        n_eff = effective_sizes(current["resid"])
        j_full = pooled_j(current["resid"], forces)
        rows = []
        for lab in selected:
            others = [sp for sp in sel_specs if sp.label != lab]
            progress(f"diagnose: backward check, the model without {lab}")
            st = {sp.label: fixed[sp.effect] for sp in others}
            red = fit_joint(engine, others, st, {}, current["sse"], n_eff, flow_for, effect_argument, new=(),
                            max_iter=LOVO_FOLD_ITER, intervals_to=NO_INTERVALS)
            n_lab = len(search_params(next(sp for sp in sel_specs if sp.label == lab)))
            score = -red.delta_bic + n_lab * float(np.log(max(float(n_eff.sum()), 1.0)))
            rows.append({"effect": lab, "delta_BIC_eff": score, "J_without": red.j_pooled,
                         "J_reduction": 1.0 - j_full / red.j_pooled, "fit": red})
        weak = [r for r in rows if not (r["delta_BIC_eff"] <= SELECT_DELTA_BIC and r["J_reduction"] >= MIN_J_REDUCTION)]
        if not weak:
            break
        worst = max(weak, key=lambda r: r["delta_BIC_eff"])
        red = worst.pop("fit")
        dropped.append({k: v for k, v in worst.items() if k != "fit"})
        keep = [i for i, lab in enumerate(selected) if lab != worst["effect"]]
        selected = [selected[i] for i in keep]
        sel_specs = [sel_specs[i] for i in keep]
        fixed = {k: dict(v) for k, v in red.effects.items()}
        engine.set_warm(red.warm)
        sse, _, resid = engine.evaluate(effect_argument(fixed), flow_for(fixed), keep=True)
        current = {"sse": sse, "resid": [r if r is not None else f for r, f in zip(resid, forces, strict=True)]}
    return selected, sel_specs, fixed, dropped
