"""Fast ensemble kernel: structure-of-arrays blocks that LLVM vectorizes.

:func:`advance_ensemble_fast` has the contract of
:func:`liethermo.kernels.ensemble.advance_ensemble` (same arguments, same
in-place arrays ``Y, P, OUT, ISTAT, FSTAT``, same status codes) and computes
the same numbers: every floating-point operation of the straightforward
kernel is done in the same order, without fused multiply-adds or
reassociation (``fastmath`` stays off), so results agree bitwise — states,
status flags, failing steps, Newton iteration counts and max h|Ω|.  The one
place where it does not call the same function is the exp in
1/T(σ) = exp(−σ·(1/c_v))·(1/T₀) (model.inverse_temperature); see below.

How it is fast
--------------
* ``prange`` runs over blocks of ``BLOCK`` members.  A block copies its
  members into one flat buffer, row by row (structure of arrays: row r holds
  quantity r of every lane), advances them for the whole call, and copies
  them back.  Every row sits at a compile-time offset of the same buffer, so
  LLVM sees no possible aliasing and vectorizes the inner loops over lanes
  (packed ``vmulpd``/``vaddpd``/``vsqrtpd`` on ymm/zmm registers; the only
  packed divisions left are the Cayley factor and the Newton 1/det).
* A step is a few straight-line sweeps over the lanes; branches become
  selects.  The VI's Newton iterations run in lock-step over the block with a
  per-lane convergence mask: a converged lane keeps its X, and the block
  stops iterating as soon as no lane runs.  Once only a few lanes still run
  (``NEWTON_FALLBACK``), they finish one by one in scalar code, so one
  slow or diverging member does not hold the whole block.
* A failed member (Newton failure or non-finite state) is written back at
  once and its lane is filled with the block's last lane (compaction), so
  dead members cost nothing — explicit RK2 loses most of the random paper
  ensemble within ~100 steps — and never touch their neighbours' values.
* 1/T(σ) without a libm call: for |σ/c_v| ≤ ``EXP_SMALL``
  (2⁻¹⁶; in the paper scene σ/c_v ≈ 1e-9) exp is evaluated as glibc's own
  ``exp`` does for such arguments (reduction index 0, so r = x exactly, and
  glibc's degree-5 polynomial coefficients): 1 + (r + r²(C₂ + rC₃) +
  r⁴(C₄ + rC₅)).  It matched ``math.exp`` bitwise on 2·10⁷ random
  arguments per range up to 2⁻¹²; a mismatch could only come from glibc's
  fused multiply-adds rounding the tiny tail differently, would be one ulp
  of T, and would only touch σ (σ does not feed back into Ω, Γ, R).
  A lane whose argument is larger (or not finite) is recomputed with the
  straightforward kernel's own code (``math.exp``).
* Explicit RK steps *with* the attitude (16-wide state) and the
  ``reference`` method are not vectorized: they run the straightforward
  per-member code (the RK ones inside the block structure).

Buffers are allocated per block (not per step); nothing is compiled at
import time.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import jit, pjit, prange
from .ensemble import (
    FS_MAX_H_OMEGA,
    IS_FAIL_STEP,
    IS_NEWTON_MAX,
    IS_NEWTON_TOTAL,
    IS_STATUS,
    IS_STEPS,
    METHOD_REFERENCE,
    METHOD_RK2,
    METHOD_RK4,
    METHOD_VI,
    STATUS_NEWTON,
    STATUS_NONFINITE,
    STATUS_OK,
    advance_member,
)
from .model import NSTATE_BASE
from .rk import DOP853_STAGES, rk2_step, rk4_step
from .vi import NEWTON_MAXITER, NEWTON_OK, NEWTON_SINGULAR

#: members per block (lanes); a block's buffer is NROWS·BLOCK doubles
BLOCK = 128
#: when at most this many lanes of a block still iterate, they finish in scalar code
NEWTON_FALLBACK = 16
#: |σ/c_v| up to which exp is evaluated inline (glibc's path for tiny arguments)
EXP_SMALL = 2.0**-16

# glibc's exp polynomial (sysdeps/ieee754/dbl-64/e_exp_data.c, EXP_POLY_ORDER 5)
_C2 = float.fromhex("0x1.ffffffffffdbdp-2")
_C3 = float.fromhex("0x1.555555555543cp-3")
_C4 = float.fromhex("0x1.55555cf172b91p-5")
_C5 = float.fromhex("0x1.1111167a4d017p-7")

# Rows of the per-block buffer; lane i of row r is buf[r*BLOCK + i].
R_Y = 0  # 16 rows: state (model.py layout; 7 or 16 used)
R_P = 16  # 9 rows: parameters (model.py layout)
R_GN = 25  # 3 rows: Γ_{k+1} (VI)
R_SN = 28  # σ_{k+1} (VI)
R_X = 29  # 3 rows: Newton iterate X (VI)
R_B = 32  # 3 rows: constant part b of F (VI)
R_SC0 = 35  # |Ω_k|∞ (VI)
R_RUN = 36  # 1.0 while the lane's Newton iteration runs
R_CODE = 37  # Newton outcome code of this step
R_ITS = 38  # Newton iterations of this step
R_HW = 39  # max h|Ω_k| so far (FSTAT)
R_NTOT = 40  # Newton iterations, total (ISTAT)
R_NMAX = 41  # Newton iterations, max per step (ISTAT)
R_STEPS = 42  # steps done at entry (ISTAT)
R_MEMBER = 43  # member index of the lane
R_FLAG = 44  # per-step outcome: 0 ok, else what to do (see sweeps)
R_RN = 45  # 9 rows: R_{k+1} (VI with attitude)
R_TMP = 45  # 7 rows: RK stage state (shares R_RN's rows: RK has no R there)
R_ACC = 54  # 7 rows: RK4 sum of stages
R_IH = 61  # 3 rows: I_k/h (VI Jacobian diagonal, hoisted: same value)
R_AC = 64  # αc (VI, hoisted)
R_INV = 65  # 5 rows: 1/I₁, 1/I₂, 1/I₃, 1/c_v, 1/T₀ (hoisted: same values)
NROWS = 70

# offsets (compile-time constants inside the kernels)
O_Y = R_Y * BLOCK
O_P = R_P * BLOCK
O_GN = R_GN * BLOCK
O_SN = R_SN * BLOCK
O_X = R_X * BLOCK
O_B = R_B * BLOCK
O_SC0 = R_SC0 * BLOCK
O_RUN = R_RUN * BLOCK
O_CODE = R_CODE * BLOCK
O_ITS = R_ITS * BLOCK
O_HW = R_HW * BLOCK
O_NTOT = R_NTOT * BLOCK
O_NMAX = R_NMAX * BLOCK
O_STEPS = R_STEPS * BLOCK
O_MEMBER = R_MEMBER * BLOCK
O_FLAG = R_FLAG * BLOCK
O_RN = R_RN * BLOCK
O_TMP = R_TMP * BLOCK
O_ACC = R_ACC * BLOCK
O_IH = R_IH * BLOCK
O_AC = R_AC * BLOCK
O_INV = R_INV * BLOCK
B1 = BLOCK  # row stride

# per-step outcome flags (R_FLAG)
FLAG_OK = 0.0
FLAG_NEWTON = 1.0  # Newton failed: STATUS_NEWTON
FLAG_NONFINITE = 2.0  # STATUS_NONFINITE
FLAG_EXACT = 3.0  # exp argument outside EXP_SMALL: redo with math.exp


# --------------------------------------------------------------------------
# inline pieces shared by the vector sweeps and the scalar fallbacks


@jit(inline="always")
def _exp_small(x):
    """exp(x) for |x| ≤ EXP_SMALL, as glibc evaluates it there."""
    r2 = x * x
    return 1.0 + (((0.0 + x) + r2 * (_C2 + x * _C3)) + r2 * r2 * (_C4 + x * _C5))


@jit(inline="always")
def _finite(x):
    return x - x == 0.0


@jit(inline="always")
def _rhs7(w0, w1, w2, G0, G1, G2, s, I1, I2, I3, c, gx, gy, gz, iI1, iI2, iI3, icv, iT0):
    """model.rhs for the 7-wide state, inline exp; returns (dy0..dy6, small).
    iI_k = 1/I_k, icv = 1/c_v, iT0 = 1/T₀ are loop invariants (hoisted)."""
    P0 = I1 * w0
    P1 = I2 * w1
    P2 = I3 * w2
    d0 = ((P1 * w2 - P2 * w1) - c * w0 + (G1 * gz - G2 * gy)) * iI1
    d1 = ((P2 * w0 - P0 * w2) - c * w1 + (G2 * gx - G0 * gz)) * iI2
    d2 = ((P0 * w1 - P1 * w0) - c * w2 + (G0 * gy - G1 * gx)) * iI3
    d3 = G1 * w2 - G2 * w1
    d4 = G2 * w0 - G0 * w2
    d5 = G0 * w1 - G1 * w0
    x = -(s * icv)  # model.inverse_temperature
    small = abs(x) <= EXP_SMALL
    d6 = c * (w0 * w0 + w1 * w1 + w2 * w2) * (_exp_small(x) * iT0)
    return d0, d1, d2, d3, d4, d5, d6, small


@jit(inline="always")
def _newton_iter(x0, x1, x2, b0, b1, b2, I1, I2, I3, Ih0, Ih1, Ih2, ac, h, ih):
    """One Newton correction d = J(X)⁻¹F(X) of vi.newton_momentum, same
    operations (momentum_residual, momentum_jacobian, solve3); returns
    (d0, d1, d2, det).  d is meaningless when det is 0 or not finite.
    Ih_k = I_k·(1/h), ac = αc and ih = 1/h are loop invariants computed once
    per block."""
    # momentum_residual
    Q0 = I1 * x0
    Q1 = I2 * x1
    Q2 = I3 * x2
    xQ = x0 * Q0 + x1 * Q1 + x2 * Q2
    F0 = Q0 * ih + 0.5 * (x1 * Q2 - x2 * Q1) + 0.25 * h * xQ * x0 + ac * x0 + b0
    F1 = Q1 * ih + 0.5 * (x2 * Q0 - x0 * Q2) + 0.25 * h * xQ * x1 + ac * x1 + b1
    F2 = Q2 * ih + 0.5 * (x0 * Q1 - x1 * Q0) + 0.25 * h * xQ * x2 + ac * x2 + b2
    # momentum_jacobian (J[i, j] = off-diagonal part + 0.5 h X_i Q_j, + diagonal)
    J00 = 0.0 + 0.5 * h * x0 * Q0
    J01 = 0.5 * (-x2 * I2 + Q2) + 0.5 * h * x0 * Q1
    J02 = 0.5 * (x1 * I3 - Q1) + 0.5 * h * x0 * Q2
    J10 = 0.5 * (x2 * I1 - Q2) + 0.5 * h * x1 * Q0
    J11 = 0.0 + 0.5 * h * x1 * Q1
    J12 = 0.5 * (-x0 * I3 + Q0) + 0.5 * h * x1 * Q2
    J20 = 0.5 * (-x1 * I1 + Q1) + 0.5 * h * x2 * Q0
    J21 = 0.5 * (x0 * I2 - Q0) + 0.5 * h * x2 * Q1
    J22 = 0.0 + 0.5 * h * x2 * Q2
    J00 += Ih0 + 0.25 * h * xQ + ac  # Ih_k = I_k·(1/h)
    J11 += Ih1 + 0.25 * h * xQ + ac
    J22 += Ih2 + 0.25 * h * xQ + ac
    # solve3 (columns a, b, c)
    a0 = J00
    a1 = J10
    a2 = J20
    e0 = J01
    e1 = J11
    e2 = J21
    c0 = J02
    c1 = J12
    c2 = J22
    bc0 = e1 * c2 - e2 * c1
    bc1 = e2 * c0 - e0 * c2
    bc2 = e0 * c1 - e1 * c0
    det = a0 * bc0 + a1 * bc1 + a2 * bc2
    ca0 = c1 * a2 - c2 * a1
    ca1 = c2 * a0 - c0 * a2
    ca2 = c0 * a1 - c1 * a0
    ab0 = a1 * e2 - a2 * e1
    ab1 = a2 * e0 - a0 * e2
    ab2 = a0 * e1 - a1 * e0
    inv = 1.0 / det
    d0 = (bc0 * F0 + bc1 * F1 + bc2 * F2) * inv
    d1 = (ca0 * F0 + ca1 * F1 + ca2 * F2) * inv
    d2 = (ab0 * F0 + ab1 * F1 + ab2 * F2) * inv
    return d0, d1, d2, det


# --------------------------------------------------------------------------
# explicit Runge–Kutta sweeps (7-wide state), one right-hand side per sweep
# (a fused RK4 step is one long dependency chain per lane; split, the
# out-of-order core overlaps many lanes).  Rows: R_Y state, R_TMP stage
# state, R_ACC (RK4) the running sum k1 + 2k2 + 2k3 (+ k4 at the end, in
# rk.rk4_step's order).


@jit(inline="always")
def _load_params(S, i):
    return (S[O_P + i], S[O_P + B1 + i], S[O_P + 2 * B1 + i], S[O_P + 3 * B1 + i],
            S[O_P + 4 * B1 + i], S[O_P + 5 * B1 + i], S[O_P + 6 * B1 + i],
            S[O_P + 7 * B1 + i], S[O_P + 8 * B1 + i])


@jit(inline="always")
def _load7(S, off, i):
    return (S[off + i], S[off + B1 + i], S[off + 2 * B1 + i], S[off + 3 * B1 + i],
            S[off + 4 * B1 + i], S[off + 5 * B1 + i], S[off + 6 * B1 + i])


@jit(inline="always")
def _load_recips(S, i):
    return (S[O_INV + i], S[O_INV + B1 + i], S[O_INV + 2 * B1 + i], S[O_INV + 3 * B1 + i],
            S[O_INV + 4 * B1 + i])


@jit(inline="always")
def _recips(S, i, uni, pv):
    """Lane i's (1/I₁, 1/I₂, 1/I₃, 1/c_v, 1/T₀): the tuple pv when the block
    is uniform, else its rows."""
    if uni:
        return pv
    return _load_recips(S, i)


@jit(inline="always")
def _params(S, i, uni, pp):
    """Lane i's parameters: the tuple pp when the block is uniform (all
    lanes share them; they then live in registers), else its rows."""
    if uni:
        return pp
    return _load_params(S, i)


@jit
def _rk_first(S, nb, h, rk4, uni, pp, pv):
    """max h|Ω_k|; k1 = f(y); tmp = y + (h/2)k1; acc = k1 (RK4).  R_FLAG is
    set to FLAG_EXACT where an exp argument is out of range, else FLAG_OK."""
    a = 0.5 * h
    for i in range(nb):
        I1, I2, I3, c, gx, gy, gz, cv, T0 = _params(S, i, uni, pp)
        iI1, iI2, iI3, icv, iT0 = _recips(S, i, uni, pv)
        y0, y1, y2, y3, y4, y5, y6 = _load7(S, O_Y, i)
        hw = h * np.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        hm = S[O_HW + i]
        S[O_HW + i] = hw if hw > hm else hm
        k0, k1, k2, k3, k4, k5, k6, small = _rhs7(
            y0, y1, y2, y3, y4, y5, y6, I1, I2, I3, c, gx, gy, gz, iI1, iI2, iI3, icv, iT0)
        S[O_TMP + i] = y0 + a * k0
        S[O_TMP + B1 + i] = y1 + a * k1
        S[O_TMP + 2 * B1 + i] = y2 + a * k2
        S[O_TMP + 3 * B1 + i] = y3 + a * k3
        S[O_TMP + 4 * B1 + i] = y4 + a * k4
        S[O_TMP + 5 * B1 + i] = y5 + a * k5
        S[O_TMP + 6 * B1 + i] = y6 + a * k6
        if rk4:
            S[O_ACC + i] = k0
            S[O_ACC + B1 + i] = k1
            S[O_ACC + 2 * B1 + i] = k2
            S[O_ACC + 3 * B1 + i] = k3
            S[O_ACC + 4 * B1 + i] = k4
            S[O_ACC + 5 * B1 + i] = k5
            S[O_ACC + 6 * B1 + i] = k6
        S[O_FLAG + i] = FLAG_OK if small else FLAG_EXACT


@jit
def _rk4_mid(S, nb, a, uni, pp, pv):
    """RK4 stage 2 or 3: k = f(tmp); acc += 2k; tmp = y + a k."""
    for i in range(nb):
        I1, I2, I3, c, gx, gy, gz, cv, T0 = _params(S, i, uni, pp)
        iI1, iI2, iI3, icv, iT0 = _recips(S, i, uni, pv)
        u0, u1, u2, u3, u4, u5, u6 = _load7(S, O_TMP, i)
        k0, k1, k2, k3, k4, k5, k6, small = _rhs7(
            u0, u1, u2, u3, u4, u5, u6, I1, I2, I3, c, gx, gy, gz, iI1, iI2, iI3, icv, iT0)
        S[O_ACC + i] = S[O_ACC + i] + 2.0 * k0
        S[O_ACC + B1 + i] = S[O_ACC + B1 + i] + 2.0 * k1
        S[O_ACC + 2 * B1 + i] = S[O_ACC + 2 * B1 + i] + 2.0 * k2
        S[O_ACC + 3 * B1 + i] = S[O_ACC + 3 * B1 + i] + 2.0 * k3
        S[O_ACC + 4 * B1 + i] = S[O_ACC + 4 * B1 + i] + 2.0 * k4
        S[O_ACC + 5 * B1 + i] = S[O_ACC + 5 * B1 + i] + 2.0 * k5
        S[O_ACC + 6 * B1 + i] = S[O_ACC + 6 * B1 + i] + 2.0 * k6
        S[O_TMP + i] = S[O_Y + i] + a * k0
        S[O_TMP + B1 + i] = S[O_Y + B1 + i] + a * k1
        S[O_TMP + 2 * B1 + i] = S[O_Y + 2 * B1 + i] + a * k2
        S[O_TMP + 3 * B1 + i] = S[O_Y + 3 * B1 + i] + a * k3
        S[O_TMP + 4 * B1 + i] = S[O_Y + 4 * B1 + i] + a * k4
        S[O_TMP + 5 * B1 + i] = S[O_Y + 5 * B1 + i] + a * k5
        S[O_TMP + 6 * B1 + i] = S[O_Y + 6 * B1 + i] + a * k6
        fl = S[O_FLAG + i]
        S[O_FLAG + i] = fl if small else FLAG_EXACT


@jit
def _rk_last(S, nb, h, rk4, uni, pp, pv):
    """k = f(tmp); y_new = y + h k (RK2) or y + h(acc + k)·(1/6) (RK4).  A lane
    is updated only if y_new is finite and no exp argument was out of range;
    otherwise y is left as it was and R_FLAG says why (FLAG_NONFINITE or
    FLAG_EXACT).  Returns the number of flagged lanes."""
    nflag = 0
    for i in range(nb):
        I1, I2, I3, c, gx, gy, gz, cv, T0 = _params(S, i, uni, pp)
        iI1, iI2, iI3, icv, iT0 = _recips(S, i, uni, pv)
        u0, u1, u2, u3, u4, u5, u6 = _load7(S, O_TMP, i)
        k0, k1, k2, k3, k4, k5, k6, small = _rhs7(
            u0, u1, u2, u3, u4, u5, u6, I1, I2, I3, c, gx, gy, gz, iI1, iI2, iI3, icv, iT0)
        y0, y1, y2, y3, y4, y5, y6 = _load7(S, O_Y, i)
        if rk4:
            n0 = y0 + h * (S[O_ACC + i] + k0) * (1.0 / 6.0)
            n1 = y1 + h * (S[O_ACC + B1 + i] + k1) * (1.0 / 6.0)
            n2 = y2 + h * (S[O_ACC + 2 * B1 + i] + k2) * (1.0 / 6.0)
            n3 = y3 + h * (S[O_ACC + 3 * B1 + i] + k3) * (1.0 / 6.0)
            n4 = y4 + h * (S[O_ACC + 4 * B1 + i] + k4) * (1.0 / 6.0)
            n5 = y5 + h * (S[O_ACC + 5 * B1 + i] + k5) * (1.0 / 6.0)
            n6 = y6 + h * (S[O_ACC + 6 * B1 + i] + k6) * (1.0 / 6.0)
        else:
            n0 = y0 + h * k0
            n1 = y1 + h * k1
            n2 = y2 + h * k2
            n3 = y3 + h * k3
            n4 = y4 + h * k4
            n5 = y5 + h * k5
            n6 = y6 + h * k6
        small = small & (S[O_FLAG + i] == FLAG_OK)
        fin = (_finite(n0) & _finite(n1) & _finite(n2) & _finite(n3) & _finite(n4)
               & _finite(n5) & _finite(n6))
        upd = fin & small
        S[O_Y + i] = n0 if upd else y0
        S[O_Y + B1 + i] = n1 if upd else y1
        S[O_Y + 2 * B1 + i] = n2 if upd else y2
        S[O_Y + 3 * B1 + i] = n3 if upd else y3
        S[O_Y + 4 * B1 + i] = n4 if upd else y4
        S[O_Y + 5 * B1 + i] = n5 if upd else y5
        S[O_Y + 6 * B1 + i] = n6 if upd else y6
        S[O_FLAG + i] = FLAG_OK if upd else (FLAG_NONFINITE if small else FLAG_EXACT)
        nflag += 0 if upd else 1
    return nflag


@jit
def _rk_sweep(S, nb, h, rk4, uni, pp, pv):
    """One RK2 (rk4=False) or RK4 step of lanes [0, nb), in place (see
    _rk_last for the flags).  Returns the number of flagged lanes."""
    _rk_first(S, nb, h, rk4, uni, pp, pv)
    if rk4:
        _rk4_mid(S, nb, 0.5 * h, uni, pp, pv)
        _rk4_mid(S, nb, h, uni, pp, pv)
    return _rk_last(S, nb, h, rk4, uni, pp, pv)


@jit
def _rk_lane_exact(S, i, n, h, rk4, y, p, work, ynew):
    """Step lane i with the straightforward code (rk.rk2_step / rk4_step):
    sets R_FLAG to FLAG_OK (state updated) or FLAG_NONFINITE."""
    for k in range(n):
        y[k] = S[O_Y + k * B1 + i]
    for k in range(9):
        p[k] = S[O_P + k * B1 + i]
    if rk4:
        rk4_step(y, p, h, n, work, ynew)
    else:
        rk2_step(y, p, h, n, work, ynew)
    for k in range(n):
        if not np.isfinite(ynew[k]):
            S[O_FLAG + i] = FLAG_NONFINITE
            return
    for k in range(n):
        S[O_Y + k * B1 + i] = ynew[k]
    S[O_FLAG + i] = FLAG_OK


@jit
def _hw_sweep(S, nb, h):
    """max h|Ω_k| update alone (for the scalar RK path)."""
    for i in range(nb):
        y0 = S[O_Y + i]
        y1 = S[O_Y + B1 + i]
        y2 = S[O_Y + 2 * B1 + i]
        hw = h * np.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        hm = S[O_HW + i]
        S[O_HW + i] = hw if hw > hm else hm


# --------------------------------------------------------------------------
# variational integrator sweeps


@jit
def _vi_prepare(S, nb, h, ih, beta, uni, pp, pv):
    """Per lane: max h|Ω_k|, Γ_{k+1} (Cayley), σ_{k+1}, b, predictor X,
    |Ω_k|∞, and resets the Newton mask.  Returns the number of lanes whose
    exp argument needs math.exp (R_FLAG = FLAG_EXACT)."""
    nexact = 0
    for i in range(nb):
        I1, I2, I3, c, gx, gy, gz, cv, T0 = _params(S, i, uni, pp)
        iI1, iI2, iI3, icv, iT0 = _recips(S, i, uni, pv)
        w0 = S[O_Y + i]
        w1 = S[O_Y + B1 + i]
        w2 = S[O_Y + 2 * B1 + i]
        v0 = S[O_Y + 3 * B1 + i]
        v1 = S[O_Y + 4 * B1 + i]
        v2 = S[O_Y + 5 * B1 + i]
        sg = S[O_Y + 6 * B1 + i]
        hw = h * np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        hm = S[O_HW + i]
        S[O_HW + i] = hw if hw > hm else hm
        # so3.cayley_apply(w = −hΩ_k, Γ_k)
        u0 = -h * w0
        u1 = -h * w1
        u2 = -h * w2
        s = 4.0 / (4.0 + (u0 * u0 + u1 * u1 + u2 * u2))
        t0 = u1 * v2 - u2 * v1
        t1 = u2 * v0 - u0 * v2
        t2 = u0 * v1 - u1 * v0
        q0 = u1 * t2 - u2 * t1
        q1 = u2 * t0 - u0 * t2
        q2 = u0 * t1 - u1 * t0
        G0 = v0 + s * (t0 + 0.5 * q0)
        G1 = v1 + s * (t1 + 0.5 * q1)
        G2 = v2 + s * (t2 + 0.5 * q2)
        S[O_GN + i] = G0
        S[O_GN + B1 + i] = G1
        S[O_GN + 2 * B1 + i] = G2
        # explicit entropy update
        x = -(sg * icv)  # model.inverse_temperature
        small = abs(x) <= EXP_SMALL
        S[O_SN + i] = sg + h * c * (w0 * w0 + w1 * w1 + w2 * w2) * (_exp_small(x) * iT0)
        S[O_FLAG + i] = FLAG_OK if small else FLAG_EXACT
        nexact += 0 if small else 1
        # vi.momentum_constant
        P0 = I1 * w0
        P1 = I2 * w1
        P2 = I3 * w2
        wP = w0 * P0 + w1 * P1 + w2 * P2
        r0 = G1 * gz - G2 * gy
        r1 = G2 * gx - G0 * gz
        r2 = G0 * gy - G1 * gx
        S[O_B + i] = -P0 * ih + 0.5 * (w1 * P2 - w2 * P1) - 0.25 * h * wP * w0 - r0 + beta * c * w0
        S[O_B + B1 + i] = -P1 * ih + 0.5 * (w2 * P0 - w0 * P2) - 0.25 * h * wP * w1 - r1 + beta * c * w1
        S[O_B + 2 * B1 + i] = -P2 * ih + 0.5 * (w0 * P1 - w1 * P0) - 0.25 * h * wP * w2 - r2 + beta * c * w2
        # vi.predictor
        S[O_X + i] = w0 + h * ((P1 * w2 - P2 * w1) - c * w0 + (G1 * gz - G2 * gy)) * iI1
        S[O_X + B1 + i] = w1 + h * ((P2 * w0 - P0 * w2) - c * w1 + (G2 * gx - G0 * gz)) * iI2
        S[O_X + 2 * B1 + i] = w2 + h * ((P0 * w1 - P1 * w0) - c * w2 + (G0 * gy - G1 * gx)) * iI3
        S[O_SC0 + i] = max(abs(w0), abs(w1), abs(w2))
        S[O_RUN + i] = 1.0
        S[O_CODE + i] = NEWTON_MAXITER
        S[O_ITS + i] = 0.0
    return nexact


@jit
def _vi_sigma_exact(S, nb, h):
    """σ_{k+1} with math.exp (vi.vi_step's own expression) for FLAG_EXACT lanes."""
    for i in range(nb):
        if S[O_FLAG + i] != FLAG_EXACT:
            continue
        w0 = S[O_Y + i]
        w1 = S[O_Y + B1 + i]
        w2 = S[O_Y + 2 * B1 + i]
        sg = S[O_Y + 6 * B1 + i]
        c = S[O_P + 3 * B1 + i]
        iT = math.exp(-(sg * (1.0 / S[O_P + 7 * B1 + i]))) * (1.0 / S[O_P + 8 * B1 + i])
        S[O_SN + i] = sg + h * c * (w0 ** 2 + w1 ** 2 + w2 ** 2) * iT
        S[O_FLAG + i] = FLAG_OK


@jit
def _vi_attitude(S, nb, h):
    """R_{k+1} = R_k cay(hΩ̂_k) (so3.attitude_update, same operations)."""
    for i in range(nb):
        w0 = -(-h * S[O_Y + i])
        w1 = -(-h * S[O_Y + B1 + i])
        w2 = -(-h * S[O_Y + 2 * B1 + i])
        s = 4.0 / (4.0 + (w0 * w0 + w1 * w1 + w2 * w2))
        ww = w0 * w0 + w1 * w1 + w2 * w2
        sh = s * 0.5
        C00 = 1.0 + sh * (w0 * w0 - ww)
        C01 = 0.0 + sh * (w0 * w1 - 0.0)
        C02 = 0.0 + sh * (w0 * w2 - 0.0)
        C10 = 0.0 + sh * (w1 * w0 - 0.0)
        C11 = 1.0 + sh * (w1 * w1 - ww)
        C12 = 0.0 + sh * (w1 * w2 - 0.0)
        C20 = 0.0 + sh * (w2 * w0 - 0.0)
        C21 = 0.0 + sh * (w2 * w1 - 0.0)
        C22 = 1.0 + sh * (w2 * w2 - ww)
        C01 += -s * w2
        C02 += s * w1
        C10 += s * w2
        C12 += -s * w0
        C20 += -s * w1
        C21 += s * w0
        for r in range(3):
            Ra = S[O_Y + (7 + 3 * r) * B1 + i]
            Rb = S[O_Y + (8 + 3 * r) * B1 + i]
            Rc = S[O_Y + (9 + 3 * r) * B1 + i]
            S[O_RN + (3 * r) * B1 + i] = Ra * C00 + Rb * C10 + Rc * C20
            S[O_RN + (3 * r + 1) * B1 + i] = Ra * C01 + Rb * C11 + Rc * C21
            S[O_RN + (3 * r + 2) * B1 + i] = Ra * C02 + Rb * C12 + Rc * C22


@jit(inline="always")
def _invariants(S, i, uni, pq):
    """(I₁·(1/h), I₂·(1/h), I₃·(1/h), αc) of lane i: pq when the block is uniform."""
    if uni:
        return pq
    return S[O_IH + i], S[O_IH + B1 + i], S[O_IH + 2 * B1 + i], S[O_AC + i]


@jit
def _newton_sweep(S, nb, h, ih, tol, it, uni, pp, pq):
    """Newton iteration number ``it`` on every lane whose mask is set
    (vi.newton_momentum's stopping rules, per lane).  Returns the number of
    lanes still running."""
    nrun = 0
    for i in range(nb):
        run = S[O_RUN + i] != 0.0
        x0 = S[O_X + i]
        x1 = S[O_X + B1 + i]
        x2 = S[O_X + 2 * B1 + i]
        I1, I2, I3, c, gx, gy, gz, cv, T0 = _params(S, i, uni, pp)
        Ih0, Ih1, Ih2, ac = _invariants(S, i, uni, pq)
        d0, d1, d2, det = _newton_iter(
            x0, x1, x2, S[O_B + i], S[O_B + B1 + i], S[O_B + 2 * B1 + i],
            I1, I2, I3, Ih0, Ih1, Ih2, ac, h, ih)
        sing = (det == 0.0) | (not _finite(det))
        n0 = x0 - d0
        n1 = x1 - d1
        n2 = x2 - d2
        step = max(abs(d0), abs(d1), abs(d2))
        scale = max(abs(n0), abs(n1), abs(n2), S[O_SC0 + i])
        nanstep = not (step == step)
        conv = step <= tol * scale
        move = run & (not sing)
        S[O_X + i] = n0 if move else x0
        S[O_X + B1 + i] = n1 if move else x1
        S[O_X + 2 * B1 + i] = n2 if move else x2
        bad = sing | nanstep
        code = S[O_CODE + i]
        code = NEWTON_SINGULAR if bad else (NEWTON_OK if conv else code)
        S[O_CODE + i] = code if run else S[O_CODE + i]
        S[O_ITS + i] = it if run else S[O_ITS + i]
        still = run & (not bad) & (not conv)
        S[O_RUN + i] = 1.0 if still else 0.0
        nrun += 1 if still else 0
    return nrun


@jit
def _newton_lane(S, i, h, ih, tol, it0, maxiter):
    """Finish lane i's Newton iteration from iteration it0 on, in scalar code
    (same operations as _newton_sweep / vi.newton_momentum)."""
    x0 = S[O_X + i]
    x1 = S[O_X + B1 + i]
    x2 = S[O_X + 2 * B1 + i]
    b0 = S[O_B + i]
    b1 = S[O_B + B1 + i]
    b2 = S[O_B + 2 * B1 + i]
    I1 = S[O_P + i]
    I2 = S[O_P + B1 + i]
    I3 = S[O_P + 2 * B1 + i]
    Ih0 = S[O_IH + i]
    Ih1 = S[O_IH + B1 + i]
    Ih2 = S[O_IH + 2 * B1 + i]
    ac = S[O_AC + i]
    scale0 = S[O_SC0 + i]
    code = NEWTON_MAXITER
    its = maxiter
    for it in range(it0, maxiter + 1):
        d0, d1, d2, det = _newton_iter(x0, x1, x2, b0, b1, b2, I1, I2, I3, Ih0, Ih1, Ih2, ac, h,
                                     ih)
        if det == 0.0 or not np.isfinite(det):
            code = NEWTON_SINGULAR
            its = it
            break
        x0 -= d0
        x1 -= d1
        x2 -= d2
        step = max(abs(d0), abs(d1), abs(d2))
        scale = max(abs(x0), abs(x1), abs(x2), scale0)
        if not (step == step):
            code = NEWTON_SINGULAR
            its = it
            break
        if step <= tol * scale:
            code = NEWTON_OK
            its = it
            break
    S[O_X + i] = x0
    S[O_X + B1 + i] = x1
    S[O_X + 2 * B1 + i] = x2
    S[O_CODE + i] = code
    S[O_ITS + i] = its
    S[O_RUN + i] = 0.0


@jit
def _vi_commit(S, nb):
    """Accept the step where Newton converged and the new state is finite;
    accumulate Newton statistics; flag failures.  Returns the number of
    failed lanes."""
    nfail = 0
    for i in range(nb):
        its = S[O_ITS + i]
        S[O_NTOT + i] += its
        nm = S[O_NMAX + i]
        S[O_NMAX + i] = its if its > nm else nm
        n0 = S[O_X + i]
        n1 = S[O_X + B1 + i]
        n2 = S[O_X + 2 * B1 + i]
        n3 = S[O_GN + i]
        n4 = S[O_GN + B1 + i]
        n5 = S[O_GN + 2 * B1 + i]
        n6 = S[O_SN + i]
        conv = S[O_CODE + i] == NEWTON_OK
        fin = (_finite(n0) & _finite(n1) & _finite(n2) & _finite(n3) & _finite(n4)
               & _finite(n5) & _finite(n6) & (S[O_FLAG + i] == FLAG_OK))
        upd = conv & fin
        S[O_Y + i] = n0 if upd else S[O_Y + i]
        S[O_Y + B1 + i] = n1 if upd else S[O_Y + B1 + i]
        S[O_Y + 2 * B1 + i] = n2 if upd else S[O_Y + 2 * B1 + i]
        S[O_Y + 3 * B1 + i] = n3 if upd else S[O_Y + 3 * B1 + i]
        S[O_Y + 4 * B1 + i] = n4 if upd else S[O_Y + 4 * B1 + i]
        S[O_Y + 5 * B1 + i] = n5 if upd else S[O_Y + 5 * B1 + i]
        S[O_Y + 6 * B1 + i] = n6 if upd else S[O_Y + 6 * B1 + i]
        S[O_FLAG + i] = FLAG_OK if upd else (FLAG_NONFINITE if conv else FLAG_NEWTON)
        nfail += 0 if upd else 1
    return nfail


@jit
def _vi_attitude_check(S, nb):
    """Before _vi_commit (16-wide state): a non-finite R_{k+1} flags the lane."""
    for i in range(nb):
        fin = True
        for k in range(9):
            fin = fin & _finite(S[O_RN + k * B1 + i])
        S[O_FLAG + i] = S[O_FLAG + i] if fin else FLAG_NONFINITE


@jit
def _vi_attitude_commit(S, nb):
    """After _vi_commit: R_k ← R_{k+1} on the lanes that stepped."""
    for i in range(nb):
        ok = S[O_FLAG + i] == FLAG_OK
        for k in range(9):
            S[O_Y + (7 + k) * B1 + i] = S[O_RN + k * B1 + i] if ok else S[O_Y + (7 + k) * B1 + i]


@jit
def _vi_step_block(S, nb, n, h, ih, beta, tol, maxiter, uni, pp, pv, pq):
    """One VI step of lanes [0, nb).  Returns the number of failed lanes
    (R_FLAG = FLAG_NEWTON or FLAG_NONFINITE); the others have stepped."""
    nexact = _vi_prepare(S, nb, h, ih, beta, uni, pp, pv)
    if nexact:
        _vi_sigma_exact(S, nb, h)
    if n > NSTATE_BASE:
        _vi_attitude(S, nb, h)
    it = np.int64(1)  # np.int64: no Literal[int] overloads of the callees
    while it <= maxiter:
        nrun = _newton_sweep(S, nb, h, ih, tol, it, uni, pp, pq)
        if nrun == 0:
            break
        if nrun <= NEWTON_FALLBACK and it < maxiter:
            for i in range(nb):
                if S[O_RUN + i] != 0.0:
                    _newton_lane(S, i, h, ih, tol, it + 1, maxiter)
            break
        it += 1
    if n > NSTATE_BASE:
        # the flag must also see R, but Newton failure takes precedence
        _vi_attitude_check(S, nb)
    nfail = _vi_commit(S, nb)
    if n > NSTATE_BASE:
        _vi_attitude_commit(S, nb)
    return nfail


# --------------------------------------------------------------------------
# the block driver


@jit
def _retire(S, i, nb, n, done, Y, ISTAT, FSTAT):
    """Write failed lane i back (status, failing step, statistics; the state
    is the last accepted one) and move lane nb−1 into its place."""
    m = int(S[O_MEMBER + i])
    for k in range(n):
        Y[m, k] = S[O_Y + k * B1 + i]
    flag = S[O_FLAG + i]
    ISTAT[m, IS_STATUS] = STATUS_NEWTON if flag == FLAG_NEWTON else STATUS_NONFINITE
    steps = int(S[O_STEPS + i]) + done
    ISTAT[m, IS_FAIL_STEP] = steps + 1
    ISTAT[m, IS_STEPS] = steps
    ISTAT[m, IS_NEWTON_TOTAL] = int(S[O_NTOT + i])
    ISTAT[m, IS_NEWTON_MAX] = int(S[O_NMAX + i])
    FSTAT[m, FS_MAX_H_OMEGA] = S[O_HW + i]
    last = nb - 1
    if i != last:
        for r in range(NROWS):
            S[r * B1 + i] = S[r * B1 + last]


@jit
def _uniform(S, nb):
    """True if all lanes have bitwise the same parameters as lane 0."""
    for k in range(9):
        a = S[O_P + k * B1]
        sa = math.copysign(1.0, a)
        for i in range(1, nb):
            b = S[O_P + k * B1 + i]
            if not (a == b and sa == math.copysign(1.0, b)):
                return False
    return True


@jit
def _advance_block(method, Y, P, m0, m1, h, every, n_out, alpha, beta, tol, maxiter,
                   OUT, ISTAT, FSTAT):
    n = Y.shape[1]
    S = np.zeros(NROWS * BLOCK)
    nb = np.int64(0)  # np.int64: no Literal[int] overloads of the callees
    for m in range(m0, m1):
        if ISTAT[m, IS_STATUS] != STATUS_OK:
            continue
        for k in range(n):
            S[O_Y + k * B1 + nb] = Y[m, k]
        for k in range(9):
            S[O_P + k * B1 + nb] = P[m, k]
        S[O_HW + nb] = FSTAT[m, FS_MAX_H_OMEGA]
        S[O_NTOT + nb] = ISTAT[m, IS_NEWTON_TOTAL]
        S[O_NMAX + nb] = ISTAT[m, IS_NEWTON_MAX]
        S[O_STEPS + nb] = ISTAT[m, IS_STEPS]
        S[O_MEMBER + nb] = m
        nb += 1
    if nb == 0:
        return
    # loop invariants: the kernels' only divisions by parameters and h, done
    # once per call (the simple kernel's 1.0/x gives the same bits)
    ih = 1.0 / h
    for i in range(nb):
        S[O_IH + i] = S[O_P + i] * ih
        S[O_IH + B1 + i] = S[O_P + B1 + i] * ih
        S[O_IH + 2 * B1 + i] = S[O_P + 2 * B1 + i] * ih
        S[O_AC + i] = alpha * S[O_P + 3 * B1 + i]
        S[O_INV + i] = 1.0 / S[O_P + i]
        S[O_INV + B1 + i] = 1.0 / S[O_P + B1 + i]
        S[O_INV + 2 * B1 + i] = 1.0 / S[O_P + 2 * B1 + i]
        S[O_INV + 3 * B1 + i] = 1.0 / S[O_P + 7 * B1 + i]
        S[O_INV + 4 * B1 + i] = 1.0 / S[O_P + 8 * B1 + i]
    uni = _uniform(S, nb)
    pp = _load_params(S, 0)
    pv = _load_recips(S, 0)
    pq = (S[O_IH], S[O_IH + B1], S[O_IH + 2 * B1], S[O_AC])
    rk4 = method == METHOD_RK4
    vec_rk = n == NSTATE_BASE
    y = np.empty(n)
    p = np.empty(9)
    work = np.empty((DOP853_STAGES, n))
    ynew = np.empty(n)
    done = np.int64(0)
    for j in range(n_out):
        for _ in range(every):
            if method == METHOD_VI:
                nfail = _vi_step_block(S, nb, n, h, ih, beta, tol, maxiter, uni, pp, pv, pq)
            elif vec_rk:
                nfail = _rk_sweep(S, nb, h, rk4, uni, pp, pv)
                if nfail:
                    for i in range(nb):
                        if S[O_FLAG + i] == FLAG_EXACT:
                            _rk_lane_exact(S, i, n, h, rk4, y, p, work, ynew)
                    nfail = 0
                    for i in range(nb):
                        nfail += S[O_FLAG + i] != FLAG_OK
            else:
                _hw_sweep(S, nb, h)
                nfail = 0
                for i in range(nb):
                    _rk_lane_exact(S, i, n, h, rk4, y, p, work, ynew)
                    nfail += S[O_FLAG + i] != FLAG_OK
            if nfail:
                i = np.int64(0)
                while i < nb:
                    if S[O_FLAG + i] != FLAG_OK:
                        _retire(S, i, nb, n, done, Y, ISTAT, FSTAT)
                        nb -= 1
                    else:
                        i += 1
                if nb == 0:
                    return
            done += 1
        for i in range(nb):
            m = int(S[O_MEMBER + i])
            for k in range(n):
                OUT[m, j, k] = S[O_Y + k * B1 + i]
    for i in range(nb):
        m = int(S[O_MEMBER + i])
        for k in range(n):
            Y[m, k] = S[O_Y + k * B1 + i]
        ISTAT[m, IS_STEPS] = int(S[O_STEPS + i]) + done
        ISTAT[m, IS_NEWTON_TOTAL] = int(S[O_NTOT + i])
        ISTAT[m, IS_NEWTON_MAX] = int(S[O_NMAX + i])
        FSTAT[m, FS_MAX_H_OMEGA] = S[O_HW + i]


@pjit
def advance_ensemble_fast(method, Y, P, h, every, n_out, alpha, beta, tol, maxiter,
                          nsub, A, B, OUT, ISTAT, FSTAT):
    """Same contract and results as ensemble.advance_ensemble (see module
    docstring); VI, RK2 and RK4 run in vectorized blocks of BLOCK members."""
    N, n = Y.shape
    if method == METHOD_VI or method == METHOD_RK2 or method == METHOD_RK4:
        nblocks = (N + BLOCK - 1) // BLOCK
        for bi in prange(nblocks):
            m0 = bi * BLOCK
            m1 = min(N, m0 + BLOCK)
            _advance_block(method, Y, P, m0, m1, h, every, n_out, alpha, beta, tol,
                           maxiter, OUT, ISTAT, FSTAT)
    else:
        for m in prange(N):
            advance_member(method, Y[m], P[m], h, n, every, n_out, alpha, beta, tol,
                           maxiter, nsub, A, B, OUT[m], ISTAT[m], FSTAT[m])
