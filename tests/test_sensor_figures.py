"""The sensor figures (paper Figs. 6-9): written, and plotting the very quantities the tables report.

The curves behind Fig. 7 and Fig. 8(b) come from small pure functions of the evaluation
(:func:`experiments.calibration.branch_figure`, :func:`experiments.calibration.crosstalk_trace`) that the plot
functions call; their peaks must equal the table's nonlinearity, hysteresis and crosstalk.
"""

import numpy as np
import pytest

from experiments.calibration import branch_figure, crosstalk_trace, plot_calibration
from experiments.thermal import run_thermal
from sensor.evaluation import evaluate_sensor
from sim.params import TestbedParams

FS_NM = TestbedParams().photoreflector.full_scale_nm

CALIBRATION_FIGURES = ("calibration_channels.png", "calibration_nonlinearity.png", "calibration_crosstalk_noise.png")
MIN_PNG_BYTES = 10_000  # a figure with its traces drawn, not an empty canvas


@pytest.fixture(scope="module")
def evaluation():
    return evaluate_sensor(TestbedParams(), seed=0)


def test_calibration_writes_figs_6_7_8(evaluation, tmp_path):
    """plot_calibration writes one PNG per paper figure (6, 7, 8), each with content."""
    paths = plot_calibration(evaluation, tmp_path)
    assert [p.name for p in paths] == list(CALIBRATION_FIGURES)
    for p in paths:
        assert p.stat().st_size > MIN_PNG_BYTES, p


@pytest.mark.parametrize("name", ["nonlinearity", "hysteresis"])
def test_fig7_peak_equals_the_table_value(evaluation, name):
    """The largest |deviation| plotted in Fig. 7(c) / (d) is Table III's nonlinearity / hysteresis."""
    curve = getattr(branch_figure(evaluation), f"{name}_pct_fs")
    assert np.max(np.abs(curve)) == pytest.approx(evaluation.figures[f"{name}_pct_fs"][0], rel=1e-12)


def test_fig7_curves_are_consistent(evaluation):
    """Fig. 7(a)'s average is the mean of its branches, and average - line is Fig. 7(c)'s deviation."""
    bf = branch_figure(evaluation)
    np.testing.assert_allclose(bf.average_nm, 0.5 * (bf.ascending_nm + bf.descending_nm))
    np.testing.assert_allclose(100.0 * (bf.average_nm - bf.line_nm) / FS_NM, bf.nonlinearity_pct_fs, atol=1e-12)
    np.testing.assert_allclose(100.0 * (bf.ascending_nm - bf.descending_nm) / FS_NM, bf.hysteresis_pct_fs,
                               atol=1e-12)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_fig8_crosstalk_peak_equals_the_table_value(evaluation, axis):
    """The largest |apparent T_z| plotted under T_x / T_y, in % FS, is Table IV's crosstalk; tared to zero
    mean on the unloaded samples."""
    apparent, result = crosstalk_trace(evaluation, axis)
    assert 100.0 * np.max(np.abs(apparent)) / FS_NM == pytest.approx(
        evaluation.figures[f"crosstalk_t{axis}_pct_fs"][0], rel=1e-12)
    assert abs(apparent[result.at_index]) == np.max(np.abs(apparent))
    unloaded = evaluation.crosstalk_records[axis].schedule.branch == 0
    assert apparent[unloaded].mean() == pytest.approx(0.0, abs=1e-12)


def test_thermal_writes_fig_9(tmp_path):
    """run_thermal's result plots thermal_drift.png with content."""
    figures = run_thermal(TestbedParams(), seed=0).plot(tmp_path)
    assert [p.name for p in figures] == ["thermal_drift.png"]
    assert figures[0].stat().st_size > MIN_PNG_BYTES
