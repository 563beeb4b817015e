"""The ``check`` job: validate and segment a data set, print what was found, optionally fit stage 1.
Writes nothing.
"""

from __future__ import annotations

import time

from bayesdamper.inference.pointfit import fit_point
from bayesdamper.inference.problem import TransientProblem
from bayesdamper.run.plan import TWO_STAGE, plan_dataset
from bayesdamper.run.stages import data_table


def run_check(data_dir: str, *, tmax: float = 3.0, fit: bool = True, mode: str = "auto") -> None:
    """``bayesdamper check``: validate, classify each record, then segment, stage 1 and the Nelder-Mead
    stage 2 (two-stage mode) or the whole-record least-squares fit; print tables."""
    t0 = time.perf_counter()
    plan = plan_dataset(data_dir, tmax, mode)
    ds = plan.ds
    print(f"data set {ds.name!r}: {len(ds.records)} test(s), A_P = {ds.damper.piston_area:g} m^2, "
          f"V01 = {ds.damper.chamber_volume_1:g} m^3, V02 = {ds.damper.chamber_volume_2:g} m^3, "
          f"B0 = {ds.damper.liquid_bulk_modulus:g} Pa")
    print(f"mode: {plan.mode} ({plan.mode_reason})")
    for line in plan.describe():
        print(f"  {line}")
    print()
    if plan.mode != TWO_STAGE:
        _check_whole(plan, fit)
        print(f"\nchecked in {time.perf_counter() - t0:.1f} s")
        return
    segs, transients, static = plan.segs, plan.transients, plan.static
    print(f"{len(transients)} transient(s)")
    hdr = f"{'test':<16}{'step':>5}  {'kind':<9}{'dir':>4}{'v [mm/s]':>10}{'t_step [s]':>12}" \
          f"{'F_step [N]':>12}{'plateau F [N]':>15}"
    print(hdr)
    print("-" * len(hdr))
    for st in data_table(ds, segs)["steps"]:
        pf = f"{st['plateau_force_N']:15.1f}" if st["plateau_force_N"] is not None else f"{'-':>15}"
        if st["plateau_force_N"] is not None and not st.get("plateau_in_stage1", True):
            pf += "  drifting: not in stage 1"
        print(f"{st['test']:<16}{st['index']:>5}  {st['kind']:<9}{st['direction']:>+4d}"
              f"{st['velocity_m_s'] * 1e3:10.3f}{st['t_step_s']:12.3f}{st['force_N']:12.1f}{pf}")
    print()
    if any(st["plateau_force_N"] is not None and not st.get("plateau_in_stage1", True)
           for st in data_table(ds, segs)["steps"]):
        print("a plateau whose force still drifts (linear trend |t| > 3) is not a point of eq. (4): stage 1 "
              "leaves it out")
    print("stage 1, eq. (4) per direction (least squares, ±1 standard error):")
    for f, lab in ((static.forward, "12"), (static.backward, "21")):
        se = f.standard_errors
        print(f"  C_L{lab} = {f.laminar:.4e} ± {se[0]:.1e} kg m^-4 s^-1   "
              f"C_Q{lab} = {f.quadratic:.4e} ± {se[1]:.1e} kg m^-7   "
              f"(n = {f.n}, residual sd {f.residual_std:.3g} Pa)")
    if fit:
        print()
        print("stage 2, Nelder-Mead on eq. (9) (the paper's point estimate):")
        print(f"  {'transient':<22}{'kind':<9}{'dir':>4}{'v [mm/s]':>10}{'alpha_V':>11}{'p_R [Pa]':>12}"
              f"{'J':>9}")
        flow = static.coefficients
        for tr in transients:
            pf = fit_point(TransientProblem.from_transient(tr, ds.damper, flow))
            print(f"  {tr.id:<22}{tr.kind:<9}{tr.direction:>+4d}{tr.velocity * 1e3:10.3f}"
                  f"{pf.alpha_v:11.2f}{pf.p_r:12.4g}{pf.cost:9.4f}")
    print(f"\nchecked in {time.perf_counter() - t0:.1f} s")


def _check_whole(plan, fit: bool) -> None:
    """The whole-record part of ``check``: the decimation of each record and its least-squares fit."""
    import numpy as np

    from bayesdamper.inference.whole import WholeLogPosterior, WholeRecordProblem, WholeSpace, static_scales
    from bayesdamper.inference.whole_stage import point_fit, quasi_static_start

    print(f"{'record':<22}{'samples':>8}{'decim.':>7}{'rate [Hz]':>10}")
    for w in plan.windows:
        print(f"{w.id:<22}{w.time.size:>8}{w.decimation:>7}{w.rate_hz:>10.1f}")
    if not fit:
        return
    print()
    print("whole-record least squares on eq. (9) (all parameters at once):")
    print(f"  {'record':<22}{'C_L12':>11}{'C_Q12':>11}{'C_L21':>11}{'C_Q21':>11}{'alpha_V':>9}{'p_R [Pa]':>11}"
          f"{'J':>8}")
    for w in plan.windows:
        prob = WholeRecordProblem(w, plan.ds.damper)
        ws = WholeSpace.build(static_scales(w, plan.ds.damper.piston_area), float(np.max(np.abs(w.force))))
        lp = WholeLogPosterior(prob, ws)
        flow4, off = quasi_static_start(prob, False)
        x, j = point_fit(lp, off, flow4)
        print(f"  {w.id:<22}" + "".join(f"{v:11.3e}" for v in x[:4]) + f"{np.exp(x[4]):9.1f}{np.exp(x[5]):11.4g}"
              f"{j:8.4f}")
