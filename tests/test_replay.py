"""Internal numerical differentiation: the composed kernel records its steps and replays them.

A forward difference of two error-controlled solves carries the difference of their discretisation errors divided by
the step, noise of the order of the tolerance over the step; a solve at the perturbed parameters on the steps of the
solve it is differenced against differs from it smoothly (Bock's internal numerical differentiation). Checked here:
a replay reproduces its recording, a difference on replayed steps matches a tight central difference where two
error-controlled solves at the search's tolerance do not, and a replay that does not fit falls back to error
control (other restart intervals, or a solution that has left the recorded one).
"""

import numpy as np
import pytest

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER
from bayesdamper.physics.compose import compose, solve_composed
from bayesdamper.physics.excitation import PiecewisePolynomial

D = RIG_A_DAMPER
FLOW = PAPER_FLOW.as_array()
#: A reversal at 1 mm/s after a plateau, samples at 250 Hz off the step, 3 s: a transient of the search's kind.
KT = np.array([0.0, 1.0137, 11.0137, 15.0137])
KY = np.array([0.0, 0.0, 1e-2, 6e-3])
T0 = KT[2]
T_OUT = T0 + np.arange(1, 751) / 250.0
TWO_STATE = {"two_state": {"polytropic_exponent": 1.2, "refill_conductance_m3_per_s_Pa": 2e-11}}
DP0 = 1.2e6
DRIVE = PiecewisePolynomial.from_knots(KT, KY)


def _solve(effects, alpha_v, p_r, rtol, drive=DRIVE, **kw):
    c = compose(effects)
    return solve_composed(c, T_OUT, c.transform_input(drive), T0, DP0, 1e-3, D, FLOW, alpha_v, p_r, rtol, 1.0,
                          max_steps=3 * T_OUT.size, **kw)


def test_a_replay_of_the_recorded_steps_is_the_recorded_solve():
    f, status, steps = _solve(TWO_STATE, 40.0, 4e5, 1e-5, record=True)
    assert status == 0 and steps is not None and steps.size > 10
    assert np.all(np.diff(steps) > 0) and steps[-1] == pytest.approx(T_OUT[-1], abs=1e-12)
    g, status2, again = _solve(TWO_STATE, 40.0, 4e5, 1e-5, record=True, replay=steps)
    assert status2 == 0 and np.array_equal(again, steps)
    assert np.max(np.abs(g - f)) <= 1e-9 * np.max(np.abs(f))  # the same steps: rounding of h only


@pytest.mark.parametrize("effects", [TWO_STATE, {}], ids=["two-state", "eq. (7) composed"])
def test_a_difference_on_replayed_steps_is_smooth_in_its_step(effects):
    """d force / d log p_R by forward differences at rtol 1e-5, against a central difference at rtol 1e-11. On
    replayed steps the difference is the derivative of the discrete solution, whatever the step: within 5 % of the
    exact one at the search's step 1e-4 and still at 1e-7 (measured 3.5 % for the two-state model, whose refill
    switches within a step, and 0.07-0.2 % without it). Two error-controlled solves differ by their errors' noise
    over the step, which at 1e-7 is many times that (measured 40 % and 8 %): what a regression to error-controlled
    differences fails."""
    if not effects:  # the composed kernel proper (not eq. (7)'s own fast path): an effect with a state, held off
        effects = {"actuator_lag": {"time_constant_s": 1e-6}}
    a, p = 40.0, 4e5
    exact = (_solve(effects, a, p * np.exp(1e-5), 1e-11)[0] - _solve(effects, a, p * np.exp(-1e-5), 1e-11)[0]) / 2e-5
    f0, _, steps = _solve(effects, a, p, 1e-5, record=True)

    def error(h, replay):
        d = (_solve(effects, a, p * np.exp(h), 1e-5, replay=replay)[0] - f0) / h
        return float(np.linalg.norm(d - exact) / np.linalg.norm(exact))

    assert error(1e-4, steps) <= 0.05 and error(1e-7, steps) <= 0.05
    assert error(1e-7, steps) < 0.5 * error(1e-7, None)


def test_a_replay_that_does_not_fit_is_solved_with_error_control():
    """Steps recorded on another input (a restart break elsewhere) are refused, and so are steps far too long for
    the solution they are replayed on (a much stiffer gas); either way the result is the error-controlled solve."""
    _, _, steps = _solve(TWO_STATE, 40.0, 4e5, 1e-5, record=True)
    other = PiecewisePolynomial.from_knots(KT + np.array([0.0, 0.0, 0.05, 0.05]), KY)
    ref = _solve(TWO_STATE, 40.0, 4e5, 1e-5, drive=other, record=True)
    got = _solve(TWO_STATE, 40.0, 4e5, 1e-5, drive=other, record=True, replay=steps)
    assert got[1] == 0 and np.array_equal(got[0], ref[0]) and np.array_equal(got[2], ref[2])
    stiff = _solve(TWO_STATE, 4000.0, 4e5, 1e-5, record=True)
    replayed = _solve(TWO_STATE, 4000.0, 4e5, 1e-5, record=True, replay=steps)
    assert not np.array_equal(stiff[2], steps)
    assert np.array_equal(replayed[0], stiff[0]) and np.array_equal(replayed[2], stiff[2])


def test_the_sensitivities_replay_the_steps_of_the_re_fit_they_difference_against(monkeypatch):
    """The search's sensitivities to a shared parameter replay the steps its re-fit recorded at the window's optimum:
    the same columns, bit for bit, as solving that optimum once more to record them, one solve fewer a window."""
    from test_model_comparison import synthetic_windows

    import bayesdamper.diagnosis.engine as E
    from bayesdamper.inference.problem import EffectsProblem
    from bayesdamper.physics.with_effects import effect_argument

    problems, _, _, truth = synthetic_windows()
    problems, truth = problems[:2], truth[:2]
    engine = E.ProfileEngine(problems, [p.inner_start(a, pr) for p, (a, pr) in zip(problems, truth, strict=True)])
    base = effect_argument(TWO_STATE)
    bumped = effect_argument({"two_state": {**TWO_STATE["two_state"], "polytropic_exponent": 1.2 + 1e-3}})
    engine.restart()
    _, xs, resid = engine.evaluate(base, None)
    solves = []
    original = EffectsProblem.simulate_inner

    def counted(self, *a, **kw):
        solves.append(1)
        return original(self, *a, **kw)

    monkeypatch.setattr(EffectsProblem, "simulate_inner", counted)
    carried = engine.sensitivities((base, None), [bumped], [None], np.array([1e-3]), [0, 1], xs, resid)
    n_carried = len(solves)
    engine._steps.clear()  # as after a record that overflowed: the optimum is solved again to record them
    solves.clear()
    again = engine.sensitivities((base, None), [bumped], [None], np.array([1e-3]), [0, 1], xs, resid)
    assert all(np.array_equal(a, b) for a, b in zip(carried, again, strict=True))
    assert np.all(np.isfinite(carried[0])) and np.any(carried[0] != 0.0)
    assert (n_carried, len(solves)) == (2, 4)
