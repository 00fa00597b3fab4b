"""Closed-form quantities derived from the parameter set (no MuJoCo here: these are the oracles too).

The lumped chain, output-referred, absolute angles θ:
    rotor+gear (J_gear, LuGre to ground) --backlash-- flange+hub (J_out) --K_t-- ring+lever (J_lever)
    --k_lc·L² (locked fixture only)-- ground.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

if TYPE_CHECKING:
    from sim.params import TestbedParams


@dataclass(frozen=True)
class Derived:
    """Derived physical quantities, SI units in the field names."""

    flexure_shear_modulus_pa: float
    flexure_second_moment_m4: float
    spoke_stiffness_n_per_m: float
    flexure_stiffness_nm_per_rad: float
    hub_inertia_kgm2: float
    hub_mass_kg: float
    flange_inertia_kgm2: float
    output_inertia_kgm2: float
    reflected_rotor_inertia_kgm2: float
    ring_inertia_kgm2: float
    lever_bar_inertia_kgm2: float
    lever_side_inertia_kgm2: float
    lever_side_mass_kg: float
    flexure_damping_nms_per_rad: float
    flexure_mode_hz: float
    loadcell_stiffness_n_per_m: float
    lever_bending_stiffness_n_per_m: float
    tip_support_stiffness_n_per_m: float
    loadcell_rot_stiffness_nm_per_rad: float
    loadcell_rot_damping_nms_per_rad: float
    presliding_damping_nms_per_rad: float
    motor_peak_torque_motor_side_nm: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def annulus_inertia(density: float, r_in: float, r_out: float, thickness: float) -> tuple[float, float]:
    """Mass [kg] and polar moment of inertia [kg·m²] of a flat annulus about its axis."""
    mass = density * math.pi * (r_out**2 - r_in**2) * thickness
    return mass, 0.5 * mass * (r_out**2 + r_in**2)


def flexure_stiffness(p: TestbedParams) -> tuple[float, float, float, float]:
    """Paper Eq. 7: K_t = n·r_i²·(l³/(3EI) + l/(κGA))⁻¹ with I = h·b³/12, A = b·h, G = E/(2(1+ν)).

    Returns (K_t [N·m/rad], k_b [N/m], I [m⁴], G [Pa]). The paper writes n = 4 spokes.
    """
    f = p.flexure
    shear_modulus = f.youngs_modulus_pa / (2.0 * (1.0 + f.poisson_ratio))
    second_moment = f.beam_height_m * f.beam_width_m**3 / 12.0
    area = f.beam_width_m * f.beam_height_m
    compliance = (f.beam_length_m**3 / (3.0 * f.youngs_modulus_pa * second_moment)
                  + f.beam_length_m / (f.shear_correction * shear_modulus * area))
    k_b = 1.0 / compliance
    return f.spoke_count * f.inner_radius_m**2 * k_b, k_b, second_moment, shear_modulus


def derive(p: TestbedParams) -> Derived:
    """All derived quantities of a parameter set."""
    f, lever = p.flexure, p.lever
    k_t, k_b, second_moment, shear = flexure_stiffness(p)
    # Hub: the moving central part of the flexure, an annulus r_bore..r_i of the beam height (assumed).
    hub_mass, hub_j = annulus_inertia(f.density_kg_m3, f.hub_bore_radius_m, f.inner_radius_m,
                                      f.beam_height_m)
    flange_j = 0.5 * p.flange.mass_kg * p.flange.radius_m**2
    # Outer ring r_i + l .. r_o carries the lever; the spokes' own inertia (4 x 1.7 g) is neglected.
    ring_mass, ring_j = annulus_inertia(f.density_kg_m3, f.inner_radius_m + f.beam_length_m,
                                        f.outer_radius_m, f.beam_height_m)
    bar_mass = lever.density_kg_m3 * lever.length_m * lever.width_m * lever.thickness_m
    bar_j = bar_mass * (lever.length_m**2 / 3.0 + lever.width_m**2 / 12.0)  # bar from the axis to the tip
    lever_j = ring_j + bar_j
    n = p.motor.gear_ratio
    j_reflected = n**2 * p.motor.rotor_inertia_kgm2
    # Tip support: the load cell's spring in series with the lever bending as a cantilever (3EI/L³,
    # bending in the plane of rotation, I = t·w³/12); as a rotation spring it is k·L².
    k_cell = p.loadcell.capacity_n / p.loadcell.full_scale_deflection_m
    k_bend = 3.0 * lever.youngs_modulus_pa * lever.thickness_m * lever.width_m**3 / 12.0 / lever.length_m**3
    k_tip = 1.0 / (1.0 / k_cell + 1.0 / k_bend)
    k_lc = k_tip * lever.length_m**2
    return Derived(
        flexure_shear_modulus_pa=shear,
        flexure_second_moment_m4=second_moment,
        spoke_stiffness_n_per_m=k_b,
        flexure_stiffness_nm_per_rad=k_t,
        hub_inertia_kgm2=hub_j,
        hub_mass_kg=hub_mass,
        flange_inertia_kgm2=flange_j,
        output_inertia_kgm2=hub_j + flange_j,
        reflected_rotor_inertia_kgm2=j_reflected,
        ring_inertia_kgm2=ring_j,
        lever_bar_inertia_kgm2=bar_j,
        lever_side_inertia_kgm2=lever_j,
        lever_side_mass_kg=ring_mass + bar_mass,
        flexure_damping_nms_per_rad=2.0 * f.structural_damping_ratio * math.sqrt(k_t * lever_j),
        flexure_mode_hz=math.sqrt(k_t / hub_j) / (2.0 * math.pi),
        loadcell_stiffness_n_per_m=k_cell,
        lever_bending_stiffness_n_per_m=k_bend,
        tip_support_stiffness_n_per_m=k_tip,
        loadcell_rot_stiffness_nm_per_rad=k_lc,
        loadcell_rot_damping_nms_per_rad=2.0 * p.loadcell.damping_ratio * math.sqrt(k_lc * lever_j),
        presliding_damping_nms_per_rad=2.0 * p.friction.presliding_damping_ratio * math.sqrt(
            p.friction.presliding_stiffness_nm_per_rad * j_reflected),
        motor_peak_torque_motor_side_nm=p.motor.peak_torque_nm / n,
    )


FIXTURES = ("locked", "free")
# solref time constants of the model's constraint rows [s]: MuJoCo resolves none stiffer than two physics steps
SOLVER_TIME_CONSTANTS = (("backlash", "stop_time_constant_s"), ("friction", "load_friction_time_constant_s"))


def lumped_modes_hz(p: TestbedParams, fixture: str, backlash_closed: bool, gear_stuck: bool = True) -> np.ndarray:
    """Undamped natural frequencies [Hz] of the lumped chain, ascending, rigid-body modes (0 Hz) included.

    ``gear_stuck`` adds the LuGre presliding stiffness from the gear to ground (the gear at rest);
    ``backlash_closed`` merges gear and output flange (a stop in contact).
    """
    if fixture not in FIXTURES:
        raise ValueError(f"fixture = {fixture!r}: valid values are {FIXTURES}")
    d = derive(p)
    j_gear = d.reflected_rotor_inertia_kgm2
    masses = [j_gear, d.output_inertia_kgm2, d.lever_side_inertia_kgm2]
    k = np.zeros((3, 3))

    def spring(i: int, j: int | None, stiffness: float) -> None:
        k[i, i] += stiffness
        if j is not None:
            k[j, j] += stiffness
            k[i, j] -= stiffness
            k[j, i] -= stiffness

    if gear_stuck:
        spring(0, None, p.friction.presliding_stiffness_nm_per_rad)
    spring(1, 2, d.flexure_stiffness_nm_per_rad)
    if fixture == "locked":
        spring(2, None, d.loadcell_rot_stiffness_nm_per_rad)
    m = np.diag(masses)
    if backlash_closed:  # θ_gear = θ_out: reduce with T mapping (θ_gear, θ_lever) -> (θ_gear, θ_out, θ_lever)
        t = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        k, m = t.T @ k @ t, t.T @ m @ t
    omega_sq = scipy.linalg.eigh(k, m, eigvals_only=True)
    return np.sqrt(np.clip(omega_sq, 0.0, None)) / (2.0 * math.pi)


def stiffest_mode_rad_s(p: TestbedParams, fixture: str) -> float:
    """Highest natural frequency [rad/s] over the backlash states and friction states of a fixture."""
    return 2.0 * math.pi * max(float(lumped_modes_hz(p, fixture, closed, stuck).max())
                               for closed in (True, False) for stuck in (True, False))


def substeps_by_rule(p: TestbedParams, fixture: str) -> dict[str, int]:
    """Physics steps per control tick each part of the rule asks for (see :func:`physics_timestep`):
    ``modes`` (1) and ``presliding`` (2). σ1 = 2ζ·sqrt(σ0·J) makes (2) grow as the reflected inertia falls."""
    s = p.simulation
    t_ctrl = s.control_period_s
    bristle_time_s = derive(p).presliding_damping_nms_per_rad / p.friction.presliding_stiffness_nm_per_rad
    return {"modes": math.ceil(t_ctrl * stiffest_mode_rad_s(p, fixture) / s.max_omega_dt),
            "presliding": math.ceil(t_ctrl / (s.max_step_per_bristle_time * bristle_time_s))}


def substeps_per_tick(p: TestbedParams, fixture: str, rule: str | None = None) -> int:
    """Physics steps per control tick under ``rule`` (``simulation.substeps_rule`` if None).

    ``accurate``: the smallest count that meets both parts of the rule (:func:`substeps_by_rule`).
    ``fast``: ``simulation.fast_substeps_per_tick``, or the accurate count if that is lower, and never fewer
    than the stability part (1) asks for; it gives up the presliding accuracy part (2).
    """
    rule = p.simulation.substeps_rule if rule is None else rule
    parts = substeps_by_rule(p, fixture)
    accurate = max(1, *parts.values())
    if rule == "accurate":
        return accurate
    if rule == "fast":
        return min(accurate, max(p.simulation.fast_substeps_per_tick, parts["modes"]))
    raise ValueError(f"rule = {rule!r}: valid values are 'accurate', 'fast' (simulation.substeps_rule)")


def physics_timestep(p: TestbedParams, fixture: str, rule: str | None = None) -> tuple[float, int]:
    """The physics step h [s] and substeps per control tick from the stated rule.

    Rule (``accurate``): h = T_ctrl / n with the smallest integer n such that
      (1) ω_max·h <= simulation.max_omega_dt, ω_max the stiffest mode of the lumped chain in any backlash
          or friction state (stability with margin for every mode), and
      (2) h <= simulation.max_step_per_bristle_time · σ1/σ0 (accuracy of the presliding dynamics, whose
          bristle state MuJoCo advances explicitly).
    The current loop is integrated exactly by MuJoCo (exponential update), so it does not bound h.
    ``fast`` keeps (1) and drops (2) for ``simulation.fast_substeps_per_tick`` steps (:func:`substeps_per_tick`).

    Parameters
    ----------
    p : TestbedParams
        The parameter set.
    fixture : {'locked', 'free'}
        The fixture the step is for.
    rule : {'accurate', 'fast'}, optional
        The substep rule; ``p.simulation.substeps_rule`` if None.

    Returns
    -------
    h : float
        The physics step [s].
    n : int
        Physics steps per control tick.
    """
    n = substeps_per_tick(p, fixture, rule)
    return p.simulation.control_period_s / n, n


def implicit_joint_damping(p: TestbedParams) -> bool:
    """Whether MuJoCo's Euler integrator treats joint damping implicitly (its ``eulerdamp`` flag).

    True under ``simulation.substeps_rule = 'accurate'``, False under ``'fast'``. Euler applies the implicit
    damping after the constraint solve, which computed the backlash stop's force against M rather than M + h·D;
    at 8 substeps per ms that takes a quarter to 40 % of the damping of the lever's ringing against a closed stop,
    and in the free fixture the hub chatters on its stop (benchmarks/README.md, 'Fidelity presets'). Explicit,
    the flexure's damping c is stable while c·h/μ < 2, μ the hub and lever's reduced inertia (0.09 at 8
    substeps per ms at the defaults).
    """
    return p.simulation.substeps_rule != "fast"


def solver_time_constants(p: TestbedParams, fixture: str) -> dict[tuple[str, str], float]:
    """The solref time constants [s] the model uses, by ``(group, field)`` of ``SOLVER_TIME_CONSTANTS``.

    They are the parameters' values, except that under ``simulation.substeps_rule = 'fast'`` each is raised to
    two of its physics steps where it is shorter (the defaults are two steps of the accurate rule, and MuJoCo
    resolves no constraint faster than two steps). The parameters themselves are checked against the accurate
    rule's step (``build.check_time_constants``), so a parameter set valid for one rule is valid for both.
    """
    floor_s = 2.0 * physics_timestep(p, fixture)[0] if p.simulation.substeps_rule == "fast" else 0.0
    return {(group, name): max(getattr(getattr(p, group), name), floor_s)
            for group, name in SOLVER_TIME_CONSTANTS}
