"""The composed kernel with the first library effects against an independent scipy reference, and its bindings.

The reference integrates eq. (7) with friction, actuator lag, valve dynamics, series compliance and inertia, and
optionally the two-state model eq. (1) (both absolute chamber pressures refilled from an accumulator), with
``scipy.integrate.solve_ivp(method="Radau")``, written independently of the kernel: eq. (8) in the paper's
textbook form, the two-state model on the states (p_1, p_2) where the kernel carries (Δp, mean pressure), and the
input an analytic function of time (a piecewise-linear displacement or a sine) where the kernel reads polynomial
pieces. Checked here: the composed kernel (:func:`~bayesdamper.physics.compose.solve_composed`) against it
from rest and across a reversal, one effect at a time and all together, on a smooth input, and the two-state
composition; failures reported as a status, never NaN; the Python wrapper
(:func:`~bayesdamper.physics.with_effects.simulate_effects`), the window binding
(:class:`~bayesdamper.inference.problem.EffectsProblem`) and ``bayesdamper simulate`` with effects.
"""

import functools
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bayesdamper.core.errors import BayesDamperError, SettingsError
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.inference.problem import EffectsProblem, WindowProblem
from bayesdamper.physics.compose import ComposedEffects, compose, solve_composed
from bayesdamper.physics.effects import _FIRST, EFFECTS, complete_effects
from bayesdamper.physics.effects.friction import SIGN_VELOCITY_M_S
from bayesdamper.physics.effects.inertia import CORNER_TIME_S
from bayesdamper.physics.effects.valve_dynamics import MIN_OPENING
from bayesdamper.physics.excitation import PiecewiseLinear, PiecewisePolynomial
from bayesdamper.physics.orifice import pressure_drop
from bayesdamper.physics.reference import simulate_two_state
from bayesdamper.physics.rodas import STATUS_BAD_INPUT, STATUS_OK
from bayesdamper.physics.single_state import solve_eq7
from bayesdamper.physics.with_effects import simulate_effects, two_state_effects

D = RIG_A_DAMPER
AREA = D.piston_area
FLOW4 = PAPER_FLOW.as_array()
DYN = DynamicParameters(1 / 0.03, 3.0e5)
SPEED = 1e-3  # [m/s]
RATE = 250.0  # [Hz]
#: Check-valve conductance of the two-state model's accumulator [m^3 s^-1 Pa^-1] (the synthetic data's).
TWO_STATE_G = 1e-8
#: Every first-library effect at its off values vs the eq. (7) kernel (both rtol 1e-9): the effects' extra
#: states (constant at their off values) only change the composed kernel's error norm and step sequence, so the
#: two agree to the solvers' global error (measured <= 4e-10 relative L2 at rtol 1e-9; it scales with rtol),
#: five orders below any effect's change of the force.
OFF_RTOL = 1e-8
#: Tolerances [-], [Pa] of that comparison.
OFF_SOLVER_TOL = (1e-9, 1e-4)
#: Kernel (rtol 1e-7) vs Radau (rtol 1e-10): relative L2 error of the force. Measured <= 4e-8 for every
#: combination on eq. (7) (piecewise-linear and sine inputs), <= 2e-7 on the two-state model; the effects change the
#: force by 6e-4..1 relative, and a 1 % change of any one parameter moves it by 6e-6..6e-4, so a modelling slip
#: cannot hide.
REF_RTOL = 1e-6
#: Smallest change of the force (relative L2) each checked effect must make, in units of the tolerance it is
#: checked at (the weakest, inertia after a step from rest, changes it by 6e-4).
VISIBLE = 100


def rel_l2(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ----------------------------------------------------------------------------- independent reference
def linear_input(kt, ky):
    """The analytic piecewise-linear displacement through knots: (breaks, piece(t, k) -> (y, v, a))."""
    kt, ky = np.asarray(kt, float), np.asarray(ky, float)

    def piece(t, k):
        v = (ky[k + 1] - ky[k]) / (kt[k + 1] - kt[k])
        return ky[k] + v * (t - kt[k]), v, 0.0

    return kt, piece


def sine_input(amplitude, frequency, t_end):
    """y = A sin(2π f t) on [0, t_end] as one smooth piece: (breaks, piece(t, k) -> (y, v, a))."""
    w = 2 * math.pi * frequency

    def piece(t, k):
        return amplitude * math.sin(w * t), amplitude * w * math.cos(w * t), -amplitude * w * w * math.sin(w * t)

    return np.array([0.0, t_end]), piece


def reference_force(t_out, inp, t0, dp0, v_prev, effects, alpha_v=DYN.liquid_gas_ratio, p_r=DYN.reference_pressure,
                    accumulator=None, kappa=1.0):
    """Radau solution of eq. (7) with effects (or, with ``accumulator=(p_a, G)``, of the two-state model eq. (1),
    its chambers' moduli eq. (2) about the charge p_a with polytropic exponent ``kappa``).

    ``inp`` is ``(breaks, piece)`` with ``piece(t, k) -> (y_A, v_A, a_A)`` on ``[breaks[k], breaks[k + 1]]``; the
    integration restarts at every break. States: Δp (or p_1, p_2), the valve opening x, the lag's trail
    y_A - y_D, the corner-filtered velocity v_f. Returns the force [N] at ``t_out``.
    """
    e = complete_effects(effects)
    assert "backlash" not in e, "the reference has no play operator"
    fr = e.get("friction", {"coulomb_N": 0.0, "viscous_Ns_per_m": 0.0, "stribeck_N": 0.0,
                            "stribeck_velocity_m_s": 1.0})
    tau_a = e.get("actuator_lag", {}).get("time_constant_s", 0.0)
    tau_v, p_v = e.get("valve_dynamics", {}).get("time_constant_s", 0.0), e.get("valve_dynamics", {}).get(
        "opening_pressure_Pa", 0.0)
    k_s = e.get("series_compliance", {}).get("stiffness_N_per_m", math.inf)
    comp = 0.0 if math.isinf(k_s) else 1.0 / k_s
    mass = e.get("inertia", {}).get("mass_kg", 0.0)
    b0, v01, v02 = D.liquid_bulk_modulus, D.chamber_volume_1, D.chamber_volume_2
    two = accumulator is not None
    p_a, g_acc = accumulator if two else (p_r, 0.0)
    n_p = 2 if two else 1  # pressure states

    def bulk(p):  # eq. (3) with p_0 -> p_R
        return b0 * (1 + alpha_v) / (alpha_v + b0 * p_r / p**2)

    def bulk_gas(p):  # eq. (2) about the charge: gas volume (p_a/p)^(1/κ) of its value there
        r = p_a / p
        return b0 * (1 + r ** (1 / kappa) / alpha_v) / (1 + b0 / (kappa * p_a) * r ** ((kappa + 1) / kappa) / alpha_v)

    def x_ss(dp):
        return max(1 - math.exp(-abs(dp) / p_v), MIN_OPENING)

    def signals(t, z, k):
        """(dz/dt, piston velocity v_P, actuator velocity v_A and acceleration a_A, Δp)."""
        ya, va, aa = piece(t, k)
        dp = z[0] - z[1] if two else z[0]
        xv, lag, vf = z[n_p:]
        vd = lag / tau_a if tau_a > 0 else va
        y = ya - lag - comp * AREA * dp
        c_l, c_q = (FLOW4[0], FLOW4[1]) if dp >= 0 else (FLOW4[2], FLOW4[3])
        q = math.copysign((-c_l + math.sqrt(c_l**2 + 4 * c_q * abs(dp))) / (2 * c_q), dp)
        dx = 0.0
        if p_v > 0 and tau_v > 0:
            q *= xv
            dx = (x_ss(dp) - xv) / tau_v
        elif p_v > 0:
            q *= x_ss(dp)
        if two:
            p1, p2 = z[0], z[1]
            assert p1 > 1e4 and p2 > 1e4, "below the kernel's pressure floor: not the same model"
            g1, g2 = bulk_gas(p1) / (v01 - AREA * y), bulk_gas(p2) / (v02 + AREA * y)
            q1, q2 = g_acc * max(p_a - p1, 0.0), g_acc * max(p_a - p2, 0.0)
            ddp = ((g1 + g2) * (AREA * vd - q) + g1 * q1 - g2 * q2) / (1 + (g1 + g2) * AREA**2 * comp)
            vp = vd - comp * AREA * ddp
            dpress = [g1 * (AREA * vp - q + q1), g2 * (-AREA * vp + q + q2)]
        else:
            b_hi, b_lo = bulk(p_r + abs(dp)), bulk(p_r)
            b1, b2 = (b_hi, b_lo) if dp >= 0 else (b_lo, b_hi)
            kk = b1 / (v01 - AREA * y) + b2 / (v02 + AREA * y)
            ddp = kk * (AREA * vd - q) / (1 + kk * AREA**2 * comp)
            vp = vd - comp * AREA * ddp
            dpress = [ddp]
        rates = dpress + [dx, va - vd if tau_a > 0 else 0.0, aa + (va - vf) / CORNER_TIME_S]
        return rates, vp, va, aa, dp

    def force(t, z, k):
        _, vp, va, aa, dp = signals(t, z, k)
        level = fr["coulomb_N"]
        if fr["stribeck_N"] > 0:
            level += fr["stribeck_N"] * math.exp(-(vp / fr["stribeck_velocity_m_s"]) ** 2)
        fric = level * math.tanh(vp / SIGN_VELOCITY_M_S) + fr["viscous_Ns_per_m"] * vp
        return AREA * dp + fric + mass * (aa + (va - z[-1]) / CORNER_TIME_S)

    breaks, piece = inp
    pressure = [p_a + max(dp0, 0.0), p_a + max(-dp0, 0.0)] if two else [dp0]
    z = np.array(pressure + [x_ss(dp0) if (p_v > 0 and tau_v > 0) else 1.0, v_prev * tau_a, v_prev])
    atol = [1e-6] * n_p + [1e-12, 1e-14, 1e-14]
    out = np.full(t_out.size, np.nan)
    for k in range(breaks.size - 1):
        ta, tb = max(breaks[k], t0), min(breaks[k + 1], t_out[-1])
        if tb <= ta:
            continue
        first = t_out <= ta if np.all(np.isnan(out)) else np.zeros(t_out.size, bool)
        out[first] = force(ta, z, k)
        sel = np.flatnonzero((t_out > ta) & (t_out <= tb))
        t_eval = t_out[sel] if sel.size and t_out[sel[-1]] == tb else np.append(t_out[sel], tb)
        sol = solve_ivp(lambda t, z_, k=k: signals(t, z_, k)[0], (ta, tb), z, method="Radau", t_eval=t_eval,
                        rtol=1e-10, atol=atol)
        assert sol.status == 0, sol.message
        for j, i in enumerate(sel):
            out[i] = force(t_out[i], sol.y[:, j], k)
        z = sol.y[:, -1]
    return out


def kernel_force(t_out, drive, t0, dp0, v_prev, effects, rtol=1e-7, atol=1e-3, alpha_v=DYN.liquid_gas_ratio,
                 p_r=DYN.reference_pressure):
    """The composed kernel on ``drive`` (the measured displacement; the effects' input transforms applied here)."""
    comp = effects if isinstance(effects, ComposedEffects) else compose(effects)
    d = comp.transform_input(drive).cover(t0, float(t_out[-1]))
    return solve_composed(comp, t_out, d, t0, dp0, v_prev, D, FLOW4, alpha_v, p_r, rtol, atol)


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
def test_first_effects_off_equal_the_eq7_kernel(case):
    t, kt, ky, t0, dp0, v_prev = window_case(*case)
    off = {name: EFFECTS[name].off_values() for name in _FIRST}
    f, st = kernel_force(t, PiecewisePolynomial.from_knots(kt, ky), t0, dp0, v_prev, off, *OFF_SOLVER_TOL)
    w = PiecewisePolynomial.from_knots(kt, ky).window(t0, float(t[-1]))
    dp, st7, _ = solve_eq7(t, w.breaks, w.coefs, w.restart, dp0, AREA, D.chamber_volume_1, D.chamber_volume_2,
                           D.liquid_bulk_modulus, FLOW4, DYN.liquid_gas_ratio, DYN.reference_pressure, 0, 0.0,
                           *OFF_SOLVER_TOL)
    assert st == STATUS_OK and st7 == STATUS_OK
    assert rel_l2(f, AREA * dp) < OFF_RTOL


COMBOS = {name: {name: {}} for name in _FIRST if name != "backlash"}  # the reference has no play operator
COMBOS["friction+stribeck+viscous"] = {"friction": {"stribeck_N": 80.0, "viscous_Ns_per_m": 2e4}}
COMBOS["valve_quasi_static"] = {"valve_dynamics": {"time_constant_s": 0.0}}
COMBOS["valve_slow"] = {"valve_dynamics": {"time_constant_s": 1.0, "opening_pressure_Pa": 2e5}}
COMBOS["valve_fast_lag_fast"] = {"valve_dynamics": {"time_constant_s": 1e-4},
                                 "actuator_lag": {"time_constant_s": 1e-4}}
COMBOS["soft_mount"] = {"series_compliance": {"stiffness_N_per_m": 1e6}}
ALL = {"friction": {}, "actuator_lag": {}, "valve_dynamics": {}, "series_compliance": {}, "inertia": {}}
#: Each combination from rest and across a reversal (the latter in the slow suite: "all" covers every effect's start
#: after a reversal in the default one), and all together in all four cases.
REF_CASES = [pytest.param(name, CASES[0], id=f"{name}-{CASE_IDS[0]}") for name in COMBOS]
REF_CASES += [pytest.param(name, CASES[3], id=f"{name}-{CASE_IDS[3]}", marks=pytest.mark.slow) for name in COMBOS]
REF_CASES += [pytest.param("all", c, id=f"all-{i}") for c, i in zip(CASES, CASE_IDS, strict=True)]


@pytest.mark.parametrize("combo,case", REF_CASES)
def test_kernel_matches_radau_reference(combo, case):
    t, kt, ky, t0, dp0, v_prev = window_case(*case, rate=50.0)  # the Python reference is slow per sample
    eff = ALL if combo == "all" else COMBOS[combo]
    drive = PiecewisePolynomial.from_knots(kt, ky)
    f, st = kernel_force(t, drive, t0, dp0, v_prev, eff)
    assert st == STATUS_OK and np.all(np.isfinite(f))
    ref = reference_force(t, linear_input(kt, ky), t0, dp0, v_prev, eff)
    assert rel_l2(f, ref) < REF_RTOL, rel_l2(f, ref)
    plain, _ = kernel_force(t, drive, t0, dp0, v_prev, None)
    assert rel_l2(ref, plain) > VISIBLE * REF_RTOL  # the effect is visible at this tolerance


# ----------------------------------------------------------------------------- smooth input
def spline_drive(t, y):
    """Quintic interpolating spline through samples as the kernels' polynomial pieces (no restart inside)."""
    from scipy.interpolate import PPoly, make_interp_spline

    pp = PPoly.from_spline(make_interp_spline(t, y, k=5))
    keep = np.diff(pp.x) > 0
    brk = np.r_[pp.x[:-1][keep], pp.x[1:][keep][-1]]
    return PiecewisePolynomial(brk, pp.c[::-1, keep].T, np.zeros(brk.size, dtype=bool))


#: A 0.7 Hz, 3 mm sine from mid-stroke at peak speed (13 mm/s; reversals at 0.36 s and 1.07 s), through a
#: quintic spline at 300 Hz: its displacement is within 1e-15 m of the sine, its velocity 1e-10 and its
#: acceleration 2e-8 relative, far below the tolerances below.
SINE_A, SINE_F, SINE_END = 3e-3, 0.7, 1.6
SINE_T = np.arange(0.0, SINE_END + 1e-9, 1 / 300)
SINE = spline_drive(SINE_T, SINE_A * np.sin(2 * np.pi * SINE_F * SINE_T))
SINE_V0 = SINE_A * 2 * np.pi * SINE_F
#: Effects on the sine: the lag delays by a visible 0.22 rad (26 % of the force); the heaviest mass of the prior
#: (1e4 kg) adds m a(t), 0.25 % (the corner filter stays at v_A on a smooth input); all five ODE effects together.
LAG, MASS = {"actuator_lag": {"time_constant_s": 0.05}}, {"inertia": {"mass_kg": 1e4}}
SMOOTH = [pytest.param({**LAG, **MASS}, id="actuator_lag+inertia"),
          pytest.param(LAG, id="actuator_lag", marks=pytest.mark.slow),
          pytest.param(MASS, id="inertia", marks=pytest.mark.slow),
          pytest.param(ALL, id="all", marks=pytest.mark.slow)]


@pytest.mark.parametrize("effects", SMOOTH)
def test_kernel_on_a_smooth_input_matches_radau_with_the_analytic_sine(effects):
    """Spline pieces in the kernel against the analytic sin, cos and -sin in the reference, from the steady state
    at the peak speed (both start with the lag's trail and the filter at v_A(0))."""
    t = np.arange(0.0, SINE_END, 0.01)
    f, st = kernel_force(t, SINE, 0.0, 0.0, SINE_V0, effects)
    assert st == STATUS_OK
    ref = reference_force(t, sine_input(SINE_A, SINE_F, SINE_END), 0.0, 0.0, SINE_V0, effects)
    assert rel_l2(f, ref) < REF_RTOL, rel_l2(f, ref)
    for name in effects:  # each effect is visible at this tolerance
        without, _ = kernel_force(t, SINE, 0.0, 0.0, SINE_V0, {k: v for k, v in effects.items() if k != name})
        assert rel_l2(ref, without) > VISIBLE * REF_RTOL, name


#: Brute-force play operator on a time grid of step PLAY_DT (plus the breaks) vs the exact pieces: between grid
#: points the clip recursion misses at most the part of a smooth reversal beyond its samples, |a| DT^2 / 8 < 2e-11 m
#: here (reversals at velocity jumps sit on the breaks), and the pieces' roots are exact to round-off (measured
#: <= 1e-12 m): 1e-10 m is 1e-7 of the wider gap.
PLAY_ATOL = 1e-10  # [m]
PLAY_DT = 2e-5  # [s]
PLAY_GAPS = (1e-3, 2e-4)  # [m]: the narrow play is taken up by the input's smallest reversal, the wide one is not


def brute_force_play(t, ya, gap):
    """``y_P <- clip(y_P, y_A - r, y_A + r)`` sample by sample, from the piston centred in the play."""
    r = 0.5 * gap
    out = np.empty_like(ya)
    yp = float(ya[0])
    for i, y in enumerate(ya.tolist()):
        yp = min(max(yp, y - r), y + r)
        out[i] = yp
    return out


def _check_play(drive, gap):
    from bayesdamper.physics.effects.backlash import play_polynomial

    t = np.union1d(np.arange(drive.start, drive.end, PLAY_DT), drive.breaks)
    brute = brute_force_play(t, drive.displacement(t), gap)
    piston = play_polynomial(drive, gap)
    assert np.max(np.abs(piston.displacement(t) - brute)) < PLAY_ATOL, gap
    held = np.diff(brute) == 0
    assert 0.05 < held.mean() < 0.9  # the piston rests for part of the record and moves for the rest


def quadratic_reversals():
    """Quadratic pieces, each monotone, the velocity changing sign by a jump at every break (restart breaks);
    the third piece's 0.37 mm rise stays inside the wide play."""
    breaks = np.array([0.0, 0.8, 2.0, 2.6, 3.0, 4.2])
    vc = [(2e-3, -0.5e-3), (-2.5e-3, 0.6e-3), (0.5e-3, 0.2e-3), (-0.8e-3, 0.5e-3), (3e-3, -1e-3)]
    coefs, y = [], 0.0
    for (v, c), h in zip(vc, np.diff(breaks), strict=True):
        assert v * (v + 2 * c * h) > 0  # no reversal inside the piece
        coefs.append([y, v, c])
        y += v * h + c * h * h
    return PiecewisePolynomial(breaks, np.array(coefs), np.ones(breaks.size, dtype=bool))


@pytest.mark.parametrize("gap", PLAY_GAPS)
def test_backlash_on_polynomial_pieces_equals_a_brute_force_play_operator(gap):
    """Degree 2 (the general root-finding path, not the degree-1 knots): contacts at roots inside the pieces,
    releases at the reversals on the breaks."""
    _check_play(quadratic_reversals(), gap)


def smooth_reversals():
    """A 0.7 Hz, 3 mm sine with a 3.1 Hz, 0.8 mm ripple through a quintic spline at 300 Hz: 18 reversals with zero
    velocity inside the spline's pieces, some of the ripple's small ones inside the wide play."""
    ts = np.arange(0.0, 3.0 + 1e-9, 1 / 300)
    return spline_drive(ts, 3e-3 * np.sin(2 * np.pi * 0.7 * ts) + 0.8e-3 * np.sin(2 * np.pi * 3.1 * ts + 0.4))


def hermite_reversals():
    """Cubic Hermite pieces through the extrema with zero slope there: every reversal on a break, the velocity
    passing continuously through 0 (no restart); the 0.4 mm rise stays inside the wide play."""
    from scipy.interpolate import CubicHermiteSpline

    te = np.array([0.0, 1.0, 2.0, 2.6, 3.2, 4.5])
    h = CubicHermiteSpline(te, [0.0, 2e-3, -1e-3, -0.6e-3, -1.1e-3, 1.5e-3], np.zeros(te.size))
    return PiecewisePolynomial(h.x, h.c[::-1].T, np.zeros(te.size, dtype=bool))


@pytest.mark.parametrize("gap", PLAY_GAPS)
@pytest.mark.parametrize("inp", [smooth_reversals, hermite_reversals])
def test_backlash_on_a_smooth_input_equals_a_brute_force_play_operator(inp, gap):
    _check_play(inp(), gap)


# ----------------------------------------------------------------------------- robustness
def test_random_prior_draws_succeed_and_are_finite():
    """The first effects drawn log-uniformly over their prior boxes, α_V and p_R over theirs, four cases."""
    rng = np.random.default_rng(7)
    n_fail = 0
    for _ in range(200):
        t, kt, ky, t0, dp0, v_prev = window_case(int(rng.choice([1, -1])), bool(rng.random() < 0.5))
        eff = {name: {p.name: float(np.exp(rng.uniform(np.log(p.lower), np.log(p.upper))))
                      for p in EFFECTS[name].params}
               for name in _FIRST if rng.random() < 0.5}
        a, p = np.exp(rng.uniform(np.log(2.0), np.log(5000.0))), np.exp(rng.uniform(np.log(1e3), np.log(1e7)))
        drive = PiecewisePolynomial.from_knots(kt, ky)
        f, st = kernel_force(t, drive, t0, dp0, v_prev, eff, 1e-6, 1.0, alpha_v=a, p_r=p)
        n_fail += st != STATUS_OK
        assert st != STATUS_OK or np.all(np.isfinite(f))
    assert n_fail == 0


def _first_value(comp, name):
    """Index in ``comp.values`` of the first parameter of the effect ``name``."""
    k = comp.names.index(name)
    return sum(len(EFFECTS[n].params) for n in comp.names[:k])


@pytest.mark.parametrize("change,status", [
    (dict(t0=4.7), STATUS_BAD_INPUT),  # samples before t0
    (dict(value=("valve_dynamics", math.nan)), STATUS_BAD_INPUT),
    (dict(value=("inertia", -math.inf)), STATUS_BAD_INPUT),  # +inf is admissible (an off stiffness), -inf never
    (dict(dp0=math.inf), STATUS_BAD_INPUT),
    (dict(p_r=0.0), STATUS_BAD_INPUT),
    (dict(ky_scale=1e3), "failed"),  # a 5 m stroke empties a chamber
    (dict(rtol=1e-15, atol=1e-15), None),  # impossible tolerance: fails cleanly, whatever the reason
])
def test_impossible_inputs_give_status_not_nan(change, status):
    """Values :func:`compose` would refuse reach the kernel only by a hand-made ComposedEffects: a status, no raise."""
    t, kt, ky, t0, dp0, v_prev = window_case(1, True)
    comp = compose(ALL)
    if "value" in change:
        name, value = change.pop("value")
        values = comp.values.copy()
        values[_first_value(comp, name)] = value
        comp = ComposedEffects(comp.names, values)
    ky = ky * change.pop("ky_scale", 1.0)
    kw = dict(t0=t0, dp0=dp0, rtol=1e-7, atol=1e-3, p_r=DYN.reference_pressure) | change
    drive = comp.transform_input(PiecewisePolynomial.from_knots(kt, ky))
    f, st = solve_composed(comp, t, drive, kw["t0"], kw["dp0"], v_prev, D, FLOW4, DYN.liquid_gas_ratio, kw["p_r"],
                           kw["rtol"], kw["atol"])
    assert f.shape == t.shape
    if status is None:
        assert st != STATUS_OK or np.all(np.isfinite(f))  # never NaN with status 0
    elif status == "failed":
        assert st != STATUS_OK
    else:
        assert st == status


@pytest.mark.parametrize("name", _FIRST)
def test_compose_refuses_inadmissible_values_in_one_line(name):
    p = EFFECTS[name].params[0]
    bad = 0.0 if p.reciprocal else -1.0
    with pytest.raises(SettingsError) as err:
        compose({name: {p.name: bad}})
    assert p.name in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(SettingsError):
        compose({name: {p.name: math.nan}})


def test_wrapper_raises_one_line_error():
    exc = PiecewiseLinear([0.0, 1.0, 2.0], [0.0, 0.0, 1.0])  # 1 m stroke: chamber volume <= 0
    with pytest.raises(BayesDamperError) as err:
        simulate_effects(np.linspace(0, 2, 11), exc, D, PAPER_FLOW, DYN, {"friction": {}}, t0=0.0)
    assert "composed solve failed" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(SettingsError):
        simulate_effects(np.linspace(0, 2, 11), exc, D, PAPER_FLOW, DYN, {"gravity": {}})
    with pytest.raises(SettingsError, match="before the start"):
        simulate_effects(np.linspace(0, 2, 11), exc, D, PAPER_FLOW, DYN, {"friction": {}}, t0=0.5)


def test_wrapper_error_names_the_emptied_chamber():
    exc = PiecewiseLinear([0.0, 1.0, 2.0], [0.0, 0.0, 1.0])
    with pytest.raises(BayesDamperError, match="chamber volume"):
        simulate_effects(np.linspace(0, 2, 11), exc, D, PAPER_FLOW, DYN, {"friction": {}}, t0=0.0)


# ----------------------------------------------------------------------------- problem binding
@pytest.fixture(scope="module")
def friction_dataset(tmp_path_factory):
    from bayesdamper.io.dataset import load_dataset
    from bayesdamper.io.segmentation import segment_dataset
    from bayesdamper.io.synthetic import write_dataset

    effects = {"friction": {"coulomb_N": 150.0}, "actuator_lag": {"time_constant_s": 0.02},
               "backlash": {"gap_m": 2e-5}}
    out = write_dataset(tmp_path_factory.mktemp("effects") / "ds", [1.2e-3], DYN, effects=effects)
    return effects, segment_dataset(load_dataset(out))[0]


#: The problem's force from the step force vs a solve from the Δp0 that the step force implies: the same solve but
#: for the Newton iterate of Δp0 (converged to round-off, the force being affine in Δp0 with slope A_P).
SAME_START_N = 1e-6  # [N]


def test_problem_reproduces_simulated_transients(friction_dataset):
    """Noise-free data simulated with effects: the problem with the true effects matches every window."""
    effects, seg = friction_dataset
    comp = compose(effects)
    assert len(seg.transients) == 3
    for tr in seg.transients:
        pb = EffectsProblem.from_window(tr, D, PAPER_FLOW)
        assert pb.step_force == pytest.approx(tr.dp0 * AREA) and not pb.free_start
        f, ok = pb.simulate_force(DYN.liquid_gas_ratio, DYN.reference_pressure, comp)
        assert ok
        # CSV rounding (1e-4 N), segmentation's fitted knots and the step-force average limit this
        assert np.max(np.abs(f - pb.force)) < 0.01 * np.max(np.abs(pb.force)), tr.id
        f0, ok0 = pb.simulate_force(DYN.liquid_gas_ratio, DYN.reference_pressure, compose(None))
        assert ok0 and np.max(np.abs(f0 - pb.force)) > 5 * np.max(np.abs(f - pb.force))
        # the step force includes friction: Δp0 = (F_step - F_f(v_before)) / A_P, v_before the piston's velocity
        # behind the play just before the step (the lag's steady trail keeps it)
        drive = comp.transform_input(tr.drive).cover(tr.t_step, float(tr.time[-1]))
        v_before = drive.velocity_before(tr.t_step)
        assert (v_before == 0.0) == (tr.kind == "initial")
        dp0 = (pb.step_force - 150.0 * np.sign(v_before)) / AREA
        f_dp0, st = solve_composed(comp, pb.time, drive, tr.t_step, dp0, v_before, D, FLOW4, DYN.liquid_gas_ratio,
                                   DYN.reference_pressure, pb.rtol, pb.atol)
        assert st == STATUS_OK and np.max(np.abs(f_dp0 - f)) < SAME_START_N, tr.id
        # a parameter the kernel cannot use: a failed solve, not an exception or NaN to the sampler
        values = comp.values.copy()
        values[_first_value(comp, "friction")] = math.nan  # the Coulomb force
        f_bad, ok_bad = pb.simulate_force(DYN.liquid_gas_ratio, DYN.reference_pressure,
                                          ComposedEffects(comp.names, values))
        assert not ok_bad and f_bad.shape == pb.time.shape


#: EffectsProblem without effects (composed kernel, rtol 1e-6) vs the eq. (7) window (its own kernel, same
#: tolerances): the same ODE from the same Δp0 by the same method, so they agree far below the solvers' global
#: error (measured <= 2e-10); any effect left on, or a different start, shows at >= 1e-3.
NO_EFFECT_RTOL = 1e-6


def test_problem_without_effects_equals_eq7_on_the_transient(friction_dataset):
    _, seg = friction_dataset
    for tr in seg.transients:
        pb = EffectsProblem.from_window(tr, D, PAPER_FLOW)
        f, ok = pb.simulate_force(50.0, 2e5, compose(None))
        eq7 = WindowProblem.from_window(tr, D, PAPER_FLOW, rtol=pb.rtol, atol=pb.atol)
        f7, ok7 = eq7.simulate_force(50.0, 2e5)
        assert ok and ok7 and rel_l2(f, f7) < NO_EFFECT_RTOL, rel_l2(f, f7)


# ----------------------------------------------------------------------------- two-state model with effects
TWO_EXC = PiecewiseLinear([0.0, 0.5, 3.0, 5.0], [0.0, 0.0, 2.5e-3, 0.5e-3])
TWO_T = np.arange(0.0, 5.0, 0.01)
#: Composed two-state model (default tolerances, rtol 1e-6, atol 0.01 Pa) vs the package's scipy two-state model
#: (rtol 1e-8): the force's solver error, measured 2.5e-3 N on forces of 4 kN.
TWO_STATE_N = 0.01  # [N]


@functools.cache
def _two_state_plain():
    return AREA * simulate_two_state(TWO_T, TWO_EXC, D, PAPER_FLOW, DYN, t0=0.0,
                                     accumulator_conductance=TWO_STATE_G).dp


def _two_state(effects):
    return simulate_effects(TWO_T, TWO_EXC, D, PAPER_FLOW, DYN, two_state_effects(DYN, effects, TWO_STATE_G),
                            t0=0.0)


def test_two_state_effects_off_and_friction():
    """Eq. (7) composed with the accumulator at p_R is the two-state model eq. (1); friction adds F_C sign(v)."""
    plain = _two_state_plain()
    off = _two_state(None)
    assert np.max(np.abs(off - plain)) < TWO_STATE_N
    eq7 = simulate_effects(TWO_T, TWO_EXC, D, PAPER_FLOW, DYN, None, t0=0.0)
    assert np.max(np.abs(eq7 - plain)) > 100 * TWO_STATE_N  # eq. (6) is a different model
    fr = _two_state({"friction": {"coulomb_N": 120.0}})
    v = TWO_EXC.velocity(TWO_T)
    away = np.min(np.abs(TWO_T[:, None] - TWO_EXC.knot_times[None, :]), axis=1) > 0.01
    # friction changes neither the ODE nor its steps: the difference is the friction force to round-off
    assert np.allclose((fr - off)[away], 120.0 * np.sign(v[away]), atol=1e-6)
    # the same effect on the two bases: of similar size (eq. (6) approximates eq. (1))
    both = {"valve_dynamics": {}, "series_compliance": {}, "actuator_lag": {}}
    d2 = _two_state(both) - off
    d7 = simulate_effects(TWO_T, TWO_EXC, D, PAPER_FLOW, DYN, both, t0=0.0) - eq7
    assert np.max(np.abs(d2)) == pytest.approx(np.max(np.abs(d7)), rel=0.3)
    with pytest.raises(SettingsError):
        two_state_effects(DYN, None, 0.0)


TWO_STATE_CASES = [pytest.param("all", ALL, id="all"),
                   pytest.param("valve_slow", COMBOS["valve_slow"], id="valve_slow", marks=pytest.mark.slow),
                   pytest.param("soft_mount", COMBOS["soft_mount"], id="soft_mount", marks=pytest.mark.slow),
                   pytest.param("friction", {**COMBOS["friction+stribeck+viscous"], "inertia": {}},
                                id="friction+stribeck+viscous+inertia", marks=pytest.mark.slow)]


@pytest.mark.parametrize("combo,eff", TWO_STATE_CASES)
def test_two_state_with_effects_matches_radau_reference(combo, eff):
    """The composed two-state model with effects (states Δp, p̄ and the effects') against the reference on
    (p_1, p_2): from rest through a ramp and a reversal, and (all effects) a reversal window starting loaded."""
    f, st = kernel_force(TWO_T, TWO_EXC.as_polynomial(), 0.0, 0.0, 0.0, two_state_effects(DYN, eff, TWO_STATE_G))
    assert st == STATUS_OK
    ref = reference_force(TWO_T, linear_input(TWO_EXC.knot_times, TWO_EXC.knot_displacements), 0.0, 0.0, 0.0, eff,
                          accumulator=(DYN.reference_pressure, TWO_STATE_G))
    assert rel_l2(f, ref) < REF_RTOL, rel_l2(f, ref)
    # an adiabatic-leaning gas (κ 1.3): the kernel's eq. (2) against the reference's
    fk, st = kernel_force(TWO_T, TWO_EXC.as_polynomial(), 0.0, 0.0, 0.0,
                          two_state_effects(DYN, eff, TWO_STATE_G, kappa=1.3))
    refk = reference_force(TWO_T, linear_input(TWO_EXC.knot_times, TWO_EXC.knot_displacements), 0.0, 0.0, 0.0, eff,
                           accumulator=(DYN.reference_pressure, TWO_STATE_G), kappa=1.3)
    assert st == STATUS_OK and rel_l2(fk, refk) < REF_RTOL, rel_l2(fk, refk)
    assert rel_l2(refk, ref) > VISIBLE * REF_RTOL  # κ is visible in the force
    assert rel_l2(ref, _two_state_plain()) > VISIBLE * REF_RTOL
    if combo == "all":
        t, kt, ky, t0, dp0, v_prev = window_case(-1, True, rate=50.0)
        f, st = kernel_force(t, PiecewisePolynomial.from_knots(kt, ky), t0, dp0, v_prev,
                             two_state_effects(DYN, eff, TWO_STATE_G))
        ref = reference_force(t, linear_input(kt, ky), t0, dp0, v_prev, eff,
                              accumulator=(DYN.reference_pressure, TWO_STATE_G))
        assert st == STATUS_OK and rel_l2(f, ref) < REF_RTOL, rel_l2(f, ref)


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
