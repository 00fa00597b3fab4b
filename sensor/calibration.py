"""Calibration of the photo-reflector array: eight channel voltages to joint torque.

Paper: Sec. IV-A "Calibration Method and Experiment", Eqs. 10-17.

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
Cubes of volts make ``A`` badly scaled and the eight channels are nearly collinear (all follow the same
torque). Internally every channel is mapped to ``u = (x - mid) / half_range`` in [-1, 1] (an invertible
change of the column basis, ``B = A T``, ``theta = T phi``) and ``B = Q R`` is factorised in one
streaming pass of chunks of :data:`CHUNK_ROWS` rows (O(N 25^2) work, O(chunk) memory, ``A`` is never
formed): a Householder tall-skinny QR (TSQR) for short records, and for N >= :data:`SKETCH_MIN_N` a
Cholesky QR of ``B R_s^-1``, preconditioned by the R factor ``R_s`` of a random row sample, which runs
at matrix-multiply speed and is accepted only if ``cond(B R_s^-1) <= 1e3`` (else TSQR). Either way
the conditioning is that of ``B``, not of ``B^T B``. The quiet block's centred factor comes out of the
same pass (see ``_factor_tsqr`` and ``_factor_sketched``).

In the coordinates ``z = R phi / sqrt(N)`` the objective divided by N is
``||z - c||^2 + gamma ||P0 z||^2 + const`` and the constraint rows are sqrt(N) times rows of the
orthonormal ``Q``; a second change ``w = U z`` with ``U^T U = I + gamma P0^T P0`` turns every QP into a
Euclidean projection ``minimize ||w - d||^2 s.t. G_w w <= h``, well conditioned for any gamma.

The 2N inequality constraints are handled by an exact cutting-plane (working-set) scheme: solve with
the current working set, evaluate ``A theta - y`` on all rows (one O(N 25) pass), add the most violated
rows (the worst of each run of neighbouring violations first), repeat until no row exceeds ``e_max``
by more than ``feasibility_tol_nm = 1e-9 FS``. Between passes over all rows only a candidate subset is
checked (the rows whose residual was above half the bound, at most 65 536; on a cold start with more
than twice that many rows, an evenly spaced subset): when the candidates meet the bound, a pass over all
rows confirms it or starts a new candidate set, so the stopping test is always on all rows. All BLAS
calls are small (25 columns) and run single-threaded. The small QPs go to ProxQP through qpsolvers
(solver name ``"proxqp"``, the ProxSuite solver) and are polished to the exact KKT point of their active
set; if ProxQP reports failure on a working set that an LP shows to be feasible (its infeasibility test
is loose for thin feasible sets), the projection is solved exactly by Lawson-Hanson least-distance
programming (``scipy.optimize.nnls``). Because every working set is a subset of the true constraints,
the final point solves the full problem; if a working set is infeasible, so is the full problem, and
the smallest feasible bound is found by a minimax LP (HiGHS), also by a cutting plane over rows.
"""

from __future__ import annotations

import contextlib
import functools
import math
import threading
import time
import warnings
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
import qpsolvers
import scipy.linalg
import scipy.optimize
import threadpoolctl

__all__ = [
    "N_CHANNELS",
    "N_COEFFICIENTS",
    "FS_NM",
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
    "design_matrix",
    "fit_least_squares",
    "fit_qp",
    "quiet_segment_mask",
    "select_gamma",
    "smallest_feasible_e_max",
]

# --- Constants from the paper -------------------------------------------------------------------
N_CHANNELS = 8
"""Photo-reflector channels; Sec. IV-A: ``x = [V_1 ... V_8]``."""

N_COEFFICIENTS = 3 * N_CHANNELS + 1
"""Columns of the design matrix; Sec. IV-A, Eq. 10: ``A = [x^3 x^2 x 1]`` is N x 25."""

FS_NM = 80.0
"""Full scale [N m]; Sec. IV-B: "FS is defined as the design maximum T_z^max = 80 N m"."""

E_MAX_FRACTION_FS = 0.002
"""Error bound as a fraction of full scale; Eq. 14: ``e_max = 0.002 * FS``."""

E_MAX_NM = E_MAX_FRACTION_FS * FS_NM
"""Default error bound [N m] = 0.16 N m (Eq. 14 with FS = 80 N m)."""

# --- Our choices (the paper gives no value) ---------------------------------------------------------
QUIET_TAU_THRESHOLD_NM = 0.05
"""Default quiet-segment threshold tau_th [N m]. Paper (after Eq. 17) names the rule |tau| <= tau_th
but no value; ours is about 5 counts of the MINI85 reference resolution 7/748 N m (Sec. IV-A)."""

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

CHUNK_ROWS = 4_096
"""Rows per chunk in the streaming passes over the data (memory ~ 26 * 8 bytes * CHUNK_ROWS)."""

PREDICT_CHUNK_ROWS = 8_192
"""Rows per chunk when evaluating ``A theta`` (the Horner temporaries stay in cache)."""

MAX_ROWS_ADDED_PER_ITERATION = 128
"""Cutting-plane: at most this many violated rows enter the working set per iteration."""

CANDIDATE_MARGIN_FRACTION = 0.5
"""Cutting-plane: after a pass over all rows, the rows with ``|a_k theta - y_k|`` above this
fraction of ``e_max`` become the candidate set that the next iterations check (the others would need
the solution to move their prediction by at least half the bound); a pass over all rows confirms
the result (see :meth:`_QPSolver.solve`)."""

MAX_CANDIDATE_ROWS = 65_536
"""Cutting-plane: the candidate set keeps at most this many rows (the largest residuals); above
half of N the candidate set is all rows."""

MAX_CUTTING_PLANE_ITERATIONS = 200
"""Cutting-plane: iteration cap; reaching it raises instead of returning an unproven point."""

SKETCH_ROWS = 16_384
"""Rows sampled for the preconditioner of the sketched Cholesky QR (see ``_factor_sketched``)."""

SKETCH_MIN_N = 4 * SKETCH_ROWS
"""Data at least this long are factorised by the sketched Cholesky QR; shorter ones by TSQR."""

SKETCH_SEED = 20_240_917
"""Seed of the row sample (fixed: the same data give the same factor)."""

SKETCH_MAX_COND = 1e3
"""Accept the sketched factor only if cond(R_c) <= 1e3 (relative error ~ eps * 1e6); else TSQR."""

RANK_RTOL = 1e-12
"""The scaled design matrix is called rank-deficient when min |R_ii| / max |R_ii| falls below this."""

PROXQP_EPS_ABS = 1e-11
"""ProxQP absolute stopping tolerance for the small working-set QPs (qpsolvers default 1e-3 is far
too loose); the KKT polish then makes the point exact for its active set."""

PROXQP_MAX_ITER = 10_000
"""ProxQP outer-iteration cap."""

HIGHS_TOLERANCE = 1e-9
"""HiGHS primal/dual feasibility tolerance for the minimax LP (default 1e-7; at 1e-10, the smallest
value HiGHS accepts, its simplex sometimes stops on numerical difficulties)."""


# Tolerances of the KKT polish of a small QP (``_polish``) and of the exact LDP fallback (``_project_ldp``).
POLISH_MULTIPLIER_RTOL = 1e-9
"""A row of a small QP counts as active when its multiplier exceeds this times the largest multiplier
(or 1), and a polished active set is rejected when a multiplier falls below minus this times the largest:
ProxQP's multipliers at ``PROXQP_EPS_ABS`` are accurate to far better than 1e-9 relative of the largest."""

POLISH_KKT_RTOL = 1e-9
"""The equality-constrained KKT system of a polished active set is accepted as consistent when its
least-squares solution reproduces the right-hand side to this relative (and ``1e-9 * max|rhs|`` absolute)
accuracy; a larger misfit means dependent rows with conflicting bounds, and the unpolished point is kept."""

POLISH_PRIMAL_TOL_FRACTION = 1e-3
"""A row outside the polished active set counts as violated when it exceeds its bound by more than this
fraction of the feasibility tolerance (``FEASIBILITY_TOL_FRACTION_FS * fs_nm``): the polished point then
meets the cutting plane's acceptance test with a 1000x margin."""

LDP_NNLS_MAXITER_PER_ROW = 50
"""Iteration cap of ``scipy.optimize.nnls`` in the LDP fallback, per constraint row (scipy's default is 3
per column; Lawson-Hanson adds or drops one row per iteration, and degenerate working sets cycle longer)."""

LDP_INCOMPATIBLE_TOL = 1e-14
"""The LDP's NNLS residual component ``r[n] = (f^T u - 1)`` at or below this in magnitude means
``[E^T; f^T] u = e_{n+1}`` is solved exactly, i.e. the constraints are incompatible (Lawson & Hanson,
ch. 23); for a compatible set ``|r[n]|`` is of order 1, so 1e-14 (~50 float64 epsilons) separates the two."""

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
        super().__init__(
            f"QP calibration is infeasible: no theta satisfies |A theta - y| <= e_max = "
            f"{e_max_nm:.6g} N m ({100 * e_max_nm / fs_nm:.4g} % FS) on all {n_samples} samples; "
            f"the smallest feasible e_max is {smallest_feasible_e_max_nm:.6g} N m "
            f"({100 * smallest_feasible_e_max_nm / fs_nm:.4g} % FS), from the LP "
            f"min t s.t. |A theta - y| <= t (HiGHS)."
        )


@dataclass(frozen=True)
class SolveDiagnostics:
    """How a calibration was solved and how well it fits its own data.

    Attributes
    ----------
    solver : str
        The factorisation (``"tsqr"``: Householder, or ``"sketched-cholqr"``: randomly
        preconditioned Cholesky QR, for N >= 65 536), prefixed by ``"cutting-plane+proxqp on"``
        for the QP; the count of exact LDP fallback solves is appended if there were any.
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
    def from_dict(cls, d: dict[str, Any]) -> "Calibration":
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


# --- Streaming numerics -------------------------------------------------------------------------------
@functools.cache
def _blas_controller() -> threadpoolctl.ThreadpoolController:
    return threadpoolctl.ThreadpoolController()


_blas_lock = threading.Lock()
_blas_fits_running = 0          # fits inside _single_threaded_blas, all threads (guarded by _blas_lock)


def _single_threaded_blas(fit):
    """Run ``fit`` with one BLAS thread: a speed-up only, never a condition of the result.

    Every BLAS call here is small (25 columns): with OpenBLAS's worker threads each call paid about a
    millisecond of thread wake-up on the 2-core development machine, so the QP at N = 1e6 took
    1.3-1.8x longer with two threads than with one (``benchmarks/README.md``). OpenBLAS has one
    process-wide thread count, which threadpoolctl lets only one Python thread change at a time and
    restores in that thread when its ``with`` block ends. So a fit that starts while no other fit runs
    sets the limit for its duration (in a ``with`` block, in its own thread) and restores what it found;
    fits that start while another runs, in other threads, run under whatever limit is in force. If
    threadpoolctl cannot work here the fit runs without the limit.
    """
    @functools.wraps(fit)
    def wrapper(*args, **kwargs):
        global _blas_fits_running
        with _blas_lock:
            first = _blas_fits_running == 0
            _blas_fits_running += 1
        try:
            limit = contextlib.nullcontext()
            if first:
                try:
                    limit = _blas_controller().limit(limits=1, user_api="blas")
                except Exception as exc:  # the limit is a speed-up: never let it stop a fit
                    warnings.warn(f"BLAS threads not limited ({exc!r}): the fit runs at the default count",
                                  RuntimeWarning, stacklevel=2)
            with limit:
                return fit(*args, **kwargs)
        finally:
            with _blas_lock:
                _blas_fits_running -= 1
    return wrapper


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


@dataclass(frozen=True)
class _Factor:
    """Column basis and triangular factors of one data set (see module docstring)."""

    n: int
    mid: np.ndarray          # (8,) [V]
    inv_half: np.ndarray     # (8,) [1/V]
    r: np.ndarray            # (25, 25) upper triangular, R / sqrt(N) with B = [u^3 u^2 u 1] = Q R
    c: np.ndarray            # (25,) Q^T y / sqrt(N) [N m]
    pen: np.ndarray | None   # (k, 25): pen^T pen = B_0c^T B_0c (centred quiet block, unscaled)
    n_quiet: int
    method: str              # "tsqr" or "sketched-cholqr"


def _fill_basis_t(v_chunk: np.ndarray, mid, inv_half, out_t: np.ndarray) -> None:
    """Transposed basis rows: ``out_t[0:25, :k] = [u^3; u^2; u; 1]`` with ``u = (v - mid) inv_half``
    (channels along the rows, samples contiguous: the elementwise steps run on long rows)."""
    u = out_t[16:24]
    np.copyto(u, v_chunk.T)
    u -= mid[:, None]
    u *= inv_half[:, None]
    np.multiply(u, u, out=out_t[8:16])
    np.multiply(out_t[8:16], u, out=out_t[0:8])
    out_t[24] = 1.0


def _basis_rows_raw(v_rows: np.ndarray, mid, inv_half) -> np.ndarray:
    """``B`` rows (k, 25) for the given voltage rows."""
    bt = np.empty((N_COEFFICIENTS, v_rows.shape[0]))
    _fill_basis_t(v_rows, mid, inv_half, bt)
    return np.ascontiguousarray(bt.T)


def _basis_rows(v_rows: np.ndarray, fac: _Factor) -> np.ndarray:
    return _basis_rows_raw(v_rows, fac.mid, fac.inv_half)


def _mid_half(v: np.ndarray, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half range of each channel [V], over ``rows`` (a sample) or all rows; raises if a
    channel is constant over all rows."""
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


def _check_rank(r: np.ndarray, shape) -> None:
    d = np.abs(np.diag(r))
    if d.min() < RANK_RTOL * d.max():
        raise ValueError(f"the design matrix of v (shape {shape}) is numerically rank-deficient "
                         f"(min/max |R_ii| = {d.min() / d.max():.2e} < {RANK_RTOL:g}); the channels "
                         f"do not determine {N_COEFFICIENTS} coefficients")


def _factor(v: np.ndarray, y: np.ndarray, quiet_mask: np.ndarray | None) -> _Factor:
    """Factorise ``B = Q R`` and the centred quiet block in one streaming pass over the data.

    Large data (N >= :data:`SKETCH_MIN_N`) go through :func:`_factor_sketched` (randomly
    preconditioned Cholesky QR, gemm speed); if its accuracy check fails, and for small data, the
    Householder TSQR of :func:`_factor_tsqr` is used.
    """
    n = v.shape[0]
    if n >= SKETCH_MIN_N:
        rows = np.sort(np.random.default_rng(SKETCH_SEED).choice(n, size=min(n, SKETCH_ROWS),
                                                                 replace=False))
        mid, inv_half = _mid_half(v, rows)       # a sample's range is enough for the scaling
        fac = _factor_sketched(v, y, quiet_mask, mid, inv_half, rows)
        if fac is not None:
            return fac
    mid, inv_half = _mid_half(v)
    return _factor_tsqr(v, y, quiet_mask, mid, inv_half)


def _factor_tsqr(v, y, quiet_mask, mid, inv_half) -> _Factor:
    """Householder TSQR of ``[B y]`` and of the quiet rows ``[1 B_nc]`` (``B_nc = B[:, :24]``).

    The R factor of ``[1, X]`` carries the centred block in its trailing part: with
    ``R = [[r11, r12], [0, R22]]``, ``R22^T R22 = X^T X - X^T 1 1^T X / n = X_c^T X_c`` (Householder
    centring, no cancellation).
    """
    n = v.shape[0]
    buf_t = np.empty((N_COEFFICIENTS + 1, min(n, CHUNK_ROWS)))
    r_aug = np.zeros((0, N_COEFFICIENTS + 1))
    r_q = np.zeros((0, N_COEFFICIENTS))
    n_quiet = 0
    for i in range(0, n, CHUNK_ROWS):
        j = min(n, i + CHUNK_ROWS)
        bt = buf_t[:, :j - i]
        _fill_basis_t(v[i:j], mid, inv_half, bt)
        bt[N_COEFFICIENTS] = y[i:j]
        r_aug = np.linalg.qr(np.vstack([r_aug, bt.T]), mode="r")
        if quiet_mask is not None:
            sel = quiet_mask[i:j]
            kq = int(np.count_nonzero(sel))
            if kq:
                q = np.empty((kq, N_COEFFICIENTS))
                q[:, 0] = 1.0
                q[:, 1:] = bt[:N_COEFFICIENTS - 1, sel].T
                r_q = np.linalg.qr(np.vstack([r_q, q]), mode="r")
                n_quiet += kq
    r = r_aug[:N_COEFFICIENTS, :N_COEFFICIENTS] / math.sqrt(n)
    _check_rank(r, v.shape)
    c = r_aug[:N_COEFFICIENTS, N_COEFFICIENTS] / math.sqrt(n)
    pen = None
    if quiet_mask is not None:
        pen = np.zeros((N_COEFFICIENTS - 1, N_COEFFICIENTS))
        m = min(r_q.shape[0], N_COEFFICIENTS) - 1
        pen[:m, :N_COEFFICIENTS - 1] = r_q[1:m + 1, 1:]
    return _Factor(n=n, mid=mid, inv_half=inv_half, r=r, c=c, pen=pen, n_quiet=n_quiet,
                   method="tsqr")


def _factor_sketched(v, y, quiet_mask, mid, inv_half, rows) -> _Factor | None:
    """Randomly preconditioned Cholesky QR; None if its accuracy check fails.

    1. ``R_s`` = Householder R of the sample ``rows`` of ``B`` (uniform, fixed seed).
    2. One pass: ``W = B R_s^-1`` chunk by chunk, accumulating ``W^T W``, ``W^T y`` and, for the
       quiet rows, the shifted sums of ``W`` (shift = mean of the sample's quiet rows, so the centred
       Gram ``sum (w - mu)(w - mu)^T`` is formed without cancellation).
    3. ``W^T W = R_c^T R_c`` (Cholesky) and ``R = R_c R_s``, ``Q^T y = R_c^-T W^T y``.

    If the sample represents the rows well, ``W`` has nearly orthogonal columns (cond ~ 1-10), so
    the Gram matrix loses nothing; the check ``cond(R_c) <= SKETCH_MAX_COND`` (relative error of the
    factor ~ eps cond(R_c)^2 <= 2e-10) guards against a sample that missed high-leverage rows.
    This is the randomized Cholesky QR of Fan, Guo & Lin (2021), with a row-sampling sketch.
    """
    n = v.shape[0]
    b_s = _basis_rows_raw(v[rows], mid, inv_half)
    r_s = np.linalg.qr(b_s, mode="r")
    d = np.abs(np.diag(r_s))
    if d.min() < RANK_RTOL * d.max():
        return None
    rs_inv_t = scipy.linalg.solve_triangular(r_s, np.eye(N_COEFFICIENTS)).T   # R_s^-T
    shift = np.zeros((N_COEFFICIENTS, 1))
    if quiet_mask is not None and np.any(quiet_mask[rows]):
        shift = (b_s[quiet_mask[rows]] @ rs_inv_t.T).mean(axis=0)[:, None]
    gw = np.zeros((N_COEFFICIENTS, N_COEFFICIENTS))
    gy = np.zeros(N_COEFFICIENTS)
    sq = np.zeros((N_COEFFICIENTS, N_COEFFICIENTS))
    sq1 = np.zeros(N_COEFFICIENTS)
    n_quiet = 0
    buf_t = np.empty((N_COEFFICIENTS, CHUNK_ROWS))
    wbuf_t = np.empty((N_COEFFICIENTS, CHUNK_ROWS))
    for i in range(0, n, CHUNK_ROWS):
        j = min(n, i + CHUNK_ROWS)
        bt, wt = buf_t[:, :j - i], wbuf_t[:, :j - i]
        _fill_basis_t(v[i:j], mid, inv_half, bt)
        np.matmul(rs_inv_t, bt, out=wt)                 # W^T = R_s^-T B^T
        gw += wt @ wt.T
        gy += wt @ y[i:j]
        if quiet_mask is not None:
            sel = quiet_mask[i:j]
            if sel.any():
                wq = wt[:, sel] - shift
                sq += wq @ wq.T
                sq1 += wq.sum(axis=1)
                n_quiet += wq.shape[1]
    try:
        r_c = np.linalg.cholesky(gw).T
    except np.linalg.LinAlgError:
        return None
    if np.linalg.cond(r_c) > SKETCH_MAX_COND:
        return None
    r = (r_c @ r_s) / math.sqrt(n)
    _check_rank(r, v.shape)
    c = scipy.linalg.solve_triangular(r_c, gy, trans="T") / math.sqrt(n)
    pen = None
    if quiet_mask is not None:
        gq = sq - np.outer(sq1, sq1) / n_quiet           # centred Gram of the quiet W rows
        evals, evecs = np.linalg.eigh(0.5 * (gq + gq.T))
        pen = (np.sqrt(np.clip(evals, 0.0, None))[:, None] * evecs.T) @ r_s
    return _Factor(n=n, mid=mid, inv_half=inv_half, r=r, c=c, pen=pen, n_quiet=n_quiet,
                   method="sketched-cholqr")


def _theta_from_phi(phi: np.ndarray, fac: _Factor) -> np.ndarray:
    """Coefficients in the monomial basis of volts from those of ``u = alpha x + beta``."""
    p3, p2, p1, p0 = phi[0:8], phi[8:16], phi[16:24], phi[24]
    a = fac.inv_half
    b = -fac.mid * fac.inv_half
    theta = np.empty(N_COEFFICIENTS)
    theta[0:8] = p3 * a ** 3
    theta[8:16] = 3 * p3 * a ** 2 * b + p2 * a ** 2
    theta[16:24] = 3 * p3 * a * b ** 2 + 2 * p2 * a * b + p1 * a
    theta[24] = p0 + np.sum(p3 * b ** 3 + p2 * b ** 2 + p1 * b)
    return theta


def _theta_from_z(z: np.ndarray, fac: _Factor) -> np.ndarray:
    return _theta_from_phi(scipy.linalg.solve_triangular(fac.r, z), fac)


def _constraint_rows(v: np.ndarray, idx: np.ndarray, fac: _Factor) -> np.ndarray:
    """Rows ``g_k`` with ``a_k theta = g_k z`` (``g_k = R^-T b_k``), shape (len(idx), 25)."""
    b = _basis_rows(v[idx], fac)
    return scipy.linalg.solve_triangular(fac.r, b.T, trans="T").T


def _residual(v, y, theta, out: np.ndarray | None = None) -> np.ndarray:
    """``r = A theta - y`` [N m] on all rows (one streaming pass)."""
    r = _predict(v, theta, out=out)
    r -= y
    return r


@dataclass(frozen=True)
class _FitStats:
    residual_max_nm: float
    rms_error_nm: float
    quiet_sum_sq_nm2: float   # ||A_0c theta||^2
    quiet_std_nm: float | None


def _fit_stats(r: np.ndarray, y: np.ndarray, quiet_mask: np.ndarray | None) -> _FitStats:
    """Max and RMS of the residual, and the spread of ``tau_hat = r + y`` on the quiet segment."""
    qss, qstd = 0.0, None
    if quiet_mask is not None:
        tq = r[quiet_mask] + y[quiet_mask]
        tq -= tq.mean()
        qss = float(np.dot(tq, tq))
        qstd = math.sqrt(qss / tq.size)
    return _FitStats(residual_max_nm=float(np.max(np.abs(r))),
                     rms_error_nm=math.sqrt(float(np.dot(r, r)) / r.size),
                     quiet_sum_sq_nm2=qss, quiet_std_nm=qstd)


def _candidate_rows(abs_r: np.ndarray, e_max_nm: float) -> np.ndarray | None:
    """Rows the cutting plane re-checks between passes over all rows (sorted indices): those with
    ``|r| > CANDIDATE_MARGIN_FRACTION * e_max``, at most :data:`MAX_CANDIDATE_ROWS` of the largest;
    None (check every row) if that would be more than half of them."""
    idx = np.flatnonzero(abs_r > CANDIDATE_MARGIN_FRACTION * e_max_nm)
    if idx.size > MAX_CANDIDATE_ROWS:
        top = np.argpartition(-abs_r[idx], MAX_CANDIDATE_ROWS - 1)[:MAX_CANDIDATE_ROWS]
        idx = np.sort(idx[top])
    return None if idx.size > abs_r.size // 2 else idx


def _select_violated(excess: np.ndarray, k_max: int,
                     sample_index: np.ndarray | None = None) -> np.ndarray:
    """Up to ``k_max`` positions in ``excess`` with ``excess > 0``.

    Violations come in runs of neighbouring samples that carry nearly the same constraint, so the
    worst row of each run is taken first (runs ranked by their worst excess), then, if room is left,
    the next worst rows overall. ``sample_index`` (sorted) gives each position's sample number when
    ``excess`` covers a subset of the rows (default: position = sample).
    """
    idx = np.flatnonzero(excess > 0)
    if idx.size <= k_max:
        return idx
    ex = excess[idx]
    samples = idx if sample_index is None else sample_index[idx]
    starts = np.flatnonzero(np.concatenate([[True], np.diff(samples) > 1]))
    run_max = np.maximum.reduceat(ex, starts)
    ends = np.append(starts[1:], idx.size)
    if starts.size > k_max:
        top = np.argpartition(-run_max, k_max - 1)[:k_max]
    else:
        top = np.arange(starts.size)
    heads = np.array([starts[j] + int(np.argmax(ex[starts[j]:ends[j]])) for j in top], dtype=int)
    if heads.size < k_max:
        ex_rest = ex.copy()
        ex_rest[heads] = -np.inf
        more = np.argpartition(-ex_rest, k_max - heads.size - 1)[:k_max - heads.size]
        heads = np.concatenate([heads, more])
    return idx[heads]


# --- Least squares -----------------------------------------------------------------------------------
@_single_threaded_blas
def fit_least_squares(v: np.ndarray, tau_ref: np.ndarray, *, fs_nm: float = FS_NM,
                      quiet_mask: np.ndarray | None = None) -> Calibration:
    """Conventional least-squares calibration (Eq. 11).

    Solves::

        minimize_theta  ||A theta - y||_2^2,   A = design_matrix(v),  y = tau_ref

    by a QR factorisation of the column-rescaled design matrix, streamed in chunks (never forming
    ``A``): Householder TSQR, or for N >= 65 536 a randomly preconditioned Cholesky QR with an
    accuracy check that falls back to TSQR. The plain normal equations are not used, so the
    conditioning is that of ``A``, not of its square.

    Parameters
    ----------
    v : numpy.ndarray, shape (N, 8)
        Channel voltages [V].
    tau_ref : numpy.ndarray, shape (N,)
        Reference torque ``y`` [N m].
    fs_nm : float
        Full scale [N m], stored with the result.
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
    fac = _factor(v, y, None)
    theta = _theta_from_z(fac.c, fac)
    ps = _fit_stats(_residual(v, y, theta), y, quiet_mask)
    diag = SolveDiagnostics(
        solver=fac.method, iterations=1, n_working_constraints=0, n_active_constraints=0,
        residual_max_nm=ps.residual_max_nm, rms_error_nm=ps.rms_error_nm,
        quiet_std_nm=ps.quiet_std_nm, objective_nm2=ps.rms_error_nm ** 2 * v.shape[0],
        feasibility_tol_nm=0.0, solve_time_s=time.perf_counter() - t0)
    return Calibration(theta=theta, method="ls", gamma=0.0, e_max_nm=None, fs_nm=fs_nm,
                       n_samples=v.shape[0],
                       n_quiet=0 if quiet_mask is None else int(np.count_nonzero(quiet_mask)),
                       diagnostics=diag)


# --- Minimax LP (smallest feasible e_max) ----------------------------------------------------------------
def _minimax_lp_rows(g: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """``min t s.t. |g z - y| <= t`` on the given rows (HiGHS). Returns (z, t).

    Tries HiGHS with tight feasibility tolerances first; HiGHS occasionally stops with status 4
    ("numerical difficulties") at tight tolerances, so the default settings and then the
    interior-point method are tried before giving up.
    """
    k, p = g.shape
    cost = np.zeros(p + 1)
    cost[p] = 1.0
    ones = np.ones((k, 1))
    a_ub = np.block([[g, -ones], [-g, -ones]])
    b_ub = np.concatenate([y, -y])
    bounds = [(None, None)] * p + [(0, None)]
    tight = {"primal_feasibility_tolerance": HIGHS_TOLERANCE,
             "dual_feasibility_tolerance": HIGHS_TOLERANCE}
    messages = []
    for method, options in (("highs", tight), ("highs", {}), ("highs-ipm", tight)):
        res = scipy.optimize.linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method=method,
                                     options=options)
        if res.status == 0:
            return res.x[:p], float(res.x[p])
        messages.append(f"{method}: status {res.status} ({res.message})")
    raise RuntimeError("minimax LP failed: " + "; ".join(messages))


def _minimax(v, y, fac: _Factor, seed_rows: np.ndarray, tol_nm: float,
             r_buf: np.ndarray) -> tuple[float, np.ndarray, int]:
    """Exact ``min_theta max_k |a_k theta - y_k|`` by a cutting plane over rows.

    Returns (achieved max residual [N m], theta, iterations). The achieved value is feasible by
    construction and exceeds the LP optimum by at most ``tol_nm``.
    """
    rows = np.unique(seed_rows)
    g = _constraint_rows(v, rows, fac)
    for it in range(1, MAX_CUTTING_PLANE_ITERATIONS + 1):
        z, t = _minimax_lp_rows(g, y[rows])
        theta = _theta_from_z(z, fac)
        r = _residual(v, y, theta, out=r_buf)
        excess = np.abs(r)
        r_max = float(np.max(excess))
        if r_max <= t + tol_nm:
            return r_max, theta, it
        excess -= t + tol_nm
        excess[rows] = -np.inf                       # both signs of these rows are in the LP
        new = _select_violated(excess, MAX_ROWS_ADDED_PER_ITERATION)
        if new.size == 0:
            raise RuntimeError("minimax cutting plane stalled: violated rows are already in the "
                               "working set (LP tolerance too loose for this data)")
        rows = np.concatenate([rows, new])
        g = np.vstack([g, _constraint_rows(v, new, fac)])
    raise RuntimeError(f"minimax cutting plane did not converge in {MAX_CUTTING_PLANE_ITERATIONS} "
                       f"iterations")


@_single_threaded_blas
def smallest_feasible_e_max(v: np.ndarray, tau_ref: np.ndarray, *,
                            fs_nm: float = FS_NM) -> float:
    """Smallest ``e_max`` [N m] for which Eq. 15 is feasible.

    Solves the minimax (Chebyshev) fit::

        minimize_{theta, t}  t   subject to  -t <= A theta - y <= t   (all N rows)

    with HiGHS (``scipy.optimize.linprog``) by a cutting plane over rows: solve on a working set,
    add the rows whose residual exceeds ``t + 1e-9 FS``, repeat. Returns the achieved
    ``max_k |a_k theta - y_k|``, which is feasible and within ``1e-9 FS`` of the LP optimum.
    """
    v, y = _check_fit_inputs(v, tau_ref)
    fs_nm = _check_positive("fs_nm", fs_nm)
    fac = _factor(v, y, None)
    r_buf = np.empty(v.shape[0])
    seed = _seed_rows(_residual(v, y, _theta_from_z(fac.c, fac), out=r_buf))
    val, _, _ = _minimax(v, y, fac, seed, FEASIBILITY_TOL_FRACTION_FS * fs_nm, r_buf)
    return val


def _seed_rows(r: np.ndarray) -> np.ndarray:
    """Starting rows for the minimax LP: 2 * 25 rows among the 1 % largest |r|, one per run."""
    k = min(r.size, 2 * N_COEFFICIENTS)
    a = np.abs(r)
    thr = np.partition(a, a.size - k)[a.size - k]          # k-th largest |r|
    thr = min(thr, float(np.quantile(a, 0.99)))
    return _select_violated(a - np.nextafter(thr, -np.inf), k)


# --- QP -------------------------------------------------------------------------------------------------------
def _polish(p: np.ndarray, q: np.ndarray, g: np.ndarray, h: np.ndarray, z: np.ndarray,
            lam: np.ndarray | None, tol: float) -> np.ndarray:
    """Exact KKT point of ``min 1/2 z'Pz + q'z s.t. g z <= h`` for the active set suggested by a
    first-order solution (``z``, multipliers ``lam``).

    Starting from the rows with positive multipliers, solve the equality-constrained KKT system,
    then add rows it violates and drop rows with negative multipliers, a few times. Returns ``z``
    unchanged if no consistent active set is found (the first-order point is then used as is).
    """
    n = z.size
    if lam is None or lam.size == 0:
        return z
    lam_scale = max(1.0, float(np.max(np.abs(lam))))
    active = np.flatnonzero(lam > POLISH_MULTIPLIER_RTOL * lam_scale)
    for _ in range(10):
        m = active.size
        kkt = np.zeros((n + m, n + m))
        kkt[:n, :n] = p
        kkt[:n, n:] = g[active].T
        kkt[n:, :n] = g[active]
        rhs = np.concatenate([-q, h[active]])
        sol = np.linalg.lstsq(kkt, rhs, rcond=None)[0]
        zz, mu = sol[:n], sol[n:]
        if not np.allclose(kkt @ sol, rhs, rtol=POLISH_KKT_RTOL,
                           atol=POLISH_KKT_RTOL * max(1.0, np.max(np.abs(rhs)))):
            return z  # inconsistent (dependent rows with conflicting bounds)
        slack = g @ zz - h
        bad_primal = np.setdiff1d(np.flatnonzero(slack > POLISH_PRIMAL_TOL_FRACTION * tol), active)
        mu_scale = max(1.0, float(np.max(np.abs(mu), initial=0.0)))
        bad_dual = active[mu < -POLISH_MULTIPLIER_RTOL * mu_scale]
        if bad_primal.size == 0 and bad_dual.size == 0:
            return zz
        active = np.union1d(np.setdiff1d(active, bad_dual), bad_primal)
    return z


def _project_ldp(d: np.ndarray, g: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact Euclidean projection ``argmin ||w - d|| s.t. g w <= h`` (Lawson & Hanson 1974,
    "Solving Least Squares Problems", ch. 23: least distance programming by NNLS).

    With ``x = w - d`` the problem is ``min ||x|| s.t. E x >= f``, ``E = -g``, ``f = g d - h``;
    NNLS ``min_{u >= 0} ||[E^T; f^T] u - e_{n+1}||`` gives ``x = -r[:n] / r[n]`` from its residual
    ``r``, and the multipliers ``lam = 2 u / r[n]`` of ``min ||w - d||^2``.
    Returns (w, lam). Raises RuntimeError if NNLS reports the constraints incompatible.
    """
    n = d.size
    e, f = -g, g @ d - h
    mat = np.vstack([e.T, f[None, :]])
    rhs = np.zeros(n + 1)
    rhs[n] = 1.0
    u, _ = scipy.optimize.nnls(mat, rhs, maxiter=LDP_NNLS_MAXITER_PER_ROW * mat.shape[1])
    r = mat @ u - rhs
    if abs(r[n]) <= LDP_INCOMPATIBLE_TOL:
        raise RuntimeError("least-distance projection: constraints incompatible")
    x = -r[:n] / r[n]
    return d + x, 2.0 * u / abs(r[n])


class _QPSolver:
    """Cutting-plane solver for Eq. 17 on one factorised data set; reusable across gammas.

    Coordinates: ``z = R phi / sqrt(N)`` (orthonormal data term), then for a given gamma
    ``w = U z`` with ``U^T U = I + gamma * P0^T P0`` (QR of ``[I; sqrt(gamma) P0]``), so that the
    objective divided by N is ``||w - d||^2 + const`` and each small QP is a Euclidean projection
    ``minimize ||w - d||^2 s.t. G_w w <= h``: ProxQP's best-conditioned case for any gamma.
    """

    def __init__(self, v, y, quiet_mask, fac: _Factor, fs_nm: float):
        self.v, self.y, self.quiet_mask, self.fac = v, y, quiet_mask, fac
        self.fs_nm = fs_nm
        self.tol_nm = FEASIBILITY_TOL_FRACTION_FS * fs_nm
        self.r_buf = np.empty(v.shape[0])
        self.abs_buf = np.empty(v.shape[0])
        # working set: row indices, signs (+1: a theta - y <= e, -1: -(a theta - y) <= e), and
        # the signed rows in z coordinates (sign * a_k theta = g_k z)
        self.rows = np.zeros(0, dtype=int)
        self.signs = np.zeros(0, dtype=int)
        self.g = np.zeros((0, N_COEFFICIENTS))
        self.n_fallback_solves = 0
        # P0 with ||A_0c theta||^2 / N = ||P0 z||^2  (phi = R^-1 z, R scaled by 1/sqrt(N))
        self.p0 = scipy.linalg.solve_triangular(fac.r, fac.pen.T, trans="T").T / math.sqrt(fac.n)

    def _add(self, idx: np.ndarray, signs: np.ndarray) -> None:
        g = _constraint_rows(self.v, idx, self.fac) * signs[:, None]
        self.rows = np.concatenate([self.rows, idx])
        self.signs = np.concatenate([self.signs, signs])
        self.g = np.vstack([self.g, g])

    def solve(self, gamma: float, e_max_nm: float) -> Calibration:
        t0 = time.perf_counter()
        fac, v, y = self.fac, self.v, self.y
        n = N_COEFFICIENTS
        # ||z - c||^2 + gamma ||P0 z||^2 = ||[I; sqrt(gamma) P0] z - [c; 0]||^2 = ||U z - d||^2 + k
        q_u, u = np.linalg.qr(np.vstack([np.eye(n), math.sqrt(gamma) * self.p0]))
        d = q_u[:n].T @ fac.c
        w = d.copy()                                    # unconstrained optimum
        bound = e_max_nm + self.tol_nm
        iterations, full_passes = 1, 0
        cand = None       # the rows the next check covers (sorted indices); None: every row
        if self.rows.size:  # warm start from a previous gamma: those rows are true constraints
            w = self._solve_working_set(u, d, w, e_max_nm)
        elif v.shape[0] > 2 * MAX_CANDIDATE_ROWS:   # cold start: first settle on an evenly spaced subset
            cand = np.arange(0, v.shape[0], -(-v.shape[0] // MAX_CANDIDATE_ROWS))
            v_cand, y_cand = v[cand], y[cand]
        while True:
            theta = _theta_from_z(scipy.linalg.solve_triangular(u, w), fac)
            if cand is not None:
                r = _residual(v_cand, y_cand, theta)
                if float(np.max(np.abs(r))) <= bound:
                    cand = None                         # the candidates hold: check every row
            if cand is None:
                r = _residual(v, y, theta, out=self.r_buf)
                full_passes += 1
                if float(np.max(np.abs(r, out=self.abs_buf))) <= bound:
                    break
                cand = _candidate_rows(self.abs_buf, e_max_nm)
                if cand is not None:
                    v_cand, y_cand, r = v[cand], y[cand], r[cand]
            if iterations >= MAX_CUTTING_PLANE_ITERATIONS:
                raise RuntimeError(f"QP cutting plane did not converge in "
                                   f"{MAX_CUTTING_PLANE_ITERATIONS} iterations (max residual "
                                   f"{float(np.max(np.abs(r))):.6g} N m > e_max {e_max_nm:.6g} N m)")
            self._add(*self._most_violated(r, cand, bound))
            w = self._solve_working_set(u, d, w, e_max_nm)
            iterations += 1
        ps = _fit_stats(r, y, self.quiet_mask)
        n_active = int(np.count_nonzero(np.abs(r) >= e_max_nm - self.tol_nm))
        diag = SolveDiagnostics(
            solver=f"cutting-plane+proxqp on {fac.method}" + (
                f" ({self.n_fallback_solves} LDP fallback solves)" if self.n_fallback_solves else ""),
            iterations=iterations, full_passes=full_passes,
            n_working_constraints=int(self.rows.size), n_active_constraints=n_active,
            residual_max_nm=ps.residual_max_nm, rms_error_nm=ps.rms_error_nm,
            quiet_std_nm=ps.quiet_std_nm,
            objective_nm2=ps.rms_error_nm ** 2 * fac.n + gamma * ps.quiet_sum_sq_nm2,
            feasibility_tol_nm=self.tol_nm, solve_time_s=time.perf_counter() - t0)
        return Calibration(theta=theta, method="qp", gamma=gamma, e_max_nm=e_max_nm,
                           fs_nm=self.fs_nm, n_samples=fac.n, n_quiet=fac.n_quiet,
                           diagnostics=diag)

    def _most_violated(self, r: np.ndarray, cand: np.ndarray | None,
                       bound: float) -> tuple[np.ndarray, np.ndarray]:
        """Rows (indices into all rows) and signs to add: the most violated of the residuals ``r``
        on ``cand`` (None: all rows), leaving out rows already constrained with the same sign."""
        excess = np.abs(r)
        excess -= bound
        rows, signs = self.rows, self.signs
        if cand is not None:                            # working-set rows among the candidates
            pos = np.minimum(np.searchsorted(cand, rows), cand.size - 1)
            inside = cand[pos] == rows
            rows, signs = pos[inside], signs[inside]
        excess[rows[signs == np.where(r[rows] >= 0, 1, -1)]] = -np.inf
        new = _select_violated(excess, MAX_ROWS_ADDED_PER_ITERATION, cand)
        if new.size == 0:
            raise RuntimeError("QP cutting plane stalled: the only violated rows are already in "
                               "the working set (small-QP accuracy below the feasibility "
                               f"tolerance {self.tol_nm:.3g} N m); likely causes: a large gamma or an "
                               "e_max within a fraction of a percent of the smallest feasible one")
        new_signs = np.where(r[new] >= 0, 1, -1)
        return (new if cand is None else cand[new]), new_signs

    def _solve_working_set(self, u, d, w0, e_max_nm) -> np.ndarray:
        """``minimize ||w - d||^2 s.t. G_w w <= h`` on the working set (ProxQP, then polish)."""
        g_w = scipy.linalg.solve_triangular(u, self.g.T, trans="T").T     # g z = g U^-1 w
        h = e_max_nm + self.signs * self.y[self.rows]
        p, q = 2.0 * np.eye(N_COEFFICIENTS), -2.0 * d
        sol = qpsolvers.solve_problem(qpsolvers.Problem(p, q, g_w, h), solver="proxqp",
                                      initvals=w0, eps_abs=PROXQP_EPS_ABS, eps_rel=0.0,
                                      max_iter=PROXQP_MAX_ITER)
        if sol.found:
            return _polish(p, q, g_w, h, sol.x, sol.z, self.tol_nm)
        # ProxQP's infeasibility test is loose (its eps_primal_inf is not reachable through
        # qpsolvers): it can call a thin but feasible working set infeasible. Decide with the LP,
        # then solve the projection exactly by Lawson-Hanson LDP/NNLS.
        self._raise_if_infeasible(e_max_nm)
        self.n_fallback_solves += 1
        w, lam = _project_ldp(d, g_w, h)
        return _polish(p, q, g_w, h, w, lam, self.tol_nm)

    def _raise_if_infeasible(self, e_max_nm: float) -> None:
        _, t_ws = _minimax_lp_rows(self.g * self.signs[:, None], self.y[self.rows])
        if t_ws > e_max_nm:
            e_min, _, _ = _minimax(self.v, self.y, self.fac, self.rows, self.tol_nm, self.r_buf)
            raise InfeasibleCalibrationError(e_max_nm, e_min, self.fac.n, self.fs_nm)


def _prepare_qp(v, tau_ref, quiet_mask, fs_nm) -> _QPSolver:
    v, y = _check_fit_inputs(v, tau_ref)
    fs_nm = _check_positive("fs_nm", fs_nm)
    quiet_mask = _check_quiet_mask(quiet_mask, v.shape[0])
    return _QPSolver(v, y, quiet_mask, _factor(v, y, quiet_mask), fs_nm)


@_single_threaded_blas
def fit_qp(v: np.ndarray, tau_ref: np.ndarray, *, gamma: float, quiet_mask: np.ndarray,
           e_max_nm: float = E_MAX_NM, fs_nm: float = FS_NM) -> Calibration:
    """Quiet-segment-penalised, error-bounded calibration (the paper's QP, Eq. 17).

    Solves::

        minimize_theta  ||A theta - y||_2^2 + gamma * ||A_0c theta||_2^2
        subject to      -e_max <= A theta - y <= e_max          (every row k = 1..N, Eq. 15-16)

    with ``A = design_matrix(v)``, ``y = tau_ref``, ``A_0 = A[quiet_mask]`` and
    ``A_0c = A_0 - 1 mu^T``, ``mu = mean of the rows of A_0`` (Eqs. 12-13).

    The solution is exact up to ``feasibility_tol_nm = 1e-9 * fs_nm``: an exact cutting plane over
    rows (module docstring) adds violated rows to a working set, solves the small QP with ProxQP
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
        Error bound ``e_max`` [N m]; default 0.2 % of 80 N m (Eq. 14). ``math.inf`` removes the
        constraints.
    fs_nm : float
        Full scale [N m], sets the feasibility tolerance.

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
    solver = _prepare_qp(v, tau_ref, quiet_mask, fs_nm)
    cal = solver.solve(gamma, e_max_nm)
    diag = cal.diagnostics
    return Calibration(theta=cal.theta, method="qp", gamma=gamma, e_max_nm=e_max_nm,
                       fs_nm=cal.fs_nm, n_samples=cal.n_samples, n_quiet=cal.n_quiet,
                       diagnostics=SolveDiagnostics(**{**asdict(diag),
                                                       "solve_time_s": time.perf_counter() - t0}))


@_single_threaded_blas
def select_gamma(v: np.ndarray, tau_ref: np.ndarray, *, quiet_mask: np.ndarray,
                 e_max_nm: float = E_MAX_NM, gammas: np.ndarray = DEFAULT_GAMMA_GRID,
                 lambda_weight: float = DEFAULT_LAMBDA_WEIGHT,
                 fs_nm: float = FS_NM) -> GammaSelection:
    """Choose gamma on a grid by the paper's criterion (after Eq. 17).

    For each ``gamma`` in ``gammas`` solve :func:`fit_qp` and evaluate::

        J(gamma) = RMSE(tau_hat, tau)^2 + lambda * Var(tau_hat)|_{I_0}        [N^2 m^2]

    with ``RMSE`` over all N calibration samples and the population variance over the quiet
    segment (``= ||A_0c theta||^2 / |I_0|``); return the first minimiser. The data are factorised
    once and the cutting-plane working set is carried from one gamma to the next (its rows are true
    constraints, so each solve stays exact).

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
    solver = _prepare_qp(v, tau_ref, quiet_mask, fs_nm)
    cals = [solver.solve(float(gi), e_max_nm) for gi in g]
    rmse = np.array([c.diagnostics.rms_error_nm for c in cals])
    qvar = np.array([c.diagnostics.quiet_std_nm ** 2 for c in cals])
    crit = rmse ** 2 + lam * qvar
    best = int(np.argmin(crit))
    return GammaSelection(gammas=g, criterion_nm2=crit, rmse_nm=rmse, quiet_var_nm2=qvar,
                          lambda_weight=lam, best_index=best, gamma=float(g[best]),
                          calibration=cals[best])
