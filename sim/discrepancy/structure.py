"""What the residual still holds after the findings: the "unexplained" verdict and its signature.

The library names what it holds; a log may carry something else. After the selection, the effort residual of
the final model is regressed on a generic basis (fitted on the fit part, scored on the held-out part by the same
significance rule as a candidate effect):

- velocity, velocity·|velocity|, the sign of the velocity while sliding, acceleration, position, sin and cos of
  position (a hinge), the command's rate, time, and the products that make an inertia or a friction
  level vary with position (acceleration or the sign of the velocity times the position, or its sine and
  cosine) or a friction level drift with time;
- the strongest lines of the residual's spectrum on the fit part (each a sine and a cosine in time).

The command itself is not in the basis: with it, the basis holds every term of the balance and rebuilds any
residual by scaling the whole balance to nothing. If the final model's held-out effort error (the median of its RMS
per block of ``block_s``, :func:`median_block_rms`) exceeds ``max_remainder`` of the command (RMS), or if that
generic model explains a significant part of the held-out residual (the candidates' rules 'bic', 'gain', 'size' and
'events'), the verdict is a discrepancy the library does not name, described by the basis terms that carry it
("effort error grows with v|v|", "a 6.0 Hz line not locked to position"), with the RMSE it leaves. So is a
candidate effect that would explain a third or more of the residual but was refused because its parameters sit at a
bound of the rig's plausible range or drift across the log (non-stationary): the nearest library effect is then
named as not fitting, not as the finding (unless it only scales the whole balance, as an effort gain at its
bound does). A remainder below the smallest reportable change (``min_effort_change`` of the command) is not
unexplained, whatever its shape, nor is one within RESOLUTION_MULTIPLE x the effort error the position encoder's
resolution alone leaves (:attr:`Surrogate.resolution_floor <sim.discrepancy.model.Surrogate.resolution_floor>`).
The whiteness of the held-out residual (Ljung-Box, at the band's rate of independent samples) is reported beside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from sim.discrepancy.effects import EFFECTS
from sim.discrepancy.effects.periodic_disturbance import spectral_lines
from sim.discrepancy.model import Surrogate, channel_unit
from sim.discrepancy.selection import (
    Candidate,
    ChannelScore,
    block_samples,
    compare,
    effort_change,
    event_test,
    passes_events,
)
from sim.discrepancy.signals import rms

SPECTRAL_TERMS = 2  # spectral lines of the residual in the generic basis
WHITENESS_LAGS = 10  # Ljung-Box lags (independent samples)
NEAREST_GAIN = 1.0 / 3.0  # a refused candidate explaining this much makes the remainder "unexplained"
UNEXPLAINED_RULES = ("bound", "stationary")  # ... when refused for these
TERM_SHOWN_GAIN = 0.5  # a basis term is named if alone it gains this share of the whole basis's gain ...
TERMS_SHOWN = 2  # ... or is among the strongest two
RESOLUTION_MULTIPLE = 1.5  # a remainder within this x the encoder's resolution floor is that floor's noise

PHRASES = {
    "velocity": "effort error grows with the velocity",
    "velocity squared": "effort error grows with v|v| (quadratic in speed)",
    "sign of velocity": "effort error steps at every motion reversal (a friction level)",
    "acceleration": "effort error follows the acceleration (an inertia error)",
    "position": "effort error grows with the position (a spring toward a rest position)",
    "sin/cos of position": "effort error follows the joint angle once per turn (gravity, an unbalance)",
    "command rate": "effort error follows the command's rate (a timing error)",
    "time": "effort error drifts with time",
    "acceleration x position": "effort error follows the acceleration times a function of position (an inertia "
                                "that varies with position)",
    "sign of velocity x position": "effort error steps at reversals by an amount that varies with position (a "
                                   "friction level that varies with position)",
    "sign of velocity x time": "effort error steps at reversals by an amount that drifts with time (a friction "
                               "level that changes over the log: warm-up, wear)",
}


@dataclass(frozen=True)
class Structure:
    """What the final model's residual still holds.

    Attributes
    ----------
    unexplained : bool
        A significant discrepancy the library does not name remains.
    description : list of str
        The residual's signature in words.
    rmse : dict of str to float
        Held-out RMSE the final model leaves, per channel [channel units].
    generic_gain : float
        Held-out RMSE drop a generic model of the effort residual achieves [1].
    remainder_fraction : float
        The effort error left on the held-out part, as a fraction of the command's RMS [1]: the median of its RMS
        per block of the rule 'events' (:func:`median_block_rms`), robust to a transient that one RMS over the
        whole part would be dominated by.
    terms : dict of str to float
        Held-out gain of each basis term alone [1].
    lines : list of dict
        Spectral lines of the residual: frequency [Hz], share of the residual's variance, position-locked.
    whiteness : dict
        Ljung-Box statistic and p-value of the held-out effort residual.
    refused : list of str
        Nearest library effects that would explain much but were refused, and why.
    resolution_floor : float
        The effort error the position encoder's resolution alone leaves [channel unit] (RMS).
    """

    unexplained: bool
    description: list[str]
    rmse: dict[str, float]
    generic_gain: float
    remainder_fraction: float
    terms: dict[str, float]
    lines: list[dict[str, Any]] = field(default_factory=list)
    whiteness: dict[str, float] = field(default_factory=dict)
    refused: list[str] = field(default_factory=list)
    resolution_floor: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"unexplained": self.unexplained, "description": self.description, "rmse": self.rmse,
                "generic_gain": self.generic_gain, "remainder_fraction": self.remainder_fraction,
                "terms": self.terms, "lines": self.lines,
                "whiteness": self.whiteness, "refused": self.refused, "resolution_floor": self.resolution_floor}


def _basis(model: Surrogate, residual: np.ndarray) -> dict[str, list[np.ndarray]]:
    d = model.data
    v, sliding = d.velocity, ~model.stuck
    terms: dict[str, list[np.ndarray]] = {
        "velocity": [v], "velocity squared": [v * np.abs(v)], "sign of velocity": [np.where(sliding, np.sign(v), 0.0)],
        "acceleration": [d.acceleration], "position": [d.position],
        "command rate": [d.filt(d.derivative(d.u_full))], "time": [d.t - d.t[0]],
    }
    sign = np.where(sliding, np.sign(v), 0.0)
    x = d.position - float(np.mean(d.position))
    if model.rig.joint == "hinge" and float(np.ptp(d.position)) > 1.0:
        terms["sin/cos of position"] = [np.sin(d.position), np.cos(d.position)]
        shapes = [np.sin(d.position), np.cos(d.position)]
    else:
        shapes = [x]
    terms["acceleration x position"] = [d.acceleration * shape for shape in shapes]
    terms["sign of velocity x position"] = [sign * shape for shape in shapes]
    terms["sign of velocity x time"] = [sign * (d.t - d.t[0])]
    ok = d.fit & np.isfinite(residual)
    if ok.sum() > 32:
        for f in spectral_lines(model, residual, ok, SPECTRAL_TERMS):
            t = d.t - d.t_full[0]
            gain = d.sine_gain(f)
            terms[f"line {f:.2f} Hz"] = [gain * np.sin(2 * math.pi * f * t), gain * np.cos(2 * math.pi * f * t)]
    return terms


def _regress(columns: list[np.ndarray], residual: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """The residual after subtracting the least-squares combination of ``columns`` fitted on ``fit`` (a constant
    included)."""
    x = np.column_stack([np.ones(len(residual))] + columns)
    scale = np.maximum(np.abs(x[fit]).max(axis=0), 1e-300)
    coef, *_ = np.linalg.lstsq(x[fit] / scale, residual[fit], rcond=None)
    return residual - (x / scale) @ coef


def _score(model: Surrogate, residual: np.ndarray) -> ChannelScore:
    held = residual[model.data.held]
    sel = held[np.isfinite(held)]
    return ChannelScore({"effort": rms(sel)}, {"effort": len(sel) * model.data.independent_per_grid_sample},
                        {"effort": held})


def ljung_box(x: np.ndarray, lags: int) -> dict[str, float]:
    """Ljung-Box Q over ``lags`` lags of ``x`` and its p-value (χ² with ``lags`` degrees of freedom)."""
    x = x[np.isfinite(x)]
    n = len(x)
    if n <= lags + 1:
        return {"q": float("nan"), "p_value": float("nan"), "lags": lags}
    x = x - x.mean()
    denominator = float(x @ x)
    if denominator <= 0:
        return {"q": 0.0, "p_value": 1.0, "lags": lags}
    q = n * (n + 2) * sum((float(x[:-k] @ x[k:]) / denominator) ** 2 / (n - k) for k in range(1, lags + 1))
    return {"q": float(q), "p_value": float(chi2.sf(q, lags)), "lags": lags}


def median_block_rms(residual: np.ndarray, block: int) -> float:
    """The median over consecutive blocks of ``block`` samples of each block's RMS (finite samples only; a last
    partial block counts if it holds half a block) [residual's unit]; the RMS of all if there is no full block."""
    x = np.asarray(residual, dtype=float)
    values = []
    for start in range(0, len(x), block):
        part = x[start:start + block]
        part = part[np.isfinite(part)]
        if len(part) >= max(1, block // 2):
            values.append(rms(part))
    return float(np.median(values)) if values else rms(x)


def residual_structure(model: Surrogate, theta: dict[str, float], current: ChannelScore,
                       refused: list[Candidate]) -> Structure:
    """The final model's residual structure (module docstring)."""
    cfg = model.config
    d = model.data
    residual = model.residuals(theta)["effort"]
    fit = d.fit & np.isfinite(residual)
    before = _score(model, residual)
    terms = _basis(model, residual)
    block = block_samples(model)
    ok_fit = fit & np.all(np.isfinite(np.column_stack([c for cols in terms.values() for c in cols])), axis=1)
    after = _score(model, _regress([c for cols in terms.values() for c in cols], residual, ok_fit))
    n_columns = sum(len(c) for c in terms.values())
    delta, gains = compare(before, after, n_columns)
    gain = gains.get("effort", 0.0)
    z, share = event_test(before, after, block)
    significant = (delta < -cfg.min_ic_drop and gain >= cfg.min_relative_gain
                   and effort_change(before, after) >= cfg.min_effort_change * model.command_rms
                   and passes_events(gain, z, share, cfg.min_event_z))
    alone = {}
    for name, columns in terms.items():
        _, g = compare(before, _score(model, _regress(columns, residual, ok_fit)), len(columns))
        alone[name] = g.get("effort", 0.0)
    description = []
    lines = []
    for rank, (name, value) in enumerate(sorted(alone.items(), key=lambda kv: -kv[1])):
        if name.startswith("line "):
            frequency = float(name.split()[1])
            locked = _locked_to_position(model, theta, residual, ok_fit, value)
            lines.append({"frequency_hz": frequency, "gain": value, "locked_to_position": locked})
        if significant and value > 0 and (value >= TERM_SHOWN_GAIN * gain or rank < TERMS_SHOWN):
            if name.startswith("line "):
                where = "locked to position" if lines[-1]["locked_to_position"] else "not locked to position"
                phrase = f"a {float(name.split()[1]):.1f} Hz line {where}"
            else:
                phrase = PHRASES[name]
            description.append(f"{phrase} (alone it explains {100 * value:.0f} % of the held-out residual)")
    nearest = []
    for c in refused:
        if c.rejected_by in UNEXPLAINED_RULES and c.gain >= NEAREST_GAIN and EFFECTS[c.effect].explains_at_bound:
            why = (f"its {', '.join(c.at_bound)} sits at a bound of the rig's plausible range"
                   if c.rejected_by == "bound" else c.note)
            nearest.append(f"{c.effect} would explain {100 * c.gain:.0f} % of the held-out error, but {why}")
    if significant and not description:
        description.append("the residual holds structure no single basis term carries")
    rmse = {c: current.rmse[c] for c in current.rmse}
    typical = median_block_rms(residual[d.held], block)
    fraction = typical / model.command_rms if model.command_rms > 0 else float("nan")
    # below the smallest reportable change, or within what the position encoder's resolution leaves, nothing
    # material is left, whatever its shape
    resolved = typical > RESOLUTION_MULTIPLE * model.resolution_floor
    too_large = fraction >= cfg.max_remainder and resolved
    material = fraction >= cfg.min_effort_change and resolved
    unexplained = too_large or (material and (significant or bool(nearest)))
    if unexplained:
        unit = channel_unit("effort", model.rig.joint)
        description.insert(0, f"the final model leaves {rmse['effort']:.4g} {unit} RMS of effort error held out, "
                              f"{typical:.4g} {unit} in a typical block of {cfg.block_s:g} s (median; "
                              f"{100 * fraction:.2g} % of the command's RMS"
                              + (f", above the {100 * cfg.max_remainder:g} % a model of the right physics leaves"
                                 if too_large else "")
                              + f"); a generic model of it explains {max(100 * gain, 0):.0f} %")
    independent = max(1, int(round(1.0 / d.independent_per_grid_sample)))
    whiteness = ljung_box(residual[d.held][::independent], min(WHITENESS_LAGS, max(1, int(d.held.sum()) // 8)))
    return Structure(unexplained, description, rmse, gain, fraction, alone, lines, whiteness, nearest,
                     model.resolution_floor)


def _locked_to_position(model: Surrogate, theta: dict[str, float], residual: np.ndarray, fit: np.ndarray,
                        line_gain: float) -> bool:
    """Whether a position-periodic term (the cogging effect's screened fit) explains the residual as well as the
    spectral line does."""
    cogging = EFFECTS["cogging"]
    if not cogging.applies(model.rig) or cogging.identifiable(model, theta):
        return False
    starts, _ = cogging.starts(model, theta)
    if not starts:
        return False
    trial = {**theta, **starts[0]}
    before = _score(model, residual)
    shifted = residual - cogging.load(model, trial) + cogging.load(model, theta)
    _, g = compare(before, _score(model, shifted), 3)
    return g.get("effort", 0.0) >= line_gain
