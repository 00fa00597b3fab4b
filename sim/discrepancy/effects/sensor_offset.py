"""Sensor offset: the joint torque sensor's zero error b (reading = τ + b)."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import TESTBED, Effect, Param, Realisation, signed

SYNTHETIC_RANGE_NM = (0.03, 0.1)


def needs_reference(model) -> str | None:
    """Why the sensor's effects cannot be revealed (no independent torque reference), or None."""
    if "sensor" not in model.channels:
        return "no independent torque reference for the sensor (needs tau_sensor and a load cell, or the free fixture)"
    return None


class SensorOffset(Effect):
    name = "sensor_offset"
    revealing_experiment = "locked"
    description = "torque sensor zero error"
    params = (Param("sensor_offset", "N·m", "N·m", "zero error of the torque sensor b"),)
    rigs = frozenset({TESTBED})
    channel = "sensor"
    signature = "constant (sensor)"
    order = 60

    def bounds(self, key, scale, theta):
        span = max(scale.load_span, scale.effort)
        return -span, span

    def identifiable(self, model, theta):
        return needs_reference(model)

    def sensor(self, model, theta, tau):
        return theta["sensor_offset"]

    def signature_signal(self, model, theta):
        return np.ones(len(model.data.t))

    def realise(self, values, rig):
        b = values["sensor_offset"]
        return Realisation(sensor=lambda tau, temperature: np.full(len(tau), b))

    def draw(self, rig, rng):
        return {"sensor_offset": signed(rng, *SYNTHETIC_RANGE_NM)}


EFFECT = SensorOffset()
