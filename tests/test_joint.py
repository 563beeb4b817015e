"""The joint stage 2 (step Δp, flow coefficients, α_V, p_R sampled together) and the plateau noise estimate.

Data come from the independent scipy generator (tests/independent.py), with the velocity step off the
sample grid.
"""

import math
import pickle
from pathlib import Path

import numpy as np
import pytest
from independent import PAPER_FLOW, RIG_A, ar1_noise, force_noise, simulate, triangle_input

from bayesdamper.core.params import DamperConstants, FlowCoefficients
from bayesdamper.inference import joint
from bayesdamper.inference.identify import identify_window
from bayesdamper.inference.stage2 import StageTwoSettings
from bayesdamper.io.dataset import TestRecord
from bayesdamper.io.segmentation import segment_record

DAMPER = DamperConstants(RIG_A["area"], RIG_A["v01"], RIG_A["v02"], RIG_A["b0"])
RATE = 200.0
T_FIRST = 1.0 + 0.37 / RATE  # off the grid
SPEED = 1.0e-3


def _prior(noise: joint.PlateauNoise, rel_sd: float = 0.01, dof: float = 10.0) -> joint.StageOnePrior:
    m = np.array(PAPER_FLOW, dtype=float)
    sd = rel_sd * m
    corr = np.array([[1.0, -0.97], [-0.97, 1.0]])
    cov = np.zeros((4, 4))
    cov[:2, :2] = np.outer(sd[:2], sd[:2]) * corr
    cov[2:, 2:] = np.outer(sd[2:], sd[2:]) * corr
    return joint.StageOnePrior(m, cov, np.array([dof, dof]), noise)


def _record(alpha_v=40.0, p_r=2.5e5, sd=10.0, phi=0.0, seed=0, rate=RATE, clean=False):
    inp = triangle_input(SPEED, 5e-3, 0.0, T_FIRST, cycles=0.75)
    t = np.arange(int(round((T_FIRST + 15.0 + 0.05) * rate))) / rate
    f = simulate(inp, t, RIG_A, PAPER_FLOW, alpha_v, p_r, rtol=1e-10)
    if not clean:
        f = f + force_noise(t.size, sd, phi, seed)
    rec = TestRecord("tri", Path("tri.csv"), t, inp.displacement(t), f, "0" * 64)
    return segment_record(rec, DAMPER, tmax=3.0)


@pytest.fixture(scope="module")
def segmented():
    return _record()


# ------------------------------------------------------------------------------------------ plateau noise


@pytest.mark.parametrize("phi", [0.0, 0.9, 0.97])
def test_plateau_ar1_estimate_is_unbiased_where_the_raw_one_is_not(phi):
    """20 stretches of 300 samples about unknown means: the pooled lag-1 estimate is biased low by about
    (1 + 3φ)/300 (Marriott & Pope); the corrected one is within 4 of its standard errors of φ, averaged over
    10 seeded repetitions."""
    est, raw = [], []
    for rep in range(10):
        segs = [5.0 * k + force_noise(300, 12.0, phi, [rep, k]) for k in range(20)]
        pn = joint.ar1_from_segments(segs)
        est.append(pn.phi)
        xs = [s - s.mean() for s in segs]
        raw.append(sum(x[1:] @ x[:-1] for x in xs) / sum(x[:-1] @ x[:-1] for x in xs))
        assert pn.sigma_e == pytest.approx(12.0 * math.sqrt(1 - phi**2), rel=0.05)  # 6000 innovations: sd 0.9 %
    se = math.sqrt((1 - phi**2) / 6000) / math.sqrt(10)
    assert abs(np.mean(est) - phi) < 4 * se + 1e-3
    bias = (1 + 3 * phi) / 300
    assert np.mean(raw) < phi - 0.5 * bias  # the correction is needed: the raw estimate is low


def test_plateau_noise_reads_the_plateaus_of_a_record():
    seg = _record(sd=15.0, phi=0.9, seed=3)
    pn = joint.plateau_noise([seg])
    assert pn.n_plateaus == len(seg.plateaus)
    se = math.sqrt((1 - 0.9**2) / pn.n_samples)  # asymptotic sd of the lag-1 estimate
    assert pn.phi == pytest.approx(0.9, abs=4 * se)
    assert pn.sigma_e == pytest.approx(15.0 * math.sqrt(1 - 0.9**2), rel=4 / math.sqrt(2 * pn.n_samples))


def test_dp0_sd_is_the_ar1_mean_sd():
    """The sd of the mean of n AR(1) samples (the formula of JointProblem.dp0_sd) against Monte Carlo."""
    phi, sd, n = 0.95, 20.0, 30
    means = [ar1_noise(n, sd, phi, k).mean() for k in range(4000)]
    pn = joint.PlateauNoise(phi, sd * math.sqrt(1 - phi**2), 1000, 5)
    seg = _record()
    tr = seg.transients[0]
    jp = joint.JointProblem(tr.id, tr.time, tr.force, tr.pre_time[:n], tr.pre_force[:n], tr.t_step, tr.local_drive,
                            float(tr.dp0), DAMPER, _prior(pn))
    assert jp.pre_force.size == n
    assert jp.dp0_sd() * DAMPER.piston_area == pytest.approx(np.std(means), rel=0.05)  # MC sd error 1.1 %


# ------------------------------------------------------------------------------------------ log-posterior


def test_transients_carry_the_samples_before_the_step(segmented):
    for tr in segmented.transients:
        assert tr.pre_time.size >= 25
        assert np.all(tr.pre_time < tr.t_step) and tr.pre_time[-1] > tr.t_step - 1.0 / RATE - 1e-12
        assert tr.dp0 == pytest.approx(tr.pre_force.mean() / DAMPER.piston_area)
        assert np.isclose(tr.time[0] - tr.pre_time[-1], 1.0 / RATE)  # contiguous with the window


@pytest.mark.parametrize("code", [joint.PLATEAU, joint.AR1, joint.WHITE])
def test_compiled_equals_reference(segmented, code):
    pn = joint.PlateauNoise(0.3, 9.0, 1000, 4)
    for tr in segmented.transients:
        jp = joint.JointProblem.from_window(tr, DAMPER, _prior(pn), code)
        sp = jp.space()
        lp = joint.JointLogPosterior(jp, sp)
        rng = np.random.default_rng(1)
        centre = np.r_[math.log(40.0), math.log(2.5e5), jp.dp0_estimate, PAPER_FLOW, [0.3] if code == joint.AR1 else []]
        for _ in range(4):
            th = centre + rng.normal(0, 0.02, centre.size) * np.r_[1, 1, 1e-3 * abs(jp.dp0_estimate) + 100,
                                                                   np.array(PAPER_FLOW) * 0.1,
                                                                   [1.0] if code == joint.AR1 else []]
            a, b = lp(th), lp.reference(th)
            assert np.isfinite(a)
            assert a == pytest.approx(b, rel=1e-9, abs=1e-6)


def test_minus_inf_outside_box_and_never_nan(segmented):
    pn = joint.PlateauNoise(0.0, 10.0, 1000, 4)
    jp = joint.JointProblem.from_window(segmented.transients[0], DAMPER, _prior(pn))
    lp = joint.JointLogPosterior(jp, jp.space())
    good = np.r_[math.log(40.0), math.log(2.5e5), jp.dp0_estimate, PAPER_FLOW]
    bad = [good + np.r_[100, 0, 0, 0, 0, 0, 0], np.full(7, np.nan), good * np.r_[1, 1, 1, -1, 1, 1, 1],
           np.r_[good[:2], 1e30, good[3:]]]
    out = lp.batch(np.array(bad))
    assert np.all(out == -np.inf)
    assert np.isfinite(lp(good))
    assert pickle.loads(pickle.dumps(lp))(good) == lp(good)


def test_map_recovers_every_parameter_on_noise_free_data():
    """Noise-free independent data, a prior centred 1 % off the true flow coefficients: the MAP of all seven
    parameters sits at the truth (the window determines the coefficients of its direction far better than
    a 1 % prior)."""
    seg = _record(alpha_v=60.0, p_r=1.5e5, clean=True)
    pn = joint.PlateauNoise(0.0, 1.0, 1000, 4)
    prior = _prior(pn, rel_sd=0.01)
    prior = joint.StageOnePrior(prior.mean * np.array([1.01, 0.99, 1.01, 0.99]), prior.cov, prior.dof, pn)
    tr = seg.transients[1]  # the reversal: both directions' coefficients act
    jp = joint.JointProblem.from_window(tr, DAMPER, prior)
    lp = joint.JointLogPosterior(jp, jp.space())
    x, cov = joint.fit_map(lp, np.r_[math.log(45.0), math.log(2e5), jp.dp0_estimate, prior.mean])
    assert cov is not None
    assert math.exp(x[0]) == pytest.approx(60.0, rel=2e-3)
    assert math.exp(x[1]) == pytest.approx(1.5e5, rel=5e-3)
    assert x[2] == pytest.approx(tr.pre_force.mean() / DAMPER.piston_area, rel=1e-4)


#: J of the cut's posterior-predictive median over Nelder-Mead's: the median curve of draws spread over Δp0 and
#: the flow coefficients is not the optimum's curve; 1 % slack is a tenth of the rule on rig-A (10 %).
CUT_J_SLACK = 1.01


@pytest.mark.parametrize("coupling", ["cut", "joint"])
def test_propagated_interval_covers_a_start_from_rest_the_conditional_one_misses(coupling):
    """The conditional posterior's failure on one start from rest (α_V 90, p_R 30 kPa, white 10 N): conditioned on
    the mean step force the 90 % interval of α_V is a few tenths of a percent wide and misses the truth by many of its
    widths; sampled jointly it holds it. Seed 0 of 1, not chosen: with the conditional posterior's z of 4-50
    on this data set (5 of 6 starts missed in the issue), any seed shows it."""
    seg = _record(alpha_v=90.0, p_r=3.0e4, sd=10.0, seed=0)
    pn = joint.plateau_noise([seg])
    static_like = _prior(pn, rel_sd=0.003)
    tr = seg.transients[0]
    flow = FlowCoefficients(*PAPER_FLOW)
    cond = identify_window(tr, DAMPER, flow, StageTwoSettings(noise_model="ar1", propagate=False), 0).entry
    jnt = identify_window(tr, DAMPER, flow, StageTwoSettings(coupling=coupling), 0, prior=static_like).entry
    assert jnt["converged"] and jnt["propagated"]
    assert jnt["alpha_V"]["lo"] <= 90.0 <= jnt["alpha_V"]["hi"]
    assert jnt["p_R_Pa"]["lo"] <= 3.0e4 <= jnt["p_R_Pa"]["hi"]
    width = cond["alpha_V"]["hi"] - cond["alpha_V"]["lo"]
    assert abs(cond["alpha_V"]["median"] - 90.0) > 2 * width
    assert jnt["J"] <= (CUT_J_SLACK if coupling == "cut" else 1.001) * jnt["ls"]["J"]


def test_only_flow_coefficients_cut_by_zero_are_sampled_as_logs():
    """A flow coefficient whose MAP lies within JOINT_BOUND_SDS Laplace sd of 0 is sampled as its log; one far from
    0 stays linear (a straight C_L-C_Q ridge would bend in the log); without a covariance every one is logged."""
    from bayesdamper.inference.identify import FLOW_DIMS, JOINT_BOUND_SDS, _cut_by_zero

    x = np.array([3.5, 12.6, 0.0, 2.4e10, 4.3e16, 1.0e8, 5.1e16])
    lower = np.zeros(7)
    sd = np.array([1e-3, 1e-3, 300.0, 6e8, 5e13, 1.0e8, 6e13])  # CL21: MAP 1 sd above 0
    cov = np.diag(sd**2)
    assert list(_cut_by_zero(x, lower, cov)) == [5]
    cov[5, 5] = (x[5] / (1.01 * JOINT_BOUND_SDS)) ** 2  # just beyond the rule's reach
    assert list(_cut_by_zero(x, lower, cov)) == []
    assert list(_cut_by_zero(x, lower, None)) == list(FLOW_DIMS)


def test_a_window_near_a_prior_bound_is_sampled_with_the_pilots_proposal(segmented):
    """A reversal sampled in the default box gets the Laplace proposal; in a box whose p_R bound lies below its
    optimum (the MAP on the bound, as a slow test's p_R on the 10 MPa bound: the Gaussian at the MAP is cut by the
    box) it gets the pilot's. Both are checked every JOINT_CHECK_EVERY steps and converge (R-hat, ESS and 50 τ
    rules). The default box's 99 % intervals hold the truth (two intervals at 99 %: a calibrated posterior misses
    one about 2 % of the time; seed 0 of 1, not chosen); the cut box's posterior of p_R is piled against its bound
    (its median within its own 99 % interval's width of it) and inside it."""
    from bayesdamper.inference.identify import BOUND_MOVE, JOINT_CHECK_EVERY, JOINT_MOVE

    prior = _prior(joint.plateau_noise([segmented]))
    tr = segmented.transients[1]

    def run(top):
        e = identify_window(tr, DAMPER, FlowCoefficients(*PAPER_FLOW),
                            StageTwoSettings(credible_mass=0.99, p_r_bounds=(1.0e3, top)), 0, prior=prior).entry
        assert e["converged"], (top, e["convergence"])
        assert e["sampler"]["check_every"] == JOINT_CHECK_EVERY
        return e

    wide = run(1.0e7)
    assert wide["sampler"]["move"] == JOINT_MOVE
    assert wide["alpha_V"]["lo"] <= 40.0 <= wide["alpha_V"]["hi"], wide["alpha_V"]
    assert wide["p_R_Pa"]["lo"] <= 2.5e5 <= wide["p_R_Pa"]["hi"], wide["p_R_Pa"]
    top = 0.95 * wide["p_R_Pa"]["median"]
    cut = run(top)
    assert cut["sampler"]["move"] == BOUND_MOVE
    p = cut["p_R_Pa"]
    assert p["hi"] <= top and top - p["median"] < p["hi"] - p["lo"], p
