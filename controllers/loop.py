"""Closed control loops on the simulated testbed, tick by tick, recorded as a :class:`~sim.runlog.RunLog`.

Order within control tick k: read the measured torque (and angles) from the plant's state at the end of tick
k-1, compute the command, step the plant one tick with it, record the signals at the end of tick k. The
``tau_cmd`` column is the command sent to the driver (the plant applies the current-to-torque map,
:mod:`sim.motor_torque`).
"""

from __future__ import annotations

import numpy as np

from controllers.admittance import AdmittanceController
from controllers.feedback import TorqueFeedback
from controllers.pi import PITorqueController
from sensor.photoreflector import CHANNELS
from sim.plant import SIGNAL_UNITS, Plant
from sim.run import Progress, signal_columns
from sim.runlog import HOLD_END, RunLog, add_voltage_columns

PROGRESS_EVERY_TICKS = 1000


def apply_hub_torque(plant: Plant, tau_nm: float) -> None:
    """Apply an external torque [N·m] about the joint axis on the gear's output flange + sensor hub, i.e.
    between the gear and the flexure (the sensor and the load cell both see it, the current estimate does
    not).

    Stand-in for a missing plant input (``Plant.step`` only takes a torque on the lever): it writes MuJoCo's
    ``xfrc_applied`` of the body named 'output', which ``Plant.reset`` clears.
    """
    plant.data.body("output").xfrc_applied[5] = tau_nm


def _check_profile(name: str, values, n: int) -> np.ndarray:
    if values is None:
        return np.zeros(n)
    values = np.asarray(values, dtype=float)
    if values.shape != (n,) or not np.isfinite(values).all():
        raise ValueError(f"{name} must be {n} finite values (one per tick), got shape {values.shape}")
    return values


def run_torque_loop(plant: Plant, controller: PITorqueController, feedback: TorqueFeedback,
                    tau_ref_nm, tau_ext_nm=None, tau_hub_nm=None, *, progress_label: str | None = None,
                    meta: dict | None = None) -> RunLog:
    """Torque control: ``controller`` drives the plant to ``tau_ref_nm`` on ``feedback``'s measurement.

    Parameters
    ----------
    plant : Plant
        Stepped from its current state.
    controller : PITorqueController
        Stepped once per tick with (reference, measured torque).
    feedback : TorqueFeedback
        Source of the measured torque ('current' or 'sensor').
    tau_ref_nm : (N,) array
        Torque reference per tick [N·m].
    tau_ext_nm : (N,) array, optional
        External torque on the lever per tick [N·m].
    tau_hub_nm : (N,) array, optional
        External torque on the output flange / sensor hub per tick [N·m] (see :func:`apply_hub_torque`).
    progress_label : str, optional
        Print progress to stderr under this label.

    Returns
    -------
    RunLog
        The plant's signals (``sim.plant.SIGNAL_UNITS``) plus ``tau_ref``, ``tau_feedback`` (the measured
        torque the controller used), ``tau_ext`` and ``tau_hub`` [N·m], and in sensor mode ``tau_sensor`` and the
        channel voltages ``v1`` ... ``v8`` [V] it was computed from.
    """
    tau_ref = _check_profile("tau_ref_nm", tau_ref_nm, len(np.atleast_1d(tau_ref_nm)))
    n = len(tau_ref)
    tau_ext = _check_profile("tau_ext_nm", tau_ext_nm, n)
    tau_hub = _check_profile("tau_hub_nm", tau_hub_nm, n)
    out, times, measured = np.empty((n, len(SIGNAL_UNITS))), np.empty(n), np.empty(n)
    bar = Progress(progress_label, n, plant.params.simulation.control_period_s) if progress_label else None
    use_hub = bool(np.any(tau_hub))
    volts = np.empty((n, CHANNELS)) if feedback.kind == "sensor" else None
    for k in range(n):
        measured[k] = feedback.read(plant)
        if volts is not None:
            volts[k] = feedback.voltages_v
        command = controller.step(tau_ref[k], measured[k])
        if use_hub:
            apply_hub_torque(plant, tau_hub[k])
        plant.step(command, tau_ext[k])
        times[k] = plant.time_s
        plant.read_signals(out[k])
        if bar is not None and (k % PROGRESS_EVERY_TICKS == PROGRESS_EVERY_TICKS - 1 or k == n - 1):
            bar.update(k + 1)
    extra = {"tau_ref": tau_ref.copy(), "tau_feedback": measured, "tau_ext": tau_ext.copy(),
             "tau_hub": tau_hub.copy()}
    units = {"time": "s", **SIGNAL_UNITS, **{name: "N·m" for name in extra}}
    if feedback.kind == "sensor":
        extra["tau_sensor"] = measured.copy()
        units["tau_sensor"] = "N·m"
        add_voltage_columns(extra, units, volts)
    return RunLog(signal_columns(out, times, extra), units,
                  {"fixture": plant.fixture, "feedback": feedback.kind, "physics_timestep_s": plant.timestep_s,
                   "lever_length_m": plant.params.lever.length_m,
                   "loadcell_reading_noise_n": plant.params.loadcell.reading_noise_n,
                   "torque_saturation_per_nm": plant.params.motor.torque_saturation_per_nm,
                   "time_convention": HOLD_END, **(meta or {})})


def run_admittance_loop(plant: Plant, controller: AdmittanceController, feedback: TorqueFeedback,
                        hand, *, progress_label: str | None = None, meta: dict | None = None) -> RunLog:
    """Admittance control on the free lever, pushed by a hand model.

    Parameters
    ----------
    plant : Plant
        The 'free' fixture, stepped from its current state.
    controller : AdmittanceController
        Stepped once per tick with τ_ext = -τ_measured and the motor's angle and velocity.
    feedback : TorqueFeedback
        The torque sensor (the paper's τ_ext).
    hand : object with ``n_ticks`` and ``torque_nm(k, angle_rad, velocity_rad_s) -> float``
        The torque the hand applies to the lever at tick k given the lever's state.

    Returns
    -------
    RunLog
        Plant signals plus ``tau_ext`` (hand torque), ``tau_feedback``, ``theta_ref`` [rad] and
        ``omega_ref`` [rad/s] of the virtual dynamics, and in sensor mode ``tau_sensor`` and ``v1`` ... ``v8`` [V].
    """
    n = int(hand.n_ticks)
    out, times = np.empty((n, len(SIGNAL_UNITS))), np.empty(n)
    measured, hand_torque, theta_ref, omega_ref = (np.empty(n) for _ in range(4))
    bar = Progress(progress_label, n, plant.params.simulation.control_period_s) if progress_label else None
    volts = np.empty((n, CHANNELS)) if feedback.kind == "sensor" else None
    for k in range(n):
        measured[k] = feedback.read(plant)
        if volts is not None:
            volts[k] = feedback.voltages_v
        theta_ref[k], omega_ref[k] = controller.reference_angle_rad, controller.reference_velocity_rad_s
        command = controller.step(-measured[k], plant.motor_angle_rad, plant.motor_velocity_rad_s)
        hand_torque[k] = hand.torque_nm(k, plant.output_angle_rad, plant.output_velocity_rad_s)
        plant.step(command, hand_torque[k])
        times[k] = plant.time_s
        plant.read_signals(out[k])
        if bar is not None and (k % PROGRESS_EVERY_TICKS == PROGRESS_EVERY_TICKS - 1 or k == n - 1):
            bar.update(k + 1)
    extra = {"tau_ext": hand_torque, "tau_feedback": measured, "theta_ref": theta_ref, "omega_ref": omega_ref}
    units = {"time": "s", **SIGNAL_UNITS, "tau_ext": "N·m", "tau_feedback": "N·m", "theta_ref": "rad",
             "omega_ref": "rad/s"}
    if feedback.kind == "sensor":
        extra["tau_sensor"] = measured.copy()
        units["tau_sensor"] = "N·m"
        add_voltage_columns(extra, units, volts)
    return RunLog(signal_columns(out, times, extra), units,
                  {"fixture": plant.fixture, "feedback": feedback.kind, "physics_timestep_s": plant.timestep_s,
                   "lever_length_m": plant.params.lever.length_m,
                   "loadcell_reading_noise_n": plant.params.loadcell.reading_noise_n,
                   "time_convention": HOLD_END, **(meta or {})})
