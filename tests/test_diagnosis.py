"""Residual diagnosis: noise from plateaus, the structure test, the criterion, and the closed loop."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from bayesdamper.diagnosis.candidates import effective_sizes, pooled_j
from bayesdamper.diagnosis.loop import MIN_J_REDUCTION, SELECT_DELTA_BIC
from bayesdamper.diagnosis.residual import plateau_noise, structure_test
from bayesdamper.physics.effects import EFFECTS

RATE = 250.0
NOISE_SD = 20.0


def _segs(rng, n_plateaus=6, seconds=3.0, phi=0.0):
    t = np.arange(0.0, n_plateaus * seconds, 1 / RATE)
    e = rng.standard_normal(t.size) * NOISE_SD
    if phi:
        for i in range(1, e.size):
            e[i] = phi * e[i - 1] + np.sqrt(1 - phi**2) * e[i]
    f = 1000.0 + 5.0 * t + e  # slow drift on the plateaus is removed by the detrending
    plateaus = [SimpleNamespace(t_start=k * seconds + 0.1, t_end=(k + 1) * seconds - 0.1) for k in range(n_plateaus)]
    rec = SimpleNamespace(time=t, force=f, sample_rate=RATE)
    return [SimpleNamespace(record=rec, plateaus=plateaus)]


def test_plateau_noise_recovers_sd():
    noise = plateau_noise(_segs(np.random.default_rng(0)))
    # 4000+ samples: the sd is estimated to ~1.5 %
    assert noise["sigma_N"] == pytest.approx(NOISE_SD, rel=0.05)
    assert abs(noise["rho"]) < 0.1


def test_structure_test_false_alarm_rate_and_power():
    rng = np.random.default_rng(1)
    noise = plateau_noise(_segs(rng, n_plateaus=10))
    t = np.arange(0.0, 3.0, 1 / RATE)
    alarms = [structure_test(rng.standard_normal(t.size) * NOISE_SD, RATE, noise)["structured"] for _ in range(200)]
    # alpha = 1e-3; allow a few false alarms in 200 (the dof are approximations)
    assert sum(alarms) <= 4
    bump = 60.0 * np.exp(-((t - 0.6) / 0.2) ** 2)  # a 60 N smooth bump: 3x the noise sd
    hits = [structure_test(bump + rng.standard_normal(t.size) * NOISE_SD, RATE, noise)["structured"]
            for _ in range(50)]
    assert np.mean(hits) > 0.95


def test_effective_size_and_pooled_j():
    rng = np.random.default_rng(2)
    white = rng.standard_normal(1000)
    smooth = np.convolve(rng.standard_normal(1100), np.ones(100) / 100, mode="valid")[:1000]
    n = effective_sizes([white, smooth])
    assert n[0] == pytest.approx(1000, rel=0.1)
    assert n[1] < 50
    f = [np.ones(4), 2 * np.ones(4)]
    r = [np.ones(4), np.zeros(4)]
    assert pooled_j(r, f) == pytest.approx(np.sqrt(4 / 20))


def test_pooled_j_at_the_least_squares_optima_pools_the_per_transient_j():
    """pooled_j_ls weighs each transient's eq. (9) J by its force energy: the pooled J of residuals of those norms."""
    from bayesdamper.diagnosis.summary import pooled_j_ls

    rng = np.random.default_rng(5)
    forces = [rng.normal(0, s, n) for s, n in ((1e3, 300), (8e3, 500), (2e2, 100))]
    resid = [rng.normal(0, s, f.size) for s, f in zip((30.0, 400.0, 1.0), forces, strict=True)]
    entries = [{"ls": {"J": float(np.linalg.norm(r) / np.linalg.norm(f))}} for r, f in zip(resid, forces, strict=True)]
    assert pooled_j_ls(entries, forces) == pytest.approx(pooled_j(resid, forces), rel=1e-12)
    assert pooled_j_ls(entries[:1], forces[:1]) == pytest.approx(entries[0]["ls"]["J"], rel=1e-12)


# ----------------------------------------------------------------------------------------------------
# the closed loop on bayesdamper's own synthetic data with an undeclared effect (make test-confusion; not in CI:
# the correctness claim is the table on independent reference data, tests/test_confusion.py, which CI runs)

EFFECT_CASES = ["none", "friction", "backlash", "actuator_lag", "valve_dynamics", "series_compliance", "inertia"]
#: Force noise of the synthetic tests [N] (rig-A's plateau noise is ~12 N).
LOOP_NOISE_N = 15.0
#: Truth of the base model: the two-state model eq. (1) with its accumulator closed. At these values eq. (7)
#: re-fitted per transient leaves a pooled J of ~0.0026 on noise-free data: never exactly right, but
#: close enough that the control must select nothing.
LOOP_TRUTH = (1000.0, 3.0e5)
#: The closed accumulator: the lowest check-valve conductance the two-state effect admits [m^3 s^-1 Pa^-1]
#: (at 0.3 MPa below the charge it refills 3e-10 m^3/s, nothing over a test). The composed kernel, which
#: injects the effects, takes a conductance > 0 only.
LOOP_CONDUCTANCE = next(p.lower for p in EFFECTS["two_state"].params if p.name == "refill_conductance_m3_per_s_Pa")


def _loop_case(effect: str, tmp_path):
    """The diagnosis of the case's data, and ``{test: (t, noise-free force, measured force)}`` of its generator."""
    from bayesdamper.core.params import DynamicParameters
    from bayesdamper.io.dataset import load_dataset
    from bayesdamper.io.synthetic import write_dataset
    from bayesdamper.run.diagnose import run_diagnosis

    effects = None if effect == "none" else {effect: {}}
    sets = {}
    for name, noise in (("data", LOOP_NOISE_N), ("clean", 0.0)):  # the same records without the noise
        sets[name] = load_dataset(write_dataset(
            tmp_path / f"{name}_{effect}", [0.5e-3, 1.0e-3, 1.5e-3], DynamicParameters(*LOOP_TRUTH),
            model="two-state", noise_n=noise, seed=7, effects=effects, accumulator_conductance=LOOP_CONDUCTANCE))
    clean = {r.name: r.force for r in sets["clean"].records}
    truth = {r.name: (r.time, clean[r.name], r.force) for r in sets["data"].records}
    d = run_diagnosis(str(tmp_path / f"data_{effect}"), str(tmp_path / f"out_{effect}"), seed=1, workers=2,
                      max_steps=600, figures=False, quiet=True)
    return d, truth


#: Known failure: series compliance is supported in sample (two_state + series_compliance ΔBIC_eff about -5900) but
#: the stiffness fitted on two speeds predicts the third worse: the out-of-sample rule says "none". Strict, so that a
#: fix shows.
_CASES = [pytest.param(e, marks=pytest.mark.xfail(strict=True, reason="out-of-sample rule rejects the "
                                                  "series compliance fitted on two speeds of three"))
          if e == "series_compliance" else e for e in EFFECT_CASES]


@pytest.mark.confusion
@pytest.mark.parametrize("effect", _CASES)
def test_loop_finds_the_undeclared_effect(effect, tmp_path):
    """Two-state truth + one injected effect (the library's default values), undeclared: diagnose names the injected
    family, with the two-state physics at most besides, unless the effect is below the loop's floor; J falls and ends
    within 2x of the true model's J (the library holds the whole truth); the control gets nothing but the two-state
    physics. The rule of the independent table (tests/test_confusion.py) and of benchmarks/random_sets.py."""
    d, truth = _loop_case(effect, tmp_path)
    from test_confusion import FAMILY, TWO_STATE_FAMILY, _j_truth

    # judged by family: a 2nd-order servo naming a 1st-order lag, or a poppet naming a valve lag, is the right
    # physics in a richer form (the library holds both)
    named = {FAMILY[lab.split("@", 1)[0]] for lab in d["selected"]}
    j_truth = _j_truth(d, truth)
    row = {"injected": effect, "selected": d["selected"], "J_before": d["baseline"]["J_pooled"],
           "J_after": d["final"]["J_pooled"], "J_truth": j_truth,
           "scores": {c["effect"]: round(c["score"], 1) for c in d["candidates"]}}
    print("CONFUSION", json.dumps(row))
    if effect == "none":
        assert named <= {TWO_STATE_FAMILY}, row  # the control gets no rig effect
    else:
        assert named <= {FAMILY[effect], TWO_STATE_FAMILY}, row
        # an effect left unnamed must be below the loop's floor: the model without it already ends within
        # 1 / (1 - MIN_J_REDUCTION) of the truth's J, so even the whole truth would not lower J by the fifth the loop
        # asks of an effect (the random sets' "below the floor", benchmarks/random_sets.py)
        assert FAMILY[effect] in named or d["final"]["J_pooled"] <= j_truth / (1.0 - MIN_J_REDUCTION), row
        assert d["final"]["J_pooled"] < d["baseline"]["J_pooled"], row
    assert d["final"]["J_pooled"] <= 2.0 * j_truth, row
    assert d["candidates"] and all(c["criterion"] == "delta_BIC_eff" for c in d["candidates"])
    assert set(d) >= {"dataset", "noise_N", "baseline", "candidates", "selected", "final", "drift_before",
                      "drift_after"}
    assert SELECT_DELTA_BIC < 0
