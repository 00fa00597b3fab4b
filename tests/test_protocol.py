"""The simulated calibration rig produces the paper's loading protocol."""

import numpy as np
import pytest

from sensor.photoreflector import PhotoReflectorArray
from sensor.protocol import (
    CALIBRATION_CYCLES,
    PRELOAD_LABEL,
    QUIET_S,
    calibration_schedule,
    crosstalk_schedule,
    record,
    resolution_schedule,
)

DT = 1e-3


def test_calibration_schedule_loads_to_25_nm_five_times_each_way():
    """Five positive then five negative cycles reaching ±25 N·m, each ending in a quiet segment, each
    direction preceded by a preload cycle to the full load (label -1)."""
    s = calibration_schedule(DT)
    assert s.tz_nm.max() == pytest.approx(25.0) and s.tz_nm.min() == pytest.approx(-25.0)
    assert len(np.unique(s.cycle[s.cycle != PRELOAD_LABEL])) == 2 * CALIBRATION_CYCLES
    preload = s.tz_nm[s.cycle == PRELOAD_LABEL]
    assert preload.max() == pytest.approx(25.0) and preload.min() == pytest.approx(-25.0)
    for k in range(2 * CALIBRATION_CYCLES):
        in_cycle = s.tz_nm[s.cycle == k]
        assert np.sign(in_cycle[np.abs(in_cycle) > 0]).tolist().count(1 if k < CALIBRATION_CYCLES else -1) > 0
        assert np.all(in_cycle[-round(QUIET_S / DT):] == 0.0)
    assert np.all(s.tx_nm == 0.0) and np.all(s.ty_nm == 0.0)


def test_branch_labels_mark_loading_and_unloading():
    """Loading samples have |T| non-decreasing, unloading samples |T| non-increasing."""
    s = calibration_schedule(DT)
    d = np.diff(np.abs(s.tz_nm))
    assert np.all(d[s.branch[1:] > 0] >= -1e-12)
    assert np.all(d[s.branch[1:] < 0] <= 1e-12)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_crosstalk_schedule_applies_only_the_off_axis_moment(axis):
    """T_z stays zero while T_x (or T_y) goes to 25 N·m and back."""
    s = crosstalk_schedule(DT, axis)
    moment = s.tx_nm if axis == "x" else s.ty_nm
    other = s.ty_nm if axis == "x" else s.tx_nm
    assert moment.max() == pytest.approx(25.0) and np.all(other == 0.0) and np.all(s.tz_nm == 0.0)


def test_resolution_record_is_ten_seconds_of_no_load_at_1_khz():
    """The resolution record is 10 000 samples of zero torque."""
    s = resolution_schedule(DT)
    assert len(s) == 10_000 and np.all(s.tz_nm == 0.0)


def test_record_is_reproducible_from_its_seeds():
    """The same sensor seed and reference seed give the same record."""
    s = crosstalk_schedule(DT, "x")
    a = record(s, PhotoReflectorArray(seed=2), np.random.default_rng(5))
    b = record(s, PhotoReflectorArray(seed=2), np.random.default_rng(5))
    assert np.array_equal(a.voltages_v, b.voltages_v) and np.array_equal(a.tau_reference_nm, b.tau_reference_nm)
