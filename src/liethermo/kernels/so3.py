"""SO(3) helpers on plain float arrays (numba-compiled).

Conventions: ``hat(w) v = w × v``; the Cayley map
``cay(ŵ) = (I − ŵ/2)⁻¹ (I + ŵ/2)`` (Hairer–Lubich–Wanner IV.8.3), which in
vector form reads

    cay(ŵ) v = v + 4/(4 + |w|²) (w × v + ½ w × (w × v)).

It rotates by the angle 2·atan(|w|/2) about w (not |w|): the phase error of a
Cayley step of size h|Ω| is ≈ (h|Ω|)³/12 per step.  All functions write into
caller-allocated ``out`` arrays; none allocates.
"""

from __future__ import annotations

import numpy as np

from ._jit import jit


@jit
def cross(a, b, out):
    """out = a × b (out may not alias a or b)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@jit
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@jit
def hat(w, out):
    """out = ŵ, the 3×3 skew matrix with ŵ v = w × v."""
    out[0, 0] = 0.0
    out[0, 1] = -w[2]
    out[0, 2] = w[1]
    out[1, 0] = w[2]
    out[1, 1] = 0.0
    out[1, 2] = -w[0]
    out[2, 0] = -w[1]
    out[2, 1] = w[0]
    out[2, 2] = 0.0


@jit
def cayley_apply(w, v, out):
    """out = cay(ŵ) v, computed without forming the matrix.

    out may alias v.
    """
    s = 4.0 / (4.0 + (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]))
    # u = w × v
    u0 = w[1] * v[2] - w[2] * v[1]
    u1 = w[2] * v[0] - w[0] * v[2]
    u2 = w[0] * v[1] - w[1] * v[0]
    # q = w × u
    q0 = w[1] * u2 - w[2] * u1
    q1 = w[2] * u0 - w[0] * u2
    q2 = w[0] * u1 - w[1] * u0
    out[0] = v[0] + s * (u0 + 0.5 * q0)
    out[1] = v[1] + s * (u1 + 0.5 * q1)
    out[2] = v[2] + s * (u2 + 0.5 * q2)


@jit
def cayley_matrix(w, out):
    """out = cay(ŵ) = I + 4/(4+|w|²) (ŵ + ½ ŵ²) as a 3×3 matrix."""
    s = 4.0 / (4.0 + (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]))
    ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    for i in range(3):
        for j in range(3):
            # (ŵ²)_ij = w_i w_j − |w|² δ_ij
            sq = w[i] * w[j] - (ww if i == j else 0.0)
            out[i, j] = (1.0 if i == j else 0.0) + s * 0.5 * sq
    out[0, 1] += -s * w[2]
    out[0, 2] += s * w[1]
    out[1, 0] += s * w[2]
    out[1, 2] += -s * w[0]
    out[2, 0] += -s * w[1]
    out[2, 1] += s * w[0]


@jit
def attitude_update(R, w, out):
    """out = R cay(ŵ): the attitude update R_{k+1} = R_k cay(hΩ̂_k) with w = hΩ_k.

    out must not alias R.
    """
    C = np.empty((3, 3))
    cayley_matrix(w, C)
    for i in range(3):
        for j in range(3):
            out[i, j] = R[i, 0] * C[0, j] + R[i, 1] * C[1, j] + R[i, 2] * C[2, j]


@jit
def cayley_inverse(Q, out):
    """out = w with cay(ŵ) = Q, for a rotation Q with trace > −1.

    From Q − Qᵀ = s (ŵ) ... closed form: ŵ = 2 (Q − I)(Q + I)⁻¹; in vector form
    w = 2 vee(Q − Qᵀ) / (1 + tr Q).
    """
    d = 1.0 + Q[0, 0] + Q[1, 1] + Q[2, 2]
    out[0] = 2.0 * (Q[2, 1] - Q[1, 2]) / d
    out[1] = 2.0 * (Q[0, 2] - Q[2, 0]) / d
    out[2] = 2.0 * (Q[1, 0] - Q[0, 1]) / d
