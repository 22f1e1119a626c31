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
With D₁ = ½(I₃−I₂), D₂ = ½(I₁−I₃), D₃ = ½(I₂−I₁) (so ½X×𝕀X = (D₁x₂x₃, …)),
M_i = I_i/h + αc and L_i = βc − I_i/h, component 1 reads

       F₁ = M₁x₁ + D₁x₂x₃ + (h/4)(X·𝕀X)x₁ + b₁,
       b₁ = L₁Ω₁ + D₁Ω₂Ω₃ − (h/4)(Ω·𝕀Ω)Ω₁ − (Γ_{k+1}×g⃗)₁,

which is how the lane functions below evaluate F, J and b, with explicit fused
multiply-adds.  The straightforward kernel (``vi_step``) and the vectorized
block kernel (kernels/fast.py) call the same lane functions, so they agree
bitwise.
Newton starts from an explicit predictor (one explicit Euler step of the
continuous equations with Γ_{k+1}) and stops when the step is below
``tol · max(|X|∞, |Ω_k|∞)``.  A step that does not converge within
``maxiter`` iterations (or meets a singular/non-finite Jacobian) is reported
as failed and never accepted.

Ω_k is a step velocity: Ω_k = cay⁻¹(R_kᵀR_{k+1})/h ≈ Ω(t_k + h/2) (E4).
"""

from __future__ import annotations

import numpy as np

from ._jit import fma, jit
from .model import (P_C, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3, coefficients, cross_lane,
                    omega_rate, sigma_rate)
from .so3 import attitude_update, cayley_lane

# Newton outcome codes
NEWTON_OK = 0
NEWTON_MAXITER = 1
NEWTON_SINGULAR = 2

# the VI's per-member coefficients (vi_coefficients); V_* index the tuple
(V_I1, V_I2, V_I3, V_D1, V_D2, V_D3, V_M1, V_M2, V_M3, V_L1, V_L2, V_L3, V_GX, V_GY, V_GZ,
 V_H2, V_H4) = range(17)
NVCOEF = 17


@jit(inline="always")
def vi_coefficients(p, h, alpha, beta):
    """(I₁, I₂, I₃, D₁, D₂, D₃, M₁, M₂, M₃, L₁, L₂, L₃, g_x, g_y, g_z, h/2, h/4)
    of one member (see module docstring)."""
    I1 = p[P_I1]
    I2 = p[P_I2]
    I3 = p[P_I3]
    c = p[P_C]
    ih = 1.0 / h
    ac = alpha * c
    bc = beta * c
    return (I1, I2, I3, 0.5 * (I3 - I2), 0.5 * (I1 - I3), 0.5 * (I2 - I1),
            fma(I1, ih, ac), fma(I2, ih, ac), fma(I3, ih, ac),
            fma(-I1, ih, bc), fma(-I2, ih, bc), fma(-I3, ih, bc),
            p[P_GX], p[P_GY], p[P_GZ], 0.5 * h, 0.25 * h)


@jit(inline="always")
def momentum_constant_lane(w0, w1, w2, G0, G1, G2, v):
    """b (kg m² s⁻²) from Ω_k and Γ_{k+1}."""
    h4wP = v[V_H4] * fma(v[V_I1] * w0, w0, fma(v[V_I2] * w1, w1, (v[V_I3] * w2) * w2))
    t0, t1, t2 = cross_lane(G0, G1, G2, v[V_GX], v[V_GY], v[V_GZ])
    b0 = fma(v[V_L1], w0, fma(v[V_D1] * w1, w2, fma(-h4wP, w0, -t0)))
    b1 = fma(v[V_L2], w1, fma(v[V_D2] * w2, w0, fma(-h4wP, w1, -t1)))
    b2 = fma(v[V_L3], w2, fma(v[V_D3] * w0, w1, fma(-h4wP, w2, -t2)))
    return b0, b1, b2


@jit(inline="always")
def predictor_lane(w0, w1, w2, G0, G1, G2, q, h):
    """Explicit Euler step of the continuous Ω̇ with Γ_{k+1}: an O(h²) guess."""
    d0, d1, d2 = omega_rate(w0, w1, w2, G0, G1, G2, q)
    return fma(h, d0, w0), fma(h, d1, w1), fma(h, d2, w2)


@jit(inline="always")
def residual_jacobian_lane(x0, x1, x2, b0, b1, b2, v):
    """F(X) and the rows of J(X): (F₀, F₁, F₂, J00, J01, J02, J10, …, J22)."""
    Q0 = v[V_I1] * x0
    Q1 = v[V_I2] * x1
    Q2 = v[V_I3] * x2
    h4xQ = v[V_H4] * fma(Q0, x0, fma(Q1, x1, Q2 * x2))
    F0 = fma(v[V_M1], x0, fma(v[V_D1] * x1, x2, fma(h4xQ, x0, b0)))
    F1 = fma(v[V_M2], x1, fma(v[V_D2] * x2, x0, fma(h4xQ, x1, b1)))
    F2 = fma(v[V_M3], x2, fma(v[V_D3] * x0, x1, fma(h4xQ, x2, b2)))
    hx0 = v[V_H2] * x0
    hx1 = v[V_H2] * x1
    hx2 = v[V_H2] * x2
    J00 = fma(Q0, hx0, v[V_M1] + h4xQ)
    J01 = fma(Q1, hx0, v[V_D1] * x2)
    J02 = fma(Q2, hx0, v[V_D1] * x1)
    J10 = fma(Q0, hx1, v[V_D2] * x2)
    J11 = fma(Q1, hx1, v[V_M2] + h4xQ)
    J12 = fma(Q2, hx1, v[V_D2] * x0)
    J20 = fma(Q0, hx2, v[V_D3] * x1)
    J21 = fma(Q1, hx2, v[V_D3] * x0)
    J22 = fma(Q2, hx2, v[V_M3] + h4xQ)
    return F0, F1, F2, J00, J01, J02, J10, J11, J12, J20, J21, J22


@jit(inline="always")
def solve3_lane(J00, J01, J02, J10, J11, J12, J20, J21, J22, r0, r1, r2):
    """(J⁻¹r, det J) by Cramer's rule: the rows of J⁻¹ are the cross products
    of J's columns a, e, c divided by det = a·(e×c).  Meaningless when det is
    0 or not finite."""
    bc0, bc1, bc2 = cross_lane(J01, J11, J21, J02, J12, J22)
    det = fma(J00, bc0, fma(J10, bc1, J20 * bc2))
    ca0, ca1, ca2 = cross_lane(J02, J12, J22, J00, J10, J20)
    ab0, ab1, ab2 = cross_lane(J00, J10, J20, J01, J11, J21)
    inv = 1.0 / det
    d0 = fma(bc0, r0, fma(bc1, r1, bc2 * r2)) * inv
    d1 = fma(ca0, r0, fma(ca1, r1, ca2 * r2)) * inv
    d2 = fma(ab0, r0, fma(ab1, r1, ab2 * r2)) * inv
    return d0, d1, d2, det


@jit(inline="always")
def newton_lane(x0, x1, x2, b0, b1, b2, v):
    """One Newton correction d = J(X)⁻¹F(X): (d₀, d₁, d₂, det J)."""
    F0, F1, F2, J00, J01, J02, J10, J11, J12, J20, J21, J22 = residual_jacobian_lane(
        x0, x1, x2, b0, b1, b2, v)
    return solve3_lane(J00, J01, J02, J10, J11, J12, J20, J21, J22, F0, F1, F2)


@jit
def momentum_constant(omega, gamma_next, p, h, beta, b):
    """b: the X-independent part of F (see module docstring)."""
    v = vi_coefficients(p, h, 0.0, beta)
    b[0], b[1], b[2] = momentum_constant_lane(omega[0], omega[1], omega[2], gamma_next[0],
                                              gamma_next[1], gamma_next[2], v)


@jit
def momentum_residual(X, b, p, h, alpha, F):
    """F = F(X) of the momentum equation, given its constant part b."""
    v = vi_coefficients(p, h, alpha, 0.0)
    r = residual_jacobian_lane(X[0], X[1], X[2], b[0], b[1], b[2], v)
    F[0] = r[0]
    F[1] = r[1]
    F[2] = r[2]


@jit
def momentum_jacobian(X, p, h, alpha, J):
    """J = ∂F/∂X (analytic)."""
    v = vi_coefficients(p, h, alpha, 0.0)
    r = residual_jacobian_lane(X[0], X[1], X[2], 0.0, 0.0, 0.0, v)
    for i in range(3):
        for j in range(3):
            J[i, j] = r[3 + 3 * i + j]


@jit
def solve3(J, r, out):
    """out = J⁻¹ r in closed form (Cramer).  Returns the determinant; out is
    left untouched when it is zero or not finite."""
    d0, d1, d2, det = solve3_lane(J[0, 0], J[0, 1], J[0, 2], J[1, 0], J[1, 1], J[1, 2],
                                  J[2, 0], J[2, 1], J[2, 2], r[0], r[1], r[2])
    if det == 0.0 or not np.isfinite(det):
        return det
    out[0] = d0
    out[1] = d1
    out[2] = d2
    return det


@jit
def predictor(omega, gamma_next, p, h, out):
    """Explicit Euler step of Π̇ = Π×Ω − cΩ + Γ×g⃗ (with Γ_{k+1}): O(h²) guess."""
    q = coefficients(p)
    out[0], out[1], out[2] = predictor_lane(omega[0], omega[1], omega[2], gamma_next[0],
                                            gamma_next[1], gamma_next[2], q, h)


@jit(inline="always")
def newton_stop(x0, x1, x2, d0, d1, d2, scale0, tol):
    """(step, converged) of vi.newton_momentum's rule for the iterate X − d:
    step = |d|∞ ≤ tol·max(|X − d|∞, |Ω_k|∞)."""
    step = max(abs(d0), abs(d1), abs(d2))
    scale = max(abs(x0), abs(x1), abs(x2), scale0)
    return step, step <= tol * scale


@jit(inline="always")
def newton_iterate(x0, x1, x2, b0, b1, b2, v, scale0, tol, maxiter):
    """Newton iterations 1 … maxiter from X = (x0, x1, x2) with newton_momentum's
    stopping rules: returns (X, code, iterations).  On a singular or
    non-finite Jacobian X is the last iterate before it."""
    code = NEWTON_MAXITER
    its = maxiter
    for it in range(1, maxiter + 1):
        d0, d1, d2, det = newton_lane(x0, x1, x2, b0, b1, b2, v)
        if det == 0.0 or not np.isfinite(det):
            code = NEWTON_SINGULAR
            its = it
            break
        x0 -= d0
        x1 -= d1
        x2 -= d2
        step, conv = newton_stop(x0, x1, x2, d0, d1, d2, scale0, tol)
        if not (step == step):  # NaN step
            code = NEWTON_SINGULAR
            its = it
            break
        if conv:
            code = NEWTON_OK
            its = it
            break
    return x0, x1, x2, code, its


@jit(inline="always")
def newton_solve_lane(w0, w1, w2, G0, G1, G2, q, v, h, tol, maxiter):
    """Ω_{k+1} from Ω_k and Γ_{k+1}: b, the predictor, then newton_iterate;
    returns (X, code, iterations)."""
    b0, b1, b2 = momentum_constant_lane(w0, w1, w2, G0, G1, G2, v)
    x0, x1, x2 = predictor_lane(w0, w1, w2, G0, G1, G2, q, h)
    scale0 = max(abs(w0), abs(w1), abs(w2))
    return newton_iterate(x0, x1, x2, b0, b1, b2, v, scale0, tol, maxiter)


@jit
def newton_momentum(omega, gamma_next, p, h, alpha, beta, tol, maxiter, X):
    """Solve F(X) = 0 for X = Ω_{k+1}; X holds the result.

    Returns (code, iterations).  code is NEWTON_OK, NEWTON_MAXITER or
    NEWTON_SINGULAR.
    """
    q = coefficients(p)
    v = vi_coefficients(p, h, alpha, beta)
    x0, x1, x2, code, its = newton_solve_lane(omega[0], omega[1], omega[2], gamma_next[0],
                                              gamma_next[1], gamma_next[2], q, v, h, tol, maxiter)
    X[0] = x0
    X[1] = x1
    X[2] = x2
    return code, its


@jit
def vi_step(y, p, h, n, alpha, beta, tol, maxiter, ynew):
    """One VI step y → ynew (flat state, see model.py).  Returns (code, iters)."""
    w0 = y[0]
    w1 = y[1]
    w2 = y[2]
    G0, G1, G2 = cayley_lane(-(h * w0), -(h * w1), -(h * w2), y[3], y[4], y[5])
    ynew[3] = G0
    ynew[4] = G1
    ynew[5] = G2
    q = coefficients(p)
    ynew[6] = fma(h, sigma_rate(w0, w1, w2, y[6], q), y[6])
    if n > 7:
        w = np.empty(3)
        w[0] = h * w0
        w[1] = h * w1
        w[2] = h * w2
        R = y[7:16].reshape((3, 3))
        Rn = ynew[7:16].reshape((3, 3))
        attitude_update(R, w, Rn)
    v = vi_coefficients(p, h, alpha, beta)
    ynew[0], ynew[1], ynew[2], code, its = newton_solve_lane(w0, w1, w2, G0, G1, G2, q, v, h, tol,
                                                             maxiter)
    return code, its


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
