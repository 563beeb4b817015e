"""The figures an ``identify`` run writes into ``OUT/figures/``.

Layout (paths relative to the output folder):

* ``figures/figure3_static.{png,pdf}``: stage-1 fit (paper Fig. 3);
* ``figures/figure8_transients_p<k>.{png,pdf}``: transients with predictive bands, ``FIGURE8_PANELS``
  per page (paper Fig. 8);
* ``figures/figure9_drift.{png,pdf}``: p_R and 100/α_V against speed (paper Fig. 9);
* ``figures/corner/<id>.png`` and ``figures/trace/<id>.png``: per-transient posterior diagnostics
  (PNG only, to keep the run fast).

The plotting itself is in :mod:`bayesdamper.plots`; this module only pages, names and saves.
"""

from __future__ import annotations

import math
from pathlib import Path

from . import plots
from .outputs import save_figure

#: Folder, inside the output folder, that holds every figure.
FIGURES_DIR = "figures"
#: Transients per page of Figure 8.
FIGURE8_PANELS = 12
#: Formats of the per-transient diagnostic figures (many files: PNG only).
DIAGNOSTIC_FORMATS = ("png",)
#: Histogram bins of the per-transient corner plots (fewer is faster).
CORNER_BINS = 20
#: Draws shown per corner plot at most (evenly thinned).
CORNER_MAX_SAMPLES = 10000


def _n_ensembles(summary: dict, n_chains: int) -> int:
    n = summary.get("settings", {}).get("sampler", {}).get("n_ensembles", 1)
    return int(n) if n and n_chains % int(n) == 0 else 1


def write_identify_figures(out_dir: Path, ds, segs, static, results, summary: dict) -> dict[str, list[str]]:
    """Write every figure of an ``identify`` run and return where they went.

    Parameters
    ----------
    out_dir : Path
        The run's output folder; figures go to ``out_dir / "figures"``.
    ds : bayesdamper.data.Dataset
        The data set (its name titles the figures).
    segs : sequence of bayesdamper.segmentation.SegmentedRecord
        Segmented records (not needed by the current figures; part of the stable signature).
    static : bayesdamper.static.StaticFit
        Stage-1 fit.
    results : sequence of bayesdamper.identify.TransientResult
        Stage-2 results, in summary order.
    summary : dict
        The run summary (``segments``, ``drift``, ``credible_mass``, ``settings``).

    Returns
    -------
    dict of str to list of str
        ``"figure3_static"``, ``"figure8_transients"``, ``"figure9_drift"``, ``"corner"`` and
        ``"trace"``, each mapped to its files' paths relative to ``out_dir`` (POSIX separators).
    """
    del segs  # kept in the signature for figures that need the raw segments
    out_dir = Path(out_dir)
    fig_dir = out_dir / FIGURES_DIR
    for sub in ("", "corner", "trace"):
        (fig_dir / sub).mkdir(parents=True, exist_ok=True)
    mass = float(summary.get("credible_mass", 0.9))
    written: dict[str, list[str]] = {k: [] for k in
                                     ("figure3_static", "figure8_transients", "figure9_drift", "corner", "trace")}

    def save(key: str, fig, stem: Path, formats: tuple[str, ...] = ("png", "pdf")) -> None:
        if ds is not None and key.startswith("figure"):
            fig.suptitle(f"data set {ds.name!r}", fontsize=9, x=0.01, ha="left", color="0.35")
        for p in save_figure(fig, stem, formats):
            written[key].append(Path(p).relative_to(out_dir).as_posix())

    save("figure3_static", plots.figure3_static(static), fig_dir / "figure3_static")

    results = list(results)
    n_pages = math.ceil(len(results) / FIGURE8_PANELS)
    for k in range(n_pages):
        page = results[k * FIGURE8_PANELS:(k + 1) * FIGURE8_PANELS]
        save("figure8_transients", plots.figure8_transients(page, FIGURE8_PANELS, credible_mass=mass),
             fig_dir / f"figure8_transients_p{k + 1}")

    entries = summary.get("segments") or [r.entry for r in results]
    if entries:
        save("figure9_drift", plots.figure9_drift(entries, summary.get("drift") or None, mass),
             fig_dir / "figure9_drift")

    for r in results:
        sid = r.entry["id"]
        save("corner", plots.corner_plot(r, bins=CORNER_BINS, max_samples=CORNER_MAX_SAMPLES,
                                         credible_mass=mass),
             fig_dir / "corner" / sid, DIAGNOSTIC_FORMATS)
        save("trace", plots.trace_rank_plot(r, _n_ensembles(summary, r.chains.shape[0])),
             fig_dir / "trace" / sid, DIAGNOSTIC_FORMATS)
    return written
