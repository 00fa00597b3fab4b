"""experiments.units: the paper's percentile among sensor units, the same result wherever the units run, failed units
named, the command's usage errors."""

import json
import re
from types import SimpleNamespace

import pytest

from experiments import units
from experiments.units import FigureSpread, UnitRun, figure_spreads, percentile_of, run_units
from sim.executor import Executor


def row(quantity, sim, paper=1.0, table="III"):
    return {"table": table, "quantity": quantity, "unit": "N·m", "paper": paper, "sim": sim}


@pytest.mark.parametrize(("value", "sample", "expected"), [
    (2.5, [1.0, 2.0, 3.0, 4.0], 50.0),         # 2 of 4 below
    (2.0, [1.0, 2.0, 3.0, 4.0], 37.5),         # 1 below, 1 tie counted half: 1.5 / 4
    (2.0, [2.0, 2.0, 2.0], 50.0),              # all ties
    (3.0, [1.0, 3.0, 3.0, 5.0, 7.0], 40.0),    # 1 below, 2 ties: 2 / 5
    (0.5, [1.0, 2.0, 3.0], 0.0),               # the paper below every unit
    (9.0, [1.0, 2.0, 3.0], 100.0),             # the paper above every unit
    (1.0, [4.0], 0.0),
])
def test_the_papers_percentile_counts_units_below_and_ties_half(value, sample, expected):
    assert percentile_of(value, sample) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(("value", "sample", "message"), [
    (1.0, [], "sample"), (1.0, [1.0, float("nan")], "sample"), (float("nan"), [1.0], "value")])
def test_a_percentile_of_nothing_or_of_nan_names_the_argument(value, sample, message):
    with pytest.raises(ValueError, match=f"{message} = .*valid"):
        percentile_of(value, sample)


def test_spreads_keep_each_units_value_and_name_what_is_not_simulated_or_the_same_for_every_unit():
    runs = [UnitRun(0, (row("a", 1.0), row("b", 0.5), row("c", None)), "rational", {}),
            UnitRun(1, (row("a", 3.0), row("b", 0.5), row("c", None)), "poly4", {}),
            UnitRun(2, (row("a", 2.0),), None, {"thermal": "RuntimeError: no fit"})]
    spreads, missing = figure_spreads(runs)
    assert [s.quantity for s in spreads] == ["a", "b"] and missing == ["III c"]
    a, b = spreads
    assert a.values == {0: 1.0, 1: 3.0, 2: 2.0} and a.spread == (1.0, 2.0, 3.0)
    assert a.percentile == pytest.approx(100 * 0.5 / 3)  # paper 1.0 ties unit 0
    assert b.values == {0: 0.5, 1: 0.5} and b.same_for_every_unit and not a.same_for_every_unit
    result = units.UnitsResult(0, 0, runs, spreads, missing)
    assert result.failures == {2: {"thermal": "RuntimeError: no fit"}} and result.fallbacks == {1: "poly4"}


def test_drift_models_give_each_models_median_rms_and_how_often_it_is_lowest():
    """Medians over the units each model was fitted on; a unit without a thermal result counts for none."""
    runs = [UnitRun(0, (), "rational", {}, {"rational": 1.0, "poly4": 2.0, "gaussian": 4.0}),
            UnitRun(1, (), "poly4", {}, {"poly4": 1.0, "gaussian": 3.0}),
            UnitRun(2, (), "rational", {}, {"rational": 3.0, "poly4": 5.0, "gaussian": 2.0}),
            UnitRun(3, (), None, {"thermal": "RuntimeError: no fit"})]
    medians, lowest = units.UnitsResult(0, 0, runs, [], []).drift_models()
    assert medians == {"gaussian": 3.0, "poly4": 2.0, "rational": 2.0}
    assert lowest == {"gaussian": 1, "poly4": 1, "rational": 1}


def fake_calibration(params, seed):
    value = 1.0 + params.photoreflector.unit_seed + seed
    return SimpleNamespace(rows=lambda: [row("max error", value), {**row("max error", 99.0), "reading": "alternative",
                                                                    "reason": "another reading"}])


def fake_thermal(params, seed):
    if params.photoreflector.unit_seed == 1:
        raise RuntimeError("no zero-drift model could be fitted to the chamber record")
    return SimpleNamespace(rows=lambda: [row("zero drift", 0.1 * (1 + params.photoreflector.unit_seed), table="V")],
                           compensation_model="rational")


def test_a_unit_whose_experiment_fails_is_counted_and_named_and_keeps_its_other_figures(monkeypatch):
    monkeypatch.setattr(units, "run_calibration", fake_calibration)
    monkeypatch.setattr(units, "run_thermal", fake_thermal)
    result = run_units(units=3, seed=1)
    assert [r.unit_seed for r in result.runs] == [0, 1, 2]
    assert result.failures == {1: {"thermal": "RuntimeError: no zero-drift model could be fitted to the chamber "
                                              "record"}}
    calibration, thermal = result.figures
    assert calibration.values == {0: 2.0, 1: 3.0, 2: 4.0}  # the alternative reading (99) is not a figure here
    assert thermal.values == {0: 0.1, 2: pytest.approx(0.3)}
    text = result.text()
    assert "failed: 1 of 3 units" in text and "unit 1: thermal: RuntimeError: no zero-drift model" in text
    assert json.loads(json.dumps(result.to_dict()))["failures"] == {"1": result.failures[1]}


@pytest.fixture(scope="module")
def two_units_in_process():
    return run_units(units=2, seed=0, executor=Executor(1))


@pytest.mark.slow  # runs two sensor units' calibration and thermal experiments: about 30 s each
def test_two_units_give_the_same_result_in_process_and_on_two_processes(two_units_in_process):
    result = two_units_in_process
    assert run_units(units=2, seed=0, executor=Executor(2)) == result
    first, second = (tuple(r["sim"] for r in run.rows) for run in result.runs)
    assert first != second  # the units differ, so would a mix-up
    primary_tables = {f.table for f in result.figures}
    assert primary_tables == {"III", "IV", "III-B resolution", "V", "III-C"}
    assert not result.failures


@pytest.mark.slow  # runs two sensor units' calibration and thermal experiments: about 30 s each
def test_two_units_give_the_same_result_on_a_local_ray_cluster(two_units_in_process):
    assert run_units(units=2, seed=0, executor=Executor(ray="local")) == two_units_in_process


@pytest.mark.slow  # runs two sensor units' calibration and thermal experiments: about 30 s each
def test_the_reference_instruments_figures_are_the_same_for_every_unit_and_the_sensors_are_not(two_units_in_process):
    same = {f.quantity for f in two_units_in_process.figures if f.same_for_every_unit}
    assert same == {"1-h drift RMS at 0 N·m, MINI85 (the reference)", "1-h drift RMS at 10 N·m, MINI85 (the reference)"}
    assert "DYJN-104" in " ".join(two_units_in_process.not_simulated)


def test_a_spread_needs_at_least_one_unit():
    with pytest.raises(ValueError, match=r"units = 0: valid range \[1, "):
        run_units(units=0)


@pytest.mark.parametrize(("args", "message"), [
    (["--units", "0"], "argument --units: 0: valid values are integers >= 1"),
    (["--units", "2147483649"], r"--units 2147483649: valid range \[1, 2147483648\]"),
    (["--workers", "0"], "argument --workers: 0: valid values are integers >= 1"),
    (["--seed", "-1"], "argument --seed: -1: valid seeds are integers >= 0"),
])
def test_bad_flags_are_usage_errors_naming_the_flag_and_its_range(args, message, capsys):
    with pytest.raises(SystemExit) as exc:
        units.main([*args, "--no-plot"])
    assert exc.value.code == 2
    assert re.search(message, capsys.readouterr().err)


def test_the_command_prints_the_table_and_writes_the_json(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(units, "run_calibration", fake_calibration)
    monkeypatch.setattr(units, "run_thermal", fake_thermal)
    path = tmp_path / "units.json"
    assert units.main(["--units", "3", "--json", str(path), "--no-plot"]) == 0
    out, err = capsys.readouterr()
    assert "III max error" in out and units.PERCENTILE_DEFINITION in out and "failed: 1 of 3 units" in out
    assert "units: 3/3" in err
    data = json.loads(path.read_text())
    assert data["units"] == [0, 1, 2] and data["run"]["units"] == 3 and data["run"]["seed"] == 0
    first = data["figures"][0]
    assert first["percentile_pct"] == pytest.approx(100 * 0.5 / 3)
    assert first["values"] == {"0": 1.0, "1": 2.0, "2": 3.0}


def test_the_plot_draws_the_unit_dependent_figures(tmp_path):
    spreads = [FigureSpread("III", "a", "N·m", 1.0, {0: 0.5, 1: 2.0}), FigureSpread("V", "b", "N·m", 1.0, {0: 1, 1: 1})]
    result = units.UnitsResult(0, 0, [UnitRun(0, (), None, {}), UnitRun(1, (), None, {})], spreads, [])
    (path,) = result.plot(tmp_path)
    assert path == tmp_path / "units_spread.png" and path.stat().st_size > 0
