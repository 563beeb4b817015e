"""Input-reconstruction benchmark: wall time of ``reconstruct_input`` on long records.

Records of 60 s at 1 kHz (60 000 samples), 5 µm of white displacement noise: a 2 Hz, 5 mm sine (which gets the
harmonic part) and a multisine to 3 Hz (the penalised spline alone), plus the same sine at 200 Hz over 10 minutes.
Each is reconstructed ``--repeats`` times; min / median / max wall time [s] are printed with the rms velocity error
against the analytic velocity.

Usage: ``python benchmarks/reconstruct.py [--repeats N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from bayesdamper.io.reconstruct import reconstruct_input


def _sine(t, freq=2.0, amp=5e-3):
    w = 2 * np.pi * freq
    return amp * np.sin(w * t), amp * w * np.cos(w * t)


def _multisine(t, top=3.0, seed=0):
    rng = np.random.default_rng(seed)
    freqs = np.linspace(0.1, top, 12)
    amps = 1e-3 / freqs
    phases = rng.uniform(0, 2 * np.pi, freqs.size)
    arg = 2 * np.pi * np.outer(t, freqs) + phases
    return np.sin(arg) @ amps, (2 * np.pi * freqs * np.cos(arg)) @ amps


CASES = {
    "sine 2 Hz, 60 s at 1 kHz": (_sine, 1000.0, 60.0),
    "multisine to 3 Hz, 60 s at 1 kHz": (_multisine, 1000.0, 60.0),
    "sine 2 Hz, 600 s at 200 Hz": (_sine, 200.0, 600.0),
}
NOISE = 5e-6  # [m]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = {}
    for name, (signal, rate, duration) in CASES.items():
        t = np.arange(int(round(rate * duration))) / rate
        y, v = signal(t)
        ym = y + NOISE * np.random.default_rng(1).standard_normal(t.size)
        walls, err = [], float("nan")
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            rec = reconstruct_input(t, ym)
            walls.append(time.perf_counter() - t0)
            err = float(np.sqrt(np.mean((rec.velocity(t) - v) ** 2)))
        rows[name] = {"samples": t.size, "min_s": min(walls), "median_s": float(np.median(walls)),
                      "max_s": max(walls), "velocity_rms_error_m_s": err, "harmonics": rec.n_harmonics}
        print(f"{name:36s} n={t.size:7d}  wall min/median/max {min(walls):6.2f} / {np.median(walls):6.2f} / "
              f"{max(walls):6.2f} s  velocity error {err * 1e6:8.3f} µm/s  harmonics {rec.n_harmonics}")
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
