"""The commands' workflows: load -> segment -> stage 1 -> stage 2 -> outputs.

Each function validates everything it can *before* it writes anything, so a run that fails on bad
input leaves an existing output folder as it was.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .data import load_dataset
from .drift import fit_drift
from .errors import SettingsError
from .identify import StageTwoSettings, TransientResult, identify_transient
from .likelihood import make_noise_model
from .outputs import atomic_write_json, versions
from .pointfit import fit_point
from .problem import TransientProblem
from .sampling import SamplerSettings
from .segmentation import segment_dataset
from .static import fit_static


class Progress:
    """One-line progress messages on stderr, only when stderr is a terminal."""

    def __init__(self, enabled: bool | None = None):
        self.enabled = sys.stderr.isatty() if enabled is None else enabled

    def __call__(self, msg: str) -> None:
        if self.enabled:
            print(msg, file=sys.stderr, flush=True)


def prepare(data_dir: str | Path, tmax: float):
    """Load, validate and segment a data set; fit stage 1. Raises DataError on bad input."""
    ds = load_dataset(data_dir, tmax=tmax)
    segs = segment_dataset(ds, tmax=tmax)
    transients = [t for s in segs for t in s.transients]
    plateaus = [p for s in segs for p in s.plateaus]
    static = fit_static(plateaus, source=str(ds.path))
    return ds, segs, transients, static


def run_check(data_dir: str, *, tmax: float = 3.0, fit: bool = True) -> None:
    """``bayesdamper check``: validate, segment, stage 1 and the Nelder-Mead stage 2; print tables."""
    t0 = time.perf_counter()
    ds, segs, transients, static = prepare(data_dir, tmax)
    print(f"data set {ds.name!r}: {len(ds.records)} test(s), {len(transients)} transient(s), "
          f"A_P = {ds.damper.piston_area:g} m^2, V01 = {ds.damper.chamber_volume_1:g} m^3, "
          f"V02 = {ds.damper.chamber_volume_2:g} m^3, B0 = {ds.damper.liquid_bulk_modulus:g} Pa")
    print()
    plateau = {(p.test, p.index): p for s in segs for p in s.plateaus}
    hdr = f"{'test':<16}{'step':>5}  {'kind':<9}{'dir':>4}{'v [mm/s]':>10}{'t_step [s]':>12}" \
          f"{'F_step [N]':>12}{'plateau F [N]':>15}"
    print(hdr)
    print("-" * len(hdr))
    for s in segs:
        for st in s.steps:
            p = plateau.get((s.record.name, st.index))
            pf = f"{np.sign(st.direction) * p.pressure_drop * ds.damper.piston_area:15.1f}" if p else f"{'-':>15}"
            print(f"{s.record.name:<16}{st.index:>5}  {st.kind:<9}{st.direction:>+4d}"
                  f"{abs(st.velocity_after) * 1e3:10.3f}{st.time:12.3f}{st.force:12.1f}{pf}")
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
        print(f"  {'transient':<22}{'kind':<9}{'dir':>4}{'v [mm/s]':>10}{'alpha_V':>11}{'p_R [Pa]':>12}{'J':>9}")
        flow = static.coefficients
        for tr in transients:
            pf = fit_point(TransientProblem.from_transient(tr, ds.damper, flow))
            print(f"  {tr.id:<22}{tr.kind:<9}{tr.direction:>+4d}{tr.velocity * 1e3:10.3f}"
                  f"{pf.alpha_v:11.2f}{pf.p_r:12.4g}{pf.cost:9.4f}")
    print(f"\nchecked in {time.perf_counter() - t0:.1f} s")


def _bounds(values, name: str) -> tuple[float, float] | None:
    if values is None:
        return None
    if len(values) != 2 or not (0 < values[0] < values[1]) or not np.all(np.isfinite(values)):
        raise SettingsError(f"{name}: expected LOW,HIGH with 0 < LOW < HIGH, got {values}")
    return (float(values[0]), float(values[1]))


def _worker(args) -> TransientResult:
    tr, damper, flow, settings, seed, nc, prov, draws = args
    return identify_transient(tr, damper, flow, settings, seed, nc, prov, static_draws=draws)


def _pool(workers: int):
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    return ProcessPoolExecutor(max_workers=workers, mp_context=ctx)


def identify_all(transients, damper, flow, settings: StageTwoSettings, seed: int, workers: int,
                 posterior_dir: Path | None, provenance: dict, progress: Progress,
                 static_draws: np.ndarray | None = None) -> list[TransientResult]:
    """Stage 2 for every transient, on ``workers`` processes; results in input order.

    ``static_draws`` (rows of [C_L12, C_Q12, C_L21, C_Q21] from stage 1) switch on the check of how
    much the stage-1 uncertainty moves each transient's optimum.
    """
    tasks = [(tr, damper, flow, settings, seed,
              None if posterior_dir is None else posterior_dir / f"{tr.id}.nc", provenance, static_draws)
             for tr in transients]
    results: list[TransientResult | None] = [None] * len(tasks)

    def report(i: int, res: TransientResult, done: int) -> None:
        e = res.entry
        state = "converged" if e["converged"] else "NOT converged"
        progress(f"[{done}/{len(tasks)}] {e['id']}: {state}, R-hat {e['rhat_max']:.3f}, "
                 f"ESS {e['ess_bulk_min']:.0f}, τ_max {max(e['tau'].values()):.0f}, {e['wall_s']:.1f} s")

    if workers <= 1 or len(tasks) == 1:
        for i, task in enumerate(tasks):
            progress(f"sampling {task[0].id} ...")
            results[i] = _worker(task)
            report(i, results[i], i + 1)
    else:
        with _pool(workers) as ex:
            futs = {ex.submit(_worker, task): i for i, task in enumerate(tasks)}
            from concurrent.futures import as_completed

            for done, fut in enumerate(as_completed(futs), 1):
                i = futs[fut]
                results[i] = fut.result()
                report(i, results[i], done)
    return results  # type: ignore[return-value]


def drift_summary(entries: list[dict], credible_mass: float, seed: int) -> dict:
    """Slope of α_V and p_R against piston speed for all transients (and per direction)."""
    out = {}
    ok = [e for e in entries if e["converged"]] or entries
    for name in ("alpha_V", "p_R_Pa"):
        v = np.array([e["velocity_m_s"] for e in ok])
        m = np.array([e["posterior_mean"][name] for e in ok])
        s = np.array([e["posterior_sd"][name] for e in ok])
        res = fit_drift(v, m, s, credible_mass, seed)
        res["by_direction"] = {}
        for d in (1, -1):
            sel = np.array([e["direction"] == d for e in ok])
            if sel.sum() >= 3 and np.ptp(v[sel]) > 0:
                res["by_direction"][str(d)] = fit_drift(v[sel], m[sel], s[sel], credible_mass, seed)
        res["n_transients"] = int(len(ok))
        out[name] = res
    return out


def run_identify(data_dir: str, out: str, *, seed: int = 0, credible_mass: float = 0.9, tmax: float = 3.0,
                 workers: int = 0, noise_model: str = "ar1", alpha_v_prior=None, p_r_prior=None,
                 max_steps: int | None = None, only: str | None = None, figures: bool = True) -> dict:
    """``bayesdamper identify``: stage 1 and Bayesian stage 2 for every transient; write OUT."""
    t0 = time.perf_counter()
    make_noise_model(noise_model)  # validate before any work
    sampler = SamplerSettings() if max_steps is None else SamplerSettings(max_steps=max_steps)
    kw = {}
    if (b := _bounds(alpha_v_prior, "--alpha-v-prior")) is not None:
        kw["alpha_v_bounds"] = b
    if (b := _bounds(p_r_prior, "--p-r-prior")) is not None:
        kw["p_r_bounds"] = b
    settings = StageTwoSettings(credible_mass=credible_mass, noise_model=noise_model, sampler=sampler, **kw)
    settings.space()
    ds, segs, transients, static = prepare(data_dir, tmax)
    if only:
        wanted = {s.strip() for s in only.split(",") if s.strip()}
        unknown = wanted - {t.id for t in transients}
        if unknown:
            raise SettingsError(f"--only: unknown segment id(s) {', '.join(sorted(unknown))}")
        transients = [t for t in transients if t.id in wanted]
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    post_dir = out_dir / "posteriors"
    post_dir.mkdir(exist_ok=True)
    progress = Progress()
    prov = {"dataset": ds.name, "dataset_path": str(ds.path), "input_sha256": ds.input_hashes(),
            "dataset_sha256": ds.sha256, "versions": versions(), "tmax_s": tmax, "run_seed": seed}
    progress(f"stage 1 done; sampling {len(transients)} transient(s) on {workers} worker(s)")
    from .identify import N_STATIC_DRAWS, STATIC_NEGLIGIBLE_RATIO

    draws = static.sample(N_STATIC_DRAWS, np.random.default_rng(seed))
    results = identify_all(transients, ds.damper, static.coefficients, settings, seed, workers, post_dir,
                           prov, progress, draws)
    entries = [r.entry for r in results]
    ratios = np.array([[e["static_sensitivity"]["ratio"][k] for k in ("alpha_V", "p_R_Pa")] for e in entries])
    summary = {
        "dataset": ds.name, "credible_mass": credible_mass,
        "static": static.intervals(credible_mass),
        "segments": entries,
        "drift": drift_summary(entries, credible_mass, seed) if len(entries) >= 3 else {},
        "settings": settings.as_dict(), "seed": seed, "tmax_s": tmax, "provenance": prov,
        "n_converged": int(sum(e["converged"] for e in entries)),
        "static_uncertainty": {
            "method": f"optimum re-fitted under {N_STATIC_DRAWS} draws of the stage-1 coefficients; ratio = "
                      "sd of the optima / posterior sd (log parameters)",
            "max_ratio": {"alpha_V": float(np.nanmax(ratios[:, 0])), "p_R_Pa": float(np.nanmax(ratios[:, 1]))},
            "median_ratio": {"alpha_V": float(np.nanmedian(ratios[:, 0])),
                             "p_R_Pa": float(np.nanmedian(ratios[:, 1]))},
            "threshold": STATIC_NEGLIGIBLE_RATIO,
            "negligible": bool(all(e["static_sensitivity"]["negligible"] for e in entries)),
        },
    }
    if figures:
        from .figures import write_identify_figures

        summary["figures"] = write_identify_figures(out_dir, ds, segs, static, results, summary)
    wall = time.perf_counter() - t0
    summary["wall_time_s"] = wall
    atomic_write_json(out_dir / "summary.json", summary)
    n_ok = summary["n_converged"]
    print(f"identified {len(entries)} transient(s) of {ds.name!r}: {n_ok} converged, "
          f"{len(entries) - n_ok} not; results in {out_dir}; wall time {wall:.1f} s")
    return summary
