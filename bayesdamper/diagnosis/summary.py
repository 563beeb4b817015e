"""What a diagnosis reports: J before and after (per window, per speed, pooled), drift, the p_R split, the structure
before and after, and the settings and provenance — the content of ``diagnosis.json``.
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
from bayesdamper.diagnosis.candidates import pooled_j
from bayesdamper.diagnosis.loop import SELECT_DELTA_BIC
from bayesdamper.diagnosis.residual import SMOOTH_S, STRUCTURE_ALPHA, describe_residual, structure_test
from bayesdamper.diagnosis.residual import summarise_structure as _summarise_structure
from bayesdamper.inference.drift import drift_summary

__all__ = ["GENERIC", "p_r_split", "pooled_j_ls", "summarise_diagnosis"]

#: The generic effect: a candidate only with the structure the residual's signature found.
GENERIC = "unnamed_dynamics"


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


def summarise_diagnosis(ds, windows, base, final, base_resid, final_resid, noise, noises, rows, structure,
                        signature, rounds, selected, fixed, names, settings, final_settings, credible_mass: float,
                        seed: int, prov: dict) -> dict:
    """The diagnosis as plain values (``diagnosis.json``): everything :func:`bayesdamper.run.diagnose.run_diagnosis`
    computed, with J before and after per window and per speed, drift before and after and the structure of the
    residual after."""
    forces = [w.force for w in windows]
    base_entries = [r.entry for r in base]
    final_entries = [r.entry for r in final]
    after_rows = []
    for w, r, nz in zip(windows, final_resid, noises, strict=True):
        rate = 1.0 / float(np.median(np.diff(w.time)))
        after_rows.append(structure_test(r, rate, nz) | describe_residual(w.time - w.t_step, r, w.force, rate)
                          | {"id": w.id, "velocity_m_s": w.velocity, "direction": w.direction, "kind": w.kind})
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
                  "J": {e["id"]: e["J"] for e in final_entries}},
        "J_pooled_by_velocity_mm_s": per_velocity,
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
                                   "every sample"},
        "final_segments": final_entries,
        "settings": settings.as_dict(), "final_settings": final_settings.as_dict(), "seed": seed,
        "effects_considered": [getattr(n, "label", n) for n in names],
        "unnamed_candidates": [{"label": n.label, "structure": n.extra, "reading": n.reading,
                                "search": {k: [v.lower, v.upper] for k, v in n.overrides.items()}}
                               for n in names if not isinstance(n, str) and n.effect == GENERIC],
        "search_starts": {n.label: n.starts for n in names if not isinstance(n, str) and n.starts},
        "provenance": prov,
    }

