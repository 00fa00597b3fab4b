"""Constant effort: a constant force on a slide, a constant torque on a hinge or on the testbed's motor joint.

One law with several causes: gravity along an inclined slide (m·g·sin(incline)), a cable's or a hose's steady pull,
an offset of the drive's command (a driver's current-sense offset b: its current loop drives the measured current
to the command, so the motor delivers the command less b), and friction levels that differ by direction of
motion by ``Δ = F_c+ − F_c− = 2·c`` (levels ``F_c ± Δ/2`` are a symmetric level plus the constant ``Δ/2``). The
effort the joint needs for it is the constant ``c`` [N·m | N], at rest and in motion alike.
"""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import (
    HINGE,
    MIN_SLIDING_FRACTION,
    SLIDE,
    Effect,
    Param,
    Realisation,
    linear_starts,
    signed,
)

MIN_DIRECTION_FRACTION = 0.02  # >= 2 % of the samples sliding each way (else it is a Coulomb level)
TESTBED_RANGE = (0.015, 0.03)  # synthetic draws [N·m], either sign
RIGID_RANGE_OF_COULOMB = {HINGE: (0.1, 0.2), SLIDE: (1.0, 2.0)}  # synthetic draws: x the rig's Coulomb level


class ConstantEffort(Effect):
    name = "constant_effort"
    revealing_experiment = "free"
    description = ("a constant force (slide) or torque (hinge): gravity along an incline, a steady pull, an offset "
                   "of the drive's command, or friction levels that differ by direction by twice it")
    params = (Param("constant_effort", "N·m", "N", "constant effort the joint needs c (positive: against positive "
                    "motion)", fields={HINGE: "constant_effort", SLIDE: "constant_effort"}, valid=(-1e6, 1e6)),)
    signature = "constant (mean while sliding)"
    linear_signature = True
    order = 13

    def bounds(self, key, scale, theta):
        return -scale.effort, scale.effort

    def identifiable(self, model, theta):
        v, threshold = model.data.velocity, model.stick_velocity
        if min((v > threshold).mean(), (v < -threshold).mean()) < MIN_DIRECTION_FRACTION:
            return "the joint does not slide in both directions (a constant is then a Coulomb level)"
        if np.mean(~model.stuck) < MIN_SLIDING_FRACTION:
            return "the joint hardly slides"
        return None

    def load(self, model, theta):
        return theta["constant_effort"]

    def starts(self, model, theta):
        coef = linear_starts(model, theta, [np.ones(len(model.data.t))])
        return ([] if coef is None else [{"constant_effort": float(theta["constant_effort"] + coef[0])}]), ()

    def evidence(self, model, theta, residual, mask):
        """The residual's mean over its RMS on the sliding samples of ``mask`` [1]: its correlation with a constant
        (about the origin: a constant has no variance to correlate with)."""
        r = residual[mask & ~model.stuck]
        r = r[np.isfinite(r)]
        if not len(r):
            return None
        return float(np.mean(r) / np.sqrt(np.mean(r * r))) if np.any(r) else 0.0

    def signature_signal(self, model, theta):
        return (~model.stuck).astype(float)

    def realise(self, values, rig):
        c = values["constant_effort"]
        return Realisation(load=lambda q, qd, t: c)

    def draw(self, rig, rng):
        if rig.model == "testbed":
            return {"constant_effort": signed(rng, *TESTBED_RANGE)}
        low, high = RIGID_RANGE_OF_COULOMB[rig.joint]
        return {"constant_effort": signed(rng, low * rig.rigid["coulomb"], high * rig.rigid["coulomb"])}


EFFECT = ConstantEffort()
