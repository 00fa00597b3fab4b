"""Quadratic drag: an effort growing with the square of the velocity, ``c·v·|v|`` (fluid drag, fans, pumps)."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import Effect, Param, Realisation, needs_sliding

MAX_FORCE_OF_EFFORT = 10.0  # fit bound: c·v_max² up to ten times the largest effort in the log
TYPICAL_SPEED = {"testbed": 3.0, "hinge": 3.0, "slide": 0.3}  # synthetic draws: speed of the experiments [rad/s | m/s]
DRAG_OF_COULOMB = (1.0, 3.0)  # synthetic draws: c·v_typ² = this x the rig's Coulomb level


def velocity_squared(v: np.ndarray) -> np.ndarray:
    """v·|v| [(rad/s)² | (m/s)²]."""
    return v * np.abs(v)


class QuadraticDrag(Effect):
    name = "quadratic_drag"
    revealing_experiment = "free"
    description = "effort growing with the square of the velocity (fluid drag, fans)"
    params = (Param("drag_coefficient", "N·m·s²/rad²", "N·s²/m²", "drag coefficient c of c·v·|v|"),)
    signature = "velocity squared (v|v|)"
    linear_signature = True
    order = 14

    def bounds(self, key, scale, theta):
        return 0.0, MAX_FORCE_OF_EFFORT * scale.effort / scale.velocity**2

    def identifiable(self, model, theta):
        return needs_sliding(model)

    def load(self, model, theta):
        return theta["drag_coefficient"] * velocity_squared(model.data.velocity)

    def signature_signal(self, model, theta):
        return velocity_squared(model.data.velocity)

    def realise(self, values, rig):
        c = values["drag_coefficient"]
        return Realisation(load=lambda q, qd, t: c * qd * abs(qd))

    def draw(self, rig, rng):
        level = rig.params.friction.coulomb_torque_nm if rig.model == "testbed" else rig.rigid["coulomb"]
        speed = TYPICAL_SPEED["testbed" if rig.model == "testbed" else rig.joint]
        return {"drag_coefficient": level * float(rng.uniform(*DRAG_OF_COULOMB)) / speed**2}


EFFECT = QuadraticDrag()
