"""Checks of a log against its rig before any analysis: implausible input is refused, not analysed.

Each check names the column, the row (spreadsheet numbering, the header is row 1) and what was seen:

- the time column: a sampling step too coarse for the analysis band (a time column in milliseconds);
- the command: beyond the rig's peak effort (the testbed: the driver's current limit) by more than 1 %
  (a command in mN·m, a wrong gain);
- the positions of a hinge: a jump of about 2π in one sample (an encoder wrapped to one turn; ``unwrap``
  unwraps it);
- the fixture: a locked testbed log whose lever turns;
- the effort balance, once the baseline is fitted (:func:`check_effort_balance`): a model that needs several
  times the logged effort to make the logged motion because its inertial terms are out of scale (positions in
  degrees or millimetres, a command in mN·m, a mass far off).

:func:`to_hold_end` brings a log stamped in the ``command`` time convention to the ``hold_end`` convention the
analysis uses (``docs/run_log_format.md``).
"""

from __future__ import annotations

import math

import numpy as np

from sim.discrepancy.model import Surrogate, channel_unit
from sim.discrepancy.rig import Rig
from sim.discrepancy.signals import rms
from sim.logio import row_of
from sim.motor_torque import CurrentToTorqueMap
from sim.runlog import HOLD_END, TIME_CONVENTIONS, RunLog

PEAK_TOLERANCE = 0.01  # commands may exceed the rig's peak effort by 1 % (rounding in the log)
WRAP_TOLERANCE = 0.1  # a step within 10 % of 2π ...
WRAP_STEP_RATIO = 50.0  # ... and 50 x the median nonzero step is a wrap
LOCKED_MOTION_RAD = 0.05  # a locked lever turns by less than 0.05 rad (3°: the load cell's full deflection is ~0.1°)
MAX_EFFORT_RATIO = 3.0  # the baseline's effort error may not exceed 3 x the command (RMS) ...
MAX_INERTIAL_SCALE = 3.0  # ... unless the logged effort matches the rig's inertial terms within this factor
POSITION_COLUMNS = ("q", "q_motor")
ASSUMED_CONVENTION = "assumed: neither the rig nor the log states it"  # where the time convention comes from


class InputError(ValueError):
    """A log that the rig cannot have produced, or that is not what its columns claim; ``column`` and ``row``
    name where (row: spreadsheet numbering, the header is row 1)."""

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None) -> None:
        super().__init__(message)
        self.column, self.row = column, row


def peak_command(rig: Rig) -> float:
    """The largest command the rig accepts [N·m | N] (inf if it states none)."""
    if rig.model == "testbed":
        assert rig.params is not None
        return CurrentToTorqueMap.from_params(rig.params).command_limit_nm
    return rig.rigid.get("peak_effort", math.inf)


def time_convention(log: RunLog, rig: Rig) -> tuple[str, str]:
    """(convention, where it comes from): the rig's ``time_convention``, the log's metadata, or the default
    ``hold_end``; a rig and a log that disagree are refused."""
    stated = log.meta.get("time_convention")
    if stated is not None and stated not in TIME_CONVENTIONS:
        raise InputError(f"the log's metadata says time_convention = {stated!r}; valid values are "
                         f"{', '.join(map(repr, TIME_CONVENTIONS))}")
    if rig.time_convention is not None:
        if stated is not None and stated != rig.time_convention:
            raise InputError(f"rig {rig.source} says time_convention = {rig.time_convention!r} but the log's "
                             f"metadata says {stated!r}")
        return rig.time_convention, f"rig {rig.source}"
    if stated is not None:
        return stated, "the log's metadata"
    return HOLD_END, ASSUMED_CONVENTION


def to_hold_end(log: RunLog, convention: str) -> RunLog:
    """``log`` in the hold-end convention: row k's state follows the commands up to row k.

    In the ``command`` convention row k holds the state measured when command k was computed, so command k acts
    after it: the state of row k + 1 is the first to follow it. Pairing each state with the command before it
    (and dropping the first row, whose preceding command is not in the log) is the same physics stamped at the
    end of each hold.
    """
    if convention == HOLD_END:
        return log
    columns = {name: np.asarray(values)[1:] for name, values in log.columns.items()}
    columns["tau_cmd"] = np.asarray(log["tau_cmd"])[:-1]
    return type(log)(columns, dict(log.units), {**log.meta, "time_convention": HOLD_END})


def check_log(log: RunLog, rig: Rig, *, unwrap: bool = False, filter_cutoff_hz: float) -> RunLog:
    """Refuse a log the rig cannot have produced (module docstring); return it, with its hinge angles unwrapped
    if ``unwrap``.

    Raises
    ------
    InputError
        Naming the column, the row and what was seen.
    """
    t = np.asarray(log["time"], dtype=float)
    dt = float(np.median(np.diff(t)))
    if dt >= 0.5 / filter_cutoff_hz:
        resampled = log.meta.get("mapping", {}).get("resampled_s")
        hint = (" The record was resampled to that step: choose a finer one (resample in the rig's [log] table)."
                if resampled else " Column 'time' looks like milliseconds: state its unit (units.time = \"ms\" in "
                "the rig's [log] table, or --log units.time=ms)." if 0.5 <= dt <= 2.0 else "")
        raise InputError(f"column 'time': the median sampling step is {dt:.6g} s ({1 / dt:.4g} Hz); the analysis "
                         f"band ({filter_cutoff_hz:g} Hz) needs at least {2 * filter_cutoff_hz:g} Hz.{hint}",
                         column="time")
    u = np.asarray(log["tau_cmd"], dtype=float)
    peak = peak_command(rig)
    worst = int(np.argmax(np.abs(u)))
    if abs(u[worst]) > (1.0 + PEAK_TOLERANCE) * peak:
        unit = log.units.get("tau_cmd", "")
        ratio = abs(u[worst]) / peak
        hint = (" Is the command in mN·m or mN?" if ratio > 100 else
                " Is the command in another unit, or is the rig's peak effort wrong?")
        where, row = located(log, worst)
        raise InputError(f"column 'tau_cmd', {where}: {u[worst]:.6g} {unit} is {ratio:.3g} x the rig's "
                         f"peak command {peak:.6g} {unit}; the rig cannot have applied it.{hint}",
                         column="tau_cmd", row=row)
    columns = dict(log.columns)
    if rig.joint == "hinge":
        for name in POSITION_COLUMNS:
            if name not in columns:
                continue
            q = np.asarray(columns[name], dtype=float)
            wraps = wrapped_steps(q)
            if len(wraps) and unwrap:
                columns[name] = np.unwrap(q)
            elif len(wraps):
                k = int(wraps[0])
                where, row = located(log, k + 1)
                raise InputError(f"column {name!r}, {where}: the angle jumps by {q[k + 1] - q[k]:+.4g} rad "
                                 f"in one sample ({len(wraps)} such jump(s)): an encoder wrapped to one turn? "
                                 f"Unwrap it (--unwrap)", column=name, row=row)
    if rig.model == "testbed" and rig.fixture == "locked" and "q" in columns:
        q = np.asarray(columns["q"], dtype=float)
        span = float(np.ptp(q))
        if span > LOCKED_MOTION_RAD:
            k = int(np.argmax(np.abs(q - q[0])))
            where, row = located(log, k)
            raise InputError(f"column 'q': the lever turns through {span:.3g} rad ({where} is "
                             f"{q[k] - q[0]:+.3g} rad from the first), but rig {rig.source} says fixture = 'locked' "
                             f"(at most {LOCKED_MOTION_RAD:g} rad); is it a free-fixture log?", column="q",
                             row=row)
    if columns is log.columns or all(columns[k] is log.columns[k] for k in columns):
        return log
    return type(log)(columns, dict(log.units), dict(log.meta))


def wrapped_steps(q: np.ndarray) -> np.ndarray:
    """Indices k where ``q[k+1] - q[k]`` is about ±2π and far above the typical step (a wrapped encoder)."""
    steps = np.diff(q)
    moving = np.abs(steps[steps != 0])
    if not len(moving):
        return np.zeros(0, dtype=int)
    typical = float(np.median(moving))
    near_turn = np.abs(np.abs(steps) - 2 * math.pi) < WRAP_TOLERANCE * 2 * math.pi
    return np.flatnonzero(near_turn & (np.abs(steps) > WRAP_STEP_RATIO * typical))


def located(log: RunLog, k: int) -> tuple[str, int | None]:
    """Where sample ``k`` of ``log`` is in its file, in words and as a row (spreadsheet numbering): the row, counted
    from the file's first for a span of a mapped record; for a resampled record, its time (no row of the file)."""
    mapping = log.meta.get("mapping", {})
    if mapping.get("resampled_s"):
        step_ms = 1e3 * mapping["resampled_s"]
        return f"at t = {float(log['time'][k]):.6g} s (the record resampled to {step_ms:g} ms)", None
    row = row_of(k + mapping.get("first_sample", 0))
    return f"row {row}", row


def check_effort_balance(model: Surrogate, theta: dict[str, float], effort_rmse: float) -> None:
    """Refuse a baseline that needs several times the logged effort to make the logged motion, when its inertial
    terms are what is out of scale.

    The balance may be far off for physics the rig lacks (a pendulum's weight on a rig that states none). A wrong
    unit scales the inertial and viscous terms instead: the effort the rest of the balance leaves is
    least-squares fitted by ``α`` times them plus the shapes of the common loads (a constant, a friction level,
    and a hinge's sin and cos of its angle) on the fit part, and a log is refused when the baseline's effort
    error exceeds MAX_EFFORT_RATIO x the command's RMS and ``α`` lies outside [1/MAX_INERTIAL_SCALE,
    MAX_INERTIAL_SCALE] (positions in degrees give α ≈ 1/57, in millimetres 1/1000; a command in mN·m 1000).
    A baseline whose effort error exceeds the command's RMS with ``α`` below -1/MAX_INERTIAL_SCALE has the effort's
    sign reversed against the position's, and is refused so.
    """
    d = model.data
    command_rms = rms(d.filt(d.u_full)[d.held])
    if not (command_rms > 0 and effort_rmse > command_rms):
        return
    residual = model.residuals(theta)["effort"]
    inertial = theta["inertia"] * d.acceleration + theta["viscous"] * d.velocity
    sliding = ~model.stuck
    shapes = [inertial, np.ones(len(d.t)), np.where(sliding, np.sign(d.velocity), 0.0)]
    if model.rig.joint == "hinge":
        angle = d.q if d.q is not None else d.position
        shapes += [np.sin(angle), np.cos(angle)]
    ok = d.fit & np.isfinite(residual)
    if ok.sum() <= len(shapes):
        return
    basis = np.column_stack([shape[ok] for shape in shapes])
    scale = np.maximum(np.abs(basis).max(axis=0), 1e-300)
    coef, *_ = np.linalg.lstsq(basis / scale, (residual + inertial)[ok], rcond=None)
    alpha = coef[0] / scale[0]
    unit = channel_unit("effort", model.rig.joint)
    said = (f"the rig cannot produce the logged motion with the logged effort: the baseline's effort error is "
            f"{effort_rmse:.4g} {unit} RMS, {effort_rmse / command_rms:.3g} x the command's {command_rms:.4g} {unit}, "
            f"and the logged effort matches {alpha:.3g} x the rig's inertial terms")
    if alpha <= -1.0 / MAX_INERTIAL_SCALE:
        raise InputError(f"{said}: the effort's sign is reversed against the position's. Reverse one of them "
                         f"(a minus in the rig's [log] table: columns.tau_cmd = \"-NAME\", or --log "
                         f"columns.tau_cmd=-NAME)", column="tau_cmd")
    if effort_rmse <= MAX_EFFORT_RATIO * command_rms or 1.0 / MAX_INERTIAL_SCALE <= alpha <= MAX_INERTIAL_SCALE:
        return
    position_unit = "m" if model.rig.joint == "slide" else "rad"
    raise InputError(f"{said}. Check the units of 'q' ({position_unit}; degrees or millimetres?), 'tau_cmd' ({unit}) "
                     f"and 'time' (s), and the rig's inertia or mass", column="q")
