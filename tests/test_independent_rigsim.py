"""The independent rigid-joint simulator (tests/independent/rigsim.py) against closed-form solutions."""

import math

import numpy as np
import pytest

from tests.independent.rigsim import (
    CONTROL_PERIOD_S,
    PID,
    OpenLoop,
    Plant,
    delay_pattern,
    delivered_effort,
    multisine,
    simulate,
)

DT = CONTROL_PERIOD_S


def open_loop(plant, commands, **kwargs):
    return simulate(plant, OpenLoop(np.asarray(commands, float)), len(commands), encoder_step=None, **kwargs)


def crossings(t, x):
    """Times where x crosses zero upwards (linear interpolation) [s]."""
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def test_coulomb_friction_decelerates_linearly_and_stops_at_m_v0_over_fc():
    m, fc, v0 = 0.05, 0.3, 2.0
    run = open_loop(Plant("hinge", m, coulomb=fc), np.zeros(600), v0=v0)
    stop = m * v0 / fc
    moving = run.time < stop - 2 * DT
    assert run.v_true[moving] == pytest.approx(v0 - fc / m * run.time[moving], abs=1e-9)
    assert np.all(run.v_true[run.time > stop + DT] == 0.0)
    h = DT / 20  # semi-implicit Euler moves by the new velocity: the stop position is short by ~v0·h/2
    assert run.q_true[-1] == pytest.approx(m * v0**2 / (2 * fc), abs=v0 * h)


def test_viscous_friction_decays_exponentially_with_time_constant_m_over_sigma2():
    m, sigma2, v0 = 2.0, 8.0, 0.3
    run = open_loop(Plant("slide", m, viscous=sigma2, stick_velocity=1e-7), np.zeros(500), v0=v0)
    # explicit in the friction: the decay per step is 1 − h·σ2/m for exp(−h·σ2/m), 1e-4 of σ2 here
    assert run.v_true == pytest.approx(v0 * np.exp(-sigma2 / m * run.time), rel=3e-4)


def test_a_force_below_breakaway_never_moves_the_joint_and_one_above_accelerates_at_f_minus_fc_over_m():
    m, fc, fs = 0.05, 0.3, 0.45
    plant = Plant("hinge", m, coulomb=fc, breakaway=fs, stribeck_velocity=0.1)
    assert np.all(open_loop(plant, np.full(1000, 0.99 * fs)).q_true == 0.0)
    run = open_loop(plant, np.full(1000, 0.5))
    first = run.v_true[0] / DT  # the first millisecond: friction at the static level
    assert first == pytest.approx((0.5 - fs) / m, rel=1e-3)
    late = (run.v_true[-1] - run.v_true[-101]) / (100 * DT)
    assert late == pytest.approx((0.5 - fc) / m, rel=1e-6)


def test_asymmetric_friction_levels_differ_by_direction():
    m, fc, delta = 0.05, 0.3, 0.1
    plant = Plant("hinge", m, coulomb=fc, asymmetry=delta)
    assert np.all(open_loop(plant, np.full(200, fc + 0.5 * delta - 1e-3)).q_true == 0.0)
    assert np.all(open_loop(plant, np.full(200, -(fc - 0.5 * delta) + 1e-3)).q_true == 0.0)
    up = open_loop(plant, np.full(200, 1.0))
    down = open_loop(plant, np.full(200, -1.0))
    assert up.v_true[-1] / up.time[-1] == pytest.approx((1.0 - fc - delta / 2) / m, rel=1e-6)
    assert down.v_true[-1] / down.time[-1] == pytest.approx(-(1.0 - fc + delta / 2) / m, rel=1e-6)


@pytest.mark.parametrize("delay", [0.0, 3.3e-3, 5e-3])
def test_a_command_step_arrives_delay_later(delay):
    m = 1.0
    commands = np.r_[np.zeros(100), np.ones(200)]  # u_100 is held from t = 100·dt
    run = open_loop(Plant("slide", m, delay=delay), commands)
    expected = np.maximum(run.time - 100 * DT - delay, 0.0) / m
    assert run.v_true == pytest.approx(expected, abs=1e-12)


def test_delay_pattern_weights_split_the_step_that_holds_the_arrival():
    pattern = delay_pattern(2.51e-3, 1e-3, 20)
    assert pattern[9] == (-3, 0.0)
    assert pattern[10][0] == -3 and pattern[10][1] == pytest.approx(0.8)
    assert pattern[11] == (-2, 0.0)


def two_mass_free_motion(fraction, fr, zeta):
    m, u = 2.0, 50.0
    plant = Plant("slide", m, compliant_fraction=fraction, resonance_frequency=fr, damping_ratio=zeta)
    dt = 1e-4  # finer rows for the peaks; physics still at 20 kHz
    commands = np.zeros(6000)
    commands[0] = u  # an impulse u·dt on the driven mass
    run = simulate(plant, OpenLoop(commands), len(commands), encoder_step=None, dt=dt, substeps=2)
    return run.time, run.v_true - u * dt / m  # the driven mass's velocity about the centre of mass


@pytest.mark.parametrize("fraction, fr, zeta", [(0.3, 15.0, 0.05), (0.5, 20.0, 0.02)])
def test_two_mass_drivetrain_oscillates_at_the_resonance_with_the_stated_damping(fraction, fr, zeta):
    t, x = two_mass_free_motion(fraction, fr, zeta)
    up = crossings(t, x)
    period = np.mean(np.diff(up[:6]))
    assert 1 / period == pytest.approx(fr * math.sqrt(1 - zeta**2), rel=2e-3)
    peaks = [np.max(np.abs(x[(t >= a) & (t < b)])) for a, b in zip(up[:5], up[1:6], strict=False)]
    decrement = np.mean(np.log(np.array(peaks[:-1]) / np.array(peaks[1:])))
    assert decrement / math.sqrt(4 * math.pi**2 + decrement**2) == pytest.approx(zeta, rel=0.03)


def test_backlash_leaves_the_driven_mass_alone_inside_the_gap():
    m, fraction, u = 2.0, 0.4, 10.0
    plant = Plant("slide", m, compliant_fraction=fraction, resonance_frequency=20.0, backlash_width=2e-3)
    run = open_loop(plant, np.full(40, u))
    m1 = (1 - fraction) * m
    free = run.q_true < 1e-3 - 1e-6  # the half gap is 1 mm
    assert free.sum() > 10
    assert run.v_true[free] == pytest.approx(u / m1 * run.time[free], rel=1e-9)
    assert run.v_true[-1] < u / m1 * run.time[-1] * 0.99  # contact: the second mass now takes part


def test_gravity_pendulum_small_oscillation_period():
    m, a = 0.05, 0.5
    run = open_loop(Plant("hinge", m, gravity_amplitude=a, gravity_angle=0.3), np.zeros(8000), q0=0.3 + 0.01)
    up = crossings(run.time, run.q_true - 0.3)
    assert np.mean(np.diff(up)) == pytest.approx(2 * math.pi * math.sqrt(m / a), rel=2e-4)


def test_slide_gravity_is_a_constant_force():
    run = open_loop(Plant("slide", 2.0, gravity_amplitude=4.0), np.zeros(200))
    assert run.v_true[-1] == pytest.approx(-4.0 / 2.0 * run.time[-1], rel=1e-9)


def test_position_spring_period():
    m, k = 2.0, 200.0
    run = open_loop(Plant("slide", m, spring_stiffness=k, spring_rest_position=0.01), np.zeros(3000))
    up = crossings(run.time, run.q_true - 0.01)
    assert np.mean(np.diff(up)) == pytest.approx(2 * math.pi * math.sqrt(m / k), rel=2e-4)


@pytest.mark.parametrize("u", [4.0, 12.0])  # within and beyond the peak effort (clipped)
def test_effort_gain_and_rolloff_give_the_steady_force(u):
    k, gain, c, peak = 100.0, 0.9, 0.15, 10.0
    plant = Plant("slide", 1.0, viscous=20.0, spring_stiffness=k, effort_gain=gain, torque_rolloff=c,
                  peak_effort=peak)
    run = open_loop(plant, np.full(3000, u))
    uc = min(u, peak)
    expected = gain * uc * (1 - c * (uc / peak) ** 2)
    assert delivered_effort(plant, u) == pytest.approx(expected)
    assert k * run.q_true[-1] == pytest.approx(expected, rel=1e-6)


def test_cogging_holds_a_constant_command_where_it_balances():
    amp, period, phase, u = 0.05, 0.1, 0.4, 0.03
    plant = Plant("hinge", 1e-4, viscous=0.05, cogging_amplitude=amp, cogging_period=period, cogging_phase=phase)
    run = open_loop(plant, np.full(3000, u))
    q = run.q_true[-1]
    assert amp * math.sin(2 * math.pi * q / period + phase) == pytest.approx(-u, abs=1e-7)


def test_periodic_disturbance_gives_the_driven_response_of_a_damped_mass():
    m, sigma2, amp, f = 0.05, 0.5, 0.2, 4.0
    plant = Plant("hinge", m, viscous=sigma2, disturbance_amplitude=amp, disturbance_frequency=f)
    run = open_loop(plant, np.zeros(3000), v0=0.0)
    w = 2 * math.pi * f
    late = run.time > 2.0  # transients decay with m/σ2 = 0.1 s
    assert np.max(np.abs(run.v_true[late])) == pytest.approx(amp / abs(sigma2 + 1j * m * w), rel=2e-3)


def test_quadratic_drag_terminal_velocity():
    f, cq = 2.0, 0.5
    run = open_loop(Plant("slide", 0.2, drag_coefficient=cq), np.full(3000, f))
    assert run.v_true[-1] == pytest.approx(math.sqrt(f / cq), rel=1e-6)


@pytest.mark.parametrize("joint", ["hinge", "slide"])
def test_position_dependent_inertia_conserves_kinetic_energy(joint):
    m0, alpha, v0 = 1.0, 0.5, 2.0
    plant = Plant(joint, m0, inertia_variation=alpha, inertia_length=1.0)
    run = open_loop(plant, np.zeros(1000), v0=v0)
    mass = m0 * (1 + alpha * np.sin(run.q_true)) if joint == "hinge" else m0 * (1 + alpha * run.q_true)
    energy = 0.5 * mass * run.v_true**2
    assert energy == pytest.approx(0.5 * m0 * v0**2, rel=1e-3)
    assert np.ptp(run.v_true) > 0.3  # the velocity changes with the inertia


def test_friction_varying_with_position_sets_the_breakaway_where_the_joint_sits():
    fc, beta, period = 0.3, 0.3, 2.0
    plant = Plant("hinge", 0.05, coulomb=fc, friction_variation=beta, friction_period=period)
    at_peak = period / 4  # sin = 1: the level is fc·(1 + β)
    assert np.all(open_loop(plant, np.full(200, 1.25 * fc), q0=at_peak).q_true == at_peak)
    assert open_loop(plant, np.full(200, 1.25 * fc), q0=-at_peak).q_true[-1] > -at_peak


def test_quantisation_step_and_time_conventions():
    plant = Plant("slide", 2.0, coulomb=3.0, viscous=8.0, peak_effort=100.0)
    ref = multisine(2000, 0.1, 3)
    end = simulate(plant, PID.tuned(ref, 2.0, 5.0, 100.0), 2000, seed=1, noise_std=2e-6)
    command = simulate(plant, PID.tuned(ref, 2.0, 5.0, 100.0), 2000, seed=1, noise_std=2e-6,
                       time_convention="command")
    steps = end.q / 1e-6
    assert steps == pytest.approx(np.round(steps), abs=1e-6)
    assert end.time[0] == pytest.approx(DT) and command.time[0] == 0.0
    assert np.array_equal(end.tau_cmd, command.tau_cmd)
    assert np.array_equal(command.q[1:], end.q[:-1])


def test_pid_tracks_the_reference_and_runs_are_deterministic():
    plant = Plant("hinge", 0.05, coulomb=0.3, viscous=0.05, peak_effort=10.0)
    ref = multisine(4000, 1.0, 5)
    runs = [simulate(plant, PID.tuned(ref, 0.05, 5.0, 10.0), 4000, seed=2) for _ in range(2)]
    assert np.array_equal(runs[0].q, runs[1].q) and np.array_equal(runs[0].tau_cmd, runs[1].tau_cmd)
    error = ref.position[1:] - runs[0].q[:-1]
    assert np.sqrt(np.mean(error**2)) < 0.02 * np.ptp(ref.position)


def test_battery_writes_a_log_rig_and_truth_the_project_reads(tmp_path):
    from sim.discrepancy.rig import load_rig
    from sim.logio import read_log
    from tests.independent.battery import cases, write_case

    chosen = {c.name: c for c in cases()}
    assert len(chosen) == len(cases())
    for name in ("gravity-slide-multisine-s133", "emps-estimation"):
        truth = write_case(chosen[name], tmp_path, 2.0)
        log = read_log(tmp_path / name / "log.csv", joint=truth["joint"])
        rig = load_rig(tmp_path / name / "rig.toml")
        assert len(log) == 2000 and rig.joint == "slide"
        assert truth["hidden"][0]["effect"] in ("gravity", "coulomb_friction")
