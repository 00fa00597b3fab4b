"""Admittance controller of the paper (Sec. IV-C, Eqs. 30-34): a virtual mass-damper(-spring) driven by the
external torque, tracked by a PD loop on the motor's angle and velocity.

Virtual dynamics (Eq. 30)::

    M_d θ_r'' + B_d θ_r' + K_d (θ_r - θ_0) = τ_ext

discretised at T_s (Eqs. 31-32, forward Euler; the angle update is not written in the paper and uses the same
rule)::

    a_r(k)     = (τ_ext(k) - B_d ω_r(k) - K_d (θ_r(k) - θ_0)) / M_d
    ω_r(k+1)   = ω_r(k) + T_s a_r(k)
    θ_r(k+1)   = θ_r(k) + T_s ω_r(k)

inner PD loop (Eqs. 33-34)::

    τ_cmd(k) = K_p (θ_r(k) - θ(k)) + K_v (ω_r(k) - ω(k))

Paper values: M_d = 0.03 kg·m², B_d = 0.6 N·m·s/rad, K_d = 0, T_s = 1 ms. The paper does not give K_p, K_v.

Choice of the PD gains (documented, not from the paper)
-------------------------------------------------------
The PD moves the geared motor, whose output-referred inertia is dominated by the reflected rotor,
J ≈ N²·J_rotor = 6.4e-3 kg·m² (+2e-4 for the output flange and the lever side), against a gear breakaway of
0.13 N·m. We take K_p = 30 N·m/rad, so that the breakaway torque leaves at most 0.13/30 = 4.3 mrad of angle
error, and K_v = 2·sqrt(K_p·J) ≈ 0.9 N·m·s/rad, critically damped: the inner loop's natural frequency
sqrt(K_p/J) ≈ 68 rad/s (11 Hz) is 3.4 times the virtual dynamics' corner B_d/M_d = 20 rad/s (3.2 Hz), and its
velocity-loop crossover K_v/J ≈ 140 rad/s loses only 13° of phase to the ~1.7 ms of sampling, command delay
and current lag.

Sign: the torque sensor measures the torque the flexure passes from the motor to the lever. A hand pushing
the lever positive with the motor holding makes that negative, so the external torque on the joint is
τ_ext = -τ_sensor (quasi-static; the lever side inertia, 1.9e-4 kg·m², is neglected, as the paper does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controllers.pi import PAPER_CONTROL_PERIOD_S, check_range
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams

# Paper Sec. IV-C: desired inertia, damping and stiffness of the virtual dynamics.
PAPER_DESIRED_INERTIA_KGM2 = 0.03
PAPER_DESIRED_DAMPING_NMS_PER_RAD = 0.6
PAPER_DESIRED_STIFFNESS_NM_PER_RAD = 0.0
# Chosen (see module docstring): inner PD on the motor's output-referred angle and velocity.
DEFAULT_ANGLE_GAIN_NM_PER_RAD = 30.0
DEFAULT_VELOCITY_GAIN_NMS_PER_RAD = 0.9
# The default motor's driver limit [N·m]: the command that delivers its 18 N·m peak torque (sim.motor_torque).
DEFAULT_OUTPUT_LIMIT_NM = CurrentToTorqueMap.from_params(TestbedParams()).command_limit_nm


@dataclass
class AdmittanceController:
    """Discrete admittance controller (paper Eqs. 30-34) with an inner PD loop.

    Parameters
    ----------
    desired_inertia_kgm2 : float
        M_d [kg·m²] (> 0).
    desired_damping_nms_per_rad : float
        B_d [N·m·s/rad].
    desired_stiffness_nm_per_rad : float
        K_d [N·m/rad].
    angle_gain_nm_per_rad : float
        K_p of the inner loop [N·m/rad].
    velocity_gain_nms_per_rad : float
        K_v of the inner loop [N·m·s/rad].
    period_s : float
        T_s [s].
    output_limit_nm : float
        Largest command magnitude [N·m]; default the default motor's driver limit, 26.3 N·m
        (``CurrentToTorqueMap.command_limit_nm``: the command that delivers the 18 N·m peak torque).
    rest_angle_rad : float
        θ_0, the virtual spring's rest angle and the initial reference [rad].
    measured : str
        The observation key of the measured torque: τ_ext = -observation[measured] (the torque sensor).

    Attributes
    ----------
    reference_angle_rad, reference_velocity_rad_s : float
        The virtual dynamics' state θ_r(k) [rad], ω_r(k) [rad/s].
    """

    desired_inertia_kgm2: float = PAPER_DESIRED_INERTIA_KGM2
    desired_damping_nms_per_rad: float = PAPER_DESIRED_DAMPING_NMS_PER_RAD
    desired_stiffness_nm_per_rad: float = PAPER_DESIRED_STIFFNESS_NM_PER_RAD
    angle_gain_nm_per_rad: float = DEFAULT_ANGLE_GAIN_NM_PER_RAD
    velocity_gain_nms_per_rad: float = DEFAULT_VELOCITY_GAIN_NMS_PER_RAD
    period_s: float = PAPER_CONTROL_PERIOD_S
    output_limit_nm: float = DEFAULT_OUTPUT_LIMIT_NM
    rest_angle_rad: float = 0.0
    measured: str = "tau_sensor"
    # recorded by sim.run.run_loop every tick: the measured torque and the virtual state at the tick's start
    log_units = {"tau_feedback": "N·m", "theta_ref": "rad", "omega_ref": "rad/s"}

    def __post_init__(self) -> None:
        self.desired_inertia_kgm2 = check_range("desired_inertia_kgm2", self.desired_inertia_kgm2, 0.0,
                                                low_open=True)
        self.desired_damping_nms_per_rad = check_range("desired_damping_nms_per_rad",
                                                       self.desired_damping_nms_per_rad, 0.0)
        self.desired_stiffness_nm_per_rad = check_range("desired_stiffness_nm_per_rad",
                                                        self.desired_stiffness_nm_per_rad, 0.0)
        self.angle_gain_nm_per_rad = check_range("angle_gain_nm_per_rad", self.angle_gain_nm_per_rad, 0.0)
        self.velocity_gain_nms_per_rad = check_range("velocity_gain_nms_per_rad",
                                                     self.velocity_gain_nms_per_rad, 0.0)
        self.period_s = check_range("period_s", self.period_s, 0.0, low_open=True)
        self.output_limit_nm = check_range("output_limit_nm", self.output_limit_nm, 0.0, low_open=True)
        self.rest_angle_rad = check_range("rest_angle_rad", self.rest_angle_rad, -1e6, 1e6)
        # Forward Euler of the virtual dynamics, x+ = [[1, T], [-T·K/M, 1 - T·B/M]] x, is stable (Jury) for
        # T·B/M < 2 and T·K < B; K = 0 leaves the marginal pole at 1 of a free mass.
        leak = self.period_s * self.desired_damping_nms_per_rad / self.desired_inertia_kgm2
        if leak >= 2.0:
            raise ValueError(f"desired_damping_nms_per_rad = {self.desired_damping_nms_per_rad}: T_s·B_d/M_d = "
                             f"{leak:.3g} must be < 2 for the discrete virtual dynamics to be stable (valid range "
                             f"[0, {2.0 * self.desired_inertia_kgm2 / self.period_s:g}) N·m·s/rad)")
        stiffness_limit = self.desired_damping_nms_per_rad / self.period_s
        if self.desired_stiffness_nm_per_rad > 0.0 and self.desired_stiffness_nm_per_rad >= stiffness_limit:
            valid = (f"valid range [0, {stiffness_limit:g}) N·m/rad at B_d = {self.desired_damping_nms_per_rad:g} "
                     f"N·m·s/rad" if stiffness_limit > 0.0 else "it must be 0 when desired_damping_nms_per_rad = 0")
            raise ValueError(f"desired_stiffness_nm_per_rad = {self.desired_stiffness_nm_per_rad}: T_s·K_d must be "
                             f"< B_d for the discrete virtual dynamics to be stable ({valid})")
        self.reset()

    def reset(self, angle_rad: float | None = None) -> None:
        """Start the virtual dynamics at rest at ``angle_rad`` (θ_0 if None) [rad]."""
        self.reference_angle_rad = self.rest_angle_rad if angle_rad is None else float(angle_rad)
        self.reference_velocity_rad_s = 0.0
        self._logged = (math.nan, self.reference_angle_rad, 0.0)

    def step(self, observation) -> float:
        """One tick of a control loop (:class:`sim.run.Controller`): :meth:`update` with τ_ext = minus the
        measured torque and the motor's angle ``q_motor`` and velocity ``qd_motor`` (output side)."""
        measured = observation[self.measured]
        self._logged = (measured, self.reference_angle_rad, self.reference_velocity_rad_s)
        return self.update(-measured, observation["q_motor"], observation["qd_motor"])

    def log_values(self) -> tuple[float, float, float]:
        """The measured torque [N·m], θ_r [rad] and ω_r [rad/s] at the start of the last step."""
        return self._logged

    def update(self, tau_ext_nm: float, angle_rad: float, velocity_rad_s: float) -> float:
        """One tick (Eqs. 31-34): the torque command [N·m] from the external torque [N·m] and the measured
        angle [rad] and velocity [rad/s]; advances the virtual dynamics to the next tick."""
        theta_r, omega_r = self.reference_angle_rad, self.reference_velocity_rad_s
        command = (self.angle_gain_nm_per_rad * (theta_r - angle_rad)
                   + self.velocity_gain_nms_per_rad * (omega_r - velocity_rad_s))
        command = min(max(command, -self.output_limit_nm), self.output_limit_nm)
        accel = (tau_ext_nm - self.desired_damping_nms_per_rad * omega_r
                 - self.desired_stiffness_nm_per_rad * (theta_r - self.rest_angle_rad)) / self.desired_inertia_kgm2
        self.reference_velocity_rad_s = omega_r + self.period_s * accel
        self.reference_angle_rad = theta_r + self.period_s * omega_r
        return command
