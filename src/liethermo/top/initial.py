"""Initial conditions of an ensemble, reproducible from ``ensemble.seed``.

* ``ensemble.members = 1``: the scene's own data, exactly (Ω₀ = initial.omega,
  R₀ = initial.R, Γ₀ = R₀ᵀe₃, S = S₀).
* more members: member i's initial condition depends only on (seed, i) — not
  on how the ensemble is chunked or distributed — because members are drawn
  in fixed blocks of :data:`BLOCK` from ``SeedSequence([seed, block])``:
  attitude R uniform on SO(3) (Haar measure: a normalised 4-D Gaussian
  quaternion), spin direction uniform on the sphere, spin magnitude uniform
  in ``spin_range × |initial.omega|``.
"""

from __future__ import annotations

import numpy as np

BLOCK = 1024


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4) in (w, x, y, z) order."""
    w, x, y, z = q.T
    R = np.empty((q.shape[0], 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def _draw_block(seed: int, block: int, omega_norm: float, spin_range) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(np.random.SeedSequence([seed, block]))
    q = rng.standard_normal((BLOCK, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    d = rng.standard_normal((BLOCK, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    mag = rng.uniform(spin_range[0], spin_range[1], BLOCK) * omega_norm
    return d * mag[:, None], quat_to_matrix(q)


def max_spin(scene: dict) -> float:
    """The largest |Ω(0)| (rad s⁻¹) any member of the scene's ensemble can
    start with: |initial.omega|, times ``ensemble.spin_range``[1] when the
    members are drawn (more than one)."""
    w = float(np.linalg.norm(np.asarray(scene["initial"]["omega"], dtype=np.float64)))
    if int(scene["ensemble"]["members"]) > 1:
        w *= float(scene["ensemble"]["spin_range"][1])
    return w


def heat_bound(scene: dict, phys) -> float:
    """An upper bound (J) of the heat any member of the scene's ensemble can
    produce: its initial mechanical energy above rest, at most
    ½ I_max (s_hi |Ω(0)|)² + (max V − min V) with s_hi = ``ensemble.spin_range``[1]
    (1 for a single member).  The same for every member chunk of a run, so
    the kernels' model (see :func:`liethermo.top.physics.build_model`) and with
    it every member's bits do not depend on how the ensemble is split.
    ``phys``: the scene's physics (any number of members)."""
    from .physics import potential_span

    w = max_spin(scene)
    span = float(np.max(potential_span(phys), initial=0.0))
    return 0.5 * float(np.max(phys.inertia, initial=0.0)) * w * w + span


def initial_conditions(scene: dict, start: int = 0, stop: int | None = None):
    """Initial Ω (N, 3) and R (N, 3, 3) of members ``start:stop``."""
    members = int(scene["ensemble"]["members"])
    stop = members if stop is None else stop
    omega0 = np.asarray(scene["initial"]["omega"], dtype=np.float64)
    R0 = np.asarray(scene["initial"]["R"], dtype=np.float64)
    n = stop - start
    if members == 1:
        return np.repeat(omega0[None], n, 0), np.repeat(R0[None], n, 0)
    seed = int(scene["ensemble"]["seed"])
    sr = scene["ensemble"]["spin_range"]
    w = np.linalg.norm(omega0)
    omegas, Rs = [], []
    for b in range(start // BLOCK, (stop - 1) // BLOCK + 1):
        ob, Rb = _draw_block(seed, b, w, sr)
        lo = max(start - b * BLOCK, 0)
        hi = min(stop - b * BLOCK, BLOCK)
        omegas.append(ob[lo:hi])
        Rs.append(Rb[lo:hi])
    return np.concatenate(omegas), np.concatenate(Rs)
