"""Run logs: one format for simulated and measured runs (time series with units).

Files are read and written by :mod:`sim.logio` (CSV, Parquet, MATLAB .mat; see docs/run_log_format.md).

The standard columns (names and units) are those a measured log can also carry; a simulated run adds the
plant's true internal signals under further names, each with its unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

VOLTAGE_COLUMNS = tuple(f"v{k}" for k in range(1, 9))  # the eight photo-reflector channels of the log format

STANDARD_UNITS: dict[str, str] = {
    "time": "s",
    "tau_cmd": "N·m",
    "q": "rad",
    "qd": "rad/s",
    "q_ref": "rad",
    "q_motor": "rad",
    "tau_sensor": "N·m",
    "force_loadcell": "N",
    "tau_ref": "N·m",
    "temperature": "°C",
    **{name: "V" for name in VOLTAGE_COLUMNS},
}


# Time conventions of a log's rows (meta key "time_convention"; docs/run_log_format.md): "hold_end" stamps row k
# at the end of the hold of its command, with the state measured then (the command of row k acted on the state
# of row k); "command" stamps it when its command was computed from the state measured then (the command of
# row k acts on the state of row k + 1). The project's own logs are "hold_end".
HOLD_END, COMMAND = "hold_end", "command"
TIME_CONVENTIONS = (HOLD_END, COMMAND)


def add_voltage_columns(columns: dict[str, np.ndarray], units: dict[str, str], voltages_v: np.ndarray) -> None:
    """Add the photo-reflector channel voltages, an (N, channels) array [V], as the standard columns v1, v2, ..."""
    volts = np.asarray(voltages_v, dtype=float)
    for name, column in zip(VOLTAGE_COLUMNS, volts.T, strict=True):
        columns[name] = column.copy()
        units[name] = STANDARD_UNITS[name]


@dataclass(frozen=True)
class RunLog:
    """Equal-length 1-D columns sampled at ``time`` [s].

    Attributes
    ----------
    columns : dict of str to ndarray
        Signal name to samples. Standard names carry the units of ``STANDARD_UNITS``.
    units : dict of str to str
        Unit of every column.
    meta : dict
        What produced the run (fixture, seed, parameters, ...), JSON-serialisable.
    """

    columns: dict[str, np.ndarray]
    units: dict[str, str]
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if "time" not in self.columns:
            raise ValueError("a run log needs a 'time' column [s]")
        n = len(self.columns["time"])
        for name, values in self.columns.items():
            if np.ndim(values) != 1 or len(values) != n:
                raise ValueError(f"column {name!r} has shape {np.shape(values)}; every column must be 1-D of "
                                 f"length {n} like 'time'")
            if name not in self.units:
                raise ValueError(f"column {name!r} has no unit")
            if name in STANDARD_UNITS and self.units[name] != STANDARD_UNITS[name]:
                raise ValueError(f"column {name!r} is in {self.units[name]!r}; the format fixes "
                                 f"{STANDARD_UNITS[name]!r}")

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"no column {name!r}; columns: {', '.join(self.columns)}") from None

    def __len__(self) -> int:
        return len(self.columns["time"])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: columns as lists, units, meta."""
        return {"columns": {k: v.tolist() for k, v in self.columns.items()}, "units": dict(self.units),
                "meta": self.meta}
