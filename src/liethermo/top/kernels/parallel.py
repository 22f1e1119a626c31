"""Run kernels on threads: member ranges (straightforward kernel) or block
ranges (vectorized kernel), split into about twelve tasks per thread so that
uneven members (diverging RK members, slow Newton iterations) and a core
taken away for a while (a shared or virtual machine) balance out
(benchmarks/README.md, "Whole runs against their kernels").

The kernel functions are compiled with ``nogil=True``; Python threads then
run them truly in parallel, with no numba threading layer to compile or
configure.  ``threads`` defaults to :func:`liethermo.threads.kernel_threads`:
the cores the process may use (affinity, cgroup quota) or what the run set,
capped by ``NUMBA_NUM_THREADS`` (a Dask worker sets 1).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

TASKS_PER_THREAD = 12


def default_threads() -> int:
    from ...threads import kernel_threads

    return kernel_threads()


def pool(threads: int) -> ThreadPoolExecutor:
    """The process's pool of ``threads`` threads (made on first use, then kept):
    :func:`liethermo.threads.thread_pool`."""
    from ...threads import thread_pool

    return thread_pool(threads)


def run_ranges(fn, n_items: int, args_before: tuple, args_after: tuple,
               threads: int | None = None, min_items: int = 1) -> None:
    """Call ``fn(*args_before, lo, hi, *args_after)`` over ranges [lo, hi)
    covering 0 … n_items−1, on ``threads`` threads (a first call that must
    compile holds numba's compiler lock; the others wait for it)."""
    if n_items <= 0:
        return
    threads = default_threads() if threads is None else max(1, int(threads))
    ntasks = 1 if threads == 1 else min(n_items // max(1, min_items) or 1, TASKS_PER_THREAD * threads)
    bounds = [round(k * n_items / ntasks) for k in range(ntasks + 1)]
    ranges = [(bounds[k], bounds[k + 1]) for k in range(ntasks) if bounds[k + 1] > bounds[k]]
    from ...threads import kernels_running

    with kernels_running():  # a run's writer thread waits meanwhile
        if len(ranges) == 1:
            fn(*args_before, ranges[0][0], ranges[0][1], *args_after)
            return
        futures = [pool(threads).submit(fn, *args_before, lo, hi, *args_after)
                   for lo, hi in ranges]
        for f in futures:
            f.result()


__all__ = ["run_ranges", "default_threads", "pool"]
