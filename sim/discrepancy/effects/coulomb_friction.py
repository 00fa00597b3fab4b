"""Coulomb friction: the sliding (dry) friction level differs from the rig's."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import Effect, Param, needs_sliding, up_or_down

COULOMB_UP, COULOMB_DOWN = (1.244, 1.389), (0.5, 0.778)  # synthetic draws: x F_c
COULOMB_BELOW_BREAKAWAY = 0.97  # the testbed: a raised level stays below 0.97 F_s (else it is drawn lower)
RIGID_UP, RIGID_DOWN = (1.3, 1.6), (0.5, 0.7)  # a rigid joint: one dry level (static = sliding) x these
MAX_LEVEL_OF_EFFORT = 2.0  # fit bound: a friction level up to twice the largest effort in the log


class CoulombFriction(Effect):
    name = "coulomb_friction"
    revealing_experiment = "free"
    description = "dry friction level while sliding"
    params = (Param("coulomb", "N·m", "N", "sliding (Coulomb) friction level F_c",
                    fields={"testbed": "friction.coulomb_torque_nm", "hinge": "friction.coulomb",
                            "slide": "friction.coulomb"}, valid=(0.0, 1e4)),)
    signature = "sign of velocity"
    linear_signature = True
    order = 10

    def bounds(self, key, scale, theta):
        return 0.0, MAX_LEVEL_OF_EFFORT * scale.effort

    def identifiable(self, model, theta):
        return needs_sliding(model)

    def signature_signal(self, model, theta):
        return np.where(model.stuck, 0.0, np.sign(model.data.velocity))

    def draw(self, rig, rng):
        if rig.model != "testbed":  # MuJoCo's frictionloss is one level: static and sliding move together
            level = up_or_down(rng, rig.rigid["coulomb"], RIGID_UP, RIGID_DOWN)
            return {"coulomb": level, "breakaway": level}
        fr = rig.params.friction
        level = up_or_down(rng, fr.coulomb_torque_nm, COULOMB_UP, COULOMB_DOWN)
        if level > COULOMB_BELOW_BREAKAWAY * fr.breakaway_torque_nm:  # no room below the breakaway level
            level = fr.coulomb_torque_nm * float(rng.uniform(*COULOMB_DOWN))
        return {"coulomb": level}


EFFECT = CoulombFriction()
