"""The discrepancy analysis: a measured log + a rig -> findings, held-out gains, the extended rig.

Steps (``analyse``):

1. prepare the log (filter, differentiate, choose the load source) and split it into a leading fit part
   (``config.fit_fraction``) and a trailing held-out part, contiguous, with filter guards;
2. re-fit the rig's free baseline parameters (and nuisances: the encoder offset of the kinematic channel) on
   the fit part;
3. residuals and diagnostics of the baseline on the held-out part; which effects the log cannot reveal;
4. forward selection (:mod:`sim.discrepancy.selection`) over the identifiable effects;
5. the extended rig (baseline values replaced where a baseline effect was found with another value, the other
   effects added), and optionally a windowed MuJoCo replay of the held-out part before and after.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sim.discrepancy.diagnostics import EVIDENCE, Signature, autocorrelation, identifiability, score_signatures
from sim.discrepancy.effects import EFFECTS, NATIVE_KEYS, NEUTRAL
from sim.discrepancy.fit import fit_keys
from sim.discrepancy.model import Surrogate, baseline_theta, channel_unit
from sim.discrepancy.null import ModelLogUnavailable, model_log
from sim.discrepancy.rig import AddedEffect, Rig, check_rig_matches_log
from sim.discrepancy.selection import (
    MAX_ROUNDS,
    CandidateScore,
    against_model_log,
    carried_by_model,
    held_out_score,
    make_pool,
    run_round,
)
from sim.discrepancy.signals import AnalysisConfig, Prepared, prepare
from sim.runlog import RunLog

CHANNEL_MEANING = {
    "effort": "effort-prediction residual: commanded effort minus the effort the model needs for the measured "
              "motion and load",
    "sensor": "torque sensor minus the transmitted torque the model predicts it reads",
    "kinematic": "motor angle minus lever angle minus flexure twist, against the backlash model",
}


@dataclass(frozen=True)
class Finding:
    """An accepted effect: fitted parameters (with units and the baseline's value), held-out RMSE, evidence."""

    effect: str
    parameters: dict[str, dict[str, Any]]
    rmse_heldout_before: float
    rmse_heldout_after: float
    gain: float
    evidence: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "parameters": self.parameters,
                "rmse_heldout_before": self.rmse_heldout_before, "rmse_heldout_after": self.rmse_heldout_after,
                "gain": self.gain, "evidence": self.evidence}


@dataclass(frozen=True)
class DiscrepancyResult:
    """Everything the analysis found.

    Attributes
    ----------
    baseline : dict
        The baseline model: rig, split, re-fitted free parameters, held-out RMSE per channel, autocorrelation,
        signatures, effects the log cannot reveal and why, the first round's candidate table, timings.
    findings : list of Finding
        Accepted effects in the order found.
    verdict : {'found', 'no significant discrepancy'}
    signal : dict
        Residual channels used, with their meaning.
    units : dict
        Unit of each channel.
    extended_rig : Rig
        The rig with the findings, for ``--save-rig``.
    theta_baseline, theta_final : dict
        Surrogate parameters before and after.
    residuals_baseline, residuals_final : dict of ndarray
        Residual channels over the whole log (NaN where a sample does not count).
    replay : dict
        Windowed MuJoCo replay of the held-out part (empty if not run).
    """

    baseline: dict[str, Any]
    findings: list[Finding]
    verdict: str
    signal: dict[str, str]
    units: dict[str, str]
    extended_rig: Rig = field(repr=False)
    theta_baseline: dict[str, float] = field(repr=False, default_factory=dict)
    theta_final: dict[str, float] = field(repr=False, default_factory=dict)
    residuals_baseline: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    residuals_final: dict[str, np.ndarray] = field(repr=False, default_factory=dict)
    time: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    held: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, bool))
    replay: dict[str, Any] = field(default_factory=dict)

    @property
    def found(self) -> list[str]:
        return [f.effect for f in self.findings]

    def to_dict(self) -> dict[str, Any]:
        baseline = dict(self.baseline)
        if self.replay:
            baseline["replay"] = {k: v for k, v in self.replay.items() if not isinstance(v, np.ndarray)}
        return {"baseline": baseline, "findings": [f.to_dict() for f in self.findings], "verdict": self.verdict,
                "signal": self.signal, "units": self.units}


def _progress(message: str, enabled: bool) -> None:
    if enabled:
        print(f"discrepancy: {message}", file=sys.stderr, flush=True)


def _parameters(effect: str, before: dict[str, float], after: dict[str, float], joint: str) -> dict[str, dict]:
    out = {}
    for p in EFFECTS[effect].params:
        in_baseline = p.key in NATIVE_KEYS or before.get(p.key, NEUTRAL.get(p.key)) != NEUTRAL.get(p.key)
        entry = {"value": after[p.key], "unit": p.unit(joint)}
        if in_baseline and p.key in before:
            entry["baseline"] = before[p.key]
        out[p.key] = entry
    return out


def analyse(log: RunLog, rig: Rig, config: AnalysisConfig | None = None, *, progress: bool = False,
            replay: bool = False) -> DiscrepancyResult:
    """Run the discrepancy analysis of ``log`` against ``rig`` (see the module docstring)."""
    config = config or AnalysisConfig()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    check_rig_matches_log(rig, log)
    data = prepare(log, rig, config)
    surrogate = Surrogate(data, rig, config)
    theta0 = baseline_theta(rig)
    timings["prepare_s"] = time.perf_counter() - t0

    # 2. baseline re-fit of the free parameters (+ nuisance), scaled by the untouched baseline's RMS
    t = time.perf_counter()
    raw = surrogate.residuals(theta0)
    scales = {c: _rms(r[data.fit]) or 1.0 for c, r in raw.items()}
    nuisance = ("kin_offset",) if "kinematic" in surrogate.channels else ()
    free = rig.free_keys
    base_fit = fit_keys(surrogate, theta0, free + nuisance, scales)
    theta = base_fit.theta
    residuals_baseline = surrogate.residuals(theta)
    scales = {c: _rms(r[data.fit]) or 1.0 for c, r in residuals_baseline.items()}
    before = held_out_score(surrogate, theta)
    timings["baseline_fit_s"] = time.perf_counter() - t
    rmse = ", ".join(f"{c} {value:.4g} {channel_unit(c, rig.joint)}" for c, value in before.rmse.items())
    _progress(f"baseline held-out RMSE: {rmse} ({len(log)} samples, split at {data.split_time:.3f} s)",
              progress)

    # 3. diagnostics and identifiability
    t = time.perf_counter()
    sigs = score_signatures(surrogate, theta, residuals_baseline, data.held)
    not_identifiable = {name: why for name in EFFECTS if (why := identifiability(name, surrogate, theta))}
    candidates = [name for name in EFFECTS if name not in not_identifiable]
    timings["diagnostics_s"] = time.perf_counter() - t

    # 4. forward selection
    t = time.perf_counter()
    findings: list[Finding] = []
    rounds: list[list[CandidateScore]] = []
    model_log_notes: list[str] = []
    pool = make_pool(surrogate)
    try:
        current, current_score = theta, before
        for round_index in range(MAX_ROUNDS):
            if not candidates:
                break
            _progress(f"round {round_index + 1}: fitting {len(candidates)} candidate effects", progress)
            scores = run_round(surrogate, candidates, current, free + nuisance, scales, current_score, before,
                               pool)
            t_model_log = time.perf_counter()
            best, model_log_note = _first_passing(scores, log, rig, data, config, theta0, current, findings,
                                                  free + nuisance, scales)
            timings["model_log_s"] = timings.get("model_log_s", 0.0) + time.perf_counter() - t_model_log
            rounds.append(scores)
            if model_log_note:
                model_log_notes.append(model_log_note)
            if best is None:
                break
            channel = best.best_channel
            findings.append(Finding(
                effect=best.effect, parameters=_parameters(best.effect, theta0, best.fit.theta, rig.joint),
                rmse_heldout_before=current_score.rmse[channel], rmse_heldout_after=best.score.rmse[channel],
                gain=best.gains[channel],
                evidence=_evidence(best, surrogate, current, channel)))
            _progress(f"found {best.effect} (held-out {channel} RMSE -{100 * best.gains[channel]:.1f} %, "
                      f"ΔBIC {best.delta_bic:.1f}, consistency t {best.consistency_t:.2f})", progress)
            current, current_score = best.fit.theta, best.score
            candidates = [c for c in candidates if c != best.effect]
    finally:
        if pool is not None:
            pool.shutdown()
    timings["selection_s"] = time.perf_counter() - t

    extended = _extended_rig(rig, theta0, current, findings)
    residuals_final = surrogate.residuals(current)
    replay_result: dict[str, Any] = {}
    if replay:
        from sim.discrepancy.replay import replay_held_out

        t = time.perf_counter()
        _progress("replaying the held-out part through MuJoCo (baseline and extended rig)", progress)
        replay_result = replay_held_out(log, rig, extended, data, config)
        timings["replay_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t0

    units = {c: channel_unit(c, rig.joint) for c in surrogate.channels}
    baseline = {
        "rig": rig.to_dict(),
        "split": {"fit": f"t < {data.split_time:.6g} s (first {100 * config.fit_fraction:g} %)",
                  "held_out": f"t >= {data.split_time:.6g} s", "guard_s": config.guard_s,
                  "fit_samples": int(data.fit.sum()), "held_out_samples": int(data.held.sum())},
        "free_parameters": {k: {"value": theta[k], "rig": theta0[k]} for k in free},
        "rmse_heldout": before.rmse,
        "autocorrelation": {c: autocorrelation(r[data.held], data.dt) for c, r in residuals_baseline.items()},
        "signatures": [s.to_dict() for s in sigs],
        "not_identifiable": not_identifiable,
        "rule_3_reference": "; ".join(model_log_notes) or "the same fit on the current model's own log",
        "candidates": [[s.to_dict() for s in scores] for scores in rounds],
        "significance_rule": {"min_ic_drop": config.min_ic_drop, "min_relative_gain": config.min_relative_gain,
                              "min_parameter_change": config.min_parameter_change,
                              "min_consistency_t": config.min_consistency_t,
                              "criterion": "held-out BIC over independent samples (x 2 f_c / f_s) and a "
                                           "Diebold-Mariano test of the held-out improvement"},
        "config": config.to_dict(),
        "timings_s": timings,
    }
    return DiscrepancyResult(
        baseline=baseline, findings=findings, verdict="found" if findings else "no significant discrepancy",
        signal={c: CHANNEL_MEANING[c] for c in surrogate.channels}, units=units, extended_rig=extended,
        theta_baseline=theta, theta_final=current, residuals_baseline=residuals_baseline,
        residuals_final=residuals_final, time=data.t, held=data.held, replay=replay_result)


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if len(x) else 0.0


def _evidence(best: CandidateScore, surrogate: Surrogate, theta: dict[str, float], channel: str) -> dict[str, Any]:
    """The signature that points at the effect, its correlation with the residual before, ΔBIC, gains."""
    residuals = surrogate.residuals(theta)
    wanted = EVIDENCE[best.effect]
    sig: Signature | None = next((s for s in score_signatures(surrogate, theta, residuals, surrogate.data.held)
                                  if s.name == wanted), None)
    return {"signature": wanted, "channel": sig.channel if sig else channel,
            "correlation_before": sig.correlation if sig else None, "delta_bic": best.delta_bic,
            "consistency_t": best.consistency_t,
            "gains_by_channel": best.gains, "model_log_parameters": best.model_log_parameters}


def _extended_rig(rig: Rig, theta0: dict[str, float], theta: dict[str, float], findings: list[Finding]) -> Rig:
    """The rig with native parameters updated and non-native effects added."""
    native = {k: theta[k] for k in NATIVE_KEYS | set(rig.free_keys) if k in theta and theta[k] != theta0.get(k)}
    if rig.model != "testbed":
        native = {k: v for k, v in native.items() if k not in ("load_coefficient", "presliding_stiffness",
                                                                "backlash_width")}
        coulomb = native.get("coulomb", rig.rigid["coulomb"])
        tied = rig.rigid["breakaway"] == rig.rigid["coulomb"] and "breakaway" not in native
        if tied or coulomb > native.get("breakaway", rig.rigid["breakaway"]):  # one level: static = sliding
            native["breakaway"] = coulomb
    added = []
    for f in findings:
        keys = EFFECTS[f.effect].keys
        if all(k in NATIVE_KEYS for k in keys):
            continue
        added.append(AddedEffect(f.effect, {k: theta[k] for k in keys}))
    return rig.with_effects(tuple(added), native)


def _first_passing(scores: list[CandidateScore], log: RunLog, rig: Rig, data: Prepared, config: AnalysisConfig,
                   theta0: dict[str, float], current: dict[str, float], findings: list[Finding],
                   free: tuple[str, ...], scales: dict[str, float]) -> tuple[CandidateScore | None, str | None]:
    """The first candidate (best ΔBIC first) that passes the significance rule, rule 3 measured from the
    current model's own log for an effect the model carries; ``scores`` updated in place. Also a note when the
    model's log cannot be made (rule 3 then measured from the model's value)."""
    model_surrogate: Surrogate | None = None
    note = None
    for i, score in enumerate(scores):
        if not score.passes:
            continue
        if carried_by_model(score.effect, current) and note is None:
            if model_surrogate is None:
                try:
                    model_rig = _extended_rig(rig, theta0, current, findings)
                    model_data = prepare(model_log(log, model_rig, data, config.model_log_seed), model_rig, config)
                    model_surrogate = Surrogate(model_data, model_rig, config)
                except ModelLogUnavailable as why:
                    note = f"no model log ({why}): rule 3 measured from the model's value"
            if model_surrogate is not None:
                score = scores[i] = against_model_log(score, model_surrogate, current, free, scales)
                if not score.passes:
                    continue
        return score, note
    return None, note
