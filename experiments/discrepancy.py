"""What the simulation gets wrong on a measured log, which effect causes it, and how much the fix predicts.

    python -m experiments.discrepancy LOG --rig RIG.toml [--json OUT] [--plot DIR] [--save-rig OUT.toml]
                                      [--joint hinge|slide] [--workers N] [--no-replay]

LOG is a run log (CSV, Parquet or .mat, docs/run_log_format.md); RIG.toml describes what produced it
(docs/discrepancy.md). Neither file is modified. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from experiments.common import write_json
from sim.discrepancy.analysis import analyse
from sim.discrepancy.report import format_result, plot_result
from sim.discrepancy.rig import RigError, load_rig, save_rig
from sim.discrepancy.signals import AnalysisConfig
from sim.logio import LogError, read_log


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("log", type=Path, help="run log (.csv, .parquet, .mat)")
    parser.add_argument("--rig", type=Path, required=True, metavar="TOML", help="rig description")
    parser.add_argument("--json", type=Path, help="write the result as JSON")
    parser.add_argument("--plot", type=Path, metavar="DIR", help="save PNG figures in DIR")
    parser.add_argument("--save-rig", type=Path, metavar="TOML", help="write the extended rig (must not exist)")
    parser.add_argument("--workers", type=int, default=2, help="processes for the candidate fits (default 2)")
    parser.add_argument("--no-replay", action="store_true", help="skip the MuJoCo replay of the held-out part")
    args = parser.parse_args(argv)
    try:
        rig = load_rig(args.rig)
    except RigError as exc:
        parser.error(str(exc))
    if args.save_rig is not None and args.save_rig.exists():
        parser.error(f"--save-rig {args.save_rig} exists; choose a new file (inputs are never overwritten)")
    try:
        log = read_log(args.log, joint=rig.joint)
    except (LogError, FileNotFoundError) as exc:
        parser.error(f"{args.log}: {exc}")
    try:
        result = analyse(log, rig, AnalysisConfig(workers=max(1, args.workers)), progress=True,
                         replay=not args.no_replay)
    except (RigError, ValueError) as exc:
        parser.error(str(exc))
    print(format_result(result))
    if args.json:
        write_json(args.json, result.to_dict())
        print(f"wrote {args.json}")
    if args.plot:
        for path in plot_result(result, args.plot):
            print(f"figure: {path}")
    if args.save_rig:
        header = (f"Extended rig written by experiments.discrepancy from {args.log.name} and {args.rig.name}.\n"
                  f"Findings: {', '.join(result.found) or 'none'}.")
        print(f"wrote {save_rig(result.extended_rig, args.save_rig, header=header)}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
