"""Stage 1: eq. (4) least squares per direction, with honest standard errors."""

from types import SimpleNamespace

import numpy as np
import pytest

from bayesdamper.core.errors import DataError
from bayesdamper.core.params import PAPER_FLOW
from bayesdamper.inference.stage1 import fit_direction, fit_static

AREA = 4.2e-3
SPEEDS = np.linspace(0.5e-3, 1.5e-3, 11)
#: Plateau scatter [Pa] typical of rig-A (mean of ~500 samples of ~20 N noise, plus model error).
NOISE_PA = 2.0e3
#: Replicates of the coverage check; with 400 the binomial sd of a 90 % coverage is 1.5 %.
N_REPLICATES = 400
#: Accepted coverage band for nominal 90 % intervals (± ~3 binomial sd).
COVERAGE_BAND = (0.85, 0.95)


def _plateaus(rng, noise=NOISE_PA):
    out = []
    for direction, cl, cq in ((1, PAPER_FLOW.laminar_12, PAPER_FLOW.quadratic_12),
                              (-1, PAPER_FLOW.laminar_21, PAPER_FLOW.quadratic_21)):
        q = AREA * SPEEDS
        dp = cl * q + cq * q * q + noise * rng.standard_normal(q.size)
        out += [SimpleNamespace(direction=direction, flow_rate=qi, pressure_drop=di)
                for qi, di in zip(q, dp, strict=True)]
    return out


def test_noise_free_recovers_coefficients_exactly():
    fit = fit_static(_plateaus(np.random.default_rng(0), noise=0.0))
    np.testing.assert_allclose(fit.coefficients.as_array(), PAPER_FLOW.as_array(), rtol=1e-9)
    assert fit.forward.residual_std < 1e-3 and fit.backward.residual_std < 1e-3


def test_prediction_passes_through_points():
    fit = fit_static(_plateaus(np.random.default_rng(1)))
    f = fit.forward
    resid = f.pressure_drop - f.predict(f.flow_rate)
    assert np.sqrt(np.mean(resid**2)) < 2 * NOISE_PA


def test_standard_errors_are_honest():
    """Nominal 90 % t-intervals cover the true coefficients 85-95 % of the time."""
    rng = np.random.default_rng(2)
    truth = PAPER_FLOW.as_array()
    hits = np.zeros(4)
    for _ in range(N_REPLICATES):
        iv = fit_static(_plateaus(rng)).intervals(0.9)
        hits += [iv[k]["lo"] <= t <= iv[k]["hi"] for k, t in zip(("CL12", "CQ12", "CL21", "CQ21"), truth, strict=True)]
    cov = hits / N_REPLICATES
    assert np.all(cov > COVERAGE_BAND[0]) and np.all(cov < COVERAGE_BAND[1]), cov


def test_covariance_matches_replicate_spread():
    rng = np.random.default_rng(3)
    est = np.array([fit_static(_plateaus(rng)).coefficients.as_array() for _ in range(300)])
    se = np.sqrt(np.diag(fit_static(_plateaus(rng)).covariance))
    # the replicate spread estimates the sd to ~4 % (300 replicates); one fit's se varies ~25 % (9 dof)
    np.testing.assert_allclose(est.std(axis=0), se, rtol=0.5)


def test_too_few_plateaus_is_a_data_error():
    with pytest.raises(DataError, match="need at least 3"):
        fit_direction(np.array([1e-6, 2e-6]), np.array([1e5, 2e5]), 1, "x")


def test_single_velocity_is_a_data_error():
    with pytest.raises(DataError, match="one velocity"):
        fit_direction(np.full(4, 2e-6), np.full(4, 1e5), 1, "x")


def test_offset_estimate_under_friction_that_keeps_eq4_positive():
    """Coulomb friction (200 N, both directions) and a -150 N load-cell offset on three speeds: the forward plateaus
    carry +50 N and the backward +350 N, eq. (4) alone fits both with positive coefficients, so stage 1 reports no
    offset; the offset fit's estimate, the diagnosis' start for ``load_cell_offset``, is the offset (the symmetric
    friction projects out of the antisymmetric offset when both directions have the same speeds). Noise-free: to
    1 N. Fewer than three plateaus in a direction: no estimate."""
    from bayesdamper.inference.stage1 import offset_estimate

    friction, offset = 200.0, -150.0
    plateaus = []
    for direction, cl, cq in ((1, PAPER_FLOW.laminar_12, PAPER_FLOW.quadratic_12),
                              (-1, PAPER_FLOW.laminar_21, PAPER_FLOW.quadratic_21)):
        for v in (0.5e-3, 1.0e-3, 1.5e-3):
            q = AREA * v
            dp = cl * q + cq * q * q + (friction + direction * offset) / AREA
            plateaus.append(SimpleNamespace(direction=direction, flow_rate=q, pressure_drop=dp))
    static = fit_static(plateaus)
    assert static.offset is None and not static.constrained
    assert offset_estimate(plateaus, AREA) == pytest.approx(offset, abs=1.0)
    assert offset_estimate(plateaus[:5], AREA) is None
