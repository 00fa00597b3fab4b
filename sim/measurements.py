"""What the testbed's own instruments read, as :class:`sim.run.Measurement` objects.

Each reads the plant at the end of a tick. The optical joint torque sensor is
:class:`sensor.readout.OpticalTorqueSensor`; the rest is here:

* :class:`CurrentEstimate` ``tau_current_estimate`` [N·m]: the driver's N·K_t·i (it assumes the nominal K_t),
  blind to the gear's friction, backlash, load-dependent losses and the current-to-torque nonlinearity.
* :class:`MotorEncoder` ``q_motor`` [rad] and :class:`MotorVelocity` ``qd_motor`` [rad/s], output side.
* :class:`LeverAngle` ``q`` [rad] and :class:`LeverVelocity` ``qd`` [rad/s].
* :class:`BoardThermometer` ``temperature`` [°C]: the TMP117 reading.
* :class:`LoadCell` ``tau_loadcell`` [N·m]: force x lever length through the amplifier's first-order low-pass,
  plus the load cell's white reading noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from sim.lowpass import lowpass_gain, lowpass_step
from sim.params import TestbedParams
from sim.plant import Plant

LOADCELL_NOISE_STREAM = 0x10AD  # spawn key separating the load cell's noise from the sensor's for one seed


class _PlantSignal:
    """A noiseless reading of one plant accessor."""

    name = ""
    unit = ""
    extra_units: Mapping[str, str] = {}

    def reset(self) -> None:
        """Stateless."""

    def extra_values(self) -> Sequence[float]:
        return ()


class CurrentEstimate(_PlantSignal):
    """The driver's current-based torque estimate N·K_t·i [N·m, output side]."""

    name, unit = "tau_current_estimate", "N·m"

    def read(self, plant: Plant) -> float:
        return plant.current_torque_estimate_nm


class MotorEncoder(_PlantSignal):
    """The motor angle, output side [rad]."""

    name, unit = "q_motor", "rad"

    def read(self, plant: Plant) -> float:
        return plant.motor_angle_rad


class MotorVelocity(_PlantSignal):
    """The motor velocity the driver reports, output side [rad/s]."""

    name, unit = "qd_motor", "rad/s"

    def read(self, plant: Plant) -> float:
        return plant.motor_velocity_rad_s


class LeverAngle(_PlantSignal):
    """The lever's absolute angle [rad]."""

    name, unit = "q", "rad"

    def read(self, plant: Plant) -> float:
        return plant.output_angle_rad


class LeverVelocity(_PlantSignal):
    """The lever's angular velocity [rad/s]."""

    name, unit = "qd", "rad/s"

    def read(self, plant: Plant) -> float:
        return plant.output_velocity_rad_s


class BoardThermometer(_PlantSignal):
    """The TMP117's reading of the sensor board's temperature [°C]."""

    name, unit = "temperature", "°C"

    def read(self, plant: Plant) -> float:
        return plant.tmp117_temperature_c


class LoadCell:
    """The load cell's torque reading [N·m]: force x lever length through the amplifier, a first-order low-pass
    of ``loadcell.amplifier_bandwidth_hz`` sampled every control period (:mod:`sim.lowpass`), plus white noise
    of standard deviation ``loadcell.reading_noise_n`` x ``lever.length_m`` added after the filter.

    The filter starts at the first reading after :meth:`reset` (no start-up transient); reading a batched plant
    (N testbeds), it keeps N states and :meth:`restart` starts chosen ones again. ``noise``: an int seeds the
    load cell's own stream of that seed (:func:`noise_rng`, apart from the sensor's), restarted by :meth:`reset`;
    a Generator (or anything with its ``normal``) is drawn from as it goes; None reads without noise. The free
    fixture has no load cell: there the reading is the flexure's true torque, unfiltered and without noise.
    """

    name, unit = "tau_loadcell", "N·m"
    extra_units: Mapping[str, str] = {}

    def __init__(self, params: TestbedParams, noise: int | np.random.Generator | None = None) -> None:
        self.lever_m = params.lever.length_m
        self.sigma_nm = params.loadcell.reading_noise_n * self.lever_m
        self.gain = lowpass_gain(params.loadcell.amplifier_bandwidth_hz, params.simulation.control_period_s)
        self._noise = noise
        self.reset()

    def reset(self) -> None:
        """Restart the filter and a seeded noise stream (a Generator goes on where it is)."""
        rng = noise_rng(self._noise) if isinstance(self._noise, (int, np.integer)) else self._noise
        self._rng = rng
        self._normal = rng.normal if rng is not None and self.sigma_nm > 0.0 else None
        self._filtered: float | np.ndarray = math.nan  # NaN: the next reading starts the filter

    def restart(self, ids) -> None:
        """Start the filter of testbeds ``ids`` of a batched plant again at their next reading."""
        if isinstance(self._filtered, np.ndarray):
            self._filtered = self._filtered.copy()  # the last reading may be the caller's: leave it alone
            self._filtered[ids] = math.nan

    def read(self, plant: Plant) -> float:
        if plant.fixture != "locked":
            return plant.flexure_torque_nm
        value = plant.loadcell_force_n * self.lever_m  # what it measures is the force at the lever tip
        state = self._filtered
        if isinstance(value, np.ndarray):  # N testbeds
            filtered = np.where(np.isnan(state), value, lowpass_step(state, value, self.gain))
        else:
            filtered = value if math.isnan(state) else lowpass_step(state, value, self.gain)
        self._filtered = filtered
        return filtered + self._normal(0.0, self.sigma_nm) if self._normal is not None else filtered

    def extra_values(self) -> Sequence[float]:
        return ()


def noise_rng(seed: int) -> np.random.Generator:
    """The load cell's noise stream of a run of ``seed``."""
    return np.random.default_rng([seed, LOADCELL_NOISE_STREAM])
