"""Eq. (2), (3) and (6): the exact κ = 1 relation, the mixture definition, branch logic, twins."""

from __future__ import annotations

import numpy as np
import pytest

from bayesdamper.core.errors import SettingsError
from bayesdamper.core.params import ATMOSPHERIC_PRESSURE
from bayesdamper.physics.compressibility import (
    bulk_modulus,
    bulk_modulus_and_slope,
    bulk_modulus_general,
    bulk_modulus_scalar,
    chamber_bulk_moduli,
    chamber_bulk_moduli_scalar,
)

#: Closed-form identities evaluated in double precision: a few ulp per operation.
IDENTITY_RTOL = 1e-13
#: Central-difference slope check: truncation O(h^2) and rounding O(eps/h) meet near 1e-8.
SLOPE_RTOL = 1e-6

B0 = 1.5e9
P0 = ATMOSPHERIC_PRESSURE
PRESSURES = np.logspace(3, 8, 41)  # 1 kPa to 100 MPa
ALPHAS = [2.0, 30.0, 5000.0]


@pytest.mark.parametrize("alpha", ALPHAS)
def test_eq3_vs_eq2_exact_relation_at_kappa_1(alpha):
    """B_(3)/B_(2) = (1 + α_V)/(α_V + p_0/p): equal at p = p_0, within 1/α_V for p >= p_0."""
    b2 = bulk_modulus_general(PRESSURES, B0, alpha, P0, 1.0)
    b3 = bulk_modulus(PRESSURES, B0, alpha, P0)
    np.testing.assert_allclose(b3 / b2, (1 + alpha) / (alpha + P0 / PRESSURES), rtol=IDENTITY_RTOL)
    assert bulk_modulus(P0, B0, alpha, P0) == pytest.approx(bulk_modulus_general(P0, B0, alpha, P0, 1.0),
                                                             rel=IDENTITY_RTOL)
    above = PRESSURES >= P0  # the pressurised range eq. (6) uses
    assert np.all(np.abs(b3[above] / b2[above] - 1) <= 1 / alpha + IDENTITY_RTOL)


@pytest.mark.parametrize("kappa", [1.0, 1.4])
@pytest.mark.parametrize("alpha", ALPHAS)
def test_eq2_is_the_mixture_bulk_modulus(alpha, kappa):
    """Eq. (2) = (V_L + V_G) / (V_L/B_0 + V_G/(κ p)) with V_G = (V_L/α_V)(p_0/p)^(1/κ)."""
    v_l = 1.0
    v_g = v_l / alpha * (P0 / PRESSURES) ** (1 / kappa)
    mixture = (v_l + v_g) / (v_l / B0 + v_g / (kappa * PRESSURES))
    np.testing.assert_allclose(bulk_modulus_general(PRESSURES, B0, alpha, P0, kappa), mixture,
                               rtol=IDENTITY_RTOL)


def test_eq3_limits_and_monotonicity():
    b = bulk_modulus(PRESSURES, B0, 30.0, 1e5)
    assert np.all(np.diff(b) > 0)  # gas stiffens with pressure
    assert np.all(b < B0 * 31 / 30)  # bounded by the gas-compressed limit B_0 (1 + α_V)/α_V
    assert bulk_modulus(1e12, B0, 30.0, 1e5) == pytest.approx(B0 * 31 / 30, rel=1e-6)


@pytest.mark.parametrize("dp", [-3e6, -1.0, 0.0, 1.0, 3e6])
def test_eq6_branches(dp):
    p_r, alpha = 3e5, 33.0
    b1, b2 = chamber_bulk_moduli(dp, B0, alpha, p_r)
    loaded = bulk_modulus(p_r + abs(dp), B0, alpha, p_r)
    base = bulk_modulus(p_r, B0, alpha, p_r)
    expected = (loaded, base) if dp >= 0 else (base, loaded)
    assert (b1, b2) == pytest.approx(expected, rel=IDENTITY_RTOL)
    assert chamber_bulk_moduli_scalar(dp, B0, alpha, p_r) == pytest.approx(expected, rel=IDENTITY_RTOL)


def test_eq6_continuous_at_zero():
    p_r, alpha = 1e5, 30.0
    base = bulk_modulus(p_r, B0, alpha, p_r)
    for eps in (1e-3, 1e-6, 1e-9):
        for dp in (eps, -eps):
            b1, b2 = chamber_bulk_moduli(dp, B0, alpha, p_r)
            assert b1 == pytest.approx(base, rel=10 * eps / p_r + 1e-15)
            assert b2 == pytest.approx(base, rel=10 * eps / p_r + 1e-15)
    assert chamber_bulk_moduli(0.0, B0, alpha, p_r) == (base, base)


def test_eq6_vectorised_shapes():
    mags = np.array([0.0, 1e2, 3e5, 1e6])
    dp = np.concatenate([-mags[::-1], mags[1:]]).reshape(7, 1)
    b1, b2 = chamber_bulk_moduli(dp, B0, 30.0, 1e5)
    assert b1.shape == b2.shape == (7, 1)
    np.testing.assert_array_equal(b1[::-1], b2)  # symmetric in the sign of Δp


@pytest.mark.parametrize("p", [1e3, 1e5, 3e6, 1e8])
@pytest.mark.parametrize("alpha", ALPHAS)
def test_scalar_twins(alpha, p):
    p_ref = 1e5
    assert bulk_modulus_scalar(p, B0, alpha, p_ref) == pytest.approx(bulk_modulus(p, B0, alpha, p_ref),
                                                                    rel=IDENTITY_RTOL)
    b, slope = bulk_modulus_and_slope(p, B0, alpha, p_ref)
    assert b == pytest.approx(bulk_modulus(p, B0, alpha, p_ref), rel=IDENTITY_RTOL)
    h = 1e-5 * p
    hi, lo = bulk_modulus_scalar(p + h, B0, alpha, p_ref), bulk_modulus_scalar(p - h, B0, alpha, p_ref)
    fd = (hi - lo) / (2 * h)
    rounding = 4 * np.finfo(float).eps * b / h  # cancellation in the difference of two B values
    assert slope == pytest.approx(fd, rel=SLOPE_RTOL, abs=rounding)


@pytest.mark.parametrize(
    "args",
    [(0.0, B0, 30.0, 1e5), (-1.0, B0, 30.0, 1e5), (1e5, B0, 0.0, 1e5), (1e5, B0, 30.0, -1.0),
     (1e5, np.nan, 30.0, 1e5)],
)
def test_invalid_inputs_raise(args):
    with pytest.raises(SettingsError):
        bulk_modulus(*args)
