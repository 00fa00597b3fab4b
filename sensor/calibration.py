"""Calibration of the photo-reflector array: eight channel voltages to joint torque.

Paper: Sec. III-A "Calibration Method and Experiment", Eqs. 10-17.

The calibration map is a per-channel cubic in the channel voltages (Eq. 10)::

    tau_hat = A @ theta,   A = [x**3, x**2, x, 1]   (N x 25),   x = [V_1 ... V_8]  [V]

with ``theta`` (25,) the "calibration matrix". Two ways to obtain ``theta``:

* :func:`fit_least_squares` -- the conventional fit (Eq. 11)::

      minimize_theta  ||A theta - y||_2^2

* :func:`fit_qp` -- the paper's quiet-segment-penalised, error-bounded fit (Eq. 17)::

      minimize_theta  ||A theta - y||_2^2 + gamma * ||A_0c theta||_2^2
      subject to      |A theta - y| <= e_max        (element-wise, all N rows)

  where ``A_0c = A_0 - 1 mu^T`` is the design matrix restricted to the quiet segment ``I_0`` and
  centred by its column means ``mu`` (Eqs. 12-13), so ``||A_0c theta||^2 = |I_0| * Var(tau_hat on I_0)``.

``y`` is the reference torque [N m] (ATI MINI85 in the paper), ``gamma`` [-] weighs the noise penalty
and ``e_max`` [N m] bounds every sample's error (Eq. 14: 0.2 % FS).

Numerics (what the paper, which used MATLAB ``lsqlin`` on all 2N constraints, does not need to say)
------------------------------------------------------------------------------------------------------
Both fits go to the constrained least-squares engine :mod:`sensor.constrained_lsq` (streamed QR, exact cutting
plane over the 2N rows, ProxQP subproblems, minimax LP for infeasible bounds), with the design given as a rule
(:class:`ChannelCubics`) rather than an N x 25 array. Cubes of volts make ``A`` badly scaled and the eight
channels are nearly collinear (all follow the same torque): the engine works in the basis
``u = (x - mid) / half_range`` in [-1, 1] of every channel (an invertible change of the column basis,
``B = A T``, ``theta = T phi``), and in the conditioning of ``B``, not of ``B^T B``. A row counts as violating
the bound when it exceeds ``e_max`` by more than ``feasibility_tol_nm = 1e-9 FS``.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from sensor import constrained_lsq as lsq
from sim.params import PhotoReflectorParams

__all__ = [
    "N_CHANNELS",
    "N_COEFFICIENTS",
    "E_MAX_FRACTION_FS",
    "E_MAX_NM",
    "QUIET_TAU_THRESHOLD_NM",
    "FEASIBILITY_TOL_FRACTION_FS",
    "DEFAULT_GAMMA_GRID",
    "DEFAULT_LAMBDA_WEIGHT",
    "MAX_GAMMA",
    "Calibration",
    "SolveDiagnostics",
    "GammaSelection",
    "InfeasibleCalibrationError",
    "ChannelCubics",
    "design_matrix",
    "fit_least_squares",
    "fit_qp",
    "quiet_segment_mask",
    "select_gamma",
    "smallest_feasible_e_max",
]

# --- Constants from the paper -------------------------------------------------------------------
N_CHANNELS = 8
"""Photo-reflector channels; Sec. III-A: ``x = [V_1 ... V_8]``."""

N_COEFFICIENTS = 3 * N_CHANNELS + 1
"""Columns of the design matrix; Sec. III-A, Eq. 10: ``A = [x^3 x^2 x 1]`` is N x 25."""

E_MAX_FRACTION_FS = 0.002
"""Error bound as a fraction of full scale; Eq. 14: ``e_max = 0.002 * FS``."""

_FS_NM = PhotoReflectorParams().full_scale_nm
"""Default full scale [N m]: ``photoreflector.full_scale_nm`` of the default parameters (80 N m, Sec. III-B)."""

E_MAX_NM = E_MAX_FRACTION_FS * _FS_NM
"""Default error bound [N m] = 0.16 N m (Eq. 14 with the default FS = 80 N m)."""

# --- Our choices (the paper gives no value) ---------------------------------------------------------
QUIET_TAU_THRESHOLD_NM = 0.05
"""Default quiet-segment threshold tau_th [N m]. Paper (after Eq. 17) names the rule |tau| <= tau_th
but no value; ours is about 5 counts of the MINI85 reference resolution 7/748 N m (Sec. III-A)."""

FEASIBILITY_TOL_FRACTION_FS = 1e-9
"""A row counts as violating the bound when ``|a_k theta - y_k| > e_max + 1e-9 * FS`` (our choice:
far below any physical resolution, well above the float64 rounding of a prediction)."""

DEFAULT_GAMMA_GRID = np.logspace(-2.0, 4.0, 13)
"""Logarithmic gamma grid [-] for :func:`select_gamma` (paper: "a logarithmic grid", no values)."""

DEFAULT_LAMBDA_WEIGHT = 1.0
"""Weight lambda [-] of the quiet-segment variance in the gamma criterion (paper: no value; 1.0
weighs the two squared torques [N^2 m^2] equally)."""

MAX_GAMMA = 1e6
"""Largest accepted ``gamma``, 100x below the smallest at which a feasible problem failed. A large penalty
outweighs the data term so far that the small QPs lose the accuracy the cutting plane relies on: at 1e10-1e20
feasible problems stalled or were called incompatible, and at 1e8 one of 480 fits stalled with a bound
1.0001x the smallest feasible one and 16 candidate rows; every fit up to 1e7 of those
and of 432 others (N = 300-3000, bounds 1.0001x the smallest to 0.2 % FS, both ways of checking rows) met
the bound. The paper's grid ends at 1e4."""

MIN_QUIET_SAMPLES = N_COEFFICIENTS + 1
"""Fewest quiet-segment samples accepted: the centred quiet block must be able to span all 24
non-constant directions of ``A`` (24 + 1 for the centring + 1 spare)."""

PREDICT_CHUNK_ROWS = 8_192
"""Rows per chunk when evaluating ``A theta`` (the Horner temporaries stay in cache)."""


class InfeasibleCalibrationError(ValueError):
    """No ``theta`` satisfies ``|A theta - y| <= e_max`` on every sample.

    Attributes
    ----------
    e_max_nm : float
        The bound that was asked for [N m].
    smallest_feasible_e_max_nm : float
        ``min_theta max_k |a_k theta - y_k|`` [N m] (the minimax LP value): any ``e_max`` at or above
        it is feasible.
    """

    def __init__(self, e_max_nm: float, smallest_feasible_e_max_nm: float, n_samples: int,
                 fs_nm: float):
        self.e_max_nm = float(e_max_nm)
        self.smallest_feasible_e_max_nm = float(smallest_feasible_e_max_nm)
        self.n_samples = int(n_samples)
        self.fs_nm = float(fs_nm)
        super().__init__(
            f"QP calibration is infeasible: no theta satisfies |A theta - y| <= e_max = "
            f"{e_max_nm:.6g} N m ({100 * e_max_nm / fs_nm:.4g} % FS) on all {n_samples} samples; "
            f"the smallest feasible e_max is {smallest_feasible_e_max_nm:.6g} N m "
            f"({100 * smallest_feasible_e_max_nm / fs_nm:.4g} % FS), from the LP "
            f"min t s.t. |A theta - y| <= t (HiGHS)."
        )

    def __reduce__(self):
        """Rebuilt from its fields, so the error crosses process boundaries (a worker's calibration)."""
        return type(self), (self.e_max_nm, self.smallest_feasible_e_max_nm, self.n_samples, self.fs_nm)


@dataclass(frozen=True)
class SolveDiagnostics:
    """How a calibration was solved and how well it fits its own data.

    Attributes
    ----------
    solver : str
        The factorisation (``"tsqr"``: Householder, or ``"sketched-cholqr"``: randomly
        preconditioned Cholesky QR, for N >= 65 536), prefixed by ``"cutting-plane+proxqp on"``
        for a QP with a bound or a penalty (``fit_qp`` with ``gamma = 0`` and ``e_max = inf`` is least squares);
        the count of exact LDP fallback solves is appended if there were any.
    iterations : int
        Solves performed (1 = the unconstrained solution already met the bound).
    n_working_constraints : int
        Rows in the final working set (of the 2N in Eq. 16).
    n_active_constraints : int
        Rows with ``|a_k theta - y_k| >= e_max - feasibility_tol_nm`` at the solution.
    residual_max_nm : float
        ``max_k |a_k theta - y_k|`` [N m].
    rms_error_nm : float
        ``sqrt(mean((A theta - y)^2))`` [N m].
    quiet_std_nm : float or None
        Population std of ``tau_hat`` on the quiet segment [N m] (None without a quiet segment).
    objective_nm2 : float
        ``||A theta - y||^2 + gamma ||A_0c theta||^2`` [N^2 m^2] (gamma = 0 for least squares).
    feasibility_tol_nm : float
        Tolerance of the bound check [N m].
    full_passes : int
        Evaluations of ``A theta - y`` on all N rows (the QP checks a candidate subset in between).
    solve_time_s : float
        Wall time of the fit [s]. Kept for benchmarks and printing only: it differs from run to run, so it
        is left out of comparisons (``==``) and of :meth:`to_dict` (the same seed gives the same JSON).
    """

    solver: str
    iterations: int
    n_working_constraints: int
    n_active_constraints: int
    residual_max_nm: float
    rms_error_nm: float
    quiet_std_nm: float | None
    objective_nm2: float
    feasibility_tol_nm: float
    full_passes: int = 1
    solve_time_s: float = field(default=math.nan, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary of the deterministic fields (everything but ``solve_time_s``)."""
        d = asdict(self)
        del d["solve_time_s"]
        return d


@dataclass(frozen=True, eq=False)
class Calibration:
    """A fitted calibration ``tau_hat = A theta`` (Eq. 10).

    Attributes
    ----------
    theta : numpy.ndarray, shape (25,)
        Coefficients in the column order of :func:`design_matrix`: ``theta[0:8]`` multiply
        ``V_k^3`` [N m / V^3], ``theta[8:16]`` multiply ``V_k^2`` [N m / V^2], ``theta[16:24]``
        multiply ``V_k`` [N m / V], ``theta[24]`` is the offset [N m]. Read-only.
    method : {"ls", "qp"}
        Eq. 11 or Eq. 17.
    gamma : float
        Quiet-segment penalty weight [-] (0 for ``"ls"``).
    e_max_nm : float or None
        Error bound [N m] (None for ``"ls"``).
    fs_nm : float
        Full scale used for tolerances [N m].
    n_samples : int
        Calibration samples N.
    n_quiet : int
        Quiet-segment samples |I_0| (0 for ``"ls"`` fitted without a quiet mask).
    diagnostics : SolveDiagnostics
        Solver record.
    """

    theta: np.ndarray
    method: Literal["ls", "qp"]
    gamma: float
    e_max_nm: float | None
    fs_nm: float
    n_samples: int
    n_quiet: int
    diagnostics: SolveDiagnostics = field(repr=False)

    def __post_init__(self):
        theta = np.array(self.theta, dtype=float)  # private copy
        if theta.shape != (N_COEFFICIENTS,):
            raise ValueError(f"theta must have shape ({N_COEFFICIENTS},); got {theta.shape}")
        theta.setflags(write=False)
        object.__setattr__(self, "theta", theta)

    def predict(self, v: np.ndarray) -> np.ndarray:
        """Torque estimate ``tau_hat = A(v) theta`` [N m], shape (N,), for voltages ``v`` (N, 8) [V].

        Evaluated per channel by Horner's rule, without forming ``A``.
        """
        v = _check_voltages(v)
        return _predict(v, self.theta)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (lists and floats); inverse of :meth:`from_dict`."""
        return {
            "theta": self.theta.tolist(),
            "theta_columns": _column_names(),
            "method": self.method,
            "gamma": self.gamma,
            "e_max_nm": self.e_max_nm,
            "fs_nm": self.fs_nm,
            "n_samples": self.n_samples,
            "n_quiet": self.n_quiet,
            "diagnostics": self.diagnostics.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Calibration:
        """Rebuild a :class:`Calibration` from :meth:`to_dict` output (``diagnostics.solve_time_s`` is NaN:
        wall times are not serialised; a dictionary that still carries one keeps it)."""
        return cls(theta=np.asarray(d["theta"], dtype=float), method=d["method"],
                   gamma=float(d["gamma"]),
                   e_max_nm=None if d["e_max_nm"] is None else float(d["e_max_nm"]),
                   fs_nm=float(d["fs_nm"]), n_samples=int(d["n_samples"]),
                   n_quiet=int(d["n_quiet"]), diagnostics=SolveDiagnostics(**d["diagnostics"]))


@dataclass(frozen=True, eq=False)
class GammaSelection:
    """Result of :func:`select_gamma`.

    Attributes
    ----------
    gammas : numpy.ndarray, shape (G,)
        The grid [-], ascending.
    criterion_nm2 : numpy.ndarray, shape (G,)
        ``RMSE(tau_hat, tau)^2 + lambda * Var(tau_hat on I_0)`` [N^2 m^2] per gamma.
    rmse_nm : numpy.ndarray, shape (G,)
        RMSE over all calibration samples [N m].
    quiet_var_nm2 : numpy.ndarray, shape (G,)
        Population variance of ``tau_hat`` on the quiet segment [N^2 m^2].
    lambda_weight : float
        lambda [-].
    best_index : int
        Index of the chosen gamma (first minimiser).
    gamma : float
        The chosen gamma.
    calibration : Calibration
        The QP calibration at the chosen gamma (its ``diagnostics.solve_time_s`` counts that
        gamma's cutting plane only; the factorisation is shared by the grid).
    """

    gammas: np.ndarray
    criterion_nm2: np.ndarray
    rmse_nm: np.ndarray
    quiet_var_nm2: np.ndarray
    lambda_weight: float
    best_index: int
    gamma: float
    calibration: Calibration

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {"gammas": self.gammas.tolist(), "criterion_nm2": self.criterion_nm2.tolist(),
                "rmse_nm": self.rmse_nm.tolist(), "quiet_var_nm2": self.quiet_var_nm2.tolist(),
                "lambda_weight": self.lambda_weight, "best_index": self.best_index,
                "gamma": self.gamma, "calibration": self.calibration.to_dict()}


# --- Input checks ---------------------------------------------------------------------------------
def _column_names() -> list[str]:
    ch = range(1, N_CHANNELS + 1)
    return ([f"V{k}^3" for k in ch] + [f"V{k}^2" for k in ch] + [f"V{k}" for k in ch] + ["1"])


def _check_voltages(v: Any, name: str = "v") -> np.ndarray:
    arr = np.asarray(v, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != N_CHANNELS:
        raise ValueError(f"{name} must have shape (N, {N_CHANNELS}) [V] (one column per "
                         f"photo-reflector channel); got shape {np.shape(v)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _check_fit_inputs(v: Any, tau_ref: Any) -> tuple[np.ndarray, np.ndarray]:
    v = _check_voltages(v)
    y = np.asarray(tau_ref, dtype=float)
    if y.ndim != 1 or y.shape[0] != v.shape[0]:
        raise ValueError(f"tau_ref must have shape (N,) = ({v.shape[0]},) to match v "
                         f"{v.shape}; got shape {np.shape(tau_ref)}")
    if not np.all(np.isfinite(y)):
        raise ValueError("tau_ref contains NaN or inf")
    if v.shape[0] <= N_COEFFICIENTS:
        raise ValueError(f"need more than {N_COEFFICIENTS} samples to fit {N_COEFFICIENTS} "
                         f"coefficients; got v with shape {v.shape}")
    return v, y


def _check_quiet_mask(quiet_mask: Any, n: int) -> np.ndarray:
    mask = np.asarray(quiet_mask)
    if mask.dtype != bool or mask.shape != (n,):
        raise ValueError(f"quiet_mask must be a boolean array of shape ({n},); got dtype "
                         f"{mask.dtype} and shape {mask.shape}")
    n0 = int(np.count_nonzero(mask))
    if n0 < MIN_QUIET_SAMPLES:
        raise ValueError(f"quiet_mask selects {n0} samples; at least {MIN_QUIET_SAMPLES} are "
                         f"needed for the quiet-segment penalty")
    return mask


def _check_positive(name: str, value: float, *, allow_inf: bool = False, allow_zero: bool = False):
    value = float(value)
    ok = (value >= 0 if allow_zero else value > 0) and (allow_inf or math.isfinite(value))
    if not ok or math.isnan(value):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}"
                         f"{'' if allow_inf else ' and finite'}; got {value!r}")
    return value


def _check_gamma(gamma: float) -> float:
    gamma = _check_positive("gamma", gamma, allow_zero=True)
    if gamma > MAX_GAMMA:
        raise ValueError(f"gamma = {gamma:g}: valid range [0, {MAX_GAMMA:g}] (a larger quiet-segment penalty "
                         f"is beyond the accuracy of the small QPs; the paper's grid ends at 1e4)")
    return gamma


# --- Public helpers ---------------------------------------------------------------------------------
def design_matrix(v: np.ndarray) -> np.ndarray:
    """The paper's design matrix ``A = [x^3 x^2 x 1]`` (Eq. 10).

    Parameters
    ----------
    v : numpy.ndarray, shape (N, 8)
        Channel voltages ``x = [V_1 ... V_8]`` [V].

    Returns
    -------
    numpy.ndarray, shape (N, 25)
        Columns ``V_1^3 .. V_8^3, V_1^2 .. V_8^2, V_1 .. V_8, 1``.
    """
    v = _check_voltages(v)
    return np.hstack([v ** 3, v ** 2, v, np.ones((v.shape[0], 1))])


def quiet_segment_mask(tau_ref: np.ndarray,
                       tau_threshold_nm: float = QUIET_TAU_THRESHOLD_NM) -> np.ndarray:
    """Quiet segment ``I_0 = {k : |tau_k| <= tau_th}`` (paper, after Eq. 17).

    Parameters
    ----------
    tau_ref : numpy.ndarray, shape (N,)
        Reference torque [N m].
    tau_threshold_nm : float
        ``tau_th`` [N m].

    Returns
    -------
    numpy.ndarray of bool, shape (N,)

    Raises
    ------
    ValueError
        If fewer than ``MIN_QUIET_SAMPLES`` (26) samples qualify.

    Notes
    -----
    The paper's rule is "near-static/no-load conditions (e.g. |tau| <= tau_th)"; only the torque
    threshold is implemented. A rate condition could be added by the caller (``mask & slow``).
    """
    y = np.asarray(tau_ref, dtype=float)
    if y.ndim != 1:
        raise ValueError(f"tau_ref must have shape (N,); got shape {y.shape}")
    th = _check_positive("tau_threshold_nm", tau_threshold_nm, allow_zero=True)
    mask = np.abs(y) <= th
    n0 = int(np.count_nonzero(mask))
    if n0 < MIN_QUIET_SAMPLES:
        raise ValueError(f"quiet segment |tau_ref| <= {th:g} N m selects {n0} of {y.size} "
                         f"samples; at least {MIN_QUIET_SAMPLES} are needed (raise "
                         f"tau_threshold_nm or record a longer no-load segment)")
    return mask


# --- The design of Eq. 10 as a rule (sensor.constrained_lsq.StructuredDesign) ---------------------------------
class ChannelCubics:
    """The design ``A = [x^3 x^2 x 1]`` (Eq. 10) of channel voltages ``v`` (N, 8) [V], never formed.

    A :class:`sensor.constrained_lsq.StructuredDesign`: ``A @ theta`` by per-channel Horner, and the basis
    ``[u^3 u^2 u 1]`` of the channels mapped to ``u = (x - mid) / half_range`` in [-1, 1]. ``v`` must be
    checked (shape (N, 8), finite) by the caller.
    """

    def __init__(self, v: np.ndarray):
        self.v = v
        self.shape = (v.shape[0], N_COEFFICIENTS)

    def matvec(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        return _predict(self.v, x, out=out)

    def take(self, rows: np.ndarray) -> ChannelCubics:
        return ChannelCubics(self.v[rows])

    def basis(self, rows: np.ndarray | None = None) -> _ScaledCubics:
        mid, inv_half = _mid_half(self.v, rows)
        return _ScaledCubics(self.v, mid, inv_half)


@dataclass(frozen=True, eq=False)
class _ScaledCubics:
    """The basis ``B = [u^3 u^2 u 1]``, ``u = (v - mid) * inv_half`` (a :class:`sensor.constrained_lsq.Basis`)."""

    v: np.ndarray
    mid: np.ndarray          # (8,) [V]
    inv_half: np.ndarray     # (8,) [1/V]
    constant_column: int = N_COEFFICIENTS - 1

    def fill_t(self, rows: slice | np.ndarray, out_t: np.ndarray) -> None:
        """Transposed basis rows: ``out_t[0:25, :k] = [u^3; u^2; u; 1]`` (channels along the rows, samples
        contiguous: the elementwise steps run on long rows)."""
        u = out_t[16:24]
        np.copyto(u, self.v[rows].T)
        u -= self.mid[:, None]
        u *= self.inv_half[:, None]
        np.multiply(u, u, out=out_t[8:16])
        np.multiply(out_t[8:16], u, out=out_t[0:8])
        out_t[24] = 1.0

    def to_design(self, phi: np.ndarray) -> np.ndarray:
        """Coefficients in the monomial basis of volts from those of ``u = alpha x + beta``."""
        p3, p2, p1, p0 = phi[0:8], phi[8:16], phi[16:24], phi[24]
        a = self.inv_half
        b = -self.mid * self.inv_half
        theta = np.empty(N_COEFFICIENTS)
        theta[0:8] = p3 * a ** 3
        theta[8:16] = 3 * p3 * a ** 2 * b + p2 * a ** 2
        theta[16:24] = 3 * p3 * a * b ** 2 + 2 * p2 * a * b + p1 * a
        theta[24] = p0 + np.sum(p3 * b ** 3 + p2 * b ** 2 + p1 * b)
        return theta


def _predict(v: np.ndarray, theta: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``A(v) @ theta`` by per-channel Horner, in chunks (no N x 25 temporary).

    Each chunk is transposed to (8, rows) so that the Horner steps run along contiguous rows.
    """
    n = v.shape[0]
    out = np.empty(n) if out is None else out
    c3, c2, c1 = theta[0:8, None], theta[8:16, None], theta[16:24, None]
    ones = np.ones(N_CHANNELS)
    rows = min(n, PREDICT_CHUNK_ROWS)
    xt, w = np.empty((N_CHANNELS, rows)), np.empty((N_CHANNELS, rows))
    for i in range(0, n, PREDICT_CHUNK_ROWS):
        x = v[i:i + PREDICT_CHUNK_ROWS]
        k = x.shape[0]
        xk, wk = xt[:, :k], w[:, :k]
        np.copyto(xk, x.T)
        np.multiply(xk, c3, out=wk)
        wk += c2
        wk *= xk
        wk += c1
        wk *= xk
        np.matmul(ones, wk, out=out[i:i + k])
    out += theta[24]
    return out


def _mid_half(v: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centre and inverse half range of each channel [V, 1/V], over ``rows`` (a sample) or all rows; raises if
    a channel is constant over all rows."""
    src = v if rows is None else v[rows]
    vmin, vmax = src.min(axis=0), src.max(axis=0)
    half = 0.5 * (vmax - vmin)
    flat = half <= 1e-12 * np.maximum(1.0, np.abs(vmax))
    if np.any(flat):
        if rows is not None:
            return _mid_half(v)
        raise ValueError(f"channel(s) {(np.flatnonzero(flat) + 1).tolist()} of v are constant; "
                         f"the design matrix is rank-deficient")
    return 0.5 * (vmax + vmin), 1.0 / half


def _diagnostics(sol: lsq.Solution, n_quiet: int, feasibility_tol_nm: float, solve_time_s: float) -> SolveDiagnostics:
    """The engine's solution as the calibration's solver record."""
    return SolveDiagnostics(
        solver=sol.solver, iterations=sol.iterations, full_passes=sol.full_passes,
        n_working_constraints=sol.n_working_rows, n_active_constraints=sol.n_active_rows,
        residual_max_nm=sol.residual_max, rms_error_nm=sol.residual_rms,
        quiet_std_nm=None if sol.penalty is None else math.sqrt(sol.penalty / n_quiet),
        objective_nm2=sol.objective, feasibility_tol_nm=feasibility_tol_nm,
        solve_time_s=solve_time_s)


def _qp_problem(v, tau_ref, quiet_mask, e_max_nm: float, gamma: float) -> lsq.Problem:
    """Eq. 17 as an engine problem (inputs checked with the calibration's names)."""
    v, y = _check_fit_inputs(v, tau_ref)
    quiet_mask = _check_quiet_mask(quiet_mask, v.shape[0])
    return lsq.Problem(ChannelCubics(v), y, residual_bound=e_max_nm, penalty_rows=quiet_mask, penalty_weight=gamma)


def _qp_calibration(sol: lsq.Solution, problem: lsq.Problem, gamma: float, fs_nm: float,
                    solve_time_s: float) -> Calibration:
    """The QP calibration of an engine solution; raises :class:`InfeasibleCalibrationError` if it has none."""
    n, n_quiet = problem.target.size, int(np.count_nonzero(problem.penalty_rows))
    if not sol.found:
        raise InfeasibleCalibrationError(problem.residual_bound, sol.smallest_feasible_bound, n, fs_nm)
    return Calibration(theta=sol.x, method="qp", gamma=gamma, e_max_nm=problem.residual_bound, fs_nm=fs_nm,
                       n_samples=n, n_quiet=n_quiet,
                       diagnostics=_diagnostics(sol, n_quiet, FEASIBILITY_TOL_FRACTION_FS * fs_nm, solve_time_s))


# --- The paper's fits ----------------------------------------------------------------------------------------
def fit_least_squares(v: np.ndarray, tau_ref: np.ndarray, *, fs_nm: float = _FS_NM,
                      quiet_mask: np.ndarray | None = None) -> Calibration:
    """Conventional least-squares calibration (Eq. 11).

    Solves::

        minimize_theta  ||A theta - y||_2^2,   A = design_matrix(v),  y = tau_ref

    by a QR factorisation of the column-rescaled design matrix, streamed in chunks (never forming
    ``A``): Householder TSQR, or for N >= 65 536 a randomly preconditioned Cholesky QR with an
    accuracy check that falls back to TSQR (:func:`sensor.constrained_lsq.solve`). The plain normal
    equations are not used, so the conditioning is that of ``A``, not of its square.

    Parameters
    ----------
    v : numpy.ndarray, shape (N, 8)
        Channel voltages [V].
    tau_ref : numpy.ndarray, shape (N,)
        Reference torque ``y`` [N m].
    fs_nm : float
        Full scale [N m], stored with the result (default ``photoreflector.full_scale_nm``).
    quiet_mask : numpy.ndarray of bool, shape (N,), optional
        Only used to report ``diagnostics.quiet_std_nm``.

    Returns
    -------
    Calibration
        ``method="ls"``, ``gamma=0``, ``e_max_nm=None``.
    """
    t0 = time.perf_counter()
    v, y = _check_fit_inputs(v, tau_ref)
    fs_nm = _check_positive("fs_nm", fs_nm)
    if quiet_mask is not None:
        quiet_mask = _check_quiet_mask(quiet_mask, v.shape[0])
    n_quiet = 0 if quiet_mask is None else int(np.count_nonzero(quiet_mask))
    sol = lsq.solve(lsq.Problem(ChannelCubics(v), y, penalty_rows=quiet_mask),
                    feasibility_tol=FEASIBILITY_TOL_FRACTION_FS * fs_nm)
    return Calibration(theta=sol.x, method="ls", gamma=0.0, e_max_nm=None, fs_nm=fs_nm, n_samples=v.shape[0],
                       n_quiet=n_quiet, diagnostics=_diagnostics(sol, n_quiet, 0.0, time.perf_counter() - t0))


def smallest_feasible_e_max(v: np.ndarray, tau_ref: np.ndarray, *, fs_nm: float = _FS_NM) -> float:
    """Smallest ``e_max`` [N m] for which Eq. 15 is feasible.

    Solves the minimax (Chebyshev) fit::

        minimize_{theta, t}  t   subject to  -t <= A theta - y <= t   (all N rows)

    with HiGHS (``scipy.optimize.linprog``) by a cutting plane over rows
    (:func:`sensor.constrained_lsq.solve_minimax`). Returns the achieved ``max_k |a_k theta - y_k|``, which is
    feasible and within ``1e-9 FS`` of the LP optimum.
    """
    v, y = _check_fit_inputs(v, tau_ref)
    fs_nm = _check_positive("fs_nm", fs_nm)
    return lsq.solve_minimax(lsq.Problem(ChannelCubics(v), y),
                             feasibility_tol=FEASIBILITY_TOL_FRACTION_FS * fs_nm).bound


def fit_qp(v: np.ndarray, tau_ref: np.ndarray, *, gamma: float, quiet_mask: np.ndarray,
           e_max_nm: float = E_MAX_NM, fs_nm: float = _FS_NM) -> Calibration:
    """Quiet-segment-penalised, error-bounded calibration (the paper's QP, Eq. 17).

    Solves::

        minimize_theta  ||A theta - y||_2^2 + gamma * ||A_0c theta||_2^2
        subject to      -e_max <= A theta - y <= e_max          (every row k = 1..N, Eq. 15-16)

    with ``A = design_matrix(v)``, ``y = tau_ref``, ``A_0 = A[quiet_mask]`` and
    ``A_0c = A_0 - 1 mu^T``, ``mu = mean of the rows of A_0`` (Eqs. 12-13).

    The solution is exact up to ``feasibility_tol_nm = 1e-9 * fs_nm``: an exact cutting plane over
    rows (:mod:`sensor.constrained_lsq`) adds violated rows to a working set, solves the small QP with ProxQP
    (qpsolvers solver ``"proxqp"``) and polishes it to the KKT point of its active set, and stops when
    no row of the full data violates the bound by more than the tolerance. Cost: one O(N 25^2)
    factorisation pass plus one O(N 25) residual pass per iteration; memory O(N) beyond the inputs.

    Parameters
    ----------
    v : numpy.ndarray, shape (N, 8)
        Channel voltages [V].
    tau_ref : numpy.ndarray, shape (N,)
        Reference torque ``y`` [N m].
    gamma : float
        Quiet-segment penalty weight [-], in ``[0, MAX_GAMMA]`` = [0, 1e6] (paper: chosen by
        :func:`select_gamma`).
    quiet_mask : numpy.ndarray of bool, shape (N,)
        Quiet segment ``I_0`` (see :func:`quiet_segment_mask`), at least 26 samples.
    e_max_nm : float
        Error bound ``e_max`` [N m]; default 0.2 % of the default full scale, 80 N m (Eq. 14). ``math.inf``
        removes the constraints.
    fs_nm : float
        Full scale [N m], sets the feasibility tolerance (default ``photoreflector.full_scale_nm``).

    Returns
    -------
    Calibration
        ``method="qp"``; ``diagnostics`` records iterations, working-set and active rows, max and RMS
        residual and solve time.

    Raises
    ------
    InfeasibleCalibrationError
        If no ``theta`` meets the bound; ``.smallest_feasible_e_max_nm`` holds the minimax LP value.
    """
    gamma = _check_gamma(gamma)
    e_max_nm = _check_positive("e_max_nm", e_max_nm, allow_inf=True)
    t0 = time.perf_counter()
    fs_nm = _check_positive("fs_nm", fs_nm)
    problem = _qp_problem(v, tau_ref, quiet_mask, e_max_nm, gamma)
    sol = lsq.solve(problem, feasibility_tol=FEASIBILITY_TOL_FRACTION_FS * fs_nm)
    return _qp_calibration(sol, problem, gamma, fs_nm, time.perf_counter() - t0)


def select_gamma(v: np.ndarray, tau_ref: np.ndarray, *, quiet_mask: np.ndarray,
                 e_max_nm: float = E_MAX_NM, gammas: np.ndarray = DEFAULT_GAMMA_GRID,
                 lambda_weight: float = DEFAULT_LAMBDA_WEIGHT,
                 fs_nm: float = _FS_NM) -> GammaSelection:
    """Choose gamma on a grid by the paper's criterion (after Eq. 17).

    For each ``gamma`` in ``gammas`` solve :func:`fit_qp` and evaluate::

        J(gamma) = RMSE(tau_hat, tau)^2 + lambda * Var(tau_hat)|_{I_0}        [N^2 m^2]

    with ``RMSE`` over all N calibration samples and the population variance over the quiet
    segment (``= ||A_0c theta||^2 / |I_0|``); return the first minimiser. The data are factorised
    once and the cutting-plane working set is carried from one gamma to the next
    (:func:`sensor.constrained_lsq.solve_path`; its rows are true constraints, so each solve stays exact).

    Parameters
    ----------
    v, tau_ref, quiet_mask, e_max_nm, fs_nm
        As in :func:`fit_qp`.
    gammas : array_like, shape (G,)
        Candidate gamma values >= 0 (sorted ascending internally).
    lambda_weight : float
        ``lambda >= 0`` [-].

    Notes
    -----
    The criterion is evaluated in-sample, as the paper describes it; since ``gamma = 0`` minimises
    the RMSE term and the variance term falls with gamma, ``lambda`` alone sets the trade-off.
    """
    g = np.sort(np.asarray(gammas, dtype=float).ravel())
    if g.size == 0 or np.any(~np.isfinite(g)) or np.any(g < 0) or np.any(g > MAX_GAMMA):
        raise ValueError(f"gammas must be a non-empty array of values in [0, {MAX_GAMMA:g}]; got {gammas!r}")
    lam = _check_positive("lambda_weight", lambda_weight, allow_zero=True)
    e_max_nm = _check_positive("e_max_nm", e_max_nm, allow_inf=True)
    fs_nm = _check_positive("fs_nm", fs_nm)
    problem = _qp_problem(v, tau_ref, quiet_mask, e_max_nm, 0.0)
    sols = lsq.solve_path(problem, [float(gi) for gi in g], feasibility_tol=FEASIBILITY_TOL_FRACTION_FS * fs_nm)
    cals = [_qp_calibration(sol, problem, float(gi), fs_nm, sol.solve_time_s) for sol, gi in zip(sols, g, strict=True)]
    rmse = np.array([c.diagnostics.rms_error_nm for c in cals])
    qvar = np.array([c.diagnostics.quiet_std_nm ** 2 for c in cals])
    crit = rmse ** 2 + lam * qvar
    best = int(np.argmin(crit))
    return GammaSelection(gammas=g, criterion_nm2=crit, rmse_nm=rmse, quiet_var_nm2=qvar,
                          lambda_weight=lam, best_index=best, gamma=float(g[best]),
                          calibration=cals[best])
