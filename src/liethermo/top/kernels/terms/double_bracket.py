"""Double-bracket friction: an internal friction that keeps the coadjoint orbits.

The friction f = ad*_ζ μ with ζ = λ[ad*_{∂h/∂μ} μ]^♯ of the paper's remark on
coadjoint orbits reads, on SO(3) with μ = 𝕀Ω,

    f = λ μ×(μ×Ω),      −⟨f, Ω⟩ = λ|μ×Ω|² ≥ 0,

so |μ| is a Casimir (f ⟂ μ) and, without torques and Stokes friction, the
body loses kinetic energy at fixed |μ| until it spins about its major axis
(energy |μ|²/(2 I_max)): the flat spin of a dissipating free body.  λ is in
s kg⁻¹ m⁻².

Discrete form (variational integrator, docs/model.md): with
m = ½(M_h(X) + M_{−h}(X)) = 𝕀X + (h²/4)(X·𝕀X)X, the friction of a step is

    D(X) = −λ m×(m×X) = λ(|m|² X − (m·X) m),

placed like the trapezoid friction (half on each side of the node form).
D ⟂ m and |M_h(X)| = |M_{−h}(X)|, so |μ_{k+1}| = |μ_k| exactly; its power
⟨D, X⟩ = λ|m×X|² ≥ 0 is the heat of the step.  Its Jacobian, with
B = ∂m/∂X = diag(I + (h²/4)X·𝕀X) + (h²/2) X (𝕀X)ᵀ,

    ∂D/∂X = λ(2 X (Bᵀm)ᵀ + |m|² Id − m mᵀ − m (BᵀX)ᵀ − (m·X) B).

Coefficients of :class:`DoubleBracket`: λ.  (With an entropy-dependent
inertia the continuous law scales with s², μ = s𝕀₀Ω.)
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from .._jit import fma
from ..gen import cadd, madd
from ..so3 import cross_lane, norm2_lane
from . import (LAW_MOMENTUM_NORM, LAW_SPHERICAL_DECAY, ROLE_MOMENTUM_FRICTION, Parameter, ScalarTerm, Setting, angular_acceleration, bcast, discrete_power,
               dissipated_power, nonlinear_friction)


class DoubleBracket(namedtuple("DoubleBracket", "lam")):
    __slots__ = ()


def coefficients(internal_friction: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 1) coefficients from λ (N,)."""
    return np.asarray(internal_friction, dtype=np.float64).reshape(-1, 1)


@angular_acceleration.register(DoubleBracket)
def _acceleration(term, inertia, iscale, w, G, a):
    w0, w1, w2 = w
    a0, a1, a2 = a
    I = inertia
    m0, m1, m2 = I.I1 * w0, I.I2 * w1, I.I3 * w2
    u0, u1, u2 = cross_lane(m0, m1, m2, w0, w1, w2)
    f0, f1, f2 = cross_lane(m0, m1, m2, u0, u1, u2)
    lam = term.lam if iscale is None else term.lam * (iscale * iscale)
    return (madd(lam * I.iI1, f0, a0), madd(lam * I.iI2, f1, a1), madd(lam * I.iI3, f2, a2))


@dissipated_power.register(DoubleBracket)
def _power(term, inertia, iscale, w, p):
    w0, w1, w2 = w
    I = inertia
    u0, u1, u2 = cross_lane(I.I1 * w0, I.I2 * w1, I.I3 * w2, w0, w1, w2)
    lam = term.lam if iscale is None else term.lam * (iscale * iscale)
    return madd(lam, norm2_lane(u0, u1, u2), p)


@discrete_power.register(DoubleBracket)
def _discrete_power(term, inertia, h, x, p):
    x0, x1, x2 = x
    I = inertia
    Q0, Q1, Q2 = I.I1 * x0, I.I2 * x1, I.I3 * x2
    h4xQ = (0.25 * (h * h)) * fma(Q0, x0, fma(Q1, x1, Q2 * x2))
    u0, u1, u2 = cross_lane(fma(h4xQ, x0, Q0), fma(h4xQ, x1, Q1), fma(h4xQ, x2, Q2), x0, x1, x2)
    return madd(term.lam, norm2_lane(u0, u1, u2), p)


@nonlinear_friction.register(DoubleBracket)
def _discrete(term, inertia, h, x, f, J):
    x0, x1, x2 = x
    f0, f1, f2 = f
    j00, j01, j02, j10, j11, j12, j20, j21, j22 = J
    I = inertia
    lam = term.lam
    Q0, Q1, Q2 = I.I1 * x0, I.I2 * x1, I.I3 * x2
    h4xQ = (0.25 * (h * h)) * fma(Q0, x0, fma(Q1, x1, Q2 * x2))
    h2 = 0.5 * (h * h)
    m0, m1, m2 = fma(h4xQ, x0, Q0), fma(h4xQ, x1, Q1), fma(h4xQ, x2, Q2)
    mm = norm2_lane(m0, m1, m2)
    mx = fma(m0, x0, fma(m1, x1, m2 * x2))
    xx = norm2_lane(x0, x1, x2)
    # D = λ(|m|² X − (m·X) m)
    d0 = lam * fma(mm, x0, -(mx * m0))
    d1 = lam * fma(mm, x1, -(mx * m1))
    d2 = lam * fma(mm, x2, -(mx * m2))
    # B = diag(b) + h2 X Qᵀ, b_i = I_i + h4xQ
    b0, b1, b2 = I.I1 + h4xQ, I.I2 + h4xQ, I.I3 + h4xQ
    # Bᵀm: (Bᵀm)_j = b_j m_j + h2 (m·X) Q_j ;  BᵀX: (BᵀX)_j = b_j x_j + h2 |X|² Q_j
    p0, p1, p2 = fma(b0, m0, h2 * mx * Q0), fma(b1, m1, h2 * mx * Q1), fma(b2, m2, h2 * mx * Q2)
    q0, q1, q2 = fma(b0, x0, h2 * xx * Q0), fma(b1, x1, h2 * xx * Q1), fma(b2, x2, h2 * xx * Q2)
    t = h2 * mx  # (m·X) h2, for the X Qᵀ part of (m·X) B
    # J_ij = λ(2 x_i p_j + |m|² δ_ij − m_i m_j − m_i q_j − (m·X) b_i δ_ij − t x_i Q_j)
    c0, c1, c2 = mm - mx * b0, mm - mx * b1, mm - mx * b2
    J00 = lam * (fma(2.0 * x0, p0, -fma(m0, m0, m0 * q0)) - t * x0 * Q0 + c0)
    J01 = lam * (fma(2.0 * x0, p1, -fma(m0, m1, m0 * q1)) - t * x0 * Q1)
    J02 = lam * (fma(2.0 * x0, p2, -fma(m0, m2, m0 * q2)) - t * x0 * Q2)
    J10 = lam * (fma(2.0 * x1, p0, -fma(m1, m0, m1 * q0)) - t * x1 * Q0)
    J11 = lam * (fma(2.0 * x1, p1, -fma(m1, m1, m1 * q1)) - t * x1 * Q1 + c1)
    J12 = lam * (fma(2.0 * x1, p2, -fma(m1, m2, m1 * q2)) - t * x1 * Q2)
    J20 = lam * (fma(2.0 * x2, p0, -fma(m2, m0, m2 * q0)) - t * x2 * Q0)
    J21 = lam * (fma(2.0 * x2, p1, -fma(m2, m1, m2 * q1)) - t * x2 * Q1)
    J22 = lam * (fma(2.0 * x2, p2, -fma(m2, m2, m2 * q2)) - t * x2 * Q2 + c2)
    return ((cadd(d0, f0), cadd(d1, f1), cadd(d2, f2)),
            (cadd(J00, j00), cadd(J01, j01), cadd(J02, j02),
             cadd(J10, j10), cadd(J11, j11), cadd(J12, j12),
             cadd(J20, j20), cadd(J21, j21), cadd(J22, j22)))


class _DoubleBracket(ScalarTerm):
    name = "double_bracket"
    settings = (Setting("body", "internal_friction", 0.0, "s kg-1 m-2",
                        "λ of the double-bracket friction λ μ×(μ×Ω), which keeps |μ| (the flat spin)"),)
    parameters = (Parameter("internal_friction", (), "s kg-1 m-2",
                            "friction lambda",
                            comment="double-bracket friction f = lambda mu x (mu x Omega)"),)
    friction = True
    nonlinear_friction = True
    role = ROLE_MOMENTUM_FRICTION
    kernel_class = DoubleBracket
    coefficients = coefficients
    no_exact_flow = "its flow has no closed form (it must keep |μ| and K + U with heat)"
    scene_doc = (
        "*Internal friction* — `body.internal_friction = λ > 0` adds the double-bracket "
        "friction λ μ×(μ×Ω), which keeps |μ|; with no other torque or friction the body "
        "ends in a flat spin (the built-in `flat_spin`).")

    def keeps(self, law, phys):
        # λ μ×(μ×Ω) is ⟂ μ, and 0 when μ ∥ Ω (a spherical top)
        if law in (LAW_SPHERICAL_DECAY, LAW_MOMENTUM_NORM):
            return np.ones(phys.n, dtype=bool)
        return super().keeps(law, phys)

    def torque(self, phys, omega, gamma, scale):
        mu = scale[..., None] * bcast(phys.inertia, omega) * omega if np.ndim(scale) else (
            scale * bcast(phys.inertia, omega) * omega)
        lam = bcast(phys.internal_friction, omega[..., 0])[..., None]
        return lam * np.cross(mu, np.cross(mu, omega))

    def discrete_friction(self, phys, h, x):
        # D(X) = λ(|m|² X − (m·X) m), m = 𝕀₀X + (h²/4)(X·𝕀₀X)X
        Q = bcast(phys.inertia, x) * x
        m = Q + (0.25 * h * h) * np.sum(Q * x, axis=-1, keepdims=True) * x
        lam = bcast(phys.internal_friction, x[..., 0])[..., None]
        return lam * (np.sum(m * m, axis=-1, keepdims=True) * x - np.sum(m * x, axis=-1, keepdims=True) * m)

    def dissipated_power(self, phys, omega, scale):
        mu = scale[..., None] * bcast(phys.inertia, omega) * omega if np.ndim(scale) else (
            scale * bcast(phys.inertia, omega) * omega)
        return bcast(phys.internal_friction, omega[..., 0]) * np.sum(np.cross(mu, omega) ** 2, axis=-1)


TERM = _DoubleBracket()
