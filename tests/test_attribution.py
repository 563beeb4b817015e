"""The out-of-sample evidence: folds of whole speeds, the pass rule, paired differences."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from profile_fakes import loop_fit, table_search

from bayesdamper.diagnosis.attribution import MAX_FOLDS, LovoScore, lovo_passes, paired, runner_up, velocity_folds
from bayesdamper.diagnosis.candidates import CandidateSpec
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.run.progress import Progress


def test_folds_are_whole_speeds_dealt_round_robin():
    v = [0.5e-3, -0.5e-3, 1e-3, 1e-3, 1.5e-3, 2e-3, 2.5e-3, 3e-3, 3.5e-3, 4e-3]
    folds = velocity_folds(v)
    assert len(folds) == MAX_FOLDS
    assert sorted(np.concatenate(folds).tolist()) == list(range(len(v)))
    for f in folds:  # a speed (either direction) never split over folds
        speeds = {round(abs(v[i]), 9) for i in f}
        assert all(round(abs(v[j]), 9) not in speeds for g in folds if g is not f for j in g)
    assert len(velocity_folds([1e-3, 2e-3, 1e-3])) == 2


def test_pass_rule_every_fold_and_se_with_enough_folds():
    # three folds: every fold better suffices (2 df: no usable normal se), one worse fails
    assert lovo_passes(LovoScore(550.0, 268.0, (10.0, 240.0, 300.0)))
    assert not lovo_passes(LovoScore(530.0, 268.0, (-10.0, 240.0, 300.0)))
    # four folds: every fold better is no significant sign test (1/16): also above the margin, Student's t with 3 df
    # at 2.3 % (3.31 se); 2.8 se, enough for a normal 2 se, is not
    assert lovo_passes(LovoScore(420.0, 120.0, (194.0, 51.0, 70.0, 105.0)))
    assert not lovo_passes(LovoScore(420.0, 150.0, (194.0, 51.0, 70.0, 105.0)))
    assert not lovo_passes(LovoScore(58.0, 40.0, (1.0, 1.0, 1.0, 55.0)))
    # five folds and more: every fold better is the sign test at 2^-5 = 3.1 %, whatever the se of unequal folds
    assert lovo_passes(LovoScore(218.0, 138.6, (11.0, 7.0, 9.0, 39.0, 152.0)))
    assert not lovo_passes(LovoScore(200.0, 50.0, (-1.0, 51.0, 50.0, 50.0, 50.0)))


def test_the_margin_is_students_t_at_the_level_of_two_normal_standard_errors():
    """The margin in standard errors (:func:`se_margin`): with an se from G folds' own spread, P(T > margin) is
    P(Z > 2) for T ~ t(G - 1), checked by simulation (seeded; within 4 binomial sds of 2.3 % over 200 000 draws,
    0.13 % absolute; a normal 2 would be exceeded 7 % of the time with 4 folds); it falls towards 2 as the folds
    grow, and with one fold there is none."""
    from scipy.stats import norm

    from bayesdamper.diagnosis.attribution import se_margin

    rng = np.random.default_rng(11)
    for g in (4, 6, 11):
        d = rng.standard_normal((200_000, g))
        t = d.sum(axis=1) / np.sqrt(g * d.var(axis=1, ddof=1))  # the gain over its se under no effect
        p = norm.sf(2.0)
        assert abs(np.mean(t > se_margin(g)) - p) < 4.0 * math.sqrt(p * (1.0 - p) / t.size), g
    margins = [se_margin(g) for g in range(3, 40)]
    assert all(a > b > 2.0 for a, b in zip(margins, margins[1:], strict=False))
    assert se_margin(1) == math.inf and se_margin(200) == pytest.approx(2.0, abs=0.02)


def test_paired_difference_and_its_se():
    a = LovoScore(6.0, 1.0, (1.0, 2.0, 3.0))
    b = LovoScore(3.0, 1.0, (0.0, 1.0, 2.0))
    p = paired(a, b)
    assert p["gain"] == 3.0 and p["se"] == 0.0
    c = LovoScore(3.0, 1.0, (2.0, 0.0, 1.0))
    q = paired(a, c)
    assert math.isclose(q["se"], math.sqrt(3 * np.var([-1.0, 2.0, 2.0], ddof=1)))


def test_the_runner_up_is_the_best_scored_option_other_than_the_selection():
    """When the last resort sets a generic option aside for a physical one, the generic option (the largest held-out
    gain of the others) is the selection's runner-up; options not scored out of sample are never it."""
    def row(effect, gain):
        return {"effect": effect, **({"_lovo": LovoScore(gain, 1.0, (gain,))} if gain is not None else {})}

    generic, physical, other, unscored = (row("valve+unnamed", 1110.0), row("two_state+valve", 998.0),
                                          row("valve+unnamed_force", 1044.0), row("leakage", None))
    rows = [generic, physical, other, unscored]
    assert runner_up(rows, physical) is generic
    assert runner_up(rows, generic) is other
    assert runner_up(rows, None) is generic
    assert runner_up([physical, unscored], physical) is None
    tie = row("valve+friction", 1110.0)
    assert runner_up([physical, generic, tie], physical) is generic  # the first of equal gains


def test_screening_subset_takes_every_speed_and_rotates_the_kind():
    from bayesdamper.diagnosis.attribution import screening_subset

    speeds = [v * 1e-3 + d for v in np.arange(0.5, 1.55, 0.1) for d in (0.0, 2e-7, -3e-7)]  # 11 tests x 3 steps
    sub = screening_subset(speeds)
    assert sub.tolist() == [3 * g + g % 3 for g in range(11)]  # one per speed: s0, s1, s2, s0, ...
    assert screening_subset(speeds[:12]) is None  # 12 or fewer: all
    two = screening_subset([1e-3] * 10 + [2e-3] * 10)
    assert two.tolist() == list(range(6)) + list(range(11, 17))  # 6 per speed, rotated by one at the second


def test_a_screened_grid_finds_the_same_optimum_and_scores_on_every_transient():
    """The grid on a subset picks the start; the local search and the score use all transients."""
    from profile_fakes import FakeProfileEngine, fake_problem

    from bayesdamper.diagnosis.candidates import CandidateSpec, fit_joint

    class Engine(FakeProfileEngine):
        def __init__(self, screen):
            self.problems = [fake_problem(np.ones(20)) for _ in range(16)]
            self.screen = screen
            self.calls = []

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            k = np.arange(16) if idx is None else np.asarray(idx)
            self.calls.append(len(k))
            tau = eff["valve_dynamics"]["time_constant_s"]
            sse = 20.0 * (1.0 + (np.log(tau / 0.03)) ** 2 * (1 + 0.1 * k))
            return sse, np.zeros((k.size, 2)), [np.full(20, math.sqrt(v / 20)) for v in sse]

    out = {}
    for screen in (None, np.array([0, 5, 10])):
        eng = Engine(screen)
        fit = fit_joint(eng, [CandidateSpec("valve_dynamics")], {}, {"valve_dynamics": {}}, np.full(16, 40.0),
                        np.full(16, 20.0), lambda e: None, lambda e: e)
        out[screen is None] = (fit, eng.calls)
    full, screened = out[True][0], out[False][0]
    assert screened.effects["valve_dynamics"]["time_constant_s"] == pytest.approx(0.03, rel=0.02)
    assert screened.delta_bic == pytest.approx(full.delta_bic, abs=0.5)
    assert 3 in out[False][1] and 3 not in out[True][1]  # the grid ran on the subset


def test_a_pair_must_earn_its_second_effect():
    """The reference control: accumulator + a generic effect of gain ~1e-16 had the largest fold gain by 1.5
    (noise) and was selected; now a pair must meet the criterion over its better member too."""
    from bayesdamper.diagnosis.loop import check_pairs

    def row(effect, score, j):
        return {"effect": effect, "score": score, "J_pooled": j, "supported": True, "pair": "+" in effect}

    rows = [row("accumulator", -3303.6, 0.00311), row("unnamed@flow", -864.9, 0.0044),
            row("accumulator+unnamed@flow", -3281.8, 0.00311), row("friction", -900.0, 0.004),
            row("accumulator+friction", -3400.0, 0.0024)]
    check_pairs(rows)
    assert [r["supported"] for r in rows] == [True, True, False, True, True]
    assert rows[2]["over_better_member"]["member"] == "accumulator"
    assert rows[4]["over_better_member"]["delta_BIC_eff"] == pytest.approx(-96.4)
    rows[4]["J_pooled"] = 0.0028  # ΔBIC enough but J only 10 % lower than the accumulator's
    rows[4]["supported"] = True
    check_pairs(rows)
    assert not rows[4]["supported"]


def test_interval_sds_of_a_ridge():
    """The information of a Gaussian log-likelihood with correlation 0.95: the marginal sds are sqrt(diag(Σ)) (3.2
    times the conditional ones); a parameter on its bound keeps its conditional sd, as does a direction without
    information (inf)."""
    from bayesdamper.diagnosis.candidates import interval_sds

    cov = np.array([[1.0, 0.95 * 0.5], [0.95 * 0.5, 0.25]]) * 0.01
    info = np.linalg.inv(cov)
    z0 = np.array([1.0, 2.0])
    lo, hi = np.array([0.0, 0.0]), np.array([3.0, 4.0])
    cond = 1.0 / np.sqrt(np.diag(info))
    np.testing.assert_allclose(interval_sds(info, z0, lo, hi, False), cond)
    sd = interval_sds(info, z0, lo, hi, True)
    np.testing.assert_allclose(sd, np.sqrt(np.diag(cov)), rtol=1e-12)
    assert np.all(sd > 3.0 * cond)
    at_bound = interval_sds(info, np.array([0.0, 2.0]), lo, hi, True)
    np.testing.assert_allclose(at_bound, cond)
    flat = interval_sds(np.diag([0.0, 4.0]), z0, lo, hi, True)
    assert flat[0] == np.inf and flat[1] == pytest.approx(0.5)


def _last_resort_case(generic_folds, physical_folds, physical_passes, folds=True):
    from bayesdamper.diagnosis.candidates import CandidateSpec
    from bayesdamper.diagnosis.loop import unnamed_last_resort

    specs = {"unnamed_dynamics@flow": CandidateSpec("unnamed_dynamics@flow"),
             "two_state": CandidateSpec("two_state"), "friction": CandidateSpec("friction")}

    def row(effect, score, per_fold, passes):
        sc = LovoScore(float(sum(per_fold)), 1.0, tuple(per_fold))
        return {"effect": effect, "score": score, "passes": passes, "supported": passes, "lovo": sc.as_dict(),
                "_lovo": sc}

    gen = row("unnamed_dynamics@flow", -900.0, generic_folds, True)
    phys = row("two_state", -800.0, physical_folds, physical_passes)
    weak = row("friction", -5.0, [-1.0, -2.0, -1.0, -3.0, -2.0, -1.0][:len(generic_folds)], False)
    return unnamed_last_resort(gen, [gen, phys, weak], [], specs, None, [0] if folds else None, [], {}, None, None,
                               None, {})


def test_the_generic_effect_is_named_only_when_it_beats_the_physics_out_of_sample():
    # clearly better than the two-state model in every fold (paired gains 40 +- small): named
    best, rec = _last_resort_case([60.0, 70.0, 65.0, 80.0, 75.0], [20.0, 25.0, 30.0, 35.0, 30.0], True)
    assert best["effect"] == "unnamed_dynamics@flow" and rec["kept"] and not rec["indistinguishable_from"]
    # within the margin of the two-state model, which passes on its own: the physics is named instead
    best, rec = _last_resort_case([30.0, 25.0, 40.0, 20.0, 35.0], [28.0, 30.0, 33.0, 25.0, 31.0], True)
    assert best["effect"] == "two_state" and not rec["kept"] and "two_state" in rec["indistinguishable_from"]
    # within the margin, and no physical option passes: nothing is named
    best, rec = _last_resort_case([30.0, 25.0, 40.0, 20.0, 35.0], [28.0, 30.0, 33.0, 25.0, 31.0], False)
    assert best is None and not rec["kept"]
    # without speed folds there is no out-of-sample comparison: a passing physical option wins
    best, rec = _last_resort_case([60.0, 70.0, 65.0, 80.0, 75.0], [20.0, 25.0, 30.0, 35.0, 30.0], True, folds=False)
    assert best["effect"] == "two_state"
    # the generic option's gains over a rival pass the same held-out rule as an option's over the current model:
    phys = [20.0, 25.0, 30.0, 35.0, 30.0, 28.0]
    # every one of four folds better by 2.5 se: past a normal 2 se, short of Student's t with 3 df (3.31): physics
    diff = np.array([1.0, 6.0, 2.0, 3.5])
    assert 2.0 < diff.sum() / math.sqrt(diff.size * np.var(diff, ddof=1)) < 3.31
    best, rec = _last_resort_case(list(np.add(phys[:4], diff)), phys[:4], True)
    assert best["effect"] == "two_state" and not rec["kept"], rec
    assert rec["rivals"][0]["n_folds"] == 4 and not rec["rivals"][0]["beats"]
    # every one of three folds better, or of six (the sign test at 1.6 %), whatever the se: named
    for n in (3, 6):
        best, rec = _last_resort_case(list(np.add(phys[:n], [1.0, 6.0, 0.5, 3.5, 9.0, 0.2][:n])), phys[:n], True)
        assert best["effect"] == "unnamed_dynamics@flow" and rec["kept"], (n, rec)
    # one of six folds worse (not an outlier among them): not beaten
    best, rec = _last_resort_case(list(np.add(phys, [4.0, 6.0, -1.0, 5.0, 3.0, 2.0])), phys, True)
    assert best["effect"] == "two_state" and not rec["kept"]


def test_the_two_state_pairs_come_from_the_screen_on_the_two_state_model(monkeypatch):
    """Every other candidate is screened on the two-state model held at its values, and the pairs are the best of
    that screen, even when the two-state model alone fits worse than the current model (a masked effect: a compliant
    mount on a two-state damper) and even where the round's own ranking differs; the round's best singles on eq. (7)
    are paired too (a valve's narrow basin between the screen's grid points), the others are not."""
    import bayesdamper.diagnosis.two_state_pairs as tsp

    specs = {n: CandidateSpec(n) for n in ("two_state", "friction", "backlash", "inertia", "leakage")}
    calls = []

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, **k):
        refilling = fixed.get("two_state", {}).get(tsp.REFILL) == tsp.REFILL_START
        calls.append(("screen" if grid_only else "pair", tuple(c.label for c in cands), tuple(fixed), refilling))
        # on the two-state model the screen ranks the candidates in the reverse of the round's own order
        score = {"friction": -5.0, "backlash": -10.0, "inertia": -20.0, "leakage": -30.0}.get(cands[-1].label, 0.0)
        return SimpleNamespace(labels=tuple(c.label for c in cands), delta_bic=score,
                               effects={c.effect: {} for c in cands}, effect="+".join(c.label for c in cands))

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    singles = [SimpleNamespace(labels=(n,), delta_bic=s, effects={n: {}}, effect=n)
               for n, s in (("friction", -40.0), ("backlash", -30.0), ("inertia", -20.0), ("leakage", -10.0))]
    for ts_score in (+203.0, -500.0):
        calls.clear()
        ts = SimpleNamespace(labels=("two_state",), delta_bic=ts_score, effects={"two_state": {}}, effect="two_state",
                             at_bound=[])
        out, screen = tsp.two_state_pairs(None, [ts, *singles], specs, list(specs), np.zeros(3), np.ones(3), None,
                                           Progress(False))
        screens = [c for c in calls if c[0] == "screen"]
        # each library effect on the model as fitted alone and on it refilling
        for refilling in (False, True):
            assert sorted(c[1] for c in screens if c[3] == refilling) == [("backlash",), ("friction",), ("inertia",),
                                                                          ("leakage",)]
        assert all(c[2] == ("two_state",) for c in screens)
        assert sorted(screen.alone) == ["backlash", "friction", "inertia", "leakage"]  # each one's best point
        # the screen's best three, then friction: the round's best single (its third best, inertia, is in already;
        # leakage is fourth there)
        assert [o.labels for o in out] == [("two_state", "leakage"), ("two_state", "inertia"),
                                           ("two_state", "backlash"), ("two_state", "friction")]
    # a single that did not improve on eq. (7) is not paired for it
    calls.clear()
    worse = [SimpleNamespace(labels=(n,), delta_bic=s, effects={n: {}}, effect=n)
             for n, s in (("friction", +4.0), ("backlash", -30.0), ("inertia", -20.0), ("leakage", -10.0))]
    out, _ = tsp.two_state_pairs(None, [ts, *worse], specs, list(specs), np.zeros(3), np.ones(3), None,
                                  Progress(False))
    assert [o.labels for o in out] == [("two_state", "leakage"), ("two_state", "inertia"), ("two_state", "backlash")]


def test_the_best_physical_screens_are_paired_whatever_generic_filters_rank_above_them(monkeypatch):
    """Generic filters can take the screen's first places on the two-state model (a compliant mount on a two-state
    damper looks like a flow filter); the library effects that improve on the two-state model are paired with it all
    the same, the PAIR_FROM best of them (a generic option is named only over the best physical ones), and a library
    effect the screen finds no better than the two-state model alone is not."""
    import bayesdamper.diagnosis.two_state_pairs as tsp

    generic = [f"unnamed_dynamics@{p}" for p in ("flow", "force", "flow:q", "force:q")]
    physical = ["series_compliance", "leakage", "friction", "backlash", "inertia"]
    specs = {n: CandidateSpec(n) for n in ["two_state", *generic, *physical]}
    screen = {**dict(zip(generic, (-900.0, -800.0, -700.0, -600.0), strict=True)),
              **dict(zip(physical, (-500.0, -400.0, -300.0, -200.0, +5.0), strict=True))}

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, **k):
        label = cands[-1].label
        return SimpleNamespace(labels=(label,) if grid_only else ("two_state", label), delta_bic=screen[label],
                               effects={c.effect: {} for c in cands}, effect="+".join(c.label for c in cands))

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    ts = SimpleNamespace(labels=("two_state",), delta_bic=+20.0, effects={"two_state": {}}, effect="two_state")
    out, _ = tsp.two_state_pairs(None, [ts], specs, list(specs), np.zeros(3), np.ones(3), None, Progress(False))
    paired = [o.labels[1] for o in out]
    assert paired == generic[:tsp.PAIR_FROM] + physical[:tsp.PAIR_FROM]
    assert "backlash" not in paired and "inertia" not in paired


def test_the_options_refitted_are_the_best_and_the_best_physical_ones():
    """A later round re-fits its best screened candidates jointly with the selected effects: the first PAIR_FROM and
    the first PAIR_FROM that hold no generic effect, in rank order, each once."""
    from bayesdamper.diagnosis.spec import best_and_physical, holds_generic

    labels = ["unnamed_dynamics@force", "unnamed_dynamics@flow", "load_cell_offset", "unnamed_dynamics@flow:q",
              "series_compliance", "gas_spring", "inertia"]
    specs = {n: CandidateSpec(n) for n in labels}
    ranked = [SimpleNamespace(effect=n) for n in labels]
    got = [c.effect for c in best_and_physical(ranked, specs, 3)]
    assert got == labels[:3] + ["series_compliance", "gas_spring"]
    assert [c.effect for c in best_and_physical(ranked[2:], specs, 3)] == labels[2:6]  # and the third physical one
    assert holds_generic("two_state+unnamed_dynamics@flow", specs | {"two_state": CandidateSpec("two_state")})
    assert not holds_generic("series_compliance", specs)


def test_a_two_state_pair_is_started_from_its_screens_and_the_candidates_own_optimum(monkeypatch):
    """A pair of the two-state model is refined from several starts, each for GLOBAL_LM_ITER iterations, the best
    continued; the better refinement is the option. The two-state side as fitted alone with the screen's point on it;
    at its defaults with the candidate's own optimum on eq. (7), where the candidate improved alone (a valve's screen
    point in a chattering basin, its own optimum in the ringing one); and with the accumulator refilling
    (REFILL_START): with a library effect's point on the refilling screen (the valve's pair is best from there: the
    refilling model's best valve lies in another basin than the screen's on the model as fitted alone; the leak's pair
    too) and with the candidate's own optimum where it improved alone. A generic candidate, screened on the model as
    fitted alone only, starts on the refilling model from that screen's point and searched afresh, without a start."""
    import bayesdamper.diagnosis.two_state_pairs as tsp

    generic = "unnamed_dynamics@flow"
    specs = {n: CandidateSpec(n) for n in ("two_state", "poppet_valve", "leakage", generic)}
    pairs, starts_ts, screens, continued = [], [], [], []

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, max_iter=None, **k):
        spec = cands[-1]
        label, eff = spec.label, spec.effect
        if grid_only:  # the screens: every point at 6 Hz on the model as fitted alone, at 2.5 Hz on it refilling
            on_refill = fixed["two_state"].get(tsp.REFILL) == tsp.REFILL_START
            screens.append((label, on_refill))
            return SimpleNamespace(labels=(label,), delta_bic=-50.0, effects={eff: {"f": 2.5 if on_refill else 6.0}},
                                   effect=label)
        assert k.get("dtol") == tsp.LM_DTOL_SEARCH  # an option is refined to the search's stop, not the reported one
        if max_iter == tsp.LM_ITER - tsp.GLOBAL_LM_ITER:  # the best start continued: 10 better
            continued.append((label, start[label]["f"], start["two_state"]["score"]))
            return SimpleNamespace(labels=("two_state", label), delta_bic=start["two_state"]["score"] - 10.0,
                                   effects={"two_state": {}, eff: {}}, effect=f"two_state+{label}")
        assert max_iter == tsp.GLOBAL_LM_ITER
        f = start[label]["f"] if label in start else None  # None: searched afresh
        pairs.append((label, f))
        starts_ts.append(start["two_state"])
        refilling = start["two_state"].get(tsp.REFILL) == tsp.REFILL_START
        score = {6.0: -100.0, 1.8: -1100.0, 2.5: -50.0, None: -50.0}[f]
        score -= 200.0 if refilling and label == "leakage" else 0.0
        score = -2500.0 if f == 2.5 and label == "poppet_valve" else score
        return SimpleNamespace(labels=("two_state", label), delta_bic=score,
                               effects={"two_state": {"score": score}, eff: {"f": f}}, effect=f"two_state+{label}")

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    ts = SimpleNamespace(labels=("two_state",), delta_bic=+40.0, effects={"two_state": {"G": 1e-15}},
                         effect="two_state", at_bound=[{"param": "G"}])
    valve = SimpleNamespace(labels=("poppet_valve",), delta_bic=-600.0, effects={"poppet_valve": {"f": 1.8}},
                            effect="poppet_valve")
    leak = SimpleNamespace(labels=("leakage",), delta_bic=+5.0, effects={"leakage": {"f": 0.3}}, effect="leakage")
    out, screen = tsp.two_state_pairs(None, [ts, valve, leak], specs, list(specs), np.zeros(3), np.ones(3), None,
                                      Progress(False))
    assert sorted(screens) == sorted([("poppet_valve", False), ("poppet_valve", True), ("leakage", False),
                                      ("leakage", True), (generic, False)])
    assert screen.alone == {"poppet_valve": {"f": 6.0}, "leakage": {"f": 6.0}, generic: {"f": 6.0}}  # as fitted alone
    own, defaults = {"G": 1e-15}, EFFECTS["two_state"].defaults()
    refilling = {**own, tsp.REFILL: tsp.REFILL_START}
    key = lambda r: (r[0][0], -1.0 if r[0][1] is None else r[0][1], sorted(r[1]))  # noqa: E731
    assert sorted(zip(pairs, starts_ts, strict=True), key=key) == sorted([
        (("leakage", 6.0), own), (("leakage", 2.5), refilling),  # did not improve alone: no own optimum
        (("poppet_valve", 6.0), own), (("poppet_valve", 1.8), defaults), (("poppet_valve", 2.5), refilling),
        (("poppet_valve", 1.8), refilling),
        ((generic, 6.0), own), ((generic, 6.0), refilling), ((generic, None), refilling)], key=key)
    # each start refined for GLOBAL_LM_ITER iterations, the best continued to the budget, and the continuation is the
    # option where it is better
    assert sorted(continued) == [("leakage", 2.5, -250.0), ("poppet_valve", 2.5, -2500.0), (generic, 6.0, -100.0)]
    best = {o.effect: o for o in out}
    assert best["two_state+poppet_valve"].delta_bic == -2510.0  # from the refilling screen's point
    assert best["two_state+leakage"].delta_bic == -260.0
    assert best[f"two_state+{generic}"].delta_bic == -110.0


def test_a_library_effect_masked_on_the_two_state_model_fitted_alone_ranks_by_its_refilling_screen(monkeypatch):
    """A stiff mount on a two-state damper: on the two-state model as fitted alone (its accumulator not refilling)
    the mount is no better than nothing, behind generic filters and other library effects; on the same model
    refilling it is the best candidate. A candidate ranks by the better of its two screens, so the mount is paired
    with the two-state model (and first); without its refilling screen it would not be."""
    import bayesdamper.diagnosis.two_state_pairs as tsp

    generic = [f"unnamed_dynamics@{p}" for p in ("flow", "force", "flow:q")]
    physical = ["friction", "backlash", "inertia", "series_compliance"]
    specs = {n: CandidateSpec(n) for n in ["two_state", *generic, *physical]}
    alone = {**dict(zip(generic, (-900.0, -800.0, -700.0), strict=True)),
             **dict(zip(physical, (-300.0, -200.0, -100.0, +5.0), strict=True))}
    on_refill = {n: +50.0 for n in physical} | {"series_compliance": -2000.0}

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, **k):
        label = cands[-1].label
        if grid_only:
            refilling = fixed["two_state"].get(tsp.REFILL) == tsp.REFILL_START
            score = on_refill[label] if refilling else alone[label]
            return SimpleNamespace(labels=(label,), delta_bic=score, effects={cands[-1].effect: {}}, effect=label)

        return SimpleNamespace(labels=("two_state", label), delta_bic=-1.0,
                               effects={"two_state": {}, cands[-1].effect: {}}, effect=f"two_state+{label}")

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    ts = SimpleNamespace(labels=("two_state",), delta_bic=+20.0, effects={"two_state": {}}, effect="two_state")
    out, _ = tsp.two_state_pairs(None, [ts], specs, list(specs), np.zeros(3), np.ones(3), None, Progress(False))
    assert [o.labels[1] for o in out][0] == "series_compliance"
    assert {o.labels[1] for o in out} == {"series_compliance", *generic[:2], "friction", "backlash"}
    on_refill["series_compliance"] = +60.0  # masked on both: not paired
    out, _ = tsp.two_state_pairs(None, [ts], specs, list(specs), np.zeros(3), np.ones(3), None, Progress(False))
    assert "series_compliance" not in {o.labels[1] for o in out}


def test_before_a_generic_option_every_library_effect_the_screens_found_better_is_paired(monkeypatch):
    """Before a generic option is named in the first round, the library effects not yet paired whose screen improved
    on the two-state model alone are fitted jointly with it, best screen first (a one-element valve screened into a
    wrong basin ranks below the pairs fitted); a generic candidate, one already paired or one whose screen is no
    better than the two-state model alone is not."""
    import bayesdamper.diagnosis.two_state_pairs as tsp

    generic = "unnamed_dynamics@flow"
    names = ("two_state", "series_compliance", "poppet_valve", "valve_dynamics", "friction", generic)
    specs = {n: CandidateSpec(n) for n in names}
    screen = {"series_compliance": -900.0, generic: -800.0, "valve_dynamics": -450.0, "poppet_valve": -500.0,
              "friction": -300.0}
    fitted = []

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, max_iter=None, **k):
        label, eff = cands[-1].label, cands[-1].effect
        if grid_only:
            return SimpleNamespace(labels=(label,), delta_bic=screen[label], effects={eff: {}}, effect=label)
        fitted.append(label)
        return SimpleNamespace(labels=("two_state", label), delta_bic=-1.0, effects={"two_state": {}, eff: {}},
                               effect=f"two_state+{label}")

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    monkeypatch.setattr(tsp, "PAIR_FROM", 1)
    monkeypatch.setattr(tsp, "residual_peaks", lambda *a: [])  # no spectral peak: no ringing pair (their own tests)
    ts = SimpleNamespace(labels=("two_state",), delta_bic=-400.0, effects={"two_state": {}}, effect="two_state")
    out, screens = tsp.two_state_pairs(None, [ts], specs, list(specs), np.zeros(3), np.ones(3), None,
                                       Progress(False))
    assert screens.paired == {"series_compliance"}  # the best screen and the best library effect: the same
    fitted.clear()
    more = tsp.physical_pairs_left(None, screens, [ts], specs, np.zeros(3), np.ones(3), None, Progress(False))
    assert [m.labels[1] for m in more] == ["poppet_valve", "valve_dynamics"]
    assert set(fitted) == {"poppet_valve", "valve_dynamics"}  # friction's screen is no better than the model alone
    assert screens.paired == {"series_compliance", "poppet_valve", "valve_dynamics"}
    assert tsp.physical_pairs_left(None, screens, [ts], specs, np.zeros(3), np.ones(3), None, Progress(False)) == []
    assert tsp.physical_pairs_left(None, None, [ts], specs, np.zeros(3), np.ones(3), None, Progress(False)) == []


def test_a_two_state_pair_already_fitted_from_its_members_is_also_fitted_from_the_pair_starts(monkeypatch):
    """Where the two-state model and a candidate are both among the round's best singles, their pair is fitted first
    from the members' own optima (the two-state model at no refill, its flat part); the two-state pairs fit it from
    their starts as well, and the best of all stands for the pair in the round's list (replaced, not duplicated).
    A pair whose earlier fit is better than every start keeps that fit."""
    import bayesdamper.diagnosis.two_state_pairs as tsp

    specs = {n: CandidateSpec(n) for n in ("two_state", "poppet_valve", "leakage")}

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, **k):
        label = cands[-1].label
        if grid_only:
            return SimpleNamespace(labels=(label,), delta_bic=-50.0, effects={label: {"f": 2.0}}, effect=label)
        refilling = start["two_state"].get(tsp.REFILL) == tsp.REFILL_START
        score = {"poppet_valve": -2500.0 if refilling else -900.0, "leakage": -100.0}[label]
        return SimpleNamespace(labels=("two_state", label), delta_bic=score, effects={"two_state": {}, label: {}},
                               effect=f"two_state+{label}")

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    ts = SimpleNamespace(labels=("two_state",), delta_bic=-30.0, effects={"two_state": {"G": 1e-15}},
                         effect="two_state")
    valve = SimpleNamespace(labels=("poppet_valve",), delta_bic=-1000.0, effects={"poppet_valve": {"f": 2.0}},
                            effect="poppet_valve")
    leak = SimpleNamespace(labels=("leakage",), delta_bic=-20.0, effects={"leakage": {"f": 0.3}}, effect="leakage")
    earlier_valve = SimpleNamespace(labels=("poppet_valve", "two_state"), delta_bic=-970.0, effects={},
                                    effect="poppet_valve+two_state")
    earlier_leak = SimpleNamespace(labels=("two_state", "leakage"), delta_bic=-400.0, effects={},
                                   effect="two_state+leakage")
    fits = [ts, valve, leak, earlier_valve, earlier_leak]
    out, _ = tsp.two_state_pairs(None, fits, specs, list(specs), np.zeros(3), np.ones(3), None, Progress(False))
    assert out == []  # both pairs were in the list already: nothing added
    pairs = [f for f in fits if len(f.labels) == 2]
    assert len(pairs) == 2
    assert {f.effect: f.delta_bic for f in pairs} == {"two_state+poppet_valve": -2500.0, "two_state+leakage": -400.0}
    assert earlier_leak in fits and earlier_valve not in fits


def test_a_supported_physical_option_beyond_the_rivals_is_scored_when_the_generic_loses(monkeypatch):
    """A round like a compliant mount's at 100 Hz: the generic option is within the margin of the two best physical
    options by ΔBIC_eff, pairs that fail their check over their better member (not supported, so not selectable);
    the two-state model alone, supported but ranked below them, had not been scored out of sample. It is scored now
    and selected when it passes the rule; when it does not, the answer is none."""
    import bayesdamper.diagnosis.loop as loop

    specs = {n: CandidateSpec(n) for n in ("unnamed_dynamics@flow", "two_state", "gas_spring", "poppet_valve")}

    def row(effect, score, per_fold, supported):
        r = {"effect": effect, "score": score, "supported": supported, "passes": supported and per_fold is not None}
        if per_fold is not None:
            sc = LovoScore(float(sum(per_fold)), 1.0, tuple(per_fold))
            r.update(lovo=sc.as_dict(), _lovo=sc)
        return r

    fits = [SimpleNamespace(effect="two_state", labels=("two_state",), effects={"two_state": {}})]
    for ts_folds, selected in (((20.0, 22.0, 18.0, 21.0, 19.0), "two_state"), ((20.0, -2.0, 18.0, 21.0, 19.0), None)):
        scored = []

        def fake_lovo(engine, folds, cand, effects, *a, folds_of=ts_folds, scored=scored, **k):
            scored.append(tuple(c.label for c in cand))
            return LovoScore(float(sum(folds_of)), 1.0, folds_of)

        monkeypatch.setattr(loop, "lovo_score", fake_lovo)
        gen = row("unnamed_dynamics@flow", -1335.0, [30.0, 25.0, 40.0, 20.0, 35.0], True)
        rivals = [row("two_state+gas_spring", -1346.0, [28.0, 30.0, 33.0, 25.0, 31.0], False),
                  row("two_state+poppet_valve", -1234.0, [29.0, 31.0, 32.0, 24.0, 30.0], False)]
        ts = row("two_state", -1078.0, None, True)
        best, rec = loop.unnamed_last_resort(gen, [gen, *rivals, ts], fits, specs, None, [0], [], {}, None, None,
                                             None, {})
        assert not rec["kept"] and sorted(rec["indistinguishable_from"]) == sorted(r["effect"] for r in rivals)
        assert scored == [("two_state",)]  # the rivals were scored already; the supported single is scored now
        assert rec["fallback"] == [{"effect": "two_state", "passes": selected is not None}]
        assert (best["effect"] if best else None) == selected


def test_a_round_that_selects_nothing_says_why_for_each_option():
    """The report's account of a round with no selection names, for every option that passes the criterion in
    sample, why it was not selected, and for a best pair that does not pass over its better member, that check."""
    from bayesdamper.diagnosis.summary import none_selected_lines

    lovo = {"gain": 600.0, "se": 100.0, "per_fold": [100.0, 120.0, 130.0, 110.0, 140.0]}
    candidates = [
        {"effect": "two_state+gas_spring", "score": -1346.0, "J_reduction": 0.49, "supported": False, "lovo": lovo,
         "over_better_member": {"member": "two_state", "delta_BIC_eff": -269.0, "J_reduction": 0.13}},
        {"effect": "unnamed_dynamics@flow", "score": -1335.0, "J_reduction": 0.48, "supported": True, "lovo": lovo,
         "not_named": "a physical explanation predicts the held-out speeds as well"},
        {"effect": "leakage", "score": -1200.0, "J_reduction": 0.30, "supported": True,
         "lovo": {**lovo, "per_fold": [-5.0, 120.0, 130.0, 110.0, 140.0]}},
        {"effect": "two_state", "score": -1078.0, "J_reduction": 0.41, "supported": True},
    ]
    first, best = none_selected_lines(candidates)
    assert "leakage: not the held-out speeds" in first
    assert "unnamed_dynamics@flow: not named" in first
    assert "two_state: not scored out of sample" in first
    assert "two_state+gas_spring" not in first  # not supported: not among those that pass in sample
    assert best.startswith("Best candidate: two_state+gas_spring") and "over its better member two_state" in best
    assert "J -13%" in best
    assert none_selected_lines(candidates[:1] + [{**candidates[3], "supported": False}])[0].startswith(
        "Selected: none - no candidate passes")


def test_the_reports_line_on_a_generic_option_names_the_pairs_fitted_before_naming_it():
    """The report says which two-state pairs were fitted before the generic option was named, each rival's paired
    gain, and the verdict; a record without such pairs says nothing of them."""
    from bayesdamper.diagnosis.summary import last_resort_lines

    rec = {"generic": "two_state+unnamed_dynamics@flow", "kept": False, "indistinguishable_from": ["two_state+x"],
           "pairs_fitted_before_naming": ["two_state+poppet_valve"],
           "rivals": [{"effect": "two_state+poppet_valve", "gain_over": -12.5, "se": 3.0, "n_folds": 6,
                       "beats": False}]}
    (line,) = last_resort_lines([{"last_resort": rec}, {"last_resort": None}])
    assert "before it was named, also fitted: two_state+poppet_valve" in line
    assert "two_state+poppet_valve (-12.5, se 3.0, 6 folds: not beaten)" in line
    assert line.endswith("not named; indistinguishable from two_state+x.")
    (line,) = last_resort_lines([{"last_resort": {**rec, "pairs_fitted_before_naming": [], "kept": True}}])
    assert "also fitted" not in line and ": named;" in line


def test_a_generic_option_that_beats_the_rivals_fitted_loses_to_a_library_pair_fitted_before_naming_it(monkeypatch):
    """The loop's wiring (fakes for the searches, no speed folds: an option passes when supported): in the first
    round a two-state + generic pair is the only supported option and no physical rival passes, so it would be named;
    the library pairs the screens left are fitted first, one of them (the two-state model with a valve) passes, and
    it is selected instead; the round's record lists the pairs fitted and says the generic option was not named."""
    import bayesdamper.diagnosis.loop as loop

    generic = "unnamed_dynamics@flow"
    names = ["two_state", generic, "friction", "poppet_valve"]
    # J of the current model is 0.1 (unit residuals, forces of 10); supported: ΔBIC_eff <= -10 and J <= 0.08
    table = {("two_state",): (-100.0, 0.085), (generic,): (-50.0, 0.09), ("friction",): (-20.0, 0.095),
             ("poppet_valve",): (-10.0, 0.098), ("two_state", generic): (-500.0, 0.04),
             ("two_state", "friction"): (-110.0, 0.083), (generic, "friction"): (-60.0, 0.088),
             ("two_state", "poppet_valve"): (-800.0, 0.03)}

    asked = []

    def fake_left(engine, screens, fits, specs, *a):
        asked.append(sorted(f.effect for f in fits))
        return [loop_fit(("two_state", "poppet_valve"), *table[("two_state", "poppet_valve")])]

    engine = SimpleNamespace(evaluate=lambda *a, **k: (np.full(3, 50.0), None, [np.ones(50)] * 3),
                             set_warm=lambda w: None)
    monkeypatch.setattr(loop, "search_option", table_search(table))
    monkeypatch.setattr(loop, "two_state_pairs", lambda *a: ([], SimpleNamespace(alone={})))
    monkeypatch.setattr(loop, "physical_pairs_left", fake_left)
    monkeypatch.setattr(loop, "research_basins", lambda search, fit, held, new, subset=None: (fit, []))
    monkeypatch.setattr(loop, "search_variants", lambda search, fit, held, new: (fit, [], {}))
    monkeypatch.setattr(loop, "fit_joint", lambda engine, cand, start, *a, **k: loop_fit(
        ("two_state", "poppet_valve"), -805.0, 0.029))
    monkeypatch.setattr(loop, "backward_check", lambda engine, sel, specs, fixed, *a: (sel, specs, fixed, []))
    selected, fixed, rounds = loop.select_effects(engine, names, [np.full(50, 10.0)] * 3, lambda e: None,
                                                  Progress(False))
    assert selected == ["two_state", "poppet_valve"]
    assert len(asked) == 1  # once, before the generic option would have been named
    lr = rounds[0]["last_resort"]
    assert lr["generic"] == f"two_state+{generic}" and not lr["kept"]
    assert lr["pairs_fitted_before_naming"] == ["two_state+poppet_valve"]
    assert rounds[0]["selected"] == "two_state+poppet_valve"
    assert rounds[1]["selected"] is None
