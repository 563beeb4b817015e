"""The figure of a prediction: the calibrated damper's force against time and against displacement, with its 50 %
and 90 % predictive bands and the measured force where the history has one."""

from __future__ import annotations

from pathlib import Path

from bayesdamper.io.outputs import save_figure
from bayesdamper.report.style import FORCE_DISPLAY

#: Points drawn per curve (evenly thinned beyond it).
MAX_POINTS = 4000


def prediction_figure(pred, stem: Path) -> list[Path]:
    """Write ``stem.png`` and ``stem.pdf``: (a) force against time, (b) force against displacement (curves thinned
    evenly to :data:`MAX_POINTS` points)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11.0, 4.6))
    ax_t, ax_y = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.6, 1.0]})
    # at most MAX_POINTS points per curve: a 60 s history at 1 kHz drawn whole costs seconds and shows no more
    k = max(1, -(-pred.time.size // MAX_POINTS))
    t, q = pred.time[::k], pred.quantiles[:, ::k] * FORCE_DISPLAY
    ax_t.fill_between(t, q[0], q[4], color="C0", alpha=0.2, lw=0, label="90 % band", gid="band-90")
    ax_t.fill_between(t, q[1], q[3], color="C0", alpha=0.4, lw=0, label="50 % band", gid="band-50")
    ax_t.plot(t, q[2], color="C0", lw=1.0, label="predictive median", gid="median")
    y_mm = pred.displacement[::k] * 1e3
    ax_y.plot(y_mm, q[2], color="C0", lw=1.0, gid="loop-median")
    if pred.measured is not None:
        f = pred.measured[::k] * FORCE_DISPLAY
        ax_t.plot(t, f, color="k", lw=0.5, alpha=0.8, label="measured", gid="measured")
        ax_y.plot(y_mm, f, color="k", lw=0.5, alpha=0.8, gid="loop-measured")
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("damper force [kN]")
    ax_y.set_xlabel("displacement [mm]")
    ax_y.set_ylabel("damper force [kN]")
    for ax in (ax_t, ax_y):
        ax.grid(alpha=0.3)
    ax_t.legend(fontsize=8, loc="upper right")
    info = pred.info
    lo, hi = info["calibrated_speed_range_m_s"]
    title = (f"{info['model']}: operating speed {1e3 * pred.speed:.3g} mm/s (calibrated {1e3 * lo:.3g}-"
             f"{1e3 * hi:.3g} mm/s{', extrapolated' if info['extrapolated'] else ''})")
    if "coverage_90" in info:
        title += f"; measured inside the 90 % band {100 * info['coverage_90']:.0f} %, J {info['J_median']:.4f}"
    fig.suptitle(title, fontsize=9)
    Path(stem).parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, Path(stem))
