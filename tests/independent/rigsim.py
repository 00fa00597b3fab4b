"""Independent simulator of a rigid one-degree-of-freedom joint (hinge or slide) under a 1 kHz digital controller.

Written from the formulas below, without the project's physics (``sim.discrepancy``, ``sim.plant``, ``models``,
``controllers``), so that a wrong formula in the analysis cannot hide behind shared code. Units: hinge rad, N·m,
kg·m², rad/s; slide m, N, kg, m/s (written [N·m | N], ...). The formulas are the contract.

Equation of motion of the driven mass m (position q, velocity v; its q is the one measured)::

    m·a = u_d(t) − F_f + F_x(q, t) + F_k

Delivered effort ``u_d``: the controller's command u_k is held for its period (zero-order hold), then::

    u_c = clip(u, −peak_effort, peak_effort)
    u_r = u_c·(1 − c·min(|u_c|/peak_effort, 1)²)        torque_constant_nonlinearity, c = torque_rolloff [1]
    u_d(t) = g·u_r(t − d)                               effort_gain g [1], transport_delay d [s]

Each physics step of h = dt/substeps carries the exact mean of the delayed hold over the step (a delayed step of
the command arrives d later, to within the step's averaging).

Friction, Karnopp stick-slip. Levels (asymmetric_friction Δ = F_c+ − F_c− [N·m | N]; position and warm-up factor
λ = (1 + β·sin(2π·q/P_long))·(1 + γ·exp(−t/T_w)), 1 unless those outside-library effects are on)::

    F_c± = λ·F_c ± Δ/2,   F_s± = λ·F_s ± Δ/2              (F_s ≥ F_c; F_s = F_c without Stribeck)

- stuck, |v| < v_stick: F_a = u_d + F_x + F_k − ½·m'(q)·v² is the applied non-friction force. If
  −F_s− ≤ F_a ≤ F_s+ the joint stays (v := 0, friction = F_a); else it breaks away with friction F_s+ (F_a > 0)
  or −F_s− (F_a < 0);
- sliding, s = sign(v): ``F_f = s·(F_c,s + (F_s,s − F_c,s)·exp(−(|v|/v_s)^δ)) + σ2·v + c_q·v·|v|``
  (coulomb_friction F_c, stribeck_friction F_s and v_s [rad/s | m/s], δ = 2, viscous_friction σ2
  [N·m·s/rad | N·s/m], quadratic_drag c_q [N·m·s²/rad² | N·s²/m²]);
- a sliding velocity that would change sign within a step stops at zero: q advances by v·τ/2 to the crossing
  τ = −v/a, and the next step decides stick or breakaway.

Other forces ``F_x``::

    gravity               hinge −A·sin(q − q0) (A = m·g·r [N·m], q0 [rad]); slide −A (A = m·g·sin(incline) [N])
    position_spring       −k_s·(q − q_rest)                      k_s [N·m/rad | N/m], q_rest [rad | m]
    cogging               +A_c·sin(2π·q/P + φ)                   A_c [N·m | N], P [rad | m], φ [rad]
    periodic_disturbance  +A_d·sin(2π·f·t + φ_d)                 A_d [N·m | N], f [Hz], φ_d [rad]; t from the start

drivetrain_compliance (two masses): the driven mass m1 = (1 − φ)·m carries u_d, friction, F_x and the measured
q; the compliant mass m2 = φ·m (position x2) is coupled by a spring k and damper c::

    f_r = (1/2π)·sqrt(k·(1/m1 + 1/m2)) [Hz],  μ = m1·m2/(m1 + m2),  ζ = c/(2·sqrt(k·μ))
    F_k = k·(x2 − q) + c·(v2 − v) on m1,  −F_k on m2 (m2·a2 = −F_k)

Outside the analysis library:

- ``backlash`` (width w [rad | m]) in the two-mass coupling, δ = x2 − q: F_k = max(k·(δ − w/2) + c·(v2 − v), 0)
  for δ > w/2, min(k·(δ + w/2) + c·(v2 − v), 0) for δ < −w/2, 0 inside the gap (contact cannot pull);
- ``position_dependent_inertia``: m(q) = m0·(1 + α·sin q) (hinge) or m0·(1 + α·q/L) (slide, L [m]); from the
  Lagrangian, m(q)·a = (forces) − ½·m'(q)·v²;
- ``friction_varying_with_position``: λ above with β [1], P_long [rad | m];
- ``friction_warmup``: λ above with γ [1] (friction γ higher at the start, decaying as the grease warms), T_w [s].

Sensor: measured position y = s_q·round((q + n)/s_q), n white (std ``noise_std``), s_q the encoder step (hinge
2π/2^17 rad, slide 1 µm by default). The command is logged as computed.

Timing: the controller runs every dt = 1 ms from the measured position; physics runs at h = dt/20 (20 kHz),
semi-implicit Euler with the stick and zero-crossing events above. Row k of a log (``time_convention="hold_end"``,
the project's own convention: ``sim.run`` steps the plant, then stamps ``plant.time_s`` and reads the state)::

    time = (k + 1)·dt,  tau_cmd = u_k (computed from y(k·dt), held over (k·dt, (k+1)·dt]),  q = y((k + 1)·dt)

``time_convention="command"`` logs what a controller records at its own instant: time = k·dt, tau_cmd = u_k,
q = y(k·dt) (the sample u_k was computed from): the command's stamp is dt earlier relative to the positions.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

CONTROL_PERIOD_S = 1e-3  # dt: controller and log period [s]
SUBSTEPS = 20  # physics steps per control period: 20 kHz
HINGE_ENCODER_STEP_RAD = 2 * math.pi / 2**17  # 17-bit absolute encoder, counts per turn
SLIDE_ENCODER_STEP_M = 1e-6  # 1 µm linear scale
STICK_FRACTION = 1e-4  # v_stick as a fraction of a typical velocity [1]
TIME_CONVENTIONS = ("hold_end", "command")


@dataclass(frozen=True)
class Plant:
    """The true joint: every effect's parameter, neutral by default. Units [hinge | slide].

    Attributes
    ----------
    joint : {'hinge', 'slide'}
    mass : float
        m, the total moving inertia [kg·m² | kg].
    coulomb, breakaway : float
        F_c, F_s (None: F_s = F_c) [N·m | N].
    stribeck_velocity : float
        v_s [rad/s | m/s]; used only when F_s > F_c.
    viscous : float
        σ2 [N·m·s/rad | N·s/m].
    asymmetry : float
        Δ = F_c+ − F_c− [N·m | N].
    drag_coefficient : float
        c_q of c_q·v·|v| [N·m·s²/rad² | N·s²/m²].
    effort_gain : float
        g, delivered effort per unit command [1].
    peak_effort : float
        Clip and roll-off reference [N·m | N] (inf: none).
    torque_rolloff : float
        c, fraction of the command lost at peak effort [1].
    delay : float
        d, command dead time [s].
    gravity_amplitude, gravity_angle : float
        A [N·m | N], q0 [rad] (hinge only).
    spring_stiffness, spring_rest_position : float
        k_s [N·m/rad | N/m], q_rest [rad | m].
    cogging_amplitude, cogging_period, cogging_phase : float
        A_c [N·m | N], P [rad | m], φ [rad].
    disturbance_amplitude, disturbance_frequency, disturbance_phase : float
        A_d [N·m | N], f [Hz], φ_d [rad].
    compliant_fraction, resonance_frequency, damping_ratio : float
        φ [1] (0: rigid), f_r [Hz], ζ [1] of the two-mass drivetrain.
    backlash_width : float
        w [rad | m] in the two-mass coupling (needs compliant_fraction > 0).
    inertia_variation, inertia_length : float
        α [1], L [m] (slide) of the position-dependent inertia.
    friction_variation, friction_period : float
        β [1], P_long [rad | m] of the position-varying friction level.
    friction_warmup, warmup_time : float
        γ [1], T_w [s] of the friction level decaying after the start.
    stick_velocity : float
        v_stick, the stuck band [rad/s | m/s].
    """

    joint: str
    mass: float
    coulomb: float = 0.0
    breakaway: float | None = None
    stribeck_velocity: float = 0.05
    viscous: float = 0.0
    asymmetry: float = 0.0
    drag_coefficient: float = 0.0
    effort_gain: float = 1.0
    peak_effort: float = math.inf
    torque_rolloff: float = 0.0
    delay: float = 0.0
    gravity_amplitude: float = 0.0
    gravity_angle: float = 0.0
    spring_stiffness: float = 0.0
    spring_rest_position: float = 0.0
    cogging_amplitude: float = 0.0
    cogging_period: float = 1.0
    cogging_phase: float = 0.0
    disturbance_amplitude: float = 0.0
    disturbance_frequency: float = 1.0
    disturbance_phase: float = 0.0
    compliant_fraction: float = 0.0
    resonance_frequency: float = 10.0
    damping_ratio: float = 0.05
    backlash_width: float = 0.0
    inertia_variation: float = 0.0
    inertia_length: float = 1.0
    friction_variation: float = 0.0
    friction_period: float = 1.0
    friction_warmup: float = 0.0
    warmup_time: float = 10.0
    stick_velocity: float = 1e-4

    def __post_init__(self) -> None:
        if self.joint not in ("hinge", "slide"):
            raise ValueError(f"joint = {self.joint!r}; expected 'hinge' or 'slide'")
        if self.mass <= 0:
            raise ValueError(f"mass = {self.mass}: must be > 0")
        if self.static_level < self.coulomb:
            raise ValueError(f"breakaway = {self.breakaway} below coulomb = {self.coulomb}")
        if not 0.0 <= self.compliant_fraction < 1.0:
            raise ValueError(f"compliant_fraction = {self.compliant_fraction}: must be in [0, 1)")
        if self.backlash_width and not self.compliant_fraction:
            raise ValueError("backlash sits in the two-mass coupling: set compliant_fraction > 0")
        if self.inertia_variation and self.compliant_fraction:
            raise ValueError("position_dependent_inertia is for the rigid (one-mass) joint only")
        if abs(self.inertia_variation) >= 1.0:
            raise ValueError(f"inertia_variation = {self.inertia_variation}: |α| < 1 keeps the inertia positive")
        if self.delay < 0 or self.stick_velocity <= 0:
            raise ValueError("delay must be >= 0 and stick_velocity > 0")

    @property
    def static_level(self) -> float:
        """F_s [N·m | N]."""
        return self.coulomb if self.breakaway is None else self.breakaway

    def two_mass(self) -> tuple[float, float, float, float]:
        """(m1, m2, k, c) of the two-mass drivetrain [kg | kg·m², N/m | N·m/rad, N·s/m | N·m·s/rad]."""
        m1 = (1.0 - self.compliant_fraction) * self.mass
        m2 = self.compliant_fraction * self.mass
        mu = m1 * m2 / (m1 + m2)
        k = mu * (2 * math.pi * self.resonance_frequency) ** 2
        return m1, m2, k, 2.0 * self.damping_ratio * math.sqrt(k * mu)

    def with_(self, **changes: float) -> Plant:
        """A copy with ``changes``."""
        return replace(self, **changes)


def delivered_effort(plant: Plant, u: float) -> float:
    """u_d for a command u (no delay): g·u_c·(1 − c·min(|u_c|/peak, 1)²), u_c clipped at ±peak [N·m | N]."""
    peak = plant.peak_effort
    uc = min(max(u, -peak), peak)
    if plant.torque_rolloff:
        uc *= 1.0 - plant.torque_rolloff * min(abs(uc) / peak, 1.0) ** 2
    return plant.effort_gain * uc


def delay_pattern(delay: float, dt: float = CONTROL_PERIOD_S, substeps: int = SUBSTEPS
                  ) -> list[tuple[int, float]]:
    """Per physics step of a tick: (offset of the command in effect at the step's start, relative to the tick's
    own command; weight of the next command over the step) for a dead time ``delay`` [s].

    In step s of tick k the delayed hold is command ``k + o`` from the step's start, and command ``k + o + 1``
    over the last ``w`` of the step.
    """
    d = delay / (dt / substeps)  # in physics steps
    pattern = []
    for s in range(substeps):
        offset = math.floor((s - d) / substeps + 1e-12)
        jump = (offset + 1) * substeps + d  # step index (relative to the tick) where the next command arrives
        weight = min(max(s + 1 - jump, 0.0), 1.0)
        pattern.append((offset, weight))
    return pattern


# ------------------------------------------------------------------------------------------------- references


@dataclass(frozen=True)
class Reference:
    """A position reference sampled at the control instants t_k = k·dt: r [rad | m], its rate [rad/s | m/s]."""

    position: np.ndarray
    velocity: np.ndarray
    name: str = ""


def _ramp(t: np.ndarray, rise_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Smoothstep fade-in w(t) from 0 to 1 over ``rise_s`` and its derivative [1/s]."""
    x = np.clip(t / rise_s, 0.0, 1.0)
    return x * x * (3 - 2 * x), np.where((t > 0) & (t < rise_s), 6 * x * (1 - x) / rise_s, 0.0)


def multisine(n: int, span: float, seed: int, *, frequencies: tuple[float, ...] = (0.2, 0.37, 0.7, 1.3, 2.4),
              rise_s: float = 2.0, dt: float = CONTROL_PERIOD_S) -> Reference:
    """Sum of sines with random phases: tone i has amplitude span·f_0/f_i (equal velocity amplitudes
    2π·f_0·span), faded in over ``rise_s``, starting at r = 0 [rad | m]."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    phases = rng.uniform(-math.pi, math.pi, len(frequencies))
    s = np.zeros(n)
    sd = np.zeros(n)
    for f, ph in zip(frequencies, phases, strict=True):
        a = span * frequencies[0] / f
        s += a * (np.sin(2 * math.pi * f * t + ph) - math.sin(ph))
        sd += a * 2 * math.pi * f * np.cos(2 * math.pi * f * t + ph)
    w, wd = _ramp(t, rise_s)
    return Reference(w * s, wd * s + w * sd, "multisine")


def chirp(n: int, speed: float, *, f0: float = 0.1, f1: float = 5.0, rise_s: float = 2.0,
          dt: float = CONTROL_PERIOD_S) -> Reference:
    """Exponential sine sweep f0 → f1 [Hz] over the run at constant velocity amplitude ``speed`` [rad/s | m/s]
    (position amplitude speed/(2π·f(t)))."""
    t = np.arange(n) * dt
    duration = n * dt
    rate = math.log(f1 / f0) / duration
    freq = f0 * np.exp(rate * t)
    phase = 2 * math.pi * f0 * (np.exp(rate * t) - 1.0) / rate
    w, _ = _ramp(t, rise_s)
    r = w * speed / (2 * math.pi * freq) * np.sin(phase)
    return Reference(r, np.gradient(r, dt), "chirp")


def point_to_point(n: int, span: float, speed: float, seed: int, *, dwell_s: tuple[float, float] = (0.3, 1.0),
                   speed_range: tuple[float, float] = (0.3, 1.0), low: float | None = None,
                   dt: float = CONTROL_PERIOD_S) -> Reference:
    """Minimum-jerk moves between random targets in [low, low + 2·span] (low = −span by default), each at a
    peak speed drawn in ``speed_range``·``speed``, separated by dwells drawn in ``dwell_s`` [s]: a breakaway at
    each start."""
    rng = np.random.default_rng(seed)
    low = -span if low is None else low
    t = np.arange(n) * dt
    r = np.zeros(n)
    rd = np.zeros(n)
    pos, now = 0.0 if low <= 0.0 <= low + 2 * span else low, 0.0
    r[:] = pos
    now += rng.uniform(*dwell_s)
    while now < t[-1]:
        target = rng.uniform(low, low + 2 * span)
        if abs(target - pos) < 0.1 * span:
            continue
        peak = speed * rng.uniform(*speed_range)
        move = 1.875 * abs(target - pos) / peak  # min-jerk peak speed = 1.875·Δ/T
        inside = (t >= now) & (t < now + move)
        x = (t[inside] - now) / move
        r[inside] = pos + (target - pos) * (10 * x**3 - 15 * x**4 + 6 * x**5)
        rd[inside] = (target - pos) / move * (30 * x**2 - 60 * x**3 + 30 * x**4)
        r[t >= now + move] = target
        rd[t >= now + move] = 0.0
        pos, now = target, now + move + rng.uniform(*dwell_s)
    return Reference(r, rd, "point_to_point")


def back_and_forth(n: int, span: float, speed: float, acceleration: float, *, dwell_s: float = 0.5,
                   dt: float = CONTROL_PERIOD_S) -> Reference:
    """Sweeps between −span and +span at a constant ``speed`` [rad/s | m/s], each with a trapezoidal velocity
    profile (``acceleration`` [rad/s² | m/s²] at both ends; a triangle where the cruise would be shorter than
    nothing), separated by dwells of ``dwell_s``: a friction-identification run at one speed. It starts at rest
    at r = 0 and sweeps to +span first."""
    t = np.arange(n) * dt
    r = np.zeros(n)
    rd = np.zeros(n)
    pos, now, target = 0.0, dwell_s, span
    while now < t[-1]:
        distance = abs(target - pos)
        peak = min(speed, math.sqrt(distance * acceleration))  # the triangle's peak when the cruise vanishes
        ramp = peak / acceleration
        move = 2 * ramp + (distance - peak * ramp) / peak
        inside = (t >= now) & (t < now + move)
        tau = t[inside] - now
        up, down = np.minimum(tau, ramp), np.clip(tau - (move - ramp), 0.0, ramp)
        travelled = (0.5 * acceleration * up**2 + peak * np.clip(tau - ramp, 0.0, move - 2 * ramp)
                     + peak * down - 0.5 * acceleration * down**2)
        direction = math.copysign(1.0, target - pos)
        r[inside] = pos + direction * travelled
        rd[inside] = direction * np.minimum(np.minimum(acceleration * tau, peak), acceleration * (move - tau))
        r[t >= now + move] = target
        rd[t >= now + move] = 0.0
        pos, now, target = target, now + move + dwell_s, -target
    return Reference(r, rd, "back_and_forth")


# ------------------------------------------------------------------------------------------------ controllers


class OpenLoop:
    """A fixed command sequence u_k [N·m | N], one per control period."""

    def __init__(self, commands: np.ndarray) -> None:
        self.commands = [float(u) for u in commands]

    def __call__(self, k: int, y: float) -> float:
        return self.commands[k]


class PID:
    """Position PID at the control rate on the measured position y, with velocity feedforward of the reference.

    u = kp·e + ki·I + kd·(ṙ − v̂), e = r − y; v̂ is the backward difference of y low-passed (first order) at
    ``derivative_cutoff_hz``; u clipped at ±``limit``; the integral I stops while the output is saturated in
    the direction of e (conditional integration: anti-windup).
    """

    def __init__(self, reference: Reference, kp: float, ki: float, kd: float, limit: float, *,
                 derivative_cutoff_hz: float = 150.0, dt: float = CONTROL_PERIOD_S) -> None:
        self.r = reference.position.tolist()
        self.rd = reference.velocity.tolist()
        self.kp, self.ki, self.kd, self.limit, self.dt = kp, ki, kd, limit, dt
        self.alpha = math.exp(-2 * math.pi * derivative_cutoff_hz * dt)
        self.integral = 0.0
        self.v_hat = 0.0
        self.y_prev: float | None = None

    @classmethod
    def tuned(cls, reference: Reference, mass: float, bandwidth_hz: float, limit: float, **kwargs) -> PID:
        """Gains placing the closed loop of a free mass at (s + ω)³, ω = 2π·bandwidth: kd = 3mω, kp = 3mω²,
        ki = mω³."""
        w = 2 * math.pi * bandwidth_hz
        return cls(reference, 3 * mass * w * w, mass * w**3, 3 * mass * w, limit, **kwargs)

    def __call__(self, k: int, y: float) -> float:
        if self.y_prev is not None:
            self.v_hat = self.alpha * self.v_hat + (1 - self.alpha) * (y - self.y_prev) / self.dt
        self.y_prev = y
        e = self.r[k] - y
        raw = self.kp * e + self.ki * self.integral + self.kd * (self.rd[k] - self.v_hat)
        u = min(max(raw, -self.limit), self.limit)
        if u == raw or (e > 0) != (raw > 0):
            self.integral += e * self.dt
        return u


class CascadePPI:
    """Cascaded P position / PI velocity loop (the EMPS drive's structure): v_ref = kp·(r − y),
    volt = kv·(v_ref − v̂) + ki·∫(v_ref − v̂) clipped at ±``volt_limit`` [V], effort = gain·volt [N].

    v̂ as in :class:`PID`; the integral stops while the voltage is saturated in the direction of the error.
    """

    def __init__(self, reference: Reference, kp: float, kv: float, ki: float, gain: float, volt_limit: float, *,
                 derivative_cutoff_hz: float = 150.0, dt: float = CONTROL_PERIOD_S) -> None:
        self.r = reference.position.tolist()
        self.kp, self.kv, self.ki, self.gain, self.volt_limit, self.dt = kp, kv, ki, gain, volt_limit, dt
        self.alpha = math.exp(-2 * math.pi * derivative_cutoff_hz * dt)
        self.integral = 0.0
        self.v_hat = 0.0
        self.y_prev: float | None = None

    def __call__(self, k: int, y: float) -> float:
        if self.y_prev is not None:
            self.v_hat = self.alpha * self.v_hat + (1 - self.alpha) * (y - self.y_prev) / self.dt
        self.y_prev = y
        ev = self.kp * (self.r[k] - y) - self.v_hat
        raw = self.kv * ev + self.ki * self.integral
        volt = min(max(raw, -self.volt_limit), self.volt_limit)
        if volt == raw or (ev > 0) != (raw > 0):
            self.integral += ev * self.dt
        return self.gain * volt


class QuantisedCommand:
    """A controller's command as a drive register holds it: u = s·round(clip(c, −L, L)/s), c the wrapped
    controller's command, s the register's step (a PWM duty in 1/885 of full scale: s = 1/885), L ``limit``.

    ``counts(u)`` is the register's integer round(u/s).
    """

    def __init__(self, controller: Callable[[int, float], float], step: float, limit: float) -> None:
        self.controller, self.step, self.limit = controller, step, limit

    def counts(self, u: float) -> int:
        """The register's integer for a command u [1]."""
        return int(round(min(max(u, -self.limit), self.limit) / self.step))

    def __call__(self, k: int, y: float) -> float:
        return self.counts(self.controller(k, y)) * self.step


class Impedance:
    """Impedance (virtual spring-damper) control to a moving setpoint r: u = K·(r − y) + D·(ṙ − v̂), clipped at
    ±``limit``; v̂ as in :class:`PID`. K [N·m/rad | N/m], D [N·m·s/rad | N·s/m]."""

    def __init__(self, reference: Reference, stiffness: float, damping: float, limit: float, *,
                 derivative_cutoff_hz: float = 150.0, dt: float = CONTROL_PERIOD_S) -> None:
        self.r = reference.position.tolist()
        self.rd = reference.velocity.tolist()
        self.k, self.d, self.limit, self.dt = stiffness, damping, limit, dt
        self.alpha = math.exp(-2 * math.pi * derivative_cutoff_hz * dt)
        self.v_hat = 0.0
        self.y_prev: float | None = None

    def __call__(self, k: int, y: float) -> float:
        if self.y_prev is not None:
            self.v_hat = self.alpha * self.v_hat + (1 - self.alpha) * (y - self.y_prev) / self.dt
        self.y_prev = y
        u = self.k * (self.r[k] - y) + self.d * (self.rd[k] - self.v_hat)
        return min(max(u, -self.limit), self.limit)


class EnergyPump:
    """Energy pumping on a pendulum (hinge, gravity A·sin(q − q0) about its rest angle q0): the swing's energy
    E = ½·J·v̂² + A·(1 − cos(y − q0)) [J] is driven to a target E*(t_k) by u = clip(k_E·(E* − E), −L, L)·s,
    s = sign(v̂) (+1 while v̂ = 0, so that a pendulum at rest is kicked); v̂ as in :class:`PID`.

    ``energy_target`` holds E*(t_k) [J] per control period; J [kg·m²], A [N·m] and q0 [rad] are what the
    controller assumes, k_E ``gain`` [N·m/J], L ``limit`` [N·m].
    """

    def __init__(self, energy_target: np.ndarray, inertia: float, amplitude: float, rest_angle: float,
                 gain: float, limit: float, *, derivative_cutoff_hz: float = 150.0,
                 dt: float = CONTROL_PERIOD_S) -> None:
        self.target = [float(e) for e in energy_target]
        self.inertia, self.amplitude, self.rest = inertia, amplitude, rest_angle
        self.gain, self.limit, self.dt = gain, limit, dt
        self.alpha = math.exp(-2 * math.pi * derivative_cutoff_hz * dt)
        self.v_hat = 0.0
        self.y_prev: float | None = None

    def energy(self, y: float, v: float) -> float:
        """E = ½·J·v² + A·(1 − cos(y − q0)) [J]."""
        return 0.5 * self.inertia * v * v + self.amplitude * (1.0 - math.cos(y - self.rest))

    def __call__(self, k: int, y: float) -> float:
        if self.y_prev is not None:
            self.v_hat = self.alpha * self.v_hat + (1 - self.alpha) * (y - self.y_prev) / self.dt
        self.y_prev = y
        u = min(max(self.gain * (self.target[k] - self.energy(y, self.v_hat)), -self.limit), self.limit)
        return -u if self.v_hat < 0 else u


# ------------------------------------------------------------------------------------------------- simulation


@dataclass(frozen=True)
class Run:
    """A simulated run at the control rate (n rows; see the module docstring for the time convention).

    Attributes
    ----------
    time : ndarray
        Row times [s].
    tau_cmd : ndarray
        Commands as computed [N·m | N].
    q : ndarray
        Measured (quantised, noisy) position [rad | m].
    q_true, v_true : ndarray
        True position and velocity of the driven mass at the measurement instants [rad | m, rad/s | m/s].
    joint : str
    meta : dict
    """

    time: np.ndarray
    tau_cmd: np.ndarray
    q: np.ndarray
    q_true: np.ndarray
    v_true: np.ndarray
    joint: str
    meta: dict = field(default_factory=dict)

    def to_log(self):
        """The run as a project run log (``RunLog``, or ``SlideRunLog`` for a slide): time, tau_cmd, q."""
        from sim.logio import SlideRunLog, joint_units
        from sim.runlog import RunLog

        units = joint_units(self.joint)
        columns = {"time": self.time.copy(), "tau_cmd": self.tau_cmd.copy(), "q": self.q.copy()}
        cls = SlideRunLog if self.joint == "slide" else RunLog
        return cls(columns, {name: units[name] for name in columns}, dict(self.meta))


def quantise(x: np.ndarray, step: float | None) -> np.ndarray:
    """x rounded to the nearest multiple of ``step`` (None: unchanged)."""
    return x.copy() if not step else np.round(x / step) * step


def default_encoder_step(joint: str) -> float:
    """The default encoder step: 2π/2^17 rad (hinge), 1 µm (slide)."""
    return HINGE_ENCODER_STEP_RAD if joint == "hinge" else SLIDE_ENCODER_STEP_M


def simulate(plant: Plant, controller: Callable[[int, float], float], n: int, *, seed: int = 0,
             encoder_step: float | None | str = "default", noise_std: float = 0.0, q0: float = 0.0,
             v0: float = 0.0, time_convention: str = "hold_end", dt: float = CONTROL_PERIOD_S,
             substeps: int = SUBSTEPS) -> Run:
    """Run ``plant`` under ``controller`` for ``n`` control periods.

    Parameters
    ----------
    plant : Plant
    controller : callable (k, y) -> u
        Called at t_k = k·dt with the measured position y(t_k) [rad | m]; returns the command u_k [N·m | N].
    n : int
        Rows of the log.
    seed : int
        Seed of the sensor noise (``numpy.random.default_rng``).
    encoder_step : float, None or 'default'
        Quantisation step of the measured position [rad | m]; None: none; 'default': 2π/2^17 rad or 1 µm.
    noise_std : float
        White noise added to the position before quantisation [rad | m].
    q0, v0 : float
        Initial position [rad | m] and velocity [rad/s | m/s] (the compliant mass starts with the same).
    time_convention : {'hold_end', 'command'}
    dt : float
        Control period [s].
    substeps : int
        Physics steps per control period.
    """
    if time_convention not in TIME_CONVENTIONS:
        raise ValueError(f"time_convention = {time_convention!r}; expected one of {TIME_CONVENTIONS}")
    step = default_encoder_step(plant.joint) if encoder_step == "default" else encoder_step
    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, noise_std, n + 1) if noise_std else np.zeros(n + 1)
    q_true, v_true, tau = _integrate(plant, controller, n, step, noise.tolist(), q0, v0, dt, substeps)
    measured = quantise(q_true + noise, step)
    if time_convention == "hold_end":
        time, q_rows = np.arange(1, n + 1) * dt, slice(1, n + 1)
    else:
        time, q_rows = np.arange(n) * dt, slice(0, n)
    meta = {"source": "tests.independent.rigsim", "seed": seed, "time_convention": time_convention,
            "encoder_step": step, "noise_std": noise_std}
    return Run(time, tau, measured[q_rows], q_true[q_rows], v_true[q_rows], plant.joint, meta)


def _integrate(plant: Plant, controller: Callable[[int, float], float], n: int, step: float | None,
               noise: list[float], q: float, v: float, dt: float, substeps: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The physics loop: true position and velocity at t_k = k·dt (k = 0..n) and the n commands."""
    h = dt / substeps
    hinge = plant.joint == "hinge"
    # friction
    fc, fs = plant.coulomb, plant.static_level
    half_asym = 0.5 * plant.asymmetry
    stribeck = fs > fc
    inv_vs = 1.0 / plant.stribeck_velocity
    sigma2, cq = plant.viscous, plant.drag_coefficient
    vband = plant.stick_velocity
    beta, two_pi_over_plong = plant.friction_variation, 2 * math.pi / plant.friction_period
    gamma, tw = plant.friction_warmup, plant.warmup_time
    # other forces
    grav_a, grav_q0 = plant.gravity_amplitude, plant.gravity_angle
    ks, qrest = plant.spring_stiffness, plant.spring_rest_position
    cog_a, cog_k, cog_ph = plant.cogging_amplitude, 2 * math.pi / plant.cogging_period, plant.cogging_phase
    dist_a, dist_w, dist_ph = plant.disturbance_amplitude, 2 * math.pi * plant.disturbance_frequency, \
        plant.disturbance_phase
    position_forces = bool(grav_a or ks or cog_a)
    # inertia
    alpha = plant.inertia_variation
    m0 = plant.mass
    two_mass = plant.compliant_fraction > 0.0
    if two_mass:
        m1, m2, kk, cc = plant.two_mass()
    else:
        m1, m2, kk, cc = m0, 1.0, 0.0, 0.0
    half_gap = 0.5 * plant.backlash_width
    x2, v2 = q, v
    # delivered effort: delay buffer of mapped commands, padded with zeros before the start
    pattern = delay_pattern(plant.delay, dt, substeps)
    pad = 2 - min(o for o, _ in pattern)
    buffer = [0.0] * pad
    q_out = [0.0] * (n + 1)
    v_out = [0.0] * (n + 1)
    tau = [0.0] * n
    q_out[0], v_out[0] = q, v
    exp, sin, cos = math.exp, math.sin, math.cos
    t = 0.0
    for k in range(n):
        y = q + noise[k]
        if step:
            y = round(y / step) * step
        u = float(controller(k, y))
        tau[k] = u
        buffer.append(delivered_effort(plant, u))
        base = pad + k
        efforts = [buffer[base + o] * (1.0 - w) + buffer[base + o + 1] * w if w else buffer[base + o]
                   for o, w in pattern]
        lam_t = 1.0 + gamma * exp(-t / tw) if gamma else 1.0
        for s in range(substeps):
            t_s = t + s * h
            force = efforts[s]
            if position_forces:
                if grav_a:
                    force -= grav_a * sin(q - grav_q0) if hinge else grav_a
                if ks:
                    force -= ks * (q - qrest)
                if cog_a:
                    force += cog_a * sin(cog_k * q + cog_ph)
            if dist_a:
                force += dist_a * sin(dist_w * t_s + dist_ph)
            if two_mass:
                gap = x2 - q
                if half_gap:
                    if gap > half_gap:
                        fk = max(kk * (gap - half_gap) + cc * (v2 - v), 0.0)
                    elif gap < -half_gap:
                        fk = min(kk * (gap + half_gap) + cc * (v2 - v), 0.0)
                    else:
                        fk = 0.0
                else:
                    fk = kk * gap + cc * (v2 - v)
                force += fk
                v2 -= fk / m2 * h
                x2 += v2 * h
            m = m1
            if alpha:
                if hinge:
                    m = m0 * (1.0 + alpha * sin(q))
                    force -= 0.5 * m0 * alpha * cos(q) * v * v
                else:
                    m = m0 * (1.0 + alpha * q / plant.inertia_length)
                    force -= 0.5 * m0 * alpha / plant.inertia_length * v * v
            lam = lam_t * (1.0 + beta * sin(two_pi_over_plong * q)) if beta else lam_t
            if -vband < v < vband:
                hi = lam * fs + half_asym  # F_s+
                lo = lam * fs - half_asym  # F_s−
                if -lo <= force <= hi:
                    v = 0.0
                    continue
                friction = (hi if force > 0 else -lo) + sigma2 * v + cq * v * abs(v)
                v += (force - friction) / m * h
                q += v * h
                continue
            if v > 0:
                level_c = lam * fc + half_asym
                level = level_c + lam * (fs - fc) * exp(-(v * inv_vs) ** 2) if stribeck else level_c
                friction = level + sigma2 * v + cq * v * v
            else:
                level_c = lam * fc - half_asym
                level = level_c + lam * (fs - fc) * exp(-(v * inv_vs) ** 2) if stribeck else level_c
                friction = -level + sigma2 * v - cq * v * v
            a = (force - friction) / m
            v_new = v + a * h
            if (v > 0.0) != (v_new > 0.0):  # zero crossing while sliding: stop there
                q -= 0.5 * v * v / a
                v = 0.0
            else:
                v = v_new
                q += v * h
        t += dt
        q_out[k + 1], v_out[k + 1] = q, v
    return np.array(q_out), np.array(v_out), np.array(tau)
