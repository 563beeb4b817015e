"""Pieces of the HTML report (:mod:`bayesdamper.report.html`): escaping, number and interval formatting, tables,
figure blocks, the drift table, and the three sections that only read their own part of the results — the data
set with its windows (``summary["data"]`` and ``summary["plan"]``), the diagnosis (``diagnosis.json``) and the
provenance (``summary["provenance"]``, ``summary["settings"]`` and ``run.json``). Imports nothing of the report
itself.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from html import escape
from pathlib import Path

#: Symbols and units of the flow coefficients of eq. (4).
_STATIC_UNITS = {"CL12": ("C<sub>L,12</sub>", "kg m<sup>-4</sup> s<sup>-1</sup>"),
                 "CQ12": ("C<sub>Q,12</sub>", "kg m<sup>-7</sup>"),
                 "CL21": ("C<sub>L,21</sub>", "kg m<sup>-4</sup> s<sup>-1</sup>"),
                 "CQ21": ("C<sub>Q,21</sub>", "kg m<sup>-7</sup>")}
#: Display scale and unit of the parameters in the tables.
_PARAMS = {"alpha_V": ("α<sub>V</sub> [-]", 1.0), "p_R_Pa": ("p<sub>R</sub> [kPa]", 1e-3),
           "phi": ("φ [-]", 1.0)}


def _e(x: object) -> str:
    return escape(str(x), quote=True)


def _num(x: object, fmt: str = ".4g", scale: float = 1.0) -> str:
    """A number for a table cell; '–' for a missing value, '∞' for an infinite one."""
    if x is None or isinstance(x, bool) or not isinstance(x, int | float):
        return "–" if x is None else _e(x)
    v = float(x) * scale
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return _e(format(round(v), fmt) if fmt.endswith("d") else format(v, fmt))


def _interval(d: object, fmt: str = ".4g", scale: float = 1.0) -> str:
    """``median [lo, hi]`` of a ``{median, lo, hi}`` dict."""
    if not isinstance(d, Mapping) or "median" not in d:
        return _value(d)
    lo, hi = _num(d.get("lo"), fmt, scale), _num(d.get("hi"), fmt, scale)
    return f"{_num(d['median'], fmt, scale)} [{lo}, {hi}]"


def _yes(flag: object, yes: str = "yes", no: str = "no") -> str:
    return f'<span class="ok">{yes}</span>' if flag else f'<span class="no">{no}</span>'


def _value(v: object) -> str:
    """Any JSON value, compactly (numbers formatted, nested values as JSON)."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None or isinstance(v, int | float):
        return _num(v)
    if isinstance(v, str):
        return _e(v)
    return f"<code>{_e(json.dumps(v, default=str, allow_nan=True))}</code>"


def _table(header: Iterable[str], rows: Iterable[Iterable[str]], left: int = 1,
           classes: Iterable[str] | None = None) -> str:
    """An HTML table; cells are already HTML. The first ``left`` columns are left-aligned."""
    def cells(tag: str, items: Iterable[str]) -> str:
        return "".join(f'<{tag} class="l">{c}</{tag}>' if i < left else f"<{tag}>{c}</{tag}>"
                       for i, c in enumerate(items))

    classes = list(classes) if classes is not None else []
    body = []
    for i, row in enumerate(rows):
        cls = classes[i] if i < len(classes) else ""
        body.append((f'<tr class="{cls}">' if cls else "<tr>") + cells("td", row) + "</tr>")
    return f"<table><thead><tr>{cells('th', header)}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _kv_table(items: Mapping) -> str:
    return _table(["", "value"], ([_e(k), _value(v)] for k, v in items.items()))


def _figures(out_dir: Path, paths: Iterable[str] | None, caption: str, missing: str, *,
             per_file: bool = False) -> str:
    """``<figure>`` blocks for the PNGs among ``paths`` that exist in ``out_dir``, with links to the rest.

    With ``per_file`` every caption starts with the file's stem (a window's id), so that one caption text can
    serve a figure per window."""
    paths = [str(p) for p in (paths or [])]
    present = [p for p in paths if (out_dir / p).is_file()]
    pngs = [p for p in present if p.lower().endswith((".png", ".svg", ".jpg", ".jpeg"))]
    if not pngs:
        return f'<p class="note">{_e(missing)}</p>'
    out = []
    for p in pngs:
        stem = p.rsplit(".", 1)[0]
        others = [q for q in present if q != p and q.rsplit(".", 1)[0] == stem]
        links = "".join(f' <a href="{_e(q)}">{_e(q.rsplit(".", 1)[1].upper())}</a>' for q in others)
        text = f"{stem.rsplit('/', 1)[-1]}: {caption}" if per_file else caption
        out.append(f'<figure><img src="{_e(p)}" alt="{_e(text)}" loading="lazy">'
                   f"<figcaption>{_e(text)} ({_e(p)}{')' if not links else ';' + links + ')'}"
                   "</figcaption></figure>")
    return "".join(out)


def _damper_table(d: Mapping) -> str:
    """The damper's known constants (``DamperConstants`` as a dict), with a sentence saying where from."""
    return ("<p>The damper's known constants (from <code>damper.toml</code>):</p>"
            + _table(["constant", "value"], [
                ["piston area A<sub>P</sub> [m<sup>2</sup>]", _num(d.get("piston_area"))],
                ["chamber volume V<sub>0,1</sub> [m<sup>3</sup>]", _num(d.get("chamber_volume_1"))],
                ["chamber volume V<sub>0,2</sub> [m<sup>3</sup>]", _num(d.get("chamber_volume_2"))],
                ["liquid bulk modulus B<sub>0</sub> [Pa]", _num(d.get("liquid_bulk_modulus"))]]))


def _drift_table(drift: Mapping | None, mass: float) -> str:
    if not drift:
        return '<p class="note">No drift fit (it needs at least three windows at two or more speeds).</p>'
    rows = []
    for name, d in drift.items():
        label, scale = _PARAMS.get(name, (_e(name), 1.0))
        rows.append([f"{label} (all)", _interval(d.get("slope_per_m_s"), ".4g", scale * 1e-3),
                     _yes(d.get("credible_nonzero")), _num(d.get("intrinsic_scatter"), ".3g", scale),
                     _num(d.get("n_transients"), "d")])
        for direction, dd in (d.get("by_direction") or {}).items():
            rows.append([f"{label} (direction {int(direction):+d})",
                         _interval(dd.get("slope_per_m_s"), ".4g", scale * 1e-3),
                         _yes(dd.get("credible_nonzero")), _num(dd.get("intrinsic_scatter"), ".3g", scale),
                         ""])
    return _table(["parameter", f"slope per mm/s, median [{mass:.0%}]", "credibly ≠ 0", "intrinsic scatter",
                   "windows"], rows, left=1)


# --------------------------------------------------------------------------------------------- data set and windows
def _windows_of(summary: Mapping) -> list[dict]:
    """Every window's description: the plan's (all windows of the data set), else the identified entries'."""
    plan = summary.get("plan") or {}
    if plan.get("windows"):
        return list(plan["windows"])
    return [dict(e.get("window") or {}, id=e.get("id"), test=e.get("test"), kind=e.get("kind"))
            for e in summary.get("segments", [])]


def _inputs_of(summary: Mapping, windows: list[dict]) -> dict:
    """How each cycle-windowed record's input was reconstructed: the plan's, else its windows'."""
    out = dict((summary.get("plan") or {}).get("inputs") or {})
    for w in windows:
        if w.get("input") and w.get("test") not in out:
            out[w["test"]] = w["input"]
    return out


def _records_table(summary: Mapping, windows: list[dict]) -> str:
    data = summary.get("data") or {}
    kinds = {r["name"]: r for r in (summary.get("plan") or {}).get("records", [])}
    count: dict[str, dict[str, int]] = {}
    for w in windows:
        c = count.setdefault(str(w.get("test")), {})
        c[w.get("kind")] = c.get(w.get("kind"), 0) + 1

    def windows_cell(name: str) -> str:
        c = count.get(name, {})
        steps = sum(v for k, v in c.items() if k != "cycles")
        parts = ([f"{steps} transient(s)"] if steps else []) + (
            [f"{c['cycles']} window(s) of cycles"] if c.get("cycles") else [])
        return ", ".join(parts) or "–"

    rows = []
    for r in data.get("records", []):
        k = kinds.get(r.get("name"), {})
        rows.append([_e(r["file"]), _e(k.get("kind", "–")), _e(k.get("description", "")),
                     windows_cell(r.get("name")), _num(r["n_samples"], "d"), _num(r["sample_rate_Hz"], ".1f"),
                     _num(r["duration_s"], ".2f"), f"<code>{_e(str(r['sha256'])[:12])}</code>"])
    return _table(["file", "kind", "what it is", "windows", "samples", "sample rate [Hz]", "duration [s]",
                   "SHA-256 (first 12)"], rows, left=4)


def _segmentation_table(summary: Mapping, ids: set) -> str:
    rows = []
    for st in (summary.get("data") or {}).get("steps", []):
        sid = f"{st['test']}_s{st['index']}"  # the transient's window id
        rows.append([f"<b>{_e(sid)}</b>" if sid in ids else _e(sid), _e(st["kind"]),
                     f"{int(st['direction']):+d}",
                     _num(st["velocity_m_s"], ".3f", 1e3), _num(st["t_step_s"], ".3f"),
                     _num(st.get("window_s"), ".3f"), _num(st["force_N"], ".1f"),
                     _num(st.get("plateau_force_N"), ".1f")
                     + ("" if st.get("plateau_force_N") is None
                        else ' <span class="note">drifting: not in stage 1</span>'
                        if not st.get("plateau_in_stage1", True)
                        else f' <span class="note">approached (τ {st["plateau_approach_tau_s"]:.2f} s): settled force '
                             'extrapolated</span>' if st.get("plateau_approach_tau_s") is not None else "")])
    return ("<p><b>Transients.</b> Every velocity step of a triangular test (the start from rest and each reversal) "
            f"begins a transient window of T<sub>max</sub> = {_num(summary.get('tmax_s'), 'g')} s (or up to the "
            "end of its ramp, where the next velocity change or the end of the record comes first), its state at the "
            "start given by the mean force of the settled samples before the step; the settled end of each ramp is "
            "a plateau, one point of the static characteristic. Where its force still drifts (linear trend "
            "|t| &gt; 3 under the plateaus' noise, each plateau about its own line) the point is the settled force "
            "an exponential approach fitted to the plateau extrapolates to; where that approach is no faster than "
            "the plateau's length or leaves a trend, stage 1 leaves the plateau out. Bold rows were identified in "
            "this run.</p>"
            + _table(["transient (step)", "kind", "dir", "v [mm/s]", "t<sub>step</sub> [s]", "window [s]",
                      "F at step [N]", "plateau F [N]"], rows, left=2))


def _cycle_windows_table(summary: Mapping, windows: list[dict], ids: set) -> str:
    cyc = [w for w in windows if w.get("kind") == "cycles"]
    rules = list(dict.fromkeys(str(w.get("rule", "")) for w in cyc if w.get("rule")))
    rows = []
    for w in cyc:
        wid = str(w.get("id"))
        rows.append([f"<b>{_e(wid)}</b>" if wid in ids else _e(wid), _e(w.get("record_kind", "")),
                     f"{_num(w.get('t_start_s'), '.3f')} – {_num(w.get('t_end_s'), '.3f')}",
                     _num(w.get("cycles"), ".2f"), _num(w.get("cycle_s"), ".4g"), _e(w.get("starts", "–")),
                     _value(w.get("ends_at_rest")),
                     _num(w.get("n_samples"), "d"), _num(w.get("rate_Hz"), ".4g"), _num(w.get("decimation"), "d")])
    out = ["<p><b>Windows of cycles.</b> A sine, sweep or random record is cut into windows by its own time scale: "
           + "; ".join(_e(r) for r in rules) + ". A window that starts at rest has the rest samples' mean force as "
           "its state at the start (like a start from rest); one that starts in motion has no such data, and the "
           "pressure difference at its start is sampled with its other parameters. Bold rows were identified in "
           "this run.</p>",
           _table(["window", "record", "span [s]", "cycles", "cycle [s]", "starts", "ends at rest", "samples",
                   "rate [Hz]", "decimation"], rows, left=2)]
    inputs = _inputs_of(summary, cyc)
    if inputs:
        out.append("<p>The model's input in a window of cycles is the measured displacement reconstructed as a "
                   "smooth curve; its error is estimated from the record itself (the displacement's noise and "
                   "converter step) and carried to the force by bootstrap replicates of the reconstruction (posterior "
                   "section: the input's error relative to the noise).</p>")
        out.append(_table(["record", "reconstruction", "displacement noise sd [µm]", "ADC step [µm]",
                           "fit residual rms [µm]", "velocity error [mm/s]"], (
            [_e(name), _e(d.get("method", "")), _num(d.get("noise_sd_m"), ".3g", 1e6),
             _num(d.get("adc_step_m"), ".3g", 1e6), _num(d.get("residual_rms_m"), ".3g", 1e6),
             _num(d.get("velocity_error_m_s"), ".3g", 1e3)
             + (f' <span class="note">({int(d["n_bootstrap"])} bootstrap replicates)</span>'
                if d.get("n_bootstrap") else "")] for name, d in inputs.items()), left=2))
    return "".join(out)


def _data_section(summary: Mapping) -> str:
    """Section 1: the damper, the records with their kind and windows, the transients' segmentation and the
    windows of cycles with their rule and the input's reconstruction."""
    out = ['<h2 id="data">1. Data set and windows</h2>']
    data = summary.get("data") or {}
    if not data:
        return out[0] + '<p class="note">This summary has no data-set table.</p>'
    windows = _windows_of(summary)
    ids = {e["id"] for e in summary.get("segments", [])}
    out.append(_damper_table(data.get("damper", {})))
    out.append("<p>Test records (one CSV file each) and the windows each is identified in:</p>")
    out.append(_records_table(summary, windows))
    if data.get("steps"):
        out.append(_segmentation_table(summary, ids))
    if any(w.get("kind") == "cycles" for w in windows):
        out.append(_cycle_windows_table(summary, windows, ids))
    return "".join(out)


# --------------------------------------------------------------------------------------------- diagnosis
#: Captions of the diagnosis's figures (other names: the name itself).
_DIAGNOSIS_FIGURES = {
    "residuals": "residuals of every window before (top) and after (bottom) the selected effects",
    "figure8_before": "Figure 8 before the diagnosis (eq. (7)): transients at the lowest, middle and highest speed",
    "figure8_after": "Figure 8 after the diagnosis (with the selected effects)",
    "figure9_before": "Figure 9 before the diagnosis (eq. (7))",
    "figure9_after": "Figure 9 after the diagnosis (with the selected effects)",
    "loops_before": "window of cycles before the diagnosis (eq. (7))",
    "loops_after": "window of cycles after the diagnosis (with the selected effects)"}


def _lovo_cell(c: Mapping) -> str:
    lv = c.get("lovo")
    if not isinstance(lv, Mapping):
        return "–"
    folds = lv.get("per_fold") or []
    aside = set(lv.get("outlying_folds") or [])
    shown = ", ".join((f"<s>{_num(g, '+.0f')}</s>" if i in aside else _num(g, "+.0f")) for i, g in enumerate(folds))
    return (f"{_num(lv.get('gain'), '+.1f')} (se {_num(lv.get('se'), '.1f')})"
            + (f'<br><span class="note">folds {shown}</span>' if folds else ""))


def _candidates_table(diagnosis: Mapping, mass: float) -> str:
    rows = []
    for c in diagnosis.get("candidates") or []:
        params = c.get("params") or {}
        ptxt = "<br>".join(f"{_e(k)} = {_interval(v, '.4g')}" for k, v in params.items()) \
            if isinstance(params, Mapping) else _value(params)
        aside = (c.get("lovo") or {}).get("outlying_folds") if isinstance(c.get("lovo"), Mapping) else None
        rows.append([_e(c.get("effect", "?")), _num(c.get("score"), ".1f"), _e(c.get("criterion", "")),
                     _num(c.get("J_pooled"), ".4f"), ptxt or "–", _lovo_cell(c),
                     ", ".join(str(int(i) + 1) for i in aside) if aside else "–",
                     _yes(c.get("effect") in (diagnosis.get("selected") or []), "selected", "–")])
    if not rows:
        return ""
    return ("<p>Candidate effects, first round (lower score = better supported). The held-out gain is the "
            "leave-velocities-out improvement of the fit over the current model, with its standard error and each "
            "fold's gain; a fold whose gain is an outlier among the folds' (struck through, numbered from 1) is set "
            "aside from the gain and its se:</p>"
            + _table(["effect", "score", "criterion", "pooled J", f"parameters, median [{mass:.0%}]",
                      "held-out gain (se)", "folds set aside", ""], rows, left=1))


def _backward_check(diagnosis: Mapping) -> str:
    rounds = diagnosis.get("rounds") or []
    if not any("backward_check" in r for r in rounds):
        return ""
    dropped = [b for r in rounds for b in (r.get("backward_check") or [])]
    text = ("<p>Backward check: each selected effect was tested against the model without it (the others re-fitted) "
            "by the same criterion; ")
    if not dropped:
        return text + "every selected effect kept its place.</p>"
    return (text + "the effects below were dropped, a later selection explaining what they did:</p>"
            + _table(["effect dropped", "ΔBIC<sub>eff</sub> of adding it back", "pooled J without it",
                      "J reduction with it"],
                     ([_e(b.get("effect", "?")), _num(b.get("delta_BIC_eff"), "+.1f"), _num(b.get("J_without"), ".4f"),
                       _num(b.get("J_reduction"), ".1%") if isinstance(b.get("J_reduction"), int | float) else "–"]
                      for b in dropped)))


def _window_j_table(diagnosis: Mapping) -> str:
    base, final = diagnosis.get("baseline") or {}, diagnosis.get("final") or {}
    jb, jf = base.get("J") or {}, final.get("J") or {}
    if not isinstance(jb, Mapping) or not jb:
        return ""
    jf = jf if isinstance(jf, Mapping) else {}
    info = {w.get("id"): w for w in diagnosis.get("windows") or []}
    final_entries = {e.get("id"): e for e in diagnosis.get("final_segments") or []}
    selected = bool(diagnosis.get("selected"))
    rows = []
    for k, v in jb.items():
        w, e = info.get(k, {}), final_entries.get(k, {})
        row = [_e(k), _e(w.get("kind", "–")),
               f"{_num(w.get('t_start_s'), '.3f')} – {_num(w.get('t_end_s'), '.3f')}" if w else "–",
               _num(v, ".4f"), _num(jf.get(k), ".4f")]
        if selected:
            row += [_interval(e.get("alpha_V"), "#.4g"), _interval(e.get("p_R_Pa"), "#.4g", 1e-3),
                    _yes(e.get("converged")) if e else "–"]
        rows.append(row)
    header = ["window", "kind", "span [s]", "J baseline", "J final"] + (
        ["final α<sub>V</sub>", "final p<sub>R</sub> [kPa]", "converged"] if selected else [])
    return ("<p>Eq. (9) J per window before and after the selected effects"
            + (", with the final model's posterior (its effects held at their values)" if selected else "")
            + ":</p>" + _table(header, rows, left=2))


def _diagnosis_section(diagnosis: Mapping | None, out_dir: Path, mass: float, note: str | None,
                       extra: Iterable[str] = ()) -> str:
    """Section 6: what the diagnosis tested and selected, the noise it judged against (and where from), the
    candidates with their held-out gains and outlying folds, the backward check, J per window before and after,
    drift before and after, the ``extra`` blocks (the calibrated damper's) and its figures."""
    head = '<h2 id="diagnosis">6. Diagnosis of unmodelled effects</h2>'
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
    noise = diagnosis.get("noise") or {}
    out.append(_table(["", "value"], [
        ["noise sd [N]", _num(diagnosis.get("noise_N"), ".3g")],
        ["noise from", _e(noise.get("source", "the plateaus"))],
        ["windows diagnosed", _num(len(diagnosis.get("windows") or (base.get("J") or {})), "d")],
        ["pooled J, eq. (7) baseline", _num(base.get("J_pooled"), ".4f")],
        ["pooled J, final model", _num(final.get("J_pooled"), ".4f")],
        ["selected effects", _e(", ".join(map(str, diagnosis.get("selected") or []))) or "none"]]))
    out.append(_candidates_table(diagnosis, mass))
    out.append(_backward_check(diagnosis))
    out.append(_window_j_table(diagnosis))
    if diagnosis.get("drift_before") or diagnosis.get("drift_after"):
        out.append("<p>Drift with speed before the diagnosis:</p>"
                   + _drift_table(diagnosis.get("drift_before"), mass))
        out.append("<p>…and after it (with the selected effects):</p>"
                   + _drift_table(diagnosis.get("drift_after"), mass))
    out.extend(extra)
    for name, paths in (diagnosis.get("figures") or {}).items():
        paths = paths if isinstance(paths, list) else [paths]
        caption = _DIAGNOSIS_FIGURES.get(name, f"diagnosis: {str(name).replace('_', ' ')}")
        out.append(_figures(out_dir, paths, caption, f"Diagnosis figure {name} not found.",
                            per_file=str(name).startswith("loops")))
    return "".join(out)


# --------------------------------------------------------------------------------------------- provenance
def _provenance_section(summary: Mapping, out_dir: Path) -> str:
    """Section 7: the run's identity (data set, its SHA-256, seed, settings, timing from ``run.json``), the input
    files' SHA-256, the package versions and links to the machine-readable results."""
    prov = summary.get("provenance") or {}
    out = ['<h2 id="provenance">7. Provenance</h2>',
           "<p>Everything needed to reproduce these numbers: the same input files (by SHA-256), the same "
           "settings and seed, and the same package versions. Each window's posterior, with the same "
           f'provenance, is in <code>{_e("posteriors/<id>.nc")}</code> (NetCDF, ArviZ layout).</p>']
    run = {"data set": summary.get("dataset"), "identification mode": summary.get("mode"),
           "data-set folder": prov.get("dataset_path"),
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
                    "windows sampled in this run": len(log.get("computed") or []),
                    "windows resumed from earlier runs": len(log.get("resumed") or []),
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
    """A nested mapping as one level, its keys joined with dots."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out
