"""Where the candidate search starts: every window's least-squares optimum of the calibrated baseline, which the
sampler's Monte Carlo error does not move (:func:`bayesdamper.diagnosis.calibrated.least_squares_optima`)."""

from types import SimpleNamespace

import numpy as np
import pytest

from bayesdamper.core.params import DynamicParameters
from bayesdamper.diagnosis.calibrated import least_squares_optima, search_problems
from bayesdamper.io.synthetic import write_dataset
from bayesdamper.run.diagnose import STEPS_PER_SAMPLE as STEPS
from bayesdamper.run.plan import plan_dataset

#: The truth (α_V [-], p_R [Pa]) of the eq. (7) data.
PAPER_TRUTH = (40.0, 3.0e5)


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    data = tmp_path_factory.mktemp("lsq") / "data"
    write_dataset(data, [0.5e-3, 1.0e-3, 1.5e-3], DynamicParameters(*PAPER_TRUTH), noise_n=15.0, seed=3)
    return plan_dataset(data, 3.0, "auto")


def _results(windows, scale: float, ls: bool = True):
    """Stand-ins of the baseline's results: posterior medians ``scale`` times the truth (the Monte Carlo error of
    a median, exaggerated) and a point fit at the truth ×1.05 (the same in every call)."""
    alpha, p_r = PAPER_TRUTH
    out = []
    for w in windows:
        entry = {"alpha_V": {"median": scale * alpha}, "p_R_Pa": {"median": scale * p_r},
                 "dp0_Pa": {"median": scale * float(w.dp0)}}
        if ls:
            entry["ls"] = {"alpha_V": 1.05 * alpha, "p_R_Pa": 1.05 * p_r}
        out.append(SimpleNamespace(entry=entry))
    return out


def test_the_search_starts_where_least_squares_ends_whatever_the_posterior_medians(planned):
    """Two baselines that differ only in their posterior medians (by 2 %, ten times a median's usual Monte Carlo
    error) give the same optima, residuals and warm starts to the bit: the start is the point fit, and the optimum
    is the re-fit's from it. Each optimum fits at least as well as the truth (a least-squares optimum of the data,
    up to the re-fit's tolerance: 1e-6 of the SSE) and α_V, p_R land within 10 % of the truth (15 N of noise on
    kilonewtons)."""
    windows, flow0, damper = planned.windows, planned.static.coefficients, planned.ds.damper
    a = least_squares_optima(windows, _results(windows, 1.0), damper, flow0, STEPS, workers=1)
    b = least_squares_optima(windows, _results(windows, 1.02), damper, flow0, STEPS, workers=1)
    for oa, ob in zip(a[0], b[0], strict=True):
        assert oa == ob
    for ra, rb in zip(a[1], b[1], strict=True):
        np.testing.assert_array_equal(ra, rb)
    wa = search_problems(windows, a[0], damper, flow0, STEPS)[1]
    wb = search_problems(windows, b[0], damper, flow0, STEPS)[1]
    for xa, xb in zip(wa, wb, strict=True):
        np.testing.assert_array_equal(xa, xb)

    from bayesdamper.inference.problem import EffectsProblem
    from bayesdamper.physics.with_effects import effect_argument

    alpha, p_r = PAPER_TRUTH
    for w, opt, r in zip(windows, a[0], a[1], strict=True):
        prob = EffectsProblem.from_window(w, damper, flow0)
        f_true, ok = prob.simulate_inner(prob.inner_start(alpha, p_r), effect_argument({}))
        assert ok
        sse_true = float(np.sum((f_true - w.force) ** 2))
        assert float(r @ r) <= sse_true * (1 + 1e-6), w.id
        assert abs(opt["alpha_V"] / alpha - 1) < 0.1 and abs(opt["p_R_Pa"] / p_r - 1) < 0.1, (w.id, opt)


def test_without_a_point_fit_the_search_starts_from_the_medians_and_still_reaches_the_optimum(planned):
    """An entry without a point fit (``ls``) starts from its posterior medians; the re-fit still ends at the same
    optimum as from the point fit, to the re-fit's tolerance (xtol 1e-4 in log α_V and log p_R: a relative 1e-3
    bounds two ends of it)."""
    windows, flow0, damper = planned.windows, planned.static.coefficients, planned.ds.damper
    a = least_squares_optima(windows, _results(windows, 1.0), damper, flow0, STEPS, workers=1)
    c = least_squares_optima(windows, _results(windows, 0.9, ls=False), damper, flow0, STEPS, workers=1)
    for oa, oc in zip(a[0], c[0], strict=True):
        assert oc["alpha_V"] == pytest.approx(oa["alpha_V"], rel=1e-3)
        assert oc["p_R_Pa"] == pytest.approx(oa["p_R_Pa"], rel=1e-3)
