"""What the discrepancy analysis reports is what it saves: every final figure is the saved rig's.

Each case runs the command line as a user would (logs written as files, a rig file, ``--json`` and
``--save-rig``), then runs it again with the saved rig as the rig: the saved rig loads, and the second run's
baseline (its held-out RMSE and every log's relative effort error) is the first run's final model, figure for
figure. The cases are the test suite's kinds of log: the testbed (locked and free fixtures), rigid hinges and slides
of the project's simulator, and logs of the independent simulator (tests/independent) with a validation record,
in the 'command' time convention unstated, and records zeroed anew.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from experiments import discrepancy as cli
from experiments.synthetic_logs import hidden_effect_log
from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.model import baseline_theta
from sim.discrepancy.rig import load_rig, rig_to_toml
from sim.logio import write_log
from tests.independent import battery, rigsim

DURATION_S = 10.0
TRUE_COULOMB = battery.baseline("slide", 36)["coulomb"]  # the rig's own: nothing but the time stamps differs


def _project_case(experiment: str, effect: str, seed: int):
    log, rig, _ = hidden_effect_log(experiment, [effect], seed, DURATION_S)
    return [log], [], rig_to_toml(rig)


def _independent(joint: str, seed: int, n: int, *, convention: str = "hold_end", offset: float = 0.0,
                 coulomb: float | None = None):
    """A rigid joint of the independent simulator under a PID multisine (its truth: Coulomb 1.3 x the rig's)."""
    values = battery.baseline(joint, seed)
    plant = battery.plant_of(joint, values, coulomb=coulomb or 1.3 * values["coulomb"])
    ref = battery.reference(joint, "multisine", seed, n)
    run = rigsim.simulate(plant, rigsim.PID.tuned(ref, values["mass"], 5.0, plant.peak_effort), n, seed=seed,
                          time_convention=convention)
    log = run.to_log()
    columns = dict(log.columns)
    columns["tau_cmd"] = columns["tau_cmd"] + offset  # a sensor zeroed anew reads the effort with an offset
    meta = {k: v for k, v in log.meta.items() if k != "time_convention"}  # the convention stated nowhere
    return type(log)(columns, dict(log.units), meta), values


def _independent_rig(joint: str, values: dict) -> str:
    return battery.rig_toml({"joint": joint, **values}, "independent rigid joint")


def _validation_case():
    estimation, values = _independent("slide", 31, 12000, convention="command")
    validation, _ = _independent("slide", 32, 8000, convention="command")
    return [estimation], [validation], _independent_rig("slide", values)


def _rezeroed_case():
    first, values = _independent("hinge", 33, 10000, offset=0.1)
    second, _ = _independent("hinge", 34, 10000, offset=-0.15)
    third, _ = _independent("hinge", 35, 8000, offset=0.02)
    return [first, second], [third], _independent_rig("hinge", values)


CASES = {
    "testbed-locked-sensor_offset": lambda: _project_case("locked", "sensor_offset", 2),
    "testbed-free-cogging": lambda: _project_case("free", "cogging", 3),
    "hinge-gravity": lambda: _project_case("hinge", "gravity", 4),
    "slide-constant_effort": lambda: _project_case("slide", "constant_effort", 5),
    "independent-slide-validation-command-convention": _validation_case,
    "independent-hinge-records-zeroed-anew": _rezeroed_case,
}


def _run(paths: list, validation: list, rig_path, out_json, save=None) -> dict:
    argv = [*map(str, paths), "--rig", str(rig_path), "--json", str(out_json), "--workers", "1", "--no-replay",
            "--no-plot"]
    if validation:
        argv += ["--validate", *map(str, validation)]
    if save is not None:
        argv += ["--save-rig", str(save)]
    cli.main(argv)
    return json.loads(out_json.read_text(encoding="utf-8"))


@pytest.mark.parametrize("case", list(CASES))
def test_the_saved_rig_loads_and_an_analysis_of_it_starts_where_the_first_ended(case, tmp_path, capsys):
    estimation, validation, rig_text = CASES[case]()
    paths = []
    for i, log in enumerate([*estimation, *validation]):
        paths.append(tmp_path / f"record{i}.csv")
        write_log(log, paths[-1])
    rig_path = tmp_path / "rig.toml"
    rig_path.write_text(rig_text, encoding="utf-8")
    n = len(estimation)
    first = _run(paths[:n], paths[n:], rig_path, tmp_path / "first.json", tmp_path / "saved.toml")
    carried = baseline_theta(load_rig(tmp_path / "saved.toml"))
    assert all(EFFECTS[f["effect"]].present(carried) for f in first["findings"])
    for f in first["findings"]:
        for name, p in f["parameters"].items():
            assert carried[name] == p["value"]
    second = _run(paths[:n], paths[n:], tmp_path / "saved.toml", tmp_path / "second.json")
    final, again = first["final"]["rmse_heldout"], second["baseline"]["rmse_heldout"]
    assert set(final) == set(again)
    for channel, value in final.items():  # a channel without held-out samples is null in both
        assert again[channel] == (None if value is None else pytest.approx(value, rel=1e-9)), channel
    for a, b in zip(first["logs"], second["logs"], strict=True):
        assert a["log"] == b["log"]
        assert b["relative_effort_error"]["baseline"] == pytest.approx(a["relative_effort_error"]["final"], rel=1e-9)
    report = capsys.readouterr().out
    for entry in first["logs"]:  # the printed figure is the saved one
        assert f"final model {entry['relative_effort_error']['final']:.4f}" in report
    for f in first["findings"]:  # every accepted value inside its range, none on a bound
        for name, p in f["parameters"].items():
            low, high = p["bounds"]
            assert low < p["value"] < high, (f["effect"], name, p)


def test_a_stated_hold_end_convention_makes_a_one_sample_dead_time_a_saved_finding(tmp_path):
    """Logs stamped in the 'command' convention but stated as 'hold_end' act one sample late: with the convention
    stated, that dead time is a confident finding, and it is saved."""
    log, values = _independent("slide", 36, 12000, convention="command", coulomb=TRUE_COULOMB)
    path, rig_path = tmp_path / "log.csv", tmp_path / "rig.toml"
    write_log(log, path)
    rig_path.write_text('time_convention = "hold_end"\n' + _independent_rig("slide", values), encoding="utf-8")
    result = _run([path], [], rig_path, tmp_path / "out.json", tmp_path / "saved.toml")
    assert [f["effect"] for f in result["findings"]] == ["transport_delay"]
    assert result["findings"][0]["parameters"]["delay"]["value"] == pytest.approx(1e-3, abs=2e-4)
    assert load_rig(tmp_path / "saved.toml").rigid["delay"] == pytest.approx(1e-3, abs=2e-4)
    assert not result["tentative"]


def test_an_unstated_convention_is_saved_with_the_rig_and_the_figures_are_the_saved_rigs(tmp_path):
    """The same logs with no convention stated: the saved rig states time_convention = 'command', carries no dead
    time, and its figures are the ones reported."""
    log, values = _independent("slide", 36, 12000, convention="command", coulomb=TRUE_COULOMB)
    path, rig_path = tmp_path / "log.csv", tmp_path / "rig.toml"
    write_log(log, path)
    rig_path.write_text(_independent_rig("slide", values), encoding="utf-8")
    result = _run([path], [], rig_path, tmp_path / "out.json", tmp_path / "saved.toml")
    saved = load_rig(tmp_path / "saved.toml")
    assert saved.time_convention == "command" and saved.rigid["delay"] == 0.0
    assert result["verdict"] == "time convention" and result["findings"] == []
    assert result["logs"][0]["relative_effort_error"]["final"] < result["logs"][0]["relative_effort_error"]["baseline"]
    assert np.isfinite(result["final"]["rmse_heldout"]["effort"])
