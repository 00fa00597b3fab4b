"""Windowed replay of the held-out part through MuJoCo: the log's command into the baseline and extended rig.

Each window (``config.replay_window_s``) starts from the state the log measures at the sample before it, so an
integrating plant under closed-loop commands does not drift away, and the window's first command is the one the
log applied next:

* the flexure twist from the measured transmitted torque (τ/K_t), the LuGre bristle deflection the measured
  motor motion implies (:func:`measured_bristle_rad`), the drive's delay buffer holding the log's commands of
  the ticks before (as many as the longest dead time the analysis fits, ``effects.MAX_DELAY_S``) and, on the
  testbed, its current loop where they took it (:meth:`sim.plant.Plant.hold_commands`); a rigid joint:
  position and velocity;
* a rigid joint with drivetrain compliance: the spring deflected as the measured acceleration loads it;
* locked fixture: the lever where the load cell's deflection puts it, a loaded hub pressed into the stop its
  torque closes (as far as the stop's soft constraint yields, :func:`stop_compliance_rad_per_nm`), the motor
  behind them; velocities from the rates of the load and of the twist. The load cell resolves the lever's
  position far better than the encoders (a count of the motor encoder is 0.07 N·m at the load cell, one of
  the lever encoder 0.26 N·m);
* free fixture: the motor angle and velocity from the encoder, the hub inside the dead band where the angles
  put it.

On the locked fixture a window starts where the load cell is quiet (:func:`_quiet_starts`): the filtered load
rounds off a slip of the gear that lasts a few milliseconds, so a window started inside one would take a wrong
rate and miss the slip by tenths of a N·m.

On the model's own 10 s logs the replay retraces the log to 0.006 N·m (locked, the load cell's noise),
0.0003 rad (free) and 0.006 N·m (closed loop) RMS, within 0.025 N·m (0.0001 rad) in each window's first five
milliseconds (tests/test_discrepancy_model_log.py). The compared signal is the load-cell torque (locked
fixture), or the lever angle relative to the window start (free fixture and rigid joints).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.ndimage import maximum_filter1d

from sim.discrepancy.effects.transport_delay import MAX_DELAY_S
from sim.discrepancy.laws import stribeck_level
from sim.discrepancy.model import bristle_state
from sim.discrepancy.rig import Rig
from sim.discrepancy.signals import AnalysisConfig, Prepared, white_noise_std
from sim.discrepancy.simulate import InitialState, realisations, run_rigid, run_testbed, testbed_plant
from sim.run import run_open_loop
from sim.runlog import RunLog


def held_runs(data: Prepared) -> list[tuple[int, int]]:
    """Full-rate index ranges [start, stop) of the contiguous runs of the held-out part."""
    held = np.concatenate([[False], data.held, [False]])
    starts, stops = np.flatnonzero(held[1:] & ~held[:-1]), np.flatnonzero(held[:-1] & ~held[1:])
    return [(int(data.grid[a]), int(data.grid[b - 1]) + 1) for a, b in zip(starts, stops, strict=True)]


MAX_WINDOWS = 120  # at most this many windows, evenly spread over the held-out part (60 s of replay)


def _windows(data: Prepared, config: AnalysisConfig) -> list[tuple[int, int]]:
    length = max(2, int(round(config.replay_window_s / data.dt)))
    out = []
    for first, end in held_runs(data):
        out += [(s, min(s + length, end)) for s in range(max(first, 1), end, length) if min(s + length, end) - s >= 2]
    if len(out) > MAX_WINDOWS:
        out = [out[i] for i in np.linspace(0, len(out) - 1, MAX_WINDOWS).round().astype(int)]
    return out


QUIET_NOISE_MULTIPLE = 4.0  # a quiet load: the raw reading within this many noise std of its filtered value
QUIET_HALF_WIDTH_S = 0.005  # [s] ... at every sample this close to the window's start
MAX_START_SHIFT = 0.5  # a window's start moves on by at most this fraction of its length


def _quiet_starts(log: RunLog, rig: Rig, data: Prepared, windows: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Locked fixture: each window's start moved on to the first sample where the load cell is quiet (its raw
    reading within QUIET_NOISE_MULTIPLE noise std of the filtered one for QUIET_HALF_WIDTH_S either side), at
    most MAX_START_SHIFT of the window on; the nominal start where no sample is quiet. A window started during a
    slip of the gear would take the slip's rate from the filtered load, which rounds a few-millisecond slip off,
    and miss it by tenths of a N·m. Other fixtures and rigid joints: the windows as they are."""
    if rig.model != "testbed" or rig.fixture != "locked" or "force_loadcell" not in log.columns:
        return windows
    force = np.asarray(log["force_loadcell"], dtype=float)
    residual = np.abs(force - data.filt_full(force))
    half = max(1, int(round(QUIET_HALF_WIDTH_S / data.dt)))
    loud = maximum_filter1d(residual, 2 * half + 1) > QUIET_NOISE_MULTIPLE * white_noise_std(force)
    out = []
    for start, stop in windows:
        reach = start + int(MAX_START_SHIFT * (stop - start))
        quiet = np.flatnonzero(~loud[start - 1:reach])
        out.append((start + int(quiet[0]), stop) if len(quiet) else (start, stop))
    return out


def _motor_angle(log: RunLog, data: Prepared, filtered: bool = True) -> np.ndarray:
    """The motor-side angle at full rate [rad], filtered unless asked raw: the motor encoder, else the only
    encoder the log has."""
    q = np.asarray(log["q_motor"] if "q_motor" in log.columns else log["q"], dtype=float)
    return data.filt_full(q) if filtered else q


def _lever_angle(log: RunLog, data: Prepared, filtered: bool = True) -> np.ndarray:
    """The lever angle at full rate [rad], filtered unless asked raw: the lever encoder, else the motor-side
    angle (rigid gear)."""
    if "q" not in log.columns:
        return _motor_angle(log, data, filtered)
    q = np.asarray(log["q"], dtype=float)
    return data.filt_full(q) if filtered else q


def measured_state(log: RunLog, rig: Rig, data: Prepared, *, at_rest: bool = False,
                   contact_torque: float = AnalysisConfig.contact_torque) -> Callable[[int], InitialState]:
    """k -> a function that puts the plant of ``rig`` into the log's measured state at sample k (the module
    docstring says how). Rigid joint: position and velocity. ``at_rest``: velocities zero and the encoders' raw
    angles (a start at the log's first sample, where the zero-phase filter's edge biases both by the motion that
    follows); ``contact_torque`` [N·m]: above it the hub is loaded.
    The driver's state is set by the run (``previous_commands`` of :func:`sim.discrepancy.simulate.run_testbed`).
    """
    if rig.model != "testbed":
        q = np.asarray(log["q"], dtype=float)
        velocity = data.gradient(data.filt_full(q))
        if at_rest:
            velocity = np.zeros(len(q))
        deflection, deflection_rate = _compliance_state(rig, data, velocity)

        def rigid_state(k: int) -> InitialState:
            def initial(model: Any, d: Any) -> None:
                d.qpos[0], d.qvel[0] = q[k], velocity[k]
                if deflection is not None:  # the compliant body, joint 1 (relative to the driven one)
                    d.qpos[1], d.qvel[1] = deflection[k], deflection_rate[k]
            return initial
        return rigid_state
    assert rig.params is not None
    from models.gim8108_testbed.derived import derive

    derived = derive(rig.params)
    k_t = derived.flexure_stiffness_nm_per_rad
    half_gap = 0.5 * rig.params.backlash.width_rad
    bristle = measured_bristle_rad(rig, data) * rig.params.motor.gear_ratio  # motor side: MuJoCo's dcmotor state
    q_motor, q_lever = _motor_angle(log, data, not at_rest), _lever_angle(log, data, not at_rest)
    velocity = data.gradient(q_motor)
    if "force_loadcell" in log.columns:
        tau = data.filt_full(np.asarray(log["force_loadcell"], dtype=float) * rig.params.lever.length_m)
    elif "tau_sensor" in log.columns:
        tau = data.filt_full(np.asarray(log["tau_sensor"], dtype=float))
    else:
        tau = np.zeros(len(q_motor))
    flex_rate = -data.gradient(tau) / k_t  # rates from the filtered load (the raw reading is noisy)
    locked = rig.fixture == "locked" and "force_loadcell" in log.columns
    if locked:
        # The load cell's own deflection places the lever, the motor sits behind it by the flexure's twist and the
        # gap: at the load cell's stiffness (5.5 kN·m/rad at the defaults) one count of the motor encoder
        # (12 µrad at the output) is 0.07 N·m, one of the lever encoder (48 µrad) 0.26 N·m; the load cell's
        # reading is good to its noise. The encoders only say where in the dead band an unloaded hub floats.
        # Positions from the raw reading: the 25 Hz filter rounds the load's stick-slip corners by several
        # 0.01 N·m, which a window starting there would keep in the flexure.
        k_lc = derived.loadcell_rot_stiffness_nm_per_rad
        velocity = data.gradient(tau) / k_lc - flex_rate
        tau = np.asarray(log["force_loadcell"], dtype=float) * rig.params.lever.length_m
        q_lever_loadcell = tau / k_lc
        stop_rad_per_nm = stop_compliance_rad_per_nm(rig)
    if at_rest:
        velocity = flex_rate = np.zeros(len(tau))

    def testbed_state(k: int) -> InitialState:
        def initial(model: Any, d: Any) -> None:
            adr = {name: model.joint(name).qposadr[0] for name in ("motor", "backlash", "flexure")}
            flex = -tau[k] / k_t
            gap = min(max(q_lever[k] - q_motor[k] - flex, -half_gap), half_gap)
            motor = q_motor[k]
            if locked:
                if abs(tau[k]) > contact_torque:  # loaded: the hub presses into the stop its torque closes
                    gap = -math.copysign(half_gap + stop_rad_per_nm * abs(tau[k]), tau[k])
                motor = q_lever_loadcell[k] - flex - gap
            d.qpos[adr["motor"]], d.qpos[adr["backlash"]], d.qpos[adr["flexure"]] = motor, gap, flex
            d.qvel[model.joint("motor").dofadr[0]] = velocity[k]
            d.qvel[model.joint("flexure").dofadr[0]] = flex_rate[k]
            d.act[model.actuator_actadr[model.actuator("motor").id]] = bristle[k]
        return initial
    return testbed_state


def _compliance_state(rig: Rig, data: Prepared, velocity: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
    """A rigid joint with drivetrain compliance: the spring's deflection [rad | m] the measured motion implies,
    quasi-static (the compliant part φ·m follows the measured acceleration a: deflection -φ·m·a/k), and its rate
    (zero: a third derivative of the encoder is noise); (None, None) without compliance. Started unloaded, the
    spring would ring at the resonance through every window that starts while the joint accelerates."""
    body = next((r.compliant_body for r in realisations(rig) if r.compliant_body is not None), None)
    if body is None:
        return None, None
    fraction, stiffness, _ = body
    deflection = -fraction * rig.rigid["inertia"] * data.gradient(velocity) / stiffness
    return deflection, np.zeros(len(deflection))


STOP_CALIBRATION_NM = 10.0  # [N·m] held on the locked lever to measure the stop's compliance
STOP_CALIBRATION_TICKS = 300  # control ticks of that hold (the stop settles within a few ms)


def stop_compliance_rad_per_nm(rig: Rig) -> float:
    """How far the loaded hub presses into its backlash stop per N·m [rad/(N·m)]: MuJoCo's soft stop constraint
    (solref, solimp) yields under load; measured by holding STOP_CALIBRATION_NM on the rig's locked lever.

    A replay window that put a loaded hub at the stop's edge would start without the stop's force, and the load
    cell would swing by tenths of a N·m in its first milliseconds while the hub settles those few µrad."""
    if rig.fixture != "locked":
        raise ValueError("the stop's compliance is measured on the locked fixture")
    plant = testbed_plant(rig)
    plant.reset(backlash_side=1)
    run_open_loop(plant, np.full(STOP_CALIBRATION_TICKS, STOP_CALIBRATION_NM), progress=False)
    depth = abs(plant.backlash_angle_rad) - 0.5 * rig.params.backlash.width_rad
    return max(depth, 0.0) / abs(plant.flexure_torque_nm)


def measured_bristle_rad(rig: Rig, data: Prepared) -> np.ndarray:
    """The LuGre bristle deflection [rad, output-referred] the measured motor motion implies at each sample, at
    the rig's friction parameters (the surrogate's exact per-sample update,
    :func:`sim.discrepancy.model.bristle_state`).

    A stuck gear holds part of its load in the bristle; a window started with an empty bristle lets the motor
    creep up to a presliding displacement g/σ0 before it holds, which shifts the load-cell torque by up to the
    drivetrain stiffness times that displacement for as long as the gear stays stuck."""
    fr = rig.params.friction
    v = data.step_velocity
    g = stribeck_level(v, fr.coulomb_torque_nm, fr.breakaway_torque_nm, fr.stribeck_velocity_rad_s)
    return bristle_state(v, g, fr.presliding_stiffness_nm_per_rad, data.dt)


def _replay(log: RunLog, rig: Rig, data: Prepared, windows: list[tuple[int, int]],
            contact_torque: float) -> tuple[np.ndarray, str, str]:
    u = np.asarray(log["tau_cmd"], dtype=float)
    state_at = measured_state(log, rig, data, contact_torque=contact_torque)
    for start, _ in windows:  # each window starts from the state at the sample before it
        if start < 1:
            raise ValueError("a replay window cannot start at the log's first sample")

    n_history = math.ceil(MAX_DELAY_S / data.dt) + 2  # the longest dead time the analysis fits, and two ticks

    def history(start: int) -> np.ndarray:
        return u[max(0, start - n_history):start]
    out = []
    if rig.model == "testbed":
        assert rig.params is not None
        plant = testbed_plant(rig)
        locked = rig.fixture == "locked"
        q_lever = _lever_angle(log, data)
        for start, stop in windows:
            run = run_testbed(rig, lambda i, s, k=start: float(u[k + i]), stop - start, initial=state_at(start - 1),
                              plant=plant, previous_commands=history(start))
            if locked:
                out.append(run.columns["force_loadcell"] * rig.params.lever.length_m)
            else:
                out.append(run.columns["q"] - q_lever[start])
        signal, unit = ("load-cell torque", "N·m") if locked else ("lever angle from window start", "rad")
    else:
        q = np.asarray(log["q"], dtype=float)
        for start, stop in windows:
            run = run_rigid(rig, lambda i, s, k=start: float(u[k + i]), stop - start, initial=state_at(start - 1),
                            previous_commands=history(start))
            out.append(run.columns["q"] - q[start])
        signal, unit = "position from window start", "m" if rig.joint == "slide" else "rad"
    return np.concatenate(out), signal, unit


def _measured(log: RunLog, rig: Rig, data: Prepared, windows: list[tuple[int, int]]) -> np.ndarray:
    parts = []
    for start, stop in windows:
        if rig.model == "testbed" and rig.fixture == "locked":
            parts.append(np.asarray(log["force_loadcell"][start:stop]) * rig.params.lever.length_m
                         if "force_loadcell" in log.columns else np.asarray(log["tau_sensor"][start:stop]))
        else:
            q = np.asarray(log["q"] if "q" in log.columns else log["q_motor"])
            parts.append(q[start:stop] - q[start])
    return np.concatenate(parts)


def replay_held_out(log: RunLog, baseline: Rig, extended: Rig, data: Prepared,
                    config: AnalysisConfig) -> dict[str, Any]:
    """Replay the held-out windows through both rigs; RMSE of each against the measured signal."""
    nominal = _windows(data, config)
    windows = _quiet_starts(log, baseline, data, nominal)
    if not windows:
        return {}
    measured = _measured(log, baseline, data, windows)
    sim_base, signal, unit = _replay(log, baseline, data, windows, config.contact_torque)
    sim_ext, _, _ = _replay(log, extended, data, windows, config.contact_torque)
    time = np.concatenate([data.t_full[a:b] for a, b in windows])
    rmse = lambda x: float(math.sqrt(np.mean((x - measured) ** 2)))  # noqa: E731
    first = np.cumsum([0] + [b - a for a, b in windows[:-1]])
    return {"signal": signal, "unit": unit, "windows": len(windows), "window_s": config.replay_window_s,
            "window_first": first, "samples": len(time),
            "skipped_samples": sum(a - n for (a, _), (n, _) in zip(windows, nominal, strict=True)),
            "rmse_baseline": rmse(sim_base), "rmse_extended": rmse(sim_ext), "time": time, "measured": measured,
            "simulated_baseline": sim_base, "simulated_extended": sim_ext}
