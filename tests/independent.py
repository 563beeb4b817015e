"""Independent reference data for tests: eq. (7) re-implemented with scipy, nothing from bayesdamper.

This helper module (not a test file) re-derives the model of the paper brief ``docs/paper.md`` from its
equations alone, so that bayesdamper can be judged against data bayesdamper did not make. It must never
import ``bayesdamper``.

Model, SI units throughout; state Δp = p_1 - p_2 [Pa]:

* eq. (3) with p_0 -> p_R:  B(p) = B_0 (1 + α_V) / (α_V + B_0 p_R / p^2);
* eq. (6): Δp >= 0: B_1 = B(p_R + Δp), B_2 = B(p_R);  Δp < 0: B_1 = B(p_R), B_2 = B(p_R + |Δp|);
* eq. (8): Q = sign(Δp) 2|Δp| / (C_L + sqrt(C_L^2 + 4 C_Q |Δp|)), the (C_L12, C_Q12) pair for Δp > 0 and
  (C_L21, C_Q21) for Δp < 0 (the cancellation-free root of eq. (4), exact for C_Q = 0);
* eq. (7): dΔp/dt = (B_1/(V_01 - A_P y) + B_2/(V_02 + A_P y)) (A_P dy/dt - Q(Δp));
* force F = A_P Δp + F_0 + F_c tanh(v / v_eps) (offset and Coulomb friction optional, default off).

Inputs are small objects with analytic ``displacement(t)`` [m], ``velocity(t)`` [m/s] and
``breakpoints(t0, t1)`` (times in (t0, t1) where dy/dt is not smooth); :func:`simulate` restarts the
Radau integration at every breakpoint. Sweeps, random inputs, stops and starts from rest are in
``independent_records``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.signal import lfilter

__all__ = [
    "PAPER_FLOW",
    "RIG_A",
    "SMALL",
    "SMALL_FLOW",
    "MultisineInput",
    "SineInput",
    "TriangleInput",
    "ar1_noise",
    "bulk_modulus",
    "force_noise",
    "make_record",
    "multisine_input",
    "orifice_flow",
    "quasi_static_dp",
    "segment_functions",
    "simulate",
    "simulate_two_state",
    "sine_input",
    "triangle_input",
    "white_noise",
    "write_dataset",
]

#: rig-A: A_P [m^2], V_01, V_02 [m^3], B_0 [Pa].
RIG_A = dict(area=4.2e-3, v01=1.5e-4, v02=1.5e-4, b0=1.5e9)
#: The paper's Fig. 3 coefficients (C_L12 [kg m^-4 s^-1], C_Q12 [kg m^-7], C_L21, C_Q21).
PAPER_FLOW = (2.4255e10, 4.3126e16, 0.8572e10, 5.0805e16)
#: A small "MR-like" damper: A_P = 9 cm^2, 30 cm^3 per chamber.
SMALL = dict(area=9e-4, v01=3e-5, v02=3e-5, b0=1.5e9)
#: Flow pair for :data:`SMALL`. With Q = A_P v at 50 / 75 mm/s (Q = 4.5e-5 / 6.75e-5 m^3/s) eq. (4) gives
#: Δp = 1.76e5 / 2.94e5 Pa, F = 158 / 264 N (CH1 -> CH2) and 147 / 255 N (CH2 -> CH1).
SMALL_FLOW = (3.0e9, 2.0e13, 2.5e9, 2.5e13)


# ----------------------------------------------------------------------------- model equations
def bulk_modulus(p, b0: float, alpha_v: float, p_r: float):
    """Eq. (3) with p_0 replaced by p_R: B(p) [Pa] at absolute pressure ``p`` [Pa]."""
    p = np.asarray(p, dtype=float)
    return b0 * (1.0 + alpha_v) / (alpha_v + b0 * p_r / (p * p))


def _coefficients(dp: float, flow) -> tuple[float, float]:
    return (flow[0], flow[1]) if dp >= 0.0 else (flow[2], flow[3])


def orifice_flow(dp: float, flow) -> float:
    """Eq. (8): orifice flow Q [m^3/s] at pressure difference ``dp`` [Pa] (positive CH1 -> CH2)."""
    c_l, c_q = _coefficients(dp, flow)
    mag = abs(dp)
    if mag == 0.0:
        return 0.0
    q = 2.0 * mag / (c_l + math.sqrt(c_l * c_l + 4.0 * c_q * mag))
    return math.copysign(q, dp)


def quasi_static_dp(q, flow):
    """Eq. (4) per direction: Δp [Pa] that drives flow ``q`` [m^3/s] (C_12 pair for q >= 0)."""
    q = np.asarray(q, dtype=float)
    c_l = np.where(q >= 0.0, flow[0], flow[2])
    c_q = np.where(q >= 0.0, flow[1], flow[3])
    return c_l * q + c_q * q * np.abs(q)


# ----------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class SineInput:
    """y(t) = offset + a(t) sin(2π f t + phase), a(t) ramped in from t = 0 (see :func:`sine_input`)."""

    amplitude: float
    frequency: float
    offset: float = 0.0
    phase: float = 0.0
    ramp_cycles: float = 0.0

    @property
    def ramp_time(self) -> float:
        """Duration of the cosine ramp-in [s] (0 without ramp)."""
        return self.ramp_cycles / self.frequency

    def _envelope(self, t):
        """Amplitude a(t) [m] and its rate da/dt [m/s]."""
        t = np.asarray(t, dtype=float)
        if self.ramp_cycles <= 0.0:
            return np.full(t.shape, self.amplitude), np.zeros(t.shape)
        tr = self.ramp_time
        s = np.clip(t / tr, 0.0, 1.0)
        inside = (t > 0.0) & (t < tr)
        a = self.amplitude * 0.5 * (1.0 - np.cos(np.pi * s))
        da = np.where(inside, self.amplitude * 0.5 * np.pi / tr * np.sin(np.pi * s), 0.0)
        return a, da

    def displacement(self, t):
        """Piston displacement y(t) [m]."""
        t = np.asarray(t, dtype=float)
        a, _ = self._envelope(t)
        return self.offset + a * np.sin(2.0 * np.pi * self.frequency * t + self.phase)

    def velocity(self, t):
        """Piston velocity dy/dt [m/s]."""
        t = np.asarray(t, dtype=float)
        a, da = self._envelope(t)
        w = 2.0 * np.pi * self.frequency
        arg = w * t + self.phase
        return da * np.sin(arg) + a * w * np.cos(arg)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Times in (t0, t1) where the input is not smooth: 0 and the ramp end (with a ramp)."""
        if self.ramp_cycles <= 0.0:
            return np.empty(0)
        b = np.array([0.0, self.ramp_time])
        return b[(b > t0) & (b < t1)]


@dataclass(frozen=True)
class MultisineInput:
    """y(t) = Σ_k a sin(2π f_k t + φ_k) (see :func:`multisine_input`)."""

    frequencies: np.ndarray
    phases: np.ndarray
    tone_amplitude: float

    def displacement(self, t):
        """Piston displacement y(t) [m]."""
        t = np.asarray(t, dtype=float)
        arg = 2.0 * np.pi * np.multiply.outer(t, self.frequencies) + self.phases
        return self.tone_amplitude * np.sin(arg).sum(axis=-1)

    def velocity(self, t):
        """Piston velocity dy/dt [m/s]."""
        t = np.asarray(t, dtype=float)
        w = 2.0 * np.pi * self.frequencies
        arg = np.multiply.outer(t, w) + self.phases
        return self.tone_amplitude * (w * np.cos(arg)).sum(axis=-1)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """None: the multisine is smooth."""
        return np.empty(0)


@dataclass(frozen=True)
class TriangleInput:
    """Rest, then a constant-speed triangle (see :func:`triangle_input`)."""

    speed: float
    amplitude: float
    rest: float
    t_first_step: float
    cycles: float | None = None
    _quarter: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (self.speed > 0 and self.amplitude > 0 and math.isfinite(self.t_first_step)):
            raise ValueError("triangle needs speed > 0, amplitude > 0 and a finite t_first_step")
        object.__setattr__(self, "_quarter", self.amplitude / self.speed)

    @property
    def t_end(self) -> float:
        """End of the motion [s] (``inf`` without ``cycles``)."""
        if self.cycles is None:
            return math.inf
        return self.t_first_step + 4.0 * self.cycles * self._quarter

    def _shape(self, tau):
        """Unit-free triangle y/A and dy/dt / speed at time ``tau`` >= 0 after the first step."""
        q = self._quarter
        s = (tau + q) % (4.0 * q)  # phase measured from the -A corner
        rising = s < 2.0 * q
        y = np.where(rising, -1.0 + s / q, 3.0 - s / q)
        return y, np.where(rising, 1.0, -1.0)

    def displacement(self, t):
        """Piston displacement y(t) [m]: ``rest`` before the first step and after the end."""
        t = np.asarray(t, dtype=float)
        tau = np.clip(t, self.t_first_step, self.t_end) - self.t_first_step
        y, _ = self._shape(tau)
        return self.rest + self.amplitude * y

    def velocity(self, t):
        """Piston velocity dy/dt [m/s], right-continuous at the breakpoints."""
        t = np.asarray(t, dtype=float)
        _, v = self._shape(np.maximum(t - self.t_first_step, 0.0))
        moving = (t >= self.t_first_step) & (t < self.t_end)
        return np.where(moving, self.speed * v, 0.0)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Velocity steps in (t0, t1) [s]: t_first_step, the reversals and (with ``cycles``) the end."""
        q = self._quarter
        last = min(t1, self.t_end)
        n = max(0, math.ceil((last - self.t_first_step - q) / (2.0 * q)) + 1)
        b = [self.t_first_step] + [self.t_first_step + q + 2.0 * q * k for k in range(n)]
        if math.isfinite(self.t_end):
            b.append(self.t_end)
        b = np.array(sorted(set(b)))
        return b[(b > t0) & (b < t1) & (b <= self.t_end)]

    def knots(self, t_end: float) -> tuple[np.ndarray, np.ndarray]:
        """Knot times [s] from 0 to ``t_end`` and the displacement there [m] (a piecewise-linear form)."""
        t = np.concatenate(([min(0.0, self.t_first_step)], self.breakpoints(-math.inf, t_end), [t_end]))
        t = np.unique(t)
        return t, self.displacement(t)


def sine_input(amplitude: float, frequency: float, *, offset: float = 0.0, phase: float = 0.0,
               ramp_cycles: float = 0.0) -> SineInput:
    """Sinusoidal piston displacement with analytic y(t) and v(t).

    Parameters
    ----------
    amplitude : float
        Displacement amplitude [m].
    frequency : float
        Frequency [Hz], > 0.
    offset : float
        Mean displacement [m].
    phase : float
        Phase at t = 0 [rad].
    ramp_cycles : float
        If > 0, the amplitude rises as A (1 - cos(π t / T_r)) / 2 over T_r = ramp_cycles / frequency
        seconds from t = 0 (zero amplitude before t = 0); y and v stay continuous.

    Returns
    -------
    SineInput
        ``displacement(t)`` [m], ``velocity(t)`` [m/s], ``breakpoints(t0, t1)`` [s].
    """
    if not frequency > 0:
        raise ValueError(f"frequency must be > 0, got {frequency!r}")
    return SineInput(float(amplitude), float(frequency), float(offset), float(phase), float(ramp_cycles))


def multisine_input(amplitude_rms: float, f_lo: float, f_hi: float, n_tones: int, seed) -> MultisineInput:
    """Random-phase multisine with analytic y(t) and v(t).

    Parameters
    ----------
    amplitude_rms : float
        RMS displacement [m] (equal tone amplitudes A_rms sqrt(2 / n_tones)).
    f_lo, f_hi : float
        Lowest and highest tone [Hz]; tones equally spaced (``np.linspace``).
    n_tones : int
        Number of tones, >= 1.
    seed : int or numpy.random.SeedSequence
        Seed of ``np.random.default_rng``; phases uniform on [0, 2π).

    Returns
    -------
    MultisineInput
    """
    if n_tones < 1 or not 0 < f_lo <= f_hi:
        raise ValueError("multisine needs n_tones >= 1 and 0 < f_lo <= f_hi")
    freqs = np.linspace(f_lo, f_hi, n_tones)
    phases = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, n_tones)
    return MultisineInput(freqs, phases, float(amplitude_rms) * math.sqrt(2.0 / n_tones))


def triangle_input(speed: float, amplitude: float, rest: float, t_first_step: float, *,
                   cycles: float | None = None) -> TriangleInput:
    """Rest, then a constant-speed triangle: piecewise-linear y(t), piecewise-constant v(t).

    Parameters
    ----------
    speed : float
        Piston speed |v| [m/s], > 0.
    amplitude : float
        Triangle amplitude A [m], > 0.
    rest : float
        Rest displacement [m]: y = rest until ``t_first_step``, then rest + (0 -> +A -> -A -> +A ...).
    t_first_step : float
        Time of the first velocity step [s]; need not lie on any sample grid.
    cycles : float, optional
        Periods T = 4A/speed of motion, after which the piston rests where it is; default: forever.

    Returns
    -------
    TriangleInput
        ``displacement(t)``, ``velocity(t)`` (right-continuous), ``breakpoints(t0, t1)`` (the velocity
        steps in (t0, t1)) and ``knots(t_end)``.
    """
    return TriangleInput(float(speed), float(amplitude), float(rest), float(t_first_step),
                         None if cycles is None else float(cycles))


# ----------------------------------------------------------------------------- simulation
def segment_functions(inp, ta: float, tb: float):
    """Scalar y(t) [m] and v(t) [m/s] valid on the closed segment [ta, tb] between two breakpoints.

    A velocity step at a segment's end must not leak into the segment (Radau evaluates its last stage at the
    end point; its step control keeps such a leak near 1e-8 N, and this keeps it out): a :class:`TriangleInput`
    is linear on the segment, an input with an ``on_segment(ta, tb)`` method (the wrappers of
    ``independent_records``) gives its own one-sided form, and any other input is smooth and is read directly.
    """
    if isinstance(inp, TriangleInput):  # linear on the segment: do not read v at the kinks
        ya, va = float(inp.displacement(ta)), float(inp.velocity(0.5 * (ta + tb)))
        return (lambda t: ya + va * (t - ta)), (lambda t: va)
    if hasattr(inp, "on_segment"):
        return inp.on_segment(ta, tb)
    return (lambda t: float(inp.displacement(t))), (lambda t: float(inp.velocity(t)))


def simulate(inp, t_samples, damper: dict, flow, alpha_v: float, p_r: float, *, dp0: float | None = None,
             t0: float | None = None, rtol: float = 1e-11, atol: float = 1e-6, f0: float = 0.0,
             coulomb: float = 0.0, v_eps: float = 1e-3, return_dp: bool = False) -> np.ndarray:
    """Damper force of eq. (7) at the sample times, with scipy's Radau.

    Parameters
    ----------
    inp : SineInput, MultisineInput or TriangleInput
        Piston motion (any object with ``displacement``, ``velocity``, ``breakpoints``).
    t_samples : array_like, shape (n,)
        Non-decreasing sample times [s], all >= ``t0``.
    damper : dict
        ``area`` A_P [m^2], ``v01``, ``v02`` V_0,1, V_0,2 [m^3], ``b0`` B_0 [Pa].
    flow : sequence of 4 floats
        (C_L12, C_Q12, C_L21, C_Q21) of eq. (8) ([kg m^-4 s^-1], [kg m^-7]).
    alpha_v, p_r : float
        Liquid-gas ratio α_V [-] and reference pressure p_R [Pa] of eq. (6).
    dp0 : float, optional
        Δp at ``t0`` [Pa]; default the quasi-static Δp of eq. (4) at Q = A_P v(t0) (0 at rest).
    t0 : float, optional
        Start of the integration [s]; default ``t_samples[0]``.
    rtol, atol : float
        Radau tolerances ([-], [Pa]).
    f0 : float
        Constant force offset [N].
    coulomb, v_eps : float
        Coulomb friction F_c tanh(v / v_eps): level [N] and smoothing speed [m/s].
    return_dp : bool
        Return Δp [Pa] instead of the force.

    Returns
    -------
    ndarray, shape (n,)
        Force F = A_P Δp + f0 + coulomb tanh(v / v_eps) [N] (or Δp [Pa]) at ``t_samples``.

    Raises
    ------
    ValueError
        Bad sample times or a chamber volume that is not positive at a sample time or breakpoint.
    RuntimeError
        If a Radau solve fails.
    """
    t_samples = np.asarray(t_samples, dtype=float)
    if t_samples.ndim != 1 or t_samples.size == 0 or np.any(np.diff(t_samples) < 0):
        raise ValueError("t_samples must be a non-empty, non-decreasing 1-D array")
    t0 = float(t_samples[0]) if t0 is None else float(t0)
    if t_samples[0] < t0:
        raise ValueError(f"t_samples start at {t_samples[0]!r} s, before t0 = {t0!r} s")
    area, v01, v02, b0 = (float(damper[k]) for k in ("area", "v01", "v02", "b0"))
    flow = tuple(float(c) for c in flow)
    t1 = float(t_samples[-1])
    edges = np.concatenate(([t0], inp.breakpoints(t0, t1), [t1])) if t1 > t0 else np.array([t0])
    keep = np.concatenate(([True], np.diff(edges) > 1e-12 * np.maximum(1.0, np.abs(edges[1:]))))
    edges = edges[keep]  # breakpoints a rounding error apart (or at t1) are one
    edges[-1] = max(edges[-1], t1)
    y_check = inp.displacement(np.concatenate((edges, t_samples)))
    if np.any(v01 - area * y_check <= 0.0) or np.any(v02 + area * y_check <= 0.0):
        raise ValueError("a chamber volume V_0 -/+ A_P y is not positive during the input")
    b_ref = float(bulk_modulus(p_r, b0, alpha_v, p_r))
    if dp0 is None:
        dp0 = float(quasi_static_dp(area * float(inp.velocity(t0)), flow))

    def make_rhs(y_of, v_of):
        def parts(t, dp):
            y, v = y_of(t), v_of(t)
            vol1, vol2 = v01 - area * y, v02 + area * y
            mag = abs(dp)
            p_l = p_r + mag
            g = b0 * p_r / (p_l * p_l)
            b_l = b0 * (1.0 + alpha_v) / (alpha_v + g)
            db_l = b_l * 2.0 * g / (p_l * (alpha_v + g))  # dB/dp of eq. (3)
            if dp >= 0.0:
                s, ds = b_l / vol1 + b_ref / vol2, db_l / vol1
            else:
                s, ds = b_ref / vol1 + b_l / vol2, -db_l / vol2
            c_l, c_q = _coefficients(dp, flow)
            root = math.sqrt(c_l * c_l + 4.0 * c_q * max(mag, 1e-9))
            r = area * v - orifice_flow(dp, flow)
            return s, ds, r, 1.0 / root

        def rhs(t, x):
            s, _, r, _ = parts(t, x[0])
            return [s * r]

        def jac(t, x):
            s, ds, r, dq = parts(t, x[0])
            return [[ds * r - s * dq]]

        return rhs, jac

    out = np.empty(t_samples.size)
    out[t_samples <= t0] = dp0
    x = float(dp0)
    for ta, tb in zip(edges[:-1], edges[1:], strict=True):
        rhs, jac = make_rhs(*segment_functions(inp, ta, tb))
        sol = solve_ivp(rhs, (ta, tb), [x], method="Radau", jac=jac, rtol=rtol, atol=atol, dense_output=True)
        if sol.status != 0:
            raise RuntimeError(f"Radau solve of eq. (7) failed on [{ta!r}, {tb!r}] s "
                               f"(alpha_V={alpha_v!r}, p_R={p_r!r} Pa): {sol.message}")
        sel = (t_samples > ta) & (t_samples <= tb)
        if np.any(sel):
            out[sel] = sol.sol(t_samples[sel])[0]
        x = float(sol.y[0, -1])
    if return_dp:
        return out
    force = area * out + f0
    if coulomb:
        force = force + coulomb * np.tanh(inp.velocity(t_samples) / v_eps)
    return force


def simulate_two_state(inp, t_samples, damper: dict, flow, alpha_v: float, p_charge: float, *,
                       rtol: float = 1e-10, atol: float = 1e-3) -> np.ndarray:
    """Damper force of the two-state model eq. (1) at the sample times (scipy Radau), from rest.

    States: absolute chamber pressures p_1, p_2 [Pa], both ``p_charge`` at rest (no accumulator);
    dp_1/dt = B(p_1)/V_1 (A_P v - Q), dp_2/dt = B(p_2)/V_2 (-A_P v + Q) with Q = eq. (8) of p_1 - p_2 and
    B of eq. (3) with p_0 -> ``p_charge`` (α_V is the liquid-gas ratio at the charge pressure). Unlike
    eq. (7), the unloaded chamber's pressure falls below the charge as the loaded one rises, so eq. (6)'s
    p_R is only an approximation of this model: data from it are misspecified for eq. (7).

    Returns
    -------
    ndarray, shape (n,)
        Force A_P (p_1 - p_2) [N].
    """
    t_samples = np.asarray(t_samples, dtype=float)
    t0, t1 = float(t_samples[0]), float(t_samples[-1])
    area, v01, v02, b0 = (float(damper[k]) for k in ("area", "v01", "v02", "b0"))
    flow = tuple(float(c) for c in flow)
    edges = np.concatenate(([t0], inp.breakpoints(t0, t1), [t1]))
    edges = edges[np.concatenate(([True], np.diff(edges) > 1e-12 * np.maximum(1.0, np.abs(edges[1:]))))]
    edges[-1] = max(edges[-1], t1)

    def b_of(p):
        return b0 * (1.0 + alpha_v) / (alpha_v + b0 * p_charge / (p * p))

    out = np.empty((t_samples.size, 2))
    out[t_samples <= t0] = p_charge
    x = np.array([p_charge, p_charge])
    for ta, tb in zip(edges[:-1], edges[1:], strict=True):
        ya, va = float(inp.displacement(ta)), float(inp.velocity(0.5 * (ta + tb)))

        def rhs(t, p, ya=ya, va=va, ta=ta):
            y = ya + va * (t - ta)
            q = orifice_flow(p[0] - p[1], flow)
            r = area * va - q
            return [b_of(p[0]) / (v01 - area * y) * r, -b_of(p[1]) / (v02 + area * y) * r]

        sol = solve_ivp(rhs, (ta, tb), x, method="Radau", rtol=rtol, atol=atol, dense_output=True)
        if sol.status != 0:
            raise RuntimeError(f"Radau solve of eq. (1) failed on [{ta!r}, {tb!r}] s: {sol.message}")
        sel = (t_samples > ta) & (t_samples <= tb)
        if np.any(sel):
            out[sel] = sol.sol(t_samples[sel]).T
        x = sol.y[:, -1]
    return area * (out[:, 0] - out[:, 1])


# ----------------------------------------------------------------------------- noise and records
def white_noise(n: int, sd: float, seed) -> np.ndarray:
    """Gaussian white noise: ``n`` samples of standard deviation ``sd`` (``np.random.default_rng(seed)``)."""
    return sd * np.random.default_rng(seed).standard_normal(n)


def ar1_noise(n: int, sd: float, phi: float, seed) -> np.ndarray:
    """Stationary Gaussian AR(1) noise e_k = φ e_{k-1} + w_k with MARGINAL standard deviation ``sd``.

    e_0 ~ N(0, sd^2) and w_k ~ N(0, sd^2 (1 - φ^2)), so every sample has variance sd^2; |φ| < 1.
    """
    if not abs(phi) < 1.0:
        raise ValueError(f"AR(1) needs |phi| < 1, got {phi!r}")
    w = np.random.default_rng(seed).standard_normal(n)
    innovations = sd * math.sqrt(1.0 - phi * phi) * w
    if n:
        innovations[0] = sd * w[0]
    return lfilter([1.0], [1.0, -phi], innovations)


def force_noise(n: int, sd: float, phi: float, seed) -> np.ndarray:
    """White noise (``phi`` = 0) or stationary AR(1) noise of marginal sd ``sd`` [N]."""
    return ar1_noise(n, sd, phi, seed) if phi else white_noise(n, sd, seed)


def make_record(inp, duration: float, rate: float, damper: dict, flow, alpha_v: float, p_r: float, *,
                noise: str = "white", sd: float, phi: float = 0.97, seed, displacement_noise: float = 0.0,
                t_start: float = 0.0, **simulate_kw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A measured record: sample times, noisy displacement and noisy force.

    Parameters
    ----------
    inp, damper, flow, alpha_v, p_r
        As :func:`simulate`.
    duration : float
        Record length [s]; n = round(duration * rate) samples.
    rate : float
        Sampling rate [Hz]; t = t_start + k / rate.
    noise : {"white", "ar1"}
        Force noise model.
    sd : float
        Marginal standard deviation of the force noise [N].
    phi : float
        AR(1) coefficient (``noise="ar1"``).
    seed : int or numpy.random.SeedSequence
        Root seed; the force and displacement noise use independent child streams.
    displacement_noise : float
        Standard deviation of white displacement noise [m].
    t_start : float
        First sample time [s], may be off any grid; the integration starts there.
    **simulate_kw
        Passed to :func:`simulate` (``dp0``, ``rtol``, ``atol``, ``f0``, ``coulomb``, ...).

    Returns
    -------
    t, y, force : ndarray, shape (n,)
        Times [s], measured displacement [m], measured force [N].
    """
    n = int(round(duration * rate))
    t = t_start + np.arange(n) / rate
    force = simulate(inp, t, damper, flow, alpha_v, p_r, **simulate_kw)
    s_force, s_disp = np.random.SeedSequence(seed).spawn(2)
    if noise == "white":
        force = force + white_noise(n, sd, s_force)
    elif noise == "ar1":
        force = force + ar1_noise(n, sd, phi, s_force)
    else:
        raise ValueError(f"noise must be 'white' or 'ar1', got {noise!r}")
    y = inp.displacement(t) + white_noise(n, displacement_noise, s_disp)
    return t, y, force


def write_dataset(folder, records: dict, damper_dict: dict, name: str) -> Path:
    """Write the interchange format: ``damper.toml`` and one ``<record>.csv`` per record.

    Parameters
    ----------
    folder : str or Path
        Output folder (created if needed).
    records : dict
        ``{record name: (t [s], y [m], F [N])}``.
    damper_dict : dict
        ``area``, ``v01``, ``v02``, ``b0`` as in :data:`RIG_A`.
    name : str
        Damper name for ``damper.toml``.

    Returns
    -------
    Path
        The folder. CSV floats are written with ``repr`` (shortest round-trip form).
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    d = {k: float(damper_dict[k]) for k in ("area", "v01", "v02", "b0")}
    (root / "damper.toml").write_text(
        "[damper]\n"
        f"name = {json.dumps(name)}\n"
        f"piston_area_m2 = {d['area']!r}\n"
        f"chamber_volume_1_m3 = {d['v01']!r}\n"
        f"chamber_volume_2_m3 = {d['v02']!r}\n"
        f"liquid_bulk_modulus_Pa = {d['b0']!r}\n"
    )
    for rec, (t, y, f) in records.items():
        rows = zip(np.asarray(t, float).tolist(), np.asarray(y, float).tolist(), np.asarray(f, float).tolist(),
                   strict=True)
        lines = ["time_s,displacement_m,force_N"] + [f"{a!r},{b!r},{c!r}" for a, b, c in rows]
        (root / f"{rec}.csv").write_text("\n".join(lines) + "\n")
    return root
