"""``torquebed/TorqueTracking-v0`` as a Gymnasium vector environment: N testbeds advanced together by MuJoCo's
batched stepping on threads (:class:`sim.batched.BatchedPlant`), step for step what N single environments give
(:class:`envs.torque_tracking.TorqueTrackingEnv`) in Gymnasium's ``SyncVectorEnv`` for the same seeds.

``gymnasium.make_vec("torquebed/TorqueTracking-v0", num_envs=N)`` after ``import torquebed``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.torque_tracking import (
    DEFAULT_EPISODE_S,
    OBSERVATION_NAMES,
    TorqueTrackingEnv,
    check_options,
    draw_episode,
    observation_into,
    tracking_reward,
)
from models.gim8108_testbed.build import history_samples
from sensor.photoreflector import NormalBank
from sensor.readout import TorqueSensorStack
from sim.batched import BatchedPlant
from sim.measurements import BoardThermometer, CurrentEstimate, LoadCell, MotorEncoder, MotorVelocity
from sim.params import TestbedParams, field_range
from sim.plant import Plant, clip
from sim.run import ControlLoop

STEP_INFO = ("loadcell_torque_nm", "reference_nm", "tracking_error_nm", "command_nm", "time_s")


class TorqueTrackingVectorEnv(VectorEnv):
    """N torque-tracking testbeds stepped together (see :class:`envs.torque_tracking.TorqueTrackingEnv` for the
    task, spaces, reward and arguments).

    Environment i is the single environment seeded with ``seed + i`` (or ``seed[i]``): its own parameter set
    under domain randomisation (its own MjModel), its own sensor and load-cell noise. Autoreset is Gymnasium's
    ``AutoresetMode.NEXT_STEP``: the step after an episode ends resets that environment (reward 0, its reset
    info) while the others step. ``reset(options=...)`` takes the single environment's options; a value given
    as a list or tuple of N holds one value per environment (None: not given for that one).

    Parameters
    ----------
    num_envs : int
        N, at least 1.
    nthread : int
        Threads of the batched physics, the caller's included (0: every CPU).
    **kwargs
        The single environment's arguments (``task``, ``episode_duration_s``, ``fixture``, ``feedback_noise``,
        ``domain_randomization``, ``randomization_scale``, ``ctrl_cost_weight``, ``params``).
    """

    metadata = {"render_modes": [], "render_fps": 1000, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, task: str = "any", episode_duration_s: float = DEFAULT_EPISODE_S,
                 fixture: str = "locked", feedback_noise: bool = True, domain_randomization: bool = False,
                 randomization_scale: float = 0.2, ctrl_cost_weight: float = 0.0,
                 params: TestbedParams | None = None, render_mode: str | None = None, nthread: int = 0) -> None:
        if not (isinstance(num_envs, int | np.integer) and num_envs >= 1):
            raise ValueError(f"num_envs = {num_envs!r}: valid range [1, inf) (an integer)")
        if not (isinstance(nthread, int | np.integer) and nthread >= 0):
            raise ValueError(f"nthread = {nthread!r}: valid range [0, inf) (0: every CPU)")
        # The settings, checks and spaces of one environment (its plant is the nominal one, not stepped here).
        self.template = TorqueTrackingEnv(task, episode_duration_s, fixture, feedback_noise, domain_randomization,
                                          randomization_scale, ctrl_cost_weight, params, render_mode)
        t = self.template
        self.num_envs, self.render_mode = int(num_envs), None
        self.n_steps, self.dt = t.n_steps, t.dt
        self.single_action_space, self.single_observation_space = t.action_space, t.observation_space
        self.action_space = batch_space(t.action_space, self.num_envs)
        self.observation_space = batch_space(t.observation_space, self.num_envs)
        n = self.num_envs
        self._nsample = _common_nsample(t.nominal_params, fixture, randomization_scale if domain_randomization else 0)
        self.params = [t.nominal_params] * n
        self.plant = BatchedPlant([Plant(t.nominal_params, fixture, nsample=self._nsample) for _ in range(n)],
                                  nthread)
        self._sensor = TorqueSensorStack(n, t._calibration)
        self._loop = ControlLoop(self.plant, (self._sensor, MotorEncoder(), MotorVelocity(), CurrentEstimate(),
                                              BoardThermometer()))
        self._loadcell_noise = NormalBank(n)
        self._loadcell = LoadCell(t.nominal_params, self._loadcell_noise if t.feedback_noise else None)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self._references = np.zeros((n, self.n_steps))
        self._scale = np.ones(n)
        self._command_limit = np.full(n, t.box_limit_nm)
        self._k = np.zeros(n, dtype=np.int64)
        self._obs = np.zeros((n, len(OBSERVATION_NAMES)))
        self._autoreset = np.zeros(n, dtype=bool)
        self._rows = np.arange(n)
        self._reference_now = np.zeros(n)  # each environment's reference of its current tick [N·m]
        self._started = False

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        n = self.num_envs
        if seed is None:
            seeds = [None] * n
        elif isinstance(seed, int | np.integer):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"seed: a list of {len(seeds)} seeds for num_envs = {n} environments")
        per_env = self._split_options(options)
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(int(s) if isinstance(s, np.integer) else s)
        infos: dict[str, Any] = {}
        self._reset_envs(list(range(n)), per_env, infos)
        self._autoreset[:] = False
        self._started = True
        self._observe()
        return self._obs.copy(), infos

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        commands = self._commands(actions)
        n = self.num_envs
        resetting = np.flatnonzero(self._autoreset).tolist()
        stepping = ~self._autoreset
        rewards = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        infos: dict[str, Any] = {}
        if len(resetting) < n:
            ref = self._reference_now
            diverged = self.plant.step(commands, ids=np.flatnonzero(stepping) if resetting else None)
            output = self._loadcell.read(self.plant)  # read for every testbed; those reset below discard theirs
            error = output - ref
            reward = tracking_reward(error, self._scale, commands, self.template.box_limit_nm,
                                     self.template.ctrl_cost_weight)
            values = (output, ref, error, commands, self.plant.time_s)
            if resetting or diverged.any():  # the usual step has every environment graded
                graded = stepping & ~diverged
                reward = np.where(graded, reward, 0.0)
                values = [np.where(graded, value, 0.0) for value in values]
                terminated = diverged
            else:
                graded = stepping
            self._k += graded
            rewards = reward
            truncated = graded & (self._k >= self.n_steps)
            for key, value in zip(STEP_INFO, values, strict=True):
                infos[key], infos[f"_{key}"] = value, graded.copy()
            infos["diverged"], infos["_diverged"] = diverged, stepping.copy()
            for i in np.flatnonzero(diverged).tolist():
                self._add_info(infos, {"message": self.plant.divergence_message(i)}, i)
        else:
            diverged = terminated
        previous = self._obs.copy() if terminated.any() else None
        self._reset_envs(resetting, [{}] * n, infos)
        self._observe()
        if previous is not None:  # a diverged tick shows the last observation, as the single env
            self._obs[terminated] = previous[terminated]
        self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, infos

    # ------------------------------------------------------------------ helpers
    def _commands(self, actions) -> np.ndarray:
        """The actions [N·m] as (N,) commands clipped to each environment's driver limit; ValueError for a
        wrong shape or a non-finite action (nothing moves)."""
        a = np.asarray(actions)
        if a.shape != (self.num_envs, 1) or a.dtype.kind not in "fiu":
            raise ValueError(f"actions of shape {a.shape}: expected ({self.num_envs}, 1), one motor torque command "
                             f"[N·m] per environment")
        values = a[:, 0].astype(np.float64)
        if not np.isfinite(values).all():
            raise ValueError(f"actions {values[~np.isfinite(values)]} of environments "
                             f"{np.flatnonzero(~np.isfinite(values)).tolist()}: expected finite torque commands "
                             f"[N·m] (commands outside the action space are clipped to it; NaN and ±inf are refused)")
        return clip(values, -self._command_limit, self._command_limit)

    def _split_options(self, options: dict[str, Any] | None) -> list[dict[str, Any]]:
        """Each environment's checked options (a list or tuple of N values: one per environment)."""
        n = self.num_envs
        if options is None:
            return [{}] * n
        if not isinstance(options, dict):
            return [check_options(options, self.template.nominal_params)] * n  # raises, naming the options
        per_env: list[dict[str, Any]] = [{} for _ in range(n)]
        for key, value in options.items():
            values = list(value) if isinstance(value, list | tuple) else [value] * n
            if len(values) != n:
                raise ValueError(f"reset option {key!r}: {len(values)} values for num_envs = {n} environments")
            for opts, v in zip(per_env, values, strict=True):
                if v is not None:  # None in a list: the option is not given for that environment
                    opts[key] = v
        return [check_options(opts, self.template.nominal_params) for opts in per_env]

    def _reset_envs(self, ids: list[int], options: list[dict[str, Any]], infos: dict[str, Any]) -> None:
        """Draw and start a new episode of environments ``ids`` (as the single environment's reset)."""
        if not ids:
            return
        t = self.template
        plants, sides = {}, []
        for i in ids:
            draw = draw_episode(t, self._rngs[i], options[i], self.params[i])
            if draw.params is not self.params[i]:
                self.params[i] = draw.params
                plants[i] = Plant(draw.params, t.fixture, nsample=self._nsample)
            self._sensor.set_unit(i, draw.sensor_params(t.feedback_noise), draw.sensor_seed)
            self._loadcell_noise.set_rng(i, draw.loadcell_rng)
            self._loadcell.restart(i)
            self._command_limit[i] = draw.command_limit_nm
            self._scale[i] = draw.reference.scale_nm
            self._references[i] = draw.reference.values_nm
            self._k[i] = 0
            sides.append(draw.reference.first_sign)
            self._add_info(infos, draw.info(), i)
        if plants:
            self.plant.replace(plants)
        self.plant.reset(ids, sides)

    def _observe(self) -> None:
        """Every environment's observation from the loop's measurements (the last reference held at the end)."""
        self._reference_now = self._references[self._rows, np.minimum(self._k, self.n_steps - 1)]
        observed = self._loop.observe(self._reference_now)
        observation_into(observed, self._obs)

    @property
    def channel_voltages_v(self) -> np.ndarray:
        """The photo-reflector voltages [V] of the last observations, (N, 8)."""
        return self._sensor.voltages_v


def _common_nsample(nominal: TestbedParams, fixture: str, scale: float) -> int:
    """The command-history length that holds the longest delay randomisation of ``scale`` can draw (one data
    layout for every testbed of the batch)."""
    _, high = field_range(nominal, "motor", "command_delay_s")
    longest = min(nominal.motor.command_delay_s * (1.0 + scale), high)
    return history_samples(nominal.replace(motor={"command_delay_s": longest}), fixture)
