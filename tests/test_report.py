"""The HTML report: one page for any data set (triangular tests, other records cut into windows of cycles, or
both), its tables, the images that exist, the diagnosis and the provenance.

The summaries and diagnoses are built by hand in the layout of ``summary.json`` and ``diagnosis.json``; two tiny
runs (a triangular test and a sine, a few sampler steps) check the report on what the producers really write.
"""

from __future__ import annotations

import copy
import json
import re
from html import escape
from html.parser import HTMLParser
from pathlib import Path

import pytest
from independent import SMALL, SMALL_FLOW, make_record, sine_input
from independent import write_dataset as write_records

from bayesdamper.core.params import DynamicParameters
from bayesdamper.io.synthetic import write_dataset
from bayesdamper.report.html import REPORT_FILE, render_report
from bayesdamper.run.report import run_report

#: The smallest valid PNG (1 x 1 pixel), standing in for a figure.
PNG = bytes.fromhex("89504e470d0a1a0a0000000d49484452000000010000000108060000001f15c489"
                    "0000000d49444154789c63000100000500010d0a2db40000000049454e44ae426082")
#: The report's sections, in order (their anchors).
SECTIONS = ["data", "static", "posterior", "windows", "drift", "diagnosis", "provenance"]
RULE = "whole cycles of the record's own period: the fewest that last at least 10 s"
FLOW = {"CL12": 3.0e9, "CQ12": 2.0e13, "CL21": 2.5e9, "CQ21": 2.5e13}


class _Page(HTMLParser):
    """Image sources, links, section anchors, and every table as rows of cell texts, of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.links: list[str] = []
        self.anchors: list[str] = []
        self.tables: list[list[list[str]]] = []
        self.scripts = 0
        self._cell: list[str] | None = None

    @property
    def cells(self) -> list[str]:
        return [c for t in self.tables for row in t for c in row]

    def table(self, header_cell: str) -> list[list[str]]:
        """The only table whose header row has ``header_cell``."""
        (found,) = [t for t in self.tables if header_cell in t[0]]
        return found

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a["src"])
        elif tag == "a" and "href" in a:
            self.links.append(a["href"])
        elif tag == "h2":
            self.anchors.append(a.get("id"))
        elif tag == "script":
            self.scripts += 1
        elif tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.tables[-1][-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def parse(path: Path) -> tuple[str, _Page]:
    text = path.read_text(encoding="utf-8")
    page = _Page()
    page.feed(text)
    return text, page


def _interval(m, lo, hi):
    return {"median": m, "lo": lo, "hi": hi}


# ------------------------------------------------------------------------------------------- hand-built summaries
def _entry(sid: str, velocity: float, direction: int, converged: bool) -> dict:
    """A transient's entry (cut posterior, noise from the plateaus)."""
    return {"id": sid, "test": sid.rsplit("_s", 1)[0], "kind": "initial" if sid.endswith("s0") else "reversal",
            "direction": direction, "velocity_m_s": velocity, "t_start_s": 1.0,
            "window": {"id": sid, "test": sid.rsplit("_s", 1)[0], "kind": "reversal", "t_start_s": 1.0,
                       "t_end_s": 4.0, "n_samples": 300, "starts_settled": True},
            "alpha_V": _interval(33.3, 32.9, 33.7), "p_R_Pa": _interval(3.01e5, 2.95e5, 3.08e5),
            "dp0_Pa": _interval(-500.0, -1800.0, 700.0),
            "flow": {k: _interval(v, 0.99 * v, 1.01 * v) for k, v in FLOW.items()},
            "ls": {"alpha_V": 33.2, "p_R_Pa": 3.0e5, "J": 0.0071}, "J": 0.0070,
            "rhat_max": 1.004 if converged else 1.08, "ess_bulk_min": 1800.0 if converged else 240.0,
            "converged": converged, "convergence": "converged" if converged else "step budget exhausted",
            "tau": {"alpha_V": 12.0, "p_R_Pa": 11.5, "dp0_Pa": float("inf") if not converged else 15.0},
            "shape": {"ridge": not converged, "multimodal": False, "at_prior_bound": False},
            "coupling": "cut", "propagated": True, "flow_prior": "stage 1 (plateaus)",
            "noise": {"phi": -0.0135, "sigma_N": 19.99, "source": "plateaus", "model": "plateau"},
            "window_scale_ratio": 0.96, "sampler": {"n_walkers": 12}, "wall_s": 3.0}


def _cycle_window(test: str, k: int, t0: float, t1: float, kind: str = "sine") -> dict:
    """A window of cycles as the plan describes it."""
    return {"id": f"{test}_w{k}", "test": test, "kind": "cycles", "t_start_s": t0, "t_end_s": t1,
            "n_samples": int(round(100 * (t1 - t0))), "starts_settled": k == 0 and kind == "random",
            "rule": RULE, "cycle_s": 1.0, "cycles": 10.0 if k == 0 else 7.25, "periodic": kind == "sine",
            "decimation": 1, "rate_Hz": 100.0, "starts": "motion" if k == 0 else "previous window",
            "ends_at_rest": False, "record_kind": kind, "input": _INPUTS[test]}


_INPUTS = {"sine": {"noise_sd_m": 3.1e-6, "adc_step_m": 5.0e-7, "residual_rms_m": 2.9e-6,
                    "velocity_error_m_s": 4.2e-4, "n_bootstrap": 8, "method": "quintic smoothing spline, GCV"},
           "rand": {"noise_sd_m": 1.2e-6, "adc_step_m": 0.0, "residual_rms_m": 1.1e-6,
                    "velocity_error_m_s": 1.7e-4, "n_bootstrap": 8, "method": "quintic smoothing spline, GCV"}}


def _cycle_entry(window: dict, alpha_v: float, ratio: float, prior: str = "flat (no plateaus): sampled with the "
                 "window") -> dict:
    """A window of cycles' entry: flow coefficients sampled, noise from the window's spectrum, input error."""
    flat = prior.startswith("flat")
    return {"id": window["id"], "test": window["test"], "kind": "cycles", "direction": 0, "velocity_m_s": 0.0628,
            "t_start_s": window["t_start_s"], "window": window,
            "alpha_V": _interval(alpha_v, alpha_v - 1.5, alpha_v + 1.5), "p_R_Pa": _interval(3.2e5, 2.7e5, 3.6e5),
            "dp0_Pa": _interval(2.33e5, 2.29e5, 2.36e5),
            "flow": {k: _interval(v * 1.001, v * 0.97, v * 1.03) for k, v in FLOW.items()},
            "ls": {"alpha_V": alpha_v, "p_R_Pa": 3.19e5, "J": 0.0139,
                   **({k: v for k, v in FLOW.items()} if flat else {})},
            "J": 0.0138, "rhat_max": 1.002, "ess_bulk_min": 3700.0, "converged": True, "convergence": "converged",
            "tau": {"alpha_V": 3.7, "p_R_Pa": 3.3}, "shape": {"ridge": True}, "coupling": "joint",
            "propagated": True, "flow_prior": prior,
            "noise": {"phi": 0.21 if flat else -0.0135, "sigma_N": 1.92 if flat else 19.99,
                      "source": f"spectrum 3-49 Hz of {window['id']}'s residual" if flat else "plateaus"},
            "window_scale_ratio": ratio, "input_error": {"force_rms_N": 0.4, "relative_to_noise": 0.21,
                                                         "replicates": 4},
            "sampler": {"n_walkers": 16}, "wall_s": 26.0}


def _base(name: str, entries: list, records: list, plan_records: list, windows: list) -> dict:
    drift = {n: {"slope_per_m_s": _interval(-1.0, -3.0, 1.0), "intercept": _interval(1, 0, 2),
                 "credible_nonzero": False, "intrinsic_scatter": 0.1, "n_transients": 2, "by_direction": {}}
             for n in ("alpha_V", "p_R_Pa")}
    return {
        "dataset": name, "credible_mass": 0.9, "seed": 11, "tmax_s": 3.0, "mode": "auto", "segments": entries,
        "drift": drift, "n_converged": sum(e["converged"] for e in entries),
        "plan": {"mode": "auto", "records": plan_records, "windows": windows,
                 "inputs": {w["test"]: w["input"] for w in windows if "input" in w}},
        "settings": {"credible_mass": 0.9, "noise_model": "plateau", "alpha_v_bounds": [2.0, 5000.0],
                     "p_r_bounds": [1e3, 1e7], "sampler": {"n_ensembles": 4, "n_walkers": 12, "max_steps": 6000,
                                                           "tau_factor": 50.0, "rhat_max": 1.01, "ess_min": 1000.0}},
        "provenance": {"dataset": name, "dataset_path": "/data/rig-A",
                       "input_sha256": {"damper.toml": "ab" * 32, records[0]["file"]: "cd" * 32},
                       "dataset_sha256": "ef" * 32, "versions": {"python": "3.11.9", "numpy": "2.1.0"},
                       "settings_fingerprint": "12" * 32},
        "static_uncertainty": {"method": "propagated", "coupling": "cut", "propagated": True},
        "data": {"damper": {"piston_area": 0.0042, "chamber_volume_1": 1.5e-4, "chamber_volume_2": 1.5e-4,
                            "liquid_bulk_modulus": 1.5e9, "name": "rig-A"}, "records": records, "steps": []},
        "figures": {"figure3_static": [], "figure8_transients": [], "figure9_drift": ["figures/figure9_drift.png"],
                    "loops": [f"figures/loops/{e['id']}.png" for e in entries if e["kind"] == "cycles"]},
        "wall_time_s": 12.5,
    }


_TRI_RECORDS = [{"name": f"tri_{v}mm_s", "file": f"tri_{v}mm_s.csv", "n_samples": 5101, "sample_rate_Hz": 100.0,
                 "duration_s": 51.0, "sha256": c * 32} for v, c in (("0p50", "cd"), ("1p00", "a1"), ("1p50", "b2"))]
_TRI_PLAN = [{"name": r["name"], "kind": "triangular", "description": "triangular, speeds 0.50 mm/s"}
             for r in _TRI_RECORDS]
_SINE_RECORD = {"name": "sine", "file": "sine.csv", "n_samples": 1725, "sample_rate_Hz": 100.0, "duration_s": 17.25,
                "sha256": "98" * 32}
_SINE_PLAN = {"name": "sine", "kind": "sine", "description": "sine, amplitude 10 mm, 1 Hz"}


def _triangular() -> dict:
    """Three transients of triangular tests with stage 1 (the static coefficients) and plateau noise."""
    entries = [_entry("tri_0p50mm_s_s0", 5e-4, 1, True), _entry("tri_1p00mm_s_s1", 1e-3, -1, False),
               _entry("tri_1p50mm_s_s2", 1.5e-3, 1, True)]
    s = _base("rig <A> & co", entries, list(_TRI_RECORDS), list(_TRI_PLAN), [e["window"] for e in entries])
    s["mode_reason"] = "every record is a triangular test: transients after the velocity steps"
    s["static"] = {k: _interval(v, 0.98 * v, 1.02 * v)
                   for k, v in {"CL12": 2.4e10, "CQ12": 4.3e16, "CL21": 8.6e9, "CQ21": 5.1e16}.items()}
    s["static_constrained"] = []
    s["noise"] = {"phi": -0.0135, "sigma_N": 19.99, "source": "plateaus"}
    s["data"]["steps"] = [{"test": "tri_0p50mm_s", "index": 0, "kind": "initial", "direction": 1,
                           "velocity_m_s": 5e-4, "t_step_s": 1.0, "force_N": 0.5, "plateau_force_N": 1012.0}]
    s["figures"].update({"figure3_static": ["figures/figure3_static.png", "figures/figure3_static.pdf"],
                         "figure8_transients": ["figures/figure8_transients_p1.png",
                                                "figures/figure8_transients_p2.png"]})
    return s


def _cycles() -> dict:
    """A sine (two windows of cycles) and a random record (one), no plateaus: flow coefficients per window."""
    wins = [_cycle_window("sine", 0, 0.004, 10.004), _cycle_window("sine", 1, 10.004, 17.254),
            _cycle_window("rand", 0, 0.5, 12.0, "random")]
    entries = [_cycle_entry(wins[0], 30.2, 0.99), _cycle_entry(wins[1], 31.7, 2.31), _cycle_entry(wins[2], 29.4, 1.1)]
    rand_record = dict(_SINE_RECORD, name="rand", file="rand.csv", sha256="76" * 32)
    s = _base("cycles <B>", entries, [_SINE_RECORD, rand_record],
              [_SINE_PLAN, {"name": "rand", "kind": "other", "description": "random, 0.3-2 Hz"}], wins)
    s["mode_reason"] = "no triangular test: every record cut into windows of whole cycles, flow coefficients per window"
    s["static"], s["static_constrained"] = None, []
    s["static_uncertainty"] = {"method": "no plateaus", "propagated": True, "coupling": "joint"}
    return s


def _mixed() -> dict:
    """The triangular tests' transients with stage 1 (C_L,21 held at 0) and a sine's windows under its prior."""
    s = _triangular()
    wins = [_cycle_window("sine", 0, 0.004, 10.004), _cycle_window("sine", 1, 10.004, 17.254)]
    cyc = [_cycle_entry(w, a, r, "stage 1 (plateaus)") for w, a, r in zip(wins, (33.1, 33.4), (1.02, 1.04),
                                                                           strict=True)]
    s["segments"] = cyc + s["segments"]
    s["plan"]["records"].append(_SINE_PLAN)
    s["plan"]["windows"] = wins + s["plan"]["windows"]
    s["plan"]["inputs"] = {"sine": _INPUTS["sine"]}
    s["data"]["records"].append(_SINE_RECORD)
    s["figures"]["loops"] = [f"figures/loops/{w['id']}.png" for w in wins]
    s["static_constrained"] = ["C_L21"]
    s["mode_reason"] = "1 triangular test(s) segmented (stage 1 from their plateaus for every window), 1 other record"
    return s


KINDS = {"triangular": _triangular, "cycles": _cycles, "mixed": _mixed}


@pytest.fixture()
def summary() -> dict:
    return _triangular()


@pytest.fixture()
def diagnosis() -> dict:
    """A diagnosis in the layout of diagnosis.json: two rounds, the backward check dropping an effect, held-out
    gains with a fold set aside."""
    ids = ["tri_0p50mm_s_s0", "tri_1p00mm_s_s1", "tri_1p50mm_s_s2"]
    drift = {"alpha_V": {"slope_per_m_s": _interval(-2.0, -4.0, -0.5), "credible_nonzero": True,
                         "intrinsic_scatter": 0.2, "n_transients": 3}}
    cands = [{"effect": "friction", "score": -42.0, "criterion": "delta_BIC_eff", "J_pooled": 0.0081,
              "params": {"coulomb_N": _interval(35.0, 30.0, 40.0)}, "supported": True, "passes": True,
              "lovo": {"gain": 61.5, "se": 9.8, "per_fold": [55.0, 412.0, 70.0, 59.0, 62.0], "outlying_folds": [1]}},
             {"effect": "backlash", "score": 3.5, "criterion": "delta_BIC_eff", "J_pooled": 0.0120,
              "params": {"gap_m": _interval(1e-5, 2e-6, 3e-5)}}]
    final = [dict(_entry(i, 1e-3, 1, True), alpha_V=_interval(41.0, 40.5, 41.5), effects={"friction": {}})
             for i in ids]
    return {
        "dataset": "rig <A> & co", "noise_N": 19.7,
        "noise": {"sigma_N": 19.7, "rho": -0.01, "n": 6339, "source": "the plateaus of 3 triangular tests"},
        "baseline": {"J_pooled": 0.0123, "J": dict(zip(ids, [0.011, 0.013, 0.012], strict=True))},
        "candidates": cands,
        "rounds": [{"candidates": cands, "selected": "friction"},
                   {"candidates": [], "selected": "inertia",
                    "backward_check": [{"effect": "inertia", "delta_BIC_eff": 4.2, "J_without": 0.0082,
                                        "J_reduction": 0.01}]}],
        "selected": ["friction"],
        "final": {"J_pooled": 0.0080, "J": dict(zip(ids, [0.008, 0.0082, 0.0079], strict=True))},
        "windows": [{"id": i, "kind": "reversal", "t_start_s": 1.0, "t_end_s": 4.0} for i in ids],
        "final_segments": final,
        "drift_before": drift, "drift_after": {"alpha_V": dict(drift["alpha_V"], credible_nonzero=False)},
        "figures": {"residuals": ["figures/diagnosis/residuals.png"], "missing": ["figures/diagnosis/nope.png"],
                    "loops_after": ["figures/diagnosis_loops/sine_w0_after.png"]},
        "report_text": "Diagnosis of 'rig <A> & co': friction explains the early rise.",
    }


def _write_figures(out: Path, summary: dict, diagnosis: dict | None = None) -> None:
    """Write the figure files the dicts name, except figure8 page 2 and the diagnosis 'missing' one."""
    paths = [p for v in summary.get("figures", {}).values() for p in v]
    if diagnosis:
        paths += diagnosis["figures"]["residuals"] + diagnosis["figures"]["loops_after"]
    for p in paths:
        if "p2" in p:
            continue
        (out / p).parent.mkdir(parents=True, exist_ok=True)
        (out / p).write_bytes(PNG if p.endswith(".png") else b"%PDF-1.4\n")


def _check_common(out: Path, summary: dict) -> tuple[str, _Page]:
    """What every report holds: the sections in order, a posterior row and a noise row per window, the meaning of
    the intervals under model error, no scripts, only existing images and links, provenance, escaping."""
    text, page = parse(out / REPORT_FILE)
    assert page.scripts == 0
    assert page.anchors == SECTIONS
    assert page.images, "no figure in the report"
    for src in page.images:
        assert not src.startswith(("/", "http")) and (out / src).is_file(), src
    for href in page.links:
        if not href.startswith("#"):
            assert (out / href).is_file(), href
    posterior, noise = page.table("αV median [90%]"), page.table("noise estimated from")
    assert [r[0] for r in posterior[1:]] == [e["id"] for e in summary["segments"]]
    assert [r[0] for r in noise[1:]] == [e["id"] for e in summary["segments"]]
    for e, row, nrow in zip(summary["segments"], posterior[1:], noise[1:], strict=True):
        a = e["alpha_V"]
        assert row[4] == f"{a['median']:#.4g} [{a['lo']:#.4g}, {a['hi']:#.4g}]"
        assert nrow[1] == f"{e['noise']['phi']:.3f}" and nrow[3] == e["noise"]["source"]
        assert nrow[4] == f"{e['window_scale_ratio']:.2f}"
    assert "pseudo-true" in text and "σ<sub>w</sub>/σ" in text
    assert summary["mode_reason"] in text
    for k, v in summary["provenance"]["input_sha256"].items():
        assert k in page.cells and v in page.cells
    assert summary["provenance"]["settings_fingerprint"] in page.cells
    assert "numpy" in page.cells and "2.1.0" in page.cells
    assert "<A>" not in text and "<B>" not in text  # escaped
    assert "whole-record" not in text and "whole record" not in text
    return text, page


# ------------------------------------------------------------------------------------------- tests
def test_report_without_diagnosis(tmp_path, summary):
    _write_figures(tmp_path, summary)
    path = render_report(summary, None, tmp_path)
    assert path == tmp_path / REPORT_FILE
    text, page = _check_common(tmp_path, summary)
    assert "rig &lt;A&gt; &amp; co" in text
    assert "33.30 [32.90, 33.70]" in page.cells and "301.0 [295.0, 308.0]" in page.cells
    assert "figures/figure8_transients_p2.png" not in page.images  # named but not on disk: not referenced
    assert "No diagnosis is available" in text
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize("kind", list(KINDS))
def test_one_report_for_every_kind_of_data_set(tmp_path, kind):
    s = KINDS[kind]()
    _write_figures(tmp_path, s)
    render_report(s, None, tmp_path)
    text, page = _check_common(tmp_path, s)
    has_steps = any(e["kind"] != "cycles" for e in s["segments"])
    has_cycles = any(e["kind"] == "cycles" for e in s["segments"])
    # the transients' parts where there are transients, the cycles' where there are windows of cycles
    assert ("transient (step)" in page.cells) == has_steps
    assert ("figures/figure8_transients_p1.png" in page.images) == has_steps
    assert ("Transients (paper Fig. 8)" in text) == has_steps
    assert (escape(RULE) in text) == has_cycles
    assert ("figures/loops/sine_w0.png" in page.images) == has_cycles
    assert "input error / σ" in page.cells and ("reconstructed displacement" in text) == has_cycles
    assert ("prior" in page.cells) == has_cycles  # the flow coefficients sampled in the windows of cycles
    assert (s["static"] is not None) == ("figures/figure3_static.png" in page.images)
    records = page.table("what it is")
    assert {r[0]: r[1] for r in records[1:]} == {r["file"]: k["kind"] for r, k in
                                                 zip(s["data"]["records"], s["plan"]["records"], strict=True)}


def test_windows_of_cycles_without_plateaus(tmp_path):
    """Data: every window's span, cycles, start and the record's rule; the input's reconstruction per record.
    Static: one sentence. Posterior: flow coefficients per window, noise from the window, input error."""
    s = _cycles()
    _write_figures(tmp_path, s)
    render_report(s, None, tmp_path)
    text, page = _check_common(tmp_path, s)
    wins = page.table("cycles")
    assert [r[0] for r in wins[1:]] == ["sine_w0", "sine_w1", "rand_w0"]
    assert wins[1][1:6] == ["sine", "0.004 – 10.004", "10.00", "1", "motion"]
    assert wins[2][5] == "previous window" and wins[3][1] == "random"
    rec = page.table("ADC step [µm]")
    assert rec[1][:6] == ["sine", "quintic smoothing spline, GCV", "3.1", "0.5", "2.9", "0.42 (8 bootstrap replicates)"]
    assert escape(RULE) in text
    assert "estimated with the other parameters in every window" in text and "stage 1, paper Fig. 3" not in text
    assert "C<sub>L,12</sub>" not in text.split('id="static"')[1].split('id="posterior"')[0]  # no stage-1 table
    flow = page.table("prior")
    assert [r[0] for r in flow[1:]] == ["sine_w0", "sine_w1", "rand_w0"]
    assert flow[1][2] == "3.003e+09 [2.91e+09, 3.09e+09]" and flow[1][1].startswith("flat")
    noise = page.table("noise estimated from")
    assert noise[1][5:] == ["0.4", "0.21"]
    assert "<b>2.31</b>" in text and "in 1 window(s): sine_w1" in text  # σ_w/σ above 1.5: named, bold
    assert page.table("τ max")[0][2] == "dir" and page.table("τ max")[1][2] == "–"
    assert "3 window(s) of whole cycles of 2 other record(s)" in text
    assert "point fit is without plateaus, the least-squares fit of all seven parameters" in text


def test_mixed_data_set(tmp_path):
    """Transients with stage 1 (a coefficient held at 0) and windows of cycles under stage 1's prior."""
    s = _mixed()
    _write_figures(tmp_path, s)
    render_report(s, None, tmp_path)
    text, page = _check_common(tmp_path, s)
    static = page.table("constraint")
    assert [r[-1] for r in static[1:]] == ["–", "–", "held at 0", "–"]
    assert "held at 0 because the plateaus made them negative: C<sub>L,21</sub>" in text
    flow = page.table("prior")
    assert [r[0] for r in flow[1:]] == ["sine_w0", "sine_w1"] and flow[1][1] == "stage 1 (plateaus)"
    assert "3 transient(s) of 3 triangular test(s) and 2 window(s) of whole cycles of 1 other record(s)" in text
    assert "In 3 window(s) every other part has data of its own" in text
    assert "In 2 window(s) the pressure difference at the start" in text
    assert "stage 1's posterior as prior" in text
    records = page.table("what it is")
    assert [r[3] for r in records[1:]] == ["1 transient(s)"] * 3 + ["2 window(s) of cycles"]


def test_report_with_diagnosis(tmp_path, summary, diagnosis):
    _write_figures(tmp_path, summary, diagnosis)
    render_report(summary, diagnosis, tmp_path)
    text, page = _check_common(tmp_path, summary)
    assert "No diagnosis is available" not in text
    assert "figures/diagnosis/residuals.png" in page.images
    assert "figures/diagnosis_loops/sine_w0_after.png" in page.images
    assert "figures/diagnosis/nope.png" not in page.images
    cands = page.table("held-out gain (se)")
    assert [r[0] for r in cands[1:]] == ["friction", "backlash"]
    assert cands[1][5].startswith("+61.5 (se 9.8)") and cands[1][6] == "2" and cands[2][5:7] == ["–", "–"]
    assert "<s>+412</s>" in text  # the fold set aside, struck through
    assert "35.00 [30.00, 40.00]" in text or "35 [30, 40]" in text
    assert "0.0080" in page.cells and "0.0123" in page.cells  # pooled J before and after
    assert "the plateaus of 3 triangular tests" in page.cells  # where the noise came from
    dropped = page.table("effect dropped")
    assert dropped[1] == ["inertia", "+4.2", "0.0082", "1.0%"]
    assert "dropped by the backward check: inertia" in text
    per_window = page.table("J final")
    assert per_window[0][-3:] == ["final αV", "final pR [kPa]", "converged"]
    assert per_window[1][:3] == ["tri_0p50mm_s_s0", "reversal", "1.000 – 4.000"]
    assert per_window[1][5] == "41.00 [40.50, 41.50]"
    assert "friction explains the early rise" in text


def test_diagnosis_without_backward_check_or_held_out_gains(tmp_path, diagnosis):
    d = copy.deepcopy(diagnosis)
    for r in d["rounds"]:
        r.pop("backward_check", None)
    for c in d["candidates"]:
        c.pop("lovo", None)
    d["selected"] = []
    s = _cycles()
    render_report(s, d, tmp_path)
    text, page = parse(tmp_path / REPORT_FILE)
    assert "Backward check" not in text and "effect dropped" not in page.cells
    assert page.table("held-out gain (se)")[1][5:7] == ["–", "–"]
    assert "final αV" not in page.cells  # no final model table without a selection


def test_report_without_figures_says_so(tmp_path, summary):
    del summary["figures"]
    text, page = parse(render_report(summary, None, tmp_path))
    assert page.images == []
    assert text.count("was not drawn") == 3  # Figures 3, 8 and 9
    s = _cycles()
    del s["figures"]
    text, page = parse(render_report(s, None, tmp_path))
    assert page.images == [] and text.count("was not drawn") == 1 and "loops were not drawn" in text


# ------------------------------------------------------------------------------------------- tiny runs
def test_report_command_on_a_tiny_run(tmp_path):
    data = write_dataset(tmp_path / "sim", [0.5e-3, 1.0e-3, 1.5e-3], DynamicParameters(1 / 0.03, 3.0e5),
                         sample_rate=100.0, noise_n=20.0, seed=1)
    out = tmp_path / "out"
    (page_path,) = run_report(str(data), str(out), only="tri_1p00mm_s_s0", max_steps=200, workers=1)
    assert page_path == out / REPORT_FILE
    summary = json.loads((out / "summary.json").read_text())
    text, page = parse(page_path)
    assert page.scripts == 0 and page.anchors == SECTIONS
    assert {Path(p).name for p in page.images} == {"figure3_static.png", "figure8_transients_p1.png",
                                                   "figure9_drift.png"}
    for src in page.images:
        assert (out / src).is_file(), src
    assert "tri_1p00mm_s_s0" in page.cells and "plateaus" in page.table("noise estimated from")[1]
    assert summary["provenance"]["dataset_sha256"] in page.cells
    assert re.search(r"No diagnosis is available for this run: --only selects a subset", text)


def test_report_command_on_a_tiny_sine(tmp_path):
    """A 4 s sine of the small damper: one window of cycles, flow coefficients sampled, its loops drawn."""
    rec = make_record(sine_input(0.01, 1.0), 4.0, 50.0, SMALL, SMALL_FLOW, 30.0, 3.0e5, noise="white", sd=2.0,
                      seed=4, t_start=0.0037)
    data = write_records(tmp_path / "sine", {"sine": rec}, SMALL, "tiny-sine")
    out = tmp_path / "out"
    (page_path,) = run_report(str(data), str(out), only="sine_w0", max_steps=40, workers=1)
    summary = json.loads((out / "summary.json").read_text())
    text, page = parse(page_path)
    assert page.anchors == SECTIONS
    assert {Path(p).name for p in page.images} == {"sine_w0.png", "figure9_drift.png"}
    entry = summary["segments"][0]
    assert page.table("prior")[1][0] == "sine_w0"
    noise = page.table("noise estimated from")[1]
    assert noise[3] == entry["noise"]["source"] and noise[4] == f"{entry['window_scale_ratio']:.2f}"
    assert noise[6] == f"{entry['input_error']['relative_to_noise']:.2g}"
    win = page.table("cycles")[1]
    assert win[0] == "sine_w0" and win[2] == f"{entry['window']['t_start_s']:.3f} – {entry['window']['t_end_s']:.3f}"
    assert summary["mode_reason"] in text and "transient (step)" not in page.cells


def test_drift_within_a_record_is_tabled(tmp_path):
    """A record's slow drift (summary["drift_within_records"]): one row per record, axis and parameter, the change
    over the record in % with its interval, and whether it is credible."""
    s = _cycles()
    trend = {"slope": {"median": -1.0, "lo": -1.2, "hi": -0.8}, "credible_nonzero": True,
             "change": {"median": -0.19, "lo": -0.23, "hi": -0.15}}
    flat = {"slope": {"median": 0.0, "lo": -0.1, "hi": 0.1}, "credible_nonzero": False,
            "change": {"median": 0.001, "lo": -0.02, "hi": 0.02}}
    s["drift_within_records"] = {"sine": {"n_windows": 4, "trends": {"time_s": {"C_L12": trend, "alpha_V": flat},
                                                                     "temperature_C": {"C_L12": trend}}}}
    _write_figures(tmp_path, s)
    render_report(s, None, tmp_path)
    _, page = parse(tmp_path / "report.html")
    rows = page.table("change over the record (90 %)")
    assert rows[1] == ["sine", "4", "time", "C_L12", "-19 % [-23, -15]", "yes"]
    assert rows[2][3:] == ["α_V", "+0 % [-2, +2]", "no"] and rows[3][2] == "temperature"


def test_segmentation_table_says_how_each_plateau_entered_stage_one(tmp_path):
    """A plateau left out, one whose settled force was extrapolated from its approach, and a settled one."""
    s = _triangular()
    step = s["data"]["steps"][0]
    s["data"]["steps"] = [step,
                          dict(step, index=1, kind="reversal", direction=-1, plateau_force_N=-950.0,
                               plateau_in_stage1=False),
                          dict(step, index=2, kind="reversal", plateau_force_N=1020.0, plateau_in_stage1=True,
                               plateau_approach_tau_s=0.4321)]
    _write_figures(tmp_path, s)
    render_report(s, None, tmp_path)
    page = _Page()
    page.feed((tmp_path / REPORT_FILE).read_text())
    rows = {r[0]: r[-1] for r in page.table("transient (step)")[1:]}
    assert rows["tri_0p50mm_s_s0"] == "1012.0"
    assert rows["tri_0p50mm_s_s1"].endswith("drifting: not in stage 1")
    assert rows["tri_0p50mm_s_s2"].startswith("1020.0") and "approached (τ 0.43 s)" in rows["tri_0p50mm_s_s2"]
