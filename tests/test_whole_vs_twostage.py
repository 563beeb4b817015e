"""A triangular data set identified as whole records agrees with the two-stage result (issue 11).

Data bayesdamper did not make (tests/independent.py: scipy Radau): the rig-A damper with the paper's Fig. 3
flow coefficients, α_V = 1/0.03, p_R = 0.3 MPa, four triangular tests at 1.25, 1.75, 2.25 and 2.75 mm/s.
Each record: 0.6 s at rest, a ramp of QUARTER seconds up, a reversal, a ramp of 2 QUARTER seconds down,
ending 0.1 s before the next reversal (11.3-11.4 s, under the 12 s window, so no windowing; 163.7 Hz, ~1860
samples, so no decimation); the first step at 0.6137 + 0.0154 k s is off the sample grid, the force carries
white noise of SD newtons.

Why not the paper's 0.5-1.5 mm/s: at those speeds the rig-A force settles within 0.2 % only 3-5.6 s after a
velocity step (2.7 s at 1.5 mm/s), so a record of at most 12 s holds no settled plateau on its first ramp
and stage 1 is biased (three records at 0.5, 1.0, 1.5 mm/s with 3.6 s quarters: C_L21 6.6 standard
errors off the truth).
From 1.25 mm/s up the plateaus have settled, and stage 1 needs at least 3 plateaus per direction: four
records give 4 (2 degrees of freedom; with 3 records and 1 degree of freedom the stage-1 standard error is
itself so uncertain that one noise seed of three put a coefficient 51 standard errors off).

Spline ringing at the corners (:func:`test_spline_input_at_triangle_corners_costs_no_accuracy`): the
whole-record model drives eq. (7) by the quintic spline through the displacement samples, which overshoots
the ramp speed by ~30 % next to every corner. The spline interpolates the displacement, so the volume error
A_P (y_spline - y) vanishes at every sample and the force at the samples is nearly right: on noise-free
records at 163.7 Hz the force error at the truth is at most 0.4 / 1.9 / 4.3 / 12.7 N (1.25 / 1.75 / 2.25 /
2.75 mm/s, all of it in the 1-2 samples after the reversal, where the force falls by ~9 kN in 6 ms at
2.75 mm/s), and the noise-free least-squares optimum lies at most 0.12 / 0.24 / 0.19 / 0.52 posterior sd (of
these SD = 20 N records) from the truth. At 100 Hz the same records give 1.7-28 N and up to 1.0 sd. Driven
by the segmentation's piecewise-linear knots instead (the two-stage input), the error is 0.02 N and the bias
0.00 sd. So the ringing biases whole-record posteriors of triangular tests by a fixed amount in newtons:
below the intervals here, but it grows relative to them as the noise shrinks or the rate drops.

What the two-stage intervals leave out: stage 2 holds the stage-1 coefficients and the initial Δp fixed. The
library measures the first (``static_sensitivity``); the second, dp0 = mean force of the 0.15 s before the
step / A_P, carries the noise of ~25 samples (4 N here), and the α_V of an initial transient is so sensitive
to it that its posterior sd understates the spread up to 13-fold at 2.75 mm/s (:func:`_dp0_spread`; one
noise seed put an initial transient's α_V 33 posterior sds off the truth on a -13 N step force). Both are
added to the two-stage intervals before comparing (:func:`_widening`). The whole-record fit has no such
input: it starts from the quasi-static state of the first sample, at rest here.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from independent import PAPER_FLOW, RIG_A, make_record, simulate, triangle_input, write_dataset

from bayesdamper.cli import main
from bayesdamper.core.params import DamperConstants
from bayesdamper.inference.whole import WholeLogPosterior, WholeRecordProblem, WholeSpace, static_scales
from bayesdamper.inference.whole_stage import fine, gauss_newton_covariance, point_fit, quasi_static_start
from bayesdamper.io.wholerecord import RecordWindow
from bayesdamper.physics.spline_input import spline_coefficients
from bayesdamper.run.plan import TWO_STAGE, plan_dataset

DAMPER = DamperConstants(RIG_A["area"], RIG_A["v01"], RIG_A["v02"], RIG_A["b0"], "rig-A")
FLOW_NAMES = ("C_L12", "C_Q12", "C_L21", "C_Q21")
STAGE1_NAMES = dict(zip(FLOW_NAMES, ("CL12", "CQ12", "CL21", "CQ21"), strict=True))  # summary["static"] keys
DYN_NAMES = ("alpha_V", "p_R_Pa")
TRUTH = dict(zip(FLOW_NAMES, PAPER_FLOW, strict=True)) | {"alpha_V": 1 / 0.03, "p_R_Pa": 3.0e5}
SPEEDS = (1.25e-3, 1.75e-3, 2.25e-3, 2.75e-3)  # [m/s]
QUARTER = 3.6  # [s] first ramp; the second lasts twice as long (amplitude QUARTER * speed: 4.5-9.9 mm)
REST = 0.6  # [s] at rest before the first step
RATE = 163.7  # [Hz] no multiple of any step time
SD = 20.0  # [N] white force noise (rig-A's force reads 12-13 N rms at rest); plateau forces 5.5-29 kN
SEED = 7
TMAX = 3.0  # [s] stage-2 window: shorter than the first ramp (3.6 s), the transients settle within it
#: Tolerance of the comparisons in standard deviations of the difference: a Gaussian difference exceeds 4 sd
#: with probability 6.3e-5, so the 76 such comparisons below raise a false alarm on a noise seed with
#: probability below 76 x 6.3e-5 = 0.5 % (Bonferroni; less, as they share one data set). At 3.5 sd one of
#: three seeds tried failed, on a 3.2-standard-error step force (see _dp0_spread).
Z = 4.0
Z90 = 1.6449  # half-width of a Gaussian 90 % interval [sd]


def _input(k: int):
    v = SPEEDS[k]
    return triangle_input(v, QUARTER * v, 0.0, REST + 0.0137 + 0.0154 * k)


def _records(sd: float, seed: int) -> dict:
    recs = {}
    for k, v in enumerate(SPEEDS):
        inp = _input(k)
        duration = inp.t_first_step + 3 * QUARTER - 0.1  # ends on the second ramp, before the next reversal
        recs[f"tri_{v * 1e3:.2f}mm_s".replace(".", "p")] = make_record(
            inp, duration, RATE, RIG_A, PAPER_FLOW, TRUTH["alpha_V"], TRUTH["p_R_Pa"], sd=sd, seed=seed + k,
            rtol=1e-9)  # vs rtol 1e-11: at most 4 µN apart (rel. L2 5e-11) on these records
    return recs


# ------------------------------------------------------------------------------------------- fast


def test_spline_input_at_triangle_corners_costs_no_accuracy():
    """The whole-record forward model on a noise-free triangle at 2.75 mm/s (the worst record): the spline
    velocity rings at the corners, yet the force at the samples stays within one SD of the Radau reference
    and the least-squares optimum within 0.75 posterior sd (of an SD-noise record) of the truth.

    The bounds are the measured spline-corner error with about 50 % headroom (12.7 N and 0.52 sd, module
    docstring), not noise allowances: the data are noise-free, so any growth of the corner error shows here.
    """
    k = len(SPEEDS) - 1
    inp = _input(k)
    t = np.arange(round((inp.t_first_step + 3 * QUARTER - 0.1) * RATE)) / RATE
    f = simulate(inp, t, RIG_A, PAPER_FLOW, TRUTH["alpha_V"], TRUTH["p_R_Pa"], rtol=1e-10)
    w = RecordWindow("tri", "tri", t, f, inp.displacement(t), 1, RATE, "triangular")
    # the ringing is there: the spline's speed exceeds the ramp speed by > 10 % next to the corners ...
    sp_t, sp_c = spline_coefficients(t, w.displacement)
    s = np.linspace(0.0, 1.0, 64)[None, :] * np.diff(sp_t)[:, None]
    vel = sum(m * sp_c[:, m, None] * s ** (m - 1) for m in range(1, 6))
    assert np.max(np.abs(vel)) > 1.1 * SPEEDS[k]
    # ... yet the force at the samples hardly feels it
    prob = WholeRecordProblem(w, DAMPER)
    ws = WholeSpace.build(static_scales(w, DAMPER.piston_area), float(np.max(np.abs(f))))
    lp = WholeLogPosterior(prob, ws)
    truth = np.r_[PAPER_FLOW, math.log(TRUTH["alpha_V"]), math.log(TRUTH["p_R_Pa"])]
    f_model, ok = lp.simulate(truth)
    assert ok and np.max(np.abs(f_model - f)) < SD
    # the noise-free optimum, in sd of the posterior the same record would have with SD noise
    x, _ = point_fit(lp, 0.0, quasi_static_start(prob, False)[0])
    r = fine(lp).residual(x)
    sigma2 = float(r @ r) / (r.size - x.size)  # gauss_newton_covariance's own scale, divided out below
    sd = np.sqrt(np.diag(gauss_newton_covariance(lp, x)) / sigma2) * SD
    z = (x - truth) / sd
    assert np.all(np.abs(z) < 0.75), z


# ------------------------------------------------------------------------------------------- slow


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """The data set, its plan, and the summaries of both identifications (CLI, 2 workers, no figures)."""
    root = tmp_path_factory.mktemp("whole_vs_twostage")
    folder = write_dataset(root / "data", _records(SD, SEED), RIG_A, "rig-A-triangles")
    plan = plan_dataset(folder, TMAX)
    out, wall = {}, {}
    for mode in ("two-stage", "whole-record"):
        t0 = time.perf_counter()
        assert main(["identify", str(folder), "--out", str(root / mode), "--mode", mode, "--tmax", str(TMAX),
                     "--workers", "2", "--no-figures"]) == 0
        wall[mode] = time.perf_counter() - t0
        out[mode] = json.loads((root / mode / "summary.json").read_text())
    spread = _dp0_spread(plan, out["two-stage"])
    for e in out["two-stage"]["segments"]:
        e["dp0_spread"] = spread[e["id"]]
    return plan, out["two-stage"], out["whole-record"], wall


def _dp0_spread(plan, two: dict) -> dict:
    """sd [physical units] of each transient's (α_V, p_R) caused by the noise of its initial Δp.

    Stage 2 starts every transient at dp0 = (mean force of the STEP_FORCE_WINDOW = 0.15 s before the step) /
    A_P and treats it as exact. Its standard error is SD / sqrt(n) / A_P (white noise, n ~ 25 samples: 4 N),
    and α_V, p_R of an initial transient are sensitive to it (noise-free records, true flow: a step force of
    +-4 N moves α_V by -+0.1-0.2 %, 1.3 to 13 of its posterior sds from 1.25 to 2.75 mm/s; reversals, which
    start from a stiff plateau, 0.1 sd). Linearised: the least-squares optimum
    moves by -(J^T J)^-1 J^T dF/d(dp0) per unit of dp0, J the Jacobian in (log α_V, log p_R); central
    differences at the posterior median, with the kernel at rtol 1e-9 (its noise far below the differences).
    """
    from bayesdamper.inference.problem import WindowProblem
    from bayesdamper.io.segmentation import STEP_FORCE_WINDOW

    damper, flow = plan.ds.damper, plan.static.coefficients
    entries = {e["id"]: e for e in two["segments"]}
    out = {}
    for tr in plan.transients:
        e = entries[tr.id]
        t = plan.ds.record(tr.test).time
        n = np.count_nonzero((t >= tr.t_step - STEP_FORCE_WINDOW) & (t < tr.t_step))
        se = SD / math.sqrt(n) / damper.piston_area  # [Pa]
        theta = np.log([e["alpha_V"]["median"], e["p_R_Pa"]["median"]])

        def force(th, dp0, tr=tr):
            pb = WindowProblem(tr.id, tr.time, tr.force, tr.t_step, dp0, tr.knot_times, tr.knot_displacements,
                                  damper, flow, rtol=1e-9, atol=1e-3)
            f, ok = pb.simulate_force(*np.exp(th))
            assert ok
            return f

        h = 1e-3
        jac = np.column_stack([(force(theta + h * u, tr.dp0) - force(theta - h * u, tr.dp0)) / (2 * h)
                               for u in np.eye(2)])
        dfdp = (force(theta, tr.dp0 + se) - force(theta, tr.dp0 - se)) / 2  # per standard error of dp0
        shift = np.linalg.lstsq(jac, -dfdp, rcond=None)[0]
        out[tr.id] = dict(zip(DYN_NAMES, np.abs(shift) * np.exp(theta), strict=True))
    return out


def _widening(e: dict, name: str) -> float:
    """Factor on a stage-2 posterior sd (and interval) for what a *conditional* stage 2 holds fixed, added in
    quadrature: the stage-1 coefficients (``static_sensitivity``: sd of the optimum under stage-1 draws /
    posterior sd) and dp0 (:func:`_dp0_spread`, stored in the entry as ``dp0_spread`` by the fixture).
    1 for the joint stage 2 (the default since issue 9), whose posterior samples both."""
    if e.get("propagated"):
        return 1.0
    ratio = e["static_sensitivity"]["ratio"][name]
    r_static = ratio if np.isfinite(ratio) else 0.0
    r_dp0 = e["dp0_spread"][name] / e["posterior_sd"][name]
    return math.sqrt(1.0 + r_static**2 + r_dp0**2)


def _stage1_sd(interval: dict) -> float:
    """Stage 1's 90 % interval is Student-t on the plateaus' n - 2 degrees of freedom (2 here): the sd of a
    Gaussian with the same 90 % interval keeps that widening (1.78 standard errors for 2 dof)."""
    return (interval["hi"] - interval["lo"]) / (2 * Z90)


def _fmt(name: str, s: dict) -> str:
    scale, unit = {"alpha_V": (1.0, ""), "p_R_Pa": (1e3, "kPa")}.get(name, (1e10 if "L" in name else 1e16, ""))
    return f"{s['median'] / scale:8.4f} [{s['lo'] / scale:8.4f}, {s['hi'] / scale:8.4f}]{unit}"


def _table(two: dict, whole: dict, wall: dict) -> str:
    static = two["static"]
    lines = [f"wall time: two-stage {wall['two-stage']:.0f} s, whole-record {wall['whole-record']:.0f} s; "
             "median [90 % interval]; C_L in 1e10 kg m^-4 s^-1, C_Q in 1e16 kg m^-7"]
    for e in whole["records"]:
        trs = sorted((t for t in two["segments"] if t["test"] == e["test"]), key=lambda t: t["t_start_s"])
        lines.append(f"{e['id']} (J {e['J']:.4f}; transients " + ", ".join(f"{t['id']} {t['kind']}" for t in trs)
                     + ")")
        lines.append(f"  {'':8s} {'truth':>9s}   {'whole record':34s} two-stage: stage 1, or each transient "
                     "x its widening g")
        for n in FLOW_NAMES + DYN_NAMES:
            tv = TRUTH[n] / (1e3 if n == "p_R_Pa" else 1.0 if n == "alpha_V" else 1e10 if "L" in n else 1e16)
            ref = (f"stage 1 {_fmt(n, static[STAGE1_NAMES[n]])}" if n in FLOW_NAMES else
                   "   ".join(f"{_fmt(n, t[n])} x{_widening(t, n):.2f}" for t in trs))
            lines.append(f"  {n:8s} {tv:9.4f}   {_fmt(n, e[n])}   {ref}")
    return "\n".join(lines)


def _checks(two: dict, whole: dict) -> list[tuple[str, str, float]]:
    """Every comparison as (rule, what, ratio): the distance over its allowance, <= 1 passes."""
    out = []
    trs = two["segments"]
    for e in whole["records"]:
        for n in DYN_NAMES:
            w, s_w = e[n], e["posterior_sd"][n]
            lo = min(t[n]["median"] - _widening(t, n) * (t[n]["median"] - t[n]["lo"]) for t in trs)
            hi = max(t[n]["median"] + _widening(t, n) * (t[n]["hi"] - t[n]["median"]) for t in trs)
            lo, hi = lo - (w["median"] - w["lo"]), hi + (w["hi"] - w["median"])  # widened by its own interval
            out.append(("1 whole median in two-stage range", f"{e['id']} {n}: {w['median']:.6g} in "
                        f"[{lo:.6g}, {hi:.6g}]", abs(w["median"] - (lo + hi) / 2) / ((hi - lo) / 2)))
            for t in (t for t in trs if t["test"] == e["test"]):
                s = math.hypot(s_w, _widening(t, n) * t["posterior_sd"][n])
                out.append(("2 whole vs own transients", f"{e['id']} {n}: {w['median']:.6g} vs {t['id']} "
                            f"{t[n]['median']:.6g}", abs(w["median"] - t[n]["median"]) / (Z * s)))
        for n in FLOW_NAMES:
            c1 = two["static"][STAGE1_NAMES[n]]
            s = math.hypot(e["posterior_sd"][n], _stage1_sd(c1))
            out.append(("3 whole vs stage 1", f"{e['id']} {n}: {e[n]['median']:.5g} vs {c1['median']:.5g}",
                        abs(e[n]["median"] - c1["median"]) / (Z * s)))
        for n in FLOW_NAMES + DYN_NAMES:
            out.append(("4 whole vs truth", f"{e['id']} {n}: {e[n]['median']:.6g} vs {TRUTH[n]:.6g}",
                        abs(e[n]["median"] - TRUTH[n]) / (Z * e["posterior_sd"][n])))
    for n in FLOW_NAMES:
        c1 = two["static"][STAGE1_NAMES[n]]
        out.append(("4 stage 1 vs truth", f"{n}: {c1['median']:.5g} vs {TRUTH[n]:.5g}",
                    abs(c1["median"] - TRUTH[n]) / (Z * _stage1_sd(c1))))
    for t in trs:
        for n in DYN_NAMES:
            out.append(("4 stage 2 vs truth", f"{t['id']} {n}: {t[n]['median']:.6g} vs {TRUTH[n]:.6g}",
                        abs(t[n]["median"] - TRUTH[n]) / (Z * _widening(t, n) * t["posterior_sd"][n])))
    return out


@pytest.mark.slow
def test_whole_records_agree_with_two_stage_within_intervals(identified, capsys):
    """Issue 11: every whole-record posterior agrees with the two-stage result, and both with the truth.

    Rules (Z = 4 sd of the difference wherever an sd is used, see Z):
    1. α_V, p_R against the two-stage range: each whole-record median lies within the range spanned by all
       eight two-stage 90 % intervals (each widened for what stage 2 holds fixed, :func:`_widening`; the
       fluid is the same in every record), the range widened on each side by the whole record's own 90 %
       interval on that side.
    2. α_V, p_R against the record's own transients: |whole median - transient median| <= Z sqrt(s_w^2 +
       (g s_k)^2), with s_w, s_k the posterior sds and g the widening (the two share the record's data, so
       the real sd of the difference is smaller: conservative).
    3. Flow coefficients: |whole median - stage 1| <= Z sqrt(s_w^2 + s_1^2), s_1 from stage 1's Student-t
       interval (:func:`_stage1_sd`).
    4. Truth: whole-record medians within Z s_w (fair: the spline-corner bias is at most ~0.5 s_w on these
       records, module docstring and the fast test); stage-1 coefficients within Z s_1; stage-2 medians
       within Z g s_k.
    """
    plan, two, whole, wall = identified
    checks = _checks(two, whole)
    worst = {}
    for rule, what, ratio in checks:
        if rule not in worst or ratio > worst[rule][1]:
            worst[rule] = (what, ratio)
    with capsys.disabled():
        print("\n[whole record vs two-stage]\n" + _table(two, whole, wall))
        print("largest distance / allowance per rule (<= 1 passes):")
        for rule in sorted(worst):
            print(f"  rule {rule}: {worst[rule][1]:.2f} ({worst[rule][0]})")
    assert plan.mode == TWO_STAGE and {k.kind for k in plan.kinds} == {"triangular"}  # auto picks two-stage
    assert two["mode"] == "two-stage" and whole["mode"] == "whole-record"
    assert len(two["segments"]) == 2 * len(SPEEDS) and len(whole["records"]) == len(SPEEDS)
    assert all(e["converged"] for e in two["segments"] + whole["records"])
    assert all(e["window"]["decimation"] == 1 and not e["window"]["windowed"] for e in whole["records"])
    bad = [f"rule {rule}: {what}: {ratio:.2f} of the allowance" for rule, what, ratio in checks if not ratio <= 1.0]
    assert not bad, "\n".join(bad)
