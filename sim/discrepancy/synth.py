"""Synthetic "measured" logs: the simulator with hidden effects, realistic excitation and sensor noise.

Used by the hidden-effect tests and the benchmark: a log is made from a *truth* rig (the baseline with one or
more effects switched on or changed at a random value in a realistic range), and the analysis receives only
the log and the *baseline* rig.

Experiments (which make which effect identifiable, see ``docs/discrepancy.md``):

``locked``          locked fixture, open-loop torque: a slow ±8 N·m swing (0.3 Hz: load reversals, high torque,
                    slow sliding in the Stribeck region) plus a multisine (3.1 and 11 Hz), board temperature
                    ramped by 10 K (temperature chamber)
``free``            free fixture, the lever swung through ±3 rad by a position PD loop (velocity reversals,
                    several cogging periods, gravity), chamber ramp as above
``locked_pi_sensor``   locked fixture, PI torque control on the torque sensor (controllers.pi, paper gains)
``locked_pi_current``  locked fixture, PI torque control on the driver's current-based estimate
``slide``           rigid slide joint, position PD through ±0.2 m

Noise (assumed, typical of the parts): torque sensor 5 mN·m white (std), load cell 0.05 N (0.01 % of its
500 N), motor encoder 2^16 counts per motor turn (output-referred step 2π/(2^16·N)), lever encoder 2^17
counts per turn, linear encoder 1 µm. The motor encoder's resolution is a property of the rig: ``motor_encoder_counts``
of :func:`synth_log` / :func:`hidden_effect_log` makes logs of a finer encoder (``FINE_MOTOR_ENCODER_COUNTS``, a
22-bit rotor encoder as precision drives carry) or of an ideal one (``None``: no quantisation). Presliding
friction needs the fine one (docs/discrepancy.md, "Effects and the experiments that reveal them").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controllers.pi import PITorqueController
from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.rig import AddedEffect, Rig, rig_from_dict
from sim.discrepancy.simulate import run_rigid, run_testbed
from sim.logio import SlideRunLog
from sim.runlog import RunLog

TAU_SENSOR_NOISE_NM = 5e-3  # assumed: calibrated optical sensor, white noise std at 1 kHz
LOADCELL_NOISE_N = 0.05  # assumed: 0.01 % of the SBA-50L's 500 N
MOTOR_ENCODER_COUNTS = 2**16  # assumed: counts per motor turn (16-bit magnetic encoder on the rotor)
# a high-resolution rotor encoder (22 bits per turn: optical/inductive absolute encoders of precision servo drives
# reach 20-26 bits); resolves a tenth of the presliding displacement F_s/σ0 (>= 1.6e-5 rad in the drawn range)
FINE_MOTOR_ENCODER_COUNTS = 2**22
LEVER_ENCODER_COUNTS = 2**17  # assumed: absolute output encoder, counts per turn
LINEAR_ENCODER_STEP_M = 1e-6  # assumed: 1 µm linear scale
CHAMBER_RAMP_K = 10.0  # board temperature rise over a log in the chamber [K]

LOCKED_SWING_NM, LOCKED_SWING_HZ = 8.0, 0.3  # slow swing: reversals, 44 % of peak torque
LOCKED_TONES = ((0.5, 3.1), (0.3, 11.0))  # (amplitude [N·m], frequency [Hz]) of the multisine
FREE_SWING_RAD = ((2.5, 0.2), (0.6, 1.1))  # lever angle reference (amplitude [rad], frequency [Hz])
FREE_KP_NM_PER_RAD, FREE_KD_NMS_PER_RAD = 3.0, 0.15  # position PD of the free swing
FREE_COMMAND_LIMIT_NM = 4.0
SLIDE_SWING_M = ((0.15, 0.25), (0.04, 1.3))
SLIDE_KP_N_PER_M, SLIDE_KD_NS_PER_M = 400.0, 40.0
SLIDE_COMMAND_LIMIT_N = 60.0
PI_REFERENCE = ((4.0, 0.25), (0.6, 2.3))  # torque reference of the closed-loop logs (amplitude, frequency)
PI_BIAS_NM = 0.5

EXPERIMENTS = ("locked", "free", "locked_pi_sensor", "locked_pi_current", "slide")

BASELINE_SLIDE_RIG = {"model": "rigid-joint", "joint": "slide", "mass_kg": 2.0, "effort_gain": 1.0,
                      "peak_effort": 100.0, "friction": {"coulomb": 3.0, "viscous": 8.0}}


def baseline_rig(experiment: str) -> Rig:
    """The baseline rig description of an experiment (default testbed parameters, or the slide stage)."""
    if experiment == "slide":
        return rig_from_dict(BASELINE_SLIDE_RIG, source="slide baseline")
    fixture = "free" if experiment == "free" else "locked"
    return rig_from_dict({"model": "testbed", "fixture": fixture}, source=f"testbed {fixture} baseline")


# Realistic ranges of each hidden effect, (low, high) per parameter, drawn with a random sign/direction where
# listed. Values changed from the baseline are drawn away from it (at least the low bound of the change).
def draw_effect(name: str, rig: Rig, rng: np.random.Generator) -> tuple[dict[str, float], dict[str, float]]:
    """A random hidden effect: (native parameter overrides by theta key, added-effect parameters)."""
    u = rng.uniform
    up = rng.random() < 0.5
    slide = rig.joint == "slide"
    if name == "coulomb_friction":
        if slide:  # MuJoCo's frictionloss is one level: static and sliding move together
            level = rig.rigid["coulomb"] * (u(1.3, 1.6) if up else u(0.5, 0.7))
            return {"coulomb": level, "breakaway": level}, {}
        return {"coulomb": u(0.112, 0.125) if up else u(0.045, 0.07)}, {}  # baseline 0.09, below breakaway 0.13
    if name == "viscous_friction":
        base = rig.rigid["viscous"] if slide else rig.params.friction.viscous_nms_per_rad
        return {"viscous": base * (u(2.0, 3.0) if up else u(0.2, 0.4))}, {}
    if name == "stribeck_friction":
        return {"breakaway": u(0.17, 0.25), "stribeck_velocity": u(0.02, 0.1)}, {}
    if name == "asymmetric_friction":
        scale = 1.0 if not slide else 10.0
        return {}, {"asymmetry": scale * u(0.03, 0.06) * (1 if up else -1)}
    if name == "load_dependent_friction":
        return {"load_coefficient": u(0.15, 0.2) if up else u(0.03, 0.06)}, {}
    if name == "presliding_friction":
        # stiffer only: below the baseline the step rule lengthens the physics step past half the backlash stop's
        # tuned time constant, and the plant refuses the parameter set
        return {"presliding_stiffness": u(4000.0, 8000.0)}, {}
    if name == "backlash":
        return {"backlash_width": u(6e-3, 1e-2) if up else u(1e-3, 2e-3)}, {}
    if name == "cogging":
        if slide:
            return {}, {"cogging_amplitude": u(1.0, 2.0), "cogging_period": u(0.02, 0.04),
                        "cogging_phase": u(-math.pi, math.pi)}
        poles = int(rng.integers(10, 30))
        return {}, {"cogging_amplitude": u(0.02, 0.05), "cogging_period": 2 * math.pi / (8 * poles),
                    "cogging_phase": u(-math.pi, math.pi)}
    if name == "torque_constant_nonlinearity":
        return {}, {"torque_rolloff": u(0.05, 0.15)}
    if name == "transport_delay":
        return {"delay": u(2e-3, 6e-3)}, {}
    if name == "gravity":
        if slide:
            return {}, {"gravity_amplitude": u(3.0, 6.0) * (1 if up else -1), "gravity_angle": 0.0}
        return {}, {"gravity_amplitude": u(0.03, 0.06), "gravity_angle": u(-math.pi, math.pi)}
    if name == "sensor_offset":
        return {}, {"sensor_offset": u(0.03, 0.1) * (1 if up else -1)}
    if name == "sensor_gain":
        return {}, {"sensor_gain": 1.0 + u(0.02, 0.05) * (1 if up else -1)}
    if name == "sensor_thermal_drift":
        return {}, {"sensor_tempco": u(3e-3, 1e-2) * (1 if up else -1)}
    if name == "sensor_hysteresis":
        return {}, {"sensor_hysteresis": u(0.02, 0.05), "sensor_hysteresis_span": u(0.5, 2.0)}
    raise KeyError(f"unknown effect {name!r}; the library has: {', '.join(EFFECTS)}")


@dataclass(frozen=True)
class HiddenTruth:
    """What a synthetic log hides: per effect, its true parameters (theta keys, SI)."""

    effects: dict[str, dict[str, float]]
    rig: Rig = field(repr=False)

    def to_dict(self) -> dict:
        return {"effects": self.effects}


def truth_rig(baseline: Rig, effects: dict[str, tuple[dict[str, float], dict[str, float]]]) -> HiddenTruth:
    """The baseline with hidden effects: native overrides become parameters, the rest added effects."""
    native: dict[str, float] = {}
    added = []
    truth: dict[str, dict[str, float]] = {}
    for name, (overrides, extra) in effects.items():
        native.update(overrides)
        if extra:
            added.append(AddedEffect(name, extra))
        truth[name] = {**overrides, **extra}
    return HiddenTruth(truth, baseline.with_effects(tuple(added), native))


def _sensor_reading(truth: Rig, tau: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """The torque sensor's output for the true flexure torque (its effects applied, noise not yet)."""
    from sim.discrepancy.model import play_operator  # the same elastic-plastic element the analysis fits

    values = {"sensor_offset": 0.0, "sensor_gain": 1.0, "sensor_tempco": 0.0, "sensor_hysteresis": 0.0,
              "sensor_hysteresis_span": 1.0}
    for effect in truth.effects:
        values.update({k: v for k, v in effect.parameters.items() if k in values})
    reading = values["sensor_gain"] * tau + values["sensor_offset"]
    reading = reading + values["sensor_tempco"] * (temperature - truth.params.photoreflector.reference_temperature_c)
    if values["sensor_hysteresis"]:
        span = values["sensor_hysteresis_span"]
        reading = reading + values["sensor_hysteresis"] / span * (tau - play_operator(tau, span))
    return reading


def _quantise(x: np.ndarray, step: float) -> np.ndarray:
    return np.round(x / step) * step


def synth_log(experiment: str, truth: Rig, duration_s: float, seed: int, *,
              motor_encoder_counts: int | None = MOTOR_ENCODER_COUNTS) -> RunLog:
    """A measured-like log of ``experiment`` run on the ``truth`` rig, with sensor noise drawn from ``seed``.

    Parameters
    ----------
    experiment : str
        One of ``EXPERIMENTS``.
    truth : Rig
        The rig that produces the log (hidden effects included).
    duration_s : float
        Log length [s] (1 kHz samples).
    seed : int
        Seed of the sensor noise.
    motor_encoder_counts : int or None
        Motor encoder counts per motor turn [1] (``q_motor`` is quantised to 2π/(counts·N) at the output);
        None: an ideal encoder (no quantisation). Ignored by the slide (no motor encoder).
    """
    if experiment not in EXPERIMENTS:
        raise ValueError(f"experiment = {experiment!r}: valid values are {', '.join(EXPERIMENTS)}")
    if motor_encoder_counts is not None and (int(motor_encoder_counts) != motor_encoder_counts
                                             or motor_encoder_counts < 1):
        raise ValueError(f"motor_encoder_counts = {motor_encoder_counts!r}: a positive integer (counts per motor "
                         "turn) or None (ideal encoder)")
    rng = np.random.default_rng(seed)
    n = int(round(duration_s / 1e-3))
    t_of = lambda k: k * 1e-3  # noqa: E731  (command k is sent at the start of tick k)
    noise_tau = rng.normal(0.0, TAU_SENSOR_NOISE_NM, n)
    if experiment == "slide":
        def command(k: int, s: dict[str, float]) -> float:
            ref = sum(a * math.sin(2 * math.pi * f * t_of(k)) for a, f in SLIDE_SWING_M)
            u = SLIDE_KP_N_PER_M * (ref - s["q"]) - SLIDE_KD_NS_PER_M * s["qd"]
            return min(max(u, -SLIDE_COMMAND_LIMIT_N), SLIDE_COMMAND_LIMIT_N)

        run = run_rigid(truth, command, n)
        cols = {"time": run.columns["time"], "tau_cmd": run.columns["tau_cmd"],
                "q": _quantise(run.columns["q"], LINEAR_ENCODER_STEP_M)}
        return SlideRunLog(cols, {"time": "s", "tau_cmd": "N", "q": "m"}, {"experiment": experiment, "seed": seed})

    n_gear = truth.params.motor.gear_ratio
    if experiment == "locked":
        def command(k: int, s: dict[str, float]) -> float:
            t = t_of(k)
            return (LOCKED_SWING_NM * math.sin(2 * math.pi * LOCKED_SWING_HZ * t)
                    + sum(a * math.sin(2 * math.pi * f * t) for a, f in LOCKED_TONES))
    elif experiment == "free":
        def command(k: int, s: dict[str, float]) -> float:
            ref = sum(a * math.sin(2 * math.pi * f * t_of(k)) for a, f in FREE_SWING_RAD)
            u = FREE_KP_NM_PER_RAD * (ref - s["q"]) - FREE_KD_NMS_PER_RAD * s["qd"]
            return min(max(u, -FREE_COMMAND_LIMIT_NM), FREE_COMMAND_LIMIT_NM)
    else:
        pi = PITorqueController(output_limit_nm=truth.params.motor.peak_torque_nm)
        feedback = "tau_sensor" if experiment == "locked_pi_sensor" else "tau_current_estimate"
        sensor_rig = truth

        def command(k: int, s: dict[str, float]) -> float:
            t = t_of(k)
            ref = PI_BIAS_NM + sum(a * math.sin(2 * math.pi * f * t) for a, f in PI_REFERENCE)
            if feedback == "tau_sensor":  # what the controller sees is the sensor's (effects and noise) reading
                measured = float(_sensor_reading(sensor_rig, np.array([s["tau_flexure"]]),
                                                 np.array([truth.params.photoreflector.reference_temperature_c]))[0])
                measured += noise_tau[k - 1] if k else 0.0
            else:
                measured = s["tau_current_estimate"]
            return pi.step(ref, measured)

    run = run_testbed(truth, command, n)
    c = run.columns
    temperature = c["temperature"] + CHAMBER_RAMP_K * (c["time"] - c["time"][0]) / (c["time"][-1] - c["time"][0])
    tau_sensor = _sensor_reading(truth, c["tau_flexure"], temperature) + noise_tau
    cols = {"time": c["time"], "tau_cmd": c["tau_cmd"],
            "q": _quantise(c["q"], 2 * math.pi / LEVER_ENCODER_COUNTS),
            "q_motor": (c["q_motor"] if motor_encoder_counts is None else
                        _quantise(c["q_motor"], 2 * math.pi / (motor_encoder_counts * n_gear))),
            "tau_sensor": tau_sensor, "temperature": temperature}
    units = {"time": "s", "tau_cmd": "N·m", "q": "rad", "q_motor": "rad", "tau_sensor": "N·m", "temperature": "°C"}
    if truth.fixture == "locked":
        cols["force_loadcell"] = c["force_loadcell"] + rng.normal(0.0, LOADCELL_NOISE_N, n)
        units["force_loadcell"] = "N"
    return RunLog(cols, units, {"experiment": experiment, "seed": seed, "fixture": truth.fixture,
                                "motor_encoder_counts": motor_encoder_counts})


def hidden_effect_log(experiment: str, effects: list[str], seed: int, duration_s: float, *,
                      motor_encoder_counts: int | None = MOTOR_ENCODER_COUNTS) -> tuple[RunLog, Rig, HiddenTruth]:
    """A log with ``effects`` hidden at random values (drawn from ``seed``), the baseline rig, and the truth.

    ``motor_encoder_counts``: counts per motor turn of the log's motor encoder, None for an ideal one (see
    :func:`synth_log`). The analysis is not told: it reads the resolution from the log (smallest step of
    ``q_motor``).
    """
    baseline = baseline_rig(experiment)
    rng = np.random.default_rng(seed)
    drawn = {name: draw_effect(name, baseline, rng) for name in effects}
    truth = truth_rig(baseline, drawn)
    log = synth_log(experiment, truth.rig, duration_s, seed, motor_encoder_counts=motor_encoder_counts)
    return log, baseline, truth
