"""Whole-record identification on records bayesdamper did not make (tests/independent.py: scipy Radau).

Sine and multisine records at rates and start times off any grid used by bayesdamper, white noise; the
flow coefficients are never given, they are identified with α_V and p_R.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from independent import SMALL, SMALL_FLOW, make_record, multisine_input, sine_input, write_dataset

from bayesdamper.cli import main
from bayesdamper.core.errors import DataError
from bayesdamper.core.params import DamperConstants
from bayesdamper.inference.whole import WholeLogPosterior, WholeRecordProblem, WholeSpace, static_scales
from bayesdamper.inference.whole_stage import gauss_newton_covariance, point_fit, quasi_static_start
from bayesdamper.io.dataset import load_record
from bayesdamper.io.wholerecord import record_window
from bayesdamper.run.plan import TWO_STAGE, WHOLE, plan_dataset

DAMPER = DamperConstants(SMALL["area"], SMALL["v01"], SMALL["v02"], SMALL["b0"], "small")
TRUTH = dict(alpha_v=30.0, p_r=3.0e5)


def _sine(rate=200.0, duration=12.0, amplitude=0.01, freq=1.0, sd=2.0, seed=1, t_start=0.0037):
    return make_record(sine_input(amplitude, freq), duration, rate, SMALL, SMALL_FLOW,
                       TRUTH["alpha_v"], TRUTH["p_r"], noise="white", sd=sd, seed=seed, t_start=t_start,
                       rtol=1e-9)


@pytest.fixture(scope="module")
def sine_set(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sines")
    recs = {"sine_1hz": _sine(), "sine_2hz": _sine(rate=250.0, duration=8.0, amplitude=0.005, freq=2.0, seed=2)}
    write_dataset(folder, recs, SMALL, "small-sines")
    return folder


def test_point_fit_recovers_the_flow_coefficients_within_their_standard_errors(sine_set):
    """The least-squares optimum lies within 4 Gauss-Newton standard errors of the truth for every flow
    coefficient (4 sd: a two-sided 6e-5 chance per coefficient under a Gaussian posterior), and its J is
    at the noise floor (J of the truth + 2 %)."""
    rec = load_record(sine_set / "sine_1hz.csv", tmax=None)
    w = record_window(rec)
    prob = WholeRecordProblem(w, DAMPER)
    ws = WholeSpace.build(static_scales(w, DAMPER.piston_area), float(np.max(np.abs(w.force))))
    lp = WholeLogPosterior(prob, ws)
    flow4, off = quasi_static_start(prob, False)
    x, j = point_fit(lp, off, flow4)
    truth = np.r_[SMALL_FLOW, np.log(TRUTH["alpha_v"]), np.log(TRUTH["p_r"])]
    assert j <= lp.cost(truth) * 1.02
    sd = np.sqrt(np.diag(gauss_newton_covariance(lp, x)))
    z = (x[:4] - truth[:4]) / sd[:4]
    assert np.all(np.abs(z) < 4.0), z
    assert np.all(sd[:4] < 0.2 * truth[:4])  # and the errors are informative (< 20 % of the value)


def test_log_posterior_is_minus_inf_outside_the_box_and_never_nan(sine_set):
    w = record_window(load_record(sine_set / "sine_2hz.csv", tmax=None))
    ws = WholeSpace.build(static_scales(w, DAMPER.piston_area), float(np.max(np.abs(w.force))))
    lp = WholeLogPosterior(WholeRecordProblem(w, DAMPER), ws)
    rng = np.random.default_rng(3)
    lo, hi = ws.space.lower, ws.space.upper
    for _ in range(40):
        th = lo + rng.uniform(-0.2, 1.2, lo.size) * (hi - lo)
        v = lp(th)
        assert not np.isnan(v)
        if np.any(th < lo) or np.any(th > hi):
            assert v == -np.inf
    assert lp(np.r_[0.0, 0.0, SMALL_FLOW[2:], np.log(30.0), np.log(3e5)]) == -np.inf  # no flow path


def test_the_mode_is_chosen_from_the_data(sine_set, tmp_path):
    plan = plan_dataset(sine_set, 3.0)
    assert plan.mode == WHOLE and [k.kind for k in plan.kinds] == ["sine", "sine"]
    # 2400 samples at 200 Hz exceed MAX_SAMPLES: decimated by 2; 2000 samples at 250 Hz are kept
    assert [w.decimation for w in plan.windows] == [2, 1] and plan.windows[1].rate_hz == pytest.approx(250.0)
    assert "sine" in plan.describe()[0]
    with pytest.raises(DataError, match="not a triangular test") as err:
        plan_dataset(sine_set, 3.0, "two-stage")
    assert "\n" not in str(err.value) and str(sine_set) in str(err.value)
    assert plan_dataset("data/rig-A", 3.0).mode == TWO_STAGE


def test_identify_whole_records_through_the_cli(tmp_path, capsys):
    """A sine and a random-phase multisine data set, identified end to end with a short budget: the mode
    is printed and stored, every record has a posterior file, figures and a finished run.json."""
    folder = tmp_path / "data"
    recs = {"sine": _sine(rate=100.0, duration=6.0, seed=4),
            "multisine": make_record(multisine_input(0.004, 0.3, 2.0, 6, seed=5), 6.0, 100.0, SMALL, SMALL_FLOW,
                                     TRUTH["alpha_v"], TRUTH["p_r"], noise="white", sd=2.0, seed=6, rtol=1e-9)}
    write_dataset(folder, recs, SMALL, "mixed")
    out = tmp_path / "out"
    assert main(["identify", str(folder), "--out", str(out), "--max-steps", "40", "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert "mode whole-record" in err
    summary = json.loads((out / "summary.json").read_text())
    run = json.loads((out / "run.json").read_text())
    assert summary["mode"] == run["mode"] == "whole-record" and run["status"] == "complete"
    assert {e["id"] for e in summary["records"]} == {"sine", "multisine"}
    kinds = {r["name"]: r["kind"] for r in summary["plan"]["records"]}
    assert kinds == {"sine": "sine", "multisine": "other"}
    for e in summary["records"]:
        assert (out / "posteriors" / f"{e['id']}.nc").is_file()
        assert all((out / p).is_file() for p in summary["figures"][e["id"]])
        assert {"C_L12", "C_Q12", "alpha_V", "p_R_Pa", "phi"} <= set(e["posterior_mean"])
    # resumed, not re-sampled
    assert main(["identify", str(folder), "--out", str(out), "--max-steps", "40", "--workers", "1"]) == 0
    assert "resumed 2 finished record(s)" in capsys.readouterr().err
    # the report of a whole-record run: its own sections, every record's posterior row and loop figure
    from test_report import parse

    from bayesdamper.report.html import render_report

    text, page = parse(render_report(summary, None, out))
    assert "whole record" in text and "Static characteristic (stage 1" not in text
    assert {"sine", "multisine"} <= set(page.cells)
    for e in summary["records"]:  # every parameter's median [interval] of every record is in the table
        for name in ("C_L12", "C_Q21", "alpha_V"):
            assert f"{e[name]['median']:#.4g} [{e[name]['lo']:#.4g}, {e[name]['hi']:#.4g}]" in page.cells, name
    assert any(c.startswith("CL,12") for c in page.cells)
    assert sorted(page.images) == sorted(p for e in summary["records"] for p in summary["figures"][e["id"]]
                                         if p.endswith(".png"))


def _write(folder, name, t, y, f):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "damper.toml").write_text('[damper]\nname = "bad"\npiston_area_m2 = 9e-4\nchamber_volume_1_m3 = 3e-5\n'
                                        'chamber_volume_2_m3 = 3e-5\nliquid_bulk_modulus_Pa = 1.5e9\n')
    rows = "\n".join(f"{a:.10g},{b:.10g},{c:.10g}" for a, b, c in zip(t, y, f, strict=True))
    (folder / f"{name}.csv").write_text("time_s,displacement_m,force_N\n" + rows + "\n")


@pytest.mark.parametrize("case, expect", [
    ("flat", "hardly moves"),
    ("clipped", "clipped"),
    ("short", "less than one cycle"),
    ("units", "velocities up to"),
])
def test_bad_whole_records_are_one_line_errors_and_nothing_is_written(tmp_path, capsys, case, expect):
    rng = np.random.default_rng(7)
    t = np.arange(0, 10, 0.01)
    y = 0.01 * np.sin(2 * np.pi * 1.0 * t)
    f = 1e4 * np.gradient(y, t) + rng.normal(0, 1, t.size)
    if case == "flat":
        y = 1e-7 * rng.standard_normal(t.size)
    elif case == "clipped":
        f = np.clip(f, -400.0, 400.0)
    elif case == "short":
        t = np.arange(0, 0.6, 0.002)  # 0.6 s of a 1 Hz sine at 500 Hz: 300 samples, 0.6 cycle
        y = 0.01 * np.sin(2 * np.pi * 1.0 * t)
        f = 1e4 * np.gradient(y, t) + rng.normal(0, 1, t.size)
    elif case == "units":
        t = t / 1000.0  # milliseconds read as seconds
    folder = tmp_path / case
    _write(folder, "rec", t, y, f)
    out = tmp_path / "out"
    assert main(["identify", str(folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expect in err[0] and "rec.csv" in err[0], err
    assert not out.exists()
