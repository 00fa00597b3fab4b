"""First-order low-pass (a lag of time constant 1/(2π f_c)) sampled with a zero-order-hold input.

The exact discretisation over a sample period T: y_k = y_{k-1} + g·(x_k − y_{k-1}), g = 1 − exp(−2π f_c T).
Both functions are pure and broadcast, so one call filters a scalar, or one sample of N channels or N
environments (each with its own gain if ``gain`` is an array).
"""

from __future__ import annotations

import numpy as np


def lowpass_gain(bandwidth_hz, period_s: float):
    """The update gain g = 1 − exp(−2π f_c T) of a first-order low-pass sampled every ``period_s``.

    Parameters
    ----------
    bandwidth_hz : float or array
        −3 dB frequency f_c [Hz], > 0.
    period_s : float
        Sample period T [s], > 0.

    Returns
    -------
    float or numpy.ndarray
        g in (0, 1] [-], a float for a scalar ``bandwidth_hz``.

    Raises
    ------
    ValueError
        If a bandwidth or the period is not finite and positive.
    """
    f = np.asarray(bandwidth_hz, dtype=float)
    if not (np.all(np.isfinite(f)) and np.all(f > 0.0)):
        raise ValueError(f"bandwidth_hz = {bandwidth_hz!r}: valid range (0, inf) Hz")
    if not (np.isfinite(period_s) and period_s > 0.0):
        raise ValueError(f"period_s = {period_s!r}: valid range (0, inf) s")
    g = -np.expm1(-2.0 * np.pi * f * period_s)
    return float(g) if g.ndim == 0 else g


def lowpass_step(state, sample, gain):
    """One sample of the filter: y_k = y_{k-1} + g·(x_k − y_{k-1}).

    Parameters
    ----------
    state : float or array
        y_{k-1}, the previous output (start it at the first sample for no start-up transient).
    sample : float or array
        x_k, the input held over the period ending now (same unit as ``state``).
    gain : float or array
        g of :func:`lowpass_gain`.

    Returns
    -------
    float or numpy.ndarray
        y_k, broadcast over the arguments.
    """
    return state + gain * (sample - state)
