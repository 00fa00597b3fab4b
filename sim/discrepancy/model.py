"""The fast surrogate: residual channels of a parameter vector on a prepared log (inverse dynamics).

Why a surrogate: the testbed's MuJoCo plant runs about 15 000 control ticks per second, so one replay of a
60 s log takes 4 s, and fitting a library of candidate effects needs thousands of evaluations. The surrogate
evaluates the same physics *backwards* from the measured motion, vectorised in NumPy on the analysis grid
(:mod:`sim.discrepancy.signals`), in milliseconds: given the measured motion and load it computes the effort the
model needs and compares it with the effort delivered. MuJoCo is kept for the final windowed replay
(:mod:`sim.discrepancy.replay`), the model's own log (:mod:`sim.discrepancy.null`) and test logs; tests check
that the surrogate explains baseline MuJoCo logs to within their noise.

Channels (each a residual = measured - model, filtered, NaN where a sample does not count):

``effort`` [N·m | N]
    ``delivered(u) - needed``. Delivered: the command clipped at the drive's limit, through the effects' command
    maps (roll-off), the testbed motor's current-to-torque map (``sim.motor_torque``), the dead time (+ the
    current loop's lag) and the effort gain. Needed: ``J·ẍ + σ2·ẋ + Σ effect loads + friction (+ τ_trans)``.
    The testbed's gear friction is LuGre (its bristle state driven by the measured motor motion, integrated
    exactly per sample, its rate at the sample time, as MuJoCo's dcmotor applies them at its finer physics
    step) plus load-dependent dry friction ``μ·|τ_trans|`` (while stuck: at the band's edge against the motion
    on samples where the motor encoder moved, any value within ``±μ|τ_trans|`` where it did not);
    ``τ_trans`` = load-cell torque + lever inertia + lever loads (gravity), or the sensor where nothing else
    measures it. A rigid joint uses a static Stribeck curve of the velocity while sliding (evaluated at the log's
    rate, then filtered) and a stick band of ``±F_s`` while stuck, and its samples near a stick-slip transition
    do not count.
``sensor`` [N·m]
    Torque sensor against the transmitted torque: ``τ_s = τ_trans + Σ effect sensor terms`` (offset, gain,
    drift, hysteresis).
``kinematic`` [rad]
    Motor angle minus lever angle minus flexure twist ``τ_trans/K_t``: ``±w/2`` by the sign of the transmitted
    torque, plus a constant encoder offset (fitted as a nuisance); samples below ``contact_torque`` do not
    count (the hub may float in the dead band).

Each effect of :mod:`sim.discrepancy.effects` enters through its hooks (``command``, ``load``, ``lever_load``,
``sensor``); the friction, dead-time, inertia, gain and backlash effects own entries of ``theta`` that the
baseline terms here read.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import butter, sosfiltfilt

from models.gim8108_testbed.derived import derive
from sim.discrepancy.effects import EFFECTS, TESTBED, Effect, Scale, rig_kind
from sim.discrepancy.laws import stribeck_level
from sim.discrepancy.rig import Rig
from sim.discrepancy.signals import FILTER_ORDER, AnalysisConfig, Prepared, rms, testbed_constants
from sim.motor_torque import CurrentToTorqueMap

CHANNEL_UNITS = {"effort": ("N·m", "N"), "sensor": ("N·m", "N·m"), "kinematic": ("rad", "m")}
MIN_DECAY = 1e-12  # smallest per-sample decay factor of the bristle state [1]
MIN_FRICTION_LEVEL = 1e-9  # floor of the Stribeck level g(v) in the bristle update [N·m]
SCAN_BLOCK = 16  # samples per block of the bristle-state scan: products of 16 factors >= 1e-7 stay normal
CACHE_SIZE = 8  # cached terms per group (fits vary one group of parameters at a time)
RIGID_STICK_FRACTION = 0.01  # rigid joint: stuck below 1 % of the log's RMS velocity
# Rigid joint: effort samples within this many filter periods (1/f_c) of a stick-slip transition do not count.
# The plant's dry friction jumps at the transition; the filtered balance smears that jump over the filter's
# impulse response (~1/f_c each side), which the sign of the filtered velocity cannot place. The transitions are
# found at the log's rate, from the velocity in twice the analysis band: at a reversal a joint sticks for a few
# milliseconds, which the band's own velocity smears into a zero crossing. Counted, those samples carried most
# of the baseline effort residual of rigid joints under a stick-slip (Karnopp) plant (15 x the rest on a slide's
# multisine log) and gave spurious dead times and compliances.
RIGID_TRANSITION_GUARD_PERIODS = 1.0
RIGID_STICK_BAND_FACTOR = 2.0  # stick-slip transitions: from the velocity low-passed at this x the analysis band
# Testbed: the load-dependent dry friction counts as stuck (a band) below 20 % of the Stribeck velocity. The
# filtered velocity smears reversals over ~1/f_c while MuJoCo's frictionloss flips sign at once; 2 % left a
# baseline residual of 0.34 N·m on the locked experiment, 20 % leaves 0.014 N·m (8 s log).
TESTBED_STICK_FRACTION_OF_STRIBECK = 0.2
REVERSAL_WINDOW_S = 0.02  # the presliding signature: 20 ms after each motion reversal
NUISANCE_KEYS = ("kin_offset",)  # fitted alongside, never reported as an effect
RESOLUTION_NOISE_SEED = 0  # the fixed draw of the quantisation error behind Surrogate.resolution_floor


def channel_unit(channel: str, joint: str) -> str:
    hinge, slide = CHANNEL_UNITS[channel]
    return slide if joint == "slide" else hinge


def baseline_theta(rig: Rig) -> dict[str, float]:
    """The surrogate's parameter vector of a rig: its own values, its added effects, neutral values elsewhere."""
    theta: dict[str, float] = {}
    for effect in EFFECTS.values():
        theta.update(effect.absent())
    theta.update(kin_offset=0.0, effort_gain=1.0, peak_effort=math.inf, delay=0.0)
    if rig.model == "testbed":
        assert rig.params is not None
        p, d = rig.params, derive(rig.params)
        fr = p.friction
        theta.update(
            inertia=d.reflected_rotor_inertia_kgm2 + d.output_inertia_kgm2, coulomb=fr.coulomb_torque_nm,
            breakaway=fr.breakaway_torque_nm, stribeck_velocity=fr.stribeck_velocity_rad_s,
            viscous=fr.viscous_nms_per_rad, load_coefficient=fr.load_friction_coefficient,
            presliding_stiffness=fr.presliding_stiffness_nm_per_rad, delay=p.motor.command_delay_s,
            backlash_width=p.backlash.width_rad, peak_effort=p.motor.peak_torque_nm)
    else:
        theta.update(rig.rigid)
    for effect in rig.effects:
        theta.update(effect.parameters)
    return theta


def bristle_state(step_velocity: np.ndarray, g: np.ndarray, stiffness: float, dt: float) -> np.ndarray:
    """LuGre bristle deflection z [rad] driven by a measured velocity, integrated exactly per sample.

    ``dz/dt = v - σ0·|v|·z/g(v)`` has, for the velocity ``v_k`` held over one sample (the backward difference of
    the measured angle: the sample's displacement ``Δx_k = v_k·dt`` is exact) and ``g_k = g(v_k)``, the exact
    solution ``z_k = c_k·z_{k-1} + (1 - c_k)·sign(v_k)·g_k/σ0`` with ``c_k = exp(-σ0·|Δx_k|/g_k)``: the bristle
    relaxes towards its sliding deflection over the presliding displacement ``g/σ0``, whatever the sample rate.
    (Implicit Euler at 1 kHz lags the bristle behind MuJoCo's, integrated 16 times finer: at 0.05 rad/s one
    sample moves the motor by ~0.9 presliding displacements.) The linear recursion is solved block-wise with
    cumulative products (exact up to rounding).
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


def _overrides(effect: Effect, hook: str) -> bool:
    return getattr(type(effect), hook) is not getattr(Effect, hook)


@dataclass
class Surrogate:
    """Residual channels of a rig's surrogate on a prepared log; ``residuals(theta)`` is the one call."""

    data: Prepared
    rig: Rig
    config: AnalysisConfig
    theta0: dict[str, float] = field(init=False)
    scale: Scale = field(init=False)

    def __post_init__(self) -> None:
        d = self.data
        self.kind = rig_kind(self.rig)
        self.testbed = self.kind == TESTBED
        self.const = testbed_constants(self.rig) if self.testbed else {}
        self.theta0 = baseline_theta(self.rig)
        records = max(len(d.bounds), 1)
        self.effects = [e for e in EFFECTS.values() if e.applies(self.rig) and records >= e.min_records]
        self._hooks = {hook: [e for e in self.effects if _overrides(e, hook)]
                       for hook in ("command", "load", "lever_load", "sensor")}
        self._cache: dict[str, OrderedDict] = {}
        if self.config.stick_velocity is not None:
            self.stick_velocity = self.config.stick_velocity
        elif self.testbed:
            assert self.rig.params is not None
            self.stick_velocity = TESTBED_STICK_FRACTION_OF_STRIBECK * self.rig.params.friction.stribeck_velocity_rad_s
        else:
            self.stick_velocity = RIGID_STICK_FRACTION * float(np.sqrt(np.mean(d.velocity**2)))
        if self.testbed:
            self.stuck = np.abs(d.velocity) < self.stick_velocity
            self.near_transition = np.zeros(len(d.t), dtype=bool)
        else:
            v = self.transition_velocity = self._transition_velocity()
            stuck_full = np.abs(v) < self.stick_velocity
            self.stuck = stuck_full[d.grid]
            moving = np.flatnonzero(~stuck_full)
            reversals = moving[1:][np.sign(v[moving[1:]]) != np.sign(v[moving[:-1]])]  # also without a stuck sample
            changes = np.flatnonzero(stuck_full[1:] != stuck_full[:-1]) + 1
            self.near_transition = self._near(d.t_full[np.union1d(changes, reversals)])
        self.slide_sign = np.sign(d.velocity)
        self.stuck_edge, self.stuck_band = self._load_friction_while_stuck()
        self.channels = ["effort"]
        if self.testbed and d.tau_sensor is not None and d.load_source in ("loadcell", "inertia"):
            self.channels.append("sensor")
        if self.testbed and d.q is not None and d.has_motor_encoder:
            self.channels.append("kinematic")
        self.command_rms = rms(d.filt(d.u_full)[d.held | d.fit])  # [N·m | N] the command in the analysis band
        self.records = self._records()
        self.resolution_floor = self._resolution_floor()
        peak = self.theta0["peak_effort"]
        self.scale = Scale(
            effort=max(float(np.abs(d.u_full).max()), peak if math.isfinite(peak) else 0.0, 1e-12),
            inertia=self.theta0["inertia"], velocity=max(float(np.abs(d.velocity).max()), 1e-9),
            position_span=float(np.ptp(d.position)),
            load_span=float(np.ptp(self.transmitted(self.theta0))) if self.testbed else 0.0,
            duration=float(d.t_full[-1] - d.t_full[0]), dt=d.dt, band_hz=self.config.filter_cutoff_hz,
            baseline=dict(self.theta0))

    # -- helpers ------------------------------------------------------------------------------------------
    def memo(self, group: str, key: tuple, compute: Callable[[], Any]) -> Any:
        """``compute()`` cached under ``key`` in a small LRU per ``group`` (fits vary one group at a time)."""
        cache = self._cache.setdefault(group, OrderedDict())
        if key in cache:
            cache.move_to_end(key)
            return cache[key]
        value = compute()
        cache[key] = value
        if len(cache) > CACHE_SIZE:
            cache.popitem(last=False)
        return value

    def _transition_velocity(self) -> np.ndarray:
        """Rigid joint: the velocity low-passed at RIGID_STICK_BAND_FACTOR x the analysis band, full rate
        [rad/s | m/s] (the analysis band's own where that is above the Nyquist frequency)."""
        d = self.data
        cutoff = RIGID_STICK_BAND_FACTOR * self.config.filter_cutoff_hz
        if cutoff >= 0.45 / d.dt:
            return d.velocity_full
        sos = butter(FILTER_ORDER, cutoff, fs=1.0 / d.dt, output="sos")
        return d.derivative(d.per_log(lambda part: sosfiltfilt(sos, part), d.position_full))

    def _near(self, edges: np.ndarray) -> np.ndarray:
        """Grid samples within RIGID_TRANSITION_GUARD_PERIODS filter periods of any time in ``edges`` [s]."""
        d = self.data
        guard_s = RIGID_TRANSITION_GUARD_PERIODS / self.config.filter_cutoff_hz
        if not len(edges):
            return np.zeros(len(d.t), dtype=bool)
        nearest = np.searchsorted(edges, d.t)
        before = np.abs(d.t - edges[np.clip(nearest - 1, 0, len(edges) - 1)])
        after = np.abs(edges[np.clip(nearest, 0, len(edges) - 1)] - d.t)
        return np.minimum(before, after) < guard_s

    def _load_friction_while_stuck(self) -> tuple[np.ndarray, np.ndarray]:
        """The load-dependent friction of a stuck sample as ``μ|τ|·(edge ± band)`` [1, 1], filtered.

        MuJoCo's frictionloss row holds the gear until the force on it exceeds ``μ|τ|`` and sits at ``∓μ|τ|``
        while the gear moves. In between, the LuGre bristle only deflects while the gear moves. So a sample in
        which the motor encoder moved carries the band's edge with the sign of its motion (``edge``); only a
        sample in which it did not can carry any value within the band (``band``). A band on every stuck sample
        let a stiffer bristle push the presliding samples' residual into it at no cost (σ0 11-27 % high on
        current-feedback logs with a 22-bit encoder). Without a motor encoder the band stays.
        """
        d = self.data
        n = len(d.t)
        if not (self.testbed and d.has_motor_encoder):
            return np.zeros(n), np.ones(n)
        moved = (d.step_velocity != 0.0).astype(float)
        return d.filt(np.sign(d.step_velocity)), np.clip(d.filt(1.0 - moved), 0.0, None)

    def reversal_indicator(self) -> np.ndarray:
        """1 within REVERSAL_WINDOW_S after the filtered velocity changes sign, else 0 (grid)."""
        v = self.data.velocity
        s = np.sign(v)
        s[np.abs(v) < self.stick_velocity] = 0
        changes = self.data.t[np.flatnonzero(np.diff(s) != 0)]
        out = np.zeros(len(v))
        for t0 in changes:
            out[(self.data.t >= t0) & (self.data.t < t0 + REVERSAL_WINDOW_S)] = 1.0
        return out

    def _resolution_floor(self) -> float:
        """The effort error the position encoder's resolution alone leaves in the balance [N·m | N] (RMS): the
        rig's inertia and viscous terms of a quantisation error uniform over one step (a fixed draw), through the
        analysis band's filter and derivatives. Twice differentiated, a coarse encoder's steps are a noise that no
        effect explains and that some (an inertia, a compliance) can fit."""
        d = self.data
        if not d.position_resolution > 0.0:
            return 0.0
        rng = np.random.default_rng(RESOLUTION_NOISE_SEED)
        error = d.filt_full(rng.uniform(-0.5, 0.5, len(d.t_full)) * d.position_resolution)
        velocity = d.derivative(error)
        term = self.theta0["inertia"] * d.derivative(velocity) + self.theta0["viscous"] * velocity
        return rms(term[d.grid][d.fit | d.held])

    def _records(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(its grid samples, the samples its zero is fitted on) of each joined log (record): its fit part, or its
        held-out part when it is held out whole (a validation log). Empty for one log."""
        d = self.data
        out = []
        for start, stop in d.bounds:
            inside = (d.grid >= start) & (d.grid < stop)
            fitted = inside & d.fit
            out.append((inside, fitted if fitted.any() else inside & d.held))
        return out

    def _record_offsets(self, residual: np.ndarray, counted: np.ndarray) -> tuple[np.ndarray, list[float]]:
        """Each record's own zero of a residual channel (its mean on the samples its zero is fitted on that
        ``counted`` marks), as a grid array and a list [channel unit]."""
        offsets = np.zeros(len(residual))
        values = []
        for inside, fitted in self.records:
            ok = fitted & counted & np.isfinite(residual)
            value = float(np.mean(residual[ok])) if ok.any() else 0.0
            offsets[inside] = value
            values.append(value)
        return offsets, values

    # -- terms --------------------------------------------------------------------------------------------
    def delivered(self, theta: dict[str, float]) -> np.ndarray:
        """Effort reaching the joint from the command, filtered, on the grid [N·m | N]."""
        d = self.data
        command_keys = tuple(theta[k] for e in self._hooks["command"] for k in e.keys)

        def mapped() -> np.ndarray:
            peak = theta["peak_effort"]
            limit = self.const.get("command_limit", peak)  # the testbed driver's; a rigid rig saturates at its peak
            u = np.clip(d.u_full, -limit, limit)
            for effect in self._hooks["command"]:
                u = effect.command(u, theta, peak)
            if self.const.get("torque_saturation"):  # the testbed motor's current-to-torque map, after the maps
                u = CurrentToTorqueMap(self.const["torque_saturation"], peak).delivered_nm(u)
            return d.filt_full(u)

        full = self.memo("delivered", command_keys + (theta["peak_effort"],), mapped)
        # command k is held during (t_k - hold, t_k]: at the hold's centre, then delayed (and lagged)
        shift = theta["delay"] + self.const.get("current_lag", 0.0)
        return theta["effort_gain"] * np.interp(d.t - shift, d.t_full - 0.5 * d.hold_s, full)

    def mapped_command(self, theta: dict[str, float]) -> np.ndarray:
        """The command as the drive turns it into effort, at the log's rate and unfiltered [N·m | N]: clipped at
        the drive's limit and through the effects' command maps (and the testbed motor's current-to-torque map),
        before the dead time and the effort gain (the unfiltered counterpart of :meth:`delivered`'s input)."""
        peak = theta["peak_effort"]
        limit = self.const.get("command_limit", peak)
        u = np.clip(self.data.u_full, -limit, limit)
        for effect in self._hooks["command"]:
            u = effect.command(u, theta, peak)
        if self.const.get("torque_saturation"):
            u = CurrentToTorqueMap(self.const["torque_saturation"], peak).delivered_nm(u)
        return u

    def static_level(self, theta: dict[str, float]) -> float:
        """Static (breakaway) friction level [N·m | N]: a rigid joint without a Stribeck drop has one level."""
        if not self.testbed and self.theta0["breakaway"] == self.theta0["coulomb"] \
                and theta["breakaway"] == self.theta0["breakaway"]:
            return theta["coulomb"]
        return max(theta["breakaway"], theta["coulomb"])

    def friction(self, theta: dict[str, float]) -> np.ndarray:
        """Velocity-dependent gear friction (LuGre for the testbed, static for a rigid joint), filtered."""
        d = self.data
        fc, fs, vs = theta["coulomb"], self.static_level(theta), theta["stribeck_velocity"]
        if self.testbed:
            def compute() -> np.ndarray:
                sigma0 = theta["presliding_stiffness"]
                sigma1 = 2.0 * self.const["presliding_damping_ratio"] * math.sqrt(
                    sigma0 * self.const["rotor_reflected_inertia"])
                v = d.step_velocity
                z = bristle_state(v, stribeck_level(v, fc, fs, vs), sigma0, d.dt)
                # the bristle rate at the sample time: MuJoCo's dcmotor applies σ1·(z_{n+1} - z_n)/h at every
                # physics step, so its mean over a control tick is σ1·(z_k - z_{k-1})/dt, centred half a sample
                # before t_k; the balance compares every other term at t_k, so the rate is the centred difference
                return d.filt(sigma0 * z + sigma1 * d.gradient(z))

            return self.memo("friction", (fc, fs, vs, theta["presliding_stiffness"]), compute)

        def static_curve() -> np.ndarray:
            # the curve of the full-rate velocity, then filtered like every other term of the balance: the
            # Stribeck hump and the sign change at a reversal last a few milliseconds, which the filter smears
            # over ~1/f_c in the logged effort; the curve of the filtered velocity would keep them sharp. The
            # velocity is the one stick-slip transitions are found with (twice the analysis band): in the band's
            # own, a reversal lasts ~1/f_c, and the curve's drop there leaks through the filter into the samples
            # beyond the transitions' guards (a true Stribeck drop then fitted the balance worse than none)
            v = self.transition_velocity
            return d.filt(np.sign(v) * stribeck_level(v, fc, fs, vs))

        return self.memo("friction", (fc, fs, vs), static_curve)

    def cost(self, theta: dict[str, float]) -> float:
        """Sum of the squared residuals on the fit part, each channel scaled by its RMS there at the rig's own
        parameters [1] (for screening starting points)."""
        if not hasattr(self, "_cost_scales"):
            self._cost_scales = {c: rms(r[self.data.fit]) or 1.0 for c, r in self.residuals(self.theta0).items()}
        total = 0.0
        for channel, r in self.residuals(theta).items():
            sel = r[self.data.fit]
            total += float(np.sum(np.where(np.isfinite(sel), sel, 0.0) ** 2)) / self._cost_scales[channel] ** 2
        return total

    def loads(self, theta: dict[str, float]) -> np.ndarray | float:
        """Effort the joint needs for the effects' loads, on the grid [N·m | N]."""
        return sum((e.load(self, theta) for e in self._hooks["load"]), 0.0)

    def transmitted(self, theta: dict[str, float]) -> np.ndarray:
        """Torque the gear passes to the sensor hub, from the measured lever side [N·m] (the testbed)."""
        d = self.data
        if d.load_source == "sensor":  # invert the sensor's offset, drift and gain (not the loop: it needs τ)
            drift = 0.0
            if theta["sensor_tempco"] != 0.0 and d.temperature is not None:
                drift = theta["sensor_tempco"] * (d.temperature - self.const["calibration_temperature"])
            return (d.tau_sensor - theta["sensor_offset"] - drift) / theta["sensor_gain"]
        lever = self.const["lever_inertia"] * d.lever_acceleration
        if d.load_source == "loadcell":
            lever = lever + d.tau_loadcell
        return lever + sum((e.lever_load(self, theta) for e in self._hooks["lever_load"]), 0.0)

    def sensor_model(self, theta: dict[str, float], tau: np.ndarray) -> np.ndarray:
        """Sensor reading the model predicts for a transmitted torque ``tau`` [N·m]."""
        return tau + sum((e.sensor(self, theta, tau) for e in self._hooks["sensor"]), 0.0)

    def residuals(self, theta: dict[str, float]) -> dict[str, np.ndarray]:
        """Residual (measured - model) of every channel the log supports, on the grid; NaN where a sample does
        not count."""
        return self._residuals(theta)[0]

    def record_offsets(self, theta: dict[str, float]) -> dict[str, list[float]]:
        """Each record's own zero, per channel it applies to [channel unit], where ``theta`` carries the effect
        ``record_offsets`` (empty otherwise)."""
        return self._residuals(theta)[1]

    def _residuals(self, theta: dict[str, float]) -> tuple[dict[str, np.ndarray], dict[str, list[float]]]:
        """(the residual channels, the records' own zeros): with the effect ``record_offsets``, each joined log
        carries its own zero of the effort (and sensor) channel, the mean of its residual on the sliding samples it
        is fitted on (``records``), taken out before the stuck samples' band."""
        d = self.data
        out: dict[str, np.ndarray] = {}
        zeros: dict[str, list[float]] = {}
        per_record = bool(self.records) and theta.get("record_offsets", 0.0) >= 0.5
        rest = (self.delivered(theta) - theta["inertia"] * d.acceleration - theta["viscous"] * d.velocity
                - self.loads(theta))
        if self.testbed:
            tau = self.transmitted(theta)
            rest = rest - tau - self.friction(theta)
            cap = theta["load_coefficient"] * np.abs(tau)
            if per_record:
                offsets, zeros["effort"] = self._record_offsets(rest - cap * self.slide_sign, ~self.stuck)
                rest = rest - offsets
            stuck_rest = rest - cap * self.stuck_edge
            band = cap * self.stuck_band
            out["effort"] = np.where(self.stuck, stuck_rest - np.clip(stuck_rest, -band, band),
                                     rest - cap * self.slide_sign)
            if "sensor" in self.channels:
                out["sensor"] = d.tau_sensor - self.sensor_model(theta, tau)
                if per_record:
                    offsets, zeros["sensor"] = self._record_offsets(out["sensor"], np.ones(len(d.t), bool))
                    out["sensor"] = out["sensor"] - offsets
            if "kinematic" in self.channels:
                twist = d.position - d.q - tau / self.const["flexure_stiffness"]
                expected = 0.5 * theta["backlash_width"] * np.sign(tau) + theta["kin_offset"]
                out["kinematic"] = np.where(np.abs(tau) > self.config.contact_torque, twist - expected, np.nan)
        else:
            static = self.static_level(theta)
            friction = self.friction(theta)
            if per_record:
                offsets, zeros["effort"] = self._record_offsets(rest - friction, ~self.stuck & ~self.near_transition)
                rest = rest - offsets
            effort = np.where(self.stuck, rest - np.clip(rest, -static, static), rest - friction)
            out["effort"] = np.where(self.near_transition, np.nan, effort)
        return out, zeros
