"""The drift law (bayesdamper/inference/hierarchy.py) on data bayesdamper did not make (slow).

The criterion: "On independent data (a separate generator, parameters drifting with speed by a known law
plus scatter): the hierarchical trend's 90 % bands hold the true law at >= 85 % of speeds, and the test-to-test
scatter is recovered within its interval."

Data: tests/independent.py (scipy Radau, eq. (7) re-derived from the paper, no bayesdamper import), rig-A's damper
and the paper's Fig. 3 flow coefficients, rig-A's protocol as in tests/transient_coverage.py (1 s at rest, a 5 mm
triangle for 1.25 cycles: a start from rest and two reversals), nine tests at 0.5-1.5 mm/s (the paper's range),
250 Hz, white force noise of 10 N, the first step off the sample grid and different in every record. Test t has its
own true parameters, the same in all three of its windows (eq. (7) is exact, so the true scatter within a test is 0):

    log α_V,t = log LAW_ALPHA(v_t) + e_1,t,   log p_R,t = log LAW_P(v_t) + e_2,t,   e_t ~ N(0, diag(τ_α², τ_p²)),

with laws linear in physical units (so not the model's form, a straight line of the LOG parameters; over 0.5-1.5 mm/s
the log of either law departs from its chord by at most 1.1 % (α_V) and 2.1 % (p_R), a fraction of the band's width
here) and shallow like the paper's Fig. 9 (α_V falls by 26 %, p_R rises by 50 % over the range).

Identification: ``bayesdamper identify`` through its command line in a subprocess (stage 1 estimates the flow
coefficients; nothing of the truth is given), then summary.json["drift_model"].
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from independent import PAPER_FLOW, RIG_A, make_record, triangle_input, write_dataset

SPEEDS = tuple(np.linspace(0.5e-3, 1.5e-3, 9))  # [m/s] the paper's range, nine tests
AMPLITUDE = 5e-3  # [m] rig-A's triangle
REST = 1.0  # [s] at rest before the first step
RATE = 250.0  # [Hz]
SD = 10.0  # [N] white force noise (rig-A's force reads 12-13 N rms at rest)
TAU = (0.10, 0.15)  # [log units] true sd between tests of log α_V, log p_R (the population value)
SEED = 2026  # fixed before the first run, not tuned
V_REF = 1e-3  # [m/s] the laws' reference speed
NAMES = ("alpha_V", "p_R_Pa")
#: The criterion: the 90 % band of the law holds the true law at this share of the grid speeds at least.
MIN_COVERAGE = 0.85


def law_alpha(v):
    """True population law of α_V [-]: linear in speed, 60 at 1 mm/s, falling by 30 % per mm/s."""
    return 60.0 * (1.0 - 0.3 * (np.asarray(v, float) - V_REF) / V_REF)


def law_p(v):
    """True population law of p_R [Pa]: linear in speed, 0.3 MPa at 1 mm/s, rising by 40 % per mm/s."""
    return 3.0e5 * (1.0 + 0.4 * (np.asarray(v, float) - V_REF) / V_REF)


LAWS = {"alpha_V": law_alpha, "p_R_Pa": law_p}


def _name(v: float) -> str:
    return f"tri_{v * 1e3:.3f}mm_s".replace(".", "p")


def _truth() -> tuple[dict, np.ndarray]:
    """Per-test true (α_V, p_R) and the drawn log deviations e (n_tests, 2) from the law."""
    e = np.random.default_rng(SEED).standard_normal((len(SPEEDS), 2)) * np.array(TAU)
    truth = {_name(v): (float(law_alpha(v)) * math.exp(e[k, 0]), float(law_p(v)) * math.exp(e[k, 1]))
             for k, v in enumerate(SPEEDS)}
    return truth, e


def _records(truth: dict) -> dict:
    records = {}
    for k, v in enumerate(SPEEDS):
        offset = ((k + 1) * 0.6180339887) % 1.0  # an irrational fraction of a sample interval, different per record
        t_first = REST + offset / RATE
        inp = triangle_input(v, AMPLITUDE, 0.0, t_first, cycles=1.25)
        duration = t_first + 5 * AMPLITUDE / v + 0.05  # the last ramp ends with the record
        alpha, p_r = truth[_name(v)]
        records[_name(v)] = make_record(inp, duration, RATE, RIG_A, PAPER_FLOW, alpha, p_r, sd=SD,
                                        seed=[SEED, k], rtol=1e-10)
    return records


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """Truth, drawn deviations, summary.json and wall times of data generation and identification."""
    root = tmp_path_factory.mktemp("drift_law_independent")
    t0 = time.perf_counter()
    truth, e = _truth()
    data = write_dataset(root / "data", _records(truth), RIG_A, "independent-drift")
    t_data = time.perf_counter() - t0
    out = root / "out"
    cmd = [sys.executable, "-m", "bayesdamper", "identify", str(data), "--out", str(out), "--seed", str(SEED),
           "--no-figures", "--workers", "2"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    t_identify = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-4000:]
    summary = json.loads((out / "summary.json").read_text())
    return truth, e, summary, {"data": t_data, "identify": t_identify}


def _coverage(drift: dict, name: str) -> float:
    """Share of the grid speeds at which the law's 90 % band holds the true law."""
    grid = np.asarray(drift["speed_grid_m_s"])
    law = drift["parameters"][name]["law"]
    true = LAWS[name](grid)
    return float(np.mean((np.asarray(law["lo"]) <= true) & (true <= np.asarray(law["hi"]))))


def _tables(truth: dict, e: np.ndarray, summary: dict, wall: dict) -> str:
    drift = summary["drift_model"]
    lines = [f"wall time: data {wall['data']:.0f} s, identify {wall['identify']:.0f} s; "
             f"{drift.get('n_windows')} windows in {drift.get('n_tests')} tests, "
             f"law fit converged {drift['sampling']['converged']} (R-hat {drift['sampling']['rhat_max']:.3f})",
             "per test: truth vs the windows' posterior medians (kind: median [90 % interval])"]
    for k, v in enumerate(SPEEDS):
        test = _name(v)
        segs = sorted((s for s in summary["segments"] if s["test"] == test), key=lambda s: s["t_start_s"])
        a, p = truth[test]
        lines.append(f"  {test}: truth alpha_V {a:6.2f}, p_R {p / 1e3:6.1f} kPa (e = {e[k, 0]:+.3f}, {e[k, 1]:+.3f})")
        for s in segs:
            lines.append(f"    {s['kind']:9s} v {1e3 * s['velocity_m_s']:.3f} mm/s  alpha_V "
                         f"{s['alpha_V']['median']:6.2f} [{s['alpha_V']['lo']:6.2f}, {s['alpha_V']['hi']:6.2f}]  "
                         f"p_R {s['p_R_Pa']['median'] / 1e3:6.1f} [{s['p_R_Pa']['lo'] / 1e3:6.1f}, "
                         f"{s['p_R_Pa']['hi'] / 1e3:6.1f}] kPa  converged {s['converged']}")
    grid = np.asarray(drift["speed_grid_m_s"])
    lines.append(f"drift law (grid {1e3 * grid[0]:.3f}-{1e3 * grid[-1]:.3f} mm/s):")
    for j, name in enumerate(NAMES):
        par = drift["parameters"][name]
        law = par["law"]
        sc, ch = par["scatter_between_tests_log_sd"], par["change_over_range"]
        true_ch = LAWS[name](grid[-1]) / LAWS[name](grid[0]) - 1.0
        lines.append(f"  {name}: band holds the true law at {100 * _coverage(drift, name):.0f} % of speeds; "
                     f"at the ends true {LAWS[name](grid[0]):.4g} / {LAWS[name](grid[-1]):.4g}, band "
                     f"[{law['lo'][0]:.4g}, {law['hi'][0]:.4g}] / [{law['lo'][-1]:.4g}, {law['hi'][-1]:.4g}]")
        lines.append(f"    scatter between tests (log sd): tau {TAU[j]:.3f}, realised sd of e "
                     f"{e[:, j].std(ddof=1):.3f}; posterior {sc['median']:.3f} [{sc['lo']:.3f}, {sc['hi']:.3f}]")
        if "scatter_within_test_log_sd" in par:
            w = par["scatter_within_test_log_sd"]
            lines.append(f"    scatter within tests (log sd, truth 0): {w['median']:.3f} "
                         f"[{w['lo']:.3f}, {w['hi']:.3f}]")
        lines.append(f"    change over range: true {100 * true_ch:+.1f} %, posterior {100 * ch['median']:+.1f} % "
                     f"[{100 * ch['lo']:+.1f}, {100 * ch['hi']:+.1f}], drift_credible {par['drift_credible']}")
    return "\n".join(lines)


@pytest.mark.slow
def test_drift_law_bands_hold_the_true_law(identified, capsys):
    """The two rules, on one seeded data set.

    * The 90 % band of the population law holds the true law at >= 85 % of the 41 grid speeds, per parameter (the
      stated number).
    * The true τ of each parameter lies inside the 90 % interval of the sd between tests. The model estimates the
      sd of the population the tests are drawn from, so it is compared with τ, not with the realised sd of the nine
      drawn e (printed alongside).

    Both are random events of the nine drawn tests, not margins: a pointwise 90 % band misses a whole stretch of
    speeds when the drawn e happen to lean with speed, and a 90 % interval misses τ one time in ten. Measured with the
    law fit alone on 44 seeds (window posteriors emulated as narrow Gaussians about each test's truth, which reproduced
    the full runs of seeds 1-4): the band held the true law at all 41 speeds in 39 (α_V) and 34 (p_R) of 44 sets, at
    < 85 % in 4 and 10 (mean share 0.96 and 0.90, nominal 0.90); τ fell outside its interval in 5 and 7 sets; at least
    one of the four checks failed in 22 of 44. So a fail here on a new seed or a changed sampler is not by itself a
    defect; SEED was fixed before the first run and passes (all shares 100 %, τ inside both intervals).
    """
    truth, e, summary, wall = identified
    drift = summary["drift_model"]
    with capsys.disabled():
        print("\n[drift law on independent data]\n" + _tables(truth, e, summary, wall))
    assert drift["fitted"] is True, drift.get("reason")
    assert drift["sampling"]["converged"] is True, drift["sampling"]
    assert drift["n_tests"] == len(SPEEDS)
    for j, name in enumerate(NAMES):
        assert _coverage(drift, name) >= MIN_COVERAGE, name
        sc = drift["parameters"][name]["scatter_between_tests_log_sd"]
        assert sc["lo"] <= TAU[j] <= sc["hi"], (name, TAU[j], sc)


@pytest.mark.slow
def test_the_pipeline_law_is_the_law_of_the_true_test_parameters(identified, capsys):
    """The robust half of the check: the law identify fitted from its windows' posteriors agrees with the law fitted
    to the tests' true parameters themselves (each of a test's three windows a narrow posterior, 1 % sd, about the
    truth): what the law says when every window is identified perfectly. Its median within a quarter of that law's
    90 % band at every grid speed (the windows' own errors are about 1 %, the band's width is set by the scatter of
    nine tests, some 20-40 %; a biased window identification or a wrong grouping of windows into tests moves the
    law by about a band)."""
    from bayesdamper.inference.hierarchy import WindowDraws, fit_hierarchy

    truth, _, summary, _ = identified
    drift = summary["drift_model"]
    rng = np.random.default_rng(0)
    wins = [WindowDraws(f"{test}_s{k}", float(v), np.exp(np.log(truth[test]) + 0.01 * rng.standard_normal((400, 2))),
                        test)
            for v, test in ((v, _name(v)) for v in SPEEDS) for k in range(3)]
    oracle = fit_hierarchy(wins, seed=0).summary(0.9)
    rows = []
    for name in NAMES:
        got = np.log(np.asarray(drift["parameters"][name]["law"]["median"]))
        ref = oracle["parameters"][name]["law"]
        mid = np.log(np.asarray(ref["median"]))
        width = np.log(np.asarray(ref["hi"])) - np.log(np.asarray(ref["lo"]))
        rows.append(f"  {name}: |pipeline - oracle| / oracle band width, max {np.max(np.abs(got - mid) / width):.3f}")
        assert np.all(np.abs(got - mid) <= 0.25 * width), name
    with capsys.disabled():
        print("\n[drift law: pipeline against the law of the true test parameters]\n" + "\n".join(rows))
