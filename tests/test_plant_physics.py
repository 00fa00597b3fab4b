"""Plant physics against oracles: closed forms, independent computations and the paper's numbers."""

import math

import numpy as np
import pytest

from models.gim8108_testbed.derived import derive, lumped_modes_hz
from sim.characterize import (
    free_vibration_peak_hz,
    linearizable_plant,
    linearized_modes,
    measure_backlash,
    measure_breakaway,
)
from sim.params import TestbedParams
from sim.plant import Plant
from sim.thermal import ThermalState

P = TestbedParams()
P_LINEAR_MOTOR = P.replace(motor={"torque_saturation_per_nm": 0.0})  # delivers what it is commanded
D = derive(P)
TICK_S = P.simulation.control_period_s
# the command that delivers the 18 N·m peak through τ = c/(1 + α|c|): the driver's current limit, 26.3 N·m
DRIVER_LIMIT_NM = P.motor.peak_torque_nm / (1.0 - P.motor.torque_saturation_per_nm * P.motor.peak_torque_nm)


def hold(plant: Plant, tau_cmd: float, seconds: float, tau_ext: float = 0.0) -> None:
    for _ in range(round(seconds / TICK_S)):
        plant.step(tau_cmd, tau_ext)


def test_flexure_stiffness_is_the_closed_form_of_eq7():
    """K_t = 4 r_i² (l³/3EI + l/κGA)⁻¹ with the paper's Table I, computed here by hand, and compiled as is."""
    e, nu = 71.7e9, 0.33
    g = e / (2 * (1 + nu))
    length, b, h, r_i = 0.021, 0.004, 0.007, 0.019
    inertia = h * b**3 / 12
    k_t = 4 * r_i**2 / (length**3 / (3 * e * inertia) + length / (5 / 6 * g * b * h))
    assert D.flexure_stiffness_nm_per_rad == pytest.approx(k_t, rel=1e-12)
    model = Plant(P, "locked").model
    assert model.jnt_stiffness[model.joint("flexure").id] == pytest.approx(k_t, rel=1e-8)


def test_static_deflection_equals_torque_over_stiffness():
    """An external torque on the free lever, held by a stuck gear, twists the flexure by T/K_t (within 1 %)."""
    torque = 0.1  # below the breakaway torque: the gear holds
    plant = Plant(P, "free")
    plant.reset(backlash_side=-1)  # an external positive torque closes the stop a negative motor torque closes
    hold(plant, 0.0, 1.0, tau_ext=torque)
    twist = -torque / D.flexure_stiffness_nm_per_rad
    # static: the twist drifts by less than 0.01 % per second (the dry-friction rows creep a few nrad/s)
    assert abs(plant.output_velocity_rad_s) < 1e-4 * abs(twist)
    assert plant.flexure_angle_rad == pytest.approx(twist, rel=0.01)


@pytest.mark.parametrize("tau_cmd", [0.5, 3.0, -10.0, 18.0])
def test_loadcell_force_times_lever_equals_flexure_torque_at_steady_state(tau_cmd):
    """Locked fixture at rest: F_loadcell x 0.1 m = flexure torque within 1 %."""
    plant = Plant(P, "locked")
    hold(plant, tau_cmd, 1.0)
    lever_torque = plant.loadcell_force_n * P.lever.length_m
    assert lever_torque == pytest.approx(plant.flexure_torque_nm, rel=0.01)
    assert abs(lever_torque) > 0.2 * abs(tau_cmd)  # the torque really went through


def test_linearised_modes_match_the_lumped_closed_form():
    """mjd_transitionFD's undamped-equivalent frequencies equal the lumped eigenvalues within 2 %."""
    plant = linearizable_plant(P, "locked", preload_nm=1.0)
    modes = [m.natural_frequency_hz for m in linearized_modes(plant)]
    lumped = [f for f in lumped_modes_hz(P, "locked", backlash_closed=True, gear_stuck=True) if f > 0]
    assert modes == pytest.approx(lumped, rel=0.02)


# Free fixture: the hub floats in the backlash, so the flexure is kicked, gently enough (1e-4 rad/s) that
# the hub and lever do not drift onto a stop during the record.
@pytest.mark.parametrize("fixture, preload, kick, kick_rad_s", [("locked", 1.0, "motor", 0.01),
                                                                ("free", 0.0, "flexure", 1e-4)])
def test_free_vibration_spectrum_peaks_at_the_linearised_mode(fixture, preload, kick, kick_rad_s):
    """The FFT peak of a kicked plant is the lightly damped linearised mode's resonance within 2 %.

    For λ = -σ ± iω_d the impulse response's spectrum peaks at sqrt(ω_d² - σ²).
    """
    plant = linearizable_plant(P, fixture, preload)
    light = [m for m in linearized_modes(plant) if m.damping_ratio < 0.2]
    assert light, "no lightly damped mode to excite"
    mode = light[-1]
    omega_n = 2 * math.pi * mode.natural_frequency_hz
    sigma = mode.damping_ratio * omega_n
    omega_d = omega_n * math.sqrt(1 - mode.damping_ratio**2)
    expected_hz = math.sqrt(omega_d**2 - sigma**2) / (2 * math.pi)
    peak = free_vibration_peak_hz(plant, duration_s=0.5, kick_joint=kick, kick_rad_s=kick_rad_s,
                                  band_hz=(0.5 * expected_hz, 1.5 * expected_hz))
    assert peak == pytest.approx(expected_hz, rel=0.02)


def test_rule_step_keeps_the_locked_control_mode_within_2_percent():
    """At the rule's step the control-relevant mode has the frequency and damping of a 16x finer step."""
    coarse = linearizable_plant(P, "locked", 1.0)
    fine = linearizable_plant(P, "locked", 1.0, timestep_s=coarse.timestep_s / 16)
    a, b = linearized_modes(coarse)[0], linearized_modes(fine)[0]
    assert a.natural_frequency_hz == pytest.approx(b.natural_frequency_hz, rel=0.02)
    assert a.damping_ratio == pytest.approx(b.damping_ratio, rel=0.02)
    assert 50.0 < a.natural_frequency_hz < 500.0  # it is the drivetrain mode, below the loop's Nyquist rate


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_breakaway_is_the_paper_threshold_within_10_percent(sign):
    """Ramp in the free fixture: the motor starts moving for > 100 ms at 0.13 N·m ± 10 % (paper Sec. IV)."""
    assert measure_breakaway(P, sign=sign).torque_nm == pytest.approx(0.13, rel=0.10)


@pytest.mark.parametrize("fraction", [0.5, 0.95])
def test_gear_holds_below_breakaway(fraction):
    """Creep bound: below breakaway the gear drifts by less than 1 µrad over 2 s after settling."""
    plant = Plant(P, "free")
    tau = fraction * P.friction.breakaway_torque_nm
    hold(plant, tau, 1.0)
    start = plant.motor_angle_rad
    hold(plant, tau, 2.0)
    assert abs(plant.motor_angle_rad - start) < 1e-6


def test_acceleration_above_breakaway_is_net_torque_over_inertia():
    """Sliding in the free fixture: dω/dt = (τ - τ_friction)/J within 5 %, friction from the parameters, τ what the
    motor delivers for the command, c/(1 + α|c|)."""
    plant = Plant(P, "free")
    tau = 1.0
    hold(plant, tau, 0.3)
    v0 = plant.motor_velocity_rad_s
    velocities, twist_torques = [], []
    for _ in range(100):
        plant.step(tau)
        velocities.append(plant.motor_velocity_rad_s)
        twist_torques.append(plant.flexure_torque_nm)
    measured = (plant.motor_velocity_rad_s - v0) / (100 * TICK_S)
    fr = P.friction
    friction = (fr.coulomb_torque_nm + fr.load_friction_coefficient * abs(np.mean(twist_torques))
                + fr.viscous_nms_per_rad * np.mean(velocities))
    inertia = D.reflected_rotor_inertia_kgm2 + D.output_inertia_kgm2 + D.lever_side_inertia_kgm2
    delivered = tau / (1.0 + P.motor.torque_saturation_per_nm * tau)
    assert measured == pytest.approx((delivered - friction) / inertia, rel=0.05)


def test_slow_reversal_shows_the_backlash_width_within_10_percent():
    """Motor angle against load-cell torque: the two loaded branches are one backlash width apart."""
    assert measure_backlash(P).width_rad == pytest.approx(P.backlash.width_rad, rel=0.10)


def test_backlash_stop_penetrates_less_than_10_percent_of_the_gap_at_full_torque():
    """At the driver's limit (18 N·m delivered) the stop's soft constraint lets the hub into the stop by < 10 % of
    the gap."""
    plant = Plant(P, "locked")
    hold(plant, DRIVER_LIMIT_NM, 0.5)
    penetration = abs(plant.backlash_angle_rad) - 0.5 * P.backlash.width_rad
    assert 0.0 <= penetration < 0.1 * P.backlash.width_rad


def test_load_dependent_friction_grows_with_transmitted_torque():
    """The gear joint's frictionloss is (1-η)·|τ| after a tick transmitting τ, on top of the LuGre levels."""
    losses = []
    for command_nm in (2.0, 5.0, 10.0):
        plant = Plant(P, "locked")
        hold(plant, command_nm, 0.3)
        loss = plant.model.dof_frictionloss[plant.model.joint("motor").dofadr[0]]
        assert loss == pytest.approx(P.friction.load_friction_coefficient * abs(plant.flexure_torque_nm), rel=0.01)
        losses.append(loss)
    assert losses[0] < losses[1] < losses[2]
    assert losses[2] > 3 * losses[0]


@pytest.mark.parametrize("share, moves", [(0.5, False), (1.5, True)])
def test_load_friction_holds_a_torque_difference_below_its_level_and_slips_above(share, moves):
    """Stuck under 10 N·m, a command that differs from the held flexure torque by less than the gear's holding
    torque (breakaway + (1-η)·|τ|) leaves the gear in place without creep; by more, the gear slips."""
    plant = Plant(P_LINEAR_MOTOR, "locked")
    hold(plant, 10.0, 0.5)
    held_nm = plant.flexure_torque_nm
    holding_nm = P.friction.breakaway_torque_nm + P.friction.load_friction_coefficient * abs(held_nm)
    start = plant.motor_angle_rad
    hold(plant, held_nm - share * holding_nm, 1.0)
    moved = abs(plant.motor_angle_rad - start)
    assert (moved > 1e-5) if moves else (moved < 1e-6), moved


def test_current_estimate_follows_the_command_with_the_current_loop_lag():
    """The driver's estimate N·K_t·i rises as 1 - exp(-t/τ_i) after the command delay."""
    p = P.replace(motor={"command_delay_s": 0.0})
    plant = Plant(p, "locked")
    plant.step(1.0)
    tau_i = p.motor.current_loop_time_constant_s
    assert plant.current_torque_estimate_nm == pytest.approx(1.0 - math.exp(-TICK_S / tau_i), rel=1e-3)


def test_command_delay_postpones_the_current_response():
    """With a 0.5 ms delay the current after the first tick is that of a 0.5 ms shorter step."""
    delay = 5e-4
    plant = Plant(P.replace(motor={"command_delay_s": delay}), "locked")
    plant.step(1.0)
    tau_i = P.motor.current_loop_time_constant_s
    assert plant.current_torque_estimate_nm == pytest.approx(1.0 - math.exp(-(TICK_S - delay) / tau_i), rel=0.02)


@pytest.mark.parametrize("command_nm", [-12.0, 10.0, 30.0])
def test_motor_delivers_the_current_to_torque_map_of_the_limited_command(command_nm):
    """Held on the locked lever, the flexure carries τ/(1 + α|τ|) of the command τ limited to the driver's ±26.3 N·m
    (closed form), less or more the friction the gear can hold; the driver's estimate reports the limited command."""
    plant = Plant(P, "locked")
    hold(plant, command_nm, 0.5)
    limited = min(max(command_nm, -DRIVER_LIMIT_NM), DRIVER_LIMIT_NM)
    delivered = limited / (1.0 + P.motor.torque_saturation_per_nm * abs(limited))
    fr = P.friction
    holdable = fr.breakaway_torque_nm + fr.load_friction_coefficient * abs(delivered)
    assert abs(plant.flexure_torque_nm - delivered) <= holdable
    assert abs(limited - delivered) > 2 * holdable  # so the linear motor would fail the first assertion
    assert plant.current_torque_estimate_nm == pytest.approx(limited, rel=1e-9)


@pytest.mark.parametrize("params", [P, P_LINEAR_MOTOR], ids=["saturating", "linear"])
def test_motor_torque_saturates_at_the_paper_peak(params):
    """A 40 N·m command gives the 18 N·m peak motor torque (paper Sec. II) at the driver's current limit, which the
    driver's estimate reports; the load cell sees the peak less or more the friction the gear can hold."""
    plant = Plant(params, "locked")
    hold(plant, 40.0, 0.5)
    alpha = params.motor.torque_saturation_per_nm
    limit_nm = P.motor.peak_torque_nm / (1.0 - alpha * P.motor.peak_torque_nm)  # 26.3 N·m, or 18 N·m if linear
    assert plant.current_torque_estimate_nm == pytest.approx(limit_nm, rel=1e-9)
    fr = P.friction
    holdable = fr.breakaway_torque_nm + fr.load_friction_coefficient * P.motor.peak_torque_nm
    assert abs(plant.loadcell_force_n * P.lever.length_m - P.motor.peak_torque_nm) <= holdable


def test_copper_loss_is_that_of_the_current_the_driver_commands():
    """Held at 10 N·m for 2 s, the winding warms as the thermal network does with R·i², i = τ_cmd/(N·K_t): the
    current the driver commands, (1 + 10α)² = 1.38x the loss of the torque-producing current."""
    plant = Plant(P, "locked")
    ambient = plant.thermal.temperatures_c.copy()
    hold(plant, 10.0, 2.0)
    current_a = 10.0 / (P.motor.gear_ratio * P.motor.torque_constant_nm_per_a)
    reference = ThermalState(P.thermal)
    reference.advance(2.0, P.motor.winding_resistance_ohm * current_a**2)
    rise = plant.thermal.temperatures_c[1] - ambient[1]
    assert rise == pytest.approx(reference.temperatures_c[1] - ambient[1], rel=0.01)


@pytest.mark.parametrize("delay_s", [5e-4, 9.375e-4, 1e-3, 2e-3, 3.2e-3])
def test_past_commands_prime_the_driver_as_if_it_had_been_running(delay_s):
    """After hold_commands(past) a plant put in another's state delivers what the one that ran those commands
    delivers, from its first tick: the delay buffer holds the past ticks' commands (a ramp, and a delay of several
    ticks) and the current loop sits where they left it (no silent first milliseconds, no current rise)."""
    p = P.replace(motor={"command_delay_s": delay_s})
    ramp = np.linspace(2.0, 6.0, 50)
    running = Plant(p, "locked")
    for u in ramp:
        running.step(u)
    primed = Plant(p, "locked")
    primed.data.qpos[:] = running.data.qpos
    primed.data.qvel[:] = running.data.qvel
    primed.data.act[:] = running.data.act
    primed.hold_commands(ramp)
    for u in (6.1, 6.2, 6.3, 6.4, 6.5):
        running.step(u)
        primed.step(u)
        assert primed.flexure_torque_nm == pytest.approx(running.flexure_torque_nm, rel=1e-6)
        assert primed.current_torque_estimate_nm == pytest.approx(running.current_torque_estimate_nm, rel=1e-6)
