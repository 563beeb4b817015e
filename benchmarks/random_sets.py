"""The closed loop on randomly drawn triangular data sets: a confusion table on cases nobody chose.

The confusion table (``tests/test_confusion.py``) and ``benchmarks/triangular_sets.py`` judge the loop on fixed cases.
This script draws new ones from seeded ranges instead, writes each with the same independent reference generator
(``tests/reference_effects.py``: the physical two-state damper, a polytropic gas referenced to atmosphere and an
accumulator behind a line and check valves), runs a cold ``bayesdamper diagnose`` on it and judges it by the confusion
table's rule (:func:`judge`). Every draw is:

- the base: polytropic exponent κ U(1.1, 1.4), gas-to-liquid volume ratio at the charge U(0.012, 0.035), charge
  pressure U(0.4, 0.9) MPa;
- at most one rig effect, each family equally likely: none (a control), a compliant mount (series stiffness
  log-U(1e7, 3e7) N/m), check valves on the flow path (the reference's poppet: 1.5-4 Hz, damping 0.3-0.7, cracking
  log-U(10, 100) kPa, a span that settles on every plateau; in one valve case of two a check valve for each flow
  direction, in the other one valve element passing either direction), seal friction (Stribeck force 150-300 N at
  3-8 mm/s,
  viscous 5-20 N s/m) or a servo that follows its command (bandwidth 3-8 Hz, damping 0.25-0.6);
- the measurement: 100, 200, 250, 500 or 1000 Hz, force noise 8-20 N, displacement noise 0.2-0.5 µm, ADC steps of
  0, 2 or 4 N and 0, 0.5 or 1 µm, and an unzeroed load cell (±30-180 N) in two sets of three;
- rig-A's protocol: eleven speeds 0.5-1.5 mm/s, 5 mm amplitude, 1.25 cycles (33 transients).

The ranges are the families' plausible sizes, set before any run and not adjusted to the results. A case passes
when a control names nothing but the two-state physics (and the offset where the load cell has one), an effect's
family is named with at most those besides it, the pooled J after falls to at most half of the baseline's where
there is an effect, and the selected model's pooled J is within 2x of the true model's on the same samples (the
library holds every drawn form). A drawn effect that is not named is "below the floor", not a failure, when the
selected model's J is within 1 / (1 - 0.2) of the truth's: the draw made it too small for the loop's stated
criterion (an effect must lower J by a fifth), whatever the search did (:func:`judge`).

    python benchmarks/random_sets.py [-n 10] [--seed 2026] [--out /tmp/bayesdamper-random] [--workers 2]

Printed per case: what was drawn, what was selected, J before/after/truth, the verdict and the cold diagnose's wall
time; then the confusion table (drawn family x named families) and the wall times' range.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_confusion as tc  # noqa: E402
from reference_effects import alpha_for_gas_fraction  # noqa: E402

FAMILIES = ("none", "series_compliance", "poppet_valve", "seal_friction", "command_displacement")
RATES = (100.0, 200.0, 250.0, 500.0, 1000.0)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw(rng: np.random.Generator) -> tuple[dict, dict, tc.Channels]:
    """One case: (the two-state base, the injected effects, the channels)."""
    kappa, fraction, charge = rng.uniform(1.1, 1.4), rng.uniform(0.012, 0.035), rng.uniform(4.0e5, 9.0e5)
    base = {"two_state_damper": {"polytropic_exponent": kappa,
                                 "liquid_gas_ratio_atm": alpha_for_gas_fraction(fraction, charge, kappa),
                                 "charge_pressure_Pa": charge, "accumulator_volume_m3": tc.TWO_STATE_ACCUMULATOR,
                                 "line_conductance_m3_per_s_Pa": tc.TWO_STATE_LINE}}
    family = FAMILIES[int(rng.integers(len(FAMILIES)))]
    effects = {
        "none": {},
        "series_compliance": {"series_compliance": {"stiffness_N_per_m": _log_uniform(rng, 1.0e7, 3.0e7)}},
        "poppet_valve": {"poppet_valve": {"natural_frequency_Hz": rng.uniform(1.5, 4.0),
                                          "damping_ratio": rng.uniform(0.3, 0.7),
                                          "cracking_pressure_Pa": _log_uniform(rng, 1.0e4, 1.0e5),
                                          "span_Pa": 3.0e7}},
        "seal_friction": {"seal_friction": {"stribeck_N": rng.uniform(150.0, 300.0),
                                            "stribeck_velocity_m_s": rng.uniform(3.0e-3, 8.0e-3),
                                            "viscous_Ns_per_m": rng.uniform(5.0, 20.0)}},
        "command_displacement": {"command_displacement": {"bandwidth_Hz": rng.uniform(3.0, 8.0),
                                                          "damping_ratio": rng.uniform(0.25, 0.6)}},
    }[family]
    offset = 0.0 if rng.uniform() < 1.0 / 3.0 else float(rng.choice((-1.0, 1.0)) * rng.uniform(30.0, 180.0))
    ch = tc.Channels(rate=float(rng.choice(RATES)), speeds=tc.ELEVEN_SPEEDS, force_sd=rng.uniform(8.0, 20.0),
                     displacement_sd=rng.uniform(0.2e-6, 0.5e-6), force_step=float(rng.choice((0.0, 2.0, 4.0))),
                     displacement_step=float(rng.choice((0.0, 0.5e-6, 1.0e-6))), offset=offset)
    if family == "poppet_valve":  # drawn last: the other draws of a case do not depend on it
        effects["poppet_valve"]["per_direction"] = int(rng.integers(2))
    return base, effects, ch


def judge(d: dict, effects: dict, ch: tc.Channels, j_truth: float) -> tuple[str, str]:
    """The confusion table's rule (``tests/test_confusion.py``) on one diagnosis: ``("pass" | "fail" | "below the
    floor", why)``. An injected effect that is not named while the selected model's J is within 1 / (1 - the loop's
    :data:`~bayesdamper.diagnosis.loop.MIN_J_REDUCTION`) of the true model's is "below the floor": even the whole
    truth would not lower J by the fifth the loop asks of an effect, so the draw made it too small to name."""
    from bayesdamper.diagnosis.loop import MIN_J_REDUCTION

    named = tc._families(d["selected"])
    allowed = {tc.TWO_STATE_FAMILY} | ({tc.OFFSET_FAMILY} if ch.offset else set())
    j_after, j_before = d["final"]["J_pooled"], d["baseline"]["J_pooled"]
    if not effects:
        if not named <= allowed:
            return "fail", f"control named {sorted(named - allowed)}"
    else:
        want = {tc.INJECTED[n] for n in effects}
        if not named <= want | allowed:
            return "fail", f"named {sorted(named - want - allowed)} besides"
        if not named & want:
            small = j_after <= j_truth / (1.0 - MIN_J_REDUCTION)
            return ("below the floor" if small else "fail"), f"{sorted(want)} not named"
        if j_after > 0.5 * j_before:
            return "fail", f"J after {j_after:.4f} > half of {j_before:.4f}"
    if j_after > 2.0 * j_truth:
        return "fail", f"J after {j_after:.4f} > 2x the truth's {j_truth:.4f}"
    return "pass", ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=10, help="cases to draw")
    ap.add_argument("--seed", type=int, default=2026, help="seed of the draws (and of each case's noise)")
    ap.add_argument("--out", default="/tmp/bayesdamper-random", help="folder for the data sets and diagnoses")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    out = Path(a.out)
    rows = []
    for k in range(a.n):
        base, effects, ch = draw(rng)
        family = next(iter(effects), "none")
        if effects.get("poppet_valve", {}).get("per_direction") == 1:
            family += "-per-direction"
        folder = out / f"case{k:02d}-{family}"
        shutil.rmtree(folder, ignore_errors=True)
        data, truth = tc._dataset(folder / "data", effects, 1.25, seed=a.seed * 1000 + k, base=base, ch=ch)
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "bayesdamper", "diagnose", str(data), "--out",
                               str(folder / "out"), "--workers", str(a.workers), "--no-figures"],
                              capture_output=True, text=True)
        wall = time.perf_counter() - t0
        drawn = {"base": {kk: float(f"{v:.4g}") for kk, v in base["two_state_damper"].items()},
                 "effects": {e: {kk: float(f"{v:.4g}") for kk, v in p.items()} for e, p in effects.items()},
                 "rate_Hz": ch.rate, "force_sd_N": round(ch.force_sd, 1),
                 "steps": [ch.force_step, ch.displacement_step], "offset_N": round(ch.offset, 1)}
        if proc.returncode != 0:
            print(f"case {k}: diagnose failed: {proc.stderr.strip().splitlines()[-1:]}", flush=True)
            rows.append({"family": family, "named": ["(failed)"], "verdict": "fail", "wall_s": wall})
            continue
        d = json.loads((folder / "out" / "diagnosis.json").read_text())
        j_truth = tc._j_truth(d, truth)
        verdict, why = judge(d, effects, ch, j_truth)
        row = {"case": k, "family": family, "drawn": drawn, "selected": d["selected"],
               "named": sorted(tc._families(d["selected"])), "J_before": round(d["baseline"]["J_pooled"], 5),
               "J_after": round(d["final"]["J_pooled"], 5), "J_truth": round(j_truth, 5), "verdict": verdict,
               "why": why, "wall_s": round(wall, 1)}
        rows.append(row)
        print("RANDOM-SET", json.dumps(row, default=str), flush=True)
    print("\ndrawn family -> named families: cases (verdicts)")
    table = Counter((r["family"], ", ".join(r["named"]) or "nothing") for r in rows)
    for (fam, named), n in sorted(table.items()):
        verdicts = Counter(r["verdict"] for r in rows
                           if r["family"] == fam and (", ".join(r["named"]) or "nothing") == named)
        print(f"  {fam:<22} -> {named:<40} {n} ({', '.join(f'{k} {v}' for k, v in sorted(verdicts.items()))})")
    walls = [r["wall_s"] for r in rows]
    total = Counter(r["verdict"] for r in rows)
    print(f"{', '.join(f'{k} {v}' for k, v in sorted(total.items()))} of {len(rows)}; cold diagnose wall "
          f"{min(walls):.0f}-{max(walls):.0f} s (median {float(np.median(walls)):.0f} s), {a.workers} workers")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
