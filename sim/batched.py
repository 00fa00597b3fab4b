"""N simulated testbeds of one fixture stepped together: MuJoCo's batched stepping (:mod:`mujoco.batch`) on a
thread pool, with the per-tick inputs and readings of :class:`sim.plant.Plant` as (N,) arrays.

Each testbed is a :class:`Plant` of its own parameters (its own MjModel; the batch steps simulation i on plant
i's model), reset by the plant itself; its state then lives in the batch. One :meth:`BatchedPlant.step` is
one control tick of every testbed given (the same ``n_substeps`` physics steps), with the driver's limit and
current-to-torque map and the load-dependent gear friction of :func:`sim.plant.driver_input` and
:func:`sim.plant.load_frictionloss` on arrays, and each plant's thermal update every
``thermal.update_period_s``. MuJoCo's batch is bit-identical to stepping one MjData per simulation, so
testbed i runs exactly as ``Plant.step`` runs it alone. The named accessors the measurements read
(:mod:`sim.measurements`, the optical sensor) are :class:`Plant`'s as (N,) arrays, so they read a batched plant
as they read one.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import mujoco.batch
import numpy as np

from sim.motor_torque import CurrentToTorqueMap
from sim.plant import Plant, driver_input, load_frictionloss


class BatchedPlant:
    """N testbeds stepped together on ``nthread`` threads.

    Parameters
    ----------
    plants : sequence of Plant
        Testbed i's model and parameters; all of one fixture, physics step and data layout (one ``nsample``:
        see :class:`Plant`). Each is reset with :meth:`reset` before it is stepped.
    nthread : int
        Threads of the batch, the caller's included (0: every CPU).
    """

    def __init__(self, plants: Sequence[Plant], nthread: int = 0) -> None:
        plants = list(plants)
        if not plants:
            raise ValueError("plants: at least one Plant")
        first = plants[0]
        self.n = len(plants)
        self.fixture, self.n_substeps, self.timestep_s = first.fixture, first.n_substeps, first.timestep_s
        self._tick_s, self._half_step_s = first._tick_s, first._half_step_s
        self.batch = mujoco.batch.Batch(first.model, self.n, nthread)
        b = self.batch
        self._qpos, self._qvel, self._act, self._ctrl, self._time = b.qpos, b.qvel, b.act, b.ctrl, b.time
        self._ten_length, self._ten_velocity = b.bind("ten_length"), b.bind("ten_velocity")
        self._q_motor, self._q_backlash, self._q_flexure = first._q_motor, first._q_backlash, first._q_flexure
        self._dof_motor, self._u_motor, self._u_external = first._dof_motor, first._u_motor, first._u_external
        self._tendon, self._act_current = first._tendon, first._act_current
        self._nstate = mujoco.mj_stateSize(first.model, mujoco.mjtState.mjSTATE_INTEGRATION)
        if b.nstate != self._nstate:
            raise RuntimeError(f"the batch's state rows hold {b.nstate} numbers, mjSTATE_INTEGRATION {self._nstate}")
        names = ("command_limit_nm", "alpha", "gear", "k_flexure", "load_coeff", "k_loadcell", "c_loadcell",
                 "lever_m", "current_to_torque", "peak_nm")
        self._constants = {name: np.empty(self.n) for name in names}
        self._tau_cmd = np.zeros(self.n)
        self._command_sq_sum = np.zeros(self.n)
        self._ticks = np.zeros(self.n, dtype=np.int64)
        self._thermal_ticks = np.ones(self.n, dtype=np.int64)
        self._tmp117_c = np.full(self.n, np.nan)
        self._until_thermal = 0  # ticks before the next testbed may be due for its thermal update (0: look now)
        self.plants: list[Plant] = [first] * self.n
        for i, plant in enumerate(plants):
            self._set_plant(i, plant)
        self._use_models()

    # ------------------------------------------------------------------ testbeds
    def _set_plant(self, i: int, plant: Plant) -> None:
        first = self.plants[0]
        if (plant.fixture, plant.n_substeps, plant.timestep_s) != (self.fixture, self.n_substeps, self.timestep_s):
            raise ValueError(f"plant {i}: fixture {plant.fixture!r}, {plant.n_substeps} substeps of "
                             f"{plant.timestep_s} s; the batch's are {self.fixture!r}, {self.n_substeps} of "
                             f"{self.timestep_s} s")
        if mujoco.mj_stateSize(plant.model, mujoco.mjtState.mjSTATE_INTEGRATION) != self._nstate or (
                plant.model.actuator_history.tolist() != first.model.actuator_history.tolist()):
            raise ValueError(f"plant {i}: its data layout differs from the batch's (command history "
                             f"{plant.model.actuator_history[plant._u_motor, 0]} samples against "
                             f"{first.model.actuator_history[first._u_motor, 0]}): give every plant one nsample")
        self.plants[i] = plant
        c = self._constants
        limit_map = plant._torque_map
        c["command_limit_nm"][i], c["alpha"][i], c["gear"][i] = (plant._command_limit_nm, plant._alpha,
                                                                 plant._gear)
        c["k_flexure"][i], c["load_coeff"][i] = plant._k_flexure, plant._load_coeff
        c["k_loadcell"][i], c["c_loadcell"][i] = plant._k_loadcell, plant._c_loadcell
        c["lever_m"][i], c["current_to_torque"][i] = plant.params.lever.length_m, plant._current_to_torque
        c["peak_nm"][i] = limit_map.peak_torque_nm
        self._thermal_ticks[i] = plant.thermal_ticks
        self._torque_map = CurrentToTorqueMap(c["alpha"], c["peak_nm"])
        self._frictionloss = [p.model.dof_frictionloss for p in self.plants]

    def _use_models(self) -> None:
        self.batch.set_models([p.model for p in self.plants])

    def replace(self, plants: dict[int, Plant]) -> None:
        """Run testbed i on ``plants[i]`` (reset it with :meth:`reset` before stepping it)."""
        for i, plant in plants.items():
            self._set_plant(i, plant)
        self._use_models()

    def reset(self, ids: Sequence[int], backlash_side: Sequence[int] | int = 0) -> None:
        """Testbeds ``ids`` back to rest (:meth:`Plant.reset` with each one's ``backlash_side``)."""
        sides = [backlash_side] * len(ids) if isinstance(backlash_side, int) else list(backlash_side)
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        for i, side in zip(ids, sides, strict=True):
            plant = self.plants[i]
            plant.reset(backlash_side=side)
            mujoco.mj_getState(plant.model, plant.data, self.batch.state[i], spec)
            self._tau_cmd[i], self._command_sq_sum[i], self._ticks[i] = 0.0, 0.0, 0
            self._tmp117_c[i] = plant.tmp117_temperature_c
        self._until_thermal = 0  # recounted at the next step
        self.batch.forward(np.sort(np.asarray(ids, dtype=np.int32)), mujoco.mjtStage.mjSTAGE_VEL)

    # ------------------------------------------------------------------ stepping
    def step(self, tau_cmd_nm: np.ndarray, tau_ext_nm: float | np.ndarray = 0.0,
             ids: np.ndarray | None = None) -> np.ndarray:
        """Advance testbeds ``ids`` (all if None) one control tick with motor torque commands [N·m, output
        side] (one per testbed, (N,): those of the others are ignored) and external lever torques [N·m].

        Returns
        -------
        numpy.ndarray
            (N,) bool: the testbeds whose physics blew up during the tick (:class:`sim.plant.SimulationDiverged`
            for one plant; :meth:`divergence_message` says why).
        """
        c = self._constants
        tau_cmd = np.asarray(tau_cmd_nm, dtype=float)
        if tau_cmd.shape != (self.n,) or not (np.isfinite(tau_cmd).all() and np.isfinite(tau_ext_nm).all()):
            raise ValueError(f"tau_cmd_nm of shape {tau_cmd.shape}, tau_ext_nm: finite torques [N·m], one per "
                             f"testbed ({self.n},)")
        tau_nm, ctrl_motor = driver_input(tau_cmd, c["command_limit_nm"], c["alpha"], c["gear"])
        self._ctrl[:, self._u_motor] = ctrl_motor
        self._ctrl[:, self._u_external] = tau_ext_nm
        loss = load_frictionloss(c["load_coeff"], c["k_flexure"], self._qpos[:, self._q_flexure]).tolist()
        for frictionloss, value in zip(self._frictionloss, loss, strict=True):
            frictionloss[self._dof_motor] = value
        self._t_expected = self._time + self._tick_s
        if ids is None:
            self.batch.step(None, self.n_substeps)
            self._tau_cmd = tau_cmd
            self._command_sq_sum += tau_nm * tau_nm
            self._ticks += 1
            stepped = None
        else:
            stepped = np.zeros(self.n, dtype=bool)
            stepped[ids] = True
            self.batch.step(np.asarray(ids, dtype=np.int32), self.n_substeps)
            self._tau_cmd = np.where(stepped, tau_cmd, self._tau_cmd)
            self._command_sq_sum += np.where(stepped, tau_nm * tau_nm, 0.0)
            self._ticks += stepped
        self._until_thermal -= 1
        if self._until_thermal <= 0:  # some testbed may be due (the soonest one is; those not stepped are later)
            self._thermal_updates(stepped)
        diverged = (self._time < self._t_expected - self._half_step_s) | ~np.isfinite(self._qvel[:, self._dof_motor])
        return diverged if stepped is None else diverged & stepped

    def _thermal_updates(self, stepped: np.ndarray | None) -> None:
        """The thermal update of each testbed stepped this tick (all if ``stepped`` is None) whose ticks since
        reset reach a whole update period."""
        due = self._ticks % self._thermal_ticks == 0
        for i in np.flatnonzero(due if stepped is None else due & stepped).tolist():
            if self._ticks[i]:
                self._tmp117_c[i] = self.plants[i].advance_thermal(float(self._command_sq_sum[i]))
                self._command_sq_sum[i] = 0.0
        self._until_thermal = int((self._thermal_ticks - self._ticks % self._thermal_ticks).min())

    def divergence_message(self, i: int) -> str:
        """Why testbed i diverged in the last :meth:`step`."""
        return self.plants[i].divergence_message(float(self._t_expected[i]))

    # ------------------------------------------------------------------ named accessors (SI), (N,) arrays
    @property
    def time_s(self) -> np.ndarray:
        return self._time.copy()

    @property
    def motor_angle_rad(self) -> np.ndarray:
        """Motor (encoder) angle referred to the output [rad]."""
        return self._qpos[:, self._q_motor].copy()

    @property
    def motor_velocity_rad_s(self) -> np.ndarray:
        """Motor velocity referred to the output [rad/s]."""
        return self._qvel[:, self._dof_motor].copy()

    @property
    def flexure_angle_rad(self) -> np.ndarray:
        """Twist of the flexure, hub minus lever [rad]."""
        return -self._qpos[:, self._q_flexure]

    @property
    def flexure_torque_nm(self) -> np.ndarray:
        """Torque the flexure transmits from hub to lever [N·m]."""
        return self._constants["k_flexure"] * self.flexure_angle_rad

    @property
    def loadcell_torque_nm(self) -> np.ndarray:
        """Torque the load cell resists at the lever tip, spring and damper [N·m] (0 in 'free')."""
        c = self._constants
        return (c["k_loadcell"] * self._ten_length[:, self._tendon]
                + c["c_loadcell"] * self._ten_velocity[:, self._tendon])

    @property
    def loadcell_force_n(self) -> np.ndarray:
        """Load-cell force at the lever tip [N]."""
        return self.loadcell_torque_nm / self._constants["lever_m"]

    @property
    def current_torque_estimate_nm(self) -> np.ndarray:
        """The driver's current-based torque estimate N·K_t·i [N·m, output side]."""
        return self._torque_map.command_nm(self._constants["current_to_torque"] * self._act[:, self._act_current])

    @property
    def torque_command_nm(self) -> np.ndarray:
        """The last motor torque commands [N·m, output side], before clipping."""
        return self._tau_cmd.copy()

    @property
    def tmp117_temperature_c(self) -> np.ndarray:
        """Board temperatures as the TMP117s report them [°C]."""
        return self._tmp117_c.copy()
