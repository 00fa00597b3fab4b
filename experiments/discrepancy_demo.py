"""A synthetic log with one hidden effect, and the rig it is to be analysed against: a first run of the
discrepancy analysis without a rig of one's own.

    python -m experiments.discrepancy_demo [--effect NAME] [--experiment NAME] [--seed N] [--duration S]
                                           [--out DIR] [--no-plot]

The log comes from the MuJoCo testbed (or the rigid slide) with ``--effect`` hidden at a value drawn from its
realistic range with ``--seed`` (``experiments.synthetic_logs``); the rig file is the baseline, without the effect,
which is what the analysis is told. The command prints the hidden value and the command that analyses the pair;
``python -m experiments.discrepancy`` should name the effect and recover the value. Existing files are not
replaced. A --duration shorter than the analysis accepts (:func:`shortest_analysable_duration_s`) is refused
before anything is simulated. The command draws no figures (--no-plot is accepted, as by every experiment).
"""

from __future__ import annotations

import dataclasses
import shlex
import sys
from pathlib import Path

from experiments.common import (
    MAX_DURATION_S,
    add_no_figures_arg,
    check_output_paths,
    cli_parser,
    run_seconds,
    seed_arg,
)
from experiments.synthetic_logs import (
    EXPERIMENTS,
    FINE_MOTOR_ENCODER_COUNTS,
    MOTOR_ENCODER_COUNTS,
    baseline_rig,
    hidden_effect_log,
)
from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.rig import save_rig
from sim.discrepancy.signals import AnalysisConfig, minimum_samples
from sim.logio import write_log
from sim.runlog import HOLD_END

DEFAULT_EFFECT = "coulomb_friction"
DEFAULT_DURATION_S = 10.0  # [s] the length the hidden-effect sweep recovers every effect from
LOG_SAMPLE_PERIOD_S = 1e-3  # [s] the synthetic logs hold one sample per 1 ms control tick (synthetic_logs)


def shortest_analysable_duration_s() -> float:
    """The shortest demo log [s] the discrepancy analysis accepts (:func:`sim.discrepancy.signals.minimum_samples`)."""
    return minimum_samples(AnalysisConfig(), LOG_SAMPLE_PERIOD_S) * LOG_SAMPLE_PERIOD_S


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--effect", choices=sorted(EFFECTS), default=DEFAULT_EFFECT,
                        help=f"effect to hide (default {DEFAULT_EFFECT})")
    parser.add_argument("--experiment", choices=EXPERIMENTS,
                        help="experiment that produces the log (default: the one that reveals the effect)")
    parser.add_argument("--seed", type=seed_arg, default=0, help="seed of the hidden value and the noise (default 0)")
    parser.add_argument("--duration", type=run_seconds, default=DEFAULT_DURATION_S, metavar="S",
                        help=f"log length (default {DEFAULT_DURATION_S:g} s)")
    parser.add_argument("--out", type=Path, default=Path("out"), metavar="DIR",
                        help="directory of demo_log.csv and demo_rig.toml (default out/)")
    add_no_figures_arg(parser)
    args = parser.parse_args(argv)
    check_output_paths(parser, args)
    samples = minimum_samples(AnalysisConfig(), LOG_SAMPLE_PERIOD_S)
    if round(args.duration / LOG_SAMPLE_PERIOD_S) < samples:
        shortest = shortest_analysable_duration_s()
        parser.error(f"--duration {args.duration:g} s: the analysis needs a log of at least {shortest:g} s "
                     f"({samples} samples at 1 kHz: four times its filter guards of {AnalysisConfig().guard_s:g} s "
                     f"at both ends of the fit and held-out parts, and a few filter periods); valid range "
                     f"[{shortest:g}, {MAX_DURATION_S:g}] s")
    spec = EFFECTS[args.effect]
    experiment = args.experiment or spec.revealing_experiment
    if not spec.applies(baseline_rig(experiment)):
        parser.error(f"--effect {args.effect} does not apply to the rig of the {experiment!r} experiment (it applies "
                     f"to: {', '.join(sorted(spec.rigs))}); its experiment is {spec.revealing_experiment!r}")
    if experiment != spec.revealing_experiment:
        print(f"note: {args.effect} is revealed by the {spec.revealing_experiment!r} experiment; from "
              f"{experiment!r} the analysis may not name it or recover its value", file=sys.stderr)
    # an effect that needs a fine motor encoder (presliding: its displacement, docs/discrepancy.md) gets one
    encoder = FINE_MOTOR_ENCODER_COUNTS if spec.needs_fine_motor_encoder else MOTOR_ENCODER_COUNTS
    log_path, rig_path = args.out / "demo_log.csv", args.out / "demo_rig.toml"
    for path in (log_path, rig_path):
        if path.exists():
            parser.error(f"{path} exists; choose another --out (existing files are not replaced)")
    print(f"simulating {args.duration:g} s of the {experiment!r} experiment with {args.effect} hidden ...",
          file=sys.stderr)
    try:
        log, rig, truth = hidden_effect_log(experiment, [args.effect], args.seed, args.duration,
                                            motor_encoder_counts=encoder)
    except ValueError as exc:
        parser.error(f"--effect {args.effect} on {experiment!r}: {exc}")
    args.out.mkdir(parents=True, exist_ok=True)
    write_log(log, log_path)
    rig = dataclasses.replace(rig, time_convention=HOLD_END)  # the synthetic logs' (a CSV cannot say it)
    save_rig(rig, rig_path, header=f"Baseline rig of {log_path.name}, written by experiments.discrepancy_demo "
                                   f"(the hidden {args.effect} is not in it).")
    units = {p.key: p.unit(rig.joint) for p in EFFECTS[args.effect].params}
    hidden = ", ".join(f"{k} = {v:.5g} {units.get(k, '')}".rstrip() for k, v in truth.effects[args.effect].items())
    print(f"wrote {log_path} and {rig_path}")
    print(f"hidden: {args.effect} ({hidden})")
    if encoder != MOTOR_ENCODER_COUNTS:
        print(f"the log's motor encoder has {encoder} counts per turn (the default's would not reveal it)")
    print(f"analyse: python -m experiments.discrepancy {shlex.quote(str(log_path))} --rig {shlex.quote(str(rig_path))}")


if __name__ == "__main__":
    main()
