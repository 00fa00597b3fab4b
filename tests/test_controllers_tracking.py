"""The tracking-error figures: RMS and the paper's peak error, defined once."""

import numpy as np
import pytest

from controllers.tracking import tracking_error


def test_peak_error_compares_peaks_not_pointwise_errors():
    """A one-sided output (0.035..0.10 N·m against a ±0.05 N·m sine) has RMS error > peak error, as the
    paper's Table VII lists for current feedback (0.0685 / 0.0505)."""
    t = np.linspace(0, 10, 10001)
    r = 0.05 * np.sin(2 * np.pi * 0.2 * t)
    y = 0.0675 + 0.033 * np.sin(2 * np.pi * 0.2 * t)
    e = tracking_error(y, r)
    assert e.rms_nm == pytest.approx(0.0685, abs=0.001)
    assert e.peak_nm == pytest.approx(0.0505, abs=0.001)
    assert e.max_abs_nm >= e.rms_nm  # the pointwise maximum cannot be below the RMS


def test_an_offset_lagging_output_gives_the_papers_pair_under_both_peak_readings():
    """Offset +0.0505 N·m, lag 81.8°: RMS 0.0685 with crest and trough misses both 0.0505 N·m, so the
    two-sided peak reading fits the paper's current-feedback sine pair as well as the one-sided one."""
    t = np.linspace(0, 5, 50001)[:-1]  # one period of 0.2 Hz
    w = 2 * np.pi * 0.2
    r = 0.05 * np.sin(w * t)
    y = 0.0505 + 0.05 * np.sin(w * t - np.radians(81.77))
    e = tracking_error(y, r)
    assert e.rms_nm == pytest.approx(0.0685, abs=2e-5)
    assert e.peak_nm == pytest.approx(0.0505, abs=1e-6)
    assert e.trough_nm == pytest.approx(0.0505, abs=1e-6)
    assert y.min() > 0.0  # one-sided


def test_reached_fraction_is_the_mean_output_over_the_mean_reference():
    """A step output at 30 % of its reference has reached fraction 0.3 and RMS error 0.7 r."""
    e = tracking_error(np.full(100, 0.015), np.full(100, 0.05))
    assert e.reached_fraction == pytest.approx(0.3)
    assert e.rms_nm == pytest.approx(0.035)


def test_mismatched_arrays_are_refused():
    """Output and reference must have the same length."""
    with pytest.raises(ValueError, match="equal-length"):
        tracking_error(np.zeros(3), np.zeros(4))


def test_two_sided_peak_is_the_larger_miss_of_crest_and_trough():
    """Output crest 0.06 against 0.05 (miss 0.01), trough -0.02 against -0.05 (miss 0.03): two-sided 0.03."""
    r = np.array([0.0, 0.05, 0.0, -0.05])
    y = np.array([0.0, 0.06, 0.0, -0.02])
    e = tracking_error(y, r)
    assert (e.peak_nm, e.trough_nm, e.two_sided_peak_nm) == (pytest.approx(0.01), pytest.approx(0.03),
                                                             pytest.approx(0.03))
