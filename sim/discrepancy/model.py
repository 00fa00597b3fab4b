"""The fast surrogate: residual channels of a parameter vector on a prepared log (inverse dynamics).

Why a surrogate: the testbed's MuJoCo plant runs about 15 000 control ticks per second, so one replay of a
60 s log takes 4 s, and fitting 15 candidate effects needs thousands of evaluations. The surrogate evaluates
the same physics *backwards* from the measured motion, vectorised in NumPy, in milliseconds: given the
measured motor angle and the measured load on the lever it computes the effort the model needs and compares
it with the effort commanded. MuJoCo is kept for the final windowed replay (:mod:`sim.discrepancy.replay`)
and for generating test logs; tests check that the surrogate explains baseline MuJoCo logs to within their
noise.

Channels (each a residual = measured - model, filtered, NaN where a sample does not count):

``effort`` [N·m | N]
    Motor-side balance, output-referred: ``τ_m(u) + cogging = J·q̈_m + F_gear + τ_trans`` with the delivered
    torque ``τ_m`` = command through dead time (+ current-loop lag), roll-off, saturation and (testbed) the
    motor's current-to-torque map (``sim.motor_torque``); the gear
    friction ``F_gear`` = LuGre (bristle state driven by the measured motion, integrated exactly per sample, and
    its rate at the sample time, as MuJoCo's dcmotor applies them at its finer physics step) + viscous
    + asymmetry + load-dependent dry friction ``μ·|τ_trans|`` (while stuck: at the band's edge against the
    motion on samples where the motor encoder moved, any value within ``±μ|τ_trans|`` where it did not);
    ``τ_trans`` = load-cell torque + lever inertia + gravity (or the sensor where nothing else measures it).
    A rigid joint uses ``gain·u = m·q̈ + F(v) + gravity`` with a static Stribeck curve while sliding and a stick
    band of ``±F_s`` while stuck.
``sensor`` [N·m]
    Torque sensor against the transmitted torque: ``τ_s = g·τ_trans + b + c_T·(T - T_cal) + hysteresis``.
``kinematic`` [rad]
    Motor angle minus lever angle minus flexure twist ``τ_trans/K_t``: ``±w/2`` by the sign of the transmitted
    torque, plus a constant encoder offset (fitted as a nuisance); samples below ``contact_torque`` count
    not (the hub may float in the dead band).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from models.gim8108_testbed.derived import derive
from sim.discrepancy.effects import NEUTRAL, rolled_off
from sim.discrepancy.rig import Rig
from sim.discrepancy.signals import AnalysisConfig, Prepared, testbed_constants
from sim.motor_torque import CurrentToTorqueMap

CHANNEL_UNITS = {"effort": ("N·m", "N"), "sensor": ("N·m", "N·m"), "kinematic": ("rad", "m")}
MIN_DECAY = 1e-12  # smallest per-sample decay factor of the bristle state [1]
MIN_FRICTION_LEVEL = 1e-9  # floor of the Stribeck level g(v) in the bristle update [N·m]
SCAN_BLOCK = 16  # samples per block of the bristle-state scan: products of 16 factors >= 1e-7 stay normal
CACHE_SIZE = 8  # cached delivered-torque and friction terms per surrogate (fits vary one group at a time)
DEFAULT_HYSTERESIS_SPAN_NM = 1.0  # neutral span of the sensor hysteresis (irrelevant while its height is 0)
RIGID_STICK_FRACTION = 0.01  # rigid joint: stuck below 1 % of the log's RMS velocity
# Rigid joint: effort samples within this many filter periods (1/f_c) of a stick-slip transition do not count.
# The plant's dry friction jumps at the transition; the filtered balance smears that jump over the filter's
# impulse response (~1/f_c each side), which the sign of the filtered velocity cannot place. On the slide
# experiment those samples carried the baseline effort residual (0.39 N RMS within 20 ms of a transition,
# 0.004 N beyond 100 ms) and pulled a fitted dead time 0.6-0.8 ms long (it correlates with the jerk there);
# with one period excluded it comes out 0.04 ms short on seeds 21-23 (measured, tests/test_discrepancy_sweep.py).
RIGID_TRANSITION_GUARD_PERIODS = 1.0
# Testbed: the load-dependent dry friction counts as stuck (a band) below 20 % of the Stribeck velocity. The
# filtered velocity smears reversals over ~1/f_c while MuJoCo's frictionloss flips sign at once; 2 % left a
# baseline residual of 0.34 N·m on the locked experiment, 20 % leaves 0.014 N·m (measured, 8 s log).
TESTBED_STICK_FRACTION_OF_STRIBECK = 0.2


def channel_unit(channel: str, joint: str) -> str:
    hinge, slide = CHANNEL_UNITS[channel]
    return slide if joint == "slide" else hinge


def baseline_theta(rig: Rig) -> dict[str, float]:
    """The surrogate's parameter vector of a rig: its baseline values, added effects, neutral values."""
    theta: dict[str, float] = dict(NEUTRAL)
    theta.update(cogging_phase=0.0, gravity_angle=0.0, sensor_hysteresis_span=DEFAULT_HYSTERESIS_SPAN_NM,
                 kin_offset=0.0, effort_gain=1.0)
    if rig.model == "testbed":
        assert rig.params is not None
        p, d = rig.params, derive(rig.params)
        fr = p.friction
        theta.update(
            inertia=d.reflected_rotor_inertia_kgm2 + d.output_inertia_kgm2, delay=p.motor.command_delay_s,
            coulomb=fr.coulomb_torque_nm, breakaway=fr.breakaway_torque_nm,
            stribeck_velocity=fr.stribeck_velocity_rad_s, viscous=fr.viscous_nms_per_rad,
            presliding_stiffness=fr.presliding_stiffness_nm_per_rad, load_coefficient=fr.load_friction_coefficient,
            backlash_width=p.backlash.width_rad, peak_effort=p.motor.peak_torque_nm,
            cogging_period=2.0 * math.pi / p.motor.gear_ratio)
    else:
        theta.update(rig.rigid)
        theta.setdefault("peak_effort", math.inf)
        theta.setdefault("cogging_period", 1.0)
    for effect in rig.effects:
        theta.update(effect.parameters)
    return theta


def stribeck_level(velocity: np.ndarray, coulomb: float, breakaway: float, stribeck_velocity: float) -> np.ndarray:
    """Sliding friction level g(v) = F_c + (F_s - F_c)·exp(-(v/v_s)²) [N·m | N] (the plant's LuGre curve)."""
    return coulomb + (breakaway - coulomb) * np.exp(-(velocity / stribeck_velocity) ** 2)


def bristle_state(step_velocity: np.ndarray, g: np.ndarray, stiffness: float, dt: float) -> np.ndarray:
    """LuGre bristle deflection z [rad] driven by a measured velocity, integrated exactly per sample.

    ``dz/dt = v - σ0·|v|·z/g(v)`` has, for the velocity ``v_k`` held over one sample (the backward difference of
    the measured angle: the sample's displacement ``Δx_k = v_k·dt`` is exact) and ``g_k = g(v_k)``, the exact
    solution ``z_k = c_k·z_{k-1} + (1 - c_k)·sign(v_k)·g_k/σ0`` with ``c_k = exp(-σ0·|Δx_k|/g_k)``: the bristle
    relaxes towards its sliding deflection over the presliding displacement ``g/σ0``, whatever the sample rate.

    Why exact and not implicit Euler, ``z_k = (z_{k-1} + Δx_k)/(1 + σ0·|Δx_k|/g_k)``: at the 1 kHz log rate one
    sample moves the motor by a sizeable part of the presliding displacement (σ0·|Δx|/g ≈ 0.9 at 0.05 rad/s at the
    defaults), where implicit Euler lags the bristle behind MuJoCo's (which integrates it at the physics step,
    16 times finer). On the free swing that lag was a 0.8 mN·m (filtered RMS) error of σ0·z at every velocity
    reversal, most of the baseline's effort residual; with no load-dependent friction band to absorb it
    (load_friction_coefficient 0.05 instead of 0.1) a Stribeck curve fitted to it won 20 % held-out and was
    reported as a finding. The exact update leaves 0.18 mN·m (measured against MuJoCo's bristle state,
    tests/test_discrepancy.py). The linear recursion is solved block-wise with cumulative products (exact up
    to rounding).
    """
    n = len(step_velocity)
    if not stiffness > 0.0:
        raise ValueError(f"presliding stiffness = {stiffness!r} N·m/rad: valid range (0, inf)")
    level = np.maximum(g, MIN_FRICTION_LEVEL)
    decay = -stiffness * np.abs(step_velocity) * dt / level  # ln c_k
    # a factor below MIN_DECAY means the bristle reaches its sliding deflection within one sample anyway
    # (relative error < 1e-12); flooring it keeps the block products (16 factors) far from underflow
    c = np.maximum(np.exp(decay), MIN_DECAY)
    b = -np.expm1(decay) * np.sign(step_velocity) * level / stiffness
    nb = -(-n // SCAN_BLOCK)
    pad = nb * SCAN_BLOCK - n
    c = np.concatenate([c, np.ones(pad)]).reshape(nb, SCAN_BLOCK)
    b = np.concatenate([b, np.zeros(pad)]).reshape(nb, SCAN_BLOCK)
    prod = np.cumprod(c, axis=1)
    partial = np.cumsum(b / prod, axis=1)
    last_prod, last_partial = prod[:, -1], partial[:, -1]
    z_in = np.empty(nb)
    z = 0.0
    for j in range(nb):  # block to block: nb = n/16 scalar steps
        z_in[j] = z
        z = last_prod[j] * (z + last_partial[j])
    return (prod * (z_in[:, None] + partial)).ravel()[:n]


def play_operator(x: np.ndarray, half_width: float) -> np.ndarray:
    """Backlash (play) operator of half-width ``half_width`` on ``x`` (starts centred on ``x[0]``)."""
    out = np.empty_like(x)
    p = float(x[0])
    for k, xk in enumerate(x.tolist()):
        if xk - p > half_width:
            p = xk - half_width
        elif p - xk > half_width:
            p = xk + half_width
        out[k] = p
    return out


@dataclass
class Surrogate:
    """Residual channels of a rig's surrogate on a prepared log; ``residuals(theta)`` is the one call."""

    data: Prepared
    rig: Rig
    config: AnalysisConfig

    def __post_init__(self) -> None:
        d = self.data
        self.testbed = self.rig.model == "testbed"
        self.const = testbed_constants(self.rig) if self.testbed else {}
        if self.config.stick_velocity is not None:
            self.stick_velocity = self.config.stick_velocity
        elif self.testbed:
            assert self.rig.params is not None
            self.stick_velocity = TESTBED_STICK_FRACTION_OF_STRIBECK * self.rig.params.friction.stribeck_velocity_rad_s
        else:
            self.stick_velocity = RIGID_STICK_FRACTION * float(np.sqrt(np.mean(d.velocity**2)))
        self.stuck = np.abs(d.velocity) < self.stick_velocity
        self.near_transition = np.zeros(len(d.t), dtype=bool)  # effort samples left out (rigid joint)
        if not self.testbed:
            guard = int(round(RIGID_TRANSITION_GUARD_PERIODS / (self.config.filter_cutoff_hz * d.dt)))
            edges = np.flatnonzero(self.stuck[1:] != self.stuck[:-1]) + 1
            change = np.zeros(len(d.t) + 1)
            np.add.at(change, np.clip(edges - guard, 0, len(d.t)), 1.0)
            np.add.at(change, np.clip(edges + guard, 0, len(d.t)), -1.0)
            self.near_transition = np.cumsum(change[:-1]) > 0
        # a rigid joint without a Stribeck drop (breakaway == coulomb) has one dry-friction level: while its
        # breakaway is not fitted, the static level follows the Coulomb level
        self._base_breakaway = self.rig.rigid.get("breakaway") if not self.testbed else None
        self._tied_static = (not self.testbed) and self.rig.rigid["breakaway"] == self.rig.rigid["coulomb"]
        self.slide_sign = np.sign(d.velocity)
        self.stuck_edge, self.stuck_band = self._load_friction_while_stuck()
        self._cache: dict[str, OrderedDict] = {"delivered": OrderedDict(), "friction": OrderedDict(),
                                                "play": OrderedDict()}
        self.channels = ["effort"]
        if self.testbed and d.tau_sensor is not None and d.load_source in ("loadcell", "inertia"):
            self.channels.append("sensor")
        if self.testbed and d.q is not None and d.has_motor_encoder:
            self.channels.append("kinematic")

    def _load_friction_while_stuck(self) -> tuple[np.ndarray, np.ndarray]:
        """The load-dependent friction of a stuck sample as ``μ|τ|·(edge ± band)`` [1, 1], filtered.

        MuJoCo's frictionloss row holds the gear until the force on it exceeds ``μ|τ|`` and sits at ``∓μ|τ|``
        while the gear moves. In between, the LuGre bristle only deflects while the gear moves. So a sample in
        which the motor encoder moved carries the band's edge with the sign of its motion (``edge``); only a
        sample in which it did not can carry any value within the band (``band``). A band on every stuck sample
        let a stiffer bristle push the presliding samples' residual into it at no cost: σ0 came out 11-27 %
        high on the current-feedback PI logs with a 22-bit encoder, 0.2 % with no load friction
        (docs/discrepancy_limits.md). Without a motor encoder (the position is the lever's) the band stays.
        """
        d = self.data
        n = len(d.t)
        if not (self.testbed and d.has_motor_encoder):
            return np.zeros(n), np.ones(n)
        moved = (d.step_velocity != 0.0).astype(float)
        return d.filt(np.sign(d.step_velocity)), np.clip(d.filt(1.0 - moved), 0.0, None)

    def _cached(self, group: str, key: tuple, compute):  # small LRU per term group
        cache = self._cache[group]
        if key in cache:
            cache.move_to_end(key)
            return cache[key]
        value = compute()
        cache[key] = value
        if len(cache) > CACHE_SIZE:
            cache.popitem(last=False)
        return value

    def delivered(self, theta: dict[str, float]) -> np.ndarray:
        """Effort reaching the joint from the command, filtered [N·m | N]."""
        d = self.data
        lag = self.const.get("current_lag", 0.0)
        saturation = self.const.get("torque_saturation", 0.0)
        key = (theta["delay"], theta["torque_rolloff"], theta["effort_gain"], theta["peak_effort"])

        def compute() -> np.ndarray:
            peak = theta["peak_effort"]
            limit = self.const.get("command_limit", peak)  # the testbed driver's; a rigid rig saturates at its peak
            u = rolled_off(d.u, theta["torque_rolloff"], peak, limit)
            if saturation:  # the testbed motor's own current-to-torque map, after any roll-off (its clip is above)
                u = CurrentToTorqueMap(saturation, peak).delivered_nm(u)
            # command k is held during (t_k - dt, t_k]: place it at the hold's centre, then delay and lag it
            shifted = np.interp(d.t - (theta["delay"] + lag), d.t - 0.5 * d.dt, u)
            return d.filt(theta["effort_gain"] * shifted)

        return self._cached("delivered", key, compute)

    def static_level(self, theta: dict[str, float]) -> float:
        """Static (breakaway) friction level [N·m | N]."""
        if self._tied_static and theta["breakaway"] == self._base_breakaway:
            return theta["coulomb"]
        return max(theta["breakaway"], theta["coulomb"])

    def friction(self, theta: dict[str, float]) -> np.ndarray:
        """Velocity-dependent gear friction (LuGre for the testbed, static for a rigid joint), filtered."""
        d = self.data
        fc, fs, vs = theta["coulomb"], self.static_level(theta), theta["stribeck_velocity"]
        if self.testbed:
            key = (fc, fs, vs, theta["presliding_stiffness"])

            def compute() -> np.ndarray:
                sigma0 = theta["presliding_stiffness"]
                sigma1 = 2.0 * self.const["presliding_damping_ratio"] * math.sqrt(
                    sigma0 * self.const["rotor_reflected_inertia"])
                v = d.step_velocity
                z = bristle_state(v, stribeck_level(v, fc, fs, vs), sigma0, d.dt)
                # the bristle rate at the sample time: MuJoCo's dcmotor applies σ1·(z_{n+1} - z_n)/h at every
                # physics step, so its mean over a control tick is σ1·(z_k - z_{k-1})/dt, centred half a sample
                # before t_k; the balance compares every other term at t_k (filtered, centred derivatives), so
                # the rate is the centred difference (with the one-sided one, a dead time 0.1 ms short and a
                # Stribeck curve fitted to the half-sample lag of σ1·ż at reversals; measured, docs/discrepancy_limits.md)
                zdot = np.gradient(z, d.dt)
                return d.filt(sigma0 * z + sigma1 * zdot)

            return self._cached("friction", key, compute)
        v = d.velocity
        return np.sign(v) * stribeck_level(v, fc, fs, vs)

    def gravity(self, theta: dict[str, float]) -> np.ndarray | float:
        """Load of the weight of the moving part [N·m | N]."""
        if theta["gravity_amplitude"] == 0.0:
            return 0.0
        if self.rig.joint == "slide":
            return theta["gravity_amplitude"]
        q = self.data.q if self.data.q is not None else self.data.position
        return theta["gravity_amplitude"] * np.sin(q - theta["gravity_angle"])

    def cogging(self, theta: dict[str, float]) -> np.ndarray | float:
        if theta["cogging_amplitude"] == 0.0:
            return 0.0
        d = self.data
        return theta["cogging_amplitude"] * d.filt(np.sin(2.0 * math.pi * d.position / theta["cogging_period"]
                                                          + theta["cogging_phase"]))

    def hysteresis(self, theta: dict[str, float], reference: np.ndarray) -> np.ndarray | float:
        if theta["sensor_hysteresis"] == 0.0:
            return 0.0
        span = theta["sensor_hysteresis_span"]
        key = (span, float(reference.sum()), float(reference @ reference))  # the reference moves with gravity only
        played = self._cached("play", key, lambda: play_operator(reference, span))
        return theta["sensor_hysteresis"] / span * (reference - played)

    def sensor_model(self, theta: dict[str, float], reference: np.ndarray) -> np.ndarray:
        """Sensor reading the model predicts for a transmitted torque ``reference`` [N·m]."""
        d = self.data
        out = theta["sensor_gain"] * reference + theta["sensor_offset"]
        if theta["sensor_tempco"] != 0.0 and d.temperature is not None:
            out = out + theta["sensor_tempco"] * (d.temperature - self.const["calibration_temperature"])
        return out + self.hysteresis(theta, reference)

    def transmitted(self, theta: dict[str, float]) -> np.ndarray:
        """Torque the gear passes to the sensor hub, from the measured lever side [N·m]."""
        d = self.data
        if d.load_source == "sensor":  # invert the sensor model (hysteresis is not inverted: it needs a reference)
            drift = 0.0
            if theta["sensor_tempco"] != 0.0 and d.temperature is not None:
                drift = theta["sensor_tempco"] * (d.temperature - self.const["calibration_temperature"])
            return (d.tau_sensor - theta["sensor_offset"] - drift) / theta["sensor_gain"]
        lever = self.const["lever_inertia"] * d.lever_acceleration
        if d.load_source == "loadcell":
            lever = lever + d.tau_loadcell
        return lever + self.gravity(theta)

    def residuals(self, theta: dict[str, float]) -> dict[str, np.ndarray]:
        """Residual (measured - model) of every channel the log supports; NaN where a sample does not count."""
        d = self.data
        out: dict[str, np.ndarray] = {}
        rest = (self.delivered(theta) + self.cogging(theta) - theta["inertia"] * d.acceleration
                - theta["viscous"] * d.velocity - 0.5 * theta["asymmetry"])
        if self.testbed:
            tau = self.transmitted(theta)
            rest = rest - tau - self.friction(theta)
            cap = theta["load_coefficient"] * np.abs(tau)
            stuck_rest = rest - cap * self.stuck_edge
            band = cap * self.stuck_band
            out["effort"] = np.where(self.stuck, stuck_rest - np.clip(stuck_rest, -band, band),
                                     rest - cap * self.slide_sign)
            if "sensor" in self.channels:
                out["sensor"] = d.tau_sensor - self.sensor_model(theta, tau)
            if "kinematic" in self.channels:
                twist = d.filt(d.position) - d.q - tau / self.const["flexure_stiffness"]
                expected = 0.5 * theta["backlash_width"] * np.sign(tau) + theta["kin_offset"]
                out["kinematic"] = np.where(np.abs(tau) > self.config.contact_torque, twist - expected, np.nan)
        else:
            rest = rest - self.gravity(theta)
            static = self.static_level(theta)
            effort = np.where(self.stuck, rest - np.clip(rest, -static, static), rest - self.friction(theta))
            out["effort"] = np.where(self.near_transition, np.nan, effort)
        return out
