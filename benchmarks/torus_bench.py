"""One step of the torus fluid's CMP at N = 127 against one step of the sphere's
``split`` at N = 128: random fields of 1 J, h = 0.01 s, 8 members, BLAS and numba
pinned to the same number of threads; milliseconds per member-step, best of
``--repeat`` timings of ``--steps`` steps after a warm-up.

    PYTHONPATH=src python benchmarks/torus_bench.py [--threads 1] [--steps 10] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def torus_cmp(N: int, members: int, steps: int, h: float, warmup: int = 2) -> float:
    from liethermo.numerics.matrix_flow import Predictor
    from liethermo.torus import kernels as tk
    from liethermo.torus import step as ts

    b = tk.basis(N)
    rng = np.random.default_rng(0)
    f = tk.modes_of_grid(rng.standard_normal((members, N, N)), b)
    f[:, (tk.wave_numbers(N)[:, None] ** 2 + tk.wave_numbers(N)[None, :] ** 2) > 16] = 0  # |m| ≤ 4
    f[:, 0, 0] = 0
    W = tk.from_modes(f, b)
    W = W * np.sqrt(1.0 / tk.kinetic_energy(W, b))[:, None, None]
    S = np.zeros_like(W)
    th = tk.Thermo()
    pred = Predictor(1, members, N)
    act = np.arange(members)

    def step(W, S):
        W, S, _, _ = ts.strang_step(W, S, h, th, b, method="cmp", composition="triple_jump", tol=1e-14,
                                    max_iter=100, predictor=pred, active=act)
        return W, S

    for _ in range(warmup):
        W, S = step(W, S)
    t0 = time.perf_counter()
    for _ in range(steps):
        W, S = step(W, S)
    return (time.perf_counter() - t0) / (members * steps)


def sphere_split(N: int, members: int, steps: int, h: float) -> float:
    from liethermo.zeitlin.xpstep import time_fluid_cpu

    return time_fluid_cpu(N, members, steps, "split", h=h)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--members", type=int, default=8)
    a = ap.parse_args(argv)
    from liethermo.timing import pinned_threads

    t_torus, t_sphere = [], []
    with pinned_threads(a.threads):
        for _ in range(a.repeat):  # alternating the two sides
            t_torus.append(torus_cmp(127, a.members, a.steps, 0.01))
            t_sphere.append(sphere_split(128, a.members, a.steps, 0.01))
    tt, tsph = min(t_torus), min(t_sphere)
    load = os.getloadavg()[0]
    print(f"threads {a.threads}, {a.members} members, {a.steps} steps, best of {a.repeat}; load {load:.1f}")
    print(f"torus cmp  N = 127: {1e3 * tt:8.2f} ms per member-step  (all: {', '.join(f'{1e3*x:.2f}' for x in t_torus)})")
    print(f"sphere split N = 128: {1e3 * tsph:8.2f} ms per member-step  (all: {', '.join(f'{1e3*x:.2f}' for x in t_sphere)})")
    print(f"ratio torus / sphere: {tt / tsph:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
