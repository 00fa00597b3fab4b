"""The simulated testbed: MuJoCo model + data behind named accessors in SI units.

One call to :meth:`Plant.step` is one control tick (``simulation.control_period_s``, 1 ms) made of
``n_substeps`` physics steps. Nothing outside this module indexes ``qpos`` or ``act``.

Sign convention: positive motor torque turns the lever positive; the flexure torque and the load-cell
force are positive when the motor pushes the lever positive against the load cell.
"""

from __future__ import annotations

import math
import warnings

import mujoco
import numpy as np

from models.gim8108_testbed.build import build_xml
from models.gim8108_testbed.derived import derive, physics_timestep, stiffest_mode_rad_s
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.thermal import ThermalState

CURRENT_PRIMING_TIME_CONSTANTS = 10  # hold_commands replays the current loop over this many time constants
# Signals a run records every tick (see read_signals): name -> unit. Standard run-log names where they exist.
SIGNAL_UNITS: dict[str, str] = {
    "tau_cmd": "N·m",  # motor torque command, output side
    "q": "rad",  # absolute lever angle
    "qd": "rad/s",
    "q_motor": "rad",  # motor angle referred to the output
    "qd_motor": "rad/s",
    "force_loadcell": "N",
    "temperature": "°C",  # TMP117 reading of the board temperature
    "tau_flexure": "N·m",  # true torque through the flexure
    "tau_current_estimate": "N·m",  # the driver's N·K_t·i
    "current": "A",  # the current the driver measures (under saturation more than the torque-producing one)
    "backlash_angle": "rad",
}


class SimulationDiverged(RuntimeError):
    """The physics blew up; the message names the step, the stiffest mode, the likely cause and MuJoCo's own
    warning."""


class MujocoWarning(RuntimeWarning):
    """A warning of MuJoCo's (a bad value, an unstable simulation) on a run that goes on."""


# MuJoCo's warnings since they were last taken. MuJoCo's own handler prints them and appends them to
# MUJOCO_LOG.TXT in the working directory; this module installs one that keeps them here instead, and
# Plant.step raises them (SimulationDiverged) or warns (MujocoWarning).
_MUJOCO_WARNINGS: list[str] = []


def _keep_mujoco_warning(text: str) -> None:
    # Called by MuJoCo from C: an exception here would abort the process, so it only keeps the text.
    _MUJOCO_WARNINGS.append(text)


def install_mujoco_warning_handler() -> None:
    """Keep MuJoCo's warnings for :func:`take_mujoco_warnings` instead of printing them and writing
    MUJOCO_LOG.TXT into the working directory (done on import; a handler set by the caller is kept)."""
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_keep_mujoco_warning)


def take_mujoco_warnings() -> list[str]:
    """MuJoCo's warnings (texts) since the last call, oldest first; the list is emptied."""
    taken = _MUJOCO_WARNINGS[:]
    del _MUJOCO_WARNINGS[:len(taken)]
    return taken


def warn_mujoco_warnings(stacklevel: int = 2) -> None:
    """Issue every warning MuJoCo gave since the last call as a :class:`MujocoWarning` ("MuJoCo: <text>")."""
    for text in take_mujoco_warnings():
        warnings.warn(f"MuJoCo: {text}", MujocoWarning, stacklevel=stacklevel + 1)


install_mujoco_warning_handler()


def clip(x, low, high):
    """x limited to [low, high]: ``min(max(x, low), high)`` for a number, elementwise for arrays [any unit]."""
    if isinstance(x, np.ndarray):
        return np.minimum(np.maximum(x, low), high)
    return min(max(x, low), high)


def driver_input(tau_cmd_nm, command_limit_nm, saturation_per_nm, gear_ratio):
    """What the driver makes of a torque command [N·m, output side]: (the command limited to its current
    limit [N·m], the dcmotor's input: the torque it delivers, ``CurrentToTorqueMap.delivered_nm``, motor side
    [N·m]). Floats, or arrays across plants."""
    tau_nm = clip(tau_cmd_nm, -command_limit_nm, command_limit_nm)
    return tau_nm, tau_nm / ((1.0 + saturation_per_nm * abs(tau_nm)) * gear_ratio)


def load_frictionloss(load_coefficient, flexure_stiffness_nm_per_rad, flexure_qpos_rad):
    """The gear joint's frictionloss [N·m] for the torque the flexure transmits: (1 - η)·|K_t·θ|. Floats, or
    arrays across plants."""
    return load_coefficient * abs(flexure_stiffness_nm_per_rad * flexure_qpos_rad)


class Plant:
    """The GIM8108 + flexure + lever (+ load cell) testbed in one fixture.

    Parameters
    ----------
    params : TestbedParams, optional
        The parameter set (defaults if None).
    fixture : {'locked', 'free'}
        'locked': lever tip held by the load cell; 'free': the lever turns freely.
    timestep_s : float, optional
        Override the physics step [s] derived by the rule (for convergence studies); must divide the
        control period.
    nsample : int, optional
        Samples of the motor's command history (``build_xml``; the delay's own if None): plants of different
        delays given one ``nsample`` share a data layout, as batched stepping needs (:mod:`sim.batched`).
    """

    def __init__(self, params: TestbedParams | None = None, fixture: str = "locked", *,
                 timestep_s: float | None = None, nsample: int | None = None) -> None:
        self.params = params or TestbedParams()
        self.fixture = fixture
        self.derived = derive(self.params)
        self.model = mujoco.MjModel.from_xml_string(build_xml(self.params, fixture, nsample))
        control_period = self.params.simulation.control_period_s
        if timestep_s is None:  # the model already carries the rule's step
            self.n_substeps = physics_timestep(self.params, fixture)[1]
        else:
            self.n_substeps = round(control_period / timestep_s)
            if self.n_substeps < 1 or not math.isclose(self.n_substeps * timestep_s, control_period,
                                                       rel_tol=1e-9):
                raise ValueError(f"timestep_s = {timestep_s} s must divide the control period "
                                 f"{control_period} s into a whole number of steps")
            self.model.opt.timestep = timestep_s
        self.timestep_s = float(self.model.opt.timestep)
        self._tick_s = self.n_substeps * self.timestep_s
        self._half_step_s = 0.5 * self.timestep_s
        self.omega_max_rad_s = stiffest_mode_rad_s(self.params, fixture)
        self.data = mujoco.MjData(self.model)
        m = self.model
        jnt = {name: m.joint(name).qposadr[0] for name in ("motor", "backlash", "flexure")}
        self._q_motor, self._q_backlash, self._q_flexure = jnt["motor"], jnt["backlash"], jnt["flexure"]
        self._dof_motor = m.joint("motor").dofadr[0]
        self._u_motor = m.actuator("motor").id
        self._u_external = m.actuator("external").id
        self._tendon = m.tendon("lever_angle").id
        act_adr, act_num = m.actuator_actadr[self._u_motor], m.actuator_actnum[self._u_motor]
        # dcmotor activations: [LuGre bristle deflection, armature current] (MuJoCo 4.0 order).
        self._act_bristle, self._act_current = act_adr, act_adr + act_num - 1
        self._gear = self.params.motor.gear_ratio
        self._k_flexure = self.derived.flexure_stiffness_nm_per_rad
        self._k_loadcell = float(np.ravel(m.tendon_stiffness[self._tendon])[0])
        self._c_loadcell = float(np.ravel(m.tendon_damping[self._tendon])[0])
        self._load_coeff = self.params.friction.load_friction_coefficient
        self._current_to_torque = self._gear * self.params.motor.torque_constant_nm_per_a
        self._torque_map = CurrentToTorqueMap.from_params(self.params)
        self._alpha = self._torque_map.saturation_per_nm
        self._command_nm = self._torque_map.command_nm
        self._command_limit_nm = self._torque_map.command_limit_nm
        self._frictionloss = m.dof_frictionloss
        th = self.params.thermal
        self._thermal_ticks = max(1, round(th.update_period_s / control_period))
        # Views into MjData, cached for the hot loop and the accessors (mj_resetData keeps the buffers in
        # place; each MjData attribute access builds a new view).
        d = self.data
        self._ctrl, self._qpos, self._qvel, self._act = d.ctrl, d.qpos, d.qvel, d.act
        self._ten_length, self._ten_velocity = d.ten_length, d.ten_velocity
        self._thermal_period_s = self._thermal_ticks * control_period
        self._winding_resistance_ohm = self.params.motor.winding_resistance_ohm
        self.reset()

    # ------------------------------------------------------------------ stepping
    def reset(self, ambient_c: float | None = None, backlash_side: int = 0) -> None:
        """Back to rest, thermal network at its idle steady state.

        Parameters
        ----------
        ambient_c : float, optional
            Ambient temperature [°C] (``thermal.ambient_c`` if None).
        backlash_side : {0, 1, -1}
            0: hub centred in the dead band; +1 / -1: the dead band taken up as after a positive / negative
            torque (the stop that positive / negative motor torque closes is in contact).
        """
        if backlash_side not in (0, 1, -1):
            raise ValueError(f"backlash_side = {backlash_side!r}: valid values are 0, 1, -1")
        mujoco.mj_resetData(self.model, self.data)
        # Positive motor torque drives the gear ahead of the hub: that stop is at backlash = -width/2. The gear
        # turns by the half gap; hub and lever stay at zero absolute angle.
        half_gap = 0.5 * backlash_side * self.params.backlash.width_rad
        self._qpos[self._q_motor] = half_gap
        self._qpos[self._q_backlash] = -half_gap
        self._set_load_friction(0.0)
        mujoco.mj_forward(self.model, self.data)
        warn_mujoco_warnings()
        self.thermal = ThermalState(self.params.thermal, ambient_c)
        self._tmp117_c = self.thermal.tmp117_reading_c()  # quantised once per thermal update, not per read
        self._command_sq_sum = 0.0  # Σ (limited command)² over the thermal update [N²·m²]
        self._ticks = 0
        self._tau_cmd = 0.0

    def hold_commands(self, past_commands_nm) -> None:
        """Put the driver in the state the commands of the past control ticks leave it in [N·m, output side,
        oldest first; the last is the tick just before]: its delay buffer holding them and the armature current
        where the current loop has taken it. Call right after :meth:`reset` (the buffer's time stamps are then
        ..., -2h, -h). For a replay starting mid-log: a driver at rest would deliver nothing for its first
        milliseconds (the delay, then the current loop's rise)."""
        past = np.atleast_1d(np.asarray(past_commands_nm, dtype=float))
        if past.ndim != 1 or not len(past) or not np.all(np.isfinite(past)):
            raise ValueError(f"past_commands_nm: a non-empty sequence of finite torques [N·m], "
                             f"got {past_commands_nm!r}")
        m, d = self.model, self.data
        if d.time != 0.0:
            raise ValueError(f"hold_commands needs the time stamps of a reset; time = {d.time} s (call reset())")
        limit = self._command_limit_nm
        ctrl = self._torque_map.delivered_nm(np.clip(past, -limit, limit)) / self._gear  # as step() sets it
        prime_ctrl_history(m, d, self._u_motor, ctrl, self._tick_s)
        # The current loop's exact first-order update over its last ~10 time constants of physics steps: the
        # step that began j steps ago drove the current towards the command of (j·h + delay) ago.
        h, tau_i = m.opt.timestep, self.params.motor.current_loop_time_constant_s
        delay = float(m.actuator_delay[self._u_motor])
        decay = math.exp(-h / tau_i)
        steps = math.ceil(CURRENT_PRIMING_TIME_CONSTANTS * tau_i / h)

        def command_aged(age_s: float) -> float:
            return ctrl[len(ctrl) - min(_ticks_back(age_s, self._tick_s), len(ctrl))]

        current = command_aged(steps * h + delay)
        for j in range(steps, 0, -1):
            target = command_aged(j * h + delay)
            current = target + (current - target) * decay
        d.ctrl[self._u_motor] = ctrl[-1]
        d.act[self._act_current] = current / self.params.motor.torque_constant_nm_per_a
        self._tau_cmd = float(past[-1])
        mujoco.mj_forward(m, d)
        warn_mujoco_warnings()

    def _set_load_friction(self, load_nm: float) -> None:
        # Load-dependent gear friction (efficiency) is not native to MuJoCo. It is the gear joint's
        # frictionloss, (1 - η)·|transmitted torque|, set once per control tick: a stateless constraint row
        # solved implicitly. (Modulating the LuGre levels instead makes its σ1·dz/dt term spike when the
        # level drops while sliding, and the run diverges.)
        self._frictionloss[self._dof_motor] = self._load_coeff * load_nm

    def step(self, tau_cmd_nm: float, tau_ext_nm: float = 0.0) -> None:
        """Advance one control tick with a motor torque command [N·m, output side] and an external torque
        on the lever [N·m]. The driver limits the command to its current limit,
        ``CurrentToTorqueMap.command_limit_nm`` (the command that delivers motor.peak_torque_nm), and the motor
        delivers ``CurrentToTorqueMap.delivered_nm`` of that (magnetic saturation,
        ``motor.torque_saturation_per_nm``).

        Raises
        ------
        ValueError
            If a torque is not finite (the plant is left as it was).
        SimulationDiverged
            If the physics blew up during the tick.

        A warning MuJoCo gives on a tick that goes on is issued as a :class:`MujocoWarning`.
        """
        if not (math.isfinite(tau_cmd_nm) and math.isfinite(tau_ext_nm)):
            raise ValueError(f"tau_cmd_nm = {tau_cmd_nm!r} N·m, tau_ext_nm = {tau_ext_nm!r} N·m: torques must be "
                             f"finite")
        d = self.data
        self._tau_cmd = tau_cmd_nm
        ctrl = self._ctrl
        tau_nm, ctrl[self._u_motor] = driver_input(tau_cmd_nm, self._command_limit_nm, self._alpha, self._gear)
        ctrl[self._u_external] = tau_ext_nm
        # .item() reads a Python float, whose arithmetic is cheaper than numpy scalars' (and rounds alike)
        self._frictionloss[self._dof_motor] = load_frictionloss(self._load_coeff, self._k_flexure,
                                                                self._qpos.item(self._q_flexure))
        t_expected = d.time + self._tick_s
        mujoco.mj_step(self.model, d, self.n_substeps)
        # MuJoCo resets the data (time -> 0) when accelerations blow up; a time short of the
        # expected value or a non-finite state means the run diverged.
        if d.time < t_expected - self._half_step_s or not math.isfinite(self._qvel[self._dof_motor]):
            raise SimulationDiverged(self._divergence_message(t_expected))
        if _MUJOCO_WARNINGS:
            warn_mujoco_warnings()
        # Copper loss: the winding carries the driver's current (not just its torque-producing part), taken as
        # the limited command, tau_nm / (N·K_t): it lags by the command delay and the current loop (each a few ms at
        # most), nothing against the 0.1 s thermal update (and the inverse map per tick cost ~2 % of a tick).
        self._command_sq_sum += tau_nm * tau_nm
        self._ticks += 1
        if self._ticks % self._thermal_ticks == 0:
            self.advance_thermal(self._command_sq_sum)
            self._command_sq_sum = 0.0

    @property
    def thermal_ticks(self) -> int:
        """Control ticks per thermal update [-]."""
        return self._thermal_ticks

    def advance_thermal(self, command_sq_sum_nm2: float) -> float:
        """One thermal update with the mean copper loss of its control ticks, from the sum of their squared
        limited commands [N²·m²]; returns the new TMP117 reading [°C]."""
        mean_current_sq = command_sq_sum_nm2 / (self._thermal_ticks * self._current_to_torque ** 2)
        copper_w = self._winding_resistance_ohm * mean_current_sq
        self.thermal.advance(self._thermal_period_s, copper_w)
        self._tmp117_c = self.thermal.tmp117_reading_c()
        return self._tmp117_c

    def divergence_message(self, t_expected: float) -> str:
        """Why a tick that should have ended at ``t_expected`` [s] diverged (:class:`SimulationDiverged`)."""
        return self._divergence_message(t_expected)

    def _divergence_message(self, t_expected: float) -> str:
        omega_h = self.omega_max_rad_s * self.timestep_s
        return (f"simulation diverged before t = {t_expected:.6f} s (fixture {self.fixture!r}). Likely cause: "
                f"physics step h = {self.timestep_s:.3g} s is too large for the stiffest mode "
                f"ω_max = {self.omega_max_rad_s:.4g} rad/s (ω_max·h = {omega_h:.3g}; semi-implicit Euler needs "
                f"< 2). Check the stiffnesses (flexure K_t = {self._k_flexure:.4g} N·m/rad, load cell "
                f"{self._k_loadcell:.4g} N·m/rad) and inertias, or leave the step to the rule "
                f"(simulation.max_omega_dt = {self.params.simulation.max_omega_dt})."
                + "".join(f" MuJoCo: {text}" for text in take_mujoco_warnings()))

    def read_signals(self, out: np.ndarray) -> None:
        """Write the signals of ``SIGNAL_UNITS``, in its order, into ``out`` (one call per tick in a run)."""
        qpos, qvel = self._qpos, self._qvel
        lever = self._ten_length[self._tendon]
        lever_v = self._ten_velocity[self._tendon]
        estimate = self._command_nm(self._current_to_torque * self._act.item(self._act_current))  # inlined property
        out[:] = (self._tau_cmd, lever, lever_v, qpos[self._q_motor], qvel[self._dof_motor],
                  (self._k_loadcell * lever + self._c_loadcell * lever_v) / self.params.lever.length_m,
                  self.tmp117_temperature_c, -self._k_flexure * qpos[self._q_flexure],
                  estimate, estimate / self._current_to_torque, qpos[self._q_backlash])

    # ------------------------------------------------------------------ named accessors (SI)
    @property
    def time_s(self) -> float:
        return float(self.data.time)

    @property
    def motor_angle_rad(self) -> float:
        """Motor (encoder) angle referred to the output [rad]."""
        return self._qpos.item(self._q_motor)

    @property
    def motor_velocity_rad_s(self) -> float:
        """Motor velocity referred to the output [rad/s]."""
        return self._qvel.item(self._dof_motor)

    @property
    def output_angle_rad(self) -> float:
        """Absolute lever angle [rad]."""
        return self._ten_length.item(self._tendon)

    @property
    def output_velocity_rad_s(self) -> float:
        """Absolute lever velocity [rad/s]."""
        return self._ten_velocity.item(self._tendon)

    @property
    def backlash_angle_rad(self) -> float:
        """Hub angle relative to the gear, inside ±backlash.width_rad/2 [rad]."""
        return self._qpos.item(self._q_backlash)

    @property
    def flexure_angle_rad(self) -> float:
        """Twist of the flexure, hub minus lever [rad] (positive when it transmits positive torque)."""
        return -self._qpos.item(self._q_flexure)

    @property
    def flexure_torque_nm(self) -> float:
        """Torque the flexure transmits from hub to lever, K_t times its twist [N·m]."""
        return self._k_flexure * self.flexure_angle_rad

    @property
    def loadcell_torque_nm(self) -> float:
        """Torque the load cell resists at the lever tip, spring and damper [N·m] (0 in 'free')."""
        return (self._k_loadcell * self._ten_length.item(self._tendon)
                + self._c_loadcell * self._ten_velocity.item(self._tendon))

    @property
    def loadcell_force_n(self) -> float:
        """Load-cell force at the lever tip [N]."""
        return self.loadcell_torque_nm / self.params.lever.length_m

    @property
    def motor_current_a(self) -> float:
        """Armature (q-axis) current the driver measures [A]."""
        return self.current_torque_estimate_nm / self._current_to_torque

    @property
    def current_torque_estimate_nm(self) -> float:
        """The driver's torque estimate from its current sensor, N·K_t·i [N·m, output side]: blind to gear
        friction, backlash and the current-to-torque nonlinearity (the dcmotor's current state is the
        torque-producing current; the driver's is the command that delivers it)."""
        return self._command_nm(self._current_to_torque * self._act.item(self._act_current))

    @property
    def torque_command_nm(self) -> float:
        """The last motor torque command [N·m, output side], before clipping."""
        return self._tau_cmd

    @property
    def bristle_deflection_rad(self) -> float:
        """LuGre bristle deflection, motor side [rad]."""
        return self._act.item(self._act_bristle)

    @property
    def board_temperature_c(self) -> float:
        """True sensor-board temperature [°C]."""
        return self.thermal.board_c

    @property
    def tmp117_temperature_c(self) -> float:
        """Board temperature as the on-board TMP117 reports it [°C]."""
        return self._tmp117_c  # quantised at each thermal update (every thermal.update_period_s)

    @property
    def motor_temperature_c(self) -> float:
        """Motor winding temperature [°C]."""
        return self.thermal.motor_c


def _ticks_back(age_s: float, tick_s: float) -> int:
    """Which past control tick (1: the last one) was applied ``age_s`` [s] before now."""
    return max(1, math.ceil(age_s / tick_s - 1e-9))  # 1e-9: an age of exactly k ticks (to rounding) is tick k


def prime_ctrl_history(model: mujoco.MjModel, data: mujoco.MjData, actuator: int, past_ctrl: np.ndarray,
                       tick_s: float) -> None:
    """Fill a delayed actuator's history buffer with the ctrl values of past control ticks of ``tick_s`` [s]
    (oldest first), by the buffer's timestamps after a reset (..., -2h, -h); older samples than ``past_ctrl``
    covers take its oldest value. Nothing for an actuator without delay."""
    nsample = int(model.actuator_history[actuator, 0])
    if not nsample:
        return
    past = np.asarray(past_ctrl, dtype=float).ravel()
    ages = model.opt.timestep * np.arange(nsample, 0, -1)
    back = np.minimum([_ticks_back(age, tick_s) for age in ages], len(past))
    mujoco.mj_initCtrlHistory(model, data, actuator, None, np.ascontiguousarray(past[len(past) - back][:, None]))
