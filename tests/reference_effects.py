"""Independent reference simulator of eq. (7) with optional physical effects (scipy Radau, no bayesdamper).

This helper module (not a test file) extends :func:`independent.simulate` with the nine "effects" of the
effect-composition spec, written from the equations alone so that bayesdamper's compiled effect kernel can be
judged against data bayesdamper did not make, plus one pseudo-effect bayesdamper's library does not hold,
``fluid_inertance`` (an effect "in a form the library does not hold"), a physical two-state base damper
``two_state_damper`` and a compliant mount ``series_compliance`` (both below). It must never import
``bayesdamper``, and the two-state base was written from the paper's eqs. (1)-(2) without reading the library's
``two_state`` effect it is meant to judge.

Model, SI units throughout. At time t, with the measured displacement y_A(t) and its velocity v_A(t):

* piston motion y_P, v_P = y_A, v_A, or the states of the ``command_displacement`` servo;
* chamber volumes V_1 = V_01 - A y_P, V_2 = V_02 + A y_P;
* orifice flow Q_O(Δp) of eq. (8) (:func:`independent.orifice_flow`), or with ``fluid_inertance`` the state
  Q_L of L dQ_L/dt = Δp - Δp_O(Q_L), Δp_O(Q) = C_L Q + C_Q Q|Q| of eq. (4) (:func:`independent.quasi_static_dp`),
  which then replaces Q_O everywhere below; path flow
  Q = Q_O (ε + clip(x, 0, 1)) / (ε + s) [poppet_valve] + G_l Δp [leakage] + g y [unnamed_dynamics, placement 1];
* the poppet valve: one valve element passing either direction, its lift x_+ a damped oscillator
  ẍ = ω^2 (s - x) - 2ζω ẋ towards s = clip((|Δp| - p_c) / p_s, 0, 1) (x_- unused); with ``per_direction`` 1 a
  check valve for each flow direction instead, lifts x_+ and x_- each driven towards s_± = clip((±Δp - p_c) / p_s,
  0, 1), the flow passing the valve of its direction (x, s = x_+, s_+ for Δp >= 0, else x_-, s_-);
* the unnamed filter: ẅ = ω^2 (L(u) - w) - 2ζω ẇ, output y = w (``mode`` 0) or y = w - L(u) (``mode`` 1, the
  transient: zero in steady state), added as g y to the force (placement 0) or to the path flow (placement 1);
* B(p) = B_0 (1 + α_V) / (α_V + B_0 p_R / p^2); eq. (6) picks B_1, B_2 from p_R and p_R + |Δp| and
  dΔp/dt = (B_1/V_1 + B_2/V_2) (A v_P - Q) (the ``accumulator`` replaces this by two absolute pressures);
* force F = A Δp + the effects' force terms.

The physical two-state base (``two_state_damper``, replaces eq. (7)/(6); α_V and p_R of the signature are then
unused). States Δp = p_1 - p_2, p̄ = (p_1 + p_2)/2 (a linear map of the two absolute chamber pressures, reported
as ``p_1``, ``p_2``) and the accumulator pressure p_a:

* eq. (1): dp_1/dt = B(p_1)/V_1 (+A v_P - Q + r_1),  dp_2/dt = B(p_2)/V_2 (-A v_P + Q + r_2);
* eq. (2) (:func:`polytropic_bulk_modulus`): B(p) = B_0 [1 + (1/α_V0)(p_0/p)^(1/κ)] /
  [1 + (1/α_V0)(B_0/(κ p_0))(p_0/p)^((κ+1)/κ)], the free gas polytropic (exponent κ), its volume referenced to
  ATMOSPHERIC pressure p_0 = 101325 Pa: α_V0 = V_L/V_G at p_0 (gas-to-liquid ratio (1/α_V0)(p_0/p)^(1/κ) at p);
* refill r_i = q_line(p_a - p_i) + G_b (p_a - p_i): each chamber is fed from the accumulator through a restriction
  (dp = q/G + R_T q^2: laminar conductance G, optional turbulent coefficient R_T, :func:`line_flow`) and a check
  valve that opens only towards a chamber below p_a (no cracking pressure), plus an optional two-way bleed G_b;
* the accumulator's gas (same κ, volume V_a0 at the precharge p_c): p_a V_a^κ = p_c V_a0^κ, so
  dp_a/dt = -κ p_a (r_1 + r_2) / V_a(p_a), V_a(p) = V_a0 (p_c/p)^(1/κ);
* start: chambers and accumulator at p_c in equilibrium, the loaded chamber at p_c + |Δp0| (as ``accumulator``).

Choices: one line per chamber rather than one restriction feeding both check valves (the same whenever only one
valve is open, which is the case after a velocity step: only the unloaded chamber falls below p_a); the liquid's
volume is held at its p_0 value in eq. (2)'s numerator (as the paper's eq. (2)); no cavitation: below 100 Pa B is
continued linearly to 0 at p = 0, which the pressures cannot cross (eq. (2) itself tends to κ p); volumetric flows
are the same on both sides of the orifice (eq. (1)), so mass is conserved up to O(p/B_0).

The mount (``series_compliance``, stiffness k_s): the actuator (y_A or the servo's output) drives the piston through
a spring carrying A Δp, so y_P = y_act - (A/k_s) Δp and v_P = v_act - (A/k_s) dΔp/dt; writing the chamber
equations as dp_1/dt = a_1 (A v_P + e_1), dp_2/dt = a_2 (-A v_P + e_2) (any base), dΔp/dt =
[(a_1 + a_2) A v_act + a_1 e_1 - a_2 e_2] / (1 + (a_1 + a_2) A^2/k_s) (for eq. (7): K (A v_act - Q) / (1 + K A^2/k_s)
as ``reference_cycles.simulate_compliant``). The load cell reads A Δp plus the sensor-side terms (offset, mains);
friction, the gas spring and the unnamed filter are refused with it (their forces would deflect the mount too).

State vector: Δp first, then the effects' states in the canonical order of :data:`EFFECT_PARAMS`
(see :func:`state_names`). Inputs are the objects of ``independent.py`` (``displacement``, ``velocity``,
``breakpoints``); the Radau integration restarts at every input breakpoint, as :func:`independent.simulate`.

Choices where the spec leaves room:

* the servo is integrated as the tracking error e = y_P - y_A (same equations; ω^2 (y_A - y_P) of two
  nearly equal positions loses ~1e-7 m/s^2 to rounding at 1e5 Hz and stalls Radau); ``y_p`` is reported;
* the unnamed filter's driver 1 is the bare eq. (8) flow Q_O(Δp) (Q_L with ``fluid_inertance``), before the
  poppet scaling and the leak; in mode 1, L(u) is taken at the current time (no algebraic loop: u never
  depends on the filter's output);
* without the servo, force terms at a sample time use the right-continuous v_A (``inp.velocity``), like
  the Coulomb term of :func:`independent.simulate`; the unnamed filter starts at rest at its input just before
  t0 (driver v_P: the velocity before the step, ``v_prev``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from independent import TriangleInput, bulk_modulus, orifice_flow, quasi_static_dp, segment_functions
from scipy.integrate import solve_ivp

__all__ = [
    "BASES",
    "EFFECT_PARAMS",
    "EFFECT_STATES",
    "NOT_WITH_MOUNT",
    "POPPET_EPSILON",
    "alpha_for_gas_fraction",
    "gas_fraction",
    "inertance_for_frequency",
    "line_flow",
    "polytropic_bulk_modulus",
    "resolve_effects",
    "simulate_effects",
    "state_names",
]

#: Effect name -> {parameter name: default}; ``None`` marks a required parameter. The key order is the
#: canonical order of the effects' states in the state vector.
EFFECT_PARAMS: dict[str, dict[str, float | None]] = {
    "command_displacement": {"bandwidth_Hz": None, "damping_ratio": None},
    "poppet_valve": {"natural_frequency_Hz": None, "damping_ratio": None, "cracking_pressure_Pa": None,
                     "span_Pa": 1e6, "bleed_fraction": 0.1, "per_direction": 0},
    "accumulator": {"charge_pressure_Pa": None, "conductance_m3_per_s_Pa": None},
    "gas_spring": {"stiffness_N_per_m": None},
    "load_cell_offset": {"offset_N": None},
    "mains_interference": {"cos_amplitude_N": None, "sin_amplitude_N": None, "frequency_Hz": 50.0},
    "leakage": {"conductance_m3_per_s_Pa": None},
    "seal_friction": {"stribeck_N": None, "stribeck_velocity_m_s": None, "viscous_Ns_per_m": None},
    "unnamed_dynamics": {"gain": None, "natural_frequency_Hz": None, "damping_ratio": None, "threshold": 0.0,
                         "driver": 0, "law": 0, "placement": 0, "mode": 0},
    "fluid_inertance": {"inertance_kg_per_m4": None},
    "two_state_damper": {"polytropic_exponent": None, "liquid_gas_ratio_atm": None, "charge_pressure_Pa": None,
                         "accumulator_volume_m3": None, "line_conductance_m3_per_s_Pa": None,
                         "line_turbulent_kg_per_m7": 0.0, "bleed_conductance_m3_per_s_Pa": 0.0,
                         "atmospheric_pressure_Pa": 101325.0},
    "series_compliance": {"stiffness_N_per_m": None},
}

#: Effect name -> names of its states (in state-vector order); effects not listed have no state.
EFFECT_STATES: dict[str, tuple[str, ...]] = {
    "command_displacement": ("y_p", "v_p"),
    "poppet_valve": ("valve_lift", "valve_rate", "valve_lift_reverse", "valve_rate_reverse"),
    "accumulator": ("p_mean",),
    "unnamed_dynamics": ("w", "w_dot"),
    "fluid_inertance": ("q_l",),
    "two_state_damper": ("p_mean", "p_acc"),
}
#: Effects that replace eq. (7)'s pressure equation by absolute chamber pressures: at most one of them.
BASES = ("accumulator", "two_state_damper")
#: Effects the series compliance cannot be combined with: their force would deflect the mount too (friction,
#: gas spring, the unnamed filter's force) or their driver v_P would close an algebraic loop through the mount.
NOT_WITH_MOUNT = ("gas_spring", "seal_friction", "unnamed_dynamics")

#: Default ε of the poppet flow scaling (ε + clip(x, 0, 1)) / (ε + s(Δp)) (its ``bleed_fraction``).
POPPET_EPSILON = EFFECT_PARAMS["poppet_valve"]["bleed_fraction"]
#: Floor of the absolute chamber pressure used in the accumulator's bulk modulus [Pa].
ACCUMULATOR_P_FLOOR = 1e4
#: Below this absolute pressure [Pa] the two-state base's B(p) of eq. (2) is continued linearly to B = 0 at p = 0
#: (eq. (2) itself tends to κ p there): p = 0 is then a barrier the integration cannot cross (no cavitation model).
TWO_STATE_P_FLOOR = 100.0
#: Velocity scale of the seal friction's sign function tanh(v_P / V_SIGN) [m/s].
FRICTION_V_SIGN = 1e-5

# Characteristic magnitude of each kind of quantity, matched to 1 MPa of pressure, to scale the absolute
# tolerance of each state from ``atol`` [Pa]: 1 MPa <-> 1 cm <-> 0.1 m/s <-> 1e-5 m^3/s <-> 1 (unit-free).
_PRESSURE_SCALE = 1e6
_DRIVER_SCALES = {0: 1e6, 1: 1e-5, 2: 1e-2, 3: 1e-1}  # Δp [Pa], Q_O [m^3/s], y_P [m], v_P [m/s]
_INTEGER_PARAMS = {"driver": (0, 1, 2, 3), "law": (0, 1, 2, 3), "placement": (0, 1), "mode": (0, 1)}
_POSITIVE_PARAMS = ("span_Pa", "stribeck_velocity_m_s", "charge_pressure_Pa", "inertance_kg_per_m4",
                    "liquid_gas_ratio_atm", "accumulator_volume_m3", "atmospheric_pressure_Pa")
_NON_NEGATIVE_PARAMS = ("damping_ratio", "conductance_m3_per_s_Pa", "threshold", "line_conductance_m3_per_s_Pa",
                        "line_turbulent_kg_per_m7", "bleed_conductance_m3_per_s_Pa")


# ----------------------------------------------------------------------------- effect parameters
def _check(ok: bool, name: str, param: str, value: float, need: str) -> None:
    if not ok:
        raise ValueError(f"{name}.{param} must be {need}, got {value!r}")


def resolve_effects(effects: Mapping[str, Mapping[str, float]] | None) -> dict[str, dict[str, float]]:
    """Validate ``{effect: {param: value}}`` and fill the optional parameters' defaults.

    Parameters
    ----------
    effects : mapping or None
        Any subset of :data:`EFFECT_PARAMS`; ``None`` or ``{}`` means no effect.

    Returns
    -------
    dict
        ``{effect: {param: float}}`` in the canonical order of :data:`EFFECT_PARAMS`, every parameter present
        (``driver``, ``law``, ``placement`` and ``mode`` as ints).

    Raises
    ------
    ValueError
        Unknown effect or parameter, missing required parameter, or a value outside its domain: all values
        finite; frequencies, ``span_Pa``, ``stribeck_velocity_m_s``, ``charge_pressure_Pa``,
        ``inertance_kg_per_m4``, ``liquid_gas_ratio_atm``, ``accumulator_volume_m3``, ``atmospheric_pressure_Pa``
        and the mount's stiffness > 0; ``polytropic_exponent`` in [1, 2]; damping ratios, conductances,
        ``line_turbulent_kg_per_m7`` and ``threshold`` >= 0; ``threshold`` > 0 for law 3 (tanh(u / θ)); ``driver``,
        ``law`` in {0, 1, 2, 3}, ``placement`` and ``mode`` in {0, 1} (integral values); at most one of
        :data:`BASES`; ``series_compliance`` with none of :data:`NOT_WITH_MOUNT`.
    """
    effects = {} if effects is None else effects
    unknown = sorted(set(effects) - set(EFFECT_PARAMS))
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; known: {list(EFFECT_PARAMS)}")
    out: dict[str, dict[str, float]] = {}
    for name, spec in EFFECT_PARAMS.items():
        if name not in effects:
            continue
        given = effects[name]
        if not isinstance(given, Mapping):
            raise ValueError(f"effect {name!r} needs a mapping of parameters, got {given!r}")
        bad = sorted(set(given) - set(spec))
        if bad:
            raise ValueError(f"unknown parameter(s) {bad} of effect {name!r}; known: {list(spec)}")
        params: dict[str, float] = {}
        for param, default in spec.items():
            if param not in given and default is None:
                raise ValueError(f"effect {name!r} needs parameter {param!r}")
            value = float(given.get(param, default))
            _check(math.isfinite(value), name, param, value, "finite")
            if param in _INTEGER_PARAMS:
                _check(value in _INTEGER_PARAMS[param], name, param, value, f"one of {_INTEGER_PARAMS[param]}")
                value = int(value)
            elif param == "polytropic_exponent":
                _check(1.0 <= value <= 2.0, name, param, value, "in [1, 2]")
            elif param.endswith("_Hz") or param in _POSITIVE_PARAMS or name == "series_compliance":
                _check(value > 0.0, name, param, value, "> 0")
            elif param in _NON_NEGATIVE_PARAMS:
                _check(value >= 0.0, name, param, value, ">= 0")
            params[param] = value
        if name == "unnamed_dynamics" and params["law"] == 3:
            _check(params["threshold"] > 0.0, name, "threshold", params["threshold"], "> 0 with law 3")
        out[name] = params
    bases = [b for b in BASES if b in out]
    if len(bases) > 1:
        raise ValueError(f"effects {bases} both replace the pressure equation: choose one")
    clash = [n for n in NOT_WITH_MOUNT if n in out]
    if "series_compliance" in out and clash:
        raise ValueError(f"series_compliance cannot be combined with {clash} (see NOT_WITH_MOUNT)")
    return out


def state_names(effects: Mapping[str, Mapping[str, float]] | None) -> tuple[str, ...]:
    """Names of the states in state-vector order: ``"dp"`` then the effects' states (:data:`EFFECT_STATES`)."""
    names = ["dp"]
    for name in resolve_effects(effects):
        names.extend(EFFECT_STATES.get(name, ()))
    return tuple(names)


# ----------------------------------------------------------------------------- the physical two-state damper
def polytropic_bulk_modulus(p, b0: float, alpha_v0: float, kappa: float, p_atm: float = 101325.0):
    """Eq. (2): B(p) [Pa] of a liquid (B_0) carrying free gas that follows p V_G^κ = const, at absolute ``p`` [Pa].

        B(p) = B_0 [1 + (1/α_V0)(p_0/p)^(1/κ)] / [1 + (1/α_V0)(B_0/(κ p_0))(p_0/p)^((κ+1)/κ)]

    It is B = -V dp/dV of V = V_L + V_G with dV_L/dp = -V_L/B_0, V_G = V_G0 (p_0/p)^(1/κ), the liquid volume held
    at its value V_L at p_0 and α_V0 = V_L / V_G0 the liquid-gas ratio at atmospheric pressure ``p_atm`` = p_0.
    B -> B_0 as p -> ∞, B(p_0) < B_0 (as B_0 > κ p_0) and B ~ κ p as p -> 0. Below :data:`TWO_STATE_P_FLOOR` B
    is continued linearly to 0 at p = 0 (and is negative below: a pressure state cannot cross 0).
    """
    p = np.asarray(p, dtype=float)
    q = np.maximum(p, TWO_STATE_P_FLOOR)
    r = p_atm / q
    b = b0 * (1.0 + r ** (1.0 / kappa) / alpha_v0) / (1.0 + (b0 / (kappa * p_atm)) * r ** ((kappa + 1.0) / kappa)
                                                        / alpha_v0)
    return np.where(p >= TWO_STATE_P_FLOOR, b, b * p / TWO_STATE_P_FLOOR)


def gas_fraction(p, alpha_v0: float, kappa: float, p_atm: float = 101325.0):
    """Gas-to-liquid volume ratio V_G / V_L at absolute pressure ``p`` [Pa]: (1/α_V0) (p_0/p)^(1/κ)."""
    return (p_atm / np.asarray(p, dtype=float)) ** (1.0 / kappa) / alpha_v0


def alpha_for_gas_fraction(fraction: float, p: float, kappa: float, p_atm: float = 101325.0) -> float:
    """α_V0 = V_L / V_G at p_0 that gives the gas-to-liquid volume ratio ``fraction`` at pressure ``p`` [Pa]."""
    return (p_atm / p) ** (1.0 / kappa) / fraction


def line_flow(dp: float, conductance: float, turbulent: float) -> float:
    """Flow [m^3/s] through the accumulator's restriction at the pressure drop ``dp`` [Pa] >= 0: the root of
    dp = q / G + R_T q^2 (laminar conductance G [m^3/(s Pa)], turbulent coefficient R_T [kg/m^7]); 0 for G = 0."""
    if conductance <= 0.0 or dp <= 0.0:
        return 0.0
    r_l = 1.0 / conductance
    return 2.0 * dp / (r_l + math.sqrt(r_l * r_l + 4.0 * turbulent * dp))


# ----------------------------------------------------------------------------- the composed model
@dataclass
class _Model:
    """Eq. (7) plus the resolved effects: state derivatives and force (scalar states in the RHS)."""

    area: float
    v01: float
    v02: float
    b0: float
    flow: tuple[float, float, float, float]
    alpha_v: float
    p_r: float
    fx: dict[str, dict[str, float]]

    def __post_init__(self) -> None:
        self.b_ref = float(bulk_modulus(self.p_r, self.b0, self.alpha_v, self.p_r))
        self.index: dict[str, int] = {}
        n = 1
        for name in self.fx:
            if name in EFFECT_STATES:
                self.index[name] = n
                n += len(EFFECT_STATES[name])
        self.n_states = n
        self.omega = {name: 2.0 * math.pi * p[key] for name, p in self.fx.items()
                      for key in ("bandwidth_Hz", "natural_frequency_Hz") if key in p}
        mount = self.fx.get("series_compliance")
        self.compliance = self.area / mount["stiffness_N_per_m"] if mount else 0.0  # [m/Pa]

    # --- algebraic pieces
    def bulk(self, p: float) -> float:
        """B(p) of eq. (3) with p_0 -> p_R [Pa]."""
        return self.b0 * (1.0 + self.alpha_v) / (self.alpha_v + self.b0 * self.p_r / (p * p))

    def two_state_bulk(self, p: float) -> float:
        """B(p) of eq. (2) of the two-state base [Pa] (:func:`polytropic_bulk_modulus`, scalar)."""
        c = self.fx["two_state_damper"]
        p_atm, kappa, alpha = c["atmospheric_pressure_Pa"], c["polytropic_exponent"], c["liquid_gas_ratio_atm"]
        if p < TWO_STATE_P_FLOOR:
            return self.two_state_bulk(TWO_STATE_P_FLOOR) * p / TWO_STATE_P_FLOOR
        r = p_atm / p
        return self.b0 * (1.0 + r ** (1.0 / kappa) / alpha) / (
            1.0 + (self.b0 / (kappa * p_atm)) * r ** ((kappa + 1.0) / kappa) / alpha)

    def refill_flows(self, p_acc: float, p1: float, p2: float) -> tuple[float, float]:
        """Flows [m^3/s] from the accumulator into CH1 and CH2: through the restriction and a check valve that only
        opens towards a chamber below p_acc, plus the two-way bleed G_b (p_acc - p_i)."""
        c = self.fx["two_state_damper"]
        g, r_t, g_b = (c["line_conductance_m3_per_s_Pa"], c["line_turbulent_kg_per_m7"],
                       c["bleed_conductance_m3_per_s_Pa"])
        return (line_flow(p_acc - p1, g, r_t) + g_b * (p_acc - p1), line_flow(p_acc - p2, g, r_t) + g_b * (p_acc - p2))

    def accumulator_rate(self, x, refill: float) -> float:
        """dp_acc/dt [Pa/s] of the accumulator's gas, p_acc V_a^κ = p_c V_a0^κ, delivering ``refill`` [m^3/s]:
        dp_acc/dt = -κ p_acc Q_out / V_a(p_acc), V_a(p) = V_a0 (p_c/p)^(1/κ)."""
        c = self.fx["two_state_damper"]
        p_acc = float(x[self.index["two_state_damper"] + 1])
        kappa = c["polytropic_exponent"]
        gas = c["accumulator_volume_m3"] * (c["charge_pressure_Pa"] / max(p_acc, TWO_STATE_P_FLOOR)) ** (1.0 / kappa)
        return -kappa * p_acc * refill / gas

    def chambers(self, x, dp: float, q: float, vol1: float, vol2: float) -> tuple[float, float, float, float, float]:
        """The chamber equations in the form dp_1/dt = a_1 (A v_P + e_1), dp_2/dt = a_2 (-A v_P + e_2) of the
        active base (eq. (7) with eq. (6), the ``accumulator``, or the two-state base), and the accumulator's
        outflow [m^3/s] (two-state base; 0 otherwise). ``q``: the path flow CH1 -> CH2 [m^3/s]."""
        fx, idx = self.fx, self.index
        if "two_state_damper" in fx:
            i = idx["two_state_damper"]
            p1, p2 = float(x[i]) + 0.5 * dp, float(x[i]) - 0.5 * dp
            r1, r2 = self.refill_flows(float(x[i + 1]), p1, p2)
            return (self.two_state_bulk(p1) / vol1, self.two_state_bulk(p2) / vol2, -q + r1, q + r2, r1 + r2)
        if "accumulator" in fx:
            p_a, g = fx["accumulator"]["charge_pressure_Pa"], fx["accumulator"]["conductance_m3_per_s_Pa"]
            p1, p2 = float(x[idx["accumulator"]]) + 0.5 * dp, float(x[idx["accumulator"]]) - 0.5 * dp
            return (self.bulk(max(p1, ACCUMULATOR_P_FLOOR)) / vol1, self.bulk(max(p2, ACCUMULATOR_P_FLOOR)) / vol2,
                    -q + g * max(p_a - p1, 0.0), q + g * max(p_a - p2, 0.0), 0.0)
        if dp >= 0.0:
            b1, b2 = self.bulk(self.p_r + dp), self.b_ref
        else:
            b1, b2 = self.b_ref, self.bulk(self.p_r - dp)
        return b1 / vol1, b2 / vol2, -q, q, 0.0

    def openings(self, dp: float) -> tuple[float, float]:
        """Steady openings (s_+, s_-) = clip((±Δp - p_c) / p_s, 0, 1) of the valves of the two flow directions; one
        valve element for both (``per_direction`` 0): s(|Δp|) twice."""
        p = self.fx["poppet_valve"]
        pc, ps = p["cracking_pressure_Pa"], p["span_Pa"]
        if p["per_direction"] == 0:
            s = min(max((abs(dp) - pc) / ps, 0.0), 1.0)
            return s, s
        return min(max((dp - pc) / ps, 0.0), 1.0), min(max((-dp - pc) / ps, 0.0), 1.0)

    def orifice_dp(self, q: float) -> float:
        """Eq. (4): Δp_O(Q) = C_L Q + C_Q Q|Q| [Pa], the (C_L12, C_Q12) pair for Q >= 0, else (C_L21, C_Q21)."""
        c_l, c_q = (self.flow[0], self.flow[1]) if q >= 0.0 else (self.flow[2], self.flow[3])
        return c_l * q + c_q * q * abs(q)

    def orifice(self, x, dp: float) -> float:
        """Orifice flow [m^3/s]: the state Q_L with ``fluid_inertance``, else Q_O(Δp) of eq. (8)."""
        if "fluid_inertance" in self.index:
            return float(x[self.index["fluid_inertance"]])
        return orifice_flow(dp, self.flow)

    def unnamed_output(self, w: float, target: float) -> float:
        """The unnamed filter's output before the gain: w (mode 0) or w - L(u) (mode 1, zero DC gain)."""
        return w - target if self.fx["unnamed_dynamics"]["mode"] == 1 else w

    def law(self, u: float) -> float:
        """The unnamed filter's static law L(u)."""
        p = self.fx["unnamed_dynamics"]
        law, theta = p["law"], p["threshold"]
        if law == 0:
            return u
        if law == 1:
            return abs(u)
        if law == 2:
            return math.copysign(max(abs(u) - theta, 0.0), u)
        return math.tanh(u / theta)

    def piston(self, x, y_a: float, v_a: float) -> tuple[float, float]:
        """Piston displacement y_P [m] and velocity v_P [m/s] (servo states or the measured channel)."""
        if "command_displacement" in self.index:  # integrated as the tracking error e = y_P - y_A
            i = self.index["command_displacement"]
            return y_a + float(x[i]), float(x[i + 1])
        return y_a, v_a

    def driver(self, dp: float, q_o: float, y_p: float, v_p: float) -> float:
        """The unnamed filter's driver u: Δp, Q_O(Δp) of eq. (8) (Q_L with ``fluid_inertance``), y_P or v_P."""
        return (dp, q_o, y_p, v_p)[self.fx["unnamed_dynamics"]["driver"]]

    # --- dynamics
    def rhs(self, t: float, x, y_a: float, v_a: float) -> np.ndarray:
        """dx/dt at time ``t`` [s] for the measured displacement ``y_a`` [m] and velocity ``v_a`` [m/s]."""
        fx, idx, om = self.fx, self.index, self.omega
        dx = np.empty(self.n_states)
        dp = float(x[0])
        y_p, v_p = self.piston(x, y_a, v_a)
        vol1, vol2 = self.v01 - self.area * y_p, self.v02 + self.area * y_p
        q_o = self.orifice(x, dp)
        q = q_o
        target = 0.0
        if "unnamed_dynamics" in fx:
            target = self.law(self.driver(dp, q_o, y_p, v_p))  # L(u) at time t: u never depends on w
        s_fwd = s_rev = 0.0
        if "poppet_valve" in fx:
            s_fwd, s_rev = self.openings(dp)
            i = idx["poppet_valve"]
            fwd = dp >= 0.0 or fx["poppet_valve"]["per_direction"] == 0
            lift, s = (float(x[i]), s_fwd) if fwd else (float(x[i + 2]), s_rev)
            eps = fx["poppet_valve"]["bleed_fraction"]
            q = q_o * (eps + min(max(lift, 0.0), 1.0)) / (eps + s)
        if "leakage" in fx:
            q += fx["leakage"]["conductance_m3_per_s_Pa"] * dp
        if "unnamed_dynamics" in fx and fx["unnamed_dynamics"]["placement"] == 1:
            q += fx["unnamed_dynamics"]["gain"] * self.unnamed_output(float(x[idx["unnamed_dynamics"]]), target)
        if "series_compliance" in fx or "two_state_damper" in fx:  # eq. (1), chamber by chamber
            v_act, c = v_p, self.compliance  # the actuator (measured or the servo's); c = A / k_s [m/Pa], or 0
            if c:  # the piston behind the mount: y_P = y_act - c Δp, v_P = v_act - c dΔp/dt
                y_p = y_p - c * dp
                vol1, vol2 = self.v01 - self.area * y_p, self.v02 + self.area * y_p
            a1, a2, e1, e2, refill = self.chambers(x, dp, q, vol1, vol2)
            # dΔp/dt = (a1 + a2) A v_P + a1 e1 - a2 e2 with v_P = v_act - c dΔp/dt, solved for dΔp/dt
            ddp = ((a1 + a2) * self.area * v_act + a1 * e1 - a2 * e2) / (1.0 + (a1 + a2) * self.area * c)
            v_p = v_act - c * ddp
            d1, d2 = a1 * (self.area * v_p + e1), a2 * (-self.area * v_p + e2)
            dx[0] = d1 - d2
            for name in BASES:
                if name in fx:
                    dx[idx[name]] = 0.5 * (d1 + d2)
            if "two_state_damper" in fx:
                dx[idx["two_state_damper"] + 1] = self.accumulator_rate(x, refill)
            v_p = v_act  # the servo below integrates the actuator
        elif "accumulator" in fx:
            q_piston = self.area * v_p
            p_a, g = fx["accumulator"]["charge_pressure_Pa"], fx["accumulator"]["conductance_m3_per_s_Pa"]
            p_mean = float(x[idx["accumulator"]])
            p1, p2 = p_mean + 0.5 * dp, p_mean - 0.5 * dp
            b1 = self.bulk(max(p1, ACCUMULATOR_P_FLOOR))
            b2 = self.bulk(max(p2, ACCUMULATOR_P_FLOOR))
            d1 = b1 / vol1 * (q_piston - q + g * max(p_a - p1, 0.0))  # refill through check valves
            d2 = b2 / vol2 * (-q_piston + q + g * max(p_a - p2, 0.0))
            dx[0] = d1 - d2
            dx[idx["accumulator"]] = 0.5 * (d1 + d2)
        else:
            q_piston = self.area * v_p
            if dp >= 0.0:
                b1, b2 = self.bulk(self.p_r + dp), self.b_ref
            else:
                b1, b2 = self.b_ref, self.bulk(self.p_r - dp)
            dx[0] = (b1 / vol1 + b2 / vol2) * (q_piston - q)
        if "command_displacement" in fx:
            i, w, z = idx["command_displacement"], om["command_displacement"], fx["command_displacement"]
            dx[i] = v_p - v_a  # de/dt for e = y_P - y_A
            dx[i + 1] = -w * w * float(x[i]) - 2.0 * z["damping_ratio"] * w * v_p
        if "poppet_valve" in fx:
            i, w, z = idx["poppet_valve"], om["poppet_valve"], fx["poppet_valve"]
            dx[i] = x[i + 1]
            dx[i + 1] = w * w * (s_fwd - x[i]) - 2.0 * z["damping_ratio"] * w * x[i + 1]
            dx[i + 2] = x[i + 3]
            dx[i + 3] = w * w * (s_rev - x[i + 2]) - 2.0 * z["damping_ratio"] * w * x[i + 3]
        if "unnamed_dynamics" in fx:
            i, w, z = idx["unnamed_dynamics"], om["unnamed_dynamics"], fx["unnamed_dynamics"]
            dx[i] = x[i + 1]
            dx[i + 1] = w * w * (target - x[i]) - 2.0 * z["damping_ratio"] * w * x[i + 1]
        if "fluid_inertance" in fx:
            i = idx["fluid_inertance"]
            dx[i] = (dp - self.orifice_dp(float(x[i]))) / fx["fluid_inertance"]["inertance_kg_per_m4"]
        return dx

    def initial(self, dp0: float, y_a0: float, v_a0: float, v_prev: float) -> np.ndarray:
        """State vector at t0 (see :func:`simulate_effects`)."""
        fx, idx = self.fx, self.index
        x = np.zeros(self.n_states)
        x[0] = dp0
        if "command_displacement" in fx:
            i, w = idx["command_displacement"], self.omega["command_displacement"]
            x[i] = -2.0 * fx["command_displacement"]["damping_ratio"] * v_prev / w  # e = y_P - y_A
            x[i + 1] = v_prev
        if "poppet_valve" in fx:
            x[idx["poppet_valve"]], x[idx["poppet_valve"] + 2] = self.openings(dp0)
        if "accumulator" in fx:
            x[idx["accumulator"]] = fx["accumulator"]["charge_pressure_Pa"] + 0.5 * abs(dp0)  # unloaded at p_a
        if "two_state_damper" in fx:  # the accumulator and the unloaded chamber at the charge, the loaded above it
            p_c = fx["two_state_damper"]["charge_pressure_Pa"]
            x[idx["two_state_damper"]], x[idx["two_state_damper"] + 1] = p_c + 0.5 * abs(dp0), p_c
        if "fluid_inertance" in fx:
            x[idx["fluid_inertance"]] = orifice_flow(dp0, self.flow)  # steady: Δp_O(Q_L) = Δp0
        if "unnamed_dynamics" in fx:
            y_p, v_p = self.piston(x, y_a0, v_prev)  # at rest at its input just before t0
            x[idx["unnamed_dynamics"]] = self.law(self.driver(dp0, self.orifice(x, dp0), y_p, v_p))
        return x

    def atol_vector(self, atol: float) -> np.ndarray:
        """Absolute tolerance per state: ``atol`` [Pa] for pressures, scaled to the state's unit otherwise."""
        fx, idx = self.fx, self.index
        unit = atol / _PRESSURE_SCALE  # tolerance per unit of characteristic magnitude
        tol = np.full(self.n_states, float(atol))
        if "command_displacement" in fx:
            i = idx["command_displacement"]
            tol[i], tol[i + 1] = unit * _DRIVER_SCALES[2], unit * _DRIVER_SCALES[3]
        if "poppet_valve" in fx:
            i = idx["poppet_valve"]
            tol[i], tol[i + 1] = unit, unit * self.omega["poppet_valve"]
            tol[i + 2], tol[i + 3] = unit, unit * self.omega["poppet_valve"]
        if "unnamed_dynamics" in fx:
            i, p = idx["unnamed_dynamics"], fx["unnamed_dynamics"]
            scale = 1.0 if p["law"] == 3 else _DRIVER_SCALES[p["driver"]]
            tol[i], tol[i + 1] = unit * scale, unit * scale * self.omega["unnamed_dynamics"]
        if "fluid_inertance" in fx:  # 1e-5 m^3/s per MPa: 1e-17 m^3/s at atol 1e-6 Pa, i.e. about the flow
            tol[idx["fluid_inertance"]] = unit * _DRIVER_SCALES[1]  # error 1/C_L (4e-11 m^3/(s Pa)) * atol
        return tol

    def force(self, t: np.ndarray, states: np.ndarray, y_p: np.ndarray, v_p: np.ndarray) -> np.ndarray:
        """Measured force [N] at times ``t`` from the states (shape (n_states, n)) and the piston motion."""
        fx = self.fx
        f = self.area * states[0]
        if "gas_spring" in fx:
            f = f + fx["gas_spring"]["stiffness_N_per_m"] * y_p
        if "load_cell_offset" in fx:
            f = f + fx["load_cell_offset"]["offset_N"]
        if "mains_interference" in fx:
            p = fx["mains_interference"]
            arg = 2.0 * math.pi * p["frequency_Hz"] * t
            f = f + p["cos_amplitude_N"] * np.cos(arg) + p["sin_amplitude_N"] * np.sin(arg)
        if "seal_friction" in fx:
            p = fx["seal_friction"]
            stribeck = p["stribeck_N"] * np.exp(-((v_p / p["stribeck_velocity_m_s"]) ** 2))
            f = f + np.tanh(v_p / FRICTION_V_SIGN) * stribeck + p["viscous_Ns_per_m"] * v_p
        if "unnamed_dynamics" in fx and fx["unnamed_dynamics"]["placement"] == 0:
            w = states[self.index["unnamed_dynamics"]]
            if fx["unnamed_dynamics"]["mode"] == 1:  # w - L(u), u from the states at the sample times
                u = [self.driver(float(s[0]), self.orifice(s, float(s[0])), float(yp), float(vp))
                     for s, yp, vp in zip(states.T, y_p, v_p, strict=True)]
                w = w - np.array([self.law(ui) for ui in u])
            f = f + fx["unnamed_dynamics"]["gain"] * w
        return f


def inertance_for_frequency(freq_hz: float, damper: dict, flow, alpha_v: float, p_r: float, dp: float) -> float:
    """Inertance L [kg/m^4] of ``fluid_inertance`` that puts the Helmholtz resonance at ``freq_hz`` around Δp = dp.

    Linearised about the operating point Δp = ``dp`` (piston at y = 0), the pressure equation and the
    inertance equation read

        dΔp/dt = K (A v - Q_L),   L dQ_L/dt = Δp - Δp_O(Q_L),   K = B_1/V_01 + B_2/V_02,

    with B_1, B_2 of eq. (6) at ``dp`` (B(p_R + Δp) on the high side, B(p_R) on the other). With
    R = dΔp_O/dQ at the operating point this is d²Q_L/dt² + (R/L) dQ_L/dt + (K/L) Q_L = (K/L) A v: an
    undamped natural frequency ω_0 = sqrt(K / L), so L = K / (2π f)^2, and a damping ratio
    ζ = R / (2 sqrt(K L)) (decay rate ζω_0 = R / (2L)).

    Parameters
    ----------
    freq_hz : float
        Wanted undamped Helmholtz frequency f [Hz] (> 0).
    damper : dict
        ``v01``, ``v02`` [m^3] and ``b0`` B_0 [Pa] (``area`` is not needed).
    flow : sequence of 4 floats
        (C_L12, C_Q12, C_L21, C_Q21) of eq. (8). ω_0 does not depend on it (only ζ does); taken for the
        simulators' uniform signature and checked to be 4 finite numbers.
    alpha_v, p_r : float
        α_V [-] and p_R [Pa] of eq. (3)/(6).
    dp : float
        Operating Δp [Pa].

    Returns
    -------
    float
        L = (B_1/V_01 + B_2/V_02) / (2π f)^2 [kg/m^4].
    """
    if not (freq_hz > 0.0 and math.isfinite(freq_hz)):
        raise ValueError(f"freq_hz must be finite and > 0, got {freq_hz!r}")
    if len(flow) != 4 or not all(math.isfinite(float(c)) for c in flow):
        raise ValueError(f"flow must be 4 finite coefficients, got {flow!r}")
    b0, dp = float(damper["b0"]), float(dp)
    b_hi = float(bulk_modulus(p_r + abs(dp), b0, alpha_v, p_r))
    b_lo = float(bulk_modulus(p_r, b0, alpha_v, p_r))
    b1, b2 = (b_hi, b_lo) if dp >= 0.0 else (b_lo, b_hi)
    stiffness = b1 / float(damper["v01"]) + b2 / float(damper["v02"])
    return stiffness / (2.0 * math.pi * freq_hz) ** 2


def _segment(inp, ta: float, tb: float) -> tuple[Callable[[float], float], Callable[[float], float]]:
    """y_A(t), v_A(t) valid on the closed segment [ta, tb] (no breakpoint inside).

    A triangle is linear on the segment (v never read at a kink); an input with an ``on_segment(ta, tb)`` method
    (the wrappers of ``independent_records`` and ``reference_cycles``: a stop, a start from rest, the piston behind
    a play) gives its own one-sided form, so a velocity step at a segment's end does not leak into it
    (:func:`independent.segment_functions`); any other input is smooth and is read directly.
    """
    if isinstance(inp, TriangleInput):  # linear on the segment: never read v at a kink
        ya, va = float(inp.displacement(ta)), float(inp.velocity(0.5 * (ta + tb)))
        return (lambda t: ya + va * (t - ta)), (lambda t: va)
    if hasattr(inp, "on_segment"):
        return segment_functions(inp, ta, tb)
    return (lambda t: float(inp.displacement(t))), (lambda t: float(inp.velocity(t)))


# ----------------------------------------------------------------------------- simulation
def simulate_effects(inp, t_samples, damper: dict, flow, alpha_v: float, p_r: float,
                     effects: Mapping[str, Mapping[str, float]] | None = None, *, dp0: float | None = None,
                     t0: float | None = None, v_prev: float | None = None, rtol: float = 1e-10,
                     atol: float = 1e-6, return_states: bool = False) -> np.ndarray | dict[str, np.ndarray]:
    """Measured force of eq. (7) with any combination of effects, at the sample times (scipy Radau).

    Parameters
    ----------
    inp : SineInput, MultisineInput or TriangleInput (tests/independent.py), or any input of that interface
        Measured displacement channel y_A (``displacement``, ``velocity``, ``breakpoints``; optionally
        ``on_segment``): a random motion (``independent_records.random_input``), a wrapped input, or the piston
        behind a play (``reference_cycles.play_input``).
    t_samples : array_like, shape (n,)
        Non-decreasing sample times [s] (absolute record time), all >= ``t0``.
    damper : dict
        ``area`` A_P [m^2], ``v01``, ``v02`` [m^3], ``b0`` B_0 [Pa].
    flow : sequence of 4 floats
        (C_L12, C_Q12, C_L21, C_Q21) of eq. (8).
    alpha_v, p_r : float
        α_V [-] and p_R [Pa] of eq. (3)/(6) (also used by the accumulator's B(p); unused by ``two_state_damper``,
        whose B(p) is eq. (2) with its own α_V0 and κ).
    effects : mapping, optional
        ``{effect: {param: value}}``, see :data:`EFFECT_PARAMS` and :func:`resolve_effects`.
    dp0 : float, optional
        Δp at ``t0`` [Pa]; default the quasi-static Δp of eq. (4) at Q = A_P ``v_prev``
        (:func:`independent.quasi_static_dp`; not the steady state of the flow-path effects).
    t0 : float, optional
        Start of the integration [s]; default ``t_samples[0]``.
    v_prev : float, optional
        Velocity of the measured displacement just before ``t0`` [m/s]; default
        ``inp.velocity(max(t0 - 1e-9, min(t0, 0)))``, i.e. ``inp.velocity(max(t0 - 1e-9, 0))`` for t0 >= 0
        (the left value at a velocity step t0 > 1e-9 s; the right value at t0 = 0) and ``inp.velocity(t0)``
        for t0 < 0. Sets ``dp0``'s default and the servo's initial state.
    rtol, atol : float
        Radau tolerances: relative [-], absolute for Δp and p̄ [Pa]; every other state gets ``atol`` scaled by
        its characteristic magnitude per 1 MPa (1 cm, 0.1 m/s, unit lift, 1e-5 m^3/s for Q_L and flow-driven
        w; rates times ω).
    return_states : bool
        Return a dict instead of the force.

    Returns
    -------
    ndarray, shape (n,), or dict
        The force F [N] at ``t_samples``; with ``return_states`` a dict with ``"t"``, ``"force"`` and one
        array per state named as :func:`state_names` (``"dp"`` [Pa], ``"y_p"`` [m], ``"v_p"`` [m/s],
        ``"valve_lift"`` [-], ``"valve_rate"`` [1/s], ``"p_mean"`` [Pa], ``"w"``, ``"w_dot"``, ``"q_l"``
        [m^3/s], ``"p_acc"`` [Pa]; with ``two_state_damper`` also ``"p_1"``, ``"p_2"`` [Pa]). Samples at or
        before ``t0`` get the initial state. Without the servo, the force terms use y_A(t) and the right-continuous
        v_A(t) (``inp.velocity``) at the sample times.

    Raises
    ------
    ValueError
        Bad effects, bad sample times, or a non-positive chamber volume at a sample time or breakpoint.
    RuntimeError
        If a Radau solve fails.
    """
    model = _Model(*(float(damper[k]) for k in ("area", "v01", "v02", "b0")), tuple(float(c) for c in flow),
                   float(alpha_v), float(p_r), resolve_effects(effects))
    t_samples = np.asarray(t_samples, dtype=float)
    if t_samples.ndim != 1 or t_samples.size == 0 or np.any(np.diff(t_samples) < 0):
        raise ValueError("t_samples must be a non-empty, non-decreasing 1-D array")
    t0 = float(t_samples[0]) if t0 is None else float(t0)
    if t_samples[0] < t0:
        raise ValueError(f"t_samples start at {t_samples[0]!r} s, before t0 = {t0!r} s")
    t1 = float(t_samples[-1])
    edges = np.concatenate(([t0], inp.breakpoints(t0, t1), [t1])) if t1 > t0 else np.array([t0])
    keep = np.concatenate(([True], np.diff(edges) > 1e-12 * np.maximum(1.0, np.abs(edges[1:]))))
    edges = edges[keep]  # breakpoints a rounding error apart (or at t1) are one
    edges[-1] = max(edges[-1], t1)
    y_check = inp.displacement(np.concatenate((edges, t_samples)))
    if np.any(model.v01 - model.area * y_check <= 0.0) or np.any(model.v02 + model.area * y_check <= 0.0):
        raise ValueError("a chamber volume V_0 -/+ A_P y is not positive during the input")

    if v_prev is None:
        v_prev = float(inp.velocity(max(t0 - 1e-9, min(t0, 0.0))))
    v_prev = float(v_prev)
    if dp0 is None:
        dp0 = float(quasi_static_dp(model.area * v_prev, model.flow))
    x = model.initial(float(dp0), float(inp.displacement(t0)), float(inp.velocity(t0)), v_prev)
    tol = model.atol_vector(atol)

    states = np.empty((model.n_states, t_samples.size))
    states[:, t_samples <= t0] = x[:, None]
    for ta, tb in zip(edges[:-1], edges[1:], strict=True):
        y_of, v_of = _segment(inp, ta, tb)

        def rhs(t: float, z: np.ndarray, y_of=y_of, v_of=v_of) -> np.ndarray:
            return model.rhs(t, z, y_of(t), v_of(t))

        sol = solve_ivp(rhs, (ta, tb), x, method="Radau", rtol=rtol, atol=tol, dense_output=True)
        if sol.status != 0:
            raise RuntimeError(f"Radau solve failed on [{ta!r}, {tb!r}] s (effects {list(model.fx)}): "
                               f"{sol.message}")
        sel = (t_samples > ta) & (t_samples <= tb)
        if np.any(sel):
            states[:, sel] = sol.sol(t_samples[sel])
        x = sol.y[:, -1]

    if "command_displacement" in model.index:
        i = model.index["command_displacement"]
        states[i] += inp.displacement(t_samples)  # e = y_P - y_A -> y_P
        y_p, v_p = states[i], states[i + 1]
        if np.any(model.v01 - model.area * y_p <= 0.0) or np.any(model.v02 + model.area * y_p <= 0.0):
            raise ValueError("a chamber volume V_0 -/+ A_P y_P is not positive at a sample time")
    else:
        y_p, v_p = inp.displacement(t_samples), inp.velocity(t_samples)
    force = model.force(t_samples, states, np.asarray(y_p, dtype=float), np.asarray(v_p, dtype=float))
    if not return_states:
        return force
    out = {"t": t_samples, "force": force}
    out.update(zip(state_names(model.fx), states, strict=True))
    if "two_state_damper" in model.fx:
        out["p_1"], out["p_2"] = out["p_mean"] + 0.5 * out["dp"], out["p_mean"] - 0.5 * out["dp"]
    return out
