"""sim.recording: a short run written to an .rrd and read back with rerun's own reader has every entity with
the number of samples promised; the experiment flags record through the shared helper."""

import argparse
from collections import Counter

import numpy as np
import pytest
import rerun as rr

from controllers.feedback import make_feedback
from controllers.loop import run_torque_loop
from controllers.pi import PITorqueController
from experiments.common import add_experiment_args, record_log, record_rerun
from sim.params import TestbedParams
from sim.plant import Plant
from sim.recording import entity_name, record_logs
from sim.run import run_open_loop

N_TICKS = 300  # 0.3 s at 1 kHz


@pytest.fixture(scope="module")
def sensor_log():
    p = TestbedParams()
    plant = Plant(p, "locked")
    plant.reset(backlash_side=1)
    ref = np.r_[np.zeros(50), np.full(N_TICKS - 50, 0.1)]
    return run_torque_loop(plant, PITorqueController(18.0), make_feedback("sensor", p, 0), ref, meta={})


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
    """v1..v8 of a sensor-feedback log map through the factory calibration to tau_sensor, tick by tick."""
    from sensor.readout import factory_calibration

    volts = np.column_stack([sensor_log[f"v{k}"] for k in range(1, 9)])
    predicted = factory_calibration(TestbedParams()).predict(volts)
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
    open_loop_step.main(["--duration", "0.05", "--rerun", str(path)])
    rows, _ = read_back(path)
    assert rows["/open-loop_step_0.1_N_m/torque/command"] == 50
    assert "rerun recording" in capsys.readouterr().out
