"""simulation.substeps_rule: 'accurate' (the stated rule, the default) and 'fast' (8 physics steps per tick)."""

import json
import math

import mujoco
import numpy as np
import pytest

from experiments import step
from experiments.admittance import run_admittance
from models.gim8108_testbed.build import build_model, build_xml, check_time_constants, reference_xml_path
from models.gim8108_testbed.derived import FIXTURES, derive, physics_timestep, solver_time_constants
from sim.characterize import backlash_rate_rad_s, linearizable_plant, linearized_modes, settle_against_stop, stop_loaded
from sim.discrepancy.rig import load_rig, save_rig
from sim.params import ParameterError, TestbedParams, load_params
from sim.plant import Plant

P = TestbedParams()
FAST = P.replace(simulation={"substeps_rule": "fast"})
FAST_TOML = '[simulation]\nsubsteps_rule = "fast"\n'


def stiffest_mode_rad_s(p: TestbedParams, fixture: str) -> float:
    """Highest natural frequency [rad/s] of the three-inertia chain (gear, hub, lever) over the backlash and
    gear-friction states, from numpy's eigenvalues of M⁻¹K (an oracle apart from derived.lumped_modes_hz)."""
    d = derive(p)
    inertia = [d.reflected_rotor_inertia_kgm2, d.output_inertia_kgm2, d.lever_side_inertia_kgm2]
    k_flex, k_cell = d.flexure_stiffness_nm_per_rad, d.loadcell_rot_stiffness_nm_per_rad
    highest = 0.0
    for closed in (True, False):
        for stuck in (True, False):
            k = np.array([[0.0, 0.0, 0.0], [0.0, k_flex, -k_flex], [0.0, -k_flex, k_flex]])
            k[0, 0] += p.friction.presliding_stiffness_nm_per_rad if stuck else 0.0
            k[2, 2] += k_cell if fixture == "locked" else 0.0
            m = np.diag(inertia)
            if closed:  # gear and hub move as one
                k = np.array([[k[0, 0] + k[1, 1], k[1, 2]], [k[2, 1], k[2, 2]]])
                m = np.diag([inertia[0] + inertia[1], inertia[2]])
            omega_sq = np.linalg.eigvals(np.linalg.solve(m, k)).real
            highest = max(highest, math.sqrt(max(omega_sq.max(), 0.0)))
    return highest


def expected_substeps(p: TestbedParams, fixture: str, rule: str) -> int:
    """The rule written out: accurate = both parts; fast = its count (or fewer if the rule asks for fewer), not
    below the stability part."""
    s = p.simulation
    bristle_time_s = (2.0 * p.friction.presliding_damping_ratio * math.sqrt(
        p.friction.presliding_stiffness_nm_per_rad * p.motor.gear_ratio**2 * p.motor.rotor_inertia_kgm2)
        / p.friction.presliding_stiffness_nm_per_rad)
    stability = math.ceil(s.control_period_s * stiffest_mode_rad_s(p, fixture) / s.max_omega_dt)
    accuracy = math.ceil(s.control_period_s / (s.max_step_per_bristle_time * bristle_time_s))
    accurate = max(stability, accuracy)
    return accurate if rule == "accurate" else min(accurate, max(s.fast_substeps_per_tick, stability))


def test_fast_is_read_from_toml_and_survives_a_rig_files_round_trip(tmp_path):
    """[simulation] substeps_rule = "fast" in a parameter file sets the rule and nothing else; a testbed rig file
    carrying it is written back and read to the same parameters."""
    path = tmp_path / "fast.toml"
    path.write_text(FAST_TOML)
    p = load_params(path)
    assert p.simulation.substeps_rule == "fast"
    assert p == FAST and p.replace(simulation={"substeps_rule": "accurate"}) == P
    rig_path = tmp_path / "rig.toml"
    rig_path.write_text('model = "testbed"\nfixture = "locked"\n' + FAST_TOML)
    rig = load_rig(rig_path)
    again = load_rig(save_rig(rig, tmp_path / "again.toml"))
    assert again.params == rig.params == FAST


@pytest.mark.parametrize("value", ['"quick"', '"Fast"', "8", "true"])
def test_any_other_rule_is_refused_naming_the_field_and_the_valid_values(tmp_path, value):
    path = tmp_path / "bad.toml"
    path.write_text(f"[simulation]\nsubsteps_rule = {value}\n")
    with pytest.raises(ParameterError) as info:
        load_params(path)
    message = str(info.value)
    assert str(path) in message and "simulation.substeps_rule = " in message
    assert "valid values are 'accurate', 'fast'" in message


def test_accurate_is_the_default_and_gives_the_rules_substeps_and_the_reference_models():
    """The default rule is 'accurate': the step of both parts of the rule (20 per tick at the defaults), and the
    models are the reference files, byte for byte, whether the rule is left out or named."""
    named = P.replace(simulation={"substeps_rule": "accurate"})
    assert P.simulation.substeps_rule == "accurate"
    for fixture in FIXTURES:
        n = expected_substeps(P, fixture, "accurate")
        assert n == 20
        assert physics_timestep(P, fixture) == physics_timestep(named, fixture) == (1e-3 / n, n)
        assert build_xml(P, fixture) == build_xml(named, fixture) == reference_xml_path(fixture).read_text()


@pytest.mark.parametrize("fixture", FIXTURES)
def test_fast_takes_8_substeps_at_the_defaults(fixture):
    """At the defaults 'fast' runs 8 physics steps per 1 ms tick: the rule asks for 20, the stability part alone
    for at most 8 (so h = 125 µs keeps ω_max·h <= 1)."""
    assert expected_substeps(P, fixture, "fast") == 8
    plant = Plant(FAST, fixture)
    assert plant.n_substeps == 8 and plant.timestep_s == pytest.approx(1.25e-4, rel=1e-12)
    assert stiffest_mode_rad_s(P, fixture) * plant.timestep_s <= P.simulation.max_omega_dt


@pytest.mark.parametrize("simulation, friction, fixture", [
    ({"fast_substeps_per_tick": 4}, {}, "locked"),  # below the stability part (8): that part wins
    ({"fast_substeps_per_tick": 4}, {}, "free"),  # (7)
    ({}, {"presliding_damping_ratio": 4.0}, "free"),  # the rule asks for 7, fewer than 8: the rule's count
    ({"fast_substeps_per_tick": 12}, {}, "locked"),
])
def test_fast_substeps_follow_the_stated_rule(simulation, friction, fixture):
    p = TestbedParams().replace(simulation={"substeps_rule": "fast", **simulation}, friction=friction)
    assert physics_timestep(p, fixture)[1] == expected_substeps(p, fixture, "fast")


def test_fast_raises_the_solver_time_constants_to_two_of_its_steps_and_checks_the_parameters_as_accurate():
    """The default time constants (125 µs) are at least two accurate steps (2.5 of 50 µs); under 'fast' the model
    uses two of its steps (250 µs) and passes the check. A value set above that is kept; one below two accurate
    steps (100 µs) is refused whatever the rule."""
    for fixture in FIXTURES:
        check_time_constants(FAST, (fixture,))
        assert set(solver_time_constants(FAST, fixture).values()) == {2.5e-4}
        assert set(solver_time_constants(P, fixture).values()) == {1.25e-4}
        xml = build_xml(FAST, fixture)
        assert 'timestep="0.000125"' in xml
        assert 'solreflimit="0.00025 1"' in xml and 'solreffriction="0.00025 1"' in xml
    slow_stop = FAST.replace(backlash={"stop_time_constant_s": 1e-3})
    assert solver_time_constants(slow_stop, "locked")["backlash", "stop_time_constant_s"] == 1e-3
    for rule in ("accurate", "fast"):
        stiff = TestbedParams().replace(simulation={"substeps_rule": rule}, backlash={"stop_time_constant_s": 9e-5})
        with pytest.raises(ParameterError, match=r"backlash.stop_time_constant_s = 9e-05 s .*\[0.0001, 1\] s"):
            build_xml(stiff, "locked")


def test_a_short_experiment_runs_under_fast_from_its_command_line(tmp_path, capsys):
    """experiments.step --params FILE with substeps_rule = "fast" runs and writes its figures; its runs take
    physics steps of 1/8 of the 1 ms tick."""
    path, out = tmp_path / "fast.toml", tmp_path / "step.json"
    path.write_text(FAST_TOML)
    step.main(["--feedback", "current", "--duration", "0.05", "--no-plot", "--params", str(path),
               "--json", str(out)])
    rows = json.loads(out.read_text())["rows"]
    assert rows and all(math.isfinite(r["sim"]) for r in rows if r["sim"] is not None)
    result = step.run_step(load_params(path), feedbacks=("current",), duration_s=0.05)
    metas = [log.meta for log in result.logs().values()]
    assert metas and all(m["physics_timestep_s"] == pytest.approx(1e-3 / 8, rel=1e-12) for m in metas)


EULERDAMP_OFF = int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)


@pytest.mark.parametrize("fixture", FIXTURES)
def test_fast_integrates_joint_damping_explicitly_and_accurate_implicitly(fixture):
    """'fast' turns off the Euler integrator's implicit joint damping (MuJoCo's eulerdamp flag); 'accurate'
    keeps MuJoCo's default."""
    assert build_model(FAST, fixture).opt.disableflags & EULERDAMP_OFF
    assert not build_model(P, fixture).opt.disableflags & EULERDAMP_OFF
    assert 'eulerdamp="disable"' in build_xml(FAST, fixture) and "eulerdamp" not in build_xml(P, fixture)


def lever_ringing_decay_rate_per_s(p: TestbedParams) -> float:
    """Decay rate σ = c/(2μ) [1/s] of the lever ringing on the flexure against the gear and hub (the backlash stop
    closed): c the flexure's damping, μ the reduced inertia of the two sides. The chain's slowest decaying
    motion at rest (the gear on its presliding spring is near critically damped)."""
    d = derive(p)
    gear_side = d.reflected_rotor_inertia_kgm2 + d.output_inertia_kgm2
    reduced = gear_side * d.lever_side_inertia_kgm2 / (gear_side + d.lever_side_inertia_kgm2)
    return d.flexure_damping_nms_per_rad / (2.0 * reduced)


@pytest.mark.parametrize("params", [P, FAST], ids=["accurate", "fast"])
def test_the_hub_comes_to_rest_against_its_stop(params):
    """Free fixture: the gear strikes the hub and the chain settles with the hub pressed on its stop by 0.5 N·m.
    From 0.3 s on the lever's velocity and the hub's against the gear are no larger than their peaks decayed
    since by the lever ringing's physical damping, exp(-σ·0.3 s) = 2e-7 at the defaults. A hub that chatters on
    its stop keeps both at tenths of a rad/s."""
    log = settle_against_stop(Plant(params, "free"), torque_nm=0.5, duration_s=0.6)
    time_s = np.asarray(log["time"])
    sigma = lever_ringing_decay_rate_per_s(params)
    assert abs(log["backlash_angle"][-1]) >= 0.5 * params.backlash.width_rad  # on the stop
    for velocity, at_s in ((np.asarray(log["qd"]), time_s), (backlash_rate_rad_s(log), time_s[1:])):
        peak = np.argmax(np.abs(velocity))
        late = at_s >= 0.3
        envelope = abs(velocity[peak]) * math.exp(-sigma * (0.3 - at_s[peak]))
        assert at_s[peak] < 0.3 and np.sqrt(np.mean(velocity[late] ** 2)) <= envelope


@pytest.mark.parametrize("params", [P, FAST], ids=["accurate", "fast"])
def test_the_hub_stays_on_its_stop_through_the_admittance_pushes(params):
    """While the flexure presses the hub on its stop (``sim.characterize.stop_loaded``) the hub moves against the
    gear only by the stop's compliance: RMS rate <= C·RMS(dτ_flexure/dt) over those ticks, C = 10 % of the gap
    per 18 N·m, the compliance the stop is held to (tests/test_plant_physics; the flexure's torque is the load
    that presses the hub on the stop). A hub that chatters on its stop moves against the gear at ~0.1 rad/s."""
    compliance_rad_per_nm = 0.1 * params.backlash.width_rad / params.motor.peak_torque_nm
    for push, log in run_admittance(params, seed=0).logs().items():
        loaded = stop_loaded(log)
        load_rate = np.diff(np.asarray(log["tau_flexure"])) / np.diff(np.asarray(log["time"]))
        bound = compliance_rad_per_nm * float(np.sqrt(np.mean(load_rate[loaded] ** 2)))
        assert loaded.sum() > 500 and np.sqrt(np.mean(backlash_rate_rad_s(log)[loaded] ** 2)) <= bound, push


def test_fast_keeps_the_drivetrain_mode_within_3_5_percent_and_the_lever_ringings_damping_within_5_percent():
    """Locked fixture, 1 N·m preload, linearised: the control-relevant drivetrain mode under 'fast' lies within
    3.5 % of its frequency under 'accurate' (+2.8 % at the defaults: the explicit bristle update's first-order
    error h/(σ1/σ0) is 1.8 % at 20 substeps and 4.4 % at 8); the lever's ringing on the load cell keeps its damping
    ratio within 5 % (+2.4 %)."""
    accurate, fast = (linearized_modes(linearizable_plant(p, "locked", 1.0))[:2] for p in (P, FAST))
    assert fast[0].natural_frequency_hz == pytest.approx(accurate[0].natural_frequency_hz, rel=0.035)
    assert fast[1].damping_ratio == pytest.approx(accurate[1].damping_ratio, rel=0.05)
