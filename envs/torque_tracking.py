"""``torquebed/TorqueTracking-v0``: torque tracking on the simulated GIM8108 testbed, one step per 1 ms control
tick of the loop the experiments run (:class:`sim.run.ControlLoop`), opened for an agent."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from controllers.feedback import make_feedback
from envs.randomization import check_scale, randomize_params
from envs.references import TASK_CHOICES, TASKS, Reference, make_reference
from sensor.readout import factory_calibration
from sim.measurements import BoardThermometer, CurrentEstimate, LoadCell, MotorEncoder, MotorVelocity
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.plant import Plant, SimulationDiverged, clip
from sim.run import ControlLoop

FIXTURES = ("locked", "free")
OBSERVATION_NAMES = ("tau_ref", "tau_sensor", "q_motor", "qd_motor", "tau_current_estimate", "temperature")
OBSERVATION_UNITS = ("N·m", "N·m", "rad", "rad/s", "N·m", "°C")
RESET_OPTIONS = ("task", "amplitude_nm", "frequency_hz")
DEFAULT_EPISODE_S = 2.0  # [s] 2000 ticks: short episodes keep tests and tuning fast


class TorqueTrackingEnv(gym.Env):
    """Track a torque reference at the load cell of the GIM8108 + optical torque sensor testbed.

    ## Description
    The simulated rig of the paper (MuJoCo 4.0; :class:`sim.plant.Plant`): a SteadyWin GIM8108 geared BLDC
    motor, torque-commanded through its driver, drives a four-spoke flexure with eight photo-reflectors (the
    joint torque sensor) and a 0.1 m lever whose tip rests on a load cell ('locked' fixture) or turns freely
    ('free'). The agent is the torque controller running at the paper's 1 kHz: every step it reads what a real
    controller reads and commands a motor torque; the goal is that the torque the load cell measures follows
    a reference (the paper's step, sine and square tasks, or random ones). One step is exactly one tick of the
    loop the experiments run (:class:`sim.run.ControlLoop`): read the sensors at the end of the
    previous tick, command, the plant advances one control period (``n_substeps`` physics steps) with the
    torque the motor delivers for the command (the current-to-torque droop of :mod:`sim.motor_torque`).

    ## Action Space
    ``Box(-limit, limit, (1,), float32)`` with limit the driver's current limit as a torque command,
    ``CurrentToTorqueMap.command_limit_nm``: the command that delivers ``params.motor.peak_torque_nm`` (18 N·m)
    through the current-to-torque droop, 26.3 N·m by default.

    | Num | Action | Min | Max | Unit |
    |-----|--------|-----|-----|------|
    | 0 | motor torque command, output side | -limit | limit | N·m |

    Actions outside the box are clipped to it (the driver's limit; with domain randomisation, to the episode's
    motor's own limit where that is lower). An action that is not of shape (1,) or not finite (NaN, ±inf)
    raises a ``ValueError`` before the plant moves (as Gymnasium's MuJoCo environments refuse an action of the
    wrong shape); the episode can go on with a valid action.

    ## Observation Space
    ``Box(-inf, inf, (6,), float64)``: what the controller of the real rig can read at the start of a tick.

    | Num | Observation | Unit | Source |
    |-----|-------------|------|--------|
    | 0 | torque reference of this tick | N·m | the task's profile |
    | 1 | joint torque sensor reading | N·m | photo-reflectors, factory calibration, episode tare (noise, ADC, drift) |
    | 2 | motor angle, output side | rad | encoder |
    | 3 | motor velocity, output side | rad/s | driver |
    | 4 | driver's current-based torque estimate | N·m | N·K_t·i, inverse current map (``CurrentEstimate``) |
    | 5 | sensor board temperature | °C | TMP117 reading |

    The load-cell torque is not observed (it is what the reward grades); it is in ``info``.

    ## Rewards
    Per step k, with y_k the load-cell torque at the end of the tick (force x lever length through the
    amplifier's low-pass ``loadcell.amplifier_bandwidth_hz``, with the load cell's reading noise
    ``loadcell.reading_noise_n`` unless ``feedback_noise=False``; in the 'free' fixture, which has no load
    cell, the true flexure torque), r_k the reference of the tick, u_k the clipped command,
    s the episode's reward scale (largest |reference|, at least 0.01 N·m) and u_max the driver's command
    limit (the action box)::

        reward_k = -((y_k - r_k) / s)**2 - ctrl_cost_weight * (u_k / u_max)**2

    So -mean(reward) over an episode is the squared RMS tracking error relative to the reference's size
    (plus the control cost): ``s * sqrt(-mean(reward))`` is the RMS error in N·m the experiments report
    when ``ctrl_cost_weight = 0``.

    ## Starting State
    The rig at rest with the thermal network at its idle steady state at ambient, the backlash taken up on
    the side of the reference's first non-zero value (as after a previous push, as ``experiments.step``
    starts), the sensor's noise sequence seeded from the episode's seed. Domain randomisation, when on, draws
    a new parameter set per episode (:mod:`envs.randomization`). Unlike ``experiments.sinusoid``, the rig is
    not preconditioned by a previous test.

    ## Episode End
    Truncation after ``episode_duration_s`` (default 2 s = 2000 steps). Termination only if the physics
    diverges (:class:`sim.plant.SimulationDiverged`; not expected within the parameters' valid ranges), with
    ``info["diverged"] = True`` and ``info["message"]`` saying why (MuJoCo's own warning included; MuJoCo
    writes no log file, see :mod:`sim.plant`).

    ## Arguments
    ``gymnasium.make("torquebed/TorqueTracking-v0", **kwargs)`` after ``import torquebed`` (or
    ``gymnasium.make("torquebed:torquebed/TorqueTracking-v0")``); ``gymnasium.make_vec(..., num_envs=N,
    **kwargs)`` steps N of them together (:class:`envs.torque_tracking_vector.TorqueTrackingVectorEnv`, which
    also takes ``nthread``).

    | Parameter | Type | Default | Description |
    |-----------|------|---------|-------------|
    | ``task`` | str | ``"any"`` | ``"step"``, ``"sine"``, ``"square"``, ``"random"`` or ``"any"`` (one per episode) |
    | ``episode_duration_s`` | float | 2.0 | episode length [s] (whole control ticks) |
    | ``fixture`` | str | ``"locked"`` | ``"locked"``: lever on the load cell; ``"free"``: lever turns freely |
    | ``feedback_noise`` | bool | True | sensor channel noise and load-cell reading noise on / off |
    | ``domain_randomization`` | bool | False | plant and sensor parameters per episode (:mod:`envs.randomization`) |
    | ``randomization_scale`` | float | 0.2 | relative spread s of the randomisation, in [0, 0.5] |
    | ``ctrl_cost_weight`` | float | 0.0 | weight of the control cost in the reward |
    | ``params`` | TestbedParams | defaults | nominal parameter set |

    ``reset(options=...)`` takes ``task`` (as above but not ``"any"``), ``amplitude_nm`` [N·m] (step size or
    amplitude, != 0, |.| <= peak torque) and ``frequency_hz`` [Hz] (> 0, sine and square only) for that
    episode.

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": [], "render_fps": 1000}

    def __init__(self, task: str = "any", episode_duration_s: float = DEFAULT_EPISODE_S, fixture: str = "locked",
                 feedback_noise: bool = True, domain_randomization: bool = False,
                 randomization_scale: float = 0.2, ctrl_cost_weight: float = 0.0,
                 params: TestbedParams | None = None, render_mode: str | None = None) -> None:
        if task not in TASK_CHOICES:
            raise ValueError(f"task = {task!r}: valid values are {', '.join(TASK_CHOICES)}")
        if fixture not in FIXTURES:
            raise ValueError(f"fixture = {fixture!r}: valid values are {', '.join(FIXTURES)}")
        check_scale(randomization_scale)
        if not (np.isfinite(ctrl_cost_weight) and ctrl_cost_weight >= 0.0):
            raise ValueError(f"ctrl_cost_weight = {ctrl_cost_weight!r}: valid range [0, inf)")
        if render_mode is not None:
            raise ValueError(f"render_mode = {render_mode!r}: this environment does not render (valid: None); "
                             "record a run with sim.recording instead")
        self.nominal_params = params or TestbedParams()
        self.dt = self.nominal_params.simulation.control_period_s
        self.n_steps = round(episode_duration_s / self.dt)
        if not np.isfinite(episode_duration_s) or self.n_steps < 1:
            raise ValueError(f"episode_duration_s = {episode_duration_s!r}: valid range [{self.dt:g}, inf) s")
        self.task, self.fixture = task, fixture
        self.feedback_noise, self.domain_randomization = bool(feedback_noise), bool(domain_randomization)
        self.randomization_scale, self.ctrl_cost_weight = float(randomization_scale), float(ctrl_cost_weight)
        self.render_mode = None
        self.box_limit_nm = CurrentToTorqueMap.from_params(self.nominal_params).command_limit_nm
        self.action_space = spaces.Box(-self.box_limit_nm, self.box_limit_nm, (1,), np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (len(OBSERVATION_NAMES),), np.float64)
        # The nominal unit's factory calibration (cached per process; ~5 s the first time).
        self._calibration = factory_calibration(self.nominal_params)
        self.params = self.nominal_params
        self.plant = Plant(self.params, fixture)
        self._loop: ControlLoop | None = None
        self._obs = np.zeros(len(OBSERVATION_NAMES))
        self.reference: Reference | None = None
        self._k = 0

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        draw = draw_episode(self, self.np_random, check_options(options, self.nominal_params), self.params)
        self.reference = draw.reference
        if draw.params is not self.params:
            self.params = draw.params
            self.plant = Plant(self.params, self.fixture)
        sensor = make_feedback("sensor", draw.sensor_params(self.feedback_noise), draw.sensor_seed, self._calibration)
        self._loop = ControlLoop(self.plant, (sensor, MotorEncoder(), MotorVelocity(), CurrentEstimate(),
                                              BoardThermometer()))
        self._loop.reset()
        self._loadcell = LoadCell(self.params, draw.loadcell_rng if self.feedback_noise else None)
        self._command_limit = draw.command_limit_nm
        self._scale = self.reference.scale_nm
        self._reference_nm = self.reference.values_nm.tolist()  # Python floats: cheaper to index per step
        self.plant.reset(backlash_side=self.reference.first_sign)
        self._k = 0
        self._observe()
        return self._obs.copy(), draw.info()

    def step(self, action):
        if self.reference is None:
            raise RuntimeError("call reset() before step()")
        command = clip(self._action_value(action), -self._command_limit, self._command_limit)
        ref = self._reference_nm[self._k]
        plant = self.plant
        try:
            self._loop.advance(command)
        except SimulationDiverged as exc:
            return self._obs.copy(), 0.0, True, False, {"diverged": True, "message": str(exc)}
        output = self._loadcell.read(plant)
        self._k += 1
        error = output - ref
        reward = tracking_reward(error, self._scale, command, self.box_limit_nm, self.ctrl_cost_weight)
        truncated = self._k >= self.n_steps
        self._observe()
        info = {"loadcell_torque_nm": output, "reference_nm": ref, "tracking_error_nm": error,
                "command_nm": command, "time_s": plant.time_s, "diverged": False}
        return self._obs.copy(), float(reward), False, truncated, info

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _action_value(action) -> float:
        """The commanded torque [N·m] of an action of shape (1,), as a Python float.

        Raises
        ------
        ValueError
            If the action is not of shape (1,) or its value is not finite.
        """
        if not (type(action) is np.ndarray and action.dtype.kind == "f"):  # the usual case needs no conversion
            action = np.asarray(action, dtype=float)
        if action.shape != (1,):
            raise ValueError(f"action of shape {action.shape}: expected shape (1,), the action space's "
                             f"(one motor torque command [N·m])")
        value = float(action.item(0))
        if not math.isfinite(value):
            raise ValueError(f"action {value}: expected a finite torque command [N·m] (commands outside the "
                             f"action space are clipped to it; NaN and ±inf are refused)")
        return value

    def _observe(self) -> None:
        """The observation vector of OBSERVATION_NAMES from the loop's measurements."""
        observed = self._loop.observe(self._reference_nm[min(self._k, self.n_steps - 1)])  # last one held at the end
        observation_into(observed, self._obs)

    @property
    def plant(self) -> Plant:
        """The simulated rig of the current episode."""
        return self._plant

    @plant.setter
    def plant(self, plant: Plant) -> None:
        self._plant = plant
        if getattr(self, "_loop", None) is not None:
            self._loop.plant = plant

    @property
    def channel_voltages_v(self) -> np.ndarray:
        """The eight photo-reflector voltages [V] of the last observation (a new array)."""
        return self._loop.measurements[0].voltages_v


@dataclass(frozen=True)
class EpisodeDraw:
    """What an episode's reset draws from the environment's generator, in this order: the parameter set
    (domain randomisation), the task, the reference, the sensor's noise seed and the load cell's generator."""

    params: TestbedParams
    task: str
    reference: Reference
    sensor_seed: int
    loadcell_rng: np.random.Generator
    command_limit_nm: float  # what the driver applies: the action box, or less if this motor peaks sooner

    def sensor_params(self, feedback_noise: bool) -> TestbedParams:
        """The sensor's parameters: the episode's, without channel noise unless ``feedback_noise``."""
        return self.params if feedback_noise else self.params.replace(
            photoreflector={"noise_min_v": 0.0, "noise_max_v": 0.0})

    def info(self) -> dict[str, Any]:
        """The reset's info."""
        r = self.reference
        return {"task": self.task, "amplitude_nm": r.amplitude_nm, "frequency_hz": r.frequency_hz,
                "reward_scale_nm": r.scale_nm}


def draw_episode(env: TorqueTrackingEnv, rng: np.random.Generator, options: dict[str, Any],
                 params: TestbedParams) -> EpisodeDraw:
    """Draw one episode with ``env``'s settings (nominal_params, domain_randomization, randomization_scale, task,
    n_steps, dt, box_limit_nm) from ``rng``, with checked options; ``params`` is kept without randomisation."""
    if env.domain_randomization:
        params = randomize_params(env.nominal_params, rng, env.randomization_scale)
    task = options.get("task", env.task)
    if task == "any":
        task = TASKS[int(rng.integers(len(TASKS)))]
    reference = make_reference(task, env.n_steps, env.dt, rng, options.get("amplitude_nm"),
                               options.get("frequency_hz"))
    sensor_seed = int(rng.integers(2**31))
    loadcell_rng = np.random.default_rng(int(rng.integers(2**63)))
    limit = min(env.box_limit_nm, CurrentToTorqueMap.from_params(params).command_limit_nm)
    return EpisodeDraw(params, task, reference, sensor_seed, loadcell_rng, limit)


def tracking_reward(error_nm, scale_nm, command_nm, box_limit_nm, ctrl_cost_weight):
    """-((y - r) / s)² - w·(u / u_max)² of the tracking error y - r [N·m] (floats, or arrays across
    environments)."""
    u = command_nm / box_limit_nm
    e = error_nm / scale_nm
    # a float's ** 2 is libm's pow, as numpy's float_power; numpy's ** 2 on arrays is e·e, at times 1 ulp apart
    return -(e ** 2 if isinstance(e, float) else np.float_power(e, 2.0)) - ctrl_cost_weight * u * u


def observation_into(observed: dict, out: np.ndarray) -> None:
    """Write the observation vector of OBSERVATION_NAMES from a loop's measurements into ``out``: (6,) from
    floats, or (N, 6) from (N,) arrays."""
    if out.ndim == 1:
        out[:] = [observed[name] for name in OBSERVATION_NAMES]
    else:
        for j, name in enumerate(OBSERVATION_NAMES):
            out[:, j] = observed[name]


def check_options(options: dict[str, Any] | None, nominal_params: TestbedParams) -> dict[str, Any]:
    """The reset options, checked (ValueError naming the option and its valid values or range)."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ValueError(f"options must be a dict with keys among {', '.join(RESET_OPTIONS)}, got {options!r}")
    for key in options:
        if key not in RESET_OPTIONS:
            raise ValueError(f"reset option {key!r} is unknown: valid options are {', '.join(RESET_OPTIONS)}")
    opts = dict(options)
    if "task" in opts and opts["task"] not in TASKS:
        raise ValueError(f"reset option task = {opts['task']!r}: valid values are {', '.join(TASKS)}")
    peak = nominal_params.motor.peak_torque_nm
    if "amplitude_nm" in opts:
        a = opts["amplitude_nm"]
        if not (isinstance(a, (int, float)) and np.isfinite(a) and 0 < abs(a) <= peak):
            raise ValueError(f"reset option amplitude_nm = {a!r}: valid range 0 < |amplitude_nm| <= {peak:g} "
                             "N·m (the motor's peak torque)")
        opts["amplitude_nm"] = float(a)
    if "frequency_hz" in opts:
        f = opts["frequency_hz"]
        nyquist = 0.5 / nominal_params.simulation.control_period_s
        if not (isinstance(f, (int, float)) and np.isfinite(f) and 0 < f < nyquist):
            raise ValueError(f"reset option frequency_hz = {f!r}: valid range (0, {nyquist:g}) Hz")
        opts["frequency_hz"] = float(f)
    return opts
