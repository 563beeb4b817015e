"""The diagnosis's findings: what the data say about a selected parameter that ends on a bound of its search
(:func:`bound_resolution`), and the findings as report lines: parameters on a bound and the test speeds that got
worse after the selected effects were added (the data of :mod:`bayesdamper.diagnosis.summary`)."""

from __future__ import annotations

import math

import numpy as np

from bayesdamper.core.errors import BayesDamperError
from bayesdamper.diagnosis.candidates import effective_sizes
from bayesdamper.diagnosis.global_stage import GLOBAL_DISTINCT, spec_bound_flags
from bayesdamper.diagnosis.spec import CandidateSpec, _transform, _untransform, search_params

__all__ = ["FLAT_DEVIANCE", "bound_resolution", "findings_text"]


#: χ²₁'s 0.9 quantile: moving a parameter from its bound to a point changes the deviance D = N_eff log S by less than
#: this when the point lies within the 90 % interval of the profile log-likelihood -D/2 (the likelihood the search's
#: intervals use): :func:`bound_resolution`.
FLAT_DEVIANCE = 2.706


def bound_resolution(engine, selected: list, fixed: dict, names: list, flow_for, pack) -> list[dict]:
    """What the data say about each selected effect's parameter that ends on a bound (:func:`spec_bound_flags` of
    the final values ``fixed``; ``names``: the candidates, effect names or :class:`CandidateSpec`).

    The parameter is moved :data:`GLOBAL_DISTINCT` of its search range (transformed) inside, and as far past the
    bound, every other shared parameter held and each window's own parameters re-fitted (one evaluation of
    ``engine`` each). A deviance change ΔD = N_eff log(S_moved / S_bound) bounds the profile's from above (the others
    re-fitted could only lower S_moved). Against :data:`FLAT_DEVIANCE`:

    * ``"unresolved"``: the fit is the same inside (ΔD_inside below it): the data do not resolve the parameter
      between that point and the bound;
    * ``"one-sided"``: worse inside, no better past the bound (ΔD_past above minus it): the data bound it on the
      inside only (a refill already instantaneous on the transients' time scale, say);
    * ``"misfit"``: the fit improves past the bound, or the move past it is not feasible: the form does not fit the
      data as parametrised.

    Returns ``[{"effect", "param", "value", "inside", "delta_deviance", "past", "delta_deviance_past",
    "verdict"}]`` (the past entries None where that solve fails); a parameter whose move inside is not feasible is
    left out. Leaves the engine's warm starts alone.
    """
    specs = {getattr(n, "label", n): n for n in names if isinstance(n, CandidateSpec)}
    flags = [(label, specs.get(label) or CandidateSpec(label)) for label in selected]
    flags = [(label, spec, f) for label, spec in flags for f in spec_bound_flags(spec, fixed.get(spec.effect) or {})]
    if not flags:
        return []
    sse0, _, resid0 = engine.evaluate(pack(fixed), flow_for(fixed))
    if any(r is None for r in resid0):
        return []
    n_total, s0 = float(effective_sizes(resid0).sum()), float(np.sum(sse0))

    def moved(spec, name, value):
        e = {k: dict(v) for k, v in fixed.items()}
        e[spec.effect][name] = value
        try:
            sse, _, _ = engine.evaluate(pack(e), flow_for(e))
        except BayesDamperError:
            return None
        if not np.all(np.isfinite(sse)) or np.any(sse >= 1e300):
            return None
        return n_total * math.log(float(np.sum(sse)) / s0)

    out = []
    for label, spec, f in flags:
        p = next(q for q in search_params(spec) if q.name == f["param"])
        a, b = sorted((_transform(p, p.lower), _transform(p, p.upper)))
        z = _transform(p, f["value"])
        step = GLOBAL_DISTINCT * (b - a) * (1.0 if z - a < b - z else -1.0)  # towards the inside
        inside, past = _untransform(p, z + step), _untransform(p, z - step)
        d_in = moved(spec, p.name, inside)
        if d_in is None:
            continue
        d_past = moved(spec, p.name, past)
        verdict = ("unresolved" if d_in < FLAT_DEVIANCE else
                   "one-sided" if d_past is not None and d_past > -FLAT_DEVIANCE else "misfit")
        out.append({"effect": label, "param": p.name, "value": f["value"], "inside": inside, "delta_deviance": d_in,
                    "past": past if d_past is not None else None, "delta_deviance_past": d_past,
                    "verdict": verdict})
    return out


def findings_text(diagnosis: dict) -> list[str]:
    """The findings as report lines: each selected effect's parameter on its bound
    (:func:`bayesdamper.diagnosis.summary.bound_findings`), and
    which test speeds (and kinds of step) got worse after the selected effects were added, or that none did
    (:func:`bayesdamper.diagnosis.summary.j_by_speed`). Nothing on speeds when no effect was selected."""
    lines = [f["text"] + "." for f in diagnosis.get("findings") or []]
    rows = diagnosis.get("J_by_speed") or []
    if not diagnosis.get("selected") or not rows:
        return lines
    added = ", ".join(diagnosis["selected"])

    def fmt(r, kind=False):
        return (f"{r['speed_mm_s']:.2f} mm/s" + (f" ({r['kind']})" if kind else "")
                + f" ({r['J_before']:.4f} -> {r['J_after']:.4f})")

    worse = [r for r in rows if r["kind"] == "all" and r["worse"]]
    worse_speeds = {r["speed_mm_s"] for r in worse}
    by_kind = [r for r in rows if r["kind"] != "all" and r["worse"] and r["speed_mm_s"] not in worse_speeds]
    if worse:
        lines.append(f"J got worse after adding {added} at {len(worse)} of "
                     f"{sum(r['kind'] == 'all' for r in rows)} test speeds (at the posterior medians): "
                     + ", ".join(fmt(r) for r in worse) + ".")
    else:
        lines.append(f"No test speed got worse after adding {added} (J per speed at the posterior medians, before "
                     "-> after: " + ", ".join(fmt(r) for r in rows if r["kind"] == "all") + ").")
    if by_kind:
        lines.append("By kind of step, also worse: " + ", ".join(fmt(r, True) for r in by_kind) + ".")
    return lines
