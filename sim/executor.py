"""One parallel executor for every sweep: in this process, on local processes, or on a Ray cluster.

``Executor(workers=N)`` maps a function over items on N local processes (1: in this process);
``Executor(ray="auto" | ADDRESS)`` on a Ray cluster (``pip install -e ".[ray]"``; ``"local"`` starts a
one-machine cluster). ``map(fn, items, shared=...)`` returns ``[fn(shared, item) for item in items]`` in the
items' order, whatever ran where: a function that draws its random numbers from seeds carried by its item gives
the same result on one core, on many, or on a cluster. ``shared`` (a model, a parameter set) is sent once per
worker, not once per item. Every item runs with one BLAS thread (Ray's workers have one; a linear-algebra result
can differ in its last bits with the thread count), which also keeps N workers from oversubscribing N cores.

The function must be importable by name (a module-level function), as for any process pool.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import threadpoolctl

RAY_EXTRA = 'pip install -e ".[ray]"'

_shared: Any = None  # the shared object of a worker process, set by its initialiser


def _set_shared(shared: Any) -> None:
    global _shared
    _shared = shared


def _call_with_shared(fn: Callable, item: Any) -> Any:
    return _call(fn, _shared, item)


def _call(fn: Callable, shared: Any, item: Any) -> Any:
    """``fn(shared, item)`` with one BLAS thread (the count restored after)."""
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
        return fn(shared, item)


class Executor:
    """Runs ``fn(shared, item)`` over items, in order; see the module docstring.

    Parameters
    ----------
    workers : int
        Local processes (>= 1; 1 runs in this process). Ignored with ``ray``.
    ray : str, optional
        A Ray cluster's address (``"auto"``: the one this machine is attached to; ``"local"``: start one on this
        machine), or None for local processes.
    progress : callable, optional
        ``progress(done, total)`` after each finished item (in completion order).
    """

    def __init__(self, workers: int = 1, ray: str | None = None,
                 progress: Callable[[int, int], None] | None = None) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers = {workers!r}: valid range [1, {os.cpu_count() or 1}] processes")
        self.workers, self.ray_address, self.progress = workers, ray, progress
        self._ray = None
        if ray is not None:
            try:
                import ray as ray_module
            except ImportError as exc:
                raise RuntimeError(f"a Ray cluster was asked for (ray = {ray!r}) but Ray is not installed: "
                                   f"{RAY_EXTRA}") from exc
            if not ray_module.is_initialized():
                ray_module.init(address=ray, ignore_reinit_error=True,
                                log_to_driver=False, include_dashboard=False)
            self._ray = ray_module

    @property
    def where(self) -> str:
        """Where the items run, for a progress line: 'this process', '4 processes', 'Ray at auto'."""
        if self._ray is not None:
            return f"Ray at {self.ray_address}"
        return "this process" if self.workers == 1 else f"{self.workers} processes"

    @property
    def slots(self) -> int:
        """How many items run at once: the local processes, or the Ray cluster's CPUs."""
        if self._ray is not None:
            return max(1, int(self._ray.cluster_resources().get("CPU", 1)))
        return self.workers

    def map(self, fn: Callable[[Any, Any], Any], items: Iterable[Any], shared: Any = None) -> list[Any]:
        """``[fn(shared, item) for item in items]``, computed where the executor runs, in the items' order."""
        items = list(items)
        if self._ray is not None:
            return self._map_ray(fn, items, shared)
        if self.workers == 1 or len(items) <= 1:
            results = []
            for item in items:
                results.append(_call(fn, shared, item))
                self._tick(len(results), len(items))
            return results
        return self._map_processes(fn, items, shared)

    def _tick(self, done: int, total: int) -> None:
        if self.progress is not None:
            self.progress(done, total)

    def _map_processes(self, fn: Callable, items: Sequence[Any], shared: Any) -> list[Any]:
        results: list[Any] = [None] * len(items)
        with ProcessPoolExecutor(max_workers=min(self.workers, len(items)), initializer=_set_shared,
                                 initargs=(shared,)) as pool:
            futures = {pool.submit(_call_with_shared, fn, item): i for i, item in enumerate(items)}
            for done, future in enumerate(as_completed(futures), start=1):
                results[futures[future]] = future.result()
                self._tick(done, len(items))
        return results

    def _map_ray(self, fn: Callable, items: Sequence[Any], shared: Any) -> list[Any]:
        ray = self._ray
        remote = ray.remote(_call)
        shared_ref = ray.put(shared)
        refs = [remote.remote(fn, shared_ref, item) for item in items]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[Any] = [None] * len(items)
        pending, done = list(refs), 0
        while pending:
            finished, pending = ray.wait(pending, num_returns=1)
            for ref in finished:
                results[index[ref]] = ray.get(ref)
                done += 1
                self._tick(done, len(items))
        return results


def stderr_progress(label: str) -> Callable[[int, int], None]:
    """A ``progress`` callable printing 'label: done/total' to stderr."""
    def report(done: int, total: int) -> None:
        print(f"{label}: {done}/{total}", file=sys.stderr, flush=True)
    return report
