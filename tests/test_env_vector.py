"""The vector environment (``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``): step for step
what Gymnasium's SyncVectorEnv of single environments gives, autoreset included, and its refusals."""

import gymnasium as gym
import numpy as np
import pytest

import torquebed  # noqa: F401  (registers the environment)
from envs import ENV_ID
from envs.randomization import randomize_params
from envs.torque_tracking_vector import TorqueTrackingVectorEnv
from sensor.readout import TorqueSensorReadout, TorqueSensorStack, factory_calibration
from sim.batched import BatchedPlant
from sim.params import TestbedParams
from sim.plant import Plant

EPISODE_S = 0.15  # [s] 150-step episodes: 2000 steps cross 13 autoreset boundaries per environment


def _pair(n, **kwargs):
    kwargs.setdefault("episode_duration_s", EPISODE_S)
    vec = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="sync", **kwargs)
    return vec, sync


def _assert_same_infos(a: dict, b: dict, where: str) -> None:
    assert sorted(a) == sorted(b), where
    for key in a:
        assert a[key].dtype == b[key].dtype, f"{where}: info {key!r}"
        np.testing.assert_array_equal(a[key], b[key], err_msg=f"{where}: info {key!r}")


def _assert_steps_equal(vec, sync, n, steps, seed, options=None, action_scale=4.0):
    obs_v, info_v = vec.reset(seed=seed, options=options)
    obs_s, info_s = sync.reset(seed=seed, options=options)
    np.testing.assert_array_equal(obs_v, obs_s)
    _assert_same_infos(info_v, info_s, "reset")
    rng = np.random.default_rng(seed)
    resets = 0
    for k in range(steps):
        action = rng.uniform(-action_scale, action_scale, (n, 1)).astype(np.float32)
        got, want = vec.step(action), sync.step(action)
        for name, x, y in zip(("observation", "reward", "terminated", "truncated"), got[:4], want[:4], strict=True):
            assert x.dtype == y.dtype, f"step {k}: {name}"
            np.testing.assert_array_equal(x, y, err_msg=f"step {k}: {name}")
        _assert_same_infos(got[4], want[4], f"step {k}")
        resets += int(got[4].get("_task", np.zeros(n, bool)).sum())
    return resets


@pytest.mark.parametrize("fixture", ["locked", "free"])
@pytest.mark.parametrize("n", [1, 3, 8])
def test_batched_steps_equal_single_envs_in_sync_vector_env_with_randomisation_and_autoreset(n, fixture):
    """2000 random steps: observations, rewards, terminations, truncations and infos bit-identical to
    SyncVectorEnv of single environments (same seeds), across autoresets, with domain randomisation."""
    vec, sync = _pair(n, fixture=fixture, domain_randomization=True, randomization_scale=0.3)
    resets = _assert_steps_equal(vec, sync, n, 2000, seed=11)
    assert resets == n * (2000 // 151)  # every environment autoreset after each 150-step episode


def test_batched_steps_equal_for_per_env_options_seeds_and_noise_off():
    """A list of seeds, per-environment reset options (a list of N values) and noise off: equal to the single
    environments each reset with its own options."""
    n = 4
    tasks = ["step", "sine", "square", "random"]
    vec = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", episode_duration_s=0.1,
                       feedback_noise=False, task="any")
    singles = [gym.make(ENV_ID, episode_duration_s=0.1, feedback_noise=False) for _ in range(n)]
    seeds = [3, 9, 27, 81]
    obs, info = vec.reset(seed=seeds, options={"task": tasks, "amplitude_nm": 0.5})
    for i, env in enumerate(singles):
        o, inf = env.reset(seed=seeds[i], options={"task": tasks[i], "amplitude_nm": 0.5})
        np.testing.assert_array_equal(obs[i], o)
        assert info["task"][i] == inf["task"] == tasks[i]
    rng = np.random.default_rng(0)
    for _ in range(100):
        action = rng.uniform(-2, 2, (n, 1)).astype(np.float32)
        obs, reward, _, trunc, _ = vec.step(action)
        for i, env in enumerate(singles):
            o, r, _, t, _ = env.step(action[i])
            np.testing.assert_array_equal(obs[i], o)
            assert reward[i] == r and trunc[i] == t


def test_thread_count_does_not_change_a_step():
    """One thread or two: the same steps (MuJoCo's batch is bit-identical at any thread count)."""
    runs = []
    for nthread in (1, 2):
        vec = TorqueTrackingVectorEnv(num_envs=5, episode_duration_s=0.05, domain_randomization=True,
                                      nthread=nthread)
        obs, _ = vec.reset(seed=2)
        trace = [obs]
        for _ in range(120):
            trace.append(vec.step(np.full((5, 1), 0.7))[0])
        runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_a_diverging_testbed_is_flagged_with_its_message_and_the_others_go_on():
    """A physics step too long for the stiffest mode blows up: step() reports that testbed (its message says
    why), the other one steps on."""
    p = TestbedParams()
    plants = [Plant(p, "locked", timestep_s=1e-3), Plant(p, "locked", timestep_s=1e-3)]
    batch = BatchedPlant(plants, nthread=1)
    batch.reset([0, 1], [0, 0])
    flagged = np.zeros(2, bool)
    for _ in range(200):
        flagged = batch.step(np.array([20.0, 0.0]))
        if flagged.any():
            break
    assert flagged.tolist() == [True, False]
    assert "simulation diverged" in batch.divergence_message(0)
    assert batch.time_s[1] > 0.0



def test_a_testbed_left_out_of_a_step_gets_no_thermal_update_when_another_is_due():
    """Testbed 1 is stepped for one thermal period (one update), then held while testbed 0 runs on through two
    more of its updates: testbed 1 is updated no more, and its time stays where its last step left it."""
    p = TestbedParams()
    batch = BatchedPlant([Plant(p, "locked"), Plant(p, "locked")], nthread=1)
    batch.reset([0, 1], [0, 0])
    updates = [0, 0]
    for i, plant in enumerate(batch.plants):
        def counted(sq_sum, advance=plant.advance_thermal, i=i):
            updates[i] += 1
            return advance(sq_sum)
        plant.advance_thermal = counted
    period = batch.plants[0].thermal_ticks
    for _ in range(period):
        batch.step(np.array([5.0, 5.0]))
    assert updates == [1, 1]
    held_s = batch.time_s[1]
    for _ in range(2 * period):
        batch.step(np.array([5.0, 5.0]), ids=np.array([0]))
    assert updates == [3, 1]
    assert batch.time_s[1] == held_s

@pytest.mark.parametrize(("action", "message"), [(np.zeros((3, 2)), "expected (2, 1)"),
                                                 (np.array([[0.1], [np.nan]]), "expected finite"),
                                                 (np.zeros(2), "expected (2, 1)")])
def test_a_wrong_shaped_or_non_finite_action_raises_before_anything_moves(action, message):
    vec = TorqueTrackingVectorEnv(num_envs=2, episode_duration_s=0.05)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        vec.step(action)
    assert vec.plant.time_s.tolist() == [0.0, 0.0]


@pytest.mark.parametrize(("kwargs", "names"), [({"num_envs": 0}, "num_envs"), ({"nthread": -1}, "nthread"),
                                               ({"fixture": "loose"}, "fixture")])
def test_bad_constructor_arguments_raise_naming_the_argument(kwargs, names):
    with pytest.raises(ValueError, match=names):
        TorqueTrackingVectorEnv(**{"num_envs": 2, **kwargs})


def test_per_env_options_of_the_wrong_length_or_value_raise_naming_the_option():
    vec = TorqueTrackingVectorEnv(num_envs=2, episode_duration_s=0.05)
    with pytest.raises(ValueError, match="task"):
        vec.reset(seed=0, options={"task": ["step"]})
    with pytest.raises(ValueError, match="amplitude_nm"):
        vec.reset(seed=0, options={"amplitude_nm": [0.1, 99.0]})
    with pytest.raises(ValueError, match="seed"):
        vec.reset(seed=[1, 2, 3])


def test_a_sensor_stack_reads_what_each_units_own_readout_reads():
    """Four units of randomised parameters and their own seeds, fed the same twists and stepping temperatures:
    the stack's (N,) torques, voltages and tares are each readout's, bit for bit, including a unit restarted
    midway (re-tared at its first read)."""
    nominal = TestbedParams()
    calibration = factory_calibration(nominal)
    rng = np.random.default_rng(4)
    params = [randomize_params(nominal, rng, 0.4) for _ in range(4)]
    singles = [TorqueSensorReadout(p, calibration, seed=10 + i) for i, p in enumerate(params)]
    stack = TorqueSensorStack(4, calibration)
    for i, p in enumerate(params):
        stack.set_unit(i, p, 10 + i)
    twists = np.cumsum(rng.normal(0.0, 2e-4, (1500, 4)), axis=0)
    temperatures = 25.0 + 0.0078125 * np.floor(np.arange(1500) / 100)[:, None] * np.arange(1, 5)
    for k in range(1500):
        if k == 700:  # unit 2 starts over with another seed
            singles[2] = TorqueSensorReadout(params[2], calibration, seed=99)
            stack.set_unit(2, params[2], 99)
        got = stack.read_sample(twists[k], temperatures[k])
        want = [s.read_sample(float(twists[k, i]), float(temperatures[k, i])) for i, s in enumerate(singles)]
        np.testing.assert_array_equal(got, want, err_msg=f"sample {k}")
        np.testing.assert_array_equal(stack.voltages_v, [s.voltages_v for s in singles], err_msg=f"sample {k}")
        np.testing.assert_array_equal(stack.tare_nm, [s.tare_nm for s in singles], err_msg=f"sample {k}")


def test_a_longer_command_history_leaves_a_run_unchanged_and_a_shorter_one_is_refused():
    """Plants of one nsample share a batch's data layout: a buffer longer than the delay needs holds commands the
    delay never reads (the run is bit-identical); one too short for the delay is refused, naming nsample."""
    p = TestbedParams()
    commands = np.random.default_rng(8).uniform(-6.0, 6.0, 1500)
    runs = []
    for nsample in (None, 64):  # the delay needs 37 at the defaults
        plant = Plant(p, "locked", nsample=nsample)
        plant.reset(backlash_side=1)
        rows = np.empty((len(commands), 11))
        for k, command in enumerate(commands):
            plant.step(float(command))
            plant.read_signals(rows[k])
        runs.append(rows)
    np.testing.assert_array_equal(runs[0], runs[1])
    with pytest.raises(ValueError, match="nsample = 3: valid range"):
        Plant(p, "locked", nsample=3)
