"""Explicit Runge–Kutta baselines on the continuous system (flat state).

* ``rk2_step``: explicit midpoint rule (the paper's "standard Runge–Kutta of
  order 2"), order 2, 2 right-hand-side evaluations per step;
* ``rk4_step``: classical RK4, order 4, 4 evaluations;
* ``dop853_step``: the 8th-order Dormand–Prince tableau (12 stages, taken from
  scipy's ``dop853_coefficients``) used at fixed step as the high-accuracy
  reference; callers take ``nsub`` substeps per output step.

None of these preserves |Γ| = 1, RᵀR = I or the discrete Kelvin–Noether law.
"""

from __future__ import annotations

import functools

import numpy as np

from ._jit import fma, jit
from .model import rhs

DOP853_STAGES = 12
#: placeholders of the tableau's shapes, for calls that never take a DOP853 step
NO_TABLEAU_A = np.zeros((DOP853_STAGES, DOP853_STAGES))
NO_TABLEAU_B = np.zeros(DOP853_STAGES)


@functools.cache
def _dop853_tableau():
    # scipy.integrate costs ~0.3 s to import: loaded only when the reference is used
    from scipy.integrate._ivp import dop853_coefficients as dop

    return {"DOP853_A": np.ascontiguousarray(dop.A[:12, :12], dtype=np.float64),
            "DOP853_B": np.ascontiguousarray(dop.B, dtype=np.float64),
            "DOP853_C": np.ascontiguousarray(dop.C[:12], dtype=np.float64)}


def __getattr__(name):
    """``DOP853_A``, ``DOP853_B``, ``DOP853_C``: the tableau of the 8th-order DOP853
    solution (first 12 stages), loaded on first access."""
    if name in ("DOP853_A", "DOP853_B", "DOP853_C"):
        return _dop853_tableau()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@jit(inline="always")
def rk4_sum(k1, k2, k3, k4):
    """k1 + 2k2 + 2k3 + k4 as rk4_combine forms it (2(k2 + k3) as a sum, exact)."""
    s = k2 + k3
    return (s + s) + (k1 + k4)


@jit(inline="always")
def rk4_combine(y, k1, k2, k3, k4, h6):
    """y + (h/6)(k1 + 2k2 + 2k3 + k4) as rk4_step and the fast kernel evaluate it
    (h6 = h·(1/6))."""
    return fma(h6, rk4_sum(k1, k2, k3, k4), y)


@jit
def rk2_step(y, p, h, n, work, ynew):
    """Explicit midpoint: y' = y + h f(y + h/2 f(y)).  work: (2, n) scratch."""
    k1 = work[0]
    k2 = work[1]
    h2 = 0.5 * h
    rhs(y, p, n, k1)
    for i in range(n):
        ynew[i] = fma(h2, k1[i], y[i])
    rhs(ynew, p, n, k2)
    for i in range(n):
        ynew[i] = fma(h, k2[i], y[i])


@jit
def rk4_step(y, p, h, n, work, ynew):
    """Classical RK4.  work: (5, n) scratch."""
    k1 = work[0]
    k2 = work[1]
    k3 = work[2]
    k4 = work[3]
    tmp = work[4]
    h2 = 0.5 * h
    h6 = h * (1.0 / 6.0)
    rhs(y, p, n, k1)
    for i in range(n):
        tmp[i] = fma(h2, k1[i], y[i])
    rhs(tmp, p, n, k2)
    for i in range(n):
        tmp[i] = fma(h2, k2[i], y[i])
    rhs(tmp, p, n, k3)
    for i in range(n):
        tmp[i] = fma(h, k3[i], y[i])
    rhs(tmp, p, n, k4)
    for i in range(n):
        ynew[i] = rk4_combine(y[i], k1[i], k2[i], k3[i], k4[i], h6)


@jit
def dop853_step(y, p, h, n, A, B, K, tmp, ynew):
    """One fixed step of the 8th-order DOP853 solution.

    K: (12, n) stage scratch, tmp: (n,) scratch.
    """
    rhs(y, p, n, K[0])
    for s in range(1, DOP853_STAGES):
        for i in range(n):
            acc = 0.0
            for j in range(s):
                acc += A[s, j] * K[j, i]
            tmp[i] = y[i] + h * acc
        rhs(tmp, p, n, K[s])
    for i in range(n):
        acc = 0.0
        for j in range(DOP853_STAGES):
            acc += B[j] * K[j, i]
        ynew[i] = y[i] + h * acc
