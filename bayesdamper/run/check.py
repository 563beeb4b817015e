"""The ``check`` job: validate and segment a data set, print what was found, optionally fit stage 1.
Writes nothing.
"""

from __future__ import annotations

import time

from bayesdamper.inference.pointfit import fit_point
from bayesdamper.inference.problem import TransientProblem
from bayesdamper.run.stages import data_table, prepare


def run_check(data_dir: str, *, tmax: float = 3.0, fit: bool = True) -> None:
    """``bayesdamper check``: validate, segment, stage 1 and the Nelder-Mead stage 2; print tables."""
    t0 = time.perf_counter()
    ds, segs, transients, static = prepare(data_dir, tmax)
    print(f"data set {ds.name!r}: {len(ds.records)} test(s), {len(transients)} transient(s), "
          f"A_P = {ds.damper.piston_area:g} m^2, V01 = {ds.damper.chamber_volume_1:g} m^3, "
          f"V02 = {ds.damper.chamber_volume_2:g} m^3, B0 = {ds.damper.liquid_bulk_modulus:g} Pa")
    print()
    hdr = f"{'test':<16}{'step':>5}  {'kind':<9}{'dir':>4}{'v [mm/s]':>10}{'t_step [s]':>12}" \
          f"{'F_step [N]':>12}{'plateau F [N]':>15}"
    print(hdr)
    print("-" * len(hdr))
    for st in data_table(ds, segs)["steps"]:
        pf = f"{st['plateau_force_N']:15.1f}" if st["plateau_force_N"] is not None else f"{'-':>15}"
        print(f"{st['test']:<16}{st['index']:>5}  {st['kind']:<9}{st['direction']:>+4d}"
              f"{st['velocity_m_s'] * 1e3:10.3f}{st['t_step_s']:12.3f}{st['force_N']:12.1f}{pf}")
    print()
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
