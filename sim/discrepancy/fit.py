"""Bounded least squares of chosen surrogate parameters on the fit part.

Problem (per fit)::

    minimise_x  Σ_c Σ_{k ∈ fit_c} ( r_c,k(θ(x)) / s_c )²      subject to  lo <= x <= hi

``r_c`` the residual channel ``c`` of :class:`~sim.discrepancy.model.Surrogate` on the analysis grid, ``fit_c`` the
fit-part samples where it counts; ``s_c`` the channel's baseline RMS on the fit part (so channels in N·m and rad
weigh alike); ``θ(x)`` the current parameters with the entries ``keys`` set to ``x``; the bounds each effect's
:meth:`~sim.discrepancy.effects.base.Effect.bounds`, scaled to the rig and the log. Solved with scipy's
trust-region reflective ``least_squares`` from the best of the effects' starting points.

A parameter that ends at a bound of its range (not at its neutral value, nor a phase) is reported in
``FitOutcome.at_bound``: the fit wanted a value outside the range the rig makes plausible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from sim.discrepancy.effects import TESTBED, effect_of_key
from sim.discrepancy.model import NUISANCE_KEYS, Surrogate

KIN_OFFSET_BOUND_RAD = 0.1  # encoder offset between motor and lever angle [rad]
MAX_NFEV = 60  # function evaluations per least-squares refinement (x the number of parameters, at least this)
AT_BOUND = 1e-3  # a value within this fraction of a bound's magnitude ...
AT_BOUND_OF_RANGE = 1e-6  # ... plus this fraction of the range is at that bound (the solver stops within ~1e-10)
EMPTY_RANGE = "empty range"  # FitOutcome.at_bound of a parameter whose range has no room (low >= high)


@dataclass(frozen=True)
class FitOutcome:
    """A fit: the parameter vector after it, the cost, evaluations used, the bounds used, and the keys that
    ended at a bound (key -> 'lower' | 'upper')."""

    theta: dict[str, float]
    keys: tuple[str, ...]
    cost: float
    evaluations: int
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    at_bound: dict[str, str] = field(default_factory=dict)
    jacobian: np.ndarray | None = field(default=None, repr=False)
    errors: dict[str, float] | None = None  # standard errors of a fit that knows them itself [their units]
    details: dict | None = None  # what a fit of an effect's own adds (its windows, its resolution)

    def to_dict(self) -> dict:
        return {"parameters": {k: self.theta[k] for k in self.keys}, "cost": self.cost,
                "evaluations": self.evaluations}


def bounds_of(key: str, model: Surrogate, theta: dict[str, float], fitting: tuple[str, ...],
              widen: float = 1.0) -> tuple[float, float]:
    """Range of theta entry ``key`` in a fit: its effect's bounds (``widen`` x as wide away from zero, within the
    parameter's physical validity, unless the range is firm), with Coulomb <= breakaway on the testbed (its
    LuGre needs it)."""
    if key == "kin_offset":
        return -KIN_OFFSET_BOUND_RAD, KIN_OFFSET_BOUND_RAD
    effect = effect_of_key(key)
    low, high = effect.bounds(key, model.scale, theta)
    if widen != 1.0 and not effect.param(key).firm:
        low = low / widen if low > 0 else low * widen
        high = high * widen if high > 0 else high / widen
        valid = effect.param(key).valid
        low, high = max(low, valid[0]), min(high, valid[1])
    if key == "coulomb" and "breakaway" not in fitting and model.kind == TESTBED:
        high = min(high, theta["breakaway"])
    if key == "breakaway" and "coulomb" not in fitting:
        low = max(low, theta["coulomb"])
    return low, high


def residual_vector(model: Surrogate, theta: dict[str, float], mask: np.ndarray,
                    scales: dict[str, float]) -> np.ndarray:
    """Stacked, scaled residuals of every channel on ``mask`` [1]; samples that do not count are zeros (not
    dropped: the vector keeps its length while the parameters move the kinematic channel's contact set)."""
    parts = []
    for channel, r in model.residuals(theta).items():
        sel = r[mask]
        parts.append(np.where(np.isfinite(sel), sel, 0.0) / scales[channel])
    return np.concatenate(parts)


def at_bound_of(key: str, value: float, low: float, high: float, start: float | None = None) -> str | None:
    """'lower' or 'upper' if ``value`` of ``key`` sits at that bound of [low, high], else None. A phase is never
    at a bound; nor is a parameter at its neutral value (the effect absent) when the fit started there
    (``start``): a rig's nonzero value fitted down to zero is at its bound (it wanted past zero)."""
    if key in NUISANCE_KEYS:
        return None
    param = effect_of_key(key).param(key)
    if param.cyclic:
        return None
    span = high - low if math.isfinite(high - low) else max(abs(value), 1e-12)
    for side, bound in (("lower", low), ("upper", high)):
        tolerance = AT_BOUND_OF_RANGE * span + AT_BOUND * abs(bound)
        if abs(value - bound) <= tolerance and not (bound == param.neutral and start in (None, param.neutral)):
            return side
    return None


def fit_keys(model: Surrogate, theta0: dict[str, float], keys: tuple[str, ...], scales: dict[str, float],
             starts: list[dict[str, float]] | None = None, *, mask: np.ndarray | None = None,
             held: tuple[str, ...] = (), widen: float = 1.0, refine: int = 1) -> FitOutcome:
    """Least squares of ``keys`` on ``mask`` (default: the fit part), refined from the ``refine`` best of
    ``theta0`` and ``starts`` (each a partial theta; the best final fit is kept). ``held`` keys keep their screened
    start value; ``widen`` widens the bounds (:func:`bounds_of`)."""
    mask = model.data.fit if mask is None else mask
    evaluations = 0

    def cost_of(theta: dict[str, float]) -> float:
        nonlocal evaluations
        evaluations += 1
        r = residual_vector(model, theta, mask, scales)
        return float(r @ r)

    candidates = [dict(theta0)] + [{**theta0, **s} for s in starts or []]
    screened = sorted(((cost_of(t), i, t) for i, t in enumerate(candidates)), key=lambda e: (e[0], e[1]))
    keys = tuple(k for k in keys if k not in held)
    bounds = {k: bounds_of(k, model, theta0, keys, widen) for k in keys}
    # a range with no room (a breakaway range starting above its top, a rig value beyond the log's scale) holds
    # its parameter where it is, reported as at a bound
    empty = {k: EMPTY_RANGE for k in keys if not bounds[k][0] < bounds[k][1]}
    keys = tuple(k for k in keys if k not in empty)
    if not keys:
        return FitOutcome(screened[0][2], keys, screened[0][0], evaluations, bounds, empty)
    lo = np.array([bounds[k][0] for k in keys])
    hi = np.array([bounds[k][1] for k in keys])
    span = hi - lo
    inside = np.where(np.isfinite(span), 1e-9 * span, 1e-12)
    best: FitOutcome | None = None
    for _, _, start in screened[:max(1, refine)]:
        x0 = np.clip(np.clip(np.array([start[k] for k in keys]), lo, hi), lo + inside, hi - inside)
        scale = np.array([max(abs(v), 1e-3 * (s if math.isfinite(s) else 1.0))
                          for v, s in zip(x0, span, strict=True)])

        def fun(x: np.ndarray, start: dict[str, float] = start) -> np.ndarray:
            nonlocal evaluations
            evaluations += 1
            theta = dict(start)
            theta.update(zip(keys, x.tolist(), strict=True))
            return residual_vector(model, theta, mask, scales)

        solution = least_squares(fun, x0, bounds=(lo, hi), x_scale=scale, max_nfev=max(MAX_NFEV, 10 * len(keys)),
                                 method="trf", diff_step=1e-4)
        if best is not None and 2.0 * solution.cost >= best.cost:
            continue
        theta = dict(start)
        theta.update(zip(keys, solution.x.tolist(), strict=True))
        for effect in {effect_of_key(k) for k in keys if k not in NUISANCE_KEYS}:
            theta = effect.canonical(theta, model.rig.joint)
        at_bound = {**empty, **{k: side for k in keys
                                if (side := at_bound_of(k, theta[k], *bounds[k], theta0[k]))}}
        best = FitOutcome(theta, keys, float(2.0 * solution.cost), 0, bounds, at_bound, solution.jac)
    assert best is not None
    return FitOutcome(best.theta, keys, best.cost, evaluations, bounds, best.at_bound, best.jacobian)


def standard_errors(outcome: FitOutcome, dof_fraction: float) -> dict[str, float]:
    """Standard errors of the fitted keys [their units]: those the fit knows itself (``errors``), else from the
    Jacobian at the solution, the residual variance and the fraction of independent samples per residual
    ``dof_fraction`` (the filtered residual's samples are correlated): ``sqrt(diag((JᵀJ)⁻¹)·s²/dof_fraction)``."""
    if outcome.errors is not None:
        return outcome.errors
    jac = outcome.jacobian
    if jac is None or not outcome.keys:
        return {}
    m, p = jac.shape
    s2 = outcome.cost / max(m - p, 1)
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2 / max(dof_fraction, 1e-9)
    except np.linalg.LinAlgError:
        return {k: math.inf for k in outcome.keys}
    return {k: float(math.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(outcome.keys)}
