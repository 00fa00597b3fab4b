"""Forward selection of effects, judged against the current model, with a stated significance rule.

Each round fits every remaining identifiable candidate (its parameters jointly with every parameter the model
has accepted so far, the rig's free baseline parameters and the nuisances) on the fit part, and scores it on the
held-out part against the **current** model. A candidate is accepted only if every rule holds; the first that
fails is recorded as the reason (``Candidate.rejected_by``):

``simpler``
    where its fitted law degenerates into a simpler one over the span of the log (:meth:`Effect.simpler
    <sim.discrepancy.effects.base.Effect.simpler>`: a spring whose rest position lies outside the motion is a
    constant effort there, a resonance at the top of the analysis band a rigid inertia), it must pass the rules
    ``bic``, ``gain``, ``size`` and ``events`` against the model with the simpler law fitted instead; otherwise the
    simpler law is the one to name (it is a candidate of its own);
``bound``
    none of its parameters ends at a bound of its range (the range reported beside every value), and it drives
    none of the accepted parameters to a bound: a fit that wants a value the rig's scale makes implausible, or
    that only helps by shrinking the whole balance (an effort gain with every other term free), is not that
    effect;
``evidence``
    an effect whose term is its signature times a parameter (a friction level or coefficient, an inertia, a
    constant: :attr:`Effect.linear_signature <sim.discrepancy.effects.base.Effect.linear_signature>`) must find
    its signature in the held-out residual it is judged against: a correlation about zero of at least
    MIN_EVIDENCE in magnitude (:func:`signature_share`). A gain without it came by another way (a friction level
    whose band absorbs the residual of stuck samples for a load the rig lacks) and the fit is degenerate;
``bic``
    the held-out BIC falls by more than ``min_ic_drop``:
    ``ΔBIC = Σ_c n_c·ln(RSS_c,after / RSS_c,before) + k·ln(n) < -min_ic_drop``, ``n_c`` the channel's independent
    held-out samples (held-out duration x 2·f_c: the residuals are low-passed at f_c), ``k`` the candidate's
    fitted parameters;
``gain``
    in some channel the held-out RMSE falls by at least ``min_relative_gain`` of the current model's;
``size``
    an effect on the effort changes the model's held-out effort prediction by at least ``min_effort_change`` of
    the command (RMS): below that, a discrepancy is within what the surrogate resolves (its mismatch with a
    simulated plant of the same physics is 0.1-0.4 % of the command), however much of a small residual it
    explains; nor below the effort error the position encoder's resolution leaves, twice differentiated in the
    band (a coarse encoder's steps are a noise that an inertia or a compliance can fit). A dead time needs only
    the latter (:attr:`Effect.any_size <sim.discrepancy.effects.base.Effect.any_size>`): it matters to a
    controller whatever effort it leaves;
``events``
    the improvement holds across the held-out part. The per-sample drop of the squared residuals
    (channels weighted by their mean square before) is summed per block of ``block_s``; the mean block drop,
    studentised over the blocks, must reach ``min_event_z`` (a small-sample t with the blocks as the
    independent units: the residual's correlation does not reach across a block). A candidate that explains a
    third or more of the current model's error passes when it improves at least two thirds of the blocks it
    changes materially: evidence that sits in a few events (breakaways, torque peaks) is then not refused for
    being rare, while the surrogate's own mismatch, which a wrong effect can fit at a few events with gains
    of up to ~20 % (measured on logs of the rig itself), still meets the full test;
``moved``
    a parameter the model already carries moves by at least ``min_parameter_change`` of its value, measured
    from what the same fit gives on the model's own log (:mod:`sim.discrepancy.null`), so that the
    estimator's own bias is not a discrepancy;
``stationary``
    the candidate's parameters fitted on the held-out part alone agree with the fit part's within
    ``max_stability_z`` combined standard errors or ``stability_tolerance`` of their value: an effect that
    drifts across the log is reported as non-stationary, not as the effect.

The best passing candidate (lowest ΔBIC) is accepted; then every accepted effect and free parameter is re-fitted
together, and the next round searches again, until nothing passes or ``max_effects`` are accepted.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.fit import FitOutcome, at_bound_of, fit_keys, standard_errors
from sim.discrepancy.model import Surrogate
from sim.discrepancy.signals import AnalysisConfig
from sim.discrepancy.windows import LOW_SPEED, position_error
from sim.executor import Executor

RULES = ("simpler", "bound", "evidence", "bic", "gain", "size", "events", "moved", "stationary")
LARGE_GAIN = 1.0 / 3.0  # a candidate explaining this much passes 'events' on the blocks it changes
LARGE_GAIN_BLOCK_SHARE = 2.0 / 3.0  # ... if it improves this share of them
MATERIAL_BLOCK_SHARE = 0.02  # a block changes materially if its |drop| is above 2 % of the summed |drops|
MIN_BLOCKS = 4  # the block test needs at least four blocks
MIN_BLOCKS_HELD = 8  # a short held-out part is cut into at least this many blocks
MIN_EVIDENCE = 0.05  # rule 'evidence': the least |correlation| of a linear signature with the residual [1]
# (the findings of the independent battery and its real-drive stand-ins show 0.32 or more)


@dataclass(frozen=True)
class ChannelScore:
    """Held-out RMSE of each channel [channel units], its independent sample count, and the held-out residuals on
    the grid (NaN where a sample does not count) [channel units]."""

    rmse: dict[str, float]
    independent_samples: dict[str, float]
    residuals: dict[str, np.ndarray]


@dataclass(frozen=True)
class Candidate:
    """One candidate of a round: its fit and its held-out score against the current model."""

    effect: str
    fit: FitOutcome
    score: ChannelScore
    delta_bic: float
    gains: dict[str, float]  # relative held-out RMSE drop per channel, against the current model [1]
    event_z: float  # the block test's statistic [1]
    improved_block_share: float  # share of the materially changed blocks that improved [1]
    rejected_by: str | None  # the first rule that failed (None: passes)
    seconds: float
    at_bound: dict[str, str] = field(default_factory=dict)
    effort_change: float = float("nan")  # RMS change of the held-out effort prediction / command RMS [1]
    held_out_parameters: dict[str, float] | None = None  # fitted on the held-out part alone ('stationary')
    model_log_parameters: dict[str, float] | None = None  # fitted on the model's own log ('moved')
    note: str = ""
    before_rmse: dict[str, float] = field(default_factory=dict)  # the current model's, per channel scored
    signature_share: float | None = None  # rule 'evidence': how much the residual follows its signature [1]
    details: dict[str, Any] | None = None  # what the effect's own fit adds (its low-speed windows)

    @property
    def passes(self) -> bool:
        return self.rejected_by is None

    @property
    def gain(self) -> float:
        return max(self.gains.values()) if self.gains else 0.0

    @property
    def best_channel(self) -> str:
        return max(self.gains, key=self.gains.get)

    @property
    def parameters(self) -> dict[str, float]:
        return {k: self.fit.theta[k] for k in EFFECTS[self.effect].keys}

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "delta_bic": self.delta_bic, "gains": self.gains,
                "effort_change": self.effort_change, "event_z": self.event_z,
                "improved_block_share": self.improved_block_share, "passes": self.passes,
                "rejected_by": self.rejected_by, "at_bound": self.at_bound, "parameters": self.parameters,
                "held_out_parameters": self.held_out_parameters,
                "model_log_parameters": self.model_log_parameters, "signature_share": self.signature_share,
                "note": self.note, "seconds": self.seconds,
                **({"details": self.details} if self.details else {})}


def signature_share(model: Surrogate, effect: str, theta: dict[str, float]) -> float | None:
    """How much the held-out residual of ``theta`` follows ``effect``'s signature: their correlation about zero,
    Σ r·s / sqrt(Σ r² · Σ s²) [1] (not about their means: a joint sliding one way has a constant sign of velocity,
    which a level error follows entirely). None without a signature."""
    spec = EFFECTS[effect]
    signal = spec.signature_signal(model, theta)
    if signal is None:
        return None
    residual = model.residuals(theta)[spec.channel]
    mask = model.data.held & np.isfinite(residual)
    r, s = residual[mask], np.broadcast_to(signal, residual.shape)[mask]
    scale = math.sqrt(float(r @ r) * float(s @ s))
    return float(r @ s) / scale if scale > 0 else 0.0


def smallest_change(model: Surrogate) -> float:
    """The smallest change of the held-out effort prediction an effect on the effort must make (rule 'size')
    [N·m | N]: ``min_effort_change`` of the command's RMS, and the effort error the position encoder's resolution
    alone leaves (:attr:`Surrogate.resolution_floor`)."""
    return max(model.config.min_effort_change * model.command_rms, model.resolution_floor)


def held_out_score(model: Surrogate, theta: dict[str, float], mask: np.ndarray | None = None, *,
                   low_speed: bool = False) -> ChannelScore:
    """Held-out RMSE per channel and its independent sample count (``mask``: default the held-out part); with
    ``low_speed``, a rigid joint's held-out low-speed windows' position error as a channel too
    (:func:`with_low_speed`)."""
    mask = model.data.held if mask is None else mask
    per_sample = model.data.independent_per_grid_sample
    rmse, count, residuals = {}, {}, {}
    for channel, r in model.residuals(theta).items():
        held = r[mask]
        residuals[channel] = held
        sel = held[np.isfinite(held)]
        rmse[channel] = float(np.sqrt(np.mean(sel**2))) if len(sel) else float("nan")
        count[channel] = len(sel) * per_sample
    score = ChannelScore(rmse, count, residuals)
    return with_low_speed(model, theta, score) if low_speed else score


def with_low_speed(model: Surrogate, theta: dict[str, float], score: ChannelScore) -> ChannelScore:
    """``score`` with the channel ``low_speed`` [rad | m]: the position error of the windows around the held-out
    part's low-speed events (:func:`sim.discrepancy.windows.position_error`), each window one independent sample;
    unchanged where it has none or already has the channel."""
    if LOW_SPEED in score.rmse:
        return score
    error = position_error(model, theta, part="held")
    if error is None:
        return score
    values, windows = error
    held = values[model.data.held]
    sel = held[np.isfinite(held)]
    return ChannelScore({**score.rmse, LOW_SPEED: float(np.sqrt(np.mean(sel**2))) if len(sel) else float("nan")},
                        {**score.independent_samples, LOW_SPEED: float(windows)},
                        {**score.residuals, LOW_SPEED: held})


def low_speed_change(before: ChannelScore, after: ChannelScore) -> float:
    """RMS change of the low-speed windows' position error between two models [rad | m] (0 without the
    channel)."""
    b, a = before.residuals.get(LOW_SPEED), after.residuals.get(LOW_SPEED)
    if b is None or a is None:
        return 0.0
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean((b[ok] - a[ok]) ** 2))) if ok.any() else 0.0


def compare(before: ChannelScore, after: ChannelScore, n_params: int) -> tuple[float, dict[str, float]]:
    """(ΔBIC, relative gain per channel) of ``after`` against ``before``."""
    delta, gains, total = 0.0, {}, 0.0
    for channel, rmse_before in before.rmse.items():
        rmse_after = after.rmse[channel]
        n = before.independent_samples[channel]
        if not (n > 0 and rmse_before > 0 and math.isfinite(rmse_after)):
            continue
        total += n
        delta += n * math.log(max(rmse_after, 1e-300) ** 2 / rmse_before**2)
        gains[channel] = 1.0 - rmse_after / rmse_before
    delta += n_params * math.log(max(total, 1.0))
    return delta, gains


def effort_change(before: ChannelScore, after: ChannelScore) -> float:
    """RMS change of the held-out effort residual between two models [N·m | N] (0 without an effort channel)."""
    b, a = before.residuals.get("effort"), after.residuals.get("effort")
    if b is None or a is None:
        return 0.0
    ok = np.isfinite(a) & np.isfinite(b)
    return float(np.sqrt(np.mean((b[ok] - a[ok]) ** 2))) if ok.any() else 0.0


def block_samples(model: Surrogate) -> int:
    """Grid samples per block of rule 'events': ``block_s``, shorter on a short held-out part so that it holds
    MIN_BLOCKS_HELD blocks."""
    per_block = model.config.block_s / (model.data.dt * model.data.grid_step)
    return max(1, int(round(min(per_block, int(model.data.held.sum()) / MIN_BLOCKS_HELD))))


def block_drops(before: ChannelScore, after: ChannelScore, block: int) -> np.ndarray:
    """Drop of the squared residuals summed per block of ``block`` samples, channels weighted by their mean
    square before [1]."""
    drop = None
    for channel, b in before.residuals.items():
        a = after.residuals[channel]
        ok = np.isfinite(a) & np.isfinite(b)
        mean_square = float(np.mean(b[ok] ** 2)) if ok.any() else 0.0
        if mean_square <= 0.0:
            continue
        term = (np.where(ok, b, 0.0) ** 2 - np.where(ok, a, 0.0) ** 2) / mean_square
        drop = term if drop is None else drop + term
    if drop is None:
        return np.zeros(0)
    n_blocks = len(drop) // block
    return drop[:n_blocks * block].reshape(n_blocks, block).sum(axis=1) if n_blocks else np.zeros(0)


def event_test(before: ChannelScore, after: ChannelScore, block: int) -> tuple[float, float]:
    """(z, improved share): the studentised mean block drop, and the share of materially changed blocks that
    improved [1, 1] (see the module docstring, rule 'events')."""
    drops = block_drops(before, after, block)
    if len(drops) < MIN_BLOCKS:
        return float("nan"), float("nan")
    spread = float(np.std(drops, ddof=1))
    mean = float(drops.mean())
    z = mean / (spread / math.sqrt(len(drops))) if spread > 0 else math.copysign(math.inf, mean) if mean else 0.0
    material = np.abs(drops) > MATERIAL_BLOCK_SHARE * float(np.abs(drops).sum())
    share = float((drops[material] > 0).mean()) if material.any() else 0.0
    return z, share


def passes_events(candidate_gain: float, z: float, share: float, min_z: float) -> bool:
    """Rule 'events' (module docstring)."""
    return z >= min_z or (candidate_gain >= LARGE_GAIN and share >= LARGE_GAIN_BLOCK_SHARE)


def carried_by_model(effect: str, theta: dict[str, float]) -> bool:
    """Whether the current model already carries ``effect`` (present, e.g. a nonzero friction level)."""
    return EFFECTS[effect].present(theta)


def moved_enough(effect: str, before: dict[str, float], after: dict[str, float], min_change: float,
                 reference: dict[str, float] | None = None) -> bool:
    """Whether ``effect`` is new to the model or moves one of its parameters by ``min_change`` [1] of the current
    value, measured from ``reference`` (what the same fit gives on the model's own log; default: ``before``)."""
    if not carried_by_model(effect, before):
        return True
    reference = reference or before
    return any(abs(after[k] - reference[k]) >= min_change * abs(before[k]) for k in EFFECTS[effect].keys
               if not EFFECTS[effect].param(k).cyclic)


def candidate_keys(effect: str, accepted: tuple[str, ...]) -> tuple[str, ...]:
    """The keys fitted with ``effect``: its own, then the accepted and free ones (no duplicates)."""
    own = EFFECTS[effect].keys
    return own + tuple(k for k in accepted if k not in own)


def fit_effect(model: Surrogate, effect: str, theta: dict[str, float], accepted: tuple[str, ...],
               scales: dict[str, float], *, mask: np.ndarray | None = None) -> FitOutcome:
    """Fit one effect's parameters jointly with the ``accepted`` keys: its own fit (:meth:`Effect.fit
    <sim.discrepancy.effects.base.Effect.fit>`) where it has one, else least squares from its starting points."""
    spec = EFFECTS[effect]
    keys = candidate_keys(effect, accepted)
    own = spec.fit(model, theta, mask=mask)
    if own is None:
        starts, held = spec.starts(model, theta)
        return fit_keys(model, theta, keys, scales, starts, mask=mask, held=held, refine=spec.refined_starts)
    others = tuple(k for k in keys if k not in spec.keys)
    refit = fit_keys(model, {**theta, **own.values}, others, scales, mask=mask)
    bounds = {k: spec.bounds(k, model.scale, theta) for k in spec.keys}
    at_bound = {k: side for k in spec.keys if k not in own.unresolved
                and (side := at_bound_of(k, own.values[k], *bounds[k], theta[k]))}
    return replace(refit, keys=spec.keys + refit.keys, bounds={**bounds, **refit.bounds},
                   at_bound={**at_bound, **refit.at_bound}, errors=own.errors, details=own.details)


def fit_candidate(model: Surrogate, effect: str, theta: dict[str, float], accepted: tuple[str, ...],
                  scales: dict[str, float], before: ChannelScore) -> Candidate:
    """Fit one effect (with the accepted keys) and score it against ``before`` by the rules ``bound``, ``bic``,
    ``gain``, ``events`` and ``stationary`` (``moved`` needs the model's own log: :func:`against_model_log`)."""
    start = time.perf_counter()
    cfg = model.config
    spec = EFFECTS[effect]
    outcome = fit_effect(model, effect, theta, accepted, scales)
    own = set(spec.keys)
    # its own parameters, or accepted ones it drives to a bound they were not at (a degenerate joint fit, e.g.
    # an effort gain shrinking every term of the balance with it)
    at_bound = {k: side for k, side in outcome.at_bound.items()
                if k in own or at_bound_of(k, theta[k], *outcome.bounds[k]) is None}
    windowed = spec.low_speed_evidence and not model.testbed
    if windowed:
        before = with_low_speed(model, theta, before)
    after = held_out_score(model, outcome.theta, low_speed=windowed)
    delta, gains = compare(before, after, spec.n_parameters(model))
    gain = max(gains.values()) if gains else 0.0
    block = block_samples(model)
    z, share = event_test(before, after, block)
    change = effort_change(before, after)
    notes = {"bound": "at the " + "; ".join(f"{side} bound of {k}'s range [{outcome.bounds[k][0]:.4g}, "
                                            f"{outcome.bounds[k][1]:.4g}]" for k, side in at_bound.items())
             + ("" if spec.explains_at_bound else ": there it only scales the whole balance, no explanation")}
    simpler = spec.simpler(model, outcome.theta)
    if simpler is not None:
        name, why = simpler
        plain = held_out_score(model, fit_effect(model, name, theta, accepted, scales).theta, low_speed=windowed)
        extra = max(1, spec.n_parameters(model) - EFFECTS[name].n_parameters(model))
        d_simpler, g_simpler = compare(plain, after, extra)
        gain_simpler = max(g_simpler.values()) if g_simpler else 0.0
        z_simpler, share_simpler = event_test(plain, after, block)
        sized = (spec.channel != "effort" or effort_change(plain, after) >= smallest_change(model)
                 or low_speed_change(plain, after) >= model.data.position_resolution)
        if d_simpler < -cfg.min_ic_drop and gain_simpler >= cfg.min_relative_gain and sized \
                and passes_events(gain_simpler, z_simpler, share_simpler, cfg.min_event_z):
            simpler = None
        else:
            notes["simpler"] = (f"over the span of the log it is {name}: {why}; against {name} it gains "
                                f"{100 * gain_simpler:.1f} % (ΔBIC {d_simpler:.1f})")
    evidence = signature_share(model, effect, theta) if spec.linear_signature else None
    degenerate = evidence is not None and abs(evidence) < MIN_EVIDENCE
    if degenerate:
        notes["evidence"] = (f"degenerate: the residual does not follow '{spec.signature}' (their correlation "
                             f"about zero is {evidence:+.3f}), so its gain came by another way")
    checks = {"bound": not at_bound, "simpler": simpler is None, "evidence": not degenerate,
              "bic": delta < -cfg.min_ic_drop,
              "gain": gain >= cfg.min_relative_gain,
              "size": spec.channel != "effort" or change >= (model.resolution_floor if spec.any_size
                                                              else smallest_change(model))
              or low_speed_change(before, after) >= model.data.position_resolution,
              "events": passes_events(gain, z, share, cfg.min_event_z),
              "moved": moved_enough(effect, theta, outcome.theta, cfg.min_parameter_change)}
    rejected = next((rule for rule in RULES if not checks.get(rule, True)), None)
    note = notes.get(rejected, "")
    candidate = Candidate(effect, outcome, after, delta, gains, z, share, rejected, 0.0, at_bound,
                          effort_change=change / model.command_rms if model.command_rms > 0 else float("nan"),
                          note=note, before_rmse=dict(before.rmse), details=outcome.details,
                          signature_share=evidence)
    if rejected is None:
        candidate = stationarity(model, candidate, theta, accepted, scales)
    return replace(candidate, seconds=time.perf_counter() - start)


def stationarity(model: Surrogate, candidate: Candidate, theta: dict[str, float], accepted: tuple[str, ...],
                 scales: dict[str, float]) -> Candidate:
    """Rule 'stationary': the candidate's own parameters fitted on the held-out part alone (the others at the
    fit part's values) must agree with the fit part's."""
    cfg = model.config
    effect = EFFECTS[candidate.effect]
    keys = effect.stationary_keys
    if not keys:
        return candidate
    fit_part = candidate.fit
    fraction = model.data.independent_per_grid_sample
    own = effect.fit(model, fit_part.theta, mask=model.data.held)
    if own is None:
        held = fit_keys(model, fit_part.theta, keys, scales, mask=model.data.held)
        values, se_held = held.theta, standard_errors(held, fraction)
    else:
        values, se_held = {**fit_part.theta, **own.values}, own.errors
    se_fit = standard_errors(fit_part, fraction)
    drifting = []
    for key in keys:
        a, b = fit_part.theta[key], values[key]
        allowed = max(cfg.max_stability_z * math.hypot(se_fit.get(key, 0.0), se_held.get(key, 0.0)),
                      cfg.stability_tolerance * abs(a))
        if not abs(b - a) <= allowed:
            drifting.append(f"{key} {a:.4g} on the fit part, {b:.4g} on the held-out part")
    values = {k: values[k] for k in effect.keys}
    if drifting:
        return replace(candidate, rejected_by="stationary", held_out_parameters=values,
                       note="non-stationary: " + "; ".join(drifting))
    return replace(candidate, held_out_parameters=values)


def against_model_log(candidate: Candidate, model_log_model: Surrogate, theta: dict[str, float],
                      accepted: tuple[str, ...], scales: dict[str, float]) -> Candidate:
    """``candidate`` with rule 'moved' measured from the same fit on the model's own log."""
    reference = fit_effect(model_log_model, candidate.effect, theta, accepted, scales).theta
    params = {k: reference[k] for k in EFFECTS[candidate.effect].keys}
    moved = moved_enough(candidate.effect, theta, candidate.fit.theta, model_log_model.config.min_parameter_change,
                         params)
    return replace(candidate, rejected_by=candidate.rejected_by or (None if moved else "moved"),
                   model_log_parameters=params)


# ------------------------------------------------------------------------------ the round's fits (sim.executor)
def _fit(model: Surrogate, args: tuple) -> Candidate:
    return fit_candidate(model, *args)


def make_executor(config: AnalysisConfig) -> Executor:
    """The executor of the candidate fits: ``config.workers`` local processes (1: this process), or the Ray
    cluster at ``config.ray``."""
    return Executor(workers=config.workers, ray=config.ray)


def run_round(model: Surrogate, candidates: list[str], theta: dict[str, float], accepted: tuple[str, ...],
              scales: dict[str, float], before: ChannelScore, executor: Executor | None = None,
              progress: bool = False, label: str = "") -> list[Candidate]:
    """Fit and score every candidate (on ``executor``; default: this process), best ΔBIC first; one progress
    line per candidate. Each fit runs with one BLAS thread (:mod:`sim.executor`); this process keeps its own count."""
    executor = executor or Executor()
    args = [(effect, theta, accepted, scales, before) for effect in candidates]
    scores = executor.map(_fit, args, shared=model)
    if progress:
        for i, c in enumerate(scores, start=1):
            verdict = "passes" if c.passes else f"rejected ({c.rejected_by})"
            print(f"discrepancy: {label}{i}/{len(args)} {c.effect}: held-out gain {100 * c.gain:.1f} %, "
                  f"ΔBIC {c.delta_bic:.1f}, {verdict} ({c.seconds:.1f} s)", file=sys.stderr, flush=True)
    return sorted(scores, key=lambda s: (s.delta_bic, s.effect))
