"""Crosstalk of the simulated sensor (Table IV): what the figure is made of.

The calibration (:func:`sensor.evaluation.calibrate`) sees the T_x/T_y moment records, so it nulls every
deterministic tilt response of the channels; what the crosstalk figure then measures is the largest noise
excursion of the calibrated output over the moment test. Without the moment records (a T_z-only fit) the tilt
response is left uncancelled. These tests pin both facts (docs/fidelity.md explains why the figure stays
below the paper's 0.148 / 0.126 % FS).
"""

import numpy as np
import pytest

from sensor.evaluation import evaluate_sensor
from sensor.photoreflector import PhotoReflectorArray
from sensor.protocol import Schedule, record
from sim.params import TestbedParams

FS_NM = TestbedParams().photoreflector.full_scale_nm

PAPER_CROSSTALK_PCT_FS = {"x": 0.148, "y": 0.126}  # paper Table IV


@pytest.fixture(scope="module")
def evaluations():
    return {seed: evaluate_sensor(seed=seed) for seed in (0, 1)}


def _apparent(ev, axis):
    rec = ev.crosstalk_records[axis]
    out = ev.qp.predict(rec.voltages_v)
    return rec, out - out[rec.schedule.branch == 0].mean()


def _held_level_residual(ev, axis):
    """Largest held-level mean of the apparent T_z output over the moment test [N·m]: the deterministic part."""
    rec, apparent = _apparent(ev, axis)
    levels = rec.schedule.level_nm
    return max(abs(apparent[levels == lv].mean()) for lv in np.unique(levels[~np.isnan(levels)]))


def _no_load_max_excursion(ev, n, seed):
    """Largest |output - mean| of the QP output over a no-load record of n samples [N·m]."""
    array = PhotoReflectorArray(TestbedParams(), seed=seed)
    z = np.zeros(n)
    rec = record(Schedule(z, z.copy(), z.copy(), z.copy(), z.copy(), np.zeros(n, dtype=int)), array,
                 np.random.default_rng(seed))
    q = ev.qp.predict(rec.voltages_v)
    return float(np.max(np.abs(q - q.mean())))


@pytest.mark.parametrize("axis", ["x", "y"])
def test_crosstalk_is_nonzero_stable_across_seeds_and_made_of_noise(evaluations, axis):
    """Figure > 0, within 25 % between seeds; the held-level means (the tilt response the QP leaves for lower
    noise) are under half of it, and it lies within [0.7, 1.6] x the largest noise excursion of the calibrated
    output over an equally long no-load record."""
    figs = [evaluations[s].figures[f"crosstalk_t{axis}_pct_fs"][0] for s in (0, 1)]
    assert min(figs) > 0.0
    assert abs(figs[0] - figs[1]) / figs[0] < 0.25
    ev = evaluations[0]
    deterministic = _held_level_residual(ev, axis)
    figure_nm = figs[0] / 100.0 * FS_NM
    assert deterministic < figure_nm / 2.0
    floor = _no_load_max_excursion(ev, len(ev.crosstalk_records[axis].voltages_v), seed=77)
    assert 0.7 * floor <= figure_nm <= 1.6 * floor


def test_the_tilt_residual_the_qp_leaves_grows_with_channel_noise(evaluations):
    """The QP trades the tilt response's null against noise: with the noisiest channel at 0.96 mV instead of the
    default 2.4 mV the held-level residual falls more than twofold (measured 0.0063 against 0.0208 N·m)."""
    quieter = evaluate_sensor(TestbedParams().replace(photoreflector={"noise_max_v": 9.6e-4}), seed=0)
    assert _held_level_residual(evaluations[0], "x") > 2.0 * _held_level_residual(quieter, "x")


@pytest.mark.parametrize("axis", ["x", "y"])
def test_a_tz_only_calibration_leaves_the_tilt_response_uncancelled(evaluations, axis):
    """Fitted on the T_z loading record alone, the QP's unequal channel weights do not cancel the ~60 mV tilt
    response: the crosstalk (the alternative reading's figure) exceeds the paper's, and more than triples the
    crosstalk of the calibration that saw the moment records."""
    figures = evaluations[0].figures
    tz_only, with_moments = figures[f"crosstalk_t{axis}_tz_only_pct_fs"][0], figures[f"crosstalk_t{axis}_pct_fs"][0]
    assert tz_only > PAPER_CROSSTALK_PCT_FS[axis] and tz_only > 3.0 * with_moments
