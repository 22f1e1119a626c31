"""Internal energy of body and fluid: the ideal solid (Dulong–Petit).

U(S) = c_v T(S), T(S) = U′(S) = T₀ exp((S − S₀)/c_v), c_v = 3N₀R (J/K).
The kernels carry σ = S − S₀ (so that tiny increments are not lost against a
large S₀).  Coefficients of :class:`IdealSolid`: c_v, T₀, m = −1/c_v,
e₀ = 1/T₀ and the Taylor coefficients e₁ = e₀m, e₂ = e₁m/2, e₃ = e₂m/3 of
1/T(σ) = e₀ exp(mσ), σ_max = EXP_SMALL·c_v and 1/c_v.

1/T(σ) is evaluated as the cubic ((e₃σ + e₂)σ + e₁)σ + e₀ when
|σ/c_v| ≤ ``EXP_SMALL`` = 2⁻¹⁶ (the dropped quartic term is below 2⁻⁶⁸
relative, far under round-off), which LLVM vectorizes; otherwise (or when σ
is not finite) with ``math.exp``.  An ensemble whose heat can take σ/c_v
beyond 2⁻¹⁶ (a small heat capacity) gets :class:`IdealSolidWide` instead,
whose degree-8 polynomial about the middle of the reachable entropy holds
for σ/c_v from 0 to 1/8.  Every function that can use the cubic
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

from .._jit import fma, lane
from ..dispatch import capability, generic, is_present, term_class
from ..gen import is_none
from ..lanemath import exp_lane

#: |σ/c_v| up to which 1/T(σ) is its cubic Taylor polynomial
EXP_SMALL = 2.0**-16
#: |σ − σ_c|/c_v up to which 1/T(σ) is its degree-8 Taylor polynomial about σ_c
#: (IdealSolidWide): the dropped term is below (1/16)⁹/9! < 2⁻⁵⁴ relative
EXP_WIDE = 2.0**-4
#: |x| up to which log1p(x) is its quartic Taylor polynomial
LOG_SMALL = 2.0**-13


class IdealSolid(namedtuple("IdealSolid", "cv T0 m e0 e1 e2 e3 smax icv")):
    __slots__ = ()


class IdealSolidWide(namedtuple("IdealSolidWide", "cv T0 m e0 e1 e2 e3 smax icv sc f0 f1 f2 f3 f4 f5 f6 f7 f8")):
    """The same ideal solid for ensembles that heat: 1/T(σ) is the degree-8
    Taylor polynomial about σ_c = ``sc`` (f_k = 1/T(σ_c)·m^k/k!), valid for
    |σ − σ_c| ≤ c_v/16.  σ_c is the middle of the entropy the ensemble's heat
    can reach, so that σ/c_v from 0 to 1/8 (a heating by 13 %) keeps the
    vectorized path; the cubic of :class:`IdealSolid` holds only to 2⁻¹⁶,
    beyond which a lane is redone with ``math.exp`` (as it is here beyond
    the polynomial's range)."""

    __slots__ = ()
    #: the solvers evaluate 1/T(σ) with the polynomial about σ_c
    CAPABILITIES = frozenset({"wide_inverse_temperature"})


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


def coefficients_wide(heat_capacity: np.ndarray, T0: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(N, 19) coefficients of IdealSolidWide: those of :func:`coefficients`
    (σ_max = EXP_WIDE·c_v, the half-width about σ_c), σ_c = c_v·reach/2 and
    the Taylor coefficients f₀ … f₈ of 1/T about σ_c (``reach``: the σ/c_v
    the heat can reach, (N,))."""
    base = coefficients(heat_capacity, T0)
    base[:, 7] = EXP_WIDE * base[:, 0]
    cv, m, e0 = base[:, 0], base[:, 2], base[:, 3]
    sc = 0.5 * cv * np.broadcast_to(np.asarray(reach, dtype=np.float64).reshape(-1), cv.shape)
    f = [e0 * np.exp(m * sc)]
    for n in range(1, 9):
        f.append(f[-1] * m * (1.0 / n))
    return np.column_stack([base, sc] + f)


@generic(capability("wide_inverse_temperature"))
def inverse_temperature_poly(th, s):
    """(1/T(σ), valid): the cubic about 0."""
    return fma(s, fma(s, fma(s, th.e3, th.e2), th.e1), th.e0), abs(s) <= th.smax


@inverse_temperature_poly.register(True)
def inverse_temperature_wide(th, s):
    """(1/T(σ), valid): the degree-8 polynomial about σ_c, by Estrin's scheme
    (a dependency chain of 5 operations instead of Horner's 8)."""
    x = s - th.sc
    x2 = x * x
    x4 = x2 * x2
    b0 = fma(x2, fma(x, th.f3, th.f2), fma(x, th.f1, th.f0))
    b1 = fma(x2, fma(x, th.f7, th.f6), fma(x, th.f5, th.f4))
    return fma(x4, fma(x4, th.f8, b1), b0), abs(x) <= th.smax


@lane
def inverse_temperature(th, s, exact):
    """(1/T(σ), ok) in 1/K: the Taylor polynomial (the cubic; for
    IdealSolidWide degree 8 about σ_c), valid if ``small``; with ``exact`` the polynomial where
    it is valid and math.exp elsewhere (ok then always True)."""
    f, small = inverse_temperature_poly(th, s)
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


def _heat_key(thermo, P) -> str:
    """What an entropy update has to do: "none" without thermodynamics,
    "still" when nothing dissipates (P is None), else "heat"."""
    if is_none(thermo):
        return "none"
    return "heat" if is_present(P) else "still"


@generic(_heat_key, arg=(0, 1))
def entropy_rate(thermo, P, s, exact):
    """(σ̇, small) = (P/T(σ), small) in J K⁻¹ s⁻¹; (None, True) without thermodynamics."""
    return None, True


@entropy_rate.register("still")
def entropy_rate_still(thermo, P, s, exact):
    return 0.0 * s, True


@entropy_rate.register("heat")
def entropy_rate_heat(thermo, P, s, exact):
    f, small = inverse_temperature(thermo, s, exact)
    return P * f, small


def _update_key(thermo, mode, P):
    """:func:`_heat_key`, and with heat the class of the update ``mode``."""
    k = _heat_key(thermo, P)
    return term_class(mode) if k == "heat" else k


@generic(_update_key, arg=(0, 1, 3))
def entropy_step(thermo, mode, h, P, s, exact):
    """(σ', small): the variational integrator's entropy update over a step
    of size h dissipating P (explicit or symmetric, by the type of ``mode``);
    (None, True) without thermodynamics."""
    return None, True


@entropy_step.register("still")
def entropy_step_still(thermo, mode, h, P, s, exact):
    return s, True


@entropy_step.register(Explicit)
def entropy_step_explicit(thermo, mode, h, P, s, exact):
    f, small = inverse_temperature(thermo, s, exact)
    return fma(h, P * f, s), small


@entropy_step.register(Symmetric)
def entropy_step_symmetric(thermo, mode, h, P, s, exact):
    f, small = inverse_temperature(thermo, s, exact)
    L, small2 = log1p_small(((h * P) * f) * thermo.icv, exact)
    return fma(thermo.cv, L, s), small & small2
