"""The numbers docs/model.md and README.md quote about single runs of the top, measured again.

Each section prints one claim's numbers with where the page states them:

* ``compositions``: the error at t = 10 s against the reference of 8 random paper-scene members (|Ω₀| uniform in
  [0.5, 1.5]·√2 rad s⁻¹) for vi4 (Suzuki / triple jump) at h = 0.05 s and vi6 (Kahan–Li / triple jump) at
  h = 0.1 … 0.0125 s with vi6's observed orders ("Compositions");
* ``casimir``: max_k ||μ_k|/|μ_0| − 1| on the ``flat_spin`` scene over 6000 steps of 0.01 s (3001 stored nodes) for
  vi, vi4 and rk4, and where the kinetic energy ends against |μ|²/(2 I_max) ("double bracket");
* ``geometry``: ||Γ_k| − 1| and |R_kᵀR_k − Id| over 10⁴ paper steps of the VI, and RK4's ||Γ| − 1| within 300 steps
  at h = 0.1 s ("Unit Gamma and rotations");
* ``reference``: the reference's total energy error on the paper scene over 30 s relative to E_mech,0, and its
  distance to itself at twice the substeps ("Runge-Kutta baselines and the reference", README's table);
* ``fixed_point``: how far 300 paper steps at the default Newton tolerance end from the same steps iterated to a
  100× smaller tolerance ("Newton iteration").

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/model_numbers.py [SECTION ...]
"""

from __future__ import annotations

import sys

import numpy as np

from liethermo.scene import load_scene
from liethermo.top.initial import initial_conditions
from liethermo.top.laws import energy_errors
from liethermo.top.methods import MethodChoice
from liethermo.top.physics import physics_of_scene
from liethermo.top.simulate import simulate


def _scene(name: str, members: int = 1, **over):
    sc = load_scene(name, {"ensemble.members": members, **over})
    om, R = initial_conditions(sc, 0, members)
    return physics_of_scene(sc, members), om, R


def _err(a, b) -> float:
    """max over members of max(|ΔΩ| / |Ω(0)|, |ΔΓ|) at the end."""
    return float(np.max(np.maximum(np.linalg.norm(a.omega[:, -1] - b.omega[:, -1], axis=-1) /
                                   np.linalg.norm(a.omega[:, 0], axis=-1),
                                   np.linalg.norm(a.gamma[:, -1] - b.gamma[:, -1], axis=-1))))


def compositions() -> None:
    phys, om, R = _scene("paper", 8)
    T = 10.0
    ref = simulate(phys, om, R, 0.05, int(T / 0.05), "reference", every=int(T / 0.05))
    run = lambda label, h: _err(simulate(phys, om, R, h, int(round(T / h)), MethodChoice.parse(label),
                                         every=int(round(T / h))), ref)
    a, b = run("vi4", 0.05), run("vi4:triple_jump", 0.05)
    print(f"compositions: vi4 at h = 0.05 s: Suzuki {a:.2g}, triple jump {b:.2g} ({b / a:.0f}× more)")
    hs = [0.1, 0.05, 0.025, 0.0125]
    for label in ("vi6", "vi6:triple_jump"):
        e = [run(label, h) for h in hs]
        orders = ", ".join(f"{np.log2(e[i] / e[i + 1]):.1f}" for i in range(len(e) - 1))
        print(f"compositions: {label}: errors {', '.join(f'{x:.2g}' for x in e)} at h = {hs} s; orders {orders}")


def casimir() -> None:
    phys, om, R = _scene("flat_spin", 1)
    for m in ("vi", "vi4", "rk4"):
        tr = simulate(phys, om, R, 0.01, 6000, MethodChoice.parse(m), every=2)
        mu = tr.momentum if tr.family == "vi" else phys.inertia[:, None, :] * tr.omega
        n = np.linalg.norm(mu, axis=-1)
        K = 0.5 * np.sum(mu ** 2 / phys.inertia[:, None, :], axis=-1)
        floor = n[:, -1] ** 2 / (2 * phys.inertia.max())
        print(f"casimir: {m}: {tr.times.size} nodes, max ||mu_k|/|mu_0| - 1| = {np.abs(n / n[:, :1] - 1).max():.2g}; "
              f"K(t_end) / (|mu|^2 / 2 I_max) - 1 = {float(K[0, -1] / floor[0] - 1):.1g}")


def geometry() -> None:
    phys, om, R = _scene("paper", 1)
    tr = simulate(phys, om, R, 0.1, 10_000, MethodChoice.parse("vi"), attitude=True, every=10)
    g = np.abs(np.linalg.norm(tr.gamma, axis=-1) - 1).max()
    A = tr.attitude
    o = np.abs(np.einsum("mtji,mtjk->mtik", A, A) - np.eye(3)).max()
    rk = simulate(phys, om, R, 0.1, 300, MethodChoice.parse("rk4"))
    print(f"geometry: vi, 10^4 steps of 0.1 s: max ||Gamma|-1| = {g:.2g}, max |R^T R - Id| = {o:.2g}; rk4, 300 steps: "
          f"max ||Gamma|-1| = {np.abs(np.linalg.norm(rk.gamma, axis=-1) - 1).max():.2g}")


def reference() -> None:
    phys, om, R = _scene("paper", 1)
    a = simulate(phys, om, R, 0.1, 300, "reference")
    e = energy_errors(a, om, R)
    print(f"reference: paper scene, 30 s: max |E_k - E_0| / E_mech,0 = {np.abs(e['node'] / e['scale'][:, None]).max():.2g}")
    from liethermo.top.simulate import reference_substeps

    n = int(np.max(reference_substeps(0.1, phys, om)))
    b = simulate(phys, om, R, 0.1, 300, "reference", ref_substeps=2 * n)
    d = max(np.abs(a.omega - b.omega).max() / np.abs(a.omega).max(), np.abs(a.gamma - b.gamma).max())
    print(f"reference: {n} (automatic) and {2 * n} substeps per step, 30 s: largest relative difference {d:.2g}")


def fixed_point() -> None:
    phys, om, R = _scene("paper", 1)
    a = simulate(phys, om, R, 0.1, 300, MethodChoice.parse("vi"))
    b = simulate(phys, om, R, 0.1, 300, MethodChoice.parse("vi"), newton_tol=1e-16)
    e = [energy_errors(t, om, R)["node"] for t in (a, b)]
    rel = lambda x, y: float(np.abs(x - y).max() / np.abs(y).max())
    print(f"fixed_point: 300 paper steps, tol 1e-14 against 1e-16: Omega {rel(a.omega, b.omega):.1g}, "
          f"mu {rel(a.momentum, b.momentum):.1g}, E {rel(e[0], e[1]):.1g} relative (status {int(b.status[0])})")


SECTIONS = {f.__name__: f for f in (compositions, casimir, geometry, reference, fixed_point)}

if __name__ == "__main__":
    for name in sys.argv[1:] or SECTIONS:
        SECTIONS[name]()
