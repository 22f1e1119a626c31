"""The torus fluid's ideal invariants over a long CMP run: 10⁴ steps at N = 31, ν = κ = 0,
the §-7 vorticity of docs/model.md's convergence check with an entropy field
s₀ = 0.6 cos(x + y) − 0.2 sin 2y, at α = 0 and at α = 0.3.  Prints the largest change of
H, tr S², tr W² (relative) and of S_tot, tr(WS) (absolute, and in units of
N max|S| (max|W|)) over the run.

    PYTHONPATH=src python benchmarks/torus_invariants.py [--steps 10000] [--N 31] [--h 0.01]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits



def main(argv=None) -> int:
    from liethermo.torus import kernels as tk
    from liethermo.torus import step as ts
    from liethermo.torus.pseudospectral import section7_modes

    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--N", type=int, default=31)
    ap.add_argument("--h", type=float, default=0.01)
    a = ap.parse_args(argv)
    N = a.N
    b = tk.basis(N)
    W = tk.from_modes(section7_modes(N)[None], b)
    f = np.zeros((1, N, N), complex)
    f[0, 1, 1] = f[0, -1, -1] = 0.3
    f[0, 0, 2], f[0, 0, -2] = 0.1j, -0.1j
    S = tk.from_modes(f, b)
    for alpha in (0.0, 0.3):
        th = tk.Thermo(alpha=alpha)
        t0 = time.perf_counter()
        with threadpool_limits(1):
            Ws, Ss, st, _, its = ts.integrate(W, S, th=th, b=b, method="cmp", h=a.h, steps=a.steps,
                                              every=a.steps // 100)
        dt = time.perf_counter() - t0
        H = np.array([tk.kinetic_energy(Ws[:, j], b)[0] + tk.U(Ss[:, j], th, b)[0] for j in range(Ws.shape[1])])
        trS2 = np.einsum("jab,jba->j", Ss[0], Ss[0]).real
        trW2 = np.einsum("jab,jba->j", Ws[0], Ws[0]).real
        trS = np.trace(Ss[0], axis1=-2, axis2=-1).real
        trWS = np.einsum("jab,jba->j", Ws[0], Ss[0]).real
        s, w = np.abs(S).max(), np.abs(W).max()
        rel = lambda x: np.abs(x - x[0]).max() / abs(x[0])  # noqa: E731
        print(f"alpha = {alpha}: {a.steps} CMP steps of h = {a.h} s at N = {N}, status {st[0]}, {dt:.1f} s, "
              f"fixed-point iterations {its[0, 1:].mean():.2f} per step")
        print(f"  |ΔH|/H {rel(H):.2e}   |Δtr S²|/tr S² {rel(trS2):.2e}   |Δtr W²|/tr W² {rel(trW2):.2e}"
              + ("" if alpha == 0 else " (not conserved at α > 0)"))
        print(f"  |Δtr S| {np.abs(trS - trS[0]).max():.2e} = {np.abs(trS - trS[0]).max() / (N * s):.2e} N max|S|   "
              f"|Δtr WS| {np.abs(trWS - trWS[0]).max():.2e} = {np.abs(trWS - trWS[0]).max() / (N * s * w):.2e} "
              "N max|S| max|W|")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
