"""The paper's Tables VI-VII and Sec. IV behaviours from the default parameters (slow: ~1-2 min).

Run with ``python -m pytest -m slow``. The tolerance: every figure within a factor 1.5 of the
paper. The assertion messages list every row beside the paper's value, so a failure shows which figures
are off and by how much.

The target is not met yet: ``OUT_OF_BAND`` names the figures still outside a factor 1.5 with the default
parameters (seed 0) and why (docs/fidelity.md: each residual and what would settle it). They are not
excused: the full target is a strict expected failure (it turns
into an error the day it passes, so this list gets emptied), and every other figure must stay in the band.
"""

import math

import pytest

from experiments.common import format_rows, is_primary
from experiments.paper import TARGET_RATIO, run_paper

pytestmark = pytest.mark.slow

# Figures outside the band with the default parameters (ratio sim/paper measured at seed 0, 2026-11-27).
OUT_OF_BAND = {
    # RMS over the disturbance phase until regulation is lost; ours is lost later (0.38 vs 0.3 N·m) from a
    # smaller error, the paper's loss is more abrupt.
    "disturbance, current feedback: RMS error": 0.605,
    # the paper's current-feedback square output reaches ≈ +0.24 N·m (max y ≈ -0.04 N·m, the other root of its
    # peak, would force an RMS >= 0.10 N·m, above its 0.092); ours moves both ways at 14 % of the reference.
    "0.1 N·m square 1 Hz, current feedback: peak error": 0.413,
    # friction at reversals under load and the sensor's error at 10 N·m: the paper's 10 N·m error sits at the
    # crests (peak / RMS 2.8), ours is spread (0.4) (docs/fidelity.md).
    "0.05 N·m sine 0.2 Hz, sensor feedback: peak error": 1.972,
    "0.1 N·m square 1 Hz, sensor feedback: peak error": 1.530,
    "10 N·m sine 0.2 Hz, sensor feedback: RMS error": 1.846,
    "10 N·m sine 0.2 Hz, sensor feedback: peak error": 0.273,
}
# Sec. IV behaviours not reproduced: the current-feedback square's output moves both ways (55 % of its impulse
# positive) at 14 % of the reference's level, short of the 25 % an actuating output needs.
NOT_REPRODUCED = ("0.1 N·m square 1 Hz, current feedback: one-sided actuation",)


@pytest.fixture(scope="module")
def paper_result():
    return run_paper(seed=0)


def _table_rows(paper_result):
    rows = [r for r in paper_result.rows if r["table"] in ("VI", "VII") and is_primary(r)]
    assert len(rows) == 20
    return rows


def _off(rows):
    return [r for r in rows if abs(math.log(r["ratio"])) > math.log(TARGET_RATIO)]


def test_figures_in_the_band_stay_within_a_factor_1_5_of_the_paper(paper_result):
    """Every Table VI-VII figure not listed in OUT_OF_BAND is within [1/1.5, 1.5] of the paper."""
    rows = _table_rows(paper_result)
    regressed = [r for r in _off(rows) if not any(r["quantity"].endswith(k) for k in OUT_OF_BAND)]
    assert not regressed, format_rows(f"{len(regressed)} figures left the band", rows)


# How far a listed figure may move from its recorded ratio before this list must be re-measured [-]: the run
# is deterministic at seed 0, so any move is a change of the model or the protocol, not noise.
LISTED_RATIO_TOLERANCE = 0.10


def test_figures_outside_the_band_stay_where_they_were_measured(paper_result):
    """Each OUT_OF_BAND figure is within 10 % of its recorded ratio: a listed figure cannot get worse (or
    better) unnoticed; a change means re-measuring it and updating the list and docs/fidelity.md."""
    rows = {r["quantity"]: r["ratio"] for r in _table_rows(paper_result)}
    moved = []
    for key, recorded in OUT_OF_BAND.items():
        ratio = next(v for q, v in rows.items() if q.endswith(key))
        if abs(ratio / recorded - 1.0) > LISTED_RATIO_TOLERANCE:
            moved.append(f"{key}: recorded {recorded}, now {ratio:.3f}")
    assert not moved, "listed figures moved:\n" + "\n".join(moved)


@pytest.mark.xfail(strict=True, reason="the figures of OUT_OF_BAND are still outside a factor 1.5 (docs/fidelity.md)")
def test_every_motor_experiment_figure_is_within_a_factor_1_5_of_the_paper(paper_result):
    """Tables VI-VII: sim / paper in [1/1.5, 1.5] for every RMS and peak error, both feedbacks."""
    rows = _table_rows(paper_result)
    off = _off(rows)
    assert not off, format_rows(f"{len(off)} of {len(rows)} figures outside a factor {TARGET_RATIO}", rows)


def test_the_papers_behaviours_are_reproduced_except_those_listed(paper_result):
    """Step fractions, stiction, one-sided low-torque actuation, disturbance regulation, admittance."""
    missing = [f"{b.claim}: {b.simulated}" for b in paper_result.behaviours
               if not b.reproduced and not b.claim.startswith(NOT_REPRODUCED)]
    assert not missing, "not reproduced:\n" + "\n".join(missing)


@pytest.mark.xfail(strict=True, reason="the behaviours of NOT_REPRODUCED are not reproduced (docs/fidelity.md)")
def test_every_behaviour_of_the_paper_is_reproduced(paper_result):
    missing = [b.claim for b in paper_result.behaviours if not b.reproduced]
    assert not missing, "not reproduced:\n" + "\n".join(missing)
