"""A run log prepared for the analysis: filtered derivatives, the load on the lever, the fit/held-out split.

Every term of the effort balance is passed through the same zero-phase low-pass filter (Butterworth,
``AnalysisConfig.filter_cutoff_hz``): differentiating quantised encoder angles twice is only meaningful in
a band, and filtering every linear term alike keeps the balance exact for them (the filter commutes with
linear terms; the friction terms are computed from the measured motion first, then filtered).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from models.gim8108_testbed.derived import derive
from sim.discrepancy.rig import Rig
from sim.motor_torque import CurrentToTorqueMap
from sim.runlog import RunLog

FILTER_ORDER = 4  # Butterworth order of the zero-phase low-pass (8 after filtfilt's two passes)


@dataclass(frozen=True)
class AnalysisConfig:
    """Settings of the analysis, each with its unit and why.

    Attributes
    ----------
    filter_cutoff_hz : float
        Low-pass cut-off of every residual term [Hz]. Chosen: 25 Hz keeps the rigid-body and friction dynamics
        and removes the locked drivetrain mode (~60-110 Hz) and the noise of twice-differentiated encoder
        angles; the baseline surrogate matches the MuJoCo plant best between 20 and 50 Hz (measured,
        tests/test_discrepancy.py).
    fit_fraction : float
        Leading fraction of the log used to fit [1]; the rest (contiguous) is held out.
    guard_s : float
        Samples within this time of either end of the log and of the split are left out [s]: the zero-phase
        filter's transient (about 2.5 periods of the cut-off).
    stick_velocity : float or None
        Below this filtered motor velocity a sample counts as stuck [rad/s | m/s]; None: 20 % of the
        Stribeck velocity of the testbed, or 1 % of the log's RMS velocity for a rigid joint.
    contact_torque : float
        The kinematic (backlash) channel uses samples transmitting more than this torque [N·m]: below it the
        hub may float inside the dead band.
    min_relative_gain : float
        Significance rule, second part: an effect is accepted only if some channel's held-out RMSE falls by at
        least this fraction [1]. Set above the spurious gains the surrogate's own mismatch with the MuJoCo plant
        offers on baseline logs (up to ~6 % on the effort channel, measured: a delay or Coulomb tweak absorbs
        part of it), below the smallest gain of a hidden effect in the tested ranges (~13 %).
    min_parameter_change : float
        Significance rule, third part: an effect the baseline already carries (all its parameters native to the
        baseline model and nonzero) is accepted only if one of them moves by at least this fraction of its
        current value [1], measured from the value the same fit gives on the model's own log
        (:mod:`sim.discrepancy.null`: the estimator's bias is not a discrepancy). 5 %: the tolerance within which
        the analysis recovers well-excited parameters
        (tests/test_discrepancy_sweep.py), so a smaller change is not one it can state. Needed with fine motor
        encoders: on the free swing's baseline logs with a 22-bit encoder (no quantisation floor under the
        residual) a Coulomb level 0.8 % above the baseline's gained 16 % held-out (measured, seeds 31-35).
    min_ic_drop : float
        Significance rule, first part: the held-out BIC must fall by more than this [1] (10: "very strong"
        evidence on Kass & Raftery's scale).
    min_consistency_t : float
        Significance rule, fourth part: the Diebold-Mariano statistic of the held-out improvement must reach
        this [1]. 2.33: one-sided 1 % (normal quantile). Measured on 10 s logs: baseline logs' spurious best
        candidates 1.0-2.3 (the free swing's reversal residual: <= 1.9), hidden effects 2.48 and above (Stribeck,
        whose evidence also sits at the reversals), most above 3.5.
    consistency_lag_s : float
        Lag window of the Newey-West variance in that statistic [s]. 0.2 s: a residual event at a motion
        reversal spreads over about ±60 ms after the 25 Hz filter; the window covers it with margin.
    replay_window_s : float
        Length of the MuJoCo replay windows, each re-initialised from the measured state [s].
    workers : int
        Processes for the candidate fits (1: in this process).
    model_log_seed : int
        Seed of the noise drawn for the model's own log (rule 3's reference, :mod:`sim.discrepancy.null`).
    """

    filter_cutoff_hz: float = 25.0
    fit_fraction: float = 0.6
    guard_s: float = 0.1
    stick_velocity: float | None = None
    contact_torque: float = 0.05
    min_relative_gain: float = 0.10
    min_parameter_change: float = 0.05
    min_ic_drop: float = 10.0
    min_consistency_t: float = 2.33
    consistency_lag_s: float = 0.2
    replay_window_s: float = 0.5
    workers: int = 1
    model_log_seed: int = 0

    def __post_init__(self) -> None:
        for name, low, high in (("filter_cutoff_hz", 0.0, np.inf), ("fit_fraction", 0.1, 0.9),
                                ("guard_s", 0.0, np.inf), ("contact_torque", 0.0, np.inf),
                                ("min_relative_gain", 0.0, 1.0), ("min_parameter_change", 0.0, 1.0),
                                ("min_ic_drop", 0.0, np.inf), ("min_consistency_t", -np.inf, np.inf),
                                ("consistency_lag_s", 0.0, np.inf),
                                ("replay_window_s", 0.0, np.inf)):
            value = getattr(self, name)
            if not (low <= value <= high) or (name in ("filter_cutoff_hz", "replay_window_s") and value == 0):
                raise ValueError(f"{name} = {value!r}: valid range [{low:g}, {high:g}]")
        if self.workers < 1:
            raise ValueError(f"workers = {self.workers}: valid range [1, inf)")

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Prepared:
    """The log's signals as the surrogate needs them (SI; N·m / N and rad / m by joint).

    Arrays have the log's length N. Absent signals are None.
    """

    t: np.ndarray  # [s]
    dt: float  # median sampling step [s]
    u: np.ndarray  # logged effort command [N·m | N]
    position: np.ndarray  # motor-side position driving friction and cogging [rad | m]
    step_velocity: np.ndarray  # backward difference of position [rad/s | m/s], drives the bristle state
    velocity: np.ndarray  # filtered velocity [rad/s | m/s]
    acceleration: np.ndarray  # filtered acceleration [rad/s² | m/s²]
    q: np.ndarray | None  # output (lever) angle [rad], filtered
    lever_acceleration: np.ndarray | None  # [rad/s²], filtered
    tau_loadcell: np.ndarray | None  # load-cell torque at the axis, force x lever length [N·m], filtered
    tau_sensor: np.ndarray | None  # joint torque sensor [N·m], filtered
    temperature: np.ndarray | None  # [°C], filtered
    fit: np.ndarray  # bool mask of the fit part (guards excluded)
    held: np.ndarray  # bool mask of the held-out part (guards excluded)
    split_time: float  # [s]
    sos: np.ndarray  # the low-pass filter
    load_source: str  # 'loadcell', 'inertia' or 'sensor': how the transmitted torque is known
    position_resolution: float  # smallest nonzero step of the position [rad | m]
    has_motor_encoder: bool  # the log has q_motor (the position is the motor's, not the lever's)
    band_fraction: float  # 2·f_c/f_s: independent samples per sample in the filtered band [1]

    @property
    def decimation(self) -> int:
        """Step between samples counted as independent in the filtered band [samples]."""
        return max(1, int(1.0 / self.band_fraction))

    def filt(self, x: np.ndarray) -> np.ndarray:
        """The zero-phase low-pass applied to every residual term."""
        return sosfiltfilt(self.sos, x)


def smallest_step(x: np.ndarray) -> float:
    """Smallest nonzero step between consecutive samples [x's unit] (0 for a constant signal): an encoder's
    resolution read from its log."""
    steps = np.abs(np.diff(np.asarray(x, dtype=float)))
    steps = steps[steps > 0]
    return float(steps.min()) if len(steps) else 0.0


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """``x`` rounded to multiples of ``step`` [x's unit] (an encoder of that resolution)."""
    return np.round(x / step) * step


def prepare(log: RunLog, rig: Rig, config: AnalysisConfig) -> Prepared:
    """Filter and differentiate the log's signals, choose the load source, split fit and held-out parts."""
    t = np.asarray(log["time"], dtype=float)
    n = len(t)
    dt = float(np.median(np.diff(t)))
    fs = 1.0 / dt
    if config.filter_cutoff_hz >= 0.5 * fs:
        raise ValueError(f"filter_cutoff_hz = {config.filter_cutoff_hz} Hz must be below the log's Nyquist "
                         f"frequency {0.5 * fs:g} Hz")
    min_samples = int(4 * (2 * config.guard_s / dt)) + 20
    if n < min_samples:
        raise ValueError(f"the log has {n} samples; the analysis needs at least {min_samples} (four times the "
                         f"filter guards of {config.guard_s} s at both ends of the fit and held-out parts)")
    sos = butter(FILTER_ORDER, config.filter_cutoff_hz, fs=fs, output="sos")
    cols = log.columns
    has = cols.__contains__
    if rig.model == "testbed":
        position = np.asarray(cols["q_motor"] if has("q_motor") else cols["q"], dtype=float)
    else:
        position = np.asarray(cols["q"], dtype=float)
    filt = lambda x: sosfiltfilt(sos, np.asarray(x, dtype=float))  # noqa: E731
    pos_f = filt(position)
    velocity = np.gradient(pos_f, dt)
    acceleration = np.gradient(velocity, dt)
    step_velocity = np.empty(n)
    step_velocity[1:] = np.diff(position) / dt
    step_velocity[0] = step_velocity[1]
    q = lever_acc = tau_lc = None
    if has("q"):
        q = filt(cols["q"])
        lever_acc = np.gradient(np.gradient(q, dt), dt)
    elif rig.model == "testbed":
        lever_acc = acceleration
    if rig.model == "testbed" and has("force_loadcell"):
        assert rig.params is not None
        tau_lc = filt(np.asarray(cols["force_loadcell"]) * rig.params.lever.length_m)
    tau_s = filt(cols["tau_sensor"]) if has("tau_sensor") else None
    temperature = filt(cols["temperature"]) if has("temperature") else None
    if rig.model != "testbed":
        load_source = "none"
    elif tau_lc is not None:
        load_source = "loadcell"
    elif rig.fixture == "free":
        load_source = "inertia"
    else:
        load_source = "sensor"
    split = int(config.fit_fraction * n)
    guard = int(round(config.guard_s / dt))
    index = np.arange(n)
    fit = (index >= guard) & (index < split - guard)
    held = (index >= split + guard) & (index < n - guard)
    resolution = smallest_step(position)
    return Prepared(t=t, dt=dt, u=np.asarray(cols["tau_cmd"], dtype=float), position=position,
                    step_velocity=step_velocity, velocity=velocity, acceleration=acceleration, q=q,
                    lever_acceleration=lever_acc, tau_loadcell=tau_lc, tau_sensor=tau_s, temperature=temperature,
                    fit=fit, held=held, split_time=float(t[split]), sos=sos, load_source=load_source,
                    position_resolution=resolution, has_motor_encoder=has("q_motor"), band_fraction=min(1.0, 2.0 * config.filter_cutoff_hz * dt))


def testbed_constants(rig: Rig) -> dict[str, float]:
    """Fixed quantities of the testbed surrogate, from the rig's parameters (SI)."""
    assert rig.params is not None
    p = rig.params
    d = derive(p)
    return {"lever_inertia": d.lever_side_inertia_kgm2, "flexure_stiffness": d.flexure_stiffness_nm_per_rad,
            "current_lag": p.motor.current_loop_time_constant_s,
            "torque_saturation": p.motor.torque_saturation_per_nm,
            "command_limit": CurrentToTorqueMap.from_params(p).command_limit_nm,
            "rotor_reflected_inertia": d.reflected_rotor_inertia_kgm2,
            "presliding_damping_ratio": p.friction.presliding_damping_ratio,
            "calibration_temperature": p.photoreflector.reference_temperature_c,
            "gear_ratio": p.motor.gear_ratio}
