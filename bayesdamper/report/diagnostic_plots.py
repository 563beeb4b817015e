"""Per-window posterior diagnostics (corner and trace-rank plots) and the diagnosis residual figure.

Every function takes data and returns a :class:`matplotlib.figure.Figure`; nothing is shown or written
here (saving is :func:`bayesdamper.io.outputs.save_figure`). Styles: :mod:`bayesdamper.report.style`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from bayesdamper.report.style import _figure, _param_label, _pct

# --------------------------------------------------------------------------- posterior diagnostics
#: Parameters left out of the per-transient diagnostics: the flow coefficients a joint posterior samples under
#: the stage-1 prior (their intervals are in summary.json); a 7 x 7 corner plot took 40 s of rig-A's figures.
_NOT_SHOWN = ("CL12", "CQ12", "CL21", "CQ21")


def _own_parameters(result):
    """``result`` restricted to the transient's own parameters (α_V, p_R, Δp at the step, φ)."""
    keep = [k for k, n in enumerate(result.names) if n not in _NOT_SHOWN]
    if len(keep) == len(result.names):
        return result
    from dataclasses import replace

    return replace(result, names=tuple(result.names[k] for k in keep),
                   chains=np.asarray(result.chains)[..., keep])


def _flat_display(result) -> tuple[np.ndarray, list[str]]:
    chains = np.asarray(result.chains, dtype=float)
    flat = chains.reshape(-1, chains.shape[-1])
    labels, scales = zip(*(_param_label(n) for n in result.names), strict=True)
    return flat * np.array(scales), list(labels)


def corner_plot(result, *, bins: int = 20, max_samples: int | None = 20000, credible_mass: float = 0.9):
    """Corner plot of one transient's posterior, with the Nelder-Mead point as truth lines.

    Parameters
    ----------
    result : bayesdamper.inference.stage2.WindowResult
        ``chains`` shape (n_chains, n_draws, ndim) in physical units, ``names``, ``entry["ls"]``.
    bins : int
        Histogram bins per parameter (fewer draw faster).
    max_samples : int, optional
        Thin the flattened draws evenly to at most this many (speed); None keeps all.
    credible_mass : float
        Mass of the equal-tailed interval marked on the 1-D histograms and in their titles.

    Returns
    -------
    matplotlib.figure.Figure
        ndim x ndim axes (corner.py's layout); p_R shown in MPa.
    """
    import corner

    result = _own_parameters(result)
    flat, labels = _flat_display(result)
    if max_samples is not None and flat.shape[0] > max_samples:
        flat = flat[:: math.ceil(flat.shape[0] / max_samples)]
    ls = result.entry.get("ls", {})
    truths = []
    for name in result.names:
        _, scale = _param_label(name)
        truths.append(ls[name] * scale if name in ls else None)
    ranges = []
    for col in flat.T:
        lo, hi = float(np.min(col)), float(np.max(col))
        pad = 1e-3 * max(abs(lo), 1.0) if hi <= lo else 0.0
        ranges.append((lo - pad, hi + pad))
    q = [0.5 - credible_mass / 2, 0.5, 0.5 + credible_mass / 2]
    k = flat.shape[1]
    fig = _figure((2.3 * k + 0.4, 2.3 * k + 0.4), layout=None)
    corner.corner(flat, fig=fig, bins=bins, labels=labels, truths=truths, truth_color="C3", range=ranges,
                  quantiles=q, show_titles=False, label_kwargs={"fontsize": 9}, plot_datapoints=False,
                  smooth=1.0, max_n_ticks=4)
    # Plain-text titles (corner's own use mathtext, whose parsing dominates the drawing time).
    lo, med, hi = np.quantile(flat, q, axis=0)
    grid = np.array(fig.axes).reshape(k, k)
    diag = grid.diagonal()
    for i, j in zip(*np.triu_indices(k, 1), strict=True):
        fig.delaxes(grid[i, j])  # corner leaves the upper triangle as blank axes; drop them
    for ax, label, a, m, b in zip(diag, labels, lo, med, hi, strict=True):
        name = label.split(" [")[0]
        ax.set_title(f"{name} = {m:.3g}\n[{a:.3g}, {b:.3g}] ({_pct(credible_mass)})", fontsize=8)
    fig.suptitle(f"{result.entry.get('id', '')}: posterior (red: Nelder-Mead point)", y=1.02, fontsize=10)
    return fig


def trace_rank_plot(result, n_ensembles: int, *, walkers_per_ensemble: int = 3, bins: int = 20):
    """Trace of a few walkers per ensemble and rank histograms per ensemble, one row per parameter.

    Parameters
    ----------
    result : bayesdamper.inference.stage2.WindowResult
        ``chains`` shape (n_chains, n_draws, ndim), walkers ensemble-major: chain ``c`` belongs to
        ensemble ``c // (n_chains // n_ensembles)``.
    n_ensembles : int
        Number of independently started ensembles; must divide n_chains.
    walkers_per_ensemble : int
        Walkers traced per ensemble.
    bins : int
        Bins of the rank histograms. For a converged run every ensemble's histogram is flat about
        the dashed line (its expected count).

    Returns
    -------
    matplotlib.figure.Figure
        2 x ndim axes: column 0 traces, column 1 rank histograms.
    """
    result = _own_parameters(result)
    chains = np.asarray(result.chains, dtype=float)
    n_chains, n_draws, ndim = chains.shape
    if n_ensembles < 1 or n_chains % n_ensembles:
        raise ValueError(f"{n_chains} chains cannot be split into {n_ensembles} equal ensembles")
    from matplotlib.ticker import MaxNLocator, NullLocator
    from scipy.stats import rankdata

    n_walkers = n_chains // n_ensembles
    shown = min(walkers_per_ensemble, n_walkers)
    # Fixed margins rather than a layout engine: one of these is drawn per transient of every run.
    height = 2.0 * ndim + 0.9
    fig = _figure((10.0, height), layout=None)
    fig.subplots_adjust(left=0.09, right=0.98, top=1 - 0.6 / height, bottom=0.45 / height, hspace=0.12,
                        wspace=0.12)
    axes = fig.subplots(ndim, 2, squeeze=False, width_ratios=[2.2, 1], sharex="col")
    draw = np.arange(n_draws)
    edges = np.linspace(0.5, n_chains * n_draws + 0.5, bins + 1)
    expected = n_walkers * n_draws / bins
    for k, name in enumerate(result.names):
        label, scale = _param_label(name)
        ax = axes[k, 0]
        for e in range(n_ensembles):
            for w in range(shown):
                ax.plot(draw, chains[e * n_walkers + w, :, k] * scale, color=f"C{e % 10}", lw=0.6,
                        alpha=0.8, label=f"ensemble {e + 1}" if w == 0 else None)
        ax.set_ylabel(label, fontsize=9)
        ax.grid(alpha=0.3)
        ranks = rankdata(chains[:, :, k].ravel()).reshape(n_chains, n_draws)
        counts = [np.histogram(ranks[e * n_walkers:(e + 1) * n_walkers], edges)[0]
                  for e in range(n_ensembles)]
        height = 1.15 * max(expected, max(c.max() for c in counts))
        axr = axes[k, 1]
        for e, c in enumerate(counts):
            axr.stairs(c + e * height, edges, baseline=e * height, fill=True, color=f"C{e % 10}", alpha=0.7)
            axr.axhline(e * height + expected, color="k", ls="--", lw=0.7)
        # ensembles are told apart by colour (legend of the trace panel); few ticks keep drawing fast
        axr.yaxis.set_major_locator(NullLocator())
        axr.xaxis.set_major_locator(MaxNLocator(3))
        axr.set_xlim(edges[0], edges[-1])
        axr.tick_params(axis="x", labelsize=7)
        ax.yaxis.set_major_locator(MaxNLocator(4))
    axes[-1, 0].set_xlabel("draw (after burn-in, thinned) [-]")
    axes[-1, 1].set_xlabel("rank among all draws [-]")
    axes[0, 0].set_title(f"traces, {shown} walker(s) per ensemble", fontsize=9)
    axes[0, 1].set_title("rank histograms per ensemble (bottom: 1)", fontsize=9)
    ent = result.entry
    state = "" if "converged" not in ent else (", converged" if ent["converged"] else ", NOT converged")
    fig.suptitle(f"{ent.get('id', '')}: R-hat max {ent.get('rhat_max', float('nan')):.3f}, "
                 f"bulk ESS min {ent.get('ess_bulk_min', float('nan')):.0f}{state}",
                 fontsize=10, color="k" if ent.get("converged", True) else "C3")
    axes[0, 0].legend(loc="upper right", fontsize=7, ncols=min(n_ensembles, 4))
    return fig


#: Columns of the residual figure, in order: the transients by (kind, direction), then the windows of cycles.
RESIDUAL_GROUPS = (("initial", 1), ("reversal", -1), ("reversal", 1), ("cycles", 0))


def residual_figure(rows: Sequence[Mapping], *, title: str | None = None):
    """Residual F_C − F_E [N] against time since the window's start, before (top) and after (bottom) the
    diagnosis's selected effects.

    Parameters
    ----------
    rows : sequence of mappings
        One per window: ``kind``, ``direction``, ``velocity_m_s``, ``t`` (time since the step or the window's
        start [s], ndarray), ``before`` and ``after`` (residuals [N], ndarrays).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        2 x n axes, one column per group of :data:`RESIDUAL_GROUPS` present in ``rows`` (in that order, then any
        other (kind, direction)), lines coloured by speed.
    """
    import matplotlib as mpl

    present = {(str(r["kind"]), int(r["direction"])) for r in rows}
    groups = [g for g in RESIDUAL_GROUPS if g in present] + sorted(present - set(RESIDUAL_GROUPS))
    if not groups:
        raise ValueError("residual_figure needs at least one window")
    fig = _figure((4.3 * len(groups) + 0.8, 6.5))
    axes = fig.subplots(2, len(groups), sharey="row", squeeze=False)
    v = np.array([r["velocity_m_s"] for r in rows])
    norm = mpl.colors.Normalize(v.min() * 1e3, v.max() * 1e3)
    cmap = mpl.colormaps["viridis"]
    for j, (kind, d) in enumerate(groups):
        for r in rows:
            if (str(r["kind"]), int(r["direction"])) != (kind, d):
                continue
            c = cmap(norm(r["velocity_m_s"] * 1e3))
            axes[0, j].plot(r["t"], np.asarray(r["before"]), color=c, lw=0.6)
            axes[1, j].plot(r["t"], np.asarray(r["after"]), color=c, lw=0.6)
        axes[0, j].set_title("windows of cycles" if kind == "cycles" else f"{kind}, direction {d:+d}")
        axes[1, j].set_xlabel("time since the window's start [s]" if kind == "cycles" else "time since step [s]")
        axes[1, j].sharex(axes[0, j])
    axes[0, 0].set_ylabel("residual before [N]")
    axes[1, 0].set_ylabel("residual after [N]")
    for ax in axes.flat:
        ax.grid(alpha=0.3)
        ax.axhline(0.0, color="k", lw=0.5)
    fig.colorbar(mpl.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes, label="piston speed (peak for cycles) [mm/s]")
    if title:
        fig.suptitle(title)
    return fig
