"""The calibration rig of the paper (Sec. III-A, Figs. 5, 6 and 8(a)-(b)), simulated: schedules of applied moments and
the records they produce (sensor channel voltages beside the ATI MINI85 reference).

The sensor is bolted to the reference sensor and loaded with test weights on a lever: the loading is
quasi-static (seconds per step against a flexure mode of kHz), so the flexure twist is the applied torque over
K_t; the sensor's own hysteresis, noise and drift come from :class:`sensor.photoreflector.PhotoReflectorArray`.
:func:`check_params` refuses, before any run, a sensor parameter set that these protocols cannot calibrate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.gim8108_testbed.derived import derive
from sensor.calibration import E_MAX_FRACTION_FS, QUIET_TAU_THRESHOLD_NM
from sensor.photoreflector import PhotoReflectorArray, reference_torque
from sim.params import ParameterError, TestbedParams

# Paper Sec. III-B: test weights to about ±25 N·m, loading and unloading five times in each direction.
CALIBRATION_LEVELS_NM = (5.0, 10.0, 15.0, 20.0, 25.0)
CALIBRATION_CYCLES = 5
PRELOAD_CYCLES = 1  # per direction; a rate-independent slip state is set by one full excursion
PRELOAD_LABEL = -1  # ``cycle`` label of preload samples
# Assumed timing of placing weights by hand: a 0.5 s transition, then 2 s at rest on each level, and 5 s of
# no load between cycles (the quiet segments the QP penalises).
TRANSITION_S = 0.5
HOLD_S = 2.0
QUIET_S = 5.0
# Paper Sec. III-B: crosstalk moments T_x, T_y over about 25 N·m; resolution from 10 s at 1 kHz, no filtering.
CROSSTALK_LEVELS_NM = (5.0, 10.0, 15.0, 20.0, 25.0)
RESOLUTION_RECORD_S = 10.0
ADC_NOISE_MARGIN_SIGMA = 5.0  # check_params: a channel's swing plus this many noise stds must fit the ADC range
QUIET_NOISE_MARGIN_SIGMA = 5.0  # check_params: the MINI85 noise must sit this many stds inside the quiet threshold


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


def check_params(params: TestbedParams) -> None:
    """Refuse, before any run, a sensor parameter set whose fields are each in range but cannot work together.

    The checks are the constraints between fields that the simulated calibration rig needs (each raises
    :class:`sim.params.ParameterError` naming the field, its value, why, and the value that would work):

    * ADC range: over the calibration protocols (T_z to ±25 N·m, T_x and T_y to 25 N·m, at the reference
      temperature) every channel's noise-free voltage, widened by :data:`ADC_NOISE_MARGIN_SIGMA` noise stds,
      stays inside [0, ``adc_reference_v``]. A channel outside it is clipped by the ADC (a channel clipped
      throughout reads a constant and leaves the calibration rank-deficient).
    * Sensing-chain bandwidth: the first-order chain lags each 0.5 s ramp of the protocol (``R`` = the largest
      loading rate, 10 N·m/s) by ``R·dt·α/(1-α)`` (α = exp(-2π f_c dt), the ramp lag of the discrete chain,
      ≈ R/(2π f_c)), the opposite way loading and unloading; at equal voltages the two ramps then differ by
      twice the lag, so no static calibration keeps both within e_max (Eq. 14, 0.16 N·m) once the lag reaches
      it. Necessary, not sufficient: just above the limit the sensor's own hysteresis and noise can still
      make the QP infeasible, which :class:`sensor.calibration.InfeasibleCalibrationError` then reports.
    * MINI85 noise: ``reference_noise_nm`` at most 1/:data:`QUIET_NOISE_MARGIN_SIGMA` of the quiet-segment
      threshold (0.05 N·m), so the no-load samples read as no load and the QP's quiet segment (Eq. 12) is
      found; a noisier reference breaks it into fragments too short for the penalty.

    Parameters
    ----------
    params : TestbedParams
        The parameter set; the ``photoreflector``, ``flexure`` and ``simulation`` groups are read.

    Raises
    ------
    sim.params.ParameterError
        If a constraint fails; the message names the ``photoreflector.*`` field.
    """
    pr = params.photoreflector
    limit = QUIET_TAU_THRESHOLD_NM / QUIET_NOISE_MARGIN_SIGMA
    if pr.reference_noise_nm > limit:
        raise ParameterError(
            f"photoreflector.reference_noise_nm = {pr.reference_noise_nm:g} N·m: the MINI85's no-load readings "
            f"must stay within the quiet-segment threshold |tau| <= {QUIET_TAU_THRESHOLD_NM:g} N·m for the QP's "
            f"quiet segment (Eq. 12) to be found; at this noise they leave it every few samples. Valid with this "
            f"threshold: <= {limit:g} N·m ({QUIET_NOISE_MARGIN_SIGMA:g} noise stds inside it)")

    dt = params.simulation.control_period_s
    steps = [b - a for levels in (CALIBRATION_LEVELS_NM, CROSSTALK_LEVELS_NM)
             for a, b in zip((0.0, *levels[:-1]), levels, strict=True)]
    rate = max(abs(x) for x in steps) / TRANSITION_S
    alpha = math.exp(-2.0 * math.pi * pr.bandwidth_hz * dt)
    lag_nm = rate * dt * alpha / (1.0 - alpha)
    e_max_nm = E_MAX_FRACTION_FS * pr.full_scale_nm
    if lag_nm >= e_max_nm:
        k = e_max_nm / (rate * dt)                      # lag < e_max  <=>  alpha < k / (1 + k)
        f_min = -math.log(k / (1.0 + k)) / (2.0 * math.pi * dt)
        raise ParameterError(
            f"photoreflector.bandwidth_hz = {pr.bandwidth_hz:g} Hz: the sensing chain lags the calibration "
            f"protocol's {rate:g} N·m/s ramps by {lag_nm:.3g} N·m, one way loading and the other unloading, so "
            f"no calibration keeps every sample within the paper's e_max = {e_max_nm:g} N·m (Eq. 14); valid "
            f"range with {1 / dt:g} Hz sampling: > {f_min:.3g} Hz (the paper's chain: ~5 kHz, Table II)")

    lo, hi, op_lo, op_hi = _protocol_voltage_range(params)
    ref = pr.adc_reference_v
    if lo < 0.0:
        raise ParameterError(
            f"photoreflector.operating_point_v = {pr.operating_point_v:g} V (spread ±{pr.operating_point_spread_v:g}"
            f" V): a channel falls to {lo:.3g} V over the calibration protocols (±25 N·m, noise "
            f"±{ADC_NOISE_MARGIN_SIGMA:g} std included), below the ADC's 0 V floor, where it clips; raise "
            f"operating_point_v to at least {pr.operating_point_v - lo:.3g} V"
            + ("" if hi - lo <= ref else f", and photoreflector.adc_reference_v = {ref:g} V to at least "
               f"{hi - lo:.3g} V (the swing alone exceeds the ADC range)"))
    if hi > ref:
        below_op = (f"; it is below the operating points themselves ({op_lo:.3g}-{op_hi:.3g} V, "
                    f"photoreflector.operating_point_v = {pr.operating_point_v:g} V), so the ADC saturates at "
                    f"rest" if ref < op_hi else "")
        raise ParameterError(
            f"photoreflector.adc_reference_v = {ref:g} V: the channels reach {hi:.3g} V over the calibration "
            f"protocols (±25 N·m on operating points {op_lo:.3g}-{op_hi:.3g} V, noise ±{ADC_NOISE_MARGIN_SIGMA:g}"
            f" std included), and the ADC clips everything above its reference{below_op}. Valid with this "
            f"sensor: adc_reference_v >= {hi:.3g} V (the paper's ADC: 3.3 V)"
            + ("" if hi - lo > ref or pr.operating_point_v - (hi - ref) <= 0.0 else
               f", or photoreflector.operating_point_v lowered by {hi - ref:.3g} V to "
               f"{pr.operating_point_v - (hi - ref):.3g} V"))


def _protocol_voltage_range(params: TestbedParams) -> tuple[float, float, float, float]:
    """(lowest, highest) channel voltage [V] over the calibration protocols, widened by
    :data:`ADC_NOISE_MARGIN_SIGMA` noise stds, and the (lowest, highest) operating point [V] of the unit.

    T_z over ±25 N·m (the twist range widened by the largest slip the target's joint adds), then T_x and T_y
    over 0-25 N·m at no twist, at the reference temperature, noise-free (:meth:`PhotoReflectorArray.ideal_voltages`).
    """
    pr = params.photoreflector
    array = PhotoReflectorArray(params)
    span_rad = max(CALIBRATION_LEVELS_NM) / derive(params).flexure_stiffness_nm_per_rad
    span_rad += float(np.max(array.unit.slip_fraction, initial=0.0)) * pr.slip_twist_max_rad
    twist = np.linspace(-span_rad, span_rad, 401)
    moments = np.linspace(0.0, max(CROSSTALK_LEVELS_NM), 101)
    v = np.vstack([array.ideal_voltages(twist), array.ideal_voltages(np.zeros_like(moments), tx_nm=moments),
                   array.ideal_voltages(np.zeros_like(moments), ty_nm=moments)])
    margin = ADC_NOISE_MARGIN_SIGMA * array.unit.noise_v
    op = array.unit.operating_point_v
    return float(np.min(v - margin)), float(np.max(v + margin)), float(op.min()), float(op.max())
