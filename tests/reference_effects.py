"""Independent reference simulator of eq. (7) with optional physical effects (scipy Radau, no bayesdamper).

This helper module (not a test file) extends :func:`independent.simulate` with the nine "effects" of the
effect-composition spec, written from the equations alone so that bayesdamper's compiled effect kernel can be
judged against data bayesdamper did not make, plus one pseudo-effect bayesdamper's library does not hold,
``fluid_inertance`` (an effect "in a form the library does not hold"). It must never import ``bayesdamper``.

Model, SI units throughout. At time t, with the measured displacement y_A(t) and its velocity v_A(t):

* piston motion y_P, v_P = y_A, v_A, or the states of the ``command_displacement`` servo;
* chamber volumes V_1 = V_01 - A y_P, V_2 = V_02 + A y_P;
* orifice flow Q_O(Δp) of eq. (8) (:func:`independent.orifice_flow`), or with ``fluid_inertance`` the state
  Q_L of L dQ_L/dt = Δp - Δp_O(Q_L), Δp_O(Q) = C_L Q + C_Q Q|Q| of eq. (4) (:func:`independent.quasi_static_dp`),
  which then replaces Q_O everywhere below; path flow
  Q = Q_O (ε + clip(x, 0, 1)) / (ε + s(Δp)) [poppet_valve] + G_l Δp [leakage] + g y [unnamed_dynamics, placement 1];
* the unnamed filter: ẅ = ω^2 (L(u) - w) - 2ζω ẇ, output y = w (``mode`` 0) or y = w - L(u) (``mode`` 1, the
  transient: zero in steady state), added as g y to the force (placement 0) or to the path flow (placement 1);
* B(p) = B_0 (1 + α_V) / (α_V + B_0 p_R / p^2); eq. (6) picks B_1, B_2 from p_R and p_R + |Δp| and
  dΔp/dt = (B_1/V_1 + B_2/V_2) (A v_P - Q) (the ``accumulator`` replaces this by two absolute pressures);
* force F = A Δp + the effects' force terms.

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
    "EFFECT_PARAMS",
    "EFFECT_STATES",
    "POPPET_EPSILON",
    "inertance_for_frequency",
    "resolve_effects",
    "simulate_effects",
    "state_names",
]

#: Effect name -> {parameter name: default}; ``None`` marks a required parameter. The key order is the
#: canonical order of the effects' states in the state vector.
EFFECT_PARAMS: dict[str, dict[str, float | None]] = {
    "command_displacement": {"bandwidth_Hz": None, "damping_ratio": None},
    "poppet_valve": {"natural_frequency_Hz": None, "damping_ratio": None, "cracking_pressure_Pa": None,
                     "span_Pa": 1e6},
    "accumulator": {"charge_pressure_Pa": None, "conductance_m3_per_s_Pa": None},
    "gas_spring": {"stiffness_N_per_m": None},
    "load_cell_offset": {"offset_N": None},
    "mains_interference": {"cos_amplitude_N": None, "sin_amplitude_N": None, "frequency_Hz": 50.0},
    "leakage": {"conductance_m3_per_s_Pa": None},
    "seal_friction": {"stribeck_N": None, "stribeck_velocity_m_s": None, "viscous_Ns_per_m": None},
    "unnamed_dynamics": {"gain": None, "natural_frequency_Hz": None, "damping_ratio": None, "threshold": 0.0,
                         "driver": 0, "law": 0, "placement": 0, "mode": 0},
    "fluid_inertance": {"inertance_kg_per_m4": None},
}

#: Effect name -> names of its states (in state-vector order); effects not listed have no state.
EFFECT_STATES: dict[str, tuple[str, ...]] = {
    "command_displacement": ("y_p", "v_p"),
    "poppet_valve": ("valve_lift", "valve_rate"),
    "accumulator": ("p_mean",),
    "unnamed_dynamics": ("w", "w_dot"),
    "fluid_inertance": ("q_l",),
}

#: ε of the poppet flow scaling (ε + clip(x, 0, 1)) / (ε + s(Δp)).
POPPET_EPSILON = 0.1
#: Floor of the absolute chamber pressure used in the accumulator's bulk modulus [Pa].
ACCUMULATOR_P_FLOOR = 1e4
#: Velocity scale of the seal friction's sign function tanh(v_P / V_SIGN) [m/s].
FRICTION_V_SIGN = 1e-5

# Characteristic magnitude of each kind of quantity, matched to 1 MPa of pressure, to scale the absolute
# tolerance of each state from ``atol`` [Pa]: 1 MPa <-> 1 cm <-> 0.1 m/s <-> 1e-5 m^3/s <-> 1 (unit-free).
_PRESSURE_SCALE = 1e6
_DRIVER_SCALES = {0: 1e6, 1: 1e-5, 2: 1e-2, 3: 1e-1}  # Δp [Pa], Q_O [m^3/s], y_P [m], v_P [m/s]
_INTEGER_PARAMS = {"driver": (0, 1, 2, 3), "law": (0, 1, 2, 3), "placement": (0, 1), "mode": (0, 1)}


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
        finite; frequencies, ``span_Pa``, ``stribeck_velocity_m_s``, ``charge_pressure_Pa`` and
        ``inertance_kg_per_m4`` > 0; damping ratios, conductances and ``threshold`` >= 0; ``threshold`` > 0 for
        law 3 (tanh(u / θ)); ``driver``, ``law`` in {0, 1, 2, 3}, ``placement`` and ``mode`` in {0, 1}
        (integral values).
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
            elif param.endswith("_Hz") or param in ("span_Pa", "stribeck_velocity_m_s", "charge_pressure_Pa",
                                                     "inertance_kg_per_m4"):
                _check(value > 0.0, name, param, value, "> 0")
            elif param in ("damping_ratio", "conductance_m3_per_s_Pa", "threshold"):
                _check(value >= 0.0, name, param, value, ">= 0")
            params[param] = value
        if name == "unnamed_dynamics" and params["law"] == 3:
            _check(params["threshold"] > 0.0, name, "threshold", params["threshold"], "> 0 with law 3")
        out[name] = params
    return out


def state_names(effects: Mapping[str, Mapping[str, float]] | None) -> tuple[str, ...]:
    """Names of the states in state-vector order: ``"dp"`` then the effects' states (:data:`EFFECT_STATES`)."""
    names = ["dp"]
    for name in resolve_effects(effects):
        names.extend(EFFECT_STATES.get(name, ()))
    return tuple(names)


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

    # --- algebraic pieces
    def bulk(self, p: float) -> float:
        """B(p) of eq. (3) with p_0 -> p_R [Pa]."""
        return self.b0 * (1.0 + self.alpha_v) / (self.alpha_v + self.b0 * self.p_r / (p * p))

    def opening(self, dp: float) -> float:
        """Steady poppet opening s(Δp) = clip((|Δp| - p_c) / p_s, 0, 1)."""
        p = self.fx["poppet_valve"]
        return min(max((abs(dp) - p["cracking_pressure_Pa"]) / p["span_Pa"], 0.0), 1.0)

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
        s = 0.0
        if "poppet_valve" in fx:
            s = self.opening(dp)
            lift = float(x[idx["poppet_valve"]])
            q = q_o * (POPPET_EPSILON + min(max(lift, 0.0), 1.0)) / (POPPET_EPSILON + s)
        if "leakage" in fx:
            q += fx["leakage"]["conductance_m3_per_s_Pa"] * dp
        if "unnamed_dynamics" in fx and fx["unnamed_dynamics"]["placement"] == 1:
            q += fx["unnamed_dynamics"]["gain"] * self.unnamed_output(float(x[idx["unnamed_dynamics"]]), target)
        q_piston = self.area * v_p
        if "accumulator" in fx:
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
            dx[i + 1] = w * w * (s - x[i]) - 2.0 * z["damping_ratio"] * w * x[i + 1]
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
            x[idx["poppet_valve"]] = self.opening(dp0)
        if "accumulator" in fx:
            x[idx["accumulator"]] = fx["accumulator"]["charge_pressure_Pa"] + 0.5 * abs(dp0)  # unloaded at p_a
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
        α_V [-] and p_R [Pa] of eq. (3)/(6) (also used by the accumulator's B(p)).
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
        [m^3/s]). Samples at or before ``t0`` get the initial state. Without the servo, the force terms use
        y_A(t) and the right-continuous v_A(t) (``inp.velocity``) at the sample times.

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
    return out
