"""Prediction benchmark: ``bayesdamper predict`` of a 60 s displacement history sampled at 1 kHz with 200 draws.

The calibration is either a results folder's (``--results OUT`` of ``bayesdamper identify``/``report``: its
``calibration-final.nc`` or ``calibration.nc``) or, by default, a hand-made eq. (7) calibration of rig-A's damper (a
drift law with scatter, the paper's flow coefficients). The history is a multisine of 1.5 mm rms, 0.05-0.5 Hz
(speeds up to about 2 mm/s), with 1 µm of displacement noise, written as a CSV. Measured: the whole command
(``bayesdamper predict`` in a subprocess: start-up, reading, reconstruction, the draws' simulations, noise, CSV,
JSON and figure), its median over ``--repeat`` runs, and the phases in-process (reconstruction, simulations).

Usage: ``python benchmarks/predict.py [--results OUT] [--workers 2] [--repeat 3] [--quick]``.
Target: the command in <= 10 s on 2 cores.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER
from bayesdamper.inference.calibration import Calibration
from bayesdamper.inference.hierarchy import HierarchyFit

DURATION = 60.0  # [s]
RATE = 1000.0  # [Hz]
DRAWS = 200


def hand_made_calibration() -> Calibration:
    rng = np.random.default_rng(0)
    n = 2000
    beta = np.array([np.log(40.0), -0.09, np.log(3.0e5), 0.12]) + 0.005 * rng.standard_normal((n, 4))
    draws = np.column_stack([beta, np.tile([0.05, 0.08], (n, 1)), np.zeros(n), np.tile([0.03, 0.05], (n, 1)),
                             np.zeros(n)])
    windows = [{"id": f"t{i}", "test": f"t{i}", "speed_m_s": v} for i, v in enumerate(np.linspace(5e-4, 2e-3, 6))]
    flow = np.array([PAPER_FLOW.laminar_12, PAPER_FLOW.quadratic_12, PAPER_FLOW.laminar_21,
                     PAPER_FLOW.quadratic_21]) * (1 + 0.002 * rng.standard_normal((400, 4)))
    h = HierarchyFit(draws, 1, 1.2e-3, 5e-4, windows, {"converged": True}, 0, True)
    return Calibration(h, flow, 12.0, 0.0, {}, RIG_A_DAMPER, "eq. (7)", 250.0, {"benchmark": "hand-made"})


def history(path: Path, duration: float) -> Path:
    rng = np.random.default_rng(1)
    t = np.arange(0.0, duration, 1.0 / RATE)
    freqs = np.linspace(0.05, 0.5, 10)
    y = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs)
    y = 1.5e-3 * y / np.std(y) * np.clip(t / 2.0, 0, 1) + 1e-6 * rng.standard_normal(t.size)  # from rest
    path.write_text("time_s,displacement_m\n" + "\n".join(f"{a:.6f},{b:.9g}" for a, b in zip(t, y, strict=True)))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", help="a results folder to take the calibration from (default: hand-made)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="6 s of history, 40 draws, one run")
    args = ap.parse_args()
    duration, draws, repeat = (6.0, 40, 1) if args.quick else (DURATION, DRAWS, args.repeat)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        results = Path(args.results) if args.results else tmp / "results"
        if not args.results:
            results.mkdir()
            hand_made_calibration().save(results / "calibration.nc")
        hist = history(tmp / "history.csv", duration)
        walls = []
        for k in range(repeat):
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "bayesdamper", "predict", str(results), "--input", str(hist),
                                "--out", str(tmp / f"out{k}"), "--draws", str(draws), "--workers", str(args.workers)],
                               capture_output=True, text=True)
            walls.append(time.perf_counter() - t0)
            if r.returncode != 0:
                sys.exit(f"predict failed: {r.stderr.strip()}")
        # phases in-process
        from bayesdamper.io.dataset import load_history
        from bayesdamper.run.predict import calibration_path, history_drive, load_calibration

        cal = load_calibration(calibration_path(results))
        rec = load_history(hist)
        t0 = time.perf_counter()
        drive, speed, v0, _ = history_drive(rec)
        t_rec = time.perf_counter() - t0
        t0 = time.perf_counter()
        from bayesdamper.run.predict import process_map

        forces, _, failed = cal.simulate(rec.time, drive, speed, v0, draws, 0, process_map(args.workers))
        t_sim = time.perf_counter() - t0
    print(f"history: {duration:.0f} s at {RATE:.0f} Hz ({int(duration * RATE)} samples), {draws} draws, "
          f"{args.workers} worker(s), calibration: {args.results or 'hand-made eq. (7)'}")
    print(f"bayesdamper predict (whole command): min {min(walls):.2f} s, median {np.median(walls):.2f} s, "
          f"max {max(walls):.2f} s over {repeat} run(s)   [target <= 10 s]")
    print(f"  in-process: reconstruction {t_rec:.2f} s, simulations {t_sim:.2f} s "
          f"({1e3 * t_sim / draws:.1f} ms per draw, {failed} failed)")


if __name__ == "__main__":
    main()
