"""Tests for sensor.drift_fit: recovery of known constants (Eq. 20 and the two candidate forms), model
ranking, rational fits without a pole on the data range where unconstrained least squares has one, and the
rejection of a rational fit no better than its numerator alone."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st

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


def _real_roots_in(a4, a5, lo, hi):
    """Sign changes of a4 t^2 + a5 t + 1 on a dense grid of [lo, hi] or a zero on it (no root finding)."""
    t = np.linspace(lo, hi, 20_001)
    d = a4 * t * t + a5 * t + 1.0
    return bool(np.any(d == 0.0) or np.any(np.sign(d[1:]) != np.sign(d[:-1])))


def _best_pole_free_on_grid(t, y, a4_grid, a5_grid):
    """RMS of the best Eq. 20 fit whose (a4, a5) is on the grid and whose denominator keeps one sign on
    [min t, max t] (checked on 2001 points), the numerator by linear least squares for each."""
    x = t / np.max(np.abs(t))  # scaled so the linear solves are well conditioned
    dense = np.linspace(t.min(), t.max(), 2001)
    best = np.inf
    for a4 in a4_grid:
        for a5 in a5_grid:
            d_dense = a4 * dense * dense + a5 * dense + 1.0
            if not (np.all(d_dense > 0) or np.all(d_dense < 0)):
                continue
            basis = np.column_stack([x * x, x, np.ones_like(x)]) / (a4 * t * t + a5 * t + 1.0)[:, None]
            r = basis @ np.linalg.lstsq(basis, y, rcond=None)[0] - y
            best = min(best, float(np.sqrt(np.mean(r * r))))
    return best


def _unconstrained_eq20(t, y):
    """Least squares of Eq. 20 without any pole constraint, from the linearised (Levy) solution."""
    lin = np.column_stack([t * t, t, np.ones_like(t), -y * t * t, -y * t])
    scale = np.linalg.norm(lin, axis=0)
    p0 = np.linalg.lstsq(lin / scale, y, rcond=None)[0] / scale
    return scipy.optimize.least_squares(lambda p: _eq20(p, t) - y, p0, x_scale="jac", max_nfev=5000).x


def test_rational_fit_recovers_a_function_with_poles_just_outside_the_range():
    """Noise-free data from 0.03 (1 - t/25) / ((1 - t/55)(1 + t/20)), poles at 55 and -20 degC, 5 and
    10 degC outside [-10, 50], give back its constants (relative 1e-6)."""
    a_true = np.array([0.0, -0.03 / 25.0, 0.03, -1.0 / 1100.0, 1.0 / 20.0 - 1.0 / 55.0])
    y = 0.03 * (1.0 - T_C / 25.0) / ((1.0 - T_C / 55.0) * (1.0 + T_C / 20.0))
    fit = df.fit_rational_drift(T_C, y)
    np.testing.assert_allclose(fit.coefficients, a_true, rtol=RECOVERY_RTOL, atol=1e-12)


def test_rational_fit_of_noisy_data_is_within_the_noise_of_the_function():
    """With noise sigma = 5e-4 N m (seed 11) the fitted curve is within 2 sigma sqrt(5 / N) RMS of the
    noise-free Eq. 20 curve (the least-squares error of 5 constants from N points is sigma sqrt(5 / N))."""
    sigma = 5e-4
    truth = _eq20(A_TRUE, T_C)
    y = truth + np.random.default_rng(11).normal(0.0, sigma, T_C.size)
    fit = df.fit_rational_drift(T_C, y)
    err = fit.predict(T_C) - truth
    assert np.sqrt(np.mean(err * err)) < 2.0 * sigma * np.sqrt(5.0 / T_C.size)


@pytest.fixture(scope="module")
def near_linear_drift():
    """A zero drift like the simulated units': -0.5 mN m/K with a slight bend, noise 7.5 mN m (seed 5),
    600 samples over -10 ... 50 degC. Unconstrained least squares puts a pole inside the range."""
    t = np.linspace(-10.0, 50.0, 600)
    y = -5e-4 * t + 2e-6 * (t - 20.0) ** 2 + np.random.default_rng(5).normal(0.0, 7.5e-3, t.size)
    return t, y


def test_near_linear_noisy_drift_gets_the_best_pole_free_rational_fit(near_linear_drift):
    """The unconstrained optimum has a denominator root on the range; the returned fit has none, beats the
    quadratic and is at least as good as the best pole-free (a4, a5) of a 101 x 101 grid."""
    t, y = near_linear_drift
    p_free = _unconstrained_eq20(t, y)
    assert _real_roots_in(p_free[3], p_free[4], t.min(), t.max())  # the case this test is about
    fit = df.fit_rational_drift(t, y)
    assert not _real_roots_in(fit.coefficients[3], fit.coefficients[4], t.min(), t.max())
    quadratic = np.polynomial.Polynomial.fit(t, y, 2)
    assert fit.rmse_nm < np.sqrt(np.mean((quadratic(t) - y) ** 2))
    oracle = _best_pole_free_on_grid(t, y, np.linspace(-4e-4, 4e-4, 101), np.linspace(-0.04, 0.04, 101))
    assert fit.rmse_nm <= oracle * (1.0 + 1e-9)


def test_data_with_a_pole_in_range_get_a_pole_free_fit():
    """Data from 1 / (t - 20), a pole at 20 degC between two sampled intervals: the fit has no real
    denominator root on [-10, 50] and is at least as good as the best pole-free (a4, a5) of a grid."""
    t = np.r_[np.linspace(-10, 18, 30), np.linspace(22, 50, 30)]
    y = 1.0 / (t - 20.0)
    fit = df.fit_rational_drift(t, y)
    assert not _real_roots_in(fit.coefficients[3], fit.coefficients[4], -10.0, 50.0)
    oracle = _best_pole_free_on_grid(t, y, np.linspace(-4e-3, 4e-3, 101), np.linspace(-0.2, 0.2, 101))
    assert fit.rmse_nm <= oracle * (1.0 + 1e-9)


def test_rational_fit_no_better_than_its_numerator_alone_is_rejected():
    """Noise-free quadratic data: the best pole-free Eq. 20 fit is the quadratic itself, so it is rejected
    with both RMS errors; the comparison records the failure and ranks the other two."""
    y = -0.02 + 1.2e-3 * T_C - 3e-5 * T_C ** 2
    with pytest.raises(df.DriftFitError, match=r"no better than its numerator alone, the quadratic \(RMS "):
        df.fit_rational_drift(T_C, y)
    cmp_ = df.compare_drift_models(T_C, y)
    assert "rational" in cmp_.failures and set(cmp_.ranking) == {"poly4", "gaussian"}


@settings(max_examples=25, deadline=None, derandomize=True)
@given(lo=st.floats(-20.0, 30.0), width=st.floats(5.0, 80.0), slope=st.floats(-1e-3, 1e-3),
       bend=st.floats(-1e-5, 1e-5), pole_at=st.one_of(st.none(), st.floats(0.05, 0.95)),
       noise=st.floats(0.0, 1e-2), seed=st.integers(0, 2**32 - 1))
def test_a_returned_rational_fit_never_has_a_denominator_root_on_the_range(lo, width, slope, bend, pole_at,
                                                                            noise, seed):
    """Drifts with a slope, a bend, noise and sometimes a pole inside the range: a returned fit's
    denominator keeps one sign on [min t, max t]; otherwise the fit is rejected."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(lo, lo + width, 40))
    y = slope * t + bend * t * t + rng.normal(0.0, noise, t.size)
    if pole_at is not None:
        y = y + 1e-3 / (t - (lo + pole_at * width))
    try:
        fit = df.fit_rational_drift(t, y)
    except df.DriftFitError:
        return
    assert not _real_roots_in(fit.coefficients[3], fit.coefficients[4], t.min(), t.max())


def test_too_few_temperatures_are_rejected():
    """Four distinct temperatures cannot determine five constants."""
    with pytest.raises(ValueError, match="at least 5 distinct temperatures, got 4"):
        df.fit_rational_drift(np.array([0.0, 10.0, 20.0, 30.0, 30.0]), np.zeros(5))


def test_mismatched_shapes_are_reported():
    """drift_nm of another shape than t_c raises ValueError naming both shapes."""
    with pytest.raises(ValueError, match=r"drift_nm must have the shape of t_c \(121,\)"):
        df.fit_poly4_drift(T_C, np.zeros(120))
