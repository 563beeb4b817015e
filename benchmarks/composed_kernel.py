"""Cost of one composed-kernel solve: µs per solve, accepted steps and µs per step, for the effect sets the diagnosis
solves most.

The problem is a search window of rig-A's kind: a reversal at 1 mm/s after a plateau, 3 s sampled at 250 Hz, rig-A's
damper constants and the paper's flow coefficients, at the search's tolerance
(:data:`bayesdamper.inference.problem.EFFECTS_RTOL`). Each effect set is solved once to compile and count its
steps, then timed over sweeps of repeated solves (the fastest sweep is reported: the others carry the machine's other
work). The wrapper's own cost (argument checks, read-only views, the dispatch into the compiled code) is the time of
a solve of two samples a tenth of a millisecond apart, which takes a single step.

    python benchmarks/composed_kernel.py [--solves 200] [--sweeps 7] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER
from bayesdamper.inference.problem import EFFECTS_ATOL, EFFECTS_RTOL
from bayesdamper.physics.compose import compose, solve_composed
from bayesdamper.physics.excitation import PiecewisePolynomial

#: A plateau at 10 mm, then the reversal at 1 mm/s; the window starts at the reversal.
KNOTS_T = np.array([0.0, 1.0137, 11.0137, 15.0137])
KNOTS_Y = np.array([0.0, 0.0, 1e-2, 6e-3])
T0 = float(KNOTS_T[2])
SAMPLES = T0 + np.arange(1, 751) / 250.0
#: Δp at the reversal [Pa] (the plateau's), the velocity before it [m/s], the window's (α_V, p_R).
DP0, V_PREV, ALPHA_V, P_R = 1.2e6, 1e-3, 40.0, 4e5

TWO_STATE = {"polytropic_exponent": 1.2, "refill_conductance_m3_per_s_Pa": 2e-11}
SETS = {
    "eq. (7) (no effect)": {},
    "series_compliance": {"series_compliance": None},
    "poppet_valve": {"poppet_valve": None},
    "two_state": {"two_state": TWO_STATE},
    "two_state + poppet_valve": {"two_state": TWO_STATE, "poppet_valve": None},
    "two_state + series_compliance": {"two_state": TWO_STATE, "series_compliance": None},
}


def measure(spec: dict, solves: int, sweeps: int) -> dict:
    composed = compose(spec)  # None: the effect's registry defaults
    drive = composed.transform_input(PiecewisePolynomial.from_knots(KNOTS_T, KNOTS_Y))
    flow = PAPER_FLOW.as_array()

    def solve(t_out, **kw):
        return solve_composed(composed, t_out, drive, T0, DP0, V_PREV, RIG_A_DAMPER, flow, ALPHA_V, P_R,
                              EFFECTS_RTOL, EFFECTS_ATOL, **kw)

    out = solve(SAMPLES, record=True)
    steps = None if out[2] is None else int(out[2].size)
    tiny = T0 + np.array([1e-4, 2e-4])  # the wrapper's cost: a solve of a single step

    def best(t_out, n):
        times = []
        for _ in range(sweeps):
            t = time.perf_counter()
            for _ in range(n):
                solve(t_out)
            times.append((time.perf_counter() - t) / n)
        return min(times) * 1e6

    us = best(SAMPLES, solves)
    wrapper = best(tiny, 10 * solves)
    return {"status": int(out[1]), "steps": steps, "us_per_solve": us, "wrapper_us": wrapper,
            "us_per_step": (us - wrapper) / steps if steps else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solves", type=int, default=200, help="solves per timing sweep")
    ap.add_argument("--sweeps", type=int, default=7, help="timing sweeps (the fastest is reported)")
    ap.add_argument("--json", action="store_true", help="also print the results as one JSON line")
    args = ap.parse_args()
    rows = {name: measure(spec, args.solves, args.sweeps) for name, spec in SETS.items()}
    print(f"composed kernel, {SAMPLES.size} samples at 250 Hz, rtol {EFFECTS_RTOL:g}, atol {EFFECTS_ATOL:g} Pa "
          f"(fastest of {args.sweeps} sweeps of {args.solves} solves)")
    print(f"  {'effects':32s} {'status':>6s} {'steps':>6s} {'us/solve':>9s} {'us/step':>8s} {'wrapper us':>11s}")
    for name, r in rows.items():
        steps = "-" if r["steps"] is None else str(r["steps"])
        per_step = "-" if r["us_per_step"] is None else f"{r['us_per_step']:.2f}"
        print(f"  {name:32s} {r['status']:6d} {steps:>6s} {r['us_per_solve']:9.1f} {per_step:>8s} "
              f"{r['wrapper_us']:11.1f}")
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
