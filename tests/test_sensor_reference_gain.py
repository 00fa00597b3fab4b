"""The ATI MINI85's gain error (paper Sec. III-A: 1 % FS accuracy) is the calibration's truth.

The rig calibrates the sensor against the MINI85's reading (1 + g)·τ, so the calibrated sensor inherits the gain
error against the true torque, while its errors against the MINI85 (Table III) cannot see it. Both runs use the
same seed, so the channel noise and the MINI85's noise draws are the same; only the reference's scale differs.
"""

import numpy as np
import pytest

from sensor.evaluation import evaluate_sensor
from sensor.protocol import PRELOAD_LABEL
from sim.params import TestbedParams

GAIN_ERROR = 0.01  # the largest |g| the MINI85's 1 % FS accuracy allows (sim/params.py)
LEVEL_NM = 10.0  # a held level of the calibration protocol, the paper's 10 N·m drift and sine tests
# The two calibrations differ beyond the scale (1 + g) only through the MINI85's quantisation (7/748 N·m steps,
# rounding errors of std 2.7 mN·m that the scaling reshuffles), averaged by the fit over ~3e5 samples: over the
# 20 000 held samples the two outputs' difference is g·τ with a mean offset of -0.07 mN·m, a std of 0.22 mN·m
# and at most 0.64 mN·m off (seeds 0-3). 1 mN·m is 1 % of g·τ = 0.1 N·m.
PAIRED_TOLERANCE_NM = 1e-3
# Table III figures are errors in the MINI85's scale, so they scale with (1 + g); what is left is the paired
# runs' noise: the reference's rounding moves with g, which moves the max error (one extreme sample) by 0.08 %
# at seed 0 (up to 1.75 % over seeds 0-3) and the averaged figures by < 0.2 %. The seed-to-seed spread of these
# figures is 1.8 % (RMS) to 18 % (hysteresis). Evaluated against the true torque instead (the gain error on one
# side of the comparison only), the same unit's max error is 0.42 % FS and its RMS error 0.136 N·m (about 4x).
TABLE_III_RELATIVE_TOLERANCE = 0.02
TABLE_III = ("max_error_pct_fs", "rms_error_nm", "nonlinearity_pct_fs", "hysteresis_pct_fs", "repeatability_pct_fs")


@pytest.fixture(scope="module")
def evaluations():
    """The default unit calibrated and evaluated with g = 0 and g = +1 %, seed 0 for both."""
    return {g: evaluate_sensor(TestbedParams().replace(photoreflector={"reference_gain_error": g}), seed=0)
            for g in (0.0, GAIN_ERROR)}


def _held_output_at_level(ev) -> np.ndarray:
    """QP output [N·m] over the evaluation record's held +10 N·m samples (both branches, the five cycles)."""
    rec = ev.evaluation_record
    held = (rec.schedule.level_nm == LEVEL_NM) & (rec.schedule.cycle != PRELOAD_LABEL)
    assert np.all(rec.tau_true_nm[held] == LEVEL_NM)
    return ev.qp.predict(rec.voltages_v[held])


def test_a_mini85_gain_error_makes_the_calibrated_sensor_read_one_plus_g_times_the_true_torque(evaluations):
    """Calibrated against a MINI85 of gain error g = +1 %, the sensor reads (1 + g)·τ_true at 10 N·m: its error
    against the true torque is the g = 0 unit's error plus g·10 N·m within 1 mN·m, sample by sample, and its mean
    is nearer (1 + g)·10 N·m than 10 N·m."""
    out_g, out_0 = _held_output_at_level(evaluations[GAIN_ERROR]), _held_output_at_level(evaluations[0.0])
    np.testing.assert_allclose(out_g - out_0, GAIN_ERROR * LEVEL_NM, rtol=0.0, atol=PAIRED_TOLERANCE_NM)
    assert abs(out_g.mean() - (1.0 + GAIN_ERROR) * LEVEL_NM) < abs(out_g.mean() - LEVEL_NM)


@pytest.mark.parametrize("figure", TABLE_III)
def test_errors_against_the_mini85_do_not_see_its_gain_error(evaluations, figure):
    """Evaluated against the same MINI85 it was calibrated on, the g = +1 % unit's Table III figures are the
    g = 0 unit's in the MINI85's scale, (1 + g) times, within 2 %."""
    value_g, value_0 = evaluations[GAIN_ERROR].figures[figure][0], evaluations[0.0].figures[figure][0]
    assert value_g == pytest.approx((1.0 + GAIN_ERROR) * value_0, rel=TABLE_III_RELATIVE_TOLERANCE)
