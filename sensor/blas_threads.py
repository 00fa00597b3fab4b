"""One BLAS thread for the duration of a numerical routine whose BLAS calls are all small.

Every BLAS call of the constrained least-squares engine (:mod:`sensor.constrained_lsq`) works on 25 columns:
with OpenBLAS's worker threads each call paid about a millisecond of thread wake-up on the 2-core development
machine, so the calibration QP at N = 1e6 took 1.3-1.8x longer with two threads than with one
(``benchmarks/README.md``). :func:`single_threaded_blas` limits the count through threadpoolctl.
"""

from __future__ import annotations

import contextlib
import functools
import threading
import warnings
from collections.abc import Callable
from typing import TypeVar

import threadpoolctl

__all__ = ["single_threaded_blas"]

F = TypeVar("F", bound=Callable)


@functools.cache
def _controller() -> threadpoolctl.ThreadpoolController:
    return threadpoolctl.ThreadpoolController()


_lock = threading.Lock()
_running = 0          # calls inside single_threaded_blas, all threads (guarded by _lock)


def single_threaded_blas(routine: F) -> F:
    """Run ``routine`` with one BLAS thread: a speed-up only, never a condition of the result.

    OpenBLAS has one process-wide thread count, which threadpoolctl lets only one Python thread change at a
    time and restores in that thread when its ``with`` block ends. So a call that starts while no other such
    call runs sets the limit for its duration (in a ``with`` block, in its own thread) and restores what it
    found; calls that start while another runs, in other threads or nested, run under whatever limit is in
    force. If threadpoolctl cannot work here the routine runs without the limit (with a RuntimeWarning).
    """
    @functools.wraps(routine)
    def wrapper(*args, **kwargs):
        global _running
        with _lock:
            first = _running == 0
            _running += 1
        try:
            limit = contextlib.nullcontext()
            if first:
                try:
                    limit = _controller().limit(limits=1, user_api="blas")
                except Exception as exc:  # the limit is a speed-up: never let it stop the routine
                    warnings.warn(f"BLAS threads not limited ({exc!r}): the fit runs at the default count",
                                  RuntimeWarning, stacklevel=2)
            with limit:
                return routine(*args, **kwargs)
        finally:
            with _lock:
                _running -= 1
    return wrapper  # type: ignore[return-value]
