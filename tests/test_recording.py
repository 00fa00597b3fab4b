"""sim.recording: a short run written to an .rrd and read back with rerun's own reader has every entity with
the number of samples promised; the experiment flags record through the shared helper."""

import argparse
from collections import Counter

import numpy as np
import pytest
import rerun as rr

from controllers.pi import PITorqueController
from controllers.tracking import run_tracking
from experiments.common import add_experiment_args, record_log, record_rerun
from sim.params import TestbedParams
from sim.plant import Plant
from sim.recording import entity_name, record_logs
from sim.run import run_open_loop
from sim.runlog import RunLog

N_TICKS = 300  # 0.3 s at 1 kHz


@pytest.fixture(scope="module")
def sensor_log():
    p = TestbedParams()
    plant = Plant(p, "locked")
    plant.reset(backlash_side=1)
    ref = np.r_[np.zeros(50), np.full(N_TICKS - 50, 0.1)]
    return run_tracking(p, plant, PITorqueController(18.0), "sensor", 0, ref)


def read_back(path) -> tuple[Counter, set]:
    """Rows per non-static entity on the 'time' timeline, and the static entities, from rerun's RRD reader."""
    rows, static = Counter(), set()
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            static.add(chunk.entity_path)
        else:
            assert "time" in chunk.timeline_names
            rows[chunk.entity_path] += chunk.num_rows
    return rows, static


def test_sensor_run_recording_has_every_entity_with_its_sample_count(tmp_path, sensor_log):
    """Every tick of reference, sensor, load-cell, command torques, the eight voltages and the temperature;
    the 3D pose and torque arrow at 50 Hz (every 20th tick); the four parts of the rig as static geometry."""
    path = tmp_path / "run.rrd"
    summary = record_logs({"step 0.1 N·m, sensor": sensor_log}, TestbedParams(), path=path)
    root = "/step_0.1_N_m_sensor"
    assert summary.runs == {root[1:]: N_TICKS} and summary.pose_samples == {root[1:]: N_TICKS // 20}
    rows, static = read_back(path)
    for signal in ("reference", "sensor", "loadcell", "command", "feedback", "flexure"):
        assert rows[f"{root}/torque/{signal}"] == N_TICKS, signal
    for k in range(1, 9):
        assert rows[f"{root}/voltages/v{k}"] == N_TICKS
    assert rows[f"{root}/temperature/board"] == N_TICKS
    for entity in ("hub", "flexure", "torque"):
        assert rows[f"{root}/testbed/{entity}"] == N_TICKS // 20
    for part in ("motor/cylinders", "hub/cylinders", "flexure/cylinders", "flexure/boxes", "loadcell/boxes"):
        assert f"{root}/testbed/{part}" in static
    assert rr.chunk.RrdReader(path).blueprints()  # the layout travels with the file


def test_loop_log_voltages_are_the_ones_the_sensor_reading_was_computed_from(sensor_log):
    """v1..v8 of a sensor-feedback log map through the factory calibration, less the run's tare (in the log's
    meta), to tau_sensor, tick by tick."""
    from sensor.readout import factory_calibration

    volts = np.column_stack([sensor_log[f"v{k}"] for k in range(1, 9)])
    predicted = factory_calibration(TestbedParams()).predict(volts) - sensor_log.meta["sensor_tare_nm"]
    assert sensor_log.meta["sensor_tare_nm"] != 0.0
    np.testing.assert_allclose(predicted, sensor_log["tau_sensor"], rtol=1e-9, atol=1e-12)


def test_two_runs_and_a_free_fixture_run_record_side_by_side(tmp_path, sensor_log):
    """Two runs go under their own entity roots; an open-loop free-fixture run has no load cell."""
    plant = Plant(TestbedParams(), "free")
    free = run_open_loop(plant, np.full(100, 0.3), progress=False)
    path = tmp_path / "two.rrd"
    record_logs({"locked": sensor_log, "free": free}, path=path)
    rows, static = read_back(path)
    assert rows["/locked/torque/reference"] == N_TICKS
    assert rows["/free/torque/command"] == 100 and rows["/free/testbed/flexure"] == 5
    assert "/free/testbed/loadcell/boxes" not in static and "/free/torque/loadcell" not in rows


def test_rig_record_without_mechanics_records_series_only(tmp_path):
    """A calibration-rig record (voltages, torques, temperature) records its series and no 3D testbed."""
    t = np.arange(1, 41) * 0.1
    log = record_log(t, np.full((40, 8), 1.65), tau_sensor_nm=np.zeros(40), tau_mini85_nm=np.zeros(40),
                     temperature_c=np.full(40, 25.0))
    path = tmp_path / "rig.rrd"
    summary = record_logs({"chamber": log}, path=path)
    rows, static = read_back(path)
    assert summary.pose_samples == {"chamber": 0}
    assert rows["/chamber/voltages/v8"] == 40 and rows["/chamber/torque/mini85"] == 40
    assert not any("/testbed" in e for e in set(rows) | static)


def test_experiment_flags_record_through_the_shared_helper(tmp_path, sensor_log, capsys):
    """--rerun PATH on add_experiment_args writes the recording; without the flags nothing is recorded."""
    parser = argparse.ArgumentParser()
    add_experiment_args(parser)
    path = tmp_path / "x.rrd"
    record_rerun(parser.parse_args(["--rerun", str(path)]), {"a": sensor_log})
    assert path.stat().st_size > 1000 and "rerun recording" in capsys.readouterr().out
    args = parser.parse_args([])
    assert args.rerun is None and args.rerun_spawn is False
    record_rerun(args, {"a": sensor_log})  # no flags: no file, no viewer
    assert list(tmp_path.iterdir()) == [path]


def test_bad_arguments_are_refused_by_name(tmp_path, sensor_log):
    """No sink, clashing run names and a bad pose rate are refused naming the argument."""
    with pytest.raises(ValueError, match="path"):
        record_logs({"a": sensor_log})
    with pytest.raises(ValueError, match="entity paths"):
        record_logs({"a b": sensor_log, "a_b": sensor_log}, path=tmp_path / "c.rrd")
    with pytest.raises(ValueError, match="pose_rate_hz"):
        record_logs({"a": sensor_log}, path=tmp_path / "d.rrd", pose_rate_hz=0.0)
    assert entity_name("step 0.05 N·m, sensor") == "step_0.05_N_m_sensor"


def test_experiment_commands_write_their_runs_to_rerun(tmp_path, capsys):
    """experiments.step and experiments.open_loop_step with --rerun record one entity root per run."""
    from experiments import open_loop_step, step

    path = tmp_path / "step.rrd"
    step.main(["--feedback", "current", "--duration", "0.05", "--plot", str(tmp_path), "--rerun", str(path)])
    rows, _ = read_back(path)
    assert rows["/step_0.05_N_m_current/torque/reference"] == 550  # 0.5 s before the step + 0.05 s
    assert "/disturbance_current/torque/loadcell" in rows
    path = tmp_path / "open.rrd"
    open_loop_step.main(["--duration", "0.05", "--plot", str(tmp_path), "--rerun", str(path)])
    rows, _ = read_back(path)
    assert rows["/open-loop_step_0.1_N_m/torque/command"] == 50
    assert "rerun recording" in capsys.readouterr().out


# ---------------------------------------------------------------- extra series, blueprint, the analysis CLIs
def _views(container) -> list:
    """Every view of a blueprint container, depth first."""
    out = []
    for item in container.contents:
        out.extend(_views(item) if hasattr(item, "row_shares") else [item])
    return out


def series_labels(path, prefix: str) -> set[str]:
    """The series names (SeriesLines, with their units) of the entities under ``prefix``."""
    labels = set()
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        if chunk.is_static and chunk.entity_path.startswith(prefix) and "SeriesLines:names" in batch.schema.names:
            labels.update(name for names in batch.column("SeriesLines:names").to_pylist() for name in names)
    return labels


def _series_log(n: int, unit: str = "N·m", **columns) -> RunLog:
    return RunLog({"time": np.arange(1, n + 1) * 1e-3, **columns}, {"time": "s", **{c: unit for c in columns}})


def test_extra_series_go_under_their_group_on_their_own_time_with_a_view(tmp_path, sensor_log):
    """A run's extra series (here 120 samples beside a 300-tick run) are recorded under /<run>/<group>/<name>
    with their own sample count, and the run's tab gets a view titled with the group's unit; the fixed
    layout of the run is unchanged."""
    from sim.recording import blueprint

    extra = _series_log(120, measured=np.zeros(120), **{"simulated baseline": np.ones(120)})
    path = tmp_path / "extra.rrd"
    summary = record_logs({"a": sensor_log}, path=path, series={"a": {"replay": extra}})
    rows, _ = read_back(path)
    assert rows["/a/replay/measured"] == 120 and rows["/a/replay/simulated_baseline"] == 120
    assert rows["/a/torque/reference"] == N_TICKS and summary.series == {"a": {"replay": 120}}
    views = _views(blueprint(["a"], {"a": {"replay": extra}}).root_container)
    assert [(v.origin, v.name) for v in views][-1] == ("/a/replay", "replay [N·m]")
    assert "/a/replay" not in {v.origin for v in _views(blueprint(["a"]).root_container)}


def test_extra_series_clashing_with_the_layout_or_without_a_run_are_refused(tmp_path, sensor_log):
    """A group named like a fixed one, or series for a run that is not recorded, is refused by name."""
    extra = _series_log(10, x=np.zeros(10))
    with pytest.raises(ValueError, match="'torque'.*fixed layout"):
        record_logs({"a": sensor_log}, path=tmp_path / "e.rrd", series={"a": {"torque": extra}})
    with pytest.raises(ValueError, match="'b'.*not among the recorded runs"):
        record_logs({"a": sensor_log}, path=tmp_path / "f.rrd", series={"b": {"replay": extra}})


def test_blueprint_shows_only_what_a_run_has(sensor_log):
    """Given the logs, a rig record (no mechanics, no temperature) gets no 3D view and no temperature view;
    a plant run keeps the 3D testbed and all fixed views."""
    from sim.recording import blueprint

    rig = record_log(np.arange(1, 11) * 0.1, np.full((10, 8), 1.65), tau_sensor_nm=np.zeros(10))
    tabs = blueprint(["rig", "run"], logs={"rig": rig, "run": sensor_log}).root_container.contents
    assert [v.origin for v in _views(tabs[0])] == ["/rig/torque", "/rig/voltages"]
    assert [v.origin for v in _views(tabs[1])] == ["/run/testbed", "/run/torque", "/run/voltages",
                                                   "/run/temperature"]


def test_plant_card_records_the_breakaway_ramp_and_backlash_reversal_it_measured(tmp_path):
    """experiments.plant --rerun records the two simulated measurements as they ran for the card: the
    breakaway ramp ends 100 ms (100 ticks) after the motion began at the measured breakaway torque, the
    reversal is 1.5 periods of 4 s; keeping the logs changes no figure of the card."""
    import json

    from experiments import plant
    from sim.characterize import BREAKAWAY_RAMP_NM_PER_S, BREAKAWAY_SUSTAIN_S

    path, out = tmp_path / "plant.rrd", tmp_path / "card.json"
    plant.main(["--rerun", str(path), "--json", str(out), "--plot", str(tmp_path)])
    breakaway = json.loads(out.read_text())["derived"]["breakaway_torque_measured"]["value"]
    rows, static = read_back(path)
    ramp_ticks = round(breakaway / BREAKAWAY_RAMP_NM_PER_S / 1e-3) + round(BREAKAWAY_SUSTAIN_S / 1e-3)
    assert rows["/breakaway_ramp_free/torque/command"] == ramp_ticks
    assert rows["/breakaway_ramp_free/testbed/flexure"] == len(range(0, ramp_ticks, 20))
    assert "/breakaway_ramp_free/torque/loadcell" not in rows  # free fixture: no load cell
    assert rows["/backlash_reversal_locked/torque/loadcell"] == 6000
    assert rows["/backlash_reversal_locked/testbed/torque"] == 300
    assert "/backlash_reversal_locked/testbed/loadcell/boxes" in static
    card = plant.run_plant_card()
    assert card.logs == {} and card.derived == plant.run_plant_card(keep_logs=True).derived


def test_identify_defaults_records_the_runs_of_its_best_candidate(tmp_path, capsys):
    """experiments.identify_defaults --rerun records the best candidate's six step, two disturbance and six
    sinusoid runs, and its parameters are those of best_params.toml; without --rerun nothing is recorded."""
    from experiments import identify_defaults

    path = tmp_path / "best.rrd"
    argv = ["--budget", "2", "--seeds", "0", "--duration", "0.05", "--fast"]
    identify_defaults.main([*argv, "--out", str(tmp_path / "run"), "--rerun", str(path)])
    rows, _ = read_back(path)
    roots = {e.split("/")[1] for e in rows}
    assert len(roots) == 14 and rows["/step_0.05_N_m_sensor/torque/reference"] == 550
    assert rows["/disturbance_current/torque/loadcell"] == 50
    assert "rerun recording" in capsys.readouterr().out
    identify_defaults.main([*argv, "--out", str(tmp_path / "plain")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.rrd", "plain", "run"]


@pytest.fixture(scope="module")
def measured_locked(tmp_path_factory):
    """A 3 s locked-fixture log from the project's simulator (no hidden effect) and its baseline rig."""
    return _measured("locked", tmp_path_factory.mktemp("locked"))


def _measured(experiment, directory):
    from experiments.synthetic_logs import hidden_effect_log
    from sim.discrepancy.rig import rig_to_toml
    from sim.logio import write_log

    log, rig, _ = hidden_effect_log(experiment, [], seed=1, duration_s=3.0)
    log_path, rig_path = directory / "bench.parquet", directory / "rig.toml"
    write_log(log, log_path)
    rig_path.write_text(rig_to_toml(rig))
    return log_path, rig_path, len(log)


def test_discrepancy_records_the_measured_testbed_log_and_residuals_without_replay(tmp_path, measured_locked):
    """A testbed log with the plant's columns records as a run (3D testbed, torques, temperature) with its
    angles, every sample, and the residuals before/after, every analysis-grid sample; --no-replay: no replay
    series."""
    from experiments import discrepancy
    from sim.discrepancy.signals import AnalysisConfig, grid_step

    log_path, rig_path, n = measured_locked
    n_grid = len(range(0, n, grid_step(AnalysisConfig(), 1e-3)))
    path = tmp_path / "d.rrd"
    discrepancy.main([str(log_path), "--rig", str(rig_path), "--workers", "1", "--no-replay", "--plot", str(tmp_path),
                      "--rerun", str(path)])
    rows, static = read_back(path)
    root = "/measured_bench"
    for entity in ("torque/command", "torque/loadcell", "torque/sensor", "temperature/board", "position/lever",
                   "position/motor"):
        assert rows[f"{root}/{entity}"] == n, entity
    for entity in ("residual_effort/baseline", "residual_sensor/extended"):
        assert rows[f"{root}/{entity}"] == n_grid, entity
    assert rows[f"{root}/testbed/torque"] == n // 20 and f"{root}/testbed/loadcell/boxes" in static
    assert not any("/replay" in e for e in rows)


def test_discrepancy_records_the_replay_of_the_held_out_part(tmp_path, measured_locked):
    """With the replay, the measured, baseline and extended load-cell torque of every sample of the held-out
    part are recorded under /<run>/replay, labelled in N·m."""
    import json

    from experiments import discrepancy

    log_path, rig_path, _ = measured_locked
    path, out = tmp_path / "r.rrd", tmp_path / "r.json"
    discrepancy.main([str(log_path), "--rig", str(rig_path), "--workers", "1", "--json", str(out),
                      "--plot", str(tmp_path), "--rerun", str(path)])
    baseline = json.loads(out.read_text())["baseline"]
    samples = baseline["replay"]["samples"] + baseline["replay"]["skipped_samples"]  # and those quiet starts skip
    split = baseline["split"]
    assert abs(samples - split["held_out_samples"] * split["grid_step"]) <= split["grid_step"]  # the held-out part
    samples = baseline["replay"]["samples"]
    rows, _ = read_back(path)
    assert [rows[f"/measured_bench/replay/{s}"] for s in ("measured", "baseline", "extended")] == [samples] * 3
    assert series_labels(path, "/measured_bench/replay/") == {"measured [N·m]", "baseline [N·m]", "extended [N·m]"}


def test_discrepancy_records_a_slide_log_as_series_without_testbed(tmp_path):
    """A rigid slide log has no testbed geometry: its force command and position are recorded as series
    (with the residual, on the analysis grid), nothing under testbed/ or torque/."""
    from experiments import discrepancy
    from sim.discrepancy.signals import AnalysisConfig, grid_step

    log_path, rig_path, n = _measured("slide", tmp_path)
    path = tmp_path / "s.rrd"
    discrepancy.main([str(log_path), "--rig", str(rig_path), "--workers", "1", "--no-replay", "--plot", str(tmp_path),
                      "--rerun", str(path)])
    rows, static = read_back(path)
    assert rows["/measured_bench/effort/command"] == n and rows["/measured_bench/position/joint"] == n
    assert rows["/measured_bench/residual_effort/baseline"] == len(range(0, n, grid_step(AnalysisConfig(), 1e-3)))
    assert series_labels(path, "/measured_bench/effort/") == {"command [N]"}
    assert series_labels(path, "/measured_bench/position/") == {"joint [m]"}
    assert not any("/testbed" in e or "/torque" in e for e in set(rows) | static)
