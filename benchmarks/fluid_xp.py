"""Zeitlin fluid: seconds per member-step of the array-namespace steps
(zeitlin/xpstep.py) against the numba kernels, on the same members.

    OPENBLAS_NUM_THREADS=1 python benchmarks/fluid_xp.py                 # numpy vs numba, N = 32, 64
    python benchmarks/fluid_xp.py --xp cupy --N 128 256 512 --members 64  # on a GPU (CuPy)
    python benchmarks/fluid_xp.py --xp cupy --check --N 16 --no-cpu        # agreement with the kernels first

Each figure is the minimum over ``--repeats`` rounds that alternate the two
backends; every round is warm (two steps first).  The members: random fields
of unit energy, l ≤ 8, h = 0.01 s, ν = 1e-3, the fixed point started from the
predictor, as in a run.
"""

from __future__ import annotations

import argparse
import importlib

from liethermo.zeitlin import xpstep as xs


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--xp", default="numpy", help="array module: numpy or cupy")
    p.add_argument("--N", type=int, nargs="+", default=[32, 64])
    p.add_argument("--members", type=int, default=16)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--methods", nargs="+", default=["split", "rk4"])
    p.add_argument("--no-cpu", action="store_true", help="leave out the numba kernels in the timings")
    p.add_argument("--check", action="store_true",
                   help="first compare 50 steps of every method, viscous and ideal, with the numba kernels")
    a = p.parse_args(argv)
    xp = importlib.import_module(a.xp)
    if a.check:
        check(xp)
    print(f"{'N':>5} {'method':>7} {a.xp + ' (ms)':>14} {'numba (ms)':>11} {'ratio':>7}   per member-step, "
          f"{a.members} members, min of {a.repeats}")
    for N in a.N:
        for m in a.methods:
            tx, tc = [], []
            for _ in range(a.repeats):
                tx.append(xs.time_fluid_xp(xp, N, a.members, a.steps, m))
                if not a.no_cpu:
                    tc.append(xs.time_fluid_cpu(N, a.members, a.steps, m))
            x = 1e3 * min(tx)
            c = 1e3 * min(tc) if tc else float("nan")
            print(f"{N:>5} {m:>7} {x:>14.3f} {c:>11.3f} {x / c:>7.2f}", flush=True)


def check(xp, N: int = 16, members: int = 4, steps: int = 50) -> None:
    """Relative difference of W and q after ``steps`` steps (the zeitlin_decay
    scene's members, a fourth blown up by ×1000), and whether the status,
    failed steps and fixed-point iterations are identical."""
    import warnings

    import numpy as np

    from liethermo.scene import load_scene
    from liethermo.zeitlin import run as zr

    warnings.simplefilter("ignore", RuntimeWarning)
    print(f"Thomas sweeps on {xp.__name__}: {xs.xp_basis(xp, N).thomas_backend}")
    for nu in (1e-3, 0.0):
        for m in xs.METHODS:
            sc = load_scene("zeitlin_decay", {"zeitlin.N": N, "initial.lmax": 8, "ensemble.members": members,
                                              "integrator.steps": steps, "output.every": steps,
                                              "integrator.method": m, "fluid.kinematic_viscosity": nu})
            W0 = zr.initial_fields(sc)
            W0[-1] *= 1000.0
            a = zr.integrate(sc, W0, progress=False, keep_vorticity=True)
            c = xs.integrate_xp(xp, sc, W0, progress=False, keep_vorticity=True)
            ok = a.status == 0
            dW = np.abs(c.W[ok] - a.W[ok]).max() / np.abs(a.W[ok]).max()
            dq = np.abs(c.q[ok] - a.q[ok]).max() / max(np.abs(a.q[ok]).max(), 1e-300)
            same = (np.array_equal(a.status, c.status) and np.array_equal(a.failed_step, c.failed_step)
                    and np.array_equal(a.iterations, c.iterations))
            print(f"  nu = {nu:g} {m:>7}: W {dW:.2e}, q {dq:.2e} relative; status {a.status.tolist()}, "
                  f"status/failed_step/iterations identical: {same}", flush=True)


if __name__ == "__main__":
    main()
