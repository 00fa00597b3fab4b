"""Viscous friction: friction proportional to velocity (grease, bearings) differs from the rig's."""

from __future__ import annotations

from sim.discrepancy.effects.base import Effect, Param, needs_sliding, up_or_down

VISCOUS_UP, VISCOUS_DOWN = (2.0, 3.0), (0.2, 0.4)  # synthetic draws: x σ2
MAX_FORCE_OF_EFFORT = 10.0  # fit bound: σ2·v_max up to ten times the largest effort in the log


class ViscousFriction(Effect):
    name = "viscous_friction"
    revealing_experiment = "free"
    description = "friction proportional to velocity (grease, bearings)"
    params = (Param("viscous", "N·m·s/rad", "N·s/m", "viscous friction coefficient σ2",
                    fields={"testbed": "friction.viscous_nms_per_rad", "hinge": "friction.viscous",
                            "slide": "friction.viscous"}, valid=(0.0, 1e6)),)
    signature = "velocity"
    linear_signature = True
    order = 11

    def bounds(self, key, scale, theta):
        return 0.0, MAX_FORCE_OF_EFFORT * scale.effort / scale.velocity

    def identifiable(self, model, theta):
        return needs_sliding(model)

    def signature_signal(self, model, theta):
        return model.data.velocity

    def draw(self, rig, rng):
        base = rig.params.friction.viscous_nms_per_rad if rig.model == "testbed" else rig.rigid["viscous"]
        return {"viscous": up_or_down(rng, base, VISCOUS_UP, VISCOUS_DOWN)}


EFFECT = ViscousFriction()
