"""Discrepancy analysis benchmark: the time of a 60 s log and of a 1e6-row log, with the peak memory of the latter.

    python -m benchmarks.bench_discrepancy [--duration 60] [--rows 1000000] [--workers 2] [--experiment locked]
                                           [--json PATH]

1. A 60 s, 1 kHz testbed log with two hidden effects (made first, not timed), analysed in this process with the
   MuJoCo replay of the held-out part, as ``experiments.discrepancy`` runs it; where the time went (preparation,
   baseline fit, selection and each candidate's fits summed over rounds, model logs, replay).
2. A rigid slide log of ``--rows`` samples at 1 kHz (the slide's swing with a hidden dead time, made first with the
   MuJoCo rigid joint and written as Parquet, not timed), analysed by ``python -m experiments.discrepancy`` in a
   child process: its wall time and peak memory, the child's peak resident set plus its largest worker process's
   times the number of workers (an upper bound of what they held at once).

Targets: the 60 s log within 20 s and the 1e6-row log within 60 s and 2 GB, on 2 cores. The machine is shared:
the 1-minute load average before each run is printed beside it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from experiments.common import write_json
from experiments.synthetic_logs import hidden_effect_log
from sim.discrepancy.analysis import analyse
from sim.discrepancy.rig import rig_to_toml
from sim.discrepancy.signals import AnalysisConfig
from sim.logio import write_log

TARGET_60S_WALL_S = 20.0
TARGET_LARGE_WALL_S = 60.0
TARGET_LARGE_MEMORY_GB = 2.0
# runs the command line in this child and reports its own and its workers' peak resident set [kB] on stderr
MEASURED_CLI = """
import resource, runpy, sys
sys.argv = ["experiments.discrepancy", *sys.argv[1:]]
try:
    runpy.run_module("experiments.discrepancy", run_name="__main__")
finally:
    print("peak_kb", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
          resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)
"""
HIDDEN = {"locked": ["load_dependent_friction", "sensor_offset"], "free": ["coulomb_friction", "cogging"]}


def bench_60s(experiment: str, duration_s: float, workers: int, seed: int) -> dict:
    t0 = time.perf_counter()
    log, rig, _ = hidden_effect_log(experiment, HIDDEN[experiment], seed, duration_s)
    make_s = time.perf_counter() - t0
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    result = analyse(log, rig, AnalysisConfig(workers=workers), progress=False, replay=True)
    wall = time.perf_counter() - t0
    timings = result.baseline["timings_s"]
    per_effect: dict[str, float] = defaultdict(float)
    for round_scores in result.baseline["candidates"]:
        for c in round_scores:
            per_effect[c["effect"]] += c["seconds"]
    print(f"{duration_s:g} s {experiment} testbed log ({len(log)} samples, made in {make_s:.1f} s, not timed), hidden "
          f"{', '.join(HIDDEN[experiment])}; found {', '.join(result.found) or 'nothing'}")
    print(f"  analysis with replay: {wall:.1f} s wall (target {TARGET_60S_WALL_S:g} s: "
          f"{wall / TARGET_60S_WALL_S:.2f}x) with {workers} worker(s); load average before {load:.2f}")
    for key, value in timings.items():
        print(f"    {key:<16s} {value:7.2f} s")
    print(f"    candidate fits summed over {len(result.baseline['candidates'])} round(s), CPU: "
          f"{sum(per_effect.values()):.1f} s")
    for effect, seconds in sorted(per_effect.items(), key=lambda kv: -kv[1])[:6]:
        print(f"      {effect:<30s} {seconds:6.2f} s")
    return {"wall_s": wall, "timings_s": timings, "candidate_fit_s": dict(per_effect), "samples": len(log),
            "found": result.found, "load_average": load}


def bench_large(rows: int, workers: int, seed: int) -> dict:
    t0 = time.perf_counter()
    log, rig, truth = hidden_effect_log("slide", ["transport_delay"], seed, rows / 1000.0)
    make_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as folder:
        log_path, rig_path = Path(folder) / "large.parquet", Path(folder) / "rig.toml"
        write_log(log, log_path)
        rig_path.write_text(rig_to_toml(rig), encoding="utf-8")
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        cli = [str(log_path), "--rig", str(rig_path), "--workers", str(workers), "--no-plot"]
        done = subprocess.run([sys.executable, "-c", MEASURED_CLI, *cli], capture_output=True, text=True)
        wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"the analysis of the large log failed:\n{done.stderr[-2000:]}")
    own_kb, worker_kb = (int(x) for x in done.stderr.strip().splitlines()[-1].split()[1:3])
    peak_gb = (own_kb + workers * worker_kb) / 1024**2
    verdict = next((line for line in done.stdout.splitlines() if line.startswith("Verdict")), "?")
    print(f"{rows} rows ({rows / 1000.0:g} s slide log, made in {make_s:.1f} s, not timed), hidden dead time "
          f"{1e3 * truth.effects['transport_delay']['delay']:.3f} ms; {verdict}")
    print(f"  python -m experiments.discrepancy: {wall:.1f} s wall (target {TARGET_LARGE_WALL_S:g} s: "
          f"{wall / TARGET_LARGE_WALL_S:.2f}x), peak memory {peak_gb:.2f} GB (target {TARGET_LARGE_MEMORY_GB:g} GB: "
          f"the CLI {own_kb / 1024**2:.2f} GB + {workers} x its largest worker {worker_kb / 1024**2:.2f} GB); load "
          f"average before {load:.2f}")
    return {"rows": rows, "wall_s": wall, "peak_memory_gb": peak_gb, "load_average": load, "verdict": verdict}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="length of the testbed log [s] (default 60)")
    parser.add_argument("--rows", type=int, default=1_000_000, help="samples of the large log (default 1e6; 0: skip)")
    parser.add_argument("--workers", type=int, default=2, help="processes for candidate fits (default 2)")
    parser.add_argument("--experiment", choices=sorted(HIDDEN), default="locked")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    out = {"testbed": bench_60s(args.experiment, args.duration, args.workers, args.seed), "workers": args.workers}
    if args.rows:
        out["large"] = bench_large(args.rows, args.workers, args.seed)
    if args.json:
        write_json(args.json, out)


if __name__ == "__main__":
    main()
