"""Every experiment of the paper, and one table of every paper figure beside the simulated one.

    python -m experiments.paper [--seed N] [--duration S] [--json PATH] [--plot DIR] [--params TOML]

Runs the calibration and thermal experiments (``experiments.calibration``, ``experiments.thermal``), the step and
disturbance tests, the sine and square tests (both feedbacks) and the admittance pushes, then prints the table
(``ratio`` = sim / paper), the paper's qualitative behaviours with whether the simulation shows them, and with
``--plot DIR`` writes ``DIR/paper_report.md`` with every figure. ``--json`` writes ``{"rows": [{"table", "quantity",
"unit", "paper", "sim", "ratio"}], "behaviours": [...]}``; rows of alternative readings of the paper's definitions
also carry ``"reading": "alternative"`` and a ``"reason"``: they are printed in a group of their own and never
counted in the "N of M within a factor" figures.
About 1-2 min with the full-length tests.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from experiments.admittance import make_controller
from experiments.common import (
    SHORTEST_FULL_TEST_S,
    TARGET_RATIO,
    add_experiment_args,
    cli_parser,
    format_rows,
    is_primary,
    load_params_arg,
    outside_band,
    paper_row,
    record_rerun,
    run_errors,
    short_run_banner,
    write_outputs,
)
from experiments.registry import EXPERIMENTS
from experiments.step import PAPER_REACHED_FRACTION
from sim.characterize import measure_breakaway
from sim.params import TestbedParams

REPORT_FILE = "paper_report.md"  # the report --plot writes beside every experiment's figures
PLOT_FILES = (*(name for experiment in EXPERIMENTS.values() for name in experiment.plot_files), REPORT_FILE)

PAPER_BREAKAWAY_NM = 0.13  # paper Sec. IV
CLOSE_RATIO = 1.25  # [-] the tighter band the table also counts (beside TARGET_RATIO)
ONE_SIDED_SHARE = 0.8  # [-] >= 80 % of the output's impulse on one side of zero counts as one-sided
# [-] actuation at all: mean |output| at least a quarter of mean |reference|. Below the paper's smallest
# current-feedback step fraction (30 %, Sec. IV-A): a lower output is a gear that never broke free, and the sign
# share of a stuck output is its noise and offset, not one- or two-sided actuation.
ACTUATION_LEVEL = 0.25


@dataclass(frozen=True)
class Behaviour:
    """A qualitative claim of the paper and what the simulation shows."""

    claim: str
    simulated: str
    reproduced: bool

    def to_dict(self) -> dict[str, Any]:
        return {"claim": self.claim, "simulated": self.simulated, "reproduced": self.reproduced}


@dataclass(frozen=True)
class PaperResult:
    """All rows, behaviours and figures written."""

    rows: list[dict[str, Any]]
    behaviours: list[Behaviour]
    figures: list[Path] = field(default_factory=list)
    logs: dict[str, Any] = field(default_factory=dict, repr=False)  # run name -> RunLog (rerun recording)
    seed: int = 0
    duration_s: float | None = None  # [s] the shortened run length, None for the full-length tests

    def within_target(self, band: float = TARGET_RATIO) -> tuple[int, int]:
        """(number of primary rows within a factor ``band``, number of primary rows with a ratio); rows of
        alternative readings are not counted."""
        ratios = [r["ratio"] for r in self.rows if r["ratio"] is not None and is_primary(r)]
        return sum(1 for x in ratios if not outside_band(x, band)), len(ratios)

    def counts_text(self) -> str:
        """'N of M figures within a factor 1.5 (K within 1.25)', over the primary rows only."""
        within, total = self.within_target()
        close, _ = self.within_target(CLOSE_RATIO)
        return (f"{within} of {total} figures within a factor {TARGET_RATIO:g} ({close} within {CLOSE_RATIO:g}) of "
                f"the paper, primary readings only")

    def to_dict(self) -> dict[str, Any]:
        return {"rows": self.rows, "behaviours": [b.to_dict() for b in self.behaviours],
                "figures": [str(p) for p in self.figures]}


def actuation(positive_share: float, output_level: float) -> str:
    """'one-sided', 'two-sided' or 'none' (a stuck output) from the share of the output's impulse that is
    positive and mean |output| / mean |reference| (``experiments.sinusoid``)."""
    if output_level < ACTUATION_LEVEL:
        return "none"
    return "one-sided" if max(positive_share, 1.0 - positive_share) >= ONE_SIDED_SHARE else "two-sided"


def _behaviours(step, sinusoid, admittance, breakaway_nm: float) -> list[Behaviour]:
    out = []
    fractions = {c.reference_nm: c.error.reached_fraction for c in step.cases
                 if c.name.startswith("step") and c.feedback == "current"}
    if fractions:
        text = ", ".join(f"{100 * f:.0f} %" for f in fractions.values())
        paper = ", ".join(f"{100 * PAPER_REACHED_FRACTION[s]:.0f}" for s in fractions)
        steps = ", ".join(f"{s:g}" for s in fractions)
        out.append(Behaviour(f"current feedback reaches ~{paper} % of the {steps} N·m steps", f"{text}",
                             all(0.5 < f / PAPER_REACHED_FRACTION[s] < 1.5 for s, f in fractions.items())))
    out.append(Behaviour("gear stiction ≈ 0.13 N·m (smallest command giving > 100 ms of motion on a ramp)",
                         f"{breakaway_nm:.3f} N·m", abs(breakaway_nm / PAPER_BREAKAWAY_NM - 1) < 0.2))
    for c in sinusoid.cases:
        if c.waveform.amplitude_nm > 0.1:
            continue
        expected = "one-sided" if c.feedback == "current" else "two-sided"
        out.append(Behaviour(f"{c.waveform.name}, {c.feedback} feedback: {expected} actuation",
                             f"{100 * c.positive_share:.0f} % of the output's impulse positive, mean |output| "
                             f"{100 * c.output_level:.0f} % of mean |reference|",
                             actuation(c.positive_share, c.output_level) == expected))
    for c in step.cases:
        if c.name != "disturbance":
            continue
        if c.feedback == "current":
            lost = c.disturbance_at_loss_nm
            out.append(Behaviour("current feedback loses regulation at ≈ 0.3 N·m of disturbance",
                                 f"lost at {lost:.2f} N·m" if lost is not None else "never lost",
                                 lost is not None and 0.15 < lost < 0.6))
        else:
            held = c.disturbance_at_loss_nm is None and c.disturbance_max_nm >= 2.0
            out.append(Behaviour("sensor feedback holds regulation past 2 N·m of disturbance",
                                 f"held up to {c.disturbance_max_nm:.2f} N·m" if c.disturbance_at_loss_nm is None
                                 else f"lost at {c.disturbance_at_loss_nm:.2f} N·m", held))
    if admittance is not None:
        slow, fast = admittance.pushes
        out.append(Behaviour("admittance: the lever follows a slow push",
                             f"lag ≤ {slow.max_lag_rad:.3f} rad of {slow.final_angle_rad:.2f} rad, peak torque "
                             f"{slow.peak_hand_torque_nm:.2f} N·m", admittance.follows_slow))
        out.append(Behaviour("admittance: the lever resists a fast push",
                             f"lag {fast.max_lag_rad:.3f} rad, peak torque {fast.peak_hand_torque_nm:.2f} N·m "
                             f"(felt damping {fast.felt_damping_nms_per_rad:.2f} N·m·s/rad)",
                             admittance.resists_fast))
    return out


def run_paper(params: TestbedParams | None = None, seed: int = 0, duration_s: float | None = None,
              plot_dir: Path | None = None, progress: bool = False) -> PaperResult:
    """Run every experiment; rows of every paper figure beside the simulated one, and the behaviours."""
    params = params or TestbedParams()
    results = {}
    for name, experiment in EXPERIMENTS.items():
        if progress:
            print(f"experiments.{name} ...", file=sys.stderr, flush=True)
        results[name] = experiment.run(params, seed, duration_s if experiment.shortens else None,
                                       progress=progress)
    breakaway = measure_breakaway(params).torque_nm
    rows = [row for result in results.values() for row in result.rows()]
    rows.append(paper_row("IV text", "gear breakaway (stiction) torque", "N·m", PAPER_BREAKAWAY_NM, breakaway))
    figures = [path for result in results.values() for path in result.plot(plot_dir)] if plot_dir is not None else []
    logs = {name: log for result in results.values() if hasattr(result, "logs") for name, log in result.logs().items()}
    behaviours = _behaviours(results["step"], results["sinusoid"], results["admittance"], breakaway)
    return PaperResult(rows, behaviours, figures, logs, seed, duration_s)


def _cell(text: str) -> str:
    """``text`` as one markdown table cell (its '|', as in 'mean |output|', escaped)."""
    return text.replace("|", "\\|")


def markdown_report(result: PaperResult, directory: Path) -> str:
    """The report: the table, the behaviours and every figure (paths relative to ``directory``)."""
    if result.duration_s is None:
        length = "full-length tests."
    elif result.duration_s < SHORTEST_FULL_TEST_S:
        length = (f"**short run ({result.duration_s:g} s per test): a check of the command line, not comparable "
                  f"with the paper's figures.**")
    else:
        length = (f"**tests run at a set length (--duration {result.duration_s:g} s) instead of the paper "
                  f"protocol's: not comparable with the paper's figures.**")
    lines = ["# torquebed: the paper's figures beside the simulation", "",
             f"{result.counts_text()} (ratio = sim / paper); seed {result.seed}, {length}", "",
             "| table | quantity | unit | paper | sim | ratio |", "|---|---|---|---|---|---|"]

    def num(x):
        return f"{x:.4g}" if x is not None else "-"

    def row(r):
        flag = " ⚠" if outside_band(r["ratio"]) else ""
        return (f"| {r['table']} | {_cell(r['quantity'])} | {r['unit']} | {num(r['paper'])} | {num(r['sim'])} | "
                f"{num(r['ratio'])}{flag} |")

    lines += [row(r) for r in result.rows if is_primary(r)]
    alternatives = [r for r in result.rows if not is_primary(r)]
    if alternatives:
        lines += ["", "## Alternative readings of the paper's definitions", "",
                  "Beside the table, never counted in it; the paper value converted to the reading.", "",
                  "| table | quantity | unit | paper | sim | ratio | why |", "|---|---|---|---|---|---|---|"]
        lines += [f"{row(r)} {_cell(r['reason'])} |" for r in alternatives]
    lines += ["", "## Behaviours", "", "| paper | simulation | reproduced |", "|---|---|---|"]
    lines += [f"| {_cell(b.claim)} | {_cell(b.simulated)} | {'yes' if b.reproduced else 'no'} |"
              for b in result.behaviours]
    lines += ["", "## Figures", ""]
    for path in result.figures:
        rel = Path(path).resolve().relative_to(directory.resolve()) if Path(path).resolve().is_relative_to(
            directory.resolve()) else Path(path)
        lines.append(f"![{Path(path).stem}]({rel})")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    add_experiment_args(parser, feedback=False, figures=PLOT_FILES)
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args, checks=(make_controller,))
    with run_errors(parser):
        result = run_paper(params, args.seed, args.duration, args.plot, progress=True)
    short_run_banner(args)
    print(format_rows(f"The paper's figures beside the simulation ({result.counts_text()})", result.rows,
                      band=TARGET_RATIO))
    print("\nbehaviours:")
    for b in result.behaviours:
        print(f"  [{'x' if b.reproduced else ' '}] {b.claim}: {b.simulated}")
    write_outputs(args, result.to_dict())
    if args.plot:
        report = args.plot / REPORT_FILE
        report.write_text(markdown_report(result, args.plot))
        print(f"report: {report}")
    record_rerun(args, result.logs, params)


if __name__ == "__main__":
    main()
