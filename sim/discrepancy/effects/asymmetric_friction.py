"""Asymmetric friction: the friction levels differ by direction of motion (F_c+ - F_c- = Δ).

Levels ``F_c ± Δ/2`` by direction are exactly a constant effort ``Δ/2`` opposing positive motion added to a
symmetric level: the term is that constant. A constant offset of the delivered effort while sliding (a driver's
current-sense offset: its current loop drives the measured current to the command, so the motor delivers the
command less the offset b) is the same term, Δ = 2·b, and is reported here. On a slide it is the same
term as gravity along the incline and is reported as gravity.
"""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import HINGE, MIN_SLIDING_FRACTION, TESTBED, Effect, Param, Realisation, signed

MIN_DIRECTION_FRACTION = 0.02  # >= 2 % of the samples sliding each way
TESTBED_RANGE = (0.03, 0.06)  # synthetic draws [N·m]
RIGID_RANGE_OF_COULOMB = (0.2, 0.4)  # a rigid hinge: x its Coulomb level


class AsymmetricFriction(Effect):
    name = "asymmetric_friction"
    revealing_experiment = "free"
    description = ("friction levels that differ with the direction of motion, or a constant effort offset "
                   "(e.g. the driver's current-sense offset)")
    params = (Param("asymmetry", "N·m", "N", "F_c+ - F_c-: positive-direction minus negative-direction level"),)
    rigs = frozenset({TESTBED, HINGE})
    signature = "constant while sliding"
    order = 13

    def bounds(self, key, scale, theta):
        return -scale.effort, scale.effort

    def identifiable(self, model, theta):
        v, threshold = model.data.velocity, model.stick_velocity
        if min((v > threshold).mean(), (v < -threshold).mean()) < MIN_DIRECTION_FRACTION:
            return "the joint does not slide in both directions"
        if np.mean(~model.stuck) < MIN_SLIDING_FRACTION:
            return "the joint hardly slides"
        return None

    def load(self, model, theta):
        return 0.5 * theta["asymmetry"]

    def signature_signal(self, model, theta):
        return (~model.stuck).astype(float)

    def realise(self, values, rig):
        offset = 0.5 * values["asymmetry"]
        return Realisation(load=lambda q, qd, t: offset)

    def draw(self, rig, rng):
        if rig.model == "testbed":
            return {"asymmetry": signed(rng, *TESTBED_RANGE)}
        low, high = RIGID_RANGE_OF_COULOMB
        return {"asymmetry": signed(rng, low * rig.rigid["coulomb"], high * rig.rigid["coulomb"])}


EFFECT = AsymmetricFriction()
