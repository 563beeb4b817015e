"""The effects added as one module each, judged against an independent reference simulator.

``tests/reference_effects.py`` integrates eq. (7) with the same nine effects with scipy's Radau at tight
tolerance, written from the equations alone (no bayesdamper import). Here the composed kernel must
reproduce it on a triangle whose steps lie off the sample grid (1234 Hz), from rest and after a reversal,
one effect at a time and in combinations.
"""

import math

import numpy as np
import pytest
from independent import PAPER_FLOW as REF_FLOW
from independent import RIG_A, quasi_static_dp, triangle_input
from reference_effects import simulate_effects as reference_simulate

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.params import DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.inference.problem import EffectsProblem
from bayesdamper.physics.compose import L_ACTIVE, ComposedEffects, compose, kernel_source, layout, solve_composed
from bayesdamper.physics.effects import EFFECT_MODULES, EFFECT_NAMES, EFFECTS
from bayesdamper.physics.excitation import PiecewiseLinear, PiecewisePolynomial
from bayesdamper.physics.rodas import STATUS_OK
from bayesdamper.physics.with_effects import effect_argument, simulate_effects

D = DamperConstants(RIG_A["area"], RIG_A["v01"], RIG_A["v02"], RIG_A["b0"])
FLOW = FlowCoefficients(*REF_FLOW)
ALPHA_V, P_R = 40.0, 3.0e5
DYN = DynamicParameters(ALPHA_V, P_R)
SPEED, AMP, T_FIRST = 1.2e-3, 2.0e-3, 0.7371
INP = triangle_input(SPEED, AMP, 0.0, T_FIRST, cycles=2)
RATE = 1234.0
#: Composed kernel (rtol 1e-9) vs reference Radau (rtol 1e-10): relative L2 error of the force. Both are
#: accurate to ~1e-7 here; every effect below changes the force by more than 1e-3 relative (checked), so a
#: slip in an effect's physics cannot hide under the tolerance.
REF_RTOL = 2e-6
#: The new effects, each at a clearly visible strength on this damper (rig-A sized, 1.2 mm/s).
NEW = {
    "poppet_valve": {"natural_frequency_Hz": 5.0, "damping_ratio": 0.2, "cracking_pressure_Pa": 1.0e5,
                     "span_Pa": 5.0e5},
    "gas_spring": {"stiffness_N_per_m": 2.0e5},
    "load_cell_offset": {"offset_N": -80.0},
    "mains_interference": {"cos_amplitude_N": 20.0, "sin_amplitude_N": -15.0, "frequency_Hz": 50.0},
    "command_displacement": {"bandwidth_Hz": 8.0, "damping_ratio": 0.4},
    "leakage": {"conductance_m3_per_s_Pa": 2.0e-12},
    "seal_friction": {"stribeck_N": 150.0, "stribeck_velocity_m_s": 2.0e-4, "viscous_Ns_per_m": 5.0e4},
    "unnamed_dynamics": {"gain": 2.0e-3, "natural_frequency_Hz": 1.7, "damping_ratio": 0.2, "threshold": 1.0e5,
                         "driver": 0, "law": 2, "placement": 0},
}
CASES = [(n, {n: v}) for n, v in NEW.items()] + [
    ("unnamed_flow_q", {"unnamed_dynamics": {"gain": 0.3, "natural_frequency_Hz": 3.0, "damping_ratio": 0.5,
                                             "driver": 1, "law": 0, "placement": 1}}),
    ("unnamed_y_sign", {"unnamed_dynamics": {"gain": 60.0, "natural_frequency_Hz": 2.0, "damping_ratio": 0.7,
                                             "threshold": 1e-4, "driver": 2, "law": 3, "placement": 0}}),
    ("unnamed_transient_v", {"unnamed_dynamics": {"gain": -5.0e5, "natural_frequency_Hz": 5.0, "damping_ratio": 0.5,
                                                  "driver": 3, "law": 0, "placement": 0, "mode": 1}}),
    ("unnamed_transient_flow", {"unnamed_dynamics": {"gain": 0.2, "natural_frequency_Hz": 5.0, "damping_ratio": 1.0,
                                                     "driver": 1, "law": 0, "placement": 1, "mode": 1}}),
    ("poppet+friction", {"poppet_valve": NEW["poppet_valve"], "seal_friction": NEW["seal_friction"]}),
    # a large bleed: the valve adds a third of the path's flow fully open, and opens fully within the transient
    ("poppet_bleed", {"poppet_valve": {"natural_frequency_Hz": 2.0, "damping_ratio": 0.15,
                                       "cracking_pressure_Pa": 5.0e4, "span_Pa": 2.0e5, "bleed_fraction": 2.0}}),
    ("command+leakage+offset", {"command_displacement": NEW["command_displacement"], "leakage": NEW["leakage"],
                                "load_cell_offset": NEW["load_cell_offset"]}),
]
#: (t0, v_prev): the first step from rest, and the first reversal.
STARTS = {"rest": (T_FIRST, 0.0), "reversal": (T_FIRST + AMP / SPEED, SPEED)}


def _times(t0):
    return t0 + (np.arange(0, int(2.5 * RATE)) + 0.37) / RATE


def _ours(effects, t0, v_prev, dp0):
    kt, ky = INP.knots(t0 + 3.0)
    return simulate_effects(_times(t0), PiecewiseLinear(kt, ky), D, FLOW, DYN, effects, dp0=dp0, t0=t0,
                            rtol=1e-9, atol=1e-4)


def _reference(effects, t0, v_prev, dp0):
    return reference_simulate(INP, _times(t0), RIG_A, REF_FLOW, ALPHA_V, P_R, effects, dp0=dp0, t0=t0,
                              v_prev=v_prev, rtol=1e-10, atol=1e-6)


@pytest.mark.parametrize("start", list(STARTS))
@pytest.mark.parametrize("name,effects", CASES, ids=[c[0] for c in CASES])
def test_new_effects_match_the_independent_reference(name, effects, start):
    t0, v_prev = STARTS[start]
    dp0 = float(quasi_static_dp(D.piston_area * v_prev, REF_FLOW))
    ref = _reference(effects, t0, v_prev, dp0)
    got = _ours(effects, t0, v_prev, dp0)
    err = float(np.linalg.norm(got - ref) / np.linalg.norm(ref))
    plain = _reference(None, t0, v_prev, dp0)
    size = float(np.linalg.norm(ref - plain) / np.linalg.norm(ref))
    assert err < REF_RTOL, (name, start, err)
    assert size > 500 * REF_RTOL, (name, start, size)  # the effect is visible at this tolerance


def test_after_a_reversal_the_flow_meets_the_closed_check_valve_of_its_new_direction():
    """``check_valves``, a check valve for each flow direction (the reference's poppet with ``per_direction`` 1):
    after a reversal the flow passes the other valve, which opens from its seat while the one that carried the flow
    closes. The poppet valve's one element, passing either direction, meets an open valve instead. After a start
    from rest the two are the same; after a reversal the kernel follows the reference's check valves, and the single
    element differs from them by far more than the tolerance."""
    valves = {"check_valves": NEW["poppet_valve"]}
    per_direction = {"poppet_valve": {**NEW["poppet_valve"], "per_direction": 1}}
    for start, differs in (("rest", False), ("reversal", True)):
        t0, v_prev = STARTS[start]
        dp0 = float(quasi_static_dp(D.piston_area * v_prev, REF_FLOW))
        ref = _reference(per_direction, t0, v_prev, dp0)
        assert float(np.linalg.norm(_ours(valves, t0, v_prev, dp0) - ref) / np.linalg.norm(ref)) < REF_RTOL
        ramp = _times(t0) < t0 + AMP / SPEED  # up to the next reversal
        gap = float(np.linalg.norm((_ours({"poppet_valve": NEW["poppet_valve"]}, t0, v_prev, dp0) - ref)[ramp])
                    / np.linalg.norm(ref[ramp]))
        assert (gap > 500 * REF_RTOL) if differs else (gap < REF_RTOL), (start, gap)


def test_initial_dp_from_the_step_force_includes_every_effect_force():
    """from_force: Δp0 is solved so that the force in the steady state before the step is the step force."""
    kt, ky = INP.knots(8.0)
    t0 = STARTS["reversal"][0]
    eff = {"friction": {"coulomb_N": 300.0}, "load_cell_offset": {"offset_N": -120.0},
           "gas_spring": {"stiffness_N_per_m": 1e5}}
    dp0 = 2.0e5
    y0 = float(np.interp(t0, kt, ky))
    f_step = D.piston_area * dp0 + 300.0 - 120.0 + 1e5 * y0  # friction at v_prev = +1.2 mm/s (tanh saturated)
    c = compose(eff)
    t = _times(t0)
    drive = c.transform_input(PiecewisePolynomial.from_knots(kt, ky))
    f_a, s_a = solve_composed(c, t, drive, t0, dp0, SPEED, D, FLOW.as_array(), ALPHA_V, P_R, 1e-8, 1e-3)
    f_b, s_b = solve_composed(c, t, drive, t0, f_step, SPEED, D, FLOW.as_array(), ALPHA_V, P_R, 1e-8, 1e-3,
                              from_force=True)
    assert s_a == s_b == STATUS_OK
    assert np.max(np.abs(f_a - f_b)) < 1e-6 * np.max(np.abs(f_a))


def test_non_physical_solve_is_a_failed_status_never_nan_to_the_sampler():
    kt, ky = INP.knots(8.0)
    t0 = STARTS["rest"][0]
    time = _times(t0)[:200]
    # a displacement 400 times larger empties chamber 1 (V_01 / A_P = 36 mm) within the window; the window starts
    # settled at rest (step force 0)
    drive = PiecewisePolynomial.from_knots(kt, ky * 400.0)
    prob = EffectsProblem("t", time, np.zeros(time.size), t0, 0.0, 0.0, drive, D, FLOW)
    force, ok = prob.simulate_force(ALPHA_V, P_R, effect_argument({"gas_spring": {}}))
    assert not ok and force.shape == time.shape
    force, ok = prob.simulate_force(ALPHA_V, P_R, effect_argument({"gas_spring": {}}))  # the cached input
    assert not ok
    # inf * 0 inside a hook (an infinite poppet frequency) is a failed status, not an exception or NaN
    bad = ComposedEffects(("poppet_valve",), np.array([math.inf, 0.2, 1e5, 1e6, 0.1]))
    _, status = solve_composed(bad, time, PiecewisePolynomial.from_knots(kt, ky), t0, 0.0, 0.0, D, FLOW.as_array(),
                               ALPHA_V, P_R, 1e-8, 1e-3)
    assert status != STATUS_OK


def test_effect_argument_and_round_trip():
    """Every effect set, the first effects' included, is a ComposedEffects; as_dict gives the completed set back."""
    for effects in (None, {"friction": {}}, {"poppet_valve": {}, "friction": {"coulomb_N": 50.0}}):
        assert isinstance(effect_argument(effects), ComposedEffects)
    arg = effect_argument({"poppet_valve": {}, "friction": {"coulomb_N": 50.0}})
    assert arg.names == ("friction", "poppet_valve")  # registry order
    back = arg.as_dict()
    assert back["friction"]["coulomb_N"] == 50.0
    assert back["poppet_valve"] == EFFECTS["poppet_valve"].defaults()
    assert effect_argument(back).as_dict() == back and np.array_equal(effect_argument(back).values, arg.values)
    assert effect_argument(None).names == () and effect_argument(None).values.size == 0
    with pytest.raises(SettingsError, match="unknown effect"):
        effect_argument({"gravity": {}})



def test_the_library_holds_what_the_issue_names():
    assert {"poppet_valve", "seal_friction", "two_state", "gas_spring", "load_cell_offset", "mains_interference",
            "command_displacement", "leakage", "unnamed_dynamics", "constant_bulk_modulus"} <= set(EFFECT_NAMES)
    lay, n_states = layout(("friction", "two_state"))
    assert n_states == 2 and int(lay[:, L_ACTIVE].sum()) == 2  # Δp and the two-state model's mean pressure
    src = kernel_source()
    i = list(EFFECT_MODULES).index("two_state")
    assert f"p1, p2 = _e{i}.pressures(" in src and f"b1, b2 = _e{i}.moduli(" in src
    assert "    if absolute:" in src and "loaded = _bulk" in src  # eq. (6) only without absolute pressures
    with pytest.raises(SettingsError, match="bulk moduli"):
        layout(("constant_bulk_modulus", "two_state"))
    assert not EFFECTS["constant_bulk_modulus"].candidate and EFFECTS["two_state"].candidate


def test_signed_and_infinite_parameters_are_checked():
    e = EFFECTS["load_cell_offset"]
    assert e.complete({"offset_N": -40.0})["offset_N"] == -40.0
    with pytest.raises(SettingsError, match="offset_N must be finite"):
        e.complete({"offset_N": math.inf})
    with pytest.raises(SettingsError, match="must be finite and >= 0"):
        EFFECTS["gas_spring"].complete({"stiffness_N_per_m": -1.0})
    assert EFFECTS["command_displacement"].complete({"bandwidth_Hz": math.inf})["bandwidth_Hz"] == math.inf
