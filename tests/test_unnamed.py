"""Candidates of the generic effect from part 1's signature: structure and search boxes."""

import math

import pytest

from bayesdamper.diagnosis.unnamed import effect_reading, unnamed_candidates
from bayesdamper.physics.effects import EFFECTS

#: A signature as diagnose stores it (rig-A's: a 1.76 Hz pair and two real poles, Δp through a dead zone).
SIGNATURE = {"verdict": "dynamics", "fit": {
    "driver": "dp", "law": "deadzone", "threshold": 3.4e5, "eps": None, "dc_gain": -3.6e-5,
    "poles": [{"kind": "oscillatory", "frequency_hz": 1.76, "damping": 0.14},
              {"kind": "real", "time_constant_s": 0.66}, {"kind": "real", "time_constant_s": 0.035}]}}


def test_candidates_take_the_oscillatory_pair_and_the_structure():
    specs = unnamed_candidates(SIGNATURE, 4.2e-3, 5e-12, 2e-3)
    assert {s.label for s in specs} == {"unnamed_dynamics@force:low-pass", "unnamed_dynamics@force:transient",
                                        "unnamed_dynamics@flow:low-pass", "unnamed_dynamics@flow:transient"}
    for s in specs:
        f = s.overrides["natural_frequency_Hz"]
        z = s.overrides["damping_ratio"]
        assert f.lower == pytest.approx(0.88) and f.upper == pytest.approx(3.52)
        assert z.lower == pytest.approx(0.035) and z.upper == pytest.approx(0.56)
        assert s.extra["driver"] == 0.0 and s.extra["law"] == 2.0 and s.extra["threshold"] == 3.4e5
        EFFECTS["unnamed_dynamics"].complete(s.extra)  # admissible structure values
    low = next(s for s in specs if s.label == "unnamed_dynamics@force:low-pass").overrides["gain"]
    assert low.sign == -1.0 and low.log and math.isclose(low.lower, -3.6e-5 / 30)
    tr = next(s for s in specs if s.label == "unnamed_dynamics@force:transient").overrides["gain"]
    assert not tr.log and tr.lower == -tr.upper == pytest.approx(-30 * 2e-3)
    flow = next(s for s in specs if s.label == "unnamed_dynamics@flow:low-pass").overrides["gain"]
    assert flow.sign == 1.0  # -A ΔQ / slope = ΔF: a negative force gain is a positive flow gain


def test_real_poles_make_an_overdamped_pair_and_none_gives_nothing():
    sig = {"verdict": "dynamics", "fit": {**SIGNATURE["fit"], "poles": [{"kind": "real", "time_constant_s": 0.5},
                                                                       {"kind": "real", "time_constant_s": 0.02}]}}
    spec = unnamed_candidates(sig, 4.2e-3, 5e-12, 2e-3)[0]
    f = math.sqrt(spec.overrides["natural_frequency_Hz"].lower * spec.overrides["natural_frequency_Hz"].upper)
    assert f == pytest.approx(1 / (2 * math.pi * math.sqrt(0.5 * 0.02)))
    assert unnamed_candidates({"verdict": "none", "fit": None}, 4.2e-3, 5e-12, 2e-3) == []
    assert unnamed_candidates({"verdict": "dynamics", "fit": {**SIGNATURE["fit"], "driver": "tau"}}, 4.2e-3, 5e-12,
                              2e-3) == []


def test_reading_names_frequency_damping_driver_and_placement():
    text = effect_reading("unnamed_dynamics@force:transient",
                          {"natural_frequency_Hz": 1.7, "damping_ratio": 0.25, "driver": 0, "law": 2, "placement": 0,
                           "mode": 1}, "")
    assert text == ("unnamed dynamics: 1.70 Hz, damping 0.25, driven by Δp (dead zone), acting on the force "
                    "(transient)")
    assert effect_reading("friction", {}, "seal friction") == "seal friction"


def test_signature_starts_and_library_candidates_map_time_scales_by_unit():
    from bayesdamper.diagnosis.unnamed import library_candidates, signature_starts

    sig = {"verdict": "dynamics", "fit": {"poles": [{"kind": "oscillatory", "frequency_hz": 2.9, "damping": 0.2},
                                                    {"kind": "real", "time_constant_s": 0.05}]}}
    st = signature_starts(sig)
    assert st["Hz"] == pytest.approx([2.9, 1 / (2 * math.pi * 0.05)])
    assert st["damping"] == [0.2] and st["s"] == pytest.approx([1 / (2 * math.pi * 2.9), 0.05])
    specs = {c.label: c for c in library_candidates(["poppet_valve", "valve_dynamics", "friction"], sig)}
    assert specs["poppet_valve"].starts == {"natural_frequency_Hz": tuple(st["Hz"]), "damping_ratio": (0.2,)}
    assert specs["valve_dynamics"].starts == {"time_constant_s": tuple(st["s"])}
    assert specs["friction"].starts == {}
    assert signature_starts({"verdict": "none", "fit": sig["fit"]}) == {}


def test_search_starts_find_a_narrow_optimum_the_coarse_grid_misses():
    """A profile with a narrow well at 3 Hz between the grid's frequencies (0.2, 6.3, 200 Hz on poppet_valve's
    log axis): the grid and the local search alone stay on the plateau; started at part 1's 2.9 Hz they find it."""
    import numpy as np
    from profile_fakes import FakeProfileEngine, fake_problem

    from bayesdamper.diagnosis.candidates import CandidateSpec, fit_joint

    class Engine(FakeProfileEngine):
        problems = [fake_problem(np.ones(50))]

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            p = eff["poppet_valve"]
            well = math.exp(-((math.log(p["natural_frequency_Hz"] / 3.0)) / 0.08) ** 2)
            sse = 50.0 * (1.0 - 0.9 * well) * (1.0 + 0.01 * math.log(p["span_Pa"] / 3e7) ** 2)
            return np.array([sse]), np.zeros((1, 2)), [np.full(50, math.sqrt(sse / 50.0))]

    def fit(starts):
        return fit_joint(Engine(), [CandidateSpec("poppet_valve", starts=starts)], {}, {}, np.array([50.0]),
                         np.array([50.0]), lambda e: None, lambda e: e)

    plain = fit({})
    started = fit({"natural_frequency_Hz": (2.9,), "damping_ratio": (0.2,)})
    assert started.j_pooled < 0.5 and plain.j_pooled > 0.9
    assert started.effects["poppet_valve"]["natural_frequency_Hz"] == pytest.approx(3.0, rel=0.05)


def test_a_screen_grid_holds_the_candidates_optimum_of_the_round_before():
    """A later round screens a candidate by its grid alone: with the well at 3 Hz between the grid's frequencies the
    screen stays on the plateau, and with its earlier optimum as a point of the grid (CandidateSpec.points) it
    scores there. A point without a value for a grid axis is not a point."""
    import numpy as np
    from profile_fakes import FakeProfileEngine, fake_problem

    from bayesdamper.diagnosis.candidates import CandidateSpec, fit_joint

    class Engine(FakeProfileEngine):
        problems = [fake_problem(np.ones(50))]

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            p = eff["poppet_valve"]
            well = math.exp(-((math.log(p["natural_frequency_Hz"] / 3.0)) / 0.08) ** 2)
            sse = 50.0 * (1.0 - 0.9 * well)
            return np.array([sse]), np.zeros((1, 2)), [np.full(50, math.sqrt(sse / 50.0))]

    def screen(points):
        return fit_joint(Engine(), [CandidateSpec("poppet_valve", points=points)], {}, {}, np.array([50.0]),
                         np.array([50.0]), lambda e: None, lambda e: e, grid_only=True)

    earlier = {**EFFECTS["poppet_valve"].defaults(), "natural_frequency_Hz": 3.0}
    assert screen(()).j_pooled > 0.9
    held = screen((earlier,))
    assert held.j_pooled == pytest.approx(math.sqrt(0.1), rel=1e-6)
    assert held.effects["poppet_valve"]["natural_frequency_Hz"] == pytest.approx(3.0)
    partial = {k: v for k, v in earlier.items() if k != "damping_ratio"}
    assert screen((partial,)).j_pooled > 0.9


def test_stage_one_offset_starts_the_load_cell_offset_between_its_grid_points():
    """An offset of 180 N (a profile well 180 N wide, the current model at no offset) lies between the six grid points
    of load_cell_offset's ±5 kN range: the grid alone, as a later round's screen uses it, leaves the candidate no better
    than the current model; started at stage 1's estimate it reaches the well. No other effect takes the start."""
    import numpy as np
    from profile_fakes import FakeProfileEngine, fake_problem

    from bayesdamper.diagnosis.candidates import fit_joint
    from bayesdamper.diagnosis.unnamed import library_candidates

    class Engine(FakeProfileEngine):
        problems = [fake_problem(np.ones(50))]

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            off = eff["load_cell_offset"]["offset_N"]
            sse = 10.0 + 40.0 * min(1.0, ((off - 180.0) / 180.0) ** 2)
            return np.array([sse]), np.zeros((1, 2)), [np.full(50, math.sqrt(sse / 50.0))]

    def screen(offset):
        spec = {c.label: c for c in library_candidates(["load_cell_offset", "friction"], {}, offset)}
        assert spec["friction"].starts == {}
        return fit_joint(Engine(), [spec["load_cell_offset"]], {}, {}, np.array([50.0]), np.array([50.0]),
                         lambda e: None, lambda e: e, grid_only=True)

    assert screen(None).j_pooled == pytest.approx(1.0)
    started = screen(181.0)
    assert started.effects["load_cell_offset"]["offset_N"] == pytest.approx(181.0)
    assert started.j_pooled == pytest.approx(math.sqrt((10.0 + 40.0 / 180.0 ** 2) / 50.0))


def test_flow_path_candidates_for_the_other_model_drivers():
    """Part 1 chose Δp (dead zone): one more flow-path transient candidate driven by Q_O (linear law) with the
    same poles; part 1's own driver gets no duplicate, and a bad scale gives none."""
    specs = unnamed_candidates(SIGNATURE, 4.2e-3, 5e-12, 2e-3, {"dp": 1e-3, "q": 4e8, "y": 1e6})
    extra = [s for s in specs if s.label.count(":") == 2]
    assert [s.label for s in extra] == ["unnamed_dynamics@flow:transient:q"]
    s = extra[0]
    assert s.extra == {"driver": 1.0, "law": 0.0, "threshold": 0.0, "placement": 1.0, "mode": 1.0}
    assert s.overrides["gain"].upper == pytest.approx(30 * 4e8 * 5e-12 / 4.2e-3)
    assert s.overrides["natural_frequency_Hz"].lower == pytest.approx(0.88)
    EFFECTS["unnamed_dynamics"].complete(s.extra)
    assert len(unnamed_candidates(SIGNATURE, 4.2e-3, 5e-12, 2e-3, {"q": math.nan})) == 4
