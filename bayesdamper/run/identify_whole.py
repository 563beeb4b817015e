"""The ``identify`` job in whole-record mode: one joint posterior per record, resumable, with its figures.

Called by :mod:`bayesdamper.run.identify` after the data set has been validated and planned
(:mod:`bayesdamper.run.plan`); the output folder rules (fingerprint, resume, atomic files, nothing written
before validation) are the two-stage job's.
"""

from __future__ import annotations

import multiprocessing as mp
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from bayesdamper.inference.whole_stage import MODE, WholeResult, identify_record
from bayesdamper.io.outputs import atomic_write_json, versions
from bayesdamper.run.outfolder import POSTERIORS_DIR, RUN_FILE, SUMMARY_FILE, _clear, _remove_temporaries
from bayesdamper.run.progress import count_files


def load_finished_record(path: Path, window, fingerprint: str) -> WholeResult | None:
    """The stored result of ``window`` if ``path`` holds it under ``fingerprint``, else None."""
    from bayesdamper.inference import posterior as post

    if not path.is_file():
        return None
    try:
        s = post.read_transient(path)
    except Exception as err:  # noqa: BLE001 - an unreadable file is sampled again, and said so
        print(f"{path}: unreadable ({type(err).__name__}); sampling {window.id} again", file=sys.stderr)
        return None
    a = s["attrs"]
    if (a.get("settings_fingerprint") != fingerprint or a.get("segment_id") != window.id
            or a.get("mode") != MODE or s["band"] is None or s["displacement"] is None):
        return None
    return WholeResult(a["entry"], s["names"], s["chains"], s["time"], s["force"], s["band"], s["ls_force"],
                       s["displacement"])


def _task(args) -> WholeResult:
    window, damper, settings, seed, nc, prov = args
    return identify_record(window, damper, settings, seed, nc, prov)


def identify_records(windows, damper, settings, seed: int, workers: int, post_dir: Path | None, prov: dict,
                     progress) -> list[WholeResult]:
    """Whole-record identification of every window, on ``workers`` processes; results in input order."""
    tasks = [(w, damper, settings, seed, None if post_dir is None else post_dir / f"{w.id}.nc", prov)
             for w in windows]
    out: list = [None] * len(tasks)

    def report(i, res, done):
        e = res.entry
        progress(f"[{done}/{len(tasks)}] {e['id']}: {'converged' if e['converged'] else 'NOT converged'}, "
                 f"R-hat {e['rhat_max']:.3f}, ESS {e['ess_bulk_min']:.0f}, J {e['J']:.4f}, {e['wall_s']:.1f} s")
        progress.advance()

    if workers <= 1 or len(tasks) <= 1:
        for i, t in enumerate(tasks):
            out[i] = _task(t)
            report(i, out[i], i + 1)
        return out
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
        futs = {ex.submit(_task, t): i for i, t in enumerate(tasks)}
        try:
            for done, fut in enumerate(as_completed(futs), 1):
                i = futs[fut]
                out[i] = fut.result()
                report(i, out[i], done)
        except BaseException:
            ex.shutdown(wait=True, cancel_futures=True)
            raise
    return out


def identify_whole_job(job, settings, *, seed: int, credible_mass: float, workers: int, figures: bool,
                       force: bool, progress, now) -> dict:
    """Identify every record of a planned whole-record data set and write OUT (the only step that writes)."""
    from bayesdamper.run.stages import drift_summary

    t0 = time.perf_counter()
    ds, out_dir, plan = job.ds, job.out_dir, job.plan
    if force:
        _clear(out_dir)
    post_dir = out_dir / POSTERIORS_DIR
    post_dir.mkdir(parents=True, exist_ok=True)
    if (n := _remove_temporaries(out_dir)):
        progress(f"removed {n} temporary file(s) left by an interrupted run")
    prov = {"dataset": ds.name, "dataset_path": str(ds.path), "input_sha256": ds.input_hashes(),
            "dataset_sha256": ds.sha256, "versions": versions(), "run_seed": seed, "mode": MODE,
            "settings_fingerprint": job.fingerprint}
    run = {"fingerprint": job.fingerprint, "fingerprint_basis": job.basis,
           "fingerprint_of": "sha256 of the canonical JSON (sorted keys, no spaces) of fingerprint_basis",
           "status": "running", "started_utc": now(), "dataset": ds.name, "dataset_path": str(ds.path),
           "mode": MODE, "mode_reason": plan.mode_reason, "input_sha256": ds.input_hashes(),
           "settings": settings.as_dict(), "seed": seed, "versions": prov["versions"], "workers": workers,
           "records": [w.id for w in plan.windows]}
    atomic_write_json(out_dir / RUN_FILE, run)
    results = [load_finished_record(post_dir / f"{w.id}.nc", w, job.fingerprint) for w in plan.windows]
    resumed = [w.id for w, r in zip(plan.windows, results, strict=True) if r is not None]
    if resumed:
        print(f"resumed {len(resumed)} finished record(s) from {post_dir}", file=sys.stderr, flush=True)
    todo = [i for i, r in enumerate(results) if r is None]
    with progress.phase(f"whole-record identification ({ds.name})", total=len(todo), unit="record"):
        fresh = identify_records([plan.windows[i] for i in todo], ds.damper, settings, seed, workers, post_dir,
                                 prov, progress)
        progress.note(f"{sum(r.entry['converged'] for r in fresh)} converged"
                      + (f", {len(resumed)} resumed" if resumed else ""))
    for i, r in zip(todo, fresh, strict=True):
        results[i] = r
    entries = [r.entry for r in results]
    summary = {
        "dataset": ds.name, "mode": MODE, "mode_reason": plan.mode_reason, "credible_mass": credible_mass,
        "records": entries, "segments": entries, "plan": plan.as_dict(),
        "drift": drift_summary(entries, credible_mass, seed) if len(entries) >= 3 else {},
        "settings": settings.as_dict(), "seed": seed, "provenance": prov,
        "n_converged": int(sum(e["converged"] for e in entries)),
    }
    if figures:
        from bayesdamper.report.whole_figures import write_whole_figures

        with progress.phase(f"figures ({ds.name})", unit="file") as ph:
            summary["figures"] = write_whole_figures(out_dir, results, credible_mass)
            ph.done = count_files(summary["figures"])
    wall = time.perf_counter() - t0
    summary["wall_time_s"] = wall
    atomic_write_json(out_dir / SUMMARY_FILE, summary)
    run.update(status="complete", finished_utc=now(), resumed=resumed,
               computed=[plan.windows[i].id for i in todo], wall_time_s=wall)
    atomic_write_json(out_dir / RUN_FILE, run)
    n_ok = summary["n_converged"]
    print(f"identified {len(entries)} record(s) of {ds.name!r} as whole records: {n_ok} converged, "
          f"{len(entries) - n_ok} not" + (f" ({len(resumed)} resumed)" if resumed else "")
          + f"; results in {out_dir}; wall time {wall:.1f} s")
    return summary
