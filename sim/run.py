"""Run the plant tick by tick and record a :class:`~sim.runlog.RunLog`."""

from __future__ import annotations

import sys
import time
from typing import TextIO

import numpy as np

from sim.plant import SIGNAL_UNITS, Plant
from sim.runlog import HOLD_END, RunLog

PROGRESS_MIN_TICKS = 20_000  # report progress only on runs longer than 20 s of simulated time


def signal_columns(rows: np.ndarray, times: np.ndarray, extra: dict[str, np.ndarray] | None = None) -> dict:
    """Run-log columns from per-tick ``Plant.read_signals`` rows (``SIGNAL_UNITS`` order), their ``times`` [s]
    and ``extra`` columns."""
    return {"time": times, **{name: rows[:, i].copy() for i, name in enumerate(SIGNAL_UNITS)}, **(extra or {})}


class Progress:
    """Prints 'label: 40 % (4.0 of 10.0 s simulated, 31000 ticks/s)' to a stream at most once per second."""

    def __init__(self, label: str, total_ticks: int, tick_s: float, stream: TextIO | None = None,
                 interval_s: float = 1.0) -> None:
        self.label, self.total, self.tick_s = label, total_ticks, tick_s
        self.stream = stream or sys.stderr
        self.interval_s = interval_s
        self.start = self.last = time.perf_counter()

    def update(self, done: int) -> None:
        now = time.perf_counter()
        if now - self.last < self.interval_s and done < self.total:
            return
        self.last = now
        rate = done / max(now - self.start, 1e-9)
        print(f"{self.label}: {100 * done / self.total:3.0f} % ({done * self.tick_s:.1f} of "
              f"{self.total * self.tick_s:.1f} s simulated, {rate:,.0f} ticks/s)", file=self.stream)


def run_open_loop(plant: Plant, tau_cmd_nm: np.ndarray, tau_ext_nm: np.ndarray | None = None, *,
                  progress: bool = True, meta: dict | None = None) -> RunLog:
    """Apply a motor torque command (and an external lever torque) tick by tick and record the run.

    Parameters
    ----------
    plant : Plant
        Stepped from its current state (reset it first for a run from rest).
    tau_cmd_nm : (N,) array
        Motor torque command per control tick [N·m, output side].
    tau_ext_nm : (N,) array, optional
        External torque on the lever per tick [N·m] (zero if None).
    progress : bool
        Print progress to stderr on runs longer than ``PROGRESS_MIN_TICKS``.

    Returns
    -------
    RunLog
        ``time`` is the end of each tick [s]; columns are those of ``sim.plant.SIGNAL_UNITS`` plus ``tau_ext``.
    """
    tau_cmd_nm = np.asarray(tau_cmd_nm, dtype=float)
    n = len(tau_cmd_nm)
    tau_ext_nm = np.zeros(n) if tau_ext_nm is None else np.asarray(tau_ext_nm, dtype=float)
    if tau_ext_nm.shape != (n,):
        raise ValueError(f"tau_ext_nm has shape {tau_ext_nm.shape}; expected ({n},) like tau_cmd_nm")
    if not (np.isfinite(tau_cmd_nm).all() and np.isfinite(tau_ext_nm).all()):
        raise ValueError("tau_cmd_nm and tau_ext_nm must be finite")
    out = np.empty((n, len(SIGNAL_UNITS)))
    times = np.empty(n)
    bar = Progress("simulating", n, plant.params.simulation.control_period_s) if (
        progress and n >= PROGRESS_MIN_TICKS) else None
    for k in range(n):
        plant.step(tau_cmd_nm[k], tau_ext_nm[k])
        times[k] = plant.time_s
        plant.read_signals(out[k])
        if bar is not None and k % 1000 == 999:
            bar.update(k + 1)
    columns = signal_columns(out, times, {"tau_ext": tau_ext_nm.copy()})
    units = {"time": "s", **SIGNAL_UNITS, "tau_ext": "N·m"}
    return RunLog(columns, units, {"fixture": plant.fixture, "physics_timestep_s": plant.timestep_s,
                                   "substeps": plant.n_substeps, "time_convention": HOLD_END, **(meta or {})})
