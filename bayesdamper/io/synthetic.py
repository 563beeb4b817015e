"""Synthetic data sets with known truth, in the interchange format every command reads.

The protocol is rig-A's: ``REST_S`` at rest, then a triangle of amplitude ``AMPLITUDE_M`` for
``CYCLES`` cycles (0 -> +A -> -A -> +A), sampled at a constant rate. The force is the chosen forward
model's solution over the whole record (reversals included), plus Gaussian noise that is white or
AR(1)-coloured with the given marginal standard deviation.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

from bayesdamper._version import __version__
from bayesdamper.core.errors import SettingsError
from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.physics.effects import complete_effects
from bayesdamper.physics.excitation import PiecewiseLinear
from bayesdamper.physics.reference import simulate_two_state
from bayesdamper.physics.single_state import simulate_single_state

REST_S = 1.0
AMPLITUDE_M = 5.0e-3
CYCLES = 1.25
#: Accumulator check-valve conductance of the two-state reference [m^3 s^-1 Pa^-1] (0: pure eq. (1)).
TWO_STATE_ACCUMULATOR = 1e-8
#: Standard deviation of the simulated displacement measurement noise [m] (rig-A shows ~1 µm).
DISPLACEMENT_NOISE_M = 1.0e-6


def test_name(velocity_m_s: float) -> str:
    """File stem of a test at piston speed ``velocity_m_s`` [m/s], e.g. ``tri_0p50mm_s``."""
    return "tri_" + f"{velocity_m_s * 1e3:.2f}".replace(".", "p") + "mm_s"


def coloured_noise(n: int, sd: float, phi: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary AR(1) noise of marginal standard deviation ``sd`` and coefficient ``phi``."""
    if not -1 < phi < 1:
        raise SettingsError(f"--noise-phi must lie in (-1, 1), got {phi}")
    e = rng.standard_normal(n) * sd * np.sqrt(1 - phi * phi)
    out = np.empty(n)
    out[0] = rng.standard_normal() * sd
    for i in range(1, n):
        out[i] = phi * out[i - 1] + e[i]
    return out


def simulate_record(velocity: float, dynamic: DynamicParameters, *, damper: DamperConstants = RIG_A_DAMPER,
                    flow: FlowCoefficients = PAPER_FLOW, sample_rate: float = 250.0, noise_n: float = 0.0,
                    noise_phi: float = 0.0, model: str = "eq7", rng: np.random.Generator | None = None,
                    effects: dict | None = None, accumulator_conductance: float = TWO_STATE_ACCUMULATOR
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One test: sample times [s], measured displacement [m], measured force [N].

    ``effects`` (``{effect: {param: value}}``, :mod:`bayesdamper.physics.effects`) injects effects into the
    chosen base model (:func:`simulate_with_effects`); the displacement is the measured (actuator) one.
    """
    rng = rng or np.random.default_rng(0)
    exc = PiecewiseLinear.triangle(AMPLITUDE_M, velocity, rest=REST_S, cycles=CYCLES)
    t = np.arange(0.0, exc.knot_times[-1] + 0.5 / sample_rate, 1.0 / sample_rate)
    t = t[t <= exc.knot_times[-1] + 1e-12]
    if effects:
        force = simulate_with_effects(t, exc, dynamic, effects, damper=damper, flow=flow, model=model,
                                      accumulator_conductance=accumulator_conductance)
    elif model == "eq7":
        dp = simulate_single_state(t, exc, damper, flow, dynamic, dp0=0.0, t0=0.0)
    elif model == "two-state":
        dp = simulate_two_state(t, exc, damper, flow, dynamic, dp0=0.0, t0=0.0,
                                accumulator_conductance=accumulator_conductance).dp
    else:
        raise SettingsError(f"--model: unknown model {model!r}, choose eq7 or two-state")
    if not effects:
        force = damper.piston_area * dp
    y = exc.displacement(t)
    if noise_n > 0:
        force = force + coloured_noise(t.size, noise_n, noise_phi, rng)
        y = y + DISPLACEMENT_NOISE_M * rng.standard_normal(t.size)
    return t, y, force


def write_dataset(out_dir: Path, velocities: list[float], dynamic: DynamicParameters, *,
                  damper: DamperConstants = RIG_A_DAMPER, flow: FlowCoefficients = PAPER_FLOW,
                  sample_rate: float = 250.0, noise_n: float = 0.0, noise_phi: float = 0.0,
                  seed: int = 0, model: str = "eq7", overwrite: bool = False,
                  effects: dict | None = None, accumulator_conductance: float = TWO_STATE_ACCUMULATOR) -> Path:
    """Write ``damper.toml``, one CSV per velocity [m/s] and ``truth.json`` into ``out_dir``.

    ``effects`` (``{effect: {param: value}}``) are injected into the base model and recorded, with
    every parameter filled in, under ``"effects"`` in ``truth.json`` (``{}`` when none).

    The folder is assembled in a temporary sibling and renamed into place, so a failure leaves any
    existing ``out_dir`` untouched.
    """
    out_dir = Path(out_dir)
    if noise_n < 0 or not np.isfinite(noise_n):
        raise SettingsError(f"--noise-n must be >= 0, got {noise_n}")
    if not velocities or any(not (0 < v < 1.0) for v in velocities):
        raise SettingsError(f"--velocities must be positive speeds in mm/s, got {velocities}")
    if out_dir.exists() and any(out_dir.iterdir()) and not overwrite:
        raise SettingsError(f"{out_dir}: folder exists and is not empty (use --force to overwrite)")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    effects = complete_effects(effects)
    rng = np.random.default_rng(seed)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        (tmp / "damper.toml").write_text(
            "[damper]\n"
            f'name = "{out_dir.name}"\n'
            f"piston_area_m2 = {damper.piston_area!r}\n"
            f"chamber_volume_1_m3 = {damper.chamber_volume_1!r}\n"
            f"chamber_volume_2_m3 = {damper.chamber_volume_2!r}\n"
            f"liquid_bulk_modulus_Pa = {damper.liquid_bulk_modulus!r}\n")
        for v in velocities:
            t, y, f = simulate_record(v, dynamic, damper=damper, flow=flow, sample_rate=sample_rate,
                                      noise_n=noise_n, noise_phi=noise_phi, model=model, rng=rng,
                                      effects=effects, accumulator_conductance=accumulator_conductance)
            with open(tmp / f"{test_name(v)}.csv", "w") as fh:
                fh.write("time_s,displacement_m,force_N\n")
                np.savetxt(fh, np.column_stack([t, y, f]), fmt=["%.6f", "%.9e", "%.4f"], delimiter=",")
        truth = {"generator": f"bayesdamper {__version__}", "model": model, "seed": seed,
                 "velocities_m_s": list(velocities), "sample_rate_Hz": sample_rate,
                 "noise_N": noise_n, "noise_phi": noise_phi, "displacement_noise_m": DISPLACEMENT_NOISE_M,
                 "protocol": {"rest_s": REST_S, "amplitude_m": AMPLITUDE_M, "cycles": CYCLES},
                 "damper": asdict(damper), "flow": asdict(flow),
                 "alpha_V": dynamic.liquid_gas_ratio, "p_R_Pa": dynamic.reference_pressure,
                 "effects": effects, "accumulator_conductance": accumulator_conductance}
        (tmp / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
        if out_dir.exists():
            shutil.rmtree(out_dir)
        tmp.rename(out_dir)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return out_dir


def run_simulate(out_dir: str, *, velocities_mm_s: list[float], alpha_v: float, p_r: float,
                 noise_n: float, noise_phi: float, seed: int, sample_rate: float, model: str,
                 overwrite: bool = False, effects: dict | None = None) -> None:
    """CLI entry of ``bayesdamper simulate`` (speeds in mm/s; ``effects`` as for :func:`write_dataset`)."""
    dyn = DynamicParameters(alpha_v, p_r)
    path = write_dataset(Path(out_dir), [v * 1e-3 for v in velocities_mm_s], dyn, sample_rate=sample_rate,
                         noise_n=noise_n, noise_phi=noise_phi, seed=seed, model=model, overwrite=overwrite,
                         effects=effects)
    print(f"wrote {len(velocities_mm_s)} test(s) to {path}")


def simulate_with_effects(t: np.ndarray, excitation: PiecewiseLinear, dynamic: DynamicParameters,
                          effects: dict, *, damper: DamperConstants = RIG_A_DAMPER,
                          flow: FlowCoefficients = PAPER_FLOW, model: str = "eq7",
                          accumulator_conductance: float = TWO_STATE_ACCUMULATOR) -> np.ndarray:
    """Measured force [N] at ``t`` [s] of the whole record with effects injected into the base model.

    ``model="eq7"``: eq. (7) with the effects; ``"two-state"``: the two-state model eq. (1), eq. (7) composed
    with the ``two_state`` effect charged to p_R (:func:`bayesdamper.physics.with_effects.two_state_effects`).
    Both on the composed kernel (:func:`bayesdamper.physics.with_effects.simulate_effects`), from rest at t = 0.
    """
    from bayesdamper.physics.with_effects import simulate_effects, two_state_effects

    if model == "eq7":
        return simulate_effects(t, excitation, damper, flow, dynamic, effects, dp0=0.0, t0=0.0)
    if model == "two-state":
        return simulate_effects(t, excitation, damper, flow, dynamic,
                                two_state_effects(dynamic, effects, accumulator_conductance), dp0=0.0, t0=0.0)
    raise SettingsError(f"--model: unknown model {model!r}, choose eq7 or two-state")
