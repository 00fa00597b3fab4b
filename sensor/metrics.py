"""Sensor evaluation metrics, defined once, as the paper uses them (Sec. III-B, Tables III-IV).

Every metric reported in % FS is normalised by the full scale ``FS`` (``photoreflector.full_scale_nm``,
80 N m: the design maximum T_z^max, Sec. III-B) unless a different ``fs_nm`` is given -- not by the calibrated
range (+-25 N m).

=====================  ======================================================  ==================
Metric                 Definition used here                                    Paper value
=====================  ======================================================  ==================
max error              ``max_k |tau_hat_k - tau_k|`` / FS                      0.0830 % FS (T. III)
RMS error              ``sqrt(mean((tau_hat - tau)^2))``                       0.0266 N m (T. III)
nonlinearity           max deviation of the branch-average curve from its      0.111 % FS (T. III)
                       least-squares line / FS
hysteresis             max ``|ascending - descending|`` branch difference at    0.139 % FS (T. III)
                       the same reference torque / FS
repeatability          max range across repeated cycles at the same reference  0.0849 % FS (T. IV)
                       level and branch / FS
crosstalk              ``max |tau_hat|`` under an applied T_x (T_y) moment / FS  0.148 / 0.126 % FS
3-sigma resolution     ``3 * std(tau_hat)`` over a no-load record (10 s at      0.0224 N m (QP),
                       1 kHz, unfiltered)                                      0.0480 N m (LS)
drift RMS              ``sqrt(mean((tau_hat - tau)^2))`` over a one-hour test   0.0326 N m at 10 N m
                       at constant load (Sec. III-C)                            (T. V, uncompensated)
zero drift per 1 K     largest slope of the fitted zero drift over the tests'  0.014 % FS
                       temperature range x 1 K / FS (Sec. III-C)
=====================  ======================================================  ==================

What the paper leaves open, and the choice made here
-----------------------------------------------------
* **Branches.** Fig. 7(a) speaks of "upper- and lower-bound" curves of loading/unloading. Here a
  sample belongs to the *ascending* branch when the reference torque was last moving up and to the
  *descending* branch when it was last moving down (:func:`reference_direction`, with a dead band
  against reference noise and holds). For a loop that does not cross itself these are the lower and
  upper curves over the whole +-range; splitting by |tau| increasing/decreasing instead would swap
  the two curves at zero torque.
* **Common grid.** The branches are compared at the same reference torque ``c`` (bin centres;
  default :data:`DEFAULT_N_BINS` equal bins over the range both branches cover). A branch's output
  at ``c`` is its bin mean moved to ``c`` along the global sensitivity ``s`` (least-squares slope of
  ``tau_hat`` on ``tau`` over all branch samples): ``o(c) = mean(tau_hat) + s (c - mean(tau))``.
  This is exact for any linear ``tau_hat = s tau + b`` wherever the samples sit within the bin, so
  a gain or offset error never shows up as nonlinearity or hysteresis; for a curved response the
  remaining bias is second order in the bin width. Bins lacking either branch are left out.
* **Nonlinearity line.** Least-squares straight line through the branch-average curve (an
  "independent" linearity), not a terminal-point or minimax line.
* **Hysteresis.** The full branch difference, not half of it.
* **Repeatability.** The range (max - min) of the per-cycle mean error across cycles, per bin and
  per branch (so hysteresis is not counted as non-repeatability), maximised over bins and branches.
  The paper does not say whether it used a range or a standard deviation.
* **Crosstalk.** The apparent T_z output during the moment test, relative to the applied T_z
  (zero unless ``tau_z_ref`` is given); no tare unless ``tare_mask`` selects unloaded samples whose
  mean is removed first. Normalised by FS, not by the applied moment (both are reported).
* **Resolution.** Sample standard deviation (``ddof=1``) of the raw record, no detrending or
  filtering (the paper: "10 s of data acquired at 1 kHz without any filtering").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.params import PhotoReflectorParams

__all__ = [
    "DEFAULT_N_BINS",
    "DIRECTION_DEADBAND_NM",
    "RESOLUTION_RECORD_S",
    "RESOLUTION_SAMPLE_RATE_HZ",
    "ErrorMetrics",
    "BranchCurves",
    "NonlinearityResult",
    "HysteresisResult",
    "RepeatabilityResult",
    "CrosstalkResult",
    "ResolutionResult",
    "error_metrics",
    "max_error_pct_fs",
    "rms_error_nm",
    "reference_direction",
    "branch_curves",
    "nonlinearity",
    "hysteresis",
    "repeatability",
    "crosstalk",
    "resolution_3sigma",
    "drift_rms_nm",
    "zero_drift_per_kelvin_pct_fs",
]

_FS_NM = PhotoReflectorParams().full_scale_nm
"""Default full scale [N m]: ``photoreflector.full_scale_nm`` of the default parameters."""

DEFAULT_N_BINS = 50
"""Reference-torque bins for the branch curves (our choice; 1 N m wide over +-25 N m)."""

DIRECTION_DEADBAND_NM = 0.05
"""Reference movement that counts as a reversal of the loading direction [N m] (our choice: about 5
counts of the MINI85 resolution 7/748 N m, Sec. III-A, so that reference noise during holds does not
flip the branch)."""

RESOLUTION_RECORD_S = 10.0
"""Length of the no-load record for the 3-sigma resolution [s] (Sec. III-B)."""

RESOLUTION_SAMPLE_RATE_HZ = 1000.0
"""Sampling rate of that record [Hz] (Sec. III-B: 1 kHz, unfiltered)."""

_PCT = 100.0


# --- Input checks -------------------------------------------------------------------------------------
def _vector(name: str, x, n: int | None = None) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim != 1 or (n is not None and arr.shape[0] != n):
        want = "(N,)" if n is None else f"({n},)"
        raise ValueError(f"{name} must have shape {want}; got shape {np.shape(x)}")
    if arr.size == 0:
        raise ValueError(f"{name} is empty")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


def _pair(tau_hat, tau_ref) -> tuple[np.ndarray, np.ndarray]:
    ref = _vector("tau_ref", tau_ref)
    return _vector("tau_hat", tau_hat, ref.size), ref


def _fs(fs_nm: float) -> float:
    fs = float(fs_nm)
    if not (fs > 0 and math.isfinite(fs)):
        raise ValueError(f"fs_nm must be > 0 and finite; got {fs_nm!r}")
    return fs


def _direction(direction, n: int) -> np.ndarray:
    d = np.asarray(direction)
    if d.shape != (n,):
        raise ValueError(f"direction must have shape ({n},); got shape {d.shape}")
    if not np.all(np.isin(d, (-1, 0, 1))):
        raise ValueError("direction must contain only +1 (ascending), -1 (descending) or 0 (none)")
    return d.astype(np.int8)


# --- Accuracy ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ErrorMetrics:
    """Point-wise accuracy against the reference (Table III, first two columns).

    Attributes
    ----------
    max_error_nm : float
        ``max_k |tau_hat_k - tau_k|`` [N m].
    max_error_pct_fs : float
        The same in % of FS.
    rms_error_nm : float
        ``sqrt(mean((tau_hat - tau)^2))`` [N m].
    fs_nm : float
        Full scale used [N m].
    n_samples : int
    """

    max_error_nm: float
    max_error_pct_fs: float
    rms_error_nm: float
    fs_nm: float
    n_samples: int


def error_metrics(tau_hat: np.ndarray, tau_ref: np.ndarray, *, fs_nm: float = _FS_NM) -> ErrorMetrics:
    """Max error [N m, % FS] and RMS error [N m] of ``tau_hat`` against ``tau_ref`` (both (N,))."""
    t, r = _pair(tau_hat, tau_ref)
    fs = _fs(fs_nm)
    e = t - r
    emax = float(np.max(np.abs(e)))
    return ErrorMetrics(max_error_nm=emax, max_error_pct_fs=_PCT * emax / fs,
                        rms_error_nm=math.sqrt(float(np.mean(e * e))), fs_nm=fs, n_samples=e.size)


def max_error_pct_fs(tau_hat: np.ndarray, tau_ref: np.ndarray, *, fs_nm: float = _FS_NM) -> float:
    """``100 * max_k |tau_hat_k - tau_k| / FS`` [% FS]."""
    return error_metrics(tau_hat, tau_ref, fs_nm=fs_nm).max_error_pct_fs


def rms_error_nm(tau_hat: np.ndarray, tau_ref: np.ndarray) -> float:
    """``sqrt(mean((tau_hat - tau)^2))`` [N m]."""
    return error_metrics(tau_hat, tau_ref).rms_error_nm


# --- Branches ----------------------------------------------------------------------------------------------
def reference_direction(tau_ref: np.ndarray, *,
                        deadband_nm: float = DIRECTION_DEADBAND_NM) -> np.ndarray:
    """Loading direction of each sample: +1 ascending, -1 descending branch, 0 undetermined.

    A reversal is recognised when the reference moves more than ``deadband_nm`` back from its
    running extreme; the turning point is the (last) sample at that extreme, so samples held at a
    level keep the direction by which the level was reached. Samples before the first recognised
    movement take its direction; a record that never moves by more than the dead band is all 0.

    Parameters
    ----------
    tau_ref : numpy.ndarray, shape (N,)
        Reference torque [N m], in time order.
    deadband_nm : float
        Dead band [N m].

    Returns
    -------
    numpy.ndarray of int8, shape (N,)

    Notes
    -----
    A sequential scan in Python (about 1 s per 10^6 samples).
    """
    tau = _vector("tau_ref", tau_ref)
    db = float(deadband_nm)
    if not db >= 0:
        raise ValueError(f"deadband_nm must be >= 0; got {deadband_nm!r}")
    n = tau.size
    out = np.zeros(n, dtype=np.int8)
    turns: list[int] = []
    dirs: list[int] = []
    d, lo_i, hi_i, ext_i = 0, 0, 0, 0
    values = tau.tolist()
    for i in range(1, n):
        x = values[i]
        if d == 0:
            if x - values[lo_i] > db:
                d, ext_i = 1, i
                turns.append(lo_i)
                dirs.append(1)
            elif values[hi_i] - x > db:
                d, ext_i = -1, i
                turns.append(hi_i)
                dirs.append(-1)
            else:
                if x <= values[lo_i]:
                    lo_i = i
                if x >= values[hi_i]:
                    hi_i = i
        elif d == 1:
            if x >= values[ext_i]:
                ext_i = i
            elif values[ext_i] - x > db:
                turns.append(ext_i)
                dirs.append(-1)
                d, ext_i = -1, i
        else:
            if x <= values[ext_i]:
                ext_i = i
            elif x - values[ext_i] > db:
                turns.append(ext_i)
                dirs.append(1)
                d, ext_i = 1, i
    if not turns:
        return out
    out[:turns[0] + 1] = dirs[0]
    for k, start in enumerate(turns):
        stop = turns[k + 1] + 1 if k + 1 < len(turns) else n
        out[start + 1:stop] = dirs[k]
    return out


@dataclass(frozen=True, eq=False)
class BranchCurves:
    """Mean error of each branch on a common grid of reference torque.

    Attributes
    ----------
    bin_edges_nm : numpy.ndarray, shape (M + 1,)
        Reference-torque bin edges [N m].
    level_nm : numpy.ndarray, shape (M,)
        Bin centres: the reference torque at which the branches are compared [N m].
    ascending_error_nm, descending_error_nm : numpy.ndarray, shape (M,)
        Branch output at the bin centre minus the bin centre, ``o(c) - c`` with
        ``o(c) = mean(tau_hat) + sensitivity * (c - mean(tau))`` over the branch's samples in the
        bin [N m] (NaN if none).
    sensitivity : float
        ``s``: least-squares slope of ``tau_hat`` on ``tau`` over all branch samples [-].
    ascending_count, descending_count : numpy.ndarray of int, shape (M,)
        Samples per bin and branch.
    both : numpy.ndarray of bool, shape (M,)
        Bins where both branches have samples (the only ones the metrics use).
    """

    bin_edges_nm: np.ndarray
    level_nm: np.ndarray
    ascending_error_nm: np.ndarray
    descending_error_nm: np.ndarray
    ascending_count: np.ndarray
    descending_count: np.ndarray
    both: np.ndarray
    sensitivity: float


def _bin_index(tau_ref: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin of each sample (last bin closed on the right); -1 outside the edges."""
    idx = np.searchsorted(edges, tau_ref, side="right") - 1
    idx[tau_ref == edges[-1]] = edges.size - 2
    idx[(tau_ref < edges[0]) | (tau_ref > edges[-1])] = -1
    return idx


def _edges(tau_ref, direction, bin_edges_nm, n_bins) -> np.ndarray:
    if bin_edges_nm is not None:
        edges = np.asarray(bin_edges_nm, dtype=float)
        if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
            raise ValueError("bin_edges_nm must be a strictly increasing 1-D array of >= 2 edges")
        return edges
    asc, desc = tau_ref[direction > 0], tau_ref[direction < 0]
    if asc.size == 0 or desc.size == 0:
        raise ValueError("both an ascending (+1) and a descending (-1) branch are needed")
    lo, hi = max(asc.min(), desc.min()), min(asc.max(), desc.max())
    if not hi > lo:
        raise ValueError(f"the ascending and descending branches do not overlap in reference "
                         f"torque (common range [{lo:g}, {hi:g}] N m)")
    return np.linspace(lo, hi, int(n_bins) + 1)


def _bin_mean(idx, values, m) -> tuple[np.ndarray, np.ndarray]:
    ok = idx >= 0
    count = np.bincount(idx[ok], minlength=m)
    total = np.bincount(idx[ok], weights=values[ok], minlength=m)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan), count


def _branch_error_at_centres(idx, t, r, centres, slope, m) -> tuple[np.ndarray, np.ndarray]:
    """``o(c) - c`` per bin with ``o(c) = mean(t) + slope * (c - mean(r))``; and the counts."""
    mean_t, count = _bin_mean(idx, t, m)
    mean_r, _ = _bin_mean(idx, r, m)
    return mean_t + slope * (centres - mean_r) - centres, count


def branch_curves(tau_ref: np.ndarray, tau_hat: np.ndarray, direction: np.ndarray, *,
                  bin_edges_nm: np.ndarray | None = None,
                  n_bins: int = DEFAULT_N_BINS) -> BranchCurves:
    """Each branch's output error at common reference-torque levels (bin centres ``c``).

    ``error(c) = o(c) - c`` with ``o(c) = mean(tau_hat) + s * (c - mean(tau_ref))`` over the
    branch's samples in the bin and ``s`` the global least-squares sensitivity (module docstring).

    Parameters
    ----------
    tau_ref, tau_hat : numpy.ndarray, shape (N,)
        Reference and sensor torque [N m].
    direction : numpy.ndarray, shape (N,)
        +1 ascending, -1 descending, 0 ignored (see :func:`reference_direction`).
    bin_edges_nm : numpy.ndarray, optional
        Explicit bin edges [N m], e.g. around the test-weight levels.
    n_bins : int
        Otherwise, equal bins over the reference range both branches cover.
    """
    t, r = _pair(tau_hat, tau_ref)
    d = _direction(direction, r.size)
    edges = _edges(r, d, bin_edges_nm, n_bins)
    m = edges.size - 1
    centres = 0.5 * (edges[:-1] + edges[1:])
    idx = _bin_index(r, edges)
    slope = _sensitivity(t, r, d)
    asc, asc_n = _branch_error_at_centres(np.where(d > 0, idx, -1), t, r, centres, slope, m)
    desc, desc_n = _branch_error_at_centres(np.where(d < 0, idx, -1), t, r, centres, slope, m)
    both = (asc_n > 0) & (desc_n > 0)
    if not np.any(both):
        raise ValueError("no reference-torque bin holds samples of both branches")
    return BranchCurves(bin_edges_nm=edges, level_nm=centres, ascending_error_nm=asc,
                        descending_error_nm=desc, ascending_count=asc_n, descending_count=desc_n,
                        both=both, sensitivity=slope)


def _sensitivity(t: np.ndarray, r: np.ndarray, d: np.ndarray) -> float:
    """Least-squares slope of ``t`` on ``r`` over the samples with a branch (d != 0)."""
    sel = d != 0
    rc = r[sel] - r[sel].mean()
    den = float(rc @ rc)
    if den == 0.0:
        raise ValueError("the reference torque does not vary on the branch samples")
    return float(rc @ (t[sel] - t[sel].mean())) / den


@dataclass(frozen=True, eq=False)
class NonlinearityResult:
    """Nonlinearity (Table III, Fig. 7(a)-(c)).

    Attributes
    ----------
    nonlinearity_pct_fs : float
        ``100 * max |deviation| / FS``.
    max_deviation_nm : float
        Largest |deviation| of the branch-average curve from its least-squares line [N m].
    at_level_nm : float
        Reference torque where it occurs [N m].
    slope : float
        Slope of the least-squares line [-] (output per reference torque).
    offset_nm : float
        Its intercept [N m].
    level_nm, deviation_nm : numpy.ndarray, shape (M',)
        The deviation curve (Fig. 7(c)) on the bins holding both branches.
    fs_nm : float
    """

    nonlinearity_pct_fs: float
    max_deviation_nm: float
    at_level_nm: float
    slope: float
    offset_nm: float
    level_nm: np.ndarray
    deviation_nm: np.ndarray
    fs_nm: float


def nonlinearity(tau_ref: np.ndarray, tau_hat: np.ndarray, direction: np.ndarray, *,
                 fs_nm: float = _FS_NM, bin_edges_nm: np.ndarray | None = None,
                 n_bins: int = DEFAULT_N_BINS) -> NonlinearityResult:
    """Nonlinearity [% FS]: max deviation of the average of the two branches from its LS line.

    On each bin holding both branches, the average output curve is
    ``o(c) = c + (e_asc(c) + e_desc(c)) / 2`` (``c`` the bin's reference torque, ``e`` the mean
    error of a branch there); a straight line ``slope * c + offset`` is fitted to ``o`` by least
    squares, and the nonlinearity is ``100 * max_c |o(c) - slope * c - offset| / FS``.
    """
    fs = _fs(fs_nm)
    bc = branch_curves(tau_ref, tau_hat, direction, bin_edges_nm=bin_edges_nm, n_bins=n_bins)
    c = bc.level_nm[bc.both]
    if c.size < 2:
        raise ValueError("nonlinearity needs at least 2 bins holding both branches")
    out = c + 0.5 * (bc.ascending_error_nm[bc.both] + bc.descending_error_nm[bc.both])
    slope, offset = np.polyfit(c, out, 1)
    dev = out - (slope * c + offset)
    k = int(np.argmax(np.abs(dev)))
    return NonlinearityResult(nonlinearity_pct_fs=_PCT * abs(dev[k]) / fs,
                              max_deviation_nm=float(abs(dev[k])), at_level_nm=float(c[k]),
                              slope=float(slope), offset_nm=float(offset), level_nm=c,
                              deviation_nm=dev, fs_nm=fs)


@dataclass(frozen=True, eq=False)
class HysteresisResult:
    """Hysteresis (Table III, Fig. 7(d)).

    Attributes
    ----------
    hysteresis_pct_fs : float
        ``100 * max |e_asc - e_desc| / FS``.
    max_difference_nm : float
        Largest branch difference at the same reference torque [N m].
    at_level_nm : float
        Reference torque where it occurs [N m].
    level_nm, difference_nm : numpy.ndarray, shape (M',)
        ``e_asc - e_desc`` on the bins holding both branches [N m].
    fs_nm : float
    """

    hysteresis_pct_fs: float
    max_difference_nm: float
    at_level_nm: float
    level_nm: np.ndarray
    difference_nm: np.ndarray
    fs_nm: float


def hysteresis(tau_ref: np.ndarray, tau_hat: np.ndarray, direction: np.ndarray, *,
               fs_nm: float = _FS_NM, bin_edges_nm: np.ndarray | None = None,
               n_bins: int = DEFAULT_N_BINS) -> HysteresisResult:
    """Hysteresis [% FS]: ``100 * max_c |e_asc(c) - e_desc(c)| / FS`` over bins holding both
    branches (the output difference of the two branches at the same reference torque ``c``)."""
    fs = _fs(fs_nm)
    bc = branch_curves(tau_ref, tau_hat, direction, bin_edges_nm=bin_edges_nm, n_bins=n_bins)
    c = bc.level_nm[bc.both]
    diff = bc.ascending_error_nm[bc.both] - bc.descending_error_nm[bc.both]
    k = int(np.argmax(np.abs(diff)))
    return HysteresisResult(hysteresis_pct_fs=_PCT * abs(diff[k]) / fs,
                            max_difference_nm=float(abs(diff[k])), at_level_nm=float(c[k]),
                            level_nm=c, difference_nm=diff, fs_nm=fs)


@dataclass(frozen=True, eq=False)
class RepeatabilityResult:
    """Repeatability (Table IV).

    Attributes
    ----------
    repeatability_pct_fs : float
        ``100 * max spread / FS``.
    max_spread_nm : float
        Largest range (max - min) across cycles of the per-cycle output error at one bin centre
        and branch [N m].
    at_level_nm : float
        Reference torque of that bin [N m].
    at_direction : int
        Its branch (+1 ascending, -1 descending).
    n_cycles : int
        Distinct cycle labels seen.
    fs_nm : float
    """

    repeatability_pct_fs: float
    max_spread_nm: float
    at_level_nm: float
    at_direction: int
    n_cycles: int
    fs_nm: float


def repeatability(tau_ref: np.ndarray, tau_hat: np.ndarray, cycle: np.ndarray,
                  direction: np.ndarray, *, fs_nm: float = _FS_NM,
                  bin_edges_nm: np.ndarray | None = None,
                  n_bins: int = DEFAULT_N_BINS) -> RepeatabilityResult:
    """Repeatability [% FS]: max spread across repeated cycles at the same reference level.

    For every reference-torque bin and branch, each cycle's output error at the bin centre is
    formed as in :func:`branch_curves`; the spread is ``max - min`` over the cycles present (at
    least 2); the result is the largest spread over bins and branches divided by FS.

    Parameters
    ----------
    tau_ref, tau_hat : numpy.ndarray, shape (N,)
        [N m].
    cycle : numpy.ndarray of int, shape (N,)
        Repetition each sample belongs to (the paper: five loadings per direction).
    direction : numpy.ndarray, shape (N,)
        +1 / -1 / 0 as in :func:`branch_curves`.
    """
    fs = _fs(fs_nm)
    t, r = _pair(tau_hat, tau_ref)
    d = _direction(direction, r.size)
    cyc = np.asarray(cycle)
    if cyc.shape != r.shape or not np.issubdtype(cyc.dtype, np.integer):
        raise ValueError(f"cycle must be an integer array of shape {r.shape}; got dtype "
                         f"{cyc.dtype} and shape {cyc.shape}")
    labels, cyc_idx = np.unique(cyc, return_inverse=True)
    if labels.size < 2:
        raise ValueError(f"repeatability needs at least 2 cycles; got {labels.size}")
    edges = _edges(r, d, bin_edges_nm, n_bins)
    m = edges.size - 1
    centres = 0.5 * (edges[:-1] + edges[1:])
    idx = _bin_index(r, edges)
    slope = _sensitivity(t, r, d)
    nc = labels.size
    best = (-1.0, math.nan, 0)
    for sign in (1, -1):
        sel = (d == sign) & (idx >= 0)
        key = idx[sel] * nc + cyc_idx[sel]
        err, count = _branch_error_at_centres(key, t[sel], r[sel], np.repeat(centres, nc), slope,
                                              m * nc)
        err, count = err.reshape(m, nc), count.reshape(m, nc)
        enough = np.sum(count > 0, axis=1) >= 2
        if not np.any(enough):
            continue
        spread = np.nanmax(err[enough], axis=1) - np.nanmin(err[enough], axis=1)
        k = int(np.argmax(spread))
        if spread[k] > best[0]:
            best = (float(spread[k]), float(centres[enough][k]), sign)
    if best[0] < 0:
        raise ValueError("no reference-torque bin holds samples of two or more cycles on one branch")
    return RepeatabilityResult(repeatability_pct_fs=_PCT * best[0] / fs, max_spread_nm=best[0],
                               at_level_nm=best[1], at_direction=best[2], n_cycles=labels.size,
                               fs_nm=fs)


# --- Crosstalk and resolution ----------------------------------------------------------------------------
@dataclass(frozen=True)
class CrosstalkResult:
    """Crosstalk of T_x or T_y into the T_z output (Table IV).

    Attributes
    ----------
    crosstalk_pct_fs : float
        ``100 * max |tau_hat - tau_z| / FS``.
    max_apparent_torque_nm : float
        Largest apparent T_z output [N m].
    at_index : int
        Sample where it occurs.
    max_applied_moment_nm : float or None
        ``max |M|`` of the applied moment if given [N m].
    pct_of_applied_moment : float or None
        ``100 * max_apparent_torque_nm / max_applied_moment_nm`` [%] if given.
    fs_nm : float
    """

    crosstalk_pct_fs: float
    max_apparent_torque_nm: float
    at_index: int
    max_applied_moment_nm: float | None
    pct_of_applied_moment: float | None
    fs_nm: float


def crosstalk(tau_hat: np.ndarray, *, tau_z_ref: np.ndarray | None = None,
              applied_moment_nm: np.ndarray | None = None, tare_mask: np.ndarray | None = None,
              fs_nm: float = _FS_NM) -> CrosstalkResult:
    """Crosstalk [% FS]: the apparent T_z output under an applied T_x or T_y moment.

    ``crosstalk = 100 * max_k |tau_hat_k - tau_z,k| / FS`` over the moment test, with ``tau_z`` the
    applied T_z (zero unless ``tau_z_ref`` is given). If ``tare_mask`` is given, the mean of
    ``tau_hat - tau_z`` over those (unloaded) samples is removed first.

    Parameters
    ----------
    tau_hat : numpy.ndarray, shape (N,)
        Sensor T_z output during the moment test [N m].
    tau_z_ref : numpy.ndarray, shape (N,), optional
        Reference T_z [N m].
    applied_moment_nm : numpy.ndarray, shape (N,), optional
        The applied T_x or T_y [N m], only to report the ratio to it.
    tare_mask : numpy.ndarray of bool, shape (N,), optional
        Unloaded samples for a tare.
    """
    fs = _fs(fs_nm)
    t = _vector("tau_hat", tau_hat)
    apparent = t - (0.0 if tau_z_ref is None else _vector("tau_z_ref", tau_z_ref, t.size))
    if tare_mask is not None:
        tm = np.asarray(tare_mask)
        if tm.dtype != bool or tm.shape != t.shape or not np.any(tm):
            raise ValueError(f"tare_mask must be a non-empty boolean array of shape {t.shape}")
        apparent = apparent - apparent[tm].mean()
    k = int(np.argmax(np.abs(apparent)))
    amax = float(abs(apparent[k]))
    m_max = pct_m = None
    if applied_moment_nm is not None:
        m_max = float(np.max(np.abs(_vector("applied_moment_nm", applied_moment_nm, t.size))))
        pct_m = _PCT * amax / m_max if m_max > 0 else math.inf
    return CrosstalkResult(crosstalk_pct_fs=_PCT * amax / fs, max_apparent_torque_nm=amax,
                           at_index=k, max_applied_moment_nm=m_max, pct_of_applied_moment=pct_m,
                           fs_nm=fs)


@dataclass(frozen=True)
class ResolutionResult:
    """3-sigma resolution (Sec. III-B, Fig. 8(e)-(f)).

    Attributes
    ----------
    std_nm : float
        Sample standard deviation (ddof = 1) of ``tau_hat`` over the no-load record [N m].
    resolution_3sigma_nm : float
        ``3 * std_nm`` [N m].
    n_samples : int
    duration_s : float
        ``n_samples / sample_rate_hz`` [s] (the paper: 10 s).
    """

    std_nm: float
    resolution_3sigma_nm: float
    n_samples: int
    duration_s: float


def resolution_3sigma(tau_hat_no_load: np.ndarray, *,
                      sample_rate_hz: float = RESOLUTION_SAMPLE_RATE_HZ) -> ResolutionResult:
    """3-sigma resolution: ``3 * std(tau_hat)`` over a raw no-load record [N m].

    No filtering, detrending or offset removal beyond the mean; the paper's record is 10 s at
    1 kHz (:data:`RESOLUTION_RECORD_S`, :data:`RESOLUTION_SAMPLE_RATE_HZ`); ``duration_s`` is
    returned so the caller can check it.
    """
    t = _vector("tau_hat_no_load", tau_hat_no_load)
    if t.size < 2:
        raise ValueError("tau_hat_no_load needs at least 2 samples")
    fs_hz = float(sample_rate_hz)
    if not fs_hz > 0:
        raise ValueError(f"sample_rate_hz must be > 0; got {sample_rate_hz!r}")
    std = float(np.std(t, ddof=1))
    return ResolutionResult(std_nm=std, resolution_3sigma_nm=3.0 * std, n_samples=t.size,
                            duration_s=t.size / fs_hz)


# --- Temperature (Sec. III-C, Table V) ----------------------------------------------------------------------
ZERO_DRIFT_GRID_POINTS = 200  # temperatures the fitted zero drift's slope is evaluated at


def drift_rms_nm(tau_hat: np.ndarray, tau_ref: np.ndarray) -> float:
    """A one-hour test's drift RMS: ``sqrt(mean((tau_hat - tau)^2))`` of the reading against the applied torque
    at constant load [N m] (Table V)."""
    return rms_error_nm(tau_hat, tau_ref)


def zero_drift_per_kelvin_pct_fs(zero_drift_nm, t_low_c: float, t_high_c: float, *, fs_nm: float = _FS_NM) -> float:
    """The paper's "a maximum temperature change of 1 °C resulted in about 0.014 % FS": the largest change of the
    fitted zero drift over 1 °C within the tests' temperature range [% FS].

    ``zero_drift_nm`` maps temperatures [°C] (an array) to the zero drift [N m]; its slope is taken by finite
    differences on :data:`ZERO_DRIFT_GRID_POINTS` temperatures from ``t_low_c`` to ``t_high_c`` (at least 1 °C).
    """
    grid = np.linspace(t_low_c, max(t_high_c, t_low_c + 1.0), ZERO_DRIFT_GRID_POINTS)
    slope = np.max(np.abs(np.gradient(zero_drift_nm(grid), grid)))
    return _PCT * slope * 1.0 / _fs(fs_nm)
