"""Tests for sensor.metrics against cases small enough to compute by hand (FS = 80 N m)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensor import metrics as m

FS = 80.0


def test_error_metrics_by_hand():
    """Errors [0, -0.5, 0.5] N m: max 0.5 N m = 0.625 % FS, RMS sqrt(1/6) N m."""
    res = m.error_metrics(np.array([1.0, 2.0, 3.5]), np.array([1.0, 2.5, 3.0]))
    assert res.max_error_nm == pytest.approx(0.5)
    assert res.max_error_pct_fs == pytest.approx(100 * 0.5 / FS)
    assert res.rms_error_nm == pytest.approx(math.sqrt(1 / 6))
    assert m.max_error_pct_fs([1.0, 2.0, 3.5], [1.0, 2.5, 3.0]) == pytest.approx(0.625)
    assert m.rms_error_nm([1.0, 2.0, 3.5], [1.0, 2.5, 3.0]) == pytest.approx(math.sqrt(1 / 6))


def test_error_metrics_use_given_full_scale():
    """% FS scales with fs_nm: 0.5 N m of 50 N m is 1 %."""
    assert m.max_error_pct_fs([0.5], [0.0], fs_nm=50.0) == pytest.approx(1.0)


def test_mismatched_lengths_are_reported_with_shapes():
    """tau_hat and tau_ref of different lengths raise ValueError naming the shapes."""
    with pytest.raises(ValueError, match=r"tau_hat must have shape \(3,\); got shape \(2,\)"):
        m.error_metrics(np.zeros(2), np.zeros(3))


def test_reference_direction_labels_ramps_and_holds():
    """Up 0->2, hold, down to 0: the hold at the top belongs to the ascending branch."""
    tau = np.array([0.0, 1.0, 2.0, 2.0, 2.0, 1.0, 0.0, 0.0])
    np.testing.assert_array_equal(m.reference_direction(tau, deadband_nm=0.5),
                                  [1, 1, 1, 1, 1, -1, -1, -1])


def test_reference_direction_ignores_noise_inside_deadband():
    """Wiggles of 0.01 N m during a hold do not flip the branch (dead band 0.05 N m); the turn is
    at the last sample of the maximum (index 4), so index 5 already descends."""
    tau = np.array([0.0, 1.0, 1.01, 1.0, 1.01, 1.0, 0.5, 0.0])
    np.testing.assert_array_equal(m.reference_direction(tau, deadband_nm=0.05),
                                  [1, 1, 1, 1, 1, -1, -1, -1])


def test_reference_direction_of_a_flat_record_is_undetermined():
    """A record that never leaves the dead band has direction 0 everywhere."""
    np.testing.assert_array_equal(m.reference_direction(np.full(5, 3.0)), np.zeros(5))


def _loop():
    """Reference levels 0, 1, 2 N m on both branches; bins of width 1 centred on the levels.

    ascending  tau_hat = [0, 1.1, 2.0]  -> errors [0, 0.1, 0]
    descending tau_hat = [0.2, 1.3, 2.0] -> errors [0.2, 0.3, 0]
    """
    ref = np.array([0.0, 1.0, 2.0, 2.0, 1.0, 0.0])
    hat = np.array([0.0, 1.1, 2.0, 2.0, 1.3, 0.2])
    direction = np.array([1, 1, 1, -1, -1, -1])
    return ref, hat, direction, np.array([-0.5, 0.5, 1.5, 2.5])


def test_hysteresis_by_hand():
    """Branch differences [-0.2, -0.2, 0] N m: hysteresis 0.2 N m = 0.25 % FS at 0 N m."""
    ref, hat, direction, edges = _loop()
    res = m.hysteresis(ref, hat, direction, bin_edges_nm=edges)
    np.testing.assert_allclose(res.difference_nm, [-0.2, -0.2, 0.0], atol=1e-12)
    assert res.max_difference_nm == pytest.approx(0.2)
    assert res.hysteresis_pct_fs == pytest.approx(0.25)
    assert res.at_level_nm == 0.0                     # first of the two equal maxima


def test_nonlinearity_by_hand():
    """Average curve (0, 0.1), (1, 1.2), (2, 2.0); LS line 0.95 c + 0.15; deviations
    [-0.05, 0.1, -0.05]: nonlinearity 0.1 N m = 0.125 % FS at 1 N m."""
    ref, hat, direction, edges = _loop()
    res = m.nonlinearity(ref, hat, direction, bin_edges_nm=edges)
    assert res.slope == pytest.approx(0.95)
    assert res.offset_nm == pytest.approx(0.15)
    np.testing.assert_allclose(res.deviation_nm, [-0.05, 0.1, -0.05], atol=1e-12)
    assert res.max_deviation_nm == pytest.approx(0.1)
    assert res.nonlinearity_pct_fs == pytest.approx(0.125)
    assert res.at_level_nm == 1.0


def test_branch_curves_average_the_error_within_a_bin():
    """Two ascending samples in one bin, errors 0.1 and 0.3 around the centre, give 0.2 N m."""
    ref = np.array([0.9, 1.1, 1.0])
    hat = np.array([1.0, 1.4, 1.0])
    bc = m.branch_curves(ref, hat, np.array([1, 1, -1]), bin_edges_nm=np.array([0.5, 1.5]))
    assert bc.ascending_error_nm[0] == pytest.approx(0.2)
    assert bc.descending_error_nm[0] == pytest.approx(0.0)
    assert bc.ascending_count[0] == 2 and bc.descending_count[0] == 1


def test_linear_sensor_without_hysteresis_has_zero_nonlinearity_and_hysteresis():
    """tau_hat = 1.01 tau + 0.02 on both branches, samples not centred in the bins: both metrics
    are 0 (a gain or offset error is not nonlinearity)."""
    ref = np.r_[np.linspace(-25, 25, 501), np.linspace(25, -25, 333)]
    direction = m.reference_direction(ref)
    hat = 1.01 * ref + 0.02
    assert m.nonlinearity(ref, hat, direction).nonlinearity_pct_fs == pytest.approx(0, abs=1e-12)
    assert m.hysteresis(ref, hat, direction).hysteresis_pct_fs == pytest.approx(0, abs=1e-12)


def test_repeatability_by_hand():
    """Ascending cycles with errors [0, 0.1] and [0.05, 0.3] at levels 0, 1 N m: spreads 0.05 and
    0.2 N m, repeatability 0.2 N m = 0.25 % FS at 1 N m."""
    ref = np.array([0.0, 1.0, 0.0, 1.0, 1.0, 0.0])
    hat = np.array([0.0, 1.1, 0.05, 1.3, 1.0, 0.0])
    cycle = np.array([0, 0, 1, 1, 0, 0])
    direction = np.array([1, 1, 1, 1, -1, -1])
    res = m.repeatability(ref, hat, cycle, direction, bin_edges_nm=np.array([-0.5, 0.5, 1.5]))
    assert res.max_spread_nm == pytest.approx(0.2)
    assert res.repeatability_pct_fs == pytest.approx(0.25)
    assert res.at_level_nm == 1.0 and res.at_direction == 1 and res.n_cycles == 2


def test_repeatability_needs_two_cycles():
    """A single cycle raises ValueError."""
    with pytest.raises(ValueError, match="at least 2 cycles"):
        m.repeatability(np.zeros(3), np.zeros(3), np.zeros(3, dtype=int), np.array([1, 1, -1]))


def test_crosstalk_by_hand():
    """Apparent outputs [0, 0.04, -0.08, 0.02] N m under a 25 N m moment: 0.1 % FS, 0.32 % of
    the applied moment."""
    res = m.crosstalk(np.array([0.0, 0.04, -0.08, 0.02]),
                      applied_moment_nm=np.array([0.0, 10.0, 25.0, 10.0]))
    assert res.max_apparent_torque_nm == pytest.approx(0.08)
    assert res.crosstalk_pct_fs == pytest.approx(0.1)
    assert res.at_index == 2
    assert res.pct_of_applied_moment == pytest.approx(0.32)


def test_crosstalk_tare_removes_the_unloaded_offset():
    """An offset of 0.5 N m seen before loading is removed by the tare: 0.04 N m remains."""
    res = m.crosstalk(np.array([0.5, 0.5, 0.54, 0.5]),
                      tare_mask=np.array([True, True, False, False]))
    assert res.max_apparent_torque_nm == pytest.approx(0.04)


def test_resolution_3sigma_by_hand():
    """[1, -1, 1, -1] N m at 1 kHz: sample std sqrt(4/3), 3-sigma 2 sqrt(3) N m, 4 ms."""
    res = m.resolution_3sigma(np.array([1.0, -1.0, 1.0, -1.0]))
    assert res.std_nm == pytest.approx(math.sqrt(4 / 3))
    assert res.resolution_3sigma_nm == pytest.approx(2 * math.sqrt(3))
    assert res.duration_s == pytest.approx(0.004)


def test_paper_resolution_figures_are_three_sigma_of_the_stds():
    """Sec. III-B: std 0.0160 -> 0.0480 N m (LS), 0.00746 -> 0.0224 N m (QP), ratio 2.14."""
    rng = np.random.default_rng(0)
    for std, res3 in ((0.0160, 0.0480), (0.00746, 0.0224)):
        x = rng.standard_normal(10_000)
        x = (x - x.mean()) / x.std(ddof=1) * std               # exactly this sample std
        assert m.resolution_3sigma(x).resolution_3sigma_nm == pytest.approx(res3, abs=5e-5)
    assert 0.0480 / 0.0224 == pytest.approx(2.14, abs=0.005)


def test_pure_backlash_loop_has_full_width_hysteresis_and_no_nonlinearity():
    """tau_hat = tau + 0.05 * direction over a +-25 N m loop: hysteresis 0.1 N m (0.125 % FS),
    nonlinearity below 1e-6 % FS (not exactly 0: the loop's one-sample asymmetry lets the offset
    leak into the global sensitivity estimate by ~1e-9)."""
    ref = np.r_[np.linspace(-25, 25, 1001), np.linspace(25, -25, 1001)[1:]]
    direction = m.reference_direction(ref)
    hat = ref + 0.05 * direction
    assert m.hysteresis(ref, hat, direction).hysteresis_pct_fs == pytest.approx(0.125)
    assert m.nonlinearity(ref, hat, direction).nonlinearity_pct_fs < 1e-6


def test_zero_drift_per_kelvin_is_the_largest_slope_of_the_fit_over_the_tests_range():
    """A linear drift of 4 mN·m/K is 0.005 % of 80 N·m per kelvin exactly; a quadratic one's largest slope is
    at the warm end (2·a·ΔT), whatever the grid."""
    from sensor.metrics import zero_drift_per_kelvin_pct_fs

    assert zero_drift_per_kelvin_pct_fs(lambda t: 0.004 * (t - 25.0), 20.0, 30.0) == pytest.approx(0.005, rel=1e-9)
    quadratic = zero_drift_per_kelvin_pct_fs(lambda t: 0.001 * (t - 25.0) ** 2, 20.0, 30.0, fs_nm=50.0)
    assert quadratic == pytest.approx(100.0 * 2 * 0.001 * 5.0 / 50.0, rel=0.01)
    assert zero_drift_per_kelvin_pct_fs(lambda t: 0.004 * t, 25.0, 25.0) == pytest.approx(0.005, rel=1e-9)


def test_drift_rms_is_the_rms_of_the_reading_against_the_applied_torque():
    from sensor.metrics import drift_rms_nm

    assert drift_rms_nm(np.array([10.03, 9.96, 10.0, 10.01]), np.full(4, 10.0)) == pytest.approx(
        np.sqrt((0.03**2 + 0.04**2 + 0.0 + 0.01**2) / 4))
