"""Transport delay: a dead time between the logged command and the effort it produces (bus, driver processing)."""

from __future__ import annotations

import numpy as np

from sim.discrepancy.effects.base import Effect, Param

MAX_DELAY_S = 0.05  # [s] the largest dead time fitted (the testbed's motor.command_delay_s allows up to 50 ms)
MAX_DELAY_OF_DURATION = 0.05  # and at most 5 % of the log
START_STEPS = 50  # starts: a grid of this many dead times over the range
EXTRA_DELAY_S = (1.5e-3, 5.5e-3)  # synthetic draws: [s] added to the rig's dead time


class TransportDelay(Effect):
    name = "transport_delay"
    revealing_experiment = "free"
    description = "dead time between the logged command and the torque"
    params = (Param("delay", "s", "s", "command-to-effort dead time",
                    fields={"testbed": "motor.command_delay_s", "hinge": "delay_s", "slide": "delay_s"},
                    valid=(0.0, MAX_DELAY_S)),)
    signature = "command rate (time shift)"
    order = 41
    any_size = True  # a dead time matters to a controller whatever effort it leaves unexplained

    def bounds(self, key, scale, theta):
        return 0.0, min(MAX_DELAY_S, MAX_DELAY_OF_DURATION * scale.duration)

    def starts(self, model, theta):
        high = self.bounds("delay", model.scale, theta)[1]
        step = max(model.data.dt, high / START_STEPS)
        return [{"delay": float(d)} for d in np.arange(0.0, high + 1e-12, step)], ()

    def identifiable(self, model, theta):
        if not np.any(np.diff(model.data.u_full)):
            return "the command never changes"
        return None

    def signature_signal(self, model, theta):
        return model.data.filt(model.data.derivative(model.data.u_full))

    def draw(self, rig, rng):
        base = rig.params.motor.command_delay_s if rig.model == "testbed" else rig.rigid.get("delay", 0.0)
        return {"delay": base + float(rng.uniform(*EXTRA_DELAY_S))}


EFFECT = TransportDelay()
