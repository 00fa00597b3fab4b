"""The selection's machinery: the candidate fits on the project's executor (the same result in this process and
on worker processes, one BLAS thread per worker process while this process keeps its own count), and the
remainder's robust size, the periodicity rules (five periods)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import threadpoolctl

from experiments.synthetic_logs import hidden_effect_log
from sim.discrepancy import selection
from sim.discrepancy.analysis import analyse
from sim.discrepancy.effects.cogging import candidate_periods
from sim.discrepancy.effects.periodic_disturbance import spectral_lines
from sim.discrepancy.signals import AnalysisConfig, rms
from sim.discrepancy.structure import median_block_rms
from sim.executor import Executor


def _blas_threads() -> list[int]:
    return sorted({i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"})


def _without_timings(value):
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if k not in ("seconds", "timings_s", "workers")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


def test_candidate_fits_on_two_worker_processes_give_the_result_of_this_process():
    log, rig, _ = hidden_effect_log("locked", ["coulomb_friction"], seed=3, duration_s=4.0)
    one = analyse(log, rig, AnalysisConfig(workers=1), replay=False).to_dict()
    two = analyse(log, rig, AnalysisConfig(workers=2), replay=False).to_dict()
    assert one["baseline"]["candidates"]  # the rounds ran
    assert _without_timings(two) == _without_timings(one)


def test_every_fit_runs_with_one_blas_thread_and_this_process_keeps_its_count(monkeypatch):
    before = _blas_threads()

    def fit_candidate(model, effect, *rest):  # a stand-in fit reporting the BLAS threads it ran with
        return SimpleNamespace(effect=effect, delta_bic=float(max(_blas_threads())))

    monkeypatch.setattr(selection, "fit_candidate", fit_candidate)
    args = (None, ["a", "b", "c", "d"], {}, (), {}, None)
    in_workers = selection.run_round(*args, executor=Executor(workers=2))
    here = selection.run_round(*args, executor=Executor(workers=1))
    assert [c.delta_bic for c in in_workers] == [1.0] * 4
    assert [c.delta_bic for c in here] == [1.0] * 4
    assert _blas_threads() == before


def test_median_block_rms_ignores_one_transient_block():
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 1.0, 2000)
    x[1000:1040] += 30.0  # one transient: dominates the RMS of the whole, not the typical block
    assert rms(x) > 4.0
    assert median_block_rms(x, 100) == pytest.approx(1.0, rel=0.1)


def test_a_transient_in_the_held_out_part_does_not_make_the_remainder_large():
    """A 40 ms command glitch the rig did not follow, in the held-out part of a log of the rig itself: the RMS of
    the held-out effort error exceeds ``max_remainder`` of the command, the remainder (median block RMS) does
    not."""
    log, rig, _ = hidden_effect_log("locked", [], 6, 8.0)
    u = np.asarray(log["tau_cmd"], dtype=float).copy()
    u[6500:6540] += 3.0
    glitched = type(log)({**log.columns, "tau_cmd": u}, dict(log.units), dict(log.meta))
    config = AnalysisConfig()
    result = analyse(glitched, rig, config)
    command_rms = rms(np.asarray(log["tau_cmd"])[int(0.6 * len(log)):])
    assert result.structure.rmse["effort"] / command_rms > config.max_remainder
    assert result.structure.remainder_fraction < config.max_remainder


def _grid_model(n_fit: int, step_s: float = 0.01):
    """A stand-in surrogate for the periodicity rules: a grid of ``step_s`` [s] whose fit part holds n_fit samples."""
    data = SimpleNamespace(dt=1e-3, grid_step=int(round(step_s / 1e-3)), fit=np.ones(n_fit, dtype=bool),
                           position_resolution=1e-6)
    return SimpleNamespace(data=data, config=AnalysisConfig(), testbed=False)


def test_a_spectral_line_needs_five_periods_in_the_samples_it_is_found_in():
    """A 2 Hz sine over 1 s of held-out samples (two periods; the 20 s fit part would allow 0.25 Hz): no line
    below 5 Hz is claimed there; over 3 s (six periods) the 2 Hz line is found."""
    model = _grid_model(2000)
    t = np.arange(2000) * 0.01
    residual = np.sin(2 * np.pi * 2.0 * t)
    short = np.zeros(2000, dtype=bool)
    short[:100] = True
    assert all(f >= 5.0 for f in spectral_lines(model, residual, short, 3))
    longer = np.zeros(2000, dtype=bool)
    longer[:300] = True
    assert spectral_lines(model, residual, longer, 1)[0] == pytest.approx(2.0, abs=0.05)


def test_a_cogging_period_fits_five_times_in_the_position_range():
    periods = candidate_periods(_grid_model(2000), 1.0)
    assert len(periods) and periods.max() <= 1.0 / 5


def test_a_friction_level_whose_gain_comes_only_from_stuck_samples_is_refused_as_degenerate():
    """An independent simulator's point-to-point log whose logged command carries, during every dwell, a hold the
    rig does not know (a brake, a detent at rest): raising the Coulomb level widens the stuck samples' band over it
    and gains, while the sliding samples, which the rig explains, show no sign of the velocity. Refused by rule
    'evidence', naming the correlation."""
    import tomllib

    from sim.discrepancy.analysis import read_stage
    from sim.discrepancy.rig import rig_from_dict
    from tests.independent import battery, rigsim

    n = 20_000
    values = battery.baseline("hinge", 71)
    plant = battery.plant_of("hinge", values)
    reference = battery.reference("hinge", "point_to_point", 71, n)
    run = rigsim.simulate(plant, rigsim.PID.tuned(reference, values["mass"], 5.0, plant.peak_effort), n, seed=71)
    log = run.to_log()
    still = run.v_true == 0.0
    dwell = np.cumsum(np.r_[0, np.diff(still.astype(int)) != 0])
    hold = 2.4 * values["coulomb"] * np.where(dwell % 4 < 2, 1.0, -1.0)
    log = type(log)({**log.columns, "tau_cmd": log["tau_cmd"] + np.where(still, hold, 0.0)}, log.units, log.meta)
    rig = rig_from_dict(tomllib.loads(battery.rig_toml({"joint": "hinge", **values}, "the truth's")))
    stage = read_stage((log,), ("log",), ["estimation"], rig, AnalysisConfig())
    candidate = selection.fit_candidate(stage.model, "coulomb_friction", stage.theta, stage.keys, stage.scales,
                                        stage.score)
    assert candidate.gain > 0.05 and candidate.parameters["coulomb"] > 1.2 * values["coulomb"]
    assert candidate.rejected_by == "evidence" and "correlation" in candidate.note
