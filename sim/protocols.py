"""The paper's torque-control protocols (Sec. IV) as objects, defined once for the experiments and the environment.

:data:`PROTOCOLS` (name -> protocol), in the paper's order:

* :class:`Step` (Sec. IV-A, Table VI): the reference zero for :data:`PRE_STEP_S`, then 0.05, 0.1 or 0.2 N·m.
* :class:`Disturbance` (Sec. IV-A): regulation at 0.5 N·m while a hand twists the gear's output flange
  against the motor, its torque growing at a constant rate.
* :class:`Waveform` (Sec. IV-B, Table VII): the 0.05 N·m sine at 0.2 Hz, the 0.1 N·m square at 1 Hz and the
  10 N·m sine at 0.2 Hz, each from zero phase.
* :class:`Push` (Sec. IV-C, Fig. 13): a hand pushing the free lever slowly and fast.

Each gives what is applied at a time t [s] from the protocol's start: ``reference(t)`` [N·m] (the torque
reference; a Push has none), and ``hub_torque(t)`` (Disturbance) or ``torque_nm(t, angle, velocity)`` (Push)
for what the hand applies. ``experiments.step``, ``experiments.sinusoid``, ``experiments.admittance`` and
``experiments.open_loop_step`` run them on the testbed; ``envs.references`` draws the environment's paper
tasks from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PRE_STEP_S = 0.5  # [s] reference zero before the step


@dataclass(frozen=True)
class Step:
    """A torque step of ``size_nm`` [N·m] after ``pre_s`` [s] of zero reference."""

    size_nm: float
    pre_s: float = PRE_STEP_S

    @property
    def name(self) -> str:
        return f"step {self.size_nm:g} N·m"

    def reference(self, t_s: np.ndarray) -> np.ndarray:
        """The reference [N·m] at times ``t_s`` [s] from the protocol's start."""
        return np.where(np.asarray(t_s) >= self.pre_s, self.size_nm, 0.0)


@dataclass(frozen=True)
class Disturbance:
    """Regulation at ``regulated_nm`` while a hand's torque on the output flange (upstream of the flexure: the
    sensor and the load cell both see it, the driver's current does not) grows against the motor.

    The hand starts after ``pre_s`` and presses harder at ``rate_nm_per_s`` up to ``max_nm``. The rate is
    inferred, not given: a PI with reference feed-forward follows a ramp disturbance with the steady error
    rate/Ki, so the paper's sensor-feedback error of 0.0058 N·m (Table VI) implies about
    12 1/s x 0.0058 N·m = 0.07 N·m/s (2.5 N·m in ~36 s). Why the flange and not the lever: a torque on the
    lever goes straight into the load cell (16 700 N·m/rad against 760 N·m/rad through the flexure and the
    stuck gear), so no controller on the flexure's torque could keep the load cell at 0.5 N·m, which the
    paper's 0.0058 N·m sensor-feedback error shows it did.
    """

    regulated_nm: float = 0.5
    pre_s: float = 2.0  # [s] regulation before the hand pushes
    rate_nm_per_s: float = 0.07
    max_nm: float = 2.5  # [N·m] "past 2 N·m"
    name: str = "disturbance"

    @property
    def duration_s(self) -> float:
        """The whole test [s]: the regulation before the push and the ramp to the largest torque."""
        return self.pre_s + self.max_nm / self.rate_nm_per_s

    def reference(self, t_s: np.ndarray) -> np.ndarray:
        return np.full(np.shape(t_s), self.regulated_nm)

    def hub_torque(self, t_s: np.ndarray) -> np.ndarray:
        """The hand's torque on the output flange [N·m] at times ``t_s`` [s] (negative: against the motor)."""
        return -np.clip((np.asarray(t_s) - self.pre_s) * self.rate_nm_per_s, 0.0, self.max_nm)


@dataclass(frozen=True)
class Waveform:
    """A reference: 'sine' or 'square' of amplitude [N·m] and frequency [Hz], from zero phase."""

    name: str
    shape: str
    amplitude_nm: float
    frequency_hz: float

    def reference(self, t_s: np.ndarray) -> np.ndarray:
        s = np.sin(2.0 * np.pi * self.frequency_hz * t_s)
        return self.amplitude_nm * (s if self.shape == "sine" else np.where(s >= 0.0, 1.0, -1.0))


HAND_STIFFNESS_NM_PER_RAD = 5.0  # assumed: 500 N/m at the 0.1 m tip, a relaxed human grip
HAND_DAMPING_NMS_PER_RAD = 0.05  # assumed: 5 N·s/m at the tip
PUSH_ANGLE_RAD = 0.5  # [rad] the hand's travel (~29°)
REST_BEFORE_S = 0.3  # [s] hand still before the push
REST_AFTER_S = 1.5  # [s] hand still after the push


@dataclass(frozen=True)
class Push:
    """A hand moving along a minimum-jerk path of ``angle_rad`` in ``push_s``, coupled to the lever by a
    spring and damper (assumed: the paper gives no trajectory; a hand holding the lever is an impedance)::

        torque = k_h (θ_hand(t) - θ) + b_h (ω_hand(t) - ω)      [N·m] on the lever
    """

    name: str
    push_s: float
    angle_rad: float = PUSH_ANGLE_RAD
    stiffness_nm_per_rad: float = HAND_STIFFNESS_NM_PER_RAD
    damping_nms_per_rad: float = HAND_DAMPING_NMS_PER_RAD
    before_s: float = REST_BEFORE_S
    after_s: float = REST_AFTER_S

    @property
    def duration_s(self) -> float:
        return self.before_s + self.push_s + self.after_s

    def path(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hand angle [rad] and velocity [rad/s] at times ``t_s`` [s] (minimum jerk)."""
        s = np.clip((np.asarray(t_s) - self.before_s) / self.push_s, 0.0, 1.0)
        angle = self.angle_rad * (10 * s**3 - 15 * s**4 + 6 * s**5)
        velocity = self.angle_rad * (30 * s**2 - 60 * s**3 + 30 * s**4) / self.push_s
        return angle, velocity

    def torque_nm(self, t_s: float, angle_rad: float, velocity_rad_s: float) -> float:
        """The hand's torque on the lever [N·m] at time ``t_s`` [s] for the lever's angle and velocity."""
        hand_angle, hand_velocity = self.path(np.array([t_s]))
        return float(self.stiffness_nm_per_rad * (hand_angle[0] - angle_rad)
                     + self.damping_nms_per_rad * (hand_velocity[0] - velocity_rad_s))


PROTOCOLS = {p.name: p for p in (
    Step(0.05), Step(0.1), Step(0.2),
    Disturbance(),
    Waveform("0.05 N·m sine 0.2 Hz", "sine", 0.05, 0.2),
    Waveform("0.1 N·m square 1 Hz", "square", 0.1, 1.0),
    Waveform("10 N·m sine 0.2 Hz", "sine", 10.0, 0.2),
    Push("slow push", 4.0),
    Push("fast push", 0.4),
)}
STEPS = tuple(p for p in PROTOCOLS.values() if isinstance(p, Step))
STEPS_NM = tuple(p.size_nm for p in STEPS)  # [N·m] 0.05, 0.1, 0.2
DISTURBANCE: Disturbance = PROTOCOLS["disturbance"]
WAVEFORMS = tuple(p for p in PROTOCOLS.values() if isinstance(p, Waveform))
PUSHES = tuple(p for p in PROTOCOLS.values() if isinstance(p, Push))
