"""Per-step heat of the fluid's compositions over viscosity × step × N.

``split`` turns, in every step, the energy its two viscous half-flows take into heat: its entropy never decreases
(a law).  ``split4`` and ``split6`` merge adjacent half-flows into flows of negative duration (Suzuki: −0.12 h
twice per step; Kahan–Li: −0.19 h and −0.31 h), which give heat back inside a step, so whether a whole step's
heat stays ≥ its predecessor's is measured, not a law.  This script runs random ``zeitlin_decay`` fields over a grid
of N, ν and h (ν h λ_max with λ_max = N(N − 1) − 2, the Laplacian's largest eigenvalue) and prints, per (method,
N, ν, h), the steps whose heat decreased out of all member-steps, the members whose fixed point did not converge
(status 1) and the first failing step.

    PYTHONPATH=src python benchmarks/zeitlin_entropy.py            # N = 16, 32; 4 members × 200 steps
    PYTHONPATH=src python benchmarks/zeitlin_entropy.py --quick    # what tests/test_zeitlin.py runs
"""

from __future__ import annotations

import argparse

import numpy as np

from liethermo.scene import load_scene
from liethermo.zeitlin import run as zr

NUS = (1e-3, 1e-2, 0.1, 1.0)  # s-1
STEPS_H = (0.01, 0.05, 0.2)  # s


def measure(method: str, N: int, nu: float, h: float, members: int, steps: int, seed: int = 0) -> dict:
    """One run: the heat's decreasing steps, member-steps compared, failed members, first failing step."""
    sc = load_scene("zeitlin_decay", {"zeitlin.N": N, "fluid.kinematic_viscosity": nu, "integrator.method": method,
                                      "integrator.h": h, "integrator.steps": steps, "output.every": 1,
                                      "ensemble.members": members, "ensemble.seed": seed, "output.compare": []})
    ds = zr.simulate(sc, progress=False)
    q, st = ds["heat"].values, ds["status"].values
    ok = st == 0
    dq = np.diff(q[ok], axis=1)
    fs = ds["failed_step"].values[~ok]
    return {"nu_h_lambda": nu * h * (N * (N - 1) - 2), "decreasing": int((dq < 0).sum()), "compared": int(dq.size),
            "failed": int((~ok).sum()), "first_failed_step": int(fs.min()) if fs.size else -1,
            "status": sorted({int(s) for s in st})}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--members", type=int, default=4)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--N", type=int, nargs="+", default=[16, 32])
    ap.add_argument("--methods", nargs="+", default=["split4", "split6"])
    args = ap.parse_args(argv)
    print("method  N    ν (s-1)  h (s)  ν h λ_max   decreasing steps   failed members (first failing step)")
    for m in args.methods:
        for N in args.N:
            for nu in NUS:
                for h in STEPS_H:
                    r = measure(m, N, nu, h, args.members, args.steps)
                    print(f"{m:7s} {N:3d}  {nu:7.0e}  {h:5.2f}  {r['nu_h_lambda']:9.3g}   {r['decreasing']:5d} / "
                          f"{r['compared']:5d}      {r['failed']}" + (f" (step {r['first_failed_step']}, status "
                                                                     f"{r['status']})" if r["failed"] else ""))


if __name__ == "__main__":
    main()
