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
5. what the final residual still holds (:mod:`sim.discrepancy.structure`), the relative effort prediction
   error of the baseline and the final model on every log, the extended rig, and optionally a windowed MuJoCo
   replay of the held-out part before and after.
"""

from __future__ import annotations

import math
import sys
import time
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
from sim.discrepancy.fit import fit_keys
from sim.discrepancy.model import NUISANCE_KEYS, Surrogate, channel_unit
from sim.discrepancy.null import ModelLogUnavailable, model_log
from sim.discrepancy.rig import AddedEffect, Rig, check_rig_matches_log
from sim.discrepancy.selection import (
    Candidate,
    ChannelScore,
    against_model_log,
    carried_by_model,
    effort_change,
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
from sim.runlog import HOLD_END, RunLog

CHANNEL_MEANING = {
    "effort": "effort-prediction residual: commanded effort minus the effort the model needs for the measured "
              "motion and load",
    "sensor": "torque sensor minus the transmitted torque the model predicts it reads",
    "kinematic": "motor angle minus lever angle minus flexure twist, against the backlash model",
}
CONVENTION_TOLERANCE = 0.25  # a dead time within a quarter hold of one hold beyond the rig's: a time convention
STAND_IN_GAIN = 1.0 / 3.0  # beside an unexplained remainder, a finding explaining less is a stand-in
LISTED_REJECTED_GAIN = 0.10  # refused candidates with at least this held-out gain are listed with their rule
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
        Accepted effects that explain less than the unexplained remainder would: partial stand-ins.
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
        baseline and the final model on its scored part.
    signal, units : dict
        Residual channels used, with their meaning and unit.
    extended_rig : Rig
        The rig with the findings, for ``--save-rig``.
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
                "signal": self.signal, "units": self.units}


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
    theta0 = model.theta0
    _announce(model, progress)
    timings["prepare_s"] = time.perf_counter() - t0

    # 2. baseline re-fit of the free parameters (+ nuisance), scaled by the untouched baseline's RMS
    t = time.perf_counter()
    raw = model.residuals(theta0)
    scales = {c: rms(r[data.fit]) or 1.0 for c, r in raw.items()}
    nuisance = NUISANCE_KEYS if "kinematic" in model.channels else ()
    free = rig.free_keys
    base_fit = fit_keys(model, theta0, free + nuisance, scales)
    if base_fit.at_bound:
        base_fit = fit_keys(model, theta0, free + nuisance, scales, widen=WIDEN)
    theta = base_fit.theta
    residuals_baseline = model.residuals(theta)
    before = held_out_score(model, theta)
    command_rms = rms(data.filt(data.u_full)[data.held])
    check_effort_balance(before.rmse["effort"], command_rms, channel_unit("effort", rig.joint),
                         "m" if rig.joint == "slide" else "rad")
    scales = {c: rms(r[data.fit]) or 1.0 for c, r in residuals_baseline.items()}
    timings["baseline_fit_s"] = time.perf_counter() - t
    rmse = ", ".join(f"{c} {value:.4g} {channel_unit(c, rig.joint)}" for c, value in before.rmse.items())
    _progress(f"baseline held-out RMSE: {rmse} ({len(joined)} samples, {data.fit.sum()} / {data.held.sum()} "
              f"grid samples fit / held out)", progress)

    # 3. diagnostics and identifiability
    t = time.perf_counter()
    signatures = _signatures(model, theta, residuals_baseline)
    not_identifiable = {e.name: why for e in model.effects if (why := e.identifiable(model, theta))}
    candidates = [e.name for e in model.effects if e.name not in not_identifiable]
    timings["diagnostics_s"] = time.perf_counter() - t

    # 4. forward selection, each round judged against the current (jointly fitted) model
    t = time.perf_counter()
    findings: list[Finding] = []
    accepted: tuple[str, ...] = free + nuisance
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
        best, note = _first_passing(scores, sources, rig, config, model, current, findings, accepted, scales)
        timings["model_log_s"] = timings.get("model_log_s", 0.0) + time.perf_counter() - t_null
        rounds.append(scores)
        if note:
            notes.append(note)
        if best is None:
            break
        channel = best.best_channel
        findings.append(Finding(
            effect=best.effect, kind=_kind(best.effect, theta0),
            parameters={}, rmse_heldout_before=current_score.rmse[channel],
            rmse_heldout_after=best.score.rmse[channel], gain=best.gains[channel],
            evidence=_evidence(best, model, current, channel)))
        _progress(f"found {best.effect} (held-out {channel} RMSE -{100 * best.gains[channel]:.1f} %, "
                  f"ΔBIC {best.delta_bic:.1f})", progress)
        accepted = tuple(dict.fromkeys(EFFECTS[best.effect].keys + accepted))
        current, current_score = best.fit.theta, best.score
        candidates = [c for c in candidates if c != best.effect]
        while (pruned := _prune(model, findings, current, current_score, accepted, scales)) is not None:
            finding, current, current_score, accepted, reason = pruned
            findings.remove(finding)
            dropped.append({"effect": finding.effect, "reason": reason})
            _progress(f"dropped {finding.effect}: {reason}", progress)
    timings["selection_s"] = time.perf_counter() - t
    findings = [replace(f, parameters=_parameters(f.effect, theta0, current, model)) for f in findings]
    findings, convention_mismatch = _convention_mismatch(findings, conventions, theta0, current, data.hold_s)

    # 5. the remainder, the logs' errors, the extended rig, the replay
    t = time.perf_counter()
    refused = [c for c in rounds[-1] if not c.passes] if rounds else []
    structure = residual_structure(model, current, current_score, refused)
    findings, tentative = _confident(findings, structure)
    if tentative:
        structure = replace(structure, description=structure.description + [
            f"{f.effect} would explain {100 * f.gain:.0f} % of the error it was found on; beside this remainder that "
            f"makes it a partial stand-in, not a confident name (listed under 'tentative')" for f in tentative])
    timings["structure_s"] = time.perf_counter() - t
    extended = _extended_rig(rig, theta0, current, findings, model)
    residuals_final = model.residuals(current)
    replay_result: dict[str, Any] = {}
    if replay:
        full_rate = data if factor == 1 else prepare(joined, rig, config, segments=_segments(sources, config))
        replay_result = _replay(joined, rig, extended, full_rate, config, progress, timings)
    timings["total_s"] = time.perf_counter() - t0
    if findings:
        verdict = "found, and an unexplained remainder" if structure.unexplained else "found"
    elif convention_mismatch and not structure.unexplained:
        verdict = "time convention"
    else:
        verdict = "unexplained" if structure.unexplained else "no significant discrepancy"
    units = {c: channel_unit(c, rig.joint) for c in model.channels}
    baseline = {
        "rig": rig.to_dict(),
        "time_convention": conventions,
        "time_convention_mismatch": convention_mismatch,
        "split": _split(data, sources, segments, config),
        "decimation": ({"factor": factor, "rate_hz": 1.0 / data.dt,
                        "why": f"the log is longer than {MAX_ANALYSIS_SAMPLES} samples: analysed at the lower rate, "
                               f"every column low-passed below its Nyquist frequency first"} if factor > 1 else None),
        "free_parameters": {k: {"value": theta[k], "rig": theta0[k], "unit": _unit(k, rig.joint),
                                **({"at_bound": base_fit.at_bound[k], "bounds": base_fit.bounds[k]}
                                   if k in base_fit.at_bound else {})} for k in free},
        "rmse_heldout": before.rmse,
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
    return DiscrepancyResult(
        baseline=baseline, findings=findings, tentative=tentative, verdict=verdict, structure=structure,
        rejected=[_rejected(c, rig.joint) for c in refused if c.gain >= LISTED_REJECTED_GAIN],
        logs=_log_errors(model, sources, segments, theta, current),
        signal={c: CHANNEL_MEANING[c] for c in model.channels}, units=units, extended_rig=extended,
        theta_baseline=theta, theta_final=current, residuals_baseline=residuals_baseline,
        residuals_final=residuals_final, time=data.t, held=data.held, fit=data.fit, replay=replay_result)


def _convention_mismatch(findings: list[Finding], conventions: list[dict[str, str]], theta0: dict[str, float],
                         theta: dict[str, float], hold_s: float) -> tuple[list[Finding], str | None]:
    """(the findings, None), or, if the logs' time convention is stated nowhere and the dead time found exceeds
    the rig's by one command hold (within CONVENTION_TOLERANCE of it), (the findings without it, what it is):
    logs stamped in the 'command' convention read as 'hold_end' act exactly one hold late
    (:func:`sim.discrepancy.checks.to_hold_end`), a wrong convention, not a dead time of the rig."""
    delay = next((f for f in findings if f.effect == "transport_delay"), None)
    if delay is None or not conventions or any(c["from"] != ASSUMED_CONVENTION for c in conventions):
        return findings, None
    extra = theta["delay"] - theta0["delay"]
    if abs(extra - hold_s) > CONVENTION_TOLERANCE * hold_s:
        return findings, None
    return [f for f in findings if f is not delay], (
        f"the logs act one sample ({1e3 * hold_s:.3g} ms) late: a dead time of {1e3 * extra:.3g} ms beyond the rig's "
        f"is what logs stamped in the 'command' time convention (each row's state measured when its command was "
        f"computed) give when read as '{HOLD_END}', and no rig or log states the convention. State "
        f"time_convention = 'command' in the rig; if the rows are stamped at the end of each hold, state "
        f"'{HOLD_END}' and the dead time is reported as a finding")


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


def _parameters(effect: str, theta0: dict[str, float], theta: dict[str, float], model: Surrogate) -> dict[str, dict]:
    """Each parameter's value, unit, fit range and (for a re-fit) the rig's value."""
    out = {}
    spec = EFFECTS[effect]
    for p in spec.params:
        low, high = spec.bounds(p.key, model.scale, theta0)
        entry: dict[str, Any] = {"value": theta[p.key], "unit": p.unit(model.rig.joint), "bounds": [low, high]}
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
    return {"signature": effect.signature, "channel": effect.channel, "correlation_before": correlation,
            "delta_bic": best.delta_bic, "event_z": best.event_z, "improved_block_share": best.improved_block_share,
            "gains_by_channel": best.gains, "held_out_parameters": best.held_out_parameters,
            "model_log_parameters": best.model_log_parameters}


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


def _log_errors(model: Surrogate, sources: list[Source], segments: list[Segment], theta0: dict[str, float],
                theta: dict[str, float]) -> list[dict[str, Any]]:
    """Relative effort prediction error ‖F - F̂‖/‖F‖ of the baseline and the final model on each log's scored
    part (its held-out part; a log fitted whole: the whole log) [1]. F is the logged command in the analysis
    band, F - F̂ the effort residual."""
    d = model.data
    command = d.filt(d.u_full)
    before, after = model.residuals(theta0)["effort"], model.residuals(theta)["effort"]
    bounds = segments or [(0, len(d.t_full), model.config.fit_fraction)]
    out = []
    for source, (start, stop, fraction) in zip(sources, bounds, strict=True):
        inside = (d.grid >= start) & (d.grid < stop)
        part = inside & (d.held if fraction < 1.0 else (d.fit | d.held))
        ok = part & np.isfinite(before) & np.isfinite(after)
        norm = float(np.linalg.norm(command[ok]))
        errors = {name: float(np.linalg.norm(r[ok])) / norm if norm > 0 else float("nan")
                  for name, r in (("baseline", before), ("final", after))}
        scored = "whole" if fraction in (0.0, 1.0) else "held-out part"
        out.append({"log": source.name, "role": source.role, "scored": scored,
                    "relative_effort_error": errors})
    return out


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
