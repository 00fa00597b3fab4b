"""The model's own log: what the analysis estimates on a log that the current model produced.

Rule 'moved' of the significance test (:mod:`sim.discrepancy.selection`) asks an effect the baseline already carries
to move one of its parameters by ``min_parameter_change``. Measured from the model's own value, that counts the
estimator's bias as a discrepancy: the surrogate evaluates the plant's physics backwards from filtered,
quantised signals and does not return the plant's parameters exactly (a Coulomb level ~13 % low on
sensor-feedback logs with a 22-bit motor encoder). The reference is therefore the
same candidate fitted, by the same procedure, on a log the current model produced under the same command: the
model's MuJoCo plant driven open loop by the log's ``tau_cmd`` from the log's first measured positions at rest, measured
like the log (the columns the log has, each position quantised at the log's own smallest step, white noise at
the level estimated from the log's torque and force columns, the log's temperature). Its parameters differ
from the model's by the estimator's bias only; a measured log's differ by that bias plus the discrepancy.

The open-loop replay of a closed-loop log is the model's response to the command the rig actually received:
on the locked fixture it follows the measured motion when the model is right; on a free lever it may drift
away from it, which leaves it a log of the model under that command, all the reference needs.
"""

from __future__ import annotations

import numpy as np

from sim.discrepancy.replay import measured_state
from sim.discrepancy.rig import Rig
from sim.discrepancy.signals import Prepared, quantise, smallest_step, white_noise_std
from sim.discrepancy.simulate import run_rigid, run_testbed, sensor_reading
from sim.plant import SimulationDiverged
from sim.runlog import RunLog

NOISE_COLUMNS = ("tau_sensor", "force_loadcell")  # measured with white noise, whose level is estimated
POSITION_COLUMNS = ("q", "q_motor")  # quantised at the log's own step


class ModelLogUnavailable(RuntimeError):
    """The current model cannot produce a log of this command (the reason is the message)."""


def model_log(log: RunLog, rig: Rig, data: Prepared, seed: int = 0) -> RunLog:
    """The log ``rig`` produces under ``log``'s command, measured like ``log`` (see the module docstring).

    Raises
    ------
    ModelLogUnavailable
        If the simulation diverges.
    """
    u = np.asarray(log["tau_cmd"], dtype=float)
    initial = measured_state(log, rig, data, at_rest=True)(0)
    command = lambda k, state: float(u[k])  # noqa: E731
    try:
        if rig.model == "testbed":
            run = run_testbed(rig, command, len(u), initial=initial)
        else:
            run = run_rigid(rig, command, len(u), initial=initial)
    except SimulationDiverged as error:
        raise ModelLogUnavailable(f"the model's open-loop run of the log's command diverged: {error}") from error
    sim = run.columns
    rng = np.random.default_rng(seed)
    columns = {"time": np.asarray(log["time"], dtype=float), "tau_cmd": u}
    for name in POSITION_COLUMNS:
        if name in log.columns and name in sim:  # a rigid joint has no motor encoder (the analysis reads q)
            step = smallest_step(log[name])
            columns[name] = quantise(sim[name], step) if step > 0 else sim[name].copy()
    if "temperature" in log.columns:
        columns["temperature"] = np.asarray(log["temperature"], dtype=float)
    if rig.model == "testbed":  # a rigid joint's model has no transmitted torque (the analysis reads neither)
        if "tau_sensor" in log.columns:
            temperature = (columns["temperature"] if "temperature" in columns else
                           np.full(len(u), rig.params.photoreflector.reference_temperature_c))
            columns["tau_sensor"] = sensor_reading(rig, sim["tau_flexure"], temperature)
        if "force_loadcell" in log.columns:
            columns["force_loadcell"] = sim["force_loadcell"].copy()
        for name in NOISE_COLUMNS:
            if name in columns:
                columns[name] = columns[name] + rng.normal(0.0, white_noise_std(log[name]), len(u))
    return type(log)(columns, {name: log.units[name] for name in columns}, dict(log.meta))
