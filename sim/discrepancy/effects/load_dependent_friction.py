"""Load-dependent friction: dry gear friction growing with the transmitted torque, ``μ·|τ|`` (efficiency 1 - μ)."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import TESTBED, Effect, Param, needs_sliding, up_or_down

UP, DOWN = (1.5, 2.0), (0.3, 0.6)  # synthetic draws: x μ
IF_NONE = (0.05, 0.15)  # synthetic draws for a rig without it [1]
MIN_LOAD_RANGE_NM = 1.0  # the transmitted torque must span 1 N·m


class LoadDependentFriction(Effect):
    name = "load_dependent_friction"
    revealing_experiment = "locked"
    description = "gear friction growing with the transmitted torque (efficiency)"
    params = (Param("load_coefficient", "1", "1", "dry friction per unit transmitted torque (1 - η)",
                    fields={"testbed": "friction.load_friction_coefficient"}, valid=(0.0, 1.0), firm=True),)
    rigs = frozenset({TESTBED})
    signature = "load x sign of velocity"
    order = 15

    def bounds(self, key, scale, theta):
        return 0.0, 1.0

    def identifiable(self, model, theta):
        why = needs_sliding(model)
        if why:
            return why
        span = float(np.ptp(model.transmitted(theta)))
        if span < MIN_LOAD_RANGE_NM:
            return f"transmitted torque spans {span:.3g} N·m (needs {MIN_LOAD_RANGE_NM:g})"
        return None

    def signature_signal(self, model, theta):
        return np.abs(model.transmitted(theta)) * np.sign(model.data.velocity)

    def draw(self, rig, rng):
        mu = rig.params.friction.load_friction_coefficient
        return {"load_coefficient": float(rng.uniform(*IF_NONE)) if mu == 0.0 else up_or_down(rng, mu, UP, DOWN)}


EFFECT = LoadDependentFriction()
