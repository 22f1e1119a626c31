"""Newton iterations of the variational integrator while the top moves, and
where the stop on predicted convergence leaves the iterate.

A run of the paper's top spends most of its time near rest (the friction times
I_i/c are 2.1–4.2 s), where a solve converges in fewer iterations than while the
top swings; a whole-run average mixes the two.  This script prints, at
h = 0.1 s, the iterations per step (summed over the substeps of vi4/vi6) over
windows of the run — the first second, the second second, and the whole run —
for

* the paper scene as it stands (``liethermo run paper``: its own start, the
  paper's Ω₀ := Ω(0), explicit entropy update, 300 steps), and with the
  default ``legendre`` start;
* the benchmark's ensemble (``benchmarks/bench.py``: 4096 random members of the
  paper's top, |Ω₀| uniform in [0.5, 1.5]·√2 rad/s, 1000 steps) for vi, vi4, vi6.

Then 4 × 1000 random Newton solves at h = 0.1 s (a random body, |X| ~ 1.7 and
5 rad/s, predictors 10⁻² and 10⁻³ off, the setting of
``tests/test_vi.py::test_newton_stop_on_predicted_convergence_is_within_tolerance``
with more solves): how many stop farther than ε = tol·|X|∞ from the solution
iterated to its floating-point fixed point, and the largest distance in units of ε.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/newton_iterations.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from liethermo.top.initial import initial_conditions
from liethermo.top.physics import physics_of_scene
from liethermo.scene import load_scene
from liethermo.top.methods import MethodChoice
from liethermo.top.simulate import simulate


def per_step(phys, w0, R0, method, windows, **kw):
    """Iterations per step (mean over members) in each window (t_a, t_b) s at h = 0.1 s:
    differences of the totals of runs of t_a/h and t_b/h steps (the runs are identical
    where they overlap)."""
    h = 0.1
    totals = {}
    for a, b in windows:
        for t in (a, b):
            n = int(round(t / h))
            if n not in totals:
                totals[n] = 0.0 if n == 0 else simulate(phys, w0, R0, h, n, MethodChoice.of(method, **kw), every=n).newton_iterations.mean()
    return [(totals[int(round(b / h))] - totals[int(round(a / h))]) / int(round((b - a) / h)) for a, b in windows]


def iterations():
    sc = load_scene("paper")
    phys = physics_of_scene(sc, 1)
    w0, R0 = initial_conditions(sc)
    windows = [(0.0, 1.0), (1.0, 2.0), (0.0, 2.0), (0.0, 30.0)]
    head = "  ".join(f"[{a:g}, {b:g}] s" for a, b in windows)
    print(f"Newton iterations per step at h = 0.1 s, by window: {head}")
    for start, entropy in (("node", "explicit"), ("legendre", "symmetric")):
        its = per_step(phys, w0, R0, "vi", windows, start=start, entropy=entropy)
        print(f"paper scene, vi, {start} start:        " + "  ".join(f"{x:.2f}" for x in its))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench import random_ensemble

    phys = physics_of_scene(load_scene("paper"), 4096)
    w0, R0 = random_ensemble(4096)
    windows = [(0.0, 1.0), (1.0, 2.0), (0.0, 2.0), (0.0, 100.0)]
    head = "  ".join(f"[{a:g}, {b:g}] s" for a, b in windows)
    print(f"4096 random members, |Ω₀| in [0.5, 1.5]·√2 rad/s, by window: {head}")
    for method, kw in (("vi", {"start": "node", "entropy": "explicit"}), ("vi", {}), ("vi4", {}), ("vi6", {})):
        its = per_step(phys, w0, R0, method, windows, **kw)
        label = f"{method}, {kw.get('start', 'legendre')} start"
        print(f"{label:22s}                " + "  ".join(f"{x:.2f}" for x in its))


def stop_accuracy():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from conftest import make_physics
    from test_vi import _legendre, _solve

    from liethermo.top.kernels import layout as L
    from liethermo.top.physics import build_model

    rng = np.random.default_rng(8)
    h, tol = 0.1, 1e-14
    out, fp = np.empty(3), np.empty(3)
    print("random solves, h = 0.1 s: solves, beyond ε, largest |X − X_fp|∞/ε, mean iterations")
    for spin, off in ((1.0, 1e-2), (3.0, 1e-3), (1.0, 1e-3), (3.0, 1e-2)):
        beyond, worst, its_all = 0, 0.0, []
        for _ in range(1000):
            I = rng.uniform(0.5e-3, 2.0e-3, 3)
            phys = make_physics(I, 2e-5, 0.02 * rng.normal(size=3), 1e-3)
            model = build_model(phys).model
            X = spin * rng.normal(size=3)
            b = -(_legendre(I, X, h) + 0.5 * h * phys.stokes_resistance[0] * X)
            xp = X * (1.0 + off * rng.normal(size=3))
            scale0 = np.abs(xp).max()
            code, its = _solve(model, h, b, xp, scale0, tol, 30, out)
            assert code == L.NEWTON_OK
            _solve(model, h, b, xp, scale0, 0.0, 12, fp)
            ratio = np.abs(out - fp).max() / (tol * np.abs(fp).max())
            beyond += ratio > 1.0
            worst = max(worst, ratio)
            its_all.append(its)
        print(f"|X| ~ {spin * np.sqrt(3):.1f} rad/s, predictor {off:g} off: 1000, {beyond}, {worst:.2f}, "
              f"{np.mean(its_all):.2f}")


if __name__ == "__main__":
    iterations()
    stop_accuracy()
