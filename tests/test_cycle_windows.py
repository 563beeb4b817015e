"""Sine, multisine and random records on the one path: windows of whole cycles, their posteriors, the CLI run.

Records of two kinds, none made by bayesdamper:

* for the plan (how records are cut), records written with numpy alone: an analytic displacement and a viscous
  force c v plus white noise (the plan reads the displacement; the force only has to be plausible);
* for the posteriors and the CLI, eq. (7) records of the independent scipy-Radau generator (``tests/independent.py``
  and ``tests/independent_records.py``) at sample rates and start times off any grid used by bayesdamper, white
  force noise. Without plateaus the flow coefficients are never given: they are identified with α_V, p_R and the
  start's Δp.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from independent import SMALL, SMALL_FLOW, make_record, multisine_input, quasi_static_dp, sine_input, write_dataset
from independent_records import random_input, start_from_rest, stop_at

from bayesdamper.cli import main
from bayesdamper.core.errors import DataError
from bayesdamper.core.params import DamperConstants
from bayesdamper.inference import joint
from bayesdamper.inference.identify import window_noise
from bayesdamper.inference.noise import NoiseEstimate
from bayesdamper.inference.start import least_squares_start
from bayesdamper.io.windows import MAX_WINDOW_SAMPLES, MIN_REST_SAMPLES, WINDOW_RULE, WINDOW_TARGET_S
from bayesdamper.run.plan import TWO_STAGE, WHOLE, plan_dataset

ROOT = Path(__file__).resolve().parents[1]
DAMPER = DamperConstants(SMALL["area"], SMALL["v01"], SMALL["v02"], SMALL["b0"], "small")
TRUTH = dict(alpha_v=30.0, p_r=3.0e5)
#: Viscous coefficient of the numpy records [N s/m]: 60 mm/s gives 600 N, the small damper's force scale.
VISCOUS = 1.0e4
FLOW_KEYS = ("CL12", "CQ12", "CL21", "CQ21")
INTERVAL_KEYS = {"median", "lo", "hi"}


def _numpy_record(inp, duration: float, rate: float, t_start: float = 0.0037, seed: int = 0):
    """(t, y, F) of ``inp`` sampled at ``rate`` [Hz]: F = VISCOUS v + 50 N + 1 N white noise (numpy only)."""
    t = t_start + np.arange(int(round(duration * rate))) / rate
    f = VISCOUS * inp.velocity(t) + 50.0 + np.random.default_rng(seed).normal(0.0, 1.0, t.size)
    return t, inp.displacement(t), f


def _plan(tmp_path: Path, records: dict, name: str = "set", mode: str = "auto"):
    return plan_dataset(write_dataset(tmp_path / name, records, SMALL, name), 3.0, mode)


def _check_whole_cycles(windows, record_time: np.ndarray, n_cycles: int, period: float) -> None:
    """The cycle rule on one record's windows (moving from its first sample): every window but the last spans
    ``n_cycles`` whole cycles of the record's time scale (the fewest lasting >= WINDOW_TARGET_S), the last runs to
    the record's end, and every sample is in one window (every ``decimation``-th of it)."""
    assert n_cycles * period >= WINDOW_TARGET_S > (n_cycles - 1) * period
    t0 = windows[0].t_step
    for k, w in enumerate(windows):
        assert w.id == f"{w.test}_w{k}" and w.kind == "cycles" and w.direction == 0 and w.index == k
        assert w.info["rule"] == WINDOW_RULE
        assert w.info["cycle_s"] == pytest.approx(period, rel=1e-3)
        edge = t0 + k * n_cycles * w.info["cycle_s"]  # the k-th edge: the first sample at or after it
        assert w.time[0] == w.t_step == record_time[np.searchsorted(record_time, edge)]
        q = w.info["decimation"]
        i0 = int(np.searchsorted(record_time, w.t_step))
        np.testing.assert_array_equal(w.time, record_time[i0:i0 + q * w.time.size:q])
        if k < len(windows) - 1:
            assert w.info["cycles"] == n_cycles
            assert windows[k + 1].t_step > w.time[-1]
            raw_dt = 1.0 / (q * w.info["rate_Hz"])  # edges fall on the first raw sample at or after them
            assert windows[k + 1].t_step - w.t_step == pytest.approx(n_cycles * w.info["cycle_s"], abs=1.01 * raw_dt)
        else:
            assert record_time[-1] - w.time[-1] < 1.0 / w.info["rate_Hz"]  # within one (decimated) sample of the end
            assert w.info["cycles"] == pytest.approx((record_time[-1] - w.t_step) / w.info["cycle_s"], rel=1e-3)
    if all(w.info["decimation"] == 1 for w in windows):
        np.testing.assert_array_equal(np.concatenate([w.time for w in windows]), record_time)


# ------------------------------------------------------------------------------------------- the plan


@pytest.mark.parametrize("freq, rate, duration, n_cycles, decimation", [
    (1.0, 100.0, 25.3, 10, 1),     # 10 cycles of 1 s: two windows, the last of 15.3 cycles
    (0.35, 200.0, 30.0, 4, 1),     # 4 cycles of 2.86 s (11.4 s): 3 cycles would last 8.6 s
    (0.07, 1000.0, 36.0, 1, 2),    # one cycle of 14.3 s at 1 kHz: 14 286 samples > MAX_WINDOW_SAMPLES, decimated
])
def test_a_sine_record_is_cut_into_windows_of_whole_cycles(tmp_path, freq, rate, duration, n_cycles, decimation):
    rec = _numpy_record(sine_input(5e-3, freq), duration, rate)
    plan = _plan(tmp_path, {"sine": rec})
    assert plan.static is None and plan.segs == () and [k.kind for k in plan.kinds] == ["sine"]
    assert "no triangular test" in plan.mode_reason and "whole cycles" in plan.describe()[0]
    windows = plan.windows
    assert len(windows) == math.floor((duration - 1 / rate) * freq / n_cycles + 1e-6)
    _check_whole_cycles(windows, rec[0], n_cycles, 1 / freq)
    area = DAMPER.piston_area
    for k, w in enumerate(windows):
        assert w.info["decimation"] == decimation and w.time.size <= MAX_WINDOW_SAMPLES
        assert w.info["periodic"] and w.info["record_kind"] == "sine"
        assert w.info["starts"] == ("motion" if k == 0 else "previous window")
        assert not w.starts_settled and w.pre_force.size == 0
        assert w.velocity == pytest.approx(2 * np.pi * freq * 5e-3, rel=2e-3)  # the 99th percentile of |v|
        assert w.drive.start <= w.t_step and w.drive.end >= w.time[-1]  # the record's input, history included
        first = (rec[0] >= w.t_step) & (rec[0] < w.t_step + 2.5 / rate)  # its first three samples
        assert w.dp0 == pytest.approx(np.mean(rec[2][first]) / area)  # a start value from its first samples
        assert w.info["input"] == plan.inputs["sine"]
    if decimation > 1:  # the force of a decimated window is low-pass filtered, the input stays at the full rate
        w = windows[0]
        assert w.info["rate_Hz"] == pytest.approx(rate / decimation)
        np.testing.assert_array_equal(w.time, rec[0][:w.time.size * decimation:decimation])


@pytest.mark.parametrize("kind", ["multisine", "random"])
def test_broadband_records_use_their_own_time_scale(tmp_path, kind):
    """A multisine or a random record has no period: its time scale is twice the median interval between the
    velocity's zero crossings (its mean half-cycle), and the windows are whole multiples of it."""
    inp = (multisine_input(4e-3, 0.3, 2.0, 6, seed=5) if kind == "multisine" else
           random_input(0.2, 1.5, seed=3, rms_displacement=3e-3))
    rec = _numpy_record(inp, 40.0, 200.0)
    plan = _plan(tmp_path, {kind: rec})
    assert [k.kind for k in plan.kinds] == ["other"]
    v = inp.velocity(rec[0])
    crossings = rec[0][np.flatnonzero(np.sign(v[1:]) != np.sign(v[:-1]))]
    period = 2 * float(np.median(np.diff(crossings)))
    windows = plan.windows
    scale = windows[0].info["cycle_s"]
    assert scale == pytest.approx(period, rel=0.05)
    n_cycles = math.ceil(WINDOW_TARGET_S / scale - 1e-9)
    assert len(windows) >= 2 and not windows[0].info["periodic"] and windows[0].info["record_kind"] == "other"
    _check_whole_cycles(windows, rec[0], n_cycles, scale)


def test_rest_at_the_start_gives_the_first_window_its_pre_samples(tmp_path):
    """A record that starts at rest: the rest samples are the first window's pre-samples (their mean force over A_P
    is its start Δp, as the samples before a triangular test's first step); the window starts with the motion. A
    record that stops and rests at its end keeps the rest in its last window."""
    hold, rate = 2.0, 200.0
    inp = stop_at(start_from_rest(sine_input(5e-3, 1.0), hold, 1.0), hold + 1.0 + 14.0, 0.25)
    rec = _numpy_record(inp, hold + 1.0 + 14.0 + 0.25 + 1.5, rate, t_start=0.0)
    t = rec[0]
    plan = _plan(tmp_path, {"rest": rec})
    first, last = plan.windows[0], plan.windows[-1]
    assert first.starts_settled and first.info["starts"] == "rest" and first.as_dict()["starts_settled"]
    assert first.pre_force.size >= MIN_REST_SAMPLES
    np.testing.assert_array_equal(first.pre_time, t[:first.pre_time.size])  # every sample from the record's start
    np.testing.assert_array_equal(first.pre_force, rec[2][:first.pre_force.size])
    assert first.time[0] == first.t_step == t[first.pre_time.size]  # the window starts where the rest ends
    assert hold <= first.t_step < hold + 0.1  # the cosine ramp reaches 1 % of the peak speed ~0.06 s in
    assert first.dp0 == pytest.approx(np.mean(first.pre_force) / DAMPER.piston_area)
    assert all(not w.starts_settled for w in plan.windows[1:])
    assert last.info["ends_at_rest"] and last.time[-1] == t[-1]


def test_a_data_set_may_mix_triangular_tests_and_other_records(tmp_path):
    """rig-A's triangular tests with a sine of the same damper: the triangles are segmented (their plateaus give
    stage 1 for every window), the sine is cut into cycles. ``--mode two-stage`` refuses the sine in one line;
    ``--mode whole-record`` cuts every record into cycles, with no stage 1."""
    folder = tmp_path / "mixed"
    shutil.copytree(ROOT / "data" / "rig-A", folder)
    t, y, _ = _numpy_record(sine_input(2e-3, 0.1), 30.0, 100.0)
    f = 2.0e6 * np.gradient(y, t) + np.random.default_rng(2).normal(0.0, 10.0, t.size)  # ~1.3 kN at 0.63 mm/s
    rows = "\n".join(f"{a!r},{b!r},{c!r}" for a, b, c in zip(t.tolist(), y.tolist(), f.tolist(), strict=True))
    (folder / "zz_sine.csv").write_text("time_s,displacement_m,force_N\n" + rows + "\n")
    plan = plan_dataset(folder, 3.0)
    assert plan.static is not None and len(plan.segs) == 11
    assert "11 triangular test(s) segmented" in plan.mode_reason and "1 other record(s)" in plan.mode_reason
    kinds = {w.test: w.kind for w in plan.windows}
    assert kinds["zz_sine"] == "cycles" and {kinds[s.record.name] for s in plan.segs} <= {"initial", "reversal"}
    assert sum(w.kind != "cycles" for w in plan.windows) == 33 and set(plan.inputs) == {"zz_sine"}
    assert plan.describe()[-1].startswith("zz_sine: sine") and "whole cycles" in plan.describe()[-1]
    with pytest.raises(DataError, match="not a triangular test") as err:
        plan_dataset(folder, 3.0, TWO_STAGE)
    assert "\n" not in str(err.value) and str(folder / "zz_sine.csv") in str(err.value)
    whole = plan_dataset(folder, 3.0, WHOLE)
    assert whole.static is None and whole.segs == () and {w.kind for w in whole.windows} == {"cycles"}
    assert set(whole.inputs) == {r.name for r in whole.ds.records} and "forced by --mode whole-record" in \
        whole.mode_reason


def test_whole_record_mode_cuts_triangular_tests_at_their_own_period():
    """A triangle of amplitude A at speed v has the period 4 A / v: whole-record mode's windows are whole multiples
    of it (rig-A: A = 5 mm by its README's protocol, 0.5-1.5 mm/s: 13-40 s)."""
    plan = plan_dataset(ROOT / "data" / "rig-A", 3.0, WHOLE)
    wrong = {}
    for w in plan.windows:
        speed = float(w.test.split("_")[1].replace("p", ".").removesuffix("mm")) * 1e-3
        period = 4 * 5e-3 / speed
        if not w.info["cycle_s"] == pytest.approx(period, rel=0.05):
            wrong[w.test] = round(w.info["cycle_s"], 3)
    assert not wrong, wrong


# ------------------------------------------------------------------------------------------- a window's posterior


@pytest.fixture(scope="module")
def sine_window(tmp_path_factory):
    """One window of an 8 s, 1 Hz Radau sine at 200 Hz (white 2 N force noise), its joint problem with the noise
    estimated as identify does, and the true parameter vector."""
    inp = sine_input(0.01, 1.0)
    rec = make_record(inp, 8.0, 200.0, SMALL, SMALL_FLOW, TRUTH["alpha_v"], TRUTH["p_r"], noise="white", sd=2.0,
                      seed=1, t_start=0.0037, rtol=1e-9)
    plan = plan_dataset(write_dataset(tmp_path_factory.mktemp("sine"), {"sine_1hz": rec}, SMALL, "small"), 3.0)
    (w,) = plan.windows
    provisional = joint.StageOnePrior.flat(NoiseEstimate(0.0, 1.0, int(w.time.size), "provisional"))
    jp = joint.JointProblem.from_window(w, DAMPER, provisional, joint.PLATEAU)
    space = jp.space()
    x_ls, j_ls, _ = least_squares_start(jp, space)
    f_ls, _ = jp.simulate_window(x_ls)
    jp = dataclasses.replace(jp, prior=joint.StageOnePrior.flat(window_noise(w, jp.force - f_ls)))
    truth = np.r_[math.log(TRUTH["alpha_v"]), math.log(TRUTH["p_r"]),
                  quasi_static_dp(SMALL["area"] * float(inp.velocity(w.t_step)), SMALL_FLOW), SMALL_FLOW]
    return w, jp, space, x_ls, j_ls, truth


def test_least_squares_start_recovers_every_parameter_within_its_standard_errors(sine_window):
    """Without plateaus all seven (α_V, p_R, Δp0 and the four flow coefficients) come from the window: the
    least-squares start's J is at the noise floor (J of the truth + 2 %), and the MAP lies within 4 Gauss-Newton
    standard errors of the truth for every parameter (a two-sided 6e-5 chance each under a Gaussian posterior),
    with informative errors (each flow coefficient's below 20 % of its value)."""
    w, jp, space, x_ls, j_ls, truth = sine_window
    f_true, ok = jp.simulate_window(truth)
    assert ok
    assert j_ls <= 1.02 * np.linalg.norm(f_true - jp.force) / np.linalg.norm(jp.force)
    x_map, cov = joint.fit_map(joint.JointLogPosterior(jp, space), np.array(x_ls))
    assert cov is not None
    sd = np.sqrt(np.diag(cov))
    z = (x_map - truth) / sd
    assert np.all(np.abs(z) < 4.0), z
    assert np.all(sd[3:7] < 0.2 * truth[3:7]), sd[3:7] / truth[3:7]


def test_a_further_start_is_taken_only_where_it_fits_the_window_better(sine_window):
    """The diagnosis's search optimum as a further start of a window's fit (identify_window's ``start``): without
    plateaus it joins the least-squares fit's grid — a start at the truth is taken (the grid's best lies farther
    from the optimum) and ends at the same J as the fit from the grid, a start far off (α_V 3, p_R 5 MPa) is not
    taken and leaves the fit bit-identical; with stage 1 the point fit's start is the better of its own and the
    hint's (α_V, p_R) by the residual's sum of squares, and a hint whose solve fails is never taken."""
    from bayesdamper.inference.identify import better_start

    w, jp, space, x_ls, j_ls, truth = sine_window
    phys = {"alpha_V": math.exp(truth[0]), "p_R_Pa": math.exp(truth[1])}
    x_t, j_t, taken = least_squares_start(jp, space, phys | {"start_force_N": truth[2] * SMALL["area"],
                                                             "flow": truth[3:7]})
    assert taken and j_t == pytest.approx(j_ls, rel=1e-3)
    x_f, j_f, taken = least_squares_start(jp, space, {"alpha_V": 3.0, "p_R_Pa": 5e6})
    assert not taken and np.array_equal(x_f, x_ls) and j_f == j_ls

    far = [math.log(3.0), math.log(5e6), *truth[2:7]]
    start, origin = better_start(jp, far, phys, space)
    assert origin == "search optimum" and np.allclose(start[:2], truth[:2]) and start[2:] == far[2:]
    start, origin = better_start(jp, list(truth[:7]), {"alpha_V": 3.0, "p_R_Pa": 5e6}, space)
    assert origin == "own" and np.array_equal(start, truth[:7])
    assert better_start(jp, far, None, space) == (far, "own")

    class Failing:  # every solve at the hint fails
        def residual(self, theta):
            return None if np.allclose(theta[:2], truth[:2]) else jp.residual(theta)

    assert better_start(Failing(), far, phys, space) == (far, "own")


def test_log_posterior_is_minus_inf_outside_the_box_and_never_nan(sine_window):
    w, jp, space, x_ls, _, truth = sine_window
    lp = joint.JointLogPosterior(jp, space)
    rng = np.random.default_rng(3)
    lo, hi = space.lower, space.upper
    outside = 0
    for _ in range(40):
        th = lo + rng.uniform(-0.2, 1.2, lo.size) * (hi - lo)
        v = lp(th)
        assert not np.isnan(v)
        if np.any(th < lo) or np.any(th > hi):
            outside += 1
            assert v == -np.inf
    assert 0 < outside < 40
    no_path = np.r_[truth[:3], 0.0, 0.0, truth[5:7]]  # no flow from CH1 to CH2
    assert lp(no_path) == -np.inf and np.isfinite(lp(truth))
    np.testing.assert_array_equal(lp.batch(np.stack([truth, no_path])), [lp(truth), -np.inf])


# ------------------------------------------------------------------------------------------- the command line


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """A 6 s sine and a 6 s random-phase multisine at 100 Hz, identified through the CLI with a short budget (the
    tests check plumbing, not convergence), then identified again (resumed): (data folder, out folder, stderr of
    both runs, the posterior files' bytes after the first)."""
    root = tmp_path_factory.mktemp("cli")
    recs = {"sine": make_record(sine_input(0.01, 1.0), 6.0, 100.0, SMALL, SMALL_FLOW, TRUTH["alpha_v"], TRUTH["p_r"],
                                noise="white", sd=2.0, seed=4, t_start=0.0037, rtol=1e-9),
            "multisine": make_record(multisine_input(0.004, 0.3, 2.0, 6, seed=5), 6.0, 100.0, SMALL, SMALL_FLOW,
                                     TRUTH["alpha_v"], TRUTH["p_r"], noise="white", sd=2.0, seed=6, rtol=1e-9)}
    data = write_dataset(root / "data", recs, SMALL, "small-cycles")
    out = root / "out"
    args = ["identify", str(data), "--out", str(out), "--max-steps", "40", "--workers", "1"]
    errs = []
    for _ in range(2):
        buf = io.StringIO()
        with contextlib.redirect_stderr(buf):
            assert main(args) == 0
        errs.append(buf.getvalue())
        if len(errs) == 1:
            first = {p.name: p.read_bytes() for p in (out / "posteriors").glob("*.nc")}
    return data, out, errs, first


def test_identify_through_the_cli_writes_every_window(identified):
    data, out, (err, _), _ = identified
    summary = json.loads((out / "summary.json").read_text())
    run = json.loads((out / "run.json").read_text())
    assert "no triangular test" in err and summary["mode_reason"] in err
    assert summary["mode"] == run["mode"] == "auto" and run["status"] == "complete"
    assert summary["static"] is None and summary["static_constrained"] == []
    assert {r["name"]: r["kind"] for r in summary["plan"]["records"]} == {"sine": "sine", "multisine": "other"}
    ids = [e["id"] for e in summary["segments"]]
    assert sorted(ids) == ["multisine_w0", "sine_w0"] and run["windows"] == ids
    assert summary["n_converged"] == sum(e["converged"] for e in summary["segments"])
    for e in summary["segments"]:
        assert (out / "posteriors" / f"{e['id']}.nc").is_file()


def test_the_summary_entry_of_a_cycle_window(identified):
    """Every entry of summary["segments"] for a window of cycles: identity, the window and its rule, the seven
    parameters' intervals, the least-squares point, J, convergence, noise, flow prior and coupling."""
    data, out, _, _ = identified
    summary = json.loads((out / "summary.json").read_text())
    times = {name: np.loadtxt(data / f"{name}.csv", delimiter=",", skiprows=1, usecols=0) for name in
             ("sine", "multisine")}
    for e in summary["segments"]:
        t = times[e["test"]]
        assert e["id"] == f"{e['test']}_w0" and e["kind"] == "cycles" and e["direction"] == 0
        assert e["t_start_s"] == pytest.approx(t[0]) and e["velocity_m_s"] > 0.03
        win = e["window"]
        assert win["t_start_s"] == e["t_start_s"] and win["t_end_s"] == pytest.approx(t[-1])
        assert win["rule"] == WINDOW_RULE and win["decimation"] == 1 and win["n_samples"] == t.size
        assert win["cycles"] == pytest.approx((t[-1] - t[0]) / win["cycle_s"])
        assert win["input"] == summary["plan"]["inputs"][e["test"]] and "method" in win["input"]
        for name in ("alpha_V", "p_R_Pa", "dp0_Pa"):
            assert set(e[name]) == INTERVAL_KEYS and e[name]["lo"] <= e[name]["median"] <= e[name]["hi"], name
        assert set(e["flow"]) == set(FLOW_KEYS)
        for k in FLOW_KEYS:
            c = e["flow"][k]
            assert set(c) == INTERVAL_KEYS and 0 < c["lo"] <= c["median"] <= c["hi"], k
            assert e["ls"][k] > 0
        assert {"alpha_V", "p_R_Pa", "dp0_Pa", "J"} <= set(e["ls"])
        assert 0 < e["J_map"] < 0.05 and 0 < e["J"] < 0.05  # 2 N of noise on ~150 N rms: J of the noise 0.013
        assert isinstance(e["converged"], bool) and e["convergence"] and e["n_steps"] <= 40
        assert np.isfinite(e["rhat_max"]) and np.isfinite(e["ess_bulk_min"])
        assert {"phi", "sigma_N", "source"} <= set(e["noise"]) and "spectrum" in e["noise"]["source"]
        assert e["noise"]["sigma_N"] == pytest.approx(2.0, rel=0.25)
        assert e["flow_prior"].startswith("flat") and e["coupling"] == "joint" and e["effects"] == {}


def test_a_second_run_resumes_every_window(identified):
    data, out, (_, err), first = identified
    assert f"resumed 2 finished window(s) from {out / 'posteriors'}" in err
    run = json.loads((out / "run.json").read_text())
    assert sorted(run["resumed"]) == ["multisine_w0", "sine_w0"] and run["computed"] == []
    assert {p.name: p.read_bytes() for p in (out / "posteriors").glob("*.nc")} == first  # not rewritten


def test_loop_figures_of_every_window(identified):
    _, out, _, _ = identified
    summary = json.loads((out / "summary.json").read_text())
    figs = summary["figures"]
    assert figs["loops"] == [f"figures/loops/{e['id']}.png" for e in summary["segments"]]
    assert figs["figure3_static"] == [] and figs["figure8_transients"] == []  # no plateaus, no transients
    for paths in figs.values():
        for p in paths:
            assert (out / p).stat().st_size > 0


def test_the_report_of_cycle_windows_shows_their_loops_and_flow_coefficients(identified):
    from test_report import parse

    from bayesdamper.report.html import render_report

    _, out, _, _ = identified
    summary = json.loads((out / "summary.json").read_text())
    text, page = parse(render_report(summary, None, out))
    assert {e["id"] for e in summary["segments"]} <= set(page.cells)
    assert "estimated from the plateaus" not in text and "stage-1 flow coefficients" not in text
    for e in summary["segments"]:
        for k in FLOW_KEYS:
            c = e["flow"][k]
            assert f"{c['median']:#.4g} [{c['lo']:#.4g}, {c['hi']:#.4g}]" in page.cells, (e["id"], k)
    assert set(summary["figures"]["loops"]) <= set(page.images)


# ------------------------------------------------------------------------------------------- bad records


def _write(folder: Path, name: str, t, y, f) -> None:
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
def test_bad_records_are_one_line_errors_and_nothing_is_written(tmp_path, capsys, case, expect):
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
