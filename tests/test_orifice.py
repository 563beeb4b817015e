"""Eq. (4) and its inverse eq. (8): round trips, direction logic, the linear and quadratic limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayesdamper.core.params import PAPER_FLOW, FlowCoefficients
from bayesdamper.physics.orifice import flow_rate, orifice_flow, orifice_flow_and_slope, pressure_drop

#: Round trips are a few flops in double precision: 1e-12 leaves room for the sqrt and the
#: conditioning of eq. (8) (its condition number is at most 1).
ROUND_TRIP_RTOL = 1e-12
#: Central-difference slope check: truncation O(h^2) and rounding O(eps/h) meet near 1e-8.
SLOPE_RTOL = 1e-6

LINEAR = FlowCoefficients(2.0e10, 0.0, 0.9e10, 0.0)
QUADRATIC = FlowCoefficients(0.0, 4.0e16, 0.0, 5.0e16)
FLOWS = {"paper": PAPER_FLOW, "linear": LINEAR, "quadratic": QUADRATIC}

# Flows from 1e-12 to 1e-4 m^3/s in both directions (the paper's range is up to ~6e-6 m^3/s).
Q_GRID = np.concatenate([-np.logspace(-12, -4, 81), [0.0], np.logspace(-12, -4, 81)])


@pytest.mark.parametrize("name", FLOWS)
def test_eq8_inverts_eq4_both_directions(name):
    flow = FLOWS[name]
    dp = pressure_drop(Q_GRID, flow)
    np.testing.assert_allclose(flow_rate(dp, flow), Q_GRID, rtol=ROUND_TRIP_RTOL, atol=0)
    np.testing.assert_array_equal(np.sign(dp), np.sign(Q_GRID))


@pytest.mark.parametrize("name", FLOWS)
def test_eq4_inverts_eq8(name):
    flow = FLOWS[name]
    dp = np.concatenate([-np.logspace(-6, 8, 57), [0.0], np.logspace(-6, 8, 57)])
    np.testing.assert_allclose(pressure_drop(flow_rate(dp, flow), flow), dp, rtol=ROUND_TRIP_RTOL, atol=0)


def test_direction_pairs():
    q = 3e-6
    f = PAPER_FLOW
    assert pressure_drop(q, f) == pytest.approx(f.laminar_12 * q + f.quadratic_12 * q * q, rel=1e-15)
    assert pressure_drop(-q, f) == pytest.approx(-(f.laminar_21 * q + f.quadratic_21 * q * q), rel=1e-15)


def test_linear_and_quadratic_closed_forms():
    dp = np.array([-2e5, -1.0, 1e-9, 3e6])
    np.testing.assert_allclose(flow_rate(dp, LINEAR), dp / np.where(dp >= 0, 2.0e10, 0.9e10), rtol=1e-15)
    c_q = np.where(dp >= 0, 4.0e16, 5.0e16)
    np.testing.assert_allclose(flow_rate(dp, QUADRATIC), np.sign(dp) * np.sqrt(np.abs(dp) / c_q), rtol=1e-15)
    assert flow_rate(0.0, QUADRATIC) == 0.0


def test_small_dp_has_no_cancellation():
    # The textbook form (-C_L + sqrt(C_L^2 + 4 C_Q |Δp|)) / (2 C_Q) loses all digits here.
    dp = 1e-6
    assert flow_rate(dp, PAPER_FLOW) == pytest.approx(dp / PAPER_FLOW.laminar_12, rel=1e-12)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(  # coefficient ranges span the physical ones by decades; 0 gives the pure limits
    dp=st.floats(-1e8, 1e8, allow_nan=False),
    c_l=st.one_of(st.just(0.0), st.floats(1e5, 1e13)),
    c_q=st.one_of(st.just(0.0), st.floats(1e10, 1e19)),
)
def test_scalar_kernel_matches_numpy(dp, c_l, c_q):
    if c_l == 0 and c_q == 0:
        return
    flow = FlowCoefficients(c_l, c_q, 0.5 * c_l + 1.0, 2.0 * c_q)
    fl = flow.as_array()
    q_np = float(flow_rate(dp, flow))
    assert orifice_flow(dp, *fl) == pytest.approx(q_np, rel=1e-14, abs=0)
    q, _ = orifice_flow_and_slope(dp, *fl)
    assert q == pytest.approx(q_np, rel=1e-14, abs=0)


@pytest.mark.parametrize("dp", [-1e6, -1e3, -1.0, 1.0, 1e3, 1e6])
@pytest.mark.parametrize("name", FLOWS)
def test_slope_matches_central_difference(name, dp):
    fl = FLOWS[name].as_array()
    h = 1e-5 * abs(dp)
    fd = (orifice_flow(dp + h, *fl) - orifice_flow(dp - h, *fl)) / (2 * h)
    q, slope = orifice_flow_and_slope(dp, *fl)
    assert slope == pytest.approx(fd, rel=SLOPE_RTOL)
    c_l, c_q = (fl[0], fl[1]) if dp >= 0 else (fl[2], fl[3])
    assert slope == pytest.approx(1.0 / (c_l + 2.0 * c_q * abs(q)), rel=1e-12)


def test_slope_at_zero():
    assert orifice_flow_and_slope(0.0, *PAPER_FLOW.as_array()) == (0.0, 1.0 / PAPER_FLOW.laminar_12)
    q, slope = orifice_flow_and_slope(0.0, *QUADRATIC.as_array())
    assert q == 0.0 and slope == np.inf
