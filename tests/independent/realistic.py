"""Stand-ins for real drive records: logs from the independent simulator made the way real rigs record them.

``python -m tests.independent.realistic --out DIR [--only PATTERN] [--analyse] [--workers N]`` writes one folder
per case, ``DIR/<case>/``, with its record(s) (``log.csv``; the re-zeroed records ``slow.csv``, ``medium.csv``,
``fast.csv``), the rig file the analysis is told (``rig.toml``, model "rigid-joint") and ``truth.json`` (what is
hidden, in the analysis library's names, and what a right analysis reports); with ``--analyse`` it runs the
discrepancy analysis on each case (each configuration of records, for the re-zeroed ones), prints one line per
analysis and a summary, and writes ``DIR/summary.json``.

The physics is :mod:`tests.independent.rigsim` (written from formulas, no code shared with the analysis); this
module adds what stands between a rig and its record: a PWM register, a logger's irregular clock and a user's
resampling, a drive's own velocity estimate, a torque sensor zeroed anew before each record. The project is used
only to write the logs and rigs in its formats and to call the analysis.

Kinds of case (hinges; 30 s records at 1 kHz unless said):

- ``pwm-*``: a servo (12-bit encoder, 2π/4096 rad) whose command is a PWM duty: the controller's duty goes to a
  16-bit register in counts, 885 counts = 100 % duty, negative duties in two's complement; the log's ``tau_cmd``
  is the duty as a fraction of full scale (register decoded, ÷ 885), ``pwm_register`` the raw register [count].
  The rig states ``effort_gain`` = the datasheet's torque per unit duty (stall torque at the nominal supply) and
  ``peak_effort`` = 1 (100 % duty, in the units of ``tau_cmd``); the true torque per unit duty is that times a
  factor in [0.6, 0.75] or [1.3, 1.4]. A right analysis re-fits ``effort_gain`` to the true torque per unit duty
  [N·m per unit duty]. Variants: a horizontal arm (multisine), a pendulum whose gravity the rig states
  (point-to-point about its rest angle), and a clean arm (the rig right: nothing to name), the control for what
  the servo's coarse encoder alone does to the analysis.
- ``resampled-*``: the servo under its own 1 kHz position loop, read by a host logger every 5.3 ms ± 35 %
  (steps uniform in [0.65, 1.35] × 5.3 ms); each read returns the registers of the drive's last tick (position
  and duty of tick floor(t/1 ms)) stamped with the host's time. The written log is that record resampled on a
  uniform 5 ms grid as a user's converter does it: positions interpolated linearly, the command held (zero-order
  hold) or interpolated linearly, by variant (``raw_log.csv`` keeps the irregular record). One hidden effect:
  Coulomb × 1.3 (hold), viscous × 2 (linear). The converter's timing shows as a dead time the truth states
  (``converter.apparent_delay_s``), and the logger's sampling aliases the drive's duty noise into the analysis
  band (``converter.in_band_error_fraction``). ``drive_1khz.csv`` is the drive's own record of the same run,
  analysed beside it for reference.
- ``velocity-*``: a robot joint (1.2 kg·m², 2^19 counts per turn) under a torque-commanding PID; the log also
  carries the drive's velocity ``qd``: a backward difference of the encoder low-passed at 40 Hz (first order),
  reported one control period late. One hidden effect: viscous × 2, Coulomb × 1.3.
- ``rezeroed-*``: three 20 s records of the robot joint sweeping back and forth over ±0.8-1.2 rad (accelerating at
  3-5 rad/s², one draw per case) at 0.2, 0.6 and 1.5 rad/s; the logged effort is its link-side torque sensor
  (noise 0.02 N·m RMS, 16 bits over ±100 N·m; the drive delivers the commanded torque through it, so nothing
  upstream of it shows), whose zero is set anew before each record: offsets of 0.1-0.3 N·m of either sign, one
  per record. Hidden: Coulomb × 1.3 in all three. Analysed twice: slow and fast for estimation with medium for
  validation, and slow alone with fast for validation.
- ``impedance-*``: the robot joint under impedance control (K = 40 N·m/rad, D = 8 N·m·s/rad) to a setpoint that
  creeps between positions within ±0.25 rad at up to 0.15 rad/s and dwells 3-6 s: little motion, much sticking.
  Clean, Coulomb × 1.3, viscous × 2. A right analysis names the hidden effect or nothing (cannot reveal, no
  significant discrepancy, unexplained), never a wrong effect.
- ``gravity-*``: a pendulum whose m·g·r is 5-25 × its friction swinging through more than 1 rad, from a rig that
  states no gravity: a direct-drive pendulum (14-bit encoder) pumped by an energy controller to amplitudes of
  0.9-2.1 rad, and the servo pendulum under its position loop in PWM duty tracking a multisine about its rest
  angle (an open-loop duty swings the servo's heavily damped pendulum by less than 0.5 rad). A right analysis names
  gravity first, its amplitude within 25 % and its rest angle within 0.25 rad.

Deterministic: every draw comes from ``numpy.random.default_rng`` seeded by the case's seed.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt

from tests.independent.battery import _current_library, _fmt, judge, write_summary
from tests.independent.rigsim import (
    PID,
    EnergyPump,
    Impedance,
    Plant,
    QuantisedCommand,
    Reference,
    Run,
    back_and_forth,
    multisine,
    point_to_point,
    simulate,
)

DT = 1e-3  # the drives' control period [s]
DURATION_S = 30.0
RECORD_S = 20.0  # each re-zeroed record [s]
BANDWIDTH_HZ = 5.0  # position loops
G = 9.81  # [m/s²]

# PWM register: a signed duty in counts, stored in 16 bits (two's complement); 885 counts = 100 % duty.
PWM_FULL_SCALE = 885
REGISTER_BITS = 16

# A geared servo with a 12-bit magnetic encoder, its command a PWM duty: inertia at the output (rotor reflected
# through the gear, horn) [kg·m²], gear Coulomb friction [N·m], viscous friction including the back-EMF damping
# of a voltage-driven motor (K_t·K_e/R, referred to the output) [N·m·s/rad], stall torque per unit duty at the
# nominal supply [N·m], encoder counts per turn.
SERVO = {"inertia": 0.006, "coulomb": 0.1, "viscous": 0.37, "torque_per_duty": 3.0, "encoder_counts": 4096}
SERVO_DERIVATIVE_HZ = 40.0  # the servo's velocity filter: its 12-bit encoder makes a wider one's duty noisy
ARM = {"inertia": 0.004}  # a horizontal aluminium arm on the servo [kg·m²]
BOB = {"mass": 0.25, "radius": 0.2}  # a pendulum's bob [kg, m]: m·r² = 0.01 kg·m², m·g·r = 0.49 N·m
# A robot joint behind a torque-controlled drive, seen from its link side: inertia [kg·m²], friction [N·m,
# N·m·s/rad], torque limit [N·m], absolute encoder counts per turn.
ROBOT = {"inertia": 1.2, "coulomb": 2.0, "viscous": 3.0, "peak_effort": 80.0, "encoder_counts": 2**19}
TORQUE_SENSOR = {"noise_std": 0.02, "step": 100.0 / 2**15}  # [N·m]: white noise, 16 bits over ±100 N·m
OFFSET_RANGE = (0.1, 0.3)  # |zero offset| of each re-zeroed record [N·m]
# A direct-drive pendulum (motor, hub and bob): inertia [kg·m²], friction [N·m, N·m·s/rad], torque limit [N·m],
# 14-bit magnetic encoder.
DIRECT = {"inertia": 0.012, "coulomb": 0.02, "viscous": 0.002, "peak_effort": 0.5, "encoder_counts": 2**14}

LOGGER = {"mean_step_s": 5.3e-3, "jitter": 0.35, "grid_step_s": 5e-3}  # the host logger of resampled-*
DRIVE_VELOCITY = {"cutoff_hz": 40.0, "report_lag_samples": 1}
SPEEDS = {"slow": 0.2, "medium": 0.6, "fast": 1.5}  # re-zeroed records' sweep speeds [rad/s]
HIDDEN_FACTORS = {"coulomb_friction": 1.3, "viscous_friction": 2.0}  # truth / rig
GAIN_FACTORS = ((0.6, 0.75), (1.3, 1.4))  # pwm-*: true torque per unit duty / the rig's
TOLERANCE = 0.2  # relative error of a right value
GRAVITY_TOLERANCE = (0.25, 0.25)  # gravity-*: relative amplitude error [1], rest-angle error [rad]
REZEROED_ANALYSES = (("2+1", ("slow", "fast"), ("medium",)), ("1+1", ("slow",), ("fast",)))


@dataclass(frozen=True)
class Case:
    """One stand-in: its kind, variant, seed and hidden in-library effect ('' for none)."""

    name: str
    kind: str  # 'pwm', 'resampled', 'velocity', 'rezeroed', 'impedance', 'gravity'
    variant: str
    seed: int
    effect: str = ""


def cases() -> list[Case]:
    """The case list: two to four per kind."""
    return [
        Case("pwm-arm-s11", "pwm", "arm", 11, "effort_gain"),
        Case("pwm-pendulum-s12", "pwm", "pendulum", 12, "effort_gain"),
        Case("pwm-clean-s13", "pwm", "arm", 13),
        Case("resampled-hold-coulomb-s21", "resampled", "hold", 21, "coulomb_friction"),
        Case("resampled-linear-viscous-s22", "resampled", "linear", 22, "viscous_friction"),
        Case("velocity-viscous-s31", "velocity", "multisine", 31, "viscous_friction"),
        Case("velocity-coulomb-s32", "velocity", "multisine", 32, "coulomb_friction"),
        Case("rezeroed-coulomb-s41", "rezeroed", "three speeds", 41, "coulomb_friction"),
        Case("rezeroed-coulomb-s42", "rezeroed", "three speeds", 42, "coulomb_friction"),
        Case("impedance-clean-s51", "impedance", "creeping setpoint", 51),
        Case("impedance-coulomb-s52", "impedance", "creeping setpoint", 52, "coulomb_friction"),
        Case("impedance-viscous-s53", "impedance", "creeping setpoint", 53, "viscous_friction"),
        Case("gravity-pump-s61", "gravity", "pump", 61, "gravity"),
        Case("gravity-servo-s62", "gravity", "servo", 62, "gravity"),
    ]


def analyses(case: Case) -> list[tuple[str, tuple[str, ...], tuple[str, ...]]]:
    """(label, estimation record names, validation record names) of each analysis of ``case``: the re-zeroed
    records in two configurations; a resampled log, and beside it, for reference, the drive's own 1 kHz record of
    the same run (what a logger reading every tick would have)."""
    if case.kind == "rezeroed":
        return list(REZEROED_ANALYSES)
    if case.kind == "resampled":
        return [("", ("log",), ()), ("drive 1 kHz", ("drive_1khz",), ())]
    return [("", ("log",), ())]


# ------------------------------------------------------------------------------------- what a rig records


def duty_to_register(duty: float) -> int:
    """The 16-bit register holding a duty [fraction of full scale]: counts = round(duty·885) clipped at ±885,
    stored in two's complement (−1 count is 0xFFFF)."""
    counts = int(round(min(max(duty, -1.0), 1.0) * PWM_FULL_SCALE))
    return counts & (2**REGISTER_BITS - 1)


def register_to_duty(register: int | np.ndarray) -> float | np.ndarray:
    """The duty [fraction of full scale] a 16-bit register holds: two's complement decoded, ÷ 885."""
    r = np.asarray(register, dtype=np.int64)
    signed = np.where(r >= 2 ** (REGISTER_BITS - 1), r - 2**REGISTER_BITS, r)
    out = signed / PWM_FULL_SCALE
    return float(out) if np.ndim(out) == 0 else out


def logger_stamps(duration_s: float, rng: np.random.Generator, mean_step_s: float = LOGGER["mean_step_s"],
                  jitter: float = LOGGER["jitter"]) -> np.ndarray:
    """A host logger's read times [s]: the first in [2, 6] ms, then steps uniform in mean·[1 − jitter, 1 + jitter],
    up to ``duration_s``."""
    count = int(duration_s / (mean_step_s * (1 - jitter))) + 2
    steps = mean_step_s * rng.uniform(1 - jitter, 1 + jitter, count)
    stamps = rng.uniform(2e-3, 6e-3) + np.concatenate([[0.0], np.cumsum(steps)])
    return stamps[stamps < duration_s]


def resample(t_source: np.ndarray, x_source: np.ndarray, t_grid: np.ndarray, method: str) -> np.ndarray:
    """``x`` on ``t_grid``: 'linear' interpolation between the source samples, or 'hold' (zero-order hold: the
    last source sample at or before each grid time; grid times before the first sample take the first)."""
    if method == "linear":
        return np.interp(t_grid, t_source, x_source)
    if method == "hold":
        index = np.searchsorted(t_source, t_grid, side="right") - 1
        return np.asarray(x_source)[np.clip(index, 0, len(t_source) - 1)]
    raise ValueError(f"method = {method!r}; expected 'linear' or 'hold'")


def uniform_grid(t_source: np.ndarray, step_s: float) -> np.ndarray:
    """Multiples of ``step_s`` from the first source time up to the last [s]."""
    first, last = math.ceil(t_source[0] / step_s - 1e-9), math.floor(t_source[-1] / step_s + 1e-9)
    return np.arange(first, last + 1) * step_s


def drive_velocity(y: np.ndarray, dt: float = DT, cutoff_hz: float = DRIVE_VELOCITY["cutoff_hz"],
                   lag_samples: int = DRIVE_VELOCITY["report_lag_samples"]) -> np.ndarray:
    """A drive's velocity estimate of the measured positions y_k [rad/s]: v_k = α·v_{k−1} + (1 − α)·(y_k − y_{k−1})/dt,
    α = exp(−2π·f_c·dt), v_0 = 0, reported ``lag_samples`` periods late (the first ones 0)."""
    alpha = math.exp(-2 * math.pi * cutoff_hz * dt)
    v = np.zeros(len(y))
    for k in range(1, len(y)):
        v[k] = alpha * v[k - 1] + (1 - alpha) * (y[k] - y[k - 1]) / dt
    if lag_samples:
        v = np.concatenate([np.zeros(lag_samples), v[:-lag_samples]])
    return v


def torque_sensor(torque: np.ndarray, offset: float, rng: np.random.Generator,
                  noise_std: float = TORQUE_SENSOR["noise_std"], step: float = TORQUE_SENSOR["step"]) -> np.ndarray:
    """A torque sensor's reading [N·m]: s·round((τ + b + n)/s), b its zero offset, n white (std ``noise_std``), s
    its resolution."""
    return np.round((torque + offset + rng.normal(0.0, noise_std, len(torque))) / step) * step


def measured_at_ticks(run: Run) -> np.ndarray:
    """y(k·dt) for k = 0..n−1, the position each command was computed from, from a hold-end run (row k holds
    y((k + 1)·dt); y(0) is the start, quantised like the rest)."""
    step = run.meta["encoder_step"]
    if run.meta["noise_std"]:
        raise ValueError("y(0) of a noisy run is not in its log")
    y0 = round(float(run.q_true[0]) / step) * step if step else float(run.q_true[0])
    return np.concatenate([[y0], run.q[:-1]])


# -------------------------------------------------------------------------------------------------- the rigs


def _log(time_s: np.ndarray, columns: dict[str, np.ndarray], units: dict[str, str] | None = None, **meta):
    from sim.runlog import STANDARD_UNITS, RunLog

    cols = {"time": np.asarray(time_s, float), **{k: np.asarray(v, float) for k, v in columns.items()}}
    all_units = {k: STANDARD_UNITS[k] for k in cols if k in STANDARD_UNITS}
    all_units.update(units or {})
    return RunLog(cols, all_units, meta)


def rig_toml(rig: dict, header: str) -> str:
    """The project's rigid-joint rig file of a hinge: inertia, effort_gain, peak_effort (if any), gravity (if
    stated), friction."""
    lines = [f"# {header}", 'model = "rigid-joint"', 'joint = "hinge"', f"inertia_kgm2 = {rig['mass']!r}",
             f"effort_gain = {rig['effort_gain']!r}  # {rig.get('effort_unit', 'N·m per unit of tau_cmd')}"]
    if rig.get("peak_effort") is not None:
        lines.append(f"peak_effort = {rig['peak_effort']!r}  # in the units of tau_cmd")
    if "gravity_amplitude" in rig:
        lines += [f"gravity_amplitude = {rig['gravity_amplitude']!r}  # N·m",
                  f"gravity_angle_rad = {rig['gravity_angle']!r}"]
    lines += ["", "[friction]", f"coulomb = {rig['coulomb']!r}  # N·m", f"viscous = {rig['viscous']!r}  # N·m·s/rad",
              ""]
    return "\n".join(lines)


def _hidden(effect: str, parameters: dict[str, float], rig_states: dict[str, float] | None = None,
            **extra) -> dict:
    entry = {"effect": effect, "in_library": True, "parameters": parameters, "equivalent": {}}
    if rig_states is not None:
        entry["rig_states"] = rig_states
    entry.update(extra)
    return entry


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _friction_changes(effect: str, coulomb: float, viscous: float) -> tuple[dict[str, float], list[dict]]:
    """Plant overrides and the truth's hidden entry of a Coulomb or viscous factor (HIDDEN_FACTORS)."""
    if not effect:
        return {}, []
    factor = HIDDEN_FACTORS[effect]
    if effect == "coulomb_friction":
        value = coulomb * factor
        return {"coulomb": value}, [_hidden(effect, {"coulomb": value}, {"coulomb": coulomb}, factor=factor)]
    value = viscous * factor
    return {"viscous": value}, [_hidden(effect, {"viscous": value}, {"viscous": viscous}, factor=factor)]


def _servo_pid(ref: Reference, inertia: float, gain: float) -> QuantisedCommand:
    """The servo's duty: a position PID tuned at BANDWIDTH_HZ for inertia/gain [duty·s²/rad], its derivative
    low-passed at SERVO_DERIVATIVE_HZ, limited at 100 %, through the PWM register."""
    pid = PID.tuned(ref, inertia / gain, BANDWIDTH_HZ, 1.0, derivative_cutoff_hz=SERVO_DERIVATIVE_HZ)
    return QuantisedCommand(pid, 1.0 / PWM_FULL_SCALE, 1.0)


def _encoder(counts: int) -> float:
    return 2 * math.pi / counts


def pwm_case(case: Case, duration_s: float) -> tuple[dict, dict, dict]:
    """A servo commanded by a PWM duty whose torque per unit duty is off the datasheet's (module docstring)."""
    rng = np.random.default_rng([case.seed, 1])
    n = int(round(duration_s / DT))
    nominal = SERVO["torque_per_duty"]
    low, high = GAIN_FACTORS
    ratio = float(rng.uniform(*low) if rng.random() < 0.5 else rng.uniform(*high)) if case.effect else 1.0
    true_gain = nominal * ratio
    pendulum = case.variant == "pendulum"
    inertia = SERVO["inertia"] + (BOB["mass"] * BOB["radius"] ** 2 if pendulum else ARM["inertia"])
    fields = {"coulomb": SERVO["coulomb"], "viscous": SERVO["viscous"], "effort_gain": true_gain,
              "peak_effort": 1.0, "stick_velocity": 1e-4}
    rest = 0.0
    if pendulum:
        rest = float(rng.uniform(-math.pi, math.pi))
        fields.update(gravity_amplitude=BOB["mass"] * G * BOB["radius"], gravity_angle=rest)
        base = point_to_point(n, 0.8, 2.0, case.seed, dwell_s=(0.3, 1.0))
        ref = Reference(base.position + rest, base.velocity, "point_to_point about the rest angle")
    else:
        ref = multisine(n, 0.4, case.seed)
    plant = Plant("hinge", inertia, **fields)
    controller = _servo_pid(ref, inertia, nominal)
    run = simulate(plant, controller, n, seed=case.seed, encoder_step=_encoder(SERVO["encoder_counts"]), q0=rest)
    registers = np.array([duty_to_register(u) for u in run.tau_cmd], dtype=float)
    duty = register_to_duty(registers.astype(np.int64))
    log = _log(run.time, {"tau_cmd": duty, "q": run.q, "pwm_register": registers}, {"pwm_register": "count"})
    rig = {"mass": inertia, "effort_gain": nominal, "peak_effort": 1.0, "coulomb": SERVO["coulomb"],
           "viscous": SERVO["viscous"], "effort_unit": "N·m per unit duty (datasheet stall torque)"}
    if pendulum:
        rig.update(gravity_amplitude=fields["gravity_amplitude"], gravity_angle=rest)
    hidden = ([_hidden("effort_gain", {"effort_gain": true_gain}, {"effort_gain": nominal}, ratio_to_rig=ratio)]
              if case.effect else [])
    truth = {"plant": asdict(plant), "hidden": hidden,
             "controller": {"type": "PID (s + ω)³ in duty, through the PWM register", "bandwidth_hz": BANDWIDTH_HZ,
                            "tuned_for": "inertia / the rig's torque per unit duty", "limit_duty": 1.0},
             "pwm": {"full_scale_counts": PWM_FULL_SCALE, "register_bits": REGISTER_BITS,
                     "tau_cmd": "duty as a fraction of full scale (register decoded, / 885)",
                     "nominal_torque_per_duty": nominal, "true_torque_per_duty": true_gain, "ratio": ratio},
             "expected": (f"effort_gain re-fitted to {true_gain:.4g} N·m per unit duty ({ratio:.3f} x the rig's "
                          f"{nominal:g}); nothing else" if case.effect else "nothing named"),
             "encoder_step_rad": _encoder(SERVO["encoder_counts"])}
    return {"log": log}, rig, truth


def apparent_delay(run: Run, stamps: np.ndarray, ticks: np.ndarray, t_grid: np.ndarray, command: np.ndarray,
                   gain: float, band_hz: float = 25.0) -> tuple[float, float]:
    """The dead time d [s] under which a hold-end reading of the resampled log (command of row k held over the
    step before it, shifted by d) best matches the effort truly delivered at the instants its positions were
    measured, both low-passed at ``band_hz``: the converter's timing as an analysis sees it (least squares over
    d in 0.1 ms steps from −2 to +10 ms); and the RMS of what is left at that d, relative to the delivered
    effort's RMS [1] (the logger's sampling aliases the drive's command noise into the band)."""
    step = t_grid[1] - t_grid[0]
    sos = butter(4, band_hz, fs=1.0 / step, output="sos")
    measured_at = np.interp(t_grid, stamps, ticks * DT)  # the instant each resampled position was measured
    centres = (np.arange(len(run.tau_cmd)) + 0.5) * DT  # u_k is held over (k·dt, (k + 1)·dt]
    truth = sosfiltfilt(sos, gain * np.interp(measured_at, centres, run.tau_cmd))
    best, best_cost = 0.0, math.inf
    edge = int(round(0.5 / step))
    norm = float(np.sum(truth[edge:-edge] ** 2))
    for d in np.arange(-2e-3, 10e-3 + 1e-9, 1e-4):
        model = sosfiltfilt(sos, gain * np.interp(t_grid - d, t_grid - 0.5 * step, command))
        cost = float(np.sum((model - truth)[edge:-edge] ** 2))
        if cost < best_cost:
            best, best_cost = float(d), cost
    return best, math.sqrt(best_cost / norm)


def resampled_case(case: Case, duration_s: float) -> tuple[dict, dict, dict]:
    """The servo read by an irregular host logger and resampled on a uniform grid (module docstring)."""
    rng = np.random.default_rng([case.seed, 2])
    n = int(round(duration_s / DT))
    gain = SERVO["torque_per_duty"]
    inertia = SERVO["inertia"] + ARM["inertia"]
    changes, hidden = _friction_changes(case.effect, SERVO["coulomb"], SERVO["viscous"])
    fields = {"coulomb": SERVO["coulomb"], "viscous": SERVO["viscous"], "effort_gain": gain, "peak_effort": 1.0,
              "stick_velocity": 1e-4, **changes}
    plant = Plant("hinge", inertia, **fields)
    ref = multisine(n, 0.4, case.seed)
    run = simulate(plant, _servo_pid(ref, inertia, gain), n, seed=case.seed,
                   encoder_step=_encoder(SERVO["encoder_counts"]))
    stamps = logger_stamps(duration_s - 2 * DT, rng)
    ticks = np.floor(stamps / DT + 1e-9).astype(int)  # the drive's last tick at each read
    y = measured_at_ticks(run)
    raw = _log(stamps, {"tau_cmd": run.tau_cmd[ticks], "q": y[ticks]})
    method = case.variant
    t_grid = uniform_grid(stamps, LOGGER["grid_step_s"])
    command = resample(stamps, run.tau_cmd[ticks], t_grid, method)
    log = _log(t_grid, {"tau_cmd": command, "q": resample(stamps, y[ticks], t_grid, "linear")})
    delay, left = apparent_delay(run, stamps, ticks, t_grid, command, gain)
    steps = np.diff(stamps)
    rig = {"mass": inertia, "effort_gain": gain, "peak_effort": 1.0, "coulomb": SERVO["coulomb"],
           "viscous": SERVO["viscous"], "effort_unit": "N·m per unit duty (datasheet stall torque)"}
    truth = {"plant": asdict(plant), "hidden": hidden,
             "controller": {"type": "the servo's own PID (s + ω)³ in duty at 1 kHz, through the PWM register",
                            "bandwidth_hz": BANDWIDTH_HZ},
             "logger": {"mean_step_s": LOGGER["mean_step_s"], "jitter": LOGGER["jitter"],
                        "steps_s": {"min": float(steps.min()), "median": float(np.median(steps)),
                                    "max": float(steps.max())},
                        "read": "registers of the drive's last tick (floor(t / 1 ms)): position y(k·dt), duty u_k"},
             "converter": {"grid_step_s": LOGGER["grid_step_s"], "positions": "linear",
                           "command": "zero-order hold" if method == "hold" else "linear",
                           "apparent_delay_s": delay, "in_band_error_fraction": left,
                           "note": "apparent_delay_s: the dead time under which a hold-end reading of the written "
                                   "log matches the delivered effort best (the converter's, not the rig's); "
                                   "in_band_error_fraction: the RMS of the logged command's error left at that "
                                   "dead time in the 25 Hz band, relative to the delivered effort (the drive's "
                                   "command noise aliased by the logger's sampling)"},
             "expected": f"{case.effect} re-fitted to {_fmt(hidden[0]['parameters'])}; a transport_delay near "
                         f"{1e3 * delay:.1f} ms is the converter's timing",
             "encoder_step_rad": _encoder(SERVO["encoder_counts"])}
    full = _log(run.time, {"tau_cmd": run.tau_cmd, "q": run.q})
    return {"log": log, "raw_log": raw, "drive_1khz": full}, rig, truth


def _robot_plant(effect: str, **extra) -> tuple[Plant, list[dict]]:
    changes, hidden = _friction_changes(effect, ROBOT["coulomb"], ROBOT["viscous"])
    fields = {"coulomb": ROBOT["coulomb"], "viscous": ROBOT["viscous"], "peak_effort": ROBOT["peak_effort"],
              "stick_velocity": 1e-4, **extra, **changes}
    return Plant("hinge", ROBOT["inertia"], **fields), hidden


def _robot_rig() -> dict:
    return {"mass": ROBOT["inertia"], "effort_gain": 1.0, "peak_effort": ROBOT["peak_effort"],
            "coulomb": ROBOT["coulomb"], "viscous": ROBOT["viscous"]}


def velocity_case(case: Case, duration_s: float) -> tuple[dict, dict, dict]:
    """The robot joint under a PID; the log carries the drive's velocity estimate (module docstring)."""
    n = int(round(duration_s / DT))
    plant, hidden = _robot_plant(case.effect)
    ref = multisine(n, 0.8, case.seed)
    run = simulate(plant, PID.tuned(ref, ROBOT["inertia"], BANDWIDTH_HZ, ROBOT["peak_effort"]), n, seed=case.seed,
                   encoder_step=_encoder(ROBOT["encoder_counts"]))
    y = np.concatenate([measured_at_ticks(run), run.q[-1:]])  # y(k·dt), k = 0..n
    qd = drive_velocity(y)[1:]  # row k (time (k + 1)·dt) reports the estimate of tick k + 1, one tick late
    log = _log(run.time, {"tau_cmd": run.tau_cmd, "q": run.q, "qd": qd})
    truth = {"plant": asdict(plant), "hidden": hidden,
             "controller": {"type": "PID (s + ω)³", "bandwidth_hz": BANDWIDTH_HZ, "limit": ROBOT["peak_effort"]},
             "drive_velocity": {"formula": "v_k = α·v_{k-1} + (1 − α)·(y_k − y_{k-1})/dt, α = exp(−2π·f_c·dt)",
                                **DRIVE_VELOCITY, "lag_s_at_low_frequency":
                                    1.0 / (2 * math.pi * DRIVE_VELOCITY["cutoff_hz"]) + 0.5 * DT
                                    + DRIVE_VELOCITY["report_lag_samples"] * DT},
             "expected": f"{case.effect} re-fitted to {_fmt(hidden[0]['parameters'])}",
             "encoder_step_rad": _encoder(ROBOT["encoder_counts"])}
    return {"log": log}, _robot_rig(), truth


def rezeroed_runs(case: Case, duration_s: float) -> tuple[Plant, dict[str, tuple[Run, float]], dict[str, float]]:
    """The plant, each record's run (slow, medium, fast) with its torque sensor's offset [N·m], and the sweep
    (span [rad], acceleration [rad/s²]) of the re-zeroed records."""
    rng = np.random.default_rng([case.seed, 4])
    n = int(round(min(duration_s, RECORD_S) / DT))
    plant, _ = _robot_plant(case.effect)
    span, acceleration = float(rng.uniform(0.8, 1.2)), float(rng.uniform(3.0, 5.0))
    out = {}
    for i, (name, speed) in enumerate(SPEEDS.items()):
        offset = float(math.copysign(rng.uniform(*OFFSET_RANGE), rng.uniform(-1, 1)))
        ref = back_and_forth(n, span, speed, acceleration, dwell_s=0.5)
        run = simulate(plant, PID.tuned(ref, ROBOT["inertia"], BANDWIDTH_HZ, ROBOT["peak_effort"]), n,
                       seed=case.seed * 10 + i, encoder_step=_encoder(ROBOT["encoder_counts"]))
        out[name] = (run, offset)
    return plant, out, {"span_rad": span, "acceleration_rad_s2": acceleration}


def delivered_torque(plant: Plant, run: Run) -> np.ndarray:
    """The torque the drive held over each row's period [N·m]: g·clip(u, ±peak) (no roll-off, no delay)."""
    return plant.effort_gain * np.clip(run.tau_cmd, -plant.peak_effort, plant.peak_effort)


def rezeroed_case(case: Case, duration_s: float) -> tuple[dict, dict, dict]:
    """Three records of the robot joint at three speeds, their torque sensor re-zeroed per record."""
    rng = np.random.default_rng([case.seed, 5])
    plant, runs, sweep = rezeroed_runs(case, duration_s)
    _, hidden = _robot_plant(case.effect)
    records, offsets, peaks = {}, {}, {}
    for name, (run, offset) in runs.items():
        offsets[name] = offset
        reading = torque_sensor(delivered_torque(plant, run), offset, rng)
        records[name] = _log(run.time, {"tau_cmd": reading, "q": run.q})
        peaks[name] = float(np.max(np.abs(run.v_true)))
    hidden.append(_hidden("record_offsets", {"record_offsets": 1.0}, zeros=offsets))
    truth = {"plant": asdict(plant), "hidden": hidden,
             "controller": {"type": "PID (s + ω)³", "bandwidth_hz": BANDWIDTH_HZ, "limit": ROBOT["peak_effort"]},
             "records": {name: {"sweep_speed_rad_s": SPEEDS[name], "top_speed_rad_s": peaks[name],
                                "offset_nm": offsets[name]} for name in SPEEDS},
             "sweep": {**sweep, "dwell_s": 0.5},
             "torque_sensor": {**TORQUE_SENSOR, "reads": "the torque delivered to the link + the record's offset"},
             "expected": f"coulomb_friction re-fitted to {_fmt(hidden[0]['parameters'])} (shared); each record's own "
                         f"zero (record_offsets), the records' zeros differing as the offsets do",
             "encoder_step_rad": _encoder(ROBOT["encoder_counts"])}
    return records, _robot_rig(), truth


def impedance_case(case: Case, duration_s: float) -> tuple[dict, dict, dict]:
    """The robot joint under impedance control to a creeping setpoint (module docstring)."""
    n = int(round(duration_s / DT))
    plant, hidden = _robot_plant(case.effect)
    ref = point_to_point(n, 0.25, 0.15, case.seed, dwell_s=(3.0, 6.0), speed_range=(0.5, 1.0))
    stiffness, damping = 40.0, 8.0
    run = simulate(plant, Impedance(ref, stiffness, damping, ROBOT["peak_effort"]), n, seed=case.seed,
                   encoder_step=_encoder(ROBOT["encoder_counts"]))
    log = _log(run.time, {"tau_cmd": run.tau_cmd, "q": run.q})
    moving = float(np.mean(np.abs(run.v_true) > 1e-3))
    truth = {"plant": asdict(plant), "hidden": hidden,
             "controller": {"type": "impedance u = K·(r − y) + D·(ṙ − v̂)", "stiffness_nm_per_rad": stiffness,
                            "damping_nms_per_rad": damping, "limit": ROBOT["peak_effort"]},
             "motion": {"position_span_rad": float(np.ptp(run.q)), "top_speed_rad_s": float(np.abs(run.v_true).max()),
                        "moving_fraction": moving},
             "expected": ("nothing named" if not hidden else
                          f"{case.effect} re-fitted to {_fmt(hidden[0]['parameters'])}, or nothing named") +
                         " ('cannot reveal', 'no significant discrepancy' or 'unexplained'); never another effect",
             "encoder_step_rad": _encoder(ROBOT["encoder_counts"])}
    return {"log": log}, _robot_rig(), truth


def gravity_case(case: Case, duration_s: float) -> tuple[dict, dict, dict]:
    """A pendulum swinging through gravity the rig does not state (module docstring)."""
    rng = np.random.default_rng([case.seed, 6])
    n = int(round(duration_s / DT))
    rest = float(rng.uniform(-math.pi, math.pi))
    amplitude = BOB["mass"] * G * BOB["radius"]
    t = np.arange(n) * DT
    if case.variant == "pump":
        inertia = DIRECT["inertia"]
        plant = Plant("hinge", inertia, coulomb=DIRECT["coulomb"], viscous=DIRECT["viscous"],
                      peak_effort=DIRECT["peak_effort"], gravity_amplitude=amplitude, gravity_angle=rest,
                      stick_velocity=1e-4)
        swing = 1.5 + 0.6 * np.sin(2 * math.pi * t / 12.0 - math.pi / 2)  # target amplitude 0.9-2.1 rad
        controller = EnergyPump(amplitude * (1 - np.cos(swing)), inertia, amplitude, rest, gain=2.0, limit=0.25)
        encoder = _encoder(DIRECT["encoder_counts"])
        rig = {"mass": inertia, "effort_gain": 1.0, "peak_effort": DIRECT["peak_effort"],
               "coulomb": DIRECT["coulomb"], "viscous": DIRECT["viscous"]}
        control = {"type": "energy pumping", "target_amplitude_rad": "1.5 + 0.6·sin(2π·t/12 s − π/2)",
                   "gain_nm_per_j": 2.0, "limit_nm": 0.25}
        friction = DIRECT["coulomb"]
    else:
        inertia = SERVO["inertia"] + BOB["mass"] * BOB["radius"] ** 2
        gain = SERVO["torque_per_duty"]
        plant = Plant("hinge", inertia, coulomb=SERVO["coulomb"], viscous=SERVO["viscous"], effort_gain=gain,
                      peak_effort=1.0, gravity_amplitude=amplitude, gravity_angle=rest, stick_velocity=1e-4)
        base = multisine(n, 0.6, case.seed)
        ref = Reference(base.position + rest, base.velocity, "multisine about the rest angle")
        controller = _servo_pid(ref, inertia, gain)
        encoder = _encoder(SERVO["encoder_counts"])
        rig = {"mass": inertia, "effort_gain": gain, "peak_effort": 1.0, "coulomb": SERVO["coulomb"],
               "viscous": SERVO["viscous"], "effort_unit": "N·m per unit duty (datasheet stall torque)"}
        control = {"type": "the servo's PID (s + ω)³ in duty through the PWM register, tracking a multisine of "
                           "0.6 rad (slowest tone) about the rest angle; it knows nothing of gravity but its integral",
                   "bandwidth_hz": BANDWIDTH_HZ, "derivative_cutoff_hz": SERVO_DERIVATIVE_HZ}
        friction = SERVO["coulomb"]
    run = simulate(plant, controller, n, seed=case.seed, encoder_step=encoder, q0=rest)
    log = _log(run.time, {"tau_cmd": run.tau_cmd, "q": run.q})
    swing = run.q_true - rest
    hidden = [_hidden("gravity", {"gravity_amplitude": amplitude, "gravity_angle": _wrap(rest)},
                      {"gravity_amplitude": 0.0})]
    truth = {"plant": asdict(plant), "hidden": hidden, "controller": control,
             "motion": {"swing_rad": [float(swing.min()), float(swing.max())],
                        "gravity_over_friction": amplitude / friction,
                        "command_rms": float(np.sqrt(np.mean(run.tau_cmd**2)))},
             "expected": f"gravity first: amplitude {amplitude:.4g} N·m within 25 %, rest angle {_wrap(rest):.4g} rad "
                         f"within 0.25 rad", "encoder_step_rad": encoder}
    return {"log": log}, rig, truth


BUILDERS = {"pwm": pwm_case, "resampled": resampled_case, "velocity": velocity_case, "rezeroed": rezeroed_case,
            "impedance": impedance_case, "gravity": gravity_case}


def build(case: Case, duration_s: float = DURATION_S) -> tuple[dict, dict, dict]:
    """The case's records (name -> RunLog), the rig the analysis is told, and the truth."""
    records, rig, truth = BUILDERS[case.kind](case, duration_s)
    truth = {"case": case.name, "kind": case.kind, "variant": case.variant, "joint": "hinge", "seed": case.seed,
             **truth}
    return records, rig, truth


def write_case(case: Case, out: Path, duration_s: float = DURATION_S) -> dict:
    """Simulate ``case`` and write its records, rig and truth under ``out/<case>``; returns the truth."""
    from sim.logio import write_log

    t0 = time.perf_counter()
    records, rig, truth = build(case, duration_s)
    folder = out / case.name
    folder.mkdir(parents=True, exist_ok=True)
    for name, log in records.items():
        write_log(log, folder / f"{name}.csv", overwrite=True)
    (folder / "rig.toml").write_text(rig_toml(rig, f"the rig the analysis is told, stand-in case {case.name}"),
                                     encoding="utf-8")
    truth["rig"] = rig
    truth["files"] = {name: f"{name}.csv" for name in records}
    truth["analyses"] = [{"label": label, "estimation": list(est), "validation": list(val)}
                         for label, est, val in analyses(case)]
    truth["durations_s"] = {name: float(log["time"][-1] - log["time"][0]) for name, log in records.items()}
    truth["generation_s"] = time.perf_counter() - t0
    (folder / "truth.json").write_text(json.dumps(truth, indent=1, default=float), encoding="utf-8")
    return truth


# -------------------------------------------------------------------------------------------------- analysis


def run_analysis(folder: Path, estimation: tuple[str, ...], validation: tuple[str, ...], workers: int = 1):
    """The discrepancy analysis of a case's records (the project's current API): the first estimation record,
    the others fitted with it, the validation records held out."""
    from sim.discrepancy.analysis import analyse
    from sim.discrepancy.rig import load_rig
    from sim.discrepancy.signals import AnalysisConfig
    from sim.logio import read_log

    def read(name: str):
        return read_log(folder / f"{name}.csv", joint="hinge")

    logs = [read(name) for name in (*estimation, *validation)]
    names = tuple(f"{name}.csv" for name in (*estimation, *validation))
    return analyse(logs[0], load_rig(folder / "rig.toml"), AnalysisConfig(workers=workers),
                   also=tuple(logs[1:len(estimation)]), validation=tuple(logs[len(estimation):]), names=names)


def _analysis_summary(result) -> dict:
    """What the JSON keeps of an analysis: its verdict and own words."""
    return {"verdict": result.verdict, "unexplained": result.structure.description,
            "remainder_fraction": result.structure.remainder_fraction,
            "generic_gain": result.structure.generic_gain,
            "not_identifiable": result.baseline["not_identifiable"],
            "time_convention": result.baseline["time_convention"],
            "time_convention_mismatch": result.baseline["time_convention_mismatch"],
            "tentative": [{"effect": f.effect, "values": {k: v["value"] for k, v in f.parameters.items()},
                           "why_not_saved": f.evidence.get("why_not_saved")} for f in result.tentative],
            "rejected": result.rejected, "logs": result.logs,
            "record_offsets": {"baseline": result.baseline["record_offsets"],
                               "final": result.final.get("record_offsets", [])},
            "free_parameters": result.final.get("free_parameters", {})}


def _validation_error(analysis: dict) -> float | None:
    """The validation record's relative effort error of the final model (None without one)."""
    for entry in analysis.get("logs", []):
        if entry["role"] == "validation":
            return entry["relative_effort_error"]["final"]
    return None


def judge_rezeroed(truth: dict, findings: list[dict], analysis: dict) -> dict:
    """Re-zeroed records: is the shared Coulomb level named first within 20 %, are the records' own zeros named,
    do the zeros the analysis reports differ between records as the offsets do, and the validation record's
    relative effort error."""
    row = judge({**truth, "hidden": truth["hidden"][:1]}, findings, _current_library(),
                analysis.get("verdict", ""), TOLERANCE)
    names = [f["effect"] for f in findings]
    offsets_named = "record_offsets" in names
    zeros = truth["hidden"][1]["zeros"]
    reported = {}
    for entry in analysis.get("record_offsets", {}).get("final", []):
        reported[entry["log"].removesuffix(".csv")] = entry["effort"]["value"]
    if reported:  # compare differences from the first record: a shared constant is not the offsets'
        first = next(iter(reported))
        row["offset_errors"] = {k: (v - reported[first]) - (zeros[k] - zeros[first]) for k, v in reported.items()}
    row["reported_zeros"] = reported
    row["validation_error"] = _validation_error(analysis)
    row["verdict"] += " + offsets named" if offsets_named else " + offsets not named"
    if row["validation_error"] is not None:
        row["verdict"] += f"; validation error {100 * row['validation_error']:.1f} %"
    return row


def judge_impedance(truth: dict, findings: list[dict], analysis: dict) -> dict:
    """Little excitation: right if the hidden effect is named first (any value within 20 %), or nothing is named;
    a wrong name is never right."""
    row = judge({**truth, "kind": "effect" if truth["hidden"] else "clean"}, findings, _current_library(),
                analysis.get("verdict", ""), TOLERANCE)
    if not findings:
        effect = truth["hidden"][0]["effect"] if truth["hidden"] else None
        why = (analysis.get("not_identifiable", {}).get(effect) if effect else None)
        row["verdict"] = (f"ok (nothing named: {analysis.get('verdict', '')}"
                          + (f"; cannot reveal {effect}: {why}" if why else "") + ")")
    elif truth["hidden"] and row["verdict"] == "right":
        row["verdict"] = "ok (right)"
    elif truth["hidden"] and row["verdict"].startswith("named"):
        row["verdict"] = "ok (named, value off)"
    elif row["verdict"].startswith("SPURIOUS"):
        row["verdict"] = "WRONG NAME (spurious on a clean log)"
    return row


def judge_gravity(truth: dict, findings: list[dict], analysis: dict) -> dict:
    """Gravity first, its amplitude within 25 % and its rest angle within 0.25 rad."""
    row = judge(truth, findings, _current_library(), analysis.get("verdict", ""), TOLERANCE)
    if row["first"] == "gravity":
        errors = row["errors"]
        amp_ok = errors.get("gravity_amplitude", math.inf) <= GRAVITY_TOLERANCE[0]
        angle_ok = errors.get("gravity_angle", math.inf) <= GRAVITY_TOLERANCE[1]
        row["verdict"] = "right" if amp_ok and angle_ok else "named, value off"
    return row


def judge_resampled(truth: dict, findings: list[dict], analysis: dict) -> dict:
    """The hidden effect named first within 20 %; a transport delay is noted against the converter's timing."""
    row = judge(truth, findings, _current_library(), analysis.get("verdict", ""), TOLERANCE)
    delay = truth["converter"]["apparent_delay_s"]
    for f in findings:
        if f["effect"] == "transport_delay":
            found = f["parameters"]["delay"]["value"]
            row["verdict"] += f" (transport_delay {1e3 * found:.2f} ms; the converter's {1e3 * delay:.2f} ms)"
    return row


JUDGES = {"rezeroed": judge_rezeroed, "impedance": judge_impedance, "gravity": judge_gravity,
          "resampled": judge_resampled}


def analyse_case(folder: Path, label: str = "", workers: int = 1) -> dict:
    """Analyse one written case (one configuration of its records) and judge it."""
    truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
    config = next(a for a in truth["analyses"] if a["label"] == label)
    t0 = time.perf_counter()
    try:
        result = run_analysis(folder, tuple(config["estimation"]), tuple(config["validation"]), workers)
        findings = [f.to_dict() for f in result.findings]
        analysis = _analysis_summary(result)
        error = None
    except Exception as err:  # a case the analysis refuses is a result too
        findings, analysis, error = [], {}, f"{type(err).__name__}: {err}"
    judged = JUDGES.get(truth["kind"], lambda t, f, a: judge({**t, "kind": "effect" if t["hidden"] else "clean"}, f,
                                                               _current_library(), a.get("verdict", ""), TOLERANCE))
    row = judged(truth, findings, analysis)
    row.update(case=truth["case"] + (f" [{label}]" if label else ""), kind=truth["kind"], label=label,
               hidden=[h["effect"] for h in truth["hidden"]],
               truth={h["effect"]: h.get("zeros", h["parameters"]) for h in truth["hidden"]},
               rig_states={h["effect"]: h["rig_states"] for h in truth["hidden"] if "rig_states" in h},
               seconds=time.perf_counter() - t0, error=error, findings=findings, analysis=analysis,
               records={"estimation": config["estimation"], "validation": config["validation"]})
    if error:
        row["verdict"] = f"ERROR ({error.split(':')[0]})"
    return row


def print_table(rows: list[dict], stream=sys.stdout) -> None:
    """One line per analysis: case, hidden truth, what was found in order, the first finding's values and
    relative error, verdict, seconds."""
    print("| case | hidden truth | found (in order) | first finding | rel. err | verdict | s |", file=stream)
    print("|---|---|---|---|---|---|---|", file=stream)
    for r in rows:
        truth = "; ".join(f"{effect}: {_fmt(p)}" + (f" (rig {_fmt(r['rig_states'][effect])})"
                                                       if effect in r.get("rig_states", {}) else "")
                          for effect, p in r["truth"].items()) or "-"
        err = "-" if r["first_error"] is None else f"{100 * r['first_error']:.1f} %"
        angle = r["errors"].get("gravity_angle")
        if angle is not None:
            err += f", angle {angle:.3f} rad"
        print(f"| {r['case']} | {truth} | {', '.join(r['found']) or '-'} | {_fmt(r['first_values']) or '-'} | "
              f"{err} | {r['verdict']} | {r['seconds']:.0f} |", file=stream)


def summarise(rows: list[dict]) -> dict:
    """The score per kind."""
    def count(kind: str, ok, label: str | None = "", hidden: bool | None = None) -> str:
        subset = [r for r in rows if r["kind"] == kind and (label is None or r.get("label", "") == label)
                  and (hidden is None or bool(r["hidden"]) == hidden)]
        return f"{sum(1 for r in subset if ok(r))}/{len(subset)}"

    def right(r: dict) -> bool:
        return r["verdict"].startswith("right")

    return {
        "pwm_effort_gain_named_first_within_20pct": count("pwm", right, hidden=True),
        "pwm_clean_nothing_named_and_not_unexplained": count("pwm", lambda r: r["verdict"].startswith("ok"),
                                                             hidden=False),
        "resampled_named_first_within_20pct": count("resampled", right),
        "resampled_drive_1khz_reference_named_first_within_20pct": count("resampled", right, "drive 1 kHz"),
        "drive_velocity_named_first_within_20pct": count("velocity", right),
        "rezeroed_coulomb_named_first_within_20pct": count("rezeroed", right, None),
        "rezeroed_record_offsets_named": count("rezeroed", lambda r: "offsets named" in r["verdict"], None),
        "rezeroed_validation_error": {r["case"]: r.get("validation_error") for r in rows if r["kind"] == "rezeroed"},
        "impedance_no_wrong_name": count("impedance", lambda r: r["verdict"].startswith("ok")),
        "gravity_named_first_within_25pct_and_0.25rad": count("gravity", right),
        "errors (refused)": f"{sum(1 for r in rows if r['error'])}/{len(rows)}",
        "analysis_seconds_total": sum(r["seconds"] for r in rows),
    }


# ------------------------------------------------------------------------------------------------------- CLI


def _generate(args: tuple[Case, str, float]) -> tuple[str, float]:
    case, out, duration = args
    truth = write_case(case, Path(out), duration)
    return case.name, truth["generation_s"]


def _analyse(args: tuple[str, str, int]) -> dict:
    folder, label, workers = args
    return analyse_case(Path(folder), label, workers)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="folder for the cases (outside the repository)")
    parser.add_argument("--only", default="*", help="fnmatch pattern of case names (default: all)")
    parser.add_argument("--duration", type=float, default=DURATION_S,
                        help=f"record length [s] (re-zeroed records: at most {RECORD_S:g})")
    parser.add_argument("--analyse", action="store_true", help="run the discrepancy analysis on each case")
    parser.add_argument("--workers", type=int, default=1, help="processes over cases (the analysis runs with 1)")
    parser.add_argument("--no-generate", action="store_true", help="analyse the cases already in --out")
    parser.add_argument("--list", action="store_true", help="print the case names and exit")
    args = parser.parse_args(argv)
    chosen = [c for c in cases() if fnmatch.fnmatch(c.name, args.only)]
    if args.list:
        print("\n".join(c.name for c in chosen))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    pool = ProcessPoolExecutor(args.workers) if args.workers > 1 else None
    mapper = pool.map if pool else map
    started = time.perf_counter()
    try:
        if not args.no_generate:
            for name, seconds in mapper(_generate, [(c, str(args.out), args.duration) for c in chosen]):
                print(f"generated {name} ({seconds:.1f} s)", file=sys.stderr, flush=True)
        generated = time.perf_counter() - started
        if args.analyse:
            jobs = [(str(args.out / c.name), label, 1) for c in chosen for label, _, _ in analyses(c)]
            rows = []
            for row in mapper(_analyse, jobs):
                print(f"analysed {row['case']}: {row['verdict']} ({row['seconds']:.0f} s)", file=sys.stderr,
                      flush=True)
                rows.append(row)
            print_table(rows)
            summary = summarise(rows)
            summary["generation_wall_s"] = generated
            summary["wall_s"] = time.perf_counter() - started
            write_summary(rows, summary, args.out)
    finally:
        if pool:
            pool.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
