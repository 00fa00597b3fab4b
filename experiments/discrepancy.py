"""What the simulation gets wrong on a measured log, which effect causes it, and how much the fix predicts.

    python -m experiments.discrepancy LOG [LOG ...] --rig RIG.toml [--validate LOG ...] [--json OUT] [--plot DIR]
                                      [--save-rig OUT.toml] [--workers N | --ray [ADDRESS]] [--no-replay] [--unwrap]
                                      [--max-jitter FRACTION] [--log KEY=VALUE ...] [--rerun PATH.rrd]
                                      [--rerun-spawn]

LOG is a run log (CSV, Parquet, .mat or JSON, docs/run_log_format.md), or a drive's own record read through the
rig's [log] table or --log KEY=VALUE options (docs/own_logs.md); several logs of one rig are fitted together.
RIG.toml describes what produced them (docs/discrepancy.md); the joint (hinge or slide) comes from the rig.
--validate names validation logs: the estimation logs are then fitted whole and every candidate and the final
model are scored on the validation logs. No input file is modified. Progress goes to stderr.

--rerun / --rerun-spawn record the measured log as the run ``/measured_<LOG stem>``: a testbed log with the
plant's columns as a simulated run is (3D testbed, torques, voltages, temperature) plus its angles under
``position/`` [rad]; a rigid-joint log as its command under ``effort/`` and its position under ``position/``
(no 3D). Beside them the residual channels before and after the findings (``residual_<channel>/baseline``,
``.../extended``) and, when the replay ran, the measured against the baseline and extended rig's replayed
signal (``replay/measured``, ``replay/baseline``, ``replay/extended``, in the replayed signal's unit).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from experiments.common import (
    add_executor_args,
    add_output_args,
    add_rerun_args,
    check_output_paths,
    cli_parser,
    data_error,
    record_rerun,
    software_versions,
    write_outputs,
)
from sim.discrepancy.analysis import DiscrepancyResult, analyse
from sim.discrepancy.checks import InputError
from sim.discrepancy.report import PLOT_FILES, format_result, plot_result
from sim.discrepancy.rig import Rig, RigError, load_rig, save_rig
from sim.discrepancy.signals import AnalysisConfig
from sim.logio import LogError, read_log
from sim.logmap import LogMapError, log_map_from_dict, mapped_names, read_mapped, with_options
from sim.runlog import RunLog

# log column -> series name under /<run>/position
POSITION_SERIES = {"testbed": (("q", "lever"), ("q_motor", "motor")), "rigid-joint": (("q", "joint"),)}


def run_name(log_path: Path) -> str:
    """The measured log's run name in a recording: 'measured <file stem>'."""
    return f"measured {log_path.stem}"


def measured_run(log: RunLog, rig: Rig) -> RunLog:
    """The measured log as :func:`sim.recording.record_run` draws it: a testbed log with the rig's fixture and
    lever length (3D testbed and torque series from its columns); a rigid-joint log without columns (its
    command and position go to :func:`measured_series`; no 3D)."""
    if rig.model == "testbed":
        return RunLog(log.columns, log.units, {**log.meta, "fixture": rig.fixture,
                                               "lever_length_m": rig.params.lever.length_m})
    return RunLog({"time": log["time"]}, {"time": "s"}, {**log.meta, "fixture": f"rigid-joint {rig.joint}"})


def _group(time_s, series: dict[str, tuple]) -> RunLog:
    """A series group: name -> (values, unit) on ``time_s`` [s]."""
    return RunLog({"time": time_s, **{k: v for k, (v, _) in series.items()}},
                  {"time": "s", **{k: u for k, (_, u) in series.items()}})


def measured_series(log: RunLog, rig: Rig, result: DiscrepancyResult) -> dict[str, RunLog]:
    """Extra series of the measured run (group -> RunLog): positions, the rigid joint's command, the residual
    channels before and after the findings, and the replay of the held-out part if it ran."""
    t = log["time"]
    positions = {name: (log[c], log.units[c]) for c, name in POSITION_SERIES[rig.model] if c in log.columns}
    groups = {"position": _group(t, positions)} if positions else {}
    if rig.model != "testbed":
        groups["effort"] = _group(t, {"command": (log["tau_cmd"], log.units["tau_cmd"])})
    for c, before in result.residuals_baseline.items():
        groups[f"residual {c}"] = _group(result.time, {"baseline": (before, result.units[c]),
                                                       "extended": (result.residuals_final[c], result.units[c])})
    r = result.replay
    if r:
        groups["replay"] = _group(r["time"], {"measured": (r["measured"], r["unit"]),
                                              "baseline": (r["simulated_baseline"], r["unit"]),
                                              "extended": (r["simulated_extended"], r["unit"])})
    return groups


def _names(paths: list[Path]) -> tuple[str, ...]:
    """The logs' names in the report: their file names, or their paths where two file names are the same."""
    short = [p.name for p in paths]
    return tuple(name if short.count(name) == 1 else str(p) for name, p in zip(short, paths, strict=True))


def jitter_fraction(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise ValueError(text)
    return value


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("log", type=Path, nargs="+",
                        help="run log(s) or records of one rig (.csv, .parquet, .mat, .json), fitted together")
    parser.add_argument("--rig", type=Path, required=True, metavar="TOML", help="rig description")
    parser.add_argument("--validate", type=Path, nargs="+", default=[], metavar="LOG",
                        help="validation log(s) of the same rig: fit the estimation logs whole, score on these")
    parser.add_argument("--unwrap", action="store_true",
                        help="unwrap hinge angles that jump by 2π (an encoder wrapped to one turn)")
    parser.add_argument("--max-jitter", type=jitter_fraction, default=0.05, metavar="FRACTION",
                        help="largest accepted relative deviation of a sampling step from the median step "
                             "(default 0.05; servo logs with irregular sampling may need more)")
    parser.add_argument("--log", dest="log_options", action="append", default=[], metavar="KEY=VALUE",
                        help="how the records map onto the run log, as in the rig's [log] table and laid over it: "
                             "columns.tau_cmd='vir * gtau', units.q=deg, resample='5 ms', enable=torque_enable, "
                             "twos_complement.pwm=16, records=samples (docs/own_logs.md)")
    add_output_args(parser, "write the result as JSON", PLOT_FILES)
    parser.add_argument("--save-rig", type=Path, metavar="TOML", help="write the extended rig (must not exist)")
    add_executor_args(parser, "the candidate fits", workers=2)
    parser.add_argument("--no-replay", action="store_true", help="skip the MuJoCo replay of the held-out part")
    add_rerun_args(parser, "the measured log (3D testbed if it has the plant's columns, time series), the "
                           "residuals before and after, and the replay of the held-out part if it ran")
    args = parser.parse_args(argv)
    paths = [*args.log, *args.validate]
    check_output_paths(parser, args, inputs={"LOG": args.log, "--validate": args.validate, "--rig": args.rig})
    try:
        rig = load_rig(args.rig)
    except RigError as exc:
        data_error(parser, str(exc))
    except OSError as exc:  # a directory, no permission
        data_error(parser, f"rig file {args.rig} cannot be read: {exc.strerror or exc}")
    if args.log_options:
        try:
            table = with_options(rig.log_map.to_dict() if rig.log_map else {}, args.log_options)
            rig = dataclasses.replace(rig, log_map=log_map_from_dict(table))
        except LogMapError as exc:
            parser.error(f"--log: {exc}")
    logs, names, roles, sources = [], [], [], []
    for i, (path, name) in enumerate(zip(paths, _names(paths), strict=True)):
        try:
            if rig.log_map is None:
                found, found_names = [read_log(path, joint=rig.joint, max_jitter=args.max_jitter)], [name]
            else:
                record = read_mapped(path, rig.log_map, joint=rig.joint, max_jitter=args.max_jitter)
                found, found_names = list(record.logs), mapped_names(name, len(record.logs))
                print("\n".join(f"{name}: {note}" for note in record.notes))
        except LogError as exc:  # its message names the file
            data_error(parser, str(exc))
        except OSError as exc:
            data_error(parser, f"{path} cannot be read: {exc.strerror or exc}")
        logs += found
        names += found_names
        roles += ["estimation" if i < len(args.log) else "validation"] * len(found)
        sources += [path] * len(found)
    n = roles.count("estimation")
    config = AnalysisConfig(workers=args.workers, ray=args.ray)
    try:
        result = analyse(logs[0], rig, config, progress=True,
                         replay=not args.no_replay, also=tuple(logs[1:n]), validation=tuple(logs[n:]),
                         names=tuple(names), unwrap=args.unwrap)
    except InputError as exc:
        data_error(parser, f"{args.log[0] if n == 1 and not args.validate else 'the logs'}: {exc}")
    except (RigError, ValueError) as exc:
        data_error(parser, str(exc))
    print(format_result(result))
    write_outputs(args, result.to_dict(), lambda directory: plot_result(result, directory),
                  run=_run_entries(args, sources, names, roles, logs, config))
    if args.save_rig:
        header = (f"Extended rig written by experiments.discrepancy from {', '.join(p.name for p in paths)} and "
                  f"{args.rig.name}.\n"
                  f"Findings: {', '.join(result.found) or 'none'}.")
        args.save_rig.parent.mkdir(parents=True, exist_ok=True)
        print(f"wrote {save_rig(result.extended_rig, args.save_rig, header=header)}")
    name = run_name(args.log[0])
    record_rerun(args, lambda: {name: measured_run(logs[0], rig)}, rig.params,
                 lambda: {name: measured_series(logs[0], rig, result)})
    sys.stdout.flush()


def _run_entries(args: argparse.Namespace, sources: list[Path], names: list[str], roles: list[str], logs: list,
                 config: AnalysisConfig) -> dict:
    """What was run, for the JSON's "run" section: each log (path, role, samples, duration [s]; for a mapped record
    its name in the report and how it was mapped), the rig file, where the candidates were fitted, whether the
    replay ran, the seed of the model's own log, the versions."""
    entries = []
    for path, name, role, log in zip(sources, names, roles, logs, strict=True):
        entry = {"path": str(path), "role": role, "samples": len(log),
                 "duration_s": float(log["time"][-1] - log["time"][0])}
        if "mapping" in log.meta:
            entry.update(name=name, mapping=log.meta["mapping"]["notes"])
        entries.append(entry)
    return {"seed": config.model_log_seed, "rig": str(args.rig), "logs": entries,
            "workers": config.workers, "ray": config.ray, "replay": not args.no_replay,
            "versions": software_versions()}


if __name__ == "__main__":
    main()
