"""The ``check`` job: validate and segment a data set, print what was found, optionally fit stage 1.
Writes nothing.
"""

from __future__ import annotations

import time

from bayesdamper.inference.pointfit import fit_point
from bayesdamper.inference.problem import WindowProblem
from bayesdamper.run.plan import plan_dataset
from bayesdamper.run.stages import data_table


def run_check(data_dir: str, *, tmax: float = 3.0, fit: bool = True, mode: str = "auto") -> None:
    """``bayesdamper check``: validate, classify and window each record; print the segmentation and stage 1 of the
    triangular tests and the windows of the others, and (``fit``) a least-squares fit of every window; print
    tables."""
    t0 = time.perf_counter()
    plan = plan_dataset(data_dir, tmax, mode)
    ds = plan.ds
    print(f"data set {ds.name!r}: {len(ds.records)} test(s), A_P = {ds.damper.piston_area:g} m^2, "
          f"V01 = {ds.damper.chamber_volume_1:g} m^3, V02 = {ds.damper.chamber_volume_2:g} m^3, "
          f"B0 = {ds.damper.liquid_bulk_modulus:g} Pa")
    print(f"plan: {plan.mode_reason}")
    for line in plan.describe():
        print(f"  {line}")
    print()
    cycles = [w for w in plan.windows if w.kind == "cycles"]
    if cycles:
        _check_cycles(plan, cycles, fit)
    if plan.static is None:
        print(f"\nchecked in {time.perf_counter() - t0:.1f} s")
        return
    segs, static = plan.segs, plan.static
    transients = [w for w in plan.windows if w.kind != "cycles"]
    print(f"{len(transients)} transient(s)")
    hdr = f"{'test':<16}{'step':>5}  {'kind':<9}{'dir':>4}{'v [mm/s]':>10}{'t_step [s]':>12}" \
          f"{'window [s]':>12}{'F_step [N]':>12}{'plateau F [N]':>15}"
    print(hdr)
    print("-" * len(hdr))
    for st in data_table(ds, segs)["steps"]:
        pf = f"{st['plateau_force_N']:15.1f}" if st["plateau_force_N"] is not None else f"{'-':>15}"
        if st["plateau_force_N"] is not None and not st.get("plateau_in_stage1", True):
            pf += "  drifting: not in stage 1"
        elif st.get("plateau_approach_tau_s") is not None:
            pf += f"  approached (τ {st['plateau_approach_tau_s']:.2f} s): settled force extrapolated"
        print(f"{st['test']:<16}{st['index']:>5}  {st['kind']:<9}{st['direction']:>+4d}"
              f"{st['velocity_m_s'] * 1e3:10.3f}{st['t_step_s']:12.3f}{st['window_s']:12.3f}{st['force_N']:12.1f}{pf}")
    print()
    if any(st["plateau_force_N"] is not None and (not st.get("plateau_in_stage1", True)
                                                  or st.get("plateau_approach_tau_s") is not None)
           for st in data_table(ds, segs)["steps"]):
        print("a plateau whose force still drifts (linear trend |t| > 3) is not a point of eq. (4) by its mean: "
              "stage 1 takes the settled force an exponential approach fitted to it extrapolates to, or leaves it "
              "out where that approach is no faster than the plateau's length or leaves a trend")
    print("stage 1, eq. (4) per direction (least squares, ±1 standard error):")
    if static.constrained:
        print(f"  held at 0 (the plateaus made them negative: an unzeroed load cell or a saturating force?): "
              f"{', '.join(static.constrained)}")
    offset = static.offset_force(ds.damper.piston_area)
    if offset is not None:
        coefs = ", ".join(f"{n} = {c:.4e}" for n, c in zip(("C_L12", "C_Q12", "C_L21", "C_Q21"),
                                                             static.offset.coefficients, strict=True))
        print(f"  explained by a constant force offset F_0 = {offset[0]:.1f} ± {offset[1]:.1f} N (an unzeroed load "
              f"cell?); with it, eq. (4) gives\n    {coefs} (all positive);\n    reported, not applied: the "
              "coefficients below are eq. (4)'s alone; diagnose tests the offset (load_cell_offset)")
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
            pf = fit_point(WindowProblem.from_window(tr, ds.damper, flow))
            print(f"  {tr.id:<22}{tr.kind:<9}{tr.direction:>+4d}{tr.velocity * 1e3:10.3f}"
                  f"{pf.alpha_v:11.2f}{pf.p_r:12.4g}{pf.cost:9.4f}")
    print(f"\nchecked in {time.perf_counter() - t0:.1f} s")


def _check_cycles(plan, windows, fit: bool) -> None:
    """The windows of whole cycles: their span and input, and (``fit``) each one's least-squares fit of every
    parameter (flow coefficients included where the data set has no plateaus)."""
    import numpy as np

    print(f"{len(windows)} window(s) of whole cycles")
    print(f"{'window':<24}{'t [s]':>16}{'cycles':>8}{'samples':>9}{'v_peak [mm/s]':>15}{'input noise [um]':>18}")
    for w in windows:
        inp = w.info.get("input") or {}
        print(f"{w.id:<24}{w.t_step:8.2f}-{w.time[-1]:<7.2f}{w.info.get('cycles', float('nan')):8.2f}"
              f"{w.time.size:9d}{w.velocity * 1e3:15.3f}{inp.get('noise_sd_m', float('nan')) * 1e6:18.2f}")
    if not fit:
        return
    from bayesdamper.inference.joint import JointProblem, StageOnePrior
    from bayesdamper.inference.plateau_noise import PlateauNoise
    from bayesdamper.inference.start import least_squares_start

    print()
    print("least squares on eq. (9), every parameter of each window:")
    print(f"  {'window':<24}{'C_L12':>11}{'C_Q12':>11}{'C_L21':>11}{'C_Q21':>11}{'alpha_V':>9}{'p_R [Pa]':>11}"
          f"{'J':>8}")
    for w in windows:
        jp = JointProblem.from_window(w, plan.ds.damper, StageOnePrior.flat(PlateauNoise(0.0, 1.0, 1, 0)))
        x, j, _ = least_squares_start(jp, jp.space())
        print(f"  {w.id:<24}" + "".join(f"{v:11.3e}" for v in x[3:7]) + f"{np.exp(x[0]):9.1f}{np.exp(x[1]):11.4g}"
              f"{j:8.4f}")
    print()
