"""Flags and output helpers shared by the experiment command lines."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from sim.params import ParameterError, TestbedParams, load_params


def add_params_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params", type=Path, metavar="TOML",
                        help="TOML file overriding parameters, e.g. [friction] breakaway_torque_nm = 0.2")


def load_params_arg(parser: argparse.ArgumentParser, args: argparse.Namespace) -> TestbedParams:
    """Load --params, turning a bad file into a command-line error that names the field."""
    try:
        return load_params(args.params)
    except ParameterError as exc:
        parser.error(str(exc))


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(data), indent=2, ensure_ascii=False) + "\n")


def write_outputs(args: argparse.Namespace, data: dict[str, Any], plot=None) -> None:
    """The CLIs' --json and --plot: write ``data`` as JSON and say where; call ``plot(directory)`` (returning a
    figure path or a list of them) and print each figure's path. Nothing for an option not given."""
    if getattr(args, "json", None):
        write_json(args.json, data)
        print(f"wrote {args.json}")
    if plot is not None and getattr(args, "plot", None):
        paths = plot(args.plot)
        for path in paths if isinstance(paths, (list, tuple)) else [paths]:
            print(f"figure: {path}")


# ---------------------------------------------------------------- closed-loop experiments (issue 4)
FEEDBACK_CHOICES = ("current", "sensor", "both")


def add_experiment_args(parser: argparse.ArgumentParser, *, feedback: bool = True) -> None:
    """The flags every closed-loop experiment takes: --feedback, --seed, --duration, --json, --plot, --params,
    --rerun, --rerun-spawn."""
    if feedback:
        parser.add_argument("--feedback", choices=FEEDBACK_CHOICES, default="both",
                            help="torque measurement the PI closes on (default both)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    parser.add_argument("--duration", type=positive_seconds, metavar="S",
                        help="shorten every test to S seconds (a quick check; the paper's figures need the "
                             "full length)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the results as JSON")
    parser.add_argument("--plot", type=Path, metavar="DIR", default=Path("out"),
                        help="save PNG figures in DIR (default out/)")
    add_params_arg(parser)
    add_rerun_args(parser)


# ---------------------------------------------------------------- rerun recordings (issue 5)
def add_rerun_args(parser: argparse.ArgumentParser, what: str = "every run's log (3D testbed and time series)") -> None:
    """--rerun PATH.rrd and --rerun-spawn: record ``what`` with :mod:`sim.recording`."""
    parser.add_argument("--rerun", type=Path, metavar="PATH.rrd", help=f"write a rerun recording of {what}")
    parser.add_argument("--rerun-spawn", action="store_true", help=f"open the rerun viewer on {what}")


def rerun_requested(args: argparse.Namespace) -> bool:
    """Whether --rerun or --rerun-spawn was given (keep or build logs only then)."""
    return bool(getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False))


def record_rerun(args: argparse.Namespace, logs, params: TestbedParams | None = None, series=None) -> None:
    """Record ``logs`` (run name -> :class:`sim.runlog.RunLog`) and their extra ``series`` (run name -> group ->
    RunLog, see :func:`sim.recording.record_series`) as --rerun / --rerun-spawn ask (nothing if neither was
    given). Either may be a function returning it, called only when recording."""
    if not rerun_requested(args):
        return
    from sim.recording import record_logs

    if callable(logs):
        logs = logs()
    if callable(series):
        series = series()

    summary = record_logs(logs, params, path=args.rerun, spawn=args.rerun_spawn, series=series)
    if summary.path is not None:
        print(f"rerun recording: {summary.path} ({len(summary.runs)} runs)")


def record_log(time_s, voltages_v, *, tau_sensor_nm=None, tau_mini85_nm=None, tau_applied_nm=None,
               temperature_c=None, meta: dict | None = None):
    """A :class:`sim.runlog.RunLog` of a sensor record without mechanics (calibration rig, chamber): time [s],
    channel voltages (N, 8) [V] as v1..v8, and the torques [N·m] and TMP117 temperature [°C] given."""
    from sim.runlog import RunLog, add_voltage_columns

    columns = {"time": np.asarray(time_s, dtype=float)}
    units = {"time": "s"}
    add_voltage_columns(columns, units, voltages_v)
    for name, values, unit in (("tau_sensor", tau_sensor_nm, "N·m"), ("tau_mini85", tau_mini85_nm, "N·m"),
                               ("tau_applied", tau_applied_nm, "N·m"), ("temperature", temperature_c, "°C")):
        if values is not None:
            columns[name], units[name] = np.asarray(values, dtype=float), unit
    return RunLog(columns, units, {"fixture": "calibration rig", **(meta or {})})


def positive_seconds(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"--duration {text}: must be > 0 s")
    return value


def feedback_kinds(choice: str) -> tuple[str, ...]:
    """'both' -> ('current', 'sensor'); otherwise the one named."""
    return ("current", "sensor") if choice == "both" else (choice,)


# The load cell's reading noise (amplifier and ADC), white at the 1 kHz sampling rate [N]. Identified from the
# paper's Table VI: the sensor-feedback step errors are flat (0.0026, 0.0026, 0.0025 N·m) across step sizes, a
# measurement floor; the simulated loop alone leaves ~0.0005 N·m, so sqrt(0.0026² - 0.0005²) / 0.1 m ≈ 0.025 N
# (experiments/identify_defaults.py). That is 0.005 % of the SBA-50L's 500 N capacity, what a 24-bit
# strain-gauge amplifier gives. Defined here, not in sim.params: it is added to the logged force after a run (the
# plant's loop never sees it), and by the one function below.
LOADCELL_READING_NOISE_N = 0.025
LOADCELL_NOISE_STREAM = 0x10AD  # spawn key separating the load cell's noise from the sensor's for one seed


def loadcell_torque_nm(log, seed: int | None = None, noise_n: float = LOADCELL_READING_NOISE_N) -> np.ndarray:
    """The torque the load cell reports, force x lever length [N·m], from a run log.

    With ``seed`` the reading carries the load cell's white noise (``noise_n`` [N] standard deviation, drawn
    from its own stream of ``seed``); without it, the true force.
    """
    torque = log["force_loadcell"] * log.meta["lever_length_m"]
    if seed is None or noise_n == 0.0:
        return torque
    rng = np.random.default_rng([seed, LOADCELL_NOISE_STREAM])
    return torque + rng.normal(0.0, noise_n * log.meta["lever_length_m"], len(torque))


def paper_row(table: str, quantity: str, unit: str, paper: float | None, sim: float | None) -> dict[str, Any]:
    """One row of a paper-vs-simulation table; ratio = sim / paper (None if either is missing or paper is 0)."""
    ratio = sim / paper if (paper and sim is not None and math.isfinite(sim)) else None
    return {"table": table, "quantity": quantity, "unit": unit, "paper": paper, "sim": sim, "ratio": ratio}


def format_rows(title: str, rows: list[dict[str, Any]]) -> str:
    """Plain-text table of paper rows: quantity, paper, simulation, ratio."""
    width = max([len(r["quantity"]) for r in rows] + [8])
    lines = [title, f"{'table':8s} {'quantity':{width}s} {'unit':5s} {'paper':>9s} {'sim':>9s} {'ratio':>6s}"]

    def num(x: float | None) -> str:
        return f"{x:9.4g}" if x is not None else f"{'-':>9s}"

    for r in rows:
        ratio = f"{r['ratio']:6.2f}" if r["ratio"] is not None else f"{'-':>6s}"
        lines.append(f"{r['table']:8s} {r['quantity']:{width}s} {r['unit']:5s} {num(r['paper'])} "
                     f"{num(r['sim'])} {ratio}")
    return "\n".join(lines)
