"""Zeitlin fluid: time per member-step of split and rk4 against the BLAS bound.

    python benchmarks/zeitlin_bench.py                       # N = 32, 64, 128, 256; 64 members
    python benchmarks/zeitlin_bench.py --N 128 --loop        # also the per-member loop of products
    PYTHONPATH=/path/to/quflow python benchmarks/zeitlin_bench.py --quflow --no-table --nu 0   # quflow as a peer

The members are the ``zeitlin_decay`` scene's random fields (l ≤ 8, unit
energy) at each N, h = 0.01 s, viscosity 1e-3; the fixed point starts from
the extrapolated solutions of the last steps, as in a run.  Timings are warm (a first
step compiles and fills caches) and repeated for at least ``--seconds``; the
figure is the median of ``--rounds`` rounds alternating the methods.  The
bound: a fixed-point iteration of the isospectral midpoint is "about 4
complex GEMMs" (32 N³ flops) in the usual formulation; ours needs 2 (X = A W̃,
then X A; [A, W̃] = X − X† since A and W̃ are skew-Hermitian), 16 N³ flops.
Both bounds are given, at the DGEMM rate this machine measures (its ZGEMM
rate at that N is printed too).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from bench import cpu_name  # run as python benchmarks/zeitlin_bench.py: benchmarks/ is on the path
from liethermo.scene import load_scene
from liethermo.zeitlin import kernels as zk
from liethermo.zeitlin import run as zr


def gemm_rate(n: int, dtype, seconds: float = 0.5) -> float:
    """flop/s of one n×n product (real: 2n³ flops, complex: 8n³)."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, n)).astype(dtype)
    b = rng.standard_normal((n, n)).astype(dtype)
    if np.iscomplexobj(a):
        a = a + 1j * rng.standard_normal((n, n))
        b = b + 1j * rng.standard_normal((n, n))
    a @ b
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a @ b
        k += 1
    flops = (8 if np.iscomplexobj(a) else 2) * n ** 3
    return k * flops / (time.perf_counter() - t0)


def batched_zgemm_rate(n: int, members: int, seconds: float = 0.3) -> float:
    rng = np.random.default_rng(0)
    a = rng.standard_normal((members, n, n)) + 1j * rng.standard_normal((members, n, n))
    b = rng.standard_normal((members, n, n)) + 1j * rng.standard_normal((members, n, n))
    a @ b
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a @ b
        k += 1
    return k * 8 * n ** 3 * members / (time.perf_counter() - t0)


def fields(N: int, members: int) -> np.ndarray:
    sc = load_scene("zeitlin_decay", {"zeitlin.N": N, "initial.lmax": min(8, N - 1), "ensemble.members": members})
    return zr.initial_fields(sc)


def time_steps(step, seconds: float) -> tuple[float, int]:
    step()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        step()
        n += 1
    return (time.perf_counter() - t0) / n, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--N", type=int, nargs="+", default=[32, 64, 128, 256])
    ap.add_argument("--members", type=int, default=64)
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--nu", type=float, default=1e-3)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--loop", action="store_true", help="also time the products member by member (np.dot)")
    ap.add_argument("--quflow", action="store_true", help="time quflow's isomp_fixedpoint (importable quflow)")
    ap.add_argument("--no-table", action="store_true", help="skip the liethermo table (with --quflow)")
    ap.add_argument("--steps", type=int, default=2000, help="steps of each run of the quflow comparison")
    args = ap.parse_args()

    print(f"{cpu_name()}, {os.cpu_count()} cores, numpy {np.__version__}, "
          f"{time.strftime('%Y-%m-%d')}, {args.members} members, h = {args.h} s, ν = {args.nu}")
    dgemm = gemm_rate(1024, np.float64, 1.0)
    print(f"DGEMM rate (1024³, all threads): {dgemm / 1e9:.1f} GFLOP/s")
    print()
    head = ("|   N | split µs/member-step | its/step | µs/iteration | bound 32N³ µs/it | × bound | "
            "bound 16N³ × | batched ZGEMM GFLOP/s | rk4 µs/member-step |")
    if args.no_table:
        args.N_table = []
    else:
        args.N_table = args.N
    print(head)
    print("|" + "---|" * head.count("|")[:-1] if False else "|---|---|---|---|---|---|---|---|---|")
    for N in args.N_table:
        b = zk.basis(N)
        W0 = fields(N, args.members)
        state = {"D": None, "its": [], "W": W0, "q": np.zeros(args.members), "Wr": W0, "qr": np.zeros(args.members)}
        predictor, members = zr.Predictor(1, args.members, N), np.arange(args.members)

        def split_step():  # as a run steps: the fixed point starts from the last steps' solutions, extrapolated
            state["W"], state["q"], its, failed, state["D"] = zr.split_step(
                state["W"], state["q"], args.h, args.nu, b, (1.0,), 1e-14, 100, state["D"], predictor, members)
            assert not failed.any()
            state["its"].append(its.mean())

        def rk4_step():
            state["Wr"], state["qr"] = zr.rk4_step(state["Wr"], state["qr"], args.h, args.nu, b)

        ts, tr = [], []
        for _ in range(args.rounds):
            ts.append(time_steps(split_step, args.seconds)[0])
            tr.append(time_steps(rk4_step, args.seconds)[0])
        t_split = statistics.median(ts) / args.members
        t_rk4 = statistics.median(tr) / args.members
        its = float(np.mean(state["its"]))
        per_it = t_split / its
        b32 = 32 * N ** 3 / dgemm
        zrate = batched_zgemm_rate(N, args.members)
        print(f"| {N:3d} | {t_split * 1e6:.1f} | {its:.2f} | {per_it * 1e6:.2f} | {b32 * 1e6:.2f} | "
              f"{per_it / b32:.2f} | {per_it / (b32 / 2):.2f} | {zrate / 1e9:.1f} | {t_rk4 * 1e6:.1f} |")
        if args.loop:
            A = rng_skew(N, args.members)
            t_batch = time_steps(lambda: A @ A, 0.3)[0]
            t_loop = time_steps(lambda: [np.dot(a, a) for a in A], 0.3)[0]
            print(f"|     | products: batched matmul {t_batch / args.members * 1e6:.1f} µs, "
                  f"member loop {t_loop / args.members * 1e6:.1f} µs per member |")
    if args.quflow:
        quflow_peer(args)
    else:
        print()
        print("(--quflow adds quflow's isomp_fixedpoint as a peer)")


def rng_skew(N, M):
    rng = np.random.default_rng(1)
    A = rng.standard_normal((M, N, N)) + 1j * rng.standard_normal((M, N, N))
    return A - np.conj(np.swapaxes(A, 1, 2))


def _drift(W0: np.ndarray, W: np.ndarray) -> tuple[float, float]:
    """Relative change of tr W² and tr W⁴ (one member)."""
    c0, c1 = zk.casimirs(W0[None], (2, 4))[0], zk.casimirs(W[None], (2, 4))[0]
    return abs(c1[0] / c0[0] - 1), abs(c1[1] / c0[1] - 1)


def quflow_peer(args) -> None:
    """quflow's isomp_fixedpoint against our split step, like for like: one
    member, ν = 0, the same field and h, ``--steps`` steps, at several
    tolerances of each; the Casimir drift each leaves and its cost per step
    (the minimum over ``--rounds`` interleaved rounds).  quflow stops on the
    absolute change of its iterate in the row-sum norm (‖·‖∞) or when the
    change stops falling; liethermo on the largest entry of the change against
    tol × max|W|, or when it stalls below 100 × that."""
    import quflow as qf

    print()
    print(f"quflow isomp_fixedpoint against liethermo split: one member, ν = 0, h = {args.h} s, "
          f"{args.steps} steps, min of {args.rounds} interleaved rounds")
    print("| N | code | tolerance | ms/step | its/step | tr W² drift | tr W⁴ drift |")
    print("|---|---|---|---:|---:|---:|---:|")
    for N in args.N:
        W0 = fields(N, 1)
        b = zk.basis(N)
        winf = float(np.linalg.norm(W0[0], np.inf))
        runs = [("liethermo", f"{t:g} max|W|", t) for t in (1e-14, 1e-15, 1e-16)]
        runs += [("quflow", "auto: √ε h/ħ ‖W‖∞", "auto")]
        runs += [("quflow", f"{t:g} ‖W‖∞", t * winf) for t in (1e-13, 1e-14, 1e-15)]
        best: dict = {}
        for _ in range(args.rounds):
            for code, label, tol in runs:
                if code == "quflow":
                    W = W0[0].copy()
                    stats: dict = {"filled": True}  # quflow fills only a non-empty dict
                    qf.isomp_fixedpoint(W.copy(), args.h, steps=2, maxit=100, tol=tol, stats=stats)  # compile
                    stats = {"filled": True}
                    t0 = time.perf_counter()
                    W = qf.isomp_fixedpoint(W, args.h, steps=args.steps, maxit=100, tol=tol, stats=stats)
                    dt = (time.perf_counter() - t0) / args.steps
                    its = stats.get("iterations", float("nan"))  # per step, over this call
                else:
                    W, q, D, pred = W0.copy(), np.zeros(1), None, zr.Predictor(1, 1, N)
                    t0 = time.perf_counter()
                    n_its = 0.0
                    for _k in range(args.steps):
                        W, q, it, failed, D = zr.split_step(W, q, args.h, 0.0, b, (1.0,), tol, 100, D, pred,
                                                            np.zeros(1, int))
                        n_its += float(it[0])
                    dt = (time.perf_counter() - t0) / args.steps
                    its = n_its / args.steps
                    W = W[0]
                key = (code, label)
                d2, d4 = _drift(W0[0], W)
                if key not in best or dt < best[key][0]:
                    best[key] = (dt, its, d2, d4)
        for code, label, _tol in runs:
            dt, its, d2, d4 = best[(code, label)]
            print(f"| {N} | {code} | {label} | {dt * 1e3:.3f} | {its:.2f} | {d2:.1e} | {d4:.1e} |", flush=True)


if __name__ == "__main__":
    main()
