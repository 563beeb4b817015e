"""The paper's figures 3, 6, 8 and 9, with credible intervals where the paper has point estimates.

Every function takes data (plain arrays, the package's dataclasses, ``summary.json`` entries) and
returns a :class:`matplotlib.figure.Figure`; nothing is shown or written here (saving is
:func:`bayesdamper.io.outputs.save_figure`). Matplotlib is imported inside the functions. Display units,
colours and markers: :mod:`bayesdamper.report.style`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from bayesdamper.core.params import PAPER_FLOW, RIG_A_DAMPER, DamperConstants, DynamicParameters, FlowCoefficients
from bayesdamper.report.style import (
    DIRECTION_STYLE,
    FLOW_DISPLAY,
    FORCE_DISPLAY,
    KIND_MARKER,
    NOT_CONVERGED_COLOR,
    PRESSURE_DISPLAY,
    SPEED_DISPLAY,
    STATIC_BAND_SE,
    _figure,
    _groups,
    _pct,
    _plain_log_formatter,
)

__all__ = ["figure3_static", "figure6_parametric", "figure8_transients", "figure9_drift", "parametric_curves"]


# --------------------------------------------------------------------------------------- Figure 3
def figure3_static(static_fit, *, n_grid: int = 200, band_se: float = STATIC_BAND_SE,
                   title: str | None = None):
    """Figure 3: stage-1 plateau points and the fitted eq. (4) curve per flow direction.

    Parameters
    ----------
    static_fit : bayesdamper.inference.stage1.StaticFit
        Both directions' least-squares fits with their plateau points (Q [m^3/s], Δp [Pa]).
    n_grid : int
        Points of each fitted curve (the plateau flow rates are added to the grid, so the curve passes
        exactly through ``predict`` at every plateau's Q).
    band_se : float
        Half-width of the shaded band in standard errors of the fitted mean curve,
        ``sqrt(g^T C g)`` with ``g = [Q, Q^2]`` and C the covariance of (C_L, C_Q).

    Returns
    -------
    matplotlib.figure.Figure
        One axes; |Q| [10^-6 m^3/s] against |Δp| [MPa]. The fitted lines carry gids
        ``"static-fit-12"`` / ``"static-fit-21"``, the plateau points ``"plateaus-12"`` / ``"plateaus-21"``.
    title : str, optional
        Figure title (e.g. the data set's name).
    """
    fig = _figure((6.4, 4.6))
    ax = fig.add_subplot()
    text = []
    for fit in (static_fit.forward, static_fit.backward):
        style = DIRECTION_STYLE[fit.direction]
        tag = "12" if fit.direction == 1 else "21"
        q = np.asarray(fit.flow_rate, dtype=float)
        grid = np.union1d(np.linspace(0.0, 1.05 * q.max(), n_grid), q)
        g = np.column_stack([grid, grid * grid])
        pred = fit.predict(grid)
        se = np.sqrt(np.maximum(np.einsum("ni,ij,nj->n", g, fit.covariance, g), 0.0))
        ax.fill_between(grid * FLOW_DISPLAY, (pred - band_se * se) * PRESSURE_DISPLAY,
                        (pred + band_se * se) * PRESSURE_DISPLAY, color=style["color"], alpha=0.2, lw=0,
                        label=f"{tag}: ±{band_se:g} standard errors")
        ax.plot(grid * FLOW_DISPLAY, pred * PRESSURE_DISPLAY, color=style["color"], lw=1.5,
                label=f"{tag}: eq. (4) fit", gid=f"static-fit-{tag}")
        ax.plot(q * FLOW_DISPLAY, np.asarray(fit.pressure_drop) * PRESSURE_DISPLAY, ls="none",
                marker="o" if fit.direction == 1 else "s", mfc="none", mec=style["color"], ms=6, mew=1.2,
                label=f"{tag}: plateaus (n = {fit.n})", gid=f"plateaus-{tag}")
        se_l, se_q = fit.standard_errors
        text.append(f"$C_{{L,{tag}}}$ = {fit.laminar:.4g} ± {se_l:.2g} kg m$^{{-4}}$ s$^{{-1}}$\n"
                    f"$C_{{Q,{tag}}}$ = {fit.quadratic:.4g} ± {se_q:.2g} kg m$^{{-7}}$")
    ax.text(0.98, 0.03, "\n".join(text) + "\n(± one standard error)", transform=ax.transAxes, ha="right",
            va="bottom", fontsize=8, bbox={"boxstyle": "round", "fc": "white", "ec": "0.8"})
    ax.set_xlabel("flow rate |Q| [10$^{-6}$ m$^3$/s]")
    ax.set_ylabel("pressure drop |Δp| [MPa]")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.set_title("Stage 1: pressure-flow characteristic, eq. (4)" + (f", {title}" if title else ""))
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _drift_note(d: Mapping, name: str, credible_mass: float) -> str:
    s = d["slope_per_m_s"]
    if name == "p_R_Pa":
        k, unit = 1e-3 * 1e-3, "kPa per mm/s"  # Pa/(m/s) -> Pa/(mm/s) -> kPa/(mm/s)
    else:
        k, unit = 1e-3, "per mm/s"
    verdict = "credibly non-zero" if d["credible_nonzero"] else "not credibly non-zero"
    return (f"trend slope {k * s['median']:.3g} {unit}\n"
            f"{_pct(credible_mass)} interval [{k * s['lo']:.3g}, {k * s['hi']:.3g}]: {verdict}")


def _draw_law(ax, v_mm_s: np.ndarray, law: Mapping, name: str) -> None:
    """The hierarchical law on one Figure 9 panel: p_R in MPa, α_V as 100/α_V (bands swap ends)."""
    def y(a):
        a = np.asarray(a, float)
        return a * PRESSURE_DISPLAY if name == "p_R_Pa" else 100.0 / a

    band = law["law"]
    ax.fill_between(v_mm_s, y(band["lo"]), y(band["hi"]), color="0.5", alpha=0.2, lw=0, zorder=0,
                    gid=f"law-band-{name}")
    ax.fill_between(v_mm_s, y(band["q25"]), y(band["q75"]), color="0.4", alpha=0.3, lw=0, zorder=0,
                    gid=f"law-band50-{name}")
    ax.plot(v_mm_s, y(band["median"]), color="k", lw=1.2, zorder=1, gid=f"law-{name}")
    if "new_test" in law:
        for k in ("lo", "hi"):
            ax.plot(v_mm_s, y(law["new_test"][k]), color="k", lw=0.8, ls=":", zorder=1, gid=f"law-new-{k}-{name}")


def figure9_drift(entries: Sequence[Mapping], drift: Mapping | None = None, credible_mass: float = 0.9, *,
                  dodge: float = 0.012, yscale: str = "log", title: str | None = None, law: Mapping | None = None):
    """Figure 9: identified p_R and 100/α_V against piston speed, with credible intervals.

    Parameters
    ----------
    entries : sequence of dict
        ``summary.json`` segment entries (``direction``, ``kind``, ``velocity_m_s``, ``converged``,
        ``alpha_V`` and ``p_R_Pa`` as ``{median, lo, hi}``, ``ls`` with the Nelder-Mead point).
    drift : dict, optional
        ``summary["drift"]``: for ``"alpha_V"`` and ``"p_R_Pa"`` the trend ``intercept`` and
        ``slope_per_m_s`` (``{median, lo, hi}``, parameter units and per m/s) and ``credible_nonzero``.
        The median line ``intercept + slope v`` is drawn (on the 100/α_V panel as ``100 / (a + b v)``).
    credible_mass : float
        Mass of the intervals in ``entries`` (for the labels only).
    dodge : float
        Horizontal offset between the direction/kind groups at one speed [mm/s], so that error bars
        at the same speed do not hide one another.
    yscale : {"log", "linear"}
        Scale of both vertical axes. Log by default: the priors are log-uniform and posteriors of
        poorly constrained transients span decades (the paper's Fig. 9 is linear).
    title : str, optional
        Figure title (e.g. the data set's name).
    law : dict, optional
        The hierarchical drift law (``summary["drift_model"]``, :meth:`~bayesdamper.inference.hierarchy.
        HierarchyFit.summary`): drawn instead of the straight line, as its median, its 50 % and credible bands
        (the population law) and dotted lines bounding a new test's parameters (the law plus the scatter between
        tests).

    Returns
    -------
    matplotlib.figure.Figure
        Two axes: p_R [MPa] and 100/α_V [%] against |V_P| [mm/s]. Each axes holds one error-bar
        container per (direction, kind) group of converged transients, plus one grey container per
        group that has non-converged transients (grey face and bars, direction colour on the marker
        edge). The 100/α_V interval is [100/hi, 100/lo].
    """
    from matplotlib.lines import Line2D

    fig = _figure((11.0, 4.8))
    ax_p, ax_a = fig.subplots(1, 2)
    groups = _groups(entries)
    offsets = {g: (i - (len(groups) - 1) / 2) * dodge for i, g in enumerate(groups)}
    any_grey = False
    for g in groups:
        direction, kind = g
        colour = DIRECTION_STYLE.get(direction, {"color": "k"})["color"]
        marker = KIND_MARKER.get(kind, "D")
        for converged in (True, False):
            sel = [e for e in entries if (int(e["direction"]), str(e["kind"])) == g
                   and bool(e["converged"]) == converged]
            if not sel:
                continue
            any_grey |= not converged
            c = colour if converged else NOT_CONVERGED_COLOR
            edge = colour  # keeps the direction visible on greyed (non-converged) points
            v = np.array([e["velocity_m_s"] for e in sel]) * SPEED_DISPLAY + offsets[g]
            p = np.array([[e["p_R_Pa"][k] for k in ("median", "lo", "hi")] for e in sel]) * PRESSURE_DISPLAY
            a = np.array([[e["alpha_V"][k] for k in ("median", "hi", "lo")] for e in sel])
            inv = 100.0 / a  # median, lo (= 100/hi), hi (= 100/lo)
            ls_p = np.array([e["ls"]["p_R_Pa"] for e in sel]) * PRESSURE_DISPLAY
            ls_a = 100.0 / np.array([e["ls"]["alpha_V"] for e in sel])
            tag = f"{'12' if direction == 1 else '21'}-{kind}-{'ok' if converged else 'not-converged'}"
            for ax, y, ls_y in ((ax_p, p, ls_p), (ax_a, inv, ls_a)):
                err = np.maximum(np.vstack([y[:, 0] - y[:, 1], y[:, 2] - y[:, 0]]), 0.0)
                ax.errorbar(v, y[:, 0], yerr=err, ls="none", marker=marker, color=c, mec=edge, ms=6,
                            capsize=2, lw=1, zorder=3, gid=f"posterior-{tag}")
                ax.plot(v, ls_y, ls="none", marker=marker, mfc="none", mec=edge, ms=10, mew=1,
                        zorder=2, gid=f"ls-{tag}")
    speeds = np.array([e["velocity_m_s"] for e in entries], dtype=float)
    have_line = False
    for name, ax in (("p_R_Pa", ax_p), ("alpha_V", ax_a)):
        lw = ((law or {}).get("parameters") or {}).get(name) if (law or {}).get("fitted", True) else None
        if lw:
            _draw_law(ax, np.asarray(law["speed_grid_m_s"]) * SPEED_DISPLAY, lw, name)
            have_line = True
            continue
        d = (drift or {}).get(name)
        if not d or speeds.size == 0:
            continue
        vg = np.linspace(speeds.min(), speeds.max(), 100)
        y = d["intercept"]["median"] + d["slope_per_m_s"]["median"] * vg
        if name == "p_R_Pa":
            y = y * PRESSURE_DISPLAY
        else:
            y = np.where(y > 0, 100.0 / np.where(y > 0, y, 1.0), np.nan)
        ax.plot(vg * SPEED_DISPLAY, y, color="k", lw=1.2, zorder=1, gid=f"drift-{name}")
        have_line = True
        # above the axes, under the panel title, so that it never hides data
        ax.text(0.5, 1.015, _drift_note(d, name, credible_mass), transform=ax.transAxes, va="bottom",
                ha="center", fontsize=8, gid=f"drift-note-{name}")
    for ax, panel in ((ax_p, "(a) reference pressure"), (ax_a, "(b) gas content")):
        ax.set_xlabel("piston speed |V_P| [mm/s]" if not any(g[1] == "cycles" for g in groups) else
                      "piston speed |V_P|, of cycles their peak [mm/s]")
        ax.set_yscale(yscale)
        if yscale == "log":  # plain numbers ("20", "0.5") rather than mathtext powers of ten
            ax.yaxis.set_major_formatter(_plain_log_formatter(labelOnlyBase=False))
            ax.yaxis.set_minor_formatter(_plain_log_formatter(labelOnlyBase=False, minor_thresholds=(2, 0.5)))
        ax.grid(alpha=0.3, which="both" if yscale == "linear" else "major")
        ax.set_title(panel, fontsize=11, pad=30 if ax.texts else 6)
    ax_p.set_ylabel("reference pressure p_R [MPa]")
    ax_a.set_ylabel("gas-liquid volume ratio 100/α_V [%]")
    if title:
        fig.suptitle(title, fontsize=10)

    handles = [Line2D([], [], color=s["color"], lw=0, marker="s", ms=7, label=f"direction {s['label']}")
               for d_, s in DIRECTION_STYLE.items() if any(g[0] == d_ for g in groups)]
    step = {"initial": "step from rest", "reversal": "reversal", "cycles": "window of cycles (peak speed)"}
    handles += [Line2D([], [], color="k", lw=0, marker=KIND_MARKER.get(k, "D"), ms=6, label=step.get(k, k))
                for k in dict.fromkeys(g[1] for g in groups)]
    handles.append(Line2D([], [], color="k", marker="o", ms=4, lw=1,
                          label=f"posterior median, {_pct(credible_mass)} credible interval"))
    handles.append(Line2D([], [], color="k", lw=0, marker="o", mfc="none", ms=9, label="Nelder-Mead (LS)"))
    if any_grey:
        handles.append(Line2D([], [], color=NOT_CONVERGED_COLOR, lw=0, marker="o", mec="k", ms=6,
                              label="sampler not converged (grey)"))
    if have_line and law:
        from matplotlib.patches import Patch

        handles += [Line2D([], [], color="k", lw=1.2, label="drift law, posterior median"),
                    Patch(color="0.5", alpha=0.35, label=f"law: 50 % and {_pct(credible_mass)} bands"),
                    Line2D([], [], color="k", lw=0.8, ls=":",
                           label=f"a new test ({_pct(credible_mass)}): law + scatter between and within tests")]
    elif have_line:
        handles.append(Line2D([], [], color="k", lw=1.2, label="trend, posterior median"))
    fig.legend(handles=handles, loc="outside lower center", ncols=min(4, len(handles)), fontsize=8,
               frameon=False)
    return fig


# --------------------------------------------------------------------------------------- Figure 8
def figure8_transients(results: Sequence, max_panels: int = 12, *, ncols: int = 4,
                       credible_mass: float = 0.9, title: str | None = None):
    """Figure 8: measured transients with the posterior predictive band and the Nelder-Mead fit.

    Parameters
    ----------
    results : sequence of bayesdamper.inference.stage2.WindowResult
        Each with ``time`` (absolute) [s], ``force`` [N], ``band`` shape (3, n_times) [N],
        ``ls_force`` [N] and ``entry`` (``id``, ``t_start_s``, ``J``, ``ls["J"]``, ``direction``,
        ``converged``).
    max_panels : int
        At most this many panels (the first ``max_panels`` results); page longer lists outside.
    ncols : int
        Panels per row (at most).
    credible_mass : float
        Mass of the predictive band (for the legend only).
    title : str, optional
        Figure title (e.g. the data set's name and the page).

    Returns
    -------
    matplotlib.figure.Figure
        One axes per plotted transient: force [kN] against time since the velocity step [s].
    """
    rs = list(results)[:max_panels]
    if not rs:
        raise ValueError("figure8_transients needs at least one transient result")
    n = len(rs)
    ncols = max(1, min(ncols, n))
    nrows = math.ceil(n / ncols)
    # Fixed margins rather than a layout engine: this figure is drawn once per page of every run.
    height = 2.3 * nrows + 0.7 + (0.35 if title else 0.0)
    fig = _figure((3.1 * ncols, height), layout=None)
    fig.subplots_adjust(left=0.35 / ncols + 0.02, right=0.99, top=1 - (0.75 if title else 0.45) / height,
                        bottom=0.75 / height, hspace=0.6, wspace=0.3)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[n:]:
        fig.delaxes(ax)
    for i, (ax, r) in enumerate(zip(axes, rs, strict=False)):
        e = r.entry
        t = np.asarray(r.time) - float(e["t_start_s"])
        colour = DIRECTION_STYLE.get(int(e["direction"]), {"color": "k"})["color"]
        band = np.asarray(r.band) * FORCE_DISPLAY
        ax.plot(t, np.asarray(r.force) * FORCE_DISPLAY, color="0.45", lw=0.7, label="measured")
        ax.fill_between(t, band[0], band[2], color=colour, alpha=0.3, lw=0,
                        label=f"{_pct(credible_mass)} posterior predictive")
        ax.plot(t, band[1], color=colour, lw=1.3, label="posterior predictive median (blue 12, red 21)")
        ax.plot(t, np.asarray(r.ls_force) * FORCE_DISPLAY, color="k", ls="--", lw=1.0, label="Nelder-Mead")
        ok = bool(e.get("converged", True))
        ls_j = e.get("ls", {}).get("J", float("nan"))
        ax.set_title(f"{e['id']}\nJ = {e['J']:.3f} (NM {ls_j:.3f}){'' if ok else ', NOT converged'}",
                     fontsize=8, color="k" if ok else "C3")
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if i % ncols == 0:
            ax.set_ylabel("force [kN]", fontsize=8)
        if i + ncols >= n:
            ax.set_xlabel("time since step [s]", fontsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncols=4, fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    if title:
        fig.suptitle(title, fontsize=10, y=1 - 0.1 / height, va="top")
    return fig


# --------------------------------------------------------------------------------------- Figure 6
def parametric_curves(velocity: float = 1.5e-3, *, t_end: float = 3.0, n_times: int = 601,
                      damper: DamperConstants = RIG_A_DAMPER, flow: FlowCoefficients = PAPER_FLOW,
                      p_r_values: Sequence[float] = (0.1e6, 0.3e6, 0.4e6),
                      inverse_alpha_values: Sequence[float] = (0.01, 0.033, 0.04),
                      fixed_alpha_v: float = 1 / 0.03, fixed_p_r: float = 0.3e6,
                      amplitude: float = 5e-3) -> dict:
    """Simulated initial transients of the parametric study (paper Fig. 6), eq. (7) from rest.

    The piston starts from rest at t = 0 (Δp(0) = 0) on a triangular displacement of amplitude
    ``amplitude`` [m] at speed ``velocity`` [m/s].

    Returns
    -------
    dict
        ``time_s`` (ndarray, shape (n_times,)), ``steady_force_N`` (eq. (4) at Q = A_P V_P),
        ``p_R`` {p_R [Pa]: force [N] at ``fixed_alpha_v``} and ``inverse_alpha``
        {1/α_V [-]: force [N] at ``fixed_p_r``}.
    """
    from bayesdamper.physics.excitation import PiecewiseLinear
    from bayesdamper.physics.single_state import simulate_single_state

    t = np.linspace(0.0, t_end, n_times)
    exc = PiecewiseLinear.triangle(amplitude, velocity, rest=0.0, cycles=1.25)

    def force(alpha_v: float, p_r: float) -> np.ndarray:
        dp = simulate_single_state(t, exc, damper, flow, DynamicParameters(alpha_v, p_r), dp0=0.0, t0=0.0)
        return damper.piston_area * dp

    q = damper.piston_area * velocity
    steady = damper.piston_area * (flow.laminar_12 * q + flow.quadratic_12 * q * q)
    return {
        "time_s": t,
        "steady_force_N": float(steady),
        "p_R": {float(p): force(fixed_alpha_v, p) for p in p_r_values},
        "inverse_alpha": {float(ia): force(1.0 / ia, fixed_p_r) for ia in inverse_alpha_values},
        "velocity_m_s": float(velocity),
        "fixed_alpha_v": float(fixed_alpha_v),
        "fixed_p_r_Pa": float(fixed_p_r),
    }


def figure6_parametric(velocity: float = 1.5e-3, *, curves: Mapping | None = None, **kwargs):
    """Figure 6: parametric study of the initial transient in p_R and 1/α_V.

    Parameters
    ----------
    velocity : float
        Piston speed [m/s] (default 1.5 mm/s, as in the paper).
    curves : dict, optional
        Output of :func:`parametric_curves`; computed with ``velocity`` and ``kwargs`` if None.
    **kwargs
        Passed to :func:`parametric_curves` (``t_end``, ``n_times``, ``damper``, ``flow``, ...).

    Returns
    -------
    matplotlib.figure.Figure
        Two axes, force [kN] against time since the step [s]: (a) p_R varied at fixed α_V,
        (b) 1/α_V varied at fixed p_R; one line per value plus the eq. (4) steady-state force.
    """
    c = curves if curves is not None else parametric_curves(velocity, **kwargs)
    t = np.asarray(c["time_s"])
    fig = _figure((11.0, 4.3))
    ax_p, ax_a = fig.subplots(1, 2, sharey=True)
    styles = ["-", "--", "-."]
    for i, (p_r, f) in enumerate(c["p_R"].items()):
        ax_p.plot(t, np.asarray(f) * FORCE_DISPLAY, ls=styles[i % 3], color=f"C{i}", lw=1.5,
                  label=f"p_R = {p_r * PRESSURE_DISPLAY:.2g} MPa")
    for i, (ia, f) in enumerate(c["inverse_alpha"].items()):
        ax_a.plot(t, np.asarray(f) * FORCE_DISPLAY, ls=styles[i % 3], color=f"C{i}", lw=1.5,
                  label=f"1/α_V = {ia:.3g}")
    for ax in (ax_p, ax_a):
        ax.axhline(c["steady_force_N"] * FORCE_DISPLAY, color="0.5", ls=":", lw=1,
                   label="steady state, eq. (4)")
        ax.set_xlabel("time since step [s]")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=8)
        ax.set_xlim(t[0], t[-1])
    ax_p.set_ylabel("damper force F_D [kN]")
    v = c["velocity_m_s"] * SPEED_DISPLAY
    ax_p.set_title(f"(a) p_R varied, α_V = 1/{1 / c['fixed_alpha_v']:.3g}, V_P = {v:.3g} mm/s", fontsize=10)
    ax_a.set_title(f"(b) α_V varied, p_R = {c['fixed_p_r_Pa'] * PRESSURE_DISPLAY:.3g} MPa, "
                   f"V_P = {v:.3g} mm/s", fontsize=10)
    return fig


#: Longest stretch of a window shown against time [s] (the loops show all of it).
LOOP_TIME_S = 5.0


def window_loops(result, displacement: np.ndarray, velocity: np.ndarray, credible_mass: float = 0.9,
                 title: str | None = None):
    """A window of whole cycles against its posterior predictive: force against time (its first
    ``LOOP_TIME_S``), force against displacement and force against velocity (the loops a test engineer reads),
    measured in grey, the predictive median and band in colour, the least-squares fit dashed.

    ``displacement`` [m] and ``velocity`` [m/s] at the window's samples (the reconstructed input's velocity).
    """
    t, f = result.time, result.force
    lo, med, hi = result.band
    fig = _figure((12.0, 3.6))
    axes = fig.subplots(1, 3)
    sel = t <= t[0] + LOOP_TIME_S
    ax = axes[0]
    ax.plot(t[sel], f[sel], color="0.6", lw=1.0, label="measured")
    ax.fill_between(t[sel], lo[sel], hi[sel], color="C0", alpha=0.3, lw=0, label=f"{_pct(credible_mass)} band")
    ax.plot(t[sel], med[sel], color="C0", lw=1.0, label="posterior predictive median")
    ax.plot(t[sel], result.ls_force[sel], "--", color="C3", lw=0.8, label="least squares")
    ax.set(xlabel="time [s]", ylabel="force [N]", title=title or f"{result.entry['id']}: J = {result.entry['J']:.3f}")
    ax.legend(fontsize=7, loc="best")
    for ax, x, lab in ((axes[1], 1e3 * np.asarray(displacement), "displacement [mm]"),
                       (axes[2], 1e3 * np.asarray(velocity), "velocity [mm/s]")):
        ax.plot(x, f, ".", color="0.6", ms=1.5, label="measured")
        ax.plot(x, med, color="C0", lw=0.8, label="predictive median")
        ax.set(xlabel=lab, ylabel="force [N]")
    return fig
