"""The library of candidate effects: named physical extensions of the model, their parameters and units.

Every effect acts on the surrogate (:mod:`sim.discrepancy.model`) through named entries of the parameter
vector ``theta`` (one physical value each, SI). An effect whose parameters the baseline already carries with
a non-neutral value (Coulomb level, viscous coefficient, ...) is the *same* named effect with a different
value: the finding reports the fitted value beside the baseline's.

Effect (parameters)                               what it changes
------------------------------------------------  -------------------------------------------------------------
coulomb_friction (coulomb)                        sliding friction level F_c [N·m | N]
viscous_friction (viscous)                        friction proportional to velocity σ2 [N·m·s/rad | N·s/m]
stribeck_friction (breakaway, stribeck_velocity)  static level F_s and Stribeck velocity v_s of
                                                  g(v) = F_c + (F_s - F_c)·exp(-(v/v_s)²)
asymmetric_friction (asymmetry)                   F_c+ - F_c- [N·m | N]: friction levels differ by direction;
                                                  a constant torque Δ/2 opposing positive motion
load_dependent_friction (load_coefficient)        dry friction μ·|transmitted torque| (gear efficiency) [1]
presliding_friction (presliding_stiffness)        LuGre bristle stiffness σ0 [N·m/rad] (elastic motion in stick)
backlash (backlash_width)                         dead band between gear and sensor hub [rad]
cogging (cogging_amplitude, _period, _phase)      A·sin(2π·q_motor/P + φ) [N·m], P [rad], φ [rad]
torque_constant_nonlinearity (torque_rolloff)     delivered = u·(1 - c·min(|u|/u_peak, 1)²): fraction c
                                                  of the command lost at peak effort (magnetic saturation;
                                                  on the testbed u_peak is the rated peak torque) [1]
transport_delay (delay)                           command-to-torque dead time [s]
gravity (gravity_amplitude, gravity_angle)        load A·sin(q - q0) [N·m] (hinge), constant A [N] (slide)
sensor_offset (sensor_offset)                     torque sensor zero error b [N·m]
sensor_gain (sensor_gain)                         torque sensor scale g [1]
sensor_thermal_drift (sensor_tempco)              zero drift c_T·(T - T_cal) [N·m/K]
sensor_hysteresis (sensor_hysteresis, _span)      elastic-plastic (Prandtl) loop of half-height H [N·m] that
                                                  saturates after a torque change of S [N·m]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TESTBED_ONLY = "testbed"
ANY_RIG = "any"


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect: ``key`` of theta, units for a hinge and a slide joint, valid range."""

    key: str
    unit_hinge: str
    unit_slide: str
    low: float
    high: float
    description: str

    def unit(self, joint: str) -> str:
        return self.unit_slide if joint == "slide" else self.unit_hinge


@dataclass(frozen=True)
class EffectSpec:
    """A named physical effect: its parameters, where it applies, and its residual channel."""

    name: str
    params: tuple[ParamSpec, ...]
    rigs: str  # TESTBED_ONLY or ANY_RIG
    channel: str  # the residual channel it is expected to change most ('effort', 'sensor', 'kinematic')
    description: str

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(p.key for p in self.params)


def _p(key: str, unit_hinge: str, unit_slide: str, low: float, high: float, description: str) -> ParamSpec:
    return ParamSpec(key, unit_hinge, unit_slide, low, high, description)


MAX_FRICTION = 50.0  # [N·m | N] upper bound of any friction level a fit may return (far above both rigs')
MAX_DELAY_S = 0.02  # [s] the plant accepts command delays up to 20 control periods (sim.params)
TWO_PI = 2.0 * math.pi

EFFECTS: dict[str, EffectSpec] = {spec.name: spec for spec in (
    EffectSpec("coulomb_friction", (
        _p("coulomb", "N·m", "N", 0.0, MAX_FRICTION, "sliding (Coulomb) friction level"),), ANY_RIG, "effort",
        "dry friction level while sliding"),
    EffectSpec("viscous_friction", (
        _p("viscous", "N·m·s/rad", "N·s/m", 0.0, 100.0, "viscous friction coefficient"),), ANY_RIG, "effort",
        "friction proportional to velocity (grease, bearings)"),
    EffectSpec("stribeck_friction", (
        _p("breakaway", "N·m", "N", 0.0, MAX_FRICTION, "static (breakaway) friction level"),
        _p("stribeck_velocity", "rad/s", "m/s", 1e-4, 10.0, "Stribeck velocity")), ANY_RIG, "effort",
        "friction falling from the static to the Coulomb level with velocity"),
    EffectSpec("asymmetric_friction", (
        _p("asymmetry", "N·m", "N", -MAX_FRICTION, MAX_FRICTION,
           "F_c+ - F_c-: positive-direction minus negative-direction friction level"),), ANY_RIG, "effort",
        "friction levels that differ with the direction of motion"),
    EffectSpec("load_dependent_friction", (
        _p("load_coefficient", "1", "1", 0.0, 1.0, "dry friction per unit transmitted torque (1 - η)"),),
        TESTBED_ONLY, "effort", "gear friction growing with the transmitted torque (efficiency)"),
    EffectSpec("presliding_friction", (
        _p("presliding_stiffness", "N·m/rad", "N/m", 10.0, 1e6, "LuGre bristle stiffness σ0"),),
        TESTBED_ONLY, "effort", "elastic (presliding) displacement before breakaway"),
    EffectSpec("backlash", (
        _p("backlash_width", "rad", "m", 0.0, 0.2, "total dead band between gear and hub"),), TESTBED_ONLY,
        "kinematic", "dead band in the gear: the hub lags the motor by half the band after a torque reversal"),
    EffectSpec("cogging", (
        _p("cogging_amplitude", "N·m", "N", 0.0, MAX_FRICTION, "cogging torque amplitude"),
        _p("cogging_period", "rad", "m", 1e-4, TWO_PI, "period in joint position"),
        _p("cogging_phase", "rad", "rad", -math.pi, math.pi, "phase at position 0")), ANY_RIG, "effort",
        "position-periodic torque of the magnets"),
    EffectSpec("torque_constant_nonlinearity", (
        _p("torque_rolloff", "1", "1", -0.5, 0.9, "fraction of the command lost at peak effort"),), ANY_RIG,
        "effort", "torque per command falling at high current (magnetic saturation)"),
    EffectSpec("transport_delay", (
        _p("delay", "s", "s", 0.0, MAX_DELAY_S, "command-to-torque dead time"),), ANY_RIG, "effort",
        "dead time between the logged command and the torque"),
    EffectSpec("gravity", (
        _p("gravity_amplitude", "N·m", "N", -100.0, 100.0, "m·g·r (hinge) or m·g·sin(incline) (slide)"),
        _p("gravity_angle", "rad", "rad", -math.pi, math.pi, "joint angle of zero gravity torque")), ANY_RIG,
        "effort", "weight of the moving part on a tilted axis"),
    EffectSpec("sensor_offset", (
        _p("sensor_offset", "N·m", "N·m", -50.0, 50.0, "zero error of the torque sensor"),), ANY_RIG, "sensor",
        "torque sensor zero error"),
    EffectSpec("sensor_gain", (
        _p("sensor_gain", "1", "1", 0.5, 2.0, "scale of the torque sensor"),), ANY_RIG, "sensor",
        "torque sensor scale error"),
    EffectSpec("sensor_thermal_drift", (
        _p("sensor_tempco", "N·m/K", "N·m/K", -1.0, 1.0, "zero drift per kelvin from the calibration "
           "temperature"),), ANY_RIG, "sensor", "torque sensor zero drifting with board temperature"),
    EffectSpec("sensor_hysteresis", (
        _p("sensor_hysteresis", "N·m", "N·m", -5.0, 5.0, "loop half-height (positive: reads high while loading up)"),
        _p("sensor_hysteresis_span", "N·m", "N·m", 1e-3, 50.0, "torque change that saturates the loop")),
        ANY_RIG, "sensor", "torque sensor reading that depends on the loading direction"),
)}

# Which theta keys an effect "switches off" when absent (neutral values); keys not listed are baseline.
NEUTRAL: dict[str, float] = {
    "asymmetry": 0.0, "cogging_amplitude": 0.0, "torque_rolloff": 0.0, "gravity_amplitude": 0.0,
    "sensor_offset": 0.0, "sensor_gain": 1.0, "sensor_tempco": 0.0, "sensor_hysteresis": 0.0,
}


# Parameters the baseline model carries natively (the testbed's sim.params, a rigid joint's friction and delay):
# an effect made only of these, with nonzero current values, is a baseline effect with another value.
NATIVE_KEYS = frozenset({"coulomb", "viscous", "breakaway", "stribeck_velocity", "load_coefficient",
                         "presliding_stiffness", "backlash_width", "delay"})


def spec(name: str) -> EffectSpec:
    """The effect called ``name``; an unknown name raises ``KeyError`` listing the library."""
    try:
        return EFFECTS[name]
    except KeyError:
        raise KeyError(f"unknown effect {name!r}; the library has: {', '.join(EFFECTS)}") from None


def effect_of_key(key: str) -> EffectSpec:
    """The effect that owns theta entry ``key``."""
    for effect in EFFECTS.values():
        if key in effect.keys:
            return effect
    raise KeyError(f"no effect owns parameter {key!r}")


def canonical(theta: dict[str, float], joint: str) -> dict[str, float]:
    """One representative of parameter sets that describe the same physics: a hinge's gravity load
    ``A·sin(q - q0)`` equals ``-A·sin(q - q0 - π)``, kept with ``A >= 0`` and ``q0`` in [-π, π)."""
    if joint == "hinge" and theta.get("gravity_amplitude", 0.0) < 0.0:
        theta = dict(theta)
        theta["gravity_amplitude"] = -theta["gravity_amplitude"]
        theta["gravity_angle"] = (theta["gravity_angle"] + 2.0 * math.pi) % (2.0 * math.pi) - math.pi
    return theta


def rolled_off(u: float | np.ndarray, rolloff: float, peak: float, limit: float) -> float | np.ndarray:
    """The effort command after the drive's clip at ±``limit`` and the ``torque_constant_nonlinearity`` roll-off:
    u·(1 - c·min(|u|/peak, 1)²), the lost fraction growing to c at peak effort and staying there [N·m | N].
    Floats and arrays alike; the one definition the simulator (``simulate.command_map``) and the surrogate
    (``Surrogate.delivered``) share."""
    u = np.clip(u, -limit, limit)
    if rolloff and math.isfinite(peak):
        u = u * (1.0 - rolloff * np.minimum(np.abs(u) / peak, 1.0) ** 2)
    return u
