"""Initial conditions from their raw draws, in one pass over the members.

:func:`shape_draws` turns Gaussian quaternions, Gaussian directions and
uniform magnitudes (the draws of :mod:`liethermo.top.initial`) into Ω₀ and
R₀ with exactly numpy's arithmetic, operation by operation: a norm is the
square root of ``((0 + x₀²) + x₁²) + …`` (numpy's reduction of a short
axis), then a division, and the rotation matrix of a unit quaternion as
:func:`liethermo.top.initial.quat_to_matrix` writes it.  No fused
multiply-add (``fastmath`` off), so the bits are numpy's.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import jit


@jit(nogil=True)
def shape_draws(q, d, u, omega_norm, omega, R):
    """Ω₀ (N, 3) into ``omega`` and R₀ (N, 3, 3) into ``R`` from the raw draws
    q (N, 4), d (N, 3), u (N,): Ω₀ = d/|d| · (u |initial.omega|), R₀ the rotation
    of the unit quaternion q/|q| in (w, x, y, z) order."""
    for m in range(q.shape[0]):
        s = 0.0
        for k in range(4):
            s += q[m, k] * q[m, k]
        nq = math.sqrt(s)
        w = q[m, 0] / nq
        x = q[m, 1] / nq
        y = q[m, 2] / nq
        z = q[m, 3] / nq
        s = 0.0
        for k in range(3):
            s += d[m, k] * d[m, k]
        nd = math.sqrt(s)
        mag = u[m] * omega_norm
        for k in range(3):
            omega[m, k] = (d[m, k] / nd) * mag
        R[m, 0, 0] = 1 - 2 * (y * y + z * z)
        R[m, 0, 1] = 2 * (x * y - w * z)
        R[m, 0, 2] = 2 * (x * z + w * y)
        R[m, 1, 0] = 2 * (x * y + w * z)
        R[m, 1, 1] = 1 - 2 * (x * x + z * z)
        R[m, 1, 2] = 2 * (y * z - w * x)
        R[m, 2, 0] = 2 * (x * z - w * y)
        R[m, 2, 1] = 2 * (y * z + w * x)
        R[m, 2, 2] = 1 - 2 * (x * x + y * y)


def shaped(q: np.ndarray, d: np.ndarray, u: np.ndarray, omega_norm: float) -> tuple[np.ndarray, np.ndarray]:
    """(Ω₀, R₀) of the raw draws (new arrays)."""
    n = q.shape[0]
    omega, R = np.empty((n, 3)), np.empty((n, 3, 3))
    shape_draws(np.ascontiguousarray(q), np.ascontiguousarray(d), np.ascontiguousarray(u),
                float(omega_norm), omega, R)
    return omega, R
