"""The candidate fits on the project's executor: the same result in this process and on worker processes, and
one BLAS thread per worker process while this process keeps its own count."""

from __future__ import annotations

from types import SimpleNamespace

import threadpoolctl

from experiments.synthetic_logs import hidden_effect_log
from sim.discrepancy import selection
from sim.discrepancy.analysis import analyse
from sim.discrepancy.signals import AnalysisConfig
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


def test_worker_processes_fit_with_one_blas_thread_and_this_process_keeps_its_count(monkeypatch):
    before = _blas_threads()

    def fit_candidate(model, effect, *rest):  # a stand-in fit reporting the BLAS threads it ran with
        return SimpleNamespace(effect=effect, delta_bic=float(max(_blas_threads())))

    monkeypatch.setattr(selection, "fit_candidate", fit_candidate)
    args = (None, ["a", "b", "c", "d"], {}, (), {}, None)
    in_workers = selection.run_round(*args, executor=Executor(workers=2))
    here = selection.run_round(*args, executor=Executor(workers=1))
    assert [c.delta_bic for c in in_workers] == [1.0] * 4
    assert [c.delta_bic for c in here] == [float(max(before))] * 4
    assert _blas_threads() == before
