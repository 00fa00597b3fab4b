"""Tests for sensor.drift_fit: recovery of known constants from noise-free data (Eq. 20 and the two
candidate forms), model ranking, and rejection of a rational fit with a pole in range."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sensor import drift_fit as df

RECOVERY_RTOL = 1e-6
"""Relative recovery of constants from noise-free data."""

# Chamber range of the paper (Sec. III-C): -10 ... 50 degC; a dense sweep between set points.
T_C = np.linspace(-10.0, 50.0, 121)

# Eq. 20 constants with a denominator that stays positive on [-10, 50] degC (min 0.96 at -10 degC)
# and a drift of a few 0.01 N m, the size of the paper's Fig. 9(b).
A_TRUE = np.array([-2e-5, 1.5e-3, -0.02, 1e-4, 5e-3])


def _eq20(a, t):
    return (a[0] * t ** 2 + a[1] * t + a[2]) / (a[3] * t ** 2 + a[4] * t + 1.0)


def test_rational_fit_recovers_eq20_constants_from_noise_free_data():
    """Noise-free data from Eq. 20 give back a1..a5 (relative 1e-6) and a fit RMSE near 0."""
    fit = df.fit_rational_drift(T_C, _eq20(A_TRUE, T_C))
    np.testing.assert_allclose(fit.coefficients, A_TRUE, rtol=RECOVERY_RTOL)
    assert fit.rmse_nm < 1e-12
    assert fit.coefficient_names == ("a1", "a2", "a3", "a4", "a5")
    np.testing.assert_allclose(fit.predict(T_C), _eq20(A_TRUE, T_C), rtol=0, atol=1e-12)


def test_rational_fit_recovers_constants_from_the_papers_seven_set_points():
    """Seven set points -10, 0, ..., 50 degC (Sec. III-C) suffice for the five constants."""
    t = np.arange(-10.0, 51.0, 10.0)
    fit = df.fit_rational_drift(t, _eq20(A_TRUE, t))
    np.testing.assert_allclose(fit.coefficients, A_TRUE, rtol=RECOVERY_RTOL)


def test_rational_fit_refines_the_linearised_start_on_noisy_data():
    """With noise the nonlinear refinement is no worse than the linearised (Levy) solution."""
    rng = np.random.default_rng(3)
    y = _eq20(A_TRUE, T_C) + rng.normal(0.0, 5e-4, T_C.size)
    fit = df.fit_rational_drift(T_C, y)
    lin = np.column_stack([T_C ** 2, T_C, np.ones_like(T_C), -y * T_C ** 2, -y * T_C])
    p_lin = np.linalg.lstsq(lin, y, rcond=None)[0]
    rmse_lin = np.sqrt(np.mean((_eq20(p_lin, T_C) - y) ** 2))
    assert fit.rmse_nm <= rmse_lin
    assert fit.rmse_nm == pytest.approx(5e-4, rel=0.2)       # about the noise level


def test_comparison_ranks_rational_best_on_eq20_data():
    """On Eq. 20 data the rational model has the lowest RMSE; poly4 and Gaussian are worse."""
    cmp_ = df.compare_drift_models(T_C, _eq20(A_TRUE, T_C))
    assert cmp_.best == "rational"
    assert cmp_.ranking[0] == "rational" and set(cmp_.ranking) == {"rational", "poly4", "gaussian"}
    assert cmp_.fits["poly4"].rmse_nm > 1e3 * cmp_.fits["rational"].rmse_nm
    assert cmp_.fits["gaussian"].rmse_nm > 1e3 * cmp_.fits["rational"].rmse_nm
    json.dumps(cmp_.to_dict())


def test_poly4_fit_recovers_polynomial_constants():
    """Noise-free 4th-order polynomial data give back c0..c4 (relative 1e-6)."""
    c = np.array([-0.02, 1.2e-3, -3e-5, 2e-7, 1e-9])
    fit = df.fit_poly4_drift(T_C, np.polynomial.polynomial.polyval(T_C, c))
    np.testing.assert_allclose(fit.coefficients, c, rtol=RECOVERY_RTOL)


def test_gaussian_fit_recovers_gaussian_constants():
    """Noise-free a exp(-((t-b)/c)^2) + d data give back (a, b, c, d) (relative 1e-6)."""
    p = np.array([0.03, 22.0, 18.0, -0.01])
    y = p[0] * np.exp(-(((T_C - p[1]) / p[2]) ** 2)) + p[3]
    fit = df.fit_gaussian_drift(T_C, y)
    np.testing.assert_allclose(fit.coefficients, p, rtol=RECOVERY_RTOL)


def test_rational_fit_with_a_pole_in_range_is_rejected():
    """Data from 1 / (t - 20) (a pole at 20 degC, representable by Eq. 20) are rejected with the
    root named; the comparison records the failure and ranks the other two."""
    t = np.r_[np.linspace(-10, 18, 30), np.linspace(22, 50, 30)]
    y = 1.0 / (t - 20.0)
    with pytest.raises(df.DriftFitError, match=r"zero at t = 20 degC"):
        df.fit_rational_drift(t, y)
    cmp_ = df.compare_drift_models(t, y)
    assert "rational" in cmp_.failures and set(cmp_.ranking) == {"poly4", "gaussian"}


def test_too_few_temperatures_are_rejected():
    """Four distinct temperatures cannot determine five constants."""
    with pytest.raises(ValueError, match="at least 5 distinct temperatures, got 4"):
        df.fit_rational_drift(np.array([0.0, 10.0, 20.0, 30.0, 30.0]), np.zeros(5))


def test_mismatched_shapes_are_reported():
    """drift_nm of another shape than t_c raises ValueError naming both shapes."""
    with pytest.raises(ValueError, match=r"drift_nm must have the shape of t_c \(121,\)"):
        df.fit_poly4_drift(T_C, np.zeros(120))
