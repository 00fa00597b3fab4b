"""The stand-ins for real drive records (tests/independent/realistic.py) against hand-computed values, and every
case's files read back by the project's readers."""

import json
import math

import numpy as np
import pytest

from sim.discrepancy.rig import load_rig
from sim.logio import LogError, read_log
from tests.independent import realistic as rs
from tests.independent.rigsim import (
    EnergyPump,
    Impedance,
    OpenLoop,
    Plant,
    QuantisedCommand,
    Reference,
    Run,
    back_and_forth,
    delivered_effort,
)

SHORT_S = 4.0  # records of the read-back tests [s]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Every case written with SHORT_S records: {case name: (folder, truth)}."""
    out = tmp_path_factory.mktemp("realistic")
    return {c.name: (out / c.name, rs.write_case(c, out, SHORT_S)) for c in rs.cases()}


# ------------------------------------------------------------------------------------------------ PWM register


@pytest.mark.parametrize(("duty", "register"), [
    (0.0, 0x0000), (1.0, 0x0375), (-1.0, 0xFC8B), (1 / 885, 0x0001), (-1 / 885, 0xFFFF), (0.25, 221),
    (-0.25, 65536 - 221), (1.2, 885), (-3.0, 65536 - 885)])
def test_a_duty_is_stored_as_885_counts_per_full_scale_in_twos_complement(duty, register):
    """885 counts = 100 % duty (0x0375), clipped there; −1 count is 0xFFFF, −885 is 0xFC8B; 0.25 → 221.25 → 221."""
    assert rs.duty_to_register(duty) == register


@pytest.mark.parametrize(("register", "duty"), [(0x0375, 1.0), (0xFC8B, -1.0), (0xFFFF, -1 / 885),
                                                (0x7FFF, 32767 / 885), (0x8000, -32768 / 885)])
def test_a_register_decodes_as_a_signed_16_bit_count_over_885(register, duty):
    """0x8000 is the most negative count, −32768; 0x7FFF the most positive, 32767."""
    assert rs.register_to_duty(register) == duty


def test_every_count_round_trips_through_the_register_exactly():
    """count/885 → register → count/885 is the same double for every count in ±885."""
    counts = np.arange(-885, 886)
    registers = np.array([rs.duty_to_register(c / 885) for c in counts])
    assert np.all((registers >= 0) & (registers < 2**16))
    assert np.array_equal(rs.register_to_duty(registers), counts / 885)


def test_the_quantised_command_holds_whole_counts_of_the_wrapped_controller():
    """0.1234 of full scale is 109.2 counts: the drive applies 109/885; beyond ±1 it holds ±885 counts."""
    q = QuantisedCommand(OpenLoop(np.array([0.1234, -0.1234, 1.7])), 1 / 885, 1.0)
    assert [q(k, 0.0) for k in range(3)] == [109 / 885, -109 / 885, 885 / 885]
    assert q.counts(0.1234) == 109


# --------------------------------------------------------------------------------------- logger and converter


def test_the_logger_steps_jitter_35_percent_about_5_3_ms():
    """Steps lie in [0.65, 1.35] × 5.3 ms with a mean near 5.3 ms; the first read is 2-6 ms in."""
    stamps = rs.logger_stamps(30.0, np.random.default_rng(3))
    steps = np.diff(stamps)
    assert 2e-3 <= stamps[0] <= 6e-3 and stamps[-1] < 30.0
    assert steps.min() >= 0.65 * 5.3e-3 and steps.max() <= 1.35 * 5.3e-3
    assert np.mean(steps) == pytest.approx(5.3e-3, rel=0.02)
    assert np.std(steps) / np.mean(steps) == pytest.approx(0.35 / math.sqrt(3), rel=0.1)


def test_resampling_interpolates_positions_linearly_and_holds_the_command():
    """On t = 0, 3, 7 ms: x = 2t is exact under linear interpolation; the hold repeats the last sample."""
    t = np.array([0.0, 3e-3, 7e-3])
    grid = rs.uniform_grid(t, 1e-3)
    assert np.allclose(grid, np.arange(8) * 1e-3, atol=1e-15)
    assert np.allclose(rs.resample(t, 2 * t, grid, "linear"), 2 * grid)
    assert np.array_equal(rs.resample(t, np.array([1.0, 2.0, 3.0]), grid, "hold"),
                          [1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="linear"):
        rs.resample(t, t, grid, "cubic")


def test_the_converter_timing_is_half_a_grid_step_more_for_a_linearly_interpolated_command():
    """A smooth command read every 5.3 ms ± 35 % from 1 kHz registers and resampled on 5 ms: held, it reads as a
    hold-end log within 0.3 ms; interpolated linearly, it is late by half the grid step plus the registers'
    staleness, 2.5 + 0.5 = 3.0 ms."""
    n = 20000
    t = np.arange(n) * rs.DT
    u = np.sin(2 * math.pi * t) + 0.5 * np.sin(2 * math.pi * 3.3 * t)
    run = Run(t + rs.DT, u, np.zeros(n), np.zeros(n), np.zeros(n), "hinge", {})
    stamps = rs.logger_stamps(19.9, np.random.default_rng(5))
    ticks = np.floor(stamps / rs.DT + 1e-9).astype(int)
    grid = rs.uniform_grid(stamps, 5e-3)
    held, left_held = rs.apparent_delay(run, stamps, ticks, grid, rs.resample(stamps, u[ticks], grid, "hold"), 1.0)
    linear, left_linear = rs.apparent_delay(run, stamps, ticks, grid, rs.resample(stamps, u[ticks], grid, "linear"),
                                            1.0)
    assert abs(held) <= 0.3e-3 and linear == pytest.approx(3.0e-3, abs=0.2e-3)
    assert left_held < 0.02 and left_linear < 0.01


def test_the_drive_velocity_is_a_first_order_filtered_difference_reported_one_tick_late():
    """On a ramp y_k = c·k·dt the estimate is c·(1 − α^k), α = exp(−2π·40 Hz·dt), shifted by one sample."""
    c, n = 0.7, 200
    y = c * np.arange(n) * rs.DT
    alpha = math.exp(-2 * math.pi * 40.0 * rs.DT)
    expected = np.concatenate([[0.0], c * (1 - alpha ** np.arange(n - 1))])
    assert rs.drive_velocity(y) == pytest.approx(expected, abs=1e-12)


def test_the_torque_sensor_reads_the_torque_plus_its_zero_to_its_resolution():
    """Without noise the reading is the torque + offset rounded to 100/2^15 N·m."""
    torque = np.linspace(-5, 5, 101)
    reading = rs.torque_sensor(torque, 0.2, np.random.default_rng(0), noise_std=0.0)
    step = 100 / 2**15
    assert np.all(np.abs(reading - (torque + 0.2)) <= step / 2 + 1e-12)
    assert np.allclose(reading / step, np.round(reading / step), atol=1e-9)


# ------------------------------------------------------------------------------------------- rigsim additions


def test_back_and_forth_sweeps_the_span_at_the_stated_speed_and_acceleration():
    """Its velocity is the position's derivative, peaks at the speed, and changes at most at the acceleration."""
    ref = back_and_forth(12000, 0.8, 0.6, 4.0, dwell_s=0.5)
    assert ref.position.min() == pytest.approx(-0.8) and ref.position.max() == pytest.approx(0.8)
    assert np.max(np.abs(ref.velocity)) == pytest.approx(0.6)
    assert np.gradient(ref.position, rs.DT) == pytest.approx(ref.velocity, abs=4.0 * rs.DT)
    assert np.max(np.abs(np.diff(ref.velocity))) <= 4.0 * rs.DT + 1e-12


def test_impedance_is_a_spring_damper_to_the_setpoint():
    """First call (v̂ = 0): u = K·(r − y) + D·ṙ; clipped at the limit."""
    ref = Reference(np.array([0.3, 0.3]), np.array([0.1, 0.1]))
    assert Impedance(ref, 40.0, 8.0, 80.0)(0, 0.25) == pytest.approx(40 * 0.05 + 8 * 0.1)
    assert Impedance(ref, 40.0, 8.0, 1.0)(0, 0.25) == 1.0


def test_energy_pumping_kicks_a_resting_pendulum_and_brakes_an_energetic_one():
    """At rest below the target u = +min(k·(E* − E), L); above the target it opposes the motion."""
    pump = EnergyPump(np.full(3, 0.5), 0.012, 0.49, 0.0, gain=2.0, limit=0.25)
    assert pump(0, 0.0) == 0.25
    assert pump.energy(1.0, 2.0) == pytest.approx(0.5 * 0.012 * 4 + 0.49 * (1 - math.cos(1.0)))
    brake = EnergyPump(np.zeros(3), 0.012, 0.49, 0.0, gain=2.0, limit=0.25)
    brake(0, 0.0)
    assert brake(1, 0.01) < 0  # moving up (v̂ > 0) with energy above the target: a torque against the motion


# ---------------------------------------------------------------------------------------------- written cases


def test_every_case_writes_logs_read_back_by_the_format_and_a_rig_the_analysis_loads(written):
    """Each record reads with read_log at the default 5 % jitter (the resampled log is uniform); each rig loads."""
    for folder, truth in written.values():
        rig = load_rig(folder / "rig.toml")
        assert rig.model == "rigid-joint" and rig.joint == "hinge"
        assert rig.rigid["inertia"] == truth["rig"]["mass"]
        for name, file in truth["files"].items():
            if name == "raw_log":
                continue
            log = read_log(folder / file)
            assert {"time", "tau_cmd", "q"} <= set(log.columns)
            assert np.max(np.abs(log["tau_cmd"])) <= rig.rigid["peak_effort"]
        for analysis in truth["analyses"]:
            assert set(analysis["estimation"] + analysis["validation"]) <= set(truth["files"])


def test_the_pwm_log_holds_the_decoded_register_and_the_truth_the_gain_ratio(written):
    """tau_cmd is the register decoded (whole counts / 885); the rig states the nominal torque per unit duty and
    a peak of 1 (100 % duty); the truth's gain is the ratio (in [0.6, 0.75] or [1.3, 1.4]) times it."""
    for name in ("pwm-arm-s11", "pwm-pendulum-s12"):
        folder, truth = written[name]
        log = read_log(folder / "log.csv")
        assert log.units["pwm_register"] == "count"
        assert np.array_equal(log["tau_cmd"], rs.register_to_duty(log["pwm_register"].astype(np.int64)))
        assert np.allclose(log["tau_cmd"] * 885, np.round(log["tau_cmd"] * 885), atol=1e-9)
        rig = load_rig(folder / "rig.toml").rigid
        assert rig["effort_gain"] == rs.SERVO["torque_per_duty"] and rig["peak_effort"] == 1.0
        ratio = truth["pwm"]["ratio"]
        assert 0.6 <= ratio <= 0.75 or 1.3 <= ratio <= 1.4
        assert truth["hidden"][0]["parameters"]["effort_gain"] == pytest.approx(ratio * rig["effort_gain"])
        assert truth["plant"]["effort_gain"] == truth["hidden"][0]["parameters"]["effort_gain"]


def test_the_resampled_log_is_uniform_while_the_raw_record_is_refused_for_its_jitter(written):
    """The logger's own record breaks the 5 % sampling rule; the converter's log is on a 5 ms grid."""
    folder, truth = written["resampled-hold-coulomb-s21"]
    with pytest.raises(LogError, match="max_jitter"):
        read_log(folder / "raw_log.csv")
    raw = read_log(folder / "raw_log.csv", max_jitter=math.inf)
    log = read_log(folder / "log.csv")
    assert np.diff(log["time"]) == pytest.approx(np.full(len(log) - 1, 5e-3), abs=1e-12)
    assert log["time"][0] >= raw["time"][0] and log["time"][-1] <= raw["time"][-1]
    held = rs.resample(raw["time"], raw["tau_cmd"], log["time"], "hold")
    assert np.array_equal(log["tau_cmd"], held)
    assert np.allclose(log["q"], np.interp(log["time"], raw["time"], raw["q"]))
    assert truth["converter"]["command"] == "zero-order hold"


def test_the_drive_velocity_column_is_the_drives_estimate_of_the_logged_positions(written):
    """qd of row k is the filtered difference up to q of row k − 1 (one tick late)."""
    folder, _ = written["velocity-viscous-s31"]
    log = read_log(folder / "log.csv")
    y = np.concatenate([[0.0], log["q"]])  # y(0) = 0: the run starts at rest at 0
    assert log["qd"] == pytest.approx(rs.drive_velocity(y)[1:], abs=1e-9)


def test_the_re_zeroed_records_carry_exactly_the_offsets_the_truth_states(written):
    """Reading − the torque the drive held = the record's offset, to the sensor's noise over the record."""
    folder, truth = written["rezeroed-coulomb-s41"]
    case = next(c for c in rs.cases() if c.name == "rezeroed-coulomb-s41")
    plant, runs, _ = rs.rezeroed_runs(case, SHORT_S)
    zeros = truth["hidden"][1]["zeros"]
    assert len(set(zeros.values())) == 3
    for name, (run, offset) in runs.items():
        assert zeros[name] == offset == truth["records"][name]["offset_nm"]
        assert 0.1 <= abs(offset) <= 0.3
        reading = read_log(folder / f"{name}.csv")["tau_cmd"]
        difference = reading - rs.delivered_torque(plant, run)
        tolerance = 4 * rs.TORQUE_SENSOR["noise_std"] / math.sqrt(len(reading)) + rs.TORQUE_SENSOR["step"] / 2
        assert np.mean(difference) == pytest.approx(offset, abs=tolerance)
        assert np.std(difference) == pytest.approx(rs.TORQUE_SENSOR["noise_std"], rel=0.1)


def test_the_gravity_rigs_state_no_gravity_and_the_truth_states_the_pendulums(written):
    """m·g·r = 0.25 kg × 9.81 m/s² × 0.2 m = 0.4905 N·m in the truth, 0 in the rig; the pendulum starts at its
    rest angle."""
    for name in ("gravity-pump-s61", "gravity-servo-s62"):
        folder, truth = written[name]
        assert load_rig(folder / "rig.toml").rigid["gravity_amplitude"] == 0.0
        params = truth["hidden"][0]["parameters"]
        assert params["gravity_amplitude"] == pytest.approx(0.4905)
        q0 = read_log(folder / "log.csv")["q"][0]
        assert abs(((q0 - params["gravity_angle"]) + math.pi) % (2 * math.pi) - math.pi) < 0.01
        assert truth["motion"]["gravity_over_friction"] >= 4.0


def test_the_truth_files_are_json_with_the_hidden_effects_in_the_librarys_names(written):
    """Every hidden effect is an effect of the analysis library, with its parameters."""
    from sim.discrepancy.effects import EFFECTS

    for folder, _ in written.values():
        truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
        for hidden in truth["hidden"]:
            assert hidden["effect"] in EFFECTS
            assert set(hidden["parameters"]) <= {p.key for p in EFFECTS[hidden["effect"]].params}


def test_the_cases_are_deterministic():
    """The same case twice gives the same records."""
    case = next(c for c in rs.cases() if c.kind == "resampled")
    first, _, truth1 = rs.build(case, 3.0)
    second, _, truth2 = rs.build(case, 3.0)
    for name in first:
        assert all(np.array_equal(first[name][k], second[name][k]) for k in first[name].columns)
    assert truth1["hidden"] == truth2["hidden"]


def test_a_duty_commanded_servo_delivers_its_torque_per_unit_duty_up_to_full_scale():
    """The servo plant's peak is 1 (100 % duty) and its gain the torque per unit duty."""
    plant = Plant("hinge", 0.01, effort_gain=3.0, peak_effort=1.0)
    assert delivered_effort(plant, 1.5) == 3.0 and delivered_effort(plant, -0.5) == -1.5


def test_the_clean_servo_rig_states_its_true_torque_per_unit_duty(written):
    """pwm-clean: nothing hidden, the plant's gain is the rig's."""
    folder, truth = written["pwm-clean-s13"]
    assert truth["hidden"] == [] and truth["pwm"]["ratio"] == 1.0
    assert truth["plant"]["effort_gain"] == load_rig(folder / "rig.toml").rigid["effort_gain"]
