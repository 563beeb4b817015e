"""Plot functions return Figures with the expected axes and artists (synthetic inputs, no sampling), for
transients and windows of cycles; the identify and diagnosis figure writers draw what each kind of window needs."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

from matplotlib.container import ErrorbarContainer  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from bayesdamper.inference.stage1 import StaticFit, fit_direction  # noqa: E402
from bayesdamper.inference.stage2 import WindowResult  # noqa: E402
from bayesdamper.report import diagnostic_plots, figures, paper_figures, style  # noqa: E402
from bayesdamper.report.figures import write_identify_figures  # noqa: E402

#: Relative tolerance for reading plotted values back (float64 round trip through display scaling).
READBACK_RTOL = 1e-12

N_ENSEMBLES, N_WALKERS, N_DRAWS = 2, 4, 50
NAMES = ("alpha_V", "p_R_Pa", "phi")


@pytest.fixture
def static_fit() -> StaticFit:
    rng = np.random.default_rng(0)
    q = np.linspace(1e-6, 6e-6, 6)
    fits = []
    for direction, (cl, cq) in ((1, (2.4e10, 4.3e16)), (-1, (0.9e10, 5.1e16))):
        dp = cl * q + cq * q * q
        fits.append(fit_direction(q, dp * (1 + 0.02 * rng.standard_normal(q.size)), direction))
    return StaticFit(*fits)


def _entry(i: int, direction: int, kind: str, v: float, converged: bool = True) -> dict:
    a, p = 30.0 + 5 * i, 2e5 + 1e4 * i
    return {
        "id": f"test{i}_s{i % 3}", "test": f"test{i}", "kind": kind, "direction": direction,
        "velocity_m_s": v, "t_start_s": 1.0 + i,
        "alpha_V": {"median": a, "lo": 0.8 * a, "hi": 1.3 * a},
        "p_R_Pa": {"median": p, "lo": 0.9 * p, "hi": 1.2 * p},
        "ls": {"alpha_V": 1.05 * a, "p_R_Pa": 0.97 * p, "J": 0.05},
        "J": 0.04, "rhat_max": 1.005, "ess_bulk_min": 1500.0, "converged": converged,
        "posterior_mean": {"alpha_V": a, "p_R_Pa": p},
        "posterior_sd": {"alpha_V": 0.1 * a, "p_R_Pa": 0.1 * p},
    }


@pytest.fixture
def entries() -> list[dict]:
    out = []
    for i, v in enumerate((0.5e-3, 1.0e-3, 1.5e-3)):
        out.append(_entry(3 * i, 1, "initial", v))
        out.append(_entry(3 * i + 1, -1, "reversal", v, converged=i != 1))
        out.append(_entry(3 * i + 2, 1, "reversal", v))
    return out


def _result(entry: dict, seed: int = 0) -> WindowResult:
    rng = np.random.default_rng(seed)
    n_chains = N_ENSEMBLES * N_WALKERS
    med = np.array([entry["alpha_V"]["median"], entry["p_R_Pa"]["median"], 0.9])
    chains = med * (1 + 0.05 * rng.standard_normal((n_chains, N_DRAWS, 3)))
    t = entry["t_start_s"] + np.arange(0, 3.0, 0.004)
    f = entry["direction"] * 4000.0 * (1 - np.exp(-(t - t[0]) / 0.3))
    band = np.vstack([0.95 * f, f, 1.05 * f])
    return WindowResult(entry, NAMES, chains, t, f + 20 * rng.standard_normal(t.size), band, 0.98 * f)


@pytest.fixture
def results(entries) -> list[WindowResult]:
    return [_result(e, k) for k, e in enumerate(entries)]


def test_figure3_curves_pass_through_predict(static_fit):
    fig = paper_figures.figure3_static(static_fit)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 1
    ax = fig.axes[0]
    lines = {ln.get_gid(): ln for ln in ax.get_lines()}
    assert ax.get_xlabel().endswith("m$^3$/s]") and "[MPa]" in ax.get_ylabel()
    for fit, tag in ((static_fit.forward, "12"), (static_fit.backward, "21")):
        line = lines[f"static-fit-{tag}"]
        x, y = line.get_xydata().T
        q_pts = fit.flow_rate * style.FLOW_DISPLAY
        at_pts = np.interp(q_pts, x, y)
        np.testing.assert_allclose(at_pts, fit.predict(fit.flow_rate) * style.PRESSURE_DISPLAY,
                                   rtol=READBACK_RTOL)
        pts = lines[f"plateaus-{tag}"].get_xydata()
        np.testing.assert_allclose(pts[:, 1], fit.pressure_drop * style.PRESSURE_DISPLAY, rtol=READBACK_RTOL)
    assert len(ax.collections) == 2  # one ±2 SE band per direction
    for band, fit in zip(ax.collections, (static_fit.forward, static_fit.backward), strict=True):
        verts = band.get_paths()[0].vertices
        for q in fit.flow_rate:
            ys = verts[np.isclose(verts[:, 0], q * style.FLOW_DISPLAY, rtol=1e-12, atol=0), 1]
            g = np.array([q, q * q])
            half = style.STATIC_BAND_SE * np.sqrt(g @ fit.covariance @ g) * style.PRESSURE_DISPLAY
            assert ys.max() - ys.min() == pytest.approx(2 * half, rel=1e-9)
            mid = (ys.max() + ys.min()) / 2
            assert mid == pytest.approx(fit.predict(q) * style.PRESSURE_DISPLAY, rel=READBACK_RTOL)


def test_figure9_one_errorbar_container_per_group(entries):
    fig = paper_figures.figure9_drift(entries)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2
    # groups: (12, initial), (21, reversal), (12, reversal), all converged, plus one grey container
    # for the non-converged (21, reversal) transient
    for ax in fig.axes:
        containers = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
        assert len(containers) == 4
        assert sum(len(c.lines[0].get_xdata()) for c in containers) == len(entries)
        assert "[mm/s]" in ax.get_xlabel() and "[" in ax.get_ylabel()
        ls_lines = [ln for ln in ax.get_lines() if (ln.get_gid() or "").startswith("ls-")]
        assert sum(len(ln.get_xdata()) for ln in ls_lines) == len(entries)
        assert all(ln.get_markerfacecolor() == "none" for ln in ls_lines)
    assert not any((ln.get_gid() or "").startswith("drift") for ax in fig.axes for ln in ax.get_lines())


def test_figure9_inverse_alpha_interval_and_drift_line(entries):
    drift = {
        "alpha_V": {"slope_per_m_s": {"median": 1e4, "lo": 5e3, "hi": 2e4}, "intercept": {"median": 20.0},
                    "credible_nonzero": True},
        "p_R_Pa": {"slope_per_m_s": {"median": 1e7, "lo": -1e7, "hi": 3e7}, "intercept": {"median": 2e5},
                   "credible_nonzero": False},
    }
    fig = paper_figures.figure9_drift(entries[:1], drift)
    ax_p, ax_a = fig.axes
    e = entries[0]
    c = ax_a.containers[0]
    y = c.lines[0].get_ydata()[0]
    assert y == pytest.approx(100 / e["alpha_V"]["median"])
    seg = c.lines[2][0].get_segments()[0]
    assert sorted(seg[:, 1]) == pytest.approx([100 / e["alpha_V"]["hi"], 100 / e["alpha_V"]["lo"]])
    line = next(ln for ln in ax_p.get_lines() if ln.get_gid() == "drift-p_R_Pa")
    x, yl = line.get_xydata().T
    np.testing.assert_allclose(yl, (2e5 + 1e7 * x / style.SPEED_DISPLAY) * style.PRESSURE_DISPLAY,
                               rtol=1e-9)
    assert any(ln.get_gid() == "drift-alpha_V" for ln in ax_a.get_lines())
    texts = " ".join(t.get_text() for t in ax_p.texts)
    assert "not credibly non-zero" in texts


def test_figure8_panels_and_bands(results):
    fig = paper_figures.figure8_transients(results, max_panels=5)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 5
    for ax, r in zip(fig.axes, results, strict=False):
        assert len(ax.get_lines()) == 3  # measured, predictive median, Nelder-Mead
        assert len(ax.collections) == 1  # predictive band
        x = ax.get_lines()[0].get_xdata()
        assert x[0] == pytest.approx(0.0)
        assert r.entry["id"] in ax.get_title()
    assert fig.axes[0].get_ylabel() == "force [kN]"
    assert len(paper_figures.figure8_transients(results).axes) == len(results)


def test_corner_plot(results):
    fig = diagnostic_plots.corner_plot(results[0], bins=10)
    assert isinstance(fig, Figure)
    k = len(NAMES)
    assert len(fig.axes) == k * (k + 1) // 2  # lower triangle and diagonal; the blank upper ones removed
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert len(titles) == k and titles[0].startswith("α_V = ")


def test_trace_rank_plot(results):
    r = results[0]
    fig = diagnostic_plots.trace_rank_plot(r, N_ENSEMBLES, walkers_per_ensemble=2)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2 * len(NAMES)
    trace_axes, rank_axes = fig.axes[0::2], fig.axes[1::2]
    assert all(len(ax.get_lines()) == N_ENSEMBLES * 2 for ax in trace_axes)
    for ax in rank_axes:
        assert len(ax.patches) == N_ENSEMBLES
    with pytest.raises(ValueError):
        diagnostic_plots.trace_rank_plot(r, 3)


def test_figure6_from_given_curves():
    t = np.linspace(0, 3, 50)
    curves = {"time_s": t, "steady_force_N": 4000.0, "velocity_m_s": 1.5e-3, "fixed_alpha_v": 1 / 0.03,
              "fixed_p_r_Pa": 3e5,
              "p_R": {p: 4000 * (1 - np.exp(-t / (0.1 + p * 1e-6))) for p in (1e5, 3e5, 4e5)},
              "inverse_alpha": {a: 4000 * (1 - np.exp(-t / (10 * a))) for a in (0.01, 0.033, 0.04)}}
    fig = paper_figures.figure6_parametric(curves=curves)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 2
    for ax in fig.axes:
        assert len(ax.get_lines()) == 4  # three values + steady state
        assert "[s]" in ax.get_xlabel()


def test_figure6_simulates():
    fig = paper_figures.figure6_parametric(n_times=30, t_end=1.0)
    ax_p, ax_a = fig.axes
    forces = [ln.get_ydata() for ln in ax_p.get_lines()[:3]]
    assert all(np.all(np.isfinite(f)) for f in forces)
    assert forces[0][0] == pytest.approx(0.0, abs=1e-9)
    assert forces[0][-1] > 0


def test_write_identify_figures(tmp_path, static_fit, results, entries):
    summary = {"segments": entries, "credible_mass": 0.9, "drift": {},
               "settings": {"sampler": {"n_ensembles": N_ENSEMBLES}}}
    out = write_identify_figures(tmp_path, None, [], static_fit, results[:2], summary)
    assert set(out) == {"figure3_static", "figure8_transients", "figure9_drift", "loops", "corner", "trace"}
    assert out["loops"] == []  # loops are drawn for windows of whole cycles only (tests/test_cycle_windows.py)
    assert out["figure3_static"] == ["figures/figure3_static.png", "figures/figure3_static.pdf"]
    assert out["corner"] == [f"figures/corner/{r.entry['id']}.png" for r in results[:2]]
    for paths in out.values():
        for p in paths:
            assert (tmp_path / p).stat().st_size > 0


# ------------------------------------------------------------------------------------------- windows of cycles
def _cycle_entry(i: int, v: float = 0.063) -> dict:
    e = _entry(i, 0, "cycles", v)
    e.update(id=f"sine{i}_w0", test=f"sine{i}")
    return e


def _cycle_result(entry: dict, seed: int = 0) -> WindowResult:
    """A window of 3 cycles of a 1 Hz sine: force 200 sin(2π t + 0.3) N, its predictive band ±5 %."""
    rng = np.random.default_rng(seed)
    n_chains = N_ENSEMBLES * N_WALKERS
    med = np.array([entry["alpha_V"]["median"], entry["p_R_Pa"]["median"], 0.1])
    chains = med * (1 + 0.05 * rng.standard_normal((n_chains, N_DRAWS, 3)))
    t = entry["t_start_s"] + np.arange(0, 3.0, 0.01)
    f = 200.0 * np.sin(2 * np.pi * t + 0.3)
    band = np.vstack([f - 10.0, f, f + 10.0])
    return WindowResult(entry, NAMES, chains, t, f + rng.standard_normal(t.size), band, 0.99 * f)


def _window(result: WindowResult) -> SimpleNamespace:
    """What the figures read of a :class:`bayesdamper.io.windows.Window`: a 10 mm, 1 Hz sine as the input."""
    e = result.entry
    t = np.asarray(result.time)
    return SimpleNamespace(id=e["id"], kind=e["kind"], direction=e["direction"], velocity=e["velocity_m_s"],
                           time=t, t_step=float(t[0]), displacement=0.01 * np.sin(2 * np.pi * t),
                           drive=SimpleNamespace(velocity=lambda x: 0.02 * np.pi * np.cos(2 * np.pi * x)))


def test_window_loops_against_time_displacement_and_velocity():
    r = _cycle_result(_cycle_entry(0))
    w = _window(r)
    fig = paper_figures.window_loops(r, w.displacement, w.drive.velocity(w.time))
    ax_t, ax_y, ax_v = fig.axes
    assert r.entry["id"] in ax_t.get_title() and len(ax_t.collections) == 1  # the predictive band
    sel = r.time <= r.time[0] + paper_figures.LOOP_TIME_S
    np.testing.assert_array_equal(ax_t.get_lines()[0].get_xdata(), r.time[sel])
    measured, median = ax_y.get_lines()
    np.testing.assert_allclose(measured.get_xdata(), 1e3 * w.displacement, rtol=READBACK_RTOL)
    np.testing.assert_allclose(median.get_ydata(), r.band[1], rtol=READBACK_RTOL)
    np.testing.assert_allclose(ax_v.get_lines()[0].get_xdata(), 1e3 * w.drive.velocity(w.time), rtol=READBACK_RTOL)
    assert "[mm]" in ax_y.get_xlabel() and "[mm/s]" in ax_v.get_xlabel()


def test_figure9_places_windows_of_cycles_at_their_peak_speed(entries):
    cyc = [_cycle_entry(20, 1.26e-3), _cycle_entry(21, 1.27e-3)]
    fig = paper_figures.figure9_drift(entries + cyc)
    for ax in fig.axes:
        containers = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
        assert len(containers) == 5  # the four of the transients and one of the windows of cycles
        assert sum(len(c.lines[0].get_xdata()) for c in containers) == len(entries) + 2
        assert "peak" in ax.get_xlabel()
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "window of cycles (peak speed)" in labels
    assert "peak" not in paper_figures.figure9_drift(entries).axes[0].get_xlabel()


def _residual_rows(results) -> list[dict]:
    rng = np.random.default_rng(3)
    return [{"kind": r.entry["kind"], "direction": r.entry["direction"], "velocity_m_s": r.entry["velocity_m_s"],
             "t": np.asarray(r.time) - r.time[0], "before": rng.normal(0, 20, r.time.size),
             "after": rng.normal(0, 10, r.time.size)} for r in results]


def test_residual_figure_has_a_column_per_group_present(results):
    cyc = [_cycle_result(_cycle_entry(k), k) for k in range(2)]
    rows = _residual_rows(results[:2] + cyc)  # an initial (+1), a reversal (-1) and two windows of cycles
    fig = diagnostic_plots.residual_figure(rows)
    axes = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert len(axes) == 6
    top, bottom = axes[:3], axes[3:]
    assert [ax.get_title() for ax in top] == ["initial, direction +1", "reversal, direction -1", "windows of cycles"]
    assert [len(ax.get_lines()) - 1 for ax in top] == [1, 1, 2]  # one line per window, plus the zero line
    np.testing.assert_array_equal(top[2].get_lines()[0].get_ydata(), rows[2]["before"])  # in N
    np.testing.assert_array_equal(bottom[2].get_lines()[1].get_ydata(), rows[3]["after"])
    assert bottom[2].get_xlabel() == "time since the window's start [s]" and "[N]" in top[0].get_ylabel()
    only = diagnostic_plots.residual_figure(rows[2:])
    assert [ax.get_title() for ax in only.axes if ax.get_title()] == ["windows of cycles"]


@pytest.mark.parametrize("kinds", ["transients", "cycles", "both"])
def test_write_diagnosis_figures_for_any_windows(tmp_path, results, kinds):
    base = ([] if kinds == "cycles" else results[:2]) + (
        [] if kinds == "transients" else [_cycle_result(_cycle_entry(k), k) for k in range(2)])
    windows = [_window(r) for r in base]
    resid = [np.zeros(r.time.size) for r in base]
    diagnosis = {"selected": ["friction"], "drift_before": {}, "drift_after": {}}
    out = figures.write_diagnosis_figures(tmp_path, windows, base, base, resid, resid, diagnosis, workers=1)
    steps, cycles = kinds != "cycles", kinds != "transients"
    assert {"residuals", "figure9_before", "figure9_after"} <= set(out)
    assert ("figure8_before" in out and "figure8_after" in out) == steps
    if cycles:
        assert out["loops_before"] == [f"figures/diagnosis_loops/sine{k}_w0_before.png" for k in range(2)]
        assert out["loops_after"] == [f"figures/diagnosis_loops/sine{k}_w0_after.png" for k in range(2)]
    else:
        assert "loops_before" not in out
    for paths in out.values():
        for p in paths:
            assert (tmp_path / p).stat().st_size > 0


def test_write_identify_figures_draws_the_loops_of_windows_of_cycles(tmp_path, results):
    cyc = [_cycle_result(_cycle_entry(k), k) for k in range(2)]
    summary = {"segments": [r.entry for r in results[:1] + cyc], "credible_mass": 0.9, "drift": {},
               "settings": {"sampler": {"n_ensembles": N_ENSEMBLES}}}
    out = write_identify_figures(tmp_path, None, [], None, results[:1] + cyc, summary, workers=1,
                                 windows=[_window(r) for r in cyc])
    assert out["loops"] == ["figures/loops/sine0_w0.png", "figures/loops/sine1_w0.png"]
    assert out["figure3_static"] == [] and len(out["figure8_transients"]) == 2  # the transient's page, PNG + PDF
    assert len(out["corner"]) == len(out["trace"]) == 3
