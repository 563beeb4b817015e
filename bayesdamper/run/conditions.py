"""The ``diagnose`` job of one damper recorded under several conditions (several data sets, each with a
``[condition]`` table): each condition's baseline and loop, every proposed effect fitted at every condition, one
explanation chosen on the pooled evidence, shared parameters pooled, what varies reported against the condition,
and each condition's final model calibrated with that explanation (:mod:`bayesdamper.diagnosis.conditions`).

Writes ``OUT/<data set>/`` per condition (as ``diagnose`` of one data set, with a ``conditions`` section in its
``diagnosis.json``) and ``OUT/conditions.json`` + ``OUT/conditions.txt``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.diagnosis.attribution import FOLD_ITER
from bayesdamper.diagnosis.candidates import CandidateSpec, effective_sizes, fit_joint, search_params
from bayesdamper.diagnosis.conditions import (
    describe,
    eliminate,
    parameter_table,
    pooled_values,
    shared_values,
    sharing_cost,
    trend,
    union_of,
    varies,
)
from bayesdamper.diagnosis.loop import MIN_J_REDUCTION, SELECT_DELTA_BIC
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.physics.with_effects import effect_argument
from bayesdamper.run.diagnose import finish_diagnosis, prepare_diagnosis, search_effects
from bayesdamper.run.progress import Progress
from bayesdamper.run.threads import one_blas_thread

CONDITIONS_FILE = "conditions.json"


def one_damper(datasets) -> str | None:
    """Why the data sets are not one damper under several conditions (None when they are): the same damper
    constants (names aside), and a non-empty ``[condition]`` table with the same names in each."""
    first = datasets[0]
    ref = dataclasses.replace(first.damper, name="")
    for ds in datasets[1:]:
        if dataclasses.replace(ds.damper, name="") != ref:
            return f"{ds.path}: damper constants differ from {first.path}'s"
    for ds in datasets:
        if not ds.condition:
            return f"{ds.path / 'damper.toml'}: no [condition] table (what differs between the data sets)"
        if set(ds.condition) != set(first.condition):
            return (f"{ds.path / 'damper.toml'}: [condition] names {sorted(ds.condition)} differ from "
                    f"{first.path}'s {sorted(first.condition)}")
    return None


def _keyed(fit, specs: list[CandidateSpec]) -> dict:
    """A fit's search-scale estimates keyed ``"effect.param"``."""
    if len(specs) == 1:
        return {f"{specs[0].effect}.{k}": v for k, v in fit.scales.items()}
    by_label = {sp.label: sp.effect for sp in specs}
    return {f"{by_label[k.rsplit('.', 1)[0]]}.{k.rsplit('.', 1)[1]}": v for k, v in fit.scales.items()}


def _union_fit(p, union: list[str], specs: dict, own_selected: list, own_fixed: dict, progress) -> dict:
    """Condition ``p``'s fit of the whole union (module docstring of :mod:`bayesdamper.diagnosis.conditions`; the
    effects its own loop selected start from its values, the others from their grids): the table the elimination
    reads (SSE per subset, N_c, Σ F²) and the fits' effect values."""
    engine = p.engine()
    try:
        base_sse, _, resid = engine.evaluate(effect_argument({}), None, keep=True)
        forces = p.forces
        n_eff0 = effective_sizes([r if r is not None else f for r, f in zip(resid, forces, strict=True)])
        start = {lab: own_fixed[specs[lab].effect] for lab in union if lab in own_selected}
        progress(f"conditions: {p.ds.name}: fitting {' + '.join(union)} jointly")
        full = fit_joint(engine, [specs[lab] for lab in union], start, {}, base_sse, n_eff0, p.flow_for,
                         effect_argument, new=tuple(union))
        _, _, r_full = engine.evaluate(effect_argument(full.effects), p.flow_for(full.effects))
        n_c = float(effective_sizes([r if r is not None else f for r, f in zip(r_full, forces, strict=True)]).sum())
    finally:
        engine.close()
    return {"sse": {(): float(np.sum(base_sse)), tuple(union): float(np.sum(full.sse))}, "n_eff": n_c,
            "force_ss": float(sum(float(f @ f) for f in forces)), "n_eff_baseline": float(n_eff0.sum()),
            "values": {tuple(union): full.effects}, "base_sse": base_sse, "n_eff0": n_eff0}


def _fit_subsets(p, table: dict, wanted: list[tuple], specs: dict, progress) -> None:
    """Fit the subsets of ``wanted`` that condition ``p``'s ``table`` lacks, each started from the values of the
    smallest fitted superset, and add their SSE and values to it."""
    todo = [sub for sub in wanted if sub not in table["sse"]]
    if not todo:
        return
    engine = p.engine()
    try:
        for sub in todo:
            sup = min((k for k in table["values"] if set(sub) <= set(k)), key=len)
            st = {lab: table["values"][sup][specs[lab].effect] for lab in sub}
            progress(f"conditions: {p.ds.name}: the model with {' + '.join(sub)} only")
            fit = fit_joint(engine, [specs[lab] for lab in sub], st, {}, table["base_sse"], table["n_eff0"],
                            p.flow_for, effect_argument, new=(), max_iter=FOLD_ITER)
            table["sse"][sub] = float(np.sum(fit.sse))
            table["values"][sub] = fit.effects
    finally:
        engine.close()


def _intervals(p, kept: list[str], specs: dict, values: dict, progress):
    """The kept effects' estimates at condition ``p`` with intervals from the inverse of the profile likelihood's
    Gauss-Newton information, counted with the kept model's effective sample size: ``(fit, specs, N_c)``."""
    engine = p.engine()
    try:
        eff = {specs[lab].effect: values[specs[lab].effect] for lab in kept}
        sse, _, resid = engine.evaluate(effect_argument(eff), p.flow_for(eff), keep=True)
        n_eff = effective_sizes([r if r is not None else f for r, f in zip(resid, p.forces, strict=True)])
        cand = [specs[lab] for lab in kept]
        st = {lab: values[specs[lab].effect] for lab in kept}
        progress(f"conditions: {p.ds.name}: intervals of {' + '.join(kept)}")
        fit = fit_joint(engine, cand, st, {}, sse, n_eff, p.flow_for, effect_argument, new=tuple(kept),
                        max_iter=0, marginal=True)
    finally:
        engine.close()
    return fit, cand, float(n_eff.sum())


def _sse_at(p, effect_sets: list[dict]) -> list[float]:
    """Condition ``p``'s pooled SSE at each effect set (every window's own parameters re-fitted)."""
    engine = p.engine()
    try:
        return [float(np.sum(engine.evaluate(effect_argument(e), p.flow_for(e))[0])) for e in effect_sets]
    finally:
        engine.close()


def _decide_sharing(preps, table: dict, fixed: list[dict], own_sse: list[float], n_eff: list[float],
                    progress) -> None:
    """Mark each parameter of ``table`` shared or varying (:func:`bayesdamper.diagnosis.conditions.varies`): alone
    first, then the shared ones together (the costliest made varying until they pass together)."""
    keys = [k for k, row in table.items() if "pooled" in row]
    for row in table.values():
        row["shared"] = False
    if not keys:
        return
    with progress.phase("conditions: shared or varying parameters", unit="condition") as ph:
        per_key = [[] for _ in keys]
        for p, f in zip(preps, fixed, strict=True):
            for i, s_ in enumerate(_sse_at(p, [pooled_values(table, f, [k]) for k in keys])):
                per_key[i].append(s_)
            ph.done += 1
    cost = {}
    for k, sk in zip(keys, per_key, strict=True):
        cost[k] = sharing_cost(own_sse, sk, n_eff)
        table[k]["sharing_delta_BIC"] = cost[k]
        table[k]["sharing_J_increase"] = math.sqrt(sum(sk) / sum(own_sse)) - 1.0
    shared = sorted((k for k, sk in zip(keys, per_key, strict=True) if not varies(own_sse, sk, n_eff)),
                    key=lambda k: cost[k])
    while len(shared) > 1:
        together = [_sse_at(p, [pooled_values(table, f, shared)])[0] for p, f in zip(preps, fixed, strict=True)]
        for k in shared:
            table[k]["sharing_delta_BIC_together"] = sharing_cost(own_sse, together, n_eff)
        if not varies(own_sse, together, n_eff):
            break
        shared.pop()
    for k in shared:
        table[k]["shared"] = True


def _parameters_by_condition(diagnoses: list[dict], conditions: list[dict]) -> dict:
    """α_V and p_R of each condition's final model (median over windows of the posterior medians, its standard error
    as sd / sqrt(n) of the log medians) and, where they differ, their trend against each varying condition."""
    out = {}
    for name in ("alpha_V", "p_R_Pa"):
        med, se = [], []
        for d in diagnoses:
            logs = np.log([e[name]["median"] for e in d.get("final_segments", [])])
            if logs.size == 0:
                med.append(float("nan"))
                se.append(float("inf"))
                continue
            med.append(float(np.median(logs)))
            se.append(float(np.std(logs, ddof=1) / math.sqrt(logs.size)) if logs.size > 1 else float("inf"))
        row = {"median": [math.exp(m) for m in med], "log_se": se, "trend": {}}
        z, sd = np.array(med), np.array(se)
        ok = np.isfinite(z) & np.isfinite(sd) & (sd > 0)
        for k in conditions[0]:
            x = np.array([float(c[k]) for c in conditions])
            if ok.sum() >= 2 and len(set(x[ok])) >= 2:
                row["trend"][k] = trend(x[ok], z[ok], sd[ok]) | {"per": k, "scale": "log"}
        out[name] = row
    return out


@one_blas_thread()
def run_conditions(data_dirs: list, out: str, *, seed: int = 0, effects: list[str] | None = None, workers: int = 0,
                   tmax: float = 3.0, credible_mass: float = 0.9, max_steps: int | None = None,
                   figures: bool = True, quiet: bool = False, mode: str = "auto", plans=None) -> dict:
    """``bayesdamper diagnose D1 D2 ...``: the diagnosis of one damper under several conditions (module docstring).

    Returns the contents of ``OUT/conditions.json``: the conditions, each one's own selection, the union tested at
    every condition, the elimination, the explanation kept, its parameters (shared or varying, with trends), α_V
    and p_R by condition, and J before/after per condition.
    """
    from bayesdamper.io.outputs import atomic_write_json
    from bayesdamper.run.identify import dataset_folders
    from bayesdamper.run.plan import plan_dataset

    t0 = time.perf_counter()
    progress = Progress(False if quiet else None)
    if len(data_dirs) < 2:
        raise SettingsError("several conditions need at least two data-set folders")
    plans = plans or [plan_dataset(d, tmax, mode) for d in data_dirs]
    why = one_damper([pl.ds for pl in plans])
    if why:
        raise SettingsError(f"{why}: several data sets are diagnosed together only as one damper under several "
                            "conditions; diagnose them one at a time")
    folders = dataset_folders([pl.ds for pl in plans])
    out_root = Path(out)
    if out_root.exists() and not out_root.is_dir():
        raise SettingsError(f"{out_root}: exists and is not a folder")
    conditions = [dict(pl.ds.condition) for pl in plans]
    preps = [prepare_diagnosis(d, str(out_root / f), seed=seed, effects=effects, workers=workers, tmax=tmax,
                     credible_mass=credible_mass, max_steps=max_steps, progress=progress, mode=mode, plan=pl)
             for d, f, pl in zip(data_dirs, folders, plans, strict=True)]
    own = [search_effects(p) for p in preps]
    union = union_of([sel for sel, _, _ in own])
    specs: dict = {}
    for p in preps:
        for n in p.names:
            sp = n if isinstance(n, CandidateSpec) else CandidateSpec(n)
            if sp.label in union and sp.label not in specs:
                specs[sp.label] = sp
    by_effect: dict = {}
    for lab in list(union):  # one unnamed or library form per effect: the first proposed
        if specs[lab].effect in by_effect:
            union.remove(lab)
        by_effect.setdefault(specs[lab].effect, lab)
    result = {"conditions": [{"dataset": p.ds.name, "folder": f, "path": str(p.ds.path), **{"condition": c}}
                             for p, f, c in zip(preps, folders, conditions, strict=True)],
              "own_selection": [sel for sel, _, _ in own], "union": union,
              "rule": (f"backward elimination on the evidence pooled over the conditions: an effect stays when "
                       f"sum_c delta-BIC_eff <= {SELECT_DELTA_BIC:g} (its parameters counted at every condition) and "
                       f"it lowers the J pooled over every condition by >= {MIN_J_REDUCTION:.0%}; a parameter varies "
                       "with the condition when its own value per condition meets the same criterion against one "
                       "pooled value, else it is shared (alone and with the other shared ones)"),
              "seed": seed}
    kept, fixed_by_condition, table = [], [{} for _ in preps], {}
    if union:
        tables = []
        with progress.phase("conditions: every proposed effect at every condition", unit="condition") as ph:
            for p, (sel, fixed, _) in zip(preps, own, strict=True):
                tables.append(_union_fit(p, union, specs, sel, fixed, progress))
                ph.done += 1

        def need(wanted):
            for p, t in zip(preps, tables, strict=True):
                _fit_subsets(p, t, wanted, specs, progress)

        n_params = {lab: len(search_params(specs[lab])) for lab in union}
        with progress.phase("conditions: backward elimination on the pooled evidence", unit="step") as ph:
            kept, steps = eliminate(tables, union, n_params, need)
            ph.done = len(steps)
        result["elimination"] = steps
        result["sse_by_subset"] = [{"+".join(k) or "none": v for k, v in t["sse"].items()} for t in tables]
        if kept:
            per_condition, own_sse, n_kept = [], [], []
            with progress.phase("conditions: intervals per condition", unit="condition") as ph:
                for k, (p, t) in enumerate(zip(preps, tables, strict=True)):
                    fit, cand, n_c = _intervals(p, kept, specs, t["values"][tuple(kept)], progress)
                    per_condition.append(_keyed(fit, cand))
                    own_sse.append(float(np.sum(fit.sse)))
                    n_kept.append(n_c)
                    fixed_by_condition[k] = {specs[lab].effect: dict(fit.effects[specs[lab].effect]) for lab in kept}
                    ph.done += 1
            table = parameter_table(per_condition, conditions)
            _decide_sharing(preps, table, fixed_by_condition, own_sse, n_kept, progress)
            fixed_by_condition = [shared_values(table, f) for f in fixed_by_condition]
    result["kept"] = kept
    result["parameters"] = table
    units = {f"{e}.{q.name}": q.unit for e in EFFECTS for q in EFFECTS[e].params}
    result["summary_lines"] = describe(table, units)
    diagnoses = []
    for p, (_, _, rounds), fx in zip(preps, own, fixed_by_condition, strict=True):
        extra = {"conditions": {"kept": kept, "own_selection": own[preps.index(p)][0], "union": union,
                                "parameters": table, "condition": dict(p.ds.condition)}}
        diagnoses.append(finish_diagnosis(p, list(kept), fx, rounds, figures=figures, quiet=True, extra=extra))
    result["by_condition"] = [{"dataset": d["dataset"], "condition": c, "J_before": d["baseline"]["J_pooled"],
                               "J_after": d["final"]["J_pooled"], "selected_params": d["selected_params"]}
                              for d, c in zip(diagnoses, conditions, strict=True)]
    result["alpha_V_p_R"] = _parameters_by_condition(diagnoses, conditions)
    result["wall_time_s"] = time.perf_counter() - t0
    text = conditions_text(result)
    result["report_text"] = text
    atomic_write_json(out_root / CONDITIONS_FILE, result)
    (out_root / "conditions.txt").write_text(text + "\n")
    if not quiet:
        print(text)
        print(f"written to {out_root / CONDITIONS_FILE}; wall time {result['wall_time_s']:.1f} s")
    result["diagnoses"] = diagnoses  # in memory only: each condition's diagnosis.json, for the report
    return result


def conditions_text(r: dict) -> str:
    """A plain-text account of a diagnosis under several conditions."""
    names = [c["dataset"] + " (" + ", ".join(f"{k} = {v:g}" for k, v in c["condition"].items()) + ")"
             for c in r["conditions"]]
    lines = [f"One damper under {len(names)} conditions: {'; '.join(names)}."]
    for n, sel in zip(names, r["own_selection"], strict=True):
        lines.append(f"  own loop at {n}: {', '.join(sel) or 'none'}")
    lines.append(f"Tested at every condition: {', '.join(r['union']) or 'nothing (no condition selected an effect)'}.")
    for st in r.get("elimination", []):
        for row in st["rows"]:
            lines.append(f"  with {' + '.join(st['effects'])}: {row['effect']} pooled delta-BIC_eff "
                         f"{row['delta_BIC_pooled']:+.0f}, J -{row['J_reduction']:.0%} (per condition "
                         + ", ".join(f"{x:+.0f}" for x in row["delta_BIC_per_condition"]) + ")"
                         + (" -> dropped" if st["dropped"] == row["effect"] else ""))
    lines.append(f"Explanation of the damper: {', '.join(r['kept']) or 'none'}.")
    lines += r.get("summary_lines", [])
    for name, row in r.get("alpha_V_p_R", {}).items():
        vals = ", ".join(f"{m:.4g}" for m in row["median"])
        tr = "; ".join(f"log-slope {t['slope']:.3g} per {k} [{t['slope_lo']:.3g}, {t['slope_hi']:.3g}]"
                       for k, t in row["trend"].items())
        lines.append(f"{name} by condition (final model, median of windows): {vals}" + (f"; {tr}" if tr else ""))
    for b in r.get("by_condition", []):
        lines.append(f"  {b['dataset']}: pooled J {b['J_before']:.4f} -> {b['J_after']:.4f}")
    return "\n".join(lines)
