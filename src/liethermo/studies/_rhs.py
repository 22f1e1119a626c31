"""The continuous right-hand side of one member, jitted for scipy's solve_ivp."""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True)
def rhs7(y, I, C, g, T0, cv, out):
    """d/dt of y = (Ω, Γ, σ): 𝕀Ω̇ = 𝕀Ω×Ω − CΩ + Γ×g⃗, Γ̇ = Γ×Ω, σ̇ = Ω·CΩ/(T₀e^{σ/c_v})."""
    w0, w1, w2 = y[0], y[1], y[2]
    G0, G1, G2 = y[3], y[4], y[5]
    m0, m1, m2 = I[0] * w0, I[1] * w1, I[2] * w2
    out[0] = (m1 * w2 - m2 * w1 - C[0] * w0 + G1 * g[2] - G2 * g[1]) / I[0]
    out[1] = (m2 * w0 - m0 * w2 - C[1] * w1 + G2 * g[0] - G0 * g[2]) / I[1]
    out[2] = (m0 * w1 - m1 * w0 - C[2] * w2 + G0 * g[1] - G1 * g[0]) / I[2]
    out[3] = G1 * w2 - G2 * w1
    out[4] = G2 * w0 - G0 * w2
    out[5] = G0 * w1 - G1 * w0
    out[6] = (C[0] * w0 * w0 + C[1] * w1 * w1 + C[2] * w2 * w2) / (T0 * math.exp(y[6] / cv))
