"""The discrepancy analysis: measured logs + a rig -> findings, the unexplained remainder, the extended rig.

Steps (``analyse``):

1. check every log against the rig (:mod:`sim.discrepancy.checks`), bring it to the hold-end time convention,
   and join the logs: estimation logs are split into a leading fit part and a held-out part (or fitted whole
   when validation logs are given, which are then the held-out part);
2. re-fit the rig's free baseline parameters (and nuisances) on the fit part; refuse a baseline that cannot
   produce the logged motion with the logged effort;
3. diagnostics of the baseline residual; which effects the logs cannot reveal;
4. forward selection (:mod:`sim.discrepancy.selection`): each round judges every remaining candidate, fitted
   jointly with everything accepted so far, against the current model; the best that passes every rule is
   accepted, until none does;
5. the final model (:func:`final_model`): the confident findings re-fitted alone, written as the extended rig
   and read back on the logs as an analysis of it begins, so that every final figure is the saved rig's; what its
   residual still holds (:mod:`sim.discrepancy.structure`), the relative effort prediction error of the baseline
   and the final model on every log, and optionally a windowed MuJoCo replay of the held-out part before and
   after.
"""

from __future__ import annotations

import math
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sim.discrepancy.checks import (
    ASSUMED_CONVENTION,
    InputError,
    check_effort_balance,
    check_log,
    time_convention,
    to_hold_end,
)
from sim.discrepancy.effects import EFFECTS, rig_kind
from sim.discrepancy.fit import FitOutcome, fit_keys
from sim.discrepancy.model import NUISANCE_KEYS, Surrogate, channel_unit
from sim.discrepancy.null import ModelLogUnavailable, model_log
from sim.discrepancy.rig import AddedEffect, Rig, check_rig_matches_log, rig_field, rig_from_dict, rig_to_toml
from sim.discrepancy.selection import (
    Candidate,
    ChannelScore,
    against_model_log,
    carried_by_model,
    effort_change,
    fit_candidate,
    held_out_score,
    make_executor,
    run_round,
)
from sim.discrepancy.signals import (
    MAX_ANALYSIS_SAMPLES,
    AnalysisConfig,
    Prepared,
    Segment,
    decimate,
    decimation_factor,
    prepare,
    rms,
    smallest_step,
)
from sim.discrepancy.structure import Structure, residual_structure
from sim.discrepancy.windows import LOW_SPEED
from sim.runlog import COMMAND, RunLog

CHANNEL_MEANING = {
    "effort": "effort-prediction residual: commanded effort minus the effort the model needs for the measured "
              "motion and load",
    "sensor": "torque sensor minus the transmitted torque the model predicts it reads",
    "kinematic": "motor angle minus lever angle minus flexure twist, against the backlash model",
}
# [samples] with no time convention stated, a dead time found beyond the rig's within this range is read as logs
# stamped in the 'command' convention (one sample of it; the rest judged as a dead time: :func:`final_model`); a
# longer one is a dead time. Below one sample the reading in that convention stands for at most a quarter sample
# more than the data show; above, for exactly what they show.
CONVENTION_RANGE = (0.75, 1.5)
STAND_IN_GAIN = 1.0 / 3.0  # beside an unexplained remainder, a finding explaining less is a stand-in
LISTED_REJECTED_GAIN = 0.10  # refused candidates with at least this held-out gain are listed with their rule
ALTERNATIVE_SHARE = 0.05  # another candidate explaining all but this share of a finding's drop is named beside it
WIDEN = 10.0  # a free parameter that ends at a bound is re-fitted with bounds this many times as wide
SECONDS_PER_GRID_SAMPLE = 5e-5  # the expected time of a run per analysis-grid sample and candidate, per worker
# (measured on a rigid slide: 36 s for 125 000 grid samples, 12 candidates, 2 workers; a testbed costs ~5 x more)
TESTBED_COST = 5.0
ANNOUNCE_ABOVE_S = 20.0  # the expected time is announced for runs expected to take longer


@dataclass(frozen=True)
class Finding:
    """An accepted effect: fitted parameters (unit, bounds, the rig's value for a re-fit), held-out RMSE at its
    acceptance, evidence; ``kind`` 're-fit' when the rig carries the effect with another value, else 'effect'."""

    effect: str
    kind: str
    parameters: dict[str, dict[str, Any]]
    rmse_heldout_before: float
    rmse_heldout_after: float
    gain: float
    evidence: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "kind": self.kind, "parameters": self.parameters,
                "rmse_heldout_before": self.rmse_heldout_before, "rmse_heldout_after": self.rmse_heldout_after,
                "gain": self.gain, "evidence": self.evidence}


@dataclass(frozen=True)
class DiscrepancyResult:
    """Everything the analysis found.

    Attributes
    ----------
    baseline : dict
        The baseline model: rig, split, re-fitted free parameters, held-out RMSE per channel, autocorrelation,
        signatures, effects the logs cannot reveal and why, every round's candidate table, timings.
    findings : list of Finding
        Confident findings in the order found (parameters at the final joint fit).
    tentative : list of Finding
        Effects the search accepted that are not saved (partial stand-ins beside an unexplained remainder, or at a
        bound without them), with their values in the search's model and why (``evidence['why_not_saved']``).
    verdict : str
        'found', 'unexplained', 'found, and an unexplained remainder', 'time convention' (the only discrepancy is
        logs stamped in another time convention than the one assumed, see ``baseline['time_convention_mismatch']``)
        or 'no significant discrepancy'.
    structure : Structure
        What the final residual still holds (the unexplained remainder and its signature).
    rejected : list of dict
        Candidates of the last round with a large held-out gain, and the rule that refused each.
    logs : list of dict
        Each log's role (estimation, validation) and the relative effort prediction error ‖F - F̂‖/‖F‖ of the
        baseline, the final model (the saved rig) and, if any, the search's model with the tentative effects, on
        its scored part.
    signal, units : dict
        Residual channels used, with their meaning and unit.
    extended_rig : Rig
        The final model: the rig with the confident findings, as ``--save-rig`` writes it and reads it back.
    final : dict
        The final model's rig, held-out RMSE per channel, re-fitted free parameters and the logs' own zeros.
    """

    baseline: dict[str, Any]
    findings: list[Finding]
    tentative: list[Finding]
    verdict: str
    structure: Structure
    rejected: list[dict[str, Any]]
    logs: list[dict[str, Any]]
    signal: dict[str, str]
    units: dict[str, str]
    extended_rig: Rig = field(repr=False)
    final: dict[str, Any] = field(default_factory=dict)
    theta_baseline: dict[str, float] = field(repr=False, default_factory=dict)
    theta_final: dict[str, float] = field(repr=False, default_factory=dict)
    residuals_baseline: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    residuals_final: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    time: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    held: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, bool))
    fit: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, bool))
    replay: dict[str, Any] = field(default_factory=dict)

    @property
    def found(self) -> list[str]:
        return [f.effect for f in self.findings]

    def to_dict(self) -> dict[str, Any]:
        baseline = dict(self.baseline)
        if self.replay:
            baseline["replay"] = {k: v for k, v in self.replay.items() if not isinstance(v, np.ndarray)}
        return {"baseline": baseline, "findings": [f.to_dict() for f in self.findings],
                "tentative": [f.to_dict() for f in self.tentative], "verdict": self.verdict,
                "unexplained": self.structure.to_dict(), "rejected": self.rejected, "logs": self.logs,
                "final": self.final, "signal": self.signal, "units": self.units}


def _progress(message: str, enabled: bool) -> None:
    if enabled:
        print(f"discrepancy: {message}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------------- joining logs


@dataclass(frozen=True)
class Source:
    """One log of the analysis: its name, role ('estimation' or 'validation') and columns (hold-end convention)."""

    name: str
    role: str
    log: RunLog


def _segments(sources: list[Source], config: AnalysisConfig) -> list[Segment] | None:
    """The joined sources' segments (None for one log): fitted whole when validation logs are held out, else
    split at ``config.fit_fraction``."""
    if len(sources) == 1:
        return None
    _, segments = join(sources)
    if not any(s.role == "validation" for s in sources):
        segments = [(a, b, config.fit_fraction) for a, b, _ in segments]
    return segments


def join_and_prepare(sources: list[Source], rig: Rig, config: AnalysisConfig
                     ) -> tuple[RunLog, list[Segment], int, Prepared]:
    """(the sources joined as logged, their segments in the analysis's samples, the decimation factor, the
    prepared signals): a rigid joint's log longer than MAX_ANALYSIS_SAMPLES is decimated first
    (:func:`sim.discrepancy.signals.decimation_factor`), keeping its command hold and encoder step."""
    joined, _ = join(sources)
    segments = _segments(sources, config) or []
    dt = float(np.median(np.diff(joined["time"])))
    factor = decimation_factor(len(joined), dt, config, rig)
    if factor == 1:
        return joined, segments, 1, prepare(joined, rig, config, segments=segments or None)
    resolution = smallest_step(joined["q"])
    bounds = tuple((a, b) for a, b, _ in segments)
    segments = [(-(-a // factor), -(-b // factor), f) for a, b, f in segments]
    data = prepare(decimate(joined, factor, bounds), rig, config, segments=segments or None, hold_s=dt,
                   resolution=resolution)
    return joined, segments, factor, data


def join(sources: list[Source]) -> tuple[RunLog, list[Segment]]:
    """The sources as one log (each after the previous by one sampling step; the columns they all have) and
    their segments."""
    if len(sources) == 1:
        return sources[0].log, []
    first = sources[0].log
    common = [c for c in first.columns if all(c in s.log.columns for s in sources)]
    for s in sources[1:]:
        for c in common:
            if s.log.units[c] != first.units[c]:
                raise InputError(f"{s.name}: column {c!r} is in {s.log.units[c]!r}, {sources[0].name} in "
                                 f"{first.units[c]!r}", column=c)
    dt = float(np.median(np.diff(first["time"])))
    columns: dict[str, list[np.ndarray]] = {c: [] for c in common}
    segments, start, t_next = [], 0, float(first["time"][0])
    for s in sources:
        n = len(s.log)
        for c in common:
            values = np.asarray(s.log[c], dtype=float)
            columns[c].append(values - values[0] + t_next if c == "time" else values)
        t_next = columns["time"][-1][-1] + dt
        segments.append((start, start + n, 1.0 if s.role == "estimation" else 0.0))
        start += n
    joined = {c: np.concatenate(v) for c, v in columns.items()}
    return type(first)(joined, {c: first.units[c] for c in common}, dict(first.meta)), segments


# ------------------------------------------------------------------------------------------------ analysis


@dataclass(frozen=True)
class Stage:
    """A rig on the logs as an analysis reads them: each log checked and brought to the hold-end time convention,
    the logs joined and prepared, the rig's surrogate, and the rig's free parameters (and nuisances) re-fitted on
    the fit part. The analysis starts from the user's rig; its final model is the saved rig read the same way, as an
    analysis of the saved rig begins."""

    rig: Rig
    sources: list[Source]
    conventions: list[dict[str, str]]
    joined: RunLog
    segments: list[Segment]
    factor: int
    data: Prepared
    model: Surrogate
    refit: FitOutcome  # the free parameters and nuisances re-fitted
    score: ChannelScore  # held-out RMSE of the rig with them
    scales: dict[str, float]  # each channel's RMS on the fit part there (the fits' weights)
    keys: tuple[str, ...]  # the free parameters' and nuisances' theta keys

    @property
    def theta(self) -> dict[str, float]:
        return self.refit.theta


def read_stage(logs: tuple[RunLog, ...], names: tuple[str, ...], roles: list[str], rig: Rig, config: AnalysisConfig,
               unwrap: bool = False) -> Stage:
    """``rig`` on ``logs`` (see :class:`Stage`); refuses logs the rig cannot have produced.

    Raises
    ------
    InputError
        A log the rig cannot have produced, or a baseline that needs several times the logged effort.
    RigError
        A rig that does not match a log.
    """
    sources, conventions = [], []
    for name, role, each in zip(names, roles, logs, strict=True):
        check_rig_matches_log(rig, each)
        try:
            checked = check_log(each, rig, unwrap=unwrap, filter_cutoff_hz=config.filter_cutoff_hz)
            convention, where = time_convention(each, rig)
        except InputError as exc:
            raise InputError(f"{name}: {exc}" if len(logs) > 1 else str(exc), column=exc.column, row=exc.row) from None
        conventions.append({"log": name, "time_convention": convention, "from": where})
        sources.append(Source(name, role, to_hold_end(checked, convention)))
    joined, segments, factor, data = join_and_prepare(sources, rig, config)
    model = Surrogate(data, rig, config)
    raw = model.residuals(model.theta0)
    scales = {c: rms(r[data.fit]) or 1.0 for c, r in raw.items()}
    keys = rig.free_keys + (NUISANCE_KEYS if "kinematic" in model.channels else ())
    refit = fit_keys(model, model.theta0, keys, scales)
    if refit.at_bound:
        refit = fit_keys(model, model.theta0, keys, scales, widen=WIDEN)
    refit = _free_by_own_fits(model, refit, keys, scales)
    score = held_out_score(model, refit.theta)
    check_effort_balance(model, refit.theta, score.rmse["effort"])
    scales = {c: rms(r[data.fit]) or 1.0 for c, r in model.residuals(refit.theta).items()}
    return Stage(rig, sources, conventions, joined, segments, factor, data, model, refit, score, scales, keys)


def _free_by_own_fits(model: Surrogate, refit: FitOutcome, keys: tuple[str, ...], scales: dict[str, float]
                      ) -> FitOutcome:
    """``refit`` with the free parameters of an effect that has a fit of its own (a rigid joint's Stribeck
    friction, on its low-speed windows) taken from that fit, and the other keys re-fitted with them: the balance
    cannot see them."""
    for effect in model.effects:
        own_free = [k for k in effect.keys if k in keys]
        own = effect.fit(model, refit.theta) if own_free else None
        if own is None:
            continue
        others = tuple(k for k in keys if k not in own_free)
        again = fit_keys(model, {**refit.theta, **{k: own.values[k] for k in own_free}}, others, scales)
        refit = replace(again, keys=keys, bounds={**refit.bounds, **again.bounds})
    return refit


def analyse(log: RunLog, rig: Rig, config: AnalysisConfig | None = None, *, progress: bool = False,
            replay: bool = False, also: tuple[RunLog, ...] = (), validation: tuple[RunLog, ...] = (),
            names: tuple[str, ...] = (), unwrap: bool = False) -> DiscrepancyResult:
    """Run the discrepancy analysis of ``log`` (and ``also``, fitted together) against ``rig``.

    Parameters
    ----------
    log : RunLog
        The (first) estimation log.
    rig : Rig
        What produced the logs.
    config : AnalysisConfig, optional
        Settings (defaults: :class:`AnalysisConfig`).
    progress : bool
        Progress on stderr (one line per candidate).
    replay : bool
        Replay the held-out part through MuJoCo, baseline and extended rig.
    also : tuple of RunLog
        Further estimation logs of the same rig, fitted together with ``log``.
    validation : tuple of RunLog
        Validation logs: the estimation logs are then fitted whole and candidates are scored on these.
    names : tuple of str
        Names of the logs, in the order ``log``, ``also``, ``validation`` (default: log 1, log 2, ...).
    unwrap : bool
        Unwrap hinge angles that jump by 2π (an encoder wrapped to one turn) instead of refusing them.

    Raises
    ------
    InputError
        A log the rig cannot have produced (:mod:`sim.discrepancy.checks`).
    RigError
        A rig that does not match a log.
    """
    config = config or AnalysisConfig()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    logs = (log, *also, *validation)
    roles = ["estimation"] * (1 + len(also)) + ["validation"] * len(validation)
    names = tuple(names) + tuple(f"log {i + 1}" for i in range(len(names), len(logs)))

    def read(each: Rig) -> Stage:
        return read_stage(logs, names, roles, each, config, unwrap)

    # 1-2. the logs read with the rig, its free parameters (and nuisances) re-fitted
    first = read(rig)
    model, data, theta0, theta = first.model, first.data, first.model.theta0, first.theta
    _announce(model, progress)
    timings["prepare_and_baseline_s"] = time.perf_counter() - t0
    before, scales = first.score, first.scales
    residuals_baseline = model.residuals(theta)
    rmse = ", ".join(f"{c} {value:.4g} {channel_unit(c, rig.joint)}" for c, value in before.rmse.items())
    _progress(f"baseline held-out RMSE: {rmse} ({len(first.joined)} samples, {data.fit.sum()} / {data.held.sum()} "
              f"grid samples fit / held out)", progress)

    # 3. diagnostics and identifiability
    t = time.perf_counter()
    signatures = _signatures(model, theta, residuals_baseline)
    remaining = [e.name for e in model.effects]
    not_identifiable = {e.name: why for e in model.effects if (why := e.identifiable(model, theta))}
    candidates = [name for name in remaining if name not in not_identifiable]
    timings["diagnostics_s"] = time.perf_counter() - t

    # 4. forward selection, each round judged against the current (jointly fitted) model
    t = time.perf_counter()
    findings: list[Finding] = []
    accepted: tuple[str, ...] = first.keys
    rounds: list[list[Candidate]] = []
    notes: list[str] = []
    dropped: list[dict[str, str]] = []
    executor = make_executor(config)
    current, current_score = theta, before
    while candidates and len(findings) < config.max_effects:
        label = f"round {len(rounds) + 1}, "
        _progress(f"round {len(rounds) + 1}: {len(candidates)} candidate effects, each fitted with "
                  f"{len(accepted)} accepted parameter(s)", progress)
        scores = run_round(model, candidates, current, accepted, scales, current_score, executor, progress,
                           label)
        t_null = time.perf_counter()
        best, note = _first_passing(scores, first.sources, rig, config, model, current, findings, accepted, scales)
        timings["model_log_s"] = timings.get("model_log_s", 0.0) + time.perf_counter() - t_null
        rounds.append(scores)
        if note:
            notes.append(note)
        if best is None:
            break
        channel = best.best_channel
        findings.append(Finding(
            effect=best.effect, kind=_kind(best.effect, theta0),
            parameters={}, rmse_heldout_before=best.before_rmse[channel],
            rmse_heldout_after=best.score.rmse[channel], gain=best.gains[channel],
            evidence={**_evidence(best, model, current, channel), "rmse_accepted": best.score.rmse[channel],
                      "alternatives": _alternatives(best, scores, channel)}))
        _progress(f"found {best.effect} (held-out {channel} RMSE -{100 * best.gains[channel]:.1f} %, "
                  f"ΔBIC {best.delta_bic:.1f})", progress)
        accepted = tuple(dict.fromkeys(EFFECTS[best.effect].keys + accepted))
        # the next round judges against the balance's channels (a candidate scored on the low-speed windows too
        # adds that channel to its own before and after)
        current, current_score = best.fit.theta, held_out_score(model, best.fit.theta)
        # what the logs can reveal is judged against the current model: a Stribeck drop shows against a friction
        # level found in an earlier round
        remaining = [name for name in remaining if name != best.effect]
        not_identifiable = {name: why for name in remaining if (why := EFFECTS[name].identifiable(model, current))}
        candidates = [name for name in remaining if name not in not_identifiable]
        while (pruned := _prune(model, findings, current, current_score, accepted, scales)) is not None:
            finding, current, current_score, accepted, reason = pruned
            findings.remove(finding)
            dropped.append({"effect": finding.effect, "reason": reason})
            _progress(f"dropped {finding.effect}: {reason}", progress)
    timings["selection_s"] = time.perf_counter() - t

    # 5. the final model: the confident findings alone, saved and read back as an analysis of the saved rig begins
    t = time.perf_counter()
    refused = [c for c in rounds[-1] if not c.passes] if rounds else []
    final = final_model(first, read, findings, current, refused)
    _progress(f"final model (the saved rig): held-out effort RMSE {final.stage.score.rmse['effort']:.4g} "
              f"{channel_unit('effort', rig.joint)}", progress)
    structure = final.structure
    timings["final_model_s"] = time.perf_counter() - t
    replay_result: dict[str, Any] = {}
    if replay:
        full_rate = data if first.factor == 1 else prepare(first.joined, rig, config,
                                                           segments=_segments(first.sources, config))
        replay_result = _replay(first.joined, rig, final.read_as_hold_end(data.hold_s), full_rate, config, progress,
                                timings)
    timings["total_s"] = time.perf_counter() - t0
    if final.findings:
        verdict = "found, and an unexplained remainder" if structure.unexplained else "found"
    elif final.convention and not structure.unexplained:
        verdict = "time convention"
    else:
        verdict = "unexplained" if structure.unexplained else "no significant discrepancy"
    units = {c: channel_unit(c, rig.joint) for c in model.channels}
    baseline = {
        "rig": rig.to_dict(),
        "time_convention": first.conventions,
        "time_convention_mismatch": final.convention,
        "split": _split(data, first.sources, first.segments, config),
        "decimation": ({"factor": first.factor, "rate_hz": 1.0 / data.dt,
                        "why": f"the log is longer than {MAX_ANALYSIS_SAMPLES} samples: analysed at the lower rate, "
                               f"every column low-passed below its Nyquist frequency first"}
                       if first.factor > 1 else None),
        "free_parameters": _free_parameters(first, rig),
        "rmse_heldout": before.rmse,
        "record_offsets": _record_offsets(first, theta),
        "autocorrelation": {c: autocorrelation(r[data.held], data.dt * data.grid_step)
                            for c, r in residuals_baseline.items()},
        "signatures": signatures,
        "not_identifiable": not_identifiable,
        "model_log": "; ".join(notes) or "the same fit on the current model's own log",
        "dropped": dropped,
        "candidates": [[s.to_dict() for s in scores] for scores in rounds],
        "significance_rule": {"min_ic_drop": config.min_ic_drop, "min_relative_gain": config.min_relative_gain,
                              "min_effort_change": config.min_effort_change,
                              "min_event_z": config.min_event_z, "block_s": config.block_s,
                              "min_parameter_change": config.min_parameter_change,
                              "max_stability_z": config.max_stability_z,
                              "stability_tolerance": config.stability_tolerance,
                              "max_remainder": config.max_remainder},
        "config": config.to_dict(),
        "timings_s": timings,
    }
    final_entry = {"rig": final.rig.to_dict(), "rmse_heldout": final.stage.score.rmse,
                   "free_parameters": _free_parameters(final.stage, final.rig),
                   "record_offsets": _record_offsets(final.stage, final.stage.theta)}
    return DiscrepancyResult(
        baseline=baseline, findings=final.findings, tentative=final.tentative, verdict=verdict, structure=structure,
        rejected=[_rejected(c, rig.joint) for c in refused if c.gain >= LISTED_REJECTED_GAIN],
        logs=_log_errors(first, final, current), signal={c: CHANNEL_MEANING[c] for c in model.channels}, units=units,
        extended_rig=final.rig, final=final_entry, theta_baseline=theta, theta_final=final.stage.theta,
        residuals_baseline=residuals_baseline, residuals_final=_on_grid(final.stage, data),
        time=data.t, held=data.held, fit=data.fit, replay=replay_result)


# ------------------------------------------------------------------------------------------- the final model


@dataclass(frozen=True)
class FinalModel:
    """What the analysis saves and every final figure it reports.

    Attributes
    ----------
    rig : Rig
        The saved rig (``--save-rig``), as read back from its TOML text.
    stage : Stage
        The saved rig on the logs, read as an analysis of the saved rig begins: every final figure is its.
    findings : list of Finding
        The confident findings, saved, with their saved values and the held-out RMSE each brings, in order from the
        baseline to the final model.
    tentative : list of Finding
        Effects the search accepted that are not saved (partial stand-ins beside an unexplained remainder, or
        driven to a bound without them), with their values in the search's model and why.
    convention : str or None
        Why the saved rig states the 'command' time convention the logs do not state (None: it does not).
    structure : Structure
        What the final model's residual still holds.
    """

    rig: Rig
    stage: Stage
    findings: list[Finding]
    tentative: list[Finding]
    convention: str | None
    structure: Structure

    def read_as_hold_end(self, hold_s: float) -> Rig:
        """The saved rig for logs read in the hold-end convention: stating the 'command' convention, it acts one
        sample (``hold_s`` [s]) later on them (the same physics)."""
        if self.rig.time_convention != COMMAND:
            return self.rig
        delay = self.stage.model.theta0["delay"] + hold_s
        return replace(self.rig.with_effects((), {"delay": delay}), time_convention=None)


def final_model(first: Stage, read: Callable[[Rig], Stage], findings: list[Finding], current: dict[str, float],
                refused: list[Candidate]) -> FinalModel:
    """The saved rig and its figures (:class:`FinalModel`).

    1. With an unexplained remainder, effects on the effort that explain little are tentative
       (:func:`_confident`).
    2. Logs whose time convention nobody states, with a dead time found beyond the rig's within CONVENTION_RANGE
       samples, are read in the 'command' convention: one sample of the dead time is the convention (the saved
       rig states it), and what remains beyond it is a dead time only if it passes the significance rules by
       itself. Either reading saves the same total dead time above one sample.
    3. The confident findings are re-fitted without the others; one that then ends at a bound of its range is
       tentative too, and the rest re-fitted again.
    4. The rig with them is written as TOML, read back, and read on the logs as an analysis of it begins: every
       final figure comes from there.
    """
    model, theta0 = first.model, first.model.theta0
    current_score = held_out_score(model, current)
    structure = residual_structure(model, current, current_score, refused)
    confident, tentative = _confident(findings, structure)
    notes = {f.effect: (f"explains {100 * f.gain:.0f} % of the error it was found on; beside the unexplained "
                        f"remainder a partial stand-in, not a confident name") for f in tentative}
    stage, theta, convention = first, dict(current), None
    delay = next((f for f in confident if f.effect == "transport_delay"), None)
    extra = current["delay"] - theta0["delay"]
    hold = first.data.hold_s
    unstated = all(c["from"] == ASSUMED_CONVENTION for c in first.conventions)
    low, high = CONVENTION_RANGE
    if delay is not None and unstated and low * hold <= extra <= high * hold:
        stage = read(replace(first.rig, time_convention=COMMAND))
        theta = {**stage.theta, **{k: v for k, v in current.items() if k not in stage.keys}}
        confident = [f for f in confident if f is not delay]
        convention = (f"the logs act {1e3 * extra:.3g} ms late ({extra / hold:.2f} samples of {1e3 * hold:.3g} ms) "
                      f"and no rig or log states how their rows are stamped: they are read in the 'command' time "
                      f"convention (each row's state measured when its command was computed; the saved rig states "
                      f"time_convention = 'command'), which accounts for one sample. If the rows are stamped at the "
                      f"end of each hold, state time_convention = 'hold_end': the whole dead time is then a finding")
    removed = [f for f in findings if f not in confident]
    keys = tuple(dict.fromkeys(k for f in confident for k in EFFECTS[f.effect].keys)) + stage.keys
    while removed:
        start = {**theta, **{k: stage.model.theta0[k] for f in removed for k in EFFECTS[f.effect].keys
                             if k not in keys}}
        refit = fit_keys(stage.model, start, keys, stage.scales)
        theta = refit.theta
        at_bound = [f for f in confident if any(k in refit.at_bound for k in EFFECTS[f.effect].keys)]
        if not at_bound:
            break
        for f in at_bound:
            sides = ", ".join(f"{k} ({refit.at_bound[k]})" for k in EFFECTS[f.effect].keys if k in refit.at_bound)
            notes[f.effect] = f"ends at a bound of its range without the effects set aside: {sides}"
        confident = [f for f in confident if f not in at_bound]
        removed = [f for f in findings if f not in confident]
        keys = tuple(dict.fromkeys(k for f in confident for k in EFFECTS[f.effect].keys)) + stage.keys
    if convention is not None and delay is not None:
        judged = fit_candidate(stage.model, "transport_delay", theta, keys, stage.scales,
                               held_out_score(stage.model, theta))
        if judged.rejected_by == "stationary" and _stationary_total(judged, hold, stage.model.config):
            judged = replace(judged, rejected_by=None)
        if judged.passes:
            confident.append(delay)
            theta = judged.fit.theta
            convention += "; the dead time beyond that sample is a finding"
        elif extra > hold:
            convention += (f"; the {1e3 * (extra - hold):.3g} ms beyond that sample are no finding (refused by rule "
                           f"'{judged.rejected_by}')")
        else:
            convention += f" (the dead time falls {1e3 * (hold - extra):.3g} ms short of it, within the rule's margin)"
    extended = _extended_rig(stage.rig, theta0, theta, confident, stage.model)
    saved = rig_from_dict(tomllib.loads(rig_to_toml(extended)), source=first.rig.source)
    final = read(saved)
    tentative_findings = [replace(f, parameters=_parameters(f.effect, theta0, current, model,
                                                            tuple(source.name for source in first.sources)),
                                  evidence={**f.evidence, "why_not_saved": notes.get(f.effect, "")})
                          for f in findings if f not in confident and (f is not delay or convention is None)]
    return FinalModel(saved, final, _chain(first, final, confident), tentative_findings, convention,
                      _final_structure(final, refused, tentative_findings))


def _stationary_total(judged: Candidate, hold: float, config: AnalysisConfig) -> bool:
    """Rule 'stationary' for the dead time beyond the time convention's sample, judged on the whole dead time it
    belongs to (that sample and the rest): a drift of a small remainder is no drift of the dead time."""
    fitted, held_out = judged.fit.theta["delay"], (judged.held_out_parameters or {}).get("delay")
    return held_out is not None and abs(held_out - fitted) <= config.stability_tolerance * (fitted + hold)


def _chain(first: Stage, final: Stage, confident: list[Finding]) -> list[Finding]:
    """The confident findings with their saved values (the saved rig's; a free one is re-fitted again by every
    analysis of it) and, in the order accepted, the held-out RMSE of the final
    model with the findings up to each: from the rig's (the findings' parameters at the rig's values, the free ones
    as the baseline re-fitted them) to the saved rig's, the last finding's figure."""
    theta, rig_values = dict(final.theta), first.model.theta0
    theta.update({k: first.theta[k] for k in first.keys})  # the free parameters as the baseline re-fitted them
    for f in confident:
        theta.update({k: rig_values[k] for k in EFFECTS[f.effect].keys})
    previous = held_out_score(final.model, theta)
    out = []
    for i, f in enumerate(confident):
        theta.update({k: final.theta[k] for k in EFFECTS[f.effect].keys})
        if i == len(confident) - 1:
            theta.update({k: final.theta[k] for k in final.keys})
        score = held_out_score(final.model, theta)
        channel = f.evidence["channel"] if f.evidence["channel"] in score.rmse else "effort"
        before, after = previous.rmse[channel], score.rmse[channel]
        parameters = _parameters(f.effect, rig_values, final.model.theta0, final.model,
                                 tuple(source.name for source in final.sources))
        windows = (f.evidence.get(LOW_SPEED) or {}).get("fit") or {}
        if windows and not windows["resolved"]:  # the log bounds it from one side only: stated
            parameters["stribeck_velocity"].update(resolved=False, bound=windows["bound"])
        out.append(replace(f, parameters=parameters, rmse_heldout_before=before, rmse_heldout_after=after,
                           gain=1.0 - after / before if before > 0 else 0.0))
        previous = score
    return out


def _final_structure(final: Stage, refused: list[Candidate], tentative: list[Finding]) -> Structure:
    """What the final model's residual holds, with the effects set aside named."""
    structure = residual_structure(final.model, final.theta, final.score, refused)
    if not tentative:
        return structure
    return replace(structure, description=structure.description + [
        f"{f.effect} is not saved: {f.evidence['why_not_saved']} (listed under 'tentative')" for f in tentative])


def _announce(model: Surrogate, progress: bool) -> None:
    """Progress: the expected time when it is long (a 1e6-row log)."""
    testbed = TESTBED_COST if model.testbed else 1.0
    expected = SECONDS_PER_GRID_SAMPLE * testbed * len(model.data.t) * len(model.effects) / model.config.workers
    samples = len(model.data.t_full)
    message = f"{samples} samples ({samples * model.data.dt:.4g} s), analysis grid of {len(model.data.t)} points"
    if expected > ANNOUNCE_ABOVE_S:
        message += f"; expect roughly {expected:.0f} s"
    _progress(message, progress)


def _replay(joined: RunLog, rig: Rig, extended: Rig, data: Prepared, config: AnalysisConfig, progress: bool,
            timings: dict[str, float]) -> dict[str, Any]:
    """The windowed MuJoCo replay of the held-out part, or a note of why it could not run."""
    from sim.discrepancy.replay import replay_held_out
    from sim.plant import SimulationDiverged

    t = time.perf_counter()
    _progress("replaying the held-out part through MuJoCo (baseline and extended rig)", progress)
    try:
        result = replay_held_out(joined, rig, extended, data, config)
    except (SimulationDiverged, ValueError) as exc:
        result = {"skipped": f"the replay could not run: {exc}"}
    timings["replay_s"] = time.perf_counter() - t
    return result


def _unit(key: str, joint: str) -> str:
    from sim.discrepancy.effects import effect_of_key

    return "rad" if key == "kin_offset" else effect_of_key(key).param(key).unit(joint)


def _kind(effect: str, theta0: dict[str, float]) -> str:
    return "re-fit" if EFFECTS[effect].present(theta0) else "effect"


def _parameters(effect: str, theta0: dict[str, float], theta: dict[str, float], model: Surrogate,
                names: tuple[str, ...] = ()) -> dict[str, dict]:
    """Each parameter's value (of ``theta``), unit, fit range there and (for a re-fit) the rig's value (of
    ``theta0``). The records' own zeros (``record_offsets``) are given per record (``names``), without a range:
    they are profiled, not fitted within one."""
    spec = EFFECTS[effect]
    joint = model.rig.joint
    if effect == "record_offsets":
        zeros = model.record_offsets({**theta, "record_offsets": 1.0}).get("effort", [])
        return {name: {"value": zero, "unit": channel_unit("effort", joint)}
                for name, zero in zip(names, zeros, strict=False)}
    out = {}
    for p in spec.params:
        low, high = spec.bounds(p.key, model.scale, theta)
        entry: dict[str, Any] = {"value": theta[p.key], "unit": p.unit(joint), "bounds": [low, high]}
        if spec.present(theta0):
            entry["baseline"] = theta0[p.key]
        out[p.key] = entry
    return out


def _signatures(model: Surrogate, theta: dict[str, float], residuals: dict[str, np.ndarray]) -> list[dict]:
    """Correlation of each effect's signature with its channel's held-out residual, strongest first."""
    out = []
    for effect in model.effects:
        if effect.channel not in residuals:
            continue
        value = effect.evidence(model, theta, residuals[effect.channel], model.data.held)
        if value is not None:
            out.append({"signature": effect.signature, "effect": effect.name, "channel": effect.channel,
                        "correlation": value})
    return sorted(out, key=lambda s: -abs(s["correlation"]))


def _evidence(best: Candidate, model: Surrogate, theta: dict[str, float], channel: str) -> dict[str, Any]:
    """The signature that points at the effect, its correlation with the residual before, ΔBIC, gains, tests."""
    effect = EFFECTS[best.effect]
    residual = model.residuals(theta).get(effect.channel)
    correlation = None if residual is None else effect.evidence(model, theta, residual, model.data.held)
    out = {"signature": effect.signature, "channel": effect.channel, "correlation_before": correlation,
           "delta_bic": best.delta_bic, "event_z": best.event_z, "improved_block_share": best.improved_block_share,
           "gains_by_channel": best.gains, "held_out_parameters": best.held_out_parameters,
           "model_log_parameters": best.model_log_parameters, "signature_share": best.signature_share}
    if LOW_SPEED in best.score.rmse:  # the held-out low-speed windows' position error, and the windows' own fit
        out[LOW_SPEED] = {"rmse_before": best.before_rmse[LOW_SPEED], "rmse_after": best.score.rmse[LOW_SPEED],
                          "unit": "m" if model.rig.joint == "slide" else "rad", "fit": best.details}
    return out


def _alternatives(best: Candidate, scores: list[Candidate], channel: str) -> list[dict]:
    """Other candidates of the round that pass every rule checked in the round and come within ALTERNATIVE_SHARE of
    the error ``best`` explains (its held-out RMSE drop in ``channel``): laws the log tells from it only weakly."""
    drop = best.before_rmse[channel] - best.score.rmse[channel]
    out = []
    for c in scores:
        if c is best or c.effect == best.effect or c.rejected_by not in (None, "moved", "stationary"):
            continue
        shortfall = c.score.rmse.get(channel, math.inf) - best.score.rmse[channel]
        if drop > 0 and shortfall <= ALTERNATIVE_SHARE * drop:
            out.append({"effect": c.effect, "rmse_heldout_after": c.score.rmse[channel],
                        "parameters": c.parameters})
    return out


def _rejected(c: Candidate, joint: str) -> dict[str, Any]:
    effect = EFFECTS[c.effect]
    return {"effect": c.effect, "gain": c.gain, "rejected_by": c.rejected_by, "note": c.note,
            "at_bound": c.at_bound, "parameters": {k: {"value": v, "unit": effect.param(k).unit(joint)}
                                                   for k, v in c.parameters.items()}}


def _split(data: Prepared, sources: list[Source], segments: list[Segment], config: AnalysisConfig) -> dict[str, Any]:
    out: dict[str, Any] = {"guard_s": config.guard_s, "fit_samples": int(data.fit.sum()),
                           "held_out_samples": int(data.held.sum()), "grid_step": data.grid_step}
    if not segments:
        out.update(fit=f"t < {data.split_time:.6g} s (first {100 * config.fit_fraction:g} %)",
                   held_out=f"t >= {data.split_time:.6g} s")
    else:
        out["logs"] = [{"log": s.name, "role": s.role,
                        "fitted": "whole" if f == 1.0 else "none (held out)" if f == 0.0 else f"first {100 * f:g} %"}
                       for s, (_, _, f) in zip(sources, segments, strict=True)]
    return out


def _errors(stage: Stage, theta: dict[str, float]) -> list[float]:
    """Relative effort prediction error ‖F - F̂‖/‖F‖ of ``theta`` on each log's scored part (its held-out part; a
    log fitted whole, or held out whole: the whole log) [1]. F is the logged command in the analysis band, F - F̂ the
    effort residual."""
    d, model = stage.data, stage.model
    command = d.filt(d.u_full)
    residual = model.residuals(theta)["effort"]
    bounds = stage.segments or [(0, len(d.t_full), model.config.fit_fraction)]
    out = []
    for start, stop, fraction in bounds:
        inside = (d.grid >= start) & (d.grid < stop)
        ok = inside & (d.held if fraction < 1.0 else (d.fit | d.held)) & np.isfinite(residual)
        norm = float(np.linalg.norm(command[ok]))
        out.append(float(np.linalg.norm(residual[ok])) / norm if norm > 0 else float("nan"))
    return out


def _log_errors(first: Stage, final: FinalModel, current: dict[str, float]) -> list[dict[str, Any]]:
    """Each log's role and relative effort prediction error (:func:`_errors`) of the rig, of the final model (the
    saved rig, read as an analysis of it begins) and, beside it, of the search's model with the tentative effects."""
    baseline, saved = _errors(first, first.theta), _errors(final.stage, final.stage.theta)
    tentative = _errors(first, current) if final.tentative else None
    own_zero = bool(final.stage.model.record_offsets(final.stage.theta))
    whole = [fraction in (0.0, 1.0) for _, _, fraction in first.segments] or [False]  # one log: split
    out = []
    for i, source in enumerate(first.sources):
        errors = {"baseline": baseline[i], "final": saved[i]}
        if tentative is not None:
            errors["with_tentative"] = tentative[i]
        out.append({"log": source.name, "role": source.role, "scored": "whole" if whole[i] else "held-out part",
                    "own_zero": own_zero, "relative_effort_error": errors})
    return out


def _free_parameters(stage: Stage, rig: Rig) -> dict[str, dict[str, Any]]:
    """The rig's free parameters as re-fitted: value, the rig's, unit, the range used, and its bound if it ends at
    one."""
    out = {}
    for k in rig.free_keys:
        entry: dict[str, Any] = {"value": stage.theta[k], "rig": stage.model.theta0[k], "unit": _unit(k, rig.joint),
                                 "bounds": list(stage.refit.bounds[k])}
        field_value = rig_field(rig, k, stage.theta[k])
        if field_value is not None and field_value[1] != stage.theta[k]:  # another quantity in the rig file
            entry["saved_as"] = {"field": field_value[0], "value": field_value[1]}
        if k in stage.refit.at_bound:
            entry["at_bound"] = stage.refit.at_bound[k]
        out[k] = entry
    return out


def _record_offsets(stage: Stage, theta: dict[str, float]) -> list[dict[str, Any]]:
    """Each log's own zero per channel, with its unit, where ``theta`` carries the effect ``record_offsets``
    (else empty)."""
    zeros = stage.model.record_offsets(theta)
    if not zeros:
        return []
    return [{"log": source.name, **{c: {"value": values[i], "unit": channel_unit(c, stage.rig.joint)}
                                    for c, values in zeros.items()}}
            for i, source in enumerate(stage.sources)]


def _on_grid(stage: Stage, data: Prepared) -> dict[str, np.ndarray]:
    """The residual channels of the stage's final parameters at the grid times of ``data`` (its first grid sample
    at or after each: the saved rig's stage may read the logs one sample apart, in another time convention)."""
    residuals = stage.model.residuals(stage.theta)
    if len(stage.data.t) == len(data.t) and np.array_equal(stage.data.t, data.t):
        return residuals
    index = np.clip(np.searchsorted(stage.data.t, data.t), 0, len(stage.data.t) - 1)
    return {c: r[index] for c, r in residuals.items()}


def autocorrelation(r: np.ndarray, step_s: float,
                    lags_s: tuple[float, ...] = (0.01, 0.02, 0.1, 0.5)) -> dict[str, float]:
    """Normalised autocorrelation of a residual sampled every ``step_s`` at ``lags_s`` [1] (white noise: ~0)."""
    r = r[np.isfinite(r)]
    if len(r) < 2:
        return {f"{lag:g} s": float("nan") for lag in lags_s}
    r = r - r.mean()
    var = float(r @ r)
    out = {}
    for lag_s in lags_s:
        lag = int(round(lag_s / step_s))
        out[f"{lag_s:g} s"] = float(r[:-lag] @ r[lag:]) / var if 0 < lag < len(r) and var > 0 else float("nan")
    return out


def _extended_rig(rig: Rig, theta0: dict[str, float], theta: dict[str, float], findings: list[Finding],
                  model: Surrogate) -> Rig:
    """The rig with its own parameters updated (free ones and findings the rig states natively) and the other
    findings added as effects."""
    kind = rig_kind(rig)
    native: dict[str, float] = {}
    added = []
    for f in findings:
        effect = EFFECTS[f.effect]
        values = {k: theta[k] for k in effect.keys}
        if effect.native(rig):
            native.update({k: v for k, v in values.items() if kind in effect.param(k).fields})
        else:
            added.append(AddedEffect(f.effect, values))
    for key in rig.free_keys:
        native[key] = theta[key]
    if rig.model != "testbed":
        tied = rig.rigid["breakaway"] == rig.rigid["coulomb"] and "breakaway" not in native
        coulomb = native.get("coulomb", rig.rigid["coulomb"])
        if tied or coulomb > native.get("breakaway", rig.rigid["breakaway"]):  # one dry level: static = sliding
            native["breakaway"] = coulomb
    return rig.with_effects(tuple(added), {k: v for k, v in native.items() if v != theta0.get(k)})


def _confident(findings: list[Finding], structure: Structure) -> tuple[list[Finding], list[Finding]]:
    """(confident, tentative) findings. With an unexplained remainder, a finding on the effort is a partial
    stand-in for what the library does not hold, not a confident name, if it brought the held-out error down by
    less than a generic model would bring the remainder down, or explained less than a third of the error it was
    found on."""
    if not structure.unexplained:
        return findings, []
    remainder = structure.rmse.get("effort", 0.0) * max(structure.generic_gain, 0.0)
    confident = [f for f in findings if f.evidence["channel"] != "effort"
                 or (f.rmse_heldout_before - f.rmse_heldout_after >= remainder and f.gain >= STAND_IN_GAIN)]
    return confident, [f for f in findings if f not in confident]


def _prune(model: Surrogate, findings: list[Finding], current: dict[str, float], current_score: ChannelScore,
           accepted: tuple[str, ...], scales: dict[str, float]):
    """An earlier finding that the later ones made redundant, with the model refitted without it: (finding,
    theta, score, accepted keys, reason), or None. A finding is redundant when, with the rig's own value (or
    none) back in its place and the rest refitted, the held-out error grows by less than half of the smallest
    gain the analysis accepts, or the effort prediction changes by less than its smallest reportable change."""
    cfg = model.config
    for finding in findings[:-1]:
        keys = EFFECTS[finding.effect].keys
        rest = tuple(k for k in accepted if k not in keys)
        refit = fit_keys(model, {**current, **{k: model.theta0[k] for k in keys}}, rest, scales)
        score = held_out_score(model, refit.theta)
        channel = EFFECTS[finding.effect].channel
        if channel not in score.rmse or not score.rmse[channel] > 0:
            continue
        kept_gain = 1.0 - current_score.rmse[channel] / score.rmse[channel]
        change = effort_change(score, current_score) if channel == "effort" else math.inf
        if kept_gain < 0.5 * cfg.min_relative_gain or change < cfg.min_effort_change * model.command_rms:
            reason = (f"absorbed by the later findings: without it the held-out {channel} RMSE grows by "
                      f"{100 * kept_gain:.1f} %")
            return finding, refit.theta, score, rest, reason
    return None


def _first_passing(scores: list[Candidate], sources: list[Source], rig: Rig, config: AnalysisConfig,
                   model: Surrogate, current: dict[str, float], findings: list[Finding], accepted: tuple[str, ...],
                   scales: dict[str, float]) -> tuple[Candidate | None, str | None]:
    """The first candidate (best ΔBIC first) that passes every rule, rule 'moved' measured from the current
    model's own log for an effect the model carries; ``scores`` updated in place. Also a note when the model's
    log cannot be made (rule 'moved' then measured from the model's value)."""
    reference: Surrogate | None = None
    note = None
    for i, score in enumerate(scores):
        if not score.passes:
            continue
        if carried_by_model(score.effect, current) and note is None:
            if reference is None:
                try:
                    reference = _model_log_model(sources, rig, config, model, current, findings)
                except ModelLogUnavailable as why:
                    note = f"no model log ({why}): rule 'moved' measured from the model's value"
            if reference is not None:
                score = scores[i] = against_model_log(score, reference, current, accepted, scales)
                if not score.passes:
                    continue
        return score, note
    return None, note


def _model_log_model(sources: list[Source], rig: Rig, config: AnalysisConfig, model: Surrogate,
                     current: dict[str, float], findings: list[Finding]) -> Surrogate:
    """The surrogate on the current model's own logs (one per source log, joined like the sources)."""
    findings = [replace(f, parameters={}) for f in findings]
    current_rig = _extended_rig(rig, model.theta0, current, findings, model)
    replayed = []
    for s in sources:
        own = model.data if len(sources) == 1 and len(model.data.t_full) == len(s.log) else prepare(s.log, rig, config)
        replayed.append(Source(s.name, s.role, model_log(s.log, current_rig, own, config.model_log_seed)))
    return Surrogate(join_and_prepare(replayed, current_rig, config)[3], current_rig, config)
