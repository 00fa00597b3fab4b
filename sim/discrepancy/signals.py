"""A run log prepared for the analysis: filtered derivatives, the load on the lever, the fit/held-out split.

Every term of the effort balance is passed through the same zero-phase low-pass filter (Butterworth,
``AnalysisConfig.filter_cutoff_hz``): differentiating quantised encoder angles twice is only meaningful in
a band, and filtering every linear term alike keeps the balance exact for them (the filter commutes with
linear terms; terms nonlinear in the raw signals, e.g. friction driven by the measured motion, are computed
from the raw signals first, then filtered).

The residuals are evaluated on the **analysis grid**: every ``grid_step``-th sample, four samples per period of
the filter's cut-off (100 Hz for a 1 kHz log and the default 25 Hz band). The filtered terms carry nothing
above the cut-off, so the grid loses no information the analysis uses, and a long log costs a tenth of the
evaluations. Raw signals stay at the log's rate where a term needs them (the command before a nonlinear map,
the motor angle driving the bristle state).

Logs joined into one (several runs of a rig, ``segments``) are filtered and differentiated each on its own: a
filter or a difference across the joint of two runs would spread the step between their last and first samples
into both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.signal import butter, sosfiltfilt

from models.gim8108_testbed.derived import derive
from sim.motor_torque import CurrentToTorqueMap
from sim.runlog import RunLog

if TYPE_CHECKING:
    from sim.discrepancy.rig import Rig

FILTER_ORDER = 4  # Butterworth order of the zero-phase low-pass (8 after filtfilt's two passes)
GRID_SAMPLES_PER_PERIOD = 4  # analysis grid: samples per period of the filter's cut-off
MIN_GUARDED_PARTS = 4  # a log must be this many filter guards long in each of the fit and held-out parts
MAX_ANALYSIS_SAMPLES = 200_000  # a rigid joint's longer log is analysed at a lower rate ...
MIN_RATE_OF_BAND = 10.0  # ... of at least this many samples per period of the analysis band
ANTI_ALIAS_OF_NYQUIST = 0.8  # the decimation's low-pass: this fraction of the lower rate's Nyquist frequency


@dataclass(frozen=True)
class AnalysisConfig:
    """Settings of the analysis, each with its unit and why.

    Attributes
    ----------
    filter_cutoff_hz : float
        Low-pass cut-off of every residual term [Hz]. Chosen: 25 Hz keeps the rigid-body and friction dynamics
        and removes the testbed's locked drivetrain mode (~60-110 Hz) and the noise of twice-differentiated
        encoder angles; the testbed's surrogate matches the MuJoCo plant best between 20 and 50 Hz.
    fit_fraction : float
        Leading fraction of a log used to fit [1]; the rest (contiguous) is held out (unless validation logs
        are given: then the whole log is fitted and the validation logs are held out).
    guard_s : float
        Samples within this time of either end of a part are left out [s]: the zero-phase filter's transient
        (about 2.5 periods of the cut-off).
    stick_velocity : float or None
        Below this filtered motor velocity a sample counts as stuck [rad/s | m/s]; None: 20 % of the
        Stribeck velocity of the testbed, or 1 % of the log's RMS velocity for a rigid joint.
    contact_torque : float
        The kinematic (backlash) channel uses samples transmitting more than this torque [N·m]: below it the
        hub may float inside the dead band.
    min_relative_gain : float
        Significance: an effect is accepted only if some channel's held-out RMSE falls by at least this
        fraction of the current model's [1]. Above what the surrogate's own mismatch with a simulated plant lets
        a wrong effect win on logs of the rig itself (up to ~6 %), below the gain of the weakest hidden effect of
        the tested ranges (~13 %).
    min_parameter_change : float
        Significance, for a parameter the model already carries: it must move by at least this fraction of
        its current value [1], measured from what the same fit gives on the model's own log
        (:mod:`sim.discrepancy.null`: the estimator's bias is not a discrepancy). 5 %: the tolerance within
        which the analysis recovers well-excited parameters, so a smaller change is not one it can state.
    min_ic_drop : float
        Significance: the held-out BIC must fall by more than this [1] (10: "very strong" evidence on Kass &
        Raftery's scale).
    min_effort_change : float
        Size: an effect on the effort must change the held-out effort prediction by at least this fraction of
        the command's RMS [1]. 0.5 %: above the surrogate's mismatch with simulated plants of the same physics
        (0.1-0.4 % of the command on clean logs of MuJoCo and of an independent stick-slip simulator), where a
        wrong effect could otherwise explain a large share of a tiny residual.
    max_remainder : float
        The final model's held-out effort error may be at most this fraction of the command's RMS [1] before the
        remainder is called unexplained, whatever its shape. 1 %: correct models of simulated plants leave
        0.1-0.6 % (MuJoCo and an independent stick-slip simulator, every excitation), models missing an effect
        outside the library 1.2-10 %.
    min_event_z : float
        Significance, robustness: the held-out improvement, summed per block of ``block_s`` and studentised over
        the blocks, must reach this [1] (one-sided; see :mod:`sim.discrepancy.selection`).
    block_s : float
        Length of the blocks of that test [s]: longer than the residual's correlation after the filter
        (±60 ms at a motion reversal), short enough for tens of blocks in a held-out part of a few seconds.
    max_stability_z : float
        Stationarity: a parameter fitted on the held-out part alone may differ from its fit-part value by at
        most this many combined standard errors [1] or :attr:`stability_tolerance` of its value, whichever is
        larger; otherwise the effect does not hold across the log and is not accepted.
    stability_tolerance : float
        See :attr:`max_stability_z` [1]. 20 %: the surrogate's estimate of a right effect moves by up to ~12 %
        between parts of different frequency content (a dead time on the two halves of a chirp), while a
        stand-in for an effect outside the library drifts further.
    replay_window_s : float
        Length of the MuJoCo replay windows, each re-initialised from the measured state [s].
    workers : int
        Processes for the candidate fits (1: in this process; each worker runs one BLAS thread).
    ray : str or None
        A Ray cluster for the candidate fits (``"local"``: start one on this machine; an address; ``"auto"``),
        instead of ``workers`` local processes (:class:`sim.executor.Executor`).
    model_log_seed : int
        Seed of the noise drawn for the model's own log (:mod:`sim.discrepancy.null`).
    max_effects : int
        At most this many effects are added to one model.
    """

    filter_cutoff_hz: float = 25.0
    fit_fraction: float = 0.6
    guard_s: float = 0.1
    stick_velocity: float | None = None
    contact_torque: float = 0.05
    min_relative_gain: float = 0.10
    min_parameter_change: float = 0.05
    min_ic_drop: float = 10.0
    min_effort_change: float = 0.005
    max_remainder: float = 0.01
    min_event_z: float = 2.33
    block_s: float = 0.5
    max_stability_z: float = 4.0
    stability_tolerance: float = 0.2
    replay_window_s: float = 0.5
    workers: int = 1
    ray: str | None = None
    model_log_seed: int = 0
    max_effects: int = 6

    def __post_init__(self) -> None:
        for name, low, high in (("filter_cutoff_hz", 0.0, np.inf), ("fit_fraction", 0.1, 0.9),
                                ("guard_s", 0.0, np.inf), ("contact_torque", 0.0, np.inf),
                                ("min_relative_gain", 0.0, 1.0), ("min_parameter_change", 0.0, 1.0),
                                ("min_ic_drop", 0.0, np.inf), ("min_effort_change", 0.0, 1.0),
                                ("max_remainder", 0.0, np.inf),
                                ("min_event_z", -np.inf, np.inf),
                                ("block_s", 0.0, np.inf), ("max_stability_z", 0.0, np.inf),
                                ("stability_tolerance", 0.0, np.inf),
                                ("replay_window_s", 0.0, np.inf)):
            value = getattr(self, name)
            if not (low <= value <= high) or (name in ("filter_cutoff_hz", "replay_window_s", "block_s")
                                              and value == 0):
                raise ValueError(f"{name} = {value!r}: valid range [{low:g}, {high:g}]")
        if self.ray is not None and (not isinstance(self.ray, str) or not self.ray):
            raise ValueError(f"ray = {self.ray!r}: None, 'local', 'auto' or a cluster's address")
        for name in ("workers", "max_effects"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} = {getattr(self, name)}: valid range [1, inf)")

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Prepared:
    """The log's signals as the surrogate needs them (SI; N·m or N, rad or m by joint).

    Full-rate arrays have the log's length N; grid arrays (suffix-free, the analysis grid) have one value
    per ``grid_step`` samples. Absent signals are None.
    """

    t_full: np.ndarray  # [s]
    dt: float  # median sampling step [s]
    grid: np.ndarray  # indices of the analysis grid in the full-rate arrays
    u_full: np.ndarray  # logged effort command [N·m | N]
    position_full: np.ndarray  # motor-side position, raw [rad | m]
    step_velocity: np.ndarray  # backward difference of position, full rate [rad/s | m/s]
    velocity_full: np.ndarray  # filtered motor-side velocity, full rate [rad/s | m/s]
    acceleration_full: np.ndarray  # filtered motor-side acceleration, full rate [rad/s² | m/s²]
    t: np.ndarray  # grid time [s]
    u: np.ndarray  # command on the grid, raw [N·m | N]
    position: np.ndarray  # motor-side position on the grid, filtered [rad | m]
    velocity: np.ndarray  # filtered velocity [rad/s | m/s]
    acceleration: np.ndarray  # filtered acceleration [rad/s² | m/s²]
    q: np.ndarray | None  # output (lever) angle [rad], filtered
    lever_acceleration: np.ndarray | None  # [rad/s²], filtered
    tau_loadcell: np.ndarray | None  # load-cell torque at the axis, force x lever length [N·m], filtered
    tau_sensor: np.ndarray | None  # joint torque sensor [N·m], filtered
    temperature: np.ndarray | None  # [°C], filtered
    fit: np.ndarray  # bool mask of the fit part on the grid (guards excluded)
    held: np.ndarray  # bool mask of the held-out part on the grid (guards excluded)
    split_time: float  # [s]
    sos: np.ndarray  # the low-pass filter
    load_source: str  # 'loadcell', 'inertia', 'sensor' or 'none': how the transmitted torque is known
    position_resolution: float  # smallest nonzero step of the position [rad | m]
    hold_s: float  # how long each logged command was held [s] (the log's step, unless decimated)
    has_motor_encoder: bool  # the log has q_motor (the position is the motor's, not the lever's)
    band_fraction: float  # 2·f_c/f_s: independent samples per full-rate sample in the filtered band [1]
    bounds: tuple[tuple[int, int], ...] = ()  # full-rate [start, stop) of each joined log (empty: one log)

    @property
    def grid_step(self) -> int:
        return int(self.grid[1] - self.grid[0]) if len(self.grid) > 1 else 1

    @property
    def independent_per_grid_sample(self) -> float:
        """Independent samples per grid sample in the filtered band [1]."""
        return min(1.0, self.band_fraction * self.grid_step)

    def per_log(self, fn, x: np.ndarray) -> np.ndarray:
        """``fn`` applied to each joined log's part of a full-rate signal, the parts joined again."""
        return per_log(fn, x, self.bounds)

    def filt(self, x: np.ndarray) -> np.ndarray:
        """The zero-phase low-pass of a full-rate signal, on the analysis grid."""
        return self.filt_full(x)[self.grid]

    def filt_full(self, x: np.ndarray) -> np.ndarray:
        """The zero-phase low-pass of a full-rate signal, at full rate (each joined log on its own)."""
        return self.per_log(lambda part: sosfiltfilt(self.sos, part), x)

    def derivative(self, x: np.ndarray) -> np.ndarray:
        """:func:`derivative` of a full-rate signal [x's unit/s], each joined log on its own."""
        return self.per_log(lambda part: derivative(part, self.dt), x)

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """``np.gradient`` of a full-rate signal [x's unit/s] (second-order central differences), each joined log
        on its own."""
        return self.per_log(lambda part: np.gradient(part, self.dt), x)

    def sine_gain(self, frequency_hz: float) -> float:
        """Gain of the zero-phase filter on a sine of ``frequency_hz`` [1] (|H|², no phase)."""
        from scipy.signal import sosfreqz

        _, h = sosfreqz(self.sos, worN=[frequency_hz], fs=1.0 / self.dt)
        return float(abs(h[0]) ** 2)


def derivative(x: np.ndarray, dt: float) -> np.ndarray:
    """d/dt of a smooth (band-limited) signal sampled every ``dt`` [x's unit/s]: the fourth-order central
    difference (relative error (ω·dt)⁴/30: 1e-5 at 20 Hz and 1 kHz, where the second-order one of
    ``np.gradient`` is (ω·dt)²/6 = 0.26 %, an inertia error that grows with frequency), second order within two
    samples of either end."""
    x = np.asarray(x, dtype=float)
    out = np.gradient(x, dt)
    if len(x) >= 5:
        out[2:-2] = (x[:-4] - 8.0 * x[1:-3] + 8.0 * x[3:-1] - x[4:]) / (12.0 * dt)
    return out


def per_log(fn, x: np.ndarray, bounds: tuple[tuple[int, int], ...]) -> np.ndarray:
    """``fn`` (array -> array of the same length) applied to ``x[a:b]`` for each of ``bounds`` ([start, stop)
    of the joined logs, covering ``x``; empty: ``x`` is one log), the results joined."""
    x = np.asarray(x, dtype=float)
    if len(bounds) <= 1:
        return fn(x)
    return np.concatenate([fn(x[a:b]) for a, b in bounds])


def smallest_step(x: np.ndarray) -> float:
    """Smallest nonzero step between consecutive samples [x's unit] (0 for a constant signal): an encoder's
    resolution read from its log."""
    steps = np.abs(np.diff(np.asarray(x, dtype=float)))
    steps = steps[steps > 0]
    return float(steps.min()) if len(steps) else 0.0


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """``x`` rounded to multiples of ``step`` [x's unit] (an encoder of that resolution)."""
    return np.round(x / step) * step


def decimation_factor(samples: int, dt: float, config: AnalysisConfig, rig: Rig) -> int:
    """How many samples of a rigid joint's log of ``samples`` at step ``dt`` [s] make one sample of the analysis:
    1 up to MAX_ANALYSIS_SAMPLES, else as many as keep MIN_RATE_OF_BAND samples per period of the band (the
    testbed keeps every sample: its bristle state follows the motor encoder's every count)."""
    if rig.model == "testbed" or samples <= MAX_ANALYSIS_SAMPLES:
        return 1
    most = int(1.0 / (dt * MIN_RATE_OF_BAND * config.filter_cutoff_hz))
    return max(1, min(math.ceil(samples / MAX_ANALYSIS_SAMPLES), most))


def decimate(log: RunLog, factor: int, bounds: tuple[tuple[int, int], ...] = ()) -> RunLog:
    """Every column of ``log`` low-passed below the lower rate's Nyquist frequency (zero-phase; each of the joined
    logs of ``bounds`` on its own, see :func:`per_log`) and every ``factor``-th sample kept: what lies above the
    analysis band goes, the band stays."""
    t = np.asarray(log["time"], dtype=float)
    dt = float(np.median(np.diff(t)))
    sos = butter(FILTER_ORDER, ANTI_ALIAS_OF_NYQUIST * 0.5 / (dt * factor), fs=1.0 / dt, output="sos")
    low_pass = lambda part: sosfiltfilt(sos, part)  # noqa: E731
    columns = {name: (t if name == "time" else per_log(low_pass, values, bounds))[::factor].copy()
               for name, values in log.columns.items()}
    return type(log)(columns, dict(log.units), dict(log.meta))


def minimum_samples(config: AnalysisConfig, dt: float) -> int:
    """Fewest samples a log at step ``dt`` [s] needs: each of the fit and held-out parts ``MIN_GUARDED_PARTS``
    times the two filter guards, and a few periods of the filter's cut-off."""
    return int(MIN_GUARDED_PARTS * (2 * config.guard_s / dt)) + 20


def grid_step(config: AnalysisConfig, dt: float) -> int:
    """Samples between analysis-grid points for a log at step ``dt`` [s]."""
    return max(1, int(1.0 / (GRID_SAMPLES_PER_PERIOD * config.filter_cutoff_hz * dt)))


Segment = tuple[int, int, float]  # a log within a concatenation: [start, stop) samples, its fit fraction


def prepare(log: RunLog, rig: Rig, config: AnalysisConfig, *, segments: list[Segment] | None = None,
            hold_s: float | None = None, resolution: float | None = None) -> Prepared:
    """Filter and differentiate the log's signals, choose the load source, split fit and held-out parts.

    ``hold_s`` is how long each logged command was held [s] (default: the log's step; a decimated log keeps the
    original's), ``resolution`` the position encoder's step (default: the log's smallest step).

    ``segments`` are the logs a concatenated ``log`` holds (default: one, split at ``config.fit_fraction``): each
    is split into a leading fit part (its fraction; 1.0 fits the whole log, an estimation record whose
    validation records are held out; 0.0 holds it all out, a validation record) and a held-out part, with the
    filter guards at every edge.
    """
    t = np.asarray(log["time"], dtype=float)
    n = len(t)
    dt = float(np.median(np.diff(t)))
    fs = 1.0 / dt
    if config.filter_cutoff_hz >= 0.5 * fs:
        raise ValueError(f"the log is sampled every {dt:.6g} s ({fs:.4g} Hz): the analysis band "
                         f"({config.filter_cutoff_hz:g} Hz) needs at least {2 * config.filter_cutoff_hz:g} Hz; "
                         f"if column 'time' is in milliseconds, convert it to seconds")
    needed = minimum_samples(config, dt)
    if n < needed:
        raise ValueError(f"the log has {n} samples ({n * dt:.3g} s); the analysis needs at least {needed} "
                         f"({needed * dt:.3g} s: four times the {config.guard_s} s filter guards at both ends of "
                         f"the fit and held-out parts)")
    sos = butter(FILTER_ORDER, config.filter_cutoff_hz, fs=fs, output="sos")
    step = grid_step(config, dt)
    grid = np.arange(0, n, step)
    cols = log.columns
    has = cols.__contains__
    testbed = rig.model == "testbed"
    position = np.asarray(cols["q_motor"] if testbed and has("q_motor") else cols["q"], dtype=float)
    segments = segments or [(0, n, config.fit_fraction)]
    bounds = tuple((a, b) for a, b, _ in segments) if len(segments) > 1 else ()
    if bounds and (bounds[0][0] != 0 or bounds[-1][1] != n
                   or any(b != a for (_, b), (a, _) in zip(bounds[:-1], bounds[1:], strict=True))):
        raise ValueError(f"segments {bounds} must cover the log's {n} samples, each starting where the last ends")

    def full(x) -> np.ndarray:
        return per_log(lambda part: sosfiltfilt(sos, part), x, bounds)

    def diff(x) -> np.ndarray:
        return per_log(lambda part: derivative(part, dt), x, bounds)

    pos_f = full(position)
    velocity = diff(pos_f)
    acceleration = diff(velocity)
    step_velocity = np.empty(n)
    step_velocity[1:] = np.diff(position) / dt
    step_velocity[[start for start, _, _ in segments]] = 0.0  # no motion across the joint of two logs
    q = lever_acc = tau_lc = None
    if has("q"):
        q_f = full(cols["q"])
        q, lever_acc = q_f[grid], diff(diff(q_f))[grid]
    elif testbed:
        lever_acc = acceleration[grid]
    if testbed and has("force_loadcell"):
        assert rig.params is not None
        tau_lc = full(np.asarray(cols["force_loadcell"]) * rig.params.lever.length_m)[grid]
    tau_s = full(cols["tau_sensor"])[grid] if has("tau_sensor") else None
    temperature = full(cols["temperature"])[grid] if has("temperature") else None
    if not testbed:
        load_source = "none"
    elif tau_lc is not None:
        load_source = "loadcell"
    elif rig.fixture == "free":
        load_source = "inertia"
    else:
        load_source = "sensor"
    guard = int(round(config.guard_s / dt))
    fit, held = np.zeros(len(grid), dtype=bool), np.zeros(len(grid), dtype=bool)
    for start, stop, fraction in segments:
        split = start + int(round(fraction * (stop - start)))
        fit |= (grid >= start + guard) & (grid < split - guard)
        held |= (grid >= split + guard) & (grid < stop - guard)
    split = min(segments[0][0] + int(round(segments[0][2] * (segments[0][1] - segments[0][0]))), n - 1)
    u = np.asarray(cols["tau_cmd"], dtype=float)
    return Prepared(t_full=t, dt=dt, grid=grid, u_full=u, position_full=position, step_velocity=step_velocity,
                    velocity_full=velocity, acceleration_full=acceleration, t=t[grid], u=u[grid], position=pos_f[grid],
                    velocity=velocity[grid], acceleration=acceleration[grid], q=q, lever_acceleration=lever_acc,
                    tau_loadcell=tau_lc, tau_sensor=tau_s, temperature=temperature, fit=fit, held=held,
                    split_time=float(t[split]), sos=sos, load_source=load_source,
                    position_resolution=smallest_step(position) if resolution is None else resolution,
                    hold_s=dt if hold_s is None else hold_s, has_motor_encoder=has("q_motor"),
                    band_fraction=min(1.0, 2.0 * config.filter_cutoff_hz * dt), bounds=bounds)


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
            "gear_ratio": p.motor.gear_ratio, "output_inertia": d.output_inertia_kgm2}


def rms(x: np.ndarray) -> float:
    """Root mean square of the finite entries of ``x`` (0 if none) [x's unit]."""
    x = x[np.isfinite(x)]
    return float(math.sqrt(np.mean(x * x))) if len(x) else 0.0


SECOND_DIFFERENCE_GAIN = math.sqrt(6.0)  # std of x[k+1] - 2 x[k] + x[k-1] for white x of unit std
MAD_TO_STD = 1.4826  # median absolute deviation -> standard deviation of a normal distribution


def white_noise_std(x: np.ndarray) -> float:
    """Standard deviation of the white noise on a smooth signal sampled well above its bandwidth [x's unit].

    From the median absolute second difference (robust to the few large steps of impacts and transitions);
    the smooth part's second difference is negligible at 1 kHz for signals below ~20 Hz.
    """
    d2 = np.diff(np.asarray(x, dtype=float), 2)
    if len(d2) == 0:
        return 0.0
    return float(MAD_TO_STD * np.median(np.abs(d2 - np.median(d2))) / SECOND_DIFFERENCE_GAIN)
