"""The effect library: registry, parameter specs, the command-line form, and each effect's physics.

Physics is checked on rig A's protocol (rest, then a 5 mm triangle) through
:func:`bayesdamper.physics.with_effects.simulate_effects` (the composed kernel) against analytic limits: off values
reproduce eq. (7); friction and inertia add exactly known forces; backlash, lag, valve and compliance show
their defining signatures.
"""

import math

import numpy as np
import pytest

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.physics.compose import compose
from bayesdamper.physics.effects import (
    _FIRST,
    EFFECT_MODULES,
    EFFECT_NAMES,
    EFFECTS,
    complete_effects,
    get_effect,
    parse_effect_spec,
    parse_effect_specs,
)
from bayesdamper.physics.effects.backlash import backlash_knots
from bayesdamper.physics.effects.inertia import CORNER_TIME_S
from bayesdamper.physics.excitation import PiecewiseLinear
from bayesdamper.physics.single_state import simulate_single_state
from bayesdamper.physics.with_effects import simulate_effects

D = RIG_A_DAMPER
AREA = D.piston_area
DYN = DynamicParameters(1 / 0.03, 3.0e5)
SPEED = 1e-3  # [m/s]
EXC = PiecewiseLinear.triangle(5e-3, SPEED, rest=1.0, cycles=1.25)  # knots 0, 1, 6, 16, 26 s
T = np.arange(0.0, EXC.end, 1 / 250)
#: Equality of two kernel solutions of the same Δp path (rtol 1e-6): far below any effect here.
SAME_N = 0.05  # [N]


def force(effects, t=T, exc=EXC, **kw):
    return simulate_effects(t, exc, D, PAPER_FLOW, DYN, effects, t0=kw.pop("t0", 0.0), **kw)


@pytest.fixture(scope="module")
def base():
    return force(None)


def plateau(t, t_a, t_b):
    return (t > t_b - 1.2) & (t < t_b - 0.2)


# ----------------------------------------------------------------------------- registry and specs
def test_registry_names_and_parameters():
    assert list(EFFECTS)[:6] == list(_FIRST) == ["friction", "backlash", "actuator_lag", "valve_dynamics",
                                                  "series_compliance", "inertia"]
    assert list(EFFECTS) == list(EFFECT_NAMES) == list(EFFECT_MODULES)
    assert list(EFFECTS)[6:] == sorted(set(EFFECTS) - set(_FIRST))  # the others by name
    for e in EFFECTS.values():
        assert e.description and (e.required or not e.candidate)  # a base-model variant may have none
        for p in e.params:
            assert p.description and p.lower < p.upper
            assert (p.lower > 0) if p.log else True
            assert p.lower <= p.default <= p.upper or (p.optional and p.default == p.off)
            assert p.off == math.inf if p.reciprocal else True  # a stiffness: off is infinitely stiff


def test_complete_and_compose_round_trip():
    eff = {"valve_dynamics": {"time_constant_s": 0.05, "opening_pressure_Pa": 2e5},
           "friction": {"coulomb_N": 150.0}, "series_compliance": {"stiffness_N_per_m": 2e7}}
    full = complete_effects(eff)
    assert list(full) == ["friction", "valve_dynamics", "series_compliance"]  # registry order
    assert full["friction"] == EFFECTS["friction"].defaults() | {"coulomb_N": 150.0}
    c = compose(eff)
    assert c.names == tuple(full)
    assert c.as_dict() == full
    assert c.values.tolist() == [v for name in full for v in full[name].values()]
    assert c.compliance() == pytest.approx(5e-8)  # 1 / k_s
    assert compose(c.as_dict()).as_dict() == full
    off = compose({name: EFFECTS[name].off_values() for name in _FIRST})
    assert off.as_dict() == {name: EFFECTS[name].off_values() for name in _FIRST} and off.compliance() == 0.0
    assert compose(None).names == () and compose({}).as_dict() == {} and complete_effects(None) == {}


@pytest.mark.parametrize("text,name,values", [
    ("friction", "friction", {"coulomb_N": 100.0, "viscous_Ns_per_m": 0.0, "stribeck_N": 0.0}),
    ("friction:coulomb_N=150", "friction", {"coulomb_N": 150.0}),
    (" valve_dynamics:time_constant_s=0.05, opening_pressure_Pa=2e5", "valve_dynamics",
     {"time_constant_s": 0.05, "opening_pressure_Pa": 2e5}),
    ("series_compliance:stiffness_N_per_m=inf", "series_compliance", {"stiffness_N_per_m": math.inf}),
    ("inertia:mass_kg=0", "inertia", {"mass_kg": 0.0}),
])
def test_parse_effect_spec_good(text, name, values):
    got_name, got = parse_effect_spec(text)
    assert got_name == name
    assert set(got) == set(EFFECTS[name].param_names)  # defaults filled
    for k, v in values.items():
        assert got[k] == v


@pytest.mark.parametrize("text,needle", [
    ("fricton", "unknown effect"),
    ("friction:coulomb=150", "unknown parameter"),
    ("friction:coulomb_N=abc", "must be a number"),
    ("friction:coulomb_N=-5", ">= 0"),
    ("friction:coulomb_N=nan", "must be a number"),
    ("friction:coulomb_N=inf", "finite"),
    ("friction:coulomb_N", "param=value"),
    ("friction:", "nothing after"),
    ("friction:coulomb_N=1,coulomb_N=2", "twice"),
    ("series_compliance:stiffness_N_per_m=0", "> 0"),
])
def test_parse_effect_spec_bad(text, needle):
    with pytest.raises(SettingsError) as err:
        parse_effect_spec(text)
    msg = str(err.value)
    assert needle in msg and "\n" not in msg


def test_parse_effect_specs_repeated():
    assert parse_effect_specs(None) is None
    got = parse_effect_specs(["friction:coulomb_N=150", "backlash"])
    assert list(got) == ["friction", "backlash"]
    assert got["backlash"]["gap_m"] == EFFECTS["backlash"].params[0].default
    with pytest.raises(SettingsError, match="twice"):
        parse_effect_specs(["friction", "friction:coulomb_N=3"])
    with pytest.raises(SettingsError, match="unknown effect"):
        get_effect("gravity")


# ----------------------------------------------------------------------------- off = eq. (7)
#: Effects without parameter values that give eq. (7) back, and why.
NO_EXACT_OFF = {"two_state": "its absolute pressures replace eq. (6)'s guess at every value",
                "constant_bulk_modulus": "it replaces eq. (6) by one modulus"}


@pytest.mark.parametrize("name", [n for n in EFFECT_NAMES if n not in NO_EXACT_OFF])
def test_off_values_reproduce_eq7(name, base):
    f = force({name: EFFECTS[name].off_values()})
    ref = AREA * simulate_single_state(T, EXC, D, PAPER_FLOW, DYN, dp0=0.0, t0=0.0)
    assert np.max(np.abs(f - ref)) < SAME_N
    if compose({name: EFFECTS[name].off_values()}).force_only:  # eq. (7)'s own kernel, as the base: bit-identical
        assert np.array_equal(f, base)


# ----------------------------------------------------------------------------- physics
def test_friction_shifts_force_by_coulomb_with_velocity_sign(base):
    fc = 150.0
    diff = force({"friction": {"coulomb_N": fc}}) - base
    v = EXC.velocity(T)
    moving = np.abs(v) > 0
    # away from the knots (the sample at a knot takes the segment ending there)
    away = np.min(np.abs(T[:, None] - EXC.knot_times[None, :]), axis=1) > 0.01
    assert np.allclose(diff[moving & away], fc * np.sign(v[moving & away]), atol=1e-6)
    assert np.allclose(diff[~moving & away], 0.0, atol=1e-9)


#: Tolerances [-], [Pa] of the inertia check, and its force tolerance: the filter is an ODE state of the kernel, and
#: the solve with it takes other steps than the one without, so the difference carries both solves' global error
#: of Δp (measured 3e-6 N at rtol 1e-9 on forces of 4 kN; it scales with rtol): 1e-4 N is 3e-6 of the 32 N peak.
INERTIA_SOLVER_TOL = (1e-9, 1e-4)
INERTIA_N = 1e-4  # [N]


def test_inertia_adds_mass_times_corner_filtered_acceleration():
    m = 800.0
    rtol, atol = INERTIA_SOLVER_TOL
    diff = force({"inertia": {"mass_kg": m}}, rtol=rtol, atol=atol) - force(None, rtol=rtol, atol=atol)
    vel = np.concatenate(([0.0], np.diff(EXC.knot_displacements) / np.diff(EXC.knot_times), [0.0]))
    acc = np.zeros_like(T)
    for k, tk in enumerate(EXC.knot_times):
        dv = vel[k + 1] - vel[k]
        after = T > tk
        acc[after] += dv / CORNER_TIME_S * np.exp(-(T[after] - tk) / CORNER_TIME_S)
    away = np.min(np.abs(T[:, None] - EXC.knot_times[None, :]), axis=1) > 1e-6
    assert np.max(np.abs(diff[away] - m * acc[away])) < INERTIA_N
    assert np.max(np.abs(diff)) == pytest.approx(m * 2 * SPEED / CORNER_TIME_S, rel=0.1)  # the reversals
    steady = np.min(np.abs(T[:, None] - EXC.knot_times[None, :]), axis=1) > 20 * CORNER_TIME_S
    assert np.max(np.abs(diff[steady])) < INERTIA_N  # exp(-20) of the peak: nothing on steady ramps


def test_backlash_from_rest_force_flat_then_follows(base):
    gap = 1e-4
    f = force({"backlash": {"gap_m": gap}})
    dead = (T >= 1.0) & (T <= 1.0 + 0.5 * gap / SPEED)  # centred play: half the gap from rest
    assert np.all(f[dead] == 0.0)
    assert f[(T > 1.0 + 0.5 * gap / SPEED + 0.02) & (T < 1.2)].min() > 1.0
    # the same transient as eq. (7), delayed by the dead time, once the play is taken up
    delayed = force(None, exc=PiecewiseLinear(EXC.knot_times + 0.5 * gap / SPEED, EXC.knot_displacements))
    sel = (T > 1.0) & (T < 6.0)
    assert np.max(np.abs(f[sel] - delayed[sel])) < 0.02 * np.max(np.abs(f[sel] - base[sel]))


def test_backlash_at_reversal_piston_rests_for_gap_over_speed(base):
    gap = 1e-4
    t_rev = 6.0
    t = np.linspace(t_rev, t_rev + gap / SPEED, 41)
    f = force({"backlash": {"gap_m": gap}}, t=t)
    y_rev = float(EXC.displacement(t_rev))
    held = PiecewiseLinear([t_rev, t_rev + 1.0], [y_rev - 0.5 * gap, y_rev - 0.5 * gap])  # piston held
    f_held = force(None, t=t, exc=held, t0=t_rev, dp0=f[0] / AREA)
    assert np.max(np.abs(f - f_held)) < SAME_N
    # without play the force falls twice as fast at first (reversed piston, not a still one)
    no_play = force(None, t=t)
    assert (f[0] - f[4]) == pytest.approx(0.5 * (no_play[0] - no_play[4]), rel=0.05)
    # once the play is taken up the force moves on, and the plateau is that of eq. (7)
    f_late = force({"backlash": {"gap_m": gap}})
    late = plateau(T, 6.0, 16.0)
    assert np.max(np.abs(f_late[late] - base[late])) < 2.0


def test_backlash_play_operator_hand_worked():
    kt, ky = np.array([0.0, 1.0, 3.0, 4.0]), np.array([0.0, 0.0, 2.0, 1.0])
    t, y = backlash_knots(kt, ky, 0.5)  # half-width 0.25, piston centred at 0
    np.testing.assert_allclose(t, [0.0, 1.0, 1.25, 3.0, 3.5, 4.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(y, [0.0, 0.0, 0.0, 1.75, 1.75, 1.25], rtol=0, atol=1e-15)
    t, y = backlash_knots(kt, ky, 0.5, y_piston0=-0.25)  # already in contact: no dead time
    np.testing.assert_allclose(t, [0.0, 1.0, 3.0, 3.5, 4.0])
    np.testing.assert_allclose(y, [-0.25, -0.25, 1.75, 1.75, 1.25])
    t, y = backlash_knots([0.0, 1.0, 2.0], [0.0, 0.1, 0.0], 0.5)  # inside the play: piston never moves
    np.testing.assert_allclose(y, 0.0)
    t, y = backlash_knots(kt, ky, 0.0)
    assert np.array_equal(t, kt) and np.array_equal(y, ky)
    with pytest.raises(SettingsError):
        backlash_knots(kt, ky, -1e-3)


def _half_crossing(f, t_a, t_b, ref):
    """Time [s] at which ``f`` crosses half-way between ``ref``'s values at t_a and t_b."""
    sel = (T >= t_a) & (T < t_b)
    level = 0.5 * (ref[sel][0] + ref[sel][-1])
    x, tt = f[sel] - level, T[sel]
    i = np.flatnonzero(np.sign(x) != np.sign(x[0]))[0]
    return tt[i - 1] + (tt[i] - tt[i - 1]) * x[i - 1] / (x[i - 1] - x[i])


def test_actuator_lag_delays_transient_by_tau(base):
    tau = 0.02
    f = force({"actuator_lag": {"time_constant_s": tau}})
    for t_a, t_b in ((1.0, 6.0), (6.0, 16.0), (16.0, 26.0)):  # start from rest and both reversals
        delay = _half_crossing(f, t_a, t_b, base) - _half_crossing(base, t_a, t_b, base)
        assert delay == pytest.approx(tau, rel=0.05)
        late = (T > t_b - 0.5) & (T < t_b - 0.1)
        assert np.max(np.abs(f[late] - base[late])) < 1.0  # steady ramps unchanged


def test_valve_dynamics_overshoot_for_slow_valves_vanishes_fast(base):
    ramp = (T > 1.0) & (T < 6.0)
    steady = base[plateau(T, 1.0, 6.0)].mean()

    def overshoot(tau):
        f = force({"valve_dynamics": {"time_constant_s": tau, "opening_pressure_Pa": 5e4}})
        return f[ramp].max() - steady, f

    over = [overshoot(tau)[0] for tau in (1.0, 0.3, 0.1)]
    assert over[0] > 0.3 * steady  # slow valve: large overshoot after the start
    assert over[0] > over[1] > over[2]
    fast, f_fast = overshoot(1e-4)
    assert fast < 5.0  # no overshoot for a fast valve
    f_qs = force({"valve_dynamics": {"time_constant_s": 0.0, "opening_pressure_Pa": 5e4}})
    assert np.max(np.abs(f_fast - f_qs)) < 5.0  # τ_v -> 0 is the quasi-static valve


def test_series_compliance_slows_rise_keeps_steady_state(base):
    k_s = 3e7
    f = force({"series_compliance": {"stiffness_N_per_m": k_s}})
    rise = (T > 1.02) & (T < 2.5)
    assert np.all(f[rise] < base[rise])
    for t_b in (6.0, 16.0, 26.0):
        sel = (T > t_b - 0.5) & (T < t_b - 0.1)
        assert np.max(np.abs(f[sel] - base[sel])) < 0.002 * np.max(np.abs(base[sel]))
    # initial slope after the start: the mount in series with the hydraulic stiffness K A_P^2
    b_r = D.liquid_bulk_modulus * (1 + DYN.liquid_gas_ratio) / (
        DYN.liquid_gas_ratio + D.liquid_bulk_modulus / DYN.reference_pressure)
    k_h = (b_r / D.chamber_volume_1 + b_r / D.chamber_volume_2) * AREA**2  # [N/m]
    h = 1e-4
    t = np.array([1.0, 1.0 + h])
    slope = np.diff(force({"series_compliance": {"stiffness_N_per_m": k_s}}, t=t, t0=1.0))[0] / h
    assert slope == pytest.approx(SPEED * k_h * k_s / (k_h + k_s), rel=2e-3)
