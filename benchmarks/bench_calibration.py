"""Benchmark: the cutting-plane QP calibration (Eq. 17) against a least-squares floor and a
full-constraint QP solve, at N = 1e4, 1e5, 1e6 samples.

Run from the repository root::

    python -m benchmarks.bench_calibration                # N = 1e4, 1e5, 1e6
    python -m benchmarks.bench_calibration --sizes 1e4    # quick

Measured in one process (the full-constraint solves in a child process, for the timeout):

* **floor** -- the plain normal-equations least-squares fit a user would write,
  ``A = design_matrix(v); theta = solve(A^T A, A^T y)``.
* **LS (ours)** -- :func:`sensor.calibration.fit_least_squares` (TSQR below N = 65 536, sketched
  Cholesky QR above).
* **QP (ours)** -- :func:`sensor.calibration.fit_qp` with gamma = the value :func:`select_gamma`
  picks on the N = 1e4 set (default grid, lambda = 1) and gamma = 1e4, each with ``e_max = 0.2 % FS``
  (Eq. 14) and with ``e_max`` 1 % above the smallest feasible value (many active rows).
* **full QP** -- ``qpsolvers.solve_qp(P, q, G, h, solver="proxqp")`` with all 2N rows of Eq. 16 on
  the raw design matrix (the paper's formulation handed to a general solver), for the two settings
  with active bounds marked ``*``, at N <= 1e5 only, each in a child process under a timeout; at 1e6
  the dense constraint matrix alone is 400 MB and it is skipped. Its memory is the growth of the
  child's max RSS while building and solving (it includes ProxQP's own allocations). ProxQP's dense
  backend also reserves an (n + m) x (n + m) matrix (n = 25, m = 2N): 3.2 GB of address space at
  N = 1e4 (not touched, so not in the RSS), 320 GB at 1e5, which the allocator refuses.

Times are the best of ``--repeats`` runs after a warm-up call; memory is the ``tracemalloc`` peak of a separate run
(Python/numpy allocations; the solver's C++ allocations are not seen), relative to the data
``v`` (N x 8 float64) + ``tau_ref`` (N float64) + quiet mask (N bool) = 73 N bytes.

Synthetic data (seeded): 8 channels, offsets 1.2-2.0 V, sensitivities 0.024-0.04 V/(N m) of alternating
sign with a cubic term of 1 % of the linear one at 25 N m, +-2 mV direction-dependent hysteresis,
white noise 1-5 mV per channel; torque: 5 loading/unloading cycles to +-25 N m with no-load holds
(about 13 % of the samples quiet), reference noise 3 mN m.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import multiprocessing as mp
import os
import platform
import queue
import time
import tracemalloc

import numpy as np

from sensor import calibration as cal

SEED = 1
CYCLES = 5
AMPLITUDE_NM = 25.0          # Sec. III-B: calibration range +-25 N m
REFERENCE_NOISE_NM = 0.003
HYSTERESIS_V = 0.002
NOISE_RANGE_V = (1e-3, 5e-3)
SENSITIVITY_RANGE_V_PER_NM = (0.024, 0.04)   # Sec. III-B: 0.024-0.04 V/(N m)
CUBIC_FRACTION_AT_FULL_RANGE = 0.01
ACTIVE_GAMMA = 1e4
TIGHT_FACTOR = 1.01
FULL_QP_MAX_N = 100_000
FULL_QP_EPS_ABS = 1e-9
N_THETA = cal.N_COEFFICIENTS


def synthetic_calibration_data(n: int, seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """(v [V] (n, 8), tau_ref [N m] (n,)): see the module docstring."""
    rng = np.random.default_rng(seed)
    phase = (np.arange(n) / n * CYCLES) % 1.0
    tau = AMPLITUDE_NM * np.clip(1.4 * np.sin(2 * np.pi * phase), -1.0, 1.0)
    tau = np.where((np.abs(tau) < 2.0) | (phase > 0.9), 0.0, tau)
    tau_ref = tau + rng.normal(0.0, REFERENCE_NOISE_NM, n)
    v0 = rng.uniform(1.2, 2.0, 8)
    sens = rng.uniform(*SENSITIVITY_RANGE_V_PER_NM, 8) * np.where(np.arange(8) % 2 == 0, 1, -1)
    cubic = CUBIC_FRACTION_AT_FULL_RANGE * sens / AMPLITUDE_NM ** 2
    noise = rng.uniform(*NOISE_RANGE_V, 8)
    direction = np.sign(np.gradient(tau))[:, None]
    hyst = HYSTERESIS_V * rng.uniform(-1.0, 1.0, 8)
    v = np.empty((n, 8))
    for i in range(0, n, 65_536):                 # build in chunks: no (n, 8) temporaries
        t = tau[i:i + 65_536, None]
        v[i:i + 65_536] = (v0 + sens * t + cubic * t ** 3 + direction[i:i + 65_536] * hyst
                           + rng.normal(size=(t.shape[0], 8)) * noise)
    return v, tau_ref


def floor_fit(v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Normal-equations least squares on the full design matrix."""
    a = cal.design_matrix(v)
    return np.linalg.solve(a.T @ a, a.T @ y)


def _predict_chunked(theta: np.ndarray, v: np.ndarray, rows: int = 100_000) -> np.ndarray:
    """``design_matrix(v) @ theta`` a block of rows at a time (an independent evaluation)."""
    return np.concatenate([cal.design_matrix(v[i:i + rows]) @ theta
                           for i in range(0, v.shape[0], rows)])


def best_time(fn, repeats: int):
    """Best wall time of ``repeats`` calls after one untimed warm-up call, and the last result."""
    best, out = np.inf, fn()
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _full_qp_child(n: int, gamma: float, e_max: float, out: mp.Queue) -> None:
    import resource

    import qpsolvers

    v, y = synthetic_calibration_data(n)
    mask = cal.quiet_segment_mask(y)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.perf_counter()
    a = cal.design_matrix(v)
    a0 = a[mask]
    a0c = a0 - a0.mean(axis=0)
    p = 2 * (a.T @ a + gamma * a0c.T @ a0c)
    q = -2 * a.T @ y
    g = np.vstack([a, -a])
    h = np.concatenate([y + e_max, -y + e_max])
    x = qpsolvers.solve_qp(p, q, g, h, solver="proxqp", eps_abs=FULL_QP_EPS_ABS, eps_rel=0.0,
                           max_iter=100_000)
    dt = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - rss0
    out.put((dt, None if x is None else x, rss))


def full_qp(n: int, gamma: float, e_max: float, timeout_s: float):
    """Run the full-constraint solve in a child process.

    Returns ("ok", seconds, theta or None, growth of the child's max RSS [bytes]),
    ("timeout", timeout_s) or ("died", exit code) -- ProxQP's dense backend aborts the process when
    it cannot allocate its (n + m) x (n + m) KKT matrix.
    """
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    proc = ctx.Process(target=_full_qp_child, args=(n, gamma, e_max, q))
    proc.start()
    t_end = time.perf_counter() + timeout_s
    res = None
    while res is None:
        try:
            res = ("ok", *q.get(timeout=1.0))
        except queue.Empty:
            if not proc.is_alive():
                res = ("died", proc.exitcode)
            elif time.perf_counter() > t_end:
                res = ("timeout", timeout_s)
    proc.join(timeout=5)
    if proc.is_alive():
        proc.terminate()
        proc.join()
    return res


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[1e4, 1e5, 1e6])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--full-qp-timeout", type=float, default=300.0, help="seconds per full solve")
    args = ap.parse_args(argv)

    print(f"bench_calibration  {datetime.date.today()}  {platform.processor() or platform.machine()}"
          f"  cores={os.cpu_count()}  numpy {np.__version__}  repeats={args.repeats}  load average "
          f"{os.getloadavg()[0]:.2f}")
    v_sel, y_sel = synthetic_calibration_data(10_000)
    sel = cal.select_gamma(v_sel, y_sel, quiet_mask=cal.quiet_segment_mask(y_sel))
    print(f"select_gamma on N = 1e4 (default grid, lambda = {cal.DEFAULT_LAMBDA_WEIGHT}): "
          f"gamma = {sel.gamma:g}")

    for n in (int(s) for s in args.sizes):
        v, y = synthetic_calibration_data(n)
        mask = cal.quiet_segment_mask(y)
        data_bytes = v.nbytes + y.nbytes + mask.nbytes
        e_min = cal.smallest_feasible_e_max(v, y)
        print(f"\nN = {n:.0e}: data {data_bytes / 1e6:.1f} MB, quiet {mask.mean():.1%}, "
              f"smallest feasible e_max {e_min:.4f} N m")
        t_floor, theta_floor = best_time(functools.partial(floor_fit, v, y), args.repeats)
        m_floor = peak_bytes(functools.partial(floor_fit, v, y))
        rows = [("floor: normal equations (full A)", t_floor, m_floor, "")]
        t_ls, ls = best_time(functools.partial(cal.fit_least_squares, v, y), args.repeats)
        m_ls = peak_bytes(functools.partial(cal.fit_least_squares, v, y))
        dpred = np.max(np.abs(ls.predict(v) - _predict_chunked(theta_floor, v)))
        rows.append(("LS ours (fit_least_squares)", t_ls, m_ls,
                     f"{ls.diagnostics.solver}; |LS - floor| pred {dpred:.1e} N m"))
        settings = [(sel.gamma, cal.E_MAX_NM, "0.2%FS"),
                    (sel.gamma, TIGHT_FACTOR * e_min, f"{TIGHT_FACTOR}*min"),
                    (ACTIVE_GAMMA, cal.E_MAX_NM, "0.2%FS"),
                    (ACTIVE_GAMMA, TIGHT_FACTOR * e_min, f"{TIGHT_FACTOR}*min")]
        full_settings = [settings[1], settings[2]]
        fits = {}
        for gamma, e_max, e_label in settings:
            t_qp, fit = best_time(functools.partial(
                cal.fit_qp, v, y, gamma=gamma, quiet_mask=mask, e_max_nm=e_max), args.repeats)
            m_qp = peak_bytes(functools.partial(
                cal.fit_qp, v, y, gamma=gamma, quiet_mask=mask, e_max_nm=e_max))
            d = fit.diagnostics
            fits[(gamma, e_max)] = fit
            star = "*" if (gamma, e_max, e_label) in full_settings else " "
            rows.append((f"QP ours gamma={gamma:g}, e_max={e_label} {star}", t_qp, m_qp,
                         f"it {d.iterations}, passes {d.full_passes}, working {d.n_working_constraints}, active "
                         f"{d.n_active_constraints}, max|r| {d.residual_max_nm:.4f} N m"))
        for gamma, e_max, e_label in full_settings:
            label = f"full QP proxqp 2N rows, gamma={gamma:g}, {e_label}"
            if n > FULL_QP_MAX_N:
                rows.append((label, float("nan"), 0, f"skipped: N > {FULL_QP_MAX_N:.0e} "
                             f"(G alone {2 * n * 25 * 8 / 1e6:.0f} MB)"))
                continue
            res = full_qp(n, gamma, e_max, args.full_qp_timeout)
            kkt_gb = (2 * n + N_THETA) ** 2 * 8 / 1e9
            if res[0] == "timeout":
                rows.append((label, float("nan"), 0, f"timed out after {res[1]:g} s"))
                continue
            if res[0] == "died":
                rows.append((label, float("nan"), 0, f"solver process died (exit code {res[1]}); "
                             f"its dense (n+m)^2 matrix needs {kkt_gb:.0f} GB"))
                continue
            _, dt, theta_full, rss = res
            if theta_full is None:
                rows.append((label, dt, rss, "ProxQP reported failure"))
                continue
            pred_full = _predict_chunked(theta_full, v)
            diff = np.max(np.abs(pred_full - _predict_chunked(fits[(gamma, e_max)].theta, v)))
            excess = np.max(np.abs(pred_full - y)) - e_max
            rows.append((label, dt, rss, f"|full - ours| pred {diff:.1e} N m, bound excess "
                         f"{excess:.1e} N m"))
        print(f"  {'method':48s} {'time s':>8s} {'/floor':>7s} {'peak MB':>8s} {'/data':>6s}  notes")
        for label, t, mem, note in rows:
            mem_s = f"{mem / 1e6:8.1f} {mem / data_bytes:6.2f}" if mem else f"{'-':>8s} {'-':>6s}"
            print(f"  {label:48s} {t:8.3f} {t / t_floor:7.2f} {mem_s}  {note}", flush=True)
        print(f"  (load average now {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()
