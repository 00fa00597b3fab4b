"""The experiments' shared table and behaviour helpers."""

import argparse

import pytest

from experiments.common import ALTERNATIVE, format_rows, is_primary, paper_row, run_seconds, seed_arg
from experiments.paper import ACTUATION_LEVEL, PaperResult, actuation, markdown_report

PRIMARY_KEYS = {"table", "quantity", "unit", "paper", "sim", "ratio"}


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


def test_an_alternative_row_carries_its_reading_and_reason_and_a_primary_row_neither():
    primary = paper_row("III", "q", "% FS", 0.1, 0.2)
    alternative = paper_row("III", "q, other reading", "N·m", 0.05, 0.1, reading=ALTERNATIVE, reason="Why.")
    assert set(primary) == PRIMARY_KEYS and is_primary(primary)
    assert alternative == {"table": "III", "quantity": "q, other reading", "unit": "N·m", "paper": 0.05, "sim": 0.1,
                           "ratio": pytest.approx(2.0), "reading": "alternative", "reason": "Why."}
    assert not is_primary(alternative)


@pytest.mark.parametrize("kwargs, match", [({"reading": "alternative"}, "an alternative reading needs one"),
                                           ({"reason": "Why."}, "a primary row has none"),
                                           ({"reading": "other", "reason": "Why."}, "valid values are")])
def test_paper_row_refuses_a_reading_without_reason_or_a_reason_without_reading(kwargs, match):
    with pytest.raises(ValueError, match=match):
        paper_row("III", "q", "N·m", 1.0, 1.0, **kwargs)


def _mixed_rows():
    """Two primary rows (ratios 1.0 and 2.0) and two alternatives (ratios 1.0 and 3.0)."""
    return [paper_row("VI", "p in", "N·m", 1.0, 1.0), paper_row("VI", "p out", "N·m", 1.0, 2.0),
            paper_row("VI", "a in", "N·m", 1.0, 1.0, reading=ALTERNATIVE, reason="Reason A."),
            paper_row("VI", "a out", "N·m", 1.0, 3.0, reading=ALTERNATIVE, reason="Reason B.")]


def test_format_rows_prints_the_alternatives_after_the_primary_rows_each_with_its_reason():
    text = format_rows("t", _mixed_rows())
    primary, alternatives = text.split("Alternative readings")
    assert "p out" in primary and "a in" not in primary and "a out" not in primary
    assert "why: Reason A." in alternatives and "why: Reason B." in alternatives and "p in" not in alternatives
    assert "Alternative readings" not in format_rows("t", _mixed_rows()[:2])


def test_paper_counts_and_report_leave_the_alternatives_out_of_the_counts(tmp_path):
    """1 of 2 primary rows is within 1.5 (the alternatives, 1 of 2, are not counted); the JSON keeps all four
    rows; the report puts the alternatives under their own heading with their reasons."""
    result = PaperResult(_mixed_rows(), [], seed=0)
    assert result.within_target() == (1, 2) and result.within_target(1.25) == (1, 2)
    assert "1 of 2 figures within a factor 1.5 (1 within 1.25)" in result.counts_text()
    assert "primary readings only" in result.counts_text()
    assert result.to_dict()["rows"] == _mixed_rows()
    report = markdown_report(result, tmp_path)
    table, alternatives = report.split("## Alternative readings")
    assert "p out" in table and "a out" not in table
    assert "a out" in alternatives and "Reason B." in alternatives


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


