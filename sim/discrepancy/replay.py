"""Windowed replay of the held-out part through MuJoCo: the log's command into the baseline and extended rig.

Each window (``config.replay_window_s``) starts from the measured state, so an integrating plant under
closed-loop commands does not drift away: the motor angle and velocity from the encoder, the flexure twist
from the measured transmitted torque (τ/K_t), the hub inside the dead band where the angles put it. The
LuGre bristle state and the actuator's delay buffer start empty (a transient of a few ms per window). The
compared signal is the load-cell torque (locked fixture), or the lever angle relative to the window start
(free fixture and rigid joints).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from sim.discrepancy.rig import Rig
from sim.discrepancy.signals import AnalysisConfig, Prepared
from sim.discrepancy.simulate import InitialState, run_rigid, run_testbed, testbed_plant
from sim.runlog import RunLog


def _windows(data: Prepared, config: AnalysisConfig) -> list[tuple[int, int]]:
    index = np.flatnonzero(data.held)
    if not len(index):
        return []
    length = max(2, int(round(config.replay_window_s / data.dt)))
    return [(int(s), int(min(s + length, index[-1] + 1))) for s in range(int(index[0]), int(index[-1]) + 1, length)
            if min(s + length, index[-1] + 1) - s >= 2]


def _motor_angle(log: RunLog, data: Prepared) -> np.ndarray:
    """The filtered motor-side angle [rad]: the motor encoder, else the only encoder the log has."""
    return data.filt(np.asarray(log["q_motor"] if "q_motor" in log.columns else log["q"], dtype=float))


def _lever_angle(log: RunLog, data: Prepared) -> np.ndarray:
    """The lever angle [rad]: the filtered lever encoder, else the motor-side angle (rigid gear assumed)."""
    return data.q if data.q is not None else _motor_angle(log, data)


def measured_state(log: RunLog, rig: Rig, data: Prepared, *, at_rest: bool = False) -> Callable[[int], InitialState]:
    """k -> a function that puts the plant of ``rig`` into the log's measured state at sample k.

    Testbed: motor angle and velocity from the encoder, flexure twist from the measured transmitted torque
    (τ/K_t), the hub inside the dead band where the angles put it. Rigid joint: position and velocity. The
    LuGre bristle state and the actuator's delay buffer start empty. ``at_rest``: velocity zero (at the ends
    of a log the zero-phase filter's velocity is not reliable).
    """
    velocity = np.zeros(len(data.velocity)) if at_rest else data.velocity
    if rig.model != "testbed":
        q = np.asarray(log["q"], dtype=float)

        def rigid_state(k: int) -> InitialState:
            def initial(model: Any, d: Any) -> None:
                d.qpos[0], d.qvel[0] = q[k], velocity[k]
            return initial
        return rigid_state
    assert rig.params is not None
    from models.gim8108_testbed.derived import derive

    k_t = derive(rig.params).flexure_stiffness_nm_per_rad
    half_gap = 0.5 * rig.params.backlash.width_rad
    q_motor = _motor_angle(log, data)
    q_lever = _lever_angle(log, data)
    tau = (data.tau_loadcell if data.tau_loadcell is not None else
           data.tau_sensor if data.tau_sensor is not None else np.zeros(len(q_motor)))

    def testbed_state(k: int) -> InitialState:
        def initial(model: Any, d: Any) -> None:
            adr = {name: model.joint(name).qposadr[0] for name in ("motor", "backlash", "flexure")}
            flex = -tau[k] / k_t
            gap = min(max(q_lever[k] - q_motor[k] - flex, -half_gap), half_gap)
            d.qpos[adr["motor"]], d.qpos[adr["backlash"]], d.qpos[adr["flexure"]] = q_motor[k], gap, flex
            d.qvel[model.joint("motor").dofadr[0]] = velocity[k]
        return initial
    return testbed_state


def _replay(log: RunLog, rig: Rig, data: Prepared, windows: list[tuple[int, int]]) -> tuple[np.ndarray, str, str]:
    u = np.asarray(log["tau_cmd"], dtype=float)
    state_at = measured_state(log, rig, data)
    out = []
    if rig.model == "testbed":
        assert rig.params is not None
        plant = testbed_plant(rig)
        locked = rig.fixture == "locked"
        q_lever = _lever_angle(log, data)
        for start, stop in windows:
            run = run_testbed(rig, lambda i, s, k=start: float(u[k + i]), stop - start, initial=state_at(start),
                              plant=plant)
            if locked:
                out.append(run.columns["force_loadcell"] * rig.params.lever.length_m)
            else:
                out.append(run.columns["q"] - q_lever[start])
        signal, unit = ("load-cell torque", "N·m") if locked else ("lever angle from window start", "rad")
    else:
        q = np.asarray(log["q"], dtype=float)
        for start, stop in windows:
            run = run_rigid(rig, lambda i, s, k=start: float(u[k + i]), stop - start, initial=state_at(start))
            out.append(run.columns["q"] - q[start])
        signal, unit = "position from window start", "m" if rig.joint == "slide" else "rad"
    return np.concatenate(out), signal, unit


def _measured(log: RunLog, rig: Rig, data: Prepared, windows: list[tuple[int, int]]) -> np.ndarray:
    parts = []
    for start, stop in windows:
        if rig.model == "testbed" and rig.fixture == "locked":
            parts.append(np.asarray(log["force_loadcell"][start:stop]) * rig.params.lever.length_m
                         if "force_loadcell" in log.columns else data.tau_sensor[start:stop])
        else:
            q = np.asarray(log["q"] if "q" in log.columns else log["q_motor"])
            parts.append(q[start:stop] - q[start])
    return np.concatenate(parts)


def replay_held_out(log: RunLog, baseline: Rig, extended: Rig, data: Prepared, config: AnalysisConfig) -> dict[str, Any]:
    """Replay the held-out windows through both rigs; RMSE of each against the measured signal."""
    windows = _windows(data, config)
    if not windows:
        return {}
    measured = _measured(log, baseline, data, windows)
    sim_base, signal, unit = _replay(log, baseline, data, windows)
    sim_ext, _, _ = _replay(log, extended, data, windows)
    time = np.concatenate([data.t[a:b] for a, b in windows])
    rmse = lambda x: float(math.sqrt(np.mean((x - measured) ** 2)))  # noqa: E731
    return {"signal": signal, "unit": unit, "windows": len(windows), "window_s": config.replay_window_s,
            "rmse_baseline": rmse(sim_base), "rmse_extended": rmse(sim_ext), "time": time, "measured": measured,
            "simulated_baseline": sim_base, "simulated_extended": sim_ext}
