"""The control-loop runtime: one tick loop for every run of the testbed, open or closed.

A control tick k (``simulation.control_period_s``, 1 ms) is, in this order:

1. **observe**: every :class:`Measurement` reads the plant's state at the end of tick k-1, into an
   observation (a dict: measurement name -> value, plus ``time_s``, the tick's start [s], and ``tau_ref``,
   the tick's torque reference [N·m], when the run has one);
2. **control**: the :class:`Controller` maps the observation to a motor torque command [N·m, output side];
3. **advance**: external torques are applied (on the lever, on the output flange, and on the motor joint), the
   plant steps one
   tick with the command (the driver's current limit and current-to-torque map are the plant's);
4. **record**: the plant's signals at the end of tick k (``sim.plant.SIGNAL_UNITS``), the inputs, the
   observation, what the controller reports (:attr:`Controller.log_units`) and the recorded-only
   measurements (e.g. the load cell that grades a run, which the controller does not observe), read at the
   end of tick k.

:func:`run_loop` runs a whole profile; :class:`ControlLoop` exposes steps 1 and 3 for a caller that is itself
the controller (the Gymnasium environment, whose agent acts between them). A user's controller is any object
with ``reset()`` and ``step(observation) -> float``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Protocol, TextIO, runtime_checkable

import numpy as np

from sim.plant import SIGNAL_UNITS, Plant
from sim.runlog import HOLD_END, RunLog

PROGRESS_MIN_TICKS = 20_000  # report progress only on runs longer than 20 s of simulated time
PROGRESS_EVERY_TICKS = 1000


@runtime_checkable
class Measurement(Protocol):
    """A sensor read once per tick from the plant: ``name`` is its key in the observation, ``unit`` its unit.

    ``extra_units`` (name -> unit) names further columns the measurement records every tick (e.g. the optical
    sensor's channel voltages), whose values of the last read ``extra_values()`` returns in that order.
    """

    name: str
    unit: str
    extra_units: Mapping[str, str]

    def reset(self) -> None: ...

    def read(self, plant: Plant) -> float: ...

    def extra_values(self) -> Sequence[float]: ...


@runtime_checkable
class Controller(Protocol):
    """A controller stepped once per tick: ``step(observation) -> command`` [N·m, output side].

    The observation maps each measurement's name to its reading (``tau_sensor``, ``tau_current_estimate``,
    ``q_motor``, ``qd_motor``, ``q``, ``qd``, ``temperature``, ``tau_loadcell``, as the run provides them) plus
    ``time_s`` [s] and, in a tracking run, ``tau_ref`` [N·m]. ``reset()`` restores the initial state.

    ``log_units`` (name -> unit, may be empty) names internal signals the run records every tick;
    ``log_values()`` returns them, in that order, for the last step (e.g. the measured torque it used, a
    virtual reference at the start of the tick).
    """

    log_units: Mapping[str, str]

    def reset(self) -> None: ...

    def step(self, observation: Mapping[str, float]) -> float: ...

    def log_values(self) -> Sequence[float]: ...


class OpenLoop:
    """The controller of an open-loop run: command k of a profile [N·m], whatever it observes."""

    log_units: Mapping[str, str] = {}

    def __init__(self, commands_nm) -> None:
        self.commands_nm = np.asarray(commands_nm, dtype=float)
        self._k = 0

    def reset(self) -> None:
        self._k = 0

    def step(self, observation: Mapping[str, float]) -> float:
        command = float(self.commands_nm[self._k])
        self._k += 1
        return command

    def log_values(self) -> Sequence[float]:
        return ()


class Progress:
    """Prints 'label: 40 % (4.0 of 10.0 s simulated, 31000 ticks/s)' to a stream at most once per second."""

    def __init__(self, label: str, total_ticks: int, tick_s: float, stream: TextIO | None = None,
                 interval_s: float = 1.0) -> None:
        self.label, self.total, self.tick_s = label, total_ticks, tick_s
        self.stream = stream or sys.stderr
        self.interval_s = interval_s
        self.start = self.last = time.perf_counter()

    def update(self, done: int) -> None:
        now = time.perf_counter()
        if now - self.last < self.interval_s and done < self.total:
            return
        self.last = now
        rate = done / max(now - self.start, 1e-9)
        print(f"{self.label}: {100 * done / self.total:3.0f} % ({done * self.tick_s:.1f} of "
              f"{self.total * self.tick_s:.1f} s simulated, {rate:,.0f} ticks/s)", file=self.stream)


def apply_motor_torque(plant: Plant, tau_nm: float) -> None:
    """Apply a torque [N·m, output-referred] on the motor joint (the rotor and gear, before the backlash): a load
    the plant's model lacks (e.g. a spring or a disturbance on the rotor). Written to MuJoCo's ``qfrc_applied``
    of the joint named 'motor', which ``Plant.reset`` clears."""
    plant.data.joint("motor").qfrc_applied[0] = tau_nm


def apply_hub_torque(plant: Plant, tau_nm: float) -> None:
    """Apply an external torque [N·m] about the joint axis on the gear's output flange + sensor hub, i.e.
    between the gear and the flexure (the sensor and the load cell both see it, the current estimate does
    not). Written to MuJoCo's ``xfrc_applied`` of the body named 'output', which ``Plant.reset`` clears."""
    plant.data.body("output").xfrc_applied[5] = tau_nm


class ControlLoop:
    """Steps 1 and 3 of a control tick on one plant: observe with the measurements, advance with a command.

    Parameters
    ----------
    plant : Plant
        Stepped from its current state.
    measurements : sequence of Measurement
        Read in this order at every :meth:`observe`; names must be distinct.
    """

    def __init__(self, plant: Plant, measurements: Sequence[Measurement] = ()) -> None:
        names = [m.name for m in measurements]
        if len(set(names)) != len(names):
            raise ValueError(f"measurement names {names} repeat: each is a key of the observation")
        self.plant = plant
        self.measurements = tuple(measurements)
        self.observation: dict[str, float] = {}

    def reset(self) -> None:
        """Reset every measurement (the plant is reset by its owner, with its own options)."""
        for m in self.measurements:
            m.reset()

    def observe(self, tau_ref_nm: float | None = None) -> dict[str, float]:
        """Read every measurement at the plant's current state; returns the observation (one dict, reused)."""
        obs = self.observation
        obs["time_s"] = self.plant.time_s
        if tau_ref_nm is not None:
            obs["tau_ref"] = tau_ref_nm
        for m in self.measurements:
            obs[m.name] = m.read(self.plant)
        return obs

    def advance(self, command_nm: float, tau_ext_nm: float = 0.0, tau_hub_nm: float | None = None,
                tau_motor_nm: float | None = None) -> None:
        """Step the plant one tick with a command [N·m], a lever torque [N·m] and, if given, a hub torque
        [N·m] (:func:`apply_hub_torque`) and a motor-joint torque [N·m] (:func:`apply_motor_torque`)."""
        if tau_hub_nm is not None:
            apply_hub_torque(self.plant, tau_hub_nm)
        if tau_motor_nm is not None:
            apply_motor_torque(self.plant, tau_motor_nm)
        self.plant.step(command_nm, tau_ext_nm)


ExternalTorque = Callable[[int, Plant], float]  # (tick, plant at the end of the previous tick) -> N·m


def _profile(name: str, values, n: int) -> np.ndarray | None:
    if values is None:
        return None
    values = np.asarray(values, dtype=float)
    if values.shape != (n,) or not np.isfinite(values).all():
        raise ValueError(f"{name} must be {n} finite values (one per tick), got shape {values.shape}")
    return values


def run_loop(plant: Plant, controller: Controller, n_ticks: int, *, measurements: Sequence[Measurement] = (),
             recorded: Sequence[Measurement] = (), tau_ref_nm=None, tau_ext_nm=None, tau_hub_nm=None,
             external: ExternalTorque | None = None, motor_load: ExternalTorque | None = None,
             stop: Callable[[int, Plant], bool] | None = None, progress_label: str | None = None,
             meta: dict | None = None) -> RunLog:
    """Run ``n_ticks`` control ticks of ``controller`` on ``plant`` and record them.

    Parameters
    ----------
    plant : Plant
        Stepped from its current state (reset it first for a run from rest).
    controller : Controller
        Stepped once per tick with the observation (it is not reset here: reset it for a fresh run).
    n_ticks : int
        Number of control ticks.
    measurements : sequence of Measurement
        What the controller observes; each is reset, then read every tick and recorded under its name.
    recorded : sequence of Measurement
        Read at the end of every tick and recorded under its name, not observed (e.g. the load cell).
    tau_ref_nm : (n_ticks,) array, optional
        Torque reference per tick [N·m], observed as ``tau_ref`` and recorded.
    tau_ext_nm : (n_ticks,) array, optional
        External torque on the lever per tick [N·m] (zero if None).
    tau_hub_nm : (n_ticks,) array, optional
        External torque on the output flange / sensor hub per tick [N·m] (:func:`apply_hub_torque`).
    external : callable, optional
        ``external(k, plant) -> N·m``: a lever torque computed from the plant's state (e.g. a hand), added to
        ``tau_ext_nm``.
    motor_load : callable, optional
        ``motor_load(k, plant) -> N·m``: a torque on the motor joint [output-referred] computed from the plant's
        state at the end of tick k-1, held through tick k (:func:`apply_motor_torque`; not recorded).
    stop : callable, optional
        ``stop(k, plant) -> bool``, asked after tick k is recorded: True ends the run there (the log holds
        ticks 0 ... k).
    progress_label : str, optional
        Print progress to stderr under this label.
    meta : dict, optional
        Extra metadata of the log.

    Returns
    -------
    RunLog
        ``time`` (end of each tick) [s], the plant's signals (``sim.plant.SIGNAL_UNITS``; ``tau_cmd`` is the
        command sent to the driver), ``tau_ref`` if given, ``tau_ext`` (the total lever torque) and ``tau_hub``
        if given [N·m], each measurement's reading and extra columns, and the controller's logged signals.
    """
    n = int(n_ticks)
    if n < 1:
        raise ValueError(f"n_ticks = {n_ticks!r}: valid range [1, inf)")
    ref = _profile("tau_ref_nm", tau_ref_nm, n)
    ext = _profile("tau_ext_nm", tau_ext_nm, n)
    hub = _profile("tau_hub_nm", tau_hub_nm, n)
    loop = ControlLoop(plant, measurements)
    loop.reset()
    ref_list = ref.tolist() if ref is not None else None
    ext_list = ext.tolist() if ext is not None else [0.0] * n
    hub_list = hub.tolist() if hub is not None and np.any(hub) else None
    out, times = np.empty((n, len(SIGNAL_UNITS))), np.empty(n)
    lever = np.empty(n)
    recorded = tuple(recorded)
    for m in recorded:
        m.reset()
    read = np.empty((n, len(loop.measurements)))
    after = np.empty((n, len(recorded)))
    extra_units = {name: unit for m in loop.measurements for name, unit in m.extra_units.items()}
    extras = np.empty((n, len(extra_units)))
    logged_units = dict(controller.log_units)
    logged = np.empty((n, len(logged_units)))
    bar = Progress(progress_label, n, plant.params.simulation.control_period_s) if progress_label else None
    for k in range(n):
        obs = loop.observe(ref_list[k] if ref_list is not None else None)
        for i, m in enumerate(loop.measurements):
            read[k, i] = obs[m.name]
        if extra_units:
            extras[k] = [v for m in loop.measurements for v in m.extra_values()]
        try:
            command = controller.step(obs)
        except KeyError as exc:
            missing = exc.args[0] if exc.args else None
            if not isinstance(missing, str) or missing in obs:
                raise
            raise KeyError(f"the controller read {missing!r}, which this run does not observe; it observes "
                           f"{', '.join(sorted(obs))}") from exc
        if logged_units:
            logged[k] = controller.log_values()
        lever[k] = ext_list[k] + (external(k, plant) if external is not None else 0.0)
        loop.advance(command, lever[k], hub_list[k] if hub_list is not None else None,
                     motor_load(k, plant) if motor_load is not None else None)
        times[k] = plant.time_s
        plant.read_signals(out[k])
        for i, m in enumerate(recorded):
            after[k, i] = m.read(plant)
        if bar is not None and (k % PROGRESS_EVERY_TICKS == PROGRESS_EVERY_TICKS - 1 or k == n - 1):
            bar.update(k + 1)
        if stop is not None and stop(k, plant):
            n = k + 1
            out, times, lever, read, after, extras, logged = (a[:n] for a in (out, times, lever, read, after, extras,
                                                                              logged))
            ref, hub = (None if a is None else a[:n] for a in (ref, hub))
            break
    columns = signal_columns(out, times)
    units = {"time": "s", **SIGNAL_UNITS}
    if ref is not None:
        columns["tau_ref"], units["tau_ref"] = ref.copy(), "N·m"
    columns["tau_ext"], units["tau_ext"] = lever, "N·m"
    if hub is not None:
        columns["tau_hub"], units["tau_hub"] = hub.copy(), "N·m"
    for i, m in enumerate(loop.measurements):
        if m.name not in columns:
            columns[m.name], units[m.name] = read[:, i].copy(), m.unit
    for i, m in enumerate(recorded):
        columns[m.name], units[m.name] = after[:, i].copy(), m.unit
    for j, (name, unit) in enumerate({**extra_units, **logged_units}.items()):
        columns[name] = (extras[:, j] if j < len(extra_units) else logged[:, j - len(extra_units)]).copy()
        units[name] = unit
    return RunLog(columns, units, {"fixture": plant.fixture, "physics_timestep_s": plant.timestep_s,
                                   "substeps": plant.n_substeps, "lever_length_m": plant.params.lever.length_m,
                                   "time_convention": HOLD_END, **(meta or {})})


def signal_columns(rows: np.ndarray, times: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> dict:
    """Run-log columns from per-tick ``Plant.read_signals`` rows (``SIGNAL_UNITS`` order), their ``times`` [s]
    and ``extra`` columns."""
    return {"time": times, **{name: rows[:, i].copy() for i, name in enumerate(SIGNAL_UNITS)}, **(extra or {})}


def run_open_loop(plant: Plant, tau_cmd_nm, tau_ext_nm=None, *, progress: bool = True,
                  stop: Callable[[int, Plant], bool] | None = None, meta: dict | None = None) -> RunLog:
    """Apply a motor torque command (and an external lever torque) tick by tick and record the run.

    Parameters
    ----------
    plant : Plant
        Stepped from its current state (reset it first for a run from rest).
    tau_cmd_nm : (N,) array
        Motor torque command per control tick [N·m, output side].
    tau_ext_nm : (N,) array, optional
        External torque on the lever per tick [N·m] (zero if None).
    progress : bool
        Print progress to stderr on runs longer than ``PROGRESS_MIN_TICKS``.
    stop : callable, optional
        Ends the run early, as for :func:`run_loop`.

    Returns
    -------
    RunLog
        ``time`` is the end of each tick [s]; columns are those of ``sim.plant.SIGNAL_UNITS`` plus ``tau_ext``.
    """
    commands = np.asarray(tau_cmd_nm, dtype=float)
    if commands.ndim != 1 or not np.isfinite(commands).all():
        raise ValueError("tau_cmd_nm must be a 1-D array of finite torques [N·m]")
    n = len(commands)
    if tau_ext_nm is not None and np.shape(tau_ext_nm) != (n,):
        raise ValueError(f"tau_ext_nm has shape {np.shape(tau_ext_nm)}; expected ({n},) like tau_cmd_nm")
    label = "simulating" if progress and n >= PROGRESS_MIN_TICKS else None
    return run_loop(plant, OpenLoop(commands), n, tau_ext_nm=np.zeros(n) if tau_ext_nm is None else tau_ext_nm,
                    stop=stop, progress_label=label, meta=meta)
