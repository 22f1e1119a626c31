"""Quadratic drag: the torque −c₂|Ω|Ω of a body turning at moderate Reynolds number.

Where the flow around a spinning body separates, the resisting torque grows
with the square of the spin, τ = −c₂|Ω|Ω (c₂ in kg m², of the order of
ρ_fluid C_D a⁵ for a body of size a).  It dissipates −⟨τ, Ω⟩ = c₂|Ω|³ ≥ 0.

Discrete form (variational integrator): at the step velocity X,

    D(X) = c₂|X|X,      ⟨D(X), X⟩ = c₂|X|³ ≥ 0,

placed like the trapezoid friction, with the Jacobian

    ∂D/∂X = c₂(|X| Id + X Xᵀ/|X|)          (0 at X = 0).

X is a second-order approximation of Ω(t_k + h/2), so the step keeps the
scheme's order 2; the heat of a step, h⟨D(X), X⟩ ≥ 0, makes the entropy grow.

Coefficients of :class:`QuadraticDrag`: c₂ and K_i = c₂/I_i (over the
reference principal moments).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .._jit import fma, select
from ..gen import cadd, madd
from ..so3 import norm2_lane
from . import (Parameter, ScalarTerm, Setting, over_inertia, angular_acceleration, bcast, discrete_power,
               dissipated_power, nonlinear_friction)


class QuadraticDrag(namedtuple("QuadraticDrag", "c K1 K2 K3")):
    __slots__ = ()


def coefficients(c2: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 4) coefficients from c₂ (N,) and 𝕀₀ (N, 3)."""
    return over_inertia(c2, inertia0, 1)


@angular_acceleration.register(QuadraticDrag)
def _acceleration(term, inertia, iscale, w, G, a):
    w0, w1, w2 = w
    a0, a1, a2 = a
    n = math.sqrt(norm2_lane(w0, w1, w2))
    return (madd(-(term.K1 * n), w0, a0), madd(-(term.K2 * n), w1, a1),
            madd(-(term.K3 * n), w2, a2))


@dissipated_power.register(QuadraticDrag)
def _power(term, inertia, iscale, w, p):
    w0, w1, w2 = w
    n2 = norm2_lane(w0, w1, w2)
    return madd(term.c * math.sqrt(n2), n2, p)


@discrete_power.register(QuadraticDrag)
def _discrete_power(term, inertia, h, x, p):
    x0, x1, x2 = x
    n2 = norm2_lane(x0, x1, x2)
    return madd(term.c * math.sqrt(n2), n2, p)


@nonlinear_friction.register(QuadraticDrag)
def _discrete(term, inertia, h, x, f, J):
    x0, x1, x2 = x
    f0, f1, f2 = f
    j00, j01, j02, j10, j11, j12, j20, j21, j22 = J
    c = term.c
    n = math.sqrt(norm2_lane(x0, x1, x2))
    cn = c * n
    # c XXᵀ/|X|, 0 at X = 0
    q = select(n > 0.0, c / n, 0.0)
    q0, q1, q2 = q * x0, q * x1, q * x2
    return ((cadd(cn * x0, f0), cadd(cn * x1, f1), cadd(cn * x2, f2)),
            (cadd(fma(q0, x0, cn), j00), cadd(q0 * x1, j01), cadd(q0 * x2, j02),
             cadd(q1 * x0, j10), cadd(fma(q1, x1, cn), j11), cadd(q1 * x2, j12),
             cadd(q2 * x0, j20), cadd(q2 * x1, j21), cadd(fma(q2, x2, cn), j22)))



class _QuadraticDrag(ScalarTerm):
    name = "quadratic_drag"
    settings = (Setting("fluid", "quadratic_drag", 0.0, "kg m2",
                        "c₂ of the quadratic drag −c₂|Ω|Ω of a body turning at moderate Reynolds "
                        "number (≈ ρ_fluid C_D a⁵)"),)
    parameters = (Parameter("quadratic_drag", (), "kg m2",
                            "quadratic drag c2",
                            comment="friction torque -c2 |Omega| Omega"),)
    friction = True
    nonlinear_friction = True
    kernel_class = QuadraticDrag
    coefficients = coefficients
    no_exact_flow = "its flow has a closed form only for an isotropic body, which is not covered"
    scene_doc = (
        "*Quadratic drag* — `fluid.quadratic_drag = c₂ > 0` adds the torque −c₂|Ω|Ω of a "
        "body turning at moderate Reynolds number, beside or instead of the Stokes friction. "
        "Not together with thermal expansion.")

    def torque(self, phys, omega, gamma, scale):
        c = bcast(phys.quadratic_drag, omega[..., 0])[..., None]
        return -c * np.linalg.norm(omega, axis=-1, keepdims=True) * omega

    def discrete_friction(self, phys, h, x):
        return self.torque(phys, -x, None, 1.0)  # c₂|X|X

    def dissipated_power(self, phys, omega, scale):
        return bcast(phys.quadratic_drag, omega[..., 0]) * np.linalg.norm(omega, axis=-1) ** 3

    def rate_bound(self, phys, omega_max):
        c = phys.quadratic_drag
        return np.where(c != 0.0, c * omega_max / phys.inertia.min(axis=1), 0.0)


TERM = _QuadraticDrag()
