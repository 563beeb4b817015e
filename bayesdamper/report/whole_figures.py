"""Figures of a whole-record identification: the record against the posterior predictive.

Per record, ``figures/whole/<id>.{png,pdf}``: force against time (a stretch of it), force against
displacement and force against velocity (the hysteresis loops a test engineer reads), measured in grey,
the posterior-predictive median and its credible band in colour, the least-squares fit dashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayesdamper.io.outputs import save_figure
from bayesdamper.report.style import _figure, _pct

#: Longest stretch of the record shown against time [s] (loops show all of it).
TIME_PANEL_S = 5.0


def whole_record_figure(result, credible_mass: float):
    """Three panels of one record: force-time, force-displacement, force-velocity."""
    t, f, y = result.time, result.force, result.displacement
    v = np.gradient(y, t)
    lo, med, hi = result.band
    fig = _figure((12.0, 3.6))
    axes = fig.subplots(1, 3)
    sel = t <= t[0] + TIME_PANEL_S
    ax = axes[0]
    ax.plot(t[sel], f[sel], color="0.6", lw=1.0, label="measured")
    ax.fill_between(t[sel], lo[sel], hi[sel], color="C0", alpha=0.3, lw=0, label=f"{_pct(credible_mass)} band")
    ax.plot(t[sel], med[sel], color="C0", lw=1.0, label="posterior predictive median")
    ax.plot(t[sel], result.ls_force[sel], "--", color="C3", lw=0.8, label="least squares")
    ax.set(xlabel="time [s]", ylabel="force [N]", title=f"{result.entry['id']}: J = {result.entry['J']:.3f}")
    ax.legend(fontsize=7, loc="best")
    for ax, x, lab in ((axes[1], 1e3 * y, "displacement [mm]"), (axes[2], 1e3 * v, "velocity [mm/s]")):
        ax.plot(x, f, ".", color="0.6", ms=1.5, label="measured")
        ax.plot(x, med, color="C0", lw=0.8, label="predictive median")
        ax.set(xlabel=lab, ylabel="force [N]")
    axes[1].set_title(result.entry.get("description", "")[:60], fontsize=8)
    return fig


def write_whole_figures(out_dir: Path, results, credible_mass: float) -> dict:
    """Write one loop figure per record; return ``{id: [relative paths]}``."""
    out = {}
    (Path(out_dir) / "figures" / "whole").mkdir(parents=True, exist_ok=True)
    for r in results:
        fig = whole_record_figure(r, credible_mass)
        paths = save_figure(fig, Path(out_dir) / "figures" / "whole" / r.entry["id"], ("png", "pdf"))
        out[r.entry["id"]] = [str(Path(p).relative_to(out_dir)) for p in paths]
    return out


def whole_diagnosis_figure(window, base_force: np.ndarray, final_force: np.ndarray, label: str):
    """Force-velocity loop (measured, eq. (7), final model) and the residual against time, before and after."""
    t, f = window.time, window.force
    v = window.velocity()
    fig = _figure((12.0, 3.6))
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot(1e3 * v, f, ".", color="0.6", ms=1.5, label="measured")
    ax1.plot(1e3 * v, base_force, color="C0", lw=0.7, label="eq. (7) baseline")
    ax1.plot(1e3 * v, final_force, color="C3", lw=0.7, label=label)
    ax1.set(xlabel="velocity [mm/s]", ylabel="force [N]", title=window.id)
    ax1.legend(fontsize=7, loc="best")
    sel = t <= t[0] + 4 * TIME_PANEL_S
    ax2.plot(t[sel], (f - base_force)[sel], color="C0", lw=0.7, label="residual, baseline")
    ax2.plot(t[sel], (f - final_force)[sel], color="C3", lw=0.7, label=f"residual, {label}")
    ax2.set(xlabel="time [s]", ylabel="measured - computed force [N]")
    ax2.legend(fontsize=7, loc="best")
    return fig


def write_whole_diagnosis_figures(out_dir: Path, windows, base: list, final: list, label: str) -> dict:
    """One figure per record under ``figures/diagnosis``; return ``{id: [relative paths]}``."""
    out = {}
    folder = Path(out_dir) / "figures" / "diagnosis"
    folder.mkdir(parents=True, exist_ok=True)
    for w, b, f in zip(windows, base, final, strict=True):
        fig = whole_diagnosis_figure(w, b["force"], f["force"], label)
        paths = save_figure(fig, folder / f"whole_{w.id}", ("png",))
        out[w.id] = [str(Path(p).relative_to(out_dir)) for p in paths]
    return out
