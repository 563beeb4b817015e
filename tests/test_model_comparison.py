"""The model comparison: the drift-law prediction of a held-out speed, the verdict rule, the held-out J of the true
model on noise-free eq. (7) data, and the result's JSON form."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.diagnosis.comparison import (
    ALL,
    BASE,
    BaseModel,
    compare_models,
    comparison_text,
    drift_line,
    held_out_parameters,
    law_value,
    log_alpha_for_modulus,
    modulus,
    speed_folds,
    verdict,
)
from bayesdamper.diagnosis.engine import ProfileEngine
from bayesdamper.inference.problem import EffectsProblem
from bayesdamper.physics.excitation import PiecewiseLinear, as_drive
from bayesdamper.physics.single_state import simulate_single_state
from bayesdamper.physics.with_effects import effect_argument

D, FLOW = RIG_A_DAMPER, PAPER_FLOW
AMPLITUDE, REST, WINDOW_S, RATE = 5.0e-3, 1.0, 2.0, 100.0
SPEEDS = (0.5e-3, 0.75e-3, 1.0e-3, 1.5e-3)
#: The exact drift law of the synthetic data: log α_V and log p_R linear in log(v / 1 mm/s).
ALPHA_1, ALPHA_SLOPE, P_R_1, P_R_SLOPE = 30.0, -0.3, 3.0e5, 0.4


def true_pair(v: float) -> tuple[float, float]:
    s = math.log(v / 1e-3)
    return ALPHA_1 * math.exp(ALPHA_SLOPE * s), P_R_1 * math.exp(P_R_SLOPE * s)


def _window_set(forces_of):
    """Per speed a start from rest and the first reversal with (α_V, p_R) on the exact law, no noise: their problems,
    kinds, speeds and true pairs. ``forces_of(v, alpha, p_r, grids)``: each window's force [N] at its sample times
    (``grids``: kind -> times)."""
    problems, kinds, speeds, truth = [], [], [], []
    for v in SPEEDS:
        exc = PiecewiseLinear.triangle(AMPLITUDE, v, rest=REST, cycles=1.25)
        alpha, p_r = true_pair(v)
        grids = {k: t0 + np.arange(0.0, WINDOW_S, 1.0 / RATE)
                 for k, t0 in (("initial", REST), ("reversal", REST + AMPLITUDE / v))}
        for kind, f in forces_of(v, alpha, p_r, grids).items():
            t = grids[kind]
            problems.append(EffectsProblem(f"v{v * 1e3:.2f}_{kind}", t, f, float(t[0]), float(f[0]), 0.0,
                                           as_drive(exc), D, FLOW))
            kinds.append(kind)
            speeds.append(v)
            truth.append((alpha, p_r))
    return problems, kinds, speeds, truth


def synthetic_windows():
    """The windows of :func:`_window_set`, eq. (7) by bayesdamper's own simulator."""

    def forces_of(v, alpha, p_r, grids):
        exc = PiecewiseLinear.triangle(AMPLITUDE, v, rest=REST, cycles=1.25)
        t_all = np.unique(np.concatenate([np.arange(0.0, REST, 0.1), *grids.values()]))
        dp = simulate_single_state(t_all, exc, D, FLOW, DynamicParameters(alpha, p_r), dp0=0.0, t0=0.0)
        force = D.piston_area * dp
        return {kind: force[np.searchsorted(t_all, t)] for kind, t in grids.items()}

    return _window_set(forces_of)


@pytest.fixture(scope="module")
def synthetic():
    return synthetic_windows()


def _engine(problems, truth):
    # warm starts away from the truth: the in-sample fits must find it
    warm = [p.inner_start(a * 1.3, pr * 0.7) for p, (a, pr) in zip(problems, truth, strict=True)]
    return ProfileEngine(problems, warm, workers=1)


# ------------------------------------------------------------------------------------------- the drift law


def test_drift_line_recovers_a_known_line_and_predicts_the_held_out_speed():
    rng = np.random.default_rng(3)
    ls = np.log(np.array([0.5, 0.6, 0.8, 1.0, 1.2, 1.5]) * 1e-3)
    y = 2.0 - 0.7 * ls
    line = drift_line(ls, y)
    assert line["slope"] == pytest.approx(-0.7, abs=1e-12) and line["intercept"] == pytest.approx(2.0, abs=1e-9)
    assert line["se"] == pytest.approx(0.0, abs=1e-9) and line["n_speeds"] == 6
    # with scatter: the standard error is that of ordinary least squares
    noisy = y + 0.05 * rng.standard_normal(y.size)
    fit = np.polyfit(ls, noisy, 1, cov=True)
    line = drift_line(ls, noisy)
    assert line["slope"] == pytest.approx(fit[0][0]) and line["se"] == pytest.approx(math.sqrt(fit[1][0, 0]))
    # one speed: the median; none: no law
    one = drift_line([0.1, 0.1, 0.1], [1.0, 5.0, 2.0])
    assert one["slope"] is None and law_value(one, 7.0) == 2.0
    assert math.isnan(law_value(drift_line([], []), 0.0))


def test_held_out_parameters_follow_each_kinds_line_from_the_other_speeds():
    speeds = np.repeat([0.5e-3, 0.7e-3, 1.0e-3, 1.4e-3], 2)
    kinds = ["initial", "reversal"] * 4
    ls = np.log(speeds)
    # a different exact line per kind; a bad estimate at the held-out speed itself must not matter
    u = np.column_stack([np.where(np.array(kinds) == "initial", 3.0 - 0.2 * ls, 1.0 + 0.5 * ls),
                         np.where(np.array(kinds) == "initial", 12.0 + 0.1 * ls, 13.0 - 0.3 * ls)])
    truth = u.copy()
    folds = speed_folds(speeds)
    assert [f.tolist() for f in folds] == [[0, 1], [2, 3], [4, 5], [6, 7]]
    u[2] += 5.0  # the held-out window's own estimate is wrong: its prediction comes from the others
    pred, source = held_out_parameters(u, np.ones(8, dtype=bool), kinds, ls, folds)
    assert np.allclose(pred[2], truth[2], atol=1e-9)  # predicted from the three other speeds' exact line
    assert source[2] == "line, initial" and source[3] == "line, reversal"
    # the other windows' predictions use the wrong estimate of window 2 in their training: only the initial ones
    assert np.allclose(pred[[1, 3, 5, 7]], truth[[1, 3, 5, 7]], atol=1e-9)
    assert not np.allclose(pred[[0, 4, 6]], truth[[0, 4, 6]], atol=1e-3)
    # a kind with no training window of its kind takes the law of every kind; a training set of one speed: median
    pred, source = held_out_parameters(truth[:4], np.ones(4, dtype=bool), ["initial", "initial", "reversal",
                                                                           "initial"], ls[:4], speed_folds(speeds[:4]))
    assert source[2] == "median, all kinds" and np.allclose(pred[2], np.median(truth[[0, 1]], axis=0))
    assert source[0] == "median, initial" and np.allclose(pred[0], truth[3])


def test_modulus_inversion_round_trips():
    b0 = D.liquid_bulk_modulus
    for a, pr in ((30.0, 3e5), (5.0, 1e5), (200.0, 8e5)):
        b = float(modulus(math.log(a), math.log(pr), b0))
        assert log_alpha_for_modulus(b, pr, b0) == pytest.approx(math.log(a), abs=1e-9)
    assert log_alpha_for_modulus(2 * b0, 3e5, b0) == math.inf and log_alpha_for_modulus(1e5, 3e5, b0) == -math.inf


# ------------------------------------------------------------------------------------------- the verdict


def test_eq6_suffices_when_the_paired_differences_are_within_the_margin():
    eq6 = [0.10, 0.12, 0.11, 0.13, 0.09]
    other = [0.098, 0.123, 0.107, 0.132, 0.089]  # differences of both signs, mean -0.0006
    v = verdict({BASE: float(np.mean(eq6)), "other": float(np.mean(other))}, {BASE: eq6, "other": other})
    d = np.array(other) - np.array(eq6)
    margin = 2.8693 * np.std(d, ddof=1) / math.sqrt(d.size)  # Student's t, 4 df, at P(Z > 2) = 2.3 %
    a = v["against"]["other"]
    assert a["margin"] == pytest.approx(margin, rel=1e-4) and a["n_folds"] == 5
    assert a["lower_by"] == pytest.approx(float(np.mean(eq6) - np.mean(other)))
    assert 0 < a["lower_by"] < margin and not a["clearly_better"]
    assert v["winner"] == "other" and v["base_suffices"]


def test_eq6_does_not_suffice_when_another_model_is_clearly_better():
    eq6 = [0.10, 0.20, 0.30, 0.40]
    # a small but consistent gain in every fold: the folds' own spread (0.1) is no excuse, the paired one is tiny
    other = [x - 0.005 + e for x, e in zip(eq6, (1e-4, -1e-4, 2e-4, 0.0), strict=True)]
    worse = [x + 0.01 for x in eq6]
    v = verdict({BASE: 0.25, "other": float(np.mean(other)), "worse": 0.26},
                {BASE: eq6, "other": other, "worse": worse})
    assert v["against"]["other"]["clearly_better"] and not v["against"]["worse"]["clearly_better"]
    assert not v["base_suffices"] and v["winner"] == "other"
    # folds without windows of the kind (None) are left out of the pairs; one pair forms no margin
    v = verdict({BASE: 0.3, "other": 0.1}, {BASE: [None, 0.3], "other": [0.2, 0.1]})
    assert v["against"]["other"]["n_folds"] == 1 and v["against"]["other"]["margin"] is None
    assert v["base_suffices"] and v["winner"] == "other"


# ------------------------------------------------------------------------------------------- on eq. (7) data


def test_true_model_predicts_held_out_speeds_to_the_noise_floor(synthetic):
    problems, kinds, speeds, truth = synthetic
    engine = _engine(problems, truth)
    forces = [p.force for p in problems]
    # eq. (6) is the true model; a fixed friction of 300 N is a wrong one (its per-window fits absorb part of it)
    models = (BaseModel(BASE, "eq. (7) with eq. (6)"),
              BaseModel("friction300", "with 300 N friction", {"friction": {"coulomb_N": 300.0}}))
    res = compare_models(engine, forces, kinds, speeds, lambda e: None, effect_argument, D.liquid_bulk_modulus,
                         models=models)
    eq6 = res["models"][BASE]
    for w, (a, pr) in zip(eq6["windows"], truth, strict=True):
        assert w["alpha_V"] == pytest.approx(a, rel=2e-3) and w["p_R_Pa"] == pytest.approx(pr, rel=2e-3)
        assert w["alpha_V_predicted"] == pytest.approx(a, rel=5e-3)  # the law of the other speeds
        assert w["J_held_out"] < 2e-3, w
    for kind in ("initial", "reversal"):
        drift = eq6["in_sample"]["by_kind"][kind]["drift"]
        assert drift["log_alpha_V"]["slope"] == pytest.approx(ALPHA_SLOPE, abs=5e-3)
        assert drift["log_p_R"]["slope"] == pytest.approx(P_R_SLOPE, abs=5e-3)
    assert eq6["held_out"]["J_pooled"] < 1e-3
    wrong = res["models"]["friction300"]
    assert wrong["held_out"]["J_pooled"] > 20 * eq6["held_out"]["J_pooled"] and wrong["held_out"]["J_pooled"] > 0.01
    assert res["verdict"][ALL]["winner"] == BASE and res["verdict"][ALL]["base_suffices"]
    assert len(res["folds"]) == len(SPEEDS)


def independent_windows():
    """The windows of :func:`_window_set` with their forces from the independent reference (scipy Radau,
    ``tests/independent.py``: no bayesdamper code) instead of bayesdamper's own simulator."""
    from independent import PAPER_FLOW as REF_FLOW
    from independent import RIG_A, simulate, triangle_input

    def forces_of(v, alpha, p_r, grids):
        inp = triangle_input(v, AMPLITUDE, 0.0, REST, cycles=1.25)  # the motion of _window_set's triangle
        return {kind: simulate(inp, t, RIG_A, REF_FLOW, alpha, p_r, dp0=0.0, t0=0.0) for kind, t in grids.items()}

    return _window_set(forces_of)


def test_the_in_sample_fits_leave_a_corner_of_the_box():
    """Every window started in the corner of no gas (α_V at the top of the box, p_R at its bottom), where a re-fit of
    eq. (7) stops (α_V about 190 times the truth's for the worst window): the comparison's in-sample fits also start
    from the best of the spread over the box (engine.spread_starts) and find every window's truth. The data come
    from the independent reference without noise; the tolerance, 1 %, is far above the kernel's (rtol 1e-6) and
    far below the corner's error."""
    problems, kinds, speeds, truth = independent_windows()
    engine = ProfileEngine(problems, [p.inner_start(4999.0, 1.01e3) for p in problems], workers=1)
    stuck, _, _ = engine.evaluate(effect_argument({}), None)
    forces = [p.force for p in problems]
    res = compare_models(engine, forces, kinds, speeds, lambda e: None, effect_argument, D.liquid_bulk_modulus,
                         models=(BaseModel(BASE, "eq. (7) with eq. (6)"),))
    norms = np.array([float(f @ f) for f in forces])
    assert math.sqrt(stuck.sum() / norms.sum()) > 0.1  # the corner's re-fit: no fit at all
    for w, (a, pr) in zip(res["models"][BASE]["windows"], truth, strict=True):
        assert w["alpha_V"] == pytest.approx(a, rel=1e-2) and w["p_R_Pa"] == pytest.approx(pr, rel=1e-2), w


def test_a_wrong_drift_law_does_not_predict(synthetic):
    """The same windows with the training estimates' law replaced by a constant: the held-out J is far above the
    true law's (the comparison's held-out J measures the law, not the in-sample fit)."""
    problems, kinds, speeds, truth = synthetic
    engine = _engine(problems, truth)
    x_true = [p.inner_start(a, pr) for p, (a, pr) in zip(problems, truth, strict=True)]
    sse_true, _ = engine.evaluate_at(effect_argument({}), None, x_true)
    a_med, p_med = np.median([t[0] for t in truth]), np.median([t[1] for t in truth])
    x_flat = [p.inner_start(a_med, p_med) for p in problems]
    sse_flat, _ = engine.evaluate_at(effect_argument({}), None, x_flat)
    norms = np.array([float(p.force @ p.force) for p in problems])
    assert math.sqrt(sse_true.sum() / norms.sum()) < 1e-3
    assert math.sqrt(sse_flat.sum() / norms.sum()) > 0.01


def test_result_is_json_and_text(synthetic):
    problems, kinds, speeds, truth = synthetic
    sub = [k for k, s in enumerate(speeds) if s in SPEEDS[1:3]]  # two speeds: a law of one speed per fold
    engine = _engine([problems[k] for k in sub], [truth[k] for k in sub])
    res = compare_models(engine, [problems[k].force for k in sub], [kinds[k] for k in sub], [speeds[k] for k in sub],
                         lambda e: None, effect_argument, D.liquid_bulk_modulus,
                         models=(BaseModel(BASE, "eq. (7) with eq. (6)"),
                                 BaseModel("constant_bulk_modulus", "constant B", {"constant_bulk_modulus": {}},
                                           modulus_only=True),
                                 BaseModel("missing", "not in the library", {"no_such_effect": {}})))
    text = json.dumps(res, allow_nan=False)
    back = json.loads(text)
    assert back["skipped"] == ["missing"] and back["order"] == [BASE, "constant_bulk_modulus"]
    assert back["models"][BASE]["windows"][0]["law"].startswith("median")
    assert set(back["verdict"]) == {"initial", "reversal", ALL}
    lines = comparison_text(back)
    assert any("Verdict" in ln for ln in lines) and any("const. B" in ln and "initial" in ln for ln in lines)
    assert any("ridge of equal B" in ln for ln in lines)
    assert comparison_text(None) == [] and "not made" in comparison_text({"error": "x"})[0]


# ------------------------------------------------------------------------------------------- path independence


def test_a_search_depends_on_the_current_model_not_on_the_searches_before_it(synthetic):
    """Every search starts each window's re-fit from the current model's Jacobian (ProfileEngine.restart), not the
    one the last search left: the same candidate searched before and after another ends at the same optimum to the
    last bit (a Jacobian carried over from another search would change its path)."""
    from bayesdamper.diagnosis.candidates import CandidateSpec, effective_sizes, fit_joint

    problems, _, _, truth = synthetic
    engine = _engine(problems, truth)
    sse, _, resid = engine.evaluate(effect_argument({}), None, keep=True)
    n_eff = effective_sizes(resid)

    def search(name):
        return fit_joint(engine, [CandidateSpec(name)], {}, {}, sse, n_eff, lambda e: None, effect_argument,
                         intervals_to=-math.inf)

    first = search("leakage")
    other = search("series_compliance")
    again = search("leakage")
    assert other.effects != first.effects
    assert again.delta_bic == first.delta_bic
    assert again.effects == first.effects
    assert all(np.array_equal(a, b) for a, b in zip(again.warm, first.warm, strict=True))


def test_the_folds_share_their_first_refits_and_the_score_is_unchanged(synthetic, monkeypatch):
    """The leave-velocities-out folds of an option all start from its full-data optimum with the current model's
    Jacobians: within lovo_score the engine re-uses a window's re-fit or sensitivities whose inputs it has seen
    (ProfileEngine.remembering). The score is the same to the last bit as with every task run, with fewer tasks."""
    import contextlib

    from bayesdamper.diagnosis import engine as engine_module
    from bayesdamper.diagnosis.attribution import lovo_score, velocity_folds
    from bayesdamper.diagnosis.candidates import CandidateSpec, effective_sizes, fit_joint

    problems, _, speeds, truth = synthetic
    runs = {"n": 0}
    for name in ("_inner_fit", "_psi_columns"):
        fn = getattr(engine_module, name)

        def counted(task, fn=fn):
            runs["n"] += 1
            return fn(task)

        counted.__name__ = name
        monkeypatch.setattr(engine_module, name, counted)

    def score(remember: bool):
        engine = _engine(problems, truth)
        if not remember:
            engine.remembering = contextlib.nullcontext
        sse, _, resid = engine.evaluate(effect_argument({}), None, keep=True)
        n_eff = effective_sizes(resid)
        spec = CandidateSpec("command_displacement")
        fit = fit_joint(engine, [spec], {}, {}, sse, n_eff, lambda e: None, effect_argument, intervals_to=-math.inf)
        runs["n"] = 0
        sc = lovo_score(engine, velocity_folds(speeds), [spec], fit.effects, [], {}, sse, n_eff, lambda e: None,
                        effect_argument)
        return sc, runs["n"]

    plain, n_plain = score(False)
    shared, n_shared = score(True)
    assert shared == plain
    assert n_shared < n_plain, (n_shared, n_plain)
