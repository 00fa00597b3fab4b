"""Torque steps and disturbance rejection on the locked testbed, current vs sensor feedback (paper Sec. IV-A,
Table VI, Fig. 11).

    python -m experiments.step [--feedback {current,sensor,both}] [--seed N] [--duration S]
                               [--json PATH] [--plot DIR] [--params TOML]

Protocol (the paper gives the step sizes, the gains and the 1 kHz cycle; the rest is stated here):

* Steps: the rig at rest with the backlash taken up in the step's direction (as after a previous push), the
  reference zero for ``PRE_STEP_S`` then stepped to 0.05, 0.1 or 0.2 N·m (``STEPS_NM``; both from
  :mod:`sim.protocols`, which the environment shares) and held for ``STEP_HOLD_S``.
  The errors are taken over the hold once the loop has settled (from ``SETTLE_S`` after the step): the
  paper's sensor-feedback RMS errors are the same for the three step sizes (0.0026, 0.0026, 0.0025 N·m),
  which a window containing the transient would not give, and its current-feedback errors match
  (1 - reached fraction) x step, a steady-state figure. The RMS over the whole hold from the step on, the
  transient included, is reported beside it as an alternative reading.
* Disturbance (:data:`sim.protocols.DISTURBANCE`, which says why the hand twists the flange and at what rate):
  regulation at 0.5 N·m; after 2 s a hand twists the gear's output flange (upstream of the flexure: the sensor
  and the load cell both see it, the driver's current does not) against the motor, its torque growing at
  0.07 N·m/s up to 2.5 N·m.
  The run goes on to the full disturbance; the RMS error is over the disturbance phase up to where
  regulation is lost (|load-cell torque - reference| > ``REGULATION_LOST_NM``), or to the end if it is not.
  The RMS over the whole disturbance phase, past any loss, is reported beside it as an alternative reading.
  The figure shades each evaluated window and marks the loss. The paper reports the disturbance at
  which current-feedback regulation failed (≈ 0.3 N·m) and that sensor feedback held past 2 N·m.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controllers.feedback import (
    FEEDBACK_KINDS,
    ControllerFactory,
    build_controller,
    check_feedback,
)
from controllers.pi import paper_pi
from controllers.tracking import TrackingError, run_tracking, tracking_error
from experiments.common import (
    ALTERNATIVE,
    add_experiment_args,
    cli_parser,
    feedback_kinds,
    format_rows,
    load_params_arg,
    paper_row,
    record_rerun,
    run_errors,
    short_run_banner,
    write_outputs,
)
from sim.figures import save_figure
from sim.params import TestbedParams
from sim.plant import Plant
from sim.protocols import DISTURBANCE, PRE_STEP_S, STEPS_NM
from sim.run import Controller
from sim.runlog import RunLog

PLOT_FILES = ("step.png",)  # the files --plot writes

# Paper Table VI: RMS error [N·m] against the load-cell torque.
PAPER_STEP_RMS_NM = {("current", 0.05): 0.0329, ("current", 0.1): 0.0566, ("current", 0.2): 0.0685,
                     ("sensor", 0.05): 0.0026, ("sensor", 0.1): 0.0026, ("sensor", 0.2): 0.0025}
PAPER_DISTURBANCE_RMS_NM = {"current": 0.1893, "sensor": 0.0058}
# Paper Sec. IV-A: current feedback reaches ~30, 40, 65 % of the steps (mean values).
PAPER_REACHED_FRACTION = {0.05: 0.30, 0.1: 0.40, 0.2: 0.65}
# Paper Sec. IV-A: disturbance at which regulation was lost (current) / still held (sensor) [N·m].
PAPER_DISTURBANCE_LOST_NM = {"current": 0.3, "sensor": 2.0}

STEP_HOLD_S = 5.0  # [s] step held
SETTLE_S = 1.0  # [s] ~10 time constants of the PI's integral action, (1 + Kp)/Ki = 93 ms
START_UP_S = 0.2  # [s] the disturbance test's start, where the regulated torque is taken from rest (figure note)
REGULATION_LOST_NM = 0.25  # [N·m] half the regulated torque: the load cell has clearly left 0.5 N·m
TRANSIENT_REASON = ("The paper computes the RMSE of each step record (Fig. 11, Table VI) without naming a window, so "
                    "the whole record from the step on, the transient included, is a reading too.")
WHOLE_DISTURBANCE_REASON = ("The paper gives the disturbance test's RMSE without saying whether it stops where "
                            "regulation was lost, so the whole disturbance phase is a reading too.")


@dataclass(frozen=True)
class StepCase:
    """One step (or the disturbance test) under one feedback.

    Attributes
    ----------
    name : str
        'step 0.05 N·m', ..., 'disturbance'.
    feedback : str
        'current' or 'sensor'.
    reference_nm : float
        Step size or regulated torque [N·m].
    error : TrackingError
        Over the evaluation window (settled hold; disturbance phase).
    paper_rms_nm : float
        Table VI [N·m].
    disturbance_at_loss_nm : float or None
        Disturbance torque when regulation was lost [N·m] (None: held to the end; steps: None).
    disturbance_max_nm : float or None
        Largest disturbance applied [N·m] (disturbance test only).
    window_s : tuple of float
        Start and end of the evaluation window [s] (log time).
    error_whole_record : TrackingError or None
        Over the whole record from the step, or from the disturbance's start, to the end: the transient and any
        loss of regulation included (an alternative reading of Table VI).
    """

    name: str
    feedback: str
    reference_nm: float
    error: TrackingError
    paper_rms_nm: float
    disturbance_at_loss_nm: float | None = None
    disturbance_max_nm: float | None = None
    window_s: tuple[float, float] = (0.0, 0.0)
    error_whole_record: TrackingError | None = None
    log: RunLog | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        return {"name": self.name, "feedback": self.feedback, "reference_nm": self.reference_nm,
                "error": self.error.to_dict(), "paper_rms_nm": self.paper_rms_nm,
                "disturbance_at_loss_nm": self.disturbance_at_loss_nm,
                "disturbance_max_nm": self.disturbance_max_nm, "window_s": list(self.window_s),
                "error_whole_record": (self.error_whole_record.to_dict()
                                       if self.error_whole_record is not None else None)}


@dataclass(frozen=True)
class StepResult:
    """Every case of the step experiment; ``rows()`` gives the paper-vs-simulation table."""

    cases: list[StepCase]
    seed: int

    def logs(self) -> dict[str, RunLog]:
        """Run name ('<case>, <feedback>') -> its log."""
        return {f"{c.name}, {c.feedback}": c.log for c in self.cases}

    def rows(self) -> list[dict]:
        """The paper's figures beside the simulated ones, then the alternative readings."""
        out, alternatives = [], []
        for c in self.cases:
            label = f"{c.name}, {c.feedback} feedback"
            out.append(paper_row("VI", f"{label}: RMS error", "N·m", c.paper_rms_nm, c.error.rms_nm))
            if c.name.startswith("step") and c.feedback == "current":
                out.append(paper_row("IV-A text", f"{label}: reached fraction (mean)", "1",
                                     PAPER_REACHED_FRACTION[c.reference_nm], c.error.reached_fraction))
            if c.name == "disturbance":
                out.append(_disturbance_row(c, label))
            if c.error_whole_record is not None:
                steps = c.name.startswith("step")
                alternatives.append(paper_row(
                    "VI", f"{label}: RMS error, " + ("whole hold with the transient" if steps else
                                                     "whole disturbance phase, past any loss of regulation"),
                    "N·m", c.paper_rms_nm, c.error_whole_record.rms_nm, reading=ALTERNATIVE,
                    reason=TRANSIENT_REASON if steps else WHOLE_DISTURBANCE_REASON))
        return out + alternatives

    def plot(self, directory: Path) -> list[Path]:
        """Fig. 11 like the paper's, written to ``directory`` (paths)."""
        return [plot_step(self, directory)]

    def to_dict(self) -> dict:
        return {"seed": self.seed, "cases": [c.to_dict() for c in self.cases], "rows": self.rows()}


def _disturbance_row(c: StepCase, label: str) -> dict:
    """The paper's disturbance at which regulation was lost (current) or that it held past (sensor). Held to
    the end of the test, ours is a lower bound like the paper's, so that row has no ratio; a loss before the
    disturbance began (a run too short to reach it) has no figure."""
    lost = c.disturbance_at_loss_nm
    if lost is None:
        row = paper_row("IV-A text", f"{label}: disturbance regulation held up to (the test's end)", "N·m",
                        PAPER_DISTURBANCE_LOST_NM[c.feedback], c.disturbance_max_nm)
        return {**row, "ratio": None}
    return paper_row("IV-A text", f"{label}: disturbance regulation lost at", "N·m",
                     PAPER_DISTURBANCE_LOST_NM[c.feedback], lost if lost > 0.0 else None)


def run_step_case(params: TestbedParams, feedback: str, step_nm: float, seed: int = 0,
                  hold_s: float = STEP_HOLD_S, progress: bool = False,
                  controller: Controller | ControllerFactory | None = None) -> StepCase:
    """One torque step from rest under ``feedback``; errors over the settled part of the hold.
    ``controller``: as for :func:`run_step`."""
    plant = Plant(params, "locked")
    plant.reset(backlash_side=int(np.sign(step_nm)))
    dt = params.simulation.control_period_s
    n_pre, n_hold = round(PRE_STEP_S / dt), round(hold_s / dt)
    reference = np.concatenate([np.zeros(n_pre), np.full(n_hold, step_nm)])
    log = run_tracking(params, plant, build_controller(controller, paper_pi, params, feedback), feedback, seed,
                       reference, label=f"step {step_nm:g} N·m, {feedback}" if progress else None,
                       meta={"step_nm": step_nm})
    window = slice(n_pre + min(round(SETTLE_S / dt), n_hold // 2), None)
    err = tracking_error(log["tau_loadcell"][window], reference[window])
    return StepCase(f"step {step_nm:g} N·m", feedback, step_nm, err, PAPER_STEP_RMS_NM[(feedback, step_nm)],
                    window_s=(float(log["time"][window][0]), float(log["time"][-1])),
                    error_whole_record=tracking_error(log["tau_loadcell"][n_pre:], reference[n_pre:]), log=log)


def disturbance_profile(params: TestbedParams, duration_s: float | None = None) -> np.ndarray:
    """The hand's torque on the output flange per tick [N·m] (:data:`sim.protocols.DISTURBANCE`, at the end of
    each tick): zero, then growing against the motor; ``duration_s`` cuts the test short."""
    dt = params.simulation.control_period_s
    total_s = DISTURBANCE.duration_s if duration_s is None else duration_s
    return DISTURBANCE.hub_torque(np.arange(1, round(total_s / dt) + 1) * dt)


def run_disturbance_case(params: TestbedParams, feedback: str, seed: int = 0, duration_s: float | None = None,
                         progress: bool = False,
                         controller: Controller | ControllerFactory | None = None) -> StepCase:
    """Regulation at 0.5 N·m while the flange disturbance grows; errors up to where regulation is lost.
    ``controller``: as for :func:`run_step`."""
    plant = Plant(params, "locked")
    plant.reset(backlash_side=1)
    dt = params.simulation.control_period_s
    hub = disturbance_profile(params, duration_s)
    reference = DISTURBANCE.reference(np.arange(len(hub)) * dt)
    log = run_tracking(params, plant, build_controller(controller, paper_pi, params, feedback), feedback, seed,
                       reference, tau_hub_nm=hub, label=f"disturbance, {feedback}" if progress else None,
                       meta={"regulated_nm": DISTURBANCE.regulated_nm})
    output = log["tau_loadcell"]
    start = min(round(DISTURBANCE.pre_s / dt), len(hub) // 2)
    lost = np.flatnonzero(np.abs(output[start:] - DISTURBANCE.regulated_nm) > REGULATION_LOST_NM)
    end = start + int(lost[0]) + 1 if len(lost) else len(hub)
    at_loss = float(abs(hub[end - 1])) if len(lost) else None
    err = tracking_error(output[start:end], reference[start:end])
    return StepCase("disturbance", feedback, DISTURBANCE.regulated_nm, err, PAPER_DISTURBANCE_RMS_NM[feedback],
                    disturbance_at_loss_nm=at_loss, disturbance_max_nm=float(np.abs(hub[:end]).max()),
                    window_s=(float(log["time"][start]), float(log["time"][end - 1])),
                    error_whole_record=tracking_error(output[start:], reference[start:]), log=log)


def run_step(params: TestbedParams | None = None, feedbacks: tuple[str, ...] = FEEDBACK_KINDS, seed: int = 0,
             duration_s: float | None = None, progress: bool = False,
             controller: Controller | ControllerFactory | None = None) -> StepResult:
    """The paper's step and disturbance tests under each feedback.

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set (defaults if None).
    feedbacks : tuple of {'current', 'sensor'}
    seed : int
        Seed of the sensor's noise (each case uses it).
    duration_s : float, optional
        Shorten every test to this many seconds (short mode; the paper's figures need the full length).
    controller : Controller or factory, optional
        The torque controller of every case (:class:`sim.run.Controller`: ``reset()``, ``step(observation)``;
        reset before each case), or a factory ``(params, feedback) -> Controller`` called per case; by default
        the paper's PI (:func:`paper_pi`). It observes ``tau_ref``, the feedback's torque (``tau_sensor`` or
        ``tau_current_estimate``), ``q_motor`` and ``qd_motor``.
    """
    params = params or TestbedParams()
    for kind in feedbacks:
        check_feedback(kind)
    hold = STEP_HOLD_S if duration_s is None else duration_s
    cases = []
    for kind in feedbacks:
        for step in STEPS_NM:
            cases.append(run_step_case(params, kind, step, seed, hold, progress, controller))
        cases.append(run_disturbance_case(params, kind, seed, duration_s, progress, controller))
    return StepResult(cases, seed)


def plot_step(result: StepResult, directory: Path) -> Path:
    """Figure like the paper's: one panel per test, load-cell torque under each feedback beside the reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(c.name for c in result.cases))
    columns = min(2, len(names))
    rows = -(-len(names) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(6.0 * columns, 3.8 * rows), squeeze=False)
    colours = {"current": "tab:green", "sensor": "tab:gray"}
    for ax, name in zip(axes.flat, names, strict=False):  # a grid cell may be left empty
        twin = ax.twinx() if name == "disturbance" else None  # the hand's torque, on its own scale
        for c in (c for c in result.cases if c.name == name):
            log = c.log
            ax.plot(log["time"], log["tau_loadcell"], color=colours[c.feedback], lw=0.9,
                    label=f"load cell, {c.feedback} fb (RMS error {c.error.rms_nm:.4f} N·m)")
            if twin is not None:
                twin.plot(log["time"], log["tau_hub"], ":", color=colours[c.feedback], lw=1.0,
                          label=f"flange disturbance ({c.feedback} run)")
            if c.disturbance_at_loss_nm is not None:
                ax.axvline(c.window_s[1], color=colours[c.feedback], lw=1.0, ls="-.",
                           label=f"regulation lost, {c.feedback} fb ({c.disturbance_at_loss_nm:.2f} N·m)")
        windows = {c.feedback: c.window_s for c in result.cases if c.name == name}
        if len(set(windows.values())) == 1:  # the steps: one settled window for both feedbacks
            ax.axvspan(*next(iter(windows.values())), color="0.5", alpha=0.1, lw=0, label="evaluated window")
        else:
            for kind, window in windows.items():
                ax.axvspan(*window, color=colours[kind], alpha=0.1, lw=0, label=f"evaluated, {kind} fb")
        ref = next(c for c in result.cases if c.name == name).log
        ax.plot(ref["time"], ref["tau_ref"], "k--", lw=0.8, label="reference")
        if twin is not None:  # the regulated torque is taken from rest at the start: its overshoot is no finding
            peak = max(float(np.max(c.log["tau_loadcell"][c.log["time"] < START_UP_S]))
                       for c in result.cases if c.name == name)
            ax.annotate("start-up: 0.5 N·m taken from rest\n(before the push; not evaluated)", xy=(0.0, peak),
                        xytext=(0.25, 0.97), textcoords="axes fraction", fontsize=7, va="top",
                        arrowprops={"arrowstyle": "->", "lw": 0.6})
        ax.set(title=name, xlabel="time [s]", ylabel="load-cell torque [N·m]")
        handles, labels = ax.get_legend_handles_labels()
        if twin is not None:
            twin.set_ylabel("flange disturbance [N·m] (dotted)")
            more = twin.get_legend_handles_labels()
            handles, labels = handles + more[0], labels + more[1]
        ax.legend(handles, labels, fontsize=8, loc="best")
    for ax in list(axes.flat)[len(names):]:
        ax.set_visible(False)
    fig.suptitle("Step and disturbance tests, locked lever (paper Fig. 11, Table VI)", fontsize=11)
    fig.tight_layout()
    return save_figure(fig, directory, PLOT_FILES[0])


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    add_experiment_args(parser, figures=PLOT_FILES)
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args)
    print("running the step and disturbance tests (progress on stderr) ...", file=sys.stderr)
    with run_errors(parser):
        result = run_step(params, feedback_kinds(args.feedback), args.seed, args.duration, progress=True)
    short_run_banner(args)
    print(format_rows("Step and disturbance tests, locked lever: load-cell torque vs reference (Table VI)",
                      result.rows()))
    write_outputs(args, result.to_dict(), result.plot)
    record_rerun(args, result.logs(), params)


if __name__ == "__main__":
    main()
