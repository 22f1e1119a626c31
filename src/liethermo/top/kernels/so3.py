"""SO(3) on plain floats (numba-compiled).

Conventions: ``hat(w) v = w × v``; the Cayley map
``cay(ŵ) = (I − ŵ/2)⁻¹ (I + ŵ/2)`` (Hairer–Lubich–Wanner IV.8.3), which in
vector form reads

    cay(ŵ) v = v + 4/(4 + |w|²) (w × v + ½ w × (w × v)).

It rotates by the angle 2·atan(|w|/2) about w (not |w|): the phase error of a
Cayley step of size h|Ω| is ≈ (h|Ω|)³/12 per step.  The ``*_lane`` functions
are the scalar forms (explicit fused multiply-adds) that every kernel shares,
so the straightforward and the vectorized kernels get the same bits.
"""

from __future__ import annotations

from ._jit import fma, lane


@lane
def cross_lane(a0, a1, a2, b0, b1, b2):
    """a × b with one fused multiply-add per component."""
    return (fma(a1, b2, -(a2 * b1)), fma(a2, b0, -(a0 * b2)), fma(a0, b1, -(a1 * b0)))


@lane
def norm2_lane(w0, w1, w2):
    """|w|² = w·w (fused)."""
    return fma(w0, w0, fma(w1, w1, w2 * w2))


@lane
def cayley_lane(w0, w1, w2, v0, v1, v2):
    """cay(ŵ) v as a 3-tuple: v + s(u + ½ w×u), u = w×v, s = 4/(4 + |w|²)."""
    s = 4.0 / (4.0 + norm2_lane(w0, w1, w2))
    u0, u1, u2 = cross_lane(w0, w1, w2, v0, v1, v2)
    q0, q1, q2 = cross_lane(w0, w1, w2, u0, u1, u2)
    return fma(s, fma(0.5, q0, u0), v0), fma(s, fma(0.5, q1, u1), v1), fma(s, fma(0.5, q2, u2), v2)


@lane
def cayley_matrix_lane(w0, w1, w2):
    """cay(ŵ) = I + s(ŵ + ½ŵ²), s = 4/(4 + |w|²), row-major as a 9-tuple
    ((ŵ²)_ij = w_i w_j − |w|² δ_ij)."""
    ww = norm2_lane(w0, w1, w2)
    s = 4.0 / (4.0 + ww)
    sh = 0.5 * s
    return (fma(sh, fma(w0, w0, -ww), 1.0), fma(sh, w0 * w1, -(s * w2)), fma(sh, w0 * w2, s * w1),
            fma(sh, w1 * w0, s * w2), fma(sh, fma(w1, w1, -ww), 1.0), fma(sh, w1 * w2, -(s * w0)),
            fma(sh, w2 * w0, -(s * w1)), fma(sh, w2 * w1, s * w0), fma(sh, fma(w2, w2, -ww), 1.0))


@lane
def row_times_lane(r0, r1, r2, C):
    """The row vector r times the 3×3 matrix C (a row-major 9-tuple)."""
    return (fma(r0, C[0], fma(r1, C[3], r2 * C[6])), fma(r0, C[1], fma(r1, C[4], r2 * C[7])),
            fma(r0, C[2], fma(r1, C[5], r2 * C[8])))


@lane
def attitude_lane(R, w0, w1, w2):
    """R cay(ŵ) for R a row-major 9-tuple: the attitude update with w = hΩ."""
    C = cayley_matrix_lane(w0, w1, w2)
    a0, a1, a2 = row_times_lane(R[0], R[1], R[2], C)
    b0, b1, b2 = row_times_lane(R[3], R[4], R[5], C)
    c0, c1, c2 = row_times_lane(R[6], R[7], R[8], C)
    return (a0, a1, a2, b0, b1, b2, c0, c1, c2)


@lane
def attitude_rate_lane(R, w0, w1, w2):
    """Ṙ = R Ω̂ for R a row-major 9-tuple: row r of R times Ω̂ is r × Ω."""
    a0, a1, a2 = cross_lane(R[0], R[1], R[2], w0, w1, w2)
    b0, b1, b2 = cross_lane(R[3], R[4], R[5], w0, w1, w2)
    c0, c1, c2 = cross_lane(R[6], R[7], R[8], w0, w1, w2)
    return (a0, a1, a2, b0, b1, b2, c0, c1, c2)
