"""experiments.identify_defaults: the objective on the executor, the penalties, the parameter TOML, the command."""

import json
import math

import numpy as np
import pytest

from experiments import identify_defaults as ident
from sensor.calibration import InfeasibleCalibrationError
from sim.executor import Executor
from sim.params import TestbedParams, load_params, source_bound

FAST = TestbedParams().replace(simulation={"substeps_rule": "fast"})


@pytest.mark.parametrize("part", list(ident.PARTS))
def test_the_space_is_the_source_bounds_of_the_searched_parameters_within_their_valid_ranges(part):
    space = ident.default_space(part=part)
    assert [d.path for d in space.dims] == list(ident.PARTS[part])
    for d in space.dims:
        lo, hi = source_bound(d.path)
        assert lo <= d.lo < d.hi <= hi
        assert d.log == (lo > 0 and hi / lo > 3)
    for end in (np.zeros(len(space)), np.ones(len(space))):  # both ends are valid parameter sets, ties included
        TestbedParams().replace(**ident.candidate_overrides(TestbedParams(), space.overrides(end)))


def test_tied_curvature_is_the_one_over_gap_squared_expansion():
    """A reflector's 1/(d - δ)² response is (1/d²)·(1 - u)^-2, u = δ/d: the square of the geometric series
    1/(1 - u) = Σ u^k, multiplied out. Its quadratic, cubic and quartic terms at the span u = Δ/d, relative to the
    linear one, are what the tie sets from the quadratic alone."""
    geometric = np.ones(6)
    coefficients = np.polynomial.polynomial.polymul(geometric, geometric)[:6]
    for span in (0.15, 0.2067, 0.3):
        terms = coefficients[1:5] * span ** np.arange(1, 5)
        fractions = terms[1:] / terms[0]
        tied = ident.tied_overrides({"photoreflector": {"quadratic_fraction_max": fractions[0]}})["photoreflector"]
        assert [tied["quadratic_fraction_max"], tied["cubic_fraction_max"], tied["quartic_fraction_max"]] == \
            pytest.approx(fractions, rel=1e-6)
    assert ident.tied_overrides({"friction": {"coulomb_torque_nm": 0.1}}) == {"friction": {"coulomb_torque_nm": 0.1}}


def test_the_sensor_part_scores_the_calibration_and_thermal_tables_without_the_motor():
    """One candidate of the sensor part, one seed: only the calibration and thermal experiments run; every
    primary row of Tables III-V and Sec. III-C is fitted, no behaviour penalty, no breakaway."""
    assert ident.cases("sensor") == [("calibration", "", None), ("thermal", "", None)]
    assert set(ident.cases("joint")) == set(ident.cases("drivetrain")) | set(ident.cases("sensor"))
    objective = ident.Objective(ident.default_space(part="sensor"), ident.Setup(TestbedParams()), (0,), Executor(1),
                                part="sensor")
    (evaluation,) = objective.run([ident.candidate_overrides(TestbedParams(), {})])
    seed = evaluation.record["seeds"]["0"]
    assert {r["table"] for r in seed["rows"] if ident.primary(r)} == {"III", "IV", "III-B resolution", "V", "III-C"}
    assert all(r["sim"] is not None for r in seed["rows"] if ident.primary(r))  # the DYJN-104's rows are not fitted
    assert {r["group"] for r in seed["rows"]} == {"calibration", "thermal"}
    assert seed["penalties"] == {} and evaluation.record["breakaway_nm"] is None
    assert evaluation.score == pytest.approx(seed["rms_log_ratio"]) and 0.0 < evaluation.score < 2.0


def test_the_objective_is_the_same_in_process_on_two_processes_and_on_a_local_ray_cluster():
    space = ident.default_space()
    xs = [np.full(len(space), 0.4), np.linspace(0.1, 0.9, len(space))]
    setup = ident.Setup(FAST, duration_s=0.05)
    results = [ident.Objective(space, setup, (0, 3), executor)(xs)
               for executor in (Executor(1), Executor(2), Executor(ray="local"))]
    assert results[0] == results[1] == results[2]
    assert results[0][0].score != results[0][1].score  # the candidates differ, so would a mix-up
    record = results[0][0].record
    assert set(record["seeds"]) == {"0", "3"} and record["seeds"]["0"]["rows"] != record["seeds"]["3"]["rows"]
    rows = record["seeds"]["0"]["rows"]
    assert sum(ident.primary(r) for r in rows) == 20  # every Table VI-VII figure, both feedbacks


def test_hinge_penalty_is_zero_inside_the_band_and_the_squared_log_distance_outside():
    assert ident.hinge(0.3, (0.2, 0.4)) == 0.0
    assert ident.hinge(0.1, (0.2, 0.4)) == pytest.approx(math.log(2) ** 2)
    assert ident.hinge(0.8, (0.2, 0.4)) == pytest.approx(math.log(2) ** 2)
    assert ident.hinge(None, (0.2, 0.4)) == pytest.approx(math.log(0.2 / 1e-3) ** 2)
    assert ident.hinge(5.0, (2.0, math.inf)) == 0.0


def step_result(step, fraction, rows=()):
    return {"kind": "step", "feedback": "current", "reference_nm": step, "reached_fraction": fraction,
            "group": "steps", "rows": list(rows)}


def test_reached_fractions_in_their_bands_and_increasing_cost_nothing_and_a_decrease_costs():
    good = ident.penalties([step_result(0.05, 0.3), step_result(0.1, 0.4), step_result(0.2, 0.65)])
    assert all(p == 0.0 for _, p in good.values())
    bad = ident.penalties([step_result(0.05, 0.35), step_result(0.1, 0.32), step_result(0.2, 0.65)])
    assert bad["reached fraction increases with the step"][1] == pytest.approx(math.log(0.35 / 0.32) ** 2)


def test_a_held_out_group_leaves_the_score_but_not_the_report():
    def row(group, ratio, table="VI"):
        return {"table": table, "quantity": group, "unit": "N·m", "paper": 1.0, "sim": ratio, "ratio": ratio,
                "group": group}

    results = [step_result(0.05, 0.3, [row("steps", math.e)]),
               {"kind": "other", "rows": [row("disturbance", 1.0), row("disturbance", 9.0, "IV-A text")]}]
    assert ident.seed_score(results)["rms_log_ratio"] == pytest.approx(math.sqrt(0.5))
    assert ident.seed_score(results, holdout="steps")["rms_log_ratio"] == 0.0
    assert "reached fraction 0.05 N·m" not in ident.seed_score(results, holdout="steps")["penalties"]
    assert ident.group_scores([r for x in results for r in x["rows"]]) == {"steps": 1.0, "disturbance": 0.0}


def test_the_parameter_toml_loads_to_the_candidates_parameters(tmp_path):
    space = ident.default_space()
    overrides = space.overrides(np.linspace(0.05, 0.95, len(space)))
    path = tmp_path / "best.toml"
    path.write_text(ident.params_toml(overrides, "a header\nof two lines"))
    assert load_params(path) == TestbedParams().replace(**overrides)


def test_the_command_writes_its_outputs_and_resumes_reusing_its_evaluations(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["--out", str(out), "--seeds", "0", "--duration", "0.05", "--fast"]
    ident.main([*argv, "--budget", "2"])
    text = capsys.readouterr().out
    assert text.index("SHORT RUN (--duration 0.05 s)") < text.index("best score")
    first = (out / "evals.jsonl").read_text().splitlines()
    assert len(first) == 2
    params = load_params(out / "best_params.toml")
    report = json.loads((out / "report.json").read_text())
    assert {p["path"] for p in report["parameters"]} == set(ident.DRIVETRAIN)
    assert params.backlash.width_rad == next(p["value"] for p in report["parameters"]
                                             if p["path"] == "backlash.width_rad")
    assert "| table | quantity |" in (out / "report.md").read_text()
    with pytest.raises(SystemExit) as exc:  # a run is never mixed into another
        ident.main([*argv, "--budget", "2"])
    assert exc.value.code == 2 and "holds a run already" in capsys.readouterr().err
    ident.main([*argv, "--budget", "4", "--resume"])
    lines = (out / "evals.jsonl").read_text().splitlines()
    assert lines[:2] == first and len(lines) == 4
    assert json.loads((out / "report.json").read_text())["evaluations"] == 4


def test_holdout_names_the_groups():
    with pytest.raises(SystemExit) as exc:
        ident.main(["--holdout", "nonsense"])
    assert exc.value.code == 2
    assert set(ident.GROUPS) == {"steps", "disturbance", "0.05_Nm_sine_0.2_Hz", "0.1_Nm_square_1_Hz",
                                 "10_Nm_sine_0.2_Hz", "calibration", "thermal"}
    for part, group in (("drivetrain", "thermal"), ("sensor", "steps")):
        with pytest.raises(SystemExit) as exc:
            ident.main(["--part", part, "--holdout", group])
        assert exc.value.code == 2


def test_the_parameter_toml_keeps_what_the_params_file_set_beside_the_candidate(tmp_path, capsys, monkeypatch):
    # the search's best candidate as the result, even where the base parameters score lower
    monkeypatch.setattr(ident, "choose_best", lambda result, base, base_x: (result.best, result.best_x, False))
    base = tmp_path / "rig.toml"
    base.write_text("[loadcell]\nreading_noise_n = 0.02\n\n[backlash]\nwidth_rad = 0.003\n")
    out = tmp_path / "run"
    ident.main(["--out", str(out), "--params", str(base), "--budget", "2", "--seeds", "0", "--duration", "0.05",
                "--fast"])
    best = load_params(out / "best_params.toml")
    report = json.loads((out / "report.json").read_text())
    assert best.loadcell.reading_noise_n == 0.02
    width = next(p["value"] for p in report["parameters"] if p["path"] == "backlash.width_rad")
    assert best.backlash.width_rad == width != 0.003


def test_each_group_held_out_in_turn_picks_the_candidate_best_without_it_and_scores_it_on_the_group():
    def record(name, steps_ratio, disturbance_ratio):
        rows = [{"table": "VI", "quantity": "q", "unit": "N·m", "paper": 1.0, "sim": x, "ratio": x, "group": g}
                for g, x in (("steps", steps_ratio), ("disturbance", disturbance_ratio))]
        behaviours = {"reached fraction 0.05 N·m": ("steps", 0.0)}
        return {"overrides": {"name": name}, "seeds": {"0": {"rows": rows, "behaviours": behaviours}}}

    records = [record("good steps", 1.0, math.e ** 2), record("good disturbance", math.e, 1.0),
               {"overrides": {"name": "refused"}, "errors": ["ParameterError"]}]
    held = ident.rotation(records)
    assert held["steps"]["overrides"] == {"name": "good disturbance"}
    assert held["steps"]["held_out_rms_log_ratio"] == pytest.approx(1.0) and held["steps"]["fit_score"] == 0.0
    assert held["disturbance"]["overrides"] == {"name": "good steps"}
    assert held["disturbance"]["held_out_rms_log_ratio"] == pytest.approx(2.0)


def test_a_candidate_the_parameters_refuse_keeps_its_overrides_for_run_case_to_score_infeasible():
    """Coulomb above the base's breakaway breaks a rule between fields: the overrides come back unchanged."""
    base = TestbedParams().replace(friction={"breakaway_torque_nm": 0.12, "coulomb_torque_nm": 0.09})
    overrides = {"friction": {"coulomb_torque_nm": 0.13}}
    assert ident.candidate_overrides(base, overrides) == overrides


def test_a_sensor_candidate_no_calibration_can_meet_is_scored_as_an_error_not_raised(monkeypatch):
    """A calibration that cannot meet the paper's bound (InfeasibleCalibrationError) makes the case an error
    row, which the score counts as infeasible, instead of ending the search."""
    def infeasible(params, seed):
        raise InfeasibleCalibrationError(0.01, 0.02, 100, 80.0)

    monkeypatch.setitem(ident.SENSOR_CASES, "calibration", infeasible)
    out = ident.run_case(ident.Setup(TestbedParams()), ({}, 0, ("calibration", "", None)))
    assert out["error"].startswith("InfeasibleCalibrationError: QP calibration is infeasible")


@pytest.mark.parametrize("seed", ["-1", str(2**32)])
def test_a_search_seed_outside_what_cma_takes_is_a_usage_error(seed):
    with pytest.raises(SystemExit) as exc:
        ident.main(["--search-seed", seed])
    assert exc.value.code == 2


@pytest.mark.parametrize("sigma0", ["0", "-0.1", "1.5"])
def test_an_initial_step_outside_the_unit_box_is_a_usage_error_naming_its_range(sigma0, capsys):
    with pytest.raises(SystemExit) as exc:
        ident.main(["--sigma0", sigma0])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--sigma0" in err and "(0, 1]" in err


def test_the_base_parameters_are_the_result_when_no_candidate_scores_below_them():
    from experiments.search import Evaluation, SearchResult

    base = Evaluation(0.4, {"overrides": {}})
    found = Evaluation(0.5, {"overrides": {"friction": {"coulomb_torque_nm": 0.1}}})
    result = SearchResult(np.array([0.2, 0.8]), found, 10, 1, [])
    best, x, kept = ident.choose_best(result, base, [0.5, 0.5])
    assert kept and best is base and x.tolist() == [0.5, 0.5]
    better = Evaluation(0.3, found.record)
    best, x, kept = ident.choose_best(SearchResult(np.array([0.2, 0.8]), better, 10, 1, []), base, [0.5, 0.5])
    assert not kept and best is better and x.tolist() == [0.2, 0.8]
