"""The HTML report: tables, images that exist, provenance; with and without a diagnosis."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest

from bayesdamper.core.params import DynamicParameters
from bayesdamper.io.synthetic import write_dataset
from bayesdamper.report.html import REPORT_FILE, render_report
from bayesdamper.run.report import run_report

#: The smallest valid PNG (1 x 1 pixel), standing in for a figure.
PNG = bytes.fromhex("89504e470d0a1a0a0000000d49484452000000010000000108060000001f15c489"
                    "0000000d49444154789c63000100000500010d0a2db40000000049454e44ae426082")


class _Page(HTMLParser):
    """Collects image sources, links and table cell texts of a page."""

    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.links: list[str] = []
        self.cells: list[str] = []
        self.scripts = 0
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a["src"])
        elif tag == "a" and "href" in a:
            self.links.append(a["href"])
        elif tag == "script":
            self.scripts += 1
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell).strip())
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


def _entry(sid: str, velocity: float, direction: int, converged: bool) -> dict:
    return {"id": sid, "test": sid.rsplit("_s", 1)[0], "kind": "initial" if sid.endswith("s0") else "reversal",
            "direction": direction, "velocity_m_s": velocity, "t_start_s": 1.0,
            "alpha_V": _interval(33.3, 32.9, 33.7), "p_R_Pa": _interval(3.01e5, 2.95e5, 3.08e5),
            "phi": _interval(0.05, -0.02, 0.12), "ls": {"alpha_V": 33.2, "p_R_Pa": 3.0e5, "J": 0.0071},
            "J": 0.0070, "rhat_max": 1.004 if converged else 1.08, "ess_bulk_min": 1800.0 if converged else 240.0,
            "converged": converged, "convergence": "converged" if converged else "step budget exhausted",
            "tau": {"alpha_V": 12.0, "p_R_Pa": 11.5, "phi": float("inf") if not converged else 15.0},
            "shape": {"ridge": not converged, "multimodal": False, "at_prior_bound": False},
            "posterior_mean": {"alpha_V": 33.3, "p_R_Pa": 3.01e5}, "posterior_sd": {"alpha_V": 0.2, "p_R_Pa": 4e3},
            "static_sensitivity": {"ratio": {"alpha_V": 0.1, "p_R_Pa": 0.2}, "negligible": True}, "wall_s": 3.0}


@pytest.fixture()
def summary() -> dict:
    """A hand-built summary of three transients, in the layout of summary.json."""
    entries = [_entry("tri_0p50mm_s_s0", 5e-4, 1, True), _entry("tri_1p00mm_s_s1", 1e-3, -1, False),
               _entry("tri_1p50mm_s_s2", 1.5e-3, 1, True)]
    drift = {n: {"slope_per_m_s": _interval(-1.0, -3.0, 1.0), "intercept": _interval(1, 0, 2),
                 "credible_nonzero": False, "intrinsic_scatter": 0.1, "n_transients": 2, "by_direction": {}}
             for n in ("alpha_V", "p_R_Pa")}
    return {
        "dataset": "rig <A> & co", "credible_mass": 0.9, "seed": 11, "tmax_s": 3.0,
        "static": {k: _interval(v, 0.98 * v, 1.02 * v)
                   for k, v in {"CL12": 2.4e10, "CQ12": 4.3e16, "CL21": 8.6e9, "CQ21": 5.1e16}.items()},
        "segments": entries, "drift": drift, "n_converged": 2,
        "settings": {"credible_mass": 0.9, "noise_model": "ar1", "alpha_v_bounds": [2.0, 5000.0],
                     "p_r_bounds": [1e3, 1e7], "sampler": {"n_ensembles": 4, "n_walkers": 12, "max_steps": 6000,
                                                           "tau_factor": 50.0, "rhat_max": 1.01, "ess_min": 1000.0}},
        "provenance": {"dataset": "rig <A> & co", "dataset_path": "/data/rig-A",
                       "input_sha256": {"damper.toml": "ab" * 32, "tri_0p50mm_s.csv": "cd" * 32},
                       "dataset_sha256": "ef" * 32, "versions": {"python": "3.11.9", "numpy": "2.1.0"},
                       "settings_fingerprint": "12" * 32},
        "static_uncertainty": {"method": "re-fit", "max_ratio": {"alpha_V": 0.1, "p_R_Pa": 0.2},
                               "median_ratio": {"alpha_V": 0.05, "p_R_Pa": 0.1}, "threshold": 0.3,
                               "negligible": True},
        "data": {"damper": {"piston_area": 0.0042, "chamber_volume_1": 1.5e-4, "chamber_volume_2": 1.5e-4,
                            "liquid_bulk_modulus": 1.5e9, "name": "rig-A"},
                 "records": [{"name": "tri_0p50mm_s", "file": "tri_0p50mm_s.csv", "n_samples": 5101,
                              "sample_rate_Hz": 100.0, "duration_s": 51.0, "sha256": "cd" * 32}],
                 "steps": [{"test": "tri_0p50mm_s", "index": 0, "kind": "initial", "direction": 1,
                            "velocity_m_s": 5e-4, "t_step_s": 1.0, "force_N": 0.5, "plateau_force_N": 1012.0}]},
        "figures": {"figure3_static": ["figures/figure3_static.png", "figures/figure3_static.pdf"],
                    "figure8_transients": ["figures/figure8_transients_p1.png", "figures/figure8_transients_p2.png"],
                    "figure9_drift": ["figures/figure9_drift.png"]},
        "wall_time_s": 12.5,
    }


@pytest.fixture()
def diagnosis() -> dict:
    """A diagnosis in the layout of diagnosis.json."""
    ids = ["tri_0p50mm_s_s0", "tri_1p00mm_s_s1", "tri_1p50mm_s_s2"]
    drift = {"alpha_V": {"slope_per_m_s": _interval(-2.0, -4.0, -0.5), "credible_nonzero": True,
                         "intrinsic_scatter": 0.2, "n_transients": 3}}
    return {
        "dataset": "rig <A> & co", "noise_N": 19.7,
        "baseline": {"J_pooled": 0.0123, "J": dict(zip(ids, [0.011, 0.013, 0.012], strict=True))},
        "candidates": [
            {"effect": "friction", "score": -42.0, "criterion": "delta_BIC_eff", "J_pooled": 0.0081,
             "params": {"coulomb_N": _interval(35.0, 30.0, 40.0)}},
            {"effect": "backlash", "score": 3.5, "criterion": "delta_BIC_eff", "J_pooled": 0.0120,
             "params": {"gap_m": _interval(1e-5, 2e-6, 3e-5)}}],
        "selected": ["friction"],
        "final": {"J_pooled": 0.0080, "J": dict(zip(ids, [0.008, 0.0082, 0.0079], strict=True))},
        "drift_before": drift, "drift_after": {"alpha_V": dict(drift["alpha_V"], credible_nonzero=False)},
        "figures": {"residuals": ["figures/diagnosis/residuals.png"], "missing": ["figures/diagnosis/nope.png"]},
        "report_text": "Diagnosis of 'rig <A> & co': friction explains the early rise.",
    }


def _write_figures(out: Path, summary: dict, diagnosis: dict | None = None) -> None:
    """Write the figure files the dicts name, except figure8 page 2 and the diagnosis 'missing' one."""
    paths = [p for v in summary["figures"].values() for p in v]
    if diagnosis:
        paths += diagnosis["figures"]["residuals"]
    for p in paths:
        if "p2" in p:
            continue
        (out / p).parent.mkdir(parents=True, exist_ok=True)
        (out / p).write_bytes(PNG if p.endswith(".png") else b"%PDF-1.4\n")


def _check_common(out: Path, summary: dict) -> tuple[str, _Page]:
    path = out / REPORT_FILE
    assert path.is_file()
    text, page = parse(path)
    assert page.scripts == 0
    assert page.images, "no figure in the report"
    for src in page.images:
        assert not src.startswith(("/", "http")) and (out / src).is_file(), src
    for href in page.links:
        if not href.startswith("#"):
            assert (out / href).is_file(), href
    for e in summary["segments"]:  # one posterior row per transient, with its interval
        assert e["id"] in page.cells
    assert "33.30 [32.90, 33.70]" in page.cells
    assert "301.0 [295.0, 308.0]" in page.cells
    for k, v in summary["provenance"]["input_sha256"].items():  # provenance
        assert k in page.cells and v in page.cells
    assert summary["provenance"]["settings_fingerprint"] in page.cells
    assert "numpy" in page.cells and "2.1.0" in page.cells
    assert "<A>" not in text and "rig &lt;A&gt; &amp; co" in text  # escaped
    return text, page


def test_report_without_diagnosis(tmp_path, summary):
    _write_figures(tmp_path, summary)
    path = render_report(summary, None, tmp_path)
    assert path == tmp_path / REPORT_FILE
    text, page = _check_common(tmp_path, summary)
    assert "figures/figure8_transients_p2.png" not in page.images  # named but not on disk: not referenced
    assert "No diagnosis is available" in text
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]


def test_report_with_diagnosis(tmp_path, summary, diagnosis):
    _write_figures(tmp_path, summary, diagnosis)
    render_report(summary, diagnosis, tmp_path)
    text, page = _check_common(tmp_path, summary)
    assert "No diagnosis is available" not in text
    assert "figures/diagnosis/residuals.png" in page.images
    assert "figures/diagnosis/nope.png" not in page.images
    assert "friction" in page.cells and "backlash" in page.cells
    assert "35.00 [30.00, 40.00]" in text or "35 [30, 40]" in text
    assert "0.0080" in page.cells and "0.0123" in page.cells  # pooled J before and after
    assert "friction explains the early rise" in text


def test_report_without_figures_says_so(tmp_path, summary):
    del summary["figures"]
    text, page = parse(render_report(summary, None, tmp_path))
    assert page.images == []
    assert text.count("was not drawn") == 3


def test_report_command_on_a_tiny_run(tmp_path):
    data = write_dataset(tmp_path / "sim", [0.5e-3, 1.0e-3, 1.5e-3], DynamicParameters(1 / 0.03, 3.0e5),
                         sample_rate=100.0, noise_n=20.0, seed=1)
    out = tmp_path / "out"
    (page_path,) = run_report(str(data), str(out), only="tri_1p00mm_s_s0", max_steps=200, workers=1)
    assert page_path == out / REPORT_FILE
    summary = json.loads((out / "summary.json").read_text())
    text, page = parse(page_path)
    assert page.scripts == 0
    assert {Path(p).name for p in page.images} == {"figure3_static.png", "figure8_transients_p1.png",
                                                   "figure9_drift.png"}
    for src in page.images:
        assert (out / src).is_file(), src
    assert "tri_1p00mm_s_s0" in page.cells
    assert summary["provenance"]["dataset_sha256"] in page.cells
    assert re.search(r"No diagnosis is available for this run: --only selects a subset", text)
