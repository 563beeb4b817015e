"""The ``identify`` job in whole-record mode: one joint posterior per record, resumable, with its figures.

Called by :mod:`bayesdamper.run.identify` after the data set has been validated and planned
(:mod:`bayesdamper.run.plan`); the output folder rules (fingerprint, resume, atomic files, nothing written
before validation) are the two-stage job's.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from bayesdamper.inference.whole_stage import MODE, WholeResult, identify_record
from bayesdamper.run.outfolder import close_run, open_run, read_finished
from bayesdamper.run.progress import count_files
from bayesdamper.run.stages import data_table, drift_summary, run_tasks


def load_finished_record(path: Path, window, fingerprint: str) -> WholeResult | None:
    """The stored result of ``window`` if ``path`` holds it under ``fingerprint``, else None."""
    s = read_finished(path, window.id, fingerprint)
    if s is None or s["attrs"].get("mode") != MODE or s["displacement"] is None:
        return None
    return WholeResult(s["attrs"]["entry"], s["names"], s["chains"], s["time"], s["force"], s["band"],
                       s["ls_force"], s["displacement"])


def _task(args) -> WholeResult:
    window, damper, settings, seed, nc, prov = args
    return identify_record(window, damper, settings, seed, nc, prov)


def identify_records(windows, damper, settings, seed: int, workers: int, post_dir: Path | None, prov: dict,
                     progress) -> list[WholeResult]:
    """Whole-record identification of every window, on ``workers`` processes; results in input order."""
    tasks = [(w, damper, settings, seed, None if post_dir is None else post_dir / f"{w.id}.nc", prov)
             for w in windows]

    def report(i, res, done):
        e = res.entry
        progress(f"[{done}/{len(tasks)}] {e['id']}: {'converged' if e['converged'] else 'NOT converged'}, "
                 f"R-hat {e['rhat_max']:.3f}, ESS {e['ess_bulk_min']:.0f}, J {e['J']:.4f}, {e['wall_s']:.1f} s")
        progress.advance()

    return run_tasks(_task, tasks, workers, report)


def identify_whole_job(job, settings, *, seed: int, credible_mass: float, workers: int, figures: bool,
                       force: bool, progress, now) -> dict:
    """Identify every record of a planned whole-record data set and write OUT (the only step that writes)."""
    t0 = time.perf_counter()
    ds, out_dir, plan = job.ds, job.out_dir, job.plan
    post_dir, prov, run = open_run(job, settings, seed=seed, workers=workers, force=force, progress=progress,
                                   started_utc=now(), mode=MODE, prov_extra={"mode": MODE},
                                   run_extra={"records": [w.id for w in plan.windows]})
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
        "records": entries, "segments": entries, "plan": plan.as_dict(), "data": data_table(ds, []),
        "drift": drift_summary(entries, credible_mass, seed) if len(entries) >= 3 else {},
        "settings": settings.as_dict(), "seed": seed, "provenance": prov,
        "n_converged": int(sum(e["converged"] for e in entries)),
    }
    if figures:
        from bayesdamper.report.whole_figures import write_whole_figures

        with progress.phase(f"figures ({ds.name})", unit="file") as ph:
            summary["figures"] = write_whole_figures(out_dir, results, credible_mass)
            ph.done = count_files(summary["figures"])
    close_run(out_dir, summary, run, wall=time.perf_counter() - t0, finished_utc=now(), resumed=resumed,
              computed=[plan.windows[i].id for i in todo], units="whole record(s)")
    return summary
