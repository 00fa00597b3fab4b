"""The testbed's physical parameters: one typed source of truth.

Every field is SI, carries its unit and its source in ``field.metadata`` and a valid range. Groups follow the
parts of the rig (motor, gear friction, backlash, flexure, output flange, lever, load cell, thermal,
simulation). Values are given *at the gear output* where a user would measure them (friction torques,
presliding stiffness); the model builder converts them to motor-shaft units for MuJoCo.

Overrides come from TOML (``[group] field = value``) through :func:`load_params`; an unknown key, a wrong
type or a value out of range raises :class:`ParameterError` naming the field, the value and the range.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from models.errors import ParameterError

INF = math.inf
SUBSTEPS_RULES = ("accurate", "fast")  # values of simulation.substeps_rule


def range_text(low: float, high: float, *, low_open: bool = False) -> str:
    """``[low, high]`` as accepted by a finite-number check: an infinite end is open (``inf`` is refused)."""
    left = "(" if low_open or math.isinf(low) else "["
    right = ")" if math.isinf(high) else "]"
    return f"{left}{low:g}, {high:g}{right}"


def quantity(default: float, unit: str, source: str, low: float = -INF, high: float = INF,
             *, low_open: bool = False, bound: tuple[float, float] | None = None, bound_source: str = "") -> Any:
    """A dataclass field with unit, source and valid range ``[low, high]`` (``(low, high]`` if low_open).

    ``bound`` is the interval ``(lo, hi)`` the value's source allows (a datasheet spread, a paper's "≈", a
    plausible range for an assumption), with ``bound_source`` saying where it comes from; the valid range is a
    sanity limit, the bound what an identification may search."""
    if (bound is None) != (not bound_source):
        raise ValueError(f"quantity(source={source[:40]!r}...): bound and bound_source come together")
    if bound is not None and not bound[0] <= bound[1]:
        raise ValueError(f"quantity(source={source[:40]!r}...): bound {bound} has lo > hi")
    return field(default=default, metadata={"unit": unit, "source": source, "low": low, "high": high,
                                            "low_open": low_open, "bound": bound, "bound_source": bound_source})


def choice(default: str, choices: tuple[str, ...], source: str) -> Any:
    """A dataclass field that takes one of the strings ``choices`` (unit "1": a name, not a quantity)."""
    return field(default=default, metadata={"unit": "1", "source": source, "choices": choices})


@dataclass(frozen=True)
class MotorParams:
    """SteadyWin GIM8108 BLDC with its planetary stage, torque-commanded through the driver's current loop."""

    gear_ratio: float = quantity(
        8.0, "1", "assumed: GIM8108-8 variant (SteadyWin names the planetary ratio in the suffix); the 8:1 "
        "model is the one rated 18 N·m peak as the paper states (Sec. II)", 1.0, 200.0,
        bound=(8.0, 8.0), bound_source="assumed: the 18 N·m peak (paper Sec. II) fixes the GIM8108-8 variant; not "
        "identified")
    rotor_inertia_kgm2: float = quantity(
        1.0e-4, "kg·m²", "assumed: thin-rim estimate m·r² of an 81 mm outrunner rotor (can + magnets "
        "~0.075 kg at mean radius ~0.036 m), an upper bound; not in the paper or the vendor's sheet (model "
        "README, Derivations)", 0.0, 1.0, low_open=True,
        bound=(6.3e-5, 1.0e-4), bound_source="MIT Mini Cheetah rotor from CAD (6.3e-5, MiniCheetah.h) to the "
        "thin-rim upper bound m·r² (1.0e-4); not in the vendor's sheet")
    rotor_mass_kg: float = quantity(
        0.075, "kg", "assumed: can + magnets of an 81 mm outrunner, the mass of the thin-rim estimate",
        0.0, 10.0, low_open=True)
    torque_constant_nm_per_a: float = quantity(
        0.1, "N·m/A", "assumed: motor-side q-axis constant of a ~100 rpm/V 8108 outrunner (60/(2π·KV))",
        0.0, 10.0, low_open=True,
        bound=(0.07, 0.13), bound_source="assumed: ±30 % around 60/(2π·KV) for KV ≈ 100 rpm/V (the vendor's KV is "
        "not verified)")
    winding_resistance_ohm: float = quantity(
        0.3, "Ω", "assumed: dc-equivalent winding resistance of an 8108 outrunner, used for copper losses "
        "(heat into the thermal model) and back-EMF bookkeeping", 0.0, 100.0, low_open=True)
    current_loop_time_constant_s: float = quantity(
        1.14e-4, "s", "identified: first-order closed current loop, 1.4 kHz bandwidth; experiments.identify_defaults "
        "within the bound below (models/gim8108_testbed/identification.md)", 0.0, 0.1, low_open=True,
        bound=(8.0e-5, 8.0e-4), bound_source="assumed: closed current loop of 200 Hz to 2 kHz bandwidth; the paper's "
        "2 kHz is a command rate, not a loop bandwidth")
    peak_torque_nm: float = quantity(
        18.0, "N·m", "paper Sec. II: GIM8108 maximum torque at the output", 0.0, 1000.0, low_open=True)
    command_delay_s: float = quantity(
        1.79e-3, "s", "identified: CAN-FD transfer, one 1 kHz tick and the driver's processing of a torque command; "
        "experiments.identify_defaults within the bound below (models/gim8108_testbed/identification.md)", 0.0, 0.05,
        bound=(0.0, 2.0e-3), bound_source="assumed: a CAN-FD frame (tens of µs), one 1 kHz tick and the driver's "
        "processing, at most 2 ms")
    torque_saturation_per_nm: float = quantity(
        0.0232, "1/(N·m)", "identified: magnetic saturation τ = τ_cmd/(1 + α·|τ_cmd|) that the driver's current-based "
        "estimate "
        "does not see (Sec. IV-A), 19 % droop at 10 N·m; experiments.identify_defaults within the bound "
        "below (models/gim8108_testbed/identification.md)", 0.0, 0.025,
        bound=(0.0, 0.025), bound_source="assumed: the paper notes a nonlinearity (Sec. IV-A), no number; "
        "0-20 % droop at 10 N·m, below the 1/18 at which no current gives 18 N·m")


@dataclass(frozen=True)
class GearFrictionParams:
    """Gearbox friction at the output (LuGre, MuJoCo's dcmotor) plus a load-dependent part (written in Python)."""

    breakaway_torque_nm: float = quantity(
        0.13, "N·m", "paper Sec. IV: stiction threshold ≈ 0.13 N·m (smallest command that starts sustained "
        "motion)", 0.0, INF, low_open=True,
        bound=(0.117, 0.143), bound_source="paper Sec. IV: stiction threshold '≈ 0.13 N·m'; ±10 % assumed "
        "for the '≈'")
    coulomb_torque_nm: float = quantity(
        0.0855, "N·m", "identified: sliding level 0.66 of the 0.13 N·m breakaway; experiments.identify_defaults "
        "against "
        "Tables VI-VII and the described behaviours, within the bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, INF, low_open=True,
        bound=(0.065, 0.13), bound_source="assumed: 0.5-1.0x the 0.13 N·m breakaway, the Stribeck drop of greased "
        "gear stages")
    stribeck_velocity_rad_s: float = quantity(
        0.0408, "rad/s", "identified: output-side Stribeck velocity; experiments.identify_defaults within the bound "
        "below "
        "(models/gim8108_testbed/identification.md)", 0.0, INF,
        low_open=True,
        bound=(0.01, 0.2), bound_source="assumed: output-side Stribeck velocity of a greased planetary stage, "
        "0.01-0.2 rad/s; neither the paper nor the vendor gives one")
    viscous_nms_per_rad: float = quantity(
        0.00788, "N·m·s/rad", "identified: output-side viscous friction of grease and bearings; "
        "experiments.identify_defaults "
        "within the bound below (models/gim8108_testbed/identification.md)", 0.0, INF,
        bound=(0.005, 0.08), bound_source="assumed: 0.25-4x 0.02 N·m·s/rad, a grease-lubricated stage's estimate; "
        "neither the paper nor the vendor gives a viscous coefficient")
    output_viscous_share: float = quantity(
        0.1, "1", "assumed: share of viscous_nms_per_rad acting on the output flange and hub (output bearing and "
        "seal), on the output side of the backlash dead band; it damps the free output inside the gap "
        "(model README, Derivations)", 0.0, 1.0)
    presliding_stiffness_nm_per_rad: float = quantity(
        3120.0, "N·m/rad", "identified: LuGre bristle stiffness sigma0 at the output, presliding displacement "
        "breakaway/sigma0 "
        "= 42 µrad; experiments.identify_defaults within the bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, INF,
        low_open=True,
        bound=(500.0, 8000.0), bound_source="assumed: presliding displacement breakaway/sigma0 of 16-260 µrad at the "
        "output (0.16-2.6 µm at a 10 mm pitch radius)")
    presliding_damping_ratio: float = quantity(
        1.0, "1", "assumed: critically damped presliding, sigma1 = 2·ζ·sqrt(sigma0·J_reflected) (Canudas de "
        "Wit et al. 1995 size sigma1 from sigma0 and the moving mass)", 0.0, 10.0, low_open=True,
        bound=(0.6, 1.0), bound_source="assumed: 0.6 to critical; LuGre sizes sigma1 from sigma0 and the moving "
        "inertia (Canudas de Wit et al. 1995)")
    load_friction_coefficient: float = quantity(
        0.0397, "1", "identified: 1 - η of one planetary stage (η = 96 %); sim.plant writes it per tick into the gear "
        "joint's frictionloss; experiments.identify_defaults within the bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, 1.0,
        bound=(0.02, 0.04), bound_source="Beckhoff PLE080 catalogue: one planetary stage has η = 96-98 % at full "
        "load, 1 - η = 0.02-0.04 (an industrial gear; SteadyWin gives no η)")
    load_friction_time_constant_s: float = quantity(
        1.25e-4, "s", "tuned: solreffriction time constant of that frictionloss row, two physics steps (the "
        "stiffest MuJoCo resolves stably); with load_friction_impedance it bounds the creep while stuck "
        "(tests/test_plant_physics)", 0.0, 1.0, low_open=True)
    load_friction_impedance: float = quantity(
        0.9999, "1", "tuned: solimpfriction d0 = dwidth of that row, MuJoCo's maximum; (1-d)/d scales the "
        "creep velocity while stuck", 0.9, 0.9999)


@dataclass(frozen=True)
class BacklashParams:
    """Dead band between gear output and the sensor hub: MuJoCo's hinge with limited range."""

    width_rad: float = quantity(
        3.81e-4, "rad", "identified: 1.3 arcmin dead band of the planetary stage (the paper reports backlash, no "
        "value, "
        "Sec. IV); experiments.identify_defaults within the vendor's bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, 0.2,
        low_open=True,
        bound=(2.9e-4, 4.4e-3), bound_source="SteadyWin GIM8108-8: about 15 arcmin (4.4 mrad, via ODrive notes) at "
        "most; 1 arcmin (0.29 mrad), the tightest planetary class, assumed as least")
    stop_time_constant_s: float = quantity(
        1.25e-4, "s", "tuned: solref time constant of the stops, two physics steps (the stiffest MuJoCo "
        "resolves stably); with stop_impedance the stop penetrates < 10 % of the gap at 18 N·m and < 60 % "
        "in the hardest impacts of random commands (tests/test_plant_physics, test_plant_contract)",
        0.0, 1.0, low_open=True)
    stop_impedance: float = quantity(
        0.999, "1", "tuned: solimp d0 = dwidth of the stops; (1-d)/d sets the static penetration",
        0.9, 0.9999)


@dataclass(frozen=True)
class FlexureParams:
    """Four-spoke flexure (paper Sec. II, Eq. 7, Table I) and its material."""

    beam_length_m: float = quantity(0.021, "m", "paper Table I: l", 0.0, 1.0, low_open=True)
    beam_width_m: float = quantity(0.004, "m", "paper Table I: b (bending direction, I = h·b³/12)",
                                   0.0, 1.0, low_open=True)
    beam_height_m: float = quantity(0.007, "m", "paper Table I: h", 0.0, 1.0, low_open=True)
    inner_radius_m: float = quantity(0.019, "m", "paper Table I: r_i", 0.0, 1.0, low_open=True)
    sensing_radius_m: float = quantity(0.030, "m", "paper Table I: l_s", 0.0, 1.0, low_open=True)
    outer_radius_m: float = quantity(0.048, "m", "paper Sec. II: 96 mm diameter", 0.0, 1.0, low_open=True)
    spoke_count: int = quantity(4, "1", "paper Sec. II: four spokes", 3, 16)
    youngs_modulus_pa: float = quantity(
        71.7e9, "Pa", "assumed: aluminium 7075-T6 (ASM data); the paper names no material, but its 114.5 g "
        "for a 96 x 12 mm body fits aluminium, not steel", 1e9, 500e9,
        bound=(68.9e9, 71.7e9), bound_source="assumed: aluminium (paper Table II mass fits it): 6061-T6 68.9 GPa to "
        "7075-T6 71.7 GPa (ASM data)")
    poisson_ratio: float = quantity(
        0.33, "1", "assumed: aluminium 7075-T6 (ASM data)", 0.0, 0.5,
        bound=(0.33, 0.33), bound_source="assumed: aluminium, 6061-T6 and 7075-T6 both 0.33 (ASM data)")
    density_kg_m3: float = quantity(
        2810.0, "kg/m³", "assumed: aluminium 7075-T6 (ASM data)", 100.0, 25000.0,
        bound=(2700.0, 2810.0), bound_source="assumed: aluminium (paper Table II mass fits it): 6061-T6 2700 to "
        "7075-T6 2810 kg/m³ (ASM data)")
    shear_correction: float = quantity(5.0 / 6.0, "1", "paper Sec. II: κ = 5/6, rectangular section",
                                       0.0, 1.0, low_open=True)
    hub_bore_radius_m: float = quantity(
        0.010, "m", "assumed: centring bore of the hub on the motor flange", 0.0, 1.0)
    structural_damping_ratio: float = quantity(
        0.02, "1", "assumed: damping ratio of the lever side ringing on the flexure, sqrt(K_t·J_lever); "
        "2 % is typical of a bolted aluminium assembly, joints included", 0.0, 1.0,
        bound=(0.005, 0.05), bound_source="assumed: 0.5-5 % of critical, bolted aluminium assemblies with their "
        "joints")


@dataclass(frozen=True)
class FlangeParams:
    """The gear's output flange (planet carrier) that the sensor hub bolts to."""

    mass_kg: float = quantity(0.06, "kg", "assumed: aluminium planet carrier of a GIM8108", 0.0, 10.0,
                              low_open=True)
    radius_m: float = quantity(0.030, "m", "assumed: carrier radius, inside the 96 mm housing", 0.0, 1.0,
                               low_open=True)


@dataclass(frozen=True)
class LeverParams:
    """Lever arm bolted to the sensor's outer ring; its tip meets the load cell."""

    length_m: float = quantity(0.1, "m", "paper Sec. IV: 0.1 m lever arm", 0.0, 10.0, low_open=True)
    width_m: float = quantity(0.02, "m", "assumed: aluminium bar section", 0.0, 1.0, low_open=True)
    thickness_m: float = quantity(0.006, "m", "assumed: aluminium bar section", 0.0, 1.0, low_open=True)
    density_kg_m3: float = quantity(
        2700.0, "kg/m³", "assumed: aluminium 6061-T6 (ASM data)", 100.0, 25000.0,
        bound=(2700.0, 2810.0), bound_source="assumed: an aluminium bar, 6061-T6 2700 to 7075-T6 2810 kg/m³ (ASM data)")
    youngs_modulus_pa: float = quantity(
        68.9e9, "Pa", "assumed: aluminium 6061-T6 (ASM data)", 1e9, 500e9,
        bound=(68.9e9, 71.7e9), bound_source="assumed: an aluminium bar, 6061-T6 68.9 GPa to 7075-T6 71.7 GPa "
        "(ASM data)")


@dataclass(frozen=True)
class LoadCellParams:
    """CAS SBA-50L S-beam load cell at the lever tip (locked fixture)."""

    capacity_n: float = quantity(500.0, "N", "paper Sec. IV: SBA-50L, 500 N", 0.0, INF, low_open=True)
    full_scale_deflection_m: float = quantity(
        3.0e-4, "m", "assumed: typical S-beam deflection at rated capacity (0.2-0.5 mm); the tip support is "
        "this spring in series with the lever's bending", 0.0, 0.01, low_open=True,
        bound=(2.0e-4, 5.0e-4), bound_source="assumed: typical S-beam deflection at rated capacity, 0.2-0.5 mm (the "
        "SBA-50L sheet is not read)")
    damping_ratio: float = quantity(
        0.02, "1", "assumed: light damping of the tip support", 0.0, 1.0,
        bound=(0.005, 0.05), bound_source="assumed: 0.5-5 % of critical, bolted aluminium assemblies with their "
        "joints")
    reading_noise_n: float = quantity(
        0.025, "N", "tuned: inferred in closed form from Table VI's "
        "sensor-feedback step errors, flat across step sizes (a measurement floor); white at 1 kHz, "
        "added to the logged force only (model README, Derivations)", 0.0, 50.0,
        bound=(0.0, 0.026), bound_source="paper Table VI: sensor-feedback step RMS ≤ 0.0026 N·m over the 0.1 m lever "
        "bounds the reading noise by 0.026 N (the loop adds ≥ 0)")
    amplifier_bandwidth_hz: float = quantity(
        1760.0, "Hz", "identified: −3 dB frequency of the load cell's amplifier, a first-order low-pass on the force "
        "logged at the control rate (sim.lowpass); experiments.identify_defaults within the bound below "
        "(models/gim8108_testbed/identification.md)",
        0.0, 1.0e6, low_open=True,
        bound=(10.0, 5000.0), bound_source="assumed: ≥ 10 Hz, as its lag alone on Table VII's 10 N·m 0.2 Hz sine "
        "stays ≤ 0.152 N·m RMS; ≤ 5 kHz, an analog strain-gauge amplifier (1-10 kHz)")


@dataclass(frozen=True)
class ThermalParams:
    """Lumped two-node thermal network (sensor board, motor winding) in still air."""

    ambient_c: float = quantity(
        25.0, "°C", "assumed: laboratory", -40.0, 85.0,
        bound=(20.0, 30.0), bound_source="assumed: an air-conditioned laboratory")
    board_heat_capacity_j_per_k: float = quantity(
        110.0, "J/K", "assumed: 114.5 g aluminium body (paper Table II) at 900 J/(kg·K) plus the PCB",
        0.0, INF, low_open=True,
        bound=(100.0, 130.0), bound_source="assumed: 114.5 g of aluminium (paper Table II) at 900 J/(kg·K) is 103 "
        "J/K, plus 0-25 J/K of PCB and parts")
    board_to_ambient_k_per_w: float = quantity(
        5.5, "K/W", "assumed: natural convection h ≈ 10 W/(m²·K) over ~0.018 m² of sensor surface",
        0.0, INF, low_open=True,
        bound=(2.2, 11.0), bound_source="assumed: natural convection h = 5-25 W/(m²·K) over ~0.018 m² of sensor "
        "surface")
    mcu_power_w: float = quantity(0.4, "W", "assumed: STM32H7 at full clock (paper Sec. II names the MCU)",
                                  0.0, 10.0,
        bound=(0.2, 0.6), bound_source="assumed: STM32H7 run power at full clock with its peripherals (the "
        "datasheet's figures are not read)")
    motor_heat_capacity_j_per_k: float = quantity(
        230.0, "J/K", "assumed: ~0.38 kg motor at ~600 J/(kg·K)", 0.0, INF, low_open=True,
        bound=(150.0, 340.0), bound_source="assumed: ~0.38 kg of motor at 400-900 J/(kg·K) (copper and steel to "
        "aluminium)")
    motor_to_ambient_k_per_w: float = quantity(2.5, "K/W", "assumed: 96 mm housing in still air",
                                               0.0, INF, low_open=True,
        bound=(1.4, 7.1), bound_source="assumed: natural convection h = 5-25 W/(m²·K) over ~0.028 m² of a 96 x 45 mm "
        "housing")
    motor_to_board_k_per_w: float = quantity(
        5.0, "K/W", "assumed: conduction through the bolted hub; the paper notes motor heat reaches the "
        "sensor (Sec. III-C)", 0.0, INF, low_open=True,
        bound=(2.0, 20.0), bound_source="assumed: conduction through the bolted aluminium hub, contact resistance "
        "included")
    tmp117_resolution_c: float = quantity(0.0078125, "°C", "TI TMP117 datasheet: 16-bit, 7.8125 m°C LSB",
                                          0.0, 1.0, low_open=True)
    update_period_s: float = quantity(
        0.1, "s", "assumed: thermal time constants are minutes, so the network is advanced every 100 ms "
        "with the mean copper loss (multi-rate)", 0.0, 60.0, low_open=True)


_TEMPCO_SOURCE = ("assumed: coupled emitter-phototransistor reflectors change their output by -0.1 to -0.2 %/K; "
                  "the TCRT1000 temperature curve is not read")


@dataclass(frozen=True)
class PhotoReflectorParams:
    """Eight Vishay TCRT1000 photo-reflectors on the flexure's reflective surface, their ADC and the
    references of the calibration rig (paper Secs. II-III). Per-channel values of one sensor unit are drawn
    from the ranges below with ``unit_seed`` (a manufactured unit), so a seed is a sensor."""

    unit_seed: int = quantity(0, "1", "assumed: which manufactured unit; per-channel spreads are drawn with it",
                              0, 2**31 - 1)
    sensitivity_min_v_per_m: float = quantity(
        973.0, "V/m", "paper Sec. III-B: 0.024 V/(N·m) (0.6 V at 25 N·m) at the default K_t = 1217 N·m/rad and "
        "l_s = 30 mm: 0.024·K_t/l_s", 0.0, INF, low_open=True,
        bound=(973.0, 1622.0), bound_source="paper Sec. III-B: channel sensitivities 0.024-0.04 V/(N·m), times "
        "K_t/l_s at the defaults")
    sensitivity_max_v_per_m: float = quantity(
        1622.0, "V/m", "paper Sec. III-B: 0.04 V/(N·m) (1 V at 25 N·m), converted as above", 0.0, INF,
        low_open=True,
        bound=(973.0, 1622.0), bound_source="paper Sec. III-B: channel sensitivities 0.024-0.04 V/(N·m), times "
        "K_t/l_s at the defaults")
    quadratic_fraction_max: float = quantity(
        0.334, "1", "identified: |quadratic term| of the linear one at the 25 N·m calibration span, 1.5·Δ/d "
        "of a 1/d² reflector response (Δ/d = 0.223, a 2.8 mm mid gap); experiments.identify_defaults within "
        "the bound below (models/gim8108_testbed/identification.md)", 0.0, 0.5,
        bound=(0.23, 0.47), bound_source="assumed: a 1/d² reflector response at a 2-4 mm gap over the 0.62 mm gap "
        "change at 25 N·m gives 1.5·Δ/d; the TCRT1000 distance curve is not read")
    cubic_fraction_max: float = quantity(
        0.0993, "1", "identified: with the quadratic term, on the same 1/d² response, 2·(Δ/d)² of the "
        "linear one at the calibration span; experiments.identify_defaults within the bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, 0.5,
        bound=(0.048, 0.19), bound_source="assumed: a 1/d² reflector response at a 2-4 mm gap over the 0.62 mm gap "
        "change at 25 N·m gives 2·(Δ/d)²; the TCRT1000 curve is not read")
    operating_point_v: float = quantity(
        1.65, "V", "assumed: mid-range of the 3.3 V ADC, set by the LED and collector resistors", 0.0, 3.3)
    operating_point_spread_v: float = quantity(
        0.15, "V", "assumed: unit-to-unit spread of the operating point (mounting gap tolerance)", 0.0, 1.0)
    noise_min_v: float = quantity(
        1.77e-4, "V", "identified: quietest channel's white-noise std; with noise_max_v it sets the LS and "
        "QP stds of the resolution comparison (Sec. III-B); experiments.identify_defaults within the bound "
        "below (models/gim8108_testbed/identification.md)", 0.0, 1.0,
        bound=(1.5e-4, 4.0e-4), bound_source="assumed: 0.15-0.4 mV std for the quietest channel; the paper gives the "
        "calibrated stds, not the channels'")
    noise_max_v: float = quantity(
        2.40e-3, "V", "identified: noisiest channel's white-noise std, 14x the quietest, on its bound's "
        "high edge (the bound holds it); experiments.identify_defaults within the bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, 1.0,
        bound=(1.5e-4, 2.4e-3), bound_source="assumed: 1-6x the quietest channel's bound; the TCRT1000's "
        "channel-to-channel noise spread is not in the paper")
    slip_twist_max_rad: float = quantity(
        0.0103, "rad", "assumed: largest breakaway twist of the Maxwell-slip elements of the target's bolted "
        "joint, half the ±25 N·m calibration span at K_t (12.5 N·m), so loops over the calibration protocol "
        "close at their turning points and open gradually after a reversal (Fig. 7(d) shows no step)",
        0.0, 0.1, low_open=True)
    slip_fraction_min: float = quantity(
        0.00599, "1", "identified: smallest fraction of the twist a channel sees through the slipping joint "
        "(Table III's hysteresis), on its bound's high edge; experiments.identify_defaults within the bound below "
        "(models/gim8108_testbed/identification.md)", 0.0, 1.0,
        bound=(0.003, 0.006), bound_source="assumed: 0.3-0.6 % of the twist; the paper gives the hysteresis (Table "
        "III), not the channels' slip")
    slip_fraction_max: float = quantity(
        0.0182, "1", "identified: largest fraction of the twist a channel sees through the slipping joint, "
        "3.0x the smallest; its spread gives the QP its resolution gain over LS (Sec. III-B); "
        "experiments.identify_defaults within the bound below (models/gim8108_testbed/identification.md)", 0.0, 1.0,
        bound=(0.006, 0.024), bound_source="assumed: 2-4x the smallest fraction's bound of 0.3-0.6 %")
    quartic_fraction_max: float = quantity(
        0.0277, "1", "identified: with the quadratic term, on the same 1/d² response, 2.5·(Δ/d)³ of the "
        "linear one, curvature beyond the cubic basis of Eq. 10; experiments.identify_defaults within the "
        "bound below (models/gim8108_testbed/identification.md)", 0.0, 0.5,
        bound=(0.0093, 0.074), bound_source="assumed: a 1/d² reflector response at a 2-4 mm gap over the 0.62 mm gap "
        "change at 25 N·m gives 2.5·(Δ/d)³; the TCRT1000 curve is not read")
    crosstalk_v_per_nm: float = quantity(
        2.4e-3, "V/(N·m)", "paper Sec. III-B: about 0.06 V per channel at 25 N·m of T_x or T_y", 0.0, 1.0)
    crosstalk_spread: float = quantity(
        0.308, "1", "identified: relative channel-to-channel spread of the tilt response; "
        "experiments.identify_defaults within the bound below (models/gim8108_testbed/identification.md)", 0.0, 1.0,
        bound=(0.1, 0.5), bound_source="assumed: 10-50 % channel-to-channel spread of the tilt response")
    optical_tempco_min_per_k: float = quantity(
        -1.98e-3, "1/K", "identified: temperature coefficient of the most sensitive channel (coupled TCRT1000-class "
        "reflectors, drawn uniformly up to optical_tempco_max_per_k); scales a channel's whole output, its operating "
        "point included; experiments.identify_defaults (models/gim8108_testbed/identification.md)", -0.1, 0.1,
        bound=(-2.0e-3, -1.0e-3), bound_source=_TEMPCO_SOURCE)
    optical_tempco_max_per_k: float = quantity(
        -1.09e-3, "1/K", "identified: temperature coefficient of the least temperature-sensitive channel; "
        "experiments.identify_defaults within the bound below (models/gim8108_testbed/identification.md)", -0.1, 0.1,
        bound=(-2.0e-3, -1.0e-3), bound_source=_TEMPCO_SOURCE)
    reference_temperature_c: float = quantity(
        25.0, "°C", "assumed: calibration temperature", -40.0, 85.0,
        bound=(20.0, 30.0), bound_source="assumed: calibrated in an air-conditioned laboratory")
    bandwidth_hz: float = quantity(5000.0, "Hz", "paper Table II: rise-time-limited bandwidth ~5 kHz",
                                   0.0, INF, low_open=True)
    adc_bits: int = quantity(16, "1", "paper Sec. II: 16-bit ADC", 8, 32)
    adc_reference_v: float = quantity(3.3, "V", "paper Sec. III-B: 3.3 V referenced ADC", 0.0, 10.0,
                                      low_open=True)
    tare_s: float = quantity(
        1.0, "s", "assumed: the unloaded hold a rig averages for its tare at the start of each run (the paper does "
        "not describe one); its mean carries the reading's noise over sqrt(1000) at 1 kHz. 0 reads without a tare",
        0.0, 60.0)
    full_scale_nm: float = quantity(
        80.0, "N·m", "paper Sec. III-B: 'the full-scale (FS) is defined as the design maximum T_z^max = 80 N·m'; "
        "every % FS figure (Tables III-IV, the error bound e_max = 0.2 % FS of Eq. 14) is relative to it",
        0.0, 1000.0, low_open=True)
    reference_resolution_nm: float = quantity(
        7.0 / 748.0, "N·m", "paper Sec. III-A: ATI MINI85 T_z resolution 7/748 N·m", 0.0, 1.0, low_open=True)
    reference_noise_nm: float = quantity(
        4.7e-3, "N·m", "assumed: MINI85 noise std of half its resolution", 0.0, 1.0,
        bound=(0.0, 7.0 / 748.0), bound_source="assumed: the MINI85's noise std is at most its T_z resolution of "
        "7/748 N·m (paper Sec. III-A)")
    reference_gain_error: float = quantity(
        0.0, "1", "assumed: ATI MINI85 T_z gain error g, the reading is (1 + g)·τ + noise, quantised; 0 = an "
        "exact reference, because the unit's actual error is unknown. Range from paper Sec. III-A: 1 % FS "
        "accuracy; a gain error g is off by |g|·80 N·m at full scale, so |g| <= 1 % keeps the error within "
        "1 % FS", -0.01, 0.01,
        bound=(-0.01, 0.01), bound_source="paper Sec. III-A: ATI MINI85 'accuracy of 1 % full scale'; |g| ≤ 1 % "
        "keeps the error within 1 % FS")


@dataclass(frozen=True)
class SimulationParams:
    """Control rate and the rule that derives the physics step."""

    control_period_s: float = quantity(1e-3, "s", "paper Sec. IV: 1 kHz control cycle", 0.0, 1.0,
                                       low_open=True)
    max_omega_dt: float = quantity(
        1.0, "rad", "rule: every mode of the lumped chain satisfies ω·h <= this. Semi-implicit Euler is "
        "stable below 2 (margin 2) and its period error is ≈ (ω·h)²/24: <= 4.2 % for the stiffest (~1 kHz, "
        "above the 500 Hz Nyquist rate of the loop), < 0.1 % for the control-relevant mode", 0.0, 1.9,
        low_open=True)
    max_step_per_bristle_time: float = quantity(
        0.018, "1", "rule: h <= this x the LuGre bristle relaxation time sigma1/sigma0. MuJoCo 4.0's dcmotor "
        "advances the bristle state with the start-of-step velocity (explicit, first order); measured, this "
        "keeps the locked fixture's control-relevant mode within 2 % of its h -> 0 value "
        "(benchmarks/README.md)", 0.0, 1.0, low_open=True)
    substeps_rule: str = choice(
        "accurate", SUBSTEPS_RULES, "assumed: a speed/fidelity trade-off the user chooses. 'accurate': the step of "
        "max_omega_dt and max_step_per_bristle_time. 'fast': fast_substeps_per_tick steps, solver time constants "
        "raised to two steps, joint damping explicit (benchmarks/README.md, 'Fidelity presets')")
    fast_substeps_per_tick: int = quantity(
        8, "1", "assumed: physics steps per control tick under substeps_rule = 'fast' (fewer if the rule asks for "
        "fewer, never fewer than max_omega_dt asks for); 8 is what max_omega_dt alone asks for in the locked "
        "fixture at the defaults", 1, 1000)


@dataclass(frozen=True)
class TestbedParams:
    """The whole rig: one instance of every group."""

    motor: MotorParams = field(default_factory=MotorParams)
    friction: GearFrictionParams = field(default_factory=GearFrictionParams)
    backlash: BacklashParams = field(default_factory=BacklashParams)
    flexure: FlexureParams = field(default_factory=FlexureParams)
    flange: FlangeParams = field(default_factory=FlangeParams)
    lever: LeverParams = field(default_factory=LeverParams)
    loadcell: LoadCellParams = field(default_factory=LoadCellParams)
    thermal: ThermalParams = field(default_factory=ThermalParams)
    photoreflector: PhotoReflectorParams = field(default_factory=PhotoReflectorParams)
    simulation: SimulationParams = field(default_factory=SimulationParams)

    def __post_init__(self) -> None:
        for group in dataclasses.fields(self):
            _validate_group(group.name, getattr(self, group.name))
        _validate_cross(self)

    def replace(self, **groups: dict[str, Any]) -> TestbedParams:
        """A copy with fields overridden, e.g. ``p.replace(friction={"breakaway_torque_nm": 0.2})``."""
        return from_dict(groups, base=self)

    def rows(self) -> list[tuple[str, Any, str, str]]:
        """(``group.field``, value, unit, source) for every parameter, in declaration order."""
        out = []
        for group in dataclasses.fields(self):
            obj = getattr(self, group.name)
            for f in dataclasses.fields(obj):
                out.append((f"{group.name}.{f.name}", getattr(obj, f.name), f.metadata["unit"],
                            f.metadata["source"]))
        return out


def field_range(params: TestbedParams, group: str, name: str) -> tuple[float, float]:
    """The valid range [low, high] of ``group.name`` from its metadata (an open low end nudged inside).

    Raises ValueError for a field that takes one of a set of names (no range)."""
    f = next(f for f in dataclasses.fields(getattr(params, group)) if f.name == name)
    if "choices" in f.metadata:
        raise ValueError(f"{group}.{name} takes one of {f.metadata['choices']}, not a value in a range")
    low, high = f.metadata["low"], f.metadata["high"]
    if f.metadata["low_open"]:
        low = math.nextafter(low, math.inf)
    return low, high


def _bounds() -> dict[str, tuple[tuple[float, float], str]]:
    """``group.field`` -> (source bound, its source), for every field that has one, in declaration order."""
    out = {}
    for group in dataclasses.fields(TestbedParams):
        for f in dataclasses.fields(group.default_factory):
            if f.metadata.get("bound") is not None:
                out[f"{group.name}.{f.name}"] = (f.metadata["bound"], f.metadata["bound_source"])
    return out


def bounded_fields() -> tuple[str, ...]:
    """Every ``group.field`` whose source gives a bound, in declaration order."""
    return tuple(_bounds())


def _bound_entry(path: str) -> tuple[tuple[float, float], str]:
    bounds = _bounds()
    if path not in bounds:
        raise KeyError(f"{path!r} has no source bound; bounded fields: {', '.join(bounds) or 'none'}")
    return bounds[path]


def source_bound(path: str) -> tuple[float, float]:
    """The bound ``(lo, hi)`` that the source of ``path`` ("group.field") allows, in the field's unit.

    Raises KeyError naming the path and the bounded fields if the field has no bound (or does not exist)."""
    return _bound_entry(path)[0]


def bound_source(path: str) -> str:
    """Where the bound of ``path`` ("group.field") comes from; KeyError as :func:`source_bound`."""
    return _bound_entry(path)[1]


def _validate_group(name: str, obj: Any) -> None:
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        md = f.metadata
        if "choices" in md:
            if isinstance(value, str) and value in md["choices"]:
                continue
            raise ParameterError(f"{name}.{f.name} = {value!r}: valid values are "
                                 f"{', '.join(repr(c) for c in md['choices'])}")
        expected = int if f.type in (int, "int") else float
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                expected is int and not isinstance(value, int)):
            kind = "an integer" if expected is int else "a number"
            raise ParameterError(f"{name}.{f.name} = {value!r}: expected {kind} "
                                 f"[{f.metadata['unit']}]")
        low, high = md["low"], md["high"]
        below = value <= low if md["low_open"] else value < low
        if not math.isfinite(value) or below or value > high:
            unit = "" if md["unit"] == "1" else f" {md['unit']}"  # "1": dimensionless
            raise ParameterError(f"{name}.{f.name} = {value!r}{unit} is out of its valid range "
                                 f"{range_text(low, high, low_open=md['low_open'])}{unit}")


def _validate_cross(p: TestbedParams) -> None:
    fr, m = p.friction, p.motor
    if fr.coulomb_torque_nm > fr.breakaway_torque_nm:
        raise ParameterError(
            f"friction.coulomb_torque_nm = {fr.coulomb_torque_nm} N·m must not exceed "
            f"friction.breakaway_torque_nm = {fr.breakaway_torque_nm} N·m (valid range (0, breakaway])")
    if fr.breakaway_torque_nm >= m.peak_torque_nm:
        raise ParameterError(
            f"friction.breakaway_torque_nm = {fr.breakaway_torque_nm} N·m is larger than the motor can "
            f"overcome: valid range (0, motor.peak_torque_nm = {m.peak_torque_nm}) N·m")
    if m.torque_saturation_per_nm * m.peak_torque_nm >= 1.0:
        raise ParameterError(
            f"motor.torque_saturation_per_nm = {m.torque_saturation_per_nm} 1/(N·m): the current-to-torque map "
            f"flattens towards 1/α below motor.peak_torque_nm = {m.peak_torque_nm} N·m, so no current delivers the "
            f"peak (valid range [0, {1.0 / m.peak_torque_nm:.4g}) 1/(N·m) with this peak)")
    if p.flexure.inner_radius_m + p.flexure.beam_length_m >= p.flexure.outer_radius_m:
        raise ParameterError(
            f"flexure.beam_length_m = {p.flexure.beam_length_m} m: r_i + l must stay inside "
            f"outer_radius_m = {p.flexure.outer_radius_m} m (valid range (0, "
            f"{p.flexure.outer_radius_m - p.flexure.inner_radius_m:g}) m)")
    if p.flexure.hub_bore_radius_m >= p.flexure.inner_radius_m:
        raise ParameterError(
            f"flexure.hub_bore_radius_m = {p.flexure.hub_bore_radius_m} m must be below inner_radius_m "
            f"(valid range [0, {p.flexure.inner_radius_m:g}) m)")
    pr = p.photoreflector
    for low, high, unit in (("sensitivity_min_v_per_m", "sensitivity_max_v_per_m", "V/m"),
                            ("noise_min_v", "noise_max_v", "V"),
                            ("optical_tempco_min_per_k", "optical_tempco_max_per_k", "1/K"),
                            ("slip_fraction_min", "slip_fraction_max", "")):
        if getattr(pr, low) > getattr(pr, high):
            raise ParameterError(f"photoreflector.{low} = {getattr(pr, low)} {unit} must not exceed "
                                 f"photoreflector.{high} = {getattr(pr, high)} {unit}")
    if not (pr.tare_s == 0.0 or pr.tare_s >= p.simulation.control_period_s):
        raise ParameterError(f"photoreflector.tare_s = {pr.tare_s} s: valid values are 0 (no tare) or "
                             f"[{p.simulation.control_period_s:g}, 60] s (at least one control period)")
    if p.motor.command_delay_s > 20 * p.simulation.control_period_s:
        raise ParameterError(f"motor.command_delay_s = {p.motor.command_delay_s} s: valid range "
                             f"[0, {20 * p.simulation.control_period_s:g}] s (20 control periods)")


def did_you_mean(name: str, valid: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the valid name closest to a misspelt ``name``; empty if none is close."""
    close = difflib.get_close_matches(name, list(valid), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def from_dict(overrides: dict[str, Any], base: TestbedParams | None = None) -> TestbedParams:
    """Apply ``{group: {field: value}}`` to ``base`` (defaults if None), validating every key and value."""
    base = base or TestbedParams()
    groups = {f.name: f for f in dataclasses.fields(TestbedParams)}
    updated = {}
    for gname, values in overrides.items():
        if gname not in groups:
            raise ParameterError(f"unknown parameter group [{gname}]{did_you_mean(gname, groups)}; valid groups: "
                                 f"{', '.join(groups)}")
        if not isinstance(values, dict):
            raise ParameterError(f"[{gname}] must be a table of fields, got {values!r}")
        current = getattr(base, gname)
        names = {f.name: f for f in dataclasses.fields(current)}
        for key, value in values.items():
            if key not in names:
                raise ParameterError(f"unknown parameter {gname}.{key}{did_you_mean(key, names)}; valid fields "
                                     f"of [{gname}]: {', '.join(names)}")
            if names[key].type in (float, "float") and isinstance(value, int) and not isinstance(value, bool):
                values = {**values, key: float(value)}
        try:
            updated[gname] = dataclasses.replace(current, **values)
        except TypeError as exc:  # pragma: no cover - guarded by the key check above
            raise ParameterError(f"[{gname}]: {exc}") from exc
    return dataclasses.replace(base, **updated)


def load_params(path: str | Path | None = None) -> TestbedParams:
    """The default parameter set, with the overrides of a TOML file if given (the file is only read)."""
    if path is None:
        return TestbedParams()
    path = Path(path)
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ParameterError(f"parameter file {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"parameter file {path} is not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ParameterError(f"parameter file {path} is not UTF-8 text (TOML): {exc.reason} at byte "
                             f"{exc.start}") from None
    except OSError as exc:
        raise ParameterError(f"parameter file {path} cannot be read: {exc.strerror or exc}") from None
    try:
        return from_dict(data)
    except ParameterError as exc:
        raise ParameterError(f"{path}: {exc}") from None
