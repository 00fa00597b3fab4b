"""The control-loop runtime (sim.run): one tick loop, measurement objects, and user-defined controllers through
the paper's experiments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.admittance import AdmittanceController
from controllers.pi import FEEDBACK_KEYS, PITorqueController, paper_pi
from experiments.admittance import run_admittance
from experiments.sinusoid import run_sinusoid
from experiments.step import run_step
from sim.measurements import LOADCELL_NOISE_STREAM, LoadCell, MotorEncoder, MotorVelocity
from sim.params import TestbedParams
from sim.plant import Plant
from sim.run import Controller, Measurement, run_loop, run_open_loop

PARAMS = TestbedParams()
SHORT_S = 0.3  # [s] per case: the runtime, not the paper's figures, is under test


class Recorder:
    """A controller that replays a command profile and keeps every observation it was given."""

    log_units: dict = {}

    def __init__(self, commands):
        self.commands = list(commands)
        self.seen: list[dict] = []

    def reset(self) -> None:
        self.seen = []

    def step(self, observation) -> float:
        self.seen.append(dict(observation))
        return self.commands[len(self.seen) - 1]

    def log_values(self):
        return ()


def test_the_builtin_controllers_and_measurements_satisfy_the_protocols():
    assert isinstance(paper_pi(PARAMS, "sensor"), Controller)
    assert isinstance(AdmittanceController(), Controller)
    for m in (MotorEncoder(), MotorVelocity(), LoadCell(PARAMS, 0)):
        assert isinstance(m, Measurement)


def test_a_controller_observes_the_state_at_the_end_of_the_previous_tick():
    """Order within tick k: observe (end of tick k-1), command, advance, record (end of tick k)."""
    n = 50
    commands = np.linspace(0.0, 0.4, n)
    controller = Recorder(commands)
    plant = Plant(PARAMS, "locked")
    plant.reset(backlash_side=1)
    at_rest = plant.motor_angle_rad
    log = run_loop(plant, controller, n, measurements=[MotorEncoder(), MotorVelocity()], tau_ref_nm=commands)
    seen_q = np.array([o["q_motor"] for o in controller.seen])
    assert seen_q[0] == at_rest
    np.testing.assert_array_equal(seen_q[1:], log["q_motor"][:-1])
    np.testing.assert_array_equal([o["tau_ref"] for o in controller.seen], commands)
    np.testing.assert_array_equal([o["time_s"] for o in controller.seen][1:], log["time"][:-1])
    np.testing.assert_array_equal(log["tau_cmd"], commands)


def test_the_open_loop_is_the_same_tick_loop_as_a_closed_one():
    n = 200
    commands = 0.3 * np.sin(np.arange(n) * 0.05)
    a, b = Plant(PARAMS, "locked"), Plant(PARAMS, "locked")
    opened = run_open_loop(a, commands, progress=False)
    closed = run_loop(b, Recorder(commands), n, tau_ext_nm=np.zeros(n))
    for name in ("tau_cmd", "q_motor", "force_loadcell", "tau_flexure"):
        np.testing.assert_array_equal(opened[name], closed[name])


def test_the_load_cell_noise_has_its_stated_deviation_and_its_own_seeded_stream():
    """σ = reading_noise_n x lever length; seed s draws from the stream (s, LOADCELL_NOISE_STREAM); reset
    restarts it; a Generator goes on; None is noiseless; the free fixture reads the flexure without noise."""
    plant = Plant(PARAMS, "locked")
    plant.step(0.2)
    true = plant.loadcell_torque_nm
    cell = LoadCell(PARAMS, 7)
    first = np.array([cell.read(plant) for _ in range(4000)]) - true
    sigma = PARAMS.loadcell.reading_noise_n * PARAMS.lever.length_m
    np.testing.assert_allclose(first, np.random.default_rng([7, LOADCELL_NOISE_STREAM]).normal(0.0, sigma, 4000),
                               rtol=0, atol=1e-15)
    assert np.std(first) == pytest.approx(sigma, rel=0.05)
    cell.reset()
    assert cell.read(plant) - true == pytest.approx(first[0], abs=1e-15)
    assert LoadCell(PARAMS, None).read(plant) == true
    free = Plant(PARAMS, "free")
    free.step(0.2)
    assert LoadCell(PARAMS, 7).read(free) == free.flexure_torque_nm



def test_the_load_cell_lags_through_its_amplifier_from_its_first_reading_and_adds_noise_after_it():
    """Reading k is y_k = y_{k-1} + (1 − exp(−2π f_c T))·(x_k − y_{k-1}) of the true lever-tip torque x_k,
    y_0 = x_0 (no start-up transient, again after reset); the noise stream is added to y_k unfiltered."""
    params = PARAMS.replace(loadcell={"amplifier_bandwidth_hz": 20.0})
    gain = 1.0 - math.exp(-2.0 * math.pi * 20.0 * params.simulation.control_period_s)
    plant = Plant(params, "locked")
    quiet, noisy = LoadCell(params, None), LoadCell(params, 7)
    true, read, read_noisy = [], [], []
    for command in np.r_[np.full(5, 0.3), np.full(60, 1.0)]:
        plant.step(command)
        true.append(plant.loadcell_torque_nm)
        read.append(quiet.read(plant))
        read_noisy.append(noisy.read(plant))
    expected = [true[0]]
    for x in true[1:]:
        expected.append(expected[-1] + gain * (x - expected[-1]))
    np.testing.assert_allclose(read, expected, rtol=1e-12, atol=1e-15)
    assert max(read) - true[-1] < 0.5 * (max(true) - true[-1])  # 20 Hz smooths the step's overshoot
    sigma = params.loadcell.reading_noise_n * params.lever.length_m
    draws = np.random.default_rng([7, LOADCELL_NOISE_STREAM]).normal(0.0, sigma, len(read))
    np.testing.assert_allclose(np.array(read_noisy) - read, draws, rtol=0, atol=1e-14)
    quiet.reset()
    assert quiet.read(plant) == true[-1]

class BangBang:
    """A user's controller, unknown to the project: relay on the sensor's torque error, with a reference
    feed-forward. It also counts its resets."""

    log_units = {"error": "N·m"}

    def __init__(self, amplitude_nm: float = 0.05, measured: str = "tau_sensor"):
        self.amplitude_nm, self.measured, self.resets, self._error = amplitude_nm, measured, 0, 0.0

    def reset(self) -> None:
        self.resets += 1

    def step(self, observation) -> float:
        self._error = observation["tau_ref"] - observation[self.measured]
        return observation["tau_ref"] + self.amplitude_nm * np.sign(self._error)

    def log_values(self):
        return (self._error,)


def test_a_users_controller_runs_through_the_step_and_sine_experiments_unchanged():
    """A controller object is reset before each case and its logged signal is in every case's log; the
    results differ from the paper's PI's."""
    controller = BangBang()
    step = run_step(PARAMS, ("sensor",), duration_s=SHORT_S, controller=controller)
    assert controller.resets == len(step.cases) == 4
    for case in step.cases:
        np.testing.assert_allclose(case.log["error"][1:], case.log["tau_ref"][1:] - case.log["tau_sensor"][1:])
    paper = run_step(PARAMS, ("sensor",), duration_s=SHORT_S)
    assert [c.error.rms_nm for c in step.cases] != [c.error.rms_nm for c in paper.cases]
    sine = run_sinusoid(PARAMS, ("sensor",), duration_s=SHORT_S, controller=lambda p, feedback: BangBang(0.01))
    assert all("error" in c.log.columns for c in sine.cases)


def test_the_default_controller_is_the_paper_pi_given_explicitly():
    """run_step with the paper's PI as a factory gives the default run's figures exactly."""
    default = run_step(PARAMS, ("current",), duration_s=SHORT_S)
    explicit = run_step(PARAMS, ("current",), duration_s=SHORT_S, controller=paper_pi)
    assert [c.error for c in default.cases] == [c.error for c in explicit.cases]


def test_admittance_accepts_a_controller_and_rejects_a_non_controller():
    stiff = AdmittanceController(desired_damping_nms_per_rad=6.0)
    soft = run_admittance(PARAMS, duration_s=SHORT_S)
    result = run_admittance(PARAMS, duration_s=SHORT_S, controller=stiff)
    assert result.pushes[0].peak_velocity_rad_s < soft.pushes[0].peak_velocity_rad_s  # ten times the damping
    with pytest.raises(TypeError, match="reset.*step"):
        run_admittance(PARAMS, duration_s=SHORT_S, controller=lambda p, kind: 42)


def test_the_pi_closes_on_the_measurement_it_names():
    pi = PITorqueController(output_limit_nm=10.0, measured="tau_current_estimate", velocity_damping_nms_per_rad=0.5)
    u = pi.step({"tau_ref": 1.0, "tau_current_estimate": 0.5, "tau_sensor": 99.0, "qd_motor": 2.0})
    expected = PITorqueController(output_limit_nm=10.0).update(1.0, 0.5) - 0.5 * 2.0
    assert u == pytest.approx(expected)
    assert pi.log_values() == (0.5,)
    with pytest.raises(ValueError, match="velocity_damping_nms_per_rad"):
        PITorqueController(output_limit_nm=1.0, velocity_damping_nms_per_rad=-1.0)


@pytest.mark.parametrize("name", ["step", "sinusoid", "admittance"])
def test_every_controlled_paper_experiment_runs_through_the_registry_with_a_users_controller(name, tmp_path):
    """The one interface: run(params, seed, duration_s, controller) -> rows(), to_dict(), plot(directory)."""
    from experiments.registry import EXPERIMENTS

    experiment = EXPERIMENTS[name]
    if name == "admittance":
        controller = AdmittanceController(desired_damping_nms_per_rad=6.0)
    else:  # a factory: under each feedback the relay closes on that feedback's torque
        controller = lambda params, feedback: BangBang(measured=FEEDBACK_KEYS[feedback])  # noqa: E731
    result = experiment.run(PARAMS, seed=1, duration_s=SHORT_S, controller=controller)
    assert isinstance(result.rows(), list) and result.to_dict()["rows"] == result.rows()
    figures = result.plot(tmp_path)
    assert figures and all(path.stat().st_size > 10_000 for path in figures)


def test_the_sensor_experiments_refuse_a_controller_and_a_shortened_run():
    from experiments.registry import EXPERIMENTS

    with pytest.raises(ValueError, match="runs no controller"):
        EXPERIMENTS["calibration"].run(PARAMS, controller=BangBang())
    with pytest.raises(ValueError, match="no shortened mode"):
        EXPERIMENTS["thermal"].run(PARAMS, duration_s=1.0)


def test_a_controller_reading_what_the_run_does_not_observe_is_told_what_it_does():
    with pytest.raises(KeyError, match="tau_sensor.*does not observe; it observes .*tau_current_estimate"):
        run_step(PARAMS, ("current",), duration_s=SHORT_S, controller=BangBang())
