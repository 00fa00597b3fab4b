"""Synthetic "measured" logs: the simulator with hidden effects, realistic excitation and sensor noise.

Used by the hidden-effect tests, the benchmark and ``experiments.discrepancy_demo``: a log is made from a
*truth* rig (the baseline with one or more effects switched on or changed at a random value in a realistic
range), and the analysis receives only the log and the *baseline* rig.

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
from sim.discrepancy.effects import rig_kind, spec
from sim.discrepancy.rig import AddedEffect, Rig, rig_from_dict
from sim.discrepancy.signals import quantise
from sim.discrepancy.simulate import run_rigid, run_testbed, sensor_reading
from sim.logio import SlideRunLog
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams, field_range
from sim.runlog import HOLD_END, RunLog

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
HINGE_SWING_RAD = ((1.5, 0.25), (0.4, 1.3))  # rigid hinge: position reference (amplitude [rad], frequency [Hz])
HINGE_KP_NM_PER_RAD, HINGE_KD_NMS_PER_RAD = 10.0, 1.0
HINGE_COMMAND_LIMIT_NM = 2.6
HINGE_ENCODER_COUNTS = 2**17  # assumed: counts per turn of the rigid hinge's encoder
SLIDE_KP_N_PER_M, SLIDE_KD_NS_PER_M = 400.0, 40.0
SLIDE_COMMAND_LIMIT_N = 14.0
PI_REFERENCE = ((4.0, 0.25), (0.6, 2.3))  # torque reference of the closed-loop logs (amplitude, frequency)
PI_BIAS_NM = 0.5

EXPERIMENTS = ("locked", "free", "locked_pi_sensor", "locked_pi_current", "slide", "hinge", "slide_moves",
               "hinge_moves")
RIGID_EXPERIMENTS = ("slide", "hinge", "slide_moves", "hinge_moves")
TESTBED_EXPERIMENTS = tuple(e for e in EXPERIMENTS if e not in RIGID_EXPERIMENTS)
MOVES = {"hinge": 0.5, "slide": 0.05}  # point-to-point moves between ± this [rad | m] ...
MOVE_S, DWELL_S = 2.0, 0.5  # ... each taking MOVE_S with a raised-cosine velocity, then a dwell of DWELL_S [s]
# The experiment whose log reveals each effect (docs/discrepancy.md, "Effects and the experiments that reveal
# them"; the hidden-effect sweep recovers each from it). Presliding also needs a fine motor encoder.
REVEALING_EXPERIMENT = {
    "coulomb_friction": "free", "viscous_friction": "free", "stribeck_friction": "free",
    "asymmetric_friction": "free", "load_dependent_friction": "locked", "presliding_friction": "locked_pi_current",
    "backlash": "locked", "cogging": "free", "torque_constant_nonlinearity": "locked", "transport_delay": "free",
    "gravity": "free", "sensor_offset": "locked", "sensor_gain": "locked", "sensor_thermal_drift": "locked",
    "sensor_hysteresis": "locked", "effort_gain": "locked", "quadratic_drag": "free", "position_spring": "free",
    "periodic_disturbance": "free", "drivetrain_compliance": "hinge", "inertia": "hinge",
}

# peak efforts ~1.3 x the swings' largest command, so that the roll-off shows (commands reach ~75 % of the peak)
BASELINE_SLIDE_RIG = {"model": "rigid-joint", "joint": "slide", "mass_kg": 2.0, "effort_gain": 1.0,
                      "peak_effort": SLIDE_COMMAND_LIMIT_N, "friction": {"coulomb": 3.0, "viscous": 8.0}}
BASELINE_HINGE_RIG = {"model": "rigid-joint", "joint": "hinge", "inertia_kgm2": 0.05, "effort_gain": 1.0,
                      "peak_effort": HINGE_COMMAND_LIMIT_NM, "friction": {"coulomb": 0.3, "viscous": 0.05}}
RIGID_BASELINES = {"slide": BASELINE_SLIDE_RIG, "hinge": BASELINE_HINGE_RIG}


def baseline_rig(experiment: str, overrides: dict[str, dict[str, float]] | None = None) -> Rig:
    """The baseline rig description of an experiment: the testbed (``sim.params`` defaults, or ``overrides`` in the
    ``--params`` schema, e.g. ``{"friction": {"load_friction_coefficient": 0.1}}``), or the slide stage."""
    if experiment in RIGID_EXPERIMENTS:
        if overrides:
            raise ValueError(f"overrides apply to the testbed's parameters, not the rigid {experiment}")
        joint = experiment.split("_")[0]
        return rig_from_dict(RIGID_BASELINES[joint], source=f"{joint} baseline")
    fixture = "free" if experiment == "free" else "locked"
    return rig_from_dict({"model": "testbed", "fixture": fixture, **(overrides or {})},
                         source=f"testbed {fixture} baseline")


# Plausible ranges of the testbed's baseline parameters that shape the analysed logs: a user's rig differs from
# the defaults of sim.params, and the analysis must give no finding on a log of the rig it is told about
# whatever its values (tests/test_discrepancy*.py draw baselines from these). (group, field): (low, high).
BASELINE_RANGES: dict[tuple[str, str], tuple[float, float]] = {
    # N·m: the paper's stiction threshold 0.13 N·m (Sec. IV) of one unit, ±40 % for other units, greases, wear
    ("friction", "breakaway_torque_nm"): (0.08, 0.18),
    # [1] Coulomb/breakaway: 0.6 (a marked Stribeck drop) to 0.96 (almost none), the span of the grid of
    # experiments/identify_defaults.py (0.09/0.13 = 0.7 and 0.125/0.13 = 0.96)
    ("friction", "coulomb_fraction_of_breakaway"): (0.6, 0.96),
    # rad/s: the assumed 0.05 rad/s of sim.params, halved to doubled
    ("friction", "stribeck_velocity_rad_s"): (0.025, 0.1),
    # N·m·s/rad: the assumed 0.02 N·m·s/rad of sim.params, halved to doubled
    ("friction", "viscous_nms_per_rad"): (0.01, 0.04),
    # [1] 1 - η of one planetary stage of catalogue efficiency 0.85-0.98 (identify_defaults: 0.03, 0.05;
    # sim.params default 0.05)
    ("friction", "load_friction_coefficient"): (0.02, 0.15),
    # 1/(N·m): the whole valid range of sim.params; sim.plant applies it (sim.motor_torque) and the surrogate
    # carries it as a constant of the rig, so a baseline with any value must come out clean
    ("motor", "torque_saturation_per_nm"): field_range(TestbedParams(), "motor", "torque_saturation_per_nm"),
    # rad: 0.5 mrad (identify_defaults' grid-best, the sim.params default) to 3.5 mrad (0.2°, a looser stage)
    ("backlash", "width_rad"): (0.5e-3, 3.5e-3),
}
# the parameter set experiments/identify_defaults.py prefers against the paper's Tables VI-VII (the sim.params
# defaults), kept explicit so its tests still hold it if the defaults move
GRID_BEST_OVERRIDES: dict[str, dict[str, float]] = {
    "friction": {"coulomb_torque_nm": 0.09, "load_friction_coefficient": 0.05},
    "motor": {"torque_saturation_per_nm": 0.0176}, "backlash": {"width_rad": 0.5e-3}}


def random_baseline_overrides(seed: int) -> dict[str, dict[str, float]]:
    """Testbed parameter overrides drawn uniformly from ``BASELINE_RANGES`` with ``seed`` (``--params`` schema)."""
    rng = np.random.default_rng(seed)
    drawn = {key: float(rng.uniform(low, high)) for key, (low, high) in BASELINE_RANGES.items()}
    breakaway = drawn.pop(("friction", "breakaway_torque_nm"))
    fraction = drawn.pop(("friction", "coulomb_fraction_of_breakaway"))
    out: dict[str, dict[str, float]] = {"friction": {"breakaway_torque_nm": breakaway,
                                                     "coulomb_torque_nm": fraction * breakaway}}
    for (group, name), value in drawn.items():
        out.setdefault(group, {})[name] = value
    return out


def draw_effect(name: str, rig: Rig, rng: np.random.Generator) -> tuple[dict[str, float], dict[str, float]]:
    """A random hidden effect from its module's synthetic range (``Effect.draw``): (the rig's own parameters it
    changes, by theta key; the parameters of an added effect).

    Parameters
    ----------
    name : str
        An effect of the library (``sim.discrepancy.effects.EFFECTS``).
    rig : Rig
        The baseline rig; effects it already carries are changed relative to its values.
    rng : numpy.random.Generator
        The draw's random source.
    """
    effect = spec(name)
    if not effect.applies(rig):
        raise ValueError(f"{name} does not apply to a {rig_kind(rig)} rig (it applies to: "
                         f"{', '.join(sorted(effect.rigs))})")
    values = effect.draw(rig, rng)
    if effect.native(rig):
        return values, {}
    extra = {k: v for k, v in values.items() if k in effect.keys}
    return {k: v for k, v in values.items() if k not in extra}, extra


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


def point_to_point(t: float, amplitude: float) -> float:
    """Moves between -amplitude and +amplitude, each MOVE_S long with a raised-cosine velocity profile, then a
    dwell of DWELL_S [rad | m] (position reference at time t [s])."""
    cycle = MOVE_S + DWELL_S
    k, phase = divmod(t, cycle)
    start = -amplitude if int(k) % 2 == 0 else amplitude
    if phase >= MOVE_S:
        return -start
    s = phase / MOVE_S
    return start - 2.0 * start * (s - math.sin(2 * math.pi * s) / (2 * math.pi))


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
    if experiment in RIGID_EXPERIMENTS:
        joint = experiment.split("_")[0]
        slide = joint == "slide"
        swing, kp, kd, limit = (
            (SLIDE_SWING_M, SLIDE_KP_N_PER_M, SLIDE_KD_NS_PER_M, SLIDE_COMMAND_LIMIT_N) if slide
            else (HINGE_SWING_RAD, HINGE_KP_NM_PER_RAD, HINGE_KD_NMS_PER_RAD, HINGE_COMMAND_LIMIT_NM))
        if experiment.endswith("_moves"):
            reference = lambda t: point_to_point(t, MOVES[joint])  # noqa: E731
        else:
            reference = lambda t: sum(a * math.sin(2 * math.pi * f * t) for a, f in swing)  # noqa: E731

        def command(k: int, s: dict[str, float]) -> float:
            return min(max(kp * (reference(t_of(k)) - s["q"]) - kd * s["qd"], -limit), limit)

        run = run_rigid(truth, command, n)
        step = LINEAR_ENCODER_STEP_M if slide else 2 * math.pi / HINGE_ENCODER_COUNTS
        cols = {"time": run.columns["time"], "tau_cmd": run.columns["tau_cmd"], "q": quantise(run.columns["q"], step)}
        meta = {"experiment": experiment, "seed": seed, "time_convention": HOLD_END}
        if slide:
            return SlideRunLog(cols, {"time": "s", "tau_cmd": "N", "q": "m"}, meta)
        return RunLog(cols, {"time": "s", "tau_cmd": "N·m", "q": "rad"}, meta)

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
        pi = PITorqueController(output_limit_nm=CurrentToTorqueMap.from_params(truth.params).command_limit_nm)
        feedback = "tau_sensor" if experiment == "locked_pi_sensor" else "tau_current_estimate"
        sensor_rig = truth

        def command(k: int, s: dict[str, float]) -> float:
            t = t_of(k)
            ref = PI_BIAS_NM + sum(a * math.sin(2 * math.pi * f * t) for a, f in PI_REFERENCE)
            if feedback == "tau_sensor":  # what the controller sees is the sensor's (effects and noise) reading
                measured = float(sensor_reading(sensor_rig, np.array([s["tau_flexure"]]),
                                                 np.array([truth.params.photoreflector.reference_temperature_c]))[0])
                measured += noise_tau[k - 1] if k else 0.0
            else:
                measured = s["tau_current_estimate"]
            return pi.update(ref, measured)

    run = run_testbed(truth, command, n)
    c = run.columns
    temperature = c["temperature"] + CHAMBER_RAMP_K * (c["time"] - c["time"][0]) / (c["time"][-1] - c["time"][0])
    tau_sensor = sensor_reading(truth, c["tau_flexure"], temperature) + noise_tau
    cols = {"time": c["time"], "tau_cmd": c["tau_cmd"],
            "q": quantise(c["q"], 2 * math.pi / LEVER_ENCODER_COUNTS),
            "q_motor": (c["q_motor"] if motor_encoder_counts is None else
                        quantise(c["q_motor"], 2 * math.pi / (motor_encoder_counts * n_gear))),
            "tau_sensor": tau_sensor, "temperature": temperature}
    units = {"time": "s", "tau_cmd": "N·m", "q": "rad", "q_motor": "rad", "tau_sensor": "N·m", "temperature": "°C"}
    if truth.fixture == "locked":
        cols["force_loadcell"] = c["force_loadcell"] + rng.normal(0.0, LOADCELL_NOISE_N, n)
        units["force_loadcell"] = "N"
    return RunLog(cols, units, {"experiment": experiment, "seed": seed, "fixture": truth.fixture,
                                "motor_encoder_counts": motor_encoder_counts, "time_convention": HOLD_END})


def hidden_effect_log(experiment: str, effects: list[str], seed: int, duration_s: float, *,
                      motor_encoder_counts: int | None = MOTOR_ENCODER_COUNTS,
                      baseline: dict[str, dict[str, float]] | None = None) -> tuple[RunLog, Rig, HiddenTruth]:
    """A log with ``effects`` hidden at random values (drawn from ``seed``), the baseline rig, and the truth.

    Parameters
    ----------
    experiment : str
        One of ``EXPERIMENTS``.
    effects : list of str
        Effects to hide (none: a log of the baseline itself).
    seed : int
        Seed of the effects' values and of the sensor noise.
    duration_s : float
        Log length [s].
    motor_encoder_counts : int or None
        Counts per motor turn of the log's motor encoder, None for an ideal one (see :func:`synth_log`). The
        analysis is not told: it reads the resolution from the log (smallest step of ``q_motor``).
    baseline : dict, optional
        Testbed parameter overrides of the baseline rig (``--params`` schema; default: the ``sim.params``
        defaults); hidden effects the baseline carries are changed relative to its values.
    """
    rig = baseline_rig(experiment, baseline)
    rng = np.random.default_rng(seed)
    drawn = {name: draw_effect(name, rig, rng) for name in effects}
    truth = truth_rig(rig, drawn)
    log = synth_log(experiment, truth.rig, duration_s, seed, motor_encoder_counts=motor_encoder_counts)
    return log, rig, truth
