"""Independent sine and random-motion records of a damper with rig effects (scipy Radau, no bayesdamper).

This helper module (not a test file) drives the reference simulator of ``tests/reference_effects.py`` (eq. (7)
and the effects written there from the equations) with smooth inputs — sines and band-limited random motion
(``independent.sine_input``, ``independent_records.random_input``) — and adds, each from its own physics, the
three effects of a rig that ``reference_effects`` does not hold:

* ``friction``: Coulomb and viscous friction on the piston, F_c tanh(v_P / v_s) + c v_P, added to the measured
  force (v_P the piston velocity: the servo's when ``command_displacement`` is injected too);
* ``backlash``: a free play of total width g between the actuator, whose displacement is recorded, and the
  piston (:func:`play_input`): after every reversal the piston rests until the actuator has crossed the play,
  then is dragged along at y_P = y_A ∓ g/2. The play operator is applied exactly to the smooth input (reversals
  and contacts found by root finding), and the simulator restarts at every contact, where v_P jumps;
* ``series_compliance``: the damper is mounted through a spring of stiffness k_s that carries the damper force
  A_P Δp, so y_P = y_A - A_P Δp / k_s and, from eq. (7), dΔp/dt = K (A_P v_A - Q_O(Δp)) / (1 + K A_P^2 / k_s),
  K = B_1/V_1(y_P) + B_2/V_2(y_P) (:func:`simulate_compliant`; the load cell in series reads A_P Δp).

It must never import ``bayesdamper``. Records (:func:`sine_records`, :func:`random_records`) are what a lab
writes: a sample rate of a few hundred Hz, white force noise of a few N on forces of kN, white displacement noise
of a few µm, each record at its own amplitude and frequency (or rms level), so that the records span several
piston speeds. SI units throughout.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from independent import bulk_modulus, orifice_flow, quasi_static_dp, sine_input, white_noise
from independent_records import random_input
from reference_effects import FRICTION_V_SIGN, _segment, simulate_effects
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

__all__ = [
    "LAB",
    "LAB_FLOW",
    "RIG_EFFECTS",
    "PlayInput",
    "play_input",
    "random_records",
    "simulate_compliant",
    "simulate_rig",
    "sine_records",
]

#: A laboratory damper of kN forces at road speeds: 50 mm bore (A_P = 20 cm^2), 100 cm^3 per chamber.
LAB = dict(area=2.0e-3, v01=1.0e-4, v02=1.0e-4, b0=1.5e9)
#: Its flow pairs (C_L12 [kg m^-4 s^-1], C_Q12 [kg m^-7], C_L21, C_Q21): eq. (4) at Q = A_P v gives
#: F = 1.8 kN (compression) and 1.9 kN (rebound) at 94 mm/s, 330 / 320 N at 31 mm/s.
LAB_FLOW = (1.5e9, 1.75e13, 1.2e9, 2.2e13)

#: The effects this module adds to :data:`reference_effects.EFFECT_PARAMS`: name -> {parameter: default}
#: (``None``: required).
RIG_EFFECTS: dict[str, dict[str, float | None]] = {
    "friction": {"coulomb_N": None, "viscous_Ns_per_m": 0.0},
    "backlash": {"gap_m": None},
    "series_compliance": {"stiffness_N_per_m": None},
}

#: Grid step on which the actuator velocity's sign changes are bracketed before root finding [s]: a reversal pair
#: closer than this (a random motion grazing v = 0 for less than 1 ms) is not seen; the play ignores a wiggle that
#: small anyway unless it exceeds the gap, which at the band of these records (≤ 3 Hz) it cannot.
PLAY_GRID_S = 1e-3


# ----------------------------------------------------------------------------- backlash: the play operator
@dataclass(frozen=True)
class PlayInput:
    """The piston behind a play of total width ``gap`` from the actuator input ``inner`` (see :func:`play_input`).

    The motion is a sequence of pieces starting at ``starts``: ``mode`` 0 the piston rests at ``rest`` (free in
    the play), +1 it is pushed forward (y_P = y_A - gap/2), -1 pulled back (y_P = y_A + gap/2). The interface is
    that of the inputs of ``independent.py`` (``displacement``, ``velocity``, ``breakpoints``, ``on_segment``).
    """

    inner: object
    gap: float
    starts: np.ndarray
    mode: np.ndarray
    rest: np.ndarray

    def _piece(self, t) -> np.ndarray:
        return np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, self.starts.size - 1)

    def displacement(self, t):
        """Piston displacement y_P(t) [m] (the first piece extends before the start, the last after the end)."""
        t = np.asarray(t, dtype=float)
        k = self._piece(t)
        m = self.mode[k]
        return np.where(m == 0, self.rest[k], self.inner.displacement(t) - m * 0.5 * self.gap)

    def velocity(self, t):
        """Piston velocity dy_P/dt [m/s], right-continuous at a contact (where it jumps from 0 to v_A)."""
        t = np.asarray(t, dtype=float)
        m = self.mode[self._piece(t)]
        return np.where(m == 0, 0.0, self.inner.velocity(t))

    def breakpoints(self, t0: float, t1: float) -> np.ndarray:
        """Contacts and releases (the actuator's reversals) in (t0, t1), and the inner input's breakpoints."""
        b = np.unique(np.concatenate((self.starts[1:], self.inner.breakpoints(t0, t1))))
        return b[(b > t0) & (b < t1)]

    def on_segment(self, ta: float, tb: float):
        """Scalar y_P(t), v_P(t) on the closed segment [ta, tb]: the form of the piece holding its midpoint, so a
        contact at ``tb`` does not leak into the segment."""
        k = int(self._piece(0.5 * (ta + tb)))
        y_of, v_of = _segment(self.inner, ta, tb)
        if self.mode[k] == 0:
            y_rest = float(self.rest[k])
            return (lambda t: y_rest), (lambda t: 0.0)
        shift = float(self.mode[k]) * 0.5 * self.gap
        return (lambda t: y_of(t) - shift), v_of


def play_input(inner, gap: float, t_begin: float, t_end: float, *, y_piston0: float | None = None) -> PlayInput:
    """The play operator of total width ``gap`` [m] applied exactly to the smooth actuator input ``inner``.

    On [t_begin, t_end] the actuator's reversals (sign changes of its velocity, bracketed on a
    :data:`PLAY_GRID_S` grid and solved by Brent's method) cut the motion into monotone pieces. On a piece of
    direction d the piston rests at y_r until the actuator reaches the contact y_A = y_r + d gap/2 (Brent again),
    then is dragged at y_P = y_A - d gap/2 until the next reversal, where it is left at rest where it is.

    Parameters
    ----------
    inner
        Actuator displacement y_A (``displacement``, ``velocity``, ``breakpoints``), smooth in velocity.
    gap : float
        Total free play [m], > 0.
    t_begin, t_end : float
        Span [s] over which the operator is built (the simulation's start, usually before the first sample,
        and its last sample).
    y_piston0 : float, optional
        Piston position at ``t_begin`` [m]; default y_A(t_begin), centred in the play.

    Returns
    -------
    PlayInput
    """
    if not (gap > 0.0 and math.isfinite(gap) and t_end > t_begin):
        raise ValueError("the play needs gap > 0 and t_end > t_begin")
    r = 0.5 * float(gap)
    n = max(2, int(math.ceil((t_end - t_begin) / PLAY_GRID_S)) + 1)
    grid = np.linspace(t_begin, t_end, n)
    v = np.asarray(inner.velocity(grid), dtype=float)
    flips = np.flatnonzero(np.sign(v[1:]) * np.sign(v[:-1]) < 0)
    reversals = [brentq(lambda t: float(inner.velocity(t)), grid[i], grid[i + 1], xtol=1e-13, rtol=1e-15)
                 for i in flips]
    edges = [float(t_begin)] + reversals + [float(t_end)]
    y_a = lambda t: float(inner.displacement(t))  # noqa: E731
    yp = y_a(t_begin) if y_piston0 is None else min(max(float(y_piston0), y_a(t_begin) - r), y_a(t_begin) + r)
    starts, modes, rests = [], [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        d = 1.0 if float(inner.velocity(0.5 * (a + b))) > 0.0 else -1.0
        level = yp + d * r  # the actuator position at which it takes the piston along
        if d * (y_a(b) - level) <= 0.0:  # never reaches the other side of the play on this piece
            starts.append(a), modes.append(0), rests.append(yp)
            continue
        te = a if d * (y_a(a) - level) >= 0.0 else brentq(lambda t, c=level: y_a(t) - c, a, b,
                                                                        xtol=1e-13, rtol=1e-15)
        if te > a:
            starts.append(a), modes.append(0), rests.append(yp)
        starts.append(te), modes.append(int(d)), rests.append(math.nan)
        yp = y_a(b) - d * r
    return PlayInput(inner, float(gap), np.array(starts), np.array(modes, dtype=int), np.array(rests))


# ----------------------------------------------------------------------------- series compliance
def simulate_compliant(inp, t_samples, damper: dict, flow, alpha_v: float, p_r: float, stiffness: float, *,
                       t0: float | None = None, dp0: float | None = None, v_prev: float | None = None,
                       rtol: float = 1e-10, atol: float = 1e-6, return_dp: bool = False) -> np.ndarray:
    """Measured force A_P Δp [N] of eq. (7) behind a mount of stiffness ``stiffness`` [N/m] (module docstring).

    ``inp`` is the actuator displacement; the piston sits at y_P = y_A - A_P Δp / k_s. Δp starts at ``dp0``
    (default: eq. (4) at Q = A_P ``v_prev``, ``v_prev`` default v_A just before ``t0``) at ``t0`` (default the
    first sample); Radau restarts at every breakpoint of the input. ``return_dp`` returns Δp [Pa] instead.
    """
    area, v01, v02, b0 = (float(damper[k]) for k in ("area", "v01", "v02", "b0"))
    t_samples = np.asarray(t_samples, dtype=float)
    t0 = float(t_samples[0]) if t0 is None else float(t0)
    t1 = float(t_samples[-1])
    if v_prev is None:
        v_prev = float(inp.velocity(t0 - 1e-9))
    x = np.array([float(quasi_static_dp(area * v_prev, flow)) if dp0 is None else float(dp0)])
    compliance = area / float(stiffness)  # piston shift per Pa of Δp [m/Pa]

    def bulk(p: float) -> float:
        return float(bulk_modulus(p, b0, alpha_v, p_r))

    edges = np.unique(np.concatenate(([t0], inp.breakpoints(t0, t1), [t1])))
    out = np.empty(t_samples.size)
    out[t_samples <= t0] = x[0]
    for ta, tb in zip(edges[:-1], edges[1:], strict=True):
        y_of, v_of = _segment(inp, ta, tb)

        def rhs(t, z, y_of=y_of, v_of=v_of):
            dp = float(z[0])
            y_p = y_of(t) - compliance * dp
            b1, b2 = (bulk(p_r + dp), bulk(p_r)) if dp >= 0.0 else (bulk(p_r), bulk(p_r - dp))
            k = b1 / (v01 - area * y_p) + b2 / (v02 + area * y_p)
            return [k * (area * v_of(t) - orifice_flow(dp, flow)) / (1.0 + k * area * compliance)]

        sol = solve_ivp(rhs, (ta, tb), x, method="Radau", rtol=rtol, atol=atol, dense_output=True)
        if sol.status != 0:
            raise RuntimeError(f"Radau solve failed on [{ta!r}, {tb!r}] s: {sol.message}")
        sel = (t_samples > ta) & (t_samples <= tb)
        if np.any(sel):
            out[sel] = sol.sol(t_samples[sel])[0]
        x = sol.y[:, -1]
    return out if return_dp else area * out


# ----------------------------------------------------------------------------- the rig
def _resolve_rig(effects: Mapping[str, Mapping[str, float]]) -> tuple[dict, dict]:
    """Split ``effects`` into this module's (with defaults filled) and ``reference_effects``' own."""
    rig, rest = {}, {}
    for name, params in effects.items():
        if name not in RIG_EFFECTS:
            rest[name] = dict(params)
            continue
        spec = RIG_EFFECTS[name]
        bad = sorted(set(params) - set(spec))
        if bad:
            raise ValueError(f"unknown parameter(s) {bad} of effect {name!r}; known: {list(spec)}")
        filled = {}
        for k, default in spec.items():
            if k not in params and default is None:
                raise ValueError(f"effect {name!r} needs parameter {k!r}")
            filled[k] = float(params.get(k, default))
            if not math.isfinite(filled[k]) or filled[k] < 0.0:
                raise ValueError(f"{name}.{k} must be finite and >= 0, got {filled[k]!r}")
        rig[name] = filled
    if rig.get("backlash", {}).get("gap_m", 1.0) <= 0.0 or rig.get("series_compliance", {}).get(
            "stiffness_N_per_m", 1.0) <= 0.0:
        raise ValueError("backlash.gap_m and series_compliance.stiffness_N_per_m must be > 0")
    if "series_compliance" in rig and (rest or "friction" in rig):
        raise ValueError("series_compliance is simulated alone (with backlash at most): the mount carries A_P Δp")
    return rig, rest


def simulate_rig(inp, t_samples, damper: dict, flow, alpha_v: float, p_r: float,
                 effects: Mapping[str, Mapping[str, float]] | None = None, *, t0: float, dp0: float | None = None,
                 v_prev: float | None = None, rtol: float = 1e-9, atol: float = 1e-4) -> np.ndarray:
    """Measured force [N] of eq. (7) with any effects of :data:`reference_effects.EFFECT_PARAMS` and of
    :data:`RIG_EFFECTS`, driven by the actuator displacement ``inp`` from ``t0`` [s].

    Backlash turns the actuator input into the piston's (:func:`play_input`, built from ``t0``: the piston
    centred in the play there); series compliance runs :func:`simulate_compliant` on it; everything else runs
    :func:`reference_effects.simulate_effects` on it; friction is added at the piston velocity. ``dp0``,
    ``v_prev``, ``rtol``, ``atol`` [Pa] are those of the simulators.
    """
    t_samples = np.asarray(t_samples, dtype=float)
    rig, rest = _resolve_rig(effects or {})
    piston = inp
    if "backlash" in rig:
        piston = play_input(inp, rig["backlash"]["gap_m"], t0, float(t_samples[-1]))
    if "series_compliance" in rig:
        return simulate_compliant(piston, t_samples, damper, flow, alpha_v, p_r,
                                  rig["series_compliance"]["stiffness_N_per_m"], t0=t0, dp0=dp0, v_prev=v_prev,
                                  rtol=rtol, atol=atol)
    out = simulate_effects(piston, t_samples, damper, flow, alpha_v, p_r, rest, t0=t0, dp0=dp0, v_prev=v_prev,
                           rtol=rtol, atol=atol, return_states=True)
    force = out["force"]
    if "friction" in rig:
        v_p = out["v_p"] if "command_displacement" in rest else piston.velocity(t_samples)
        fr = rig["friction"]
        force = force + fr["coulomb_N"] * np.tanh(v_p / FRICTION_V_SIGN) + fr["viscous_Ns_per_m"] * v_p
    return force


# ----------------------------------------------------------------------------- records
#: Integration tolerances of the records: Radau rtol 1e-8 and atol 1e-4 Pa (1e-7 N on a 20 cm^2 piston), far
#: below the force noise of a few N.
RECORD_RTOL, RECORD_ATOL = 1e-8, 1e-4
#: Tone spacing of the random motion [Hz]: its period 1 / 0.05 = 20 s is longer than any record, so no record
#: repeats itself.
RANDOM_RESOLUTION_HZ = 0.05
#: The simulation starts this long before the first sample [s], so that every state (servo, valve, inertance,
#: the play) is in its periodic or stationary regime when the record starts.
PRE_ROLL_S = 2.0


def _measure(inp, t, force, force_sd: float, displacement_sd: float, seed) -> tuple:
    s_force, s_disp = np.random.SeedSequence(seed).spawn(2)
    y = inp.displacement(t) + white_noise(t.size, displacement_sd, s_disp)
    return t, y, force + white_noise(t.size, force_sd, s_force)


def _record(inp, duration: float, rate: float, t_start: float, damper, flow, alpha_v, p_r, effects,
            force_sd: float, displacement_sd: float, seed) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = t_start + np.arange(int(round(duration * rate))) / rate
    f = simulate_rig(inp, t, damper, flow, alpha_v, p_r, effects, t0=t_start - PRE_ROLL_S, rtol=RECORD_RTOL,
                     atol=RECORD_ATOL)
    return _measure(inp, t, f, force_sd, displacement_sd, seed)


def _freeze(effects: Mapping) -> tuple:
    return tuple(sorted((k, tuple(sorted(v.items()))) for k, v in effects.items()))


@functools.cache
def _sine_records(tones: tuple, duration: float, rate: float, damper: tuple, flow: tuple, alpha_v: float,
                  p_r: float, effects: tuple, force_sd: float, displacement_sd: float, seed: int) -> dict:
    fx = {k: dict(v) for k, v in effects}
    dm = dict(damper)
    out = {}
    for k, (amplitude, frequency) in enumerate(tones):
        inp = sine_input(amplitude, frequency)  # mid-stroke at peak speed at t = 0; running since the pre-roll
        t_start = 0.0031 * (k + 1)  # first samples off the grid of every other record
        name = f"sine_{amplitude * 1e3:g}mm_{frequency:g}Hz".replace(".", "p")
        out[name] = _record(inp, duration, rate, t_start, dm, flow, alpha_v, p_r, fx, force_sd, displacement_sd,
                            [seed, k])
    return out


@functools.cache
def _random_records(levels: tuple, band: tuple, duration: float, rate: float, damper: tuple, flow: tuple,
                    alpha_v: float, p_r: float, effects: tuple, force_sd: float, displacement_sd: float,
                    seed: int) -> dict:
    fx = {k: dict(v) for k, v in effects}
    dm = dict(damper)
    out = {}
    for k, rms in enumerate(levels):
        inp = random_input(band[0], band[1], seed=np.random.SeedSequence([seed, 1000 + k]), rms_displacement=rms,
                           resolution=RANDOM_RESOLUTION_HZ)
        t_start = 0.0047 * (k + 1)
        name = f"random_{rms * 1e3:g}mm_rms".replace(".", "p")
        out[name] = _record(inp, duration, rate, t_start, dm, flow, alpha_v, p_r, fx, force_sd, displacement_sd,
                            [seed, k])
    return out


def sine_records(tones, *, duration: float, rate: float, damper: dict, flow, alpha_v: float, p_r: float,
                 effects: Mapping | None = None, force_sd: float, displacement_sd: float, seed: int) -> dict:
    """Sine records ``{name: (t [s], y [m], F [N])}``, one per (amplitude [m], frequency [Hz]) of ``tones``.

    Each sine runs from :data:`PRE_ROLL_S` before its first sample (mid-stroke at peak speed at t = 0), so the
    record starts in the steady cycle; samples at ``rate`` [Hz] for ``duration`` [s], first sample off the grid
    by a few ms; white force noise of sd ``force_sd`` [N] and displacement noise ``displacement_sd`` [m] from
    the child streams of (``seed``, record index). Cached: the records are only read.
    """
    return _sine_records(tuple((float(a), float(f)) for a, f in tones), float(duration), float(rate),
                         tuple(sorted(damper.items())), tuple(flow), float(alpha_v), float(p_r),
                         _freeze(effects or {}), float(force_sd), float(displacement_sd), int(seed))


def random_records(levels, band, *, duration: float, rate: float, damper: dict, flow, alpha_v: float, p_r: float,
                   effects: Mapping | None = None, force_sd: float, displacement_sd: float, seed: int) -> dict:
    """Band-limited random records ``{name: (t, y, F)}``, one per rms displacement [m] of ``levels``: Gaussian
    motion with a flat displacement spectrum in ``band`` [Hz] (``independent_records.random_input``, each record
    its own draw), otherwise as :func:`sine_records`."""
    return _random_records(tuple(float(x) for x in levels), tuple(float(b) for b in band), float(duration),
                           float(rate), tuple(sorted(damper.items())), tuple(flow), float(alpha_v), float(p_r),
                           _freeze(effects or {}), float(force_sd), float(displacement_sd), int(seed))
