"""The paper's sensor evaluation (Sec. III-B, Tables III-IV, the LS/QP resolution comparison), simulated.

One call calibrates a sensor unit on the simulated rig and evaluates it on fresh records of the same
protocols (a different noise draw from the calibration record, as a second session on the rig would give):

* calibration record (:func:`sensor.protocol.calibration_schedule`) -> LS (Eq. 11) and QP (Eq. 17, gamma by
  the paper's criterion) fits;
* evaluation record, same protocol -> max and RMS error against the MINI85, nonlinearity, hysteresis,
  repeatability of the QP calibration (the paper reports its proposed calibration);
* crosstalk records (T_x, T_y to 25 N·m) and a 10 s no-load record -> crosstalk and the 3-sigma
  resolution of both calibrations.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sensor import metrics
from sensor.calibration import (
    E_MAX_FRACTION_FS,
    MIN_QUIET_SAMPLES,
    Calibration,
    GammaSelection,
    InfeasibleCalibrationError,
    fit_least_squares,
    quiet_segment_mask,
    select_gamma,
)
from sensor.photoreflector import PhotoReflectorArray
from sensor.protocol import (
    CALIBRATION_CYCLES,
    PRELOAD_LABEL,
    RigRecord,
    calibration_schedule,
    check_params,
    crosstalk_schedule,
    record,
    resolution_schedule,
)
from sim.params import TestbedParams

# Noise streams of one evaluation, derived from its seed (numpy SeedSequence spawn keys).
_STREAMS = ("calibration", "calibration_moment_x", "calibration_moment_y", "evaluation", "crosstalk_x",
            "crosstalk_y", "resolution")


@dataclass(frozen=True)
class SensorEvaluation:
    """Calibrations and the paper's figures of merit for one sensor unit and one seed.

    ``figures`` maps a name to ``(value, unit)``; names: ``max_error_pct_fs``, ``rms_error_nm``,
    ``nonlinearity_pct_fs``, ``hysteresis_pct_fs``, ``repeatability_pct_fs``, ``crosstalk_tx_pct_fs``,
    ``crosstalk_ty_pct_fs``, ``ls_std_nm``, ``ls_resolution_3sigma_nm``, ``qp_std_nm``,
    ``qp_resolution_3sigma_nm``, ``qp_improvement``; for the alternative readings of the paper's figures
    ``max_error_level_means_pct_fs`` (max error on the mean of each test-weight hold), ``nonlinearity_nm``,
    ``hysteresis_nm``, ``repeatability_nm``, ``crosstalk_tx_nm``, ``crosstalk_ty_nm`` (those figures in N·m).
    """

    ls: Calibration
    qp: Calibration
    gamma_selection: GammaSelection
    figures: dict[str, tuple[float, str]]
    calibration_record: RigRecord = field(repr=False)
    evaluation_record: RigRecord = field(repr=False)
    crosstalk_records: dict[str, RigRecord] = field(repr=False)
    resolution_record: RigRecord = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the figures with units and both calibrations."""
        return {"figures": {k: {"value": v, "unit": u} for k, (v, u) in self.figures.items()},
                "ls": self.ls.to_dict(), "qp": self.qp.to_dict(),
                "gamma_selection": {"gammas": self.gamma_selection.gammas.tolist(),
                                    "criterion_nm2": self.gamma_selection.criterion_nm2.tolist(),
                                    "gamma": self.gamma_selection.gamma}}


@dataclass(frozen=True, eq=False)
class MeasuredCycles:
    """The evaluation session's samples that Table III's figures use: the five cycles each way (the preload
    cycles only set the slip state). ``reference_nm`` (MINI85) and ``output_nm`` (the calibration) [N·m],
    ``direction`` (+1 loading, -1 unloading, :func:`sensor.metrics.reference_direction`), ``cycle`` labels,
    ``hold`` labels of the test-weight holds (:func:`sensor.metrics.hold_labels`, -1 in transitions)."""

    reference_nm: np.ndarray
    output_nm: np.ndarray
    direction: np.ndarray
    cycle: np.ndarray
    hold: np.ndarray


def measured_cycles(evaluation_record: RigRecord, calibration: Calibration) -> MeasuredCycles:
    """The samples of ``evaluation_record`` outside the preload cycles, with ``calibration``'s output there."""
    rec = evaluation_record
    measured = rec.schedule.cycle != PRELOAD_LABEL
    return MeasuredCycles(rec.tau_reference_nm[measured], calibration.predict(rec.voltages_v)[measured],
                          metrics.reference_direction(rec.tau_reference_nm)[measured], rec.schedule.cycle[measured],
                          metrics.hold_labels(rec.schedule.level_nm)[measured])


# The paper's gamma criterion is RMSE^2 + lambda Var(tau_hat on I_0) with lambda left open ("e.g.").
# lambda = 9 weighs the squared 3-sigma resolution, (3 sigma)^2 = 9 Var, equally with the squared RMS error:
# both terms are then the squares of the two figures the paper reports, in N·m.
RESOLUTION_LAMBDA_WEIGHT = 9.0


def leading_quiet_segment(tau_ref_nm: np.ndarray) -> np.ndarray:
    """I_0: the first contiguous run of no-load samples (|tau| <= tau_th) of a calibration record.

    Only one no-load segment is used: later ones follow loading cycles of either sign and carry the
    remanent slip of the target's joint, an offset that would count as "noise" in a pooled variance and
    make the penalty fight hysteresis instead of noise.

    Parameters
    ----------
    tau_ref_nm : numpy.ndarray, shape (N,)
        Reference torque of the calibration record [N·m].

    Returns
    -------
    numpy.ndarray of bool, shape (N,)
        True on the first run of samples with ``|tau_ref| <= QUIET_TAU_THRESHOLD_NM``.

    Raises
    ------
    ValueError
        If that run is shorter than ``MIN_QUIET_SAMPLES`` (a noisy reference breaks it up; the parameter-set
        form of this is caught earlier by :func:`sensor.protocol.check_params`).
    """
    mask = quiet_segment_mask(tau_ref_nm)
    start = int(np.argmax(mask))
    rest = mask[start:]
    stop = len(mask) if rest.all() else start + int(np.argmin(rest))
    out = np.zeros_like(mask)
    out[start:stop] = True
    if stop - start < MIN_QUIET_SAMPLES:
        raise ValueError(f"the leading no-load segment has {stop - start} samples; the QP needs at least "
                         f"{MIN_QUIET_SAMPLES}: record a longer no-load segment before loading")
    return out


@dataclass(frozen=True)
class RigCalibration:
    """Both calibrations of one rig session: LS (Eq. 11) and QP (Eq. 17) with its gamma selection."""

    ls: Calibration
    qp: Calibration
    gamma_selection: GammaSelection


def calibrate(torque_record: RigRecord, moment_records: list[RigRecord], *, fs_nm: float) -> RigCalibration:
    """Fit LS and QP on the T_z loading record plus the T_x/T_y moment records (target T_z from the MINI85).

    The moment records are part of the calibration data: the paper uses the redundant channels to reduce
    crosstalk, which a fit can only do if it sees the off-axis moments.

    Parameters
    ----------
    torque_record : RigRecord
        The T_z loading record (:func:`sensor.protocol.calibration_schedule`); its leading no-load segment
        is the QP's quiet segment I_0. Voltages [V], MINI85 torque [N·m].
    moment_records : list of RigRecord
        The T_x / T_y moment records (T_z = 0), appended to the data; not part of I_0.
    fs_nm : float
        Full scale [N·m] (``photoreflector.full_scale_nm``): the QP's error bound is 0.2 % of it (Eq. 14).

    Returns
    -------
    RigCalibration
        LS (Eq. 11) and QP (Eq. 17; gamma by the paper's criterion with lambda = 9) on the same data.
    """
    records = [torque_record, *moment_records]
    v = np.vstack([r.voltages_v for r in records])
    y = np.concatenate([r.tau_reference_nm for r in records])
    quiet = np.concatenate([leading_quiet_segment(torque_record.tau_reference_nm)]
                           + [np.zeros(len(r.tau_reference_nm), dtype=bool) for r in moment_records])
    selection = select_gamma(v, y, quiet_mask=quiet, lambda_weight=RESOLUTION_LAMBDA_WEIGHT,
                             e_max_nm=E_MAX_FRACTION_FS * fs_nm, fs_nm=fs_nm)
    return RigCalibration(fit_least_squares(v, y, fs_nm=fs_nm), selection.calibration, selection)


def _repeatability_per_series(ref: np.ndarray, out: np.ndarray, cycle: np.ndarray, direction: np.ndarray,
                              fs_nm: float) -> metrics.RepeatabilityResult:
    """Repeatability within each series of five same-sign cycles: the worse of the two series' results.

    The repetitions of the paper's test are the five loadings in one direction; comparing a positive cycle's
    return to zero with a negative cycle's departure from it (they share the bins around 0 N·m) would count
    hysteresis as non-repeatability.
    """
    series = [(cycle >= 0) & (cycle < CALIBRATION_CYCLES), cycle >= CALIBRATION_CYCLES]
    return max((metrics.repeatability(ref[m], out[m], cycle[m], direction[m], fs_nm=fs_nm) for m in series),
               key=lambda r: r.max_spread_nm)


def resolution_gain(params: TestbedParams | None = None, seed: int = 0) -> tuple[float, float]:
    """The resolution comparison alone: LS and QP std on a 10 s no-load record after calibrating.

    The same records (calibration, moments, no load) as :func:`evaluate_sensor` for the same seed, without
    the evaluation session, so the ratio ``ls_std / qp_std`` equals its ``qp_improvement``.

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set (defaults if None); checked by :func:`sensor.protocol.check_params` first.
    seed : int
        Seed of every noise draw of the run.

    Returns
    -------
    tuple of float
        ``(ls_std_nm, qp_std_nm)`` [N·m], sample std (ddof = 1) of each calibration's output. Both are 0 for a
        noise-free sensor (``noise_min_v = noise_max_v = 0``: the quantised no-load voltages are constant), where
        the ratio is undefined: use :func:`improvement_ratio`, which gives NaN there.

    Raises
    ------
    sim.params.ParameterError
        If the sensor parameters cannot work together (:func:`sensor.protocol.check_params`).
    sensor.calibration.InfeasibleCalibrationError
        If no calibration meets the paper's error bound on the calibration record.
    """
    params = params or TestbedParams()
    run = _recorder(params, seed)
    _, rig = _calibrated(run, params.photoreflector.full_scale_nm)
    v = run("resolution", resolution_schedule).voltages_v
    return (metrics.resolution_3sigma(rig.ls.predict(v)).std_nm, metrics.resolution_3sigma(rig.qp.predict(v)).std_nm)


def _recorder(params: TestbedParams, seed: int):
    """``run(name, schedule_of) -> RigRecord``: one protocol recorded on the rig, each ``name`` with its own
    noise stream of ``seed`` (so the records do not depend on the order they are made in)."""
    check_params(params)
    seeds = dict(zip(_STREAMS, np.random.SeedSequence(seed).spawn(len(_STREAMS)), strict=True))

    def run(name: str, schedule_of) -> RigRecord:
        ss = seeds[name]
        array = PhotoReflectorArray(params, seed=ss.generate_state(1)[0])
        return record(schedule_of(array.sample_period_s), array, np.random.default_rng(ss))

    return run


def _calibrated(run, fs_nm: float) -> tuple[RigRecord, RigCalibration]:
    """The calibration record and both calibrations fitted on it with the moment records (full scale ``fs_nm``)."""
    cal_rec = run("calibration", calibration_schedule)
    moments = [run(f"calibration_moment_{axis}", lambda dt, a=axis: crosstalk_schedule(dt, a)) for axis in "xy"]
    return cal_rec, calibrate(cal_rec, moments, fs_nm=fs_nm)


def _crosstalk(calibration: Calibration, moment_records: dict[str, RigRecord],
               fs_nm: float) -> dict[str, metrics.CrosstalkResult]:
    """Crosstalk of ``calibration`` on each moment test of ``moment_records`` (axis -> record), tared on its
    no-load start."""
    return {axis: metrics.crosstalk(calibration.predict(r.voltages_v), tare_mask=r.schedule.branch == 0, fs_nm=fs_nm)
            for axis, r in moment_records.items()}


def _tz_only_crosstalk_pct_fs(cal_rec: RigRecord, moment_records: dict[str, RigRecord],
                              fs_nm: float) -> dict[str, float]:
    """Crosstalk [% FS] of the QP calibration fitted on the T_z loading record alone (no moment records); NaN
    where no such calibration meets the error bound."""
    try:
        qp = calibrate(cal_rec, [], fs_nm=fs_nm).qp
    except InfeasibleCalibrationError:
        return {axis: float("nan") for axis in moment_records}
    return {axis: c.crosstalk_pct_fs for axis, c in _crosstalk(qp, moment_records, fs_nm).items()}


def improvement_ratio(ls_std_nm: float, qp_std_nm: float) -> float:
    """The QP's resolution gain over LS, ``ls_std / qp_std`` [1]; NaN where it is undefined (a QP std of 0,
    as a noise-free sensor gives)."""
    return ls_std_nm / qp_std_nm if qp_std_nm > 0.0 else float("nan")


def evaluate_sensor(params: TestbedParams | None = None, seed: int = 0) -> SensorEvaluation:
    """Calibrate and evaluate the sensor unit of ``params`` (``photoreflector.unit_seed``).

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set (defaults if None); checked by :func:`sensor.protocol.check_params` first.
    seed : int
        Seed of every noise draw of the run (channels and MINI85), split into independent streams.

    Returns
    -------
    SensorEvaluation
        Both calibrations, the gamma selection, the records, and ``figures`` (name -> (value, unit): % FS,
        N·m, or 1 for ``qp_improvement``, which is NaN for a noise-free sensor whose QP std is 0).

    Raises
    ------
    sim.params.ParameterError
        If the sensor parameters cannot work together (:func:`sensor.protocol.check_params`).
    sensor.calibration.InfeasibleCalibrationError
        If no calibration meets the paper's error bound on the calibration record.
    """
    params = params or TestbedParams()
    fs = params.photoreflector.full_scale_nm
    run = _recorder(params, seed)
    cal_rec, rig = _calibrated(run, fs)
    ls, qp, selection = rig.ls, rig.qp, rig.gamma_selection

    ev = run("evaluation", calibration_schedule)
    m = measured_cycles(ev, qp)
    ref, out, direction = m.reference_nm, m.output_nm, m.direction
    err = metrics.error_metrics(out, ref, fs_nm=fs)
    nonlinearity = metrics.nonlinearity(ref, out, direction, fs_nm=fs)
    hysteresis = metrics.hysteresis(ref, out, direction, fs_nm=fs)
    repeatability = _repeatability_per_series(ref, out, m.cycle, direction, fs)
    xt = {axis: run(f"crosstalk_{axis}", lambda dt, a=axis: crosstalk_schedule(dt, a)) for axis in ("x", "y")}
    cross = _crosstalk(qp, xt, fs)
    cross_tz_only = _tz_only_crosstalk_pct_fs(cal_rec, xt, fs)
    res_rec = run("resolution", resolution_schedule)
    res_ls = metrics.resolution_3sigma(ls.predict(res_rec.voltages_v))
    res_qp = metrics.resolution_3sigma(qp.predict(res_rec.voltages_v))
    figures = {
        "max_error_pct_fs": (err.max_error_pct_fs, "% FS"),
        "rms_error_nm": (err.rms_error_nm, "N·m"),
        "nonlinearity_pct_fs": (nonlinearity.nonlinearity_pct_fs, "% FS"),
        "hysteresis_pct_fs": (hysteresis.hysteresis_pct_fs, "% FS"),
        "repeatability_pct_fs": (repeatability.repeatability_pct_fs, "% FS"),
        "crosstalk_tx_pct_fs": (cross["x"].crosstalk_pct_fs, "% FS"),
        "crosstalk_ty_pct_fs": (cross["y"].crosstalk_pct_fs, "% FS"),
        "ls_std_nm": (res_ls.std_nm, "N·m"),
        "ls_resolution_3sigma_nm": (res_ls.resolution_3sigma_nm, "N·m"),
        "qp_std_nm": (res_qp.std_nm, "N·m"),
        "qp_resolution_3sigma_nm": (res_qp.resolution_3sigma_nm, "N·m"),
        "qp_improvement": (improvement_ratio(res_ls.std_nm, res_qp.std_nm), "1"),
        # the same figures in N·m, and the max error on the holds' means: the paper's alternative readings
        "max_error_level_means_pct_fs": (metrics.error_metrics(out, ref, fs_nm=fs, groups=m.hold).max_error_pct_fs,
                                         "% FS"),
        "nonlinearity_nm": (nonlinearity.max_deviation_nm, "N·m"),
        "hysteresis_nm": (hysteresis.max_difference_nm, "N·m"),
        "repeatability_nm": (repeatability.max_spread_nm, "N·m"),
        "crosstalk_tx_nm": (cross["x"].max_apparent_torque_nm, "N·m"),
        "crosstalk_ty_nm": (cross["y"].max_apparent_torque_nm, "N·m"),
        "crosstalk_tx_tz_only_pct_fs": (cross_tz_only["x"], "% FS"),
        "crosstalk_ty_tz_only_pct_fs": (cross_tz_only["y"], "% FS"),
    }
    return SensorEvaluation(ls, qp, selection, figures, cal_rec, ev, xt, res_rec)
