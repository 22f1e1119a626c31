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

In the kernels the equations take their textbook (Euler) form with per-member
coefficients computed once (:func:`coefficients`),

    Ω̇₁ = A₁Ω₂Ω₃ − K₁Ω₁ + (g_z/I₁)Γ₂ − (g_y/I₁)Γ₃,  A₁ = (I₂−I₃)/I₁, K₁ = c/I₁
    (and cyclically),  σ̇ = (c/T₀)|Ω|² exp(−σ/c_v),

evaluated with explicit fused multiply-adds (:func:`liethermo.kernels._jit.fma`)
by the inline lane functions :func:`rhs7_lane` / :func:`rhs7_lane_poly`, which
the straightforward kernels (through :func:`rhs`) and the vectorized block
kernel (kernels/fast.py) both call — so both get the same bits by
construction.  No division happens per step: the coefficients hold the only
reciprocals.  For |σ/c_v| ≤ ``EXP_SMALL`` (≈ 1e-9 in the paper scene) the
factor (c/T₀)exp(−σ/c_v) of σ̇ is its cubic Taylor polynomial in σ
(:func:`sigma_rate_poly`; the dropped term is below 2⁻⁶⁸ relative, far under
round-off; correctly rounded on every tested argument), else it uses
``math.exp`` (:func:`sigma_rate_exact`).
"""

from __future__ import annotations

import math

from ._jit import fma, jit

P_I1, P_I2, P_I3, P_C, P_GX, P_GY, P_GZ, P_CV, P_T0 = range(9)
NPARAM = 9
NSTATE_BASE = 7
NSTATE_ATTITUDE = 16


#: |σ/c_v| up to which exp(−σ/c_v) in σ̇ is its cubic Taylor polynomial (sigma_rate_poly)
EXP_SMALL = 2.0**-16

# per-member coefficients (coefficients()); Q_* index the tuple
(Q_A1, Q_A2, Q_A3, Q_K1, Q_K2, Q_K3, Q_GZ1, Q_GY1, Q_GX2, Q_GZ2, Q_GY3, Q_GX3,
 Q_MICV, Q_CT, Q_E1, Q_E2, Q_E3, Q_SMAX) = range(18)
NCOEF = 18


@jit(inline="always")
def coefficients(p):
    """The rhs coefficients of one member from its parameters p: (A₁, A₂, A₃,
    K₁, K₂, K₃, g_z/I₁, g_y/I₁, g_x/I₂, g_z/I₂, g_y/I₃, g_x/I₃, m = −1/c_v,
    c/T₀, e₁, e₂, e₃, σ_max) with A₁ = (I₂−I₃)/I₁, A₂ = (I₃−I₁)/I₂,
    A₃ = (I₁−I₂)/I₃, K_k = c/I_k (all through the correctly rounded
    reciprocals 1/I_k, 1/c_v, 1/T₀); e₁ = (c/T₀)m, e₂ = e₁m/2, e₃ = e₂m/3 are
    the Taylor coefficients of (c/T₀)exp(mσ) (sigma_rate_poly) and
    σ_max = EXP_SMALL·c_v the |σ| up to which that cubic is used."""
    I1 = p[P_I1]
    I2 = p[P_I2]
    I3 = p[P_I3]
    c = p[P_C]
    iI1 = 1.0 / I1
    iI2 = 1.0 / I2
    iI3 = 1.0 / I3
    m = -(1.0 / p[P_CV])
    cT = c * (1.0 / p[P_T0])
    e1 = cT * m
    e2 = e1 * m * 0.5
    return ((I2 - I3) * iI1, (I3 - I1) * iI2, (I1 - I2) * iI3,
            c * iI1, c * iI2, c * iI3,
            p[P_GZ] * iI1, p[P_GY] * iI1, p[P_GX] * iI2, p[P_GZ] * iI2,
            p[P_GY] * iI3, p[P_GX] * iI3,
            m, cT, e1, e2, e2 * m * (1.0 / 3.0), EXP_SMALL * p[P_CV])


@jit(inline="always")
def omega_rate(w0, w1, w2, G0, G1, G2, q):
    """Ω̇ (rad s⁻²) from Ω, Γ and the coefficients q (Euler's equations with
    Stokes drag and the gravity torque)."""
    d0 = fma(q[Q_A1] * w1, w2, fma(q[Q_GZ1], G1, fma(-q[Q_GY1], G2, -(q[Q_K1] * w0))))
    d1 = fma(q[Q_A2] * w2, w0, fma(q[Q_GX2], G2, fma(-q[Q_GZ2], G0, -(q[Q_K2] * w1))))
    d2 = fma(q[Q_A3] * w0, w1, fma(q[Q_GY3], G0, fma(-q[Q_GX3], G1, -(q[Q_K3] * w2))))
    return d0, d1, d2


@jit(inline="always")
def cross_lane(a0, a1, a2, b0, b1, b2):
    """a × b with one fused multiply-add per component."""
    return (fma(a1, b2, -(a2 * b1)), fma(a2, b0, -(a0 * b2)), fma(a0, b1, -(a1 * b0)))


@jit(inline="always")
def norm2_lane(w0, w1, w2):
    """|w|² = w·w (fused)."""
    return fma(w0, w0, fma(w1, w1, w2 * w2))


@jit(inline="always")
def rhs7_lane_poly(w0, w1, w2, G0, G1, G2, s, q):
    """f(y) for the 7-wide state with σ̇ from sigma_rate_poly whatever σ:
    returns (Ω̇₁, Ω̇₂, Ω̇₃, Γ̇₁, Γ̇₂, Γ̇₃, σ̇, small) where small says whether
    |σ| ≤ σ_max (if not, σ̇ is not the model's and rhs7_lane must be used)."""
    d0, d1, d2 = omega_rate(w0, w1, w2, G0, G1, G2, q)
    d3, d4, d5 = cross_lane(G0, G1, G2, w0, w1, w2)
    d6, small = sigma_rate_poly(w0, w1, w2, s, q)
    return d0, d1, d2, d3, d4, d5, d6, small


@jit(inline="always")
def sigma_rate(w0, w1, w2, s, q):
    """σ̇ = (c/T₀)|Ω|² exp(−σ/c_v) in J K⁻¹ s⁻¹: sigma_rate_poly where it is
    valid, else sigma_rate_exact."""
    d, small = sigma_rate_poly(w0, w1, w2, s, q)
    return d if small else sigma_rate_exact(w0, w1, w2, s, q)


@jit(inline="always")
def sigma_rate_exact(w0, w1, w2, s, q):
    """σ̇ with math.exp, for |σ| beyond σ_max (or σ not finite)."""
    return (q[Q_CT] * norm2_lane(w0, w1, w2)) * math.exp(s * q[Q_MICV])


@jit(inline="always")
def sigma_rate_poly(w0, w1, w2, s, q):
    """(σ̇, small): the vectorizable form of sigma_rate, |Ω|²·(c/T₀)exp(−σ/c_v)
    with the exponential factor as its cubic Taylor polynomial in σ,
    ((e₃σ + e₂)σ + e₁)σ + c/T₀ (fused); valid when small (|σ| ≤ σ_max, i.e.
    |σ/c_v| ≤ EXP_SMALL: the dropped quartic term is < 2⁻⁶⁸ relative)."""
    f = fma(s, fma(s, fma(s, q[Q_E3], q[Q_E2]), q[Q_E1]), q[Q_CT])
    return norm2_lane(w0, w1, w2) * f, abs(s) <= q[Q_SMAX]


@jit(inline="always")
def rhs7_lane(w0, w1, w2, G0, G1, G2, s, q):
    """f(y) for the 7-wide state: (Ω̇, Γ̇, σ̇) as a 7-tuple."""
    d0, d1, d2, d3, d4, d5, d6, small = rhs7_lane_poly(w0, w1, w2, G0, G1, G2, s, q)
    if not small:
        d6 = sigma_rate_exact(w0, w1, w2, s, q)
    return d0, d1, d2, d3, d4, d5, d6


@jit
def rhs(y, p, n, dy):
    """dy = f(y) for the continuous system; n = 7 or 16 (with attitude)."""
    q = coefficients(p)
    w0 = y[0]
    w1 = y[1]
    w2 = y[2]
    d = rhs7_lane(w0, w1, w2, y[3], y[4], y[5], y[6], q)
    for i in range(7):
        dy[i] = d[i]
    if n > NSTATE_BASE:
        # Ṙ = R Ω̂: row i of R is y[7+3i : 10+3i], and a row r times Ω̂ is r × Ω
        for i in range(3):
            r0 = y[7 + 3 * i]
            r1 = y[8 + 3 * i]
            r2 = y[9 + 3 * i]
            e0, e1, e2 = cross_lane(r0, r1, r2, w0, w1, w2)
            dy[7 + 3 * i] = e0
            dy[8 + 3 * i] = e1
            dy[9 + 3 * i] = e2


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
