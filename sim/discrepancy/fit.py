"""Bounded least squares of chosen surrogate parameters on the fit part.

Problem (per fit)::

    minimise_x  Σ_c Σ_{k ∈ fit_c} ( r_c,k(θ(x)) / s_c )²      subject to  lo <= x <= hi

``r_c`` the residual channel ``c`` of :class:`~sim.discrepancy.model.Surrogate`, ``fit_c`` the fit-part samples
where it counts, decimated to the filter band; ``s_c`` the channel's baseline RMS on the fit part (so channels
in N·m and rad weigh alike); ``θ(x)`` the current parameters with the entries ``keys`` set to ``x``. Solved
with scipy's trust-region reflective ``least_squares``; a few starting points (grids over parameters the cost
is not convex in: cogging period, hysteresis span, delay, Stribeck velocity) are screened first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from sim.discrepancy.effects import EFFECTS, MAX_DELAY_S, canonical, effect_of_key
from sim.discrepancy.model import Surrogate

INERTIA_RANGE = (0.1, 10.0)  # re-fitted inertia within this factor of the baseline [1]
GAIN_RANGE = (0.1, 10.0)  # re-fitted effort gain [1]
KIN_OFFSET_BOUND_RAD = 0.1  # encoder offset between motor and lever angle [rad]
MAX_NFEV = 60  # function evaluations per least-squares refinement


@dataclass(frozen=True)
class FitOutcome:
    """A fit: the parameter vector after it, the cost, evaluations used."""

    theta: dict[str, float]
    keys: tuple[str, ...]
    cost: float
    evaluations: int

    def to_dict(self) -> dict:
        return {"parameters": {k: self.theta[k] for k in self.keys}, "cost": self.cost,
                "evaluations": self.evaluations}


def bounds_of(key: str, theta0: dict[str, float], surrogate: Surrogate, fitting: tuple[str, ...]) -> tuple[float, float]:
    """Valid range of theta entry ``key`` in a fit (physical range; Coulomb <= breakaway for the testbed; the
    hysteresis span at most a quarter of the load range)."""
    if key == "inertia":
        return INERTIA_RANGE[0] * theta0["inertia"], INERTIA_RANGE[1] * theta0["inertia"]
    if key == "effort_gain":
        return GAIN_RANGE
    if key == "kin_offset":
        return -KIN_OFFSET_BOUND_RAD, KIN_OFFSET_BOUND_RAD
    if key == "delay":
        return 0.0, MAX_DELAY_S
    p = next(p for p in effect_of_key(key).params if p.key == key)
    low, high = p.low, p.high
    if key == "coulomb" and "breakaway" not in fitting and surrogate.testbed:  # LuGre needs F_c <= F_s
        high = min(high, theta0["breakaway"])
    if key == "breakaway" and "coulomb" not in fitting:
        low = max(low, theta0["coulomb"])
    if key == "sensor_hysteresis_span":
        # Until the torque has moved 2S after a reversal, the loop H/S·(τ - p) rises like a sensor gain; with S at
        # half the load range or more it never leaves its start (a gain and an offset, not hysteresis). A quarter
        # of the range lets a full swing show the loop rise and then saturate.
        high = min(high, max(low, 0.25 * float(np.ptp(surrogate.transmitted(theta0)))))
    return low, high


def residual_vector(surrogate: Surrogate, theta: dict[str, float], mask: np.ndarray, scales: dict[str, float],
                    decimation: int) -> np.ndarray:
    """Stacked, scaled residuals of every channel on ``mask`` (decimated) [1]."""
    parts = []
    for channel, r in surrogate.residuals(theta).items():
        sel = r[mask][::decimation]
        # samples that do not count are zeros, not dropped: the vector keeps its length while the parameters
        # move the kinematic channel's contact set
        parts.append(np.where(np.isfinite(sel), sel, 0.0) / scales[channel])
    return np.concatenate(parts)


def fit_keys(surrogate: Surrogate, theta0: dict[str, float], keys: tuple[str, ...], scales: dict[str, float],
             starts: list[dict[str, float]] | None = None) -> FitOutcome:
    """Least squares of ``keys`` from the best of ``starts`` (each a partial theta) on the fit part."""
    data = surrogate.data
    decimation = data.decimation
    mask = data.fit
    evaluations = 0

    def cost_of(theta: dict[str, float]) -> float:
        nonlocal evaluations
        evaluations += 1
        r = residual_vector(surrogate, theta, mask, scales, decimation)
        return float(r @ r)

    best = dict(theta0)
    best_cost = cost_of(best)
    for start in starts or []:
        candidate = {**theta0, **start}
        c = cost_of(candidate)
        if c < best_cost:
            best, best_cost = candidate, c
    if not keys:
        return FitOutcome(best, keys, best_cost, evaluations)
    lo, hi = zip(*(bounds_of(k, theta0, surrogate, keys) for k in keys))
    lo, hi = np.array(lo), np.array(hi)
    x0 = np.clip(np.array([best[k] for k in keys]), lo, hi)
    span = hi - lo
    inside = np.where(np.isfinite(span), 1e-9 * span, 1e-12)
    x0 = np.clip(x0, lo + inside, hi - inside)
    scale = np.array([max(abs(v), 1e-3 * (s if math.isfinite(s) else 1.0)) for v, s in zip(x0, span, strict=True)])

    def fun(x: np.ndarray) -> np.ndarray:
        nonlocal evaluations
        evaluations += 1
        theta = dict(best)
        theta.update(zip(keys, x.tolist(), strict=True))
        return residual_vector(surrogate, theta, mask, scales, decimation)

    solution = least_squares(fun, x0, bounds=(lo, hi), x_scale=scale, max_nfev=MAX_NFEV, method="trf",
                             diff_step=1e-4)
    theta = dict(best)
    theta.update(zip(keys, solution.x.tolist(), strict=True))
    return FitOutcome(canonical(theta, surrogate.rig.joint), keys, float(2.0 * solution.cost), evaluations)


def effect_starts(name: str, theta: dict[str, float], surrogate: Surrogate) -> tuple[list[dict[str, float]], tuple[str, ...]]:
    """Starting points of an effect's fit and the keys held at the screened value (not refined).

    Linear sub-problems are solved directly (cogging: amplitude and phase for each period of a grid; gravity:
    ``A·sin(q - q0)`` is linear in ``A·cos q0`` and ``A·sin q0``); grids cover the rest.
    """
    data = surrogate.data
    spec = EFFECTS[name]
    if name == "cogging":
        return _cogging_starts(theta, surrogate), ("cogging_period",)
    if name == "gravity":
        r = surrogate.residuals(theta)["effort"]
        q = data.q if data.q is not None else data.position
        ok = data.fit & np.isfinite(r)
        if surrogate.rig.joint == "slide":
            return [{"gravity_amplitude": float(np.mean(-r[ok]))}], ("gravity_angle",)
        a = np.column_stack([np.sin(q[ok]), -np.cos(q[ok])])  # residual = -(A cos q0 sin q - A sin q0 cos q)
        coef, *_ = np.linalg.lstsq(a, -r[ok], rcond=None)
        amp = float(math.hypot(*coef))
        return [{"gravity_amplitude": amp, "gravity_angle": float(math.atan2(coef[1], coef[0]))}], ()
    if name == "transport_delay":
        return [{"delay": d} for d in np.arange(0.0, MAX_DELAY_S + 1e-12, 1e-3)], ()
    if name == "stribeck_friction":
        return [{"stribeck_velocity": theta["stribeck_velocity"] * f, "breakaway": theta["breakaway"] * g}
                for f in (0.3, 1.0, 3.0) for g in (1.0, 1.5, 2.0)], ()
    if name == "presliding_friction":
        return [{"presliding_stiffness": theta["presliding_stiffness"] * f} for f in (0.2, 0.5, 2.0, 5.0)], ()
    if name == "sensor_hysteresis":
        return [{"sensor_hysteresis_span": s, "sensor_hysteresis": h} for s in (0.25, 0.5, 1.0, 2.0, 4.0)
                for h in (-0.03, 0.03)], ()
    if name == "sensor_gain":
        return [{"sensor_gain": g} for g in (0.97, 1.03)], ()
    if name == "torque_constant_nonlinearity":
        return [{"torque_rolloff": c} for c in (-0.1, 0.1)], ()
    if name == "backlash":
        return [{"backlash_width": theta["backlash_width"] * f} for f in (0.3, 2.0)], ()
    starts = []
    for p in spec.params:  # a small step each way from the current value
        v = theta[p.key]
        step = max(abs(v) * 0.3, 0.01 * (p.high - p.low) if math.isfinite(p.high - p.low) else 0.01)
        starts += [{p.key: min(max(v + s, p.low), p.high)} for s in (-step, step)]
    return starts, ()


def _cogging_starts(theta: dict[str, float], surrogate: Surrogate) -> list[dict[str, float]]:
    data = surrogate.data
    r = surrogate.residuals(theta)["effort"]
    ok = data.fit & np.isfinite(r)
    span = float(np.ptp(data.position[ok])) if ok.any() else 0.0
    periods = candidate_periods(surrogate, span)
    best: tuple[float, dict[str, float]] | None = None
    for period in periods:
        phase = 2.0 * math.pi * data.position / period
        a = np.column_stack([data.filt(np.sin(phase))[ok], data.filt(np.cos(phase))[ok]])
        coef, *_ = np.linalg.lstsq(a, -r[ok], rcond=None)  # residual + cogging = 0
        explained = float(np.sum((a @ coef) ** 2))
        if best is None or explained > best[0]:
            amp = float(math.hypot(*coef))
            best = (explained, {"cogging_amplitude": amp, "cogging_period": float(period),
                                "cogging_phase": float(math.atan2(coef[1], coef[0]))})
    return [best[1]] if best else []


MIN_PERIODS_IN_RANGE = 3  # a cogging period must fit at least 3 times in the position range to be fitted
MAX_POLES = 60  # testbed: pole counts tried, 1..60
RIGID_PERIOD_GRID = 300  # rigid joint: log-spaced periods tried


def candidate_periods(surrogate: Surrogate, position_span: float) -> np.ndarray:
    """Cogging periods the log can reveal [rad | m]: 2π/(N·poles) for the testbed, a grid for a rigid joint."""
    if surrogate.testbed:
        n = surrogate.const["gear_ratio"]
        periods = 2.0 * math.pi / (n * np.arange(1, MAX_POLES + 1))
    else:
        resolution = max(surrogate.data.position_resolution, 1e-9)
        periods = np.geomspace(max(20 * resolution, 1e-6), max(position_span, 1e-6), RIGID_PERIOD_GRID)
    return periods[periods * MIN_PERIODS_IN_RANGE <= position_span]
