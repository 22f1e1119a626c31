"""exp and expm1 as lane functions: plain float arithmetic that LLVM vectorizes.

``math.exp`` and ``math.expm1`` are calls into the C library; a lane loop
that contains one stays scalar.  :func:`exp_lane` and :func:`expm1_lane`
compute the same functions with fused multiply-adds, compares, selects and
two integer-bit operations, all of which have packed forms (AVX2: ``vfmadd…pd``,
``vblendvpd``, ``vpaddq``, ``vpsllq``, ``vpsrlq``), so a loop that calls them
stays one vectorized body.  Both kernels call them, so the straightforward
and the vectorized kernels keep computing the same bits.

Method (x clamped to [−746, 710], beyond which exp is 0 or inf anyway; NaN
passes through):

1. k = round(x/ln 2) by the magic-number trick: k_d = fma(x, log₂e, 1.5·2⁵²)
   holds k in its low mantissa bits (its ulp is 1), k = k_d − 1.5·2⁵²;
2. Cody–Waite reduction x − k ln 2 = r + r_l with ln 2 = C₁ + C₂ (C₁ the
   double nearest ln 2): fma(−k, C₁, x) is exact (x and kC₁ are multiples
   of ulp(C₁)/2 or finer and the difference is below ½), r = fma(−k, C₂, ·)
   and r_l its rounding error; |r| ≤ ln2/2 (+ a rounding);
3. e^(r + r_l) = 1 + r + r₂ + t with r₂ + r₂ₗ = r²/2 exactly (a product and
   its fused remainder) and the small rest t = r³c(r) + r₂ₗ + r_l(1 + r + r₂),
   c the Taylor polynomial 1/3! + r/4! + … + r¹¹/14! (Horner, fused): the
   first dropped term r¹⁵/15! is below 2⁻⁶³; the large parts are summed
   with exact two-sums, so the result is rounded about once;
4. 2ᵏ from the exponent bits: the low bits of k_d are 2⁵¹ + k, so
   u = bits(k_d) − bits(1.5·2⁵²) + 2048 = k + 2048 ≥ 0; 2ᵏ is split into
   2^k₁·2^k₂, k₁ = ⌊u/2⌋ − 1024, both normal over the whole clamped range,
   so that gradual underflow and overflow come out right:
   exp(x) = fma(2^k₁, 1 + r, 2^k₁(…))·2^k₂;
5. expm1(x) = (2ᵏ − 1) + 2ᵏr + 2ᵏr₂ + 2ᵏt, the first three summed exactly
   (2ᵏ − 1 is exact up to k = 53; beyond, the −1 joins the small rest); for
   k > 1022 (x > 708.7), where 2ᵏ(1 + r) could overflow, exp(x); ±0 stays ±0.

:func:`exp_small` is the same arithmetic for |x| ≤ ``SMALL`` < ln2/2, where
k = 0 and steps 1, 2 and 4 are exact no-ops: the same bits at half the
cost.  :func:`expm1_small` is x + x²q(x) with a short Taylor polynomial q for
|x| ≤ ``SMALL_M1`` = 1/16, a quarter of the cost; expm1_lane returns it
there.  Both return a flag that says whether x was in their range, for
sweeps that redo a flagged lane with the full function (the coupled top's
Newton iteration: its entropy increment Δ/c_v is far below 1/16).

Accuracy (tests/test_lanemath.py, against the C library and 64-bit-mantissa
references): at most 0.55 ulp for exp and 0.56 ulp for expm1 on normal
results (0.75 ulp for subnormal ones, rounded twice), so never more than
1 ulp from ``math.exp`` / ``math.expm1``; expm1 exact near 0 and at ±0.
"""

from __future__ import annotations

from ._jit import bits_float, float_bits, fma, lane, select

LOG2E = 1.4426950408889634
#: ln 2 = LN2_HI + LN2_LO (LN2_HI the double nearest ln 2)
LN2_HI = 0.6931471805599453
LN2_LO = 2.3190468138462996e-17
#: 1.5·2⁵²: adding it rounds to an integer, held in the low mantissa bits
SHIFT = 6755399441055744.0
#: bits(SHIFT) − 2048: u = bits(k_d) − U_BIAS = k + 2048
U_BIAS = 0x4338000000000000 - 2048
#: beyond these x, exp(x) is inf or 0 (in double precision) anyway
X_HIGH = 710.0
X_LOW = -746.0
#: |x| up to which exp_small is valid (k = 0: |x| log₂e < ½)
SMALL = 0.34
#: |x| up to which expm1_small is valid (and used by expm1_lane)
SMALL_M1 = 0.0625

# Taylor coefficients 1/n!, n = 3 … 14 (the doubles nearest)
_C3 = 0.16666666666666666
_C4 = 0.041666666666666664
_C5 = 0.008333333333333333
_C6 = 0.001388888888888889
_C7 = 0.0001984126984126984
_C8 = 2.48015873015873e-05
_C9 = 2.7557319223985893e-06
_C10 = 2.755731922398589e-07
_C11 = 2.505210838544172e-08
_C12 = 2.08767569878681e-09
_C13 = 1.6059043836821613e-10
_C14 = 1.1470745597729725e-11


@lane
def exp_parts(x):
    """(r, r₂, t, 2^k₁, 2^k₂, k): exp(x) = (1 + r + r₂ + t)·2^k₁·2^k₂ with
    k = k₁ + k₂, |r| ≤ ln2/2, r₂ = r²/2 rounded and t the small rest
    (see module docstring)."""
    xc = select(x > X_HIGH, X_HIGH, x)
    xc = select(xc < X_LOW, X_LOW, xc)
    kd = fma(xc, LOG2E, SHIFT)
    k = kd - SHIFT
    r1 = fma(-k, LN2_HI, xc)
    r = fma(-k, LN2_LO, r1)
    rl = fma(-k, LN2_LO, r1 - r)  # x − k ln 2 = r + rl
    hr = 0.5 * r
    r2 = r * hr
    r2l = fma(r, hr, -r2)  # r²/2 = r2 + r2l exactly
    c = fma(r, _C14, _C13)
    c = fma(r, c, _C12)
    c = fma(r, c, _C11)
    c = fma(r, c, _C10)
    c = fma(r, c, _C9)
    c = fma(r, c, _C8)
    c = fma(r, c, _C7)
    c = fma(r, c, _C6)
    c = fma(r, c, _C5)
    c = fma(r, c, _C4)
    c = fma(r, c, _C3)
    # e^(r + rl) − 1 − r − r²/2 = r³c(r) + rl(1 + r + r²/2) + O(rl r³)
    t = fma(r * r2, 2.0 * c, r2l + fma(rl, r + r2, rl))
    u = float_bits(kd) - U_BIAS
    u1 = u >> 1
    s1 = bits_float((u1 - 1) << 52)
    s2 = bits_float((u - u1 - 1) << 52)
    return r, r2, t, s1, s2, k


@lane
def _exp_scaled(r, r2, t, s1, s2):
    """(1 + r + r₂ + t)·s1·s2 with one rounding (unless subnormal)."""
    a = 1.0 + r
    al = (1.0 - a) + r  # 1 + r = a + al exactly (|r| < 1)
    return fma(s1, a, s1 * ((al + r2) + t)) * s2


@lane
def exp_lane(x):
    """exp(x) (≤ 1 ulp; inf above ≈709.78, 0 below ≈−745.1, NaN for NaN)."""
    r, r2, t, s1, s2, k = exp_parts(x)
    return _exp_scaled(r, r2, t, s1, s2)


@lane
def expm1_lane(x):
    """expm1(x) = eˣ − 1 (≤ 1 ulp, with full relative accuracy near 0):
    expm1_small where that is valid, else the reduction."""
    r, r2, t, s1, s2, k = exp_parts(x)
    # k ≤ 1022: (2ᵏ − 1) + 2ᵏr summed exactly (|2ᵏ − 1| ≥ |2ᵏr| for k ≠ 0), then the
    # rest; 2ᵏ − 1 is exact up to k = 53, beyond it the −1 goes with the rest
    s = s1 * s2
    one = select(k > 53.0, 0.0, 1.0)
    a = s - one
    b = s * r
    hi = a + b
    lo = ((a - hi) + b) - (1.0 - one)
    b2 = s * r2
    hi2 = hi + b2
    lo2 = (hi - hi2) + b2  # |hi| ≥ |b2|: hi + b2 = hi2 + lo2 exactly
    small = hi2 + fma(s, t, lo + lo2)
    # k > 1022: eˣ − 1 rounds to eˣ (the small form would overflow in 2ᵏ(1 + r))
    big = _exp_scaled(r, r2, t, s1, s2)
    near0, ok = expm1_small(x)
    return select(ok, near0, select(k > 1022.0, big, small))


@lane
def _small_parts(x):
    """(r₂, t) of exp_parts for |x| ≤ ln2/2 (k = 0: r = x, no rounding error)."""
    hr = 0.5 * x
    r2 = x * hr
    r2l = fma(x, hr, -r2)
    c = fma(x, _C14, _C13)
    c = fma(x, c, _C12)
    c = fma(x, c, _C11)
    c = fma(x, c, _C10)
    c = fma(x, c, _C9)
    c = fma(x, c, _C8)
    c = fma(x, c, _C7)
    c = fma(x, c, _C6)
    c = fma(x, c, _C5)
    c = fma(x, c, _C4)
    c = fma(x, c, _C3)
    return r2, fma(x * r2, 2.0 * c, r2l)


@lane
def exp_small(x):
    """(exp(x), ok): ok when |x| ≤ SMALL, and then the bits of exp_lane(x) at
    half its cost (no reduction, no scaling)."""
    r2, t = _small_parts(x)
    a = 1.0 + x
    al = (1.0 - a) + x
    return a + ((al + r2) + t), abs(x) <= SMALL


@lane
def expm1_small(x):
    """(expm1(x), ok): ok when |x| ≤ SMALL_M1, and then what expm1_lane(x)
    returns (it uses this form there): x + x²q(x), q the Taylor polynomial
    1/2! + x/3! + … + x⁷/9! (the first dropped term, x¹⁰/10!, is below
    2⁻⁵⁸ of the result), one rounding but for x² and q, whose errors weigh
    |x|/2 ≤ 2⁻⁵; ±0 stays ±0."""
    q = fma(x, _C9, _C8)
    q = fma(x, q, _C7)
    q = fma(x, q, _C6)
    q = fma(x, q, _C5)
    q = fma(x, q, _C4)
    q = fma(x, q, _C3)
    q = fma(x, q, 0.5)
    return select(x == 0.0, x, fma(x * x, q, x)), abs(x) <= SMALL_M1


@lane
def expm1_sel(x, exact):
    """(expm1(x), ok): with ``exact`` expm1_lane (ok True), else expm1_small —
    the same bits where ok, so that a lane flagged by a vectorized sweep and
    redone with ``exact`` computes what the straightforward kernel computes."""
    if exact:
        return expm1_lane(x), True
    return expm1_small(x)
