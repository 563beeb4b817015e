"""The profile search's global stage, its bound findings and the per-speed J before and after (fast, seeded).

The global stage (:func:`bayesdamper.diagnosis.candidates.global_starts`) starts narrow-basin parameters from the
signature's poles and from the data; a parameter that ends on a bound of its search is a finding, not a result; and
every test speed whose J got worse after the effects were added is said (:mod:`bayesdamper.diagnosis.summary`).
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from profile_fakes import FakeProfileEngine, fake_problem

import bayesdamper.diagnosis.candidates as cand
from bayesdamper.diagnosis.candidates import (
    CandidateSpec,
    SearchParam,
    bound_flags,
    fit_joint,
    global_starts,
    narrow_kind,
    search_params,
    spec_bound_flags,
    spectral_peaks,
)
from bayesdamper.diagnosis.summary import annotate_bounds, bound_findings, findings_text, j_by_speed

# ----------------------------------------------------------------------------------------------- narrow parameters


def test_narrow_kinds_from_names_and_units():
    assert narrow_kind("poppet_valve", "natural_frequency_Hz") == "frequency"
    assert narrow_kind("poppet_valve", "damping_ratio") == "damping"
    assert narrow_kind("poppet_valve", "cracking_pressure_Pa") == "threshold"
    assert narrow_kind("poppet_valve", "span_Pa") == "span"
    assert narrow_kind("poppet_valve", "bleed_fraction") == "bleed"
    assert narrow_kind("valve_dynamics", "opening_pressure_Pa") == "threshold"
    assert narrow_kind("command_displacement", "bandwidth_Hz") == "frequency"
    assert narrow_kind("valve_dynamics", "time_constant_s") is None
    assert narrow_kind("accumulator", "charge_pressure_Pa") is None  # a pressure, but no threshold
    assert narrow_kind("friction", "coulomb_N") is None


# --------------------------------------------------------------------------------------------------- bound flags


def test_bound_flags_in_search_coordinates():
    """Log parameters are judged on the log of their range: within 1 % of it from a bound is on the bound."""
    poppet = CandidateSpec("poppet_valve")
    flags = spec_bound_flags(poppet, {"natural_frequency_Hz": 3.31, "damping_ratio": 3.0,
                                      "cracking_pressure_Pa": 1.05e3, "span_Pa": 1.0e8})
    assert [(f["param"], f["side"]) for f in flags] == [("damping_ratio", "upper"), ("cracking_pressure_Pa", "lower"),
                                                         ("span_Pa", "upper")]
    assert flags[0]["value"] == pytest.approx(3.0) and flags[0]["bound"] == pytest.approx(3.0)
    assert flags[1]["bound"] == pytest.approx(1.0e3)
    # 1.1 kPa is 1.2 % of the log range above 1 kPa: inside; a damping ratio of 2.8 (1.4 % below 3) too, 2.9 not
    assert spec_bound_flags(poppet, {"natural_frequency_Hz": 3.31, "damping_ratio": 2.8,
                                     "cracking_pressure_Pa": 1.1e3, "span_Pa": 3.0e7}) == []
    # a linear signed parameter, and a negative one searched on the log of its magnitude: the side is physical
    lin = SearchParam("gain", -2.0, 2.0, False)
    neg = SearchParam("gain", -1e-3, -1e-6, True, -1.0)
    z = np.array([1.97, math.log(0.99e-3)])
    lo = np.array([-2.0, math.log(1e-6)])
    hi = np.array([2.0, math.log(1e-3)])
    out = bound_flags([("a", lin), ("b", neg)], z, lo, hi)
    assert [(f["param"], f["side"]) for f in out] == [("a", "upper"), ("b", "lower")]
    assert out[1]["bound"] == pytest.approx(-1e-3)


def test_bound_flag_on_a_constructed_fit():
    """A fit whose optimum lies beyond the search box ends on the bound, and says so (``at_bound``)."""

    class Engine(FakeProfileEngine):
        problems = [fake_problem(np.ones(40))]

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            tau = eff["actuator_lag"]["time_constant_s"]  # SSE falls towards a time constant beyond the 0.5 s bound
            sse = 40.0 * (0.2 + 0.8 / (1.0 + tau))
            return np.array([sse]), np.zeros((1, 2)), [np.full(40, math.sqrt(sse / 40.0))]

    fit = fit_joint(Engine(), [CandidateSpec("actuator_lag")], {}, {}, np.array([40.0]), np.array([40.0]),
                    lambda e: None, lambda e: e)
    assert fit.at_bound == [{"param": "time_constant_s", "value": pytest.approx(0.5), "bound": pytest.approx(0.5),
                             "side": "upper"}]
    assert set(fit.cost) >= {"grid", "refine", "intervals"}

    class GasEngine(FakeProfileEngine):
        problems = [fake_problem(np.ones(40))]

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            p = eff["two_state"]  # SSE falls towards an isothermal gas (κ 1, a physical limit) and towards G 1e-15
            sse = 40.0 * (0.2 + (p["polytropic_exponent"] - 0.9) ** 2 + 0.01 * math.log(p[
                "refill_conductance_m3_per_s_Pa"] / 1e-16))
            return np.array([sse]), np.zeros((1, 2)), [np.full(40, math.sqrt(sse / 40.0))]

    gas = fit_joint(GasEngine(), [CandidateSpec("two_state")], {}, {}, np.array([40.0]), np.array([40.0]),
                    lambda e: None, lambda e: e)
    assert gas.effects["two_state"]["polytropic_exponent"] == pytest.approx(1.0)
    assert [f["param"] for f in gas.at_bound] == ["refill_conductance_m3_per_s_Pa"]


def test_findings_of_the_selected_effects_and_the_candidate_rows():
    names = [CandidateSpec("poppet_valve"), "friction",
             CandidateSpec("unnamed_dynamics@flow:transient", {"gain": SearchParam("gain", -0.8, 0.8, False)})]
    fixed = {"poppet_valve": {"natural_frequency_Hz": 3.31, "damping_ratio": 3.0, "cracking_pressure_Pa": 3.5e4,
                              "span_Pa": 1.0e8},
             "unnamed_dynamics": {"gain": 0.79, "natural_frequency_Hz": 1.86, "damping_ratio": 0.44, "driver": 1.0}}
    found = bound_findings(["poppet_valve", "unnamed_dynamics@flow:transient"], fixed, names)
    assert [(f["effect"], f["param"]) for f in found] == [
        ("poppet_valve", "damping_ratio"), ("poppet_valve", "span_Pa"), ("unnamed_dynamics@flow:transient", "gain")]
    assert found[0]["text"] == ("poppet_valve: damping_ratio ends on its upper bound (3): the form does not fit these "
                                "data as parametrised; its value is not a result")
    assert found[2]["text"].startswith("unnamed_dynamics@flow:transient: gain ends on its upper bound (0.79)")
    # a bound that is a physical limit (an isothermal gas) is a result, not a finding; the other parameter is judged
    gas = {"two_state": {"polytropic_exponent": 1.0, "refill_conductance_m3_per_s_Pa": 1e-15}}
    assert [f["param"] for f in bound_findings(["two_state"], gas, ["two_state"])] == [
        "refill_conductance_m3_per_s_Pa"]
    lines = findings_text({"findings": found, "selected": [], "J_by_speed": []})
    assert lines == [f["text"] + "." for f in found]
    # the candidate rows: single fits keyed by the parameter, joint fits by label.parameter
    rounds = [{"candidates": [
        {"effect": "poppet_valve", "params": {k: {"median": v} for k, v in fixed["poppet_valve"].items()}},
        {"effect": "friction", "params": {"coulomb_N": {"median": 120.0}}},
        {"effect": "unnamed_dynamics@flow:transient", "params": {
            "poppet_valve.damping_ratio": {"median": 0.5}, "poppet_valve.span_Pa": {"median": 1.0e5},
            "unnamed_dynamics@flow:transient.gain": {"median": -0.2}}}]}]
    annotate_bounds(rounds, names)
    rows = rounds[0]["candidates"]
    assert [f["param"] for f in rows[0]["at_bound"]] == ["damping_ratio", "span_Pa"]
    assert rows[1]["at_bound"] == []
    assert [(f["param"], f["side"]) for f in rows[2]["at_bound"]] == [("poppet_valve.span_Pa", "lower")]


class _BoundsEngine(FakeProfileEngine):
    """One window of 2000 samples whose poppet-valve SSE does not change with the cracking pressure below 10 kPa
    (flat down to the bound, 1 kPa) and grows by 1 % per unit of log span below its upper bound (100 MPa), and above
    it falls on as much (``saturates``: stays); the residual is white, so N_eff is about the window's length."""

    problems = [fake_problem(np.ones(2000))]
    noise = np.random.default_rng(7).standard_normal(2000)

    def __init__(self, saturates=False):
        self.calls, self.saturates = [], saturates

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        self.calls.append(keep)
        p = eff["poppet_valve"]
        span = math.log(1e8 / p["span_Pa"])
        sse = 2000.0 * (1.0 + 0.01 * max(0.0, math.log(p["cracking_pressure_Pa"] / 1e4))
                        + 0.01 * (max(span, 0.0) if self.saturates else span))
        return np.array([sse]), np.zeros((1, 2)), [self.noise * math.sqrt(sse / 2000.0)]


def test_a_parameter_on_a_bound_is_unresolved_one_sided_or_a_misfit_by_its_profile_there():
    """:func:`bound_resolution` moves each bound parameter a tenth of its range inside and as far past the bound.
    The cracking pressure's fit does not change inside (deviance 0: unresolved). The span's gets worse inside
    (N_eff x 1 % x 0.69 = 13.8, above 2.71) and better past the bound (the form misfits), or, where the fit saturates
    past the bound, no better there (a one-sided bound). The findings say so; no model is made current."""
    from bayesdamper.diagnosis.findings import FLAT_DEVIANCE, bound_resolution
    from bayesdamper.diagnosis.global_stage import GLOBAL_DISTINCT

    fixed = {"poppet_valve": {"natural_frequency_Hz": 2.0, "damping_ratio": 0.5, "cracking_pressure_Pa": 1.0e3,
                              "span_Pa": 1.0e8, "bleed_fraction": 0.5}}
    n_eff = float(cand.effective_sizes([_BoundsEngine.noise])[0])
    step = math.log1p(0.01 * GLOBAL_DISTINCT * math.log(1000.0))
    for saturates in (False, True):
        engine = _BoundsEngine(saturates)
        checks = bound_resolution(engine, ["poppet_valve"], fixed, ["poppet_valve"], lambda e: None, lambda e: e)
        assert engine.calls and not any(engine.calls)
        by = {c["param"]: c for c in checks}
        assert set(by) == {"cracking_pressure_Pa", "span_Pa"}
        pc, span = by["cracking_pressure_Pa"], by["span_Pa"]
        assert pc["inside"] == pytest.approx(1e3 * 3000.0 ** GLOBAL_DISTINCT)  # a tenth of the log range up
        assert pc["past"] == pytest.approx(1e3 / 3000.0 ** GLOBAL_DISTINCT)
        assert pc["delta_deviance"] == pytest.approx(0.0, abs=1e-9) and pc["verdict"] == "unresolved"
        assert span["inside"] == pytest.approx(1e8 / 1000.0 ** GLOBAL_DISTINCT)
        assert span["delta_deviance"] == pytest.approx(n_eff * step, rel=1e-6)
        assert span["delta_deviance"] > FLAT_DEVIANCE
        past = 0.0 if saturates else n_eff * math.log1p(-0.01 * GLOBAL_DISTINCT * math.log(1000.0))
        assert span["delta_deviance_past"] == pytest.approx(past, rel=1e-6, abs=1e-9)
        assert span["verdict"] == ("one-sided" if saturates else "misfit")
        found = {f["param"]: f for f in bound_findings(["poppet_valve"], fixed, ["poppet_valve"], checks)}
        assert found["cracking_pressure_Pa"]["text"].startswith(
            f"poppet_valve: cracking_pressure_Pa ends on its lower bound (1000), and the fit is the same at "
            f"{pc['inside']:.4g} (deviance +0.00, within the 90 % level 2.71)")
        assert found["cracking_pressure_Pa"]["text"].endswith("read it as a one-sided bound, not a value")
        assert found["span_Pa"]["resolution"]["verdict"] == span["verdict"]
        if saturates:
            assert found["span_Pa"]["text"].endswith(f"the data bound it on one side only; read it as at least "
                                                     f"{span['inside']:.4g}, not a value")
        else:
            assert found["span_Pa"]["text"].endswith("the form does not fit these data as parametrised; its value "
                                                     "is not a result")
    # a check of another value (another fit) does not apply
    moved = {"poppet_valve": dict(fixed["poppet_valve"], cracking_pressure_Pa=1.001e3)}
    again = {f["param"]: f for f in bound_findings(["poppet_valve"], moved, ["poppet_valve"], checks)}
    assert "resolution" not in again["cracking_pressure_Pa"] and "resolution" in again["span_Pa"]
    assert again["cracking_pressure_Pa"]["text"].endswith("its value is not a result")


# ------------------------------------------------------------------------------------------ J per speed and kind


def _window(test, v, kind, n=200, seed=0):
    rng = np.random.default_rng(seed)
    return SimpleNamespace(test=test, velocity=v, kind=kind, force=1000.0 + rng.normal(0.0, 50.0, n))


def test_j_per_speed_and_kind_and_which_got_worse():
    """Three tests (0.5, 1.0, 1.5 mm/s), a start from rest and a reversal each; residuals built so that 0.5 mm/s
    gets worse, 1.0 mm/s better, and at 1.5 mm/s only the reversal is worse (the speed as a whole better)."""
    wins, before, after = [], [], []
    scale = {(0.5, "initial"): (0.02, 0.03), (0.5, "reversal"): (0.02, 0.025), (1.0, "initial"): (0.04, 0.01),
             (1.0, "reversal"): (0.04, 0.02), (1.5, "initial"): (0.08, 0.01), (1.5, "reversal"): (0.01, 0.012)}
    for k, ((v, kind), (jb, ja)) in enumerate(scale.items()):
        w = _window(f"tri_{v}", (-1) ** k * v * 1e-3 * (1.0 + 0.01 * k), kind, seed=k)
        shape = np.sin(np.linspace(0.0, 9.0, w.force.size))
        unit = shape * np.linalg.norm(w.force) / np.linalg.norm(shape)
        wins.append(w)
        before.append(jb * unit)
        after.append(ja * unit)
    rows = j_by_speed(wins, before, after)
    by = {(r["speed_mm_s"], r["kind"]): r for r in rows}
    assert len(rows) == 9 and all(r["n_windows"] == (2 if r["kind"] == "all" else 1) for r in rows)
    # the test speed is the median |v| of the record's windows (1 % apart here), not each window's own
    assert sorted({r["speed_mm_s"] for r in rows}) == pytest.approx([0.5025, 1.025, 1.5675])
    s05, s10, s15 = sorted({r["speed_mm_s"] for r in rows})
    assert by[(s05, "initial")]["J_before"] == pytest.approx(0.02) and by[(s05, "initial")]["J_after"] == \
        pytest.approx(0.03)
    # pooled over the windows of a speed, weighted by their forces' energy (here nearly equal)
    f2 = [float(w.force @ w.force) for w in wins[:2]]
    want = math.sqrt((0.02 ** 2 * f2[0] + 0.02 ** 2 * f2[1]) / sum(f2))
    assert by[(s05, "all")]["J_before"] == pytest.approx(want)
    assert [(r["speed_mm_s"], r["kind"]) for r in rows if r["worse"]] == [(s05, "initial"), (s05, "reversal"),
                                                                          (s05, "all"), (s15, "reversal")]
    assert by[(s10, "all")]["change"] < 0 and not by[(s15, "all")]["worse"]
    # with the windows' entries: the same pooled at each window's least-squares optimum
    ls = j_by_speed(wins, before, after, [{"ls": {"J": jb}} for jb, _ in scale.values()],
                    [{"ls": {"J": 0.5 * ja}} for _, ja in scale.values()])
    r = next(r for r in ls if r["speed_mm_s"] == s10 and r["kind"] == "initial")
    assert (r["J_before_ls"], r["J_after_ls"]) == (pytest.approx(0.04), pytest.approx(0.005))
    assert "J_before_ls" not in rows[0]
    d = {"selected": ["poppet_valve"], "findings": [], "J_by_speed": rows}
    lines = findings_text(d)
    assert lines[0].startswith("J got worse after adding poppet_valve at 1 of 3 test speeds (at the posterior "
                               "medians): 0.50 mm/s (")
    assert lines[1].startswith("By kind of step, also worse: 1.57 mm/s (reversal) (0.0100 -> 0.0120)")
    # none worse: said so; no effect added: nothing on speeds
    better = j_by_speed(wins, before, [0.5 * r for r in before])
    assert not any(r["worse"] for r in better)
    text = findings_text({"selected": ["poppet_valve"], "J_by_speed": better})
    assert text[0].startswith("No test speed got worse after adding poppet_valve (J per speed at the posterior "
                              "medians, before -> after: 0.50 mm/s (0.0200 -> 0.0100)")
    same = j_by_speed(wins, before, before)
    assert not any(r["worse"] for r in same)
    assert findings_text({"selected": [], "J_by_speed": same}) == []


# -------------------------------------------------------------------------------------------------- global stage


class _WellEngine(FakeProfileEngine):
    """One window whose profile SSE (of the second-order servo's bandwidth f and damping ζ) has a broad, shallow
    basin at a grid point (50 Hz, ζ 0.95: SSE 10) and a narrow, deep well at (2 Hz, ζ 0.2: SSE 0.5), between the
    coarse grid's frequencies (0.5, 5, 50, 500 Hz)."""

    problems = [fake_problem(np.ones(50))]

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        p = eff["command_displacement"]
        f, z = p["bandwidth_Hz"], p["damping_ratio"]
        broad = math.exp(-math.log(f / 50.0) ** 2 - math.log(z / 0.95) ** 2)
        well = math.exp(-(math.log(f / 2.0) / 0.3) ** 2 - (math.log(z / 0.2) / 0.5) ** 2)
        sse = 50.0 * (1.0 - 0.8 * broad - 0.99 * well)
        return np.array([sse]), np.zeros((1, 2)), [np.full(50, math.sqrt(sse / 50.0))]


class _BleedEngine(FakeProfileEngine):
    """One window whose poppet SSE depends only on the bleed ε: a narrow well at ε = 1 (SSE 1) in a flat profile
    (SSE 40): the grid, which holds ε at its default 0.1, cannot see it; the global stage's bleed starts can."""

    problems = [fake_problem(np.ones(50))]

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        eps = eff["poppet_valve"]["bleed_fraction"]
        sse = 40.0 - 39.0 * math.exp(-(math.log(eps) / 0.3) ** 2)
        return np.array([sse]), np.zeros((1, 2)), [np.full(50, math.sqrt(sse / 50.0))]


def test_a_valves_bleed_is_held_on_the_grid_and_searched_by_the_global_stage():
    """The four other poppet parameters are gridded (3 points each: 81 and no more), the bleed held at its default;
    the global stage starts it at 0.1, 1 and 10 and the refinement ends in the well at 1."""
    evaluated = []

    class Counting(_BleedEngine):
        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            evaluated.append(eff["poppet_valve"]["bleed_fraction"])
            return super().evaluate(eff, flow, keep, idx)

    fit = fit_joint(Counting(), [CandidateSpec("poppet_valve")], {}, {}, np.array([50.0]), np.array([50.0]),
                    lambda e: None, lambda e: e)
    assert fit.cost["grid"]["evaluations"] == 81
    assert np.allclose(evaluated[:81], 0.1)
    assert fit.cost["global"]["starts"] == 3
    assert fit.effects["poppet_valve"]["bleed_fraction"] == pytest.approx(1.0, rel=0.05)
    assert fit.j_pooled < 0.2  # sqrt(1 / 50) at the well, against sqrt(40 / 50) on the grid


def test_a_screen_scores_the_global_stages_starts_like_its_grid_points():
    """A screen (``grid_only``) is the grid's best point, the bleed held at its default; with ``screen_global`` the
    global stage's starts are scored too and the screen's point is the best of both (the bleed's well at 1), with no
    refinement either way."""
    args = ({}, {}, np.array([50.0]), np.array([50.0]), lambda e: None, lambda e: e)
    plain = fit_joint(_BleedEngine(), [CandidateSpec("poppet_valve")], *args, grid_only=True)
    wide = fit_joint(_BleedEngine(), [CandidateSpec("poppet_valve")], *args, grid_only=True, screen_global=True)
    assert plain.effects["poppet_valve"]["bleed_fraction"] == pytest.approx(0.1)
    assert plain.j_pooled == pytest.approx(math.sqrt(40.0 / 50.0), rel=1e-6) and "global" not in plain.cost
    assert wide.effects["poppet_valve"]["bleed_fraction"] == pytest.approx(1.0)
    assert wide.j_pooled == pytest.approx(math.sqrt(1.0 / 50.0), rel=1e-6)
    assert wide.cost["global"]["starts"] == 3 and "refine" not in wide.cost and "refine" not in plain.cost


class _MountEngine(FakeProfileEngine):
    """One window whose SSE in a mount's stiffness k has a well at 2e7 N/m (SSE 1) a third of a decade wide, between
    the screen's grid points (1e6, 6.3e6, 4e7, 2.5e8, 1.6e9, 1e10 N/m: SSE 22 at 4e7, 35 at 6.3e6, 40 further), as a
    stiff mount's on the two-state model."""

    problems = [fake_problem(np.ones(50))]

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        k = eff["series_compliance"]["stiffness_N_per_m"]
        sse = 40.0 - 39.0 * math.exp(-(math.log(k / 2e7) / 0.8) ** 2)
        return np.array([sse]), np.zeros((1, 2)), [np.full(50, math.sqrt(sse / 50.0))]


def test_a_screen_of_one_parameter_looks_between_its_grid_points():
    """With ``screen_global`` a one-parameter screen runs Brent's method within its best grid point's bracket and
    finds the well between the points (within the 1 % of the range it is asked for); a plain screen keeps the grid's
    point, and neither refines with every window."""
    args = ({}, {}, np.array([50.0]), np.array([50.0]), lambda e: None, lambda e: e)
    plain = fit_joint(_MountEngine(), [CandidateSpec("series_compliance")], *args, grid_only=True)
    wide = fit_joint(_MountEngine(), [CandidateSpec("series_compliance")], *args, grid_only=True, screen_global=True)
    grid_k = math.exp(np.linspace(math.log(1e6), math.log(1e10), cand.GRID_POINTS)[2])
    assert plain.effects["series_compliance"]["stiffness_N_per_m"] == pytest.approx(grid_k)
    assert "global" not in plain.cost and "refine" not in plain.cost
    k = wide.effects["series_compliance"]["stiffness_N_per_m"]
    assert abs(math.log(k / 2e7)) < 0.01 * math.log(1e4) * 2  # Brent's xatol, 1 % of the log range, twice
    assert wide.j_pooled < 0.2 < plain.j_pooled
    assert wide.cost["global"]["starts"] == 1 and "refine" not in wide.cost


def _servo_fit(poles=()):
    return fit_joint(_WellEngine(), [CandidateSpec("command_displacement", poles=poles)], {}, {}, np.array([50.0]),
                     np.array([50.0]), lambda e: None, lambda e: e)


def test_global_stage_finds_the_narrow_well_a_single_start_misses(monkeypatch):
    """Started at the signature's pole (2.2 Hz, ζ 0.25: SSE 13, worse than the broad basin's grid point, SSE 10),
    the global stage refines both and keeps the well; the grid and one refinement end in the broad basin, and so
    does the global stage when it may refine one start only."""
    plain = _servo_fit()
    assert plain.j_pooled == pytest.approx(math.sqrt(10.0 / 50.0), rel=0.02)  # the broad basin: J 0.447
    found = _servo_fit(((2.2, 0.25),))
    assert found.j_pooled < 0.15  # the well: J 0.1 at the bottom
    v = found.effects["command_displacement"]
    assert v["bandwidth_Hz"] == pytest.approx(2.0, rel=0.05) and v["damping_ratio"] == pytest.approx(0.2, rel=0.1)
    assert found.cost["global"]["starts"] == 1 and found.cost["refine"]["starts"] == 2
    assert found.at_bound == []
    monkeypatch.setattr(cand, "GLOBAL_REFINE", 1)
    one = _servo_fit(((2.2, 0.25),))
    assert one.j_pooled == pytest.approx(math.sqrt(10.0 / 50.0), rel=0.02)


class _RoughWellEngine(_WellEngine):
    """The well of :class:`_WellEngine`, whose rough values (a re-fit not finished, ``rough``) are 1.5 times the
    exact ones (an upper bound, ordered as the exact ones), and whose fitted own parameters x are the point's own
    coordinates (log f, log ζ): which point a re-fit started from is read off its ``start``."""

    def __init__(self, honour_rough=True):
        self.honour_rough = honour_rough
        self.calls = []  # (z of the point, start given, rough) of the objective's evaluations
        self._differencing = False

    def sensitivities(self, base, effs, flows, hs, idx, xs, resid):
        self._differencing = True  # the stand-in's sensitivities evaluate too: not the objective's evaluations
        try:
            return super().sensitivities(base, effs, flows, hs, idx, xs, resid)
        finally:
            self._differencing = False

    def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
        sse, _, resid = super().evaluate(eff, flow, keep, idx)
        p = eff["command_displacement"]
        z = np.array([math.log(p["bandwidth_Hz"]), math.log(p["damping_ratio"])])
        if not self._differencing:
            self.calls.append((z, None if start is None else np.array(start[0]), rough))
        if rough and self.honour_rough:
            sse, resid = 1.5 * sse, [math.sqrt(1.5) * r for r in resid]
        return sse, np.array([z]), resid


@pytest.mark.parametrize("grid_only", [False, True])
def test_a_grids_rough_values_rank_the_starts_and_never_score(grid_only):
    """The grid's points are evaluated rough; every value that scores (the refinement's, the screen's, the fit's)
    is exact: the fit, and a screen by the grid alone, score the same to the last bit as with an engine whose
    rough values are exact (a rough value that scored would be off by N log 1.5, 20)."""
    rough, exact = _RoughWellEngine(), _RoughWellEngine(honour_rough=False)
    fits = [fit_joint(e, [CandidateSpec("command_displacement", poles=((2.2, 0.25),))], {}, {}, np.array([50.0]),
                      np.array([50.0]), lambda e: None, lambda e: e, grid_only=grid_only) for e in (rough, exact)]
    assert fits[0].delta_bic == fits[1].delta_bic
    assert fits[0].effects == fits[1].effects
    n_grid = fits[0].cost["grid"]["evaluations"]
    assert n_grid >= 16 and all(r for _, _, r in rough.calls[:n_grid])
    assert not rough.calls[-1][2]  # the score's evaluation
    if not grid_only:
        assert fits[0].j_pooled < 0.15  # the well, found by the refinement from the global stage's start


def test_a_search_re_fits_each_point_from_the_nearest_point_it_has_evaluated():
    """The first point is re-fitted from the current model's optimum (no ``start``); every later one from the own
    parameters fitted at the nearest point evaluated before it, in units of each parameter's search range (no
    intervals asked: their information re-fits the optimum on its own)."""
    eng = _RoughWellEngine()
    fit_joint(eng, [CandidateSpec("command_displacement", poles=((2.2, 0.25),))], {}, {}, np.array([50.0]),
              np.array([50.0]), lambda e: None, lambda e: e, intervals_to=-math.inf)
    ps = search_params(CandidateSpec("command_displacement"))
    span = np.array([math.log(p.upper / p.lower) for p in ps])
    assert eng.calls[0][1] is None
    assert len(eng.calls) > 20
    for i, (z, start, _) in enumerate(eng.calls[1:], 1):
        earlier = [c[0] for c in eng.calls[:i]]
        d = [float(np.sum(((e - z) / span) ** 2)) for e in earlier]
        assert start is not None
        assert float(np.sum(((start - z) / span) ** 2)) == pytest.approx(min(d), abs=1e-12)


def test_global_starts_of_a_valve_from_poles_and_data():
    """The poppet valve: part 1's pole pairs (clipped to the box), its onset and the quantiles of |Δp| for the
    cracking pressure (merged within a tenth of the log range), the top of |Δp| times 0.1, 1, 10 for the span; at
    most 3 values per axis, every other coordinate at the grid's best point."""
    rng = np.random.default_rng(3)
    spec = CandidateSpec("poppet_valve", poles=((1.75, 0.14), (1.41, 4.6), (1.8, 0.15)), thresholds=(3.4e5,))
    ps = search_params(spec)
    flat = [(spec, p) for p in ps]
    lo = np.array([math.log(p.lower) for p in ps])
    hi = np.array([math.log(p.upper) for p in ps])
    dp = np.abs(rng.normal(0.0, 8e5, 5000))
    base = 0.5 * (lo + hi)
    starts, narrow = global_starts(flat, [0, 1, 2, 3, 4], base, lo, hi, dp)
    assert narrow == [0, 1, 2, 3, 4]
    z = np.exp(np.array(starts))
    pairs = sorted({(round(a, 3), round(b, 3)) for a, b in z[:, :2]})
    assert pairs == [(1.41, 3.0), (1.75, 0.14)]  # (1.8, 0.15) merged into (1.75, 0.14); ζ 4.6 clipped to 3
    cracks = sorted({round(c) for c in z[:, 2]})
    q = [float(np.quantile(dp, x)) for x in cand.THRESHOLD_QUANTILES]
    assert len(cracks) <= 3 and round(3.4e5) in cracks and round(q[0]) in cracks
    top = float(np.quantile(dp, 0.99))
    assert sorted({round(s) for s in z[:, 3]}) == [round(top * 0.1), round(top), round(top * 10)]
    # the bleed: for each span start, the one that keeps a plateau at the top of |Δp| just stable (10: its box's top)
    assert sorted({round(b, 6) for b in z[:, 4]}) == [0.1, 1.0, 10.0]
    assert len(starts) == 2 * len(cracks) * 3 * 3 <= 81
    # no data, no poles: nothing to start from; a spec's own box (the generic effect's) is not a narrow axis
    bare = CandidateSpec("poppet_valve")
    assert global_starts([(bare, p) for p in ps], [0, 1, 2, 3], base, lo, hi, None) == ([], [0, 1, 2, 3])
    boxed = CandidateSpec("poppet_valve", {"natural_frequency_Hz": SearchParam("natural_frequency_Hz", 1.0, 4.0, True)})
    assert global_starts([(boxed, p) for p in search_params(boxed)], [0, 1, 2, 3], base, lo, hi, None)[1] == [1, 2, 3]


def test_spectral_peaks_of_a_ringing_residual():
    """A 2.3 Hz ring (ζ 0.1) in 3-s windows with noise: the pooled periodogram's peak at 2.3 Hz; its damping from
    the half-power width (resolution-limited, so within a factor 2); noise alone gives no peak above the floor."""
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 3.0, 0.004)
    w = 2 * math.pi * 2.3
    res = [np.exp(-0.1 * w * t) * np.sin(w * math.sqrt(0.99) * t + k) * 300 + rng.normal(0, 10, t.size)
           for k in range(6)]
    peaks = spectral_peaks(res, [t] * 6)
    assert peaks[0][0] == pytest.approx(2.3, rel=0.06)
    assert 0.05 <= peaks[0][1] <= 0.2
    assert spectral_peaks([None], [t]) == []


def test_a_known_optimum_of_one_parameter_is_scored_there_without_a_search():
    """The selected option's intervals are computed at its optimum (``max_iter`` 0): a one-parameter fit with a
    start is scored at the start itself, not re-searched on a grid, and gets a finite interval about it."""
    calls = []

    class Engine(FakeProfileEngine):
        problems = [fake_problem(np.ones(40))]

        def evaluate(self, eff, flow=None, keep=False, idx=None, start=None, rough=False):
            tau = eff["actuator_lag"]["time_constant_s"]
            calls.append(tau)
            sse = 40.0 * (0.2 + 0.5 * math.log(tau / 0.05) ** 2)  # the optimum at 0.05 s, inside the box
            return np.array([sse]), np.zeros((1, 2)), [np.full(40, math.sqrt(sse / 40.0))]

    fit = fit_joint(Engine(), [CandidateSpec("actuator_lag")], {"actuator_lag": {"time_constant_s": 0.06}}, {},
                    np.array([40.0]), np.array([40.0]), lambda e: None, lambda e: e, max_iter=0)
    assert fit.effects["actuator_lag"]["time_constant_s"] == pytest.approx(0.06)
    assert "grid" not in fit.cost and len(calls) == 3  # the start and the two points of its curvature
    p = fit.params["time_constant_s"]
    assert p["lo"] < 0.06 < p["hi"] and math.isfinite(p["lo"]) and math.isfinite(p["hi"])
    # the same candidate without a start is searched on its grid first
    calls.clear()
    searched = fit_joint(Engine(), [CandidateSpec("actuator_lag")], {}, {}, np.array([40.0]), np.array([40.0]),
                         lambda e: None, lambda e: e)
    assert "grid" in searched.cost and len(calls) > 3
    assert searched.effects["actuator_lag"]["time_constant_s"] == pytest.approx(0.05, rel=0.05)


def test_the_loops_steps_count_their_wall_time_and_the_searches_run_in_them():
    """search_step closes the open step and opens the next: each search's evaluations are counted in the step open
    when it ran, and a step's wall time is the time until the next step opened (a 50 ms pause in it at least)."""
    import time

    from bayesdamper.diagnosis.global_stage import _tally, reset_search_cost, search_cost_by_step, search_step

    reset_search_cost()
    search_step("candidates searched")
    _tally({"grid": {"s": 0.0, "evaluations": 6}, "refine": {"s": 0.0, "evaluations": 4}})
    time.sleep(0.05)
    search_step("pairs")
    _tally({"refine": {"s": 0.0, "evaluations": 3}})
    _tally({"refine": {"s": 0.0, "evaluations": 2}})
    search_step(None)
    _tally({"refine": {"s": 0.0, "evaluations": 100}})  # after the loop: no step
    steps = search_cost_by_step()
    assert set(steps) == {"candidates searched", "pairs"}
    assert (steps["candidates searched"]["fits"], steps["candidates searched"]["evaluations"]) == (1, 10)
    assert (steps["pairs"]["fits"], steps["pairs"]["evaluations"]) == (2, 5)
    assert steps["candidates searched"]["s"] >= 0.05 > steps["pairs"]["s"]
    reset_search_cost()
    assert search_cost_by_step() == {}
