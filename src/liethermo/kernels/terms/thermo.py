"""Internal energy of body and fluid: the ideal solid (Dulong–Petit).

U(S) = c_v T(S), T(S) = U′(S) = T₀ exp((S − S₀)/c_v), c_v = 3N₀R (J/K).
The kernels carry σ = S − S₀ (so that tiny increments are not lost against a
large S₀).  Coefficients of :class:`IdealSolid`: c_v, T₀, m = −1/c_v,
e₀ = 1/T₀ and the Taylor coefficients e₁ = e₀m, e₂ = e₁m/2, e₃ = e₂m/3 of
1/T(σ) = e₀ exp(mσ), σ_max = EXP_SMALL·c_v and 1/c_v.

1/T(σ) is evaluated as the cubic ((e₃σ + e₂)σ + e₁)σ + e₀ when
|σ/c_v| ≤ ``EXP_SMALL`` = 2⁻¹⁶ (the dropped quartic term is below 2⁻⁶⁸
relative, far under round-off), which LLVM vectorizes; otherwise (or when σ
is not finite) with ``math.exp``.  Every function that can use the cubic
takes ``exact``: with ``exact=False`` (the vectorized sweeps) it always uses
the cubic and returns whether that was valid; with ``exact=True`` it uses the
cubic where valid and ``math.exp`` elsewhere.  The straightforward kernel
always passes True; the block kernel redoes with True every lane whose cubic
was not valid, so both compute the same bits.  (``math.exp`` stays there:
the redo is a scalar loop, where the C library's short-latency exp is
faster than :func:`..lanemath.exp_lane`'s long chain of fused multiply-adds.)

:func:`temperature` (the coupled top) is T₀·exp(σ/c_v) with
:func:`..lanemath.exp_lane` (plain float arithmetic, ≤ 1 ulp): no library
call, so the coupled top's lane loops vectorize.

Entropy updates of the variational integrator, for a step of size h whose
friction dissipates the power P (W) at the step velocity:

* ``explicit`` (the paper's): σ' = σ + h P/T(σ);
* ``symmetric``: the heat of the step equals the friction work,
  U(σ') − U(σ) = hP, i.e. σ' = σ + c_v log1p(hP/(c_v T(σ))): symmetric in
  h, so that compositions raise the order of S with the rest.  log1p(x) is
  the quartic x − x²/2 + x³/3 − x⁴/4 when |x| ≤ ``LOG_SMALL`` = 2⁻¹³
  (relative error below 2⁻⁵⁴), else ``math.log1p``.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba.extending import overload

from .._jit import LANE_OPTIONS, fma, lane
from ..gen import is_none
from ..lanemath import exp_lane

#: |σ/c_v| up to which 1/T(σ) is its cubic Taylor polynomial
EXP_SMALL = 2.0**-16
#: |x| up to which log1p(x) is its quartic Taylor polynomial
LOG_SMALL = 2.0**-13


class IdealSolid(namedtuple("IdealSolid", "cv T0 m e0 e1 e2 e3 smax icv")):
    __slots__ = ()


class Explicit(namedtuple("Explicit", "unused")):
    """The paper's explicit entropy update (a marker type)."""

    __slots__ = ()


class Symmetric(namedtuple("Symmetric", "unused")):
    """The symmetric, energy-consistent entropy update (a marker type)."""

    __slots__ = ()


EXPLICIT = Explicit(0.0)
SYMMETRIC = Symmetric(0.0)


def coefficients(heat_capacity: np.ndarray, T0: np.ndarray) -> np.ndarray:
    """(N, 9) coefficients of IdealSolid from c_v (N,) and T₀ (N,)."""
    cv = np.asarray(heat_capacity, dtype=np.float64).reshape(-1)
    T0 = np.broadcast_to(np.asarray(T0, dtype=np.float64).reshape(-1), cv.shape)
    m = -(1.0 / cv)
    e0 = 1.0 / T0
    e1 = e0 * m
    e2 = e1 * m * 0.5
    e3 = e2 * m * (1.0 / 3.0)
    return np.stack([cv, T0, m, e0, e1, e2, e3, EXP_SMALL * cv, 1.0 / cv], axis=1)


@lane
def inverse_temperature(th, s, exact):
    """(1/T(σ), ok) in 1/K: the cubic, valid if ``small``; with ``exact`` the
    cubic where it is valid and math.exp elsewhere (ok then always True)."""
    f = fma(s, fma(s, fma(s, th.e3, th.e2), th.e1), th.e0)
    small = abs(s) <= th.smax
    if exact:
        if not small:
            f = th.e0 * math.exp(s * th.m)
        return f, True
    return f, small


@lane
def temperature(th, s):
    """T(σ) = T₀ exp(σ/c_v) in K (``exp_lane``: vectorizable)."""
    return th.T0 * exp_lane(-(s * th.m))


@lane
def log1p_small(x, exact):
    """(log1p(x), ok): the quartic, valid if |x| ≤ LOG_SMALL; with ``exact``
    math.log1p where the quartic is not valid (ok then always True)."""
    L = x * fma(x, fma(x, fma(x, -0.25, 1.0 / 3.0), -0.5), 1.0)
    small = abs(x) <= LOG_SMALL
    if exact:
        if not small:
            L = math.log1p(x)
        return L, True
    return L, small


def entropy_rate(thermo, P, s, exact):
    """(σ̇, small) = (P/T(σ), small) in J K⁻¹ s⁻¹; (None, True) without thermodynamics."""
    if thermo is None:
        return None, True
    if P is None:
        return 0.0 * s, True
    f, small = inverse_temperature(thermo, s, exact)
    return P * f, small


@overload(entropy_rate, jit_options=LANE_OPTIONS)
def _entropy_rate(thermo, P, s, exact):
    if is_none(thermo):
        return lambda thermo, P, s, exact: (None, True)
    if is_none(P):  # nothing dissipates: σ stays
        return lambda thermo, P, s, exact: (0.0 * s, True)

    def impl(thermo, P, s, exact):
        f, small = inverse_temperature(thermo, s, exact)
        return P * f, small

    return impl


def entropy_step(thermo, mode, h, P, s, exact):
    """(σ', small): the variational integrator's entropy update over a step
    of size h dissipating P (explicit or symmetric, by the type of ``mode``)."""
    if thermo is None:
        return None, True
    if P is None:
        return s, True
    f, small = inverse_temperature(thermo, s, exact)
    if isinstance(mode, Explicit):
        return fma(h, P * f, s), small
    L, small2 = log1p_small(((h * P) * f) * thermo.icv, exact)
    return fma(thermo.cv, L, s), small & small2


@overload(entropy_step, jit_options=LANE_OPTIONS)
def _entropy_step(thermo, mode, h, P, s, exact):
    if is_none(thermo):
        return lambda thermo, mode, h, P, s, exact: (None, True)
    if is_none(P):
        return lambda thermo, mode, h, P, s, exact: (s, True)
    if getattr(mode, "instance_class", None) is Explicit:
        def impl(thermo, mode, h, P, s, exact):
            f, small = inverse_temperature(thermo, s, exact)
            return fma(h, P * f, s), small

        return impl
    if getattr(mode, "instance_class", None) is Symmetric:
        def impl(thermo, mode, h, P, s, exact):
            f, small = inverse_temperature(thermo, s, exact)
            L, small2 = log1p_small(((h * P) * f) * thermo.icv, exact)
            return fma(thermo.cv, L, s), small & small2

        return impl
    return None
