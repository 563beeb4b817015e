"""Plot functions return Figures with the expected axes and artists (synthetic inputs, no sampling)."""

from __future__ import annotations

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

from matplotlib.container import ErrorbarContainer  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from bayesdamper.inference.stage1 import StaticFit, fit_direction  # noqa: E402
from bayesdamper.inference.stage2 import WindowResult  # noqa: E402
from bayesdamper.report import diagnostic_plots, paper_figures, style  # noqa: E402
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
