"""Sensor gain: the joint torque sensor's scale error g (reading = g·τ)."""

from __future__ import annotations

from sim.discrepancy.effects.base import TESTBED, Effect, Param, Realisation, signed
from sim.discrepancy.effects.sensor_offset import needs_reference

MIN_LOAD_RANGE_NM = 1.0
BOUNDS = (0.5, 2.0)
STARTS = (0.97, 1.03)
SYNTHETIC_ERROR = (0.02, 0.05)  # |g - 1|


class SensorGain(Effect):
    name = "sensor_gain"
    revealing_experiment = "locked"
    description = "torque sensor scale error"
    params = (Param("sensor_gain", "1", "1", "scale of the torque sensor g", neutral=1.0, valid=BOUNDS, firm=True),)
    rigs = frozenset({TESTBED})
    channel = "sensor"
    signature = "load (sensor)"
    order = 61

    def bounds(self, key, scale, theta):
        return BOUNDS

    def starts(self, model, theta):
        return [{"sensor_gain": g} for g in STARTS], ()

    def identifiable(self, model, theta):
        why = needs_reference(model)
        if why:
            return why
        span = float(max(model.transmitted(theta)) - min(model.transmitted(theta)))
        if span < MIN_LOAD_RANGE_NM:
            return f"transmitted torque spans {span:.3g} N·m (needs {MIN_LOAD_RANGE_NM:g})"
        return None

    def sensor(self, model, theta, tau):
        return (theta["sensor_gain"] - 1.0) * tau

    def signature_signal(self, model, theta):
        return model.transmitted(theta)

    def realise(self, values, rig):
        g = values["sensor_gain"]
        return Realisation(sensor=lambda tau, temperature: (g - 1.0) * tau)

    def draw(self, rig, rng):
        return {"sensor_gain": 1.0 + signed(rng, *SYNTHETIC_ERROR)}


EFFECT = SensorGain()
