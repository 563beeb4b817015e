"""One damper under several conditions: one explanation for all of them, and what moves with the condition.

Data sets of one damper recorded under different conditions (a charge pressure, a temperature, a valve setting:
each data set's ``[condition]`` table) are diagnosed together. Each condition's own select-and-refit loop
(:mod:`bayesdamper.diagnosis.loop`) proposes effects; every effect any condition selected is then fitted at every
condition (an effect found under one condition is tested under all), each condition keeping its own effect
parameters and its own (α_V, p_R) per window. The damper's explanation is chosen by backward elimination on the
evidence pooled over the conditions:

    ΔBIC_pool(e | E) = Σ_c [ N_c log(S_c(E) / S_c(E \\ e)) + n_e log N_c ],

with S_c the pooled SSE of condition c's windows with the effects E re-fitted there, N_c its effective sample
size (Quenouille, from the residuals of the full union's fit) and n_e the parameters of e; e stays when
ΔBIC_pool ≤ :data:`~bayesdamper.diagnosis.loop.SELECT_DELTA_BIC` and it lowers the J pooled over every
condition's windows by at least :data:`~bayesdamper.diagnosis.loop.MIN_J_REDUCTION`, the same criterion one
condition's loop applies. The weakest effect that fails is dropped and the check repeats. Counting n_e at every
condition is conservative for an effect whose parameters are in truth shared. The out-of-sample part of the rule
(leave-velocities-out) is not repeated here: every effect of the union passed it where it was selected.

What varies: each kept effect parameter is estimated at every condition (profile likelihood with the kept
model's effective sample size, intervals from the full Hessian, on the parameter's search scale: log for scale
parameters, linear for signed ones like a force offset). It *varies with the condition* when its own value at
each condition, against one value for all (its inverse-variance pooled value at every condition, each window's own
parameters re-fitted), meets the criterion an effect must meet to be added: C − 1 more parameters that pay for
themselves,

    ΔBIC_share = Σ_c N_c log(S_c(pooled) / S_c(own)) − (C − 1) log N̄  ≥  −SELECT_DELTA_BIC,

and lower the J pooled over the conditions by at least MIN_J_REDUCTION (with thousands of samples a difference
of a few per mille in a mis-specified parameter is "significant" without being a change of the damper). Otherwise
it is *shared*; several shared parameters must also pass together. S_c(pooled) without re-fitting the other effect
parameters over-states the cost of sharing, so the rule leans to "varies".
A shared parameter takes its pooled value at every condition; one that varies keeps each condition's value, and its
straight-line trend against every numeric condition that differs between the data sets is reported (weighted
least squares; the slope's standard error scaled up by the residual heterogeneity when that exceeds one, the
multiplicative random-effects form of meta-regression). Cochran's Q of the estimates is reported beside it.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from bayesdamper.diagnosis.loop import MIN_J_REDUCTION, SELECT_DELTA_BIC

#: Level at which Cochran's Q (reported beside the decision) calls a parameter's estimates heterogeneous.
HETEROGENEITY_ALPHA = 0.05
#: Largest union of effects fitted at every condition (the elimination fits the union and, per step, the model
#: without each remaining effect: at most k (k + 1) / 2 + 1 joint fits per condition); a larger union keeps the
#: effects selected at the most conditions, then the first selected.
MAX_UNION = 4
#: Two-sided normal quantile of the reported 90 % intervals.
Z90 = 1.6448536269514722


def union_of(selections: list[list[str]]) -> list[str]:
    """The effects selected at any condition: by the number of conditions that selected them, then by the order they
    were first selected; at most :data:`MAX_UNION`."""
    first: dict[str, tuple[int, int]] = {}
    count: dict[str, int] = {}
    for c, sel in enumerate(selections):
        for i, lab in enumerate(sel):
            count[lab] = count.get(lab, 0) + 1
            first.setdefault(lab, (c, i))
    return sorted(count, key=lambda lab: (-count[lab], first[lab]))[:MAX_UNION]


def eliminate(tables: list[dict], labels: list[str], n_params: dict, need=None) -> tuple[list[str], list[dict]]:
    """Backward elimination on the evidence pooled over the conditions (module docstring).

    ``tables``: per condition ``{"sse": {subset tuple (in ``labels``' order; () the model without effects):
    pooled SSE [N²]}, "n_eff": N_c, "force_ss": Σ F² [N²]}``; ``n_params``: label -> number of parameters;
    ``need(subsets)``: called before a step with the subsets it reads, to fit those the tables lack (None: the
    tables hold them all). Returns the kept labels and one row per step (every effect's pooled score, the one
    dropped).
    """
    keep = list(labels)
    steps = []
    force_ss = sum(t["force_ss"] for t in tables)
    while keep:
        full = tuple(keep)
        if need is not None:
            need([full] + [tuple(x for x in keep if x != lab) for lab in keep])
        rows = []
        for lab in keep:
            without = tuple(x for x in keep if x != lab)
            per = [t["n_eff"] * math.log(t["sse"][full] / t["sse"][without]) + n_params[lab] * math.log(t["n_eff"])
                   for t in tables]
            j_full = math.sqrt(sum(t["sse"][full] for t in tables) / force_ss)
            j_without = math.sqrt(sum(t["sse"][without] for t in tables) / force_ss)
            red_c = [1.0 - math.sqrt(t["sse"][full] / t["sse"][without]) for t in tables]
            rows.append({"effect": lab, "delta_BIC_pooled": float(sum(per)), "delta_BIC_per_condition": per,
                         "J_without": j_without, "J_with": j_full, "J_reduction": 1.0 - j_full / j_without,
                         "J_reduction_per_condition": red_c})
        weak = [r for r in rows if not (r["delta_BIC_pooled"] <= SELECT_DELTA_BIC
                                        and r["J_reduction"] >= MIN_J_REDUCTION)]
        worst = max(weak, key=lambda r: r["delta_BIC_pooled"]) if weak else None
        steps.append({"effects": list(keep), "rows": rows, "dropped": worst["effect"] if worst else None})
        if worst is None:
            break
        keep.remove(worst["effect"])
    return keep, steps


def _physical(scale: dict, z: float) -> float:
    return scale["sign"] * math.exp(z) if scale["log"] else z


def heterogeneity(z: np.ndarray, sd: np.ndarray) -> dict:
    """Cochran's Q of estimates ``z`` with standard errors ``sd``: the pooled value, its sd, Q, its p-value."""
    w = 1.0 / sd**2
    zbar = float(np.sum(w * z) / np.sum(w))
    q = float(np.sum(w * (z - zbar) ** 2))
    df = z.size - 1
    return {"pooled": zbar, "pooled_sd": float(1.0 / math.sqrt(np.sum(w))), "Q": q, "df": df,
            "p_value": float(stats.chi2.sf(q, df)) if df > 0 else 1.0}


def trend(x: np.ndarray, z: np.ndarray, sd: np.ndarray) -> dict:
    """Weighted straight line z = a + b x: slope, its standard error (scaled by sqrt(Q_res / (C - 2)) when that
    exceeds one) and its 90 % interval."""
    w = 1.0 / sd**2
    X = np.column_stack([np.ones_like(x), x])
    A = X.T @ (w[:, None] * X)
    cov = np.linalg.inv(A)
    beta = cov @ (X.T @ (w * z))
    resid = z - X @ beta
    q_res = float(np.sum(w * resid**2))
    scale = math.sqrt(q_res / (x.size - 2)) if x.size > 2 else 1.0
    se = math.sqrt(cov[1, 1]) * max(scale, 1.0)
    b = float(beta[1])
    return {"intercept": float(beta[0]), "slope": b, "slope_se": se, "slope_lo": b - Z90 * se,
            "slope_hi": b + Z90 * se, "Q_residual": q_res}


def parameter_table(per_condition: list[dict], conditions: list[dict]) -> dict:
    """What is shared and what varies: ``per_condition[c]`` maps each parameter key to its search-scale estimate
    (:attr:`bayesdamper.diagnosis.candidates.CandidateFit.scales`); ``conditions[c]`` is condition c's
    ``{name: value}``. Returns per key: the per-condition values and 90 % intervals, the Q test, ``shared``, the
    pooled value (shared) or the trend against each condition that differs (varying)."""
    keys = list(per_condition[0])
    varying_conditions = [k for k in conditions[0]
                          if all(k in c for c in conditions) and len({c[k] for c in conditions}) > 1]
    out = {}
    for key in keys:
        sc = [pc[key] for pc in per_condition]
        z = np.array([s["z"] for s in sc])
        sd = np.array([s["sd"] if math.isfinite(s["sd"]) and s["sd"] > 0 else np.inf for s in sc])
        values = [{"median": _physical(s, s["z"]),
                   "lo": min(_physical(s, s["z"] - Z90 * s["sd"]), _physical(s, s["z"] + Z90 * s["sd"])),
                   "hi": max(_physical(s, s["z"] - Z90 * s["sd"]), _physical(s, s["z"] + Z90 * s["sd"])),
                   "at_bound": s.get("at_bound", False)} for s in sc]
        row = {"values": values, "scale": "log" if sc[0]["log"] else "linear"}
        finite = np.isfinite(sd)
        if finite.sum() < 2:
            row.update(shared=False, reason="fewer than two conditions with a finite standard error")
            out[key] = row
            continue
        h = heterogeneity(z[finite], sd[finite])
        row["heterogeneity"] = h | {"heterogeneous": bool(h["p_value"] < HETEROGENEITY_ALPHA)}
        row["shared"] = None  # decided by the fit (:func:`sharing_cost`)
        s0 = sc[0]
        row["pooled"] = {"median": _physical(s0, h["pooled"]),
                         "lo": min(_physical(s0, h["pooled"] - Z90 * h["pooled_sd"]),
                                   _physical(s0, h["pooled"] + Z90 * h["pooled_sd"])),
                         "hi": max(_physical(s0, h["pooled"] - Z90 * h["pooled_sd"]),
                                   _physical(s0, h["pooled"] + Z90 * h["pooled_sd"]))}
        if finite.sum() >= 2:
            row["trend"] = {}
            for k in varying_conditions:
                x = np.array([float(c[k]) for c in conditions])[finite]
                if len(set(x)) < 2:
                    continue
                t = trend(x, z[finite], sd[finite])
                t["per"] = k
                t["scale"] = row["scale"]
                row["trend"][k] = t
        out[key] = row
    return out


def sharing_cost(own: list[float], pooled: list[float], n_eff: list[float]) -> float:
    """ΔBIC_share (module docstring): per condition the SSE with each condition's own value ``own``, with the pooled
    value ``pooled``, and the effective sample size ``n_eff``."""
    c = len(own)
    fit = sum(n * math.log(max(p, 1e-300) / max(o, 1e-300)) for o, p, n in zip(own, pooled, n_eff, strict=True))
    return float(fit - (c - 1) * math.log(float(np.mean(n_eff))))


def varies(own: list[float], pooled: list[float], n_eff: list[float]) -> bool:
    """Whether each condition's own value earns its place against one pooled value (module docstring)."""
    j_gain = 1.0 - math.sqrt(sum(own) / sum(pooled)) if sum(pooled) > 0 else 0.0
    return bool(sharing_cost(own, pooled, n_eff) >= -SELECT_DELTA_BIC and j_gain >= MIN_J_REDUCTION)


def pooled_values(table: dict, fixed_c: dict, keys) -> dict:
    """Condition c's effect values ``fixed_c`` ({effect: {param: value}}) with the parameters ``keys``
    (``"effect.param"``) set to their pooled values."""
    out = {e: dict(v) for e, v in fixed_c.items()}
    for key in keys:
        effect, param = key.split(".", 1)
        if effect in out and param in out[effect] and "pooled" in table[key]:
            out[effect][param] = table[key]["pooled"]["median"]
    return out


def shared_values(table: dict, fixed_c: dict) -> dict:
    """Condition c's effect values ``fixed_c`` ({effect: {param: value}}) with every shared parameter set to its
    pooled value (keys of ``table`` are ``"effect.param"``)."""
    out = {e: dict(v) for e, v in fixed_c.items()}
    for key, row in table.items():
        effect, param = key.split(".", 1)
        if row.get("shared") and effect in out and param in out[effect]:
            out[effect][param] = row["pooled"]["median"]
    return out


def describe(table: dict, effect_units: dict) -> list[str]:
    """Plain-text lines: each parameter shared (its pooled value) or varying (its trend per condition)."""
    lines = []
    for key, row in table.items():
        unit = effect_units.get(key, "")
        vals = ", ".join(f"{v['median']:.4g}" for v in row["values"])
        if row.get("shared"):
            p, h = row["pooled"], row["heterogeneity"]
            lines.append(f"{key}: shared, {p['median']:.4g} {unit} [{p['lo']:.4g}, {p['hi']:.4g}] "
                         f"(per condition {vals}; delta-BIC of sharing {row['sharing_delta_BIC']:+.1f}; Q "
                         f"{h['Q']:.1f}, p {h['p_value']:.2f})")
        elif row.get("shared") is False and "heterogeneity" in row:
            parts = []
            for k, t in row.get("trend", {}).items():
                per = f"log({unit}) per {k}" if t["scale"] == "log" else f"{unit} per {k}"
                parts.append(f"slope {t['slope']:.4g} {per} [{t['slope_lo']:.4g}, {t['slope_hi']:.4g}]")
            lines.append(f"{key}: varies with the condition (per condition {vals} {unit}; delta-BIC of sharing "
                         f"{row.get('sharing_delta_BIC', float('nan')):+.1f}; Q {row['heterogeneity']['Q']:.1f}, p "
                         f"{row['heterogeneity']['p_value']:.2g})"
                         + (": " + "; ".join(parts) if parts else ""))
        else:
            lines.append(f"{key}: per condition {vals} {unit} ({row.get('reason', '')})")
    return lines
