"""Quantities measured by simulating the plant, the way one would measure them on the rig."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from sim.params import TestbedParams
from sim.plant import Plant, warn_mujoco_warnings
from sim.run import run_open_loop
from sim.runlog import RunLog

# Paper Sec. IV: breakaway = smallest command at which the motor velocity first exceeds a small threshold
# for a sustained duration (> 100 ms) under a ramp.
BREAKAWAY_SUSTAIN_S = 0.1
BREAKAWAY_VELOCITY_THRESHOLD_RAD_S = 0.01  # output side; assumed: "a small threshold"
BREAKAWAY_RAMP_NM_PER_S = 0.05  # slow enough that the 100 ms window adds only 0.005 N·m


@dataclass(frozen=True)
class Breakaway:
    """Breakaway torque [N·m] measured on a ramp in the free fixture, and when it happened [s].

    ``log`` is the ramp's run log up to the detection (plant signals every tick), when asked for.
    """

    torque_nm: float
    time_s: float
    ramp_nm_per_s: float
    log: RunLog | None = field(default=None, repr=False, compare=False)


def measure_breakaway(params: TestbedParams | None = None, *, sign: float = 1.0,
                      ramp_nm_per_s: float = BREAKAWAY_RAMP_NM_PER_S, keep_log: bool = False) -> Breakaway:
    """Ramp the motor command from zero in the free fixture until the motor moves for > 100 ms.

    ``keep_log``: also return the ramp's run log (``Breakaway.log``); the measurement is the same.
    """
    plant = Plant(params, "free")
    p = plant.params
    tick = p.simulation.control_period_s
    sustain_ticks = round(BREAKAWAY_SUSTAIN_S / tick)
    max_torque = min(p.motor.peak_torque_nm, 4.0 * p.friction.breakaway_torque_nm)
    n = math.ceil(max_torque / ramp_nm_per_s / tick)
    ramp = sign * ramp_nm_per_s * np.arange(1, n + 1) * tick
    moving_since: list[int] = []  # the tick the motor has been moving since (empty: at rest)
    broke_away: list[int] = []  # that tick, once the motion has lasted sustain_ticks

    def sustained(k: int, plant: Plant) -> bool:
        if abs(plant.motor_velocity_rad_s) <= BREAKAWAY_VELOCITY_THRESHOLD_RAD_S:
            moving_since.clear()
            return False
        moving_since[:] = moving_since or [k]
        if k - moving_since[0] >= sustain_ticks:
            broke_away.append(moving_since[0])
        return bool(broke_away)

    log = run_open_loop(plant, ramp, progress=False, stop=sustained,
                        meta={"experiment": "breakaway ramp", "ramp_nm_per_s": sign * ramp_nm_per_s})
    if not broke_away:
        raise RuntimeError(f"no breakaway below {max_torque:.3g} N·m: the gear never moved on the ramp")
    start = broke_away[0]
    return Breakaway(abs(float(ramp[start])), (start + 1) * tick, ramp_nm_per_s, log if keep_log else None)


@dataclass(frozen=True)
class BacklashMeasurement:
    """Dead band [rad] from the motor angle against the load-cell torque on both sides of a reversal.

    ``log`` is the reversal's run log (plant signals every tick), when asked for.
    """

    width_rad: float
    compliance_rad_per_nm: float
    log: RunLog | None = field(default=None, repr=False, compare=False)


def measure_backlash(params: TestbedParams | None = None, *, amplitude_nm: float = 2.0,
                     period_s: float = 4.0, keep_log: bool = False) -> BacklashMeasurement:
    """Slow triangular torque reversal in the locked fixture.

    With a stop closed, q_motor = τ_lc·(1/K_t + 1/k_lc) ± gap/2 whatever the gear friction (it acts between
    gear and ground). Lines fitted to the loaded part of each branch (|τ_lc| in 30-90 % of the amplitude)
    meet τ = 0 a gap apart. ``keep_log``: also return the reversal's run log (``BacklashMeasurement.log``);
    the measurement is the same.
    """
    plant = Plant(params, "locked")
    tick = plant.params.simulation.control_period_s
    t = np.arange(1, round(1.5 * period_s / tick) + 1) * tick
    phase = (t / period_s) % 1.0
    triangle = amplitude_nm * (1.0 - 4.0 * np.abs(phase - 0.5))  # -A at t=0, +A at T/2
    log = run_open_loop(plant, triangle, progress=False,
                        meta={"experiment": "backlash reversal", "amplitude_nm": amplitude_nm, "period_s": period_s})
    q_motor, tau_lc = log["q_motor"], log["force_loadcell"] * plant.params.lever.length_m
    settle = t > 0.25 * period_s  # skip the start-up from rest
    fits = []
    for side in (1.0, -1.0):
        sel = settle & (side * tau_lc > 0.3 * amplitude_nm) & (side * tau_lc < 0.9 * amplitude_nm)
        fits.append(np.polyfit(tau_lc[sel], q_motor[sel], 1))
    (slope_pos, icpt_pos), (slope_neg, icpt_neg) = fits
    return BacklashMeasurement(icpt_pos - icpt_neg, 0.5 * (slope_pos + slope_neg), log if keep_log else None)


@dataclass(frozen=True)
class Mode:
    """One oscillatory mode of the linearised plant."""

    frequency_hz: float  # damped frequency Im(λ)/2π
    natural_frequency_hz: float  # |λ|/2π
    damping_ratio: float  # -Re(λ)/|λ|

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def settle_under_preload(plant: Plant, preload_nm: float, duration_s: float = 0.5) -> None:
    """Hold a constant motor torque until the plant is at rest (locked fixture: a closed backlash stop)."""
    run_open_loop(plant, np.full(round(duration_s / plant.params.simulation.control_period_s), preload_nm),
                  progress=False)


def linearizable_plant(params: TestbedParams | None, fixture: str, preload_nm: float,
                       timestep_s: float | None = None) -> Plant:
    """A plant at rest under a preload, made linearisable.

    Without the command delay: mjd_transitionFD does not support delays, and a delay on the command does
    not change the transition of the state under a held command. Without the load-dependent dry friction:
    a stuck dry-friction row has no small-signal linearisation (it acts as a stiff damper); the LuGre
    presliding spring and damper, which govern small motions of the gear, are kept.
    """
    params = (params or TestbedParams()).replace(motor={"command_delay_s": 0.0},
                                                 friction={"load_friction_coefficient": 0.0})
    plant = Plant(params, fixture, timestep_s=timestep_s)
    settle_under_preload(plant, preload_nm)
    return plant


def linearized_modes(plant: Plant, *, epsilon: float = 1e-7) -> list[Mode]:
    """Oscillatory modes of the plant's discrete transition at its current state (mjd_transitionFD).

    The per-physics-step transition matrix A (positions, velocities, activations) has eigenvalues μ; the
    continuous equivalents are λ = ln(μ)/h. Modes are returned by ascending frequency. The plant must have
    no command delay (see :func:`linearizable_plant`).
    """
    m, d = plant.model, plant.data
    nx = 2 * m.nv + m.na
    a = np.zeros((nx, nx))
    mujoco.mjd_transitionFD(m, d, epsilon, True, a, None, None, None)
    lam = np.log(np.linalg.eigvals(a).astype(complex)) / m.opt.timestep
    modes = [Mode(float(z.imag / (2 * math.pi)), float(abs(z) / (2 * math.pi)), float(-z.real / abs(z)))
             for z in lam if z.imag > 1e-6 * abs(z)]
    return sorted(modes, key=lambda mode: mode.frequency_hz)


def free_vibration_peak_hz(plant: Plant, *, duration_s: float = 2.0, kick_joint: str = "motor",
                           kick_rad_s: float = 0.01, band_hz: tuple[float, float] = (20.0, 2000.0)) -> float:
    """Kick a joint's velocity, record the flexure twist at every physics step, return the FFT peak [Hz].

    The spectrum is zero-padded (8x) and the peak refined by a parabola through the three top bins. Kick
    the 'flexure' when the backlash is open (a gear kick would not reach the flexure).
    """
    m, d = plant.model, plant.data
    d.qvel[m.joint(kick_joint).dofadr[0]] += kick_rad_s
    n = round(duration_s / m.opt.timestep)
    twist = np.empty(n)
    q_flex = m.joint("flexure").qposadr[0]
    for k in range(n):
        mujoco.mj_step(m, d)
        twist[k] = d.qpos[q_flex]
    warn_mujoco_warnings()
    twist -= twist.mean()
    nfft = 8 * n
    spectrum = np.abs(np.fft.rfft(twist * np.hanning(n), nfft))
    freqs = np.fft.rfftfreq(nfft, m.opt.timestep)
    band = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    i = np.flatnonzero(band)[np.argmax(spectrum[band])]
    y0, y1, y2 = np.log(spectrum[i - 1:i + 2])
    shift = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    if not (band[i - 1] and band[i + 1] and abs(shift) <= 1.0):
        raise ValueError(f"no spectral peak inside {band_hz} Hz: the response is not a free vibration there")
    return float(freqs[i] + shift * (freqs[1] - freqs[0]))


# [N·m] assumed: a flexure torque above this presses the hub on a backlash stop; 25x the output bearing's drag
# at 1 rad/s (friction.output_viscous_share x viscous_nms_per_rad at the defaults).
STOP_LOADED_NM = 0.05


def settle_against_stop(plant: Plant, torque_nm: float = 0.5, duration_s: float = 0.6) -> RunLog:
    """From ``plant``'s state (free fixture; from rest with the gap centred after a reset) the motor pushes with
    ``torque_nm`` [N·m] and a hand holds the lever with ``-torque_nm``, so the gear crosses the gap, strikes the
    hub and the chain comes to rest with the hub pressed on its stop. Returns the run log (every tick)."""
    if plant.fixture != "free":
        raise ValueError(f"plant.fixture = {plant.fixture!r}: the hub settles against its stop in the 'free' fixture")
    n = round(duration_s / plant.params.simulation.control_period_s)
    return run_open_loop(plant, np.full(n, torque_nm), np.full(n, -torque_nm), progress=False)


def backlash_rate_rad_s(log: RunLog) -> np.ndarray:
    """The hub's velocity against the gear [rad/s] over each tick of ``log`` (difference of backlash_angle)."""
    return np.diff(np.asarray(log["backlash_angle"])) / np.diff(np.asarray(log["time"]))


def stop_loaded(log: RunLog, loaded_nm: float = STOP_LOADED_NM) -> np.ndarray:
    """Per tick interval of ``log`` (as :func:`backlash_rate_rad_s`): whether the flexure torque exceeds
    ``loaded_nm`` [N·m] in magnitude at both ends, pressing the hub on a stop. Pressed, the hub moves with the
    gear, against it only as fast as the stop's compliance lets the changing load push it in; a hub that
    chatters on its stop leaves it every few physics steps."""
    tau = np.abs(np.asarray(log["tau_flexure"]))
    return (tau[1:] > loaded_nm) & (tau[:-1] > loaded_nm)
