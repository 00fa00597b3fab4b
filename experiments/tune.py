"""Tune the PI torque gains (optionally with a velocity-damping term) on the Gymnasium environment and compare
them with the paper's (Kp 0.12, Ki 12 1/s) on the step and sine tasks.

    python -m experiments.tune [--feedback {sensor,current}] [--damping] [--max-evaluations N] [--gain-margin M]
                               [--workers N] [--ray [ADDRESS]] [--seed N] [--duration S] [--json PATH]
                               [--plot DIR] [--params TOML]

Controller, per 1 ms tick, on the environment's observation (``envs.torque_tracking``)::

    u_k = PI(τ_ref,k, τ_meas,k) - K_d · ω_motor,k          (K_d = 0 unless --damping)

with :class:`controllers.pi.PITorqueController` (reference feed-forward, the paper's anti-windup gain 5 1/s)
and τ_meas the sensor reading (or the driver's current-based estimate with ``--feedback current``).

Tasks (:data:`TUNE_TASKS`): the paper's 0.1 N·m step, 0.05 N·m and 10 N·m sines at 0.2 Hz, each one episode
of ``--duration`` seconds (default 3 s) from rest with a fixed seed per task (the same sensor and load-cell
noise for every candidate: common random numbers). E_t(g) is the RMS of load-cell torque minus reference
over the episode from the reference's first non-zero tick (the step; the sine's first tick), the error the
experiments report.

Optimisation problem::

    minimise  J(x) = max_t  E_t(g(x)) / E_t(g_paper)
    x = (ln Kp, ln Ki [, K_d])     subject to  Kp in [1e-3, 10], Ki in [0.1, 1000] 1/s, K_d in [0, 1] N·m·s/rad
                                   and  E_t(M·g(x)) <= E_t(g_paper) for every t   (gain margin M, default 2)

The last constraint is a gain-margin check run on the rig itself: the controller with every gain multiplied
by M (the loop gain raised by M, 6 dB for M = 2, the usual minimum gain margin of classical loop design) must
still track every task at least as well as the paper's gains do. Without it the minimax drives Kp to the edge
of instability (on the default rig the search reached Kp 1.04 while Kp 1.175 made the loop oscillate on the
10 N·m sine, RMS error 34 N·m against 0.23), gains nobody should take to hardware. The check doubles the cost
of an evaluation; ``--gain-margin 1`` switches it off.

solved by Nelder-Mead (scipy) from the paper's gains with an initial simplex of ±ln 2 in each log-gain
(+0.02 N·m·s/rad in K_d), ``--max-evaluations`` evaluations of J (default 40); J = inf outside the box or
when the physics diverges. The method is deterministic (no random draws). J(x_paper) = 1 is the first
evaluation and Nelder-Mead returns the best point it evaluated, so J(tuned) <= 1: the tuned gains are no worse
than the paper's on any task (checked again after the search; the paper's gains are returned otherwise).

What limits the gain: the minimax is set by the 0.05 N·m sine, whose error is not smooth in Ki on the
default rig (the gear sticks and slips around the zero crossings: with 3 s episodes Ki = 12.5 1/s raises its RMS
error from 0.0095 to 0.016 N·m while the step and the 10 N·m sine improve with Ki), so the search mostly
raises Kp. With a single noise realisation per task the optimum is specific to it; use ``--seed`` to check.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from controllers.feedback import check_feedback
from controllers.pi import FEEDBACK_KEYS, PAPER_KI_PER_S, PAPER_KP, PITorqueController
from controllers.tracking import tracking_error
from envs.torque_tracking import OBSERVATION_NAMES
from envs.torque_tracking_vector import TorqueTrackingVectorEnv
from experiments.common import (
    add_executor_args,
    add_experiment_args,
    cli_parser,
    executor_from_args,
    load_params_arg,
    positive_int,
    record_rerun,
    run_errors,
    short_run_banner,
    write_outputs,
)
from sim.executor import Executor
from sim.figures import save_figure
from sim.motor_torque import CurrentToTorqueMap
from sim.params import TestbedParams
from sim.runlog import RunLog

PLOT_FILES = ("tune.png",)  # the files --plot writes

DEFAULT_DURATION_S = 3.0  # [s] per task episode
DEFAULT_MAX_EVALUATIONS = 40
DEFAULT_GAIN_MARGIN = 2.0  # [-] loop-gain factor the tuned gains must tolerate (6 dB; see the module docstring)
KP_RANGE = (1e-3, 10.0)  # [-]
KI_RANGE_PER_S = (0.1, 1000.0)  # [1/s]
KD_RANGE_NMS_PER_RAD = (0.0, 1.0)  # [N·m·s/rad]
SIMPLEX_LOG_STEP = math.log(2.0)  # initial simplex: gains halved / doubled
SIMPLEX_KD_STEP = 0.02  # [N·m·s/rad]


@dataclass(frozen=True)
class TuneTask:
    """One task: its name and the environment's reset options."""

    name: str
    options: dict


TUNE_TASKS = (TuneTask("step 0.1 N·m", {"task": "step", "amplitude_nm": 0.1}),
              TuneTask("0.05 N·m sine 0.2 Hz", {"task": "sine", "amplitude_nm": 0.05, "frequency_hz": 0.2}),
              TuneTask("10 N·m sine 0.2 Hz", {"task": "sine", "amplitude_nm": 10.0, "frequency_hz": 0.2}))


@dataclass(frozen=True)
class Gains:
    """PI gains and velocity damping: Kp [-], Ki [1/s], Kd [N·m·s/rad]."""

    kp: float
    ki_per_s: float
    kd_nms_per_rad: float = 0.0

    def to_dict(self) -> dict:
        return {"kp": self.kp, "ki_per_s": self.ki_per_s, "kd_nms_per_rad": self.kd_nms_per_rad}

    def controller(self, params: TestbedParams, feedback: str = "sensor") -> PITorqueController:
        """The PI with these gains and velocity damping, closing on ``feedback`` at the driver's limit."""
        return PITorqueController(output_limit_nm=CurrentToTorqueMap.from_params(params).command_limit_nm,
                                  kp=self.kp, ki_per_s=self.ki_per_s, period_s=params.simulation.control_period_s,
                                  measured=FEEDBACK_KEYS[feedback], velocity_damping_nms_per_rad=self.kd_nms_per_rad)


PAPER_GAINS = Gains(PAPER_KP, PAPER_KI_PER_S, 0.0)


@dataclass(frozen=True)
class Episode:
    """One task run with one set of gains: RMS error [N·m] over the graded window and its traces."""

    rms_nm: float
    time_s: np.ndarray = field(repr=False)
    reference_nm: np.ndarray = field(repr=False)
    output_nm: np.ndarray = field(repr=False)


def run_episodes(vec: TorqueTrackingVectorEnv, runs: list[tuple[Gains, TuneTask, int]],
                 feedback: str = "sensor") -> list[Episode]:
    """One episode per (gains, task, seed) of ``runs``, environment i of ``vec`` (``num_envs = len(runs)``)
    running run i with its gains' controller; inf RMS for a run whose physics diverged."""
    options = {key: [task.options.get(key) for _, task, _ in runs] for key in ("task", "amplitude_nm", "frequency_hz")}
    obs, _ = vec.reset(seed=[seed for _, _, seed in runs], options=options)
    controllers = [gains.controller(vec.template.nominal_params, feedback) for gains, _, _ in runs]
    n, m = vec.n_steps, len(runs)
    time, ref, out = np.empty((m, n)), np.empty((m, n)), np.empty((m, n))
    ended = [n] * m  # ticks run by each environment (fewer if its physics diverged)
    action = np.zeros((m, 1))
    for k in range(n):
        for i, controller in enumerate(controllers):
            action[i, 0] = controller.step(dict(zip(OBSERVATION_NAMES, obs[i].tolist(), strict=True)))
        obs, _, terminated, _, info = vec.step(action)
        for i in np.flatnonzero(terminated).tolist():
            ended[i] = min(ended[i], k)
        time[:, k], ref[:, k], out[:, k] = info["time_s"], info["reference_nm"], info["loadcell_torque_nm"]
    episodes = []
    for i, k in enumerate(ended):
        if k < n:
            episodes.append(Episode(math.inf, time[i, :k], ref[i, :k], out[i, :k]))
            continue
        start = int(np.flatnonzero(ref[i])[0]) if np.any(ref[i]) else 0  # graded from the reference's first move on
        episodes.append(Episode(tracking_error(out[i, start:], ref[i, start:]).rms_nm, time[i], ref[i], out[i]))
    return episodes


_VECTOR_ENVS: dict[tuple, TorqueTrackingVectorEnv] = {}  # by (process, num_envs, length, params, threads)


def run_chunk(setup: tuple[TestbedParams | None, float, str, int], runs: list[tuple[Gains, TuneTask, int]]
              ) -> list[Episode]:
    """:func:`run_episodes` of ``runs`` on a vector environment of this process (built once per size): an item
    of the executor. ``setup`` = (params, episode length [s], feedback, physics threads: 0 every CPU)."""
    params, duration_s, feedback, nthread = setup
    # keyed by process: a forked worker inherits the parent's environments but not their threads
    key = (os.getpid(), len(runs), duration_s, params, nthread)
    for stale in [k for k in _VECTOR_ENVS if k[0] == key[0] and k[2:] != key[2:]]:  # another tuning run's
        _VECTOR_ENVS.pop(stale).close()
    if key not in _VECTOR_ENVS:
        _VECTOR_ENVS[key] = TorqueTrackingVectorEnv(len(runs), episode_duration_s=duration_s, params=params,
                                                    nthread=nthread)
    return run_episodes(_VECTOR_ENVS[key], runs, feedback)


def split(runs: list, parts: int) -> list[list]:
    """``runs`` in at most ``parts`` contiguous chunks of near-equal length, in order."""
    bounds = np.linspace(0, len(runs), min(parts, len(runs)) + 1).round().astype(int)
    return [runs[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


@dataclass(frozen=True)
class TuneResult:
    """Paper vs tuned gains and each task's RMS errors [N·m] under both."""

    paper: Gains
    tuned: Gains
    tasks: list[str]
    paper_rms_nm: list[float]
    tuned_rms_nm: list[float]
    objective: float
    evaluations: int
    feedback: str
    duration_s: float
    seed: int
    fell_back: bool
    gain_margin: float = 1.0
    margin_rms_nm: list[float] = field(default_factory=list)  # each task's RMS error, tuned gains x gain_margin
    traces: dict = field(default_factory=dict, repr=False, compare=False)

    def rows(self) -> list[dict]:
        return [{"task": t, "paper_rms_nm": p, "tuned_rms_nm": q, "ratio": q / p if p else None}
                for t, p, q in zip(self.tasks, self.paper_rms_nm, self.tuned_rms_nm, strict=True)]

    def to_dict(self) -> dict:
        return {"paper": self.paper.to_dict(), "tuned": self.tuned.to_dict(), "rows": self.rows(),
                "objective": self.objective, "evaluations": self.evaluations, "feedback": self.feedback,
                "duration_s": self.duration_s, "seed": self.seed, "fell_back_to_paper": self.fell_back,
                "gain_margin": self.gain_margin, "margin_rms_nm": self.margin_rms_nm,
                "optimizer": "Nelder-Mead on (ln Kp, ln Ki[, Kd]) from the paper's gains; "
                             "objective max_t E_t/E_t,paper, subject to E_t(M g) <= E_t(g_paper)"}


def _gains(x: np.ndarray) -> Gains | None:
    kp, ki = math.exp(x[0]), math.exp(x[1])
    kd = float(x[2]) if len(x) > 2 else 0.0
    if not (KP_RANGE[0] <= kp <= KP_RANGE[1] and KI_RANGE_PER_S[0] <= ki <= KI_RANGE_PER_S[1]
            and KD_RANGE_NMS_PER_RAD[0] <= kd <= KD_RANGE_NMS_PER_RAD[1]):
        return None
    return Gains(kp, ki, kd)


def _scaled(g: Gains, factor: float) -> Gains:
    """The controller with every gain multiplied by ``factor`` (its loop gain raised by that factor)."""
    return Gains(factor * g.kp, factor * g.ki_per_s, factor * g.kd_nms_per_rad)


def tune(params: TestbedParams | None = None, feedback: str = "sensor", damping: bool = False,
         duration_s: float = DEFAULT_DURATION_S, max_evaluations: int = DEFAULT_MAX_EVALUATIONS, seed: int = 0,
         progress: bool = False, gain_margin: float = DEFAULT_GAIN_MARGIN,
         executor: Executor | None = None) -> TuneResult:
    """Tune the gains (see the module docstring for the problem and the method).

    Parameters
    ----------
    params : TestbedParams, optional
        Parameter set of the rig (defaults if None).
    feedback : {'sensor', 'current'}
        Which measured torque the PI closes on.
    damping : bool
        Also tune the velocity-damping gain K_d [N·m·s/rad].
    duration_s : float
        Episode length per task [s].
    max_evaluations : int
        Evaluations of the objective (each runs every task once).
    seed : int
        Task t runs with environment seed ``seed + t``.
    gain_margin : float
        M >= 1: candidates whose gains x M track any task worse than the paper's gains are inadmissible
        (1 switches the check off).
    executor : Executor, optional
        Where each evaluation's episodes run, in :meth:`Executor.slots` chunks of one vector environment each
        (this process if None, its environment's threads on every core); the result does not depend on it. On one
        machine this process is the fastest (benchmarks/README.md); the executor is for a Ray cluster.
    """
    check_feedback(feedback)
    if max_evaluations < 1:
        raise ValueError(f"max_evaluations = {max_evaluations!r}: valid range [1, inf)")
    if not (math.isfinite(gain_margin) and gain_margin >= 1.0):
        raise ValueError(f"gain_margin = {gain_margin!r}: valid range [1, inf)")
    executor = executor or Executor(1)
    slots = executor.slots
    setup = (params, duration_s, feedback, 0 if slots == 1 else 1)  # one physics thread per worker
    episodes: dict[Gains, list[Episode]] = {}  # the objective's episodes, reused for the winner's traces

    def evaluate(*candidates: Gains) -> None:
        """Run every task of the candidates not run yet, all episodes together (one environment each)."""
        new = list(dict.fromkeys(g for g in candidates if g not in episodes))
        runs = [(g, task, seed + t) for g in new for t, task in enumerate(TUNE_TASKS)]
        if not runs:
            return
        chunks = executor.map(run_chunk, split(runs, slots), shared=setup)
        done = [episode for chunk in chunks for episode in chunk]
        for j, g in enumerate(new):
            episodes[g] = done[j * len(TUNE_TASKS):(j + 1) * len(TUNE_TASKS)]

    def errors(g: Gains) -> list[Episode]:
        evaluate(g)
        return episodes[g]

    paper_eps = errors(PAPER_GAINS)
    paper_rms = [e.rms_nm for e in paper_eps]

    def margin_rms(g: Gains) -> list[float]:
        """Each task's RMS error [N·m] with the gains x gain_margin (empty when the check is off)."""
        return [e.rms_nm for e in errors(_scaled(g, gain_margin))] if gain_margin > 1.0 else []

    def admissible(margin: list[float]) -> bool:
        return all(m <= p for m, p in zip(margin, paper_rms, strict=True))
    count = [1]
    if progress:
        print(f"tune: evaluation 1/{max_evaluations}: paper gains, RMS " +
              ", ".join(f"{r:.4g}" for r in paper_rms) + " N·m", file=sys.stderr)

    def objective(x: np.ndarray) -> float:
        g = _gains(x)
        if g is None:
            return math.inf
        if count[0] >= max_evaluations:
            return math.inf
        count[0] += 1
        evaluate(g, *([_scaled(g, gain_margin)] if gain_margin > 1.0 else []))
        ok = admissible(margin_rms(g))
        value = max(e.rms_nm / p for e, p in zip(errors(g), paper_rms, strict=True)) if ok else math.inf
        if progress:
            print(f"tune: evaluation {count[0]}/{max_evaluations}: Kp {g.kp:.4g}, Ki {g.ki_per_s:.4g} 1/s"
                  + (f", Kd {g.kd_nms_per_rad:.4g} N·m·s/rad" if damping else "")
                  + (f": J = {value:.4f}" if ok else f": gain margin below {gain_margin:g} (inadmissible)"),
                  file=sys.stderr)
        return value

    x0 = np.array([math.log(PAPER_KP), math.log(PAPER_KI_PER_S)] + ([0.0] if damping else []))
    steps = [SIMPLEX_LOG_STEP, SIMPLEX_LOG_STEP] + ([SIMPLEX_KD_STEP] if damping else [])
    simplex = [x0] + [x0 + step * np.eye(len(x0))[i] for i, step in enumerate(steps)]
    best = {"x": x0, "f": 1.0}

    def tracked(x: np.ndarray) -> float:
        if np.array_equal(x, x0):
            return 1.0  # J(paper) = 1 by definition, already run
        f = objective(x)
        if f < best["f"]:
            best.update(x=np.array(x), f=f)
        return f

    if max_evaluations > 1:
        minimize(tracked, x0, method="Nelder-Mead",
                 options={"initial_simplex": np.array(simplex), "maxfev": max_evaluations,
                          "xatol": 1e-3, "fatol": 1e-4})
    tuned = _gains(best["x"]) or PAPER_GAINS
    tuned_eps = errors(tuned)
    tuned_rms = [e.rms_nm for e in tuned_eps]
    tuned_margin = margin_rms(tuned)
    fell_back = any(q > p for q, p in zip(tuned_rms, paper_rms, strict=True)) or not admissible(tuned_margin)
    if fell_back:  # not expected: the objective is deterministic
        tuned, tuned_eps, tuned_rms, tuned_margin = PAPER_GAINS, paper_eps, paper_rms, margin_rms(PAPER_GAINS)
    objective_value = max(q / p for q, p in zip(tuned_rms, paper_rms, strict=True))
    traces = {task.name: {"paper": pe, "tuned": te}
              for task, pe, te in zip(TUNE_TASKS, paper_eps, tuned_eps, strict=True)}
    return TuneResult(PAPER_GAINS, tuned, [t.name for t in TUNE_TASKS], paper_rms, tuned_rms, objective_value,
                      count[0], feedback, duration_s, seed, fell_back, gain_margin, tuned_margin, traces)


def tune_logs(result: TuneResult, params: TestbedParams | None = None) -> dict:
    """Each task's episode under the paper's and the tuned gains as run logs (reference and load-cell torque;
    no angles, so a recording shows the time series only). ``params``: the rig tuned on (its lever length)."""
    lever_m = (params or TestbedParams()).lever.length_m
    logs = {}
    for task, pair in result.traces.items():
        for label, ep in pair.items():
            logs[f"{task}, {label} gains"] = RunLog(
                {"time": ep.time_s, "tau_ref": ep.reference_nm, "force_loadcell": ep.output_nm / lever_m},
                {"time": "s", "tau_ref": "N·m", "force_loadcell": "N"},
                {"fixture": "locked", "lever_length_m": lever_m,
                 **(result.paper if label == "paper" else result.tuned).to_dict()})
    return logs


def format_result(r: TuneResult) -> str:
    lines = [f"PI torque gains tuned on torquebed/TorqueTracking-v0 ({r.feedback} feedback, {r.duration_s:g} s "
             f"episodes, {r.evaluations} evaluations of J = max_t E_t / E_t,paper)",
             f"{'gains':8s} {'Kp [-]':>9s} {'Ki [1/s]':>10s} {'Kd [N·m·s/rad]':>15s}"]
    for label, g in (("paper", r.paper), ("tuned", r.tuned)):
        lines.append(f"{label:8s} {g.kp:9.4g} {g.ki_per_s:10.4g} {g.kd_nms_per_rad:15.4g}")
    width = max(len(t) for t in r.tasks)
    lines.append(f"{'task':{width}s} {'paper RMS [N·m]':>16s} {'tuned RMS [N·m]':>16s} {'ratio':>6s}")
    for row in r.rows():
        lines.append(f"{row['task']:{width}s} {row['paper_rms_nm']:16.5g} {row['tuned_rms_nm']:16.5g} "
                     f"{row['ratio']:6.3f}")
    if r.margin_rms_nm:
        lines.append(f"gain margin check, tuned gains x {r.gain_margin:g} (must not be worse than the paper's): RMS "
                     + ", ".join(f"{m:.5g}" for m in r.margin_rms_nm) + " N·m")
    if r.fell_back:
        lines.append("the search found nothing better than the paper's gains on every task: paper's gains kept")
    return "\n".join(lines)


def plot_tune(result: TuneResult, directory: Path) -> Path:
    """Load-cell torque under the paper's and the tuned gains beside the reference, one panel per task."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(result.tasks), figsize=(4.2 * len(result.tasks), 3.4), squeeze=False)
    for ax, (name, pair) in zip(axes[0], result.traces.items(), strict=True):
        ax.plot(pair["paper"].time_s, pair["paper"].reference_nm, "k--", lw=0.8, label="reference")
        for label, colour in (("paper", "tab:gray"), ("tuned", "tab:blue")):
            ep = pair[label]
            ax.plot(ep.time_s, ep.output_nm, color=colour, lw=0.8, label=f"{label} gains (RMS {ep.rms_nm:.4g})")
        ax.set(title=name, xlabel="time [s]", ylabel="load-cell torque [N·m]")
        ax.legend(fontsize=6)
    return save_figure(fig, directory, PLOT_FILES[0])


def main(argv: list[str] | None = None) -> None:
    parser = cli_parser(__doc__, __spec__.name)
    parser.add_argument("--feedback", choices=tuple(FEEDBACK_KEYS), default="sensor",
                        help="measured torque the PI closes on (default sensor)")
    parser.add_argument("--damping", action="store_true", help="also tune a velocity-damping gain K_d")
    parser.add_argument("--max-evaluations", type=positive_int, default=DEFAULT_MAX_EVALUATIONS, metavar="N",
                        help=f"evaluations of the objective (default {DEFAULT_MAX_EVALUATIONS})")
    parser.add_argument("--gain-margin", type=float, default=DEFAULT_GAIN_MARGIN, metavar="M",
                        help=f"the tuned gains x M must still track every task as well as the paper's "
                             f"(default {DEFAULT_GAIN_MARGIN:g} = 6 dB; 1 switches the check off)")
    add_executor_args(parser, "each evaluation's episodes")
    add_experiment_args(parser, feedback=False, figures=PLOT_FILES)
    args = parser.parse_args(argv)
    params = load_params_arg(parser, args)
    if not (math.isfinite(args.gain_margin) and args.gain_margin >= 1):
        parser.error(f"--gain-margin {args.gain_margin}: must be >= 1")
    duration = DEFAULT_DURATION_S if args.duration is None else args.duration
    print(f"tuning on {len(TUNE_TASKS)} tasks x {duration:g} s (progress on stderr) ...", file=sys.stderr)
    executor = executor_from_args(parser, args)
    with run_errors(parser):
        result = tune(params, args.feedback, args.damping, duration, args.max_evaluations, args.seed, progress=True,
                      gain_margin=args.gain_margin, executor=executor)
    short_run_banner(args)
    print(format_result(result))
    write_outputs(args, result.to_dict(), lambda directory: plot_tune(result, directory))
    record_rerun(args, lambda: tune_logs(result, params), params)


if __name__ == "__main__":
    main()
