"""The static HTML report of a run (``bayesdamper report``): one self-explanatory page per data set.

:func:`render_report` turns an ``identify`` summary (``summary.json``) and, if there is one, a
diagnosis (``diagnosis.json``) into ``OUT/report.html``: data set and segmentation, the static
characteristic (paper Fig. 3), the posterior of every transient with its convergence evidence, the
transients and the drift with speed (paper Figs. 8 and 9), the diagnosis, and the provenance. Pure
string templating with :func:`html.escape`; no JavaScript; images are referenced by paths relative to
the output folder and only when the file is there. Written atomically.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path

from bayesdamper._version import __version__
from bayesdamper.io.outputs import atomic_write_bytes
from bayesdamper.report.html_parts import (
    _PARAMS,
    _damper_table,
    _drift_table,
    _e,
    _figures,
    _interval,
    _kv_table,
    _num,
    _table,
    _value,
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

#: Units of the stage-1 coefficients of eq. (4).
_STATIC_UNITS = {"CL12": ("C<sub>L,12</sub>", "kg m<sup>-4</sup> s<sup>-1</sup>"),
                 "CQ12": ("C<sub>Q,12</sub>", "kg m<sup>-7</sup>"),
                 "CL21": ("C<sub>L,21</sub>", "kg m<sup>-4</sup> s<sup>-1</sup>"),
                 "CQ21": ("C<sub>Q,21</sub>", "kg m<sup>-7</sup>")}


# ---------------------------------------------------------------------------------------------

# ---------------------------------------------------------------------------------------------
# sections


def _overview(summary: Mapping, diagnosis: Mapping | None) -> str:
    segs = summary.get("segments", [])
    n = len(segs)
    n_ok = sum(bool(e.get("converged")) for e in segs)
    mass = float(summary.get("credible_mass", 0.9))
    lines = [f"<li>{n} transient(s) identified; <b>{n_ok}</b> converged by every criterion, "
             f"{n - n_ok} not (see the posterior table).</li>"]
    su = summary.get("static_uncertainty") or {}
    if su.get("propagated"):
        nz = summary.get("noise") or {}
        lines.append("<li>Every posterior includes the uncertainty of the stage-1 flow coefficients and of the "
                     "pressure difference at the step (both sampled with α<sub>V</sub> and p<sub>R</sub>); "
                     f"noise estimated from the plateaus: AR(1) φ = {_num(nz.get('phi'), '.3f')}, "
                     f"σ = {_num(nz.get('sigma_N'), '.1f')} N.</li>")
    elif su:
        ratio = su.get("max_ratio") or {}
        lines.append("<li>Uncertainty of the stage-1 flow coefficients: "
                     + ("negligible for every transient" if su.get("negligible") else
                        "<b>not negligible</b> for some transients")
                     + f" (largest ratio α<sub>V</sub> {_num(ratio.get('alpha_V'), '.2f')}, "
                     f"p<sub>R</sub> {_num(ratio.get('p_R_Pa'), '.2f')}; "
                     f"threshold {_num(su.get('threshold'), '.2g')}).</li>")
    for name, d in (summary.get("drift") or {}).items():
        label = _PARAMS.get(name, (name, 1.0))[0]
        nonzero = d.get("credible_nonzero")
        lines.append(f"<li>Drift of {label} with piston speed: "
                     + ("credibly non-zero" if nonzero else "not credibly different from 0")
                     + f" ({mass:.0%} interval of the slope excludes 0: {_yes(nonzero)}).</li>")
    lines.append("<li>Diagnosis of unmodelled effects: "
                 + ("selected " + _e(", ".join(map(str, diagnosis.get("selected") or []))) if diagnosis
                    and diagnosis.get("selected") else "no effect selected" if diagnosis else "not available")
                 + ".</li>")
    return f'<div class="box"><b>In short</b><ul>{"".join(lines)}</ul></div>'


def _data_section(summary: Mapping) -> str:
    data = summary.get("data") or {}
    out = ['<h2 id="data">1. Data set and segmentation</h2>']
    if not data:
        return out[0] + '<p class="note">This summary has no data-set table (an older version wrote it).</p>'
    d = data.get("damper", {})
    out.append(_damper_table(d))
    out.append("<p>Test records (one CSV file each):</p>")
    out.append(_table(["file", "samples", "sample rate [Hz]", "duration [s]", "SHA-256 (first 12)"],
                      ([_e(r["file"]), _num(r["n_samples"], "d"), _num(r["sample_rate_Hz"], ".1f"),
                        _num(r["duration_s"], ".2f"), f"<code>{_e(str(r['sha256'])[:12])}</code>"]
                       for r in data.get("records", [])), left=1))
    ids = {e["id"] for e in summary.get("segments", [])}
    out.append("<p>Segmentation: every velocity step (the start from rest and each reversal) begins a "
               f"transient window of T<sub>max</sub> = {_num(summary.get('tmax_s'), 'g')} s; the settled end "
               "of each ramp is a plateau, one point of the static characteristic, unless its force still drifts "
               "(linear trend |t| &gt; 3 under the plateaus' noise): stage 1 leaves such a plateau out. Bold rows "
               "were identified in this run.</p>")
    rows = []
    for st in data.get("steps", []):
        sid = f"{st['test']}_s{st['index']}"  # the transient's segment id
        rows.append([f"<b>{_e(sid)}</b>" if sid in ids else _e(sid), _e(st["kind"]),
                     f"{int(st['direction']):+d}",
                     _num(st["velocity_m_s"], ".3f", 1e3), _num(st["t_step_s"], ".3f"),
                     _num(st["force_N"], ".1f"),
                     _num(st.get("plateau_force_N"), ".1f")
                     + ("" if st.get("plateau_in_stage1", True) or st.get("plateau_force_N") is None
                        else ' <span class="note">drifting: not in stage 1</span>')])
    out.append(_table(["transient (step)", "kind", "dir", "v [mm/s]", "t<sub>step</sub> [s]",
                       "F at step [N]", "plateau F [N]"], rows, left=2))
    return "".join(out)


def _static_section(summary: Mapping, out_dir: Path) -> str:
    mass = float(summary.get("credible_mass", 0.9))
    if not summary.get("static"):
        return ('<h2 id="static">2. Static characteristic</h2>'
                "<p>No triangular test, so no plateaus and no stage 1: the flow coefficients of eq. (4) are "
                "estimated with the other parameters in every window (their intervals are in the posterior "
                "table).</p>")
    figs = (summary.get("figures") or {}).get("figure3_static")
    rows = [[f"{_STATIC_UNITS.get(k, (_e(k), ''))[0]}", _STATIC_UNITS.get(k, ("", ""))[1],
             _num(v.get("median")), _num(v.get("lo")), _num(v.get("hi"))]
            for k, v in (summary.get("static") or {}).items()]
    return ('<h2 id="static">2. Static characteristic (stage 1, paper Fig. 3)</h2>'
            "<p>Eq. (4), Δp = C<sub>L</sub> Q + C<sub>Q</sub> Q|Q|, fitted by linear least squares to the "
            "plateau points of each flow direction (12: chamber 1 to 2, Δp &gt; 0; 21: the reverse). "
            f"Intervals are {mass:.0%} Student-t intervals.</p>"
            + _table(["coefficient", "unit", "estimate", f"{mass:.0%} lo", f"{mass:.0%} hi"], rows, left=2)
            + _figures(out_dir, figs, "Figure 3: static characteristic, plateau points and fit",
                       "Figure 3 was not drawn (the run used --no-figures)."))


def _posterior_section(summary: Mapping) -> str:
    mass = float(summary.get("credible_mass", 0.9))
    segs = summary.get("segments", [])
    # joint posteriors record the sampler they ran (more walkers for more parameters)
    sampler = (segs[0].get("sampler") if segs and segs[0].get("sampler") else
               (summary.get("settings") or {}).get("sampler") or {})
    has_phi = any("phi" in e for e in segs)
    has_ratio = any("window_scale_ratio" in e for e in segs)
    header = ["transient", "kind", "dir", "v [mm/s]", f"α<sub>V</sub> median [{mass:.0%}]",
              f"p<sub>R</sub> [kPa] median [{mass:.0%}]"] + (["φ median"] if has_phi else []) + [
              "J eq. (9)", "NM J", "NM α<sub>V</sub>", "NM p<sub>R</sub> [kPa]"] + (
              ["σ<sub>w</sub>/σ"] if has_ratio else []) + ["R-hat max", "ESS min", "τ max", "converged", "shape"]
    rows, classes = [], []
    for e in segs:
        tau = max((t for t in (e.get("tau") or {}).values() if isinstance(t, int | float)), default=None)
        shape = e.get("shape") or {}
        flags = [n for n in ("ridge", "multimodal", "at_prior_bound") if shape.get(n)]
        ls = e.get("ls") or {}
        row = [_e(e["id"]), _e(e.get("kind", "")), f"{int(e.get('direction', 0)):+d}",
               _num(e.get("velocity_m_s"), ".3f", 1e3), _interval(e.get("alpha_V"), "#.4g"),
               _interval(e.get("p_R_Pa"), "#.4g", 1e-3)]
        if has_phi:
            row.append(_num((e.get("phi") or {}).get("median"), ".3f"))
        row += [_num(e.get("J"), ".4f"), _num(ls.get("J"), ".4f"), _num(ls.get("alpha_V"), ".4g"),
                _num(ls.get("p_R_Pa"), ".4g", 1e-3)]
        if has_ratio:
            row.append(_num(e.get("window_scale_ratio"), ".1f"))
        row += [_num(e.get("rhat_max"), ".3f"), _num(e.get("ess_bulk_min"), ".0f"), _num(tau, ".1f"),
                _yes(e.get("converged")) + ("" if e.get("converged") else
                                            f'<br><span class="note">{_e(e.get("convergence", ""))}</span>'),
                _e(", ".join(flags).replace("_", " ")) or "–"]
        rows.append(row)
        classes.append("" if e.get("converged") else "bad")
    su = summary.get("static_uncertainty") or {}
    if su.get("propagated"):
        cut_text = ("<p>For each transient, α<sub>V</sub> and p<sub>R</sub> of eq. (6)–(7) are sampled given the "
                    "pressure difference at the step and the four flow coefficients, and the uncertainty of those "
                    "— from their own data: the samples before the step and stage 1's plateaus — is carried into "
                    "every interval (a <em>cut</em> posterior: the window's misfit cannot drag the step force or "
                    "the static coefficients away from what their data say). ")
        joint_text = ("<p>For each transient, α<sub>V</sub> and p<sub>R</sub> of eq. (6)–(7) are sampled together "
                      "with the pressure difference at the step (the samples before the step are in the "
                      "likelihood) and the four flow coefficients (under stage 1's posterior as prior), so their "
                      "uncertainty is in every interval. ")
        what = ((cut_text if su.get("coupling", "joint") == "cut" else joint_text)
                + "The noise is AR(1) with φ from the plateaus, held fixed; in the window its scale "
                "σ<sub>w</sub> is estimated, so where the model misses the data (σ<sub>w</sub>/σ well above 1, "
                "σ the plateau noise) the intervals widen by that factor: they then promise to hold the value "
                "the eq. (9) optimum would take on noise-free data of the same test, not a true α<sub>V</sub> of "
                "a model that does not hold. J is eq. (9) of the posterior-predictive median force; NM is the "
                "paper's Nelder–Mead point estimate with the stage-1 coefficients and the mean step force. "
                "Sampled with emcee ")
        tail = ""
    else:
        what = "<p>For each transient, α<sub>V</sub> and p<sub>R</sub> of eq. (6)–(7) are sampled with emcee "
        tail = (f'<p class="note">Stage-1 uncertainty: {_e(su.get("method", ""))}; median ratio α<sub>V</sub> '
                f"{_num((su.get('median_ratio') or {}).get('alpha_V'), '.2f')}, p<sub>R</sub> "
                f"{_num((su.get('median_ratio') or {}).get('p_R_Pa'), '.2f')}.</p>" if su else "")
    return ('<h2 id="posterior">3. Posterior of every transient (stage 2)</h2>'
            + what +
            f"({_e(sampler.get('n_ensembles', '?'))} independently started ensembles of "
            f"{_e(sampler.get('n_walkers', '?'))} walkers, at most {_e(sampler.get('max_steps', '?'))} steps "
            f"each) under the {_e((summary.get('settings') or {}).get('noise_model', '?'))} noise model; "
            f"the table gives the posterior median and the equal-tailed {mass:.0%} credible interval. "
            + ("" if su.get("propagated") else
               "J is eq. (9) at the posterior median; NM is the paper's Nelder–Mead point estimate. ")
            + f"<b>Converged</b> means: the chain is longer than {_num(sampler.get('tau_factor'), 'g')} "
            "integrated autocorrelation times τ (in steps) and τ has settled, the rank-normalised R-hat "
            f"across ensembles is ≤ {_num(sampler.get('rhat_max'), 'g')} and the bulk effective sample size "
            f"(ESS) is ≥ {_num(sampler.get('ess_min'), 'g')}. Rows in red did not converge; their intervals "
            "are not to be trusted. <i>Shape</i> flags a long (log α<sub>V</sub>, log p<sub>R</sub>) ridge, "
            "two modes, or a posterior piled against a prior bound.</p>"
            + _table(header, rows, left=2, classes=classes) + tail)




def _figures_section(summary: Mapping, out_dir: Path) -> str:
    figs = summary.get("figures") or {}
    mass = float(summary.get("credible_mass", 0.9))
    return ('<h2 id="transients">4. Transients (paper Fig. 8)</h2>'
            "<p>Measured force, the Nelder–Mead fit and the posterior predictive median with its "
            f"{mass:.0%} band, per transient, time from the velocity step.</p>"
            + _figures(out_dir, figs.get("figure8_transients"), "Figure 8: transients with predictive bands",
                       "Figure 8 was not drawn (the run used --no-figures).")
            + '<h2 id="drift">5. Drift with piston speed (paper Fig. 9)</h2>'
            "<p>A straight line in piston speed is fitted to the transients' posterior means, with each "
            "transient's posterior sd and an intrinsic scatter integrated out (converged transients not piled "
            "against a prior bound, when there are any). A slope whose credible interval excludes 0 is a real "
            "drift.</p>"
            + _drift_table(summary.get("drift"), mass)
            + _figures(out_dir, figs.get("figure9_drift"), "Figure 9: p_R and 100/α_V against piston speed",
                       "Figure 9 was not drawn (the run used --no-figures)."))


def _diagnosis_section(diagnosis: Mapping | None, out_dir: Path, mass: float, note: str | None,
                       number: int = 6) -> str:
    head = f'<h2 id="diagnosis">{number}. Diagnosis of unmodelled effects</h2>'
    if not diagnosis:
        return head + ('<p class="note">No diagnosis is available for this run'
                       + (f": {_e(note)}" if note else "") + ". The diagnosis fits candidate effects "
                       "(friction, backlash, actuator lag, …) to the structured part of the residual and "
                       "keeps those the data support; run <code>bayesdamper diagnose</code> when it is "
                       "available.</p>")
    out = [head]
    if diagnosis.get("report_text"):
        out.append(f"<pre>{_e(diagnosis['report_text'])}</pre>")
    base, final = diagnosis.get("baseline") or {}, diagnosis.get("final") or {}
    unit = "window"
    out.append(_table(["", "value"], [
        [f"noise sd [N] ({_e((diagnosis.get('noise') or {}).get('source', 'plateaus'))})",
         _num(diagnosis.get("noise_N"), ".3g")],
        ["pooled J, eq. (7) baseline", _num(base.get("J_pooled"), ".4f")],
        ["pooled J, final model", _num(final.get("J_pooled"), ".4f")],
        ["selected effects", _e(", ".join(map(str, diagnosis.get("selected") or []))) or "none"]]))
    cands = diagnosis.get("candidates") or []
    if cands:
        rows = []
        for c in cands:
            params = c.get("params") or {}
            ptxt = "<br>".join(f"{_e(k)} = {_interval(v, '.4g')}" for k, v in params.items()) \
                if isinstance(params, Mapping) else _value(params)
            rows.append([_e(c.get("effect", "?")), _num(c.get("score"), ".1f"), _e(c.get("criterion", "")),
                         _num(c.get("J_pooled"), ".4f"), ptxt or "–",
                         _yes(c.get("effect") in (diagnosis.get("selected") or []), "selected", "–")])
        out.append("<p>Candidate effects, first round (lower score = better supported):</p>")
        out.append(_table(["effect", "score", "criterion", "pooled J", f"parameters, median [{mass:.0%}]",
                           ""], rows, left=1))
    jb, jf = base.get("J") or {}, final.get("J") or {}
    jf = jf if isinstance(jf, Mapping) else {}
    if isinstance(jb, Mapping) and jb:
        out.append(f"<p>Eq. (9) J per {unit} before and after the selected effects:</p>")
        out.append(_table([unit, "J baseline", "J final"],
                          ([_e(k), _num(v, ".4f"), _num(jf.get(k), ".4f")] for k, v in jb.items())))
    if diagnosis.get("drift_before") or diagnosis.get("drift_after"):
        out.append("<p>Drift with speed before the diagnosis:</p>"
                   + _drift_table(diagnosis.get("drift_before"), mass))
        out.append("<p>…and after it (with the selected effects):</p>"
                   + _drift_table(diagnosis.get("drift_after"), mass))
    for name, paths in (diagnosis.get("figures") or {}).items():
        out.append(_figures(out_dir, paths if isinstance(paths, list) else [paths],
                            f"Diagnosis: {str(name).replace('_', ' ')}",
                            f"Diagnosis figure {name} not found."))
    return "".join(out)


def _provenance_section(summary: Mapping, out_dir: Path, number: int = 7) -> str:
    prov = summary.get("provenance") or {}
    out = [f'<h2 id="provenance">{number}. Provenance</h2>',
           "<p>Everything needed to reproduce these numbers: the same input files (by SHA-256), the same "
           "settings and seed, and the same package versions. Each transient's posterior, with the same "
           f'provenance, is in <code>{_e("posteriors/<id>.nc")}</code> (NetCDF, ArviZ layout).</p>']
    run = {"data set": summary.get("dataset"), "data-set folder": prov.get("dataset_path"),
           "data-set SHA-256": prov.get("dataset_sha256"), "run seed": summary.get("seed"),
           "T_max [s]": summary.get("tmax_s"), "credible mass": summary.get("credible_mass"),
           "settings fingerprint": prov.get("settings_fingerprint"),
           "wall time of the run [s]": summary.get("wall_time_s")}
    try:
        log = json.loads((out_dir / "run.json").read_text())
    except (OSError, ValueError):
        log = {}
    if isinstance(log, dict) and log:
        run.update({"run started (UTC)": log.get("started_utc"),
                    "run finished (UTC)": log.get("finished_utc"),
                    "transients sampled in this run": len(log.get("computed") or []),
                    "transients resumed from earlier runs": len(log.get("resumed") or []),
                    "workers": log.get("scheduler") or log.get("workers")})
    out.append(_kv_table({k: v for k, v in run.items() if v is not None}))
    out.append("<p>Stage-2 settings:</p>" + _kv_table(_flat(summary.get("settings") or {})))
    out.append("<p>Input files:</p>" + _table(["file", "SHA-256"], (
        [_e(k), f"<code>{_e(v)}</code>"] for k, v in (prov.get("input_sha256") or {}).items())))
    out.append("<p>Versions:</p>" + _table(["package", "version"], (
        [_e(k), _e(v)] for k, v in (prov.get("versions") or {}).items())))
    links = [p for p in ("summary.json", "run.json", "diagnosis.json") if (out_dir / p).is_file()]
    if links:
        out.append("<p>Machine-readable results: "
                   + ", ".join(f'<a href="{_e(p)}">{_e(p)}</a>' for p in links) + ".</p>")
    return "".join(out)


def _flat(d: Mapping, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


# ---------------------------------------------------------------------------------------------


def render_report(summary: dict, diagnosis: dict | None, out_dir: Path, *,
                  diagnosis_note: str | None = None) -> Path:
    """Write ``out_dir/report.html`` from an ``identify`` summary and an optional diagnosis.

    Parameters
    ----------
    summary : dict
        The run's ``summary.json`` (``dataset``, ``segments``, ``static``, ``drift``, ``settings``,
        ``provenance``, ``data``, ``figures``, ...).
    diagnosis : dict or None
        The ``diagnosis.json`` of the same data set (``baseline``, ``candidates``, ``selected``,
        ``final``, ``drift_before``, ``drift_after``, optional ``figures`` and ``report_text``), or
        None if there is none; the report then says so.
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
        ("data", "Data"), ("static", "Static"), ("posterior", "Posterior"), ("transients", "Fig. 8"),
        ("drift", "Fig. 9"), ("diagnosis", "Diagnosis"), ("provenance", "Provenance")))
    sections = [_overview(summary, diagnosis), _data_section(summary), _static_section(summary, out_dir),
                _posterior_section(summary), _figures_section(summary, out_dir),
                _diagnosis_section(diagnosis, out_dir, mass, diagnosis_note),
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
