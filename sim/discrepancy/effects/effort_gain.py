"""Effort gain: the effort delivered per unit of command differs from the rig's (a wrong torque constant or
current-sense gain): delivered = g·u."""

from __future__ import annotations

from sim.discrepancy.effects.base import Effect, Param, Realisation, up_or_down
from sim.motor_torque import CurrentToTorqueMap

RANGE = (0.5, 2.0)  # fit bound: x the rig's gain (a torque constant off by more is not the rig's)
UP, DOWN = (1.05, 1.15), (0.85, 0.95)  # synthetic draws: x the rig's gain


class EffortGain(Effect):
    name = "effort_gain"
    revealing_experiment = "locked"
    description = "effort delivered per unit of command (torque constant, current-sense gain)"
    params = (Param("effort_gain", "1", "1", "delivered effort per unit command", neutral=1.0,
                    fields={"hinge": "effort_gain", "slide": "effort_gain"}, valid=(0.0, 1e6), firm=True),)
    signature = "command"
    order = 45  # after the roll-off: on the testbed its realisation scales what the motor's map delivers
    explains_at_bound = False  # at its bound it scales the whole balance down (or up): no explanation

    def bounds(self, key, scale, theta):
        return RANGE[0] * scale.baseline["effort_gain"], RANGE[1] * scale.baseline["effort_gain"]

    def signature_signal(self, model, theta):
        return model.data.filt(model.data.u_full)

    def realise(self, values, rig):
        if rig.model != "testbed":
            return Realisation()  # the rigid joint's own gain (its actuator's gear)
        # the plant maps the command by the motor's current-to-torque map; ask it for g times what it delivers for
        # the command its driver lets through (clipped at the current limit first, as the surrogate does; the
        # plant clips only what this map returns)
        torque_map = CurrentToTorqueMap.from_params(rig.params)
        gain, limit = values["effort_gain"], torque_map.command_limit_nm
        return Realisation(command=lambda u: torque_map.command_nm(
            gain * torque_map.delivered_nm(min(max(u, -limit), limit))))

    def draw(self, rig, rng):
        base = 1.0 if rig.model == "testbed" else rig.rigid["effort_gain"]
        return {"effort_gain": up_or_down(rng, base, UP, DOWN)}


EFFECT = EffortGain()
