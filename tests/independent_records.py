"""Independent records of every kind labs run: sweeps, random inputs, stops, starts, sensors, damper variants.

This helper module (not a test file) extends :mod:`independent` (eq. (7) re-derived with scipy from the paper
brief ``docs/paper.md``) to the records measured in laboratories, so that bayesdamper can be judged on data it
did not make. Like :mod:`independent` it must never import ``bayesdamper``. SI units throughout.

Inputs (objects with analytic ``displacement(t)`` [m], ``velocity(t)`` [m/s], ``breakpoints(t0, t1)`` [s] and,
for the wrappers, ``on_segment(ta, tb)``, read by :func:`independent.simulate`):

* :func:`sweep_input`: linear or exponential chirp, constant amplitude, optional cosine ramp-in;
* :func:`random_input`: band-limited Gaussian-like random motion, a sum of tones on a fine grid with Rayleigh
  amplitudes and uniform phases, scaled to an rms displacement or velocity;
* :func:`sine_at_speed`: a sine whose t = 0 is mid-stroke at peak speed (with ``pre_roll_s`` of
  :func:`simulate_record` the damper is then in its periodic steady state at the first sample);
* :func:`start_from_rest`: any input held at rest, then its amplitude ramped in;
* :func:`stop_at`: any input that moves until ``t_stop``, then decelerates to rest (cosine velocity taper, or
  abruptly: a velocity step) and holds still.

Measurement (:class:`Sensors`, :func:`measure`): displacement noise and ADC step, force noise (white or AR(1)),
force ADC step, an unzeroed load cell (offset), mains hum, an optional velocity channel; each sensor draws from
its own child stream of the record's seed.

Damper variants on top of eq. (7) (:func:`true_force`), each from its own physics:

* dry friction / Bingham yield: F_y tanh(v / v_eps) + c v (:func:`bingham_force`; c = 0 is Coulomb friction);
* gas-charged damper: the gas behind a floating piston pushes on the rod, F_gas = p_c A_rod (V_g / (V_g -
  A_rod y))^n, linearised to p_c A_rod + k y with k = n p_c A_rod^2 / V_g (:class:`GasCharge`);
* the two-state model eq. (1) of :func:`independent.simulate_two_state` (triangles only).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from independent import (
    TriangleInput,
    force_noise,
    segment_functions,
    simulate,
    simulate_two_state,
    sine_input,
    white_noise,
)

__all__ = [
    "GasCharge",
    "Measured",
    "MultitoneInput",
    "RampedInput",
    "Sensors",
    "SimulatedRecord",
    "StoppedInput",
    "SweepInput",
    "bingham_force",
    "mains_hum",
    "measure",
    "quantise",
    "random_input",
    "simulate_record",
    "sine_at_speed",
    "start_from_rest",
    "stop_at",
    "sweep_input",
    "true_force",
    "write_records",
]

SWEEP_LAWS = ("linear", "exponential")


def _cosine_ramp(t, t_on: float, length: float):
    """w(t) = (1 - cos(π (t - t_on) / length)) / 2 on [t_on, t_on + length], 0 before, 1 after; and dw/dt [1/s]."""
    s = np.clip((np.asarray(t, dtype=float) - t_on) / length, 0.0, 1.0)
    inside = (s > 0.0) & (s < 1.0)
    return 0.5 * (1.0 - np.cos(np.pi * s)), np.where(inside, 0.5 * np.pi / length * np.sin(np.pi * s), 0.0)


# ----------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class SweepInput:
    """y(t) = offset + a(t) sin(φ(t) + phase): a chirp from f0 at t = 0 to f1 at t = duration (see
    :func:`sweep_input`). Before 0 the frequency is f0, after ``duration`` it is f1."""

    amplitude: float
    f0: float
    f1: float
    duration: float
    law: str = "linear"
    offset: float = 0.0
    phase: float = 0.0
    ramp_s: float = 0.0

    def frequency(self, t):
        """Instantaneous frequency dφ/dt / 2π [Hz]."""
        tc = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        if self.law == "linear" or self.f1 == self.f0:
            return self.f0 + (self.f1 - self.f0) * tc / self.duration
        return self.f0 * (self.f1 / self.f0) ** (tc / self.duration)

    def _phi(self, t):
        t = np.asarray(t, dtype=float)
        tc = np.clip(t, 0.0, self.duration)
        if self.law == "linear" or self.f1 == self.f0:
            inner = self.f0 * tc + 0.5 * (self.f1 - self.f0) * tc * tc / self.duration
        else:
            log_r = math.log(self.f1 / self.f0)
            inner = self.f0 * self.duration / log_r * np.expm1(log_r * tc / self.duration)
        outside = self.f0 * np.minimum(t, 0.0) + self.f1 * np.maximum(t - self.duration, 0.0)
        return 2.0 * np.pi * (inner + outside)

    def _envelope(self, t):
        t = np.asarray(t, dtype=float)
        if self.ramp_s <= 0.0:
            return np.full(t.shape, self.amplitude), np.zeros(t.shape)
        w, dw = _cosine_ramp(t, 0.0, self.ramp_s)
        return self.amplitude * w, self.amplitude * dw

    def displacement(self, t):
        """Piston displacement y(t) [m]."""
        a, _ = self._envelope(t)
        return self.offset + a * np.sin(self._phi(t) + self.phase)

    def velocity(self, t):
        """Piston velocity dy/dt [m/s]."""
        a, da = self._envelope(t)
        arg = self._phi(t) + self.phase
        return da * np.sin(arg) + a * 2.0 * np.pi * self.frequency(t) * np.cos(arg)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Times in (t0, t1) where the acceleration jumps: 0, ``duration`` and the end of the ramp."""
        b = np.array([0.0, self.duration] + ([self.ramp_s] if self.ramp_s > 0.0 else []))
        b = np.unique(b)
        return b[(b > t0) & (b < t1)]


@dataclass(frozen=True)
class MultitoneInput:
    """y(t) = offset + Σ_k a_k sin(2π f_k t + φ_k) (see :func:`random_input`)."""

    frequencies: np.ndarray
    amplitudes: np.ndarray
    phases: np.ndarray
    offset: float = 0.0

    @property
    def period(self) -> float:
        """Common period of the tones [s] (1 / the grid step; ``inf`` off a grid)."""
        df = float(np.min(np.diff(self.frequencies))) if self.frequencies.size > 1 else float(self.frequencies[0])
        return 1.0 / df

    def displacement(self, t):
        """Piston displacement y(t) [m]."""
        arg = 2.0 * np.pi * np.multiply.outer(np.asarray(t, dtype=float), self.frequencies) + self.phases
        return self.offset + (self.amplitudes * np.sin(arg)).sum(axis=-1)

    def velocity(self, t):
        """Piston velocity dy/dt [m/s]."""
        w = 2.0 * np.pi * self.frequencies
        arg = np.multiply.outer(np.asarray(t, dtype=float), w) + self.phases
        return (self.amplitudes * w * np.cos(arg)).sum(axis=-1)

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """None: the input is smooth."""
        return np.empty(0)


@dataclass(frozen=True)
class StoppedInput:
    """``inner`` until ``t_stop``, then to rest and held (see :func:`stop_at`)."""

    inner: object
    t_stop: float
    taper_s: float = 0.0
    _stop: tuple[float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.t_stop) and self.taper_s >= 0.0):
            raise ValueError("stop needs a finite t_stop and taper_s >= 0")
        before = self.inner.breakpoints(-math.inf, self.t_stop)
        ta = float(before[-1]) if before.size else self.t_stop - 1.0
        _, v_of = segment_functions(self.inner, ta, self.t_stop)  # the left limit at t_stop
        object.__setattr__(self, "_stop", (float(self.inner.displacement(self.t_stop)), float(v_of(self.t_stop))))

    @property
    def stop_state(self) -> tuple[float, float]:
        """Displacement [m] and velocity (left limit) [m/s] of the inner input at ``t_stop``."""
        return self._stop

    @property
    def rest_position(self) -> float:
        """Where the piston holds after the stop [m]: y_s + v_s taper_s / 2."""
        y_s, v_s = self._stop
        return y_s + 0.5 * v_s * self.taper_s

    def _after(self, t):
        """y, v for t >= t_stop."""
        y_s, v_s = self._stop
        if self.taper_s == 0.0:
            return np.full(np.shape(t), y_s), np.zeros(np.shape(t))
        tau = np.clip(np.asarray(t, dtype=float) - self.t_stop, 0.0, self.taper_s)
        x = np.pi * tau / self.taper_s
        y = y_s + v_s * (0.5 * tau + self.taper_s / (2.0 * np.pi) * np.sin(x))
        return y, v_s * 0.5 * (1.0 + np.cos(x)) * (tau < self.taper_s)

    def displacement(self, t):
        """Piston displacement y(t) [m], continuous."""
        t = np.asarray(t, dtype=float)
        return np.where(t < self.t_stop, self.inner.displacement(np.minimum(t, self.t_stop)), self._after(t)[0])

    def velocity(self, t):
        """Piston velocity dy/dt [m/s]; right-continuous at an abrupt stop (0 at ``t_stop``)."""
        t = np.asarray(t, dtype=float)
        return np.where(t < self.t_stop, self.inner.velocity(np.minimum(t, self.t_stop)), self._after(t)[1])

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """The inner input's breakpoints before ``t_stop``, ``t_stop`` and the end of the taper, in (t0, t1)."""
        b = self.inner.breakpoints(t0, min(t1, self.t_stop))
        b = np.unique(np.concatenate((b[b < self.t_stop], [self.t_stop, self.t_stop + self.taper_s])))
        return b[(b > t0) & (b < t1)]

    def on_segment(self, ta: float, tb: float):
        """Scalar y(t), v(t) on the closed segment [ta, tb] (one side of the stop only)."""
        mid = 0.5 * (ta + tb)
        if mid < self.t_stop:
            return segment_functions(self.inner, ta, tb)
        return (lambda t: float(self._after(t)[0])), (lambda t: float(self._after(t)[1]))


@dataclass(frozen=True)
class RampedInput:
    """At ``rest`` until ``t_on``, then rest + w(t) (inner(t) - rest), w a cosine ramp over ``ramp_s`` (see
    :func:`start_from_rest`)."""

    inner: object
    t_on: float
    ramp_s: float
    rest: float = 0.0

    def _parts(self, t, y_in, v_in):
        w, dw = _cosine_ramp(t, self.t_on, self.ramp_s)
        return self.rest + w * (y_in - self.rest), dw * (y_in - self.rest) + w * v_in

    def displacement(self, t):
        """Piston displacement y(t) [m]."""
        t = np.asarray(t, dtype=float)
        return self._parts(t, self.inner.displacement(t), self.inner.velocity(t))[0]

    def velocity(self, t):
        """Piston velocity dy/dt [m/s] (0 before ``t_on``)."""
        t = np.asarray(t, dtype=float)
        return self._parts(t, self.inner.displacement(t), self.inner.velocity(t))[1]

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """``t_on``, the ramp's end and the inner input's breakpoints after ``t_on``, in (t0, t1)."""
        b = self.inner.breakpoints(max(t0, self.t_on), t1)
        b = np.unique(np.concatenate((b, [self.t_on, self.t_on + self.ramp_s])))
        return b[(b > t0) & (b < t1)]

    def on_segment(self, ta: float, tb: float):
        """Scalar y(t), v(t) on the closed segment [ta, tb]."""
        if 0.5 * (ta + tb) < self.t_on:
            return (lambda t: self.rest), (lambda t: 0.0)
        y_of, v_of = segment_functions(self.inner, ta, tb)

        def parts(t):
            y, v = self._parts(t, y_of(t), v_of(t))
            return float(y), float(v)

        return (lambda t: parts(t)[0]), (lambda t: parts(t)[1])


def sweep_input(amplitude: float, f0: float, f1: float, duration: float, *, law: str = "linear",
                offset: float = 0.0, phase: float = 0.0, ramp_s: float = 0.0) -> SweepInput:
    """A chirp of constant displacement amplitude between two frequencies.

    Parameters
    ----------
    amplitude : float
        Displacement amplitude [m].
    f0, f1 : float
        Frequency at t = 0 and at t = ``duration`` [Hz], > 0.
    duration : float
        Sweep time [s], > 0.
    law : {"linear", "exponential"}
        f(t) = f0 + (f1 - f0) t / T, or f(t) = f0 (f1 / f0)^(t / T); the phase is 2π ∫ f dt from t = 0.
    offset : float
        Mean displacement [m].
    phase : float
        Phase at t = 0 [rad] (0: mid-stroke at speed; π/2: at the top, at rest).
    ramp_s : float
        If > 0, the amplitude rises as A (1 - cos(π t / ramp_s)) / 2 over ``ramp_s`` seconds from t = 0 and is 0
        before (the piston rests at ``offset``).

    Returns
    -------
    SweepInput
        With ``frequency(t)`` [Hz] besides the input methods.
    """
    if law not in SWEEP_LAWS:
        raise ValueError(f"law must be one of {SWEEP_LAWS}, got {law!r}")
    if not (f0 > 0 and f1 > 0 and duration > 0 and ramp_s >= 0):
        raise ValueError("sweep needs f0, f1, duration > 0 and ramp_s >= 0")
    return SweepInput(float(amplitude), float(f0), float(f1), float(duration), law, float(offset), float(phase),
                      float(ramp_s))


def random_input(f_lo: float, f_hi: float, *, seed, rms_displacement: float | None = None,
                 rms_velocity: float | None = None, resolution: float = 0.01, offset: float = 0.0) -> MultitoneInput:
    """Band-limited random motion: tones on the grid k·``resolution`` inside [f_lo, f_hi], Rayleigh amplitudes.

    With Rayleigh amplitudes and uniform phases each tone is a complex Gaussian, so y(t) is a sample of a
    stationary Gaussian process with a flat displacement spectrum in the band (periodic with period
    1 / ``resolution``). The amplitudes are then scaled so that the rms over one period is the target exactly
    (tones on a common grid are orthogonal over the period): Σ a_k^2 / 2 = rms_y^2, or Σ (2π f_k a_k)^2 / 2 =
    rms_v^2.

    Parameters
    ----------
    f_lo, f_hi : float
        Band [Hz], 0 < f_lo <= f_hi; at least one grid frequency must lie inside.
    seed : int or numpy.random.SeedSequence
        Seed of the amplitudes and phases.
    rms_displacement, rms_velocity : float
        Target rms displacement [m] or rms velocity [m/s] over a period; exactly one.
    resolution : float
        Grid step [Hz]; the period is 1 / resolution [s].
    offset : float
        Mean displacement [m].

    Returns
    -------
    MultitoneInput
    """
    if (rms_displacement is None) == (rms_velocity is None):
        raise ValueError("give exactly one of rms_displacement and rms_velocity")
    k = np.arange(math.ceil(f_lo / resolution - 1e-9), math.floor(f_hi / resolution + 1e-9) + 1)
    k = k[k > 0]
    if not (0 < f_lo <= f_hi) or k.size == 0:
        raise ValueError(f"no grid frequency of step {resolution} Hz inside [{f_lo}, {f_hi}] Hz")
    freqs = k * resolution
    rng = np.random.default_rng(seed)
    amps = rng.rayleigh(1.0, k.size)
    phases = rng.uniform(0.0, 2.0 * np.pi, k.size)
    if rms_displacement is not None:
        amps *= rms_displacement / math.sqrt(0.5 * float(np.sum(amps**2)))
    else:
        amps *= rms_velocity / math.sqrt(0.5 * float(np.sum((2.0 * np.pi * freqs * amps) ** 2)))
    return MultitoneInput(freqs, amps, phases, float(offset))


def sine_at_speed(amplitude: float, frequency: float, *, offset: float = 0.0, direction: int = 1):
    """A sine whose t = 0 is mid-stroke (y = ``offset``) at peak speed 2π f A, moving in ``direction`` (±1).

    The :class:`independent.SineInput` with phase 0 (or π). Its record starts at speed; give
    :func:`simulate_record` a ``pre_roll_s`` of a few periods so that the damper is in its periodic steady
    state at the first sample (as when a lab starts recording a running test).
    """
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1, got {direction!r}")
    return sine_input(amplitude, frequency, offset=offset, phase=0.0 if direction > 0 else math.pi)


def start_from_rest(inp, hold_s: float, ramp_s: float, *, rest: float = 0.0) -> RampedInput:
    """Hold ``inp`` at ``rest`` [m] for ``hold_s`` [s], then ramp its amplitude about ``rest`` in over ``ramp_s``
    [s] (cosine ramp: y and v continuous). ``rest`` is usually the input's mean displacement."""
    if not (hold_s >= 0 and ramp_s > 0):
        raise ValueError("start from rest needs hold_s >= 0 and ramp_s > 0")
    return RampedInput(inp, float(hold_s), float(ramp_s), float(rest))


def stop_at(inp, t_stop: float, taper_s: float = 0.0) -> StoppedInput:
    """``inp`` until ``t_stop`` [s], then to rest and held still.

    With ``taper_s`` > 0 the velocity falls from its value v_s at ``t_stop`` as v_s (1 + cos(π τ / taper_s)) / 2,
    τ = t - t_stop (acceleration continuous at the end of the taper), and the piston comes to rest at
    y_s + v_s taper_s / 2; with ``taper_s`` = 0 the velocity steps from v_s to 0 at ``t_stop`` (a breakpoint,
    like a triangle's corner) and y holds at y_s.
    """
    return StoppedInput(inp, float(t_stop), float(taper_s))


# ----------------------------------------------------------------------------- measurement model
@dataclass(frozen=True)
class Sensors:
    """What a lab's channels add to the true y(t), F(t); every knob off by default.

    Attributes
    ----------
    displacement_sd : float
        White displacement noise sd [m].
    displacement_step : float
        Displacement ADC step [m] (the recorded value is rounded to it; 0: none).
    force_sd : float
        Force noise marginal sd [N].
    force_phi : float
        Force noise AR(1) coefficient φ (0: white).
    force_step : float
        Force ADC step [N].
    force_offset : float
        Constant offset of an unzeroed load cell [N].
    hum_amplitude, hum_frequency, hum_phase : float
        Mains hum on the force, amplitude [N] sin(2π f t + phase): amplitude [N], frequency [Hz] (50 or 60),
        phase [rad].
    velocity_channel : bool
        Record the true velocity too (a ``velocity_m_s`` column).
    velocity_sd, velocity_step : float
        Its white noise sd and ADC step [m/s].
    """

    displacement_sd: float = 0.0
    displacement_step: float = 0.0
    force_sd: float = 0.0
    force_phi: float = 0.0
    force_step: float = 0.0
    force_offset: float = 0.0
    hum_amplitude: float = 0.0
    hum_frequency: float = 50.0
    hum_phase: float = 0.0
    velocity_channel: bool = False
    velocity_sd: float = 0.0
    velocity_step: float = 0.0


@dataclass(frozen=True)
class Measured:
    """A recorded record: times [s], displacement [m], force [N] and optionally velocity [m/s]."""

    t: np.ndarray
    displacement: np.ndarray
    force: np.ndarray
    velocity: np.ndarray | None = None


def quantise(x, step: float) -> np.ndarray:
    """Round ``x`` to the ADC grid step·k (``step`` = 0: unchanged)."""
    x = np.asarray(x, dtype=float)
    return x if step == 0.0 else step * np.round(x / step)


def mains_hum(t, amplitude: float, frequency: float = 50.0, phase: float = 0.0) -> np.ndarray:
    """Mains hum amplitude·sin(2π f t + phase) [N] at times ``t`` [s]."""
    return amplitude * np.sin(2.0 * np.pi * frequency * np.asarray(t, dtype=float) + phase)


def measure(t, y, force, sensors: Sensors = Sensors(), *, seed, velocity=None) -> Measured:
    """Turn the true displacement and force at the sample times into what a lab records.

    Force channel: (F + offset + hum + noise), then rounded to the ADC step; displacement: (y + noise), rounded;
    velocity (if ``sensors.velocity_channel``): (v + noise), rounded. The three noises come from three
    independent child streams of ``seed`` (always three, so switching one channel on changes no other).

    Parameters
    ----------
    t, y, force : array_like, shape (n,)
        Sample times [s], true displacement [m], true force [N].
    sensors : Sensors
        The channels' effects.
    seed : int, sequence of int or numpy.random.SeedSequence
        Root seed of the record.
    velocity : array_like, shape (n,), optional
        True velocity [m/s]; required with a velocity channel.

    Returns
    -------
    Measured
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    s_disp, s_force, s_vel = root.spawn(3)
    s = sensors
    f = np.asarray(force, dtype=float) + s.force_offset + mains_hum(t, s.hum_amplitude, s.hum_frequency, s.hum_phase)
    if s.force_sd:
        f = f + force_noise(n, s.force_sd, s.force_phi, s_force)
    y_m = np.asarray(y, dtype=float) + (white_noise(n, s.displacement_sd, s_disp) if s.displacement_sd else 0.0)
    v_m = None
    if s.velocity_channel:
        if velocity is None:
            raise ValueError("a velocity channel needs the true velocity")
        v_m = quantise(np.asarray(velocity, dtype=float) + white_noise(n, s.velocity_sd, s_vel), s.velocity_step)
    return Measured(t, quantise(y_m, s.displacement_step), quantise(f, s.force_step), v_m)


# ----------------------------------------------------------------------------- damper variants
@dataclass(frozen=True)
class GasCharge:
    """The gas spring of a gas-charged (mono-tube) damper, acting on the rod.

    Gas of volume V_g at charge pressure p_c sits behind a floating piston; a piston displacement y (positive
    compresses chamber 1 and pushes the rod in) moves A_rod y of rod volume into the cylinder and compresses
    the gas polytropically: p_g = p_c (V_g / (V_g - A_rod y))^n. The gas pressure acts on both faces of the
    piston except the rod's cross-section, so the damper force gains p_g A_rod, which resists compression
    (positive, like A_P Δp on a compression stroke). Linearised about y = 0:

        F_gas = p_c A_rod + k y,   k = n p_c A_rod^2 / V_g,

    a charge-dependent constant force (what an unloaded damper reads at rest) plus a small gas-spring term.

    Attributes
    ----------
    charge_pressure : float
        p_c [Pa] (absolute).
    rod_area : float
        A_rod [m^2].
    gas_volume : float
        V_g at y = 0 [m^3].
    polytropic : float
        n [-]: 1 isothermal, 1.4 adiabatic (air or nitrogen).
    """

    charge_pressure: float
    rod_area: float
    gas_volume: float
    polytropic: float = 1.4

    @property
    def preload(self) -> float:
        """p_c A_rod [N]."""
        return self.charge_pressure * self.rod_area

    @property
    def rate(self) -> float:
        """Gas-spring rate k = n p_c A_rod^2 / V_g [N/m]."""
        return self.polytropic * self.charge_pressure * self.rod_area**2 / self.gas_volume

    def force(self, y, *, exact: bool = False) -> np.ndarray:
        """F_gas [N] at displacement ``y`` [m]: linearised (default) or the polytropic law itself."""
        y = np.asarray(y, dtype=float)
        if exact:
            return self.preload * (self.gas_volume / (self.gas_volume - self.rod_area * y)) ** self.polytropic
        return self.preload + self.rate * y


def bingham_force(v, yield_force: float, viscous: float = 0.0, v_eps: float = 1e-3) -> np.ndarray:
    """MR-like dry force F_y tanh(v / v_eps) + c v [N] at velocity ``v`` [m/s].

    A Bingham plastic (yield force F_y [N], post-yield damping c [N s/m]) with the sign smoothed over v_eps
    [m/s]; with c = 0 it is Coulomb friction. Added to eq. (7)'s A_P Δp, it makes the force-displacement loops
    rectangular when F_y dominates.
    """
    v = np.asarray(v, dtype=float)
    return yield_force * np.tanh(v / v_eps) + viscous * v


def true_force(inp, t, damper: dict, flow, alpha_v: float, p_r: float, *, model: str = "eq7",
               t0: float | None = None, coulomb: float = 0.0, viscous: float = 0.0, v_eps: float = 1e-3,
               gas: GasCharge | None = None, rtol: float = 1e-10, atol: float = 1e-6) -> dict[str, np.ndarray]:
    """The damper force at the sample times, by parts.

    Parameters
    ----------
    inp
        Input with ``displacement``, ``velocity``, ``breakpoints`` (a :class:`independent.TriangleInput` for
        ``model="two-state"``).
    t : array_like, shape (n,)
        Sample times [s].
    damper, flow, alpha_v
        As :func:`independent.simulate`.
    p_r : float
        p_R of eq. (6) [Pa]; the charge pressure (both chambers at rest) for ``model="two-state"``.
    model : {"eq7", "two-state"}
        Eq. (7) (:func:`independent.simulate`) or eq. (1) without accumulator (from rest at ``t[0]``).
    t0 : float, optional
        Start of the eq. (7) integration [s] (a pre-roll; Δp(t0) quasi-static); default ``t[0]``.
    coulomb, viscous, v_eps : float
        Bingham / Coulomb force of :func:`bingham_force`: F_y [N], c [N s/m], v_eps [m/s].
    gas : GasCharge, optional
        Gas-spring force on the rod (linearised law).
    rtol, atol : float
        Radau tolerances ([-], [Pa]).

    Returns
    -------
    dict of ndarray, shape (n,)
        ``"fluid"`` A_P Δp, ``"dry"`` the Bingham force, ``"gas"`` F_gas, ``"total"`` their sum [N].
    """
    t = np.asarray(t, dtype=float)
    if model == "eq7":
        fluid = simulate(inp, t, damper, flow, alpha_v, p_r, t0=t0, rtol=rtol, atol=atol)
    elif model == "two-state":
        if not isinstance(inp, TriangleInput) or t0 is not None:
            raise ValueError("the two-state model takes a TriangleInput from rest at t[0] (no pre-roll)")
        fluid = simulate_two_state(inp, t, damper, flow, alpha_v, p_r)
    else:
        raise ValueError(f"model must be 'eq7' or 'two-state', got {model!r}")
    dry = bingham_force(inp.velocity(t), coulomb, viscous, v_eps) if (coulomb or viscous) else np.zeros(t.size)
    gas_f = gas.force(inp.displacement(t)) if gas is not None else np.zeros(t.size)
    return {"fluid": fluid, "dry": dry, "gas": gas_f, "total": fluid + dry + gas_f}


# ----------------------------------------------------------------------------- records and data sets
@dataclass(frozen=True)
class SimulatedRecord:
    """A simulated record: the truth at the sample times and what the lab recorded.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times [s].
    y, v : ndarray, shape (n,)
        True displacement [m] and velocity [m/s].
    force : dict of ndarray
        True force by parts (:func:`true_force`) [N].
    measured : Measured
        The recorded channels.
    """

    t: np.ndarray
    y: np.ndarray
    v: np.ndarray
    force: dict
    measured: Measured


def simulate_record(inp, duration: float, rate: float, damper: dict, flow, alpha_v: float, p_r: float, *,
                    seed, sensors: Sensors = Sensors(), t_start: float = 0.0, pre_roll_s: float = 0.0,
                    **force_kw) -> SimulatedRecord:
    """Simulate and measure one record of n = round(duration·rate) samples at t = t_start + k / rate.

    Parameters
    ----------
    inp, damper, flow, alpha_v, p_r
        As :func:`true_force`.
    duration : float
        Record length [s].
    rate : float
        Sample rate [Hz].
    seed : int, sequence of int or numpy.random.SeedSequence
        Root seed of the sensors (:func:`measure`).
    sensors : Sensors
        Measurement model.
    t_start : float
        First sample time [s], may be off any grid.
    pre_roll_s : float
        The eq. (7) integration starts this long before ``t_start`` [s] (from the quasi-static Δp there), so a
        record of a running test starts in its steady state.
    **force_kw
        Passed to :func:`true_force` (``model``, ``coulomb``, ``viscous``, ``v_eps``, ``gas``, ``rtol``, ...).
    """
    t = t_start + np.arange(int(round(duration * rate))) / rate
    t0 = t_start - pre_roll_s if pre_roll_s > 0 else None
    parts = true_force(inp, t, damper, flow, alpha_v, p_r, t0=t0, **force_kw)
    y, v = inp.displacement(t), inp.velocity(t)
    return SimulatedRecord(t, y, v, parts, measure(t, y, parts["total"], sensors, seed=seed, velocity=v))


def _toml_value(v) -> str:
    """A TOML value: booleans, integers and floats (numpy's too) as such, anything else as a string."""
    if isinstance(v, bool | np.bool_):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        return repr(float(v))
    return json.dumps(str(v))


def write_records(folder, records: Mapping[str, Measured], damper: dict, name: str, *,
                  condition: Mapping | None = None, truth: Mapping | None = None) -> Path:
    """Write a data set: ``damper.toml`` (with an optional ``[condition]`` table), one CSV per record and
    optionally ``truth.json``.

    Parameters
    ----------
    folder : str or Path
        Output folder (created if needed).
    records : mapping of str to Measured
        Record name (the CSV stem) -> channels. CSV header ``time_s,displacement_m,force_N`` plus
        ``,velocity_m_s`` when the record has a velocity channel; floats written with ``repr``.
    damper : dict
        ``area`` [m^2], ``v01``, ``v02`` [m^3], ``b0`` [Pa] as :data:`independent.RIG_A`.
    name : str
        Damper name.
    condition : mapping, optional
        Keys and values of the ``[condition]`` table (numbers or strings), e.g. ``charge_pressure_Pa``.
    truth : mapping, optional
        JSON-serialisable truth written to ``truth.json``.

    Returns
    -------
    Path
        The folder.
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    lines = ["[damper]", f"name = {json.dumps(name)}", f"piston_area_m2 = {float(damper['area'])!r}",
             f"chamber_volume_1_m3 = {float(damper['v01'])!r}", f"chamber_volume_2_m3 = {float(damper['v02'])!r}",
             f"liquid_bulk_modulus_Pa = {float(damper['b0'])!r}"]
    if condition:
        lines += ["", "[condition]"] + [f"{k} = {_toml_value(v)}" for k, v in condition.items()]
    (root / "damper.toml").write_text("\n".join(lines) + "\n")
    for rec, m in records.items():
        cols = [m.t, m.displacement, m.force] + ([m.velocity] if m.velocity is not None else [])
        header = "time_s,displacement_m,force_N" + (",velocity_m_s" if m.velocity is not None else "")
        rows = zip(*(np.asarray(c, dtype=float).tolist() for c in cols), strict=True)
        (root / f"{rec}.csv").write_text("\n".join([header] + [",".join(map(repr, r)) for r in rows]) + "\n")
    if truth is not None:
        (root / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return root
