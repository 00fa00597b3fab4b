"""The discrepancy analysis's input: implausible logs refused by column and row, the time convention, several
logs fitted together and validation logs, decimation of long logs.

Logs come from the project's MuJoCo rigs (experiments.synthetic_logs) and from the independent simulator
(tests/independent/rigsim.py).
"""

import dataclasses
import math

import numpy as np
import pytest

from experiments import discrepancy as cli
from experiments.synthetic_logs import hidden_effect_log, synth_log
from sim.discrepancy.analysis import Source, analyse, join
from sim.discrepancy.checks import InputError, check_log, to_hold_end, wrapped_steps
from sim.discrepancy.rig import RigError, rig_from_dict
from sim.discrepancy.signals import MAX_ANALYSIS_SAMPLES, AnalysisConfig, decimation_factor, prepare
from sim.logio import write_log
from sim.runlog import COMMAND, HOLD_END
from tests.independent import rigsim

DURATION_S = 8.0
CUTOFF_HZ = AnalysisConfig().filter_cutoff_hz


@pytest.fixture(scope="module")
def hinge():
    """A clean rigid-hinge log and its rig."""
    log, rig, _ = hidden_effect_log("hinge", [], 3, DURATION_S)
    return log, rig


def _with(log, **columns):
    return type(log)({**log.columns, **columns}, dict(log.units), dict(log.meta))


def test_a_command_beyond_the_peak_effort_is_refused_naming_row_and_unit(hinge):
    """Commands logged in mN·m exceed the rig's peak by ~1000 x: refused, naming tau_cmd, the row and the hint."""
    log, rig = hinge
    with pytest.raises(InputError) as err:
        check_log(_with(log, tau_cmd=1000.0 * log["tau_cmd"]), rig, filter_cutoff_hz=CUTOFF_HZ)
    assert err.value.column == "tau_cmd" and err.value.row is not None
    assert "mN·m" in str(err.value) and "peak command" in str(err.value)


def test_a_wrapped_encoder_is_refused_and_unwrapped_on_request(hinge):
    """A hinge angle wrapped to [0, 2π) jumps by about 2π: refused with the row and --unwrap; unwrapped, it is
    the original angle to rounding."""
    log, rig = hinge
    q = np.asarray(log["q"]) + 5.0  # the swing crosses 2π
    wrapped = _with(log, q=np.mod(q, 2 * math.pi))
    assert len(wrapped_steps(np.mod(q, 2 * math.pi))) > 0
    with pytest.raises(InputError) as err:
        check_log(wrapped, rig, filter_cutoff_hz=CUTOFF_HZ)
    assert err.value.column == "q" and "--unwrap" in str(err.value)
    unwrapped = check_log(wrapped, rig, unwrap=True, filter_cutoff_hz=CUTOFF_HZ)
    offset = unwrapped["q"][0] - q[0]
    np.testing.assert_allclose(unwrapped["q"] - offset, q, atol=1e-9)


def test_a_time_column_in_milliseconds_is_named(hinge):
    log, rig = hinge
    with pytest.raises(InputError, match="milliseconds"):
        check_log(_with(log, time=1000.0 * log["time"]), rig, filter_cutoff_hz=CUTOFF_HZ)


def test_positions_in_degrees_are_refused_as_an_implausible_effort_balance(hinge):
    """Angles in degrees need ~57 x the logged effort: refused after the baseline fit, naming q's unit."""
    log, rig = hinge
    with pytest.raises(InputError, match="degrees"):
        analyse(_with(log, q=np.degrees(log["q"])), rig)


def test_an_effort_logged_with_the_opposite_sign_is_refused_naming_the_sign(hinge):
    """The command logged with its sign reversed matches -1 x the rig's inertial terms: refused, saying how to
    reverse it, rather than analysed into an unexplained remainder."""
    log, rig = hinge
    with pytest.raises(InputError,
                       match=r"matches -1(\.\d+)? x the rig's inertial terms: the effort's sign is reversed"):
        analyse(_with(log, tau_cmd=-np.asarray(log["tau_cmd"])), rig)


def test_a_locked_rig_refuses_a_log_whose_lever_turns():
    log, _, _ = hidden_effect_log("free", [], 1, 2.0)
    locked = rig_from_dict({"model": "testbed", "fixture": "locked"})
    columns = {k: v for k, v in log.columns.items()}
    with pytest.raises(InputError, match="fixture = 'locked'"):
        check_log(type(log)(columns, dict(log.units), {}), locked, filter_cutoff_hz=CUTOFF_HZ)


def test_a_rig_stating_the_lever_length_twice_differently_is_refused():
    with pytest.raises(RigError, match="lever_length_m = 0.2 and \\[lever\\] length_m = 0.1"):
        rig_from_dict({"model": "testbed", "fixture": "locked", "lever_length_m": 0.2, "lever": {"length_m": 0.1}})
    rig_from_dict({"model": "testbed", "fixture": "locked", "lever_length_m": 0.1, "lever": {"length_m": 0.1}})


def test_a_rig_and_a_log_stating_different_time_conventions_are_refused(hinge):
    log, rig = hinge
    with pytest.raises(InputError, match="time_convention"):
        analyse(log, dataclasses.replace(rig, time_convention=COMMAND))


def _slide_log(n: int, seed: int, convention: str):
    """An independent simulator's slide (2 kg, Coulomb 3 N, viscous 8 N·s/m) under a PID multisine, 1 kHz."""
    plant = rigsim.Plant("slide", mass=2.0, coulomb=3.0, viscous=8.0, peak_effort=100.0, stick_velocity=2e-5)
    reference = rigsim.multisine(n, 0.1, seed)
    controller = rigsim.PID.tuned(reference, 2.0, 5.0, 100.0)
    return rigsim.simulate(plant, controller, n, seed=seed, time_convention=convention).to_log()


def test_the_command_convention_is_the_same_physics_one_row_apart():
    """A log stamped when each command was computed, brought to the hold-end convention, is the hold-end log of
    the same run without its first row (the independent simulator logs both)."""
    end, command = (_slide_log(2000, 1, convention) for convention in (HOLD_END, COMMAND))
    converted = to_hold_end(command, COMMAND)
    np.testing.assert_array_equal(converted["tau_cmd"], end["tau_cmd"][:-1])
    np.testing.assert_allclose(converted["q"], end["q"][:-1])


def test_a_command_convention_log_gives_no_dead_time_when_stated():
    """Stated, the command convention gives no finding; stated as hold-end, the same log shows a dead time of one
    sample; stated nowhere, that one-sample dead time is reported as a wrong time convention, not as a finding."""
    log = _slide_log(12000, 2, COMMAND)
    rig = rig_from_dict({"model": "rigid-joint", "joint": "slide", "mass_kg": 2.0, "effort_gain": 1.0,
                         "peak_effort": 100.0, "friction": {"coulomb": 3.0, "viscous": 8.0}})
    assert analyse(log, rig).found == []
    hold_end = analyse(type(log)(log.columns, log.units, {"time_convention": HOLD_END}), rig)
    assert hold_end.found[:1] == ["transport_delay"]
    assert hold_end.findings[0].parameters["delay"]["value"] == pytest.approx(1e-3, abs=2e-4)
    assert hold_end.baseline["time_convention_mismatch"] is None
    unstated = analyse(type(log)(log.columns, log.units, {}), rig)
    assert "assumed" in unstated.baseline["time_convention"][0]["from"]
    assert unstated.found == [] and unstated.verdict == "time convention"
    assert "time_convention = 'command'" in unstated.baseline["time_convention_mismatch"]
    assert unstated.extended_rig.rigid["delay"] == rig.rigid["delay"]


def test_a_validation_log_holds_the_candidates_out_and_reports_both_errors():
    """Fitted on the swing, scored on point-to-point moves of the same rig: the hidden viscous coefficient is
    found, and each log reports the relative effort error of the rig and of the final model, smaller after."""
    estimation, rig, truth = hidden_effect_log("slide", ["viscous_friction"], 5, DURATION_S)
    validation = synth_log("slide_moves", truth.rig, DURATION_S, 5)
    result = analyse(estimation, rig, validation=(validation,), names=("run1", "run2"))
    assert result.found[:1] == ["viscous_friction"]
    logs = {entry["log"]: entry for entry in result.logs}
    assert logs["run1"]["role"] == "estimation" and logs["run1"]["scored"] == "whole"
    assert logs["run2"]["role"] == "validation"
    for entry in logs.values():
        assert entry["relative_effort_error"]["final"] < entry["relative_effort_error"]["baseline"]
    true = truth.effects["viscous_friction"]["viscous"]
    assert result.findings[0].parameters["viscous"]["value"] == pytest.approx(true, rel=0.05)


def test_several_logs_are_fitted_together(tmp_path, capsys):
    """Two logs of one rig on the command line: one analysis with both logs' fit parts, each log's error listed."""
    first, rig, truth = hidden_effect_log("slide", ["coulomb_friction"], 7, DURATION_S)
    paths = []
    for i, seed in enumerate((7, 8)):
        log = first if i == 0 else hidden_effect_log("slide", [], seed, DURATION_S)[0]
        paths.append(tmp_path / f"run{i}.parquet")
        write_log(log, paths[-1])
    rig_path = tmp_path / "rig.toml"
    from sim.discrepancy.rig import rig_to_toml

    rig_path.write_text(rig_to_toml(rig), encoding="utf-8")
    out = tmp_path / "out.json"
    cli.main([*map(str, paths), "--rig", str(rig_path), "--workers", "1", "--no-replay", "--no-plot",
              "--json", str(out)])
    import json

    data = json.loads(out.read_text())
    assert [entry["log"] for entry in data["logs"]] == ["run0.parquet", "run1.parquet"]
    assert [entry["role"] for entry in data["baseline"]["split"]["logs"]] == ["estimation", "estimation"]


def test_a_long_rigid_log_is_decimated_but_a_testbed_log_is_not():
    rigid = rig_from_dict({"model": "rigid-joint", "joint": "slide", "mass_kg": 2.0, "effort_gain": 1.0})
    testbed = rig_from_dict({"model": "testbed", "fixture": "locked"})
    config = AnalysisConfig()
    assert decimation_factor(MAX_ANALYSIS_SAMPLES, 1e-3, config, rigid) == 1
    assert decimation_factor(10 * MAX_ANALYSIS_SAMPLES, 1e-3, config, rigid) == 4  # 250 Hz: 10 x the 25 Hz band
    assert decimation_factor(10 * MAX_ANALYSIS_SAMPLES, 1e-3, config, testbed) == 1


def test_joined_logs_are_filtered_and_differentiated_each_on_its_own():
    """Two runs joined, the second the first with its angles 0.5 rad further on: every filtered and differentiated
    signal of the second is the first's (the angles shifted), up to rounding. Filtered across the joint, the
    0.5 rad step would leak into both runs' velocities and accelerations."""
    log, rig, _ = hidden_effect_log("free", [], 4, 1.8)
    n = len(log)
    shifted = {name: (values + 0.5 if name in ("q", "q_motor") else values) for name, values in log.columns.items()}
    second = type(log)(shifted, dict(log.units), dict(log.meta))
    joined, segments = join([Source("first", "estimation", log), Source("second", "estimation", second)])
    config = AnalysisConfig()
    data = prepare(joined, rig, config, segments=segments)
    alone = prepare(log, rig, config)
    # rounding: the 0.5 rad offset's last bit (1e-16 rad) through two differences at 1 ms, ~1e-8 rad/s²
    for name, atol in (("velocity_full", 1e-9), ("acceleration_full", 1e-6)):
        np.testing.assert_allclose(getattr(data, name)[n:], getattr(alone, name), rtol=0, atol=atol, err_msg=name)
        np.testing.assert_allclose(getattr(data, name)[:n], getattr(alone, name), rtol=0, atol=atol, err_msg=name)
    np.testing.assert_allclose(data.filt_full(joined["q"])[n:] - 0.5, alone.filt_full(log["q"]), rtol=0, atol=1e-9)
    assert data.grid_step == alone.grid_step and n % data.grid_step == 0
    lever = data.lever_acceleration.reshape(2, -1)
    np.testing.assert_allclose(lever, np.broadcast_to(alone.lever_acceleration, lever.shape), rtol=0, atol=1e-6)
