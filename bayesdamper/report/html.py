"""The static HTML report of a run (``bayesdamper report``): one self-explanatory page per data set.

:func:`render_report` turns an ``identify`` summary (``summary.json``) and, if there is one, a diagnosis
(``diagnosis.json``) into ``OUT/report.html``. One page for any data set — triangular tests, other records or
both — since every record is identified window by window: the overview; the records with their kind and windows
(the transients' segmentation, the windows of cycles with their rule and the input's reconstruction); the static
characteristic (stage 1 and paper Fig. 3 where there are plateaus); the posterior of every window with its
convergence, noise, model error and, for windows of cycles, the flow coefficients and the input's error; the
windows against the model (paper Fig. 8 for transients, the loops for windows of cycles); the drift with speed
(paper Fig. 9); the diagnosis; the provenance. Each part says only what applies to the windows there are. Pure
string templating with :func:`html.escape`; no JavaScript; images are referenced by paths relative to the output
folder and only when the file is there. Written atomically.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path

from bayesdamper._version import __version__
from bayesdamper.io.outputs import atomic_write_bytes
from bayesdamper.report.html_comparison import comparison_table
from bayesdamper.report.html_law import conditions_block, law_table, prediction_check, record_drift_table
from bayesdamper.report.html_parts import (
    _PARAMS,
    _STATIC_UNITS,
    _data_section,
    _diagnosis_section,
    _drift_table,
    _e,
    _figures,
    _interval,
    _num,
    _provenance_section,
    _table,
    _yes,
)

#: File name of the report inside the output folder.
REPORT_FILE = "report.html"

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;
color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0 1em;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:right;vertical-align:top}
th{background:#f3f3f3}td.l,th.l{text-align:left}
tr.bad td{background:#fff1f0}.ok{color:#1a7f37;font-weight:600}.no{color:#c62828;font-weight:600}
.note{color:#555;font-size:.92em}.box{background:#f6f8fa;border:1px solid #ddd;padding:.6em 1em;margin:1em 0}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}figcaption{color:#555;font-size:.9em}
code,pre{font-size:.88em;background:#f6f8fa}pre{padding:.6em;overflow-x:auto;white-space:pre-wrap}
nav a{margin-right:1em}
"""


# ---------------------------------------------------------------------------------------------
# sections
#: σ_w/σ above which the overview names a window as one where the model misses the data.
MODEL_ERROR_RATIO = 1.5


def _counts(summary: Mapping) -> dict:
    """Windows and records by kind: transients and windows of cycles, triangular and other records."""
    segs = summary.get("segments", [])
    records = (summary.get("plan") or {}).get("records") or []
    n_cyc = sum(e.get("kind") == "cycles" for e in segs)
    return {"windows": len(segs), "cycles": n_cyc, "transients": len(segs) - n_cyc,
            "converged": sum(bool(e.get("converged")) for e in segs),
            "triangular": sum(r.get("kind") == "triangular" for r in records),
            "other": sum(r.get("kind") != "triangular" for r in records),
            "cycle_records": len({e.get("test") for e in segs if e.get("kind") == "cycles"}),
            "step_records": len({e.get("test") for e in segs if e.get("kind") != "cycles"})}


def _samples_flow(e: Mapping) -> bool:
    """Whether a window samples the four flow coefficients with its other parameters (a window of cycles, or any
    window under a flat prior) instead of taking them from stage 1."""
    return bool(e.get("flow")) and (e.get("kind") == "cycles" or str(e.get("flow_prior", "")).startswith("flat"))


def _flow_overview(summary: Mapping, segs: list) -> str:
    """Where the flow coefficients of eq. (4) came from: stage 1 (with any held at 0), the windows that sample them
    with α_V and p_R and under which prior, as their entries say."""
    sampled = [e for e in segs if _samples_flow(e)]
    flat = sum(str(e.get("flow_prior", "")).startswith("flat") for e in sampled)
    prior = ("a flat prior" if flat == len(sampled) else "stage 1's posterior as prior" if not flat else
             f"a flat prior in {flat} and stage 1's posterior as prior in {len(sampled) - flat}")
    what = "window(s) of cycles" if all(e.get("kind") == "cycles" for e in sampled) else "window(s)"
    if not summary.get("static"):
        return "no plateaus, so no stage 1: estimated " + (
            f"in each of the {len(sampled)} {what} with α<sub>V</sub>, p<sub>R</sub> and the pressure difference at "
            f"its start, under {prior} (their intervals are in the posterior table)" if sampled else "in every window")
    held = ", ".join(_STATIC_UNITS.get(k.replace("_", ""), (_e(k),))[0]
                     for k in summary.get("static_constrained") or [])
    return ("stage 1 from the plateaus of the triangular tests (Figure 3)"
            + (f"; held at 0 because the plateaus made them negative: {held}" if held else "")
            + (f"; sampled with α<sub>V</sub> and p<sub>R</sub> in each of {len(sampled)} {what}, under {prior}"
               if sampled else ""))


def _noise_overview(summary: Mapping, segs: list) -> str:
    """Where the windows' noise came from, as the summary and the entries say: the plateaus' estimate for the
    windows that use it, and for the windows with a noise of their own (windows of cycles without plateaus) each
    one's method, or the range of φ and σ where there are many."""
    nz = summary.get("noise") or {}
    own = [e for e in segs if (e.get("noise") or {}).get("source")
           and not str(e["noise"]["source"]).startswith("plateaus")]
    parts = []
    if nz and len(own) < len(segs):
        parts.append(f"from the plateaus: AR(1) φ = {_num(nz.get('phi'), '.3f')}, "
                     f"σ = {_num(nz.get('sigma_N'), '.3g')} N"
                     + (f" ({len(segs) - len(own)} window(s))" if own else ""))
    if own:
        what = "window(s) of cycles" if all(e.get("kind") == "cycles" for e in own) else "window(s)"
        head = f"of the {len(own)} {what} estimated in each from its own least-squares residual"
        phi = [e["noise"]["phi"] for e in own if isinstance(e["noise"].get("phi"), int | float)]
        sigma = [e["noise"]["sigma_N"] for e in own if isinstance(e["noise"].get("sigma_N"), int | float)]
        if len(own) <= 3:
            parts.append(head + ": " + "; ".join(
                f"{_e(e['id'])}: AR(1) φ = {_num(e['noise'].get('phi'), '.3f')}, "
                f"σ = {_num(e['noise'].get('sigma_N'), '.3g')} N — {_e(e['noise']['source'])}" for e in own))
        else:
            ranges = ([f"AR(1) φ from {_num(min(phi), '.3f')} to {_num(max(phi), '.3f')}"] if phi else []) + (
                [f"σ from {_num(min(sigma), '.3g')} to {_num(max(sigma), '.3g')} N"] if sigma else [])
            parts.append(head + " (" + (", ".join(ranges) + "; " if ranges else "")
                         + "each window's method in the noise table)")
    return "; noise ".join(parts) or "not recorded in the summary"


def _overview(summary: Mapping, diagnosis: Mapping | None) -> str:
    c = _counts(summary)
    segs = summary.get("segments", [])
    mass = float(summary.get("credible_mass", 0.9))
    what = [f"{c['transients']} transient(s) of {c['step_records']} triangular test(s)"] if c["transients"] else []
    what += [f"{c['cycles']} window(s) of whole cycles of {c['cycle_records']} other record(s)"] if c["cycles"] else []
    lines = [f"<li>{c['windows']} window(s) identified ({' and '.join(what) or 'none'}); <b>{c['converged']}</b> "
             f"converged by every criterion, {c['windows'] - c['converged']} not (see the posterior table).</li>"]
    if summary.get("mode_reason"):
        mode = summary.get("mode")
        lines.append(f"<li>How the records were windowed: {_e(summary['mode_reason'])}"
                     + (f" (<code>--mode {_e(mode)}</code>)" if mode and mode != "auto" else "") + ".</li>")
    lines.append(f"<li>Flow coefficients of eq. (4): {_flow_overview(summary, segs)}.</li>")
    su = summary.get("static_uncertainty") or {}
    if su.get("propagated"):
        lines.append("<li>Every posterior includes the uncertainty of the flow coefficients and of the pressure "
                     f"difference at the window's start; noise {_noise_overview(summary, segs)}.</li>")
    elif su:
        ratio = su.get("max_ratio") or {}
        lines.append("<li>Uncertainty of the stage-1 flow coefficients: "
                     + ("negligible for every transient" if su.get("negligible") else
                        "<b>not negligible</b> for some transients")
                     + f" (largest ratio α<sub>V</sub> {_num(ratio.get('alpha_V'), '.2f')}, "
                     f"p<sub>R</sub> {_num(ratio.get('p_R_Pa'), '.2f')}; "
                     f"threshold {_num(su.get('threshold'), '.2g')}).</li>")
    ratios = [(e["window_scale_ratio"], e["id"]) for e in segs if isinstance(e.get("window_scale_ratio"), int | float)]
    if ratios:
        high = [i for r, i in ratios if r > MODEL_ERROR_RATIO]
        lines.append(f"<li>Model error: σ<sub>w</sub>/σ from {_num(min(ratios)[0], '.2f')} to "
                     f"{_num(max(ratios)[0], '.2f')}; "
                     + (f"above {MODEL_ERROR_RATIO:g} (the model misses the data, the intervals widened accordingly) "
                        f"in {len(high)} window(s): {_e(', '.join(high))}" if high else
                        f"no window above {MODEL_ERROR_RATIO:g}") + ".</li>")
    rel = [e["input_error"]["relative_to_noise"] for e in segs
           if isinstance((e.get("input_error") or {}).get("relative_to_noise"), int | float)]
    if rel:
        lines.append(f"<li>Error of the reconstructed input in the force: at most {_num(max(rel), '.2g')} of the "
                     "noise's sd.</li>")
    for name, d in (summary.get("drift") or {}).items():
        label = _PARAMS.get(name, (name, 1.0))[0]
        nonzero = d.get("credible_nonzero")
        lines.append(f"<li>Drift of {label} with piston speed: "
                     + ("credibly non-zero" if nonzero else "not credibly different from 0")
                     + f" ({mass:.0%} interval of the slope excludes 0: {_yes(nonzero)}).</li>")
    dropped = [b.get("effect", "?") for r in (diagnosis or {}).get("rounds") or []
               for b in r.get("backward_check") or []]
    lines.append("<li>Diagnosis of unmodelled effects: "
                 + ("selected " + _e(", ".join(map(str, diagnosis.get("selected") or []))) if diagnosis
                    and diagnosis.get("selected") else "no effect selected" if diagnosis else "not available")
                 + (f"; dropped by the backward check: {_e(', '.join(map(str, dropped)))}" if dropped else "")
                 + ".</li>")
    return f'<div class="box"><b>In short</b><ul>{"".join(lines)}</ul></div>'


def _static_section(summary: Mapping, out_dir: Path) -> str:
    mass = float(summary.get("credible_mass", 0.9))
    if not summary.get("static"):
        return ('<h2 id="static">2. Static characteristic</h2>'
                "<p>No triangular test, so no plateaus and no stage 1: the flow coefficients of eq. (4) are "
                "estimated with the other parameters in every window, under a flat prior (their intervals are in "
                "the posterior section).</p>")
    held = {k.replace("_", "") for k in summary.get("static_constrained") or []}
    rows = [[f"{_STATIC_UNITS.get(k, (_e(k), ''))[0]}", _STATIC_UNITS.get(k, ("", ""))[1],
             _num(v.get("median")), _num(v.get("lo")), _num(v.get("hi")),
             "<b>held at 0</b>" if k in held else "–"]
            for k, v in (summary.get("static") or {}).items()]
    cycles = [e for e in summary.get("segments", []) if e.get("kind") == "cycles"]
    return ('<h2 id="static">2. Static characteristic (stage 1, paper Fig. 3)</h2>'
            "<p>Eq. (4), Δp = C<sub>L</sub> Q + C<sub>Q</sub> Q|Q|, fitted by linear least squares to the "
            "plateau points of each flow direction (12: chamber 1 to 2, Δp &gt; 0; 21: the reverse). "
            f"Intervals are {mass:.0%} Student-t intervals. "
            + ("Eq. (8) needs both coefficients of a direction non-negative: where the plateaus made one negative "
               "it is held at 0 and the direction is fitted with the other alone (a finding for the diagnosis: an "
               "offset load cell or a force that saturates with speed bends the curve that way). " if held else "")
            + ("The windows of cycles sample the four coefficients with their other parameters, stage 1's "
               "posterior as their prior (their intervals are in the posterior section). " if cycles else "")
            + "</p>"
            + _table(["coefficient", "unit", "estimate", f"{mass:.0%} lo", f"{mass:.0%} hi", "constraint"], rows,
                     left=2)
            + _figures(out_dir, (summary.get("figures") or {}).get("figure3_static"),
                       "Figure 3: static characteristic, plateau points and fit",
                       "Figure 3 was not drawn (the run used --no-figures)."))


#: What each ``--noise-model`` does with the noise's AR(1) coefficient φ.
_NOISE_MODELS = {
    "plateau": "The noise is AR(1), its coefficient φ estimated where the model holds no error — the plateaus, or "
               "without plateaus the window's least-squares residual away from the excitation's band and harmonics "
               "(the noise table says which) — and held fixed.",
    "ar1": "The noise is AR(1), its coefficient φ sampled with the other parameters of each window.",
    "white": "The noise is white."}


def _sampler_text(summary: Mapping, segs: list) -> tuple[str, str]:
    """How the windows were sampled, and what *converged* means."""
    sampler = (summary.get("settings") or {}).get("sampler") or (segs[0].get("sampler") if segs else {}) or {}
    walkers = sorted({int(w) for w in ((e.get("sampler") or {}).get("n_walkers") for e in segs) if w})
    wtxt = (f"{walkers[0]}" if len(walkers) == 1 else f"{walkers[0]}–{walkers[-1]}" if walkers else
            _e(sampler.get("n_walkers", "?")))
    how = (f"emcee ({_e(sampler.get('n_ensembles', '?'))} independently started ensembles of {wtxt} walkers, more "
           f"for more parameters, at most {_e(sampler.get('max_steps', '?'))} steps each).")
    converged = (f"<b>Converged</b> means: the chain is longer than {_num(sampler.get('tau_factor'), 'g')} integrated "
                 "autocorrelation times τ (in steps) and τ has settled, the rank-normalised R-hat across ensembles is "
                 f"≤ {_num(sampler.get('rhat_max'), 'g')} and the bulk effective sample size (ESS) is ≥ "
                 f"{_num(sampler.get('ess_min'), 'g')}. Rows in red did not converge; their intervals are not to be "
                 "trusted. <i>Shape</i> flags a long (log α<sub>V</sub>, log p<sub>R</sub>) ridge, two modes, or a "
                 "posterior piled against a prior bound.")
    return how, converged


def _coupling_text(segs: list) -> str:
    """How the parts of each window other than α_V and p_R enter its posterior, for the windows there are."""
    cut = [e for e in segs if e.get("coupling") == "cut"]
    joint = [e for e in segs if e.get("coupling") != "cut" and e.get("propagated")]
    out = []
    if cut:
        out.append(f"In {len(cut)} window(s) every other part has data of its own — the settled samples before "
                   "the step for the pressure difference at the start, stage 1's plateaus for the four flow "
                   "coefficients — and the posterior is a <em>cut</em> one: α<sub>V</sub> and p<sub>R</sub> are "
                   "sampled given those parts, and their uncertainty, from their own data, is carried into every "
                   "interval; the window's misfit cannot drag them away from what their data say.")
    if joint:
        stage1 = sum(str(e.get("flow_prior", "")).startswith("stage 1") for e in joint)
        out.append(f"In {len(joint)} window(s) the pressure difference at the start (with the samples before it in "
                   "the likelihood where there are some; sampled freely where the window starts in motion) and the "
                   "four flow coefficients are sampled jointly with α<sub>V</sub> and p<sub>R</sub>, the flow "
                   "coefficients under "
                   + ("stage 1's posterior as prior" if stage1 == len(joint) else "a flat prior" if not stage1 else
                      f"stage 1's posterior as prior in {stage1} and a flat prior in {len(joint) - stage1}")
                   + "; their intervals are in the posterior table and, with their prior, in the flow-coefficient "
                   "table below.")
    return " ".join(out)


def _ratio_cell(r: object) -> str:
    cell = _num(r, ".2f")
    return f"<b>{cell}</b>" if isinstance(r, int | float) and r > MODEL_ERROR_RATIO else cell


def _noise_table(segs: list) -> str:
    rows = []
    for e in segs:
        nz, ie = e.get("noise") or {}, e.get("input_error") or {}
        phi = _interval(e["phi"], ".3f") + " (sampled)" if isinstance(e.get("phi"), Mapping) else \
            _num(nz.get("phi"), ".3f")
        rows.append([_e(e["id"]), phi, _num(nz.get("sigma_N"), ".3g"), _e(nz.get("source", "–")),
                     _ratio_cell(e.get("window_scale_ratio")), _num(ie.get("force_rms_N"), ".3g"),
                     _num(ie.get("relative_to_noise"), ".2g")])
    return _table(["window", "AR(1) φ", "noise σ [N]", "noise estimated from", "σ<sub>w</sub>/σ",
                   "input error [N]", "input error / σ"], rows, left=1)


def _flow_table(segs: list, mass: float) -> str:
    rows = [[_e(e["id"]), _e(e.get("flow_prior", "–"))] + [_interval((e.get("flow") or {}).get(k), ".4g")
                                                          for k in _STATIC_UNITS]
            for e in segs if _samples_flow(e)]
    if not rows:
        return ""
    return ("<h3>Flow coefficients sampled in the windows of cycles</h3>"
            f"<p>Median [{mass:.0%} interval] of the four coefficients of eq. (4) in each window that samples them "
            "(units as in section 2: C<sub>L</sub> in kg m<sup>-4</sup> s<sup>-1</sup>, C<sub>Q</sub> in "
            "kg m<sup>-7</sup>). Like α<sub>V</sub> and p<sub>R</sub>, under model error they estimate the "
            "window's pseudo-true values: a drift from window to window is the data's, or the model's.</p>"
            + _table(["window", "prior"] + [v[0] for v in _STATIC_UNITS.values()], rows, left=2))


def _posterior_section(summary: Mapping) -> str:
    mass = float(summary.get("credible_mass", 0.9))
    segs = summary.get("segments", [])
    has_dp0 = any(isinstance(e.get("dp0_Pa"), Mapping) for e in segs)
    has_flow = any(_samples_flow(e) for e in segs)
    header = ["window", "kind", "dir", "v [mm/s]", f"α<sub>V</sub> median [{mass:.0%}]",
              f"p<sub>R</sub> [kPa] median [{mass:.0%}]"] + (
              [f"Δp at the start [kPa] median [{mass:.0%}]"] if has_dp0 else []) + (
              [f"{v[0]} median [{mass:.0%}]" for v in _STATIC_UNITS.values()] if has_flow else []) + [
              "J eq. (9)", "point J", "point α<sub>V</sub>", "point p<sub>R</sub> [kPa]", "R-hat max", "ESS min",
              "τ max", "converged", "shape"]
    rows, classes = [], []
    for e in segs:
        tau = max((t for t in (e.get("tau") or {}).values() if isinstance(t, int | float)), default=None)
        shape = e.get("shape") or {}
        flags = [n for n in ("ridge", "multimodal", "at_prior_bound") if shape.get(n)]
        ls = e.get("ls") or {}
        row = [_e(e["id"]), _e(e.get("kind", "")), f"{int(e.get('direction', 0)):+d}" if e.get("direction") else "–",
               _num(e.get("velocity_m_s"), ".3f", 1e3), _interval(e.get("alpha_V"), "#.4g"),
               _interval(e.get("p_R_Pa"), "#.4g", 1e-3)]
        if has_dp0:
            row.append(_interval(e.get("dp0_Pa"), ".4g", 1e-3))
        if has_flow:
            row += [_interval((e.get("flow") or {}).get(k), "#.4g") if _samples_flow(e) else "–"
                    for k in _STATIC_UNITS]
        row += [_num(e.get("J"), ".4f"), _num(ls.get("J"), ".4f"), _num(ls.get("alpha_V"), ".4g"),
                _num(ls.get("p_R_Pa"), ".4g", 1e-3), _num(e.get("rhat_max"), ".3f"),
                _num(e.get("ess_bulk_min"), ".0f"), _num(tau, ".1f"),
                _yes(e.get("converged")) + ("" if e.get("converged") else
                                            f'<br><span class="note">{_e(e.get("convergence", ""))}</span>'),
                _e(", ".join(flags).replace("_", " ")) or "–"]
        rows.append(row)
        classes.append("" if e.get("converged") else "bad")
    su = summary.get("static_uncertainty") or {}
    point = []
    if any("CL12" not in (e.get("ls") or {}) for e in segs):
        point.append("the paper's Nelder–Mead estimate of α<sub>V</sub> and p<sub>R</sub> with the stage-1 "
                     "coefficients and the force at the start")
    if any("CL12" in (e.get("ls") or {}) for e in segs):
        point.append("without plateaus, the least-squares fit of all seven parameters (α<sub>V</sub>, p<sub>R</sub>, "
                     "the start's Δp and the flow coefficients), where the sampler starts")
    tail = ""
    if su and not su.get("propagated"):
        tail = (f'<p class="note">Stage-1 uncertainty: {_e(su.get("method", ""))}; median ratio α<sub>V</sub> '
                f"{_num((su.get('median_ratio') or {}).get('alpha_V'), '.2f')}, p<sub>R</sub> "
                f"{_num((su.get('median_ratio') or {}).get('p_R_Pa'), '.2f')}.</p>")
    cycles = any(e.get("kind") == "cycles" for e in segs)
    how, converged = _sampler_text(summary, segs)
    noise_model = str((summary.get("settings") or {}).get("noise_model", "plateau"))
    return ('<h2 id="posterior">3. Posterior of every window</h2>'
            "<p>In every window, α<sub>V</sub> and p<sub>R</sub> of eq. (6)–(7) are sampled with " + how + " "
            + _coupling_text(segs) + f" The tables give the posterior median and the equal-tailed {mass:.0%} "
            "credible interval"
            + ("; the flow coefficients' columns (C<sub>L</sub> in kg m<sup>-4</sup> s<sup>-1</sup>, C<sub>Q</sub> in "
               "kg m<sup>-7</sup>) are filled for the windows that sample them" + (
                   ", the others take stage 1's (section 2)" if summary.get("static") else "") if has_flow else "")
            + ".</p>"
            "<p><b>What the intervals mean.</b> " + _NOISE_MODELS.get(noise_model, "") + " In every window the "
            "noise's scale σ<sub>w</sub> is estimated, so where the model misses the data (σ<sub>w</sub>/σ well "
            f"above 1, σ the noise's sd; bold above {MODEL_ERROR_RATIO:g}) the intervals widen by that factor: they "
            "then promise to hold the <em>pseudo-true</em> value, the one the fit would take on noise-free data of "
            "the same window, not a true α<sub>V</sub> of a model that does not hold. This holds for every window "
            "and every parameter sampled in it. "
            + ("In a window of cycles the input is the reconstructed displacement; the force its error moves is "
               "part of the residual, which σ<sub>w</sub> holds: a fraction of the noise widens the intervals by "
               "less than that fraction squared; where it rivals the noise the intervals widen with "
               "σ<sub>w</sub>/σ (input error / σ in the noise table). " if cycles else "")
            + "J is eq. (9) of the posterior-predictive median force; the point fit is "
            + "; ".join(point) + ". " + converged + "</p>"
            + _table(header, rows, left=2, classes=classes) + tail
            + "<h3>Noise, model error and the input</h3>" + _noise_table(segs)
            + _flow_table(segs, mass))


def _figures_section(summary: Mapping, out_dir: Path) -> str:
    figs = summary.get("figures") or {}
    mass = float(summary.get("credible_mass", 0.9))
    segs = summary.get("segments", [])
    out = ['<h2 id="windows">4. The windows against the model</h2>',
           f"<p>Measured force, the posterior predictive median with its {mass:.0%} band and the point fit, for every "
           "window.</p>"]
    if any(e.get("kind") != "cycles" for e in segs):
        out.append("<h3>Transients (paper Fig. 8)</h3><p>Per transient, time from the velocity step.</p>"
                   + _figures(out_dir, figs.get("figure8_transients"), "Figure 8: transients with predictive bands",
                              "Figure 8 was not drawn (the run used --no-figures)."))
    if any(e.get("kind") == "cycles" for e in segs):
        out.append("<h3>Windows of cycles</h3><p>Per window: the force against time (its first seconds), against "
                   "displacement and against velocity (the reconstructed input's), measured in grey.</p>"
                   + _figures(out_dir, figs.get("loops"), "force against time, displacement and velocity",
                              "The windows' loops were not drawn (the run used --no-figures).", per_file=True))
    out.append('<h2 id="drift">5. Drift with piston speed (paper Fig. 9)</h2>'
               "<p>A straight line in piston speed is fitted to the windows' posterior means"
               + (" (a window of cycles at its peak speed)" if any(e.get("kind") == "cycles" for e in segs) else "")
               + ", with each window's posterior sd and an intrinsic scatter integrated out (converged windows not "
               "piled against a prior bound, when there are any). A slope whose credible interval excludes 0 is a "
               "real drift.</p>"
               + _drift_table(summary.get("drift"), mass)
               + law_table(summary.get("drift_model"), mass)
               + record_drift_table(summary.get("drift_within_records"), mass)
               + _figures(out_dir, figs.get("figure9_drift"), "Figure 9: p_R and 100/α_V against piston speed",
                          "Figure 9 was not drawn (the run used --no-figures)."))
    return "".join(out)


# ---------------------------------------------------------------------------------------------


def _calibrated_blocks(diagnosis, mass: float) -> list[str]:
    """The diagnosis's calibrated damper: the drift law with the selected effects and the prediction check."""
    if not diagnosis:
        return []
    out = []
    if diagnosis.get("drift_model_after"):
        out.append("<p>The drift law with the selected effects:</p>" + law_table(diagnosis["drift_model_after"], mass))
    out.append(prediction_check(diagnosis.get("prediction_check")))
    out.append(conditions_block(diagnosis.get("conditions")))
    out.append(comparison_table(diagnosis.get("model_comparison")))
    return out


def render_report(summary: dict, diagnosis: dict | None, out_dir: Path, *,
                  diagnosis_note: str | None = None) -> Path:
    """Write ``out_dir/report.html`` from an ``identify`` summary and an optional diagnosis.

    Parameters
    ----------
    summary : dict
        The run's ``summary.json``: ``dataset``, ``segments`` (one entry per window, transient or cycles),
        ``static`` (None without plateaus), ``static_constrained``, ``plan``, ``mode``, ``mode_reason``, ``noise``,
        ``static_uncertainty``, ``drift``, ``settings``, ``provenance``, ``data``, ``figures``, ...; missing keys
        leave their part out.
    diagnosis : dict or None
        The ``diagnosis.json`` of the same data set (``noise``, ``baseline``, ``candidates``, ``rounds``,
        ``selected``, ``final``, ``windows``, ``final_segments``, ``drift_before``, ``drift_after``, optional
        ``figures`` and ``report_text``), or None if there is none; the report then says so.
    out_dir : Path
        The run's output folder; figure paths in both dicts are relative to it.
    diagnosis_note : str, optional
        Why there is no diagnosis (shown when ``diagnosis`` is None).

    Returns
    -------
    Path
        The written report.
    """
    out_dir = Path(out_dir)
    mass = float(summary.get("credible_mass", 0.9))
    name = summary.get("dataset", "?")
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    nav = "".join(f'<a href="#{a}">{t}</a>' for a, t in (
        ("data", "Data"), ("static", "Static"), ("posterior", "Posterior"), ("windows", "Windows"),
        ("drift", "Drift"), ("diagnosis", "Diagnosis"), ("provenance", "Provenance")))
    sections = [_overview(summary, diagnosis), _data_section(summary), _static_section(summary, out_dir),
                _posterior_section(summary), _figures_section(summary, out_dir),
                _diagnosis_section(diagnosis, out_dir, mass, diagnosis_note, _calibrated_blocks(diagnosis, mass)),
                _provenance_section(summary, out_dir)]
    method = ("the single-state model eq. (7) with the pressure-difference bulk modulus eq. (6), identified window "
              "by window (the transients after the velocity steps of triangular tests, with the flow coefficients "
              "from their plateaus; whole cycles of other records, with the flow coefficients estimated in each "
              "window), with Bayesian posteriors instead of single points.")
    body = "".join([
        f"<h1>Damper identification: data set {_e(repr(name))}</h1>",
        f'<p class="note">Written by bayesdamper {_e(__version__)} on {_e(stamp)}. Method: B. Titurus, '
        f"<i>Complete semi-analytical damper model identification using triangular displacement inputs</i>: "
        f"{method}</p>",
        f"<nav>{nav}</nav>",
        *sections,
    ])
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>bayesdamper report: {_e(name)}</title><style>{_CSS}</style></head>"
            f"<body>{body}</body></html>\n")
    path = out_dir / REPORT_FILE
    atomic_write_bytes(path, page.encode("utf-8"))
    return path
