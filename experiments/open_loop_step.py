"""Open-loop torque steps on the locked testbed: what the driver's torque command alone delivers.

    python -m experiments.open_loop_step [--steps 0.05 0.1 0.2] [--duration 2] [--params TOML]
                                         [--json PATH] [--plot DIR]

The GIM8108 driver closes its own current loop, so a torque command is what a controller built on the
current-based estimate ends up asking for: the load cell shows what the gear lets through. The paper's
current-feedback steps reached about 30, 40 and 65 % of 0.05, 0.1 and 0.2 N·m (Sec. IV-A).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from experiments.common import (
    add_output_args,
    add_params_arg,
    add_rerun_args,
    cli_parser,
    load_params_arg,
    record_rerun,
    run_seconds,
    write_outputs,
)
from experiments.step import PAPER_REACHED_FRACTION
from sim.figures import save_figure
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.plant import Plant
from sim.protocols import STEPS_NM
from sim.run import run_open_loop
from sim.runlog import RunLog

PLOT_FILES = ("open_loop_step.png",)  # the files --plot writes

SETTLED_FRACTION = 0.5  # the mean is taken over the second half of each step


@dataclass(frozen=True)
class StepOutcome:
    """One step: command [N·m], mean load-cell torque once settled [N·m], reached fraction, RMS error [N·m]."""

    command_nm: float
    loadcell_mean_nm: float
    reached_fraction: float
    rms_error_nm: float
    current_estimate_mean_nm: float
    paper_reached_fraction: float | None


@dataclass(frozen=True)
class OpenLoopStepResult:
    steps: list[StepOutcome]
    logs: list[RunLog]

    def to_dict(self) -> dict:
        return {"steps": [asdict(s) for s in self.steps],
                "units": {"command_nm": "N·m", "loadcell_mean_nm": "N·m", "rms_error_nm": "N·m",
                          "current_estimate_mean_nm": "N·m", "reached_fraction": "1"}}


def run_open_loop_step(params: TestbedParams | None = None, steps_nm: tuple[float, ...] = STEPS_NM,
                       duration_s: float = 2.0) -> OpenLoopStepResult:
    """Each step from rest in the locked fixture, the backlash taken up in the step's direction (as after a
    previous push): a constant torque command held for ``duration_s``."""
    if duration_s <= 0:
        raise ValueError(f"duration_s = {duration_s}: must be > 0 s")
    outcomes, logs = [], []
    for tau in steps_nm:
        plant = Plant(params, "locked")
        plant.reset(backlash_side=int(np.sign(tau)))
        n = max(2, round(duration_s / plant.params.simulation.control_period_s))
        log = run_open_loop(plant, np.full(n, tau),
                            meta={"step_nm": tau, "lever_length_m": plant.params.lever.length_m})
        lc = log["force_loadcell"] * plant.params.lever.length_m
        settled = slice(int(SETTLED_FRACTION * n), n)
        mean = float(lc[settled].mean())
        outcomes.append(StepOutcome(
            command_nm=tau, loadcell_mean_nm=mean, reached_fraction=mean / tau,
            rms_error_nm=float(np.sqrt(np.mean((lc - tau) ** 2))),
            current_estimate_mean_nm=float(log["tau_current_estimate"][settled].mean()),
            paper_reached_fraction=PAPER_REACHED_FRACTION.get(tau)))
        logs.append(log)
    return OpenLoopStepResult(outcomes, logs)


def format_result(result: OpenLoopStepResult) -> str:
    lines = ["Open-loop torque steps, locked fixture (load-cell torque = force x lever length)",
             f"{'command [N·m]':>14s} {'load cell [N·m]':>16s} {'reached':>8s} {'paper':>7s} {'ratio':>6s} "
             f"{'RMS err [N·m]':>14s} {'current est. [N·m]':>19s}"]
    for s in result.steps:
        paper = f"{s.paper_reached_fraction:7.0%}" if s.paper_reached_fraction else f"{'-':>7s}"
        ratio = f"{s.reached_fraction / s.paper_reached_fraction:6.2f}" if s.paper_reached_fraction else f"{'-':>6s}"
        lines.append(f"{s.command_nm:14.3f} {s.loadcell_mean_nm:16.4f} {s.reached_fraction:8.0%} {paper} {ratio} "
                     f"{s.rms_error_nm:14.4f} {s.current_estimate_mean_nm:19.4f}")
    lines.append("paper: current-feedback PI steps of Sec. IV-A (mean output / reference)")
    return "\n".join(lines)


def plot_result(result: OpenLoopStepResult, directory: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, len(result.steps), figsize=(4 * len(result.steps), 3.2), squeeze=False)
    for ax, step, log in zip(axes[0], result.steps, result.logs, strict=True):
        lever = log.meta.get("lever_length_m", 0.1)
        ax.plot(log["time"], log["force_loadcell"] * lever, label="load cell")
        ax.plot(log["time"], log["tau_current_estimate"], "--", label="current estimate")
        ax.axhline(step.command_nm, color="k", lw=0.8, label="command")
        ax.set(title=f"{step.command_nm:g} N·m step", xlabel="time [s]", ylabel="torque [N·m]")
        ax.legend(fontsize=7)
    return save_figure(fig, directory, PLOT_FILES[0])


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--steps", type=float, nargs="+", default=list(STEPS_NM), metavar="N·m",
                        help="torque commands of the steps [N·m] (default 0.05 0.1 0.2)")
    parser.add_argument("--duration", type=run_seconds, default=2.0, metavar="S",
                        help="seconds per step (default 2)")
    add_output_args(parser, figures=PLOT_FILES)
    add_params_arg(parser)
    add_rerun_args(parser)
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args, uses_sensor=False)
    limit_nm = CurrentToTorqueMap.from_params(params).command_limit_nm
    for step_nm in args.steps:
        if not (math.isfinite(step_nm) and 0.0 < abs(step_nm) <= limit_nm):
            parser.error(f"--steps {step_nm:g} N·m: valid steps are non-zero, within the driver's command limit "
                         f"±{limit_nm:.3g} N·m")
    result = run_open_loop_step(params, tuple(args.steps), args.duration)
    print(format_result(result))
    write_outputs(args, result.to_dict(), lambda directory: plot_result(result, directory))
    logs = {f"open-loop step {s.command_nm:g} N·m": g for s, g in zip(result.steps, result.logs, strict=True)}
    record_rerun(args, logs, params)


if __name__ == "__main__":
    main()
