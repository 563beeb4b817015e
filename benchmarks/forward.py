"""Forward-model benchmark: the compiled eq. (7) kernel against scipy on the same problems.

Problems: a 3 s transient sampled at 250 Hz, rig-A damper constants, the paper's flow coefficients,
piston speed 1 mm/s, every (α_V, p_R) of a grid across the prior box, and four transients each:
from rest in both directions (dp0 = 0) and after a reversal in both directions (dp0 = the static
plateau of the opposite direction, eq. (4), starting at ±5 mm stroke).

Measured:
  * the kernel's µs per solve at its default tolerances (after a warm-up compile; median of
    sweeps over all problems), and at looser rtol for reference,
  * ``scipy.integrate.solve_ivp(method="LSODA", rtol=1e-8)`` µs per solve (plain-Python right-hand
    side, knots as breakpoints: :func:`bayesdamper.physics.reference.reference_single_state`),
  * the worst relative L2 error of the kernel against ``Radau`` at ``rtol=1e-11``, ``atol=1e-9`` Pa.

Usage: ``python benchmarks/forward.py [--json] [--quick]``. With ``--json`` the last line is
``{"us_per_solve": .., "scipy_us_per_solve": .., "speedup": .., "rel_error": ..}``.
Targets: speedup >= 100 and rel_error <= 1e-4.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DynamicParameters
from bayesdamper.physics.orifice import pressure_drop
from bayesdamper.physics.reference import reference_single_state
from bayesdamper.physics.rodas import DEFAULT_ATOL, DEFAULT_RTOL
from bayesdamper.physics.single_state import solve_single_state

SAMPLE_RATE = 250.0  # [Hz]
WINDOW = 3.0  # [s]
SPEED = 1e-3  # [m/s]
STROKE_START = 5e-3  # [m], displacement at a reversal
ALPHAS = (3.0, 30.0, 300.0, 3000.0)
PRESSURES = (1e3, 1e5, 1e6, 1e7)
KERNEL_SWEEPS = 15  # timing sweeps over all problems; the median sweep is reported
SCIPY_RTOL, REF_RTOL, REF_ATOL = 1e-8, 1e-11, 1e-9
TOLERANCE_SWEEP = (1e-4, 1e-5, DEFAULT_RTOL)  # kernel rtol values timed; the JSON uses the default


def problems(quick: bool) -> list[dict]:
    """All benchmark problems: (α_V, p_R) grid x four transients."""
    area = RIG_A_DAMPER.piston_area
    q = area * SPEED
    cases = [
        ("rest +", 0.0, 0.0, +SPEED, 0.0),
        ("rest -", 0.0, 0.0, -SPEED, 0.0),
        ("rev +>-", STROKE_START, 0.0, -SPEED, float(pressure_drop(+q, PAPER_FLOW))),
        ("rev ->+", -STROKE_START, 0.0, +SPEED, float(pressure_drop(-q, PAPER_FLOW))),
    ]
    grid = [(a, p) for a in ALPHAS for p in PRESSURES]
    if quick:
        grid = [(3.0, 1e3), (30.0, 1e5), (3000.0, 1e7)]
    out = []
    for a, p in grid:
        for name, y0, t_step, v, dp0 in cases:
            knot_t = np.array([t_step, t_step + WINDOW])
            knot_y = np.array([y0, y0 + v * WINDOW])
            out.append(dict(case=name, alpha_v=a, p_r=p, knot_t=knot_t, knot_y=knot_y, dp0=dp0))
    return out


def kernel(t, pb, rtol=DEFAULT_RTOL, atol=DEFAULT_ATOL):
    d = RIG_A_DAMPER
    return solve_single_state(t, pb["knot_t"], pb["knot_y"], pb["dp0"], d.piston_area, d.chamber_volume_1,
                              d.chamber_volume_2, d.liquid_bulk_modulus, PAPER_FLOW.as_array(),
                              pb["alpha_v"], pb["p_r"], 0, 0.0, rtol, atol)


def scipy_solve(t, pb, method, rtol, atol):
    from bayesdamper.physics.excitation import PiecewiseLinear

    return reference_single_state(t, PiecewiseLinear(pb["knot_t"], pb["knot_y"]), RIG_A_DAMPER, PAPER_FLOW,
                                  DynamicParameters(pb["alpha_v"], pb["p_r"]), dp0=pb["dp0"], t0=0.0,
                                  method=method, rtol=rtol, atol=atol)


def time_kernel(t, pbs, rtol, atol) -> float:
    """Median over sweeps of the mean µs per solve."""
    sweeps = []
    for _ in range(KERNEL_SWEEPS):
        t0 = time.perf_counter()
        for pb in pbs:
            kernel(t, pb, rtol, atol)
        sweeps.append((time.perf_counter() - t0) / len(pbs) * 1e6)
    return float(np.median(sweeps))


def rel_l2(x, ref) -> float:
    return float(np.linalg.norm(x - ref) / np.linalg.norm(ref))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print a JSON summary as the last line")
    ap.add_argument("--quick", action="store_true", help="3 parameter pairs instead of 16")
    args = ap.parse_args()
    t = np.arange(int(round(WINDOW * SAMPLE_RATE)) + 1) / SAMPLE_RATE
    pbs = problems(args.quick)

    t0 = time.perf_counter()
    kernel(t, pbs[0])  # compile (or load the cache)
    compile_s = time.perf_counter() - t0

    rows = []
    scipy_total = 0.0
    refs = []
    for pb in pbs:
        dp, status, n_rhs = kernel(t, pb)
        if status != 0:
            raise SystemExit(f"kernel failed on {pb['case']} alpha_V={pb['alpha_v']} p_R={pb['p_r']}")
        t1 = time.perf_counter()
        lsoda = scipy_solve(t, pb, "LSODA", SCIPY_RTOL, 1e-6)
        scipy_total += time.perf_counter() - t1
        ref = scipy_solve(t, pb, "Radau", REF_RTOL, REF_ATOL)
        refs.append(ref)
        rows.append((pb, n_rhs, rel_l2(dp, ref), rel_l2(lsoda, ref)))
    scipy_us = scipy_total / len(pbs) * 1e6

    print(f"eq. (7) forward-model benchmark: {len(pbs)} problems, {t.size} samples, "
          f"compile/load {compile_s:.2f} s")
    print(f"kernel at rtol={DEFAULT_RTOL:g}, atol={DEFAULT_ATOL:g} Pa; errors vs Radau rtol={REF_RTOL:g}")
    print(f"{'case':8} {'alpha_V':>8} {'p_R [Pa]':>9} {'n_rhs':>6} {'rel L2 err':>10} {'LSODA err':>10}")
    for pb, n, e, es in rows:
        print(f"{pb['case']:8} {pb['alpha_v']:8.0f} {pb['p_r']:9.0e} {n:6d} {e:10.1e} {es:10.1e}")
    us = worst = None
    for rtol in TOLERANCE_SWEEP:
        errs = [rel_l2(kernel(t, pb, rtol, DEFAULT_ATOL)[0], ref) for pb, ref in zip(pbs, refs, strict=True)]
        us_r = time_kernel(t, pbs, rtol, DEFAULT_ATOL)
        tag = "  (default)" if rtol == DEFAULT_RTOL else ""
        print(f"kernel rtol={rtol:<6g}: {us_r:8.1f} us/solve, worst rel L2 error {max(errs):.1e}{tag}")
        if rtol == DEFAULT_RTOL:
            us, worst = us_r, max(errs)
    print(f"scipy LSODA rtol={SCIPY_RTOL:g}: {scipy_us:8.1f} us/solve, worst rel L2 error "
          f"{max(r[3] for r in rows):.1e}")
    print(f"speedup at default tolerances: {scipy_us / us:.0f}x (targets: >= 100x, rel error <= 1e-4)")
    if args.json:
        print(json.dumps({"us_per_solve": round(us, 2), "scipy_us_per_solve": round(scipy_us, 1),
                          "speedup": round(scipy_us / us, 1), "rel_error": float(f"{worst:.3e}")}))


if __name__ == "__main__":
    main()
