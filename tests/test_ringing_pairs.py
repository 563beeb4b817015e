"""The two-state model's pairs with ringing library effects, started at the residual's spectral peaks
(:func:`bayesdamper.diagnosis.two_state_pairs.ringing_pairs`)."""

from types import SimpleNamespace

import numpy as np
import pytest

import bayesdamper.diagnosis.two_state_pairs as tsp
from bayesdamper.diagnosis.candidates import CandidateSpec
from bayesdamper.run.progress import Progress


def test_the_ringing_parameters_are_a_frequency_and_a_damping_ratio_both_free():
    assert tsp.ringing_params(CandidateSpec("poppet_valve")) == ("natural_frequency_Hz", "damping_ratio")
    assert tsp.ringing_params(CandidateSpec("command_displacement")) == ("bandwidth_Hz", "damping_ratio")
    for name in ("series_compliance", "friction", "actuator_lag", "two_state"):
        assert tsp.ringing_params(CandidateSpec(name)) is None


class _Engine:
    """Windows of 3 s at 250 Hz; what the two-state model leaves is a 2.5 Hz ring at ζ 0.3 on each."""

    def __init__(self, screen):
        t = np.arange(0.0, 3.0, 1.0 / 250.0)
        self.problems = [SimpleNamespace(time=t + 10.0 * k) for k in range(4)]
        self.n = 4
        self.screen = screen
        self.calls = []

    def evaluate(self, eff, flow, idx=None, **k):
        self.calls.append((list(idx), flow))
        resid = []
        for i in idx:
            t = self.problems[i].time - self.problems[i].time[0]
            w = 2 * np.pi * 2.5
            r = np.exp(-0.3 * w * t) * np.sin(w * np.sqrt(1 - 0.09) * t)
            resid.append(r)
        return np.zeros(len(idx)), [None] * len(idx), resid


@pytest.mark.parametrize("screen", [np.array([1, 3]), None])
def test_the_residual_peaks_are_read_on_the_screening_windows(screen):
    """One evaluation of the two-state model held at its values, on the screening windows (every window without
    them); the strongest peak is the ring's frequency and damping ratio within the periodogram's resolution
    (a 3-s Hann window: ±0.5 Hz, and the half-power width of a ζ 0.3 ring widened by the window's own)."""
    engine = _Engine(screen)
    held = {"polytropic_exponent": 1.2}
    peaks = tsp.residual_peaks(engine, held, lambda e: ("flow", e["two_state"]["polytropic_exponent"]))
    assert engine.calls == [([1, 3] if screen is not None else [0, 1, 2, 3], ("flow", 1.2))]
    f, z = peaks[0]
    assert abs(f - 2.5) < 0.5 and 0.15 < z < 0.6, peaks


def test_no_peak_where_the_flow_of_the_held_model_is_infeasible():
    from bayesdamper.core.errors import BayesDamperError

    def flow_for(e):
        raise BayesDamperError("infeasible")

    assert tsp.residual_peaks(_Engine(None), {}, flow_for) == []


def test_a_ringing_library_effect_left_unpaired_is_paired_from_each_peak(monkeypatch):
    """The valve's screen ranks behind three one-parameter effects (PAIR_FROM 3): the ranked pairs leave it out. It
    is paired from the pair's own starts (its screen points on the two-state model as fitted alone and refilling) and
    from every spectral peak, its other parameters at its screen point on the model as fitted alone; each start is
    refined for GLOBAL_LM_ITER iterations and the best continued to the budget; the pair is an option and the valve
    counts as paired. The servo (ringing, but ranked among the pairs) and the generic ringing filter are not fitted
    again; a non-ringing effect left out is not fitted from the peaks."""
    generic = "unnamed_dynamics@flow"
    names = ("two_state", "backlash", "actuator_lag", "series_compliance", "command_displacement", "poppet_valve",
             "friction", generic)
    specs = {n: CandidateSpec(n) for n in names}
    screen = {"backlash": -3163.0, "actuator_lag": -3160.0, "command_displacement": -3158.0,
              "series_compliance": -3150.0, "poppet_valve": -3137.0, "friction": -3100.0, generic: -3000.0}
    point = {"natural_frequency_Hz": 2.05, "damping_ratio": 1.74, "cracking_pressure_Pa": 1.1e4, "span_Pa": 3e7,
             "bleed_fraction": 0.1}
    refined, continued = [], []

    def fake_fit(engine, cands, start, fixed, *a, grid_only=False, max_iter=None, **k):
        label, eff = cands[-1].label, cands[-1].effect
        if grid_only:
            return SimpleNamespace(labels=(label,), delta_bic=screen[label],
                                   effects={eff: dict(point) if eff == "poppet_valve" else {}}, effect=label)
        if label != "poppet_valve":
            return SimpleNamespace(labels=("two_state", label), delta_bic=-3170.0,
                                   effects={"two_state": {}, eff: {}}, effect=f"two_state+{label}")
        v = start[label]
        if max_iter == tsp.LM_ITER - tsp.GLOBAL_LM_ITER:
            continued.append((start["two_state"], v))
            score = -3300.0
        else:
            assert max_iter == tsp.GLOBAL_LM_ITER
            refined.append((start["two_state"], v))
            score = -3250.0 if v["natural_frequency_Hz"] == 2.39 else -3120.0
        return SimpleNamespace(labels=("two_state", label), delta_bic=score,
                               effects={"two_state": dict(start["two_state"]), eff: dict(v)},
                               effect=f"two_state+{label}")

    monkeypatch.setattr(tsp, "fit_joint", fake_fit)
    monkeypatch.setattr(tsp, "PAIR_FROM", 3)
    peaks = [(7.1, 0.05), (2.39, 0.227)]
    monkeypatch.setattr(tsp, "residual_peaks", lambda engine, held, flow_for: peaks)
    held = {"polytropic_exponent": 1.19, "refill_conductance_m3_per_s_Pa": 2.1e-11}
    ts = SimpleNamespace(labels=("two_state",), delta_bic=-3159.0, effects={"two_state": held}, effect="two_state")
    out, screens = tsp.two_state_pairs(None, [ts], specs, list(specs), np.zeros(3), np.ones(3), None,
                                       Progress(False))
    # the ranked pairs (also the best physical screens), then the valve from the peaks; the servo once, by its rank
    assert [o.labels[1] for o in out] == ["backlash", "actuator_lag", "command_displacement", "poppet_valve"]
    refilling = {**held, tsp.REFILL: tsp.REFILL_START}
    assert refined == [(held, point), (refilling, point)] + [
        (held, {**point, "natural_frequency_Hz": f, "damping_ratio": z}) for f, z in peaks]
    assert continued == [(held, {**point, "natural_frequency_Hz": 2.39, "damping_ratio": 0.227})]
    valve = next(o for o in out if o.labels[1] == "poppet_valve")
    assert valve.delta_bic == -3300.0 and "poppet_valve" in screens.paired


def test_without_a_peak_or_a_ringing_candidate_nothing_is_fitted(monkeypatch):
    """No spectral peak: the ringing effect left out is not fitted from it; no ringing candidate left: the residual
    is not evaluated at all (the engine is not touched)."""
    specs = {n: CandidateSpec(n) for n in ("two_state", "poppet_valve", "friction")}
    screens = tsp.TwoStateScreens(SimpleNamespace(labels=("two_state",)), {}, [],
                                  {"poppet_valve": {}, "friction": {}}, {})
    monkeypatch.setattr(tsp, "residual_peaks", lambda *a: [])
    monkeypatch.setattr(tsp, "fit_joint", lambda *a, **k: pytest.fail("no fit without a start"))
    assert tsp.ringing_pairs(None, screens, [], specs, np.zeros(3), np.ones(3), None, Progress(False)) == []
    assert screens.paired == set()
    screens.paired.add("poppet_valve")
    monkeypatch.setattr(tsp, "residual_peaks", lambda *a: pytest.fail("no evaluation without a ringing candidate"))
    assert tsp.ringing_pairs(None, screens, [], specs, np.zeros(3), np.ones(3), None, Progress(False)) == []
