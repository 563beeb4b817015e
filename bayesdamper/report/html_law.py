"""Report blocks of the calibrated damper: the hierarchical drift law (trend against scatter between tests) and
the leave-one-test-out check of its predictions."""

from __future__ import annotations

from collections.abc import Mapping

from bayesdamper.report.html_parts import _e, _num, _table

_LABEL = {"alpha_V": "α_V", "p_R_Pa": "p_R"}


def _pct_interval(d: Mapping | None, scale: float = 100.0, fmt: str = "+.0f") -> str:
    if not d:
        return "–"
    return (f"{_num(d.get('median'), fmt, scale)} % [{_num(d.get('lo'), fmt, scale)}, "
            f"{_num(d.get('hi'), fmt, scale)}]")


def law_table(law: Mapping | None, mass: float) -> str:
    """The drift law: per parameter the change over the calibrated speed range (the trend) beside the scatter
    between tests (as an sd of the log parameter, in %), whether the drift is credible, and the convergence."""
    if not law:
        return ""
    if not law.get("fitted", True):
        return f'<p class="note">No drift law: {_e(law.get("reason", ""))}.</p>'
    lo, hi = law.get("speed_range_m_s", [None, None])
    pct = f"{round(100 * mass)} %"
    rows = []
    for name, p in (law.get("parameters") or {}).items():
        med = (p.get("law") or {}).get("median") or []
        rows.append([_e(_LABEL.get(name, name)),
                     _num(med[0] if med else None, ".4g", 1e-6 if name == "p_R_Pa" else 1.0),
                     _num(med[-1] if med else None, ".4g", 1e-6 if name == "p_R_Pa" else 1.0),
                     _pct_interval(p.get("change_over_range")),
                     _pct_interval(p.get("scatter_between_tests_log_sd"), fmt=".0f"),
                     _pct_interval(p.get("scatter_within_test_log_sd"), fmt=".0f"),
                     "yes" if p.get("drift_credible") else "no"])
    cov = law.get("covariate")
    cov_text = ""
    if cov:
        sl = cov.get("slope_log_per_unit") or {}
        cov_text = (f"<p>Covariate {_e(cov.get('name'))} (the tests' means, {_num(cov['range'][0], '.4g')}–"
                    f"{_num(cov['range'][1], '.4g')}; the law above is drawn at {_num(cov.get('law_at'), '.4g')}): "
                    + "; ".join(f"{_e(_LABEL.get(n, n))} {_pct_interval(sl.get(n), fmt='+.2f')} per unit"
                                for n in ("alpha_V", "p_R_Pa")) + ".</p>")
    sm = law.get("sampling") or {}
    corr = law.get("scatter_correlation")
    return (f"<p>The drift law ({_e(law.get('method', ''))}), fitted to {_num(law.get('n_windows'), 'd')} windows of "
            f"{_num(law.get('n_tests'), 'd')} tests "
            f"at {_num(lo, '.3g', 1e3)}–{_num(hi, '.3g', 1e3)} mm/s. The trend is the law's change between the "
            "slowest and the fastest calibrated speed; the scatters are sds of the log parameter (in %) between tests "
            "at one speed and between the windows of one test (kind of step, …): what a new test adds to the "
            "trend. A change whose interval excludes 0 is a drift; a scatter larger than the change means the tests "
            "differ more among themselves than with speed. "
            f"Brackets: {pct} credible intervals. p_R in MPa.</p>"
            + _table(["parameter", "law at slowest", "law at fastest", "change over the range (trend)",
                      "scatter between tests", "scatter between windows of a test", "drift credible"],
                     rows, left=1)
            + cov_text
            + f"<p class=\"note\">Hyper-posterior: {'converged' if sm.get('converged') else 'NOT converged'} "
              f"(R-hat {_num(sm.get('rhat_max'), '.3f')}, bulk ESS {_num(sm.get('ess_bulk_min'), '.0f')}, "
              f"τ {_num(sm.get('tau_max'), '.1f')} steps)"
            + (f"; correlation of the scatter of α_V and p_R {_num(corr.get('median'), '.2f')} "
               f"[{_num(corr.get('lo'), '.2f')}, {_num(corr.get('hi'), '.2f')}]" if corr else "")
            + (f"; measurement noise of a prediction: sd {_num(law['prediction_noise'].get('sigma_N'), '.3g')} N, "
               f"AR(1) φ {_num(law['prediction_noise'].get('phi'), '.3f')}" if law.get("prediction_noise") else "")
            + ".</p>")


def prediction_check(check: Mapping | None) -> str:
    """The leave-one-test-out table: per left-out test the share of its samples inside the 90 % and 50 %
    predictive bands and J of the median, for each calibrated model."""
    models = (check or {}).get("models") or {}
    if not models:
        return ""
    out = ["<h3>Predictions of tests the calibration did not see</h3>"
           f"<p>{_e(check.get('method', ''))}; {_num(check.get('n_draws'), 'd')} draws per test. An honest band "
           "holds about 90 % (50 %) of the samples; a much wider band is safe but loose, a narrower one "
           "overconfident.</p>"]
    labels = list(models)
    tests = list(dict.fromkeys(r["test"] for m in models.values() for r in m.get("rows", [])))
    header = ["test", "speed [mm/s]"] + [f"{lab}: {col}" for lab in labels
                                         for col in ("in 90 % band", "in 50 % band", "J of median")]
    rows = []
    for t in tests:
        cells, speed = [], None
        for lab in labels:
            r = next((x for x in models[lab].get("rows", []) if x["test"] == t), {})
            speed = speed if speed is not None else r.get("speed_m_s")
            ext = " (extrapolated)" if r.get("extrapolated") else ""
            if "coverage_90" not in r and r:  # not scored: too few tests left for a law, or every solve failed
                cells += [_e(r.get("failed") or r.get("law", "")), "–", "–"]
                continue
            cells += [_num(r.get("coverage_90"), ".0%") + ext, _num(r.get("coverage_50"), ".0%"),
                      _num(r.get("J_median"), ".4f")]
        rows.append([_e(t), _num(speed, ".3g", 1e3)] + cells)
    rows.append(["<b>median</b>", ""] + [c for lab in labels for c in (
        _num(models[lab].get("coverage_90"), ".0%"), _num(models[lab].get("coverage_50"), ".0%"),
        _num(models[lab].get("J_median"), ".4f"))])
    out.append(_table(header, rows, left=1))
    return "".join(out)


def conditions_block(c: Mapping | None) -> str:
    """One damper under several conditions: the explanation kept over all of them and, per effect parameter,
    whether it is shared (pooled value) or varies with the condition (values and trend)."""
    if not c:
        return ""
    cond = c.get("condition") or {}
    here = ", ".join(f"{_e(k)} = {_num(v, '.4g')}" for k, v in cond.items())
    own = ", ".join(c.get("own_selection") or []) or "none"
    rows = []
    for key, row in (c.get("parameters") or {}).items():
        vals = "; ".join(f"{_num(v['median'], '.4g')} [{_num(v['lo'], '.4g')}, {_num(v['hi'], '.4g')}]"
                         for v in row.get("values", []))
        if row.get("shared"):
            p = row["pooled"]
            verdict = f"shared: {_num(p['median'], '.4g')} [{_num(p['lo'], '.4g')}, {_num(p['hi'], '.4g')}]"
        else:
            verdict = "varies with the condition" + "".join(
                f"; slope per {_e(k)} {_num(t['slope'], '.4g')} [{_num(t['slope_lo'], '.4g')}, "
                f"{_num(t['slope_hi'], '.4g')}]" + (" (log scale)" if t.get("scale") == "log" else "")
                for k, t in (row.get("trend") or {}).items())
        rows.append([_e(key), vals, verdict])
    return (f'<h3>One damper under several conditions</h3><p>This data set is one condition ({here}) of a damper '
            f"diagnosed under several. Its own loop selected: {_e(own)}. Every effect a condition selected "
            f"({_e(', '.join(c.get('union') or []) or 'none')}) was fitted at every condition; the explanation kept "
            f"on the evidence pooled over them: <b>{_e(', '.join(c.get('kept') or []) or 'none')}</b>. "
            "Per parameter, the values at each condition (90 % intervals) and whether they are shared (Cochran's Q) "
            "or vary with the condition (weighted straight line against it). The full account is "
            "<code>conditions.json</code> one folder up.</p>"
            + (_table(["parameter", "per condition", "verdict"], rows, left=3) if rows else ""))


def record_drift_table(drift: Mapping | None, mass: float) -> str:
    """Slow drift within long records: per record and parameter the change over the record (a % of the parameter's
    mean, with its interval) against the windows' time and, where the records carry one, their temperature."""
    if not drift:
        return ""
    rows = []
    for test, rec in drift.items():
        for axis, trends in (rec.get("trends") or {}).items():
            for name, t in trends.items():
                rows.append([_e(test), str(rec.get("n_windows", "")), _e("time" if axis == "time_s" else
                                                                         "temperature"),
                             _e(_LABEL.get(name, name)), _pct_interval(t.get("change")),
                             "yes" if t.get("credible_nonzero") else "no"])
    pct = f"{round(100 * mass)} %"
    return ("<h3>Drift within a record</h3><p>The windows of one long record share its speed: a trend among them is "
            "the record's own slow drift (the fluid warming, say). Change over the record, as a share of the "
            f"parameter's mean, with its {pct} interval, from a straight line in the windows' mid-time (and mean "
            "temperature, where the records have a temperature_C column).</p>"
            + _table(["record", "windows", "against", "parameter", f"change over the record ({pct})",
                      "credible"], rows))
