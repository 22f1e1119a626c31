"""The variational integrator of Couéraud & Gay-Balmaz (SPEC §3).

One step k → k+1 from (Ω_k, Γ_k, σ_k[, R_k]):

1. Γ_{k+1} = cay(−hΩ̂_k) Γ_k                       (erratum E2: with the h)
   R_{k+1} = R_k cay(hΩ̂_k)                         (attitude, if requested)
2. σ_{k+1} = σ_k + h c |Ω_k|² / T(σ_k)             (explicit entropy update)
3. Ω_{k+1} = X solves F(X) = 0 with

       F(X) = 𝕀X/h + ½ X×𝕀X + (h/4)(X·𝕀X) X + α c X + b,
       b    = −Π_k/h + ½ Ω_k×Π_k − (h/4)(Ω_k·Π_k) Ω_k − Γ_{k+1}×g⃗ + β c Ω_k,

   friction "trapezoid" (the paper's printed scheme): α = β = ½;
   friction "endpoint" (the paper's f_d^±, E3): α = 1, β = 0.

The Jacobian is analytic,

       J(X) = 𝕀/h + ½(X̂𝕀 − \\widehat{𝕀X}) + (h/4)(2 X (𝕀X)ᵀ + (X·𝕀X) Id) + α c Id,

and the 3×3 Newton system is solved in closed form (adjugate / determinant).
Newton starts from an explicit predictor (one explicit Euler step of the
continuous equations with Γ_{k+1}) and stops when the step is below
``tol · max(|X|∞, |Ω_k|∞)``.  A step that does not converge within
``maxiter`` iterations (or meets a singular/non-finite Jacobian) is reported
as failed and never accepted.

Ω_k is a step velocity: Ω_k = cay⁻¹(R_kᵀR_{k+1})/h ≈ Ω(t_k + h/2) (E4).
"""

from __future__ import annotations

import numpy as np

from ._jit import jit
from .model import P_C, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3, inverse_temperature
from .so3 import attitude_update, cayley_apply

# Newton outcome codes
NEWTON_OK = 0
NEWTON_MAXITER = 1
NEWTON_SINGULAR = 2


@jit
def momentum_constant(omega, gamma_next, p, h, beta, b):
    """b: the X-independent part of F (see module docstring)."""
    I1 = p[P_I1]
    I2 = p[P_I2]
    I3 = p[P_I3]
    c = p[P_C]
    w0 = omega[0]
    w1 = omega[1]
    w2 = omega[2]
    P0 = I1 * w0
    P1 = I2 * w1
    P2 = I3 * w2
    wP = w0 * P0 + w1 * P1 + w2 * P2
    # Γ_{k+1} × g⃗
    G0 = gamma_next[0]
    G1 = gamma_next[1]
    G2 = gamma_next[2]
    t0 = G1 * p[P_GZ] - G2 * p[P_GY]
    t1 = G2 * p[P_GX] - G0 * p[P_GZ]
    t2 = G0 * p[P_GY] - G1 * p[P_GX]
    ih = 1.0 / h
    b[0] = -P0 * ih + 0.5 * (w1 * P2 - w2 * P1) - 0.25 * h * wP * w0 - t0 + beta * c * w0
    b[1] = -P1 * ih + 0.5 * (w2 * P0 - w0 * P2) - 0.25 * h * wP * w1 - t1 + beta * c * w1
    b[2] = -P2 * ih + 0.5 * (w0 * P1 - w1 * P0) - 0.25 * h * wP * w2 - t2 + beta * c * w2


@jit
def momentum_residual(X, b, p, h, alpha, F):
    """F = F(X) of the momentum equation, given its constant part b."""
    I1 = p[P_I1]
    I2 = p[P_I2]
    I3 = p[P_I3]
    ac = alpha * p[P_C]
    x0 = X[0]
    x1 = X[1]
    x2 = X[2]
    Q0 = I1 * x0
    Q1 = I2 * x1
    Q2 = I3 * x2
    xQ = x0 * Q0 + x1 * Q1 + x2 * Q2
    ih = 1.0 / h
    F[0] = Q0 * ih + 0.5 * (x1 * Q2 - x2 * Q1) + 0.25 * h * xQ * x0 + ac * x0 + b[0]
    F[1] = Q1 * ih + 0.5 * (x2 * Q0 - x0 * Q2) + 0.25 * h * xQ * x1 + ac * x1 + b[1]
    F[2] = Q2 * ih + 0.5 * (x0 * Q1 - x1 * Q0) + 0.25 * h * xQ * x2 + ac * x2 + b[2]


@jit
def momentum_jacobian(X, p, h, alpha, J):
    """J = ∂F/∂X (analytic)."""
    I = (p[P_I1], p[P_I2], p[P_I3])
    ac = alpha * p[P_C]
    Q = (I[0] * X[0], I[1] * X[1], I[2] * X[2])
    xQ = X[0] * Q[0] + X[1] * Q[1] + X[2] * Q[2]
    # ½ (X̂ 𝕀 − (𝕀X)^): entries
    # X̂𝕀 = [[0, -x2 I2, x1 I3], [x2 I1, 0, -x0 I3], [-x1 I1, x0 I2, 0]]
    # Q̂  = [[0, -Q2, Q1], [Q2, 0, -Q0], [-Q1, Q0, 0]]
    J[0, 0] = 0.0
    J[0, 1] = 0.5 * (-X[2] * I[1] + Q[2])
    J[0, 2] = 0.5 * (X[1] * I[2] - Q[1])
    J[1, 0] = 0.5 * (X[2] * I[0] - Q[2])
    J[1, 1] = 0.0
    J[1, 2] = 0.5 * (-X[0] * I[2] + Q[0])
    J[2, 0] = 0.5 * (-X[1] * I[0] + Q[1])
    J[2, 1] = 0.5 * (X[0] * I[1] - Q[0])
    J[2, 2] = 0.0
    ih = 1.0 / h
    for i in range(3):
        for j in range(3):
            J[i, j] += 0.5 * h * X[i] * Q[j]
        J[i, i] += I[i] * ih + 0.25 * h * xQ + ac


@jit
def solve3(J, r, out):
    """out = J⁻¹ r in closed form (rows of the inverse are cross products of
    columns divided by the determinant).  Returns the determinant; out is
    left untouched when it is zero or not finite."""
    # columns
    a0 = J[0, 0]
    a1 = J[1, 0]
    a2 = J[2, 0]
    b0 = J[0, 1]
    b1 = J[1, 1]
    b2 = J[2, 1]
    c0 = J[0, 2]
    c1 = J[1, 2]
    c2 = J[2, 2]
    # bc = b × c, ca = c × a, ab = a × b
    bc0 = b1 * c2 - b2 * c1
    bc1 = b2 * c0 - b0 * c2
    bc2 = b0 * c1 - b1 * c0
    det = a0 * bc0 + a1 * bc1 + a2 * bc2
    if det == 0.0 or not np.isfinite(det):
        return det
    ca0 = c1 * a2 - c2 * a1
    ca1 = c2 * a0 - c0 * a2
    ca2 = c0 * a1 - c1 * a0
    ab0 = a1 * b2 - a2 * b1
    ab1 = a2 * b0 - a0 * b2
    ab2 = a0 * b1 - a1 * b0
    inv = 1.0 / det
    out[0] = (bc0 * r[0] + bc1 * r[1] + bc2 * r[2]) * inv
    out[1] = (ca0 * r[0] + ca1 * r[1] + ca2 * r[2]) * inv
    out[2] = (ab0 * r[0] + ab1 * r[1] + ab2 * r[2]) * inv
    return det


@jit
def predictor(omega, gamma_next, p, h, out):
    """Explicit Euler step of Π̇ = Π×Ω − cΩ + Γ×g⃗ (with Γ_{k+1}): O(h²) guess."""
    I1 = p[P_I1]
    I2 = p[P_I2]
    I3 = p[P_I3]
    c = p[P_C]
    w0 = omega[0]
    w1 = omega[1]
    w2 = omega[2]
    P0 = I1 * w0
    P1 = I2 * w1
    P2 = I3 * w2
    G0 = gamma_next[0]
    G1 = gamma_next[1]
    G2 = gamma_next[2]
    iI1 = 1.0 / I1
    iI2 = 1.0 / I2
    iI3 = 1.0 / I3
    out[0] = w0 + h * ((P1 * w2 - P2 * w1) - c * w0 + (G1 * p[P_GZ] - G2 * p[P_GY])) * iI1
    out[1] = w1 + h * ((P2 * w0 - P0 * w2) - c * w1 + (G2 * p[P_GX] - G0 * p[P_GZ])) * iI2
    out[2] = w2 + h * ((P0 * w1 - P1 * w0) - c * w2 + (G0 * p[P_GY] - G1 * p[P_GX])) * iI3


@jit
def newton_momentum(omega, gamma_next, p, h, alpha, beta, tol, maxiter, X):
    """Solve F(X) = 0 for X = Ω_{k+1}; X holds the result.

    Returns (code, iterations).  code is NEWTON_OK, NEWTON_MAXITER or
    NEWTON_SINGULAR.
    """
    b = np.empty(3)
    F = np.empty(3)
    J = np.empty((3, 3))
    d = np.empty(3)
    momentum_constant(omega, gamma_next, p, h, beta, b)
    predictor(omega, gamma_next, p, h, X)
    scale0 = max(abs(omega[0]), abs(omega[1]), abs(omega[2]))
    for it in range(1, maxiter + 1):
        momentum_residual(X, b, p, h, alpha, F)
        momentum_jacobian(X, p, h, alpha, J)
        det = solve3(J, F, d)
        if det == 0.0 or not np.isfinite(det):
            return NEWTON_SINGULAR, it
        X[0] -= d[0]
        X[1] -= d[1]
        X[2] -= d[2]
        step = max(abs(d[0]), abs(d[1]), abs(d[2]))
        scale = max(abs(X[0]), abs(X[1]), abs(X[2]), scale0)
        if not (step == step):  # NaN step
            return NEWTON_SINGULAR, it
        if step <= tol * scale:
            return NEWTON_OK, it
    return NEWTON_MAXITER, maxiter


@jit
def vi_step(y, p, h, n, alpha, beta, tol, maxiter, ynew):
    """One VI step y → ynew (flat state, see model.py).  Returns (code, iters)."""
    omega = y[0:3]
    gamma = y[3:6]
    w = np.empty(3)
    w[0] = -h * omega[0]
    w[1] = -h * omega[1]
    w[2] = -h * omega[2]
    gnew = ynew[3:6]
    cayley_apply(w, gamma, gnew)
    c = p[P_C]
    ynew[6] = y[6] + h * c * (omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2) * inverse_temperature(
        y[6], p)
    if n > 7:
        w[0] = -w[0]
        w[1] = -w[1]
        w[2] = -w[2]
        R = y[7:16].reshape((3, 3))
        Rn = ynew[7:16].reshape((3, 3))
        attitude_update(R, w, Rn)
    X = ynew[0:3]
    return newton_momentum(omega, gnew, p, h, alpha, beta, tol, maxiter, X)


@jit
def kelvin_noether_quantity(omega, gamma, p, h):
    """I_k = h Γ_k·(Π_k + (h/2) Ω_k×Π_k + (h²/4)(Ω_k·Π_k) Ω_k)  (kg m² s⁻¹ · s)."""
    P0 = p[P_I1] * omega[0]
    P1 = p[P_I2] * omega[1]
    P2 = p[P_I3] * omega[2]
    wP = omega[0] * P0 + omega[1] * P1 + omega[2] * P2
    v0 = P0 + 0.5 * h * (omega[1] * P2 - omega[2] * P1) + 0.25 * h * h * wP * omega[0]
    v1 = P1 + 0.5 * h * (omega[2] * P0 - omega[0] * P2) + 0.25 * h * h * wP * omega[1]
    v2 = P2 + 0.5 * h * (omega[0] * P1 - omega[1] * P0) + 0.25 * h * h * wP * omega[2]
    return h * (gamma[0] * v0 + gamma[1] * v1 + gamma[2] * v2)
