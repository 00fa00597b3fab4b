"""Tests for sensor.constrained_lsq: least squares under an element-wise residual bound with a spread penalty.

Oracles, none sharing the engine's code: ``numpy.linalg.lstsq`` (unconstrained, and penalised as one stacked
least-squares problem), ``qpsolvers`` with ProxQP on all 2N constraints of the dense problem, ``scipy.optimize
.linprog`` (HiGHS) on all rows for the minimax bound, and the KKT conditions checked directly (multipliers of
the active rows by ``scipy.optimize.nnls``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import qpsolvers
import scipy.optimize
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sensor import constrained_lsq as lsq

TOL = 1e-9
"""Feasibility tolerance handed to the engine (units of the target, which is O(1) here)."""
X_RTOL = 1e-8
"""Relative agreement of exact solutions' coefficients on well-conditioned problems."""
QP_PRED_ATOL = 1e-6
"""Engine vs full-constraint ProxQP (eps_abs 1e-10 on the raw matrix): predictions A x."""
QP_OBJ_RTOL = 1e-8
"""... and relative agreement of the objective values."""
LP_ATOL = 1e-7
"""Minimax bound vs HiGHS on all rows (the engine reports an achieved max residual within TOL of its LP)."""
KKT_RTOL = 1e-6
"""Direct KKT check: stationarity residual relative to the size of the data gradient ``2 ||A^T b||``."""


# --- Test problems (every draw from an explicit seed) ---------------------------------------------------------
def _random_problem(seed: int, n_rows: int = 120, n_cols: int = 5, noise: float = 0.5):
    """Gaussian design with an intercept-free linear truth, heavy-tailed noise (so a bound can bite), and a
    penalty block on the first fifth of the rows."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n_rows, n_cols))
    b = a @ rng.normal(size=n_cols) + noise * rng.standard_t(3, size=n_rows)
    rows = np.zeros(n_rows, dtype=bool)
    rows[: max(2, n_rows // 5)] = True
    return a, b, rows


def _centred(a, rows):
    a0 = a[rows]
    return a0 - a0.mean(axis=0)


def _objective(a, b, rows, weight, x) -> float:
    r = a @ x - b
    p = _centred(a, rows) @ x if rows is not None else np.zeros(1)
    return float(r @ r + weight * p @ p)


def _lstsq_penalised(a, b, rows, weight):
    """min ||A x - b||^2 + w ||C_S A x||^2 as one stacked least-squares problem."""
    if rows is None or weight == 0.0:
        return np.linalg.lstsq(a, b, rcond=None)[0]
    a0c = _centred(a, rows)
    return np.linalg.lstsq(np.vstack([a, math.sqrt(weight) * a0c]), np.r_[b, np.zeros(a0c.shape[0])],
                           rcond=None)[0]


def _proxqp_full(a, b, rows, weight, bound):
    """The dense QP with all 2N rows, handed to qpsolvers/ProxQP."""
    a0c = _centred(a, rows) if rows is not None else np.zeros((1, a.shape[1]))
    p = 2 * (a.T @ a + weight * a0c.T @ a0c)
    q = -2 * a.T @ b
    sol = qpsolvers.solve_problem(qpsolvers.Problem(p, q, np.vstack([a, -a]), np.r_[b + bound, bound - b]),
                                  solver="proxqp", eps_abs=1e-10, eps_rel=0.0, max_iter=200_000)
    assert sol.found, "oracle ProxQP solve failed"
    return sol.x


def _linprog_minimax(a, b) -> float:
    """min t s.t. -t <= A x - b <= t on all rows (HiGHS)."""
    n, p = a.shape
    ones = np.ones((n, 1))
    res = scipy.optimize.linprog(np.r_[np.zeros(p), 1.0], A_ub=np.block([[a, -ones], [-a, -ones]]),
                                 b_ub=np.r_[b, -b], bounds=[(None, None)] * p + [(0, None)], method="highs")
    assert res.status == 0, res.message
    return float(res.x[-1])


def _kkt_stationarity(a, b, rows, weight, bound, x) -> float:
    """Relative residual of ``grad f(x) + sum_i lam_i s_i a_i = 0`` over multipliers ``lam >= 0`` of the rows at
    the bound (``s_i`` the sign of their residual), by NNLS."""
    r = a @ x - b
    grad = 2 * a.T @ r
    if rows is not None:
        a0c = _centred(a, rows)
        grad = grad + 2 * weight * a0c.T @ (a0c @ x)
    active = np.flatnonzero(np.abs(r) >= bound - 1e-7 * max(1.0, bound)) if math.isfinite(bound) else []
    scale = 2 * np.linalg.norm(a.T @ b)
    if len(active) == 0:
        return float(np.linalg.norm(grad) / scale)
    m = (np.sign(r[active])[:, None] * a[active]).T
    _, res = scipy.optimize.nnls(m, -grad)
    return float(res / scale)


class _Powers:
    """A structured design ``A = [1, t, t^2, ..., t^(n-1)]`` of one variable t, never formed: the rule-based
    counterpart of ``numpy.vander(t, n, increasing=True)``, its basis scaled by t -> t / max|t| and its
    constant column first."""

    def __init__(self, t: np.ndarray, n: int):
        self.t, self.shape = t, (t.size, n)

    def matvec(self, x, out=None):
        y = np.polynomial.polynomial.polyval(self.t, x)
        if out is None:
            return y
        out[:] = y
        return out

    def take(self, rows):
        return _Powers(self.t[rows], self.shape[1])

    def basis(self, rows=None):
        return _ScaledPowers(self.t, self.shape[1], 1.0 / np.max(np.abs(self.t)))


class _ScaledPowers:
    constant_column = 0

    def __init__(self, t, n, inv_scale):
        self.t, self.n, self.s = t, n, inv_scale

    def fill_t(self, rows, out_t):
        out_t[:] = (self.t[rows] * self.s)[None, :] ** np.arange(self.n)[:, None]

    def to_design(self, phi):
        return phi * self.s ** np.arange(self.n)


# --- Unconstrained -------------------------------------------------------------------------------------------
@settings(max_examples=25, deadline=None, database=None)
@given(seed=st.integers(0, 2 ** 20), n_cols=st.integers(1, 8), extra_rows=st.integers(0, 60))
def test_unconstrained_solution_equals_numpy_lstsq(seed, n_cols, extra_rows):
    """No bound, no penalty: x equals numpy.linalg.lstsq, and the Solution reports its residual and objective."""
    a, b, _ = _random_problem(seed, n_cols + extra_rows + 1, n_cols)
    sol = lsq.solve(lsq.Problem(a, b), feasibility_tol=TOL)
    x_ref = np.linalg.lstsq(a, b, rcond=None)[0]
    assert sol.found and sol.status == "optimal" and sol.solver == "tsqr"
    np.testing.assert_allclose(sol.x, x_ref, rtol=0, atol=X_RTOL * max(1.0, np.max(np.abs(x_ref))))
    r = a @ x_ref - b
    assert sol.objective == pytest.approx(float(r @ r), rel=1e-10)
    assert sol.residual_max == pytest.approx(np.max(np.abs(r)), rel=1e-8)
    assert sol.n_working_rows == 0 and sol.iterations == 1 and sol.kkt_residual == 0.0
    assert _kkt_stationarity(a, b, None, 0.0, math.inf, sol.x) < KKT_RTOL


@pytest.mark.parametrize("weight", [0.5, 30.0, 1e4])
def test_unbounded_penalised_solution_equals_the_stacked_least_squares(weight):
    """Without a bound the penalised problem is one least-squares problem ``[A; sqrt(w) C_S A] x ~ [b; 0]``."""
    a, b, rows = _random_problem(3)
    sol = lsq.solve(lsq.Problem(a, b, penalty_rows=rows, penalty_weight=weight), feasibility_tol=TOL)
    x_ref = _lstsq_penalised(a, b, rows, weight)
    np.testing.assert_allclose(a @ sol.x, a @ x_ref, rtol=0, atol=1e-9 * np.max(np.abs(b)))
    assert sol.penalty == pytest.approx(float(np.sum((_centred(a, rows) @ sol.x) ** 2)), rel=1e-8, abs=1e-12)
    assert sol.objective == pytest.approx(_objective(a, b, rows, weight, x_ref), rel=1e-10)


# --- Bounded: against ProxQP on all rows and the KKT conditions ----------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("weight", [0.0, 1.0, 100.0])
def test_bounded_solution_equals_full_constraint_proxqp_and_meets_kkt(seed, weight):
    """A bound between the minimax value and the LS max residual: the engine's point equals ProxQP on all 2N
    rows, meets the bound on every row, and satisfies the KKT conditions with non-negative multipliers."""
    a, b, rows = _random_problem(seed)
    e_min = _linprog_minimax(a, b)
    ls_max = np.max(np.abs(a @ np.linalg.lstsq(a, b, rcond=None)[0] - b))
    bound = 0.5 * (e_min + ls_max)
    sol = lsq.solve(lsq.Problem(a, b, residual_bound=bound, penalty_rows=rows, penalty_weight=weight),
                    feasibility_tol=TOL)
    x_ref = _proxqp_full(a, b, rows, weight, bound)
    assert sol.found and sol.n_active_rows > 0 and sol.solver.startswith("cutting-plane+proxqp on")
    np.testing.assert_allclose(a @ sol.x, a @ x_ref, rtol=0, atol=QP_PRED_ATOL)
    assert _objective(a, b, rows, weight, sol.x) == pytest.approx(_objective(a, b, rows, weight, x_ref),
                                                                  rel=QP_OBJ_RTOL)
    assert np.max(np.abs(a @ sol.x - b)) <= bound + TOL
    np.testing.assert_allclose(sol.residual, a @ sol.x - b, rtol=0, atol=1e-12)
    assert _kkt_stationarity(a, b, rows, weight, bound, sol.x) < KKT_RTOL
    assert sol.kkt_residual < 1e-8


@settings(max_examples=20, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 20), n_cols=st.integers(1, 6), n_rows=st.integers(20, 150),
       factor=st.floats(1.02, 3.0), log10_weight=st.floats(-2.0, 3.0))
def test_random_bounded_problems_meet_the_bound_and_the_kkt_conditions(seed, n_cols, n_rows, factor,
                                                                      log10_weight):
    """Random feasible problems: every row meets the bound and the point is a KKT point of the full problem."""
    a, b, rows = _random_problem(seed, n_rows, n_cols)
    bound = factor * _linprog_minimax(a, b)
    weight = 10.0 ** log10_weight
    sol = lsq.solve(lsq.Problem(a, b, residual_bound=bound, penalty_rows=rows, penalty_weight=weight),
                    feasibility_tol=TOL)
    assert sol.found
    assert np.max(np.abs(a @ sol.x - b)) <= bound + TOL
    assert _kkt_stationarity(a, b, rows, weight, bound, sol.x) < KKT_RTOL


def test_candidate_subset_and_sketched_factor_give_the_full_constraint_solution(monkeypatch):
    """At N = 3000 with a cold start on an evenly spaced subset of at most 16 candidate rows, and with the
    sketched Cholesky QR forced (a 64-row sample), the solution still equals ProxQP on all rows."""
    a, b, rows = _random_problem(5, 3000, 4)
    bound = 1.2 * _linprog_minimax(a, b)
    monkeypatch.setattr(lsq, "MAX_CANDIDATE_ROWS", 16)
    monkeypatch.setattr(lsq, "SKETCH_MIN_N", 0)
    monkeypatch.setattr(lsq, "SKETCH_ROWS", 64)
    sol = lsq.solve(lsq.Problem(a, b, residual_bound=bound, penalty_rows=rows, penalty_weight=10.0),
                    feasibility_tol=TOL)
    assert sol.solver.endswith("sketched-cholqr") and sol.full_passes >= 2
    np.testing.assert_allclose(a @ sol.x, a @ _proxqp_full(a, b, rows, 10.0, bound), rtol=0, atol=QP_PRED_ATOL)


def test_duplicated_rows_give_the_solution_of_the_distinct_rows():
    """Every row given twice (degenerate, linearly dependent constraints): the objective doubles, the minimiser of
    the bounded problem does not change."""
    a, b, _ = _random_problem(8, 80, 3)
    bound = 1.1 * _linprog_minimax(a, b)
    once = lsq.solve(lsq.Problem(a, b, residual_bound=bound), feasibility_tol=TOL)
    twice = lsq.solve(lsq.Problem(np.vstack([a, a]), np.r_[b, b], residual_bound=bound), feasibility_tol=TOL)
    np.testing.assert_allclose(a @ twice.x, a @ once.x, rtol=0, atol=QP_PRED_ATOL)
    assert twice.objective == pytest.approx(2 * once.objective, rel=1e-8)


def test_solve_path_equals_one_solve_per_weight():
    """Warm-started solves over a weight grid give each weight's standalone solution."""
    a, b, rows = _random_problem(4, 200, 5)
    problem = lsq.Problem(a, b, residual_bound=1.3 * _linprog_minimax(a, b), penalty_rows=rows)
    weights = [0.1, 10.0, 1000.0]
    path = lsq.solve_path(problem, weights, feasibility_tol=TOL)
    for w, sol in zip(weights, path, strict=True):
        alone = lsq.solve(lsq.Problem(a, b, residual_bound=problem.residual_bound, penalty_rows=rows,
                                      penalty_weight=w), feasibility_tol=TOL)
        np.testing.assert_allclose(a @ sol.x, a @ alone.x, rtol=0, atol=QP_PRED_ATOL)


def test_structured_design_gives_the_solution_of_its_dense_matrix():
    """A rule-based design (powers of t, constant column first) and its dense Vandermonde matrix: one solution."""
    rng = np.random.default_rng(11)
    t = np.sort(rng.uniform(-3.0, 2.0, 400))
    b = np.sin(t) + 0.05 * rng.normal(size=t.size)
    rows = np.abs(t) < 0.5
    dense = np.vander(t, 5, increasing=True)
    bound = 1.2 * _linprog_minimax(dense, b)
    kw = {"residual_bound": bound, "penalty_rows": rows, "penalty_weight": 3.0}
    structured = lsq.solve(lsq.Problem(_Powers(t, 5), b, **kw), feasibility_tol=TOL)
    from_array = lsq.solve(lsq.Problem(dense, b, **kw), feasibility_tol=TOL)
    np.testing.assert_allclose(dense @ structured.x, dense @ from_array.x, rtol=0, atol=QP_PRED_ATOL)
    np.testing.assert_allclose(dense @ structured.x, dense @ _proxqp_full(dense, b, rows, 3.0, bound), rtol=0,
                               atol=QP_PRED_ATOL)


# --- Minimax and infeasibility ----------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 6, 7])
def test_minimax_bound_equals_linprog_on_all_rows(seed):
    """solve_minimax's bound is the HiGHS LP optimum on all rows, and it is achieved by its x."""
    a, b, _ = _random_problem(seed, 400, 6)
    mm = lsq.solve_minimax(lsq.Problem(a, b), feasibility_tol=TOL)
    assert mm.bound == pytest.approx(_linprog_minimax(a, b), abs=LP_ATOL)
    assert np.max(np.abs(a @ mm.x - b)) == pytest.approx(mm.bound, abs=1e-12)


def test_infeasible_bound_is_reported_with_the_smallest_feasible_one():
    """A bound below the minimax value: found False, status "infeasible", smallest_feasible_bound = the LP's
    value; just above that value the problem solves and meets the bound; a path reports it for every weight."""
    a, b, rows = _random_problem(9)
    e_lp = _linprog_minimax(a, b)
    problem = lsq.Problem(a, b, residual_bound=0.7 * e_lp, penalty_rows=rows, penalty_weight=1.0)
    sol = lsq.solve(problem, feasibility_tol=TOL)
    assert not sol.found and sol.status == "infeasible" and sol.x is None
    assert sol.smallest_feasible_bound == pytest.approx(e_lp, abs=LP_ATOL)
    path = lsq.solve_path(problem, [0.1, 1.0], feasibility_tol=TOL)
    assert [s.status for s in path] == ["infeasible", "infeasible"]
    ok = lsq.solve(lsq.Problem(a, b, residual_bound=1.001 * sol.smallest_feasible_bound), feasibility_tol=TOL)
    assert ok.found and np.max(np.abs(a @ ok.x - b)) <= 1.001 * sol.smallest_feasible_bound + TOL


# --- Bad input ----------------------------------------------------------------------------------------------------
def _ok():
    a, b, rows = _random_problem(0, 30, 3)
    return {"design": a, "target": b, "residual_bound": 1.0, "penalty_rows": rows, "penalty_weight": 1.0}


@pytest.mark.parametrize(("field", "value", "message"), [
    ("design", np.zeros(30), r"Problem.design must be a 2-D array"),
    ("design", np.full((30, 3), np.nan), r"Problem.design contains NaN"),
    ("design", np.ones((2, 3)), r"Problem.design must have shape \(N, n\) with N >= n >= 1"),
    ("target", np.zeros(29), r"Problem.target must have shape \(N,\) = \(30,\).*\(29,\)"),
    ("target", np.r_[np.zeros(29), np.inf], r"Problem.target contains NaN or inf"),
    ("residual_bound", 0.0, r"Problem.residual_bound must be > 0"),
    ("residual_bound", math.nan, r"Problem.residual_bound must be > 0"),
    ("penalty_rows", np.ones(30), r"Problem.penalty_rows must be a boolean array of shape \(30,\)"),
    ("penalty_rows", np.eye(1, 30, dtype=bool)[0], r"Problem.penalty_rows selects 1 rows; at least 2"),
    ("penalty_weight", -1.0, r"Problem.penalty_weight must be >= 0 and finite"),
    ("penalty_weight", math.inf, r"Problem.penalty_weight must be >= 0 and finite"),
])
def test_bad_problem_field_is_refused_naming_the_field_and_valid_range(field, value, message):
    with pytest.raises(ValueError, match=message):
        lsq.Problem(**{**_ok(), field: value})


def test_penalty_weight_without_penalty_rows_is_refused():
    with pytest.raises(ValueError, match=r"Problem.penalty_weight = 1 needs Problem.penalty_rows"):
        lsq.Problem(**{**_ok(), "penalty_rows": None})


@pytest.mark.parametrize("tol", [0.0, -1e-9, math.nan, math.inf])
def test_feasibility_tolerance_must_be_positive_and_finite(tol):
    with pytest.raises(ValueError, match="feasibility_tol must be > 0 and finite"):
        lsq.solve(lsq.Problem(**_ok()), feasibility_tol=tol)


def test_rank_deficient_design_is_refused():
    """Two equal columns (and, separately, a zero column) leave x undetermined: a ValueError says so."""
    a, b, _ = _random_problem(1, 50, 3)
    with pytest.raises(ValueError, match="numerically rank-deficient"):
        lsq.solve(lsq.Problem(np.c_[a, a[:, 0]], b), feasibility_tol=TOL)
    with pytest.raises(ValueError, match=r"Problem.design: column\(s\) \[3\] are zero"):
        lsq.solve(lsq.Problem(np.c_[a, np.zeros(50)], b, residual_bound=1.0), feasibility_tol=TOL)


def test_solve_path_refuses_a_bad_weight_before_any_solve():
    with pytest.raises(ValueError, match=r"Problem.penalty_weight must be >= 0 and finite; got -1"):
        lsq.solve_path(lsq.Problem(**_ok()), [1.0, -1.0], feasibility_tol=TOL)
