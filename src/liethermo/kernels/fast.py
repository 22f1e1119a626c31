"""Fast ensemble kernel: structure-of-arrays blocks that LLVM vectorizes.

:func:`advance_ensemble_fast` has the contract of
:func:`liethermo.kernels.ensemble.advance_ensemble` (same arguments, same
in-place arrays ``Y, P, OUT, ISTAT, FSTAT``, same status codes) and computes
the same numbers: both kernels evaluate a step through the same inline lane
functions (model.rhs7_lane*, vi.*_lane, so3.*_lane, rk.rk4_combine), whose
explicit fused multiply-adds fix every rounding, so results agree bitwise —
states, status flags, failing steps, Newton iteration counts and max h|Ω|.

How it is fast
--------------
* ``prange`` runs over blocks of ``BLOCK`` members.  A block copies its
  members into one flat buffer, row by row (structure of arrays: row r holds
  quantity r of every lane), advances them for the whole call, and copies
  them back.  Every row sits at a compile-time offset of the same buffer, so
  LLVM sees no possible aliasing and vectorizes the loops over lanes
  (packed ``vfmadd…pd``/``vmulpd``/``vaddpd`` on ymm or zmm registers).
* Two versions of the block kernel, chosen once per call
  (:func:`shared_params`): when all members share their parameters (a
  random ensemble of one scene) the coefficients are tuples that live in
  registers; else each lane reads its own coefficient rows.  The choice is
  not made per lane: LLVM does not unswitch loops this big, and loaded the
  rows under a mask in every iteration.
* An explicit RK step is one sweep over the lanes: all stages of a lane stay
  in registers, only the state is loaded and stored, from one state buffer
  to the other (R_Y → R_YB → R_Y …) with plain stores; a flagged lane still
  has its old state in the source buffer.  The max of h|Ω_k| is
  kept as the max of |Ω_k|² (h·sqrt is monotone: same value, one square root
  per call instead of per step).
* The VI's Newton iterations run in lock-step over the block with a per-lane
  convergence mask: a converged lane keeps its X, and the block stops
  iterating as soon as no lane runs.  Once only a few lanes still run
  (``NEWTON_COMPACT``), they are copied to the first lanes of a scratch
  buffer and finish there, so one slow or diverging member does not hold
  the whole block.
* No lane store is conditional.  A store of "new if c else the row's own
  value" becomes a masked store (``vmaskmovpd``) in LLVM's x86 back end,
  slow microcode on AMD Zen 3; the sweeps store unconditionally (exact
  arithmetic blends, ``_jit.select``, the RK double buffer), and the VI
  accepts a step only after its failed lanes are retired (``_vi_check``,
  then ``_vi_accept``).  ``liethermo bench --asm`` counts masked
  instructions; the tests require none in the lane loops.
* A failed member (Newton failure or non-finite state) is written back at
  once and its lane is filled with the block's last lane (compaction), so
  dead members cost nothing — explicit RK2 loses most of the random paper
  ensemble within ~100 steps — and never touch their neighbours' values.
* exp(−σ/c_v) is the inline cubic of ``model.sigma_rate_poly`` in the
  sweeps; a lane whose |σ/c_v| is beyond ``EXP_SMALL`` (or not finite) is
  flagged and recomputed with the straightforward kernel's own operations
  (``math.exp``; for RK lanes in registers with the block's coefficients).
* Explicit RK steps *with* the attitude (16-wide state) and the
  ``reference`` method are not vectorized: they run the straightforward
  per-member code (the RK ones inside the block structure).

Buffers are allocated per block (not per step); nothing is compiled at
import time.  The ``reference`` method goes to the straightforward kernel.
"""

from __future__ import annotations

import numpy as np

from ._jit import fma, jit, pjit, prange, select
from .ensemble import (
    FS_MAX_H_OMEGA,
    IS_FAIL_STEP,
    IS_NEWTON_MAX,
    IS_NEWTON_TOTAL,
    IS_STATUS,
    IS_STEPS,
    METHOD_RK2,
    METHOD_RK4,
    METHOD_VI,
    STATUS_NEWTON,
    STATUS_NONFINITE,
    STATUS_OK,
    advance_ensemble,
)
from .model import (EXP_SMALL, NCOEF, NSTATE_BASE, coefficients, rhs7_lane, rhs7_lane_poly,
                    sigma_rate_exact, sigma_rate_poly)
from .rk import DOP853_STAGES, rk2_step, rk4_step, rk4_sum
from .so3 import cayley_lane, cayley_matrix_lane, row_times_lane
from .vi import (
    NEWTON_MAXITER,
    NEWTON_OK,
    NEWTON_SINGULAR,
    NVCOEF,
    momentum_constant_lane,
    newton_lane,
    newton_stop,
    predictor_lane,
    vi_coefficients,
)

__all__ = ["advance_ensemble_fast", "BLOCK", "EXP_SMALL"]

#: members per block (lanes); a block's buffer is NROWS·ROW doubles
BLOCK = 128
#: row stride of the block buffer (doubles): BLOCK plus a pad, so that the
#: rows of one lane do not all fall into a few cache sets (a stride of 1 KiB
#: maps lane i of every row into 4 of the L1's 64 sets)
ROW = BLOCK + 8
#: when at most this many lanes of a block still iterate, they finish on a compact copy
NEWTON_COMPACT = BLOCK // 4

# Rows of the per-block buffer; lane i of row r is buf[r*ROW + i].
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
R_HW = 39  # max h|Ω_k| at entry (FSTAT)
R_NTOT = 40  # Newton iterations, total (ISTAT)
R_NMAX = 41  # Newton iterations, max per step (ISTAT)
R_STEPS = 42  # steps done at entry (ISTAT)
R_MEMBER = 43  # member index of the lane
R_FLAG = 44  # per-step outcome: 0 ok, else what to do (see sweeps)
R_RN = 45  # 9 rows: R_{k+1} (VI with attitude)
R_W2 = 54  # max |Ω_k|² over the steps of this call
R_Q = 55  # NCOEF rows: model.coefficients
R_V = R_Q + NCOEF  # NVCOEF rows: vi.vi_coefficients
NROWS = R_V + NVCOEF
# 7 rows: the other state buffer of the vectorized RK steps, in rows only the
# VI uses (Γ_{k+1}, σ_{k+1}, X): a block runs one method
R_YB = R_GN

# offsets (compile-time constants inside the kernels)
O_Y = R_Y * ROW
O_P = R_P * ROW
O_GN = R_GN * ROW
O_SN = R_SN * ROW
O_X = R_X * ROW
O_B = R_B * ROW
O_SC0 = R_SC0 * ROW
O_RUN = R_RUN * ROW
O_CODE = R_CODE * ROW
O_ITS = R_ITS * ROW
O_HW = R_HW * ROW
O_NTOT = R_NTOT * ROW
O_NMAX = R_NMAX * ROW
O_STEPS = R_STEPS * ROW
O_MEMBER = R_MEMBER * ROW
O_FLAG = R_FLAG * ROW
O_RN = R_RN * ROW
O_W2 = R_W2 * ROW
O_Q = R_Q * ROW
O_V = R_V * ROW
O_YB = R_YB * ROW
B1 = ROW  # row stride

# per-step outcome flags (R_FLAG)
FLAG_OK = 0.0
FLAG_NEWTON = 1.0  # Newton failed: STATUS_NEWTON
FLAG_NONFINITE = 2.0  # STATUS_NONFINITE
FLAG_EXACT = 3.0  # exp argument outside EXP_SMALL: redo with math.exp


# --------------------------------------------------------------------------
# loads


@jit(inline="always")
def _finite(x):
    return x - x == 0.0


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
def _store7(S, off, i, a0, a1, a2, a3, a4, a5, a6):
    S[off + i] = a0
    S[off + B1 + i] = a1
    S[off + 2 * B1 + i] = a2
    S[off + 3 * B1 + i] = a3
    S[off + 4 * B1 + i] = a4
    S[off + 5 * B1 + i] = a5
    S[off + 6 * B1 + i] = a6


@jit(inline="always")
def _rows_q(S, i):
    return (S[O_Q + i], S[O_Q + B1 + i], S[O_Q + 2 * B1 + i], S[O_Q + 3 * B1 + i],
            S[O_Q + 4 * B1 + i], S[O_Q + 5 * B1 + i], S[O_Q + 6 * B1 + i],
            S[O_Q + 7 * B1 + i], S[O_Q + 8 * B1 + i], S[O_Q + 9 * B1 + i],
            S[O_Q + 10 * B1 + i], S[O_Q + 11 * B1 + i], S[O_Q + 12 * B1 + i],
            S[O_Q + 13 * B1 + i], S[O_Q + 14 * B1 + i], S[O_Q + 15 * B1 + i],
            S[O_Q + 16 * B1 + i], S[O_Q + 17 * B1 + i])


@jit(inline="always")
def _rows_v(S, i):
    return (S[O_V + i], S[O_V + B1 + i], S[O_V + 2 * B1 + i], S[O_V + 3 * B1 + i],
            S[O_V + 4 * B1 + i], S[O_V + 5 * B1 + i], S[O_V + 6 * B1 + i],
            S[O_V + 7 * B1 + i], S[O_V + 8 * B1 + i], S[O_V + 9 * B1 + i],
            S[O_V + 10 * B1 + i], S[O_V + 11 * B1 + i], S[O_V + 12 * B1 + i],
            S[O_V + 13 * B1 + i], S[O_V + 14 * B1 + i], S[O_V + 15 * B1 + i],
            S[O_V + 16 * B1 + i])


@jit(inline="always")
def _track_w2(S, i, y0, y1, y2, down):
    """Running max (min when h < 0: ``down``) of |Ω_k|², the simple kernel's
    expression under its sqrt.  Row R_W2 starts at −1 (+inf when down): no
    step yet."""
    ww = y0 * y0 + y1 * y1 + y2 * y2
    # + 0.0 is exact here (the row never holds −0: it holds −1, +inf or a sum of
    # squares) and keeps the store unconditional: see _newton_sweep
    m = S[O_W2 + i] + 0.0
    upd = (ww < m) if down else (ww > m)
    S[O_W2 + i] = select(upd, ww, m)


# --------------------------------------------------------------------------
# explicit Runge–Kutta sweeps (7-wide state): one sweep per step.  A lane
# is updated only if its new state is finite and no exp argument was out of
# range; otherwise y is left as it was and R_FLAG = FLAG_EXACT sends it to
# the straightforward code (_rk_lane_exact), which steps it or flags it
# FLAG_NONFINITE.  They return the number of flagged lanes.


@jit(inline="always")
def _rk_store(S, i, dst, small, hf, y0, y1, y2, y3, y4, y5, y6, k0, k1, k2, k3, k4, k5, k6):
    """Lane i's new state y + hf·k goes to the rows at dst, unconditionally;
    R_FLAG says whether it holds (finite and ``small``) or the lane must be
    redone from its old state (FLAG_EXACT).  Returns 1 if flagged."""
    n0 = fma(hf, k0, y0)
    n1 = fma(hf, k1, y1)
    n2 = fma(hf, k2, y2)
    n3 = fma(hf, k3, y3)
    n4 = fma(hf, k4, y4)
    n5 = fma(hf, k5, y5)
    n6 = fma(hf, k6, y6)
    # one test for all seven: their sum is finite if they all are; if it is
    # not (a component is inf/NaN, or a finite sum overflowed), the lane is
    # redone by the straightforward code, which decides exactly
    upd = _finite(((n0 + n1) + (n2 + n3)) + ((n4 + n5) + n6)) & small
    _store7(S, dst, i, n0, n1, n2, n3, n4, n5, n6)
    S[O_FLAG + i] = select(upd, FLAG_OK, FLAG_EXACT)
    return 0 if upd else 1


@jit(inline="always")
def _rk_buffers(flip):
    """(source, destination) offsets of a vectorized RK step.  The new state
    goes to the other buffer with plain stores: a lane that must keep its old
    state (flagged) still has it in the source.  A store of "new or the row's
    own value" would become a masked store (vmaskmovpd), slow microcode on
    AMD Zen; flip is a literal, so both offsets are compile-time constants."""
    if flip == 0:
        return O_Y, O_YB
    return O_YB, O_Y


@jit
def _rk2_sweep(S, nb, h, qq, flip):
    """One explicit-midpoint step (rk.rk2_step) of lanes [0, nb) from the state
    rows R_Y to R_YB (flip a literal 0) or back (a literal 1)."""
    src, dst = _rk_buffers(flip)
    h2 = 0.5 * h
    nflag = 0
    for i in range(nb):
        q = _rows_q(S, i) if qq is None else qq
        y0, y1, y2, y3, y4, y5, y6 = _load7(S, src, i)
        _track_w2(S, i, y0, y1, y2, h < 0.0)
        a0, a1, a2, a3, a4, a5, a6, sa = rhs7_lane_poly(y0, y1, y2, y3, y4, y5, y6, q)
        b0, b1, b2, b3, b4, b5, b6, sb = rhs7_lane_poly(
            fma(h2, a0, y0), fma(h2, a1, y1), fma(h2, a2, y2), fma(h2, a3, y3),
            fma(h2, a4, y4), fma(h2, a5, y5), fma(h2, a6, y6), q)
        nflag += _rk_store(S, i, dst, sa & sb, h, y0, y1, y2, y3, y4, y5, y6,
                           b0, b1, b2, b3, b4, b5, b6)
    return nflag


@jit
def _rk4_sweep(S, nb, h, qq, flip):
    """One classical RK4 step (rk.rk4_step) of lanes [0, nb), from the state
    rows R_Y to R_YB (flip a literal 0) or back (a literal 1)."""
    src, dst = _rk_buffers(flip)
    h2 = 0.5 * h
    h6 = h * (1.0 / 6.0)
    nflag = 0
    for i in range(nb):
        q = _rows_q(S, i) if qq is None else qq
        y0, y1, y2, y3, y4, y5, y6 = _load7(S, src, i)
        _track_w2(S, i, y0, y1, y2, h < 0.0)
        a0, a1, a2, a3, a4, a5, a6, sa = rhs7_lane_poly(y0, y1, y2, y3, y4, y5, y6, q)
        b0, b1, b2, b3, b4, b5, b6, sb = rhs7_lane_poly(
            fma(h2, a0, y0), fma(h2, a1, y1), fma(h2, a2, y2), fma(h2, a3, y3),
            fma(h2, a4, y4), fma(h2, a5, y5), fma(h2, a6, y6), q)
        c0, c1, c2, c3, c4, c5, c6, sc = rhs7_lane_poly(
            fma(h2, b0, y0), fma(h2, b1, y1), fma(h2, b2, y2), fma(h2, b3, y3),
            fma(h2, b4, y4), fma(h2, b5, y5), fma(h2, b6, y6), q)
        d0, d1, d2, d3, d4, d5, d6, sd = rhs7_lane_poly(
            fma(h, c0, y0), fma(h, c1, y1), fma(h, c2, y2), fma(h, c3, y3),
            fma(h, c4, y4), fma(h, c5, y5), fma(h, c6, y6), q)
        # the new state is rk4_combine(y, a, b, c, d, h6) = y + h6·rk4_sum(a, b, c, d)
        nflag += _rk_store(S, i, dst, sa & sb & sc & sd, h6, y0, y1, y2, y3, y4, y5, y6,
                           rk4_sum(a0, b0, c0, d0), rk4_sum(a1, b1, c1, d1),
                           rk4_sum(a2, b2, c2, d2), rk4_sum(a3, b3, c3, d3),
                           rk4_sum(a4, b4, c4, d4), rk4_sum(a5, b5, c5, d5),
                           rk4_sum(a6, b6, c6, d6))
    return nflag


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
def _rk_lane_exact7(S, i, src, dst, h, rk4, q):
    """_rk_lane_exact for the 7-wide state, in registers, with the lane's
    coefficients q (shared or its rows) instead of recomputing them from its
    parameters: the same operations as rk.rk2_step / rk4_step (through
    model.rhs), without their five divisions per stage.  From the state rows
    at src to those at dst."""
    y0, y1, y2, y3, y4, y5, y6 = _load7(S, src, i)
    h2 = 0.5 * h
    a0, a1, a2, a3, a4, a5, a6 = rhs7_lane(y0, y1, y2, y3, y4, y5, y6, q)
    b0, b1, b2, b3, b4, b5, b6 = rhs7_lane(
        fma(h2, a0, y0), fma(h2, a1, y1), fma(h2, a2, y2), fma(h2, a3, y3),
        fma(h2, a4, y4), fma(h2, a5, y5), fma(h2, a6, y6), q)
    if rk4:
        h6 = h * (1.0 / 6.0)
        c0, c1, c2, c3, c4, c5, c6 = rhs7_lane(
            fma(h2, b0, y0), fma(h2, b1, y1), fma(h2, b2, y2), fma(h2, b3, y3),
            fma(h2, b4, y4), fma(h2, b5, y5), fma(h2, b6, y6), q)
        d0, d1, d2, d3, d4, d5, d6 = rhs7_lane(
            fma(h, c0, y0), fma(h, c1, y1), fma(h, c2, y2), fma(h, c3, y3),
            fma(h, c4, y4), fma(h, c5, y5), fma(h, c6, y6), q)
        n0 = fma(h6, rk4_sum(a0, b0, c0, d0), y0)
        n1 = fma(h6, rk4_sum(a1, b1, c1, d1), y1)
        n2 = fma(h6, rk4_sum(a2, b2, c2, d2), y2)
        n3 = fma(h6, rk4_sum(a3, b3, c3, d3), y3)
        n4 = fma(h6, rk4_sum(a4, b4, c4, d4), y4)
        n5 = fma(h6, rk4_sum(a5, b5, c5, d5), y5)
        n6 = fma(h6, rk4_sum(a6, b6, c6, d6), y6)
    else:
        n0 = fma(h, b0, y0)
        n1 = fma(h, b1, y1)
        n2 = fma(h, b2, y2)
        n3 = fma(h, b3, y3)
        n4 = fma(h, b4, y4)
        n5 = fma(h, b5, y5)
        n6 = fma(h, b6, y6)
    if not (np.isfinite(n0) and np.isfinite(n1) and np.isfinite(n2) and np.isfinite(n3)
            and np.isfinite(n4) and np.isfinite(n5) and np.isfinite(n6)):
        S[O_FLAG + i] = FLAG_NONFINITE
        return
    _store7(S, dst, i, n0, n1, n2, n3, n4, n5, n6)
    S[O_FLAG + i] = FLAG_OK


@jit
def _w2_sweep(S, nb, h):
    """max |Ω_k|² update alone (for the scalar RK path)."""
    for i in range(nb):
        _track_w2(S, i, S[O_Y + i], S[O_Y + B1 + i], S[O_Y + 2 * B1 + i], h < 0.0)


# --------------------------------------------------------------------------
# variational integrator sweeps (vi.vi_step, lane by lane)


@jit
def _vi_prepare(S, nb, h, tol, first, qq, vv):
    """Per lane: max |Ω_k|², Γ_{k+1} (Cayley), σ_{k+1}, b, predictor X,
    |Ω_k|∞, the Newton mask and, if ``first``, Newton iteration 1 (as
    _newton_sweep does it; the predictor never leaves the registers).
    Returns the number of lanes whose exp argument needs math.exp (R_FLAG =
    FLAG_EXACT)."""
    nexact = 0
    for i in range(nb):
        q = _rows_q(S, i) if qq is None else qq
        v = _rows_v(S, i) if vv is None else vv
        w0 = S[O_Y + i]
        w1 = S[O_Y + B1 + i]
        w2 = S[O_Y + 2 * B1 + i]
        sg = S[O_Y + 6 * B1 + i]
        _track_w2(S, i, w0, w1, w2, h < 0.0)
        G0, G1, G2 = cayley_lane(-(h * w0), -(h * w1), -(h * w2),
                                 S[O_Y + 3 * B1 + i], S[O_Y + 4 * B1 + i], S[O_Y + 5 * B1 + i])
        S[O_GN + i] = G0
        S[O_GN + B1 + i] = G1
        S[O_GN + 2 * B1 + i] = G2
        rate, small = sigma_rate_poly(w0, w1, w2, sg, q)
        S[O_SN + i] = fma(h, rate, sg)
        S[O_FLAG + i] = select(small, FLAG_OK, FLAG_EXACT)
        nexact += 0 if small else 1
        b0, b1, b2 = momentum_constant_lane(w0, w1, w2, G0, G1, G2, v)
        S[O_B + i] = b0
        S[O_B + B1 + i] = b1
        S[O_B + 2 * B1 + i] = b2
        x0, x1, x2 = predictor_lane(w0, w1, w2, G0, G1, G2, q, h)
        sc0 = max(abs(w0), abs(w1), abs(w2))
        S[O_SC0 + i] = sc0
        d0, d1, d2, det = newton_lane(x0, x1, x2, b0, b1, b2, v)
        sing = (det == 0.0) | (not _finite(det))
        n0 = x0 - d0
        n1 = x1 - d1
        n2 = x2 - d2
        step, conv = newton_stop(n0, n1, n2, d0, d1, d2, sc0, tol)
        bad = sing | (not (step == step))
        stay = sing | (not first)
        S[O_X + i] = select(stay, x0, n0)
        S[O_X + B1 + i] = select(stay, x1, n1)
        S[O_X + 2 * B1 + i] = select(stay, x2, n2)
        code = NEWTON_SINGULAR if bad else (NEWTON_OK if conv else NEWTON_MAXITER)
        S[O_CODE + i] = select(first, code, NEWTON_MAXITER)
        S[O_ITS + i] = select(first, 1.0, 0.0)
        S[O_RUN + i] = select((first & (bad | conv)), 0.0, 1.0)
    return nexact


@jit
def _vi_sigma_exact(S, nb, h, qq):
    """σ_{k+1} with math.exp (vi.vi_step's own expression) for FLAG_EXACT lanes
    (qq: the shared coefficients, or None: the lane's rows)."""
    for i in range(nb):
        if S[O_FLAG + i] != FLAG_EXACT:
            continue
        sg = S[O_Y + 6 * B1 + i]
        q = _rows_q(S, i) if qq is None else qq
        S[O_SN + i] = fma(h, sigma_rate_exact(S[O_Y + i], S[O_Y + B1 + i], S[O_Y + 2 * B1 + i],
                                              sg, q), sg)
        S[O_FLAG + i] = FLAG_OK


@jit(inline="always")
def _attitude_row(S, i, r, C):
    """Row r of R_{k+1} = R_k C for lane i (r a literal 0, 1, 2)."""
    a, b, c = row_times_lane(S[O_Y + (7 + 3 * r) * B1 + i], S[O_Y + (8 + 3 * r) * B1 + i],
                             S[O_Y + (9 + 3 * r) * B1 + i], C)
    S[O_RN + (3 * r) * B1 + i] = a
    S[O_RN + (3 * r + 1) * B1 + i] = b
    S[O_RN + (3 * r + 2) * B1 + i] = c


@jit
def _vi_attitude(S, nb, h):
    """R_{k+1} = R_k cay(hΩ̂_k) (so3.attitude_update, same operations).  The rows
    are written out (no loop over r): with a loop LLVM left the lane loop scalar."""
    for i in range(nb):
        C = cayley_matrix_lane(h * S[O_Y + i], h * S[O_Y + B1 + i], h * S[O_Y + 2 * B1 + i])
        _attitude_row(S, i, 0, C)
        _attitude_row(S, i, 1, C)
        _attitude_row(S, i, 2, C)


@jit
def _newton_sweep(S, nb, tol, it, vv):
    """Newton iteration number ``it`` on every lane whose mask is set
    (vi.newton_momentum's stopping rules, per lane).  Returns the number of
    lanes still running."""
    nrun = 0
    for i in range(nb):
        run = S[O_RUN + i] != 0.0
        x0 = S[O_X + i]
        x1 = S[O_X + B1 + i]
        x2 = S[O_X + 2 * B1 + i]
        v = _rows_v(S, i) if vv is None else vv
        d0, d1, d2, det = newton_lane(x0, x1, x2, S[O_B + i], S[O_B + B1 + i],
                                      S[O_B + 2 * B1 + i], v)
        sing = (det == 0.0) | (not _finite(det))
        n0 = x0 - d0
        n1 = x1 - d1
        n2 = x2 - d2
        step, conv = newton_stop(n0, n1, n2, d0, d1, d2, S[O_SC0 + i], tol)
        nanstep = not (step == step)
        move = run & (not sing)
        # A lane that stays keeps its row values.  Written as x − (d or +0), not as
        # "new if move else old": a store of select(c, new, old-from-that-address)
        # becomes a masked store (vmaskmovpd), slow microcode on AMD Zen.  Exact:
        # x − d is n, and x − (+0) is x for every x (−0, inf and NaN included).
        S[O_X + i] = x0 - select(move, d0, 0.0)
        S[O_X + B1 + i] = x1 - select(move, d1, 0.0)
        S[O_X + 2 * B1 + i] = x2 - select(move, d2, 0.0)
        bad = sing | nanstep
        code_old = S[O_CODE + i]
        code = select(bad, NEWTON_SINGULAR, select(conv, NEWTON_OK, code_old))
        its_old = S[O_ITS + i]
        # codes and counts are small integers: old + (new − old) is new exactly
        S[O_CODE + i] = code_old + select(run, code - code_old, 0.0)
        S[O_ITS + i] = its_old + select(run, it - its_old, 0.0)
        still = run & (not bad) & (not conv)
        S[O_RUN + i] = select(still, 1.0, 0.0)
        nrun += 1 if still else 0
    return nrun


@jit
def _newton_compact(S, S2, idx, nb, tol, its, maxiter, vv):
    """Finish the Newton iterations of the few lanes still running (iterations
    its+1 … maxiter) on a compact copy: their rows go to lanes 0 … k−1 of the
    scratch buffer S2, _newton_sweep runs there (same arithmetic per lane) and
    the results come back.  One slow member then costs a sweep over a handful
    of lanes instead of the whole block."""
    k = np.int64(0)  # not a literal 0: that gave _newton_sweep a second specialization
    for i in range(nb):
        if S[O_RUN + i] != 0.0:
            idx[k] = i
            k += 1
    for r in range(R_X, R_ITS + 1):  # X, b, |Ω_k|∞, mask, code, iterations
        for j in range(k):
            S2[r * B1 + j] = S[r * B1 + idx[j]]
    if vv is None:
        for r in range(R_V, R_V + NVCOEF):
            for j in range(k):
                S2[r * B1 + j] = S[r * B1 + idx[j]]
    nrun = k
    while its < maxiter and nrun > 0:
        its += 1
        nrun = _newton_sweep(S2, k, tol, its, vv)
    for r in (R_X, R_X + 1, R_X + 2, R_RUN, R_CODE, R_ITS):
        for j in range(k):
            S[r * B1 + idx[j]] = S2[r * B1 + j]


@jit
def _vi_check(S, nb):
    """After the Newton sweeps: flag the lanes whose step fails (Newton did not
    converge, or the new state is not finite) and accumulate the Newton
    statistics of every lane.  Returns the number of failed lanes.  The state
    rows are not touched: a failed lane is retired with its last accepted
    state before _vi_accept moves the others on."""
    nfail = 0
    for i in range(nb):
        its = S[O_ITS + i]
        S[O_NTOT + i] += its
        nm = S[O_NMAX + i]
        # max of two small non-negative integers, exact, without a select on the
        # row's own value (see _newton_sweep)
        S[O_NMAX + i] = 0.5 * ((its + nm) + abs(its - nm))
        n0 = S[O_X + i]
        n1 = S[O_X + B1 + i]
        n2 = S[O_X + 2 * B1 + i]
        n3 = S[O_GN + i]
        n4 = S[O_GN + B1 + i]
        n5 = S[O_GN + 2 * B1 + i]
        n6 = S[O_SN + i]
        conv = S[O_CODE + i] == NEWTON_OK
        # x − x is 0 for finite x and NaN otherwise, so the sum is 0 exactly when all
        # seven are finite (no overflow: it adds zeros): one compare, no branches
        zero = (((n0 - n0) + (n1 - n1)) + ((n2 - n2) + (n3 - n3))
                + (((n4 - n4) + (n5 - n5)) + (n6 - n6)))
        upd = conv & (zero == 0.0) & (S[O_FLAG + i] == FLAG_OK)
        S[O_FLAG + i] = select(upd, FLAG_OK, select(conv, FLAG_NONFINITE, FLAG_NEWTON))
        nfail += 0 if upd else 1
    return nfail


@jit
def _vi_accept(S, nb, n):
    """Move every lane on to its new state (all lanes passed _vi_check: failed
    ones were retired first)."""
    for i in range(nb):
        S[O_Y + i] = S[O_X + i]
        S[O_Y + B1 + i] = S[O_X + B1 + i]
        S[O_Y + 2 * B1 + i] = S[O_X + 2 * B1 + i]
        S[O_Y + 3 * B1 + i] = S[O_GN + i]
        S[O_Y + 4 * B1 + i] = S[O_GN + B1 + i]
        S[O_Y + 5 * B1 + i] = S[O_GN + 2 * B1 + i]
        S[O_Y + 6 * B1 + i] = S[O_SN + i]
    if n > NSTATE_BASE:
        for k in range(9):
            for i in range(nb):
                S[O_Y + (7 + k) * B1 + i] = S[O_RN + k * B1 + i]


@jit
def _vi_attitude_check(S, nb):
    """Before _vi_check (16-wide state): a non-finite R_{k+1} flags the lane
    (the sum of x − x over its nine entries is 0 exactly when all are finite;
    written out: as a loop over the entries LLVM left the lane loop scalar)."""
    for i in range(nb):
        zero = ((((S[O_RN + i] - S[O_RN + i]) + (S[O_RN + B1 + i] - S[O_RN + B1 + i]))
                 + ((S[O_RN + 2 * B1 + i] - S[O_RN + 2 * B1 + i])
                    + (S[O_RN + 3 * B1 + i] - S[O_RN + 3 * B1 + i])))
                + (((S[O_RN + 4 * B1 + i] - S[O_RN + 4 * B1 + i])
                    + (S[O_RN + 5 * B1 + i] - S[O_RN + 5 * B1 + i]))
                   + ((S[O_RN + 6 * B1 + i] - S[O_RN + 6 * B1 + i])
                      + ((S[O_RN + 7 * B1 + i] - S[O_RN + 7 * B1 + i])
                         + (S[O_RN + 8 * B1 + i] - S[O_RN + 8 * B1 + i])))))
        flag = S[O_FLAG + i]
        # flags are small integers: flag + (NONFINITE − flag) is NONFINITE exactly
        S[O_FLAG + i] = flag + select(zero == 0.0, 0.0, FLAG_NONFINITE - flag)


@jit
def _vi_step_block(S, S2, idx, nb, n, h, tol, maxiter, qq, vv):
    """One VI step of lanes [0, nb) up to _vi_check.  Returns the number of
    failed lanes (R_FLAG = FLAG_NEWTON or FLAG_NONFINITE); the caller retires
    them, then moves the others on with _vi_accept."""
    first = maxiter >= 1
    nexact = _vi_prepare(S, nb, h, tol, first, qq, vv)
    if nexact:
        _vi_sigma_exact(S, nb, h, qq)
    if n > NSTATE_BASE:
        _vi_attitude(S, nb, h)
    # iterations done: 1 (by _vi_prepare) unless maxiter is 0
    its = np.int64(1) if first else np.int64(0)  # np.int64: no Literal[int] overloads
    nrun = 0
    for i in range(nb):
        nrun += S[O_RUN + i] != 0.0
    while its < maxiter and nrun > 0:
        if nrun <= NEWTON_COMPACT and nrun < nb:
            _newton_compact(S, S2, idx, nb, tol, its, maxiter, vv)
            break
        its += 1
        nrun = _newton_sweep(S, nb, tol, its, vv)
    if n > NSTATE_BASE:
        # the flag must also see R, but Newton failure takes precedence
        _vi_attitude_check(S, nb)
    return _vi_check(S, nb)


# --------------------------------------------------------------------------
# the block driver


@jit(inline="always")
def _max_h_omega(S, i, h):
    """max h|Ω_k| over the member's steps: the value at entry or h·sqrt of the
    max |Ω_k|² of this call (the same as the simple kernel's running max of
    h·sqrt(|Ω_k|²), since h·sqrt is non-decreasing)."""
    hm = S[O_HW + i]
    w = S[O_W2 + i]
    if not ((w < np.inf) if h < 0.0 else (w >= 0.0)):
        return hm  # no step (or, for h < 0, only steps whose h|Ω| is −inf)
    hw = h * np.sqrt(w)
    return hw if hw > hm else hm


@jit
def _retire(S, i, nb, n, cur, done, h, Y, ISTAT, FSTAT):
    """Write failed lane i back (status, failing step, statistics; the state
    is the last accepted one, in the rows at cur) and move lane nb−1 into its
    place."""
    m = int(S[O_MEMBER + i])
    for k in range(n):
        Y[m, k] = S[cur + k * B1 + i]
    flag = S[O_FLAG + i]
    ISTAT[m, IS_STATUS] = STATUS_NEWTON if flag == FLAG_NEWTON else STATUS_NONFINITE
    steps = int(S[O_STEPS + i]) + done
    ISTAT[m, IS_FAIL_STEP] = steps + 1
    ISTAT[m, IS_STEPS] = steps
    ISTAT[m, IS_NEWTON_TOTAL] = int(S[O_NTOT + i])
    ISTAT[m, IS_NEWTON_MAX] = int(S[O_NMAX + i])
    FSTAT[m, FS_MAX_H_OMEGA] = _max_h_omega(S, i, h)
    last = nb - 1
    if i != last:
        for r in range(NROWS):
            S[r * B1 + i] = S[r * B1 + last]


@jit
def _step(method, S, S2, idx, nb, n, h, tol, maxiter, qq, vv, par, y, p, work, ynew):
    """One step of lanes [0, nb); returns the number of failed lanes (R_FLAG ≠
    FLAG_OK).  qq, vv: the block's coefficient tuples if it is uniform, else
    None (the sweeps then read each lane's rows).  The vectorized RK steps go
    from the state rows R_Y to R_YB (par 0) or back (par 1); the others stay
    in R_Y."""
    rk4 = method == METHOD_RK4
    if method == METHOD_VI:
        return _vi_step_block(S, S2, idx, nb, n, h, tol, maxiter, qq, vv)
    nfail = 0
    if n == NSTATE_BASE:
        # literal flips: each direction is its own compilation with constant offsets
        if rk4:
            nfail = _rk4_sweep(S, nb, h, qq, 0) if par == 0 else _rk4_sweep(S, nb, h, qq, 1)
        else:
            nfail = _rk2_sweep(S, nb, h, qq, 0) if par == 0 else _rk2_sweep(S, nb, h, qq, 1)
        if nfail:
            src = O_Y if par == 0 else O_YB
            dst = O_YB if par == 0 else O_Y
            for i in range(nb):
                if S[O_FLAG + i] == FLAG_EXACT:
                    if qq is None:
                        _rk_lane_exact7(S, i, src, dst, h, rk4, _rows_q(S, i))
                    else:
                        _rk_lane_exact7(S, i, src, dst, h, rk4, qq)
            nfail = 0
            for i in range(nb):
                nfail += S[O_FLAG + i] != FLAG_OK
    else:
        _w2_sweep(S, nb, h)
        for i in range(nb):
            _rk_lane_exact(S, i, n, h, rk4, y, p, work, ynew)
            nfail += S[O_FLAG + i] != FLAG_OK
    return nfail


@jit
def _fill_block(method, Y, P, m0, m1, h, ISTAT, FSTAT):
    """The block buffer S of members [m0, m1) that are still running (lanes
    0 … nb−1), and the Newton compaction scratch (S2, idx; VI only)."""
    n = Y.shape[1]
    S = np.zeros(NROWS * ROW)
    S2 = np.zeros(NROWS * ROW if method == METHOD_VI else 0)
    idx = np.zeros(BLOCK if method == METHOD_VI else 0, np.int64)
    nb = np.int64(0)  # np.int64: no Literal[int] overloads of the callees
    for m in range(m0, m1):
        if ISTAT[m, IS_STATUS] != STATUS_OK:
            continue
        for k in range(n):
            S[O_Y + k * B1 + nb] = Y[m, k]
        for k in range(9):
            S[O_P + k * B1 + nb] = P[m, k]
        S[O_HW + nb] = FSTAT[m, FS_MAX_H_OMEGA]
        S[O_W2 + nb] = np.inf if h < 0.0 else -1.0
        S[O_NTOT + nb] = ISTAT[m, IS_NEWTON_TOTAL]
        S[O_NMAX + nb] = ISTAT[m, IS_NEWTON_MAX]
        S[O_STEPS + nb] = ISTAT[m, IS_STEPS]
        S[O_MEMBER + nb] = m
        nb += 1
    return S, S2, idx, nb


@jit
def _advance_block_shared(method, Y, P, pp, m0, m1, h, every, n_out, alpha, beta, tol,
                          maxiter, OUT, ISTAT, FSTAT):
    """Members [m0, m1), all with the parameters pp: the coefficients are
    tuples, which live in registers (the simple kernel computes them with the
    same functions from the same parameters: same bits)."""
    S, S2, idx, nb = _fill_block(method, Y, P, m0, m1, h, ISTAT, FSTAT)
    if nb > 0:
        _block_steps(method, S, S2, idx, nb, Y.shape[1], h, every, n_out, tol, maxiter,
                     coefficients(pp), vi_coefficients(pp, h, alpha, beta), Y, OUT, ISTAT, FSTAT)


@jit
def _advance_block_rows(method, Y, P, m0, m1, h, every, n_out, alpha, beta, tol, maxiter,
                        OUT, ISTAT, FSTAT):
    """Members [m0, m1) with their own parameters: each lane's coefficients
    go to its rows, where the sweeps read them."""
    S, S2, idx, nb = _fill_block(method, Y, P, m0, m1, h, ISTAT, FSTAT)
    if nb == 0:
        return
    for i in range(nb):
        q = coefficients(_load_params(S, i))
        for k in range(NCOEF):
            S[O_Q + k * B1 + i] = q[k]
        v = vi_coefficients(_load_params(S, i), h, alpha, beta)
        for k in range(NVCOEF):
            S[O_V + k * B1 + i] = v[k]
    _block_steps(method, S, S2, idx, nb, Y.shape[1], h, every, n_out, tol, maxiter, None, None,
                 Y, OUT, ISTAT, FSTAT)


@jit
def _block_steps(method, S, S2, idx, nb, n, h, every, n_out, tol, maxiter, qq, vv,
                 Y, OUT, ISTAT, FSTAT):
    """The steps of a filled block, its outputs, and the write-back of its
    members at the end.  qq, vv: the coefficient tuples of an ensemble that
    shares its parameters, else None (rows)."""
    y = np.empty(n)
    p = np.empty(9)
    work = np.empty((DOP853_STAGES, n))
    ynew = np.empty(n)
    done = np.int64(0)
    # the state is in the rows at cur: R_Y, or R_YB after an odd number of
    # vectorized RK steps (par 1)
    flips = method != METHOD_VI and n == NSTATE_BASE
    par = np.int64(0)
    cur = O_Y
    for j in range(n_out):
        for _ in range(every):
            nfail = _step(method, S, S2, idx, nb, n, h, tol, maxiter, qq, vv, par, y, p, work,
                          ynew)
            if nfail:
                i = np.int64(0)
                while i < nb:
                    if S[O_FLAG + i] != FLAG_OK:
                        _retire(S, i, nb, n, cur, done, h, Y, ISTAT, FSTAT)
                        nb -= 1
                    else:
                        i += 1
                if nb == 0:
                    return
            if method == METHOD_VI:
                _vi_accept(S, nb, n)
            if flips:
                par = 1 - par
                cur = O_YB if par == 1 else O_Y
            done += 1
        for i in range(nb):
            m = int(S[O_MEMBER + i])
            for k in range(n):
                OUT[m, j, k] = S[cur + k * B1 + i]
    for i in range(nb):
        m = int(S[O_MEMBER + i])
        for k in range(n):
            Y[m, k] = S[cur + k * B1 + i]
        ISTAT[m, IS_STEPS] = int(S[O_STEPS + i]) + done
        ISTAT[m, IS_NEWTON_TOTAL] = int(S[O_NTOT + i])
        ISTAT[m, IS_NEWTON_MAX] = int(S[O_NMAX + i])
        FSTAT[m, FS_MAX_H_OMEGA] = _max_h_omega(S, i, h)


@pjit
def _advance_blocks_shared(method, Y, P, pp, h, every, n_out, alpha, beta, tol, maxiter,
                           OUT, ISTAT, FSTAT):
    """prange over blocks of BLOCK members (VI, RK2, RK4), all with parameters pp."""
    N = Y.shape[0]
    nblocks = (N + BLOCK - 1) // BLOCK
    for bi in prange(nblocks):
        m0 = bi * BLOCK
        _advance_block_shared(method, Y, P, pp, m0, min(N, m0 + BLOCK), h, every, n_out, alpha,
                              beta, tol, maxiter, OUT, ISTAT, FSTAT)


@pjit
def _advance_blocks_rows(method, Y, P, h, every, n_out, alpha, beta, tol, maxiter,
                         OUT, ISTAT, FSTAT):
    """prange over blocks of BLOCK members (VI, RK2, RK4), each with its own
    parameters."""
    N = Y.shape[0]
    nblocks = (N + BLOCK - 1) // BLOCK
    for bi in prange(nblocks):
        m0 = bi * BLOCK
        _advance_block_rows(method, Y, P, m0, min(N, m0 + BLOCK), h, every, n_out, alpha, beta,
                            tol, maxiter, OUT, ISTAT, FSTAT)


def shared_params(P):
    """P[0] (a copy) if every row of P is bitwise equal to it, else None.

    The block kernel has a version for each case: shared parameters give
    coefficient tuples that live in registers; else every lane reads its
    coefficients from its rows.  Numba compiles a version on its first use,
    so the paper scene (one parameter set) never compiles the other."""
    if P.shape[0] == 0:
        return None
    bits = np.ascontiguousarray(P, dtype=np.float64).view(np.int64)
    if (bits == bits[0]).all():
        return np.array(P[0], dtype=np.float64)
    return None


def advance_ensemble_fast(method, Y, P, h, every, n_out, alpha, beta, tol, maxiter,
                          nsub, A, B, OUT, ISTAT, FSTAT):
    """Same contract and results as ensemble.advance_ensemble (see module
    docstring); VI, RK2 and RK4 run in vectorized blocks of BLOCK members,
    the ``reference`` method is handed to ensemble.advance_ensemble.

    A Python function, not a jitted one: the reference (DOP853) and the
    straightforward per-member steps then stay out of the block kernel's
    compilation, which takes ~6 s less on a cold numba cache."""
    if method == METHOD_VI or method == METHOD_RK2 or method == METHOD_RK4:
        pp = shared_params(P)
        if pp is not None:
            _advance_blocks_shared(method, Y, P, pp, h, every, n_out, alpha, beta, tol, maxiter,
                                   OUT, ISTAT, FSTAT)
        else:
            _advance_blocks_rows(method, Y, P, h, every, n_out, alpha, beta, tol, maxiter,
                                 OUT, ISTAT, FSTAT)
    else:
        advance_ensemble(method, Y, P, h, every, n_out, alpha, beta, tol, maxiter,
                         nsub, A, B, OUT, ISTAT, FSTAT)
