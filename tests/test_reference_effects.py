"""Self-checks of the independent effect simulator (tests/reference_effects.py), without bayesdamper.

Rig-A (tests/independent.py) on a 1 mm/s, 2 mm triangle: each ramp lasts 2 s. The plateau checks use a
nearly gas-free fluid (α_V = 1000, p_R = 150 kPa: Δp relaxes with τ < 50 ms), so the last 0.5 s of the
rising ramp (> 30 τ after the reversal) is a steady plateau; the other checks use α_V = 60 (τ up to ~0.5 s).

The pseudo-effect ``fluid_inertance`` (L dQ_L/dt = Δp - Δp_O(Q_L)) is checked with L_RING = 9.24e9 kg/m^4,
the Helmholtz frequency sqrt(K/L) = 2π 5 Hz at the plateau Δp = 863 kPa with α_V = 1000
(K = B_1/V_01 + B_2/V_02 = 9.12e12 Pa/m^3; R = dΔp_O/dQ = 3.87e11 Pa s/m^3, so ζ = R/(2 sqrt(K L)) = 0.67 and
the decay rate R/(2L) = 21/s: gone, e^-31, by the plateau), and with a tiny L = 1e3 kg/m^4 (lag L/R < 1.2e-7 s).

The physical two-state base ``two_state_damper`` (eq. (1) with eq. (2)'s polytropic gas referenced to atmospheric
pressure, an accumulator behind a line and check valves) is checked against eq. (2)'s definition -V dp/dV, its
limits (p -> ∞, p_0, p -> 0), a chamber pinned at the charge by a large accumulator and a fast line (an independent
one-chamber ODE), the plateau of eq. (4) after the refill, shut check valves while both chambers are above the
accumulator, the liquid-volume balance of chambers and accumulator, and positive pressures without refill; the
mount ``series_compliance`` against ``reference_cycles.simulate_compliant``.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from independent import (
    PAPER_FLOW,
    RIG_A,
    SMALL,
    SMALL_FLOW,
    orifice_flow,
    quasi_static_dp,
    simulate,
    sine_input,
    triangle_input,
)
from reference_effects import (
    EFFECT_PARAMS,
    alpha_for_gas_fraction,
    gas_fraction,
    inertance_for_frequency,
    line_flow,
    polytropic_bulk_modulus,
    resolve_effects,
    simulate_effects,
    state_names,
)
from scipy.integrate import cumulative_simpson, solve_ivp
from scipy.optimize import brentq

ALPHA_V, P_R = 60.0, 1.5e5
ALPHA_STIFF = 1e3  # plateau checks: B(p_R + Δp) ~ 1.2 GPa at 860 kPa, τ = V / (B dQ/dΔp) ~ 45 ms
SPEED, AMPLITUDE, T_FIRST = 1e-3, 2e-3, 0.2537  # [m/s], [m], [s]: the first step off the 5 ms grid
INP = triangle_input(SPEED, AMPLITUDE, 0.0, T_FIRST, cycles=0.5)  # up 2 s, down 2 s, then rest
T = np.arange(0.0, 4.5, 1 / 200)
RAMP_UP = (T > T_FIRST + 1.5) & (T < T_FIRST + 2.0)  # last 0.5 s of the rising ramp (> 7 relaxation times)
AREA = RIG_A["area"]
DP_PLATEAU = float(quasi_static_dp(AREA * SPEED, PAPER_FLOW))  # 862.6 kPa: eq. (4) at Q = A v, F = 3623 N
#: Ringing inertance: 5 Hz Helmholtz resonance at the plateau with α_V = 1000 (9.24e9 kg/m^4, ζ = 0.67).
L_RING = inertance_for_frequency(5.0, RIG_A, PAPER_FLOW, ALPHA_STIFF, P_R, DP_PLATEAU)

#: Same equations, same Radau, same tolerances (rtol 1e-10): only the step sequences may differ.
NO_EFFECT_RTOL = 1e-6
#: An effect at its "off" value: the extra states change the error norm, not the equations (rtol 1e-10).
OFF_RTOL = 1e-8
#: Radau rtol 1e-8 vs 1e-11 with three stiff effects (relative L2): global error <= 10 rtol (seen: 4e-11).
CONVERGENCE_RTOL = 1e-7
#: Plateau force vs an algebraic steady state (exact: the volumes drop out of it): after > 30 relaxation
#: times the transient is < 1e-12 of Δp, so 1e-6 only has to cover the rtol 1e-10 integration error.
PLATEAU_RTOL = 1e-6
#: Poppet at 10 kHz, ζ 1 vs the quasi-static flow: lift lag 2ζ/ω = 32 µs times ds/dt <= 10/s over
#: ε + s >= 0.1 gives a < 3e-3 flow error at the reversals only (relative L2 of the force ~1e-4).
FAST_POPPET_RTOL = 1e-3
#: Small-signal ringing vs the linearised ω_d = sqrt(K/L) sqrt(1 - ζ^2) at y = 0: the chamber volumes drift
#: by < 0.2 % over the first two half periods (seen: 0.3 % on the half period, 1 % on the decay ratio).
HELMHOLTZ_RTOL = 0.01


def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
    """Relative L2 distance ||a - b|| / ||b||."""
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def run(effects: dict | None = None, alpha_v: float = ALPHA_V, **kw) -> np.ndarray | dict:
    """The reference simulator on the module's triangle record."""
    return simulate_effects(INP, T, RIG_A, PAPER_FLOW, alpha_v, P_R, effects, **kw)


@pytest.fixture(scope="module")
def bare() -> np.ndarray:
    """Force without effects [N]."""
    return run()


def steady_dp(conductance: float) -> float:
    """Δp [Pa] on the rising ramp with a linear leak: Q_O(Δp) + G Δp = A_P v (eq. (8) + leak)."""
    q = AREA * SPEED
    return brentq(lambda dp: orifice_flow(dp, PAPER_FLOW) + conductance * dp - q, 0.0, 1e8, xtol=1e-9, rtol=1e-14)


# ----------------------------------------------------------------------------- independence, API
def test_reference_imports_nothing_from_bayesdamper():
    for name in ("reference_effects.py", "test_reference_effects.py"):
        tree = ast.parse((Path(__file__).parent / name).read_text())
        mods = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        mods += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        assert mods and not any(m.split(".")[0] == "bayesdamper" for m in mods)


@pytest.mark.parametrize("bad", [
    {"no_such_effect": {}},
    {"leakage": {"conductance": 1e-12}},
    {"leakage": {}},
    {"unnamed_dynamics": {"gain": 1.0, "natural_frequency_Hz": 1.0, "damping_ratio": 0.5, "law": 3}},
    {"unnamed_dynamics": {"gain": 1.0, "natural_frequency_Hz": 1.0, "damping_ratio": 0.5, "driver": 4}},
    {"poppet_valve": {"natural_frequency_Hz": 1.0, "damping_ratio": 0.5, "cracking_pressure_Pa": math.nan}},
    {"unnamed_dynamics": {"gain": 1.0, "natural_frequency_Hz": 1.0, "damping_ratio": 0.5, "mode": 2}},
    {"unnamed_dynamics": {"gain": 1.0, "natural_frequency_Hz": 1.0, "damping_ratio": 0.5, "mode": 0.5}},
    {"fluid_inertance": {}},
    {"fluid_inertance": {"inertance_kg_per_m4": 0.0}},
    {"fluid_inertance": {"inertance_kg_per_m4": -1e9}},
    {"two_state_damper": {"polytropic_exponent": 0.9, "liquid_gas_ratio_atm": 10.0, "charge_pressure_Pa": 5e5,
                          "accumulator_volume_m3": 1e-3, "line_conductance_m3_per_s_Pa": 1e-11}},
    {"two_state_damper": {"polytropic_exponent": 1.4, "liquid_gas_ratio_atm": 0.0, "charge_pressure_Pa": 5e5,
                          "accumulator_volume_m3": 1e-3, "line_conductance_m3_per_s_Pa": 1e-11}},
    {"two_state_damper": {"polytropic_exponent": 1.4, "liquid_gas_ratio_atm": 10.0, "charge_pressure_Pa": 5e5,
                          "accumulator_volume_m3": 1e-3}},
    {"two_state_damper": {"polytropic_exponent": 1.4, "liquid_gas_ratio_atm": 10.0, "charge_pressure_Pa": 5e5,
                          "accumulator_volume_m3": 1e-3, "line_conductance_m3_per_s_Pa": 1e-11,
                          "bleed_conductance_m3_per_s_Pa": -1e-13}},
    {"two_state_damper": {"polytropic_exponent": 1.4, "liquid_gas_ratio_atm": 10.0, "charge_pressure_Pa": 5e5,
                          "accumulator_volume_m3": 1e-3, "line_conductance_m3_per_s_Pa": 1e-11},
     "accumulator": {"charge_pressure_Pa": 5e5, "conductance_m3_per_s_Pa": 1e-11}},  # two bases
    {"series_compliance": {"stiffness_N_per_m": 0.0}},
    {"series_compliance": {"stiffness_N_per_m": 2e7}, "seal_friction": {"stribeck_N": 1.0,
                                                                        "stribeck_velocity_m_s": 1e-3,
                                                                        "viscous_Ns_per_m": 0.0}},
    {"series_compliance": {"stiffness_N_per_m": 2e7}, "gas_spring": {"stiffness_N_per_m": 1e4}},
])
def test_bad_effects_raise(bad):
    with pytest.raises(ValueError):
        resolve_effects(bad)


def test_defaults_and_state_order():
    fx = resolve_effects({"unnamed_dynamics": {"gain": 1.0, "natural_frequency_Hz": 2.0, "damping_ratio": 0.3},
                          "mains_interference": {"cos_amplitude_N": 1.0, "sin_amplitude_N": -1.0},
                          "poppet_valve": {"natural_frequency_Hz": 50.0, "damping_ratio": 0.5,
                                           "cracking_pressure_Pa": 1e5}})
    assert fx["mains_interference"]["frequency_Hz"] == 50.0 and fx["poppet_valve"]["span_Pa"] == 1e6
    assert (fx["unnamed_dynamics"]["threshold"], fx["unnamed_dynamics"]["driver"]) == (0.0, 0)
    assert fx["unnamed_dynamics"]["mode"] == 0 and isinstance(fx["unnamed_dynamics"]["mode"], int)
    assert state_names(fx) == ("dp", "valve_lift", "valve_rate", "valve_lift_reverse", "valve_rate_reverse", "w",
                               "w_dot")
    assert state_names({"fluid_inertance": {"inertance_kg_per_m4": 1e9}, **fx})[-1] == "q_l"
    assert state_names({name: {} for name in ()}) == ("dp",)


# ----------------------------------------------------------------------------- no effects, "off" values
def test_no_effects_equals_independent_simulate(bare):
    ref = simulate(INP, T, RIG_A, PAPER_FLOW, ALPHA_V, P_R, rtol=1e-10)
    assert 3000.0 < np.max(np.abs(ref)) < 5000.0  # rig-A's kN forces at 1 mm/s
    assert rel_l2(bare, ref) < NO_EFFECT_RTOL


def test_no_effects_equals_independent_simulate_on_a_ramped_sine():
    """The smooth-input path (no triangle shortcut): SMALL damper, 10 mm at 1 Hz ramped in over half a cycle."""
    inp, t = sine_input(0.01, 1.0, ramp_cycles=0.5), np.arange(0.0, 1.5, 1 / 500)
    ref = simulate(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, rtol=1e-10)
    got = simulate_effects(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5)
    assert np.max(np.abs(ref)) > 100.0 and rel_l2(got, ref) < NO_EFFECT_RTOL


OFF_VALUES = {
    "poppet_valve": {"natural_frequency_Hz": 100.0, "damping_ratio": 0.5, "cracking_pressure_Pa": -1e12},  # s ≡ 1
    "gas_spring": {"stiffness_N_per_m": 0.0},
    "load_cell_offset": {"offset_N": 0.0},
    "mains_interference": {"cos_amplitude_N": 0.0, "sin_amplitude_N": 0.0},
    "leakage": {"conductance_m3_per_s_Pa": 0.0},
    "seal_friction": {"stribeck_N": 0.0, "stribeck_velocity_m_s": 1e-3, "viscous_Ns_per_m": 0.0},
    "unnamed_dynamics": {"gain": 0.0, "natural_frequency_Hz": 5.0, "damping_ratio": 0.3},
}
UNNAMED_VARIANTS = [dict(driver=1, law=1, placement=1), dict(driver=2, law=2, threshold=1e-3),
                    dict(driver=3, law=3, threshold=1e-4, placement=1), dict(driver=3, law=0, mode=1)]
OFF_CASES = [pytest.param({k: v}, id=k) for k, v in OFF_VALUES.items()] + [
    pytest.param({"unnamed_dynamics": {**OFF_VALUES["unnamed_dynamics"], **u}}, id=f"unnamed_dynamics-law{u['law']}")
    for u in UNNAMED_VARIANTS]


@pytest.mark.parametrize("effects", OFF_CASES)
def test_effect_at_off_value_is_no_effect(effects, bare):
    assert rel_l2(run(effects), bare) < OFF_RTOL


def test_fast_servo_is_a_pure_delay(bare):
    """1e5 Hz servo, ζ 1: for slow signals a delay 2ζ/ω, so |ΔF| <= 2 (2ζ/ω) |dF/dt| (relative L2)."""
    tau = 2.0 * 1.0 / (2.0 * np.pi * 1e5)
    f = run({"command_displacement": {"bandwidth_Hz": 1e5, "damping_ratio": 1.0}})
    bound = 2.0 * tau * np.linalg.norm(np.gradient(bare, T)) / np.linalg.norm(bare)
    assert 1e-6 < bound < 1e-4
    assert rel_l2(f, bare) < bound


def test_fast_poppet_follows_the_orifice_law(bare):
    """f_v = 10 kHz, ζ 1, cracking 200 kPa: the lift tracks s(Δp), so the flow is eq. (8) (see FAST_POPPET_RTOL)."""
    out = run({"poppet_valve": {"natural_frequency_Hz": 1e4, "damping_ratio": 1.0, "cracking_pressure_Pa": 2e5}},
              return_states=True)
    assert rel_l2(out["force"], bare) < FAST_POPPET_RTOL
    s = np.clip((np.abs(out["dp"]) - 2e5) / 1e6, 0.0, 1.0)
    assert np.max(np.abs(out["valve_lift"] - s)) < 1e-3 and np.ptp(s) > 0.3  # it does open and close


def test_tolerance_convergence_with_three_effects():
    effects = {"command_displacement": {"bandwidth_Hz": 20.0, "damping_ratio": 0.6},
               "poppet_valve": {"natural_frequency_Hz": 200.0, "damping_ratio": 0.4, "cracking_pressure_Pa": 1e5},
               "unnamed_dynamics": {"gain": 3e-13, "natural_frequency_Hz": 3.0, "damping_ratio": 0.2,
                                    "law": 1, "placement": 1}}
    loose, tight = run(effects, rtol=1e-8), run(effects, rtol=1e-11)
    assert rel_l2(loose, tight) < CONVERGENCE_RTOL


# ----------------------------------------------------------------------------- force terms
def test_additive_force_terms(bare):
    """Offset, gas spring, mains and seal friction add their closed forms to the force (no state change)."""
    rng = np.random.default_rng(20240611)
    f0, k_g, a_c, a_s = rng.uniform(-200.0, 200.0), rng.uniform(1e4, 1e5), rng.uniform(-5, 5), rng.uniform(-5, 5)
    f_m, f_s, v_st, c_v = rng.uniform(45.0, 65.0), rng.uniform(10.0, 50.0), 4e-4, rng.uniform(1e3, 1e4)
    y, v = INP.displacement(T), INP.velocity(T)
    scale = np.max(np.abs(bare))
    assert np.allclose(run({"load_cell_offset": {"offset_N": f0}}) - bare, f0, rtol=0, atol=1e-9 * scale)
    assert np.allclose(run({"gas_spring": {"stiffness_N_per_m": k_g}}) - bare, k_g * y, rtol=0, atol=1e-9 * scale)
    mains = a_c * np.cos(2 * np.pi * f_m * T) + a_s * np.sin(2 * np.pi * f_m * T)
    got = run({"mains_interference": {"cos_amplitude_N": a_c, "sin_amplitude_N": a_s, "frequency_Hz": f_m}})
    assert np.allclose(got - bare, mains, rtol=0, atol=1e-9 * scale)
    friction = np.tanh(v / 1e-5) * f_s * np.exp(-(v / v_st) ** 2) + c_v * v
    got = run({"seal_friction": {"stribeck_N": f_s, "stribeck_velocity_m_s": v_st, "viscous_Ns_per_m": c_v}})
    assert np.allclose(got - bare, friction, rtol=0, atol=1e-9 * scale) and np.ptp(friction) > 1.0


# ----------------------------------------------------------------------------- steady plateaus
def test_leakage_plateau_force():
    g_l = 1e-12
    dp = steady_dp(g_l)
    assert dp < 0.9 * float(quasi_static_dp(AREA * SPEED, PAPER_FLOW))  # the leak matters
    f = run({"leakage": {"conductance_m3_per_s_Pa": g_l}}, ALPHA_STIFF)
    assert np.allclose(f[RAMP_UP], AREA * dp, rtol=PLATEAU_RTOL, atol=0)


def test_unnamed_flow_path_on_dp_is_a_leak_on_the_plateau():
    """placement 1, driver Δp, linear: Q += g w with w -> Δp, so the plateau is the leakage one (G_l = g)."""
    f = run({"unnamed_dynamics": {"gain": 1e-12, "natural_frequency_Hz": 20.0, "damping_ratio": 0.7,
                                  "placement": 1}}, ALPHA_STIFF)
    assert np.allclose(f[RAMP_UP], AREA * steady_dp(1e-12), rtol=PLATEAU_RTOL, atol=0)


def test_unnamed_force_output_on_flow_driver():
    """placement 0, driver Q_O, dead zone θ: on the plateau w = Q_O - θ = A v - θ, so F = A Δp + g (A v - θ)."""
    gain, theta = -2e8, 1e-6  # [N s/m^3], [m^3/s]: -640 N
    out = run({"unnamed_dynamics": {"gain": gain, "natural_frequency_Hz": 15.0, "damping_ratio": 0.5,
                                    "driver": 1, "law": 2, "threshold": theta}}, ALPHA_STIFF, return_states=True)
    dp = float(quasi_static_dp(AREA * SPEED, PAPER_FLOW))
    want = AREA * dp + gain * (AREA * SPEED - theta)
    assert np.allclose(out["force"][RAMP_UP], want, rtol=PLATEAU_RTOL, atol=0)
    assert out["w"][0] == 0.0  # at rest: L(Q_O(0)) = 0


def test_accumulator_without_line_keeps_the_orifice_plateau():
    """p_a = 1 GPa, G = 0: a stiffer transient, but on the plateau Q = A v fixes Δp (eq. (4))."""
    bare = run(alpha_v=ALPHA_STIFF)
    f = run({"accumulator": {"charge_pressure_Pa": 1e9, "conductance_m3_per_s_Pa": 0.0}}, ALPHA_STIFF)
    want = AREA * float(quasi_static_dp(AREA * SPEED, PAPER_FLOW))
    assert np.allclose(f[RAMP_UP], want, rtol=PLATEAU_RTOL, atol=0)
    assert np.allclose(bare[RAMP_UP], want, rtol=PLATEAU_RTOL, atol=0)
    assert rel_l2(f, bare) > 0.01  # the transients differ: the check can fail


def test_accumulator_refill_holds_the_unloaded_chamber_at_the_charge():
    """Check-valve refill: on the plateau Q = A v (eq. (4)) and the unloaded chamber sits at p_a (p̄ = p_a + Δp/2)."""
    p_a, g = 5e5, 1e-9
    out = run({"accumulator": {"charge_pressure_Pa": p_a, "conductance_m3_per_s_Pa": g}}, ALPHA_STIFF,
              return_states=True)
    assert out["p_mean"][0] == p_a
    dp = float(quasi_static_dp(AREA * SPEED, PAPER_FLOW))
    assert np.allclose(out["force"][RAMP_UP], AREA * dp, rtol=PLATEAU_RTOL, atol=0)
    assert np.allclose(out["p_mean"][RAMP_UP], p_a + 0.5 * dp, rtol=1e-3, atol=0)


# ----------------------------------------------------------------------------- servo
def test_servo_starts_in_ramp_tracking_and_rings_at_the_reversal():
    """Started mid-ramp (v_prev = v): y_P = y_A - 2ζv/ω, F = A Δp(Av) + k_g y_P, steady until the reversal;
    then v_P is the second-order step response to the -2v velocity step."""
    f_s, zeta, k_g = 4.0, 0.3, 5e4
    w = 2.0 * np.pi * f_s
    t0 = 1.0
    t = T[T >= t0]
    out = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R,
                           {"command_displacement": {"bandwidth_Hz": f_s, "damping_ratio": zeta},
                            "gas_spring": {"stiffness_N_per_m": k_g}}, return_states=True)
    ramp = t < T_FIRST + 2.0
    y_p = INP.displacement(t) - 2.0 * zeta * SPEED / w
    assert np.allclose(out["y_p"][ramp], y_p[ramp], rtol=0, atol=1e-12)
    assert np.allclose(out["v_p"][ramp], SPEED, rtol=1e-9, atol=0)
    want = AREA * float(quasi_static_dp(AREA * SPEED, PAPER_FLOW)) + k_g * y_p[ramp]
    assert np.allclose(out["force"][ramp], want, rtol=1e-9, atol=0)
    back = (t > T_FIRST + 2.0) & (t < T_FIRST + 4.0)
    tau = t[back] - (T_FIRST + 2.0)
    wd = w * math.sqrt(1.0 - zeta**2)
    step = 1.0 - np.exp(-zeta * w * tau) * (np.cos(wd * tau) + zeta / math.sqrt(1.0 - zeta**2) * np.sin(wd * tau))
    assert np.allclose(out["v_p"][back], SPEED - 2.0 * SPEED * step, rtol=0, atol=1e-9 * SPEED)


def test_default_v_prev_is_the_velocity_just_before_t0():
    """t0 on the first velocity step: v_prev = 0, so Δp starts at 0 (the right value would give eq. (4))."""
    t = T[T >= T_FIRST]
    t = np.concatenate(([T_FIRST], t))
    dp = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, return_states=True)["dp"]
    assert dp[0] == 0.0 and dp[-1] < 0.0
    dp = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, v_prev=SPEED, return_states=True)["dp"]
    assert dp[0] == float(quasi_static_dp(AREA * SPEED, PAPER_FLOW))


def test_every_effect_at_once_runs_and_reports_every_state():
    effects = {"command_displacement": {"bandwidth_Hz": 30.0, "damping_ratio": 0.7},
               "poppet_valve": {"natural_frequency_Hz": 150.0, "damping_ratio": 0.5, "cracking_pressure_Pa": 5e4},
               "accumulator": {"charge_pressure_Pa": 2e6, "conductance_m3_per_s_Pa": 1e-12},
               "gas_spring": {"stiffness_N_per_m": 2e4}, "load_cell_offset": {"offset_N": -12.0},
               "mains_interference": {"cos_amplitude_N": 2.0, "sin_amplitude_N": -1.0},
               "leakage": {"conductance_m3_per_s_Pa": 2e-13},
               "seal_friction": {"stribeck_N": 20.0, "stribeck_velocity_m_s": 5e-4, "viscous_Ns_per_m": 3e3},
               "unnamed_dynamics": {"gain": 1e-4, "natural_frequency_Hz": 1.7, "damping_ratio": 0.25, "mode": 1},
               "fluid_inertance": {"inertance_kg_per_m4": 1e9}}
    # every effect but the two-state base (one base at a time) and the mount (not with friction or the filter)
    assert list(effects) == [n for n in EFFECT_PARAMS if n not in ("two_state_damper", "series_compliance")]
    out = run(effects, return_states=True)
    assert set(out) == {"t", "force", *state_names(effects)} and len(state_names(effects)) == 11
    assert all(np.all(np.isfinite(v)) for v in out.values())


# ----------------------------------------------------------------------------- unnamed filter, mode 1
def test_unnamed_transient_mode_on_the_force_is_mode_0_minus_the_steady_part():
    """placement 0, driver v_P: the states do not depend on the mode, so F_0 - F_1 = g L(u) = g v exactly;
    mode 1's term g (w - v) is -g Δv right after a velocity step and gone (e^-23) by the plateau."""
    gain = -5e5  # [N s/m]: 500 N, 14 % of the plateau force, at 1 mm/s
    ud = {"gain": gain, "natural_frequency_Hz": 5.0, "damping_ratio": 0.5, "driver": 3}
    bare = run(alpha_v=ALPHA_STIFF)
    mode0 = run({"unnamed_dynamics": ud}, ALPHA_STIFF)
    mode1 = run({"unnamed_dynamics": {**ud, "mode": 1}}, ALPHA_STIFF)
    scale = AREA * DP_PLATEAU
    assert np.allclose(mode0 - mode1, gain * INP.velocity(T), rtol=0, atol=1e-9 * scale)  # seen: 5e-13 N
    assert np.allclose(mode1[RAMP_UP], bare[RAMP_UP], rtol=PLATEAU_RTOL, atol=0)  # seen: 8e-12 relative
    after = (T > T_FIRST) & (T < T_FIRST + 0.3)
    assert np.max(np.abs(mode1[after] - bare[after])) > 0.1 * scale  # seen: 0.138 (-g v at the first sample)


def test_unnamed_transient_mode_in_the_flow_path_vanishes_on_the_plateau():
    """placement 1, driver Q_O, g = 0.2: Q = Q_O + g (w - Q_O) is Q_O on the plateau, so Δp is eq. (4) at A v
    (mode 0 would give eq. (4) at A v / (1 + g)); right after the step w lags Q_O and the force differs."""
    gain = 0.2
    ud = {"gain": gain, "natural_frequency_Hz": 5.0, "damping_ratio": 1.0, "driver": 1, "placement": 1}
    bare = run(alpha_v=ALPHA_STIFF)
    mode1 = run({"unnamed_dynamics": {**ud, "mode": 1}}, ALPHA_STIFF)
    mode0 = run({"unnamed_dynamics": ud}, ALPHA_STIFF)
    scale = AREA * DP_PLATEAU
    assert np.allclose(mode1[RAMP_UP], bare[RAMP_UP], rtol=PLATEAU_RTOL, atol=0)  # seen: 6e-13 relative
    assert np.allclose(mode1[RAMP_UP], scale, rtol=PLATEAU_RTOL, atol=0)
    want0 = AREA * float(quasi_static_dp(AREA * SPEED / (1.0 + gain), PAPER_FLOW))
    assert np.allclose(mode0[RAMP_UP], want0, rtol=PLATEAU_RTOL, atol=0)
    after = (T > T_FIRST) & (T < T_FIRST + 0.3)
    assert np.max(np.abs(mode1[after] - bare[after])) > 0.05 * scale  # seen: 0.16


# ----------------------------------------------------------------------------- fluid inertance (pseudo-effect)
def test_inertance_for_frequency_is_k_over_omega_squared():
    b_hi = RIG_A["b0"] * (1 + ALPHA_STIFF) / (ALPHA_STIFF + RIG_A["b0"] * P_R / (P_R + DP_PLATEAU) ** 2)
    b_lo = RIG_A["b0"] * (1 + ALPHA_STIFF) / (ALPHA_STIFF + RIG_A["b0"] / P_R)
    k = (b_hi + b_lo) / RIG_A["v01"]  # v01 = v02
    assert math.isclose(L_RING, k / (2 * math.pi * 5.0) ** 2, rel_tol=1e-12)
    assert 9.2e9 < L_RING < 9.3e9
    # eq. (6) swaps B_1 and B_2 with the sign of Δp: the same K for a symmetric damper
    assert math.isclose(inertance_for_frequency(5.0, RIG_A, PAPER_FLOW, ALPHA_STIFF, P_R, -DP_PLATEAU), L_RING)
    with pytest.raises(ValueError):
        inertance_for_frequency(0.0, RIG_A, PAPER_FLOW, ALPHA_STIFF, P_R, DP_PLATEAU)


def test_tiny_inertance_is_no_effect(bare):
    """L = 1e3 kg/m^4: Q_L lags Q_O(Δp) by L/R <= L/min(C_L) = 1.2e-7 s, i.e. the force by about as much, so
    |ΔF| <= 2 (L/min C_L) |dF/dt| (relative L2; seen 1.3e-8 against a bound of 5.6e-7)."""
    inertance = 1e3
    out = run({"fluid_inertance": {"inertance_kg_per_m4": inertance}}, return_states=True)
    tau = inertance / min(PAPER_FLOW[0], PAPER_FLOW[2])
    bound = 2.0 * tau * np.linalg.norm(np.gradient(bare, T)) / np.linalg.norm(bare)
    assert 1e-7 < bound < 1e-5
    assert rel_l2(out["force"], bare) < bound
    q_o = np.array([orifice_flow(d, PAPER_FLOW) for d in out["dp"]])
    assert np.allclose(out["q_l"], q_o, rtol=0, atol=1e-5 * AREA * SPEED)
    assert out["q_l"][0] == 0.0  # at rest: Q_O(0)


def test_ringing_inertance_overshoots_then_settles_on_eq8():
    """L_RING after the first velocity step: the force overshoots the plateau by ~50 % (no inertance: a
    monotone rise), yet on the plateau the flow is eq. (8) again, so the force is the no-effect one."""
    bare = run(alpha_v=ALPHA_STIFF)
    out = run({"fluid_inertance": {"inertance_kg_per_m4": L_RING}}, ALPHA_STIFF, return_states=True)
    f, scale = out["force"], AREA * DP_PLATEAU
    after = (T > T_FIRST) & (T < T_FIRST + 1.0)
    assert np.max(np.abs(f[after] - bare[after])) > 0.01 * scale  # seen: 0.76
    assert np.max(f[after]) > 1.3 * scale and np.max(bare[after]) < scale  # seen: 1.50 and 1.0
    assert np.allclose(f[RAMP_UP], bare[RAMP_UP], rtol=PLATEAU_RTOL, atol=0)  # seen: 3e-13 relative
    assert np.allclose(f[RAMP_UP], scale, rtol=PLATEAU_RTOL, atol=0)
    assert np.allclose(out["q_l"][RAMP_UP], AREA * SPEED, rtol=PLATEAU_RTOL, atol=0)


def test_inertance_small_signal_ringing_matches_the_helmholtz_formula():
    """Start on the ramp 1 % above the plateau Δp (Q_L steady at it): Δp rings about the plateau with
    ω_d = ω_0 sqrt(1 - ζ^2), ω_0^2 = K/L = (2π 5 Hz)^2, ζ = R / (2 sqrt(K L)), losing e^(-π ζ/sqrt(1-ζ^2))
    per half period (see HELMHOLTZ_RTOL)."""
    r = PAPER_FLOW[0] + 2.0 * PAPER_FLOW[1] * AREA * SPEED  # dΔp_O/dQ at the plateau
    w0 = 2.0 * math.pi * 5.0
    zeta = r / (2.0 * math.sqrt(w0**2 * L_RING * L_RING))  # K = ω_0^2 L
    assert 0.6 < zeta < 0.7
    t0 = T_FIRST + 0.01
    t = np.arange(t0, t0 + 0.6, 1 / 4000)
    out = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_STIFF, P_R,
                           {"fluid_inertance": {"inertance_kg_per_m4": L_RING}}, dp0=1.01 * DP_PLATEAU, v_prev=SPEED,
                           return_states=True)
    x = out["dp"] - DP_PLATEAU
    i = np.nonzero(np.sign(x[1:]) != np.sign(x[:-1]))[0]
    crossings = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    half = math.pi / (w0 * math.sqrt(1.0 - zeta**2))  # 0.1340 s
    assert len(crossings) >= 3
    assert np.allclose(np.diff(crossings[:3]), half, rtol=HELMHOLTZ_RTOL, atol=0)  # seen: 0.1336, 0.1332 s
    peaks = [np.max(np.abs(x[(t > a) & (t < b)])) for a, b in zip(crossings[:2], crossings[1:3], strict=True)]
    ratio = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta**2))  # 0.0606
    assert math.isclose(peaks[1] / peaks[0], ratio, rel_tol=2 * HELMHOLTZ_RTOL)  # seen: 0.0613


def test_unnamed_flow_driver_is_the_inertance_flow():
    """With fluid_inertance, driver 1 is Q_L: a fast filter (200 Hz, ζ 1: lag 2ζ/ω = 1.6 ms) keeps w on Q_L,
    not on Q_O(Δp), while the two differ by more than A v during the ringing; mode 1 on the force adds exactly
    g (w - Q_L) to A Δp."""
    gain = 3e8  # [N s/m^3]
    out = run({"unnamed_dynamics": {"gain": gain, "natural_frequency_Hz": 200.0, "damping_ratio": 1.0, "driver": 1,
                                    "mode": 1}, "fluid_inertance": {"inertance_kg_per_m4": L_RING}},
              ALPHA_STIFF, return_states=True)
    extra = out["force"] - AREA * out["dp"]
    assert np.allclose(extra, gain * (out["w"] - out["q_l"]), rtol=0, atol=1e-9 * AREA * DP_PLATEAU)
    q_o = np.array([orifice_flow(d, PAPER_FLOW) for d in out["dp"]])
    assert np.max(np.abs(out["q_l"] - q_o)) > AREA * SPEED  # seen: 1.3 A v
    assert np.max(np.abs(out["w"] - out["q_l"])) < 0.2 * AREA * SPEED  # seen: 0.064 A v (1.3 if driven by Q_O)


def test_tolerance_convergence_with_fluid_inertance():
    effects = {"fluid_inertance": {"inertance_kg_per_m4": L_RING},
               "poppet_valve": {"natural_frequency_Hz": 200.0, "damping_ratio": 0.4, "cracking_pressure_Pa": 1e5},
               "unnamed_dynamics": {"gain": 0.2, "natural_frequency_Hz": 3.0, "damping_ratio": 0.3, "driver": 1,
                                    "placement": 1, "mode": 1}}
    loose, tight = run(effects, rtol=1e-8), run(effects, rtol=1e-11)
    assert rel_l2(loose, tight) < CONVERGENCE_RTOL


# ----------------------------------------------------------------------------- smooth inputs and rig effects
# (tests/reference_cycles.py: the reference driven by sines and random motion, with friction, backlash and a
# compliant mount; the records of tests/test_confusion_cycles.py)
#: Two independent Radau integrations of the same equations (independent.simulate vs simulate_effects, rtol 1e-10):
#: only their step sequences differ.
TWO_SIMULATORS_RTOL = 1e-6


def test_reference_cycles_imports_nothing_from_bayesdamper():
    tree = ast.parse((Path(__file__).parent / "reference_cycles.py").read_text())
    mods = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    mods += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert mods and not any(m.split(".")[0] == "bayesdamper" for m in mods)


def test_a_wrapped_input_is_integrated_on_its_one_sided_segments():
    """An abrupt stop (a velocity step, ``independent_records.stop_at``): simulate_effects reads the wrapper's
    ``on_segment`` like independent.simulate, so the two integrators agree, and the stop shows (the force relaxes)."""
    from independent_records import stop_at

    inp = stop_at(sine_input(0.01, 1.0), 1.13)
    t = np.arange(0.0, 2.0, 1 / 500)
    ref = simulate(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, rtol=1e-10)
    got = simulate_effects(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5)
    assert rel_l2(got, ref) < TWO_SIMULATORS_RTOL
    assert abs(got[-1]) < 1e-3 * np.max(np.abs(got))  # at rest after the stop: Δp has relaxed


def test_random_motion_drives_the_reference_like_independent_simulate():
    from independent_records import random_input

    inp = random_input(0.3, 3.0, seed=7, rms_displacement=0.003, resolution=0.05)
    t = np.arange(0.0, 3.0, 1 / 200)
    ref = simulate(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, t0=-1.0, rtol=1e-10)
    got = simulate_effects(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, t0=-1.0)
    assert np.max(np.abs(ref)) > 100.0 and rel_l2(got, ref) < TWO_SIMULATORS_RTOL


def test_play_operator_on_a_sine():
    """Sine A sin(ωt) behind a play g: after the top reversal (t = T/4) the piston rests at A - g/2 until
    A sin(ωt) = A - g, then follows at y_A + g/2; it never leaves the play, and moves at 0 or at v_A."""
    from reference_cycles import play_input

    a, f, gap = 0.005, 2.0, 4e-4
    inp = sine_input(a, f)
    play = play_input(inp, gap, 0.0, 1.0)
    w = 2 * math.pi * f
    t = np.linspace(0.0, 1.0, 20001)
    y_p, v_p, y_a, v_a = play.displacement(t), play.velocity(t), inp.displacement(t), inp.velocity(t)
    assert np.all(np.abs(y_a - y_p) <= 0.5 * gap * (1 + 1e-12))
    assert np.all((v_p == 0.0) | (v_p == v_a))
    t_contact = (math.pi - math.asin(1 - gap / a)) / w  # first time after T/4 with y_A = A - g
    rest = (t > 0.25 / f + 1e-6) & (t < t_contact - 1e-6)
    assert np.allclose(y_p[rest], a - 0.5 * gap, rtol=0, atol=1e-12) and np.all(v_p[rest] == 0.0)
    after = (t > t_contact + 1e-6) & (t < 0.75 / f)
    assert np.allclose(y_p[after], y_a[after] + 0.5 * gap, rtol=0, atol=1e-12)
    assert np.any(np.isclose(play.breakpoints(0.0, 1.0), t_contact, rtol=0, atol=1e-10))
    assert math.isclose(np.ptp(y_p[t > 0.3]), 2 * a - gap, rel_tol=1e-6)  # the piston's stroke is the play's less


def test_backlash_force_from_two_integrators_and_its_vanishing_limit():
    """The piston behind the play drives independent.simulate (its own segment handling) and simulate_rig alike; a
    play of 1 nm changes the force by far less than 0.4 mm does."""
    from reference_cycles import play_input, simulate_rig

    inp = sine_input(0.005, 2.0)
    t = np.arange(0.0, 1.5, 1 / 500)
    kw = dict(t0=-0.5, rtol=1e-10, atol=1e-6)
    rig = simulate_rig(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, {"backlash": {"gap_m": 4e-4}}, **kw)
    ref = simulate(play_input(inp, 4e-4, -0.5, 1.5), t, SMALL, SMALL_FLOW, 30.0, 3e5, **kw)
    assert rel_l2(rig, ref) < TWO_SIMULATORS_RTOL
    bare = simulate_rig(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, {}, **kw)
    tiny = simulate_rig(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, {"backlash": {"gap_m": 1e-9}}, **kw)
    assert rel_l2(tiny, bare) < 1e-3 * rel_l2(rig, bare) and rel_l2(rig, bare) > 0.01


def test_coulomb_friction_adds_its_closed_form():
    from reference_cycles import simulate_rig

    inp = sine_input(0.005, 2.0)
    t = np.arange(0.0, 1.0, 1 / 500)
    bare = simulate_rig(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, {}, t0=-0.5)
    got = simulate_rig(inp, t, SMALL, SMALL_FLOW, 30.0, 3e5, {"friction": {"coulomb_N": 40.0,
                                                                           "viscous_Ns_per_m": 200.0}}, t0=-0.5)
    v = inp.velocity(t)
    assert np.allclose(got - bare, 40.0 * np.tanh(v / 1e-5) + 200.0 * v, rtol=0, atol=1e-6)


def test_stiff_mount_is_eq7_and_a_soft_one_slows_the_rise_as_a_series_spring():
    """k_s = 1e15 N/m: eq. (7). A soft mount after a 1 mm/s step from rest, laminar orifice, nearly gas-free fluid
    (B ≈ B_0): dΔp/dt = K (A v - Δp / C_L) / (1 + K A^2 / k_s), an exponential of time constant
    C_L (1 + K A^2 / k_s) / K to the plateau A v C_L (K = 2 B_0 / V_0 up to the piston's 2 µm travel)."""
    from reference_cycles import simulate_compliant

    t = np.arange(0.0, 0.3, 1 / 2000)
    inp = triangle_input(SPEED, AMPLITUDE, 0.0, 0.0)
    bare = simulate(inp, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, dp0=0.0, t0=0.0, rtol=1e-10)
    stiff = simulate_compliant(inp, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, 1e15, dp0=0.0, t0=0.0)
    assert rel_l2(stiff, bare) < TWO_SIMULATORS_RTOL
    laminar, k_s = (2.4e10, 0.0, 2.4e10, 0.0), 2e7
    f = simulate_compliant(inp, t, RIG_A, laminar, 1e9, 1e5, k_s, dp0=0.0, t0=0.0)
    k = 2 * RIG_A["b0"] / RIG_A["v01"]
    tau = laminar[0] * (1 + k * AREA**2 / k_s) / k
    want = AREA * SPEED * laminar[0] * AREA * (1 - np.exp(-t / tau))
    assert 0.01 < tau / t[-1] < 0.2  # the rise is seen and finished within the record
    assert np.allclose(f, want, rtol=0, atol=1e-3 * want[-1])


def test_records_are_seeded_and_span_several_speeds():
    from reference_cycles import LAB, LAB_FLOW, random_records, sine_records

    kw = dict(duration=2.0, rate=200.0, damper=LAB, flow=LAB_FLOW, alpha_v=40.0, p_r=2e5, force_sd=3.0,
              displacement_sd=2e-6, seed=3)
    sines = sine_records(((0.01, 0.5), (0.005, 3.0)), **kw)
    again = sine_records(((0.01, 0.5), (0.005, 3.0)), **{**kw, "seed": 4})
    rand = random_records((0.0015, 0.004), (0.3, 3.0), **kw)
    assert list(sines) == ["sine_10mm_0p5Hz", "sine_5mm_3Hz"] and len(rand) == 2
    peaks = []
    for recs in (sines, rand):
        for t, y, f in recs.values():
            assert t.size == 400 and np.all(np.isfinite(f)) and np.max(np.abs(f)) > 100.0
            peaks.append(np.max(np.abs(np.gradient(y, t))))
    assert peaks[1] > 2 * peaks[0] and peaks[3] > 1.5 * peaks[2]
    (t, y, f), (_, y2, f2) = sines["sine_10mm_0p5Hz"], again["sine_10mm_0p5Hz"]
    assert 1.5 < np.std(f - f2) / math.sqrt(2) < 4.5 and 1e-6 < np.std(y - y2) / math.sqrt(2) < 3e-6  # the noises


# ----------------------------------------------------------------------------- the physical two-state base
# ``two_state_damper``: absolute chamber pressures (eq. (1)), B(p) of eq. (2) with a polytropic gas referenced to
# atmospheric pressure, an accumulator (own pressure state) behind a restriction and check valves. α_V and p_R of
# the simulator's signature are not used by it.
P_ATM = 101325.0
P_CHARGE = 5.0e5


def two_state(kappa: float = 1.4, fraction: float = 0.02, line: float = 2e-11, volume: float = 1e-3,
              charge: float = P_CHARGE, **extra) -> dict:
    """The two-state base: gas-to-liquid ratio ``fraction`` at the charge, an accumulator of ``volume`` [m^3] behind
    a laminar line of conductance ``line`` [m^3/(s Pa)]."""
    return {"two_state_damper": {"polytropic_exponent": kappa,
                                 "liquid_gas_ratio_atm": alpha_for_gas_fraction(fraction, charge, kappa),
                                 "charge_pressure_Pa": charge, "accumulator_volume_m3": volume,
                                 "line_conductance_m3_per_s_Pa": line, **extra}}


@pytest.mark.parametrize("kappa", [1.0, 1.1, 1.4])
def test_polytropic_bulk_modulus_is_minus_v_dp_dv_of_liquid_and_gas(kappa):
    """Eq. (2) from its definition: per unit liquid volume at p_0, V(p) = 1 - (p - p_0)/B_0 + (1/α)(p_0/p)^(1/κ) and
    B = (1 + (1/α)(p_0/p)^(1/κ)) / (-dV/dp) (the liquid's volume held at p_0 in the numerator), by central
    differences over 20 kPa to 50 MPa (a slipped exponent or p_0 -> p_R fails by far more than 1e-7)."""
    b0, alpha = RIG_A["b0"], 15.0
    p = np.geomspace(2e4, 5e7, 40)
    h = 1e-6 * p

    def vol(q):
        return 1.0 - (q - P_ATM) / b0 + (P_ATM / q) ** (1.0 / kappa) / alpha

    want = (1.0 + (P_ATM / p) ** (1.0 / kappa) / alpha) / -((vol(p + h) - vol(p - h)) / (2.0 * h))
    assert np.allclose(polytropic_bulk_modulus(p, b0, alpha, kappa), want, rtol=1e-7, atol=0)


def test_polytropic_bulk_modulus_limits_and_gas_fraction():
    b0, alpha = RIG_A["b0"], 15.0
    for kappa in (1.0, 1.4):
        assert math.isclose(float(polytropic_bulk_modulus(1e13, b0, alpha, kappa)), b0, rel_tol=1e-6)  # p -> ∞
        at_p0 = float(polytropic_bulk_modulus(P_ATM, b0, alpha, kappa))
        assert math.isclose(at_p0, b0 * (1 + 1 / alpha) / (1 + b0 / (alpha * kappa * P_ATM)), rel_tol=1e-12)
        assert at_p0 < 0.01 * b0  # 6 % gas at p_0: a soft mixture
        b = polytropic_bulk_modulus(np.geomspace(1e2, 1e9, 300), b0, alpha, kappa)
        assert np.all(np.diff(b) > 0) and np.all(b < b0)
        assert float(polytropic_bulk_modulus(0.0, b0, alpha, kappa)) == 0.0  # the barrier at p = 0
    # the same gas fraction at the charge: the adiabatic gas is the stiffer (its stiffness κ p / fraction)
    stiff, soft = (float(polytropic_bulk_modulus(P_CHARGE, b0, alpha_for_gas_fraction(0.02, P_CHARGE, k), k))
                   for k in (1.4, 1.0))
    assert 1.3 < stiff / soft < 1.4
    a = alpha_for_gas_fraction(0.02, P_CHARGE, 1.1)
    assert math.isclose(float(gas_fraction(P_CHARGE, a, 1.1)), 0.02, rel_tol=1e-12)
    assert math.isclose(float(gas_fraction(P_ATM, a, 1.1)), 1.0 / a, rel_tol=1e-12)


def test_line_flow_solves_the_laminar_turbulent_loss():
    g, r_t = 2e-11, 3e16
    for dp in (1.0, 1e4, 1e6):
        q = line_flow(dp, g, r_t)
        assert math.isclose(q / g + r_t * q * q, dp, rel_tol=1e-12)
    assert line_flow(1e5, g, 0.0) == g * 1e5 and line_flow(-1e5, g, r_t) == 0.0 and line_flow(1e5, 0.0, r_t) == 0.0


def test_two_state_with_a_large_accumulator_and_a_fast_line_pins_the_unloaded_chamber():
    """κ = 1, a 1 m^3 accumulator behind a 1e-7 m^3/(s Pa) line, first ramp from rest: CH2 is held at the charge
    (refill time V_2 / (B(p_c) G) ~ 6e-5 s, deficit A v / G <= 42 Pa), so Δp = p_1 - p_c follows the one-chamber
    equation dΔp/dt = B(p_c + Δp) / V_1 (A v - Q_O(Δp)), integrated here on its own. Without the line both chambers
    compress (eq. (1) closed): far from it."""
    fx = two_state(kappa=1.0, line=1e-7, volume=1.0)
    alpha = fx["two_state_damper"]["liquid_gas_ratio_atm"]
    t = T[(T > T_FIRST) & (T < T_FIRST + 2.0)]
    kw = dict(t0=T_FIRST, dp0=0.0, v_prev=0.0, rtol=1e-9, return_states=True)
    out = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, fx, **kw)

    def rhs(tt, z):
        b = float(polytropic_bulk_modulus(P_CHARGE + z[0], RIG_A["b0"], alpha, 1.0))
        return [b / (RIG_A["v01"] - AREA * SPEED * (tt - T_FIRST)) * (AREA * SPEED - orifice_flow(z[0], PAPER_FLOW))]

    pinned = solve_ivp(rhs, (T_FIRST, t[-1]), [0.0], method="Radau", t_eval=t, rtol=1e-11, atol=1e-6).y[0]
    assert np.max(np.abs(out["p_2"] - P_CHARGE)) < 50.0 and np.max(np.abs(out["p_acc"] - P_CHARGE)) < 5.0
    assert rel_l2(out["dp"], pinned) < 1e-4  # seen: 2.2e-5 (CH2 42 Pa below the charge at most)
    assert np.max(out["dp"]) > 0.5 * DP_PLATEAU  # the check sees a real rise
    closed = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, two_state(kappa=1.0, line=0.0, volume=1.0),
                              **kw)
    assert rel_l2(closed["dp"], pinned) > 0.01 and np.min(closed["p_2"]) < P_CHARGE - 5e4


@pytest.mark.parametrize("mount", [None, 2e8])
def test_two_state_unloaded_chamber_dips_below_the_charge_and_is_refilled(mount):
    """0.2 % gas at the charge, a 1e-10 line: after the step CH2 falls below the charge (the piston draws A v from it
    before the orifice passes it on), the check valve refills it, and on the plateau Q = A v (eq. (4)) with CH2 back
    at the accumulator's pressure; the accumulator only delivers (check valves, no bleed). A 200 kN/mm mount slows
    the rise but leaves the plateau (dΔp/dt = 0 there, so v_P = v_A)."""
    fx = two_state(fraction=0.002, line=1e-10)
    if mount:
        fx["series_compliance"] = {"stiffness_N_per_m": mount}
    out = run(fx, return_states=True, rtol=1e-9)
    assert out["p_acc"][0] == P_CHARGE and out["p_mean"][0] == P_CHARGE
    # seen: 5e-10 relative; 5e-7 with the mount (its slower rise, τ x1.6, leaves a remnant of the transient)
    assert np.allclose(out["force"][RAMP_UP], AREA * DP_PLATEAU, rtol=PLATEAU_RTOL * (10 if mount else 1), atol=0)
    assert np.allclose(out["p_2"][RAMP_UP], out["p_acc"][RAMP_UP], rtol=0, atol=0.1)  # seen: 1e-4 / 8e-3 Pa
    assert np.min(out["p_2"]) < P_CHARGE - 2e4  # seen: 27 / 24 kPa below
    assert np.all(np.diff(out["p_acc"]) <= 1e-6) and out["p_acc"][-1] < P_CHARGE - 1.0
    if mount:
        bare = run(two_state(fraction=0.002, line=1e-10), rtol=1e-9)
        assert rel_l2(out["force"], bare) > 0.01


def test_two_state_no_refill_while_both_chambers_are_above_the_accumulator():
    """Piston at rest, started loaded (Δp0 = ±500 kPa: the loaded chamber at p_c + |Δp0|, the other at p_c): Δp
    relaxes through the orifice and the unloaded chamber rises from the charge, so the check valves stay shut: p_acc
    stays at the charge exactly and the line changes nothing. A two-way bleed of the same size would."""
    t = np.arange(0.0, 0.25, 1 / 2000)  # before the first step at T_FIRST
    for dp0 in (5e5, -5e5):
        kw = dict(dp0=dp0, t0=0.0, v_prev=0.0, rtol=1e-9, return_states=True)
        out = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, two_state(line=1e-9), **kw)
        shut = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, two_state(line=0.0), **kw)
        bleed = simulate_effects(INP, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R,
                                 two_state(line=0.0, bleed_conductance_m3_per_s_Pa=1e-9), **kw)
        assert np.all(out["p_acc"] == P_CHARGE)
        assert rel_l2(out["force"], shut["force"]) < 1e-9
        low = out["p_2"] if dp0 > 0 else out["p_1"]
        assert low[0] == P_CHARGE and np.all(low >= P_CHARGE - 1e-6) and low[-1] > P_CHARGE + 1e4
        assert 0.0 < out["dp"][-1] / dp0 < 0.5  # relaxing (seen: 0.14)
        assert rel_l2(bleed["force"], out["force"]) > 1e-3 and bleed["p_acc"][-1] > P_CHARGE


def test_two_state_liquid_volume_balance():
    """Book-keeping of eq. (1) with Φ(p) = ∫_{p_c}^p dp'/B(p'): V_1 dΦ(p_1) + V_2 dΦ(p_2) = (r_1 + r_2) dt (the
    piston terms cancel, V_1 + V_2 is constant), and the accumulator has delivered R = V_a ((p_c/p_acc)^(1/κ) - 1)
    = ∫ (r_1 + r_2) dt, so V_1 Φ(p_1) + V_2 Φ(p_2) - R - ∫ A v (Φ(p_2) - Φ(p_1)) dt stays 0: one full cycle with a
    small accumulator, a laminar-turbulent line and a two-way bleed all active."""
    kappa = 1.25
    fx = two_state(kappa=kappa, line=2e-11, volume=5e-5, line_turbulent_kg_per_m7=2e16,
                   bleed_conductance_m3_per_s_Pa=2e-13)
    c = fx["two_state_damper"]
    inp = triangle_input(SPEED, AMPLITUDE, 0.0, T_FIRST, cycles=1.0)
    t = np.union1d(np.arange(0.0, inp.t_end + 0.3, 1 / 4000), inp.breakpoints(0.0, inp.t_end + 1.0))
    out = simulate_effects(inp, t, RIG_A, PAPER_FLOW, ALPHA_V, P_R, fx, rtol=1e-10, return_states=True)
    grid = np.geomspace(1e4, 1e7, 20001)
    phi_grid = cumulative_simpson(1.0 / polytropic_bulk_modulus(grid, RIG_A["b0"], c["liquid_gas_ratio_atm"], kappa),
                                  x=grid, initial=0.0)

    def phi(p):
        return np.interp(p, grid, phi_grid) - np.interp(P_CHARGE, grid, phi_grid)

    y = inp.displacement(t)
    f1, f2 = phi(out["p_1"]), phi(out["p_2"])
    delivered = c["accumulator_volume_m3"] * ((P_CHARGE / out["p_acc"]) ** (1.0 / kappa) - 1.0)
    g = f2 - f1
    piston = np.concatenate(([0.0], np.cumsum(AREA * inp.velocity(0.5 * (t[1:] + t[:-1])) * 0.5 * (g[1:] + g[:-1])
                                               * np.diff(t))))
    stored = (RIG_A["v01"] - AREA * y) * f1 + (RIG_A["v02"] + AREA * y) * f2
    scale = np.max(np.abs(delivered))
    assert scale > 1e-7 and np.ptp(out["p_acc"]) > 1e3  # the accumulator works (seen: 1.8e-6 m^3, 22 kPa)
    # seen: 7e-8 (Φ from κ = 1.4 instead of 1.25: 6e-2); without the piston term: 0.19
    assert np.max(np.abs(stored - delivered - piston)) < 1e-6 * scale
    assert np.max(np.abs(stored - delivered)) > 0.01 * scale


def test_two_state_pressures_stay_positive_without_refill():
    """Charge 120 kPa, 1 % gas, no line: the unloaded chamber's gas expands below atmospheric pressure (no cavitation
    model) and the pressures stay > 0 (B ~ κ p as p -> 0)."""
    out = run(two_state(fraction=0.01, line=0.0, charge=1.2e5), return_states=True, rtol=1e-8)
    low = np.minimum(out["p_1"], out["p_2"])
    assert np.all(low > 0.0) and np.min(low) < 0.6 * 1.2e5  # seen: 46 kPa
    assert np.all(np.isfinite(out["force"]))


def test_series_compliance_on_eq7_matches_the_compliant_reference():
    """The mount in simulate_effects (y_P = y_A - A Δp / k_s, dΔp/dt solved from the chamber equations) against
    reference_cycles.simulate_compliant (its own closed form of the same equations)."""
    from reference_cycles import simulate_compliant

    got = run({"series_compliance": {"stiffness_N_per_m": 2e7}})
    ref = simulate_compliant(INP, T, RIG_A, PAPER_FLOW, ALPHA_V, P_R, 2e7)
    assert rel_l2(got, ref) < TWO_SIMULATORS_RTOL
    assert rel_l2(got, run()) > 0.01


def test_two_state_composes_with_the_other_effects():
    """A poppet valve held open (cracking -1e12 Pa: s ≡ 1) on the two-state base is the bare base; rig-A's check
    valve (2 Hz, ζ 0.5, cracking 15 kPa) changes it; every compatible effect at once runs and reports p_1, p_2."""
    base = two_state()
    bare = run(base, rtol=1e-9)
    held = run({**base, "poppet_valve": OFF_VALUES["poppet_valve"]}, rtol=1e-9)
    assert rel_l2(held, bare) < OFF_RTOL
    valve = {"natural_frequency_Hz": 2.0, "damping_ratio": 0.5, "cracking_pressure_Pa": 1.5e4, "span_Pa": 3e7}
    assert rel_l2(run({**base, "poppet_valve": valve}, rtol=1e-8), bare) > 0.01
    everything = {**base, "series_compliance": {"stiffness_N_per_m": 2e7}, "poppet_valve": valve,
                  "command_displacement": {"bandwidth_Hz": 30.0, "damping_ratio": 0.7},
                  "load_cell_offset": {"offset_N": -12.0}, "leakage": {"conductance_m3_per_s_Pa": 2e-13},
                  "mains_interference": {"cos_amplitude_N": 2.0, "sin_amplitude_N": -1.0},
                  "fluid_inertance": {"inertance_kg_per_m4": 1e9}}
    out = run(everything, rtol=1e-8, return_states=True)
    assert set(out) == {"t", "force", "p_1", "p_2", *state_names(everything)}
    assert all(np.all(np.isfinite(v)) for v in out.values())
    friction = {"stribeck_N": 20.0, "stribeck_velocity_m_s": 5e-4, "viscous_Ns_per_m": 3e3}
    with_friction = run({**base, "seal_friction": friction}, rtol=1e-9)
    v = INP.velocity(T)
    want = np.tanh(v / 1e-5) * 20.0 * np.exp(-(v / 5e-4) ** 2) + 3e3 * v
    assert np.allclose(with_friction - bare, want, rtol=0, atol=1e-6 * np.max(np.abs(bare)))
