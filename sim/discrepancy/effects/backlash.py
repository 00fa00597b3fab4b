"""Backlash: the dead band between the gear and the sensor hub (the testbed's kinematic channel).

After a torque reversal the hub lags the motor by half the band: the motor angle minus the lever angle minus the
flexure twist is ``±w/2`` by the sign of the transmitted torque.
"""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import TESTBED, Effect, Param, up_or_down

UP, DOWN = (1.714, 2.857), (0.2857, 0.5714)  # synthetic draws: x the width
MIN_REVERSALS = 2
MAX_WIDTH_OF_SPAN = 1.0  # fit bound: at most the log's position span
STARTS = (0.3, 2.0)  # x the current width


class Backlash(Effect):
    name = "backlash"
    revealing_experiment = "locked"
    description = "dead band in the gear: the hub lags the motor by half the band after a torque reversal"
    params = (Param("backlash_width", "rad", "m", "total dead band between gear and hub",
                    fields={"testbed": "backlash.width_rad"}, valid=(0.0, 1.0)),)
    rigs = frozenset({TESTBED})
    channel = "kinematic"
    signature = "sign of load (kinematic)"
    order = 17

    def bounds(self, key, scale, theta):
        return 0.0, max(MAX_WIDTH_OF_SPAN * scale.position_span, 10 * scale.baseline["backlash_width"])

    def starts(self, model, theta):
        return [{"backlash_width": theta["backlash_width"] * f} for f in STARTS], ()

    def identifiable(self, model, theta):
        if "kinematic" not in model.channels:
            return "needs both q (lever) and q_motor"
        tau = model.transmitted(theta)
        loaded = np.sign(tau[np.abs(tau) > model.config.contact_torque])
        if np.count_nonzero(np.diff(loaded)) < MIN_REVERSALS:
            return "fewer than two reversals of the transmitted torque"
        return None

    def signature_signal(self, model, theta):
        return np.sign(model.transmitted(theta))

    def draw(self, rig, rng):
        return {"backlash_width": up_or_down(rng, rig.params.backlash.width_rad, UP, DOWN)}


EFFECT = Backlash()
