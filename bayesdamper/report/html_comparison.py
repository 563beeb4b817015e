"""Report block of the diagnosis's model comparison (:mod:`bayesdamper.diagnosis.comparison`): eq. (7) with eq. (6),
with a constant bulk modulus and the two-state model, in sample and held out, per kind of step, with the verdict."""

from __future__ import annotations

from collections.abc import Mapping

from bayesdamper.report.html_parts import _e, _num, _table

_NAMES = {"eq6": "eq. (7) with eq. (6)", "constant_bulk_modulus": "constant bulk modulus", "two_state": "two-state"}


def _slope(line: Mapping | None) -> str:
    if not line or line.get("slope") is None:
        return "–"
    se = line.get("se")
    return _num(line["slope"], "+.2f") + (f" ± {_num(se, '.2f')}" if se is not None else "")


def comparison_table(result: Mapping | None) -> str:
    """The comparison as HTML: the rules, a table model × kind (windows, in-sample and held-out pooled J, median α_V
    and p_R, drift slopes of log α_V and log p_R in log speed with standard errors), the shared parameters and the
    verdict per kind; empty without a comparison."""
    if not result:
        return ""
    head = "<h3>Base models compared by held-out prediction</h3>"
    if result.get("error"):
        return head + f'<p class="note">Not made: {_e(result["error"])}.</p>'
    models, kinds, rules = result.get("models") or {}, list(result.get("kinds") or []), result.get("rules") or {}
    speeds = [f.get("speed_m_s") for f in result.get("folds") or []]
    out = [head, f'<p class="note">{_e(rules.get("folds", ""))} ({len(speeds)} folds); {_e(rules.get("law", ""))}; '
                 f'{_e(rules.get("shared", ""))}. {_e(rules.get("margin", ""))}.</p>']
    rows = []
    for key in result.get("order") or []:
        m = models[key]
        for kind in [*kinds, "all"]:
            ins = (m.get("in_sample") or {}).get("by_kind", {}).get(kind) or {}
            ho = (m.get("held_out") or {}).get("by_kind", {}).get(kind) or {}
            drift = ins.get("drift") or {}
            rows.append([_e(_NAMES.get(key, m.get("label", key))), _e(kind), _num(ins.get("n_windows"), "d"),
                         _num(ins.get("J_pooled"), ".4f"), _num(ho.get("J_pooled"), ".4f"),
                         _num(ins.get("alpha_V_median"), ".1f"), _num(ins.get("p_R_Pa_median"), ".3f", 1e-6),
                         _slope(drift.get("log_alpha_V")), _slope(drift.get("log_p_R"))])
    out.append(_table(["model", "kind", "windows", "J in sample", "J held out", "median α_V", "median p_R [MPa]",
                       "d log α_V / d log v", "d log p_R / d log v"], rows, left=2))
    notes = []
    for key in result.get("order") or []:
        m = models[key]
        sh = m.get("shared")
        if sh:
            vals = ", ".join(f"{_e(k)} = {_num(p.get('median'), '.4g')} [{_num(p.get('lo'), '.3g')}, "
                             f"{_num(p.get('hi'), '.3g')}]" for k, p in (sh.get("params") or {}).items())
            notes.append(f"{_e(_NAMES.get(key, key))}: shared parameters fitted on all windows: {vals}.")
        if m.get("modulus_only"):
            notes.append(f"{_e(_NAMES.get(key, key))}: α_V and p_R act only through the modulus B(p_R) of eq. (3); "
                         "each window's pair is where its fit stopped on the ridge of equal B, and its law is that "
                         "of log B.")
    if notes:
        out.append('<p class="note">' + "<br>".join(notes) + "</p>")
    items = []
    for kind, v in (result.get("verdict") or {}).items():
        others = "; ".join(
            f"{_e(_NAMES.get(m, m))}: held-out J {'lower' if (a.get('lower_by') or 0) > 0 else 'higher'} by "
            f"{_num(abs(a['lower_by']) if a.get('lower_by') is not None else None, '.4f')} "
            f"(margin {_num(a.get('margin'), '.4f')}, {_num(a.get('n_folds'), 'd')} folds)"
            for m, a in (v.get("against") or {}).items())
        verdict = ('<span class="ok">eq. (6) suffices</span>' if v.get("base_suffices")
                   else '<span class="no">eq. (6) does not suffice</span>')
        items.append(f"<li>{_e(kind)}: best held out {_e(_NAMES.get(v.get('winner'), v.get('winner')))}; {verdict}"
                     + (f" ({others})" if others else "") + "</li>")
    out.append("<ul>" + "".join(items) + "</ul>")
    if result.get("wall_time_s") is not None:
        out.append(f'<p class="note">Wall time of the comparison: {_num(result["wall_time_s"], ".0f")} s.</p>')
    return "".join(out)
