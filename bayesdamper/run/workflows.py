"""The commands' workflows: load -> segment -> stage 1 -> stage 2 -> outputs -> report.

Each function validates everything it can *before* it writes anything, so a run that fails on bad
input leaves an existing output folder as it was.

An ``identify`` output folder holds ``run.json`` (the settings fingerprint and provenance),
``summary.json``, ``posteriors/<id>.nc`` and ``figures/``. Runs are resumable: a transient whose
posterior file exists and carries the same settings fingerprint is read back, not re-sampled, and its
file is not rewritten. A folder holding results of other settings is refused unless ``force`` is set.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import re
import shutil
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from bayesdamper.core.errors import SettingsError
from bayesdamper.inference.drift import fit_drift
from bayesdamper.inference.likelihood import LogPosterior, make_noise_model
from bayesdamper.inference.pointfit import fit_point
from bayesdamper.inference.problem import TransientProblem
from bayesdamper.inference.sampling import SamplerSettings
from bayesdamper.inference.stage1 import fit_static
from bayesdamper.inference.stage2 import StageTwoSettings, TransientResult, identify_transient
from bayesdamper.io.dataset import load_dataset
from bayesdamper.io.outputs import atomic_write_json, versions
from bayesdamper.io.segmentation import segment_dataset
from bayesdamper.report.figures import FIGURES_DIR
from bayesdamper.report.html import REPORT_FILE

#: Files and folders an ``identify`` run owns inside its output folder (``--force`` clears them).
RUN_FILE = "run.json"
SUMMARY_FILE = "summary.json"
POSTERIORS_DIR = "posteriors"
OWNED = (POSTERIORS_DIR, FIGURES_DIR, SUMMARY_FILE, RUN_FILE, REPORT_FILE)
#: Name of a temporary file of the atomic writers (``outputs.atomic_write_bytes``,
#: ``posterior.write_netcdf``): ``.<name>.tmp<pid>``. Only a killed process leaves one behind.
_TEMPORARY = re.compile(r"^\..+\.tmp\d+$")


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


def warm_up_kernels(transient, damper, flow, settings: StageTwoSettings) -> float:
    """Compile, or load from numba's on-disk cache, the kernels stage 2 calls; return the seconds spent.

    One log-posterior evaluation and one forward solve at the centre of the prior box, in this
    process. Run before a pool of worker processes starts, so the cache exists and forked workers
    inherit the compiled code instead of each compiling it again.
    """
    t0 = time.perf_counter()
    problem = TransientProblem.from_transient(transient, damper, flow)
    space = settings.space()
    centre = (space.lower + space.upper) / 2
    LogPosterior(problem, make_noise_model(settings.noise_model), space).batch(centre[None, :])
    problem.simulate_force(*space.to_physical(centre[None, :])[0, :2])
    return time.perf_counter() - t0


def identify_all(transients, damper, flow, settings: StageTwoSettings, seed: int, workers: int,
                 posterior_dir: Path | None, provenance: dict, progress: Progress,
                 static_draws: np.ndarray | None = None, *, client=None) -> list[TransientResult]:
    """Stage 2 for every transient, on ``workers`` processes or a Dask cluster; results in input order.

    ``static_draws`` (rows of [C_L12, C_Q12, C_L21, C_Q21] from stage 1) switch on the check of how
    much the stage-1 uncertainty moves each transient's optimum. ``client`` (a connected
    ``dask.distributed.Client``) sends the tasks to its cluster instead of the local pool.
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

    if not tasks:
        return []
    if client is not None:
        from bayesdamper.run.distributed import map_transients

        return map_transients(client, tasks, report)
    if workers <= 1 or len(tasks) == 1:
        for i, task in enumerate(tasks):
            progress(f"sampling {task[0].id} ...")
            results[i] = _worker(task)
            report(i, results[i], i + 1)
    else:
        # Compile (or load) the numba kernels once here: forked workers inherit them, and the on-disk
        # cache exists for spawned ones, instead of every worker compiling the same code at once.
        progress(f"numba kernels ready in {warm_up_kernels(transients[0], damper, flow, settings):.1f} s")
        with _pool(workers) as ex:
            futs = {ex.submit(_worker, task): i for i, task in enumerate(tasks)}
            try:
                for done, fut in enumerate(as_completed(futs), 1):
                    i = futs[fut]
                    results[i] = fut.result()
                    report(i, results[i], done)
            except BaseException:  # interrupted or failed: do not start the queued transients
                ex.shutdown(wait=True, cancel_futures=True)
                raise
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


# ---------------------------------------------------------------------------------------------
# settings fingerprint and the state of an output folder


def fingerprint_basis(settings: dict, tmax: float, seed: int, dataset_sha256: str) -> dict:
    """What a stored result depends on: stage-2 settings, window length [s], run seed, input data."""
    basis = {"settings": settings, "tmax_s": float(tmax), "seed": int(seed), "dataset_sha256": dataset_sha256}
    return json.loads(json.dumps(basis))  # tuples -> lists, as read back from a file


def settings_fingerprint(basis: dict) -> str:
    """SHA-256 of the canonical JSON (sorted keys, no spaces) of a :func:`fingerprint_basis`."""
    return hashlib.sha256(json.dumps(basis, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _flatten(d, prefix: str = "") -> dict:
    if not isinstance(d, dict):
        return {prefix: d}
    out = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def _differences(old: dict, new: dict) -> list[str]:
    a, b = _flatten(old), _flatten(new)
    out = []
    for k in sorted(set(a) | set(b)):
        if a.get(k) != b.get(k):
            out.append("the input data (dataset_sha256)" if k == "dataset_sha256" else
                       f"{k} {json.dumps(a.get(k))} -> {json.dumps(b.get(k))}")
    return out


def _stored_basis(out_dir: Path) -> tuple[str, dict | None] | None:
    """Where ``out_dir`` records the settings of results it holds, and their basis.

    None if it holds no results; ``(source, None)`` if it holds results whose settings are unknown.
    Results of versions before ``run.json`` are recognised by their ``summary.json`` or posteriors.
    """
    from bayesdamper.inference import posterior as post

    if (out_dir / RUN_FILE).is_file():
        try:
            return RUN_FILE, json.loads((out_dir / RUN_FILE).read_text())["fingerprint_basis"]
        except (OSError, ValueError, KeyError, TypeError):
            return RUN_FILE, None
    if (out_dir / SUMMARY_FILE).is_file():
        try:
            s = json.loads((out_dir / SUMMARY_FILE).read_text())
            return SUMMARY_FILE, fingerprint_basis(s["settings"], s["tmax_s"], s["seed"],
                                                   s["provenance"]["dataset_sha256"])
        except (OSError, ValueError, KeyError, TypeError):
            return SUMMARY_FILE, None
    ncs = sorted((out_dir / POSTERIORS_DIR).glob("*.nc")) if (out_dir / POSTERIORS_DIR).is_dir() else []
    if ncs:
        try:
            a = post.read_transient(ncs[0])["attrs"]
            return (f"{POSTERIORS_DIR}/{ncs[0].name}",
                    fingerprint_basis(a["settings"], a["tmax_s"], a["run_seed"], a["dataset_sha256"]))
        except Exception:  # noqa: BLE001 - any unreadable file: settings unknown
            return f"{POSTERIORS_DIR}/{ncs[0].name}", None
    return None


def check_output_folder(out_dir: Path, basis: dict, force: bool) -> None:
    """Raise SettingsError if ``out_dir`` holds results of other (or unknown) settings and not ``force``."""
    if out_dir.exists() and not out_dir.is_dir():
        raise SettingsError(f"{out_dir}: exists and is not a folder")
    if force or not out_dir.is_dir():
        return
    stored = _stored_basis(out_dir)
    if stored is None:
        return
    source, old = stored
    if old is None:
        why = f"{source} records no readable settings"
    elif old == basis:
        return
    else:
        why = "; ".join(_differences(old, basis)) + " differ"
    raise SettingsError(f"{out_dir}: holds results of different settings ({why}); use --force to overwrite")


def _clear(out_dir: Path) -> None:
    for name in OWNED:
        p = out_dir / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def _remove_temporaries(out_dir: Path) -> int:
    """Delete temporary files a killed run's atomic writers left in the folders this run owns."""
    n = 0
    for folder in (out_dir, out_dir / POSTERIORS_DIR, out_dir / FIGURES_DIR):
        if not folder.is_dir():
            continue
        for p in (folder.rglob("*") if folder != out_dir else folder.iterdir()):
            if p.is_file() and _TEMPORARY.match(p.name):
                p.unlink()
                n += 1
    return n


def _load_finished(path: Path, transient, fingerprint: str) -> TransientResult | None:
    """The stored result of ``transient`` if ``path`` holds it under ``fingerprint``, else None."""
    from bayesdamper.inference import posterior as post

    if not path.is_file():
        return None
    try:
        s = post.read_transient(path)
    except Exception as err:  # noqa: BLE001 - an unreadable file is sampled again, and said so
        print(f"{path}: unreadable ({type(err).__name__}); sampling {transient.id} again", file=sys.stderr)
        return None
    a = s["attrs"]
    if (a.get("settings_fingerprint") != fingerprint or a.get("segment_id") != transient.id
            or not isinstance(a.get("entry"), dict) or s["band"] is None or s["ls_force"] is None):
        return None
    return TransientResult(a["entry"], s["names"], s["chains"], s["time"], s["force"], s["band"],
                           s["ls_force"])


def dataset_folder(name: str) -> str:
    """A file-name-safe folder name for a data set called ``name``."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "dataset"
    return safe


def data_table(ds, segs) -> dict:
    """The data set and its segmentation as plain values (for ``summary.json`` and the report)."""
    plateau = {(p.test, p.index): p for s in segs for p in s.plateaus}
    steps = []
    for s in segs:
        for st in s.steps:
            p = plateau.get((s.record.name, st.index))
            steps.append({
                "test": s.record.name, "index": int(st.index), "kind": st.kind,
                "direction": int(st.direction), "velocity_m_s": float(abs(st.velocity_after)),
                "t_step_s": float(st.time), "force_N": float(st.force),
                "plateau_force_N": (float(np.sign(st.direction) * p.pressure_drop * ds.damper.piston_area)
                                    if p else None)})
    records = [{"name": r.name, "file": r.path.name, "n_samples": int(r.time.size),
                "sample_rate_Hz": float(r.sample_rate), "duration_s": r.duration, "sha256": r.sha256}
               for r in ds.records]
    return {"damper": asdict(ds.damper), "records": records, "steps": steps}


# ---------------------------------------------------------------------------------------------
# identify


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


def _stage_two_settings(credible_mass, noise_model, alpha_v_prior, p_r_prior, max_steps) -> StageTwoSettings:
    make_noise_model(noise_model)  # validate before any work
    if max_steps is not None and max_steps < 1:
        raise SettingsError(f"--max-steps must be a positive number of steps, got {max_steps}")
    sampler = SamplerSettings() if max_steps is None else SamplerSettings(max_steps=max_steps)
    kw = {}
    if (b := _bounds(alpha_v_prior, "--alpha-v-prior")) is not None:
        kw["alpha_v_bounds"] = b
    if (b := _bounds(p_r_prior, "--p-r-prior")) is not None:
        kw["p_r_bounds"] = b
    settings = StageTwoSettings(credible_mass=credible_mass, noise_model=noise_model, sampler=sampler, **kw)
    settings.space()
    return settings


def _plan(data_dirs: list, out: str | Path, settings: StageTwoSettings, seed: int, tmax: float,
          only: str | None, force: bool) -> list[_Job]:
    """Load, segment and fit stage 1 for every data set; check the output folders. Writes nothing."""
    prepared = [prepare(d, tmax) for d in data_dirs]
    if only:
        wanted = {s.strip() for s in only.split(",") if s.strip()}
        unknown = wanted - {t.id for p in prepared for t in p[2]}
        if unknown:
            raise SettingsError(f"--only: unknown segment id(s) {', '.join(sorted(unknown))}")
        prepared = [(ds, segs, [t for t in trs if t.id in wanted], st) for ds, segs, trs, st in prepared]
    out_root = Path(out)
    if out_root.exists() and not out_root.is_dir():
        raise SettingsError(f"{out_root}: exists and is not a folder")
    if len(prepared) == 1:
        outs = [out_root]
    else:
        names = [dataset_folder(p[0].name) for p in prepared]
        for i, n in enumerate(names):
            if n in names[:i]:
                j = names.index(n)
                raise SettingsError(f"{data_dirs[j]}, {data_dirs[i]}: both data sets are called {n!r}; "
                                    "give them distinct [damper] names")
        outs = [out_root / n for n in names]
    jobs = []
    for (ds, segs, trs, static), out_dir in zip(prepared, outs, strict=True):
        if not trs:
            continue
        basis = fingerprint_basis(settings.as_dict(), tmax, seed, ds.sha256)
        check_output_folder(out_dir, basis, force)
        jobs.append(_Job(ds, segs, trs, static, out_dir, basis, settings_fingerprint(basis)))
    if not jobs:
        raise SettingsError("no transient to identify")
    return jobs


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _identify_one(job: _Job, settings: StageTwoSettings, *, seed: int, credible_mass: float, tmax: float,
                  workers: int, figures: bool, force: bool, client, scheduler: str | None) -> dict:
    """Stage 2 and the outputs of one validated data set (the only step that writes)."""
    t0 = time.perf_counter()
    ds, out_dir = job.ds, job.out_dir
    if force:
        _clear(out_dir)
    post_dir = out_dir / POSTERIORS_DIR
    post_dir.mkdir(parents=True, exist_ok=True)
    progress = Progress()
    if (n := _remove_temporaries(out_dir)):
        progress(f"removed {n} temporary file(s) left by an interrupted run")
    prov = {"dataset": ds.name, "dataset_path": str(ds.path), "input_sha256": ds.input_hashes(),
            "dataset_sha256": ds.sha256, "versions": versions(), "tmax_s": tmax, "run_seed": seed,
            "settings_fingerprint": job.fingerprint}
    run = {"fingerprint": job.fingerprint, "fingerprint_basis": job.basis,
           "fingerprint_of": "sha256 of the canonical JSON (sorted keys, no spaces) of fingerprint_basis",
           "status": "running", "started_utc": _now(), "dataset": ds.name, "dataset_path": str(ds.path),
           "input_sha256": ds.input_hashes(), "settings": settings.as_dict(), "seed": seed, "tmax_s": tmax,
           "versions": prov["versions"], "workers": workers, "scheduler": scheduler,
           "transients": [t.id for t in job.transients]}
    atomic_write_json(out_dir / RUN_FILE, run)

    results: list[TransientResult | None] = [
        _load_finished(post_dir / f"{tr.id}.nc", tr, job.fingerprint) for tr in job.transients]
    resumed = [tr.id for tr, r in zip(job.transients, results, strict=True) if r is not None]
    if resumed:
        print(f"resumed {len(resumed)} finished transient(s) from {post_dir}", file=sys.stderr, flush=True)
    todo = [i for i, r in enumerate(results) if r is None]
    progress(f"stage 1 done; sampling {len(todo)} transient(s) on "
             + (f"the cluster at {scheduler}" if client is not None else f"{workers} worker(s)"))
    from bayesdamper.inference.stage2 import N_STATIC_DRAWS, STATIC_NEGLIGIBLE_RATIO

    draws = job.static.sample(N_STATIC_DRAWS, np.random.default_rng(seed))
    fresh = identify_all([job.transients[i] for i in todo], ds.damper, job.static.coefficients, settings,
                         seed, workers, post_dir, prov, progress, draws, client=client)
    for i, r in zip(todo, fresh, strict=True):
        results[i] = r
    entries = [r.entry for r in results]
    ratios = np.array([[e["static_sensitivity"]["ratio"][k] for k in ("alpha_V", "p_R_Pa")] for e in entries])
    summary = {
        "dataset": ds.name, "credible_mass": credible_mass,
        "static": job.static.intervals(credible_mass),
        "segments": entries,
        "drift": drift_summary(entries, credible_mass, seed) if len(entries) >= 3 else {},
        "settings": settings.as_dict(), "seed": seed, "tmax_s": tmax, "provenance": prov,
        "n_converged": int(sum(e["converged"] for e in entries)),
        "static_uncertainty": {
            "method": f"optimum re-fitted under {N_STATIC_DRAWS} draws of the stage-1 coefficients; ratio = "
                      "sd of the optima / posterior sd (log parameters)",
            "max_ratio": {"alpha_V": float(np.nanmax(ratios[:, 0])),
                          "p_R_Pa": float(np.nanmax(ratios[:, 1]))},
            "median_ratio": {"alpha_V": float(np.nanmedian(ratios[:, 0])),
                             "p_R_Pa": float(np.nanmedian(ratios[:, 1]))},
            "threshold": STATIC_NEGLIGIBLE_RATIO,
            "negligible": bool(all(e["static_sensitivity"]["negligible"] for e in entries)),
        },
        "data": data_table(ds, job.segs),
    }
    if figures:
        from bayesdamper.report.figures import write_identify_figures

        summary["figures"] = write_identify_figures(out_dir, ds, job.segs, job.static, results, summary,
                                                    workers=workers)
    wall = time.perf_counter() - t0
    summary["wall_time_s"] = wall
    atomic_write_json(out_dir / SUMMARY_FILE, summary)
    run.update(status="complete", finished_utc=_now(), resumed=resumed,
               computed=[job.transients[i].id for i in todo], wall_time_s=wall)
    atomic_write_json(out_dir / RUN_FILE, run)
    n_ok = summary["n_converged"]
    print(f"identified {len(entries)} transient(s) of {ds.name!r}: {n_ok} converged, "
          f"{len(entries) - n_ok} not" + (f" ({len(resumed)} resumed)" if resumed else "")
          + f"; results in {out_dir}; wall time {wall:.1f} s")
    return summary


def run_identify(data_dir: str | os.PathLike | Sequence[str | os.PathLike], out: str, *, seed: int = 0,
                 credible_mass: float = 0.9, tmax: float = 3.0, workers: int = 0, noise_model: str = "ar1",
                 alpha_v_prior=None, p_r_prior=None, max_steps: int | None = None, only: str | None = None,
                 figures: bool = True, force: bool = False,
                 scheduler: str | None = None) -> dict | list[dict]:
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
    settings = _stage_two_settings(credible_mass, noise_model, alpha_v_prior, p_r_prior, max_steps)
    jobs = _plan(dirs, out, settings, seed, tmax, only, force)
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    client = None
    if scheduler:
        from bayesdamper.run.distributed import connect

        client = connect(scheduler)
    try:
        summaries = [_identify_one(job, settings, seed=seed, credible_mass=credible_mass, tmax=tmax,
                                   workers=workers, figures=figures, force=force, client=client,
                                   scheduler=scheduler) for job in jobs]
    finally:
        if client is not None:
            client.close()
    return summaries[0] if single else summaries


def identify_out_dir(out: str | Path, summary: dict, n_datasets: int) -> Path:
    """The folder :func:`run_identify` wrote ``summary`` into."""
    return Path(out) if n_datasets == 1 else Path(out) / dataset_folder(summary["dataset"])


# ---------------------------------------------------------------------------------------------
# report


def run_report(data_dir: str | os.PathLike | Sequence[str | os.PathLike], out: str, *, seed: int = 0,
               credible_mass: float = 0.9, tmax: float = 3.0, workers: int = 0, max_steps: int | None = None,
               figures: bool = True, diagnose: bool = True, **identify_options) -> list[Path]:
    """``bayesdamper report``: ``identify``, then (if available) ``diagnose``, then ``OUT/report.html``.

    Takes the options of :func:`run_identify`. Returns the written report(s), one per data set.
    """
    from bayesdamper.report.html import render_report

    single = isinstance(data_dir, str | os.PathLike)
    dirs = [data_dir] if single else list(data_dir)
    summaries = run_identify(dirs, out, seed=seed, credible_mass=credible_mass, tmax=tmax, workers=workers,
                             max_steps=max_steps, figures=figures, **identify_options)
    run_diagnosis, note = None, None
    if not diagnose:
        note = "not requested"
    elif identify_options.get("only"):
        note = "--only selects a subset of the transients; the diagnosis needs them all"
    else:
        try:
            from bayesdamper.diagnosis.loop import run_diagnosis
        except ImportError as err:  # not part of this installation (yet): the report says so
            note = f"the diagnosis module cannot be imported ({err})"
            print(f"bayesdamper report: no diagnosis: {note}", file=sys.stderr)
    pages = []
    for d, summary in zip(dirs, summaries, strict=True):
        out_dir = identify_out_dir(out, summary, len(dirs))
        diagnosis = None
        if run_diagnosis is not None:
            diagnosis = run_diagnosis(str(d), str(out_dir), seed=seed, workers=workers, tmax=tmax,
                                      credible_mass=credible_mass, max_steps=max_steps, figures=figures)
        page = render_report(summary, diagnosis, out_dir, diagnosis_note=note)
        print(f"report written to {page}")
        pages.append(page)
    return pages
