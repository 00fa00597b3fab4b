"""CMA-ES over a box (experiments.search): convergence on a known optimum, resume, the space's map."""

import math

import numpy as np
import pytest

from experiments.search import Dimension, Evaluation, SearchStore, Space, minimise

OPTIMUM = np.array([0.2, 0.7, 0.95, 0.35])


def quadratic(xs):
    return [Evaluation(float(np.sum((x - OPTIMUM) ** 2)), {"x": [float(v) for v in x]}) for x in xs]


def test_the_search_finds_a_known_optimum_and_stays_in_the_box():
    seen = []

    def objective(xs):
        seen.extend(xs)
        return quadratic(xs)

    result = minimise(objective, [0.5] * 4, seed=3, budget=400)
    assert np.allclose(result.best_x, OPTIMUM, atol=1e-3)
    assert result.best.score < 1e-6 and result.best.record["x"] == [float(v) for v in result.best_x]
    assert all(np.all((x >= 0.0) & (x <= 1.0)) for x in seen)
    assert result.evaluations == len(seen) <= 400 + 7  # the last generation completed
    assert [h[2] for h in result.history] == sorted((h[2] for h in result.history), reverse=True)


def test_an_optimum_outside_the_box_ends_on_its_edge():
    def objective(xs):
        return [Evaluation(float(np.sum((x - np.array([1.4, 0.5])) ** 2))) for x in xs]

    result = minimise(objective, [0.5, 0.5], seed=2, budget=300)
    assert result.best_x[0] == pytest.approx(1.0, abs=1e-3) and result.best_x[1] == pytest.approx(0.5, abs=1e-2)


class Interrupted(Exception):
    pass


def test_a_resumed_run_ends_where_the_uninterrupted_run_ends_and_reuses_its_evaluations(tmp_path):
    settings = {"objective": "quadratic"}
    whole = minimise(quadratic, [0.5] * 4, seed=5, budget=120, store=SearchStore(tmp_path / "whole", settings))
    calls = []

    def interrupted(xs):
        calls.append(len(xs))
        if len(calls) == 6:
            np.random.default_rng(0).normal(size=3)  # the objective's own draws change nothing
            np.random.seed(99)
            raise Interrupted
        return quadratic(xs)

    with pytest.raises(Interrupted):
        minimise(interrupted, [0.5] * 4, seed=5, budget=120, store=SearchStore(tmp_path / "cut", settings))
    fresh = []

    def counted(xs):
        fresh.extend(xs)
        return quadratic(xs)

    resumed = minimise(counted, [0.5] * 4, seed=5, budget=120,
                       store=SearchStore(tmp_path / "cut", settings, resume=True))
    assert np.array_equal(resumed.best_x, whole.best_x) and resumed.best.score == whole.best.score
    assert resumed.history == whole.history and resumed.evaluations == whole.evaluations
    assert len(fresh) == whole.evaluations - 5 * calls[0]  # five generations were kept
    lines = (tmp_path / "cut" / "evals.jsonl").read_text().splitlines()
    assert len(lines) == whole.evaluations


def test_a_store_refuses_to_mix_runs(tmp_path):
    SearchStore(tmp_path / "run", {"seeds": [0]})
    with pytest.raises(ValueError, match="holds a run already"):
        SearchStore(tmp_path / "run", {"seeds": [0]})
    with pytest.raises(ValueError, match=r"other settings \(seeds"):
        SearchStore(tmp_path / "run", {"seeds": [1]}, resume=True)
    with pytest.raises(ValueError, match="no run to resume"):
        SearchStore(tmp_path / "other", {"seeds": [0]}, resume=True)


def test_a_wide_bound_is_searched_in_log_scale_and_the_map_inverts():
    wide, narrow = Dimension("a.wide", 1e-4, 1e-2), Dimension("a.narrow", 0.02, 0.05)
    assert wide.log and not narrow.log and not Dimension("a.zero", 0.0, 1.0).log
    assert wide.value(0.5) == pytest.approx(1e-3) and narrow.value(0.5) == pytest.approx(0.035)
    space = Space((wide, narrow))
    x = np.array([0.3, 0.8])
    assert space.positions(space.values(x)) == pytest.approx(x)
    assert space.overrides(x) == {"a": {"wide": pytest.approx(1e-4 * 100 ** 0.3), "narrow": pytest.approx(0.044)}}
    assert wide.edge(0.005) == "low" and wide.edge(0.995) == "high" and wide.edge(0.5) is None
    assert math.isclose(wide.value(2.0), 1e-2)  # clipped into the bound


@pytest.mark.parametrize("kwargs,message", [({"budget": 1}, "budget = 1: valid range"),
                                            ({"seed": -1}, "seed = -1: valid range"),
                                            ({"sigma0": 0.0}, "sigma0 = 0.0: valid range")])
def test_bad_search_settings_name_their_range(kwargs, message):
    with pytest.raises(ValueError, match=message):
        minimise(quadratic, [0.5] * 4, **{"seed": 1, "budget": 10, **kwargs})


def test_a_bound_must_be_ordered_and_a_log_scale_positive():
    with pytest.raises(ValueError, match="lo < hi"):
        Dimension("a.b", 1.0, 1.0)
    with pytest.raises(ValueError, match="log scale needs lo > 0"):
        Dimension("a.b", 0.0, 1.0, log=True)
