"""The continuous heavy top in Stokes flow (body frame), on flat state vectors.

State layout (``y``, float64): ``y[0:3] = Ω`` (rad s⁻¹), ``y[3:6] = Γ = Rᵀe₃``
(1), ``y[6] = σ = S − S₀`` (J K⁻¹, entropy produced since the start; kept
relative to S₀ so that tiny increments are not lost against a large S₀), and,
only when the attitude is requested, ``y[7:16] = R`` row-major.  ``NSTATE_BASE
= 7``; ``NSTATE_ATTITUDE = 16``.

Parameter layout (``p``, float64, one row per member): principal moments
``I₁, I₂, I₃`` (kg m²), Stokes coefficient ``c = 8πμa³`` (N m s), the gravity
torque vector ``g⃗ = mgℓχ`` (N m), ``c_v = 3N₀R_gas`` (J K⁻¹) and ``T₀`` (K).

Equations (SPEC §1):

    Π̇ = −Ω×Π − cΩ + Γ×g⃗,   Π = 𝕀Ω
    Γ̇ = Γ×Ω
    σ̇ = c|Ω|² / T(σ),       T(σ) = T₀ exp(σ/c_v)
    Ṙ = R Ω̂                  (only with the attitude)

The kernels divide by nothing that changes from step to step: 𝕀⁻¹ enters as
the products with 1/I_k, and 1/T(σ) as exp(−σ·(1/c_v))·(1/T₀) (see
:func:`inverse_temperature`).  The reciprocals 1/I_k, 1/c_v, 1/T₀ are
correctly rounded, so the fast kernel (kernels/fast.py), which computes them
once per block, gets the same bits.
"""

from __future__ import annotations

import math

from ._jit import jit

P_I1, P_I2, P_I3, P_C, P_GX, P_GY, P_GZ, P_CV, P_T0 = range(9)
NPARAM = 9
NSTATE_BASE = 7
NSTATE_ATTITUDE = 16


@jit
def inverse_temperature(sigma, p):
    """1/T = exp(−σ·(1/c_v))·(1/T₀) in K⁻¹ — the form every kernel uses (no
    per-step division; within round-off of 1/(T₀ exp(σ/c_v)))."""
    return math.exp(-(sigma * (1.0 / p[P_CV]))) * (1.0 / p[P_T0])


@jit
def rhs(y, p, n, dy):
    """dy = f(y) for the continuous system; n = 7 or 16 (with attitude)."""
    I1 = p[P_I1]
    I2 = p[P_I2]
    I3 = p[P_I3]
    c = p[P_C]
    gx = p[P_GX]
    gy = p[P_GY]
    gz = p[P_GZ]
    w0 = y[0]
    w1 = y[1]
    w2 = y[2]
    G0 = y[3]
    G1 = y[4]
    G2 = y[5]
    P0 = I1 * w0
    P1 = I2 * w1
    P2 = I3 * w2
    iI1 = 1.0 / I1
    iI2 = 1.0 / I2
    iI3 = 1.0 / I3
    # Π̇ = Π×Ω − cΩ + Γ×g
    dy[0] = ((P1 * w2 - P2 * w1) - c * w0 + (G1 * gz - G2 * gy)) * iI1
    dy[1] = ((P2 * w0 - P0 * w2) - c * w1 + (G2 * gx - G0 * gz)) * iI2
    dy[2] = ((P0 * w1 - P1 * w0) - c * w2 + (G0 * gy - G1 * gx)) * iI3
    # Γ̇ = Γ×Ω
    dy[3] = G1 * w2 - G2 * w1
    dy[4] = G2 * w0 - G0 * w2
    dy[5] = G0 * w1 - G1 * w0
    dy[6] = c * (w0 * w0 + w1 * w1 + w2 * w2) * inverse_temperature(y[6], p)
    if n > NSTATE_BASE:
        # Ṙ = R Ω̂ ; row i of R is y[7+3i : 10+3i]; (RΩ̂)_i = R_i × ... : row·Ω̂
        for i in range(3):
            r0 = y[7 + 3 * i]
            r1 = y[8 + 3 * i]
            r2 = y[9 + 3 * i]
            # (r Ω̂)_j = Σ_k r_k Ω̂_kj ; Ω̂ = [[0,-w2,w1],[w2,0,-w0],[-w1,w0,0]]
            dy[7 + 3 * i] = r1 * w2 - r2 * w1
            dy[8 + 3 * i] = -r0 * w2 + r2 * w0
            dy[9 + 3 * i] = r0 * w1 - r1 * w0


@jit
def kinetic_energy(w, p):
    """K = ½ Ω·𝕀Ω in J."""
    return 0.5 * (p[P_I1] * w[0] * w[0] + p[P_I2] * w[1] * w[1] + p[P_I3] * w[2] * w[2])


@jit
def potential_energy(G, p):
    """V = mgℓ Γ·χ in J."""
    return p[P_GX] * G[0] + p[P_GY] * G[1] + p[P_GZ] * G[2]


@jit
def internal_energy_change(sigma, p):
    """U(S) − U(S₀) = c_v T₀ expm1(σ/c_v) in J, without cancellation."""
    return p[P_CV] * p[P_T0] * math.expm1(sigma / p[P_CV])
