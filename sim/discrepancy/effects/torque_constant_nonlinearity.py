"""Torque-constant roll-off: the effort per unit command falls at high command (magnetic saturation).

The drive delivers ``u·(1 - c·min(|u|/u_peak, 1)²)``: the lost fraction grows with the square of the command and
reaches ``c`` at the rig's peak effort ``u_peak`` (the testbed: the motor's rated peak torque), staying there beyond.
"""

from __future__ import annotations

import math

import numpy as np

from sim.discrepancy.effects.base import Effect, Param, Realisation
from sim.motor_torque import CurrentToTorqueMap

MIN_PEAK_FRACTION = 0.3  # commands must reach 30 % of the peak effort
SYNTHETIC_RANGE = (0.05, 0.15)
BOUNDS = (-0.5, 0.9)  # [1]: a rising (negative c) or falling torque constant
STARTS = (-0.1, 0.1)


def rolled_off(u: np.ndarray | float, rolloff: float, peak: float) -> np.ndarray | float:
    """``u·(1 - c·min(|u|/peak, 1)²)`` [u's unit]."""
    return u * (1.0 - rolloff * np.minimum(np.abs(u) / peak, 1.0) ** 2)


class TorqueConstantNonlinearity(Effect):
    name = "torque_constant_nonlinearity"
    revealing_experiment = "locked"
    description = "torque per command falling at high current (magnetic saturation)"
    params = (Param("torque_rolloff", "1", "1", "fraction of the command lost at peak effort", valid=BOUNDS,
                    firm=True),)
    signature = "command cubed"
    order = 40

    def bounds(self, key, scale, theta):
        return BOUNDS

    def starts(self, model, theta):
        return [{"torque_rolloff": c} for c in STARTS], ()

    def identifiable(self, model, theta):
        peak = theta["peak_effort"]
        if not math.isfinite(peak):
            return "the rig states no peak effort (peak_effort) to refer the roll-off to"
        reach = float(np.abs(model.data.u_full).max())
        if reach < MIN_PEAK_FRACTION * peak:
            unit = "N" if model.rig.joint == "slide" else "N·m"
            return (f"commands reach {reach:.3g} {unit}, below {100 * MIN_PEAK_FRACTION:g} % of the peak effort "
                    f"{peak:.3g} {unit}")
        return None

    def command(self, u, theta, peak):
        c = theta["torque_rolloff"]
        return rolled_off(u, c, peak) if c else u

    def signature_signal(self, model, theta):
        return model.data.filt(model.data.u_full ** 3)

    def realise(self, values, rig):
        c = values["torque_rolloff"]
        peak = rig.params.motor.peak_torque_nm if rig.model == "testbed" else rig.rigid.get("peak_effort", math.inf)
        if not math.isfinite(peak):
            raise ValueError("torque_constant_nonlinearity needs the rig's peak effort (peak_effort)")
        # the drive limits the command before the magnets roll it off (the surrogate clips first too); the testbed's
        # plant clips only after this map, at its driver's current limit; a rigid joint's map is already clipped
        limit = CurrentToTorqueMap.from_params(rig.params).command_limit_nm if rig.model == "testbed" else peak
        return Realisation(command=lambda u: float(rolled_off(min(max(u, -limit), limit), c, peak)))

    def draw(self, rig, rng):
        return {"torque_rolloff": float(rng.uniform(*SYNTHETIC_RANGE))}


EFFECT = TorqueConstantNonlinearity()
