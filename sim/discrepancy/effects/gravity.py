"""Gravity: the weight of the moving part of a hinge on a tilted axis.

A hinge needs ``A·sin(q - q0)`` (A = m·g·r, q0 the angle of zero gravity torque; the testbed: on its lever). On a
slide gravity along the incline is a constant force: :mod:`sim.discrepancy.effects.constant_effort`.
"""

from __future__ import annotations

import math

import numpy as np

from sim.discrepancy.effects.base import HINGE, TESTBED, Effect, Param, Realisation, linear_starts, wrap_angle

MIN_RANGE_RAD = 1.0  # a hinge must turn through 1 rad
MAX_OF_EFFORT = 2.0  # fit bound: A up to twice the largest effort in the log
TESTBED_RANGE_NM = (0.03, 0.06)  # synthetic draws
RIGID_RANGE_OF_COULOMB = (1.0, 2.0)  # synthetic draws: x the rig's Coulomb level


class Gravity(Effect):
    name = "gravity"
    revealing_experiment = "free"
    description = "weight of the moving part of a hinge on a tilted axis"
    params = (Param("gravity_amplitude", "N·m", "N", "m·g·r", fields={"hinge": "gravity_amplitude"},
                    valid=(-1e6, 1e6)),
              Param("gravity_angle", "rad", "rad", "joint angle of zero gravity torque", neutral=None, cyclic=True,
                    fields={"hinge": "gravity_angle_rad"},
                    valid=(-math.pi, math.pi)))
    rigs = frozenset({TESTBED, HINGE})
    signature = "sin(position)"
    order = 50

    def bounds(self, key, scale, theta):
        if key == "gravity_amplitude":
            return -MAX_OF_EFFORT * scale.effort, MAX_OF_EFFORT * scale.effort
        return -2 * math.pi, 2 * math.pi

    def canonical(self, theta, joint):
        theta = dict(theta)
        if theta["gravity_amplitude"] < 0.0:  # A·sin(q - q0) = -A·sin(q - q0 - π)
            theta["gravity_amplitude"] = -theta["gravity_amplitude"]
            theta["gravity_angle"] += math.pi
        theta["gravity_angle"] = wrap_angle(theta["gravity_angle"])
        return theta

    def _angle(self, model):
        return model.data.q if model.data.q is not None else model.data.position

    def _torque(self, model, theta):
        amplitude = theta["gravity_amplitude"]
        if amplitude == 0.0:
            return 0.0
        return amplitude * np.sin(self._angle(model) - theta["gravity_angle"])

    def load(self, model, theta):
        return 0.0 if model.kind == TESTBED else self._torque(model, theta)

    def lever_load(self, model, theta):
        return self._torque(model, theta) if model.kind == TESTBED else 0.0

    def starts(self, model, theta):
        if model.kind == TESTBED:  # on the lever: through the transmitted torque, not a linear start
            return [{"gravity_amplitude": a, "gravity_angle": q0} for a in (0.02, 0.05)
                    for q0 in np.linspace(-math.pi, math.pi, 8, endpoint=False)], ()
        q = self._angle(model)
        coef = linear_starts(model, theta, [np.sin(q), -np.cos(q)])  # A·sin(q - q0) = A cos q0 sin q - A sin q0 cos q
        if coef is None:
            return [], ()
        return [{"gravity_amplitude": float(math.hypot(*coef)),
                 "gravity_angle": float(math.atan2(coef[1], coef[0]))}], ()

    def identifiable(self, model, theta):
        span = float(np.ptp(self._angle(model)))
        if span < MIN_RANGE_RAD:
            return f"the joint turns through {span:.3g} rad (needs {MIN_RANGE_RAD:g} rad)"
        return None

    def signature_signal(self, model, theta):
        return np.sin(self._angle(model))

    def realise(self, values, rig):
        amplitude, angle = values["gravity_amplitude"], values.get("gravity_angle", 0.0)
        if rig.model == "testbed":
            return Realisation(lever_load=lambda q: amplitude * math.sin(q - angle))
        return Realisation(load=lambda q, qd, t: amplitude * math.sin(q - angle))

    def draw(self, rig, rng):
        if rig.model == "testbed":
            return {"gravity_amplitude": float(rng.uniform(*TESTBED_RANGE_NM)),
                    "gravity_angle": float(rng.uniform(-math.pi, math.pi))}
        level = rig.rigid["coulomb"] * float(rng.uniform(*RIGID_RANGE_OF_COULOMB))
        return {"gravity_amplitude": level, "gravity_angle": float(rng.uniform(-math.pi, math.pi))}


EFFECT = Gravity()
