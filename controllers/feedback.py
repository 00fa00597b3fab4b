"""Where a torque loop gets its measured torque: the motor driver's current-based estimate or the calibrated
optical joint torque sensor.

* ``current``: the driver's N·K_t·i, what a GIM8108 reports: :attr:`sim.plant.Plant.current_torque_estimate_nm`
  (the driver assumes the nominal K_t). It is blind to the gear's friction, backlash, load-dependent losses and
  the current-to-torque nonlinearity.
* ``sensor``: :class:`sensor.readout.TorqueSensorReadout`, the photo-reflector array read once per tick from
  the flexure's twist and the TMP117 temperature through the factory calibration (QP), with its channel
  noise, ADC quantisation, hysteresis and thermal drift.
"""

from __future__ import annotations

from typing import Protocol

from sim.params import TestbedParams

FEEDBACK_KINDS = ("current", "sensor")


class TorqueFeedback(Protocol):
    """A measured torque [N·m], read from the plant once per control tick."""

    kind: str

    def read(self, plant) -> float: ...

    def reset(self) -> None: ...


class CurrentFeedback:
    """The driver's current-based torque estimate N·K_t·i [N·m, output side]."""

    kind = "current"

    def read(self, plant) -> float:
        return plant.current_torque_estimate_nm

    def reset(self) -> None:
        """Stateless."""


class SensorFeedback:
    """The calibrated optical torque sensor [N·m] (noise drawn from ``seed``)."""

    kind = "sensor"

    def __init__(self, params: TestbedParams | None = None, seed: int = 0, calibration=None) -> None:
        from sensor.readout import TorqueSensorReadout

        self.readout = TorqueSensorReadout(params, calibration, seed=seed)

    def read(self, plant) -> float:
        return self.readout.read_plant(plant)

    def reset(self) -> None:
        self.readout.reset()

    @property
    def voltages_v(self):
        """The eight channel voltages [V] of the last read (NaN before the first)."""
        return self.readout.voltages_v


def make_feedback(kind: str, params: TestbedParams | None = None, seed: int = 0,
                  calibration=None) -> TorqueFeedback:
    """The feedback source named ``kind`` ('current' or 'sensor'); ``seed`` drives the sensor's noise;
    ``calibration`` (a :class:`sensor.calibration.Calibration`) replaces the sensor's factory calibration of
    ``params`` (e.g. the nominal unit's calibration read by a unit whose parameters drifted)."""
    if kind == "current":
        return CurrentFeedback()
    if kind == "sensor":
        return SensorFeedback(params, seed, calibration)
    raise ValueError(f"feedback = {kind!r}: valid values are {', '.join(FEEDBACK_KINDS)}")
