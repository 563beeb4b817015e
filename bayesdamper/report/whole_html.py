"""The report's sections for a whole-record identification (sine, sweep, multisine, random records).

A whole-record run has no plateaus, transients or stage 1: each record (or the stated window of it) is one
posterior of every parameter. :func:`whole_body` gives the sections that replace the two-stage ones of
:mod:`bayesdamper.report.html` (data and plan, the posterior per record, the loops, drift); the diagnosis
and provenance sections are shared, with :func:`whole_diagnosis_extra` adding the parameters of the effects
the whole-record diagnosis added.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from bayesdamper.report.html_parts import _damper_table, _drift_table, _e, _figures, _interval, _num, _table, _yes


def _noise_name(summary: Mapping) -> str:
    """The noise model a whole record ran: "plateau" has no plateaus to read here and falls back to "ar1"."""
    name = (summary.get("settings") or {}).get("noise_model", "?")
    return "ar1 (φ sampled; a whole record has no plateaus)" if name == "plateau" else name


#: Parameters of a whole-record posterior, in table order: (key, label, display scale).
WHOLE_PARAMS = (("C_L12", "C<sub>L,12</sub> [kg m<sup>-4</sup> s<sup>-1</sup>]", 1.0),
                ("C_Q12", "C<sub>Q,12</sub> [kg m<sup>-7</sup>]", 1.0),
                ("C_L21", "C<sub>L,21</sub> [kg m<sup>-4</sup> s<sup>-1</sup>]", 1.0),
                ("C_Q21", "C<sub>Q,21</sub> [kg m<sup>-7</sup>]", 1.0),
                ("alpha_V", "α<sub>V</sub> [-]", 1.0), ("p_R_Pa", "p<sub>R</sub> [kPa]", 1e-3),
                ("offset_N", "force offset [N]", 1.0), ("phi", "φ [-]", 1.0))


def whole_overview(summary: Mapping, diagnosis: Mapping | None) -> str:
    recs = summary.get("records") or []
    n_ok = sum(bool(e.get("converged")) for e in recs)
    lines = [f"<li>Mode: <b>whole record</b> ({_e(summary.get('mode_reason', ''))}): every parameter of eq. (7), "
             "the four flow coefficients included, sampled jointly on the eq. (9) residual of each record.</li>",
             f"<li>{len(recs)} record(s) identified; <b>{n_ok}</b> converged by every criterion, "
             f"{len(recs) - n_ok} not.</li>"]
    if diagnosis:
        base, final = diagnosis.get("baseline") or {}, diagnosis.get("final") or {}
        sel = diagnosis.get("selected") or []
        lines.append("<li>Diagnosis: " + (f"added {_e(', '.join(map(str, sel)))}" if sel else "nothing added")
                     + f"; pooled J {_num(base.get('J_pooled'), '.3f')} → {_num(final.get('J_pooled'), '.3f')}.</li>")
    else:
        lines.append("<li>Diagnosis of unmodelled effects: not available.</li>")
    return f'<div class="box"><b>In short</b><ul>{"".join(lines)}</ul></div>'


def _data(summary: Mapping) -> str:
    data = summary.get("data") or {}
    plan = summary.get("plan") or {}
    out = ['<h2 id="data">1. Data set and what was done with each record</h2>']
    d = data.get("damper") or {}
    if d:
        out.append(_damper_table(d))
    files = {r.get("name"): r for r in data.get("records") or []}
    rows = []
    for k, w in zip(plan.get("records") or [], plan.get("windows") or [], strict=False):
        f = files.get(k.get("name"), {})
        span = w.get("record_span_s") or [None, None]
        used = (f"{_num(w.get('t_start_s'), '.2f')}–{_num(w.get('t_end_s'), '.2f')} s"
                + (" (window)" if w.get("windowed") else " (all)"))
        rows.append([_e(k.get("name")), _e(k.get("description")), _num(f.get("sample_rate_Hz"), ".1f"),
                     _num(f.get("duration_s") or (span[1] - span[0] if None not in span else None), ".2f"), used,
                     f"{_num(w.get('rate_Hz'), '.1f')} Hz, {_num(w.get('n_samples'), 'd')} samples"])
    out.append("<p>Each record is classified from its displacement, checked (flat, clipped, too short, units), "
               "then identified as a whole: decimated (zero-phase anti-alias filter) and, if longer than the "
               "window rule allows, cut to a stated window.</p>")
    out.append(_table(["record", "what it is", "rate [Hz]", "duration [s]", "identified on", "after decimation"],
                      rows, left=2))
    rules = {(w.get("decimation_rule"), w.get("window_rule")) for w in plan.get("windows") or []}
    for dec, win in sorted(rules, key=str):
        out.append(f'<p class="note">Decimation: {_e(dec or "none")}. Window: {_e(win or "the whole record")}.</p>')
    return "".join(out)


def _posterior(summary: Mapping) -> str:
    mass = float(summary.get("credible_mass", 0.9))
    sampler = (summary.get("settings") or {}).get("sampler") or {}
    recs = summary.get("records") or []
    keys = [p for p in WHOLE_PARAMS if any(p[0] in e for e in recs)]
    header = ["record"] + [f"{lab} median [{mass:.0%}]" for _, lab, _ in keys] + [
        "J eq. (9)", "R-hat max", "ESS min", "τ max", "steps", "converged"]
    rows, classes = [], []
    for e in recs:
        tau = max((t for t in (e.get("tau") or {}).values() if isinstance(t, int | float)), default=None)
        row = [_e(e.get("id"))] + [_interval(e.get(k), "#.4g", s) for k, _, s in keys]
        row += [_num(e.get("J"), ".4f"), _num(e.get("rhat_max"), ".3f"), _num(e.get("ess_bulk_min"), ".0f"),
                _num(tau, ".1f"), _num(e.get("n_steps"), "d"),
                _yes(e.get("converged")) + ("" if e.get("converged") else
                                            f'<br><span class="note">{_e(e.get("convergence", ""))}</span>')]
        rows.append(row)
        classes.append("" if e.get("converged") else "bad")
    move = recs[0].get("move", sampler.get("move", "?")) if recs else "?"
    return ('<h2 id="posterior">2. Posterior of every record</h2>'
            "<p>Flow coefficients uniform on [0, 100× the record's scale], α<sub>V</sub> and p<sub>R</sub> "
            "log-uniform on the stage-2 boxes; likelihood on the eq. (9) residual of the whole (decimated) record "
            f"under the {_e(_noise_name(summary))} noise model with the scale marginalised. "
            f"emcee with {_e(sampler.get('n_ensembles', '?'))} independently started ensembles "
            f"(move {_e(move)}: differential evolution plus independence proposals from the Gauss-Newton "
            "approximation at the least-squares optimum, an exact Metropolis-Hastings step). "
            f"<b>Converged</b>: chain longer than {_num(sampler.get('tau_factor'), 'g')} τ with τ settled, "
            f"R-hat across ensembles ≤ {_num(sampler.get('rhat_max'), 'g')}, bulk ESS ≥ "
            f"{_num(sampler.get('ess_min'), 'g')}. Medians with equal-tailed {mass:.0%} intervals; J at the "
            "posterior median. Rows in red did not converge.</p>"
            + _table(header, rows, left=1, classes=classes))


def _loops(summary: Mapping, out_dir: Path) -> str:
    figs = summary.get("figures") or {}
    mass = float(summary.get("credible_mass", 0.9))
    out = ['<h2 id="transients">3. Records against the posterior predictive</h2>',
           "<p>Per record: force against time (the first seconds), against displacement and against velocity "
           f"(the loops); measured in grey, posterior-predictive median and {mass:.0%} band in colour, "
           "least squares dashed.</p>"]
    if not figs:
        out.append('<p class="note">No figures were drawn (the run used --no-figures).</p>')
    for rid, paths in figs.items():
        out.append(_figures(out_dir, paths if isinstance(paths, list) else [paths], f"Record {rid}",
                            f"Figure of {rid} not found."))
    out.append('<h2 id="drift">4. Drift with speed</h2>'
               "<p>A straight line in each record's speed (99th percentile of |v|) fitted to the records' "
               "posterior means with their sd and an intrinsic scatter integrated out.</p>"
               + _drift_table(summary.get("drift"), mass))
    return "".join(out)


def whole_body(summary: Mapping, out_dir: Path) -> str:
    """Sections 1-4 of a whole-record report."""
    return _data(summary) + _posterior(summary) + _loops(summary, out_dir)


def whole_diagnosis_extra(diagnosis: Mapping, mass: float) -> str:
    """Parameters of the added effects per record, static findings before and after, residual left."""
    out = []
    for name, d in (diagnosis.get("selected_params") or {}).items():
        per = d.get("per_record") or {}
        keys = sorted({k for v in per.values() for k in v})
        rows = [[_e(rid)] + [_interval(v.get(k), ".4g") for k in keys] for rid, v in per.items()]
        out.append(f"<p>Added: <b>{_e(name)}</b> — {_e(d.get('reading', ''))}. Least-squares values with "
                   f"Laplace {mass:.0%} intervals (residual correlation allowed for), per record:</p>")
        out.append(_table(["record"] + [_e(k) for k in keys], rows, left=1))
    for when in ("before", "after"):
        found = diagnosis.get(f"static_findings_{when}") or {}
        items = [f"{_e(rid)}: {_e(f.get('text', f.get('finding', '')))}" for rid, fs in found.items()
                 for f in (fs if isinstance(fs, list) else [])]
        if items:
            out.append(f"<p>Static findings {when} the added effects:</p><ul>"
                       + "".join(f"<li>{i}</li>" for i in items) + "</ul>")
    final = diagnosis.get("final") or {}
    ratio = final.get("residual_rms_over_noise") or {}
    if ratio:
        out.append("<p>Residual left by the final model, rms over the noise estimate (1 = nothing left): "
                   + ", ".join(f"{_e(k)} {_num(v, '.2f')}" for k, v in ratio.items()) + ".</p>")
    return "".join(out)


__all__ = ["WHOLE_PARAMS", "whole_body", "whole_diagnosis_extra", "whole_overview"]
