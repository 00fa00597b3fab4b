"""The Gymnasium environment torquebed/TorqueTracking-v0: API contract, determinism, options, randomisation,
vectorisation, and that one step is one tick of the experiments' loop."""

import dataclasses
import re
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import torquebed
from controllers.feedback import make_feedback
from controllers.pi import PITorqueController
from envs import ENV_ID, register_envs
from envs.randomization import RANDOMIZED_FIELDS
from envs.torque_tracking import OBSERVATION_NAMES, TorqueTrackingEnv
from sensor.readout import factory_calibration
from sim.lowpass import lowpass_gain
from sim.measurements import LoadCell, MotorEncoder, MotorVelocity
from sim.params import TestbedParams, field_range
from sim.plant import Plant
from sim.run import run_loop

ROOT = Path(__file__).resolve().parents[1]
SHORT_S = 0.05  # [s] 50-step episodes


def make(**kwargs) -> TorqueTrackingEnv:
    return TorqueTrackingEnv(episode_duration_s=kwargs.pop("episode_duration_s", SHORT_S), **kwargs)


def rollout(env, seed, actions, options=None):
    obs, _ = env.reset(seed=seed, options=options)
    out = [obs]
    rewards = []
    for a in actions:
        obs, r, term, trunc, _ = env.step(np.array([a], np.float32))
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.array(out), np.array(rewards)


# What Gymnasium's checker advises against by design here: the action is a torque in N·m (not normalised), and
# the observations (angles, velocities) have no bounds.
CHECK_ENV_ADVICE = ("For Box action spaces, we recommend using a symmetric and normalized space",
                    "A Box observation space minimum value is -infinity",
                    "A Box observation space maximum value is infinity")


def test_check_env_passes():
    """Gymnasium's own checker accepts the environment (spaces, seeding, reset/step contract) and warns of
    nothing but the design choices of CHECK_ENV_ADVICE."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(make(), skip_render_check=True)
    others = [str(w.message) for w in caught if not any(a in str(w.message) for a in CHECK_ENV_ADVICE)]
    assert not others


def test_make_by_id_after_import_of_torquebed_and_registration_is_idempotent():
    """gymnasium.make works with the id ``import torquebed`` registered; registering twice does not raise."""
    gym.register_envs(torquebed)
    assert ENV_ID in torquebed.ENV_IDS
    register_envs()
    env = gym.make(ENV_ID, episode_duration_s=SHORT_S)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (len(OBSERVATION_NAMES),)
    assert isinstance(env.unwrapped, TorqueTrackingEnv)


def _fresh(code: str) -> str:
    """stdout of ``code`` run in a fresh interpreter (its error output if it fails)."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.parametrize("code", [
    f"import gymnasium, torquebed; gymnasium.register_envs(torquebed); print(gymnasium.make('{ENV_ID}').spec.id)",
    f"import gymnasium; print(gymnasium.make('torquebed:{ENV_ID}').spec.id)",  # Gymnasium's module prefix
])
def test_a_fresh_interpreter_makes_the_env_after_import_torquebed(code):
    """Gymnasium 1.x reads no entry points: ``import torquebed`` (or the ``torquebed:`` prefix) registers the id."""
    assert _fresh(code) == ENV_ID


def test_the_simulation_packages_register_nothing_and_load_no_gymnasium():
    """``import sim`` and the packages below the environments leave Gymnasium unloaded and the id unregistered."""
    assert _fresh("import sys; import sim, sim.params, sim.plant, models, sensor.readout, sim.run, "
                  "controllers.feedback; print('gymnasium' in sys.modules)") == "False"
    assert _fresh(f"import gymnasium, sim, sim.plant; print('{ENV_ID}' in gymnasium.registry)") == "False"


def test_the_readme_example_runs():
    """The README's Python example of the environment runs as written, in a fresh interpreter."""
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", readme, re.S | re.M)
    assert len(blocks) == 1, "the README holds one Python example"
    assert re.fullmatch(r"0\.\d+ N·m step: the load cell ends at \S+ N·m, RMS error \S+ N·m", _fresh(blocks[0]))


def test_same_seed_same_episode_and_another_seed_differs():
    """Observations and rewards repeat exactly for a seed (noise, task draw); another seed changes them."""
    actions = np.linspace(0.0, 0.3, 40)
    a_obs, a_rew = rollout(make(), 7, actions)
    b_obs, b_rew = rollout(make(), 7, actions)
    c_obs, _ = rollout(make(), 8, actions)
    np.testing.assert_array_equal(a_obs, b_obs)
    np.testing.assert_array_equal(a_rew, b_rew)
    assert not np.array_equal(a_obs, c_obs)


def test_episode_truncates_after_its_duration():
    """episode_duration_s = 0.05 s gives 50 steps, the last one truncated, none terminated."""
    env = make()
    env.reset(seed=0)
    flags = [env.step(np.zeros(1, np.float32))[2:4] for _ in range(50)]
    assert flags[-1] == (False, True)
    assert not any(t or u for t, u in flags[:-1])


def test_reset_options_set_task_amplitude_and_frequency():
    """options task/amplitude_nm/frequency_hz define the episode's reference."""
    env = make(episode_duration_s=1.0)
    _, info = env.reset(seed=0, options={"task": "sine", "amplitude_nm": 2.0, "frequency_hz": 1.0})
    assert info["task"] == "sine"
    ref = env.reference.values_nm
    t = np.arange(len(ref)) * 1e-3
    np.testing.assert_allclose(ref, 2.0 * np.sin(2 * np.pi * t))
    _, info = env.reset(seed=0, options={"task": "step", "amplitude_nm": 0.2})
    assert env.reference.values_nm[0] == 0.0 and env.reference.values_nm[-1] == 0.2
    _, info = env.reset(seed=0, options={"task": "square"})
    assert set(np.unique(env.reference.values_nm)) == {-0.1, 0.1}  # the paper's 0.1 N·m square wave
    _, info = env.reset(seed=0, options={"task": "random"})
    assert 0.0 < np.abs(env.reference.values_nm).max() <= 10.0


@pytest.mark.parametrize("options,names", [
    ({"tasks": "step"}, ["tasks", "task", "amplitude_nm", "frequency_hz"]),
    ({"task": "ramp"}, ["task", "step", "sine", "square", "random"]),
    ({"amplitude_nm": 50.0}, ["amplitude_nm", "18"]),
    ({"amplitude_nm": 0.0}, ["amplitude_nm"]),
    ({"frequency_hz": -1.0}, ["frequency_hz", "500"]),
])
def test_bad_reset_options_raise_naming_the_option_and_valid_values(options, names):
    """A bad option is refused with its name and the valid keys / values / range."""
    with pytest.raises(ValueError) as exc:
        make().reset(seed=0, options=options)
    for name in names:
        assert name in str(exc.value)


@pytest.mark.parametrize("kwargs,names", [
    ({"task": "ramp"}, ["task", "any"]), ({"fixture": "clamped"}, ["fixture", "locked", "free"]),
    ({"randomization_scale": 0.9}, ["randomization_scale", "0.5"]),
    ({"episode_duration_s": 0.0}, ["episode_duration_s"]), ({"ctrl_cost_weight": -1.0}, ["ctrl_cost_weight"]),
])
def test_bad_constructor_arguments_raise_naming_the_argument(kwargs, names):
    """A bad argument is refused with its name and the valid values."""
    with pytest.raises(ValueError) as exc:
        make(**kwargs)
    for name in names:
        assert name in str(exc.value)


def command_limit_nm(motor) -> float:
    """The command that delivers the peak torque through τ = c/(1 + α|c|), solved by hand: peak/(1 - α·peak)."""
    return motor.peak_torque_nm / (1.0 - motor.torque_saturation_per_nm * motor.peak_torque_nm)


def test_action_is_clipped_to_the_command_that_delivers_the_peak_torque():
    """A command beyond the driver's limit (the command that delivers the 18 N·m peak, 26.3 N·m) is applied as
    the limit; the action space is that box."""
    env = make()
    limit = command_limit_nm(TestbedParams().motor)
    assert -env.action_space.low[0] == env.action_space.high[0] == pytest.approx(limit, rel=1e-6)  # float32
    env.reset(seed=0)
    assert env.step(np.array([1e3], np.float32))[4]["command_nm"] == pytest.approx(limit, rel=1e-12)
    assert env.plant.torque_command_nm == pytest.approx(limit, rel=1e-12)


@pytest.mark.parametrize("action,message", [
    (np.array([np.nan], np.float32), "action nan: expected a finite torque command"),
    (np.array([np.inf]), "action inf: expected a finite torque command"),
    (np.array([0.1, 0.2], np.float32), "action of shape (2,): expected shape (1,)"),
    (np.float32(0.1), "action of shape (): expected shape (1,)"),
    ([[0.1]], "action of shape (1, 1): expected shape (1,)"),
])
def test_a_non_finite_or_wrong_shaped_action_raises_and_leaves_no_file(tmp_path, monkeypatch, action, message):
    """A NaN or infinite command, or an action not of the action space's shape, raises a ValueError naming it
    (as Gymnasium's MuJoCo environments do for a wrong shape), before the plant moves; MuJoCo writes nothing
    into the working directory."""
    monkeypatch.chdir(tmp_path)
    env = make()
    env.reset(seed=0)
    with pytest.raises(ValueError) as exc:
        env.step(action)
    assert message in str(exc.value)
    assert env.plant.time_s == 0.0
    assert env.step(np.zeros(1, np.float32))[4]["diverged"] is False  # the episode goes on
    assert not any(tmp_path.iterdir())


def test_a_diverging_simulation_terminates_the_episode_saying_so_and_writes_no_file(tmp_path, monkeypatch):
    """A plant that diverges (one physics step per tick cannot resolve its ~1 kHz modes) ends the episode with
    info["diverged"] and a message naming the physics step and MuJoCo's own warning; no MUJOCO_LOG.TXT."""
    monkeypatch.chdir(tmp_path)
    env = make(episode_duration_s=2.0)
    env.reset(seed=0)
    env.plant = Plant(env.params, "locked", timestep_s=1e-3)
    env.plant.reset(backlash_side=env.reference.first_sign)
    for _ in range(2000):
        _, reward, terminated, _, info = env.step(env.action_space.high)
        if terminated:
            break
    assert terminated and info["diverged"] is True and reward == 0.0
    assert "simulation diverged" in info["message"] and "MuJoCo: Nan, Inf or huge value" in info["message"]
    assert not any(tmp_path.iterdir())


def test_randomised_motors_never_take_more_than_the_box_nor_more_than_their_own_driver_limit():
    """With the torque droop randomised, a command far beyond the box is applied as the box limit or as the episode's
    motor's own limit (the command that delivers its 18 N·m peak), whichever is lower."""
    env = make(domain_randomization=True, randomization_scale=0.5)
    box = float(env.action_space.high[0])
    applied = []
    for seed in range(6):
        env.reset(seed=seed)
        applied.append(env.step(np.array([1e3], np.float32))[4]["command_nm"])
        assert applied[-1] == pytest.approx(min(box, command_limit_nm(env.params.motor)), rel=1e-6)
    assert min(applied) < 0.99 * box  # some episodes' motors reach their peak below the box


def test_reward_is_the_normalised_squared_load_cell_error_plus_control_cost():
    """Without noise, reward = -((τ_loadcell - τ_ref)/s)² - w (u/u_max)² with τ_loadcell the plant's lever-tip
    torque through the amplifier's low-pass (started at the first reading)."""
    w = 0.5
    env = make(feedback_noise=False, ctrl_cost_weight=w)
    env.reset(seed=0, options={"task": "sine", "amplitude_nm": 0.5, "frequency_hz": 5.0})
    gain = lowpass_gain(env.params.loadcell.amplifier_bandwidth_hz, env.dt)
    filtered = None
    for k, u in enumerate((0.0, 0.4, 0.8, -0.3)):
        ref = env.reference.values_nm[k]
        _, reward, *_ = env.step(np.array([u], np.float32))
        true = env.plant.loadcell_torque_nm
        filtered = true if filtered is None else filtered + gain * (true - filtered)
        error = filtered - ref
        scale = np.abs(env.reference.values_nm).max()  # the episode's largest |reference|
        assert env.reference.scale_nm == scale
        expected = -(error / scale) ** 2 - w * (float(np.float32(u)) / command_limit_nm(TestbedParams().motor)) ** 2
        assert reward == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_reward_is_zero_at_rest_on_a_zero_reference_without_noise():
    """The rig at rest, the reference zero (before the step), no command: load cell 0, reward 0."""
    env = make(feedback_noise=False)
    env.reset(seed=0, options={"task": "step", "amplitude_nm": 0.1})
    _, reward, *_ = env.step(np.zeros(1, np.float32))
    assert reward == pytest.approx(0.0, abs=1e-12)


def test_one_step_is_one_tick_of_the_experiments_torque_loop():
    """A PI on the env's sensor observation reproduces the experiments' loop (sim.run.run_loop): its load-cell
    torque exactly (noise off)."""
    env = make(feedback_noise=False, episode_duration_s=0.3)
    obs, _ = env.reset(seed=0, options={"task": "step", "amplitude_nm": 0.1})
    pi = PITorqueController(output_limit_nm=command_limit_nm(TestbedParams().motor))
    loadcell = []
    for _ in range(env.n_steps):
        obs, _, _, _, info = env.step(np.array([pi.update(obs[0], obs[1])]))
        loadcell.append(info["loadcell_torque_nm"])
    p = TestbedParams()
    plant = Plant(p, "locked")
    plant.reset(backlash_side=1)
    feedback = make_feedback("sensor", p.replace(photoreflector={"noise_min_v": 0.0, "noise_max_v": 0.0}), 0,
                             factory_calibration(p))
    log = run_loop(plant, PITorqueController(output_limit_nm=command_limit_nm(p.motor)), env.n_steps,
                   measurements=[feedback, MotorEncoder(), MotorVelocity()], recorded=[LoadCell(p, None)],
                   tau_ref_nm=env.reference.values_nm)
    np.testing.assert_array_equal(np.array(loadcell), log["tau_loadcell"])
    assert np.abs(log["force_loadcell"]).max() * p.lever.length_m > 0.05  # the step was followed


def test_domain_randomization_stays_in_range_repeats_for_a_seed_and_differs_between_seeds():
    """Every randomised field is within its valid range and within ±scale of nominal; same seed, same set."""
    env = make(domain_randomization=True, randomization_scale=0.2)
    nominal = TestbedParams()
    drawn = []
    for seed in (0, 1, 0):
        env.reset(seed=seed)
        drawn.append(env.params)
        for group, name in RANDOMIZED_FIELDS:
            value, base = getattr(getattr(env.params, group), name), getattr(getattr(nominal, group), name)
            low, high = field_range(env.params, group, name)
            assert low <= value <= high
            assert abs(value - base) <= 0.2 * abs(base) * (1 + 1e-12)
        assert env.params.friction.coulomb_torque_nm <= env.params.friction.breakaway_torque_nm
        assert env.plant.params is env.params
    assert drawn[0] == drawn[2] and drawn[0] != drawn[1]
    changed = [(g, n) for g, n in RANDOMIZED_FIELDS
               if getattr(getattr(drawn[0], g), n) != getattr(getattr(nominal, g), n)]
    assert len(changed) == len(RANDOMIZED_FIELDS)
    assert dataclasses.replace(drawn[0]) == drawn[0]


def test_free_fixture_runs_and_tracks_the_flexure_torque():
    """In the free fixture the graded output is the flexure torque (no load cell)."""
    env = make(fixture="free", feedback_noise=False)
    env.reset(seed=0, options={"task": "step", "amplitude_nm": 0.1})
    for _ in range(20):
        _, _, _, _, info = env.step(np.array([0.5], np.float32))
    assert info["loadcell_torque_nm"] == env.plant.flexure_torque_nm


def _vector_obs(vec_cls, **kwargs):
    vec = vec_cls([lambda: make() for _ in range(2)], **kwargs)
    try:
        obs, _ = vec.reset(seed=[3, 4])
        assert obs.shape == (2, len(OBSERVATION_NAMES))
        trace = [obs]
        for _ in range(5):
            obs, rew, term, trunc, _ = vec.step(np.full((2, 1), 0.2, np.float32))
            assert rew.shape == (2,) and not term.any() and not trunc.any()
            trace.append(obs)
        return np.array(trace)
    finally:
        vec.close()


def test_sync_and_async_vector_envs_step_and_agree():
    """SyncVectorEnv and AsyncVectorEnv (2 processes) give the same observations for the same seeds."""
    factory_calibration(TestbedParams())  # cached here, inherited by the forked workers
    sync = _vector_obs(gym.vector.SyncVectorEnv)
    async_ = _vector_obs(gym.vector.AsyncVectorEnv, context="fork")
    np.testing.assert_array_equal(sync, async_)
    assert not np.array_equal(sync[:, 0], sync[:, 1])  # the two seeds differ
