"""Dot products over a short last axis, and the summary's energy figures, in one compiled pass each.

The labelling's energies and norms are sums of three products per node:
K = ½ Σᵢ Iᵢ Ωᵢ Ωᵢ, V = Σᵢ gᵢ Γᵢ, |Γ|² = Σᵢ Γᵢ Γᵢ.  Written in numpy, each is a
product array, another product array and a reduction: three passes and two
temporaries the size of the state.  :func:`dot3_rows` does it in one pass
with numpy's arithmetic: the products left to right, then ``(p₀ + p₁) + p₂``
onto 0 as numpy reduces a short axis (so −0 sums to +0), no fused
multiply-add (``fastmath`` off), so the bits are numpy's.

:func:`energy_error_figures` and :func:`unit_norm_defect` reduce a chunk's energy
error and |Γ| to the summary's maxima and counts in one pass each, computing every
value with numpy's operations in numpy's order, so the figures are those numpy's
arrays give, without the arrays.
"""

from __future__ import annotations

import numpy as np
from numba import types

from ._jit import jit

_VIEW = types.Array(types.float64, 3, "A", readonly=True)


#: one signature (any strides, read-only views) so one compiled pass serves every caller
@jit((_VIEW, _VIEW, _VIEW, types.Array(types.float64, 2, "C")), nogil=True)
def dot3_rows(a, b, c, out):
    """``out[m, t] = Σᵢ a[m, t, i] b[m, t, i] c[m, t, i]`` over i = 0, 1, 2, products
    left to right and summed as ``np.sum(…, axis=-1)``; a, b, c (M, T, 3) views (any
    strides, broadcast ones too), out (M, T)."""
    for m in range(out.shape[0]):
        for t in range(out.shape[1]):
            s = a[m, t, 0] * b[m, t, 0] * c[m, t, 0] + a[m, t, 1] * b[m, t, 1] * c[m, t, 1]
            s += a[m, t, 2] * b[m, t, 2] * c[m, t, 2]
            out[m, t] = s + 0.0


_ROWS = types.Array(types.float64, 2, "A", readonly=True)
_COL = types.Array(types.float64, 1, "A", readonly=True)


@jit((_ROWS, _ROWS, _ROWS, _COL, _COL, _COL, types.float64, types.Array(types.float64, 1, "C")), nogil=True)
def energy_error_figures(K, V, dU, K0, V0, scale, diverged_above, out):
    """The summary's energy figures in one pass, without the (M, T) arrays between.

    Over members m and stored times t, the energy error E = ((K − K₀) + (V − V₀)) + ΔU
    in numpy's order of operations (so the bits of the labelled ``energy_error``) and
    r = |E| / |scale|; into ``out``: max |E|, max r, max r at t index 0 (each over the
    finite values, −inf where there are none), and the number of members whose
    fmax over t of (0, r) exceeds ``diverged_above`` (NaN skipped, as ``np.fmax``).
    K, V, dU (M, T) and K0, V0, scale (M,) are views of any strides."""
    e_abs = -np.inf
    e_rel = -np.inf
    e_rel0 = -np.inf
    diverged = 0
    for m in range(K.shape[0]):
        s = abs(scale[m])
        worst = 0.0
        for t in range(K.shape[1]):
            e = abs(((K[m, t] - K0[m]) + (V[m, t] - V0[m])) + dU[m, t])
            r = e / s
            if np.isfinite(e) and e > e_abs:
                e_abs = e
            if np.isfinite(r):
                if r > e_rel:
                    e_rel = r
                if t == 0 and r > e_rel0:
                    e_rel0 = r
            if r > worst:  # False for NaN: fmax keeps the other
                worst = r
        if worst > diverged_above:
            diverged += 1
    out[0] = e_abs
    out[1] = e_rel
    out[2] = e_rel0
    out[3] = diverged


@jit((_VIEW, types.Array(types.float64, 1, "C")), nogil=True)
def unit_norm_defect(G, out):
    """``out[0]`` = max over the finite values of | |G[m, t]| − 1 | of vectors G (M, T, 3)
    (any strides; −inf where none is finite), the norm as :func:`dot3_rows` and
    ``np.sqrt`` compute it (so the bits of ``norm3``)."""
    worst = -np.inf
    for m in range(G.shape[0]):
        for t in range(G.shape[1]):
            s = G[m, t, 0] * G[m, t, 0] * 1.0 + G[m, t, 1] * G[m, t, 1] * 1.0
            s += G[m, t, 2] * G[m, t, 2] * 1.0
            d = abs(np.sqrt(s + 0.0) - 1.0)
            if np.isfinite(d) and d > worst:
                worst = d
    out[0] = worst


@jit((_ROWS, _COL, _ROWS, _COL, types.Array(types.float64, 1, "C")), nogil=True)
def decay_error_span(W, W0, E, scale, out):
    """The span over members of r = maxₜ |W[m, t] − W0[m] E[m, t]| / scale[m], in one pass.

    The values numpy's arrays give: the product, difference and absolute value of
    ``np.abs(W - W0[:, None] * E)``, the maximum over t propagating NaN as
    ``np.maximum`` does, then the division.  Into ``out``: the least and the largest
    finite r (inf and −inf where none is finite) and the number of finite r.
    W, E (M, T) and W0, scale (M,) are views of any strides (E may be broadcast)."""
    lo = np.inf
    hi = -np.inf
    count = 0
    for m in range(W.shape[0]):
        d = abs(W[m, 0] - W0[m] * E[m, 0])
        for t in range(1, W.shape[1]):
            x = abs(W[m, t] - W0[m] * E[m, t])
            if not x <= d:  # x larger, or either NaN: np.maximum's result
                d = x if not np.isnan(d) else d
        r = d / scale[m]
        if np.isfinite(r):
            count += 1
            if r < lo:
                lo = r
            if r > hi:
                hi = r
    out[0] = lo
    out[1] = hi
    out[2] = count
