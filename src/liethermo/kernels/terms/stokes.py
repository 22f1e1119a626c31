"""Stokes friction: the torque −CΩ of a body turning in a viscous fluid.

* :class:`StokesSphere` — a sphere of radius a, C = c·Id, c = 8πμa³ (N m s);
* :class:`StokesDiagonal` — a triaxial ellipsoid (Jeffery 1922), C =
  diag(C₁, C₂, C₃) in the body's principal frame (docs/model.md).

Coefficients: the friction coefficients and K_i = C_i/I_i (over the reference
principal moments).  Dissipated power −⟨f, Ω⟩ = Ω·CΩ (W).  Both are linear in
Ω, so the variational integrator folds C into its Newton matrix.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..gen import cadd, madd
from ..so3 import norm2_lane
from . import angular_acceleration, discrete_power, dissipated_power, implements, linear_friction


class StokesSphere(namedtuple("StokesSphere", "c K1 K2 K3")):
    __slots__ = ()


class StokesDiagonal(namedtuple("StokesDiagonal", "C1 C2 C3 K1 K2 K3")):
    __slots__ = ()


def sphere_coefficients(c: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 4) from c (N,) and 𝕀₀ (N, 3)."""
    c = np.asarray(c, dtype=np.float64).reshape(-1, 1)
    return np.hstack([c, c * (1.0 / np.asarray(inertia0, dtype=np.float64).reshape(-1, 3))])


def diagonal_coefficients(C: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 6) from diag C (N, 3) and 𝕀₀ (N, 3)."""
    C = np.asarray(C, dtype=np.float64).reshape(-1, 3)
    return np.hstack([C, C * (1.0 / np.asarray(inertia0, dtype=np.float64).reshape(-1, 3))])


@implements(angular_acceleration, StokesSphere)
def _sphere_acc(term, inertia, iscale, w0, w1, w2, G0, G1, G2, a0, a1, a2):
    return madd(-term.K1, w0, a0), madd(-term.K2, w1, a1), madd(-term.K3, w2, a2)


@implements(dissipated_power, StokesSphere)
def _sphere_power(term, inertia, iscale, w0, w1, w2, p):
    return madd(term.c, norm2_lane(w0, w1, w2), p)


@implements(discrete_power, StokesSphere)
def _sphere_discrete_power(term, inertia, h, x0, x1, x2, p):
    return madd(term.c, norm2_lane(x0, x1, x2), p)


@implements(linear_friction, StokesSphere)
def _sphere_linear(term, c0, c1, c2):
    return cadd(term.c, c0), cadd(term.c, c1), cadd(term.c, c2)


@implements(angular_acceleration, StokesDiagonal)
def _diag_acc(term, inertia, iscale, w0, w1, w2, G0, G1, G2, a0, a1, a2):
    return madd(-term.K1, w0, a0), madd(-term.K2, w1, a1), madd(-term.K3, w2, a2)


@implements(dissipated_power, StokesDiagonal)
def _diag_power(term, inertia, iscale, w0, w1, w2, p):
    return madd(term.C1 * w0, w0, madd(term.C2 * w1, w1, madd(term.C3 * w2, w2, p)))


@implements(discrete_power, StokesDiagonal)
def _diag_discrete_power(term, inertia, h, x0, x1, x2, p):
    return madd(term.C1 * x0, x0, madd(term.C2 * x1, x1, madd(term.C3 * x2, x2, p)))


@implements(linear_friction, StokesDiagonal)
def _diag_linear(term, c0, c1, c2):
    return cadd(term.C1, c0), cadd(term.C2, c1), cadd(term.C3, c2)
