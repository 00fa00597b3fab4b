"""The calibration rig of the paper (Sec. IV-A, Figs. 5, 6 and 8(a)-(b)), simulated: schedules of applied moments and the
records they produce (sensor channel voltages beside the ATI MINI85 reference).

The sensor is bolted to the reference sensor and loaded with test weights on a lever: the loading is
quasi-static (seconds per step against a flexure mode of kHz), so the flexure twist is the applied torque over
K_t; the sensor's own hysteresis, noise and drift come from :class:`sensor.photoreflector.PhotoReflectorArray`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.gim8108_testbed.derived import derive
from sensor.photoreflector import PhotoReflectorArray, reference_torque
from sim.params import TestbedParams

# Paper Sec. IV-B: test weights to about ±25 N·m, loading and unloading five times in each direction.
CALIBRATION_LEVELS_NM = (5.0, 10.0, 15.0, 20.0, 25.0)
CALIBRATION_CYCLES = 5
PRELOAD_CYCLES = 1  # per direction; a rate-independent slip state is set by one full excursion
PRELOAD_LABEL = -1  # ``cycle`` label of preload samples
# Assumed timing of placing weights by hand: a 0.5 s transition, then 2 s at rest on each level, and 5 s of
# no load between cycles (the quiet segments the QP penalises).
TRANSITION_S = 0.5
HOLD_S = 2.0
QUIET_S = 5.0
# Paper Sec. IV-B: crosstalk moments T_x, T_y over about 25 N·m; resolution from 10 s at 1 kHz, no filtering.
CROSSTALK_LEVELS_NM = (5.0, 10.0, 15.0, 20.0, 25.0)
RESOLUTION_RECORD_S = 10.0


@dataclass(frozen=True)
class Schedule:
    """Applied moments per sample [N·m] and labels of what each sample is.

    ``branch``: +1 while loading (|T| rising or held after a rise), -1 while unloading, 0 at no load.
    ``level_nm``: the nominal level a held sample belongs to (NaN in transitions). ``cycle``: 0-based cycle.
    """

    tz_nm: np.ndarray
    tx_nm: np.ndarray
    ty_nm: np.ndarray
    branch: np.ndarray
    level_nm: np.ndarray
    cycle: np.ndarray

    def __len__(self) -> int:
        return len(self.tz_nm)


def _staircase(levels: tuple[float, ...], sign: float, dt: float) -> tuple[list, list, list]:
    """One loading-unloading cycle: 0 -> levels -> 0, with transitions and holds, quiet time after."""
    values, branch, level = [], [], []
    path = [0.0, *levels, *reversed(levels[:-1]), 0.0]
    n_tr, n_hold, n_quiet = round(TRANSITION_S / dt), round(HOLD_S / dt), round(QUIET_S / dt)
    for a, b in zip(path[:-1], path[1:], strict=True):
        direction = 1.0 if abs(b) > abs(a) else -1.0
        values += list(sign * np.linspace(a, b, n_tr + 1)[1:])
        branch += [direction] * n_tr
        level += [np.nan] * n_tr
        values += [sign * b] * n_hold
        branch += [direction if b != 0.0 else 0.0] * n_hold
        level += [sign * b] * n_hold
    values += [0.0] * n_quiet
    branch += [0.0] * n_quiet
    level += [0.0] * n_quiet
    return values, branch, level


def calibration_schedule(dt_s: float) -> Schedule:
    """T_z weights to ±25 N·m, five loading-unloading cycles each way, starting and separated by quiet time.

    Each direction's five cycles are preceded by :data:`PRELOAD_CYCLES` preload cycle to the full load in that
    direction (labelled ``cycle = -1``), as force-transducer calibration practice prescribes (ISO 376 preloads
    before each series and after a change of direction): it sets the joint's slip state so that the five
    measured cycles repeat.
    """
    n_quiet = round(QUIET_S / dt_s)
    tz, branch, level, cycle = [0.0] * n_quiet, [0.0] * n_quiet, [0.0] * n_quiet, [0] * n_quiet
    plan = []
    for sign, first in ((1.0, 0), (-1.0, CALIBRATION_CYCLES)):
        plan += [(sign, PRELOAD_LABEL)] * PRELOAD_CYCLES + [(sign, first + k) for k in range(CALIBRATION_CYCLES)]
    for sign, label in plan:
        v, b, lv = _staircase(CALIBRATION_LEVELS_NM, sign, dt_s)
        tz += v
        branch += b
        level += lv
        cycle += [label] * len(v)
    tz = np.array(tz)
    zeros = np.zeros_like(tz)
    return Schedule(tz, zeros, zeros.copy(), np.array(branch), np.array(level), np.array(cycle))


def crosstalk_schedule(dt_s: float, axis: str) -> Schedule:
    """An off-axis moment (``axis`` 'x' or 'y') loaded to 25 N·m and back in steps, T_z = 0."""
    if axis not in ("x", "y"):
        raise ValueError(f"axis = {axis!r}: valid values are 'x', 'y'")
    v, b, lv = _staircase(CROSSTALK_LEVELS_NM, 1.0, dt_s)
    moment = np.array(v)
    zeros = np.zeros_like(moment)
    tx, ty = (moment, zeros) if axis == "x" else (zeros, moment)
    return Schedule(zeros.copy(), tx, ty, np.array(b), np.array(lv), np.zeros(len(v), dtype=int))


def resolution_schedule(dt_s: float) -> Schedule:
    """No load for 10 s (paper: 3σ resolution from 10 s at 1 kHz without filtering)."""
    n = round(RESOLUTION_RECORD_S / dt_s)
    zeros = np.zeros(n)
    return Schedule(zeros, zeros.copy(), zeros.copy(), zeros.copy(), zeros.copy(), np.zeros(n, dtype=int))


@dataclass(frozen=True)
class RigRecord:
    """What the rig records: time [s], channel voltages (N, 8) [V], MINI85 reading [N·m], true torque [N·m]."""

    time_s: np.ndarray
    voltages_v: np.ndarray
    tau_reference_nm: np.ndarray
    tau_true_nm: np.ndarray
    schedule: Schedule


def record(schedule: Schedule, sensor: PhotoReflectorArray, rng: np.random.Generator,
           temperature_c: np.ndarray | float | None = None) -> RigRecord:
    """Read the sensor and the reference through a schedule (the sensor's state carries over between calls).

    Parameters
    ----------
    schedule : Schedule
        Applied T_z, T_x, T_y per sample [N·m].
    sensor : PhotoReflectorArray
        The sensor unit; its sample period sets the time axis.
    rng : numpy.random.Generator
        Draws the MINI85's noise.
    temperature_c : (N,) array or float, optional
        Board temperature [°C] (the calibration temperature if None).

    Returns
    -------
    RigRecord
        Time [s] (first sample at one period), channel voltages (N, 8) [V], MINI85 reading and applied T_z [N·m].
    """
    params: TestbedParams = sensor.params
    twist = schedule.tz_nm / derive(params).flexure_stiffness_nm_per_rad
    v = sensor.read(twist, schedule.tx_nm, schedule.ty_nm, temperature_c)
    t = np.arange(1, len(schedule) + 1) * sensor.sample_period_s
    return RigRecord(t, v, reference_torque(schedule.tz_nm, params, rng), schedule.tz_nm.copy(), schedule)
