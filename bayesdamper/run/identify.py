"""The ``identify`` job: load -> windows (and stage 1 where there are plateaus) -> the posterior of every window ->
outputs, for one or more data sets of any kind of record.

Each function validates everything it can *before* it writes anything, so a run that fails on bad
input leaves an existing output folder as it was. The output folder, its fingerprint and resume:
:mod:`bayesdamper.run.outfolder`.
"""

from __future__ import annotations

import os
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.inference.cut import COUPLINGS
from bayesdamper.inference.drift import drift_summary, record_drift
from bayesdamper.inference.likelihood import make_noise_model
from bayesdamper.inference.sampling import SamplerSettings
from bayesdamper.inference.stage2 import StageTwoSettings, WindowResult
from bayesdamper.run.outfolder import (
    _load_finished,
    check_output_folder,
    close_run,
    fingerprint_basis,
    open_run,
    settings_fingerprint,
)
from bayesdamper.run.plan import check_mode, plan_dataset
from bayesdamper.run.predict import CALIBRATION_FILE, write_calibration
from bayesdamper.run.progress import Progress, count_files
from bayesdamper.run.stages import data_table, identify_all


def _bounds(values, name: str) -> tuple[float, float] | None:
    if values is None:
        return None
    if len(values) != 2 or not (0 < values[0] < values[1]) or not np.all(np.isfinite(values)):
        raise SettingsError(f"{name}: expected LOW,HIGH with 0 < LOW < HIGH, got {values}")
    return (float(values[0]), float(values[1]))


def dataset_folder(name: str) -> str:
    """A file-name-safe folder name for a data set called ``name``."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "dataset"
    return safe


def dataset_folders(datasets) -> list[str]:
    """The output folder of each of several data sets: its name, or its folder's name where several share a name
    (one damper tested under several conditions). SettingsError when two would still share a folder."""
    names = [dataset_folder(ds.name) for ds in datasets]
    names = [dataset_folder(ds.path.name) if names.count(n) > 1 else n
             for ds, n in zip(datasets, names, strict=True)]
    for i, n in enumerate(names):
        if n in names[:i]:
            j = names.index(n)
            raise SettingsError(f"{datasets[j].path}, {datasets[i].path}: both data sets would be written to "
                                f"{n!r}; give them distinct [damper] names or folder names")
    return names


def window_temperatures(ds, windows) -> dict[str, float]:
    """Each window's mean measured temperature [°C] over its samples, where its record has a ``temperature_C``
    column."""
    records = {r.name: r for r in ds.records}
    out = {}
    for w in windows:
        rec = records.get(w.test)
        if rec is None or getattr(rec, "temperature", None) is None:
            continue
        inside = (rec.time >= w.time[0]) & (rec.time <= w.time[-1])
        if np.any(inside):
            out[w.id] = float(np.mean(rec.temperature[inside]))
    return out


@dataclass
class _Job:
    """One data set of an ``identify`` run: validated, nothing written yet."""

    ds: object
    segs: list
    transients: list
    static: object
    out_dir: Path
    basis: dict
    fingerprint: str
    plan: object = None


def _stage_two_settings(credible_mass, noise_model, alpha_v_prior, p_r_prior, max_steps,
                        propagate: bool = True, coupling: str = "cut") -> StageTwoSettings:
    make_noise_model(noise_model)  # validate before any work
    if coupling not in COUPLINGS:
        raise SettingsError(f"--coupling must be one of {', '.join(COUPLINGS)}, got {coupling!r}")
    if max_steps is not None and max_steps < 1:
        raise SettingsError(f"--max-steps must be a positive number of steps, got {max_steps}")
    sampler = SamplerSettings() if max_steps is None else SamplerSettings(max_steps=max_steps)
    kw = {}
    if (b := _bounds(alpha_v_prior, "--alpha-v-prior")) is not None:
        kw["alpha_v_bounds"] = b
    if (b := _bounds(p_r_prior, "--p-r-prior")) is not None:
        kw["p_r_bounds"] = b
    settings = StageTwoSettings(credible_mass=credible_mass, noise_model=noise_model, sampler=sampler,
                                propagate=propagate, coupling=coupling, **kw)
    settings.space()
    return settings


def _plan(data_dirs: list, out: str | Path, settings: StageTwoSettings, seed: int, tmax: float,
          only: str | None, force: bool, mode: str = "auto") -> list[_Job]:
    """Load, classify and window every data set (stage 1 where there are plateaus); check the output folders.
    Writes nothing."""
    plans = [plan_dataset(d, tmax, mode) for d in data_dirs]
    prepared = [(p.ds, p.segs, p.windows, p.static) for p in plans]
    if only:
        wanted = {s.strip() for s in only.split(",") if s.strip()}
        unknown = wanted - {t.id for p in prepared for t in p[2]}
        if unknown:
            raise SettingsError(f"--only: unknown window id(s) {', '.join(sorted(unknown))}")
        prepared = [(ds, segs, [t for t in trs if t.id in wanted], st) for ds, segs, trs, st in prepared]
    out_root = Path(out)
    if out_root.exists() and not out_root.is_dir():
        raise SettingsError(f"{out_root}: exists and is not a folder")
    outs = [out_root] if len(prepared) == 1 else [out_root / n for n in dataset_folders([p[0] for p in prepared])]
    jobs = []
    for (ds, segs, trs, static), out_dir, p in zip(prepared, outs, plans, strict=True):
        if not trs:
            continue
        basis = fingerprint_basis({**settings.as_dict(), "mode": p.mode}, tmax, seed, ds.sha256)
        check_output_folder(out_dir, basis, force)
        jobs.append(_Job(ds, segs, trs, static, out_dir, basis, settings_fingerprint(basis), p))
    if not jobs:
        raise SettingsError("no window to identify")
    for p in plans:  # only once every input is valid: a bad run prints one line
        print(f"{p.ds.name}: {p.mode_reason}", file=sys.stderr, flush=True)
    return jobs


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _identify_one(job: _Job, settings: StageTwoSettings, *, seed: int, credible_mass: float, tmax: float,
                  workers: int, figures: bool, force: bool, client, scheduler: str | None,
                  progress: Progress) -> dict:
    """The posteriors and the outputs of one validated data set (the only step that writes)."""
    t0 = time.perf_counter()
    ds, out_dir, static = job.ds, job.out_dir, job.static
    post_dir, prov, run = open_run(job, settings, seed=seed, workers=workers, force=force, progress=progress,
                                   started_utc=_now(), mode=job.plan.mode, prov_extra={"tmax_s": tmax},
                                   run_extra={"tmax_s": tmax, "scheduler": scheduler,
                                              "windows": [t.id for t in job.transients]})

    results: list[WindowResult | None] = [
        _load_finished(post_dir / f"{tr.id}.nc", tr, job.fingerprint) for tr in job.transients]
    resumed = [tr.id for tr, r in zip(job.transients, results, strict=True) if r is not None]
    if resumed:
        print(f"resumed {len(resumed)} finished window(s) from {post_dir}", file=sys.stderr, flush=True)
    todo = [i for i, r in enumerate(results) if r is None]
    progress(f"sampling {len(todo)} window(s) on "
             + (f"the cluster at {scheduler}" if client is not None else f"{workers} worker(s)"))
    from bayesdamper.inference.joint import StageOnePrior, plateau_noise
    from bayesdamper.inference.stage2 import N_STATIC_DRAWS, STATIC_NEGLIGIBLE_RATIO

    prior = None
    draws = None
    flow = static.coefficients if static is not None else None
    if static is not None and settings.propagate:
        noise = plateau_noise(job.segs)
        prior = StageOnePrior.from_fit(static, noise)
        progress(f"plateau noise: AR(1) φ {noise.phi:.3f}, σ {noise.sigma:.1f} N "
                 f"({noise.n_plateaus} plateaus, {noise.n_samples} samples)")
    elif static is not None:
        draws = static.sample(N_STATIC_DRAWS, np.random.default_rng(seed))
    with progress.phase(f"posteriors ({ds.name})", total=len(todo), unit="window"):
        fresh = identify_all([job.transients[i] for i in todo], ds.damper, flow, settings, seed, workers, post_dir,
                             prov, progress, draws, client=client, prior=prior)
        progress.note(f"{sum(r.entry['converged'] for r in fresh)} converged"
                      + (f", {len(resumed)} resumed" if resumed else ""))
    for i, r in zip(todo, fresh, strict=True):
        results[i] = r
    entries = [r.entry for r in results]
    summary = {
        "dataset": ds.name, "out_folder": out_dir.name, "condition": dict(ds.condition),
        "mode": job.plan.mode, "mode_reason": job.plan.mode_reason,
        "credible_mass": credible_mass, "plan": job.plan.as_dict(),
        "static": static.intervals(credible_mass) if static is not None else None,
        "static_constrained": static.constrained if static is not None else [],
        "static_offset_N": (dict(zip(("value", "se"), static.offset_force(ds.damper.piston_area), strict=True))
                            if static is not None and static.offset is not None else None),
        "segments": entries,
        "drift": drift_summary(entries, credible_mass, seed) if len(entries) >= 3 else {},
        "drift_within_records": record_drift(entries, window_temperatures(ds, job.transients), credible_mass, seed),
        "settings": settings.as_dict(), "seed": seed, "tmax_s": tmax, "provenance": prov,
        "n_converged": int(sum(e["converged"] for e in entries)),
        "data": data_table(ds, job.segs),
    }
    if prior is not None:
        summary["noise"] = prior.noise.as_dict()
        summary["static_uncertainty"] = {
            "method": ("propagated as a cut: the step's Δp (samples before the step) and the four flow "
                       "coefficients (stage 1, moment-matched Student-t per direction) keep their own posteriors "
                       "and move α_V, p_R along the window optimum's sensitivity"
                       if settings.coupling == "cut" else
                       "propagated jointly: the four flow coefficients are sampled in every window's posterior "
                       "under the stage-1 posterior (Student-t per direction) as prior, with the step's Δp"),
            "coupling": settings.coupling, "propagated": True}
    elif static is not None:
        ratios = np.array([[e["static_sensitivity"]["ratio"][k] for k in ("alpha_V", "p_R_Pa")]
                           for e in entries])
        summary["static_uncertainty"] = {
            "method": f"optimum re-fitted under {N_STATIC_DRAWS} draws of the stage-1 coefficients; ratio = "
                      "sd of the optima / posterior sd (log parameters)",
            "max_ratio": {"alpha_V": float(np.nanmax(ratios[:, 0])),
                          "p_R_Pa": float(np.nanmax(ratios[:, 1]))},
            "median_ratio": {"alpha_V": float(np.nanmedian(ratios[:, 0])),
                             "p_R_Pa": float(np.nanmedian(ratios[:, 1]))},
            "threshold": STATIC_NEGLIGIBLE_RATIO,
            "negligible": bool(all(e["static_sensitivity"]["negligible"] for e in entries)),
            "propagated": False}
    else:
        summary["static_uncertainty"] = {
            "method": "no plateaus: the flow coefficients are sampled in every window with α_V, p_R and the start's "
                      "Δp (flat prior); the noise of each window is estimated from its least-squares residual "
                      "away from the excitation's band and harmonics", "propagated": True, "coupling": "joint"}
    _, summary["drift_model"] = write_calibration(out_dir / CALIBRATION_FILE, results, ds.damper, None, seed=seed,
                                               credible_mass=credible_mass, provenance=prov, progress=progress,
                                               records=ds.records)
    if figures:
        from bayesdamper.report.figures import write_identify_figures

        with progress.phase(f"figures ({ds.name})", unit="file") as ph:
            summary["figures"] = write_identify_figures(out_dir, ds, job.segs, static, results, summary,
                                                        workers=workers, windows=job.transients)
            ph.done = count_files(summary["figures"])
    close_run(out_dir, summary, run, wall=time.perf_counter() - t0, finished_utc=_now(), resumed=resumed,
              computed=[job.transients[i].id for i in todo], units="window(s)")
    return summary


def run_identify(data_dir: str | os.PathLike | Sequence[str | os.PathLike], out: str, *, seed: int = 0,
                 credible_mass: float = 0.9, tmax: float = 3.0, workers: int = 0, noise_model: str = "plateau",
                 alpha_v_prior=None, p_r_prior=None, max_steps: int | None = None, only: str | None = None,
                 figures: bool = True, force: bool = False,
                 scheduler: str | None = None, mode: str = "auto", propagate: bool = True,
                 coupling: str = "cut") -> dict | list[dict]:
    """``bayesdamper identify``: stage 1 and Bayesian stage 2 for every transient; write OUT.

    Parameters
    ----------
    data_dir : path or sequence of paths
        One data-set folder (results go into ``out``) or several (each into ``out/<data-set name>``).
    out : str
        Output folder. If it already holds results of the same settings (fingerprint of the stage-2
        settings, ``tmax``, ``seed`` and the input files), finished transients are resumed; of
        different settings, SettingsError unless ``force``, which clears the old results first.
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``) to run the transients on instead of
        ``workers`` local processes.
    mode : str
        ``"auto"`` (two-stage when every record is a triangular test, else whole-record), or forced
        ``"two-stage"`` / ``"whole-record"`` (:mod:`bayesdamper.run.plan`).

    Returns
    -------
    dict or list of dict
        The summary (``summary.json``) of a single ``data_dir`` path; a list of them, in order, for a
        sequence.

    Raises
    ------
    DataError, SettingsError
        Before anything is written, for any bad input, setting or output folder.
    """
    single = isinstance(data_dir, str | os.PathLike)
    dirs = [data_dir] if single else list(data_dir)
    if not dirs:
        raise SettingsError("no data-set folder given")
    settings = _stage_two_settings(credible_mass, noise_model, alpha_v_prior, p_r_prior, max_steps, propagate,
                                   coupling)
    progress = Progress()
    check_mode(mode)
    with progress.phase("load, classify, windows, stage 1", unit="data set") as ph:
        jobs = _plan(dirs, out, settings, seed, tmax, only, force, mode)
        ph.done = len(jobs)
        ph.note = ", ".join(f"{len(j.transients)} windows" for j in jobs)
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    client = None
    if scheduler:
        from bayesdamper.run.distributed import connect

        client = connect(scheduler)
    try:
        summaries = [_identify_one(job, settings, seed=seed, credible_mass=credible_mass, tmax=tmax,
                                   workers=workers, figures=figures, force=force, client=client,
                                   scheduler=scheduler, progress=progress) for job in jobs]
    finally:
        if client is not None:
            client.close()
    return summaries[0] if single else summaries


def identify_out_dir(out: str | Path, summary: dict, n_datasets: int) -> Path:
    """The folder :func:`run_identify` wrote ``summary`` into."""
    return Path(out) if n_datasets == 1 else Path(out) / summary.get("out_folder", dataset_folder(summary["dataset"]))
