"""Inertia: the moving part's inertia (a rigid joint's mass or moment of inertia, the testbed's rotor) differs
from the rig's."""

from __future__ import annotations

from sim.discrepancy.effects.base import Effect, Param, needs_acceleration, up_or_down

RANGE = (0.1, 10.0)  # fit bound: x the rig's value
UP, DOWN = (1.2, 1.4), (0.65, 0.8)  # synthetic draws: x the rig's value


class Inertia(Effect):
    name = "inertia"
    revealing_experiment = "hinge"
    description = "inertia (mass) of the moving part"
    params = (Param("inertia", "kg·m²", "kg", "inertia (mass) of the joint, output-referred", neutral=None,
                    fields={"testbed": "motor.rotor_inertia_kgm2", "hinge": "inertia_kgm2", "slide": "mass_kg"},
                    valid=(0.0, 1e6)),)
    signature = "acceleration"
    linear_signature = True
    order = 1

    def bounds(self, key, scale, theta):
        return RANGE[0] * scale.baseline["inertia"], RANGE[1] * scale.baseline["inertia"]

    def identifiable(self, model, theta):
        return needs_acceleration(model, theta)

    def signature_signal(self, model, theta):
        return model.data.acceleration

    def draw(self, rig, rng):
        if rig.model == "testbed":
            raise ValueError("inertia is not drawn for the testbed (its rotor sets the physics step)")
        return {"inertia": up_or_down(rng, rig.rigid["inertia"], UP, DOWN)}


EFFECT = Inertia()
