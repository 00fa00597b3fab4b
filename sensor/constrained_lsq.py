"""Large-N least squares under an element-wise residual bound, with a penalty on the fit's spread over a row subset.

The engine of the photo-reflector calibration (:mod:`sensor.calibration`, paper Eq. 17), for any design
matrix with few columns (n ~ 25) and many rows (N up to 1e6 and more). A :class:`Problem` is::

    minimize_x   ||A x - b||_2^2 + w * ||C_S A x||_2^2
    subject to   |A x - b| <= e                   (element-wise, every row k = 1..N)

with ``A`` the design (N x n), ``b`` the target, ``e`` the residual bound (``inf``: no constraint), ``S``
the penalty rows and ``C_S`` the centring over them (``||C_S A x||^2 = sum_{k in S} (a_k x - mean_S(A x))^2``,
|S| times the population variance of the fit on S), ``w >= 0`` the penalty weight. :func:`solve` returns a
:class:`Solution` (``found`` False and ``status = "infeasible"`` when no ``x`` meets the bound);
:func:`solve_path` solves one problem for several penalty weights; :func:`solve_minimax` gives the smallest
feasible bound ``min_x max_k |a_k x - b_k|``.

The design is a dense array or a :class:`StructuredDesign`: a rule that fills rows of a well-scaled column
basis on demand and multiplies by ``A`` without forming it (the calibration's per-channel cubics).

Numerics
--------
The design is mapped to a well-scaled basis ``B = A T`` (``T`` invertible; the design's own choice, e.g. every
column scaled into [-1, 1]) and ``B = Q R`` is factorised in one streaming pass of chunks of
:data:`CHUNK_ROWS` rows (O(N n^2) work, O(chunk) memory): a Householder tall-skinny QR (TSQR) for short
records, and for N >= :data:`SKETCH_MIN_N` a Cholesky QR of ``B R_s^-1``, preconditioned by the R factor
``R_s`` of a random row sample, which runs at matrix-multiply speed and is accepted only if
``cond(B R_s^-1) <= 1e3`` (else TSQR). Either way the conditioning is that of ``B``, not of ``B^T B``. The
centred penalty block comes out of the same pass.

In the coordinates ``z = R phi / sqrt(N)`` (``x = T phi``) the objective divided by N is
``||z - c||^2 + w ||P0 z||^2 + const`` and the constraint rows are sqrt(N) times rows of the orthonormal
``Q``; a second change ``v = U z`` with ``U^T U = I + w P0^T P0`` turns every subproblem into a Euclidean
projection ``minimize ||v - d||^2 s.t. G v <= h``, well conditioned for any w.

The 2N inequality constraints are handled by an exact cutting-plane (working-set) scheme: solve with the
current working set, evaluate ``A x - b`` on all rows (one O(N n) pass), add the most violated rows (the worst
of each run of neighbouring violations first), repeat until no row exceeds ``e`` by more than the feasibility
tolerance. Between passes over all rows only a candidate subset is checked (the rows whose residual was above
half the bound, at most :data:`MAX_CANDIDATE_ROWS`; on a cold start with more than twice that many rows, an
evenly spaced subset): when the candidates meet the bound, a pass over all rows confirms it or starts a new
candidate set, so the stopping test is always on all rows. The small QPs go to ProxQP through qpsolvers
(solver ``"proxqp"``) and are polished to the exact KKT point of their active set; if ProxQP reports failure
on a working set that an LP shows to be feasible (its infeasibility test is loose for thin feasible sets),
the projection is solved exactly by Lawson-Hanson least-distance programming (``scipy.optimize.nnls``).
Because every working set is a subset of the true constraints, the final point solves the full problem; if a
working set is infeasible, so is the full problem, and the smallest feasible bound is found by a minimax LP
(HiGHS), also by a cutting plane over rows. All BLAS calls are small and run on one thread
(:func:`sensor.blas_threads.single_threaded_blas`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
import qpsolvers
import scipy.linalg
import scipy.optimize

from sensor.blas_threads import single_threaded_blas

__all__ = [
    "Basis",
    "StructuredDesign",
    "DenseDesign",
    "Problem",
    "Solution",
    "MinimaxSolution",
    "solve",
    "solve_path",
    "solve_minimax",
]

# --- Numerical settings ----------------------------------------------------------------------------------
CHUNK_ROWS = 4_096
"""Rows per chunk in the streaming passes over the data (memory ~ (n + 1) * 8 bytes * CHUNK_ROWS)."""

MAX_ROWS_ADDED_PER_ITERATION = 128
"""Cutting plane: at most this many violated rows enter the working set per iteration."""

CANDIDATE_MARGIN_FRACTION = 0.5
"""Cutting plane: after a pass over all rows, the rows with ``|a_k x - b_k|`` above this fraction of ``e``
become the candidate set that the next iterations check (the others would need the solution to move their
prediction by at least half the bound); a pass over all rows confirms the result."""

MAX_CANDIDATE_ROWS = 65_536
"""Cutting plane: the candidate set keeps at most this many rows (the largest residuals); above half of N the
candidate set is all rows."""

MAX_CUTTING_PLANE_ITERATIONS = 200
"""Cutting plane: iteration cap; reaching it raises instead of returning an unproven point."""

SKETCH_ROWS = 16_384
"""Rows sampled for the preconditioner of the sketched Cholesky QR (see ``_factor_sketched``)."""

SKETCH_MIN_N = 4 * SKETCH_ROWS
"""Data at least this long are factorised by the sketched Cholesky QR; shorter ones by TSQR."""

SKETCH_SEED = 20_240_917
"""Seed of the row sample (fixed: the same data give the same factor)."""

SKETCH_MAX_COND = 1e3
"""Accept the sketched factor only if cond(R_c) <= 1e3 (relative error ~ eps * 1e6); else TSQR."""

RANK_RTOL = 1e-12
"""The scaled design is called rank-deficient when min |R_ii| / max |R_ii| falls below this."""

PROXQP_EPS_ABS = 1e-11
"""ProxQP absolute stopping tolerance for the small working-set QPs (qpsolvers default 1e-3 is far too loose);
the KKT polish then makes the point exact for its active set."""

PROXQP_MAX_ITER = 10_000
"""ProxQP outer-iteration cap."""

HIGHS_TOLERANCE = 1e-9
"""HiGHS primal/dual feasibility tolerance for the minimax LP (default 1e-7; at 1e-10, the smallest value HiGHS
accepts, its simplex sometimes stops on numerical difficulties)."""

POLISH_MULTIPLIER_RTOL = 1e-9
"""A row of a small QP counts as active when its multiplier exceeds this times the largest multiplier (or 1),
and a polished active set is rejected when a multiplier falls below minus this times the largest: ProxQP's
multipliers at ``PROXQP_EPS_ABS`` are accurate to far better than 1e-9 relative of the largest."""

POLISH_KKT_RTOL = 1e-9
"""The equality-constrained KKT system of a polished active set is accepted as consistent when its
least-squares solution reproduces the right-hand side to this relative (and ``1e-9 * max|rhs|`` absolute)
accuracy; a larger misfit means dependent rows with conflicting bounds, and the unpolished point is kept."""

POLISH_PRIMAL_TOL_FRACTION = 1e-3
"""A row outside the polished active set counts as violated when it exceeds its bound by more than this
fraction of the feasibility tolerance: the polished point then meets the cutting plane's acceptance test with
a 1000x margin."""

LDP_NNLS_MAXITER_PER_ROW = 50
"""Iteration cap of ``scipy.optimize.nnls`` in the LDP fallback, per constraint row (scipy's default is 3 per
column; Lawson-Hanson adds or drops one row per iteration, and degenerate working sets cycle longer)."""

LDP_INCOMPATIBLE_TOL = 1e-14
"""The LDP's NNLS residual component ``r[n] = (f^T u - 1)`` at or below this in magnitude means
``[E^T; f^T] u = e_{n+1}`` is solved exactly, i.e. the constraints are incompatible (Lawson & Hanson, ch. 23);
for a compatible set ``|r[n]|`` is of order 1, so 1e-14 (~50 float64 epsilons) separates the two."""


# --- Designs -----------------------------------------------------------------------------------------------
@runtime_checkable
class Basis(Protocol):
    """A well-scaled column basis ``B = A T`` of a design (``T`` invertible, n x n).

    ``constant_column`` is the index of a column of ``B`` that is identically 1 (None if there is none): its
    centred version is zero, so the penalty factor leaves it out.
    """

    constant_column: int | None

    def fill_t(self, rows: slice | np.ndarray, out_t: np.ndarray) -> None:
        """Write ``B[rows].T`` into ``out_t``, shape (n, k)."""

    def to_design(self, phi: np.ndarray) -> np.ndarray:
        """Coefficients ``x = T phi`` of the design from those of the basis."""


@runtime_checkable
class StructuredDesign(Protocol):
    """A design matrix ``A`` (``shape`` = (N, n)) given by a rule and never formed."""

    shape: tuple[int, int]

    def matvec(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``A @ x``, shape (N,), written into ``out`` if given."""

    def take(self, rows: np.ndarray) -> StructuredDesign:
        """The design of the rows ``rows`` (sorted indices)."""

    def basis(self, rows: np.ndarray | None = None) -> Basis:
        """A well-scaled basis, its scaling taken from the sample ``rows`` (None: from all rows)."""


@dataclass(frozen=True, eq=False)
class DenseDesign:
    """A design given as an array ``matrix`` (N, n); its basis scales every column to max |B_kj| = 1."""

    matrix: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.matrix.shape

    def matvec(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        return np.matmul(self.matrix, x, out=out)

    def take(self, rows: np.ndarray) -> DenseDesign:
        return DenseDesign(self.matrix[rows])

    def basis(self, rows: np.ndarray | None = None) -> _ScaledColumns:
        src = self.matrix if rows is None else self.matrix[rows]
        peak = np.max(np.abs(src), axis=0)
        if np.any(peak == 0.0):
            if rows is not None:
                return self.basis()
            raise ValueError(f"Problem.design: column(s) {np.flatnonzero(peak == 0.0).tolist()} are zero; "
                             f"the design is rank-deficient")
        return _ScaledColumns(self.matrix, 1.0 / peak)


@dataclass(frozen=True, eq=False)
class _ScaledColumns:
    matrix: np.ndarray
    scale: np.ndarray
    constant_column: int | None = None

    def fill_t(self, rows: slice | np.ndarray, out_t: np.ndarray) -> None:
        np.multiply(self.matrix[rows].T, self.scale[:, None], out=out_t)

    def to_design(self, phi: np.ndarray) -> np.ndarray:
        return phi * self.scale


# --- Problem and solution ------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Problem:
    """``minimize ||A x - b||^2 + w ||C_S A x||^2  s.t.  |A x - b| <= e`` (module docstring).

    Attributes
    ----------
    design : numpy.ndarray, shape (N, n), or StructuredDesign
        ``A``; N >= n >= 1. An array is stored as a float copy.
    target : numpy.ndarray, shape (N,)
        ``b`` (any unit; the residual, the bound and the tolerances share it).
    residual_bound : float
        ``e`` > 0, ``math.inf`` for none.
    penalty_rows : numpy.ndarray of bool, shape (N,), optional
        ``S``, at least 2 rows; None for no penalty.
    penalty_weight : float
        ``w`` >= 0 and finite; > 0 needs ``penalty_rows``.
    """

    design: np.ndarray | StructuredDesign
    target: np.ndarray
    residual_bound: float = math.inf
    penalty_rows: np.ndarray | None = None
    penalty_weight: float = 0.0

    def __post_init__(self) -> None:
        design = self.design
        if not isinstance(design, StructuredDesign):
            design = np.array(design, dtype=float)
            if design.ndim != 2:
                raise ValueError(f"Problem.design must be a 2-D array (N, n); got shape {design.shape}")
            if not np.all(np.isfinite(design)):
                raise ValueError("Problem.design contains NaN or inf")
        n_rows, n_cols = design.shape
        if not n_rows >= n_cols >= 1:
            raise ValueError(f"Problem.design must have shape (N, n) with N >= n >= 1; got {design.shape}")
        target = np.array(self.target, dtype=float)
        if target.shape != (n_rows,):
            raise ValueError(f"Problem.target must have shape (N,) = ({n_rows},) to match the design "
                             f"{design.shape}; got shape {target.shape}")
        if not np.all(np.isfinite(target)):
            raise ValueError("Problem.target contains NaN or inf")
        bound = float(self.residual_bound)
        if not bound > 0.0:
            raise ValueError(f"Problem.residual_bound must be > 0 (math.inf for none); got {self.residual_bound!r}")
        rows = self.penalty_rows
        if rows is not None:
            rows = np.asarray(rows)
            if rows.dtype != bool or rows.shape != (n_rows,):
                raise ValueError(f"Problem.penalty_rows must be a boolean array of shape ({n_rows},); got dtype "
                                 f"{rows.dtype} and shape {rows.shape}")
            if np.count_nonzero(rows) < 2:
                raise ValueError(f"Problem.penalty_rows selects {np.count_nonzero(rows)} rows; at least 2 are "
                                 f"needed for a spread")
        weight = _check_penalty_weight(self.penalty_weight, rows is not None)
        for name, value in (("design", design), ("target", target), ("residual_bound", bound),
                            ("penalty_rows", rows), ("penalty_weight", weight)):
            object.__setattr__(self, name, value)

    @property
    def structured_design(self) -> StructuredDesign:
        """The design as a :class:`StructuredDesign` (an array wrapped in :class:`DenseDesign`)."""
        return self.design if isinstance(self.design, StructuredDesign) else DenseDesign(self.design)


@dataclass(frozen=True, eq=False)
class Solution:
    """The result of :func:`solve`.

    Attributes
    ----------
    found : bool
        True when ``x`` solves the problem; False when no ``x`` meets the bound.
    status : {"optimal", "infeasible"}
    x : numpy.ndarray, shape (n,), or None
        The minimiser (None if not found).
    residual : numpy.ndarray, shape (N,), or None
        ``A x - b``.
    objective : float
        ``||A x - b||^2 + w ||C_S A x||^2`` (NaN if not found).
    residual_max : float
        ``max_k |a_k x - b_k|``.
    residual_rms : float
        ``sqrt(mean((A x - b)^2))``.
    penalty : float or None
        ``||C_S A x||^2`` (None without penalty rows; reported also when ``w = 0``).
    iterations : int
        Subproblems solved (1: the unconstrained minimiser met the bound).
    full_passes : int
        Evaluations of ``A x - b`` on all N rows.
    n_working_rows : int
        Rows in the final working set (of the 2N constraints).
    n_active_rows : int
        Rows with ``|a_k x - b_k| >= e - feasibility_tol``.
    kkt_residual : float
        Largest violation of the first-order conditions (stationarity, complementarity, sign of the
        multipliers) of the final working-set subproblem, in the units of ``b`` (the subproblem's objective is
        the mean-square residual in scaled coordinates); 0 for an unconstrained minimiser.
    solver : str
        The factorisation (``"tsqr"`` or ``"sketched-cholqr"``), prefixed by ``"cutting-plane+proxqp on"`` for
        a bounded or penalised problem; the count of exact LDP fallback solves is appended if there were any.
    smallest_feasible_bound : float or None
        When infeasible: ``min_x max_k |a_k x - b_k|`` (:func:`solve_minimax`); any bound at or above it is
        feasible.
    solve_time_s : float
        Wall time [s] (for :func:`solve_path`, of this weight's cutting plane only).
    """

    found: bool
    status: Literal["optimal", "infeasible"]
    x: np.ndarray | None
    residual: np.ndarray | None
    objective: float
    residual_max: float
    residual_rms: float
    penalty: float | None
    iterations: int
    full_passes: int
    n_working_rows: int
    n_active_rows: int
    kkt_residual: float
    solver: str
    smallest_feasible_bound: float | None = None
    solve_time_s: float = field(default=math.nan, compare=False)


@dataclass(frozen=True, eq=False)
class MinimaxSolution:
    """The result of :func:`solve_minimax`: ``x`` (n,) achieving ``bound = max_k |a_k x - b_k|``, within the
    feasibility tolerance of the LP optimum, after ``iterations`` LPs."""

    x: np.ndarray
    bound: float
    iterations: int


def _check_penalty_weight(weight: float, has_rows: bool) -> float:
    w = float(weight)
    if not (math.isfinite(w) and w >= 0.0):
        raise ValueError(f"Problem.penalty_weight must be >= 0 and finite; got {weight!r}")
    if w > 0.0 and not has_rows:
        raise ValueError(f"Problem.penalty_weight = {w:g} needs Problem.penalty_rows (None given)")
    return w


def _check_tol(feasibility_tol: float) -> float:
    tol = float(feasibility_tol)
    if not (math.isfinite(tol) and tol > 0.0):
        raise ValueError(f"feasibility_tol must be > 0 and finite (units of the target); got {feasibility_tol!r}")
    return tol


# --- Public solvers ------------------------------------------------------------------------------------------
@single_threaded_blas
def solve(problem: Problem, *, feasibility_tol: float) -> Solution:
    """Solve ``problem`` exactly up to ``feasibility_tol``.

    Parameters
    ----------
    problem : Problem
    feasibility_tol : float
        A row counts as violating the bound when ``|a_k x - b_k| > e + feasibility_tol`` (units of the target).

    Returns
    -------
    Solution
        ``found`` False (``status = "infeasible"``, ``smallest_feasible_bound`` set) when no ``x`` meets the
        bound. Without bound and penalty weight the least-squares solution of one factorisation.

    Raises
    ------
    ValueError
        If the design is numerically rank-deficient or ``feasibility_tol`` is not > 0.
    RuntimeError
        If the cutting plane stalls or does not converge in :data:`MAX_CUTTING_PLANE_ITERATIONS` iterations
        (small-QP accuracy below the tolerance; a very large penalty weight or a bound within a fraction of a
        percent of the smallest feasible one).
    """
    tol = _check_tol(feasibility_tol)
    t0 = time.perf_counter()
    design, b = problem.structured_design, problem.target
    if math.isinf(problem.residual_bound) and problem.penalty_weight == 0.0:
        fac = _factor(design, b, None)
        x = _x_from_z(fac.c, fac)
        r = _residual(design, b, x)
        return _solution(x, r, b, problem.penalty_rows, 0.0, problem.residual_bound, tol, solver=fac.method,
                         iterations=1, full_passes=1, n_working_rows=0, kkt_residual=0.0,
                         solve_time_s=time.perf_counter() - t0)
    cp = _CuttingPlane(design, b, problem.penalty_rows, _factor(design, b, problem.penalty_rows), tol)
    return cp.solve(problem.penalty_weight, problem.residual_bound)


@single_threaded_blas
def solve_path(problem: Problem, penalty_weights: Sequence[float], *, feasibility_tol: float) -> list[Solution]:
    """Solve ``problem`` once per penalty weight (``problem.penalty_weight`` is replaced), in the given order.

    The data are factorised once and the working set is carried from one weight to the next (its rows are true
    constraints, so each solve stays exact). If the bound is infeasible (for one weight it is for all) every
    solution is the infeasible one. Parameters, errors: as :func:`solve`; every weight is checked as
    ``Problem.penalty_weight`` first.
    """
    tol = _check_tol(feasibility_tol)
    weights = [_check_penalty_weight(w, problem.penalty_rows is not None) for w in penalty_weights]
    design, b = problem.structured_design, problem.target
    cp = _CuttingPlane(design, b, problem.penalty_rows, _factor(design, b, problem.penalty_rows), tol)
    out: list[Solution] = []
    for w in weights:
        sol = cp.solve(w, problem.residual_bound)
        if not sol.found:
            return [sol] * len(weights)
        out.append(sol)
    return out


@single_threaded_blas
def solve_minimax(problem: Problem, *, feasibility_tol: float) -> MinimaxSolution:
    """The smallest feasible bound: ``minimize_{x, t} t  s.t.  -t <= A x - b <= t`` (all N rows).

    Solved with HiGHS (``scipy.optimize.linprog``) by a cutting plane over rows: solve on a working set, add
    the rows whose residual exceeds ``t + feasibility_tol``, repeat. The returned ``bound`` is the achieved
    ``max_k |a_k x - b_k|``: feasible, and within ``feasibility_tol`` of the LP optimum. The problem's bound
    and penalty are not used.
    """
    tol = _check_tol(feasibility_tol)
    design, b = problem.structured_design, problem.target
    fac = _factor(design, b, None)
    r_buf = np.empty(b.size)
    seed = _seed_rows(_residual(design, b, _x_from_z(fac.c, fac), out=r_buf), design.shape[1])
    val, x, iterations = _minimax(design, b, fac, seed, tol, r_buf)
    return MinimaxSolution(x=x, bound=val, iterations=iterations)


def _solution(x, r, b, penalty_rows, weight, bound, tol, **counts: Any) -> Solution:
    """A found :class:`Solution` with the residual statistics of ``r = A x - b``."""
    pss = None
    if penalty_rows is not None:
        fit = r[penalty_rows] + b[penalty_rows]
        fit -= fit.mean()
        pss = float(np.dot(fit, fit))
    rms = math.sqrt(float(np.dot(r, r)) / r.size)
    return Solution(found=True, status="optimal", x=x, residual=r,
                    objective=rms ** 2 * r.size + weight * (pss or 0.0),
                    residual_max=float(np.max(np.abs(r))), residual_rms=rms, penalty=pss,
                    n_active_rows=int(np.count_nonzero(np.abs(r) >= bound - tol)), **counts)


# --- Factorisation -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Factor:
    """Column basis and triangular factors of one data set (module docstring)."""

    n: int
    basis: Basis
    r: np.ndarray            # (n, n) upper triangular, R / sqrt(N) with B = Q R
    c: np.ndarray            # (n,) Q^T b / sqrt(N)
    pen: np.ndarray | None   # (k, n): pen^T pen = B_Sc^T B_Sc (centred penalty block, unscaled)
    method: str              # "tsqr" or "sketched-cholqr"


def _basis_rows(basis: Basis, rows: np.ndarray, n_cols: int) -> np.ndarray:
    """``B`` rows (k, n) for the given row indices."""
    bt = np.empty((n_cols, rows.size))
    basis.fill_t(rows, bt)
    return np.ascontiguousarray(bt.T)


def _check_rank(r: np.ndarray, shape) -> None:
    d = np.abs(np.diag(r))
    if d.min() < RANK_RTOL * d.max():
        raise ValueError(f"the design (shape {shape}) is numerically rank-deficient (min/max |R_ii| = "
                         f"{d.min() / d.max():.2e} < {RANK_RTOL:g}): its columns do not determine {shape[1]} "
                         f"coefficients")


def _factor(design: StructuredDesign, b: np.ndarray, penalty_rows: np.ndarray | None) -> _Factor:
    """Factorise ``B = Q R`` and the centred penalty block in one streaming pass over the data.

    Large data (N >= :data:`SKETCH_MIN_N`) go through :func:`_factor_sketched` (randomly preconditioned
    Cholesky QR, gemm speed); if its accuracy check fails, and for small data, the Householder TSQR of
    :func:`_factor_tsqr` is used.
    """
    n = design.shape[0]
    if n >= SKETCH_MIN_N:
        rows = np.sort(np.random.default_rng(SKETCH_SEED).choice(n, size=min(n, SKETCH_ROWS), replace=False))
        fac = _factor_sketched(design, b, penalty_rows, design.basis(rows), rows)  # the sample sets the scaling
        if fac is not None:
            return fac
    return _factor_tsqr(design, b, penalty_rows, design.basis())


def _factor_tsqr(design: StructuredDesign, b, penalty_rows, basis: Basis) -> _Factor:
    """Householder TSQR of ``[B b]`` and of the penalty rows ``[1 B_nc]`` (``B_nc``: ``B`` without its
    constant column).

    The R factor of ``[1, X]`` carries the centred block in its trailing part: with
    ``R = [[r11, r12], [0, R22]]``, ``R22^T R22 = X^T X - X^T 1 1^T X / n = X_c^T X_c`` (Householder
    centring, no cancellation).
    """
    n, p = design.shape
    keep = np.ones(p, dtype=bool)
    if basis.constant_column is not None:
        keep[basis.constant_column] = False
    p_q = int(np.count_nonzero(keep)) + 1
    buf_t = np.empty((p + 1, min(n, CHUNK_ROWS)))
    r_aug = np.zeros((0, p + 1))
    r_q = np.zeros((0, p_q))
    for i in range(0, n, CHUNK_ROWS):
        j = min(n, i + CHUNK_ROWS)
        bt = buf_t[:, :j - i]
        basis.fill_t(slice(i, j), bt[:p])
        bt[p] = b[i:j]
        r_aug = np.linalg.qr(np.vstack([r_aug, bt.T]), mode="r")
        if penalty_rows is not None:
            sel = penalty_rows[i:j]
            kq = int(np.count_nonzero(sel))
            if kq:
                q = np.empty((kq, p_q))
                q[:, 0] = 1.0
                q[:, 1:] = bt[:p][keep][:, sel].T
                r_q = np.linalg.qr(np.vstack([r_q, q]), mode="r")
    r = r_aug[:p, :p] / math.sqrt(n)
    _check_rank(r, design.shape)
    c = r_aug[:p, p] / math.sqrt(n)
    pen = None
    if penalty_rows is not None:
        pen = np.zeros((p_q - 1, p))
        m = min(r_q.shape[0], p_q) - 1
        pen[:m, keep] = r_q[1:m + 1, 1:]
    return _Factor(n=n, basis=basis, r=r, c=c, pen=pen, method="tsqr")


def _factor_sketched(design: StructuredDesign, b, penalty_rows, basis: Basis, rows) -> _Factor | None:
    """Randomly preconditioned Cholesky QR; None if its accuracy check fails.

    1. ``R_s`` = Householder R of the sample ``rows`` of ``B`` (uniform, fixed seed).
    2. One pass: ``W = B R_s^-1`` chunk by chunk, accumulating ``W^T W``, ``W^T b`` and, for the penalty rows,
       the shifted sums of ``W`` (shift = mean of the sample's penalty rows, so the centred Gram
       ``sum (w - mu)(w - mu)^T`` is formed without cancellation).
    3. ``W^T W = R_c^T R_c`` (Cholesky) and ``R = R_c R_s``, ``Q^T b = R_c^-T W^T b``.

    If the sample represents the rows well, ``W`` has nearly orthogonal columns (cond ~ 1-10), so the Gram
    matrix loses nothing; the check ``cond(R_c) <= SKETCH_MAX_COND`` (relative error of the factor
    ~ eps cond(R_c)^2 <= 2e-10) guards against a sample that missed high-leverage rows. This is the randomized
    Cholesky QR of Fan, Guo & Lin (2021), with a row-sampling sketch.
    """
    n, p = design.shape
    b_s = _basis_rows(basis, rows, p)
    r_s = np.linalg.qr(b_s, mode="r")
    d = np.abs(np.diag(r_s))
    if d.min() < RANK_RTOL * d.max():
        return None
    rs_inv_t = scipy.linalg.solve_triangular(r_s, np.eye(p)).T   # R_s^-T
    shift = np.zeros((p, 1))
    if penalty_rows is not None and np.any(penalty_rows[rows]):
        shift = (b_s[penalty_rows[rows]] @ rs_inv_t.T).mean(axis=0)[:, None]
    gw = np.zeros((p, p))
    gy = np.zeros(p)
    sq = np.zeros((p, p))
    sq1 = np.zeros(p)
    n_pen = 0
    buf_t = np.empty((p, CHUNK_ROWS))
    wbuf_t = np.empty((p, CHUNK_ROWS))
    for i in range(0, n, CHUNK_ROWS):
        j = min(n, i + CHUNK_ROWS)
        bt, wt = buf_t[:, :j - i], wbuf_t[:, :j - i]
        basis.fill_t(slice(i, j), bt)
        np.matmul(rs_inv_t, bt, out=wt)                 # W^T = R_s^-T B^T
        gw += wt @ wt.T
        gy += wt @ b[i:j]
        if penalty_rows is not None:
            sel = penalty_rows[i:j]
            if sel.any():
                wq = wt[:, sel] - shift
                sq += wq @ wq.T
                sq1 += wq.sum(axis=1)
                n_pen += wq.shape[1]
    try:
        r_c = np.linalg.cholesky(gw).T
    except np.linalg.LinAlgError:
        return None
    if np.linalg.cond(r_c) > SKETCH_MAX_COND:
        return None
    r = (r_c @ r_s) / math.sqrt(n)
    _check_rank(r, design.shape)
    c = scipy.linalg.solve_triangular(r_c, gy, trans="T") / math.sqrt(n)
    pen = None
    if penalty_rows is not None:
        gq = sq - np.outer(sq1, sq1) / n_pen           # centred Gram of the penalty W rows
        evals, evecs = np.linalg.eigh(0.5 * (gq + gq.T))
        pen = (np.sqrt(np.clip(evals, 0.0, None))[:, None] * evecs.T) @ r_s
    return _Factor(n=n, basis=basis, r=r, c=c, pen=pen, method="sketched-cholqr")


def _x_from_z(z: np.ndarray, fac: _Factor) -> np.ndarray:
    return fac.basis.to_design(scipy.linalg.solve_triangular(fac.r, z))


def _constraint_rows(fac: _Factor, idx: np.ndarray) -> np.ndarray:
    """Rows ``g_k`` with ``a_k x = g_k z`` (``g_k = R^-T b_k``), shape (len(idx), n)."""
    b = _basis_rows(fac.basis, idx, fac.r.shape[0])
    return scipy.linalg.solve_triangular(fac.r, b.T, trans="T").T


def _residual(design: StructuredDesign, b, x, out: np.ndarray | None = None) -> np.ndarray:
    """``r = A x - b`` on all rows (one streaming pass)."""
    r = design.matvec(x, out=out)
    r -= b
    return r


# --- Row selection -------------------------------------------------------------------------------------------
def _candidate_rows(abs_r: np.ndarray, bound: float) -> np.ndarray | None:
    """Rows the cutting plane re-checks between passes over all rows (sorted indices): those with
    ``|r| > CANDIDATE_MARGIN_FRACTION * bound``, at most :data:`MAX_CANDIDATE_ROWS` of the largest; None (check
    every row) if that would be more than half of them."""
    idx = np.flatnonzero(abs_r > CANDIDATE_MARGIN_FRACTION * bound)
    if idx.size > MAX_CANDIDATE_ROWS:
        top = np.argpartition(-abs_r[idx], MAX_CANDIDATE_ROWS - 1)[:MAX_CANDIDATE_ROWS]
        idx = np.sort(idx[top])
    return None if idx.size > abs_r.size // 2 else idx


def _select_violated(excess: np.ndarray, k_max: int, sample_index: np.ndarray | None = None) -> np.ndarray:
    """Up to ``k_max`` positions in ``excess`` with ``excess > 0``.

    Violations come in runs of neighbouring samples that carry nearly the same constraint, so the worst row of
    each run is taken first (runs ranked by their worst excess), then, if room is left, the next worst rows
    overall. ``sample_index`` (sorted) gives each position's sample number when ``excess`` covers a subset of
    the rows (default: position = sample).
    """
    idx = np.flatnonzero(excess > 0)
    if idx.size <= k_max:
        return idx
    ex = excess[idx]
    samples = idx if sample_index is None else sample_index[idx]
    starts = np.flatnonzero(np.concatenate([[True], np.diff(samples) > 1]))
    run_max = np.maximum.reduceat(ex, starts)
    ends = np.append(starts[1:], idx.size)
    top = np.argpartition(-run_max, k_max - 1)[:k_max] if starts.size > k_max else np.arange(starts.size)
    heads = np.array([starts[j] + int(np.argmax(ex[starts[j]:ends[j]])) for j in top], dtype=int)
    if heads.size < k_max:
        ex_rest = ex.copy()
        ex_rest[heads] = -np.inf
        more = np.argpartition(-ex_rest, k_max - heads.size - 1)[:k_max - heads.size]
        heads = np.concatenate([heads, more])
    return idx[heads]


def _seed_rows(r: np.ndarray, n_cols: int) -> np.ndarray:
    """Starting rows for the minimax LP: 2 n (n: the design's columns) among the 1 % largest |r|, one per run."""
    k = min(r.size, 2 * n_cols)
    a = np.abs(r)
    thr = np.partition(a, a.size - k)[a.size - k]          # k-th largest |r|
    thr = min(thr, float(np.quantile(a, 0.99)))
    return _select_violated(a - np.nextafter(thr, -np.inf), k)


# --- Minimax LP (smallest feasible bound) ------------------------------------------------------------------
def _minimax_lp_rows(g: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """``min t s.t. |g z - y| <= t`` on the given rows (HiGHS). Returns (z, t).

    Tries HiGHS with tight feasibility tolerances first; HiGHS occasionally stops with status 4 ("numerical
    difficulties") at tight tolerances, so the default settings and then the interior-point method are tried
    before giving up.
    """
    k, p = g.shape
    cost = np.zeros(p + 1)
    cost[p] = 1.0
    ones = np.ones((k, 1))
    a_ub = np.block([[g, -ones], [-g, -ones]])
    b_ub = np.concatenate([y, -y])
    bounds = [(None, None)] * p + [(0, None)]
    tight = {"primal_feasibility_tolerance": HIGHS_TOLERANCE, "dual_feasibility_tolerance": HIGHS_TOLERANCE}
    messages = []
    for method, options in (("highs", tight), ("highs", {}), ("highs-ipm", tight)):
        res = scipy.optimize.linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method=method, options=options)
        if res.status == 0:
            return res.x[:p], float(res.x[p])
        messages.append(f"{method}: status {res.status} ({res.message})")
    raise RuntimeError("minimax LP failed: " + "; ".join(messages))


def _minimax(design, b, fac: _Factor, seed_rows: np.ndarray, tol: float,
             r_buf: np.ndarray) -> tuple[float, np.ndarray, int]:
    """Exact ``min_x max_k |a_k x - b_k|`` by a cutting plane over rows.

    Returns (achieved max residual, x, iterations). The achieved value is feasible by construction and exceeds
    the LP optimum by at most ``tol``.
    """
    rows = np.unique(seed_rows)
    g = _constraint_rows(fac, rows)
    for it in range(1, MAX_CUTTING_PLANE_ITERATIONS + 1):
        z, t = _minimax_lp_rows(g, b[rows])
        x = _x_from_z(z, fac)
        r = _residual(design, b, x, out=r_buf)
        excess = np.abs(r)
        r_max = float(np.max(excess))
        if r_max <= t + tol:
            return r_max, x, it
        excess -= t + tol
        excess[rows] = -np.inf                       # both signs of these rows are in the LP
        new = _select_violated(excess, MAX_ROWS_ADDED_PER_ITERATION)
        if new.size == 0:
            raise RuntimeError("minimax cutting plane stalled: violated rows are already in the working set "
                               "(LP tolerance too loose for this data)")
        rows = np.concatenate([rows, new])
        g = np.vstack([g, _constraint_rows(fac, new)])
    raise RuntimeError(f"minimax cutting plane did not converge in {MAX_CUTTING_PLANE_ITERATIONS} iterations")


# --- Small QPs -----------------------------------------------------------------------------------------------
def _polish(p: np.ndarray, q: np.ndarray, g: np.ndarray, h: np.ndarray, z: np.ndarray,
            lam: np.ndarray | None, tol: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Exact KKT point of ``min 1/2 z'Pz + q'z s.t. g z <= h`` for the active set suggested by a first-order
    solution (``z``, multipliers ``lam``); returns the point and its multipliers.

    Starting from the rows with positive multipliers, solve the equality-constrained KKT system, then add rows
    it violates and drop rows with negative multipliers, a few times. Returns ``(z, lam)`` unchanged if no
    consistent active set is found (the first-order point is then used as is).
    """
    n = z.size
    if lam is None or lam.size == 0:
        return z, lam
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
            return z, lam  # inconsistent (dependent rows with conflicting bounds)
        slack = g @ zz - h
        bad_primal = np.setdiff1d(np.flatnonzero(slack > POLISH_PRIMAL_TOL_FRACTION * tol), active)
        mu_scale = max(1.0, float(np.max(np.abs(mu), initial=0.0)))
        bad_dual = active[mu < -POLISH_MULTIPLIER_RTOL * mu_scale]
        if bad_primal.size == 0 and bad_dual.size == 0:
            lam_full = np.zeros(h.size)
            lam_full[active] = mu
            return zz, lam_full
        active = np.union1d(np.setdiff1d(active, bad_dual), bad_primal)
    return z, lam


def _project_ldp(d: np.ndarray, g: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact Euclidean projection ``argmin ||w - d|| s.t. g w <= h`` (Lawson & Hanson 1974, "Solving Least
    Squares Problems", ch. 23: least distance programming by NNLS).

    With ``x = w - d`` the problem is ``min ||x|| s.t. E x >= f``, ``E = -g``, ``f = g d - h``; NNLS
    ``min_{u >= 0} ||[E^T; f^T] u - e_{n+1}||`` gives ``x = -r[:n] / r[n]`` from its residual ``r``, and the
    multipliers ``lam = 2 u / r[n]`` of ``min ||w - d||^2``. Returns (w, lam). Raises RuntimeError if NNLS
    reports the constraints incompatible.
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


def _kkt_residual(w: np.ndarray, d: np.ndarray, g: np.ndarray, h: np.ndarray, lam: np.ndarray | None) -> float:
    """Largest violation of the KKT conditions of ``min ||w - d||^2 s.t. g w <= h`` at (w, lam)."""
    if lam is None or lam.size == 0:
        return float(np.max(np.abs(2.0 * (w - d)), initial=0.0))
    stationarity = np.max(np.abs(2.0 * (w - d) + g.T @ lam))
    complementarity = np.max(np.abs(lam * (g @ w - h)))
    return float(max(stationarity, complementarity, -np.min(lam), 0.0))


class _Infeasible(Exception):
    def __init__(self, smallest_feasible_bound: float):
        self.smallest_feasible_bound = smallest_feasible_bound


class _CuttingPlane:
    """Cutting-plane solver on one factorised data set; reusable across penalty weights.

    Coordinates: ``z = R phi / sqrt(N)`` (orthonormal data term), then for a given weight ``v = U z`` with
    ``U^T U = I + w P0^T P0`` (QR of ``[I; sqrt(w) P0]``), so that the objective divided by N is
    ``||v - d||^2 + const`` and each small QP is a Euclidean projection ``minimize ||v - d||^2 s.t. G v <= h``:
    ProxQP's best-conditioned case for any weight.
    """

    def __init__(self, design: StructuredDesign, b: np.ndarray, penalty_rows: np.ndarray | None, fac: _Factor,
                 tol: float):
        self.design, self.b, self.penalty_rows, self.fac, self.tol = design, b, penalty_rows, fac, tol
        self.p = design.shape[1]
        self.r_buf = np.empty(b.size)
        self.abs_buf = np.empty(b.size)
        # working set: row indices, signs (+1: a x - b <= e, -1: -(a x - b) <= e), and the signed rows in z
        # coordinates (sign * a_k x = g_k z)
        self.rows = np.zeros(0, dtype=int)
        self.signs = np.zeros(0, dtype=int)
        self.g = np.zeros((0, self.p))
        self.n_fallback_solves = 0
        # P0 with ||C_S A x||^2 / N = ||P0 z||^2  (phi = R^-1 z, R scaled by 1/sqrt(N))
        self.p0 = (None if fac.pen is None else
                   scipy.linalg.solve_triangular(fac.r, fac.pen.T, trans="T").T / math.sqrt(fac.n))

    def _add(self, idx: np.ndarray, signs: np.ndarray) -> None:
        g = _constraint_rows(self.fac, idx) * signs[:, None]
        self.rows = np.concatenate([self.rows, idx])
        self.signs = np.concatenate([self.signs, signs])
        self.g = np.vstack([self.g, g])

    def solve(self, weight: float, bound_e: float) -> Solution:
        try:
            return self._solve(weight, bound_e)
        except _Infeasible as exc:
            return Solution(found=False, status="infeasible", x=None, residual=None, objective=math.nan,
                            residual_max=math.nan, residual_rms=math.nan, penalty=None, iterations=0,
                            full_passes=0, n_working_rows=int(self.rows.size), n_active_rows=0,
                            kkt_residual=math.nan, solver=self._name(),
                            smallest_feasible_bound=exc.smallest_feasible_bound)

    def _name(self) -> str:
        return f"cutting-plane+proxqp on {self.fac.method}" + (
            f" ({self.n_fallback_solves} LDP fallback solves)" if self.n_fallback_solves else "")

    def _solve(self, weight: float, bound_e: float) -> Solution:
        t0 = time.perf_counter()
        fac, design, b, p = self.fac, self.design, self.b, self.p
        # ||z - c||^2 + w ||P0 z||^2 = ||[I; sqrt(w) P0] z - [c; 0]||^2 = ||U z - d||^2 + k
        stack = np.eye(p) if self.p0 is None else np.vstack([np.eye(p), math.sqrt(weight) * self.p0])
        q_u, u = np.linalg.qr(stack)
        d = q_u[:p].T @ fac.c
        w = d.copy()                                    # unconstrained optimum
        lam, g_w, h = None, np.zeros((0, p)), np.zeros(0)
        bound = bound_e + self.tol
        iterations, full_passes = 1, 0
        cand = None       # the rows the next check covers (sorted indices); None: every row
        if self.rows.size:  # warm start from a previous weight: those rows are true constraints
            w, lam, g_w, h = self._solve_working_set(u, d, w, bound_e)
        elif b.size > 2 * MAX_CANDIDATE_ROWS:   # cold start: first settle on an evenly spaced subset
            cand = np.arange(0, b.size, -(-b.size // MAX_CANDIDATE_ROWS))
            design_cand, b_cand = design.take(cand), b[cand]
        while True:
            x = _x_from_z(scipy.linalg.solve_triangular(u, w), fac)
            if cand is not None:
                r = _residual(design_cand, b_cand, x)
                if float(np.max(np.abs(r))) <= bound:
                    cand = None                         # the candidates hold: check every row
            if cand is None:
                r = _residual(design, b, x, out=self.r_buf)
                full_passes += 1
                if float(np.max(np.abs(r, out=self.abs_buf))) <= bound:
                    break
                cand = _candidate_rows(self.abs_buf, bound_e)
                if cand is not None:
                    design_cand, b_cand, r = design.take(cand), b[cand], r[cand]
            if iterations >= MAX_CUTTING_PLANE_ITERATIONS:
                raise RuntimeError(f"cutting plane did not converge in {MAX_CUTTING_PLANE_ITERATIONS} iterations "
                                   f"(max residual {float(np.max(np.abs(r))):.6g} > bound {bound_e:.6g})")
            self._add(*self._most_violated(r, cand, bound))
            w, lam, g_w, h = self._solve_working_set(u, d, w, bound_e)
            iterations += 1
        return _solution(x, r.copy(), b, self.penalty_rows, weight, bound_e, self.tol, solver=self._name(),
                         iterations=iterations, full_passes=full_passes, n_working_rows=int(self.rows.size),
                         kkt_residual=_kkt_residual(w, d, g_w, h, lam), solve_time_s=time.perf_counter() - t0)

    def _most_violated(self, r: np.ndarray, cand: np.ndarray | None, bound: float) -> tuple[np.ndarray, np.ndarray]:
        """Rows (indices into all rows) and signs to add: the most violated of the residuals ``r`` on ``cand``
        (None: all rows), leaving out rows already constrained with the same sign."""
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
            raise RuntimeError("cutting plane stalled: the only violated rows are already in the working set "
                               f"(small-QP accuracy below the feasibility tolerance {self.tol:.3g}); likely "
                               "causes: a large penalty weight or a bound within a fraction of a percent of the "
                               "smallest feasible one")
        new_signs = np.where(r[new] >= 0, 1, -1)
        return (new if cand is None else cand[new]), new_signs

    def _solve_working_set(self, u, d, w0, bound_e):
        """``minimize ||v - d||^2 s.t. G v <= h`` on the working set (ProxQP, then polish); returns
        (v, multipliers, G, h)."""
        g_w = scipy.linalg.solve_triangular(u, self.g.T, trans="T").T     # g z = g U^-1 v
        h = bound_e + self.signs * self.b[self.rows]
        p, q = 2.0 * np.eye(self.p), -2.0 * d
        sol = qpsolvers.solve_problem(qpsolvers.Problem(p, q, g_w, h), solver="proxqp", initvals=w0,
                                      eps_abs=PROXQP_EPS_ABS, eps_rel=0.0, max_iter=PROXQP_MAX_ITER)
        if sol.found:
            return (*_polish(p, q, g_w, h, sol.x, sol.z, self.tol), g_w, h)
        # ProxQP's infeasibility test is loose (its eps_primal_inf is not reachable through qpsolvers): it can
        # call a thin but feasible working set infeasible. Decide with the LP, then solve the projection
        # exactly by Lawson-Hanson LDP/NNLS.
        self._raise_if_infeasible(bound_e)
        self.n_fallback_solves += 1
        w, lam = _project_ldp(d, g_w, h)
        return (*_polish(p, q, g_w, h, w, lam, self.tol), g_w, h)

    def _raise_if_infeasible(self, bound_e: float) -> None:
        _, t_ws = _minimax_lp_rows(self.g * self.signs[:, None], self.b[self.rows])
        if t_ws > bound_e:
            e_min, _, _ = _minimax(self.design, self.b, self.fac, self.rows, self.tol, self.r_buf)
            raise _Infeasible(e_min)
