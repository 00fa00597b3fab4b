"""Contracts of the simulation loop: no warnings, determinism, model = parameters, clear failures."""

import math

import mujoco
import numpy as np
import pytest

from models.gim8108_testbed.build import build_xml, reference_xml_path
from models.gim8108_testbed.derived import FIXTURES, derive, physics_timestep
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.plant import SIGNAL_UNITS, Plant, SimulationDiverged
from sim.run import run_open_loop
from sim.runlog import STANDARD_UNITS, RunLog
from sim.thermal import ThermalState

P = TestbedParams()


@pytest.mark.parametrize("fixture", FIXTURES)
@pytest.mark.parametrize("seed", [0, 1])
def test_every_fixture_steps_under_random_commands_without_warning(fixture, seed):
    """Random motor commands up to 1.2x the driver's limit and external torques raise no MuJoCo warning."""
    rng = np.random.default_rng(seed)
    plant = Plant(P, fixture)
    n = 1500
    tau = rng.uniform(-1.2, 1.2, n) * CurrentToTorqueMap.from_params(P).command_limit_nm
    ext = rng.uniform(-1, 1, n) * (5.0 if fixture == "free" else 20.0)
    run_open_loop(plant, np.repeat(tau[::50], 50), np.repeat(ext[::50], 50), progress=False)
    assert all(w.number == 0 for w in plant.data.warning)
    assert np.isfinite(plant.data.qpos).all() and np.isfinite(plant.data.act).all()


def test_same_inputs_give_a_bit_identical_run():
    """Two runs of the same plant and commands are identical to the bit."""
    rng = np.random.default_rng(7)
    tau = rng.normal(0.0, 0.5, 800)
    a = run_open_loop(Plant(P, "locked"), tau, progress=False)
    b = run_open_loop(Plant(P, "locked"), tau, progress=False)
    for name in a.columns:
        assert np.array_equal(a[name], b[name]), name


@pytest.mark.parametrize("fixture", FIXTURES)
def test_compiled_model_values_equal_the_parameter_set(fixture):
    """Stiffness, damping, inertias, gear, friction, limits and step in the MjModel are the parameters'."""
    d = derive(P)
    m = Plant(P, fixture).model
    n = P.motor.gear_ratio
    motor = m.actuator("motor")
    assert m.opt.timestep == pytest.approx(physics_timestep(P, fixture)[0], rel=1e-9)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert m.jnt_stiffness[m.joint("flexure").id] == pytest.approx(d.flexure_stiffness_nm_per_rad, rel=1e-8)
    assert m.dof_damping[m.joint("flexure").dofadr[0]] == pytest.approx(d.flexure_damping_nms_per_rad, rel=1e-8)
    assert m.body("rotor").inertia[2] == pytest.approx(n**2 * P.motor.rotor_inertia_kgm2, rel=1e-8)
    assert m.body("output").inertia[2] == pytest.approx(d.output_inertia_kgm2, rel=1e-8)
    assert m.body("lever").inertia[2] == pytest.approx(d.lever_side_inertia_kgm2, rel=1e-8)
    assert m.jnt_range[m.joint("backlash").id] == pytest.approx([-P.backlash.width_rad / 2, P.backlash.width_rad / 2])
    assert motor.gear[0] == pytest.approx(n)
    assert motor.forcerange == pytest.approx([-P.motor.peak_torque_nm / n, P.motor.peak_torque_nm / n])
    fr = P.friction
    assert motor.dynprm[5] == pytest.approx(fr.presliding_stiffness_nm_per_rad / n**2, rel=1e-8)
    assert motor.dynprm[6] == pytest.approx(d.presliding_damping_nms_per_rad / n**2, rel=1e-8)
    assert motor.biasprm[3:6] == pytest.approx([fr.coulomb_torque_nm / n, fr.breakaway_torque_nm / n,
                                                fr.stribeck_velocity_rad_s * n], rel=1e-8)
    assert motor.gainprm[1] == pytest.approx(P.motor.torque_constant_nm_per_a)
    assert motor.dynprm[0] == pytest.approx(P.motor.current_loop_time_constant_s)
    assert m.actuator_delay[motor.id] == pytest.approx(P.motor.command_delay_s)
    k_tendon = float(np.ravel(m.tendon_stiffness[m.tendon("lever_angle").id])[0])
    expected = d.loadcell_rot_stiffness_nm_per_rad if fixture == "locked" else 0.0
    assert k_tendon == pytest.approx(expected, rel=1e-8)


@pytest.mark.parametrize("rotor_inertia", [7.573946921575264e-05, 6.3e-5, 1e-4])
def test_the_model_compiles_for_any_rotor_inertia_however_its_digits_round(rotor_inertia):
    """A body spinning about z has transverse inertias half its axial one. Both written to 9 digits, 2 x 2.42366301e-3
    is below 4.84732603e-3 (rotor inertia 7.5739e-5 kg·m²), which MuJoCo refuses (A + B >= C)."""
    p = P.replace(motor={"rotor_inertia_kgm2": rotor_inertia})
    for fixture in FIXTURES:
        m = mujoco.MjModel.from_xml_string(build_xml(p, fixture))
        a, b, c = m.body("rotor").inertia
        assert a + b >= c and c == pytest.approx(derive(p).reflected_rotor_inertia_kgm2, rel=1e-8)


@pytest.mark.parametrize("fixture", FIXTURES)
def test_reference_xml_files_are_current(fixture):
    """models/gim8108_testbed/testbed_<fixture>.xml is what the builder makes of the default parameters."""
    assert reference_xml_path(fixture).read_text() == build_xml(P, fixture), (
        "regenerate with: python -m sim.reference_models")


def test_a_diverging_run_raises_and_names_the_timestep():
    """One physics step per 1 ms tick cannot resolve the ~1 kHz modes: the error says so."""
    plant = Plant(P, "locked", timestep_s=1e-3)
    with pytest.raises(SimulationDiverged, match=r"step h = 0.001 s is too large .* ω_max"):
        for _ in range(2000):
            plant.step(P.motor.peak_torque_nm)


def test_divergence_carries_mujocos_warning_and_writes_no_log_file(tmp_path, monkeypatch, capfd):
    """MuJoCo's warning of the divergence is in the SimulationDiverged message: MuJoCo neither prints it nor
    writes MUJOCO_LOG.TXT into the working directory."""
    monkeypatch.chdir(tmp_path)
    plant = Plant(P, "locked", timestep_s=1e-3)
    with pytest.raises(SimulationDiverged, match=r"MuJoCo: Nan, Inf or huge value in QACC"):
        for _ in range(2000):
            plant.step(P.motor.peak_torque_nm)
    assert not any(tmp_path.iterdir())
    assert "WARNING" not in capfd.readouterr().out


@pytest.mark.parametrize("tau_cmd,tau_ext", [(math.nan, 0.0), (math.inf, 0.0), (0.1, math.nan), (0.1, -math.inf)])
def test_a_non_finite_command_or_external_torque_is_refused_before_the_physics_moves(tau_cmd, tau_ext):
    """Plant.step refuses a non-finite torque with a ValueError naming it; the plant stays where it was."""
    plant = Plant(P, "locked")
    with pytest.raises(ValueError, match="must be finite"):
        plant.step(tau_cmd, tau_ext)
    assert plant.time_s == 0.0
    plant.step(0.1)
    assert plant.time_s == pytest.approx(P.simulation.control_period_s)


def test_a_mujoco_warning_without_divergence_is_a_python_warning(tmp_path, monkeypatch, capfd):
    """A warning MuJoCo raises on a run that goes on (here a NaN control written past Plant.step) becomes a
    MujocoWarning at the next tick instead of a console line and a log file."""
    from sim.plant import MujocoWarning

    monkeypatch.chdir(tmp_path)
    plant = Plant(P, "locked")
    plant.data.ctrl[:] = math.nan
    mujoco.mj_step(plant.model, plant.data)
    with pytest.warns(MujocoWarning, match="MuJoCo: Nan, Inf or huge value in CTRL"):
        plant.step(0.0)
    assert not any(tmp_path.iterdir())
    assert "WARNING" not in capfd.readouterr().out


def test_timestep_override_must_divide_the_control_period():
    """A physics step that does not divide 1 ms is refused."""
    with pytest.raises(ValueError, match="whole number of steps"):
        Plant(P, "locked", timestep_s=3e-4)


def test_unknown_fixture_is_refused():
    """Fixtures are named; a typo lists the valid ones."""
    with pytest.raises(ValueError, match="valid values are"):
        Plant(P, "clamped")


def test_run_log_has_standard_columns_and_units():
    """A simulated run uses the standard column names and units of the run-log format."""
    log = run_open_loop(Plant(P, "locked"), np.full(50, 0.3), progress=False)
    for name in ("time", "tau_cmd", "q", "qd", "q_motor", "force_loadcell", "temperature"):
        assert log.units[name] == STANDARD_UNITS[name]
    assert np.allclose(np.diff(log["time"]), P.simulation.control_period_s)
    assert len(log) == 50


def test_run_rejects_non_finite_commands():
    """NaN commands are refused before anything runs."""
    with pytest.raises(ValueError, match="finite"):
        run_open_loop(Plant(P, "locked"), np.array([0.1, np.nan]), progress=False)


def test_run_log_refuses_ragged_columns_and_wrong_units():
    """Columns of unequal length or a standard column in another unit are refused with its name."""
    with pytest.raises(ValueError, match="'q'"):
        RunLog({"time": np.zeros(3), "q": np.zeros(2)}, {"time": "s", "q": "rad"})
    with pytest.raises(ValueError, match="'q' is in 'deg'"):
        RunLog({"time": np.zeros(3), "q": np.zeros(3)}, {"time": "s", "q": "deg"})


def test_thermal_update_is_exact_for_any_step():
    """One hour in one call equals 36000 calls of 0.1 s (exact discretisation), and tends to steady state."""
    a, b = ThermalState(P.thermal), ThermalState(P.thermal)
    copper_w = 5.0
    a.advance(3600.0, copper_w)
    for _ in range(36000):
        b.advance(0.1, copper_w)
    assert a.temperatures_c == pytest.approx(b.temperatures_c, abs=1e-9)
    c = ThermalState(P.thermal)
    c.advance(1e6, copper_w)
    assert c.temperatures_c == pytest.approx(c.steady_state(copper_w), abs=1e-9)


def test_idle_board_sits_above_ambient_by_mcu_heating():
    """With the motor idle, the board is warmer than ambient by P_mcu through the parallel paths to air."""
    t = P.thermal
    state = ThermalState(t)
    r_path = 1 / (1 / t.board_to_ambient_k_per_w + 1 / (t.motor_to_board_k_per_w + t.motor_to_ambient_k_per_w))
    assert state.board_c - t.ambient_c == pytest.approx(t.mcu_power_w * r_path, rel=1e-9)
    assert state.tmp117_reading_c() == pytest.approx(state.board_c, abs=t.tmp117_resolution_c / 2)


def test_copper_losses_warm_the_board_during_a_run():
    """Holding an 18 N·m command (13.7 N·m delivered) for 5 s heats the winding and the board a little
    (multi-rate update)."""
    plant = Plant(P, "locked")
    before = plant.board_temperature_c
    for _ in range(5000):
        plant.step(P.motor.peak_torque_nm)
    assert plant.motor_temperature_c > plant.board_temperature_c > before
    assert math.isfinite(plant.tmp117_temperature_c)


def test_recorded_signals_equal_the_named_accessors():
    """read_signals (the fast path of a run) returns what the named accessors return."""
    plant = Plant(P, "locked")
    for _ in range(30):
        plant.step(2.0, 0.5)
    row = np.empty(len(SIGNAL_UNITS))
    plant.read_signals(row)
    expected = [plant.torque_command_nm, plant.output_angle_rad, plant.output_velocity_rad_s,
                plant.motor_angle_rad, plant.motor_velocity_rad_s, plant.loadcell_force_n,
                plant.tmp117_temperature_c, plant.flexure_torque_nm, plant.current_torque_estimate_nm,
                plant.motor_current_a, plant.backlash_angle_rad]
    assert row == pytest.approx(expected, rel=1e-12, abs=1e-15)
