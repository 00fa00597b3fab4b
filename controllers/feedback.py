"""Where a torque loop gets its measured torque, and what each closed loop of the testbed observes.

* ``current``: the driver's N·K_t·i, what a GIM8108 reports (:class:`sim.measurements.CurrentEstimate`,
  observation key ``tau_current_estimate``; the driver assumes the nominal K_t). It is blind to the gear's
  friction, backlash, load-dependent losses and the current-to-torque nonlinearity.
* ``sensor``: :class:`sensor.readout.TorqueSensorReadout` (key ``tau_sensor``), the photo-reflector array read
  once per tick from the flexure's twist and the TMP117 temperature through the factory calibration (QP), with
  its channel noise, ADC quantisation, hysteresis and thermal drift, tared at the start of each run.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

from sensor.readout import TorqueSensorReadout
from sim.measurements import CurrentEstimate, LoadCell, MotorEncoder, MotorVelocity
from sim.params import TestbedParams
from sim.run import Controller, Measurement
from sim.runlog import RunLog

FEEDBACK_KINDS = ("current", "sensor")

# A user's controller for the experiments: built per run from the parameters and the feedback kind.
ControllerFactory = Callable[[TestbedParams, str], Controller]


def check_feedback(kind: str) -> str:
    """``kind`` if it is a feedback kind, else ValueError naming the valid ones."""
    if kind not in FEEDBACK_KINDS:
        raise ValueError(f"feedback = {kind!r}: valid values are {', '.join(FEEDBACK_KINDS)}")
    return kind


def make_feedback(kind: str, params: TestbedParams | None = None, seed: int = 0,
                  calibration=None) -> Measurement:
    """The torque measurement named ``kind`` ('current' or 'sensor'); ``seed`` drives the sensor's noise;
    ``calibration`` (a :class:`sensor.calibration.Calibration`) replaces the sensor's factory calibration of
    ``params`` (e.g. the nominal unit's calibration read by a unit whose parameters drifted)."""
    if check_feedback(kind) == "current":
        return CurrentEstimate()
    return TorqueSensorReadout(params, calibration, seed=seed)


def loop_measurements(kind: str, params: TestbedParams, seed: int = 0, calibration=None) -> list[Measurement]:
    """What a closed loop of the experiments observes: the ``kind`` torque measurement (noise of ``seed``) and
    the motor's encoder and velocity."""
    return [make_feedback(kind, params, seed, calibration), MotorEncoder(), MotorVelocity()]


def with_readout_meta(log: RunLog, measurements: Sequence[Measurement]) -> RunLog:
    """``log`` with the tare [N·m] of the sensor readout among ``measurements`` in its meta (``sensor_tare_nm``:
    the log's ``tau_sensor`` is the calibration's torque of ``v1`` ... ``v8`` minus it); as it is without one."""
    tares = [m.tare_nm for m in measurements if isinstance(m, TorqueSensorReadout)]
    return dataclasses.replace(log, meta={**log.meta, "sensor_tare_nm": tares[0]}) if tares else log


def grading_loadcell(params: TestbedParams, seed: int = 0) -> LoadCell:
    """The load cell the paper's figures are measured on, with the noise stream of ``seed``: recorded by a run,
    not observed by its controller."""
    return LoadCell(params, seed)


def build_controller(controller: Controller | ControllerFactory | None, default: ControllerFactory,
                     params: TestbedParams, kind: str) -> Controller:
    """The controller of one run: ``default(params, kind)`` if ``controller`` is None, a factory's
    ``controller(params, kind)``, or the given controller, reset."""
    if controller is None:
        return default(params, kind)
    if callable(controller) and not hasattr(controller, "step"):
        built = controller(params, kind)
    else:
        built = controller
        built.reset()
    if not (callable(getattr(built, "step", None)) and callable(getattr(built, "reset", None))):
        raise TypeError(f"controller {built!r}: expected an object with reset() and step(observation) -> float "
                        f"(sim.run.Controller), or a factory (params, feedback) -> such an object")
    return built
