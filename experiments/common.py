"""Flags and output helpers shared by the experiment command lines."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from models.gim8108_testbed.build import build_xml, check_time_constants
from models.gim8108_testbed.derived import FIXTURES
from sensor.calibration import InfeasibleCalibrationError
from sensor.protocol import check_params as check_sensor_params
from sim.executor import Executor
from sim.params import ParameterError, TestbedParams, load_params


def cli_parser(doc: str, module: str) -> argparse.ArgumentParser:
    """The parser of ``python -m module``: usage under that name, the module docstring's first paragraph as its
    description (whole sentences, not its first line)."""
    return argparse.ArgumentParser(prog=f"python -m {module}", description=" ".join(doc.split("\n\n")[0].split()))


def data_error(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """Exit 2 with ``message`` in one line, without the usage text: an input file's or a run's error, not a
    mistyped command line (those are ``parser.error``)."""
    parser.exit(2, f"{parser.prog}: error: {message}\n")


def add_executor_args(parser: argparse.ArgumentParser, what: str, workers: int = 1) -> None:
    """``--workers N`` (local processes, default ``workers``) and ``--ray [ADDRESS]`` (a Ray cluster) for the items
    of ``what``."""
    parser.add_argument("--workers", type=positive_int, default=workers, metavar="N",
                        help=f"local processes (default {workers})")
    parser.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help=f"run {what} on a Ray cluster (no address: start one on this machine)")


def executor_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace,
                       progress: Callable[[int, int], None] | None = None) -> Executor:
    """The executor of :func:`add_executor_args`' flags; a Ray that is not installed is a usage error."""
    try:
        return Executor(args.workers, ray=args.ray, progress=progress)
    except RuntimeError as exc:
        parser.error(f"--ray: {exc}")


def add_params_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--params", type=Path, metavar="TOML",
                        help="TOML file overriding parameters, e.g. [friction] breakaway_torque_nm = 0.2")


def load_params_arg(parser: argparse.ArgumentParser, args: argparse.Namespace, checks=(), *,
                    uses_sensor: bool = True) -> TestbedParams:
    """Load --params and check the output flags, before anything runs.

    A bad file, a parameter set the testbed's model cannot be built from (a constraint between fields, such as
    solver time constants the physics step of a fixture cannot resolve: the message names the fields the file
    changed that lengthen the step, and what to set in the file), one that the sensor cannot be read or
    calibrated with (``sensor.protocol.check_params``, unless ``uses_sensor`` is False) or one that a
    callable of ``checks`` (``check(params)``, raising ParameterError) refuses for this experiment becomes a
    command-line error that names the file and the field; so does an output that cannot be written, that
    clashes with another or names the --params file, and a --rerun / --rerun-spawn this machine cannot serve
    (``check_output_paths``).
    """
    checks = (*checks, check_sensor_params) if uses_sensor else tuple(checks)
    check_output_paths(parser, args, inputs={"--params": args.params})
    try:
        params = load_params(args.params)  # its errors name the file
    except ParameterError as exc:
        data_error(parser, str(exc))
    try:
        check_time_constants(params, FIXTURES, source=args.params)
        for fixture in FIXTURES:
            build_xml(params, fixture)
        for check in checks:
            check(params)
    except ParameterError as exc:
        data_error(parser, f"{args.params}: {exc}" if args.params is not None else str(exc))
    return params


@contextmanager
def run_errors(parser: argparse.ArgumentParser):
    """Turn what a parameter set can only show once it runs into a command-line error: an infeasible sensor
    calibration (the sensor parameters leave residuals the paper's 0.2 % FS bound cannot hold)."""
    try:
        yield
    except InfeasibleCalibrationError as exc:
        data_error(parser, f"{str(exc).rstrip('.')}. The sensor's parameters leave the QP calibration no solution "
                     f"within the paper's error bound: look at photoreflector.noise_min_v / noise_max_v, "
                     f"adc_bits, bandwidth_hz (its lag on the loading ramps), the slip fractions (hysteresis) and "
                     f"the optical curvature fractions")


OUTPUT_FILE_FLAGS = ("json", "rerun", "save_rig")  # flags naming a file a run writes
OUTPUT_DIR_FLAGS = ("plot", "out")  # flags naming a directory a run writes its files in
RERUN_SUFFIX = ".rrd"  # the rerun viewer opens a recording by this suffix
Inputs = Mapping[str, Path | Sequence[Path] | None]  # an input's flag (or positional name) -> its path(s)


def check_output_paths(parser: argparse.ArgumentParser, args: argparse.Namespace, inputs: Inputs | None = None
                       ) -> None:
    """Refuse, before any simulation, an output the run could not write at its end.

    Checked: no output (--json, --rerun, --save-rig, each file --plot writes, as the command declared them with
    :func:`add_output_args`) is one of ``inputs`` (flag -> the path or paths read by the run, None ignored), the
    same file as another output or a file where another output needs a folder; --json, --rerun and --save-rig
    name a file (not a directory) in a directory that exists or can be created, and is writable; --rerun ends in
    .rrd; --save-rig does not exist yet (it is never replaced); --plot and --out (a directory of outputs) are
    directories or can be created, and are writable. A usage error names both flags of a clash. Then
    :func:`check_recording`.
    """
    _check_clashes(parser, _output_files(args), _output_dirs(args), _input_paths(inputs or {}))
    for flag in OUTPUT_FILE_FLAGS:
        if getattr(args, flag, None) is not None:
            _check_output_file(parser, _option(flag), Path(getattr(args, flag)))
    for option, directory in _output_dirs(args):
        if directory.exists() and not directory.is_dir():
            parser.error(f"{option} {directory} exists and is not a directory")
        _check_writable(parser, option, directory)
    check_recording(parser, args)


def _option(flag: str) -> str:
    """'save_rig' -> '--save-rig'."""
    return f"--{flag.replace('_', '-')}"


def _input_paths(inputs: Inputs) -> dict[Path, tuple[str, Path]]:
    """Each input's resolved path -> (its flag, the path as given)."""
    read: dict[Path, tuple[str, Path]] = {}
    for flag, paths in inputs.items():
        for path in [paths] if isinstance(paths, (str, os.PathLike)) else paths or ():
            read.setdefault(Path(path).resolve(), (flag, Path(path)))
    return read


def _output_files(args: argparse.Namespace) -> list[tuple[str, Path, str | None]]:
    """The files a run writes, as (flag, path, name): --json, --rerun and --save-rig (name None), then each
    file the command declared an output folder gets (``args.plot_files`` for --plot, :func:`add_output_args`;
    ``args.out_files`` for --out) in that folder."""
    files = [(_option(f), Path(getattr(args, f)), None) for f in OUTPUT_FILE_FLAGS
             if getattr(args, f, None) is not None]
    for flag in OUTPUT_DIR_FLAGS:
        if getattr(args, flag, None) is not None:
            files += [(_option(flag), Path(getattr(args, flag)) / name, name)
                      for name in getattr(args, f"{flag}_files", ())]
    return files


def _output_dirs(args: argparse.Namespace) -> list[tuple[str, Path]]:
    """The folders a run writes its files in, as (flag, path): --plot, --out."""
    return [(_option(f), Path(getattr(args, f))) for f in OUTPUT_DIR_FLAGS if getattr(args, f, None) is not None]


def _check_clashes(parser: argparse.ArgumentParser, files: list[tuple[str, Path, str | None]],
                   dirs: list[tuple[str, Path]], read: dict[Path, tuple[str, Path]]) -> None:
    """parser.error, naming both flags, if an output file is an input, two outputs are one file, or an output
    file (--json, --rerun, --save-rig) sits where another output needs a folder (the same path, or a parent)."""
    written: dict[Path, tuple[str, Path, str | None]] = {}
    for flag, path, name in files:
        key = path.resolve()
        if key in read:
            parser.error(_input_clash(flag, path, name, *read[key]))
        if key in written:
            parser.error(_same_file(written[key], (flag, path, name)))
        written[key] = (flag, path, name)
    named = [(flag, path) for flag, path, name in files if name is None]
    for file in named:
        for other in dirs + named:
            if other[0] != file[0]:
                _check_not_inside(parser, file, other, dirs)


def _check_not_inside(parser: argparse.ArgumentParser, file: tuple[str, Path], other: tuple[str, Path],
                      dirs: list[tuple[str, Path]]) -> None:
    """parser.error if the output ``other`` (flag, path) needs the output file ``file`` to be a folder."""
    (flag, path), (other_flag, other_path) = file, other
    if other in dirs and other_path.resolve() == path.resolve():
        parser.error(f"{flag} {path} and {other_flag} {other_path} name the same path, {flag} a file and "
                     f"{other_flag} a folder; give each its own")
    if path.resolve() in other_path.resolve().parents:
        parser.error(f"{other_flag} {other_path} is inside {flag} {path}, which is a file; give each its own path")


def _input_clash(flag: str, path: Path, name: str | None, input_flag: str, input_path: Path) -> str:
    """The error of an output that would overwrite an input."""
    if name is None:
        return (f"{flag} {path} is an input of this run ({input_flag}); inputs are never overwritten: give {flag} "
                f"another file")
    return (f"{flag} {path.parent} would write {name} over {input_flag} {input_path}, an input of this run; inputs "
            f"are never overwritten: give {flag} another folder")


def _same_file(first: tuple[str, Path, str | None], second: tuple[str, Path, str | None]) -> str:
    """The error of two outputs naming one file (``first`` is --json, --rerun or --save-rig)."""
    (flag, path, _), (other_flag, other_path, name) = first, second
    if name is None:
        return f"{flag} and {other_flag} name the same file, {path}; give each its own"
    return (f"{flag} {path} is the file {other_flag} {other_path.parent} writes {name} to; give {flag} another file "
            f"or {other_flag} another folder")


def _check_output_file(parser: argparse.ArgumentParser, option: str, path: Path) -> None:
    """parser.error unless ``path`` can be written as the file of ``option`` (--json, --rerun, --save-rig)."""
    if path.is_dir():
        example = path / {"--json": "result.json", "--rerun": "run.rrd"}.get(option, "rig.toml")
        parser.error(f"{option} {path} is a directory; give a file name, e.g. {example}")
    if option == "--rerun" and path.suffix != RERUN_SUFFIX:
        parser.error(f"{option} {path}: a rerun recording is a {RERUN_SUFFIX} file (the viewer opens it by "
                     f"that suffix); e.g. {path.with_suffix(RERUN_SUFFIX)}")
    if option == "--save-rig" and path.exists():
        parser.error(f"{option} {path} exists; choose a new file (an existing file is never replaced)")
    _check_writable(parser, option, path.parent)
    if path.exists() and not os.access(path, os.W_OK):
        parser.error(f"{option} {path} exists and cannot be written")


def _check_writable(parser: argparse.ArgumentParser, flag: str, directory: Path) -> None:
    """parser.error unless a file can be created in ``directory`` or, if it does not exist yet, in its nearest
    existing ancestor (probed with a temporary file that is removed at once)."""
    existing = directory.resolve()
    while not existing.exists():
        existing = existing.parent
    try:
        if not existing.is_dir():
            raise NotADirectoryError(f"{existing} is not a directory")
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        parser.error(f"{flag}: cannot write under {existing} ({exc.strerror or exc})")


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
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(data), indent=2, ensure_ascii=False) + "\n")


def write_outputs(args: argparse.Namespace, data: dict[str, Any], plot=None, run: dict[str, Any] | None = None
                  ) -> None:
    """The CLIs' --json and --plot: write ``data`` as JSON, with the run's settings under "run" (``run_settings``
    and the CLI's own ``run`` entries), and say where; call ``plot(directory)`` (returning a figure path or a list
    of them) and print each figure's path. Nothing for an option not given."""
    if getattr(args, "json", None):
        write_json(args.json, {**data, "run": {**run_settings(args), **(run or {})}})
        print(f"wrote {args.json}")
    if plot is not None and getattr(args, "plot", None):
        if not args.plot.exists():
            print(f"creating the --plot directory {args.plot}")
        paths = plot(args.plot)
        for path in paths if isinstance(paths, (list, tuple)) else [paths]:
            print(f"figure: {path}")


# ---------------------------------------------------------------- closed-loop experiments
FEEDBACK_CHOICES = ("current", "sensor", "both")


def add_experiment_args(parser: argparse.ArgumentParser, *, feedback: bool = True,
                        figures: Sequence[str] = ()) -> None:
    """The flags every closed-loop experiment takes: --feedback, --seed, --duration, --json, --plot (writing
    ``figures``, see :func:`add_output_args`), --params, --rerun, --rerun-spawn."""
    if feedback:
        parser.add_argument("--feedback", choices=FEEDBACK_CHOICES, default="both",
                            help="torque measurement the PI closes on (default both)")
    parser.add_argument("--seed", type=seed_arg, default=0, help="seed of the sensor noise (default 0)")
    parser.add_argument("--duration", type=run_seconds, metavar="S",
                        help=f"run every test for about S seconds instead of its full length, "
                             f"{MIN_DURATION_S:g}-{MAX_DURATION_S:g} (a quick check: the figures are then not "
                             f"comparable with the paper's)")
    add_output_args(parser, figures=figures)
    add_params_arg(parser)
    add_rerun_args(parser)


def add_output_args(parser: argparse.ArgumentParser, json_help: str = "write the results as JSON",
                    figures: Sequence[str] = ()) -> None:
    """--json PATH and --plot DIR (default out/): every experiment saves its figures unless told where.

    ``figures`` are the names of the files --plot writes in DIR; they become ``args.plot_files``, which
    :func:`check_output_paths` checks against the other outputs and the inputs before the run.
    """
    parser.add_argument("--json", type=Path, metavar="PATH", help=json_help)
    parser.add_argument("--plot", type=Path, metavar="DIR", default=Path("out"),
                        help=f"write {', '.join(figures) or 'the PNG figures'} in DIR (default out/)")
    parser.set_defaults(plot_files=tuple(figures))
    parser.add_argument("--no-plot", dest="plot", action="store_const", const=None,
                        help="save no figures")


def add_no_figures_arg(parser: argparse.ArgumentParser) -> None:
    """--no-plot for a command that draws no figures: accepted, as every experiment accepts it; changes nothing."""
    parser.add_argument("--no-plot", dest="plot", action="store_const", const=None, default=None,
                        help="accepted as by every experiment; this command draws no figures")


# ---------------------------------------------------------------- rerun recordings
def add_rerun_args(parser: argparse.ArgumentParser, what: str = "every run's log (3D testbed and time series)") -> None:
    """--rerun PATH.rrd and --rerun-spawn: record ``what`` with :mod:`sim.recording`."""
    parser.add_argument("--rerun", type=Path, metavar="PATH.rrd", help=f"write a rerun recording of {what}")
    parser.add_argument("--rerun-spawn", action="store_true", help=f"open the rerun viewer on {what}")


def rerun_requested(args: argparse.Namespace) -> bool:
    """Whether --rerun or --rerun-spawn was given (keep or build logs only then)."""
    return bool(getattr(args, "rerun", None) or getattr(args, "rerun_spawn", False))


def check_recording(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse in one line (exit status 2, before anything runs) a --rerun or --rerun-spawn this machine cannot
    serve: rerun disabled by the environment (``RERUN=off``), or, for the viewer, no display or no viewer
    executable (:func:`sim.recording.viewer_unavailable`). The command line is right, so no usage text."""
    if not rerun_requested(args):
        return
    from sim.recording import rerun_disabled, viewer_unavailable

    disabled = rerun_disabled()
    if disabled:
        flag = "--rerun-spawn" if getattr(args, "rerun_spawn", False) else "--rerun"
        parser.exit(2, f"{parser.prog}: error: {flag}: {disabled}; unset RERUN (or set RERUN=on) to record\n")
    reason = viewer_unavailable() if getattr(args, "rerun_spawn", False) else None
    if reason:
        parser.exit(2, f"{parser.prog}: error: --rerun-spawn: {reason}; record to a file instead with --rerun "
                       f"PATH.rrd and open it with `rerun PATH.rrd` where a viewer can open\n")


def record_rerun(args: argparse.Namespace, logs, params: TestbedParams | None = None, series=None) -> None:
    """Record ``logs`` (run name -> :class:`sim.runlog.RunLog`) and their extra ``series`` (run name -> group ->
    RunLog, see :func:`sim.recording.record_series`) as --rerun / --rerun-spawn ask (nothing if neither was
    given). Either may be a function returning it, called only when recording.

    A viewer that does not start or take the recording (:class:`sim.recording.ViewerError`, after bounded waits)
    is said in one line on stderr; the --rerun file is still written and the command goes on.
    """
    if not rerun_requested(args):
        return
    from sim.recording import ViewerError, record_logs

    if callable(logs):
        logs = logs()
    if callable(series):
        series = series()
    try:
        summary = record_logs(logs, params, path=args.rerun, spawn=args.rerun_spawn, series=series)
    except ViewerError as exc:
        kept = f"; writing {args.rerun} without it" if args.rerun else "; the run's other outputs are written"
        print(f"--rerun-spawn: no rerun viewer: {exc}{kept}", file=sys.stderr, flush=True)
        if not args.rerun:
            return
        summary = record_logs(logs, params, path=args.rerun, series=series)
    if summary.path is not None:
        print(f"rerun recording: {summary.path} ({len(summary.runs)} runs)")
    if summary.viewer is not None:
        print(f"rerun viewer: {len(summary.runs)} runs sent to {summary.viewer}")


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


MIN_DURATION_S = 0.01  # [s] ten 1 kHz control ticks: the shortest run whose errors are defined
SHORTEST_FULL_TEST_S = 0.4  # [s] the fast push of experiments.admittance: below it every test is cut short
# [s] the full tests last 4.4-38 s (the disturbance ramp is the longest); a log keeps ~25 columns of float64 per
# 1 kHz tick, ~200 B/tick, so 120 s is ~24 MB per test and ~340 MB for experiments.paper's 14 closed-loop runs
MAX_DURATION_S = 120.0


def run_seconds(text: str) -> float:
    """argparse type of --duration: seconds within [MIN_DURATION_S, MAX_DURATION_S]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not MIN_DURATION_S <= value <= MAX_DURATION_S:  # also refuses nan
        raise argparse.ArgumentTypeError(f"{text} s: valid range [{MIN_DURATION_S:g}, {MAX_DURATION_S:g}] s")
    return value


def _integer_at_least(text: str, low: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"{value}: valid {what} are integers >= {low}")
    return value


def seed_arg(text: str) -> int:
    """argparse type of --seed: an integer >= 0 (numpy's seed sequences take no negative entropy)."""
    return _integer_at_least(text, 0, "seeds")


def positive_int(text: str) -> int:
    """argparse type of a count: an integer >= 1."""
    return _integer_at_least(text, 1, "values")


def run_settings(args: argparse.Namespace) -> dict[str, Any]:
    """What a result depends on besides the parameters: the seed, the --params file, and for a CLI with
    --duration that duration [s] and whether the figures are comparable with the paper's (full length)."""
    settings: dict[str, Any] = {"seed": getattr(args, "seed", None),
                                "params": str(args.params) if getattr(args, "params", None) else None}
    if hasattr(args, "duration"):
        settings |= {"duration_s": args.duration, "full_length": args.duration is None}
    return settings


def software_versions() -> dict[str, str]:
    """Versions of what a result was computed with: torquebed, Python, NumPy, SciPy, MuJoCo."""
    import importlib.metadata
    import platform

    versions = {"python": platform.python_version()}
    for name in ("torquebed", "numpy", "scipy", "mujoco"):
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def short_run_banner(args: argparse.Namespace) -> None:
    """With --duration, say before the tables that their figures are not comparable with the paper's."""
    if getattr(args, "duration", None) is not None:
        kind = "SHORT RUN" if args.duration < SHORTEST_FULL_TEST_S else "RUN AT A SET LENGTH"
        print(f"{kind} (--duration {args.duration:g} s): the tests' holds, windows and pushes were set from it "
              f"instead of the paper protocol's; the figures below are not comparable with the paper's")


def feedback_kinds(choice: str) -> tuple[str, ...]:
    """'both' -> ('current', 'sensor'); otherwise the one named."""
    return ("current", "sensor") if choice == "both" else (choice,)


TARGET_RATIO = 1.5  # the target band: every simulated figure within a factor 1.5 of the paper's


def outside_band(ratio: float | None, band: float = TARGET_RATIO) -> bool:
    """Whether a sim/paper ratio lies outside [1/band, band]; a ratio <= 0 does, a missing one (None) does not."""
    return ratio is not None and (ratio <= 0.0 or abs(math.log(ratio)) > math.log(band))


PRIMARY, ALTERNATIVE = "primary", "alternative"  # the readings of a paper figure a row compares under


def paper_row(table: str, quantity: str, unit: str, paper: float | None, sim: float | None, *,
              reading: str = PRIMARY, reason: str | None = None) -> dict[str, Any]:
    """One row of a paper-vs-simulation table; ratio = sim / paper (None if either is missing or paper is 0).

    ``reading``: ``"primary"`` (the paper's stated definition; the row has no ``reading`` key) or
    ``"alternative"`` (another reading the paper's text allows, its ``paper`` value converted to it where the
    conversion is defined; the row carries ``"reading": "alternative"`` and ``reason``, one sentence saying
    why the paper can be read so).
    """
    if reading not in (PRIMARY, ALTERNATIVE):
        raise ValueError(f"reading = {reading!r}: valid values are {PRIMARY!r}, {ALTERNATIVE!r}")
    if (reading == ALTERNATIVE) != bool(reason):
        raise ValueError("reason: an alternative reading needs one (a sentence saying why), a primary row has none")
    ratio = sim / paper if (paper and sim is not None and math.isfinite(sim)) else None
    row = {"table": table, "quantity": quantity, "unit": unit, "paper": paper, "sim": sim, "ratio": ratio}
    return row if reading == PRIMARY else {**row, "reading": ALTERNATIVE, "reason": reason}


def is_primary(row: dict[str, Any]) -> bool:
    """Whether a paper row compares under the paper's stated definition (it has no ``"reading": "alternative"``)."""
    return row.get("reading", PRIMARY) != ALTERNATIVE


def format_rows(title: str, rows: list[dict[str, Any]], band: float | None = TARGET_RATIO) -> str:
    """Plain-text table of paper rows: quantity, paper, simulation, ratio; a ratio outside [1/band, band] is
    marked (``band=None``: no marks). Rows of alternative readings (:func:`is_primary` false) follow in a table
    of their own, each with its reason."""
    primary = [r for r in rows if is_primary(r)]
    alternatives = [r for r in rows if not is_primary(r)]
    text = _table(title, primary, band)
    if alternatives:
        text += "\n\n" + _table("Alternative readings of the paper's definitions: where the paper does not say how "
                                 "a figure was taken (which window, which samples), the same figure taken another "
                                 "way, to show how much the definition matters; not the result above and never "
                                 "counted in it", alternatives, band)
    return text


def _table(title: str, rows: list[dict[str, Any]], band: float | None) -> str:
    width = max([len(r["quantity"]) for r in rows] + [8])
    table_width = max([len(r["table"]) for r in rows] + [8])
    lines = [title, f"{'table':{table_width}s} {'quantity':{width}s} {'unit':5s} {'paper':>9s} {'sim':>9s} "
                    f"{'ratio':>6s}"]

    def num(x: float | None) -> str:
        return f"{x:9.4g}" if x is not None else f"{'-':>9s}"

    for r in rows:
        ratio = f"{r['ratio']:6.2f}" if r["ratio"] is not None else f"{'-':>6s}"
        off = band is not None and outside_band(r["ratio"], band)
        lines.append(f"{r['table']:{table_width}s} {r['quantity']:{width}s} {r['unit']:5s} {num(r['paper'])} "
                     f"{num(r['sim'])} {ratio}{f'  <- outside a factor {band:g}' if off else ''}")
        if not is_primary(r):
            lines.append(f"{'':{table_width}s}   why: {r['reason']}")
    return "\n".join(lines)
