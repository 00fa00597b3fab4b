"""The windowed Stribeck fit (sim/discrepancy/windows.py): its forward model against closed forms, its fit against
logs of the independent simulator (tests/independent/rigsim.py) with known breakaway levels and Stribeck
velocities."""

from __future__ import annotations

import copy
import dataclasses
import functools
from types import SimpleNamespace

import numpy as np
import pytest

from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.model import Surrogate
from sim.discrepancy.rig import rig_from_dict
from sim.discrepancy.signals import AnalysisConfig, prepare
from sim.discrepancy.windows import Windows, find_windows, fit_stribeck, simulate
from tests.independent import rigsim

CONFIG = AnalysisConfig()
DT = rigsim.CONTROL_PERIOD_S
TOLERANCE = 0.2  # the fit recovers F_s and v_s within 20 %


# ------------------------------------------------------------------------------------------- forward model


def constant_windows(force: float, samples: int, substeps: int = 4, velocity0: float = 0.0) -> Windows:
    """One window under a constant force [N·m], from rest (or sliding at ``velocity0``), nothing measured."""
    steps = samples * substeps + 1
    return Windows(start=np.array([0]), event=np.array([0]), at_rest=np.array([velocity0 == 0.0]),
                   forcing=np.full((1, steps), force), measured=np.zeros((1, samples)),
                   mask=np.ones((1, samples), dtype=bool), velocity0=np.array([velocity0]), step=DT / substeps,
                   substeps=substeps, events=1)


def positions(windows: Windows, m: float, fc: float, fs: float, vs: float, sigma2: float = 0.0) -> np.ndarray:
    return simulate(windows, m, fc, sigma2, np.array([fs]), np.array([vs]))[0, 0]


def test_a_force_within_the_static_level_never_moves_a_stuck_joint():
    assert np.all(positions(constant_windows(0.449, 200), 0.05, 0.3, 0.45, 0.1) == 0.0)
    assert np.all(positions(constant_windows(-0.449, 200), 0.05, 0.3, 0.45, 0.1) == 0.0)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_breakaway_first_accelerates_at_u_minus_fs_over_m_then_at_u_minus_fc_over_m(sign):
    m, fc, fs, u = 0.05, 0.3, 0.45, 0.5
    # a Stribeck velocity far above the first millisecond's speed: friction stays at F_s, q = (u - F_s)/m·t²/2
    q = positions(constant_windows(sign * u, 1), m, fc, fs, vs=10.0)
    assert q[0] == pytest.approx(sign * 0.5 * (u - fs) / m * DT**2, rel=1e-4)
    # a vanishing Stribeck velocity: friction falls to F_c at once, the acceleration is (u - F_c)/m
    q = positions(constant_windows(sign * u, 100), m, fc, fs, vs=1e-9)
    late = (q[-1] - 2 * q[-2] + q[-3]) / DT**2
    assert late == pytest.approx(sign * (u - fc) / m, rel=1e-9)


def test_sliding_away_from_rest_follows_the_stribeck_curve():
    """Under a constant u just above F_s, m·dv/dt = u - g(v) with g = F_c + (F_s - F_c)·exp(-(v/v_s)²): by
    quadrature, the time t(v) = ∫ m/(u - g) dv and the position x(v) = ∫ m·v/(u - g) dv of each speed, compared with
    the simulated position at those times."""
    m, fc, fs, vs, u = 0.05, 0.3, 0.45, 0.05, 0.46
    q = positions(constant_windows(u, 60), m, fc, fs, vs)
    v = np.linspace(0.0, 0.3, 300_001)
    rate = m / (u - fc - (fs - fc) * np.exp(-(v / vs) ** 2))  # dt/dv
    dv = v[1] - v[0]
    t = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1])) * dv])
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] * rate[1:] + v[:-1] * rate[:-1])) * dv])
    times = DT * np.arange(1, 61)
    inside = times < t[-1]
    assert inside.sum() > 30
    assert q[inside] == pytest.approx(np.interp(times[inside], t, x), rel=1e-3, abs=1e-9)


def test_a_sliding_joint_under_coulomb_friction_stops_at_m_v0_squared_over_2_fc_and_stays():
    m, fc, v0 = 2.0, 3.0, 0.3
    q = positions(constant_windows(0.0, 400, velocity0=v0), m, fc, fc, 0.01)  # F_s = F_c: no Stribeck drop
    assert q[-1] == pytest.approx(m * v0**2 / (2 * fc), rel=1e-9)
    assert np.all(q[-100:] == q[-1])


def test_a_batch_simulates_each_parameter_set_as_alone():
    w = constant_windows(0.5, 50)
    batch = simulate(w, 0.05, 0.3, 0.05, np.array([0.4, 0.45]), np.array([0.02, 0.1]))
    for k, (fs, vs) in enumerate([(0.4, 0.02), (0.45, 0.1)]):
        assert np.array_equal(batch[k, 0], positions(w, 0.05, 0.3, fs, vs, 0.05))


# ------------------------------------------------------------------------------ logs of the independent simulator


BASE = {"hinge": {"mass": 0.05, "coulomb": 0.3, "viscous": 0.05, "peak": 10.0, "span": 1.0, "speed": 3.0},
        "slide": {"mass": 2.0, "coulomb": 3.0, "viscous": 8.0, "peak": 100.0, "span": 0.1, "speed": 0.4}}


@functools.cache
def simulated(joint: str, excitation: str, ratio: float, vs: float, seed: int, *, delay: float = 0.0,
              gain: float = 1.0, constant: float = 0.0, noise: float = 0.0) -> tuple[Surrogate, dict, rigsim.Run]:
    """A 10 s closed-loop (5 Hz PID) log of a joint with F_s = ratio x F_c (1: no Stribeck drop) and v_s, encoder
    noise of ``noise`` steps; the surrogate of its true rig (the truth's Coulomb, viscous, inertia, dead time, effort
    gain, constant force), the truth and the run."""
    b = BASE[joint]
    n = 10_000
    ref = (rigsim.multisine(n, b["span"], seed) if excitation == "multisine"
           else rigsim.point_to_point(n, 1.5 * b["span"] if joint == "hinge" else 2 * b["span"], b["speed"], seed))
    plant = rigsim.Plant(joint, b["mass"], coulomb=b["coulomb"], breakaway=ratio * b["coulomb"],
                         stribeck_velocity=vs, viscous=b["viscous"], peak_effort=b["peak"], delay=delay,
                         effort_gain=gain, gravity_amplitude=constant, stick_velocity=1e-4 * b["speed"] / 3)
    run = rigsim.simulate(plant, rigsim.PID.tuned(ref, b["mass"], 5.0, b["peak"]), n, seed=seed,
                          noise_std=noise * rigsim.default_encoder_step(joint))
    rig = rig_from_dict({"model": "rigid-joint", "joint": joint,
                         ("mass_kg" if joint == "slide" else "inertia_kgm2"): b["mass"], "effort_gain": gain,
                         "delay_s": delay, "peak_effort": b["peak"], "constant_effort": constant,
                         "friction": {"coulomb": b["coulomb"], "viscous": b["viscous"]}})
    model = Surrogate(prepare(run.to_log(), rig, CONFIG), rig, CONFIG)
    return model, {"breakaway": ratio * b["coulomb"], "stribeck_velocity": vs}, run


def stribeck_range(model: Surrogate) -> tuple[tuple[float, float], float]:
    """The Stribeck effect's ranges on ``model``: (v_s's [rad/s | m/s], F_s's top [N·m | N])."""
    effect = EFFECTS["stribeck_friction"]
    return (effect.bounds("stribeck_velocity", model.scale, model.theta0),
            effect.bounds("breakaway", model.scale, model.theta0)[1])


def case(*args, **kwargs) -> tuple[Surrogate, dict[str, float]]:
    model, truth, _ = simulated(*args, **kwargs)
    return model, truth


RECOVERED = [
    pytest.param(("hinge", "point_to_point", 1.5, 0.05, 1), {}, id="hinge-point_to_point"),
    pytest.param(("hinge", "multisine", 1.6, 0.08, 2), {}, id="hinge-multisine"),
    pytest.param(("slide", "point_to_point", 1.4, 0.01, 3), {"delay": 0.003, "gain": 0.9, "constant": 1.5},
                 id="slide-point_to_point-delay-gain-constant_force"),
    pytest.param(("slide", "multisine", 1.7, 0.015, 4), {}, id="slide-multisine"),
    pytest.param(("hinge", "point_to_point", 1.5, 0.05, 1), {"noise": 1.0}, id="hinge-point_to_point-noise"),
]


@pytest.mark.parametrize(("args", "kwargs"), RECOVERED)
def test_the_fit_recovers_the_breakaway_and_the_stribeck_velocity_of_independent_logs(args, kwargs):
    model, truth = case(*args, **kwargs)
    fit = fit_stribeck(model, model.theta0, *stribeck_range(model))
    assert fit.breakaway == pytest.approx(truth["breakaway"], rel=TOLERANCE)
    assert fit.stribeck_velocity == pytest.approx(truth["stribeck_velocity"], rel=TOLERANCE)
    assert fit.resolved and fit.bound == ""
    assert fit.interval[0] < fit.stribeck_velocity < fit.interval[1]
    assert 0 < fit.windows <= 40 and fit.seconds > 0


def test_a_log_without_a_stribeck_drop_gives_the_coulomb_level_and_no_stribeck_velocity():
    model, truth = case("hinge", "multisine", 1.0, 0.05, 5)
    fit = fit_stribeck(model, model.theta0, *stribeck_range(model))
    assert fit.breakaway == pytest.approx(truth["breakaway"], rel=0.02)
    assert not fit.resolved and fit.bound.startswith("v_s not bounded")


def test_a_stribeck_velocity_below_what_the_windows_resolve_is_bounded_from_above():
    model, truth = case("hinge", "point_to_point", 1.5, 0.001, 6)
    fit = fit_stribeck(model, model.theta0, *stribeck_range(model))
    assert fit.breakaway == pytest.approx(truth["breakaway"], rel=TOLERANCE)
    assert not fit.resolved and fit.bound.startswith("v_s below")
    assert fit.interval[1] > truth["stribeck_velocity"]


@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_windows_start_where_the_true_joint_is_at_rest_or_at_their_start_velocity(noise):
    """Row k of the log is the state at t = (k + 1)·dt: at a window's start at rest the true joint is stuck, or
    breaking away so slowly that it has not moved by an encoder step in REST_LEAD_S (at a few % of v_s; with
    encoder noise, slipping by a fraction of v_s: a still encoder cannot tell); a sliding window's start velocity
    is the true one to 2 %."""
    model, truth, run = simulated("hinge", "point_to_point", 1.5, 0.05, 1, noise=noise)
    windows = find_windows(model, model.theta0)
    rest = windows.at_rest
    assert rest.sum() >= 3
    speed = np.array([np.abs(run.v_true[start - 5:start + 1]).max() for start in windows.start[rest]])
    assert np.all(speed < (0.3 if noise else 0.03) * truth["stribeck_velocity"])
    assert np.mean(speed == 0.0) >= (0.3 if noise else 0.8)
    sliding = ~rest
    error = np.abs(windows.velocity0[sliding] - run.v_true[windows.start[sliding]])
    assert np.all(error <= 0.02 * np.abs(run.v_true[windows.start[sliding]]))


def test_windows_carry_the_logged_command_held_over_each_sample_and_lie_in_the_chosen_part():
    model, _ = case("slide", "point_to_point", 1.4, 0.01, 3, delay=0.003, gain=0.9, constant=1.5)
    theta = {**model.theta0, "delay": 0.0}
    windows = find_windows(model, theta, substeps=4, part="fit")
    u = model.data.u_full
    for w, start in enumerate(windows.start):  # row k's command acts over (t_k - dt, t_k]
        expected = 0.9 * np.repeat(u[start + 1:start + 1 + windows.mask[w].sum()], 4) - 1.5
        assert windows.forcing[w, 1:1 + len(expected)] == pytest.approx(expected, rel=1e-9, abs=1e-9)
    d = model.data
    fit_times = d.t[d.fit]
    assert np.all(d.t_full[windows.start] >= fit_times[0])
    assert np.all(d.t_full[windows.start + windows.mask.sum(axis=1)] < fit_times[-1] + d.grid_step * d.dt)


def test_the_mapped_command_is_the_independent_simulators_delivered_effort_before_its_gain():
    model, _ = case("slide", "point_to_point", 1.4, 0.01, 3, delay=0.003, gain=0.9, constant=1.5)
    theta = {**model.theta0, "torque_rolloff": 0.15}
    plant = rigsim.Plant("slide", 2.0, peak_effort=theta["peak_effort"], torque_rolloff=0.15, effort_gain=0.9)
    beyond = copy.copy(model)  # commands beyond the peak too
    beyond.data = dataclasses.replace(model.data, u_full=np.r_[model.data.u_full, 150.0, -150.0])
    expected = [rigsim.delivered_effort(plant, x) for x in beyond.data.u_full]
    assert theta["effort_gain"] * beyond.mapped_command(theta) == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_the_testbed_is_refused():
    with pytest.raises(ValueError, match="rigid joint"):
        find_windows(SimpleNamespace(testbed=True), {})
