"""Run-log reading speed: a long CSV (the pyarrow fast path) and a 60 s .mat, best of a few reads.

    python -m benchmarks.bench_logio [--csv-rows 1000000] [--mat-seconds 60] [--repeats 3]

The logs have the 13 columns of a simulated run, random values sampled at 1 kHz, written by ``write_log``
to a temporary folder; reading is ``read_log`` with the default checks.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from sim.logio import read_log, write_log
from sim.runlog import STANDARD_UNITS, RunLog

EXTRA_UNITS = {"qd_motor": "rad/s", "tau_flexure": "N·m", "tau_current_estimate": "N·m", "current": "A",
               "backlash_angle": "rad", "tau_ext": "N·m"}
STANDARD = ("time", "tau_cmd", "q", "qd", "q_motor", "force_loadcell", "temperature")


def simulated_like(rows: int, seed: int = 0) -> RunLog:
    """A log shaped like ``run_open_loop``'s (13 columns) with random values at 1 kHz."""
    rng = np.random.default_rng(seed)
    columns = {"time": 1e-3 * np.arange(rows)}
    columns.update({name: rng.normal(0.0, 1.0, rows) for name in (*STANDARD[1:], *EXTRA_UNITS)})
    units = {**{name: STANDARD_UNITS[name] for name in STANDARD}, **EXTRA_UNITS}
    return RunLog(columns, units)


def best_seconds(path: Path, repeats: int) -> float:
    """Shortest wall time of ``repeats`` reads of ``path``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        read_log(path)
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--csv-rows", type=int, default=1_000_000)
    parser.add_argument("--mat-seconds", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    warnings.simplefilter("error")
    with tempfile.TemporaryDirectory() as folder:
        csv_path = write_log(simulated_like(args.csv_rows), Path(folder) / "long.csv")
        mat_path = write_log(simulated_like(round(1000 * args.mat_seconds)), Path(folder) / "run.mat")
        print(f"CSV, {args.csv_rows} rows x 13 columns ({csv_path.stat().st_size / 1e6:.0f} MB): "
              f"{best_seconds(csv_path, args.repeats):.3f} s")
        print(f".mat, {args.mat_seconds:g} s at 1 kHz x 13 columns ({mat_path.stat().st_size / 1e6:.1f} MB): "
              f"{best_seconds(mat_path, args.repeats):.3f} s")


if __name__ == "__main__":
    main()
