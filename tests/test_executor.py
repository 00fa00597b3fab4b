"""The one parallel executor: same results in the items' order wherever the items run."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim.executor import Executor


def noisy_mean(scale: float, seed: int) -> float:
    """A seeded draw: what a sweep's item computes (its seed travels with it)."""
    return scale * float(np.random.default_rng(seed).normal(size=1000).mean())


def worker_pid(shared, item) -> tuple[int, int]:
    return item, os.getpid()


def fails_on_three(shared, item) -> int:
    if item == 3:
        raise ValueError("item 3 is refused")
    return item


def test_items_come_back_in_order_and_equal_across_worker_counts():
    seeds = list(range(12))
    one = Executor(1).map(noisy_mean, seeds, shared=2.0)
    two = Executor(2).map(noisy_mean, seeds, shared=2.0)
    assert one == two == [noisy_mean(2.0, s) for s in seeds]


def test_several_processes_share_the_work_and_report_progress():
    seen = []
    results = Executor(2, progress=lambda done, total: seen.append((done, total))).map(worker_pid, range(40))
    assert [item for item, _ in results] == list(range(40))
    assert len({pid for _, pid in results}) == 2 and os.getpid() not in {pid for _, pid in results}
    assert seen[-1] == (40, 40) and len(seen) == 40


def test_a_workers_error_reaches_the_caller():
    with pytest.raises(ValueError, match="item 3 is refused"):
        Executor(2).map(fails_on_three, range(6))


@pytest.mark.parametrize("workers", [0, -1, 1.5, True])
def test_a_bad_worker_count_names_its_range(workers):
    with pytest.raises(ValueError, match="workers = .*valid range"):
        Executor(workers)


def test_a_ray_cluster_gives_the_same_results_as_local_processes():
    seeds = list(range(8))
    cluster = Executor(ray="local")
    assert cluster.map(noisy_mean, seeds, shared=2.0) == Executor(2).map(noisy_mean, seeds, shared=2.0)
    assert cluster.slots == os.cpu_count()  # the one-machine cluster offers this machine's CPUs


def test_a_local_ray_cluster_is_started_here_whatever_ray_address_names():
    """``ray="local"`` starts a cluster on this machine even where RAY_ADDRESS names another (which ray.init()
    without an address would try to join)."""
    code = ("from sim.executor import Executor; "
            "print(Executor(ray='local').map(lambda shared, item: item + shared, [1, 2], shared=10))")
    env = {**os.environ, "RAY_ADDRESS": "127.0.0.1:1"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "[11, 12]"


def test_slots_are_the_local_processes():
    assert (Executor(1).slots, Executor(3).slots) == (1, 3)


def blas_thread_counts(shared, item) -> list[int]:
    import threadpoolctl

    return [i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]


@pytest.mark.parametrize("executor", [lambda: Executor(1), lambda: Executor(2), lambda: Executor(ray="local")],
                         ids=["this process", "2 processes", "a local Ray cluster"])
def test_every_item_runs_with_one_blas_thread_wherever_it_runs(executor):
    """One BLAS thread per item: Ray's workers have one, and a linear-algebra result can differ in its last bits
    with the thread count."""
    counts = executor().map(blas_thread_counts, range(3))
    assert all(c and set(c) == {1} for c in counts)
