"""Phase error of a Rossby–Haurwitz wave under the fluid's methods, and how it depends on the time window.

``zeitlin_ideal``'s wave (l = 6, m = 4, no noise, ν = 0) turns eastward at the exact speed
c = Ω_b (1 − 2/(l(l+1))).  Each run stores ω_lm; the wave's speed is the slope of the unwrapped phase of its
ω_{6,4} over [0, T] (least squares), and its relative error against c is printed for each window T, with the
projection |ω_{6,4}(T)| / |ω_{6,4}(0)| (1: the wave keeps its amplitude in its own mode).  A Cayley rotation turns
the modes far from the diagonal too slowly, and the energy the wave sheds into other modes changes the fitted slope
with the window: quote a phase error with its window.

    PYTHONPATH=src python benchmarks/zeitlin_phase.py                       # split, N = 16 and 48, T = 5 and 20 s
    PYTHONPATH=src python benchmarks/zeitlin_phase.py --N 128 --methods split split6
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from liethermo.scene import load_scene
from liethermo.zeitlin import run as zr

L, M = 6, 4


def wave(method: str, N: int, h: float, t_end: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(t, ω_{6,4}(t), exact speed c in rad s-1) of one run."""
    every = max(1, int(round(0.05 / h)))
    steps = int(round(t_end / h / every)) * every
    sc = load_scene("zeitlin_ideal", {"zeitlin.N": N, "initial.lmax": L, "initial.m": M, "initial.noise": 0.0,
                                      "ensemble.members": 1, "integrator.method": method, "integrator.h": h,
                                      "integrator.steps": steps, "output.every": every, "output.vorticity": True,
                                      "output.compare": []})
    ds = zr.simulate(sc, progress=False)
    C = zr.vorticity_coefficients(ds)
    mode = int(np.flatnonzero((C["l"].values == L) & (C["m"].values == M))[0])
    omega_b = float(ds["angular_momentum"].isel(member=0, t=0).sel(axis="z")) / (8 * math.pi / 3)
    return ds["t"].values, C.isel(member=0, mode=mode).values, omega_b * (1 - 2 / (L * (L + 1)))


def phase_error(t, c, exact: float, window: float) -> tuple[float, float]:
    """(relative speed error, projection) over [0, window]."""
    k = t <= window + 1e-9
    speed = -np.polyfit(t[k], np.unwrap(np.angle(c[k])), 1)[0] / M
    return speed / exact - 1.0, float(abs(c[k][-1]) / abs(c[0]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, nargs="+", default=[16, 48])
    ap.add_argument("--methods", nargs="+", default=["split"])
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--windows", type=float, nargs="+", default=[5.0, 20.0])
    args = ap.parse_args(argv)
    print(f"h = {args.h} s; relative speed error (negative: too slow) and projection per window")
    for m in args.methods:
        for N in args.N:
            t, c, exact = wave(m, N, args.h, max(args.windows))
            row = "; ".join("T = {:g} s: {:+.2e}, projection {:.3f}".format(w, *phase_error(t, c, exact, w))
                            for w in args.windows)
            print(f"{m:7s} N = {N:3d}: {row}")


if __name__ == "__main__":
    main()
