"""Zeitlin fluid: wall time of a run's steps on one and on all usable BLAS threads.

    python benchmarks/blas_threads.py                      # N = 32, 64, 96, 128, 256, 512; 2 members
    python benchmarks/blas_threads.py --N 96 256 --busy 2  # beside two busy loops (a loaded machine)

Sets the measured matrix size from which the fluid uses more than one BLAS
thread (``liethermo.zeitlin.model.BLAS_THREADED_N``).  Each size runs the
``zeitlin_decay`` scene (split, h = 0.01 s) for ``--steps`` steps, warm,
alternating the thread counts for ``--rounds`` rounds; the figure is the
median wall time.  ``--busy K`` starts K processes that spin on a core each
while timing: OpenBLAS threads wait for each other by spinning, so a pool
larger than the free cores loses far more than it gains.  The values are
the same bits on either count (tests/test_threads.py).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import time

from threadpoolctl import threadpool_limits

from liethermo.models import model_of
from liethermo.scene import load_scene
from liethermo.threads import usable_cores


def _spin(stop) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def time_run(N: int, steps: int, members: int, threads: int) -> float:
    sc = load_scene("zeitlin_decay", [f"zeitlin.N={N}", f"ensemble.members={members}",
                                      f"integrator.steps={steps}", f"output.every={steps}"])
    with threadpool_limits(threads):
        t = time.perf_counter()
        model_of(sc).run_chunk(sc, 0, members)
        return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="+", default=[32, 64, 96, 128, 256, 512])
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--members", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--busy", type=int, default=0, help="busy loops beside the timing")
    a = ap.parse_args()
    cores = usable_cores()
    stop = mp.Event()
    busy = [mp.Process(target=_spin, args=(stop,), daemon=True) for _ in range(a.busy)]
    for p in busy:
        p.start()
    try:
        print(f"# {cores} usable core(s), {a.busy} busy loop(s) beside; {a.members} members x {a.steps} steps "
              f"of split; median of {a.rounds} rounds, s (wall)")
        print(f"{'N':>5} {'1 thread':>10} {f'{cores} threads':>10} {'ratio':>7}")
        for N in a.N:
            time_run(N, 2, a.members, 1)  # basis, kernels, caches
            t = {1: [], cores: []}
            for _ in range(a.rounds):
                for n in t:
                    t[n].append(time_run(N, a.steps, a.members, n))
            m1, mc = statistics.median(t[1]), statistics.median(t[cores])
            print(f"{N:>5} {m1:>10.3f} {mc:>10.3f} {mc / m1:>7.2f}", flush=True)
    finally:
        stop.set()
        for p in busy:
            p.join()


if __name__ == "__main__":
    main()
