"""The forward model with effects: eq. (7) limit, an independent scipy reference, robustness, the problem.

The reference integrates the same augmented ODE with ``scipy.integrate.solve_ivp(method="Radau")``,
written independently of the kernel: the actuator lag and the corner filter are ODE states there
(the kernel integrates them in closed form), eq. (8) is in the paper's textbook form.
"""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.physics.augmented import solve_augmented
from bayesdamper.physics.effect_vector import EFFECT_SLOTS, VECTOR_EFFECTS, pack_effects
from bayesdamper.physics.effects import EFFECTS
from bayesdamper.physics.effects.friction import SIGN_VELOCITY_M_S
from bayesdamper.physics.effects.inertia import CORNER_TIME_S
from bayesdamper.physics.effects.valve_dynamics import MIN_OPENING
from bayesdamper.physics.excitation import PiecewiseLinear
from bayesdamper.physics.orifice import pressure_drop
from bayesdamper.physics.reference import simulate_two_state
from bayesdamper.physics.rodas import STATUS_BAD_INPUT, STATUS_VOLUME
from bayesdamper.physics.single_state import solve_single_state
from bayesdamper.physics.with_effects import AugmentedProblem, simulate_augmented, simulate_two_state_augmented

D = RIG_A_DAMPER
AREA = D.piston_area
DYN = DynamicParameters(1 / 0.03, 3.0e5)
SPEED = 1e-3  # [m/s]
RATE = 250.0  # [Hz]
#: Kernel vs eq. (7) kernel with all effects off: same algorithm, so agreement to rounding (brief: 1e-5).
OFF_RTOL = 1e-9
#: Kernel (rtol 1e-7) vs Radau (rtol 1e-10): relative L2 error of the force. Measured ~2e-8 for every
#: combination; the effects change the force by 1e-3..1e-1 relative, so a modelling slip cannot hide.
REF_RTOL = 1e-6


def rel_l2(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ----------------------------------------------------------------------------- independent reference
def reference_force(t_out, kt, ky, t0, dp0, v_prev, eff, alpha_v=DYN.liquid_gas_ratio,
                    p_r=DYN.reference_pressure):
    """Radau solution of the augmented single-state model; states (Δp, x, y_A - y_D, v_f)."""
    e = dict(zip(EFFECT_SLOTS, map(float, eff), strict=True))
    comp, tau_a, tau_v, p_v, mass = e["compliance"], e["lag_tau"], e["valve_tau"], e["valve_p"], e["mass"]
    fl = PAPER_FLOW.as_array()
    b0 = D.liquid_bulk_modulus

    def bulk(p):  # eq. (3) with p_0 -> p_R
        return b0 * (1 + alpha_v) / (alpha_v + b0 * p_r / p**2)

    def x_ss(dp):
        return max(1 - math.exp(-abs(dp) / p_v), MIN_OPENING)

    def rates(t, z, ta, ya, va):
        dp, xv, lag, vf = z
        vd = lag / tau_a if tau_a > 0 else va
        y = ya + va * (t - ta) - lag - comp * AREA * dp
        b_hi, b_lo = bulk(p_r + abs(dp)), bulk(p_r)
        b1, b2 = (b_hi, b_lo) if dp >= 0 else (b_lo, b_hi)
        k = b1 / (D.chamber_volume_1 - AREA * y) + b2 / (D.chamber_volume_2 + AREA * y)
        c_l, c_q = (fl[0], fl[1]) if dp >= 0 else (fl[2], fl[3])
        q = math.copysign((-c_l + math.sqrt(c_l**2 + 4 * c_q * abs(dp))) / (2 * c_q), dp)
        dx = 0.0
        if p_v > 0 and tau_v > 0:
            q *= xv
            dx = (x_ss(dp) - xv) / tau_v
        elif p_v > 0:
            q *= x_ss(dp)
        ddp = k * (AREA * vd - q) / (1 + k * AREA**2 * comp)
        return [ddp, dx, va - vd if tau_a > 0 else 0.0, (va - vf) / CORNER_TIME_S]

    def force(t, z, ta, ya, va):
        ddp = rates(t, z, ta, ya, va)[0]
        vd = z[2] / tau_a if tau_a > 0 else va
        vp = vd - comp * AREA * ddp
        level = e["coulomb"]
        if e["stribeck"] > 0:
            level += e["stribeck"] * math.exp(-(vp / e["stribeck_v"]) ** 2)
        fric = level * math.tanh(vp / SIGN_VELOCITY_M_S) + e["viscous"] * vp
        return AREA * z[0] + fric + mass * (va - z[3]) / CORNER_TIME_S

    z = np.array([dp0, x_ss(dp0) if (p_v > 0 and tau_v > 0) else 1.0, v_prev * tau_a, v_prev])
    out = np.full(t_out.size, np.nan)
    for k in range(kt.size - 1):
        ta, tb = max(kt[k], t0), min(kt[k + 1], t_out[-1])
        if tb <= ta:
            continue
        va = (ky[k + 1] - ky[k]) / (kt[k + 1] - kt[k])
        ya = ky[k] + va * (ta - kt[k])
        first = t_out <= ta if np.all(np.isnan(out)) else np.zeros(t_out.size, bool)
        out[first] = force(ta, z, ta, ya, va)
        sel = np.flatnonzero((t_out > ta) & (t_out <= tb))
        t_eval = t_out[sel] if sel.size and t_out[sel[-1]] == tb else np.append(t_out[sel], tb)
        sol = solve_ivp(rates, (ta, tb), z, method="Radau", t_eval=t_eval, args=(ta, ya, va), rtol=1e-10,
                        atol=[1e-6, 1e-12, 1e-14, 1e-14])
        assert sol.status == 0, sol.message
        for j, i in enumerate(sel):
            out[i] = force(t_out[i], sol.y[:, j], ta, ya, va)
        z = sol.y[:, -1]
    return out


def kernel_force(t_out, kt, ky, t0, dp0, v_prev, eff, rtol=1e-7, atol=1e-3, alpha_v=DYN.liquid_gas_ratio,
                 p_r=DYN.reference_pressure):
    f, st = solve_augmented(t_out, kt, ky, t0, dp0, v_prev, AREA, D.chamber_volume_1, D.chamber_volume_2,
                                D.liquid_bulk_modulus, PAPER_FLOW.as_array(), alpha_v, p_r, eff, rtol, atol)
    return f, st


def window_case(direction, reversal, rate=RATE):
    """A 3 s window starting 0.4 s before a velocity step (so it crosses the knot)."""
    v = direction * SPEED
    if reversal:
        kt = np.array([0.0, 5.0, 9.0])
        ky = np.array([0.0, -5.0 * v, -5.0 * v + 4.0 * v])
        dp0 = float(pressure_drop(-AREA * v, PAPER_FLOW))
        t0, v_prev = 4.6, -v
    else:
        kt = np.array([0.0, 5.0, 9.0])
        ky = np.array([0.0, 0.0, 4.0 * v])
        dp0, t0, v_prev = 0.0, 4.6, 0.0
    t = t0 + np.arange(0, int(3.0 * rate) + 1) / rate
    return t, kt, ky, t0, dp0, v_prev


CASES = [(d, r) for d in (1, -1) for r in (False, True)]
CASE_IDS = ["rest+", "rest-", "rev+", "rev-"]


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_all_off_equals_eq7_kernel(case):
    t, kt, ky, t0, dp0, v_prev = window_case(*case)
    k = int(np.searchsorted(kt, t0))  # window the knots for the eq. (7) kernel, which starts at knot 0
    wt = np.concatenate(([t0], kt[k:]))
    wy = np.interp(wt, kt, ky)
    f, st = kernel_force(t, kt, ky, t0, dp0, v_prev, np.zeros(len(EFFECT_SLOTS)), 1e-6, 1e-2)
    dp, st7, _ = solve_single_state(t, wt, wy, dp0, AREA, D.chamber_volume_1, D.chamber_volume_2,
                                    D.liquid_bulk_modulus, PAPER_FLOW.as_array(), DYN.liquid_gas_ratio,
                                    DYN.reference_pressure, 0, 0.0, 1e-6, 1e-2)
    assert st == 0 and st7 == 0
    assert rel_l2(f, AREA * dp) < OFF_RTOL


COMBOS = {name: {name: {}} for name in VECTOR_EFFECTS if name != "backlash"}  # the hand-written kernel's six
COMBOS["friction+stribeck+viscous"] = {"friction": {"stribeck_N": 80.0, "viscous_Ns_per_m": 2e4}}
COMBOS["valve_quasi_static"] = {"valve_dynamics": {"time_constant_s": 0.0}}
COMBOS["valve_slow"] = {"valve_dynamics": {"time_constant_s": 1.0, "opening_pressure_Pa": 2e5}}
COMBOS["valve_fast_lag_fast"] = {"valve_dynamics": {"time_constant_s": 1e-4},
                                 "actuator_lag": {"time_constant_s": 1e-4}}
COMBOS["soft_mount"] = {"series_compliance": {"stiffness_N_per_m": 1e6}}
ALL = {"friction": {}, "actuator_lag": {}, "valve_dynamics": {}, "series_compliance": {}, "inertia": {}}
REF_CASES = [(name, CASES[0]) for name in COMBOS] + [(name, CASES[3]) for name in COMBOS]
REF_CASES += [("all", c) for c in CASES]


@pytest.mark.parametrize("combo,case", REF_CASES, ids=[f"{n}-{c}" for n, c in REF_CASES])
def test_kernel_matches_radau_reference(combo, case):
    """Each effect alone from rest and across a reversal, and all together in all four cases."""
    t, kt, ky, t0, dp0, v_prev = window_case(*case, rate=50.0)  # the Python reference is slow per sample
    eff = pack_effects(ALL if combo == "all" else COMBOS[combo])
    f, st = kernel_force(t, kt, ky, t0, dp0, v_prev, eff)
    assert st == 0 and np.all(np.isfinite(f))
    ref = reference_force(t, kt, ky, t0, dp0, v_prev, eff)
    assert rel_l2(f, ref) < REF_RTOL, rel_l2(f, ref)


# ----------------------------------------------------------------------------- robustness
def test_random_prior_draws_succeed_and_are_finite():
    """Effects drawn log-uniformly over their prior boxes, α_V and p_R over theirs, four cases."""
    rng = np.random.default_rng(7)
    n_fail = 0
    for _ in range(200):
        t, kt, ky, t0, dp0, v_prev = window_case(int(rng.choice([1, -1])), bool(rng.random() < 0.5))
        eff = {}
        for name in VECTOR_EFFECTS:
            e = EFFECTS[name]
            if name != "backlash" and rng.random() < 0.5:
                eff[name] = {p.name: float(np.exp(rng.uniform(np.log(p.lower), np.log(p.upper))))
                             for p in e.params}
        a, p = np.exp(rng.uniform(np.log(2.0), np.log(5000.0))), np.exp(rng.uniform(np.log(1e3), np.log(1e7)))
        f, st = kernel_force(t, kt, ky, t0, dp0, v_prev, pack_effects(eff), 1e-6, 1.0, alpha_v=a, p_r=p)
        n_fail += st != 0
        assert st != 0 or np.all(np.isfinite(f))
    assert n_fail == 0


@pytest.mark.parametrize("change,status", [
    (dict(t0=4.7), STATUS_BAD_INPUT),  # samples before t0
    (dict(eff_slot=("mass", -1.0)), STATUS_BAD_INPUT),
    (dict(eff_slot=("valve_tau", math.nan)), STATUS_BAD_INPUT),
    (dict(dp0=math.inf), STATUS_BAD_INPUT),
    (dict(p_r=0.0), STATUS_BAD_INPUT),
    (dict(ky_scale=1e3), STATUS_VOLUME),  # a 5 m stroke empties a chamber
    (dict(rtol=1e-15, atol=1e-15), None),  # impossible tolerance: fails cleanly, whatever the reason
])
def test_impossible_inputs_give_status_not_nan(change, status):
    t, kt, ky, t0, dp0, v_prev = window_case(1, True)
    eff = pack_effects(ALL)
    if "eff_slot" in change:
        slot, value = change.pop("eff_slot")
        eff[EFFECT_SLOTS.index(slot)] = value
    ky = ky * change.pop("ky_scale", 1.0)
    kw = dict(t0=t0, dp0=dp0, rtol=1e-7, atol=1e-3, p_r=DYN.reference_pressure) | change
    f, st = solve_augmented(t, kt, ky, kw["t0"], kw["dp0"], v_prev, AREA, D.chamber_volume_1,
                                D.chamber_volume_2, D.liquid_bulk_modulus, PAPER_FLOW.as_array(),
                                DYN.liquid_gas_ratio, kw["p_r"], eff, kw["rtol"], kw["atol"])
    if status is None:
        assert st != 0 or np.all(np.isfinite(f))  # never NaN with status 0
    else:
        assert st == status


def test_wrapper_raises_one_line_error():
    exc = PiecewiseLinear([0.0, 1.0, 2.0], [0.0, 0.0, 1.0])  # 1 m stroke: chamber volume <= 0
    with pytest.raises(BayesDamperError) as err:
        simulate_augmented(np.linspace(0, 2, 11), exc, D, PAPER_FLOW, DYN, {"friction": {}}, t0=0.0)
    assert "chamber volume" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(SettingsError):
        simulate_augmented(np.linspace(0, 2, 11), exc, D, PAPER_FLOW, DYN, {"gravity": {}})


# ----------------------------------------------------------------------------- problem binding
@pytest.fixture(scope="module")
def friction_dataset(tmp_path_factory):
    from bayesdamper.io.dataset import load_dataset
    from bayesdamper.io.segmentation import segment_dataset
    from bayesdamper.io.synthetic import write_dataset

    effects = {"friction": {"coulomb_N": 150.0}, "actuator_lag": {"time_constant_s": 0.02},
               "backlash": {"gap_m": 2e-5}}
    out = write_dataset(tmp_path_factory.mktemp("aug") / "ds", [1.2e-3], DYN, effects=effects)
    return effects, segment_dataset(load_dataset(out))[0]


def test_problem_reproduces_simulated_transients(friction_dataset):
    """Noise-free data simulated with effects: the problem with the true effects matches every window."""
    effects, seg = friction_dataset
    eff = pack_effects(effects)
    assert len(seg.transients) == 3
    for tr in seg.transients:
        pb = AugmentedProblem.from_segmented(seg, tr, D, PAPER_FLOW)
        f, ok = pb.simulate_force(DYN.liquid_gas_ratio, DYN.reference_pressure, eff)
        assert ok
        # CSV rounding (1e-4 N), segmentation's fitted knots and the step-force average limit this
        assert np.max(np.abs(f - pb.force)) < 0.01 * np.max(np.abs(pb.force)), tr.id
        f0, ok0 = pb.simulate_force(DYN.liquid_gas_ratio, DYN.reference_pressure, np.zeros(len(eff)))
        assert ok0 and np.max(np.abs(f0 - pb.force)) > 5 * np.max(np.abs(f - pb.force))
        # the step force includes friction: Δp0 = (F_step - F_f(v_before)) / A_P
        v_before = pb.knots(float(eff[EFFECT_SLOTS.index("gap")]))[2]
        assert pb.initial_dp(eff, v_before) * AREA == pytest.approx(
            tr.dp0 * AREA - 150.0 * np.sign(v_before) if v_before else tr.dp0 * AREA, abs=1e-6)
        assert not pb.simulate_force(DYN.liquid_gas_ratio, DYN.reference_pressure, -eff - 1)[1]


def test_problem_without_effects_equals_eq7_on_the_transient(friction_dataset):
    _, seg = friction_dataset
    for tr in seg.transients:
        pb = AugmentedProblem.from_segmented(seg, tr, D, PAPER_FLOW)
        f, ok = pb.simulate_force(50.0, 2e5, np.zeros(len(EFFECT_SLOTS)))
        # eq. (7) on the transient's own two knots, extended to the last sample (which segmentation may
        # place a rounding error past t_step + tmax)
        kt, ky = tr.knot_times, tr.knot_displacements
        t1 = max(kt[-1], tr.time[-1])
        ky1 = ky[0] + (ky[1] - ky[0]) * (t1 - kt[0]) / (kt[1] - kt[0])
        dp, st, _ = solve_single_state(tr.time, np.array([kt[0], t1]), np.array([ky[0], ky1]), tr.dp0, AREA,
                                       D.chamber_volume_1, D.chamber_volume_2, D.liquid_bulk_modulus,
                                       PAPER_FLOW.as_array(), 50.0, 2e5, 0, 0.0, pb.rtol, pb.atol)
        assert ok and st == 0 and rel_l2(f, AREA * dp) < 1e-6


# ----------------------------------------------------------------------------- two-state with effects
def test_two_state_augmented_off_and_with_effects():
    exc = PiecewiseLinear([0.0, 0.5, 3.0, 5.0], [0.0, 0.0, 2.5e-3, 0.5e-3])
    t = np.arange(0.0, 5.0, 0.01)
    plain = AREA * simulate_two_state(t, exc, D, PAPER_FLOW, DYN, t0=0.0).dp
    off = simulate_two_state_augmented(t, exc, D, PAPER_FLOW, DYN, None, t0=0.0)
    assert np.max(np.abs(off - plain)) < 0.01  # [N], solver tolerance
    fr = simulate_two_state_augmented(t, exc, D, PAPER_FLOW, DYN, {"friction": {"coulomb_N": 120.0}},
                                          t0=0.0)
    v = exc.velocity(t)
    away = np.min(np.abs(t[:, None] - exc.knot_times[None, :]), axis=1) > 0.01
    assert np.allclose((fr - plain)[away], 120.0 * np.sign(v[away]), atol=1e-6)
    # the same effect on the two bases: of similar size (eq. (6) approximates eq. (1))
    both = {"valve_dynamics": {}, "series_compliance": {}, "actuator_lag": {}}
    d2 = simulate_two_state_augmented(t, exc, D, PAPER_FLOW, DYN, both, t0=0.0) - plain
    d7 = simulate_augmented(t, exc, D, PAPER_FLOW, DYN, both, t0=0.0) - simulate_augmented(
        t, exc, D, PAPER_FLOW, DYN, None, t0=0.0)
    assert np.max(np.abs(d2)) == pytest.approx(np.max(np.abs(d7)), rel=0.3)


# ----------------------------------------------------------------------------- command line
def test_simulate_cli_with_effects_writes_truth(tmp_path, capsys):
    import json

    from bayesdamper.cli import main

    out = tmp_path / "ds"
    rc = main(["simulate", str(out), "--velocities", "1.5", "--model", "two-state", "--noise-n", "5",
               "--effect", "friction:coulomb_N=150", "--effect",
               "valve_dynamics:time_constant_s=0.05,opening_pressure_Pa=2e5"])
    assert rc == 0, capsys.readouterr().err
    truth = json.loads((out / "truth.json").read_text())
    assert truth["model"] == "two-state"
    assert truth["effects"]["friction"]["coulomb_N"] == 150.0
    assert truth["effects"]["friction"]["viscous_Ns_per_m"] == 0.0
    assert truth["effects"]["valve_dynamics"] == {"time_constant_s": 0.05, "opening_pressure_Pa": 2e5}
    rc = main(["simulate", str(tmp_path / "bad"), "--effect", "friction:coulomb=1"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and "unknown parameter" in err
    assert not (tmp_path / "bad").exists()
