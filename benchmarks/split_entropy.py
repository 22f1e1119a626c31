"""Per-step entropy of the splitting and its compositions over friction × step.

``split`` turns, in every step, the kinetic energy its two friction flows of
positive duration take into heat: its entropy never decreases (a law).
``split4`` and ``split6`` compose it with factors that merge, between two
Strang steps, the adjacent half-flows of friction into one flow of negative
duration (Suzuki: −0.12 h twice; Kahan–Li: −0.19 h and −0.31 h twice each).
Those flows give heat back inside a step, so whether a whole step's entropy
increment stays ≥ 0 is a measured property, not a law.  This script measures
it on random members of the paper scene (attitudes uniform on SO(3), spins
uniform in direction, |Ω₀| uniform in [0.5, 1.5] × √2 rad s⁻¹ — the scene's
spin range times √2) over a grid of the friction per step

    κ = h · maxᵢ Cᵢ / Iᵢ        (docs/model.md "Negative substeps"; the paper
                                   scene at h = 0.1 s has κ = 0.047)

reached by scaling the Stokes resistance C at several h, and prints, per
(method, κ): the steps whose entropy decreased out of all member-steps, the
largest decrease relative to the largest entropy the member reached, and the largest
decrease in J K⁻¹.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/split_entropy.py

Also prints the merged friction durations of one step of each composition.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from liethermo.top.methods import MethodChoice
from liethermo.top.initial import initial_conditions
from liethermo.top.methods import METHODS
from liethermo.top.dataset import node_energies
from liethermo.top.physics import mechanical_energy_scale, physics_of_scene
from liethermo.scene import load_scene
from liethermo.top.simulate import STATUS_OK, simulate

KAPPAS = (0.05, 0.3, 1.0, 2.0, 3.0, 4.7, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 20.0, 30.0)
STEPS = (0.01, 0.05, 0.1, 0.2)


def merged_friction_durations(method: str, composition: str = "small_error") -> list[float]:
    """The durations (in units of h) of the friction flows of one step after
    merging the adjacent half-flows of consecutive Strang steps
    (F_{f_i h/2} F_{f_{i+1} h/2} = F_{(f_i + f_{i+1}) h/2})."""
    f = METHODS[method].substeps(composition)
    return [f[0] / 2] + [(a + b) / 2 for a, b in zip(f[:-1], f[1:])] + [f[-1] / 2]


def measure(method: str, kappa: float, h: float, members: int, steps: int, seed: int,
            composition: str = "small_error"):
    sc = load_scene("paper", {"ensemble.members": members, "ensemble.seed": seed})
    phys = physics_of_scene(sc, members)
    w0, R0 = initial_conditions(sc)
    w0 = w0 * np.sqrt(2.0)
    rate = float(np.max(phys.stokes_resistance / phys.inertia))  # maxᵢ Cᵢ/Iᵢ of the scene, s⁻¹
    phys = replace(phys, stokes_resistance=phys.stokes_resistance * (kappa / (h * rate)))
    tr = simulate(phys, w0, R0, h, steps, MethodChoice.of(method, composition=composition))
    ok = tr.status == STATUS_OK  # a variational integrator's Newton solve may fail near its singular κ
    s = tr.sigma[ok]  # (members, steps + 1), J K⁻¹
    ds = np.diff(s, axis=1)
    dec = ds < 0.0
    # the scale of a decrease: the entropy E_mech,0/T₀ of all the mechanical energy above rest
    e0 = mechanical_energy_scale(phys, w0, R0[:, 2, :])
    if not ok.any():
        return 0, 0, 0.0, 0.0, 0.0, int((~ok).sum())
    rel = np.where(dec, -ds * phys.T0[ok, None] / e0[ok, None], 0.0)
    # the largest gain of mechanical energy K + V over the run, relative to E_mech,0:
    # the exact flow only loses it; a gain above round-off is the backward friction amplifying
    e = node_energies(tr)
    gain = ((e["K"] + e["V"]).max(axis=1) - (e["K"][:, 0] + e["V"][:, 0]))[ok] / e0[ok]
    return (int(dec.sum()), ds.size, float(rel.max()), float(max(0.0, -ds.min())), float(gain.max()),
            int((~ok).sum()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--members", type=int, default=64)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--methods", nargs="+", default=["split", "split4", "split6"],
                    help="also vi, vi4, vi6 (their substeps are not merged: one entropy update each)")
    ap.add_argument("--composition", default="small_error", choices=["small_error", "triple_jump"])
    args = ap.parse_args(argv)
    for m in (m for m in args.methods if METHODS[m].family == "split"):
        d = merged_friction_durations(m, args.composition)
        print(f"{m}: friction flows of one step (× h): " + ", ".join(f"{x:+.4f}" for x in d))
    print(f"composition {args.composition}; {args.members} members × {args.steps} steps at h = {', '.join(map(str, STEPS))} s per κ")
    print("method   κ      decreasing steps   max decrease·T₀/E_mech,0   max decrease (J/K)   max gain of K+V / E_mech,0")
    for m in args.methods:
        for kappa in KAPPAS:
            n_dec = n_all = 0
            rel = absd = grow = 0.0
            failed, where = 0, []
            for h in STEPS:
                a, b, r, d, g, f = measure(m, kappa, h, args.members, args.steps, args.seed, args.composition)
                n_dec, n_all, failed = n_dec + a, n_all + b, failed + f
                rel, absd, grow = max(rel, r), max(absd, d), max(grow, g)
                where += [h] if a else []
            print(f"{m:7s} {kappa:5.2f}   {n_dec:6d} / {n_all:6d}     {rel:9.2e}                 {absd:9.2e}"
                  f"          {grow:9.2e}" + (f"   (decreases at h = {where} s)" if where else "")
                  + (f"   ({failed} members failed)" if failed else ""))


if __name__ == "__main__":
    main()
