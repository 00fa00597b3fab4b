"""The GIM8108's current-to-torque map: what the motor delivers for a torque command, and what the driver's
current-based estimate reports.

The driver turns a torque command τ_cmd into a current i = τ_cmd / (N·K_t) with its current loop and reports
N·K_t·i as its torque estimate. The torque the magnets actually produce per ampere falls at high current
(magnetic saturation), modelled as::

    τ_delivered = τ_cmd · (1 - β |τ_cmd|)          β = motor.torque_saturation_per_nm [1/(N·m)]

so the estimate (linear in the current) over-reports by τ_cmd - τ_delivered.

Written here rather than in the MJCF because MuJoCo's ``dcmotor`` has one torque constant (``motorconst`` may
differ from the back-EMF constant, but not vary with current): :class:`sim.plant.Plant` maps the command with
:meth:`CurrentToTorqueMap.delivered_nm` (inlined in ``Plant.step``) before the dcmotor, whose current state is
then the torque-producing current, and recovers the driver's current with :meth:`CurrentToTorqueMap.command_nm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.params import TestbedParams


@dataclass(frozen=True)
class CurrentToTorqueMap:
    """τ_delivered = τ_cmd (1 - β|τ_cmd|) and its inverse (β in 1/(N·m), 0: linear)."""

    saturation_per_nm: float

    @classmethod
    def from_params(cls, params: TestbedParams) -> "CurrentToTorqueMap":
        return cls(params.motor.torque_saturation_per_nm)

    def delivered_nm(self, command_nm: float | np.ndarray) -> float | np.ndarray:
        """Torque the motor produces for a command [N·m] (a float or an array of them)."""
        return command_nm * (1.0 - self.saturation_per_nm * abs(command_nm))

    def command_nm(self, delivered_nm: float) -> float:
        """The command that delivers ``delivered_nm`` [N·m] (the inverse map, on its monotonic branch)."""
        beta = self.saturation_per_nm
        root = 1.0 - 4.0 * beta * abs(delivered_nm)
        if root < 0.0:  # beyond the map's maximum 1/(4β): the largest command that maps there
            return math.copysign(1.0 / (2.0 * beta), delivered_nm)
        # (1 - √root)/(2β) with the sign, rationalised: no cancellation at small torque, and β = 0 needs no case
        return 2.0 * delivered_nm / (1.0 + math.sqrt(root))
