"""Benchmark of sine, sweep and random records through the one path: identify and diagnose, whole commands.

Two problems, both made by the independent scipy-Radau re-implementation of eq. (7) (``tests/independent.py``,
nothing from bayesdamper) and read back like any user data:

* ``three``: three 30 s records at 200 Hz of the small MR-like damper (``SMALL``, ``SMALL_FLOW``, α_V 30,
  p_R 0.3 MPa): a 1 Hz, 10 mm sine, a 2 Hz, 5 mm sine and a 0.3-3 Hz random record of 3 mm rms, white force noise
  2 N, displacement noise 2 µm. Timed: ``bayesdamper identify`` (targets: ≤ 60 s on 2 cores) and a cold
  ``bayesdamper diagnose`` (empty kernel cache, fresh output folder; target ≤ 120 s).
* ``khz``: one 30 s record at 1 kHz (a 1 Hz, 10 mm sine plus a 0.3-4 Hz multisine of 2 mm rms), timed through
  ``bayesdamper identify`` (target ≤ 60 s).

For each: the wall time of the whole command, the windows, their convergence, τ, evaluations, and whether the
90 % intervals hold the truth. Usage: ``python benchmarks/records.py [three] [khz] [--data DIR] [--json]``;
``--data`` keeps the generated data sets between runs (making them takes about a minute).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the independent reference generator (imports no bayesdamper)

from independent import (  # noqa: E402
    SMALL,
    SMALL_FLOW,
    make_record,
    multisine_input,
    sine_input,
    write_dataset,
)
from independent_records import random_input  # noqa: E402

ALPHA_V, P_R = 30.0, 3.0e5
FORCE_SD, DISPLACEMENT_SD = 2.0, 2e-6  # [N], [m]
DURATION = 30.0  # [s]
TRUTH = dict(zip(("CL12", "CQ12", "CL21", "CQ21"), SMALL_FLOW, strict=True)) | {"alpha_V": ALPHA_V, "p_R_Pa": P_R}


class _Sum:
    """Sum of two inputs (analytic displacement and velocity; breakpoints of both)."""

    def __init__(self, a, b):
        self.a, self.b = a, b

    def displacement(self, t):
        return self.a.displacement(t) + self.b.displacement(t)

    def velocity(self, t):
        return self.a.velocity(t) + self.b.velocity(t)

    def breakpoints(self, t0, t1):
        return np.union1d(self.a.breakpoints(t0, t1), self.b.breakpoints(t0, t1))


def make_three(folder: Path) -> Path:
    """Three 30 s records at 200 Hz (module docstring)."""
    inputs = {"sine_1Hz": sine_input(10e-3, 1.0), "sine_2Hz": sine_input(5e-3, 2.0),
              "random": random_input(0.3, 3.0, seed=7, rms_displacement=3e-3)}
    recs = {name: make_record(inp, DURATION, 200.0, SMALL, SMALL_FLOW, ALPHA_V, P_R, sd=FORCE_SD, seed=k,
                              displacement_noise=DISPLACEMENT_SD, rtol=1e-9)
            for k, (name, inp) in enumerate(inputs.items())}
    return write_dataset(folder, recs, SMALL, "benchmark-three")


def make_khz(folder: Path) -> Path:
    """One 30 s record at 1 kHz (module docstring)."""
    inp = _Sum(sine_input(10e-3, 1.0), multisine_input(2e-3, 0.3, 4.0, 8, seed=3))
    rec = make_record(inp, DURATION, 1000.0, SMALL, SMALL_FLOW, ALPHA_V, P_R, sd=FORCE_SD, seed=11,
                      displacement_noise=DISPLACEMENT_SD, rtol=1e-9)
    return write_dataset(folder, {"sine_multisine": rec}, SMALL, "benchmark-khz")


def _timed(args: list[str], env: dict | None = None) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "bayesdamper.cli", *args], capture_output=True, text=True, env=env)
    return time.perf_counter() - t0, proc


def _windows(summary: dict) -> dict:
    rows = []
    for e in summary["segments"]:
        held = {n: bool(e[n]["lo"] <= TRUTH[n] <= e[n]["hi"]) for n in ("alpha_V", "p_R_Pa")}
        held |= {n: bool(e["flow"][n]["lo"] <= TRUTH[n] <= e["flow"][n]["hi"]) for n in e.get("flow", {})}
        rows.append({"id": e["id"], "converged": e["converged"], "tau_max": max(e["tau"].values()),
                     "n_evaluations": e["n_evaluations"], "wall_s": e["wall_s"], "truth_held": held})
    return {"n_windows": len(rows), "n_converged": sum(r["converged"] for r in rows), "windows": rows}


def run(name: str, data: Path, diagnose: bool) -> dict:
    with tempfile.TemporaryDirectory(prefix="bd-bench-") as tmp:
        out = Path(tmp) / "out"
        wall, proc = _timed(["identify", str(data), "--out", str(out), "--no-figures"])
        if proc.returncode:
            raise SystemExit(proc.stderr)
        res = {"case": name, "identify_s": wall, **_windows(json.loads((out / "summary.json").read_text()))}
        if diagnose:
            env = dict(os.environ, BAYESDAMPER_KERNEL_CACHE=str(Path(tmp) / "kernels"))  # cold: compiled afresh
            wall, proc = _timed(["diagnose", str(data), "--out", str(Path(tmp) / "diag"), "--no-figures"], env)
            if proc.returncode:
                raise SystemExit(proc.stderr)
            d = json.loads((Path(tmp) / "diag" / "diagnosis.json").read_text())
            res |= {"diagnose_cold_s": wall, "selected": d["selected"], "J_before": d["baseline"]["J_pooled"],
                    "J_after": d["final"]["J_pooled"]}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", default=["three", "khz"], choices=["three", "khz"])
    ap.add_argument("--data", type=Path, default=None, help="folder keeping the generated data sets")
    ap.add_argument("--json", action="store_true", help="print the results as one JSON line last")
    args = ap.parse_args(argv)
    root = args.data or Path(tempfile.mkdtemp(prefix="bd-bench-data-"))
    results = []
    for case in args.cases:
        folder = root / case
        if not (folder / "damper.toml").is_file():
            (make_three if case == "three" else make_khz)(folder)
        r = run(case, folder, diagnose=case == "three")
        results.append(r)
        print(f"{case}: identify {r['identify_s']:.1f} s, {r['n_converged']}/{r['n_windows']} windows converged"
              + (f"; diagnose (cold) {r['diagnose_cold_s']:.1f} s, selected {r['selected'] or 'none'}, "
                 f"J {r['J_before']:.4f} -> {r['J_after']:.4f}" if "diagnose_cold_s" in r else ""))
        for w in r["windows"]:
            miss = [k for k, v in w["truth_held"].items() if not v]
            print(f"  {w['id']}: converged {w['converged']}, tau {w['tau_max']:.1f}, {w['n_evaluations']} "
                  f"evaluations, {w['wall_s']:.1f} s, truth outside the 90 % interval of: {', '.join(miss) or '-'}")
    if args.json:
        print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
