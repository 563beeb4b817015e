"""The Nelder-Mead polish of a search whose refinement did not converge: deferred by ``fit_joint`` and run by the loop
for the singles whose score can still decide the round (:func:`bayesdamper.diagnosis.loop.polish_contenders`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from profile_fakes import FakeProfileEngine, fake_problem

import bayesdamper.diagnosis.loop as loop
from bayesdamper.diagnosis.candidates import fit_joint
from bayesdamper.diagnosis.spec import CandidateFit, CandidateSpec


class _RoughEngine(FakeProfileEngine):
    """One window whose SSE has a smooth bowl in (log bandwidth, damping ratio) of a servo, with a ripple of 2 % of
    its size on top: the Levenberg-Marquardt refinement stalls on the ripple (its steps fail), the simplex walks
    over it."""

    problems = [fake_problem(np.ones(400))]
    noise = np.random.default_rng(3).standard_normal(400)

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        p = eff["command_displacement"]
        f, z = math.log(p["bandwidth_Hz"]), p["damping_ratio"]
        s = 400.0 * (0.3 + 0.7 * min(1.0, (f - 1.0) ** 2 + (z - 0.6) ** 2)
                     + 0.02 * abs(math.sin(40.0 * f) * math.sin(40.0 * z)))
        return np.array([s]), np.zeros((1, 2)), [self.noise / math.sqrt(float(np.mean(self.noise ** 2)))
                                                 * math.sqrt(s / 400.0)]


def _fit(engine, **kw) -> CandidateFit:
    return fit_joint(engine, [CandidateSpec("command_displacement")], kw.pop("start", {}), {}, np.array([400.0]),
                     np.array([400.0]), lambda e: None, lambda e: e, **kw)


def test_a_deferred_polish_is_the_polish_the_search_would_have_run():
    """polish None: the search polishes (its evaluations more than double); False: it stops at the refinement's
    optimum, marked pending; True from that optimum with no refinement: the polish, which scores at least as well as
    the pending optimum and about as well as the search that polished at once (the two simplexes start from the
    same point; their objectives differ only in the windows' warm starts, none here)."""
    eng = _RoughEngine()
    now = _fit(eng)
    deferred = _fit(eng, polish=False)
    assert not now.polish_pending and deferred.polish_pending
    assert now.n_evaluations > 1.5 * deferred.n_evaluations
    assert now.delta_bic < deferred.delta_bic - 1.0  # the polish gains on this profile
    label = "command_displacement"
    later = _fit(eng, start={label: deferred.effects[label]}, new=(label,), max_iter=0, polish=True)
    assert not later.polish_pending
    assert later.delta_bic <= deferred.delta_bic
    assert later.delta_bic == now.delta_bic


def _single(label: str, score: float, pending: bool) -> CandidateFit:
    return CandidateFit(label, {}, {}, score, 0.01, np.zeros(1), np.zeros(1), 10, {label: {"x": score}}, 1, (label,),
                        polish_pending=pending)


def _run(scores: dict, gains: dict, monkeypatch) -> tuple[list, list]:
    """polish_contenders on singles of the given scores (pending where the label starts with "p"), each polish
    gaining ``gains[label]``; returns the labels polished in order and the fits after."""
    polished = []

    def fake_search(engine, specs, start, fixed, current_sse, n_eff, flow_for, **kw):
        label = specs[0].label
        assert kw["max_iter"] == 0 and kw["polish"] is True and kw["new"] == (label,)
        assert start == {label: {"x": scores[label]}}
        polished.append(label)
        return dataclasses.replace(_single(label, scores[label] - gains.get(label, 0.0), False), n_evaluations=7)

    monkeypatch.setattr(loop, "search_option", fake_search)
    fits = [_single(lab, s, lab.startswith("p")) for lab, s in scores.items()]
    specs = {lab: CandidateSpec(lab) for lab in scores}
    loop.polish_contenders(None, fits, specs, {}, None, None, None, lambda *_: None)
    return polished, fits


def test_only_the_singles_that_can_still_decide_are_polished(monkeypatch):
    """PAIR_FROM = 3 singles decide (the pairs' members; the options are ranked among the best). Pending singles
    (upper bounds of their optima) are polished best first while within the largest gain any polish made of the
    third best score: here the first polish gains 50, so the bound is -600 + 50 = -550 and the pending single at
    -500 keeps its refinement's optimum, still marked; with a first gain of 150 it is polished too."""
    assert loop.PAIR_FROM == 3
    scores = {"conv": -1000.0, "p1": -800.0, "p2": -600.0, "p3": -500.0, "p4": -300.0, "conv2": 5.0}
    polished, fits = _run(scores, {"p1": 50.0, "p2": 10.0}, monkeypatch)
    assert polished == ["p1", "p2"]
    by = {f.effect: f for f in fits}
    assert by["p1"].delta_bic == -850.0 and not by["p1"].polish_pending
    assert by["p1"].n_evaluations == 17  # the search's and the polish's evaluations
    assert by["p3"].polish_pending and by["p4"].polish_pending
    assert loop._option_row(by["p3"], 0.02)["polish"].startswith("deferred")
    assert "polish" not in loop._option_row(by["p1"], 0.02)
    polished, _ = _run(scores, {"p1": 150.0, "p2": 10.0}, monkeypatch)
    assert polished == ["p1", "p2", "p3"]


def test_a_polish_that_does_not_gain_keeps_the_search_optimum(monkeypatch):
    """A polish that does not improve leaves the fit as it was, no longer pending; with fewer singles than PAIR_FROM
    every pending one is polished."""
    polished, fits = _run({"p1": -40.0, "p2": -30.0}, {}, monkeypatch)
    assert polished == ["p1", "p2"]
    assert [(f.delta_bic, f.polish_pending, f.n_evaluations) for f in fits] == [(-40.0, False, 10), (-30.0, False, 10)]


def test_a_later_screen_on_the_two_state_model_alone_starts_at_the_first_rounds_screen():
    """With the two-state model alone selected, a later round screens each candidate at the first round's two-state
    screen's best point and its optimum of the round before (points only); with any other selection on its whole grid,
    the earlier optimum among the grid's points."""
    ts, friction = CandidateSpec("two_state"), CandidateSpec("friction")
    screen = {"friction": {"coulomb_N": 40.0}}
    earlier = {"friction": {"coulomb_N": 55.0}}
    spec, only = loop.screen_spec(friction, earlier, screen, [ts])
    assert only and spec.points == ({"coulomb_N": 40.0}, {"coulomb_N": 55.0})
    spec, only = loop.screen_spec(friction, earlier, screen, [ts, CandidateSpec("series_compliance")])
    assert not only and spec.points == ({"coulomb_N": 55.0},)
    spec, only = loop.screen_spec(friction, {}, {}, [ts])
    assert not only and spec is friction


def test_a_grid_of_points_only_evaluates_those_points():
    """``points_only``: the grid stage evaluates the spec's points and nothing else, and the screen's point is the
    best of them."""
    eng = _RoughEngine()
    spec = dataclasses.replace(CandidateSpec("command_displacement"),
                               points=({"bandwidth_Hz": 2.0, "damping_ratio": 0.5},
                                       {"bandwidth_Hz": 8.0, "damping_ratio": 1.5}))
    fit = fit_joint(eng, [spec], {}, {}, np.array([400.0]), np.array([400.0]), lambda e: None, lambda e: e,
                    grid_only=True, points_only=True)
    assert fit.cost["grid"]["evaluations"] == 2
    assert fit.effects["command_displacement"] == {"bandwidth_Hz": 2.0, "damping_ratio": 0.5}
    full = fit_joint(eng, [spec], {}, {}, np.array([400.0]), np.array([400.0]), lambda e: None, lambda e: e,
                     grid_only=True)
    assert full.cost["grid"]["evaluations"] > 10
