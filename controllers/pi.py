"""PI torque controller with back-calculation anti-windup (paper Sec. V-A).

At each control tick k (period T_s)::

    e_k     = tau_ref_k - tau_meas_k                               [N·m]
    v_k     = Kp e_k + i_k                                         unsaturated command [N·m]
    u_k     = clip(v_k, -u_max, u_max)                             command to the motor [N·m]
    i_{k+1} = i_k + T_s (Ki e_k + K_aw (u_k - v_k))                integrator (forward Euler) [N·m]

Kp is dimensionless (N·m of command per N·m of error), Ki in 1/s, the back-calculation gain K_aw in 1/s:
while the output saturates, the integrator is pulled back towards the value that would just reach the limit.
The paper gives Kp = 0.12, Ki = 12.0 and an anti-windup gain of 5; the discretisation is not stated and
forward Euler is assumed (the simplest form a 1 kHz loop on a motor driver uses).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# Paper Sec. V-A: PI gains and back-calculation gain of the torque loop.
PAPER_KP = 0.12  # [-] N·m command per N·m error
PAPER_KI_PER_S = 12.0  # [1/s]
PAPER_ANTIWINDUP_PER_S = 5.0  # [1/s]
PAPER_CONTROL_PERIOD_S = 1e-3  # 1 kHz


def _check(name: str, value: float, low: float, *, low_open: bool = False) -> float:
    value = float(value)
    if not math.isfinite(value) or value < low or (low_open and value == low):
        bracket = "(" if low_open else "["
        raise ValueError(f"{name} = {value!r}: valid range {bracket}{low:g}, inf)")
    return value


@dataclass
class PITorqueController:
    """Discrete PI torque controller with output limit and back-calculation anti-windup.

    Parameters
    ----------
    output_limit_nm : float
        Largest command magnitude the motor can give [N·m] (the plant's peak torque).
    kp : float
        Proportional gain [-].
    ki_per_s : float
        Integral gain [1/s].
    antiwindup_per_s : float
        Back-calculation gain [1/s] (0 disables anti-windup).
    period_s : float
        Control period T_s [s].
    """

    output_limit_nm: float
    kp: float = PAPER_KP
    ki_per_s: float = PAPER_KI_PER_S
    antiwindup_per_s: float = PAPER_ANTIWINDUP_PER_S
    period_s: float = PAPER_CONTROL_PERIOD_S

    def __post_init__(self) -> None:
        self.output_limit_nm = _check("output_limit_nm", self.output_limit_nm, 0.0, low_open=True)
        self.kp = _check("kp", self.kp, 0.0)
        self.ki_per_s = _check("ki_per_s", self.ki_per_s, 0.0)
        self.antiwindup_per_s = _check("antiwindup_per_s", self.antiwindup_per_s, 0.0)
        self.period_s = _check("period_s", self.period_s, 0.0, low_open=True)
        self.reset()

    def reset(self, integrator_nm: float = 0.0) -> None:
        """Set the integrator state i [N·m]."""
        self.integrator_nm = float(integrator_nm)

    def step(self, tau_ref_nm: float, tau_measured_nm: float) -> float:
        """One tick: the torque command u_k [N·m] for reference and measured torque [N·m]."""
        error = tau_ref_nm - tau_measured_nm
        unsaturated = self.kp * error + self.integrator_nm
        command = min(max(unsaturated, -self.output_limit_nm), self.output_limit_nm)
        self.integrator_nm += self.period_s * (self.ki_per_s * error
                                               + self.antiwindup_per_s * (command - unsaturated))
        return command
