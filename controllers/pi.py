"""PI torque controller with reference feed-forward and back-calculation anti-windup (paper Sec. IV).

At each control tick k (period T_s)::

    e_k     = tau_ref_k - tau_meas_k                               [N·m]
    v_k     = K_ff tau_ref_k + Kp e_k + i_k                        unsaturated command [N·m]
    u_k     = clip(v_k, -u_max, u_max)                             command to the motor driver [N·m]
    i_{k+1} = i_k + T_s (Ki e_k + K_aw (u_k - v_k))                integrator (forward Euler) [N·m]

Kp and K_ff are dimensionless (N·m of command per N·m), Ki and the back-calculation gain K_aw in 1/s: while
the output saturates, the integrator is pulled back towards the value that would just reach the limit.
The paper gives Kp = 0.12, Ki = 12.0 and an anti-windup gain of 5; the discretisation is not stated and
forward Euler is assumed (the simplest form a 1 kHz loop on a motor driver uses).

Interpretation of the paper's two modes (kept throughout torquebed)
-------------------------------------------------------------------
The GIM8108 takes torque commands, which its driver turns into current with its own current loop. The paper
compares "using only the motor torque command" with "using the proposed sensor as an additional feedback
signal" (Sec. IV). We read this as one controller structure, the reference fed forward as the driver's torque
command (K_ff = 1) plus the PI acting on a measured torque:

* ``current`` feedback ("current sensor only"): the measured torque is the driver's current-based estimate
  N·K_t·i. It follows the command within the current loop's lag, so the PI only corrects that lag: the
  delivered torque is what the torque command alone gives, blind to gear friction and to the
  current-to-torque map.
* ``sensor`` feedback: the measured torque is the calibrated photo-reflector output, so the PI corrects
  whatever the gear loses.

Why K_ff = 1 (an interpretation, not a number the paper gives): with a pure PI (K_ff = 0) the loop's
tracking error at 0.2 Hz is |jω(1 + Kp)/Ki| ≈ 12 % of the reference on an ideal actuator, i.e. an RMS error
of about 0.8 N·m on the 10 N·m sine, five times the paper's 0.152 N·m with sensor feedback (Table VII); the
paper's sensor-feedback step errors are also independent of the step size (Table VI), which a pure PI's
transient would not be. Set ``feedforward_gain=0`` for the pure PI.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams, range_text

# Paper Sec. IV: PI gains and back-calculation gain of the torque loop, 1 kHz control cycle.
PAPER_KP = 0.12  # [-] N·m command per N·m error
PAPER_KI_PER_S = 12.0  # [1/s]
PAPER_ANTIWINDUP_PER_S = 5.0  # [1/s]
PAPER_CONTROL_PERIOD_S = TestbedParams().simulation.control_period_s  # [s] the parameter's default, the paper's 1 kHz
REFERENCE_FEEDFORWARD = 1.0  # [-] the reference is the driver's torque command (interpretation, see above)


def check_range(name: str, value: float, low: float, high: float = math.inf, *, low_open: bool = False) -> float:
    """``value`` as a float if it is a finite real number in ``[low, high]`` (``(low, high]`` if low_open),
    else ValueError naming the field and its valid range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} = {value!r}: expected a number in {range_text(low, high, low_open=low_open)}")
    value = float(value)
    if not math.isfinite(value) or value < low or (low_open and value == low) or value > high:
        raise ValueError(f"{name} = {value!r}: valid range {range_text(low, high, low_open=low_open)}")
    return value


@dataclass
class PITorqueController:
    """Discrete PI torque controller with reference feed-forward, output limit and back-calculation
    anti-windup.

    Parameters
    ----------
    output_limit_nm : float
        Largest command magnitude the motor can give [N·m] (the plant's peak torque).
    kp : float
        Proportional gain [-], >= 0; no upper bound is imposed, as the stable range depends on the plant
        (on the one-tick ideal plant of the tests the loop is unstable above about 1).
    ki_per_s : float
        Integral gain [1/s].
    antiwindup_per_s : float
        Back-calculation gain [1/s] (0 disables anti-windup).
    period_s : float
        Control period T_s [s].
    feedforward_gain : float
        Reference feed-forward K_ff [-] (1: the reference is the driver's torque command; 0: pure PI).
    measured : str
        The observation key of the measured torque the PI closes on (:meth:`step`): ``"tau_sensor"`` (the
        optical sensor) or ``"tau_current_estimate"`` (the driver's estimate).
    velocity_damping_nms_per_rad : float
        K_d [N·m·s/rad], >= 0: ``- K_d·qd_motor`` is added to the PI's limited command (0: the paper's PI).

    Attributes
    ----------
    integrator_nm : float
        The integrator state i_k [N·m].
    """

    output_limit_nm: float
    kp: float = PAPER_KP
    ki_per_s: float = PAPER_KI_PER_S
    antiwindup_per_s: float = PAPER_ANTIWINDUP_PER_S
    period_s: float = PAPER_CONTROL_PERIOD_S
    feedforward_gain: float = REFERENCE_FEEDFORWARD
    measured: str = "tau_sensor"
    velocity_damping_nms_per_rad: float = 0.0
    log_units = {"tau_feedback": "N·m"}  # the measured torque of each tick, recorded by sim.run.run_loop

    def __post_init__(self) -> None:
        self.output_limit_nm = check_range("output_limit_nm", self.output_limit_nm, 0.0, low_open=True)
        self.kp = check_range("kp", self.kp, 0.0)
        self.ki_per_s = check_range("ki_per_s", self.ki_per_s, 0.0)
        self.antiwindup_per_s = check_range("antiwindup_per_s", self.antiwindup_per_s, 0.0)
        self.period_s = check_range("period_s", self.period_s, 0.0, low_open=True)
        self.feedforward_gain = check_range("feedforward_gain", self.feedforward_gain, 0.0)
        self.velocity_damping_nms_per_rad = check_range("velocity_damping_nms_per_rad",
                                                        self.velocity_damping_nms_per_rad, 0.0)
        if not isinstance(self.measured, str) or not self.measured:
            raise ValueError(f"measured = {self.measured!r}: expected an observation key, e.g. 'tau_sensor'")
        self.reset()

    def reset(self, integrator_nm: float = 0.0) -> None:
        """Set the integrator state i [N·m]."""
        self.integrator_nm = float(integrator_nm)
        self._measured_nm = math.nan

    def step(self, observation) -> float:
        """One tick of a control loop (:class:`sim.run.Controller`): the command [N·m] for the observation's
        ``tau_ref`` and measured torque (key :attr:`measured`), minus K_d·``qd_motor`` if K_d > 0."""
        self._measured_nm = observation[self.measured]
        command = self.update(observation["tau_ref"], self._measured_nm)
        if self.velocity_damping_nms_per_rad:
            command -= self.velocity_damping_nms_per_rad * observation["qd_motor"]
        return command

    def log_values(self) -> tuple[float]:
        """The measured torque [N·m] the last step closed on."""
        return (self._measured_nm,)

    def update(self, tau_ref_nm: float, tau_measured_nm: float) -> float:
        """The PI law of one tick: the torque command u_k [N·m] for reference and measured torque [N·m].

        Raises ValueError on a non-finite input (a NaN would stay in the integrator for good).
        """
        if not (math.isfinite(tau_ref_nm) and math.isfinite(tau_measured_nm)):
            raise ValueError(f"PITorqueController.update: tau_ref_nm = {tau_ref_nm!r}, tau_measured_nm = "
                             f"{tau_measured_nm!r}: both must be finite (a NaN or inf reading, e.g. from a "
                             f"disconnected sensor, would stay in the integrator)")
        error = tau_ref_nm - tau_measured_nm
        unsaturated = self.feedforward_gain * tau_ref_nm + self.kp * error + self.integrator_nm
        command = min(max(unsaturated, -self.output_limit_nm), self.output_limit_nm)
        self.integrator_nm += self.period_s * (self.ki_per_s * error
                                               + self.antiwindup_per_s * (command - unsaturated))
        return command


FEEDBACK_KEYS = {"current": "tau_current_estimate", "sensor": "tau_sensor"}  # feedback kind -> observation key


def paper_pi(params: TestbedParams, feedback: str) -> PITorqueController:
    """The paper's PI torque controller (gains of Sec. IV) closing on the ``feedback`` measurement, limited to
    the driver's current limit, at the plant's control period: the default controller of the torque tests."""
    return PITorqueController(output_limit_nm=CurrentToTorqueMap.from_params(params).command_limit_nm,
                              period_s=params.simulation.control_period_s, measured=FEEDBACK_KEYS[feedback])
