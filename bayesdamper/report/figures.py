"""The figures an ``identify`` run writes into ``OUT/figures/``.

Layout (paths relative to the output folder):

* ``figures/figure3_static.{png,pdf}``: stage-1 fit (paper Fig. 3);
* ``figures/figure8_transients_p<k>.{png,pdf}``: transients with predictive bands, ``FIGURE8_PANELS``
  per page (paper Fig. 8);
* ``figures/figure9_drift.{png,pdf}``: p_R and 100/α_V against speed (paper Fig. 9);
* ``figures/loops/<id>.png``: a window of whole cycles against its predictive (force against time, displacement
  and velocity);
* ``figures/corner/<id>.png`` and ``figures/trace/<id>.png``: per-window posterior diagnostics
  (PNG only, to keep the run fast);
* the diagnosis's (:func:`write_diagnosis_figures`): ``figures/residuals_before_after``, ``figures/figure8_before``
  and ``_after`` (transients), ``figures/figure9_before`` and ``_after``, ``figures/diagnosis_loops/<id>_before.png``
  and ``_after.png`` (windows of cycles).

The plotting itself is in :mod:`bayesdamper.report.paper_figures` and
:mod:`bayesdamper.report.diagnostic_plots`; this module only pages, names and saves.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bayesdamper.io.outputs import save_figure
from bayesdamper.report import diagnostic_plots, paper_figures

#: Folder, inside the output folder, that holds every figure.
FIGURES_DIR = "figures"
#: Transients per page of Figure 8.
FIGURE8_PANELS = 12
#: Formats of the paper's figures.
PAPER_FORMATS = ("png", "pdf")
#: Formats of the per-transient diagnostic figures (many files: PNG only).
DIAGNOSTIC_FORMATS = ("png",)
#: Histogram bins of the per-transient corner plots (fewer is faster).
CORNER_BINS = 20
#: Draws shown per corner plot at most (evenly thinned).
CORNER_MAX_SAMPLES = 10000
#: Fewest figures worth starting worker processes for (per-transient diagnostics: some 0.2 s each).
MIN_JOBS_FOR_POOL = 6
#: The same for the diagnosis's figures: each is a paper figure in two formats (1-3 s), so two are worth a pool.
MIN_DIAGNOSIS_JOBS_FOR_POOL = 2

#: One figure to draw: (output key, name of the plots function, args, kwargs, stem, formats).
Job = tuple[str, str, tuple, dict, Path, tuple[str, ...]]


def _n_ensembles(summary: dict, n_chains: int) -> int:
    n = summary.get("settings", {}).get("sampler", {}).get("n_ensembles", 1)
    return int(n) if n and n_chains % int(n) == 0 else 1


def _render(job: Job) -> list[Path]:
    """Draw one figure and save it (runs in a worker process)."""
    _, func, args, kwargs, stem, formats = job
    # per-transient diagnostics (PNG only) have hand-set margins: skip the tight-bbox pass
    draw = getattr(paper_figures, func, None) or getattr(diagnostic_plots, func)
    return save_figure(draw(*args, **kwargs), stem, formats, tight=len(formats) > 1)


def _warm_up() -> None:
    """Draw one small figure, so that forked workers inherit loaded fonts and caches."""
    import io

    from matplotlib.figure import Figure

    fig = Figure(figsize=(2.0, 2.0))
    ax = fig.add_subplot()
    ax.plot([0.0, 1.0])
    ax.set_title("α_V, p_R [MPa]")
    fig.savefig(io.BytesIO(), format="png")


def _run(jobs: list[Job], workers: int, min_jobs: int = MIN_JOBS_FOR_POOL) -> list[list[Path]]:
    if workers <= 1 or len(jobs) < min_jobs:
        return [_render(j) for j in jobs]
    if "fork" in mp.get_all_start_methods():
        ctx = mp.get_context("fork")
        _warm_up()
    else:
        ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
        # jobs are ordered slowest first (multi-format paper figures), so the workers finish together
        return list(ex.map(_render, jobs, chunksize=1))


def write_identify_figures(out_dir: Path, ds, segs, static, results, summary: dict, *,
                           workers: int | None = None, windows=None) -> dict[str, list[str]]:
    """Write every figure of an ``identify`` run and return where they went.

    Parameters
    ----------
    out_dir : Path
        The run's output folder; figures go to ``out_dir / "figures"``.
    ds : bayesdamper.io.dataset.Dataset or None
        The data set (its name titles the paper's figures).
    segs : sequence of bayesdamper.io.segments.SegmentedRecord
        Segmented records (not needed by the current figures; part of the stable signature).
    static : bayesdamper.inference.stage1.StaticFit or None
        Stage-1 fit (None: no plateaus, no Figure 3).
    results : sequence of bayesdamper.inference.stage2.WindowResult
        Stage-2 results, in summary order.
    summary : dict
        The run summary (``segments``, ``drift``, ``credible_mass``, ``settings``).
    workers : int, optional
        Processes drawing figures in parallel (default: the number of CPUs); 1 draws in this process.
    windows : sequence of bayesdamper.io.windows.Window, optional
        The windows of ``results`` (their inputs draw the loops of windows of whole cycles).

    Returns
    -------
    dict of str to list of str
        ``"figure3_static"``, ``"figure8_transients"``, ``"figure9_drift"``, ``"loops"``, ``"corner"`` and
        ``"trace"``, each mapped to its files' paths relative to ``out_dir`` (POSIX separators), in
        result order.
    """
    del segs  # kept in the signature for figures that need the raw segments
    out_dir = Path(out_dir)
    fig_dir = out_dir / FIGURES_DIR
    for sub in ("", "corner", "trace", "loops"):
        (fig_dir / sub).mkdir(parents=True, exist_ok=True)
    mass = float(summary.get("credible_mass", 0.9))
    name = f"data set {ds.name!r}" if ds is not None else None
    results = list(results)
    by_id = {w.id: w for w in (windows or [])}

    jobs: list[Job] = []
    if static is not None:
        jobs.append(("figure3_static", "figure3_static", (static,), {"title": name}, fig_dir / "figure3_static",
                     PAPER_FORMATS))
    steps = [r for r in results if r.entry.get("kind") != "cycles"]
    n_pages = math.ceil(len(steps) / FIGURE8_PANELS)
    for k in range(n_pages):
        page = steps[k * FIGURE8_PANELS:(k + 1) * FIGURE8_PANELS]
        title = (name or "") + (f", page {k + 1} of {n_pages}" if n_pages > 1 else "")
        jobs.append(("figure8_transients", "figure8_transients", (page, FIGURE8_PANELS),
                     {"credible_mass": mass, "title": title.lstrip(", ") or None},
                     fig_dir / f"figure8_transients_p{k + 1}", PAPER_FORMATS))
    entries = summary.get("segments") or [r.entry for r in results]
    if entries:
        jobs.append(("figure9_drift", "figure9_drift", (entries, summary.get("drift") or None, mass),
                     {"title": name, "law": summary.get("drift_model")}, fig_dir / "figure9_drift", PAPER_FORMATS))
    for r in results:
        sid = r.entry["id"]
        w = by_id.get(sid)
        if r.entry.get("kind") == "cycles" and w is not None:
            jobs.append(("loops", "window_loops", (r, w.displacement, w.drive.velocity(w.time), mass), {},
                         fig_dir / "loops" / sid, DIAGNOSTIC_FORMATS))
        jobs.append(("corner", "corner_plot", (r,),
                     {"bins": CORNER_BINS, "max_samples": CORNER_MAX_SAMPLES, "credible_mass": mass},
                     fig_dir / "corner" / sid, DIAGNOSTIC_FORMATS))
        jobs.append(("trace", "trace_rank_plot", (r, _n_ensembles(summary, r.chains.shape[0])), {},
                     fig_dir / "trace" / sid, DIAGNOSTIC_FORMATS))

    workers = workers if workers is not None else (os.cpu_count() or 1)
    keys = ("figure3_static", "figure8_transients", "figure9_drift", "loops", "corner", "trace")
    written: dict[str, list[str]] = {k: [] for k in keys}
    for job, paths in zip(jobs, _run(jobs, workers), strict=True):
        written[job[0]].extend(Path(p).relative_to(out_dir).as_posix() for p in paths)
    return written


def _pick(results) -> list:
    """Windows at the lowest, middle and highest speed of every group: the transients per (kind, direction), the
    windows of cycles as one group."""
    out = []
    for kind, d in (("initial", 1), ("reversal", -1), ("reversal", 1), ("cycles", 0)):
        grp = sorted([r for r in results if r.entry["kind"] == kind and int(r.entry["direction"]) == d],
                     key=lambda r: r.entry["velocity_m_s"])
        if grp:
            idx = sorted({0, len(grp) // 2, len(grp) - 1})
            out += [grp[i] for i in idx]
    return out


def write_diagnosis_figures(out_dir: Path, windows, base, final, base_resid, final_resid,
                            diagnosis: dict, *, workers: int | None = None) -> dict[str, list[str]]:
    """The diagnosis's figures before and after the selected effects, into ``out_dir/figures/``.

    Parameters
    ----------
    out_dir : Path
        The output folder.
    windows : sequence of bayesdamper.io.windows.Window
        The windows of the diagnosis (transients, windows of cycles or both).
    base, final : sequence of bayesdamper.inference.stage2.WindowResult
        The eq. (7) baseline's and the final model's results, in window order.
    base_resid, final_resid : sequence of ndarray
        Their residuals [N], in window order.
    diagnosis : dict
        The diagnosis (``selected``, ``drift_before``, ``drift_after``, ``settings``).
    workers : int, optional
        Processes drawing figures in parallel.

    Returns
    -------
    dict of str to list of str
        ``"residuals"`` and ``"figure9_before"``/``"figure9_after"`` always; ``"figure8_before"``/``"figure8_after"``
        (the transients at the lowest, middle and highest speed of each kind and direction) when there are
        transients; ``"loops_before"``/``"loops_after"`` (one PNG per window of cycles at the lowest, middle and
        highest speed) when there are windows of cycles. Paths relative to ``out_dir``.
    """
    out_dir = Path(out_dir)
    fig_dir = out_dir / FIGURES_DIR
    fig_dir.mkdir(parents=True, exist_ok=True)
    windows = list(windows)
    rows = [{"kind": w.kind, "direction": w.direction, "velocity_m_s": w.velocity,
             "t": np.asarray(w.time) - w.t_step, "before": b, "after": a}
            for w, b, a in zip(windows, base_resid, final_resid, strict=True)]
    sel = ", ".join(diagnosis["selected"]) or "none"
    mass = diagnosis.get("settings", {}).get("credible_mass", 0.9)
    jobs: list[Job] = [
        ("residuals", "residual_figure", (rows,), {"title": f"residuals: eq. (7) (top) and with {sel} (bottom)"},
         fig_dir / "residuals_before_after", PAPER_FORMATS)]
    steps_before = _pick([r for r in base if r.entry["kind"] != "cycles"])
    if steps_before:
        steps_after = _pick([r for r in final if r.entry["kind"] != "cycles"])
        jobs += [("figure8_before", "figure8_transients", (steps_before,), {"title": "before: eq. (7)"},
                  fig_dir / "figure8_before", PAPER_FORMATS),
                 ("figure8_after", "figure8_transients", (steps_after,), {"title": f"after: eq. (7) + {sel}"},
                  fig_dir / "figure8_after", PAPER_FORMATS)]
    jobs += [
        ("figure9_before", "figure9_drift", ([r.entry for r in base], diagnosis["drift_before"], mass),
         {"title": "before: eq. (7)", "law": diagnosis.get("drift_model_before")}, fig_dir / "figure9_before",
         PAPER_FORMATS),
        ("figure9_after", "figure9_drift", ([r.entry for r in final], diagnosis["drift_after"], mass),
         {"title": f"after: eq. (7) + {sel}",
          "law": diagnosis.get("drift_model_after") or diagnosis.get("drift_model_before")},
         fig_dir / "figure9_after", PAPER_FORMATS)]
    by_id = {w.id: w for w in windows}
    cycles = {r.entry["id"] for r in _pick([r for r in base if r.entry["kind"] == "cycles"])}
    if cycles:
        (fig_dir / "diagnosis_loops").mkdir(exist_ok=True)
    for key, results, label in (("loops_before", base, "eq. (7)"), ("loops_after", final, f"eq. (7) + {sel}")):
        for r in results:
            sid = r.entry["id"]
            if sid in cycles:
                w = by_id[sid]
                jobs.append((key, "window_loops", (r, w.displacement, w.drive.velocity(w.time), mass),
                             {"title": f"{sid}, {label}: J = {r.entry['J']:.3f}"},
                             fig_dir / "diagnosis_loops" / f"{sid}_{key.split('_')[1]}", DIAGNOSTIC_FORMATS))
    written: dict[str, list[str]] = {}
    for job, paths in zip(jobs, _run(jobs, workers or os.cpu_count() or 1, MIN_DIAGNOSIS_JOBS_FOR_POOL), strict=True):
        written.setdefault(job[0], []).extend(Path(p).relative_to(out_dir).as_posix() for p in paths)
    return written
