"""Sensor thermal drift: the torque sensor's zero drifts with the board temperature, ``c_T·(T - T_cal)``."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import TESTBED, Effect, Param, Realisation, signed
from sim.discrepancy.effects.sensor_offset import needs_reference

MIN_TEMPERATURE_RANGE_K = 1.0
SYNTHETIC_RANGE = (3e-3, 1e-2)  # [N·m/K]


class SensorThermalDrift(Effect):
    name = "sensor_thermal_drift"
    revealing_experiment = "locked"
    description = "torque sensor zero drifting with board temperature"
    params = (Param("sensor_tempco", "N·m/K", "N·m/K", "zero drift per kelvin from the calibration temperature"),)
    rigs = frozenset({TESTBED})
    channel = "sensor"
    signature = "temperature (sensor)"
    order = 62

    def bounds(self, key, scale, theta):
        span = max(scale.load_span, scale.effort)
        return -span, span

    def identifiable(self, model, theta):
        why = needs_reference(model)
        if why:
            return why
        temperature = model.data.temperature
        if temperature is None:
            return "the log has no temperature column"
        change = float(np.ptp(temperature))
        if change < MIN_TEMPERATURE_RANGE_K:
            return f"temperature changes by {change:.3g} K (needs at least {MIN_TEMPERATURE_RANGE_K:g} K)"
        return None

    def sensor(self, model, theta, tau):
        c = theta["sensor_tempco"]
        if c == 0.0 or model.data.temperature is None:
            return 0.0
        return c * (model.data.temperature - model.const["calibration_temperature"])

    def signature_signal(self, model, theta):
        return model.data.temperature

    def realise(self, values, rig):
        c, calibration = values["sensor_tempco"], rig.params.photoreflector.reference_temperature_c
        return Realisation(sensor=lambda tau, temperature: c * (temperature - calibration))

    def draw(self, rig, rng):
        return {"sensor_tempco": signed(rng, *SYNTHETIC_RANGE)}


EFFECT = SensorThermalDrift()
