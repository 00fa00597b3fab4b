"""The alternative readings' own pieces: the step window with the transient, the chamber's settled plateaus."""

import numpy as np
import pytest

from experiments.step import run_step_case
from experiments.thermal import settled_plateaus
from sim.params import TestbedParams


def test_a_sensor_feedback_step_with_its_transient_has_the_larger_rms_error():
    """Over the whole hold from the step on, the rise of a 0.1 N·m step counts: its RMS error is above that of
    the settled window (the primary reading), which it contains."""
    case = run_step_case(TestbedParams(), "sensor", 0.1, seed=0, hold_s=0.4)
    assert case.error_whole_record is not None
    assert case.error_whole_record.rms_nm > 1.5 * case.error.rms_nm
    assert case.to_dict()["error_whole_record"]["rms_nm"] == case.error_whole_record.rms_nm


def test_settled_plateaus_label_the_second_half_of_each_hold():
    """Three holds of 4 samples: the first two samples of each are -1, the last two the plateau's index."""
    ambient = np.repeat([-10.0, 0.0, 10.0], 4)
    assert settled_plateaus(ambient).tolist() == [-1, -1, 0, 0, -1, -1, 1, 1, -1, -1, 2, 2]
    assert settled_plateaus(ambient, settled_fraction=1.0).tolist() == [0] * 4 + [1] * 4 + [2] * 4


@pytest.mark.parametrize("fraction", [0.0, 1.5, float("nan")])
def test_settled_plateaus_refuse_a_fraction_outside_zero_to_one(fraction):
    with pytest.raises(ValueError, match=r"settled_fraction .* valid range \(0, 1\]"):
        settled_plateaus(np.zeros(4), settled_fraction=fraction)
