"""Gravity: the heavy top's torque τ(Γ) = Γ × g⃗, g⃗ = m g ℓχ (N m), with the
potential energy V = g⃗·Γ.

Coefficients of :class:`Gravity`: g⃗ and its components over the reference
principal moments, g_z/I₁, g_y/I₁, g_x/I₂, g_z/I₂, g_y/I₃, g_x/I₃, so that
(𝕀₀⁻¹τ)₁ = (g_z/I₁)Γ₂ − (g_y/I₁)Γ₃ (and cyclically) costs two fused
multiply-adds.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..gen import madd
from . import angular_acceleration, implements, torque


class Gravity(namedtuple("Gravity", "gx gy gz gz1 gy1 gx2 gz2 gy3 gx3")):
    __slots__ = ()


def coefficients(gravity_torque: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 9) coefficients from g⃗ = m g ℓχ (N, 3) and 𝕀₀ (N, 3)."""
    g = np.asarray(gravity_torque, dtype=np.float64).reshape(-1, 3)
    iI = 1.0 / np.asarray(inertia0, dtype=np.float64).reshape(-1, 3)
    gx, gy, gz = g.T
    return np.stack([gx, gy, gz, gz * iI[:, 0], gy * iI[:, 0], gx * iI[:, 1], gz * iI[:, 1],
                     gy * iI[:, 2], gx * iI[:, 2]], axis=1)


def potential_energy(gravity_torque: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """V = g⃗·Γ (J): g⃗ (N, 3), Γ (N, ..., 3)."""
    g = np.asarray(gravity_torque, dtype=np.float64)
    g = g.reshape(g.shape[:1] + (1,) * (gamma.ndim - 2) + (3,))
    return np.sum(g * gamma, axis=-1)


@implements(angular_acceleration, Gravity)
def _acceleration(term, inertia, iscale, w0, w1, w2, G0, G1, G2, a0, a1, a2):
    return (madd(term.gz1, G1, madd(-term.gy1, G2, a0)),
            madd(term.gx2, G2, madd(-term.gz2, G0, a1)),
            madd(term.gy3, G0, madd(-term.gx3, G1, a2)))


@implements(torque, Gravity)
def _torque(term, G0, G1, G2, t0, t1, t2):
    return (madd(G1, term.gz, madd(-G2, term.gy, t0)),
            madd(G2, term.gx, madd(-G0, term.gz, t1)),
            madd(G0, term.gy, madd(-G1, term.gx, t2)))
