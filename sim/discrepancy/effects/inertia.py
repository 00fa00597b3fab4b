"""Inertia: the moving part's inertia (a rigid joint's mass or moment of inertia, the testbed's rotor) differs
from the rig's."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import Effect, Param, up_or_down

RANGE = (0.1, 10.0)  # fit bound: x the rig's value
UP, DOWN = (1.2, 1.4), (0.65, 0.8)  # synthetic draws: x the rig's value
MIN_INERTIAL_FRACTION = 0.02  # the log's inertial effort (RMS) must reach 2 % of the command's


class Inertia(Effect):
    name = "inertia"
    description = "inertia (mass) of the moving part"
    params = (Param("inertia", "kg·m²", "kg", "inertia (mass) of the joint, output-referred", neutral=None,
                    fields={"testbed": "motor.rotor_inertia_kgm2", "hinge": "inertia_kgm2", "slide": "mass_kg"},
                    valid=(0.0, 1e6)),)
    signature = "acceleration"
    order = 1

    def bounds(self, key, scale, theta):
        return RANGE[0] * scale.baseline["inertia"], RANGE[1] * scale.baseline["inertia"]

    def identifiable(self, model, theta):
        inertial = theta["inertia"] * float(np.sqrt(np.mean(model.data.acceleration**2)))
        command = float(np.sqrt(np.mean(model.data.u**2)))
        if inertial < MIN_INERTIAL_FRACTION * command:
            return (f"the inertial effort is {inertial:.3g} RMS, below {100 * MIN_INERTIAL_FRACTION:g} % of the "
                    f"command's {command:.3g}: the log hardly accelerates the joint")
        return None

    def signature_signal(self, model, theta):
        return model.data.acceleration

    def draw(self, rig, rng):
        if rig.model == "testbed":
            raise ValueError("inertia is not drawn for the testbed (its rotor sets the physics step)")
        return {"inertia": up_or_down(rng, rig.rigid["inertia"], UP, DOWN)}


EFFECT = Inertia()
