"""Thread pools that fit the machine: every run, probe and study sets them.

A process may use fewer cores than the machine has: its CPU affinity
(``taskset``, a batch scheduler) and its cgroup's CPU quota (a container
with ``--cpus``) both limit it, while numpy's BLAS and numba start one
thread per core of the machine.  On a loaded machine a BLAS pool larger
than the free cores is worse than none: OpenBLAS threads wait for each
other by spinning, and a product of two 96 × 96 matrices then waits for
the scheduler (docs/operations.md, "Threads").

:func:`usable_cores` is the number of cores the process may use;
:func:`pools` sets the BLAS/OpenMP pools (threadpoolctl) and numba's thread
count inside a block and restores them on leaving.  What a run uses is the
model's choice (:meth:`liethermo.models.Model.thread_counts`): the top's
kernels run members on ``usable_cores()`` threads and need no BLAS; the
fluid uses BLAS on one thread below a measured matrix size.
:func:`kernels_running` marks a call of a model's kernels, which take every
kernel thread; a run's writer thread waits for its end
(:func:`wait_for_kernels`) rather than take a core from it.

Thread counts change no result: the top's members are independent of one
another, and the fluid's BLAS products (OpenBLAS ``zgemm``/``dgemm``) give
the same bits on one and two threads (tests/test_threads.py checks both).
"""

from __future__ import annotations

import math
import os
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

#: cgroup v2 and v1 files that hold a CPU quota (the first that exists counts)
_CGROUP_V2 = Path("/sys/fs/cgroup/cpu.max")
_CGROUP_V1 = (Path("/sys/fs/cgroup/cpu/cpu.cfs_quota_us"), Path("/sys/fs/cgroup/cpu/cpu.cfs_period_us"))


def affinity_cores() -> int:
    """Cores in the process's CPU affinity mask (the machine's where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def cgroup_quota_cores(v2: Path = _CGROUP_V2, v1: tuple = _CGROUP_V1) -> float | None:
    """The cgroup's CPU quota in cores (``cpu.max`` 200000 100000 → 2.0); None: no quota."""
    try:
        quota, period = v2.read_text().split()[:2]
        return None if quota == "max" else int(quota) / int(period)
    except (OSError, ValueError):
        pass
    try:
        quota, period = (int(p.read_text()) for p in v1)
        return None if quota <= 0 else quota / period
    except (OSError, ValueError):
        return None


def usable_cores() -> int:
    """The cores this process may use: its affinity, capped by its cgroup's
    quota (rounded up: 1.5 cores lets two threads run half the time each)."""
    n = affinity_cores()
    q = cgroup_quota_cores()
    if q is not None and q > 0:
        n = min(n, max(1, math.ceil(q)))
    return n


@dataclass(frozen=True)
class ThreadCounts:
    """What a run uses: ``blas`` threads in numpy's BLAS/OpenMP pools,
    ``kernel`` threads for the model's own kernels (numba), and why."""

    blas: int
    kernel: int
    why: str = ""

    def line(self) -> str:
        return (f"  threads: {self.kernel} for the kernels, {self.blas} for BLAS (of {usable_cores()} usable "
                f"core(s)){'; ' + self.why if self.why else ''}")


#: the kernel threads set by :func:`pools` (None: outside one, the usable cores)
_kernel_threads: int | None = None


def kernel_threads() -> int:
    """Threads for a model's own kernels: the count :func:`pools` set, else
    :func:`usable_cores`; never more than ``NUMBA_NUM_THREADS`` (a Dask
    worker sets 1)."""
    import numba

    n = usable_cores() if _kernel_threads is None else _kernel_threads
    return max(1, min(n, int(numba.config.NUMBA_NUM_THREADS)))


#: the process's thread pools, by thread count and name (:func:`thread_pool`)
_POOLS: dict = {}


def thread_pool(threads: int, name: str = "liethermo"):
    """The process's pool of ``threads`` threads named ``name`` (made on first use, then
    kept): the top's kernel tasks and summary slices use ``liethermo``; a helper that may
    run while those are busy takes a name of its own, so it never waits behind them."""
    from concurrent.futures import ThreadPoolExecutor

    key = (int(threads), name)
    pool = _POOLS.get(key)
    if pool is None:
        pool = _POOLS[key] = ThreadPoolExecutor(int(threads), thread_name_prefix=name)
    return pool


def pooled_kernel_threads() -> int:
    """:func:`kernel_threads` inside a :func:`pools` block, else 1: a helper called many
    times a run (the fluid's fixed points, once a substep) splits work over threads only
    where a run, probe or study has sized the pools to the machine, and never reads the
    affinity and cgroup files on each call."""
    return 1 if _kernel_threads is None else kernel_threads()


@contextmanager
def pools(counts: ThreadCounts) -> Iterator[ThreadCounts]:
    """Set the BLAS/OpenMP pools (threadpoolctl) and the kernels' thread count
    (:func:`kernel_threads`) to ``counts`` inside the block; both restored on leaving.
    Inside a block that set the same counts (a run's chunk loop, each chunk asking for
    them again) there is nothing to set: threadpoolctl's scan of the loaded libraries
    is skipped."""
    from threadpoolctl import threadpool_limits

    global _kernel_threads, _active
    if counts == _active:
        yield counts
        return
    old, old_active = _kernel_threads, _active
    _kernel_threads = max(1, int(counts.kernel))
    _active = counts
    try:
        with threadpool_limits(limits=max(1, int(counts.blas))):
            yield counts
    finally:
        _kernel_threads, _active = old, old_active


#: the counts of the innermost :func:`pools` block that set them (None: outside one)
_active: ThreadCounts | None = None


_kernels_idle = threading.Event()
_kernels_idle.set()
_kernel_calls_lock = threading.Lock()
_kernel_calls = 0


@contextmanager
def kernels_running() -> Iterator[None]:
    """Marks a call of a model's kernels, which use every kernel thread: host work that
    can wait for it (:func:`wait_for_kernels`: the writer thread of a run) does, instead of
    taking a core from the kernels.  Calls may nest or run on several threads at once."""
    global _kernel_calls
    with _kernel_calls_lock:
        _kernel_calls += 1
        _kernels_idle.clear()
    try:
        yield
    finally:
        with _kernel_calls_lock:
            _kernel_calls -= 1
            if _kernel_calls == 0:
                _kernels_idle.set()


def wait_for_kernels() -> None:
    """Until no call of the kernels runs (:func:`kernels_running`); at once if none does."""
    _kernels_idle.wait()


__all__ = ["ThreadCounts", "affinity_cores", "cgroup_quota_cores", "kernel_threads", "kernels_running", "pools",
           "usable_cores", "wait_for_kernels"]
