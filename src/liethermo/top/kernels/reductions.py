"""Dot products over a short last axis, in one compiled pass.

The labelling's energies and norms are sums of three products per node:
K = ½ Σᵢ Iᵢ Ωᵢ Ωᵢ, V = Σᵢ gᵢ Γᵢ, |Γ|² = Σᵢ Γᵢ Γᵢ.  Written in numpy, each is a
product array, another product array and a reduction: three passes and two
temporaries the size of the state.  :func:`dot3_rows` does it in one pass
with numpy's arithmetic: the products left to right, then ``(p₀ + p₁) + p₂``
onto 0 as numpy reduces a short axis (so −0 sums to +0), no fused
multiply-add (``fastmath`` off), so the bits are numpy's.
"""

from __future__ import annotations

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
