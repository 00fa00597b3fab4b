"""Run-log reading speed: a long CSV (the pyarrow fast path), a 60 s .mat, and records read through a map.

    python -m benchmarks.bench_logio [--csv-rows 1000000] [--mat-seconds 60] [--json-records 100000]
                                     [--repeats 3]

The logs have the 13 columns of a simulated run, random values sampled at 1 kHz, written by ``write_log``
to a temporary folder; reading is ``read_log`` with the default checks. The mapped reads
(:func:`sim.logmap.read_mapped`) take the same CSV through a ``[log]`` map (an expression, a sign, units) and a
JSON log of records (a header and a list of objects) through a map that also resamples it; each is printed as a
ratio to ``read_log`` of the same rows as CSV, timed in the same process.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sim.logio import read_log, write_log
from sim.logmap import LogMap, read_mapped
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


CSV_MAP = LogMap(columns={"time": "time", "tau_cmd": "2 * tau_cmd", "q": "-q"}, units={"q": "deg"})
JSON_MAP = LogMap(columns={"time": "stamp", "tau_cmd": "pwm * header.gain", "q": "position"},
                  units={"time": "ms", "q": "deg"}, resample_s=1e-3)


def best_seconds(path: Path, repeats: int, read: Callable[[Path], object] = read_log) -> float:
    """Shortest wall time of ``repeats`` reads of ``path`` by ``read``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        read(path)
        times.append(time.perf_counter() - start)
    return min(times)


def json_records(log: RunLog, path: Path) -> Path:
    """``log`` as a JSON log of records: a header and one object per sample (ms, deg, a command in counts)."""
    records = [{"stamp": 1e3 * t, "pwm": u / 0.01, "position": np.degrees(q)}
               for t, u, q in zip(log["time"].tolist(), log["tau_cmd"].tolist(), log["q"].tolist(), strict=True)]
    path.write_text(json.dumps({"header": {"gain": 0.01}, "records": records}), encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--csv-rows", type=int, default=1_000_000)
    parser.add_argument("--mat-seconds", type=float, default=60.0)
    parser.add_argument("--json-records", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    warnings.simplefilter("error")
    with tempfile.TemporaryDirectory() as folder:
        csv_path = write_log(simulated_like(args.csv_rows), Path(folder) / "long.csv")
        plain = best_seconds(csv_path, args.repeats)
        mapped = best_seconds(csv_path, args.repeats, lambda p: read_mapped(p, CSV_MAP))
        print(f"CSV through a map (expression, sign, deg): {mapped:.3f} s, {mapped / plain:.2f} x read_log's "
              f"{plain:.3f} s")
        short = simulated_like(args.json_records)
        json_path = json_records(short, Path(folder) / "records.json")
        short_csv = write_log(short, Path(folder) / "short.csv")
        plain = best_seconds(short_csv, args.repeats)
        mapped = best_seconds(json_path, args.repeats, lambda p: read_mapped(p, JSON_MAP))
        print(f"JSON, {args.json_records} records ({json_path.stat().st_size / 1e6:.0f} MB) through a map that "
              f"resamples: {mapped:.3f} s, {mapped / plain:.1f} x read_log of the same rows as CSV ({plain:.3f} s)")
        mat_path = write_log(simulated_like(round(1000 * args.mat_seconds)), Path(folder) / "run.mat")
        print(f"CSV, {args.csv_rows} rows x 13 columns ({csv_path.stat().st_size / 1e6:.0f} MB): "
              f"{best_seconds(csv_path, args.repeats):.3f} s")
        print(f".mat, {args.mat_seconds:g} s at 1 kHz x 13 columns ({mat_path.stat().st_size / 1e6:.1f} MB): "
              f"{best_seconds(mat_path, args.repeats):.3f} s")


if __name__ == "__main__":
    main()
