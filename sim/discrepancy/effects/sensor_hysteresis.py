"""Sensor hysteresis: a reading that depends on the loading direction, an elastic-plastic (Prandtl) loop.

The loop adds ``H/S·(τ - p)``, p the play operator of half-width S on τ: it rises like a gain for a torque change
of up to 2S after a reversal, then saturates at ±H. The span is fitted up to a quarter of the load range: a wider
loop never saturates in the log and is a gain with an offset, not hysteresis.
"""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import TESTBED, Effect, Param, Realisation
from sim.discrepancy.effects.sensor_offset import needs_reference

MIN_LOAD_RANGE_NM = 1.0
MAX_SPAN_OF_RANGE = 0.25
HEIGHT_OF_RANGE = 0.5  # fit bound: |H| up to half the load range
SPAN_STARTS = (0.25, 0.5, 1.0, 2.0, 4.0)  # [N·m]
HEIGHT_STARTS = (-0.03, 0.03)  # [N·m]
SYNTHETIC = {"sensor_hysteresis": (0.02, 0.05), "sensor_hysteresis_span": (0.5, 2.0)}
DEFAULT_SPAN_NM = 1.0  # the span of a rig without the loop (irrelevant while its height is 0)


def play_operator(x: np.ndarray, half_width: float) -> np.ndarray:
    """Backlash (play) operator of half-width ``half_width`` on ``x`` (starts centred on ``x[0]``)."""
    out = np.empty_like(x)
    p = float(x[0])
    for k, xk in enumerate(x.tolist()):
        if xk - p > half_width:
            p = xk - half_width
        elif p - xk > half_width:
            p = xk + half_width
        out[k] = p
    return out


class SensorHysteresis(Effect):
    name = "sensor_hysteresis"
    revealing_experiment = "locked"
    description = "torque sensor reading that depends on the loading direction"
    params = (Param("sensor_hysteresis", "N·m", "N·m", "loop half-height H (positive: reads high while loading up)"),
              Param("sensor_hysteresis_span", "N·m", "N·m", "torque change that saturates the loop S", neutral=None,
                    default=DEFAULT_SPAN_NM, valid=(1e-6, 1e4), firm=True))
    rigs = frozenset({TESTBED})
    channel = "sensor"
    signature = "loading direction (sensor)"
    order = 63

    def bounds(self, key, scale, theta):
        span = max(scale.load_span, 1e-6)
        if key == "sensor_hysteresis":
            return -HEIGHT_OF_RANGE * span, HEIGHT_OF_RANGE * span
        return 1e-3, max(1e-3, MAX_SPAN_OF_RANGE * span)

    def starts(self, model, theta):
        return [{"sensor_hysteresis_span": s, "sensor_hysteresis": h} for s in SPAN_STARTS for h in HEIGHT_STARTS], ()

    def identifiable(self, model, theta):
        why = needs_reference(model)
        if why:
            return why
        tau = model.transmitted(theta)
        span = float(max(tau) - min(tau))
        if span < MIN_LOAD_RANGE_NM:
            return f"transmitted torque spans {span:.3g} N·m (needs {MIN_LOAD_RANGE_NM:g})"
        return None

    def sensor(self, model, theta, tau):
        height = theta["sensor_hysteresis"]
        if height == 0.0:
            return 0.0
        span = theta["sensor_hysteresis_span"]
        key = (span, float(tau.sum()), float(tau @ tau))  # the reference moves with gravity only
        played = model.memo("play", key, lambda: play_operator(tau, span))
        return height / span * (tau - played)

    def signature_signal(self, model, theta):
        tau = model.transmitted(theta)
        return tau - play_operator(tau, 1.0)

    def realise(self, values, rig):
        height, span = values["sensor_hysteresis"], values["sensor_hysteresis_span"]
        return Realisation(sensor=lambda tau, temperature: height / span * (tau - play_operator(tau, span)))

    def draw(self, rig, rng):
        return {key: float(rng.uniform(*span)) for key, span in SYNTHETIC.items()}


EFFECT = SensorHysteresis()
