"""Closed-form tests of every effect's forward models (``sim/discrepancy/effects``).

Two kinds per effect:

1. The surrogate's term (``Surrogate.residuals``) on a log whose motion is analytic and whose command is the effort
   that motion needs under the effect's physical law, computed here. Row k's command is held during
   ``(t_k - dt, t_k]``; the surrogate places it at the hold's centre, so the command of row k is the needed effort
   at ``t_k - dt/2`` (plus the dead time). With the true parameters the effort residual vanishes to the surrogate's
   numerics; a 10 % error of a parameter (or another exponent of the law) leaves a residual well above it.
2. The MuJoCo realisation (``run_rigid``, ``run_testbed``, ``sensor_reading``) against an analytic solution.

No expected value comes from the project's own functions: each is a closed form (or a bisection of one) written
here. ``CLOSED_FORM_TESTS`` names the tests that cover each effect; an effect of the library without an entry
fails ``test_every_effect_has_a_closed_form_test``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.gim8108_testbed.derived import derive
from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.model import Surrogate
from sim.discrepancy.rig import Rig, RigError, rig_from_dict
from sim.discrepancy.signals import AnalysisConfig, prepare
from sim.discrepancy.simulate import run_rigid, run_testbed, sensor_reading
from sim.logio import SlideRunLog
from sim.runlog import RunLog

TWO_PI = 2.0 * math.pi
DT = 1e-3  # [s] the project's 1 kHz logs
N_SAMPLES = 8000  # 8 s
CONFIG = AnalysisConfig()
# Effort residual of the surrogate with the true parameters (RMS on the fit and held-out parts over the command's
# RMS) [1]. What remains is the surrogate's numerics: the second central difference of the filtered position
# (relative error (ω·dt)²/12 < 1e-4 below 5 Hz), the linear interpolation of the command to the hold's centre, the
# bilinear transform of the compliance filter (1.7e-3 of its term at 9.3 Hz next to a 12 Hz resonance). Measured
# 1e-8 to 9e-4; every log below is built so that a 10 % parameter error leaves at least 1 % (5 x this).
SURROGATE_TOLERANCE = 2e-3
H_RIGID = 2e-4  # [s] run_rigid's physics step (5 per 1 ms tick)


# ------------------------------------------------------------------------------------------------- helpers


class Sines:
    """q(t) = ramp·t + Σ a·sin(2π·f·t + φ) and its derivatives, analytic."""

    def __init__(self, ramp: float, parts: tuple[tuple[float, float, float], ...]) -> None:
        self.ramp, self.parts = ramp, parts

    def q(self, t):
        return self.ramp * t + sum(a * np.sin(TWO_PI * f * t + p) for a, f, p in self.parts)

    def v(self, t):
        return self.ramp + sum(a * TWO_PI * f * np.cos(TWO_PI * f * t + p) for a, f, p in self.parts)

    def a(self, t):
        return sum(-a * (TWO_PI * f) ** 2 * np.sin(TWO_PI * f * t + p) for a, f, p in self.parts)


SWING = Sines(0.0, ((1.0, 0.4, 0.3), (0.3, 1.3, 1.0), (0.05, 3.7, 2.0)))  # hinge [rad]: reversals, 3 rad span
SLIDE_SWING = Sines(0.0, ((0.1, 0.4, 0.0), (0.02, 1.3, 1.0), (0.003, 3.1, 2.0)))  # slide [m]
ONE_WAY = {  # the joint never stops: ramp above the sines' largest velocity
    "hinge": Sines(0.15, ((0.05, 0.3, 0.0), (0.005, 1.1, 1.0), (0.0005, 2.9, 0.5))),  # 0.020-0.28 rad/s
    "slide": Sines(0.1, ((0.015, 0.4, 0.0), (0.004, 1.3, 1.0), (0.0008, 3.1, 2.0))),  # 0.020-0.18 m/s
}
J_HINGE, M_SLIDE = 0.05, 2.0  # [kg·m², kg]


def times(start: float = 0.0) -> np.ndarray:
    return start + DT * np.arange(N_SAMPLES)


def held(t: np.ndarray, dead_time: float = 0.0) -> np.ndarray:
    """Where row k's command acts: the centre of its hold, ``t_k - dt/2``, plus the dead time [s]."""
    return t - 0.5 * DT + dead_time


def effect(name: str, **params: float) -> dict:
    return {"name": name, **params}


def rigid_rig(joint: str, inertia: float, friction: dict | None = None, effects: tuple = (), **fields) -> Rig:
    """A rigid joint, frictionless unless ``friction`` says otherwise."""
    data = {"model": "rigid-joint", "joint": joint, ("mass_kg" if joint == "slide" else "inertia_kgm2"): inertia,
            "effort_gain": 1.0, "friction": friction or {"coulomb": 0.0, "viscous": 0.0}, **fields}
    if effects:
        data["effects"] = [dict(e) for e in effects]
    return rig_from_dict(data)


def rigid_log(joint: str, t: np.ndarray, q: np.ndarray, u: np.ndarray) -> RunLog:
    cols = {"time": t, "tau_cmd": np.asarray(u, dtype=float), "q": q}
    meta = {"time_convention": "hold_end"}
    if joint == "slide":
        return SlideRunLog(cols, {"time": "s", "tau_cmd": "N", "q": "m"}, meta)
    return RunLog(cols, {"time": "s", "tau_cmd": "N·m", "q": "rad"}, meta)


def surrogate(log: RunLog, rig: Rig) -> Surrogate:
    return Surrogate(prepare(log, rig, CONFIG), rig, CONFIG)


def misfit(log: RunLog, rig: Rig, *, channel: str = "effort", after: float = -math.inf, **theta: float) -> float:
    """RMS of the surrogate's ``channel`` residual on the fit and held-out parts (grid times > ``after``) over the
    command's RMS [1], with the rig's theta changed by ``theta``."""
    model = surrogate(log, rig)
    r = model.residuals({**model.theta0, **theta})[channel]
    ok = (model.data.fit | model.data.held) & np.isfinite(r) & (model.data.t > after)
    u = np.asarray(log["tau_cmd"])
    return math.sqrt(np.mean(r[ok] ** 2)) / math.sqrt(np.mean(u**2))


def assert_explains(log: RunLog, rig: Rig, *perturbed: dict, after: float = -math.inf) -> None:
    """The surrogate explains ``log`` with the rig's values and does not with each ``perturbed`` change."""
    assert misfit(log, rig, after=after) < SURROGATE_TOLERANCE
    for change in perturbed:
        assert misfit(log, rig, after=after, **change) > SURROGATE_TOLERANCE, change


def bisect(f, target: np.ndarray, low: float, high: float, steps: int = 60) -> np.ndarray:
    """x in [low, high] with f(x) = target for an increasing f, elementwise."""
    lo, hi = np.full_like(target, low), np.full_like(target, high)
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        above = f(mid) > target
        lo, hi = np.where(above, lo, mid), np.where(above, mid, hi)
    return 0.5 * (lo + hi)


# ------------------------------------------------------------------------ 1. the surrogate's terms, rigid joints


@pytest.mark.parametrize("joint", ["hinge", "slide"])
def test_inertia_needs_m_times_acceleration(joint):
    """u = m·q̈."""
    m, motion = (J_HINGE, SWING) if joint == "hinge" else (M_SLIDE, SLIDE_SWING)
    t = times()
    log = rigid_log(joint, t, motion.q(t), m * motion.a(held(t)))
    assert_explains(log, rigid_rig(joint, m), {"inertia": 1.1 * m}, {"inertia": 0.9 * m})


def test_effort_gain_delivers_g_times_command():
    """g·u = m·q̈."""
    g, t = 0.8, times()
    log = rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(held(t)) / g)
    rig = rigid_rig("hinge", J_HINGE, effort_gain=g)
    assert_explains(log, rig, {"effort_gain": 1.1 * g}, {"effort_gain": 0.9 * g})


def test_coulomb_friction_needs_fc_while_sliding():
    """u = m·q̈ + F_c (the slide moving forward throughout)."""
    fc, motion, t = 3.0, ONE_WAY["slide"], times()
    log = rigid_log("slide", t, motion.q(t), M_SLIDE * motion.a(held(t)) + fc)
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": fc, "viscous": 0.0})
    assert_explains(log, rig, {"coulomb": 1.1 * fc}, {"coulomb": 0.9 * fc})


def test_viscous_friction_needs_sigma2_v():
    """u = m·q̈ + σ2·q̇."""
    sigma2, motion, t = 8.0, ONE_WAY["slide"], times()
    log = rigid_log("slide", t, motion.q(t), M_SLIDE * motion.a(held(t)) + sigma2 * motion.v(held(t)))
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": 0.0, "viscous": sigma2})
    assert_explains(log, rig, {"viscous": 1.1 * sigma2}, {"viscous": 0.9 * sigma2})


def stribeck(v, fc, fs, vs, exponent=2.0):
    return fc + (fs - fc) * np.exp(-np.abs(v / vs) ** exponent)


def test_stribeck_friction_falls_from_fs_to_fc_as_exp_of_minus_v_over_vs_squared():
    """u = m·q̈ + F_c + (F_s - F_c)·exp(-(v/v_s)²), the hinge sliding forward at 0.2-2.8 v_s."""
    fc, fs, vs, motion, t = 0.3, 0.5, 0.1, ONE_WAY["hinge"], times()
    rig = rigid_rig("hinge", J_HINGE, {"coulomb": fc, "viscous": 0.0, "breakaway": fs, "stribeck_velocity": vs})
    tc = held(t)
    log = rigid_log("hinge", t, motion.q(t), J_HINGE * motion.a(tc) + stribeck(motion.v(tc), fc, fs, vs))
    assert_explains(log, rig, {"breakaway": 1.1 * fs}, {"stribeck_velocity": 1.1 * vs},
                    {"stribeck_velocity": 0.9 * vs})
    other_law = rigid_log("hinge", t, motion.q(t), J_HINGE * motion.a(tc) + stribeck(motion.v(tc), fc, fs, vs, 1.5))
    assert misfit(other_law, rig) > SURROGATE_TOLERANCE


@pytest.mark.parametrize("direction", [1, -1])
def test_constant_effort_is_friction_levels_that_differ_by_twice_it_between_directions(direction):
    """Levels F_c + Δ/2 moving forward, F_c - Δ/2 moving back are F_c·sign(v) plus the constant c = Δ/2:
    u = m·q̈ + F_c + Δ/2 or m·q̈ - (F_c - Δ/2)."""
    fc, delta, t = 0.3, 0.4, times()
    base = ONE_WAY["hinge"]
    motion = Sines(direction * base.ramp, tuple((direction * a, f, p) for a, f, p in base.parts))
    friction = fc + delta / 2 if direction > 0 else -(fc - delta / 2)
    log = rigid_log("hinge", t, motion.q(t), J_HINGE * motion.a(held(t)) + friction)
    rig = rigid_rig("hinge", J_HINGE, {"coulomb": fc, "viscous": 0.0},
                    effects=(effect("constant_effort", constant_effort=delta / 2),))
    assert_explains(log, rig, {"constant_effort": 0.55 * delta}, {"constant_effort": -delta / 2})


def test_constant_effort_on_a_slide_needs_c_whatever_the_motion():
    """u = m·q̈ + c on a slide swinging both ways (gravity along an incline, a steady pull)."""
    c, t = -2.0, times()
    log = rigid_log("slide", t, SLIDE_SWING.q(t), M_SLIDE * SLIDE_SWING.a(held(t)) + c)
    rig = rigid_rig("slide", M_SLIDE, constant_effort=c)
    assert_explains(log, rig, {"constant_effort": 1.1 * c}, {"constant_effort": -c})


def test_record_offsets_take_each_records_own_zero_out_of_the_effort():
    """Two records of one motion whose logged effort carries another zero each (+0.2 and -0.3 N·m): with
    record_offsets the surrogate explains both and returns those zeros; one shared constant cannot."""
    t = times()
    needed = J_HINGE * SWING.a(held(t))
    zeros = (0.2, -0.3)
    first, second = (rigid_log("hinge", t, SWING.q(t), needed + z) for z in zeros)
    rig = rigid_rig("hinge", J_HINGE)
    from sim.discrepancy.analysis import Source, join_and_prepare

    sources = [Source("a", "estimation", first), Source("b", "estimation", second)]
    model = Surrogate(join_and_prepare(sources, rig, CONFIG)[3], rig, CONFIG)
    command = math.sqrt(np.mean(needed**2))

    def misfit_of(theta: dict) -> float:
        r = model.residuals({**model.theta0, **theta})["effort"]
        ok = (model.data.fit | model.data.held) & np.isfinite(r)
        return math.sqrt(np.mean(r[ok] ** 2)) / command

    assert misfit_of({"record_offsets": 1.0}) < SURROGATE_TOLERANCE
    assert model.record_offsets({**model.theta0, "record_offsets": 1.0})["effort"] == pytest.approx(zeros, abs=2e-3)
    assert misfit_of({"constant_effort": float(np.mean(zeros))}) > 50 * SURROGATE_TOLERANCE
    assert model.record_offsets(model.theta0) == {}


def test_record_offsets_leave_the_simulated_rig_alone():
    """The records' zeros are how the records were taken: a rig carrying the effect simulates exactly as one
    without it."""
    rig = rigid_rig("hinge", J_HINGE, {"coulomb": 0.1, "viscous": 0.02})
    with_zeros = rigid_rig("hinge", J_HINGE, {"coulomb": 0.1, "viscous": 0.02},
                           effects=(effect("record_offsets", record_offsets=1.0),))
    command = lambda k, s: 0.5 * math.sin(0.01 * k)  # noqa: E731
    a, b = run_rigid(rig, command, 500), run_rigid(with_zeros, command, 500)
    np.testing.assert_array_equal(a.columns["q"], b.columns["q"])


def test_quadratic_drag_needs_c_v_abs_v():
    """u = m·q̈ + c·v·|v|."""
    c, t = 0.05, times()
    tc = held(t)
    v = SWING.v(tc)
    rig = rigid_rig("hinge", J_HINGE, effects=(effect("quadratic_drag", drag_coefficient=c),))
    log = rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(tc) + c * v * np.abs(v))
    assert_explains(log, rig, {"drag_coefficient": 1.1 * c}, {"drag_coefficient": 0.9 * c})
    other_law = rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(tc) + c * np.sign(v) * np.abs(v) ** 1.5)
    assert misfit(other_law, rig) > SURROGATE_TOLERANCE


def test_cogging_needs_minus_a_sin_of_two_pi_q_over_p_plus_phi():
    """u = m·q̈ - A·sin(2π·q/P + φ) (the magnets push the joint)."""
    a, period, phase, t = 0.4, 0.25, 0.7, times()
    tc = held(t)
    rig = rigid_rig("hinge", J_HINGE, effects=(effect("cogging", cogging_amplitude=a, cogging_period=period,
                                                      cogging_phase=phase),))
    log = rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(tc) - a * np.sin(TWO_PI * SWING.q(tc) / period + phase))
    assert_explains(log, rig, {"cogging_amplitude": 1.1 * a}, {"cogging_period": 1.01 * period},
                    {"cogging_phase": phase + 0.1}, {"cogging_phase": phase + math.pi})


def test_torque_rolloff_delivers_u_times_one_minus_c_u_over_peak_squared():
    """u·(1 - c·(|u|/u_peak)²) = m·q̈, u by bisection (|u| up to 0.84 u_peak)."""
    c, peak, t = 0.3, 4.0, times()
    needed = J_HINGE * SWING.a(held(t))

    def command_for(law_exponent):
        delivered = lambda u: u * (1.0 - c * (u / peak) ** law_exponent)  # noqa: E731  increasing on [0, peak]
        return np.sign(needed) * bisect(delivered, np.abs(needed), 0.0, peak)

    rig = rigid_rig("hinge", J_HINGE, peak_effort=peak, effects=(effect("torque_constant_nonlinearity",
                                                                        torque_rolloff=c),))
    log = rigid_log("hinge", t, SWING.q(t), command_for(2.0))
    assert np.abs(log["tau_cmd"]).max() > 0.8 * peak
    assert_explains(log, rig, {"torque_rolloff": 1.1 * c}, {"torque_rolloff": 0.9 * c})
    assert misfit(rigid_log("hinge", t, SWING.q(t), command_for(1.5)), rig) > SURROGATE_TOLERANCE


def test_transport_delay_shifts_the_command_by_d():
    """The command of row k acts at t_k - dt/2 + d: u_k = m·q̈(t_k - dt/2 + d)."""
    d, t = 0.008, times()
    motion = Sines(0.0, ((0.5, 0.6, 0.3), (0.1, 2.3, 1.0), (0.02, 5.3, 2.0)))
    log = rigid_log("hinge", t, motion.q(t), J_HINGE * motion.a(held(t, d)))
    assert_explains(log, rigid_rig("hinge", J_HINGE, delay_s=d), {"delay": 1.1 * d}, {"delay": 0.9 * d},
                    {"delay": d + 0.5 * DT})  # the last: the command placed at t_k instead of its hold's centre


def test_gravity_needs_a_sin_q_minus_q0_on_a_hinge():
    """u = m·q̈ + A·sin(q - q0)."""
    t = times()
    a, q0 = 0.4, 0.5
    gravity = a * np.sin(SWING.q(held(t)) - q0)
    rig = rigid_rig("hinge", J_HINGE, effects=(effect("gravity", gravity_amplitude=a, gravity_angle=q0),))
    assert_explains(rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(held(t)) + gravity), rig,
                    {"gravity_amplitude": 1.1 * a}, {"gravity_angle": q0 + 0.1})


def test_a_slide_states_its_constant_force_as_constant_effort_not_gravity():
    with pytest.raises(RigError, match="constant_effort"):
        rig_from_dict({"model": "rigid-joint", "joint": "slide", "mass_kg": 2.0, "effort_gain": 1.0,
                       "gravity_amplitude": -2.0})


def test_position_spring_needs_k_q_minus_q0():
    """u = m·q̈ + k·(q - q0)."""
    k, q0, t = 0.3, 0.2, times()
    tc = held(t)
    rig = rigid_rig("hinge", J_HINGE, effects=(effect("position_spring", spring_stiffness=k,
                                                      spring_rest_position=q0),))
    log = rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(tc) + k * (SWING.q(tc) - q0))
    assert_explains(log, rig, {"spring_stiffness": 1.1 * k}, {"spring_rest_position": q0 + 0.1})


def test_periodic_disturbance_needs_minus_a_sin_from_the_first_sample():
    """u = m·q̈ - A·sin(2π·f·(t - t_0) + φ), t_0 the log's first sample (here 3 s); 19 Hz, where the analysis
    filter passes 90 % of the line."""
    a, f, phase, t0 = 0.3, 19.0, 0.9, 3.0
    t = times(t0)
    tc = held(t)
    rig = rigid_rig("hinge", J_HINGE, effects=(effect("periodic_disturbance", disturbance_amplitude=a,
                                                      disturbance_frequency=f, disturbance_phase=phase),))
    log = rigid_log("hinge", t, SWING.q(t), J_HINGE * SWING.a(tc) - a * np.sin(TWO_PI * f * (tc - t0) + phase))
    assert_explains(log, rig, {"disturbance_amplitude": 1.1 * a}, {"disturbance_frequency": 1.01 * f},
                    {"disturbance_phase": phase + 0.1})


def test_drivetrain_compliance_needs_m1_q_dd_plus_m2_x2_dd():
    """m1 = (1-φ)m carries q, m2 = φm follows through k = μ(2πf_r)², c = 2ζ·sqrt(kμ), μ = φ(1-φ)m: for
    q = Σ A_i·sin(ω_i t + φ_i), x2 = Σ A_i·|H_i|·sin(ω_i t + φ_i + ∠H_i), H = (cs + k)/(m2 s² + cs + k), and
    u = m1·q̈ + m2·ẍ2. The model's filter starts from rest at the log's start: its transient decays as
    exp(-ζ(1-φ)ω_r t) (10.6/s), so only t > 1.5 s counts (e^-16)."""
    m, phi, fr, zeta = J_HINGE, 0.3, 12.0, 0.2
    mu = phi * (1 - phi) * m
    k = mu * (TWO_PI * fr) ** 2
    c = 2 * zeta * math.sqrt(k * mu)
    m1, m2 = (1 - phi) * m, phi * m
    motion = Sines(0.0, ((0.5, 0.7, 0.3), (0.02, 4.1, 1.0), (0.004, 9.3, 2.0)))  # around the resonance
    t = times()
    tc = held(t)
    x2_dd = 0.0
    for amplitude, f, p in motion.parts:
        w = TWO_PI * f
        h = (c * 1j * w + k) / (m2 * (1j * w) ** 2 + c * 1j * w + k)
        x2_dd = x2_dd - w * w * amplitude * abs(h) * np.sin(w * tc + p + np.angle(h))
    rig = rigid_rig("hinge", m, effects=(effect("drivetrain_compliance", compliant_fraction=phi,
                                                resonance_frequency=fr, damping_ratio=zeta),))
    log = rigid_log("hinge", t, motion.q(t), m1 * motion.a(tc) + m2 * x2_dd)
    assert_explains(log, rig, {"compliant_fraction": 1.1 * phi}, {"resonance_frequency": 1.1 * fr},
                    {"damping_ratio": 1.1 * zeta}, after=1.5)


# ------------------------------------------------------------------------ 1. the surrogate's terms, the testbed

# Testbed rigs for the surrogate tests: the LuGre gear friction made negligible (F_c = F_s = 1 µN·m) unless a
# test states it, the Stribeck velocity small so that the slow motor motion counts as sliding.
TESTBED_SURROGATE_FRICTION = {"breakaway_torque_nm": 1e-6, "coulomb_torque_nm": 1e-6,
                              "load_friction_coefficient": 0.0, "stribeck_velocity_rad_s": 1e-4}


def rig_of_testbed(fixture: str, friction: dict, effects: tuple = ()) -> Rig:
    data = {"model": "testbed", "fixture": fixture, "friction": friction}
    if effects:
        data["effects"] = [dict(e) for e in effects]
    return rig_from_dict(data)


def locked_log(rig: Rig, t, tau, u, q_motor, **extra) -> RunLog:
    """A locked-fixture log: the lever held still at 0 (no lever inertia torque), the load cell carrying ``tau``."""
    units = {"time": "s", "tau_cmd": "N·m", "q": "rad", "q_motor": "rad", "force_loadcell": "N",
             "tau_sensor": "N·m", "temperature": "°C"}
    cols = {"time": t, "tau_cmd": u, "q": np.zeros_like(t), "q_motor": q_motor,
            "force_loadcell": tau / rig.params.lever.length_m, **extra}
    return RunLog(cols, {k: units[k] for k in cols}, {"time_convention": "hold_end", "fixture": "locked"})


def motor_command(rig: Rig, needed: np.ndarray) -> np.ndarray:
    """The command whose torque τ = u/(1 + α|u|) is ``needed``: u = τ/(1 - α|τ|)."""
    alpha = rig.params.motor.torque_saturation_per_nm
    return needed / (1.0 - alpha * np.abs(needed))


def surrogate_dead_time(rig: Rig) -> float:
    """The testbed's command dead time as the surrogate carries it: the delay plus the current loop's lag [s]."""
    return rig.params.motor.command_delay_s + rig.params.motor.current_loop_time_constant_s


@pytest.mark.parametrize("direction", [1, -1])
def test_load_dependent_friction_needs_mu_abs_tau_against_the_motion(direction):
    """Locked fixture, the transmitted torque τ winding the flexure one way (gear sliding with q̇_m = τ̇/K_t):
    u = J·q̈_m + σ2·q̇_m + τ + μ·|τ|·sign(q̇_m)."""
    mu = 0.2
    rig = rig_of_testbed("locked", {**TESTBED_SURROGATE_FRICTION, "load_friction_coefficient": mu})
    p = rig.params
    stiffness, width = derive(p).flexure_stiffness_nm_per_rad, p.backlash.width_rad
    inertia = p.motor.gear_ratio**2 * p.motor.rotor_inertia_kgm2 + derive(p).output_inertia_kgm2
    torque = Sines(0.6 * direction, ((0.1 * direction, 0.5, 0.0), (0.01 * direction, 2.3, 0.0)))  # τ̇ >= 0.14
    t = times()
    tc = held(t, surrogate_dead_time(rig))
    tau = 3.5 + torque.q(tc - 4.0)
    v, a = torque.v(tc - 4.0) / stiffness, torque.a(tc - 4.0) / stiffness
    needed = inertia * a + p.friction.viscous_nms_per_rad * v + tau + mu * np.abs(tau) * np.sign(v)
    tau_t = 3.5 + torque.q(t - 4.0)
    log = locked_log(rig, t, tau_t, motor_command(rig, needed), tau_t / stiffness + width / 2)
    assert_explains(log, rig, {"load_coefficient": 1.1 * mu}, {"load_coefficient": 0.9 * mu})


def smooth_step(t, start: float, duration: float):
    """S(s) = s - sin(2πs)/2π, s = (t - start)/duration clipped to [0, 1], and its first two time derivatives."""
    s = np.clip((t - start) / duration, 0.0, 1.0)
    return (s - np.sin(TWO_PI * s) / TWO_PI, (1 - np.cos(TWO_PI * s)) / duration,
            TWO_PI * np.sin(TWO_PI * s) / duration**2)


def test_presliding_bristle_follows_the_lugre_closed_form():
    """LuGre ż = v - σ0|v|z/g with g = F_s = F_c: along a stroke in direction s starting from bristle z_r,
    z = s·g/σ0 + (z_r - s·g/σ0)·exp(-σ0|Δx|/g) and ż = (s·g/σ0 - z_r)·(σ0/g)·|v|·exp(-σ0|Δx|/g). Smooth strokes of
    1.5 g/σ0 back and forth (150 ms, then 350 ms at rest); the free fixture's motor (no lever column: the lever
    moves with it) needs u = (J + J_lever)·ẍ + σ2·ẋ + σ0·z + σ1·ż, σ1 = 2ζ·sqrt(σ0·N²·J_rotor)."""
    level, sigma0 = 0.13, 2000.0
    rig = rig_of_testbed("free", {**TESTBED_SURROGATE_FRICTION, "breakaway_torque_nm": level,
                                  "coulomb_torque_nm": level, "presliding_stiffness_nm_per_rad": sigma0})
    p = rig.params
    reflected = p.motor.gear_ratio**2 * p.motor.rotor_inertia_kgm2
    inertia = reflected + derive(p).output_inertia_kgm2 + derive(p).lever_side_inertia_kgm2
    sigma1 = 2 * p.friction.presliding_damping_ratio * math.sqrt(sigma0 * reflected)
    reach = level / sigma0  # the presliding displacement
    size, first, period, duration, count = 1.5 * reach, 0.3, 0.5, 0.15, 15
    t = times()
    tc = held(t, surrogate_dead_time(rig))
    x, v, a, z, zd = (np.zeros_like(t) for _ in range(5))
    z_start = 0.0
    for j in range(count):
        direction = 1 if j % 2 == 0 else -1
        s, sd, sdd = smooth_step(tc, first + j * period, duration)
        x, v, a = x + direction * size * s, v + direction * size * sd, a + direction * size * sdd
        now = (tc >= first + j * period) & ((tc < first + (j + 1) * period) | (j == count - 1))
        decay = np.exp(-size * s[now] / reach)
        z[now] = direction * reach + (z_start - direction * reach) * decay
        zd[now] = (direction * reach - z_start) / reach * size * sd[now] * decay
        z_start = direction * reach + (z_start - direction * reach) * math.exp(-size / reach)
    needed = inertia * a + p.friction.viscous_nms_per_rad * v + sigma0 * z + sigma1 * zd
    position = 0.01 + sum((1 if j % 2 == 0 else -1) * size * smooth_step(t, first + j * period, duration)[0]
                          for j in range(count))
    log = RunLog({"time": t, "tau_cmd": motor_command(rig, needed), "q_motor": position},
                 {"time": "s", "tau_cmd": "N·m", "q_motor": "rad"}, {"time_convention": "hold_end"})
    assert_explains(log, rig, {"presliding_stiffness": 1.1 * sigma0}, {"presliding_stiffness": 0.9 * sigma0})


def test_backlash_puts_the_motor_half_a_band_ahead_of_the_hub():
    """Locked fixture: q_motor - q - τ/K_t = (w/2)·sign(τ). The zero-phase filter smears the jump at a torque
    reversal over its transient: samples within CONFIG.guard_s (2.5 periods of the cut-off) of one do not count."""
    rig = rig_of_testbed("locked", TESTBED_SURROGATE_FRICTION)
    stiffness, width = derive(rig.params).flexure_stiffness_nm_per_rad, rig.params.backlash.width_rad
    t = times()
    tau = 3.0 * np.sin(TWO_PI * 0.3 * t) + 0.5 * np.sin(TWO_PI * 1.1 * t)
    log = locked_log(rig, t, tau, tau, tau / stiffness + width / 2 * np.sign(tau))
    model = surrogate(log, rig)
    reversals = t[np.flatnonzero(np.diff(np.sign(tau)))]
    away = np.min(np.abs(model.data.t[:, None] - reversals[None, :]), axis=1) > CONFIG.guard_s

    def worst(theta):
        r = model.residuals({**model.theta0, **theta})["kinematic"]
        ok = (model.data.fit | model.data.held) & np.isfinite(r) & away
        assert ok.sum() > 500
        return np.abs(r[ok]).max() / (width / 2)

    assert worst({}) < 2e-3  # the filter's tail beyond the guard (measured 8e-4)
    assert worst({"backlash_width": 1.1 * width}) > 0.09
    assert worst({"backlash_width": 0.9 * width}) > 0.09


# --------------------------------------------------------------------------------------- the sensor's terms

SENSOR_T_CAL = 25.0  # [°C] sim.params photoreflector.reference_temperature_c (checked below)


def sensor_log():
    """A locked log with a sensor column (g·τ + b + c_T·(T - T_cal)) and a temperature ramp 20 -> 40 °C."""
    rig = rig_of_testbed("locked", TESTBED_SURROGATE_FRICTION)
    assert rig.params.photoreflector.reference_temperature_c == SENSOR_T_CAL
    t = times()
    tau = 1.0 + 3.0 * np.sin(TWO_PI * 0.3 * t) + 0.5 * np.sin(TWO_PI * 1.1 * t)
    temperature = 20.0 + 20.0 * t / t[-1]
    return rig, t, tau, temperature


@pytest.mark.parametrize("name, values, expected", [
    ("sensor_offset", {"sensor_offset": 0.07}, lambda tau, temp: 0.07 + 0 * tau),
    ("sensor_gain", {"sensor_gain": 1.04}, lambda tau, temp: 0.04 * tau),
    ("sensor_thermal_drift", {"sensor_tempco": 6e-3}, lambda tau, temp: 6e-3 * (temp - SENSOR_T_CAL)),
], ids=["offset", "gain", "drift"])
def test_sensor_hook_adds_offset_gain_error_and_drift(name, values, expected):
    """reading - τ = b; (g - 1)·τ; c_T·(T - T_cal) (T the log's filtered temperature: a ramp passes the
    zero-phase filter unchanged away from its edges)."""
    rig, t, tau, temperature = sensor_log()
    log = locked_log(rig, t, tau, tau, tau / 1e3, tau_sensor=tau, temperature=temperature)
    model = surrogate(log, rig)
    grid_tau = np.linspace(-4.0, 4.0, len(model.data.t))
    added = EFFECTS[name].sensor(model, {**model.theta0, **values}, grid_tau)
    want = expected(grid_tau, 20.0 + 20.0 * model.data.t / t[-1])
    counted = model.data.fit | model.data.held  # the filter's edge transient bends the ramp within the guards,
    # and by < 1e-5 K beyond them (6e-8 N·m of drift here)
    np.testing.assert_allclose(np.broadcast_to(added, want.shape)[counted], want[counted], rtol=0, atol=2e-7)


def test_linear_sensor_effects_explain_the_sensor_channel():
    """tau_sensor = g·τ + b + c_T·(T - T_cal): the sensor residual vanishes with the true values only."""
    rig, t, tau, temperature = sensor_log()
    g, b, c = 1.04, 0.07, 6e-3
    reading = g * tau + b + c * (temperature - SENSOR_T_CAL)
    log = locked_log(rig, t, tau, tau, tau / 1e3, tau_sensor=reading, temperature=temperature)
    true = {"sensor_gain": g, "sensor_offset": b, "sensor_tempco": c}
    assert misfit(log, rig, channel="sensor", **true) < 1e-6
    for key in true:
        assert misfit(log, rig, channel="sensor", **{**true, key: 0.9 * true[key]}) > 1e-3, key


def triangle(peaks: list[float], step: float) -> np.ndarray:
    """Straight segments between successive ``peaks`` in steps of ``step`` [N·m]."""
    out = [np.array([peaks[0]])]
    for a, b in zip(peaks[:-1], peaks[1:], strict=True):
        n = int(round(abs(b - a) / step))
        out.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(out)


def hysteresis_by_hand(peaks: list[float], step: float, height: float, span: float) -> np.ndarray:
    """The loop H/S·(τ - p) on the triangle, segment by segment: the play p holds its value p_r from the segment's
    start (p_0 = τ_0; p_r = τ_r - gap_r after a reversal at τ_r) until τ - p reaches ±S, so the gap τ - p is
    min(τ - p_r, S) on a rising segment and max(τ - p_r, -S) on a falling one."""
    out, p_r = [np.array([0.0])], peaks[0]
    for a, b in zip(peaks[:-1], peaks[1:], strict=True):
        n = int(round(abs(b - a) / step))
        tau = np.linspace(a, b, n + 1)[1:]
        gap = np.minimum(tau - p_r, span) if b > a else np.maximum(tau - p_r, -span)
        p_r = b - gap[-1]
        out.append(height / span * gap)
    return np.concatenate(out)


PEAKS, STEP = [0.0, 3.0, -3.0, 2.5, 1.8, 4.0], 0.01  # a minor loop: 2.5 -> 1.8 is shorter than 2S


def test_sensor_hysteresis_hook_is_the_play_operator_loop():
    """reading - τ = H/S·(τ - p), p the play operator of half-width S starting at τ_0: saturates at ±H."""
    height, span = 0.04, 0.8
    rig, t, tau, temperature = sensor_log()
    model = surrogate(locked_log(rig, t, tau, tau, tau / 1e3, tau_sensor=tau, temperature=temperature), rig)
    wave = triangle(PEAKS, STEP)
    added = EFFECTS["sensor_hysteresis"].sensor(model, {**model.theta0, "sensor_hysteresis": height,
                                                        "sensor_hysteresis_span": span}, wave)
    np.testing.assert_allclose(added, hysteresis_by_hand(PEAKS, STEP, height, span), rtol=0, atol=1e-12)
    assert np.isclose(added.max(), height) and np.isclose(added.min(), -height)


@pytest.mark.parametrize("name, values", [
    ("sensor_offset", {"sensor_offset": -0.05}),
    ("sensor_gain", {"sensor_gain": 0.97}),
    ("sensor_thermal_drift", {"sensor_tempco": -4e-3}),
    ("sensor_hysteresis", {"sensor_hysteresis": 0.03, "sensor_hysteresis_span": 0.5}),
])
def test_sensor_reading_adds_the_effects_hand_values(name, values):
    """The simulated sensor reads τ + b, g·τ, τ + c_T·(T - T_cal), τ + H/S·(τ - p) (realisation)."""
    wave = triangle(PEAKS, STEP)
    temperature = np.linspace(15.0, 45.0, len(wave))
    truth = rig_of_testbed("locked", TESTBED_SURROGATE_FRICTION, (effect(name, **values),))
    reading = sensor_reading(truth, wave, temperature)
    want = {"sensor_offset": lambda: wave - 0.05, "sensor_gain": lambda: 0.97 * wave,
            "sensor_thermal_drift": lambda: wave - 4e-3 * (temperature - SENSOR_T_CAL),
            "sensor_hysteresis": lambda: wave + hysteresis_by_hand(PEAKS, STEP, 0.03, 0.5)}[name]()
    np.testing.assert_allclose(reading, want, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------ 2. MuJoCo realisations, rigid joints


def constant(u: float):
    return lambda k, state: u


def final_velocity(rig: Rig, u: float, n: int = 1000) -> tuple[float, float]:
    """(time [s], velocity) at the end of ``n`` ticks under a constant command from rest."""
    run = run_rigid(rig, constant(u), n)
    return float(run.columns["time"][-1]), float(run.columns["qd"][-1])


# From rest under a constant net force, semi-implicit Euler is exact for the velocity: v(t) = a·t to rounding.
EXACT = 1e-9


@pytest.mark.parametrize("joint", ["hinge", "slide"])
def test_mujoco_inertia_accelerates_at_u_over_m(joint):
    """Frictionless, constant u from rest: q̇ = (u/m)·t."""
    m, u = (0.07, 0.3) if joint == "hinge" else (3.0, 5.0)
    t, v = final_velocity(rigid_rig(joint, m), u)
    assert v == pytest.approx(u / m * t, rel=EXACT)


def test_mujoco_effort_gain_accelerates_at_g_u_over_m():
    """q̇ = (g·u/m)·t."""
    g, u = 0.8, 5.0
    t, v = final_velocity(rigid_rig("slide", M_SLIDE, effort_gain=g), u)
    assert v == pytest.approx(g * u / M_SLIDE * t, rel=EXACT)


def test_mujoco_rolloff_accelerates_at_rolled_off_u_over_m():
    """q̇ = (u·(1 - c·(u/u_peak)²)/m)·t; above u_peak the drive clips the command first: u_peak·(1 - c)."""
    c, peak = 0.3, 10.0
    rig = rigid_rig("slide", M_SLIDE, peak_effort=peak, effects=(effect("torque_constant_nonlinearity",
                                                                        torque_rolloff=c),))
    for u, delivered in ((7.0, 7.0 * (1 - c * 0.49)), (-4.0, -4.0 * (1 - c * 0.16)), (13.0, peak * (1 - c))):
        t, v = final_velocity(rig, u)
        assert v == pytest.approx(delivered / M_SLIDE * t, rel=EXACT), u


# MuJoCo's dry friction is a soft constraint: a joint held below its level creeps at ~3e-8 m/s per N here.
CREEP_BOUND_M = 1e-6


def test_mujoco_coulomb_friction_holds_below_fc_and_slides_at_u_minus_fc_over_m():
    """u < F_c: the slide stays; u > F_c: q̇ = ((u - F_c)/m)·t."""
    fc = 3.0
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": fc, "viscous": 0.0})
    assert abs(run_rigid(rig, constant(0.9 * fc), 1000).columns["q"][-1]) < CREEP_BOUND_M
    t, v = final_velocity(rig, 7.0)
    assert v == pytest.approx((7.0 - fc) / M_SLIDE * t, rel=1e-6)


def test_mujoco_viscous_friction_velocity_approaches_u_over_sigma2():
    """q̇ = (u/σ2)·(1 - exp(-σ2·t/m)); MuJoCo integrates the damping implicitly: the discrete decay
    (1 + σ2h/m)^-n departs from the exponential by ~σ2²ht/(2m²) = 2e-4 over 1 s."""
    sigma2, u = 8.0, 7.0
    run = run_rigid(rigid_rig("slide", M_SLIDE, {"coulomb": 0.0, "viscous": sigma2}), constant(u), 1000)
    t, v = run.columns["time"], run.columns["qd"]
    np.testing.assert_allclose(v, u / sigma2 * (1 - np.exp(-sigma2 * t / M_SLIDE)), rtol=0, atol=5e-4 * u / sigma2)


def test_mujoco_stribeck_friction_holds_below_fs_breaks_away_above_and_slides_on_fc():
    """F_c < u < F_s: stuck. u > F_s: breaks away. Sliding at v >> v_s: m·v̇ = u - F_c - σ2·v, so from t1
    v = v∞ + (v(t1) - v∞)·exp(-σ2(t - t1)/m), v∞ = (u - F_c)/σ2."""
    fc, fs, vs, sigma2 = 3.0, 5.0, 0.01, 8.0
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": fc, "viscous": sigma2, "breakaway": fs, "stribeck_velocity": vs})
    for u in (4.0, 4.9):
        assert abs(run_rigid(rig, constant(u), 1000).columns["q"][-1]) < CREEP_BOUND_M, u
    assert run_rigid(rig, constant(5.1), 1000).columns["qd"][-1] > 10 * vs
    u = 20.0
    run = run_rigid(rig, constant(u), 1500)
    t, v = run.columns["time"], run.columns["qd"]
    i = int(np.argmax(v > 10 * vs))  # exp(-(v/v_s)²) < 1e-43 from here
    v_inf = (u - fc) / sigma2
    expected = v_inf + (v[i] - v_inf) * np.exp(-sigma2 * (t[i:] - t[i]) / M_SLIDE)
    np.testing.assert_allclose(v[i:], expected, rtol=0, atol=5e-4 * v_inf)  # implicit damping, as above


@pytest.mark.parametrize("ratio", [0.5, 1.5])
def test_mujoco_stribeck_sliding_velocity_balances_the_stribeck_curve(ratio):
    """A constant u > F_s: the slide settles at the v with u = F_c + (F_s - F_c)·exp(-(v/v_s)²) + σ2·v, here
    v = 0.5 and 1.5 v_s (σ2 > 0.86 (F_s - F_c)/v_s: one stable solution). The balance is exact at steady state:
    what remains is the approach, exp(-t/0.16 s) after 2 s."""
    fc, fs, vs, sigma2 = 3.0, 5.0, 0.2, 20.0
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": fc, "viscous": sigma2, "breakaway": fs, "stribeck_velocity": vs})
    v = ratio * vs
    u = fc + (fs - fc) * math.exp(-ratio**2) + sigma2 * v
    assert final_velocity(rig, u, 2000)[1] == pytest.approx(v, rel=1e-4)


@pytest.mark.parametrize("carried_by", ["effect", "rig"])
@pytest.mark.parametrize("u", [0.5, -0.5])
def test_mujoco_constant_effort_accelerates_at_u_minus_c_over_j(u, carried_by):
    """A frictionless hinge needing the constant c: q̈ = (u - c)/J, whether an added effect or the rig's own field
    carries it."""
    c = 0.1
    rig = (rigid_rig("hinge", J_HINGE, effects=(effect("constant_effort", constant_effort=c),))
           if carried_by == "effect" else rigid_rig("hinge", J_HINGE, constant_effort=c))
    t, v = final_velocity(rig, u)
    assert v == pytest.approx((u - c) / J_HINGE * t, rel=EXACT)


def test_mujoco_drag_reaches_terminal_velocity_sqrt_u_over_c():
    """m·v̇ = u - c·v|v| from rest: v = v_T·tanh(t/τ), v_T = sqrt(u/c), τ = m/sqrt(u·c) (0.5 s). The drag is
    evaluated at each physics step's start: error O(h/τ) = 4e-4."""
    c, u = 8.0, 2.0
    run = run_rigid(rigid_rig("slide", M_SLIDE, effects=(effect("quadratic_drag", drag_coefficient=c),)),
                    constant(u), 3000)
    t, v = run.columns["time"], run.columns["qd"]
    v_t, tau = math.sqrt(u / c), M_SLIDE / math.sqrt(u * c)
    np.testing.assert_allclose(v, v_t * np.tanh(t / tau), rtol=0, atol=4e-4 * v_t)
    assert v[-1] == pytest.approx(v_t, rel=1e-4)


def settle_hinge(rig: Rig, u: float, start: float, n: int = 3000) -> np.ndarray:
    def initial(model, data):
        data.qpos[0] = start

    return run_rigid(rig, constant(u), n, initial=initial).columns["q"]


def critical_damping(stiffness: float, inertia: float) -> float:
    return 2.0 * math.sqrt(stiffness * inertia)


def test_mujoco_cogging_settles_where_the_cogging_balances_the_command():
    """Net effort u + A·sin(θ), θ = 2πq/P + φ: from θ = π the damped hinge settles at θ = π + asin(u/A)."""
    a, period, phase, u = 0.4, 0.2, 0.7, 0.15
    stiffness = a * TWO_PI / period * math.cos(math.asin(u / a))
    rig = rigid_rig("hinge", J_HINGE, {"coulomb": 0.0, "viscous": critical_damping(stiffness, J_HINGE)},
                    effects=(effect("cogging", cogging_amplitude=a, cogging_period=period, cogging_phase=phase),))
    q = settle_hinge(rig, u, (math.pi - phase) * period / TWO_PI)
    expected = (math.pi + math.asin(u / a) - phase) * period / TWO_PI
    assert q[-1] == pytest.approx(expected, abs=1e-7)  # 12 mrad from the start, settled to e^-40
    assert abs(q[-1] - q[0]) > 0.01


def test_mujoco_dead_time_delays_a_command_step_by_d():
    """A step U sent at tick k0 (acting from t = k0·dt) on a frictionless slide starts at k0·dt + d: at the
    end, m·v = U·(t - k0·dt - d). d = 4.42 ms is not a whole number of physics steps (history interpolated)."""
    d, u, k0 = 0.00442, 4.0, 100
    run = run_rigid(rigid_rig("slide", M_SLIDE, delay_s=d), lambda k, s: u if k >= k0 else 0.0, 200)
    t, v = run.columns["time"][-1], run.columns["qd"][-1]
    assert t - M_SLIDE * v / u == pytest.approx(k0 * DT + d, abs=1e-9)


@pytest.mark.parametrize("carried_by", ["effect", "rig"])
def test_mujoco_hinge_gravity_settles_at_q0_plus_asin_u_over_a(carried_by):
    """The hinge needs A·sin(q - q0): from q0 it settles where A·sin(q - q0) = u."""
    a, q0, u = 5.0, 0.4, 2.5  # stiffness A·cos(asin(u/A)) = 4.3 N·m/rad: ω = 9.3 rad/s, critically damped
    damping = {"coulomb": 0.0, "viscous": critical_damping(a * math.cos(math.asin(u / a)), J_HINGE)}
    rig = (rigid_rig("hinge", J_HINGE, damping, effects=(effect("gravity", gravity_amplitude=a, gravity_angle=q0),))
           if carried_by == "effect" else
           rigid_rig("hinge", J_HINGE, damping, gravity_amplitude=a, gravity_angle_rad=q0))
    assert settle_hinge(rig, u, q0)[-1] == pytest.approx(q0 + math.asin(u / a), abs=1e-7)


@pytest.mark.parametrize("carried_by", ["effect", "rig"])
def test_mujoco_slide_constant_effort_accelerates_at_u_minus_c_over_m(carried_by):
    """A slide needing the constant c: q̇ = ((u - c)/m)·t."""
    c, u = -2.0, 3.0
    rig = (rigid_rig("slide", M_SLIDE, effects=(effect("constant_effort", constant_effort=c),))
           if carried_by == "effect" else rigid_rig("slide", M_SLIDE, constant_effort=c))
    t, v = final_velocity(rig, u)
    assert v == pytest.approx((u - c) / M_SLIDE * t, rel=EXACT)


def test_mujoco_spring_step_response_is_the_damped_oscillator():
    """m·q̈ + c·q̇ + k·(q - q0) = u from rest at q0: q = q0 + (u/k)·(1 - e^(-ζωt)·(cos ω_d t + ζ/sqrt(1-ζ²)·sin ω_d t)),
    ω = sqrt(k/m) (2 Hz), ζ = 0.5; it settles at q0 + u/k. Semi-implicit Euler at ωh = 2.5e-3 (measured 4e-4)."""
    k, zeta, q0, u = M_SLIDE * (TWO_PI * 2.0) ** 2, 0.5, 0.05, 20.0
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": 0.0, "viscous": 2 * zeta * math.sqrt(k * M_SLIDE)},
                    effects=(effect("position_spring", spring_stiffness=k, spring_rest_position=q0),))

    def initial(model, data):
        data.qpos[0] = q0

    run = run_rigid(rig, constant(u), 3000, initial=initial)
    t, q = run.columns["time"], run.columns["q"]
    w = math.sqrt(k / M_SLIDE)
    wd = w * math.sqrt(1 - zeta**2)
    expected = q0 + u / k * (1 - np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2)
                                                           * np.sin(wd * t)))
    np.testing.assert_allclose(q, expected, rtol=0, atol=1e-3 * u / k)
    assert q[-1] == pytest.approx(q0 + u / k, rel=1e-6)


def test_mujoco_periodic_disturbance_drives_velocity_a_over_abs_jwm_plus_sigma2():
    """No command, m·v̇ + σ2·v = A·sin(ωt + φ) from rest: v = v_ss(t) - v_ss(0)·exp(-σ2t/m),
    v_ss = A/|jωm + σ2|·sin(ωt + φ - ∠(jωm + σ2)). The load is evaluated at each physics step's start and held
    over it, on average h/2 late: the force in the closed form is A·sin(ω(t - h/2) + φ) (what remains, 4e-4 of the
    amplitude, is the implicit damping's step)."""
    a, f, phase, sigma2 = 3.0, 3.0, 0.8, 8.0
    rig = rigid_rig("slide", M_SLIDE, {"coulomb": 0.0, "viscous": sigma2},
                    effects=(effect("periodic_disturbance", disturbance_amplitude=a, disturbance_frequency=f,
                                    disturbance_phase=phase),))
    run = run_rigid(rig, constant(0.0), 2000)
    t, v = run.columns["time"], run.columns["qd"]
    w = TWO_PI * f
    z = complex(sigma2, w * M_SLIDE)
    amplitude = a / abs(z)

    def steady(tt):
        return amplitude * np.sin(w * (tt - 0.5 * H_RIGID) + phase - np.angle(z))

    np.testing.assert_allclose(v, steady(t) - steady(0.0) * np.exp(-sigma2 * t / M_SLIDE), rtol=0,
                               atol=1e-3 * amplitude)


def test_mujoco_compliant_mass_oscillates_at_fr_with_damping_ratio_zeta():
    """After a 1-tick impulse P on a frictionless slide, the driven mass moves at P/m plus φ times the relative
    velocity, a free oscillation of the two masses at f_d = f_r·sqrt(1 - ζ²) decaying as exp(-ζ·2πf_r·t)."""
    phi, fr, zeta, impulse = 0.3, 15.0, 0.02, 0.2
    rig = rigid_rig("slide", M_SLIDE, effects=(effect("drivetrain_compliance", compliant_fraction=phi,
                                                      resonance_frequency=fr, damping_ratio=zeta),))
    run = run_rigid(rig, lambda k, s: impulse / DT if k == 0 else 0.0, 2000)
    t, v = run.columns["time"], run.columns["qd"]
    oscillation = v - impulse / M_SLIDE
    i = np.flatnonzero(oscillation[1:] * oscillation[:-1] < 0)
    crossings = t[i] - oscillation[i] * DT / (oscillation[i + 1] - oscillation[i])
    frequency = (len(crossings) - 1) / (2 * (crossings[-1] - crossings[0]))
    # linearly interpolated crossings of a 15 Hz wave sampled at 1 kHz; semi-implicit Euler's (ωh)²/24 = 1.5e-5
    assert frequency == pytest.approx(fr * math.sqrt(1 - zeta**2), rel=1e-3)
    peaks = np.flatnonzero((oscillation[1:-1] > oscillation[:-2]) & (oscillation[1:-1] >= oscillation[2:])
                           & (oscillation[1:-1] > 0)) + 1
    decay = -np.polyfit(t[peaks], np.log(oscillation[peaks]), 1)[0]
    assert decay / (TWO_PI * fr) == pytest.approx(zeta, rel=0.01)  # peaks sampled at 1 ms, implicit damping
    assert np.mean(v[-200:]) == pytest.approx(impulse / M_SLIDE, rel=1e-3)


# ---------------------------------------------------------------------------- 2. MuJoCo realisations, testbed

# The testbed with negligible gear friction (F_c = F_s = 1 µN·m, no load-dependent part) and a strong viscous
# term that damps the locked fixture's 63 Hz mode (it acts only while moving): the steady locked torque is then
# what the motor delivers minus the joint's loads.
LOW_FRICTION = {"breakaway_torque_nm": 1e-6, "coulomb_torque_nm": 1e-6, "load_friction_coefficient": 0.0,
                "viscous_nms_per_rad": 2.0}
# the gear's friction band (1e-6 N·m) and what remains of the ramp's transient after 200 ticks (measured < 1e-6)
LOCKED_TORQUE_TOLERANCE_NM = 1e-5


def locked_steady_state(rig: Rig, u: float, n: int = 400) -> dict[str, float]:
    """The last tick's signals after a raised-cosine ramp to ``u`` over 200 ticks (no ringing), held 200 ticks;
    the backlash taken up on the loaded side. ``tau_loadcell`` [N·m] at the axis."""
    def command(k, state):
        return u * (0.5 - 0.5 * math.cos(math.pi * min(k / 200, 1.0)))

    c = run_testbed(rig, command, n, backlash_side=1 if u >= 0 else -1).columns
    out = {name: float(values[-1]) for name, values in c.items()}
    out["tau_loadcell"] = out["force_loadcell"] * rig.params.lever.length_m
    return out


def motor_torque(rig: Rig, u: float) -> float:
    """The motor's torque for a command: the driver's limit (the command delivering the peak torque,
    u_lim = T_p/(1 - α·T_p)), then τ = u/(1 + α|u|)."""
    alpha, peak = rig.params.motor.torque_saturation_per_nm, rig.params.motor.peak_torque_nm
    limit = peak / (1 - alpha * peak)
    u = min(max(u, -limit), limit)
    return u / (1 + alpha * abs(u))


@pytest.mark.parametrize("u", [3.0, 10.0, -6.0, 30.0])
def test_mujoco_testbed_effort_gain_scales_the_locked_torque(u):
    """Steady locked torque g·τ(u), τ(u) = u/(1 + α|u|) after the driver's limit (30 N·m is above it)."""
    g = 0.85
    rig = rig_of_testbed("locked", LOW_FRICTION, (effect("effort_gain", effort_gain=g),))
    tau = locked_steady_state(rig, u)["tau_loadcell"]
    assert tau == pytest.approx(g * motor_torque(rig, u), abs=LOCKED_TORQUE_TOLERANCE_NM)


@pytest.mark.parametrize("u", [5.0, -12.0, 20.0, 30.0])
def test_mujoco_testbed_rolloff_then_the_motor_map_give_the_locked_torque(u):
    """r = u·(1 - c·min(|u|/T_p, 1)²) of the driver-limited command, then τ = r/(1 + α|r|) (20 N·m is between
    the peak torque and the driver's limit, 30 N·m above the limit)."""
    c = 0.15
    rig = rig_of_testbed("locked", LOW_FRICTION, (effect("torque_constant_nonlinearity", torque_rolloff=c),))
    alpha, peak = rig.params.motor.torque_saturation_per_nm, rig.params.motor.peak_torque_nm
    limit = peak / (1 - alpha * peak)
    limited = min(max(u, -limit), limit)
    rolled = limited * (1 - c * min(abs(limited) / peak, 1.0) ** 2)
    tau = locked_steady_state(rig, u)["tau_loadcell"]
    assert tau == pytest.approx(rolled / (1 + alpha * abs(rolled)), abs=LOCKED_TORQUE_TOLERANCE_NM)


MOTOR_SIDE_LOADS = {
    # name: (parameters, the torque the joint needs at the final state)
    "constant_effort": ({"constant_effort": 0.15}, lambda s: 0.15),
    "position_spring": ({"spring_stiffness": 50.0, "spring_rest_position": -0.01},
                        lambda s: 50.0 * (s["q_motor"] + 0.01)),
    "cogging": ({"cogging_amplitude": 0.05, "cogging_period": TWO_PI / (8 * 21), "cogging_phase": 1.2},
                lambda s: -0.05 * math.sin(TWO_PI * s["q_motor"] / (TWO_PI / (8 * 21)) + 1.2)),
    "gravity": ({"gravity_amplitude": 0.5, "gravity_angle": 0.7}, lambda s: 0.5 * math.sin(s["q"] - 0.7)),
}


@pytest.mark.parametrize("name", list(MOTOR_SIDE_LOADS))
@pytest.mark.parametrize("u", [3.0, -3.0])
def test_mujoco_testbed_joint_loads_shift_the_locked_torque(name, u):
    """Steady locked torque τ(u) - (the load the joint needs): c (constant effort), k·(q_m - x0) (spring),
    -A·sin(2πq_m/P + φ) (the dcmotor's cogging, 21 poles), A·sin(q - q0) (gravity on the lever)."""
    params, needed = MOTOR_SIDE_LOADS[name]
    rig = rig_of_testbed("locked", LOW_FRICTION, (effect(name, **params),))
    state = locked_steady_state(rig, u)
    assert abs(needed(state)) > 0.01
    assert state["tau_loadcell"] == pytest.approx(motor_torque(rig, u) - needed(state),
                                                  abs=LOCKED_TORQUE_TOLERANCE_NM)


def test_mujoco_testbed_load_friction_loop_is_u_over_one_plus_or_minus_mu():
    """A slow triangle 0 -> 8 -> 0 N·m on the locked fixture with friction μ·|τ| only: loading, the gear slides
    forward and τ = (τ_m - σ2·q̇_m)/(1 + μ); at the top it sticks, holding τ, until τ_m - σ2·q̇_m falls to
    (1 - μ)·τ; unloading, it slides back with τ = (τ_m - σ2·q̇_m)/(1 - μ). The plant sets the friction level from
    the previous tick's flexure torque: μ·|Δτ per tick|/(1 ∓ μ) <= 2 mN·m. No command delay; the command is held
    through its tick and the torque read at the tick's end, so for the drivetrain (slow against the tick) the drive
    is τ_m of the command half a tick later, a zero-order hold's mean delay (sampled at the command's own tick, the
    slide would lead by 2.4-3 mN·m on loading). The current loop's lag on the ramp, 0.1 ms, is 0.6 mN·m; the
    friction row's time constant is two physics steps."""
    mu = 0.2
    rig = rig_from_dict({"model": "testbed", "fixture": "locked", "motor": {"command_delay_s": 0.0},
                         "friction": {**LOW_FRICTION, "load_friction_coefficient": mu,
                                      "load_friction_time_constant_s": 1e-4}})
    sigma2 = rig.params.friction.viscous_nms_per_rad

    def command(k, state):
        return 8.0 * (k / 1000 if k < 1000 else 2 - k / 1000)

    c = run_testbed(rig, command, 2000, backlash_side=1).columns
    tau = c["tau_flexure"]
    ticks = np.arange(2000)
    held = np.interp(ticks + 0.5, ticks, c["tau_cmd"])
    drive = np.array([motor_torque(rig, u) for u in held]) - sigma2 * c["qd_motor"]
    loading, unloading = slice(200, 950), slice(1550, 1950)
    np.testing.assert_allclose(tau[loading], drive[loading] / (1 + mu), rtol=0, atol=3e-3)
    np.testing.assert_allclose(tau[unloading], drive[unloading] / (1 - mu), rtol=0, atol=3e-3)
    top = tau[1050]  # the gear still slides a few ticks past the command's peak (dead time, current loop)
    stuck = (np.arange(2000) >= 1050) & (drive > (1 - mu) * top + 0.05)
    assert stuck.sum() > 250
    np.testing.assert_allclose(tau[stuck], top, rtol=0, atol=1e-3)
    released = (np.arange(2000) > 1050) & (drive < (1 - mu) * top - 0.05)
    assert np.all(tau[released] < top - 0.03)


def test_mujoco_testbed_presliding_settles_at_minus_fs_over_sigma0_ln_one_minus_u_over_fs():
    """Free fixture, F_c = F_s = g, a constant u < g from rest: the motor creeps until σ0·z = u, with
    z = (g/σ0)(1 - exp(-σ0·x/g)) along a forward stroke: x = -(g/σ0)·ln(1 - u/g) (the linear law u/σ0 is 16 %
    short). The motor stays inside the backlash gap (the lever is not engaged). The approach overshoots by
    < 0.1 % (a return stroke is stiffer): tolerance 2e-3."""
    level, u = 0.13, 0.039
    for sigma0 in (2000.0, 4000.0):
        rig = rig_of_testbed("free", {"breakaway_torque_nm": level, "coulomb_torque_nm": level,
                                   "load_friction_coefficient": 0.0, "viscous_nms_per_rad": 0.5,
                                   "presliding_stiffness_nm_per_rad": sigma0})
        x = run_testbed(rig, constant(u), 300).columns["q_motor"]
        assert x[-1] < rig.params.backlash.width_rad / 2
        assert x[-1] == pytest.approx(-(level / sigma0) * math.log(1 - u / level), rel=2e-3), sigma0


@pytest.mark.parametrize("u", [0.5, -0.5])
def test_mujoco_testbed_backlash_puts_the_motor_half_a_band_ahead(u):
    """Locked, steady torque of either sign: q_motor - q - τ_flexure/K_t = (w/2)·sign(u). The stop is a soft
    constraint: it yields 0.5 µrad per N·m (0.1 % of w/2 at 0.5 N·m)."""
    rig = rig_of_testbed("locked", LOW_FRICTION)
    state = locked_steady_state(rig, u)
    stiffness, width = derive(rig.params).flexure_stiffness_nm_per_rad, rig.params.backlash.width_rad
    offset = state["q_motor"] - state["q"] - state["tau_flexure"] / stiffness
    assert offset == pytest.approx(math.copysign(width / 2, u), rel=2e-3)


# ------------------------------------------------------------------------------------------------- coverage

CLOSED_FORM_TESTS: dict[str, tuple[str, ...]] = {
    "inertia": ("test_inertia_needs_m_times_acceleration", "test_mujoco_inertia_accelerates_at_u_over_m"),
    "effort_gain": ("test_effort_gain_delivers_g_times_command", "test_mujoco_effort_gain_accelerates_at_g_u_over_m",
                    "test_mujoco_testbed_effort_gain_scales_the_locked_torque"),
    "coulomb_friction": ("test_coulomb_friction_needs_fc_while_sliding",
                         "test_mujoco_coulomb_friction_holds_below_fc_and_slides_at_u_minus_fc_over_m"),
    "viscous_friction": ("test_viscous_friction_needs_sigma2_v",
                         "test_mujoco_viscous_friction_velocity_approaches_u_over_sigma2"),
    "stribeck_friction": ("test_stribeck_friction_falls_from_fs_to_fc_as_exp_of_minus_v_over_vs_squared",
                          "test_mujoco_stribeck_friction_holds_below_fs_breaks_away_above_and_slides_on_fc",
                          "test_mujoco_stribeck_sliding_velocity_balances_the_stribeck_curve"),
    "constant_effort": ("test_constant_effort_is_friction_levels_that_differ_by_twice_it_between_directions",
                        "test_constant_effort_on_a_slide_needs_c_whatever_the_motion",
                        "test_mujoco_constant_effort_accelerates_at_u_minus_c_over_j",
                        "test_mujoco_slide_constant_effort_accelerates_at_u_minus_c_over_m",
                        "test_mujoco_testbed_joint_loads_shift_the_locked_torque"),
    "record_offsets": ("test_record_offsets_take_each_records_own_zero_out_of_the_effort",
                       "test_record_offsets_leave_the_simulated_rig_alone"),
    "quadratic_drag": ("test_quadratic_drag_needs_c_v_abs_v",
                       "test_mujoco_drag_reaches_terminal_velocity_sqrt_u_over_c"),
    "load_dependent_friction": ("test_load_dependent_friction_needs_mu_abs_tau_against_the_motion",
                                "test_mujoco_testbed_load_friction_loop_is_u_over_one_plus_or_minus_mu"),
    "presliding_friction": ("test_presliding_bristle_follows_the_lugre_closed_form",
                            "test_mujoco_testbed_presliding_settles_at_minus_fs_over_sigma0_ln_one_minus_u_over_fs"),
    "backlash": ("test_backlash_puts_the_motor_half_a_band_ahead_of_the_hub",
                 "test_mujoco_testbed_backlash_puts_the_motor_half_a_band_ahead"),
    "cogging": ("test_cogging_needs_minus_a_sin_of_two_pi_q_over_p_plus_phi",
                "test_mujoco_cogging_settles_where_the_cogging_balances_the_command",
                "test_mujoco_testbed_joint_loads_shift_the_locked_torque"),
    "torque_constant_nonlinearity": ("test_torque_rolloff_delivers_u_times_one_minus_c_u_over_peak_squared",
                                     "test_mujoco_rolloff_accelerates_at_rolled_off_u_over_m",
                                     "test_mujoco_testbed_rolloff_then_the_motor_map_give_the_locked_torque"),
    "transport_delay": ("test_transport_delay_shifts_the_command_by_d",
                        "test_mujoco_dead_time_delays_a_command_step_by_d"),
    "gravity": ("test_gravity_needs_a_sin_q_minus_q0_on_a_hinge",
                "test_mujoco_hinge_gravity_settles_at_q0_plus_asin_u_over_a",
                "test_mujoco_testbed_joint_loads_shift_the_locked_torque"),
    "position_spring": ("test_position_spring_needs_k_q_minus_q0",
                        "test_mujoco_spring_step_response_is_the_damped_oscillator",
                        "test_mujoco_testbed_joint_loads_shift_the_locked_torque"),
    "periodic_disturbance": ("test_periodic_disturbance_needs_minus_a_sin_from_the_first_sample",
                             "test_mujoco_periodic_disturbance_drives_velocity_a_over_abs_jwm_plus_sigma2"),
    "drivetrain_compliance": ("test_drivetrain_compliance_needs_m1_q_dd_plus_m2_x2_dd",
                              "test_mujoco_compliant_mass_oscillates_at_fr_with_damping_ratio_zeta"),
    "sensor_offset": ("test_sensor_hook_adds_offset_gain_error_and_drift",
                      "test_linear_sensor_effects_explain_the_sensor_channel",
                      "test_sensor_reading_adds_the_effects_hand_values"),
    "sensor_gain": ("test_sensor_hook_adds_offset_gain_error_and_drift",
                    "test_linear_sensor_effects_explain_the_sensor_channel",
                    "test_sensor_reading_adds_the_effects_hand_values"),
    "sensor_thermal_drift": ("test_sensor_hook_adds_offset_gain_error_and_drift",
                             "test_linear_sensor_effects_explain_the_sensor_channel",
                             "test_sensor_reading_adds_the_effects_hand_values"),
    "sensor_hysteresis": ("test_sensor_hysteresis_hook_is_the_play_operator_loop",
                          "test_sensor_reading_adds_the_effects_hand_values"),
}


def test_every_effect_has_a_closed_form_test():
    """Each effect of the library names its closed-form tests here, and they exist."""
    assert set(CLOSED_FORM_TESTS) == set(EFFECTS), "add the new effect's closed-form tests to CLOSED_FORM_TESTS"
    for name, tests in CLOSED_FORM_TESTS.items():
        assert tests, name
        for test in tests:
            assert callable(globals().get(test)), f"{name}: {test} is not a test of this file"


def test_every_effect_declares_an_experiment_of_its_rig_that_reveals_it():
    """``revealing_experiment`` names an experiment of the synthetic logs whose rig the effect applies to; only
    presliding (a displacement below the 16-bit motor encoder's step) needs the fine motor encoder."""
    from experiments.synthetic_logs import EXPERIMENTS, baseline_rig

    for name, effect in EFFECTS.items():
        assert effect.revealing_experiment in EXPERIMENTS, name
        assert effect.applies(baseline_rig(effect.revealing_experiment)), name
    assert [n for n, e in EFFECTS.items() if e.needs_fine_motor_encoder] == ["presliding_friction"]


def test_the_report_says_which_experiment_reveals_what_a_log_cannot():
    from experiments.synthetic_logs import hidden_effect_log
    from sim.discrepancy.analysis import analyse
    from sim.discrepancy.report import format_result

    log, rig, _ = hidden_effect_log("locked", [], 5, 4.0)
    result = analyse(log, rig, AnalysisConfig())
    text = format_result(result)
    assert "presliding_friction" in result.baseline["not_identifiable"]
    assert "(the 'locked_pi_current' experiment reveals it, with a fine motor encoder)" in text
