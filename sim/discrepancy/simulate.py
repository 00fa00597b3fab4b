"""MuJoCo runs of a rig with its effects: the testbed plant, or a rigid joint built here.

Each effect says how MuJoCo carries it (:meth:`~sim.discrepancy.effects.base.Effect.realise`); effects made of
the rig's own parameters (friction levels, Stribeck, viscous, presliding, load-dependent friction, backlash,
dead time, inertia, a rigid joint's gain, constant effort and gravity) are carried by the rig itself, so the plant
is built with them. The others arrive as:

- a map of the command before the drive (roll-off; the testbed's effort gain);
- a load on the joint from its state, applied as a generalised force at every physics step (rigid joint) or
  control tick (the testbed's motor joint: asymmetric friction, drag, springs, disturbances);
- a load on the testbed's lever from its angle of the previous tick (gravity; one control tick late: it
  changes slowly against 1 ms);
- MuJoCo's dcmotor cogging (the testbed);
- a second body behind a spring-damper on the joint's axis (a rigid joint's drivetrain compliance);
- a term of the torque sensor's reading (:func:`sensor_reading`).

A rigid joint is a one-body MJCF: ``frictionloss`` at the static level (stick), ``damping`` (viscous), a
``motor`` actuator with the effort gain and the command ``delay`` (history linearly interpolated), and an
``external`` actuator for the loads. A Stribeck drop (breakaway above Coulomb) is the sliding part
``(F_s - g(v))·sign(v)`` given back at every physics step, so that a sliding joint feels
``g(v) = F_c + (F_s - F_c)·exp(-(v/v_s)²)`` while a stuck one holds up to F_s.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from sim.discrepancy.effects import EFFECTS, Realisation
from sim.discrepancy.rig import Rig
from sim.measurements import (
    CurrentEstimate,
    FlexureTorque,
    LeverAngle,
    LeverVelocity,
    LoadCellForce,
    MotorEncoder,
    MotorVelocity,
)
from sim.plant import SIGNAL_UNITS, Plant, prime_ctrl_history, warn_mujoco_warnings
from sim.run import run_loop

RIGID_SUBSTEPS = 5  # rigid joint: physics steps per control tick (no stiff mode; the dry-friction row's time
# constant is two physics steps, as the testbed's tuned rows)
RIGID_FRICTION_IMPEDANCE = 0.9999  # solimpfriction d0 = dwidth of the rigid joint's dry friction (MuJoCo's max)
CONTROL_PERIOD_S = 1e-3  # rigid joint: the 1 kHz control rate of the project's logs

# command(k, state) -> effort command [N·m | N]; state holds the signals at the end of the previous tick (SI)
CommandFn = Callable[[int, dict[str, float]], float]
InitialState = Callable[[mujoco.MjModel, mujoco.MjData], None]  # sets qpos/qvel/act after a reset


@dataclass(frozen=True)
class SimulatedRun:
    """True signals of a run, one row per control tick; ``columns`` by name with ``units``."""

    columns: dict[str, np.ndarray]
    units: dict[str, str]


def realisations(rig: Rig) -> list[Realisation]:
    """How MuJoCo carries each of the rig's added effects, in the library's order."""
    added = {e.name: e.parameters for e in rig.effects}
    return [effect.realise(added[name], rig) for name, effect in EFFECTS.items() if name in added]


def command_map(rig: Rig) -> Callable[[float], float]:
    """Effort command -> what the drive is asked for before its dynamics (the effects' command maps, in order;
    a rigid joint first clips at its peak effort)."""
    maps = [r.command for r in realisations(rig) if r.command is not None]
    limit = math.inf if rig.model == "testbed" else rig.rigid.get("peak_effort", math.inf)

    def mapped(u: float) -> float:
        u = min(max(u, -limit), limit)
        for f in maps:
            u = f(u)
        return u

    return mapped


def joint_load(rig: Rig) -> Callable[[float, float, float], float] | None:
    """(q, qd, t) -> the effort the effects' loads need [N·m | N], or None without any."""
    loads = [r.load for r in realisations(rig) if r.load is not None]
    if not loads:
        return None
    return lambda q, qd, t: sum(f(q, qd, t) for f in loads)


def testbed_plant(rig: Rig) -> Plant:
    """The testbed plant of a rig, with native cogging written into the compiled model."""
    assert rig.model == "testbed" and rig.params is not None
    plant = Plant(rig.params, rig.fixture)
    for r in realisations(rig):
        if r.dcmotor_cogging is not None:
            motor = plant.model.actuator("motor").id
            plant.model.actuator_biasprm[motor, 0:3] = r.dcmotor_cogging
    return plant


class CommandController:
    """A command function as a :class:`sim.run.Controller`: ``command(k, observation)`` at tick k, passed through
    the rig's command map (:func:`command_map`); logs the command as sent, ``effort_command`` [N·m]."""

    log_units = {"effort_command": "N·m"}

    def __init__(self, command: CommandFn, cmd_map: Callable[[float], float]) -> None:
        self.command, self.cmd_map = command, cmd_map
        self.reset()

    def reset(self) -> None:
        self._k, self._sent = 0, 0.0

    def step(self, observation: Mapping[str, float]) -> float:
        self._sent = self.command(self._k, observation)
        self._k += 1
        return self.cmd_map(self._sent)

    def log_values(self) -> Sequence[float]:
        return (self._sent,)


# what a command function observes on the testbed: the true signals at the end of the previous tick
TESTBED_STATE = (LeverAngle(), LeverVelocity(), MotorEncoder(), MotorVelocity(), FlexureTorque(), CurrentEstimate(),
                 LoadCellForce())


def run_testbed(rig: Rig, command: CommandFn, n_ticks: int, *, backlash_side: int = 0,
                initial: InitialState | None = None, plant: Plant | None = None,
                previous_commands: np.ndarray | None = None) -> SimulatedRun:
    """Run the testbed of ``rig`` for ``n_ticks`` with a command function through the project's tick loop
    (:func:`sim.run.run_loop`); true signals of every tick, ``tau_cmd`` the command as sent (before the map).

    The command function observes ``TESTBED_STATE`` (q, qd, q_motor, qd_motor, tau_flexure,
    tau_current_estimate, force_loadcell; SI, true values). ``initial`` sets the state after the reset (a replay
    window starting from a measured state); ``previous_commands`` [N·m], the commands of the ticks before (oldest
    first), put the driver in the state they leave it in (:meth:`sim.plant.Plant.hold_commands`); ``plant``
    reuses a plant built by :func:`testbed_plant` for this rig (windows of one replay).
    """
    plant = plant or testbed_plant(rig)
    plant.reset(backlash_side=backlash_side)
    if initial is not None:
        initial(plant.model, plant.data)
        mujoco.mj_forward(plant.model, plant.data)
    cmd_map = command_map(rig)
    if previous_commands is not None:
        plant.hold_commands([cmd_map(float(u)) for u in previous_commands])
    load = joint_load(rig)
    lever_loads = [r.lever_load for r in realisations(rig) if r.lever_load is not None]
    t0 = plant.time_s
    motor_load = (None if load is None else
                  lambda k, p: -load(p.motor_angle_rad, p.motor_velocity_rad_s, p.time_s - t0))
    external = (None if not lever_loads else
                lambda k, p: -sum(f(p.output_angle_rad) for f in lever_loads))
    log = run_loop(plant, CommandController(command, cmd_map), n_ticks, measurements=TESTBED_STATE,
                   external=external, motor_load=motor_load)
    columns = {"time": log["time"], **{name: log[name] for name in SIGNAL_UNITS}}
    columns["tau_cmd"] = log["effort_command"]
    return SimulatedRun(columns, {"time": "s", **SIGNAL_UNITS})


def rigid_xml(rig: Rig) -> str:
    """MJCF of a rigid one-degree-of-freedom joint (slide along x or hinge about z), with a compliant second body
    if the rig has drivetrain compliance."""
    v = rig.rigid
    h = CONTROL_PERIOD_S / RIGID_SUBSTEPS
    compliant = next((r.compliant_body for r in realisations(rig) if r.compliant_body is not None), None)
    fraction, stiffness, damping = compliant or (0.0, 0.0, 0.0)

    def inertial(share: float) -> str:
        value = share * v["inertia"]
        return (f'<inertial pos="0 0 0" mass="{value:.9g}" diaginertia="1 1 1"/>' if rig.joint == "slide" else
                f'<inertial pos="0 0 0" mass="1" diaginertia="{value:.9g} {value:.9g} {value:.9g}"/>')

    delay = v.get("delay", 0.0)
    # linear interpolation of the command history: with the default zero-order hold MuJoCo rounds the dead time
    # up to a whole physics step (4.42 ms acted as 4.6 ms); interpolated, a command step's impulse arrives exactly
    # ``delay`` late
    delay_attr = f'delay="{delay:.9g}" interp="linear" nsample="{int(delay / h) + 2}"' if delay > 0 else ""
    jtype = "slide" if rig.joint == "slide" else "hinge"
    axis = "1 0 0" if rig.joint == "slide" else "0 0 1"
    imp = RIGID_FRICTION_IMPEDANCE
    static = max(v["breakaway"], v["coulomb"])
    second = (f'<body name="compliant"><joint name="compliance" type="{jtype}" axis="{axis}" '
              f'stiffness="{stiffness:.9g}" damping="{damping:.9g}"/>{inertial(fraction)}</body>'
              if compliant else "")
    return f"""<mujoco model="rigid_joint">
  <option timestep="{h:.9g}" integrator="Euler"><flag contact="disable" gravity="disable"/></option>
  <worldbody>
    <body name="mover">
      <joint name="joint" type="{jtype}" axis="{axis}" frictionloss="{static:.9g}" damping="{v['viscous']:.9g}"
             solreffriction="{2 * h:.9g} 1" solimpfriction="{imp} {imp} 0.001 0.5 2"/>
      {inertial(1.0 - fraction)}
      {second}
    </body>
  </worldbody>
  <actuator>
    <motor name="drive" joint="joint" gear="{v['effort_gain']:.9g}" {delay_attr}/>
    <motor name="external" joint="joint" gear="1"/>
  </actuator>
</mujoco>"""


@functools.lru_cache(maxsize=8)
def _compiled(xml: str) -> mujoco.MjModel:
    """The compiled model of an MJCF text (the windows of one replay share their rig's)."""
    return mujoco.MjModel.from_xml_string(xml)


def stribeck_giveback(rig: Rig) -> Callable[[float], float] | None:
    """qd -> the sliding friction a rigid joint's static ``frictionloss`` overstates, ``(F_s - g(v))·sign(v)``
    [N·m | N] (None without a Stribeck drop)."""
    v = rig.rigid
    fc, fs, vs = v["coulomb"], v["breakaway"], v["stribeck_velocity"]
    if not fs > fc:
        return None
    return lambda qd: math.copysign((fs - fc) * (1.0 - math.exp(-(qd / vs) ** 2)), qd)


def run_rigid(rig: Rig, command: CommandFn, n_ticks: int, *, initial: InitialState | None = None,
              previous_commands: np.ndarray | None = None) -> SimulatedRun:
    """Run a rigid joint rig; columns time, tau_cmd, q, qd (SI: N and m for a slide). ``initial`` and
    ``previous_commands`` as for :func:`run_testbed` (the delay buffer holds the past commands).

    A rigid joint is stepped here, not by :func:`sim.run.run_loop`: it is a one-body MJCF without the testbed
    plant's signals, driver and fixtures, and its loads act at every physics step, not once per control tick."""
    model = _compiled(rigid_xml(rig))
    data = mujoco.MjData(model)
    if initial is not None:
        initial(model, data)
        mujoco.mj_forward(model, data)
    cmd_map = command_map(rig)
    drive = model.actuator("drive").id
    if previous_commands is not None:
        past = np.array([cmd_map(float(u)) for u in previous_commands])
        prime_ctrl_history(model, data, drive, past, RIGID_SUBSTEPS * model.opt.timestep)
        data.ctrl[drive] = past[-1]
    load = joint_load(rig)
    constant = rig.rigid.get("constant_effort", 0.0)
    base_gravity, base_angle = rig.rigid.get("gravity_amplitude", 0.0), rig.rigid.get("gravity_angle", 0.0)
    giveback = stribeck_giveback(rig)
    slide = rig.joint == "slide"
    external = model.actuator("external").id
    t0 = data.time

    def force(q: float, qd: float) -> float:
        needed = constant + (base_gravity * math.sin(q - base_angle) if base_gravity else 0.0)
        if load is not None:
            needed += load(q, qd, data.time - t0)
        return (giveback(qd) if giveback is not None else 0.0) - needed

    per_step = giveback is not None or load is not None
    out = np.empty((n_ticks, 4))
    state = {"q": float(data.qpos[0]), "qd": float(data.qvel[0])}
    for k in range(n_ticks):
        u = command(k, state)
        data.ctrl[drive] = cmd_map(u)
        if per_step:
            for _ in range(RIGID_SUBSTEPS):
                data.ctrl[external] = force(float(data.qpos[0]), float(data.qvel[0]))
                mujoco.mj_step(model, data)
        else:
            data.ctrl[external] = force(state["q"], state["qd"])
            mujoco.mj_step(model, data, RIGID_SUBSTEPS)
        state["q"], state["qd"] = float(data.qpos[0]), float(data.qvel[0])
        out[k] = (data.time, u, state["q"], state["qd"])
    warn_mujoco_warnings()
    units = {"time": "s", "tau_cmd": "N" if slide else "N·m", "q": "m" if slide else "rad",
             "qd": "m/s" if slide else "rad/s"}
    return SimulatedRun({name: out[:, i].copy() for i, name in enumerate(units)}, units)


def sensor_reading(truth: Rig, tau: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """The torque sensor's output for the true flexure torque (its effects applied, noise not yet) [N·m]."""
    reading = np.asarray(tau, dtype=float).copy()
    for r in realisations(truth):
        if r.sensor is not None:
            reading = reading + r.sensor(np.asarray(tau, dtype=float), np.asarray(temperature, dtype=float))
    return reading
