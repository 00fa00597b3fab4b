"""The GIM8108's current-to-torque map: what the motor delivers for a torque command, and what the driver's
current-based estimate reports.

The driver turns a torque command τ_cmd into a current i = τ_cmd / (N·K_t) with its current loop and reports
N·K_t·i as its torque estimate. The torque the magnets actually produce per ampere falls as the current grows
(magnetic saturation of the stator teeth), modelled as the hyperbolic map::

    τ_delivered = τ_cmd / (1 + α |τ_cmd|)          α = motor.torque_saturation_per_nm [1/(N·m)]

so the estimate (linear in the current) over-reports by τ_cmd - τ_delivered. The map is monotonic and
flattens towards 1/α without a maximum, so the motor reaches the paper's peak torque (motor.peak_torque_nm,
18 N·m, Sec. II) at a finite current: the driver's current limit is the command that delivers that peak,
``command_limit_nm``. (A quadratic droop τ_cmd·(1 - β|τ_cmd|) with the same droop at 10 N·m peaks at
1/(4β) = 16.7 N·m and cannot reach 18 N·m: models/gim8108_testbed/README.md, Derivations.)

Written here rather than in the MJCF because MuJoCo's ``dcmotor`` has one torque constant (``motorconst`` may
differ from the back-EMF constant, but not vary with current): :class:`sim.plant.Plant` maps the command with
:meth:`CurrentToTorqueMap.delivered_nm` (inlined in ``Plant.step``) before the dcmotor, whose current state is
then the torque-producing current, and recovers the driver's current with :meth:`CurrentToTorqueMap.command_nm`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.params import TestbedParams


@dataclass(frozen=True)
class CurrentToTorqueMap:
    """τ_delivered = τ_cmd / (1 + α|τ_cmd|) and its inverse.

    Parameters
    ----------
    saturation_per_nm : float
        α [1/(N·m)]; 0 is a linear motor.
    peak_torque_nm : float
        The largest torque the motor delivers [N·m], at the driver's current limit.
    """

    saturation_per_nm: float
    peak_torque_nm: float

    @classmethod
    def from_params(cls, params: TestbedParams) -> CurrentToTorqueMap:
        return cls(params.motor.torque_saturation_per_nm, params.motor.peak_torque_nm)

    @property
    def command_limit_nm(self) -> float:
        """The driver's current limit as a torque command [N·m]: the command that delivers the peak torque."""
        return self.command_nm(self.peak_torque_nm)

    def delivered_nm(self, command_nm: float | np.ndarray) -> float | np.ndarray:
        """Torque the motor produces for a command [N·m] (a float or an array of them)."""
        return command_nm / (1.0 + self.saturation_per_nm * abs(command_nm))

    def command_nm(self, delivered_nm: float | np.ndarray) -> float | np.ndarray:
        """The command that delivers ``delivered_nm`` [N·m], |delivered_nm| below the asymptote 1/α: a float, or
        an array (with ``saturation_per_nm`` a float or an array of one motor's α per element)."""
        if isinstance(delivered_nm, np.ndarray):
            shortfall = 1.0 - self.saturation_per_nm * abs(delivered_nm)  # an α of 0 divides by exactly 1
            if np.any(shortfall <= 0.0):
                raise ValueError(f"delivered torques {delivered_nm[shortfall <= 0.0]} N·m: beyond the asymptote "
                                 f"1/motor.torque_saturation_per_nm of their motors")
            return delivered_nm / shortfall
        if self.saturation_per_nm == 0.0:  # a linear motor (also with an unbounded peak: no 0·inf)
            return delivered_nm
        shortfall = 1.0 - self.saturation_per_nm * abs(delivered_nm)
        if shortfall <= 0.0:
            raise ValueError(f"delivered torque {delivered_nm} N·m: the motor's map reaches at most "
                             f"1/motor.torque_saturation_per_nm = {1.0 / self.saturation_per_nm:.4g} N·m")
        return delivered_nm / shortfall
