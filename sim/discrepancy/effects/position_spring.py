"""Position spring: an effort pulling the joint toward a rest position, ``k·(x - x0)`` (cables, hoses,
compensation springs)."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import Effect, Param, Realisation, linear_starts

MAX_FORCE_OF_EFFORT = 10.0  # fit bound: k·span up to ten times the largest effort in the log
MIN_SPAN_STEPS = 100  # the position must span 100 encoder steps
FORCE_OF_COULOMB = (1.0, 3.0)  # synthetic draws: k·(span/2) = this x the rig's Coulomb level
TYPICAL_HALF_SPAN = {"testbed": 3.0, "hinge": 2.0, "slide": 0.19}  # synthetic draws [rad | m]


class PositionSpring(Effect):
    name = "position_spring"
    revealing_experiment = "free"
    description = "effort pulling the joint toward a rest position (cables, compensation springs)"
    params = (Param("spring_stiffness", "N·m/rad", "N/m", "stiffness k", valid=(0.0, 1e9)),
              Param("spring_rest_position", "rad", "m", "rest position x0", neutral=None))
    signature = "position"
    order = 51

    def bounds(self, key, scale, theta):
        span = max(scale.position_span, 1e-9)
        if key == "spring_stiffness":
            return 0.0, MAX_FORCE_OF_EFFORT * scale.effort / span
        return -1e3 * span, 1e3 * span

    def load(self, model, theta):
        k = theta["spring_stiffness"]
        return 0.0 if k == 0.0 else k * (model.data.position - theta["spring_rest_position"])

    def starts(self, model, theta):
        x = model.data.position
        coef = linear_starts(model, theta, [x, np.ones(len(x))])  # k·x - k·x0
        if coef is None or coef[0] <= 0.0:
            return [], ()
        return [{"spring_stiffness": float(coef[0]), "spring_rest_position": float(-coef[1] / coef[0])}], ()

    def identifiable(self, model, theta):
        span = float(np.ptp(model.data.position))
        steps = span / max(model.data.position_resolution, 1e-300)
        if steps < MIN_SPAN_STEPS:
            return f"the position spans {span:.3g} ({steps:.0f} encoder steps; needs {MIN_SPAN_STEPS})"
        return None

    def simpler(self, model, theta):
        rest, position = theta["spring_rest_position"], model.data.position
        low, high = float(position.min()), float(position.max())
        if theta["spring_stiffness"] > 0.0 and not low <= rest <= high:
            unit = self.param("spring_rest_position").unit(model.rig.joint)
            return "constant_effort", (f"its rest position {rest:.4g} {unit} lies outside the motion [{low:.4g}, "
                                       f"{high:.4g}] {unit}")
        return None

    def signature_signal(self, model, theta):
        return model.data.position

    def realise(self, values, rig):
        k, rest = values["spring_stiffness"], values["spring_rest_position"]
        return Realisation(load=lambda q, qd, t: k * (q - rest))

    def draw(self, rig, rng):
        kind = "testbed" if rig.model == "testbed" else rig.joint
        level = rig.params.friction.coulomb_torque_nm if rig.model == "testbed" else rig.rigid["coulomb"]
        half = TYPICAL_HALF_SPAN[kind]
        return {"spring_stiffness": level * float(rng.uniform(*FORCE_OF_COULOMB)) / half,
                "spring_rest_position": float(rng.uniform(-0.5, 0.5)) * half}


EFFECT = PositionSpring()
