"""The selected option's narrow-basin effects searched afresh (:mod:`bayesdamper.diagnosis.basins`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from profile_fakes import loop_fit, table_search

import bayesdamper.diagnosis.basins as basins
from bayesdamper.diagnosis.spec import CandidateFit, CandidateSpec


def _fit(label: str, delta_bic: float, effects: dict) -> CandidateFit:
    return CandidateFit(label, {}, {}, delta_bic, 0.01 * np.exp(delta_bic / 1e4), np.zeros(1), np.zeros(1), 10,
                        effects, 1, tuple(label.split("+")))


OPTION = {"two_state": {"polytropic_exponent": 1.2, "refill_conductance_m3_per_s_Pa": 1e-11},
          "poppet_valve": {"natural_frequency_Hz": 2.0, "damping_ratio": 0.5, "cracking_pressure_Pa": 1.1e5,
                           "span_Pa": 5e6, "bleed_fraction": 0.6}}


def test_narrow_kinds_decide_which_candidates_are_searched_afresh():
    assert basins.has_narrow(CandidateSpec("poppet_valve"))
    assert basins.has_narrow(CandidateSpec("command_displacement"))  # a bandwidth and a damping ratio
    assert not basins.has_narrow(CandidateSpec("two_state"))
    assert not basins.has_narrow(CandidateSpec("series_compliance"))
    assert not basins.has_narrow(CandidateSpec("load_cell_offset"))


@pytest.mark.parametrize(("afresh", "replaced"), [(-1500.0, True), (-1005.0, False), (-900.0, False)])
def test_a_search_afresh_replaces_the_option_only_by_very_strong_evidence(afresh, replaced):
    """The option at ΔBIC_eff −1000 against a search afresh at ``afresh``: replaced only when more than 10 lower
    (−1005 is better, but within the margin a search's tolerance can give)."""
    calls = []
    found = _fit("two_state+poppet_valve", afresh, {"two_state": dict(OPTION["two_state"]),
                                                     "poppet_valve": {**OPTION["poppet_valve"],
                                                                      "cracking_pressure_Pa": 1.5e4}})

    def search(cand, start):
        calls.append((tuple(sp.label for sp in cand), start))
        return found

    option = _fit("two_state+poppet_valve", -1000.0, OPTION)
    new = [CandidateSpec("two_state"), CandidateSpec("poppet_valve")]
    out, rows = basins.research_basins(search, option, [], new)
    # one search afresh: the valve's; the two-state model (no narrow parameter) starts at the option's optimum
    assert calls == [(("two_state", "poppet_valve"), {"two_state": OPTION["two_state"]})]
    assert out is (found if replaced else option)
    assert rows == [{"candidate": "poppet_valve", "delta_BIC_eff": -1000.0,
                     "J_pooled": option.j_pooled, "afresh_delta_BIC_eff": afresh,
                     "afresh_J_pooled": found.j_pooled, "replaced": replaced}]


@pytest.mark.parametrize(("on_subset", "afresh", "continued", "replaced"),
                         [(-480.0, -1500.0, True, True), (-480.0, -1005.0, True, False),
                          (-400.0, -1500.0, False, False), (-450.0, -1500.0, False, False)])
def test_with_a_subset_the_search_afresh_goes_on_to_every_window_only_if_better_there(on_subset, afresh, continued,
                                                                                      replaced):
    """The option scores −450 on the screening windows where it stands (one evaluation, no refinement); the search
    afresh runs there first (grid, global stage, refinement, no simplex) and ends at ``on_subset``. Only a search
    better there than the option (−480) goes on: a refinement on every window from its optimum, every effect started
    there, which replaces the option by the same very strong evidence as without a subset. A search no better on the
    subset (−400, or −450, a tie) stops there and the option's fit stands."""
    subset = np.array([0, 3, 5])
    calls = []
    first = _fit("two_state+poppet_valve", on_subset, {"two_state": {**OPTION["two_state"], "polytropic_exponent": 1.3},
                                                       "poppet_valve": {**OPTION["poppet_valve"],
                                                                        "cracking_pressure_Pa": 1.5e4}})
    found = _fit("two_state+poppet_valve", afresh, first.effects)

    def search(cand, start, idx=None, max_iter=None, polish=None):
        calls.append((tuple(sp.label for sp in cand), start, None if idx is None else list(idx), max_iter,
                      polish, cand[-1].poles))
        if idx is None:
            return found
        return _fit("two_state+poppet_valve", -450.0, OPTION) if max_iter == 0 else first

    option = _fit("two_state+poppet_valve", -1000.0, OPTION)
    valve = CandidateSpec("poppet_valve", poles=((2.0, 0.3),))
    out, rows = basins.research_basins(search, option, [], [CandidateSpec("two_state"), valve], subset=subset)
    pair = ("two_state", "poppet_valve")
    assert calls[:2] == [(pair, OPTION, [0, 3, 5], 0, None, ((2.0, 0.3),)),  # the option where it stands
                         # afresh from the data's starts, no simplex on the subset
                         (pair, {"two_state": OPTION["two_state"]}, [0, 3, 5], None, False, ())]
    assert calls[2:] == ([(pair, first.effects, None, None, None, ((2.0, 0.3),))] if continued else [])
    assert out is (found if replaced else option)
    row = {"candidate": "poppet_valve", "delta_BIC_eff": -1000.0, "J_pooled": option.j_pooled,
           "subset_delta_BIC_eff": -450.0, "subset_afresh_delta_BIC_eff": on_subset, "continued": continued,
           "replaced": replaced}
    assert rows == [{**row, "afresh_delta_BIC_eff": afresh, "afresh_J_pooled": found.j_pooled} if continued else row]


def test_the_subset_of_a_search_afresh_is_whole_windows_only():
    """The engine's screening windows when they are windows; none without a screen, or when the screen is short
    stretches appended after the windows (a whole-record data set)."""
    assert list(basins.window_subset(SimpleNamespace(screen=np.array([0, 4, 8]), n=12))) == [0, 4, 8]
    assert basins.window_subset(SimpleNamespace(screen=None, n=12)) is None
    assert basins.window_subset(SimpleNamespace(screen=np.arange(12, 20), n=12)) is None
    assert basins.window_subset(SimpleNamespace(n=12)) is None


def test_effects_selected_before_start_at_the_option_and_each_narrow_candidate_is_searched():
    """A later round's option (the valve selected before, a servo and a mount new): the servo alone is searched
    afresh, the valve and the mount start at the option's values; a replacement carries into the next search."""
    seen = []
    effects = {"poppet_valve": dict(OPTION["poppet_valve"]), "command_displacement": {"bandwidth_Hz": 4.0,
                                                                                      "damping_ratio": 0.3},
               "series_compliance": {"stiffness_N_per_m": 2e7}}

    def search(cand, start):
        seen.append(sorted(start))
        return _fit("command_displacement+series_compliance", -2000.0, effects)

    option = _fit("command_displacement+series_compliance", -1000.0, effects)
    out, rows = basins.research_basins(search, option, [CandidateSpec("poppet_valve")],
                                       [CandidateSpec("command_displacement"), CandidateSpec("series_compliance")])
    assert seen == [["poppet_valve", "series_compliance"]]
    assert [r["candidate"] for r in rows] == ["command_displacement"] and rows[0]["replaced"]
    assert out.delta_bic == -2000.0


def test_a_candidate_with_signature_starts_is_searched_afresh_from_the_data_alone():
    """The valve with part 1's poles, onsets and starts, and an earlier round's point: searched afresh without them,
    its search boxes and fixed structure kept."""
    seen = []

    def search(cand, start):
        seen.append(cand[-1])
        return _fit("two_state+poppet_valve", -1500.0, OPTION)

    valve = CandidateSpec("poppet_valve", extra={"bleed_fraction": 0.2}, poles=((1.66, 0.17),), thresholds=(3e4,),
                          starts={"natural_frequency_Hz": (1.66,)}, points=({"span_Pa": 1e6},))
    out, rows = basins.research_basins(search, _fit("two_state+poppet_valve", -1000.0, OPTION), [],
                                       [CandidateSpec("two_state"), valve])
    assert seen == [CandidateSpec("poppet_valve", extra={"bleed_fraction": 0.2})]
    assert [r["replaced"] for r in rows] == [True] and out.delta_bic == -1500.0


@pytest.mark.slow
def test_on_a_valve_the_search_afresh_leaves_a_wrong_basin(tmp_path):
    """Independent two-state data with rig-A's kind of check valve (the confusion table's reference generator, 2 Hz,
    ζ 0.5, cracking 15 kPa, span 30 MPa; 3 speeds at 200 Hz): an option that stands at a valve of another basin (an
    11 Hz, ζ 0.1 valve, where a search from the signature's starts ended on an independent set of 27 transients; the
    option scored where it stands) is replaced by the search afresh, which comes within 1.5 times the true model's J
    (the form is the library's); the search afresh from that fit does not replace it again (the margin)."""
    import math
    from functools import partial

    import test_confusion as tc

    from bayesdamper.diagnosis.candidates import effective_sizes, fit_joint
    from bayesdamper.diagnosis.engine import LM_DTOL_SEARCH
    from bayesdamper.diagnosis.loop import search_option
    from bayesdamper.physics.with_effects import effect_argument
    from bayesdamper.run.diagnose import prepare_diagnosis

    base, effects, cycles = tc.TWO_STATE_CASES["two-state + check valve 2 Hz"]
    data, truth = tc._dataset(tmp_path / "data", effects, cycles, seed=23, base=base)
    p = prepare_diagnosis(str(data), str(tmp_path / "out"), seed=0, workers=1, compare=False)
    engine = p.engine()
    try:
        sse, _, resid = engine.evaluate(effect_argument({}), None, keep=True)
        n_eff = effective_sizes([r if r is not None else f for r, f in zip(resid, p.forces, strict=True)])
        specs = [CandidateSpec("two_state"), CandidateSpec("poppet_valve")]
        wrong = {"two_state": {"polytropic_exponent": 1.2, "refill_conductance_m3_per_s_Pa": 2e-11},
                 "poppet_valve": {"natural_frequency_Hz": 11.0, "damping_ratio": 0.1, "cracking_pressure_Pa": 2.3e4,
                                  "span_Pa": 2.6e5, "bleed_fraction": 0.01}}
        option = fit_joint(engine, specs, wrong, {}, sse, n_eff, p.flow_for, effect_argument,
                           new=("two_state", "poppet_valve"), max_iter=0, intervals_to=-math.inf,
                           dtol=LM_DTOL_SEARCH)
        search = partial(search_option, engine, fixed={}, current_sse=sse, n_eff=n_eff, flow_for=p.flow_for,
                         new=("two_state", "poppet_valve"))
        subset = basins.window_subset(engine)
        out, rows = basins.research_basins(search, option, [], specs, subset=subset)
        again, rows2 = basins.research_basins(search, out, [], specs, subset=subset)
    finally:
        engine.close()
    # the generator's own J on these windows, as the confusion table computes it
    j_truth = tc._j_truth({"windows": [{"test": w.test, "t_start_s": float(w.time[0]), "t_end_s": float(w.time[-1]),
                                        "n_samples": int(w.time.size)} for w in p.windows]}, truth)
    assert any(r["replaced"] for r in rows), (rows, option.j_pooled, j_truth)
    assert out.j_pooled < 0.8 * option.j_pooled
    assert out.j_pooled <= 1.5 * j_truth, (out.j_pooled, j_truth)
    assert not any(r["replaced"] for r in rows2) and again is out


def test_the_poppet_valve_has_the_check_valves_as_its_variant_and_nothing_else_has_one():
    assert basins.variants("poppet_valve") == ("check_valves",)
    assert basins.variants("two_state") == () and basins.variants("check_valves") == ()


@pytest.mark.parametrize(("variant", "replaced"), [(-1500.0, True), (-1005.0, False)])
def test_a_variant_is_searched_in_the_effects_place_and_replaces_it_only_by_very_strong_evidence(variant, replaced):
    """The option two-state + poppet valve at ΔBIC_eff −1000: the check valves are searched in the valve's place,
    from the valve's own starts and its optimum as a grid point, the two-state model at the option's optimum, scored
    as the option's new effects; a variant at ``variant`` replaces it only when more than 10 lower."""
    calls = []
    found = _fit("two_state+check_valves", variant, {"two_state": dict(OPTION["two_state"]),
                                                      "check_valves": dict(OPTION["poppet_valve"])})

    def search(cand, start, new):
        calls.append((tuple(sp.label for sp in cand), start, new, cand[1].points, cand[1].poles))
        return found

    option = _fit("two_state+poppet_valve", -1000.0, OPTION)
    valve = CandidateSpec("poppet_valve", poles=((2.0, 0.3),))
    out, rows, added = basins.search_variants(search, option, [], [CandidateSpec("two_state"), valve])
    assert calls == [(("two_state", "check_valves"), {"two_state": OPTION["two_state"]},
                      ("two_state", "check_valves"), (OPTION["poppet_valve"],), ((2.0, 0.3),))]
    assert out is (found if replaced else option)
    assert set(added) == ({"check_valves"} if replaced else set())
    assert rows == [{"candidate": "poppet_valve", "variant": "check_valves", "delta_BIC_eff": -1000.0,
                     "J_pooled": option.j_pooled, "variant_delta_BIC_eff": variant,
                     "variant_J_pooled": found.j_pooled, "replaced": replaced}]


def test_an_option_without_variants_is_not_searched_again():
    def search(cand, start, new):
        raise AssertionError("no variant to search")

    option = _fit("two_state+series_compliance", -500.0, {"two_state": dict(OPTION["two_state"]),
                                                          "series_compliance": {"stiffness_N_per_m": 2e7}})
    out, rows, added = basins.search_variants(search, option, [], [CandidateSpec("two_state"),
                                                                   CandidateSpec("series_compliance")])
    assert out is option and rows == [] and added == {}


def test_the_reports_lines_say_whether_a_search_afresh_went_on_and_what_it_found():
    """A search afresh stopped on the screening windows says so with both scores there; one that went on gives the
    option's and the search's pooled J and ΔBIC_eff and the verdict; one without a subset has no subset scores."""
    from bayesdamper.diagnosis.summary import basins_lines

    base = {"candidate": "poppet_valve", "delta_BIC_eff": -3098.0, "J_pooled": 0.0050}
    stopped = {**base, "subset_delta_BIC_eff": -1040.0, "subset_afresh_delta_BIC_eff": -980.0, "continued": False,
               "replaced": False}
    went_on = {**base, "subset_delta_BIC_eff": -1040.0, "subset_afresh_delta_BIC_eff": -1100.0, "continued": True,
               "afresh_delta_BIC_eff": -3200.0, "afresh_J_pooled": 0.0045, "replaced": True}
    whole = {**base, "afresh_delta_BIC_eff": -3090.0, "afresh_J_pooled": 0.0051, "replaced": False}
    rounds = [{"selected": "two_state+poppet_valve", "candidates": [
        {"effect": "two_state+poppet_valve", "basins_afresh": [stopped, went_on, whole]},
        {"effect": "two_state+friction", "basins_afresh": [whole]}]}]
    a, b, c = basins_lines(rounds)
    assert "on the screening windows delta-BIC_eff -1040 -> -980, no better there, not continued" in a
    assert a.endswith("the option's fit stands") and "J 0.0050" not in a
    assert "-1040 -> -1100, J 0.0050 -> 0.0045 (delta-BIC_eff -3098 -> -3200): another basin" in b
    assert "screening" not in c and c.endswith("(delta-BIC_eff -3098 -> -3090): the option's fit stands")


# ----------------------------------------------------------------------------------------------------
# a generic option's physical rivals searched afresh before it is named (loop.rivals_afresh)

GENERIC = "unnamed_dynamics@flow"


def _specs(*labels):
    return {lab: CandidateSpec(lab) for lab in labels}


def _row(effect, score, j, **kw):
    return {"effect": effect, "score": score, "J_pooled": j, "pair": "+" in effect, "supported": True, **kw}


def test_the_best_physical_rivals_are_searched_afresh_and_a_rival_in_a_better_basin_is_re_made(monkeypatch):
    """Of the rows, the generic option and a screened-only row are no rivals; of the others the two best by ΔBIC_eff
    are searched (the third is not). The valve's search afresh finds a better basin: its fit is swapped in, its row
    re-made from it (score, J, support) with its out-of-sample score dropped, and without speed folds it passes when
    supported; its row keeps the searches. The mount has no narrow-basin parameter: nothing searched, its row
    untouched."""
    import bayesdamper.diagnosis.loop as loop

    specs = _specs("two_state", GENERIC, "poppet_valve", "series_compliance", "friction", "backlash")
    valve = _fit("two_state+poppet_valve", -2400.0, OPTION)
    mount = _fit("two_state+series_compliance", -2000.0, {})
    third = _fit("two_state+friction", -1000.0, {})
    found = _fit("two_state+poppet_valve", -7400.0, OPTION)
    fits = [_fit(f"two_state+{GENERIC}", -3000.0, {}), valve, mount, third, _fit("two_state", -900.0, {})]
    rows = [_row(f"two_state+{GENERIC}", -3000.0, 0.006), _row("two_state+poppet_valve", -2400.0, 0.0068,
                                                                 lovo={"gain": 1.0}, passes=False),
            _row("two_state+series_compliance", -2000.0, 0.0074, lovo={"gain": 2.0}, passes=True),
            _row("two_state+friction", -1000.0, 0.008), _row("two_state", -900.0, 0.011),
            _row("backlash", -5000.0, 0.005, held_selected=True)]
    searched = []

    def fake_research(search, fit, held, new, subset=None):
        searched.append(fit.effect)
        if fit is valve:
            return found, [{"candidate": "poppet_valve", "replaced": True}]
        return fit, []

    monkeypatch.setattr(loop, "research_basins", fake_research)
    engine = SimpleNamespace(screen=None, n=3)
    out = loop.rivals_afresh(engine, rows, fits, specs, [], np.ones(3), np.ones(3), lambda e: None, 0.0117, None)
    assert searched == ["two_state+poppet_valve", "two_state+series_compliance"]
    assert out == [{"effect": "two_state+poppet_valve", "searches": [{"candidate": "poppet_valve",
                                                                      "replaced": True}]}]
    assert fits[1] is found and fits[2] is mount
    v = rows[1]
    assert v["score"] == -7400.0 and v["J_pooled"] == found.j_pooled and "lovo" not in v
    assert v["supported"] and v["passes"]  # no folds: supported passes
    assert v["basins_afresh"] == out[0]["searches"]
    m = rows[2]
    assert m["lovo"] == {"gain": 2.0} and m["passes"] and "basins_afresh" not in m


def test_with_speed_folds_a_re_made_rival_waits_for_its_out_of_sample_score(monkeypatch):
    import bayesdamper.diagnosis.loop as loop

    specs = _specs("two_state", GENERIC, "poppet_valve")
    valve = _fit("two_state+poppet_valve", -2400.0, OPTION)
    fits = [valve]
    rows = [_row("two_state+poppet_valve", -2400.0, 0.0068, lovo={"gain": 1.0}, passes=True)]
    monkeypatch.setattr(loop, "research_basins", lambda search, fit, held, new, subset=None: (
        _fit("two_state+poppet_valve", -7400.0, OPTION), [{"candidate": "poppet_valve", "replaced": True}]))
    loop.rivals_afresh(SimpleNamespace(screen=None, n=3), rows, fits, specs, [], np.ones(3), np.ones(3),
                       lambda e: None, 0.0117, folds=[[0], [1], [2]])
    assert rows[0]["passes"] is False and "lovo" not in rows[0]


def test_a_generic_option_is_not_named_over_a_rival_that_a_search_afresh_moves_to_a_better_basin(monkeypatch):
    """The loop's wiring (fakes for the searches, no speed folds): in the first round the two-state + generic pair is
    the only supported option, the two-state valve pair's refinement ended in a basin that does not lower J by the
    fifth asked, and no pair is left to fit, so the generic option would be named. The rivals are searched afresh:
    the valve's moves to a basin that passes, and the pair is selected instead and not searched afresh again; the
    round's record gives the search and says the generic option was not named."""
    import bayesdamper.diagnosis.loop as loop
    from bayesdamper.run.progress import Progress

    names = ["two_state", GENERIC, "poppet_valve"]
    # J of the current model is 0.1 (unit residuals, forces of 10); supported: ΔBIC_eff <= -10 and J <= 0.08
    table = {("two_state",): (-100.0, 0.085), (GENERIC,): (-50.0, 0.09), ("poppet_valve",): (-10.0, 0.098),
             ("two_state", GENERIC): (-500.0, 0.04), ("two_state", "poppet_valve"): (-300.0, 0.083),
             (GENERIC, "poppet_valve"): (-60.0, 0.088)}

    researched = []

    def fake_research(search, fit, held, new, subset=None):
        researched.append(fit.effect)
        if fit.effect == "two_state+poppet_valve":
            return loop_fit(fit.labels, -900.0, 0.03), [{"candidate": "poppet_valve", "replaced": True}]
        return fit, []

    engine = SimpleNamespace(evaluate=lambda *a, **k: (np.full(3, 50.0), None, [np.ones(50)] * 3),
                             set_warm=lambda w: None, screen=None, n=3)
    monkeypatch.setattr(loop, "search_option", table_search(table))
    monkeypatch.setattr(loop, "two_state_pairs", lambda *a: ([], SimpleNamespace(alone={})))
    monkeypatch.setattr(loop, "physical_pairs_left", lambda *a: [])
    monkeypatch.setattr(loop, "research_basins", fake_research)
    monkeypatch.setattr(loop, "search_variants", lambda search, fit, held, new: (fit, [], {}))
    monkeypatch.setattr(loop, "fit_joint", lambda engine, cand, start, *a, **k: loop_fit(
        ("two_state", "poppet_valve"), -905.0, 0.029))
    monkeypatch.setattr(loop, "backward_check", lambda engine, sel, specs, fixed, *a: (sel, specs, fixed, []))
    selected, fixed, rounds = loop.select_effects(engine, names, [np.full(50, 10.0)] * 3, lambda e: None,
                                                  Progress(False))
    assert selected == ["two_state", "poppet_valve"]
    lr = rounds[0]["last_resort"]
    assert lr["generic"] == f"two_state+{GENERIC}" and not lr["kept"]
    assert lr["rivals_searched_afresh"] == [{"effect": "two_state+poppet_valve",
                                             "searches": [{"candidate": "poppet_valve", "replaced": True}]}]
    assert researched.count("two_state+poppet_valve") == 1  # selected, not searched afresh again
    assert rounds[0]["selected"] == "two_state+poppet_valve"
    scores = [r["score"] for r in rounds[0]["candidates"]]
    assert scores == sorted(scores)  # the report's ranking holds the re-made row in its place


def test_the_reports_line_on_a_generic_option_gives_its_rivals_searches_afresh():
    from bayesdamper.diagnosis.summary import last_resort_lines

    went_on = {"candidate": "poppet_valve", "delta_BIC_eff": -2414.0, "J_pooled": 0.0068, "continued": True,
               "afresh_delta_BIC_eff": -7378.0, "afresh_J_pooled": 0.0023, "replaced": True}
    stopped = {"candidate": "command_displacement", "delta_BIC_eff": -900.0, "J_pooled": 0.008, "continued": False,
               "replaced": False}
    rec = {"generic": f"two_state+{GENERIC}", "kept": False, "indistinguishable_from": [], "rivals": [],
           "rivals_searched_afresh": [{"effect": "two_state+poppet_valve", "searches": [went_on]},
                                      {"effect": "two_state+command_displacement", "searches": [stopped]}]}
    (line,) = last_resort_lines([{"last_resort": rec}])
    assert ("before it was named, the rivals' narrow-basin effects searched afresh: two_state+poppet_valve "
            "(poppet_valve: delta-BIC_eff -2414 -> -7378, J 0.0068 -> 0.0023, replaces the fit); "
            "two_state+command_displacement (command_displacement: no better on the screening windows, the fit "
            "stands)") in line
    (line,) = last_resort_lines([{"last_resort": {**rec, "rivals_searched_afresh": []}}])
    assert "searched afresh" not in line
