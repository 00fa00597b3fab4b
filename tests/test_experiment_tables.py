"""The experiments' shared table and behaviour helpers."""

import argparse

import pytest

from experiments.common import format_rows, paper_row, run_seconds, seed_arg
from experiments.paper import ACTUATION_LEVEL, actuation


def test_format_rows_marks_the_ratios_outside_the_band_and_only_those():
    """With band=1.5 (the default), 0.6 and 1.6 are marked, 0.7, 1.4 and a missing ratio are not; band=None
    marks none."""
    rows = [paper_row("VI", name, "N·m", 1.0, sim) for name, sim in
            [("low", 0.6), ("in low", 0.7), ("in high", 1.4), ("high", 1.6), ("none", None)]]
    lines = format_rows("t", rows, band=1.5).splitlines()[2:]
    marked = [line.split()[1] for line in lines if "outside a factor 1.5" in line]
    assert marked == ["low", "high"]
    assert format_rows("t", rows) == format_rows("t", rows, band=1.5)
    assert "outside" not in format_rows("t", rows, band=None)


@pytest.mark.parametrize("share, level, expected", [
    (1.0, 1.88, "one-sided"),   # the current-feedback 0.05 N·m sine: the output stays positive, and large
    (0.15, 0.6, "one-sided"),   # negative side counts alike
    (0.5, 1.15, "two-sided"),   # tracking a symmetric reference
    (0.15, 0.04, "none"),       # a gear that never breaks free: its sign share is its offset, not actuation
    (0.5, ACTUATION_LEVEL - 1e-9, "none"),
])
def test_actuation_needs_torque_before_its_side_counts(share, level, expected):
    assert actuation(share, level) == expected


@pytest.mark.parametrize("text", ["0.005", "121", "nan", "inf", "-1"])
def test_run_seconds_refuses_durations_outside_ten_ms_to_120_s(text):
    with pytest.raises(argparse.ArgumentTypeError, match="valid range"):
        run_seconds(text)


def test_seed_arg_takes_non_negative_integers_only():
    assert seed_arg("0") == 0 and seed_arg("17") == 17
    for text in ("-1", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError):
            seed_arg(text)


