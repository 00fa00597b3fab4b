"""MuJoCo runs of a rig with its effects: the testbed plant, or a rigid joint built here.

Effects reach MuJoCo as natively as MuJoCo allows:

- friction levels, Stribeck, viscous, presliding, load-dependent friction, backlash, command delay: the
  testbed's own parameters (``sim.params``), so the plant is rebuilt with them;
- cogging: the dcmotor's native ``cogging`` (biasprm[0:3] = amplitude, poles, phase on the motor shaft angle),
  written into the compiled model: amplitude/N at the output, period 2π/(N·poles) of the output angle;
- torque-constant roll-off: the command is mapped before it reaches the plant (a memoryless map of the command
  is what a saturating torque constant does to a torque-commanded drive);
- asymmetric friction: a constant torque -Δ/2 on the motor joint (levels F_c ± Δ/2 by direction are exactly a
  constant torque opposing positive motion; MuJoCo's LuGre is symmetric), applied beside the command, not
  through it, so that the testbed motor's current-to-torque map (``sim.motor_torque``) does not scale it;
- gravity: a torque on the lever (``external`` actuator) from the lever angle of the previous tick (one control
  tick late: gravity changes slowly against 1 ms);
- sensor effects act on the sensor reading, not the mechanics (:func:`sensor_reading`).

A rigid joint is a one-body MJCF: ``frictionloss`` (Coulomb with stick), ``damping`` (viscous), a ``motor``
actuator with the effort gain and the command ``delay`` (history linearly interpolated); gravity and cogging through a second actuator
(one tick late, as above). MuJoCo has no Stribeck curve on a plain joint, so a rigid joint with
breakaway > coulomb is not simulated here (the analysis still models it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from sim.discrepancy.effects import rolled_off
from sim.discrepancy.rig import Rig
from sim.motor_torque import CurrentToTorqueMap
from sim.plant import SIGNAL_UNITS, Plant, prime_ctrl_history

RIGID_SUBSTEPS = 5  # rigid joint: physics steps per control tick (no stiff mode; the dry-friction row's time
# constant is two physics steps, as the testbed's tuned rows)
RIGID_FRICTION_IMPEDANCE = 0.9999  # solimpfriction d0 = dwidth of the rigid joint's dry friction (MuJoCo's max)
CONTROL_PERIOD_S = 1e-3  # rigid joint: the 1 kHz control rate of the project's logs

# command(k, state) -> effort command [N·m | N]; state holds the signals of the previous tick (SI)
CommandFn = Callable[[int, dict[str, float]], float]


@dataclass(frozen=True)
class SimulatedRun:
    """True signals of a run, one row per control tick; ``columns`` by name with ``units``."""

    columns: dict[str, np.ndarray]
    units: dict[str, str]


def _effect(rig: Rig, name: str) -> dict[str, float] | None:
    for effect in rig.effects:
        if effect.name == name:
            return effect.parameters
    return None


def command_map(rig: Rig) -> Callable[[float], float]:
    """Effort command -> what the drive is asked for before its dynamics (the roll-off effect)."""
    rolloff = _effect(rig, "torque_constant_nonlinearity")
    if rig.model == "testbed":  # the roll-off refers to the rated peak torque; the driver limits the command
        peak = rig.params.motor.peak_torque_nm
        limit = CurrentToTorqueMap.from_params(rig.params).command_limit_nm
    else:
        peak = limit = rig.rigid.get("peak_effort", math.inf)
    c = rolloff["torque_rolloff"] if rolloff else 0.0
    if c and not math.isfinite(peak):
        raise ValueError("torque_constant_nonlinearity needs the rig's peak effort (peak_effort)")

    def mapped(u: float) -> float:
        return float(rolled_off(u, c, peak, limit)) if c else u  # (the plant and the rigid joint clip anyway)

    return mapped


def asymmetry_offset(rig: Rig) -> float:
    """The constant torque of asymmetric friction, -Δ/2 [N·m | N] (0 without the effect)."""
    asym = _effect(rig, "asymmetric_friction")
    return -0.5 * asym["asymmetry"] if asym else 0.0


def testbed_plant(rig: Rig) -> Plant:
    """The testbed plant of a rig, with native cogging written into the compiled model."""
    assert rig.model == "testbed" and rig.params is not None
    plant = Plant(rig.params, rig.fixture)
    cog = _effect(rig, "cogging")
    if cog:
        n = rig.params.motor.gear_ratio
        poles = 2.0 * math.pi / (n * cog["cogging_period"])
        if abs(poles - round(poles)) > 1e-6 * poles or round(poles) < 1:
            raise ValueError(f"cogging_period = {cog['cogging_period']} rad is not 2π/(N·poles) for an integer "
                             f"pole count (N = {n:g}); MuJoCo's dcmotor cogging needs one")
        motor = plant.model.actuator("motor").id
        plant.model.actuator_biasprm[motor, 0:3] = (cog["cogging_amplitude"] / n, round(poles), cog["cogging_phase"])
    return plant


InitialState = Callable[[mujoco.MjModel, mujoco.MjData], None]  # sets qpos/qvel/act after a reset


def run_testbed(rig: Rig, command: CommandFn, n_ticks: int, *, backlash_side: int = 0,
                initial: InitialState | None = None, plant: Plant | None = None,
                previous_commands: np.ndarray | None = None) -> SimulatedRun:
    """Run the testbed of ``rig`` for ``n_ticks`` with a command function; true signals of every tick.

    ``initial`` sets the state after the reset (a replay window starting from a measured state);
    ``previous_commands`` [N·m], the commands of the ticks before (oldest first), put the driver in the state
    they leave it in (:meth:`sim.plant.Plant.hold_commands`); ``plant`` reuses a plant built by
    :func:`testbed_plant` for this rig (windows of one replay).
    """
    plant = plant or testbed_plant(rig)
    plant.reset(backlash_side=backlash_side)
    if initial is not None:
        initial(plant.model, plant.data)
        mujoco.mj_forward(plant.model, plant.data)
    cmd_map = command_map(rig)
    if previous_commands is not None:
        plant.hold_commands([cmd_map(float(u)) for u in previous_commands])
    plant.data.joint("motor").qfrc_applied[0] = asymmetry_offset(rig)  # output side; cleared by Plant.reset
    grav = _effect(rig, "gravity")
    names = list(SIGNAL_UNITS)
    out = np.empty((n_ticks, len(names)))
    times = np.empty(n_ticks)
    row = np.empty(len(names))
    index = {name: i for i, name in enumerate(names)}
    plant.read_signals(row)
    state = {key: float(row[index[key]]) for key in ("q", "qd", "q_motor", "tau_flexure", "tau_current_estimate",
                                                     "force_loadcell")}
    for k in range(n_ticks):
        u = command(k, state)
        tau_ext = 0.0
        if grav:
            tau_ext = -grav["gravity_amplitude"] * math.sin(state["q"] - grav["gravity_angle"])
        plant.step(cmd_map(u), tau_ext)
        plant.read_signals(row)
        row[index["tau_cmd"]] = u  # the log holds the command as sent, not as delivered
        out[k] = row
        times[k] = plant.time_s
        for key in state:
            state[key] = row[index[key]]
    columns = {"time": times, **{name: out[:, i].copy() for i, name in enumerate(names)}}
    return SimulatedRun(columns, {"time": "s", **SIGNAL_UNITS})


def rigid_xml(rig: Rig) -> str:
    """MJCF of a rigid one-degree-of-freedom joint (slide along x or hinge about z)."""
    v = rig.rigid
    h = CONTROL_PERIOD_S / RIGID_SUBSTEPS
    if v["breakaway"] > v["coulomb"]:
        raise ValueError("a rigid joint with breakaway > coulomb cannot be simulated here (MuJoCo has no Stribeck "
                         "curve on a plain joint)")
    inertial = (f'mass="{v["inertia"]:.9g}" diaginertia="1 1 1"' if rig.joint == "slide" else
                f'mass="1" diaginertia="{v["inertia"]:.9g} {v["inertia"]:.9g} {v["inertia"]:.9g}"')
    delay = v.get("delay", 0.0)
    # linear interpolation of the command history: with the default zero-order hold MuJoCo rounds the dead time
    # up to a whole physics step (measured: 4.42 ms acted as 4.6 ms); interpolated, a command step acts after
    # the stated delay on average (its impulse arrives exactly ``delay`` late)
    delay_attr = f'delay="{delay:.9g}" interp="linear" nsample="{int(delay / h) + 2}"' if delay > 0 else ""
    jtype = "slide" if rig.joint == "slide" else "hinge"
    axis = "1 0 0" if rig.joint == "slide" else "0 0 1"
    imp = RIGID_FRICTION_IMPEDANCE
    return f"""<mujoco model="rigid_joint">
  <option timestep="{h:.9g}" integrator="Euler"><flag contact="disable" gravity="disable"/></option>
  <worldbody>
    <body name="mover">
      <joint name="joint" type="{jtype}" axis="{axis}" frictionloss="{v['coulomb']:.9g}" damping="{v['viscous']:.9g}"
             solreffriction="{2 * h:.9g} 1" solimpfriction="{imp} {imp} 0.001 0.5 2"/>
      <inertial pos="0 0 0" {inertial}/>
    </body>
  </worldbody>
  <actuator>
    <motor name="drive" joint="joint" gear="{v['effort_gain']:.9g}" {delay_attr}/>
    <motor name="external" joint="joint" gear="1"/>
  </actuator>
</mujoco>"""


def run_rigid(rig: Rig, command: CommandFn, n_ticks: int, *, initial: InitialState | None = None,
              previous_commands: np.ndarray | None = None) -> SimulatedRun:
    """Run a rigid joint rig; columns time, tau_cmd, q, qd (SI: N and m for a slide). ``initial`` and
    ``previous_commands`` as for :func:`run_testbed` (the delay buffer holds the past commands)."""
    model = mujoco.MjModel.from_xml_string(rigid_xml(rig))
    data = mujoco.MjData(model)
    if initial is not None:
        initial(model, data)
        mujoco.mj_forward(model, data)
    cmd_map, offset = command_map(rig), asymmetry_offset(rig)
    drive = model.actuator("drive").id
    if previous_commands is not None:
        past = np.array([cmd_map(float(u)) + offset for u in previous_commands])
        prime_ctrl_history(model, data, drive, past, RIGID_SUBSTEPS * model.opt.timestep)
        data.ctrl[drive] = past[-1]
    grav = _effect(rig, "gravity")
    cog = _effect(rig, "cogging")
    base_gravity = rig.rigid.get("gravity_amplitude", 0.0)
    external = model.actuator("external").id
    out = np.empty((n_ticks, 4))
    state = {"q": float(data.qpos[0]), "qd": float(data.qvel[0])}
    for k in range(n_ticks):
        u = command(k, state)
        q = state["q"]
        load = 0.0
        for amplitude, angle in ((base_gravity, rig.rigid.get("gravity_angle", 0.0)),
                                 ((grav or {}).get("gravity_amplitude", 0.0), (grav or {}).get("gravity_angle", 0.0))):
            load += amplitude if rig.joint == "slide" else amplitude * math.sin(q - angle)
        if cog:
            load -= cog["cogging_amplitude"] * math.sin(2 * math.pi * q / cog["cogging_period"] + cog["cogging_phase"])
        data.ctrl[drive] = cmd_map(u) + offset
        data.ctrl[external] = -load
        mujoco.mj_step(model, data, RIGID_SUBSTEPS)
        state["q"], state["qd"] = float(data.qpos[0]), float(data.qvel[0])
        out[k] = (data.time, u, state["q"], state["qd"])
    lin = rig.joint == "slide"
    units = {"time": "s", "tau_cmd": "N" if lin else "N·m", "q": "m" if lin else "rad", "qd": "m/s" if lin else "rad/s"}
    return SimulatedRun({name: out[:, i].copy() for i, name in enumerate(units)}, units)


def sensor_reading(truth: Rig, tau: np.ndarray, temperature: np.ndarray) -> np.ndarray:
    """The torque sensor's output for the true flexure torque (its effects applied, noise not yet)."""
    from sim.discrepancy.model import play_operator  # the same elastic-plastic element the analysis fits

    values = {"sensor_offset": 0.0, "sensor_gain": 1.0, "sensor_tempco": 0.0, "sensor_hysteresis": 0.0,
              "sensor_hysteresis_span": 1.0}
    for effect in truth.effects:
        values.update({k: v for k, v in effect.parameters.items() if k in values})
    reading = values["sensor_gain"] * tau + values["sensor_offset"]
    reading = reading + values["sensor_tempco"] * (temperature - truth.params.photoreflector.reference_temperature_c)
    if values["sensor_hysteresis"]:
        span = values["sensor_hysteresis_span"]
        reading = reading + values["sensor_hysteresis"] / span * (tau - play_operator(tau, span))
    return reading
