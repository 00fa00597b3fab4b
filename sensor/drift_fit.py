"""Temperature zero-drift models of the torque output (paper Sec. III-C, Eq. 20).

The paper measured the zero-torque output at chamber set points -10 ... 50 degC (20 min each) against
the on-board TMP117 temperature, and compensated it with a five-constant rational function (Eq. 20)::

    tau_drift(t) = (a1 t^2 + a2 t + a3) / (a4 t^2 + a5 t + 1)          t [degC], tau [N m]

which "provided the best fit among the tested candidates (e.g. a fourth-order polynomial and
Gaussian models)". Those two candidates are implemented with the forms::

    poly4:     tau_drift(t) = c0 + c1 t + c2 t^2 + c3 t^3 + c4 t^4
    gaussian:  tau_drift(t) = a exp(-((t - b) / c)^2) + d

The Gaussian form is MATLAB's ``gauss1`` (``a1 exp(-((x - b1) / c1)^2)``, the likely tool, since the
paper used MATLAB) plus a constant offset ``d``, without which a zero drift that does not return to 0
at the ends of the range cannot be fitted at all. The paper does not say which Gaussian it used.

Fits minimise the sum of squared errors over the given points: linear least squares for the
polynomial; for the rational function over the constants whose denominator has no root on the data's
temperature range (a pole there would sit inside the range the compensation is used on), by
``scipy.optimize.least_squares`` in a parametrisation that keeps the denominator positive on the range,
from several starts (:func:`fit_rational_drift`); the Gaussian by ``least_squares`` from a few heuristic
starts. A rational fit no better than its numerator alone (a quadratic) is rejected
(:class:`DriftFitError`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.optimize

__all__ = [
    "DriftFit",
    "DriftFitError",
    "DriftModelComparison",
    "compare_drift_models",
    "fit_gaussian_drift",
    "fit_poly4_drift",
    "fit_rational_drift",
]

ModelName = Literal["rational", "poly4", "gaussian"]

N_PARAMS = {"rational": 5, "poly4": 5, "gaussian": 4}
"""Free constants per model (Eq. 20 has five)."""

LSQ_TOL = 1e-15
"""ftol = xtol = gtol of ``scipy.optimize.least_squares`` (near machine precision: the fits are
tiny, and a recovered constant should be limited by the data, not by the stopping rule)."""

LSQ_MAX_NFEV = 20_000
"""Function-evaluation cap for ``least_squares``."""

POLE_FREE_FLOOR = 1e-3
"""epsilon of the pole-free denominator family (:func:`fit_rational_drift`) [-]: on the data range the
denominator's smallest value is at least ``epsilon / (2 + epsilon)`` (about 1/2000) of its largest, which keeps a
pole (and the numerator root that nearly cancels it) out of the range by a margin."""

POLE_FREE_GRID = (16, 32)
"""Points of the search grid over the pole-free denominators (the angles phi in [0, pi/2], psi in [0, pi))."""

POLE_FREE_STARTS = 4
"""Best grid points refined by ``least_squares`` (besides the quadratic)."""

IMPROVEMENT_FLOOR = 1e-12
"""Smallest RMS improvement over the quadratic fallback that counts as better, relative to ``max |drift|``
(the rounding of the fitted values; below it the two fits are the same)."""


class DriftFitError(ValueError):
    """A drift model could not be fitted acceptably (e.g. a rational fit no better than a quadratic)."""


def _rational(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    a1, a2, a3, a4, a5 = p
    return (a1 * t * t + a2 * t + a3) / (a4 * t * t + a5 * t + 1.0)


def _poly4(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.polynomial.polynomial.polyval(t, p)


def _gaussian(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b, c, d = p
    return a * np.exp(-(((t - b) / c) ** 2)) + d


_EVAL = {"rational": _rational, "poly4": _poly4, "gaussian": _gaussian}
_NAMES = {"rational": ("a1", "a2", "a3", "a4", "a5"),
          "poly4": ("c0", "c1", "c2", "c3", "c4"),
          "gaussian": ("a", "b", "c", "d")}
_UNITS = {"rational": ("N m/degC^2", "N m/degC", "N m", "1/degC^2", "1/degC"),
          "poly4": ("N m", "N m/degC", "N m/degC^2", "N m/degC^3", "N m/degC^4"),
          "gaussian": ("N m", "degC", "degC", "N m")}


@dataclass(frozen=True, eq=False)
class DriftFit:
    """A fitted zero-drift model ``tau_drift(t)``.

    Attributes
    ----------
    model : {"rational", "poly4", "gaussian"}
        Form (module docstring).
    coefficients : tuple of float
        In the order of ``coefficient_names``; units in ``coefficient_units``.
    coefficient_names : tuple of str
    coefficient_units : tuple of str
    rmse_nm : float
        ``sqrt(mean((tau_drift(t_k) - drift_k)^2))`` over the fitted points [N m].
    max_abs_error_nm : float
        ``max_k |tau_drift(t_k) - drift_k|`` [N m].
    n_points : int
    t_range_c : tuple of float
        (min, max) temperature of the data [degC]; the model is validated only there.
    """

    model: ModelName
    coefficients: tuple[float, ...]
    coefficient_names: tuple[str, ...]
    coefficient_units: tuple[str, ...]
    rmse_nm: float
    max_abs_error_nm: float
    n_points: int
    t_range_c: tuple[float, float]
    _p: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "_p", np.array(self.coefficients, dtype=float))

    def predict(self, t_c: np.ndarray | float) -> np.ndarray:
        """Drift [N m] at temperature(s) ``t_c`` [degC]."""
        return _EVAL[self.model](self._p, np.asarray(t_c, dtype=float))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        names = self.coefficient_names
        return {"model": self.model,
                "coefficients": dict(zip(names, self.coefficients, strict=True)),
                "coefficient_units": dict(zip(names, self.coefficient_units, strict=True)),
                "rmse_nm": self.rmse_nm, "max_abs_error_nm": self.max_abs_error_nm,
                "n_points": self.n_points, "t_range_c": list(self.t_range_c)}


def _check(t_c, drift_nm, model: ModelName) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_c, dtype=float)
    y = np.asarray(drift_nm, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"t_c must have shape (N,) [degC]; got shape {t.shape}")
    if y.shape != t.shape:
        raise ValueError(f"drift_nm must have the shape of t_c {t.shape}; got shape {y.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise ValueError("t_c and drift_nm must be finite")
    k = N_PARAMS[model]
    n_distinct = np.unique(t).size
    if n_distinct < k:
        raise ValueError(f"the {model} model has {k} constants; it needs at least {k} distinct "
                         f"temperatures, got {n_distinct}")
    return t, y


def _result(model: ModelName, p: np.ndarray, t: np.ndarray, y: np.ndarray) -> DriftFit:
    r = _EVAL[model](p, t) - y
    return DriftFit(model=model, coefficients=tuple(float(x) for x in p),
                    coefficient_names=_NAMES[model], coefficient_units=_UNITS[model],
                    rmse_nm=math.sqrt(float(np.mean(r * r))),
                    max_abs_error_nm=float(np.max(np.abs(r))), n_points=t.size,
                    t_range_c=(float(t.min()), float(t.max())))


def _lstsq_scaled(m: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    scale = np.linalg.norm(m, axis=0)
    scale[scale == 0] = 1.0
    return np.linalg.lstsq(m / scale, rhs, rcond=None)[0] / scale


def _denominator_roots_in_range(a4: float, a5: float, lo: float, hi: float) -> list[float]:
    """Real roots of ``a4 t^2 + a5 t + 1`` in [lo, hi]."""
    coeffs = np.array([a4, a5, 1.0])
    coeffs = np.trim_zeros(coeffs, "f")
    if coeffs.size < 2:
        return []
    roots = np.roots(coeffs)
    real = roots[np.abs(roots.imag) <= 1e-12 * np.maximum(1.0, np.abs(roots))].real
    return sorted(float(x) for x in real if lo <= x <= hi)


def _unit_vector(theta: np.ndarray) -> tuple[float, float, float]:
    """(alpha, beta, delta) on the unit sphere from the angles (phi, psi) [rad]."""
    phi, psi = theta
    return math.sin(phi) * math.cos(psi), math.sin(phi) * math.sin(psi), math.cos(phi)


def _pole_free_denominator(theta: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``d(s) = (alpha + beta s)^2 + delta^2 (1 - s^2) + epsilon`` and its derivatives in (phi, psi)."""
    phi, psi = theta
    alpha, beta, delta = _unit_vector(theta)
    u = alpha + beta * s
    w = 1.0 - s * s
    d = u * u + delta * delta * w + POLE_FREE_FLOOR
    d_phi = 2.0 * u * (math.cos(phi) * (math.cos(psi) + math.sin(psi) * s)) - 2.0 * delta * math.sin(phi) * w
    d_psi = 2.0 * u * (math.sin(phi) * (math.cos(psi) * s - math.sin(psi)))
    return d, d_phi, d_psi


def _pole_free_numerator(theta: np.ndarray, s: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares numerator ``(n0, n1, n2)`` of ``n0 + n1 s + n2 s^2`` for the denominator of ``theta``
    (a linear problem), and its sum of squared errors."""
    basis = np.column_stack([np.ones_like(s), s, s * s]) / _pole_free_denominator(theta, s)[0][:, None]
    n = _lstsq_scaled(basis, y)
    r = basis @ n - y
    return n, float(r @ r)


def _pole_free_refine(x0: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``least_squares`` over x = (n0, n1, n2, phi, psi) of ``N(s) / d(s) - drift``."""
    powers = np.column_stack([np.ones_like(s), s, s * s])

    def resid(x):
        return powers @ x[:3] / _pole_free_denominator(x[3:], s)[0] - y

    def jac(x):
        d, d_phi, d_psi = _pole_free_denominator(x[3:], s)
        q = -(powers @ x[:3]) / (d * d)
        return np.column_stack([powers / d[:, None], q * d_phi, q * d_psi])

    return scipy.optimize.least_squares(resid, x0, jac=jac, method="lm", x_scale="jac", ftol=LSQ_TOL,
                                        xtol=LSQ_TOL, gtol=LSQ_TOL, max_nfev=LSQ_MAX_NFEV).x


def _eq20_from_scaled(x: np.ndarray, centre: float, half_width: float) -> np.ndarray | None:
    """Eq. 20 constants (a1..a5) of ``N(s) / d(s)``, ``s = (t - centre) / half_width``; None if the
    denominator is 0 at t = 0, where Eq. 20 fixes it at 1."""
    alpha, beta, delta = _unit_vector(x[3:])
    to_t = np.polynomial.Polynomial([-centre / half_width, 1.0 / half_width])
    num = np.zeros(3)
    den = np.zeros(3)
    coef = np.polynomial.Polynomial(x[:3])(to_t).coef
    num[:coef.size] = coef
    coef = np.polynomial.Polynomial([alpha * alpha + delta * delta + POLE_FREE_FLOOR, 2.0 * alpha * beta,
                                     beta * beta - delta * delta])(to_t).coef
    den[:coef.size] = coef
    if not (np.isfinite(den[0]) and abs(den[0]) > np.finfo(float).eps * np.max(np.abs(den))):
        return None
    return np.array([num[2], num[1], num[0], den[2], den[1]]) / den[0]


def _pole_free_candidates(t: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
    """Eq. 20 constants refined from the quadratic and the best points of a grid over the pole-free
    denominators (fit_rational_drift)."""
    centre, half_width = 0.5 * (t.max() + t.min()), 0.5 * (t.max() - t.min())
    s = (t - centre) / half_width
    n_phi, n_psi = POLE_FREE_GRID
    grid = [np.array([(i + 0.5) * 0.5 * math.pi / n_phi, j * math.pi / n_psi])
            for i in range(n_phi) for j in range(n_psi)]
    cost = [_pole_free_numerator(theta, s, y)[1] for theta in grid]
    quadratic = np.array([0.25 * math.pi, 0.5 * math.pi])  # alpha = 0, beta = delta: d = 1/2 + epsilon
    starts = [quadratic] + [grid[k] for k in np.argsort(cost)[:POLE_FREE_STARTS]]
    out = []
    for theta in starts:
        x = _pole_free_refine(np.r_[_pole_free_numerator(theta, s, y)[0], theta], s, y)
        p = _eq20_from_scaled(x, centre, half_width)
        if p is not None:
            out.append(p)
    return out


def fit_rational_drift(t_c: np.ndarray, drift_nm: np.ndarray) -> DriftFit:
    """Fit Eq. 20, ``(a1 t^2 + a2 t + a3) / (a4 t^2 + a5 t + 1)``, by least squares without a pole on the
    data's temperature range.

    Minimises ``sum_k (tau_drift(t_k; a) - drift_k)^2`` over the constants whose denominator has no root in
    [min t, max t]. With ``s = (t - centre) / half-width`` in [-1, 1], every quadratic nonnegative on
    [-1, 1] is ``(alpha + beta s)^2 + delta^2 (1 - s^2)`` (Lukacs's theorem). The fit's denominator is that
    plus ``epsilon`` (:data:`POLE_FREE_FLOOR`), with (alpha, beta, delta) on the unit sphere at angles
    (phi, psi): positive on the range for every (phi, psi), so ``least_squares`` over the numerator's three
    constants and (phi, psi) needs no constraint. For a fixed denominator the numerator is a linear least
    squares problem; the refinement starts from the quadratic (a4 = a5 = 0) and from the
    :data:`POLE_FREE_STARTS` best of a :data:`POLE_FREE_GRID` grid of (phi, psi), each with its
    least-squares numerator, and the best result is kept (converted to Eq. 20's constants in t). A pole
    and a nearly cancelling numerator root outside the range are kept: the fit is used on the range.

    Acceptance: the quadratic ``c2 t^2 + c1 t + c0`` (Eq. 20's numerator alone, linear least squares) is the
    fallback. The best pole-free fit is returned if its RMS error is below the quadratic's by more than
    :data:`IMPROVEMENT_FLOOR` x ``max |drift|``; otherwise the denominator adds nothing and the fit is rejected.

    Parameters
    ----------
    t_c : numpy.ndarray, shape (N,)
        Temperature [degC] (on-board sensor), at least 5 distinct values.
    drift_nm : numpy.ndarray, shape (N,)
        Zero-torque output [N m].

    Raises
    ------
    DriftFitError
        If no pole-free fit is better than the quadratic; the message gives both RMS errors [N m].
    """
    t, y = _check(t_c, drift_nm, "rational")
    lo, hi = float(t.min()), float(t.max())
    best, best_sse = None, math.inf
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for p in _pole_free_candidates(t, y):
            r = _rational(p, t) - y
            sse = float(r @ r)
            if np.isfinite(sse) and sse < best_sse and not _denominator_roots_in_range(p[3], p[4], lo, hi):
                best, best_sse = p, sse
    quadratic = np.polynomial.Polynomial.fit(t, y, 2)
    rms_quadratic = math.sqrt(float(np.mean((quadratic(t) - y) ** 2)))
    rms = math.sqrt(best_sse / t.size)
    if best is None or not rms < rms_quadratic - IMPROVEMENT_FLOOR * float(np.max(np.abs(y))):
        raise DriftFitError(
            f"rational drift fit rejected: the best Eq. 20 fit without a pole in [{lo:g}, {hi:g}] degC "
            f"(RMS {rms:.6g} N m) is no better than its numerator alone, the quadratic (RMS {rms_quadratic:.6g} "
            f"N m; difference {rms_quadratic - rms:.3g} N m)")
    return _result("rational", best, t, y)


def fit_poly4_drift(t_c: np.ndarray, drift_nm: np.ndarray) -> DriftFit:
    """Fit ``c0 + c1 t + c2 t^2 + c3 t^3 + c4 t^4`` by linear least squares.

    Solved on the temperature mapped to [-1, 1] (``numpy.polynomial.Polynomial.fit``) and converted
    back to coefficients of ``t`` [degC].
    """
    t, y = _check(t_c, drift_nm, "poly4")
    poly = np.polynomial.Polynomial.fit(t, y, 4).convert()
    p = np.zeros(5)
    p[:poly.coef.size] = poly.coef
    return _result("poly4", p, t, y)


def fit_gaussian_drift(t_c: np.ndarray, drift_nm: np.ndarray) -> DriftFit:
    """Fit ``a exp(-((t - b) / c)^2) + d`` by nonlinear least squares.

    Started from three guesses (offset = mean of the end values, the minimum, the maximum; peak at
    the largest deviation from it; width = half the temperature span); the best fit is kept and
    ``c`` is reported positive.
    """
    t, y = _check(t_c, drift_nm, "gaussian")
    order = np.argsort(t)
    ts, ys = t[order], y[order]
    span = float(ts[-1] - ts[0])

    def resid(p):
        return _gaussian(p, t) - y

    best, best_cost = None, math.inf
    for d0 in (0.5 * (ys[0] + ys[-1]), float(ys.min()), float(ys.max())):
        k = int(np.argmax(np.abs(ys - d0)))
        p0 = np.array([ys[k] - d0, ts[k], 0.5 * span, d0])
        if p0[0] == 0.0:
            p0[0] = 1e-12
        sol = scipy.optimize.least_squares(resid, p0, x_scale="jac", ftol=LSQ_TOL, xtol=LSQ_TOL,
                                           gtol=LSQ_TOL, max_nfev=LSQ_MAX_NFEV)
        cost = float(np.sum(sol.fun ** 2))
        if np.isfinite(cost) and cost < best_cost:
            best, best_cost = sol.x, cost
    if best is None:
        raise DriftFitError("Gaussian drift fit failed from every start")
    best = best.copy()
    best[2] = abs(best[2])
    return _result("gaussian", best, t, y)


_FITTERS = {"rational": fit_rational_drift, "poly4": fit_poly4_drift,
            "gaussian": fit_gaussian_drift}


@dataclass(frozen=True)
class DriftModelComparison:
    """The three candidate models fitted to the same data (Sec. III-C).

    Attributes
    ----------
    fits : dict
        Model name -> :class:`DriftFit`, for the models that could be fitted.
    failures : dict
        Model name -> error message, for those that could not (e.g. a rational fit no better than a quadratic).
    ranking : tuple of str
        Fitted models by ascending ``rmse_nm``.
    best : str
        ``ranking[0]``.

    Notes
    -----
    Ranked by fit RMSE on the fitted points, as the paper compares them; the Gaussian has one
    constant fewer than the other two, and an in-sample RMSE favours more flexible models.
    """

    fits: dict[str, DriftFit]
    failures: dict[str, str]
    ranking: tuple[str, ...]
    best: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {"fits": {k: f.to_dict() for k, f in self.fits.items()},
                "failures": dict(self.failures), "ranking": list(self.ranking), "best": self.best}


def compare_drift_models(t_c: np.ndarray, drift_nm: np.ndarray) -> DriftModelComparison:
    """Fit the rational (Eq. 20), 4th-order polynomial and Gaussian drift models and rank them by
    fit RMSE [N m].

    Raises
    ------
    DriftFitError
        If none of the three could be fitted.
    """
    fits: dict[str, DriftFit] = {}
    failures: dict[str, str] = {}
    for name, fitter in _FITTERS.items():
        try:
            fits[name] = fitter(t_c, drift_nm)
        except DriftFitError as exc:
            failures[name] = str(exc)
    if not fits:
        raise DriftFitError("no drift model could be fitted: " + "; ".join(failures.values()))
    ranking = tuple(sorted(fits, key=lambda k: fits[k].rmse_nm))
    return DriftModelComparison(fits=fits, failures=failures, ranking=ranking, best=ranking[0])
