"""The vectorized ensemble kernel: structure-of-arrays blocks that LLVM vectorizes.

:func:`advance_blocks` has the contract of the straightforward kernel's
:func:`.simple.advance_members` (same stepper, same arrays, same status
codes) over the members of blocks ``b0 … b1−1`` (a block is ``BLOCK`` consecutive members),
and compute the same bits: every step goes through the same lane functions
(:mod:`.rk`, :mod:`.vi`, :mod:`.equations`, the model terms), whose explicit
fused multiply-adds fix every rounding — states, status flags, failing steps,
Newton iteration counts and max |h|·|Ω| agree bitwise.

How it is fast
--------------
* A block copies its running members into one flat buffer, row by row
  (structure of arrays: row r holds quantity r of every lane), advances them
  for the whole call, and copies them back.  Every row sits at a
  compile-time offset of the same buffer (:data:`ROWS`, derived from the
  sizes of the parts: no hand-numbered rows), so LLVM sees no possible
  aliasing and vectorizes the loops over lanes (packed ``vfmadd…pd`` on ymm
  or zmm registers).  The lane functions are ``alwaysinline``: a lane loop
  is one straight-line body.
* Two versions of every sweep, chosen once per call: when all members share
  their parameters (a random ensemble of one scene) the model is a tuple
  argument that lives in registers (``shared``); else each lane rebuilds its
  model from its parameter rows (``shared`` None).
* The kernels are compiled for the model's *type*: absent terms are not in
  the code, and a run compiles only its method family and its model.
* An explicit RK step is one sweep over the lanes: all stages of a lane stay
  in registers, only the state is loaded and stored, from one state buffer
  to the other with plain stores; a flagged lane still has its old state in
  the source buffer.
* The VI's Newton iterations run in lock-step over the block with a
  per-lane convergence mask: a converged lane keeps its X, and the block
  stops iterating as soon as no lane runs.  Once only a few lanes still run
  (``NEWTON_COMPACT``), they are copied to the first lanes of a scratch
  buffer and finish there, so one slow member does not hold the block.
* No lane store is conditional (a store of "new if c else the row's own
  value" becomes a masked store, slow microcode on AMD Zen): the sweeps
  store unconditionally (exact arithmetic blends, ``_jit.select``, the RK
  double buffer), and a step is accepted only after its failed lanes are
  retired.
* A failed member (Newton failure or non-finite state) is written back at
  once and its lane is filled with the block's last lane, so dead members
  cost nothing and never touch their neighbours' values.
* The sweeps align their stack frames to 64 bytes (:func:`._jit.align_frame`):
  LLVM keeps tuples and spilled zmm registers there, and from a frame aligned
  to 16 bytes only, whether those moves split cache lines depended on where
  the process's stack happened to land (RK4 ran at one of two speeds, 2x apart).
* 1/T(σ) and log1p in the entropy are inline polynomials in the sweeps; a
  lane outside their range is flagged and recomputed with the
  straightforward kernel's operations.
"""

from __future__ import annotations

import numpy as np

from ._jit import align_frame, jit, lane, ld, select, st
from .dispatch import capability, generic, is_present
from .gen import (finite, or_zero, tree_finite,
                  tree_sum_finite, unflatten)
from .layout import (FS_MAX_H_OMEGA, IS_FAIL_STEP, IS_NEWTON_MAX, IS_NEWTON_TOTAL, IS_STATUS,
                     IS_STEPS, NEWTON_MAXITER, NEWTON_OK, NEWTON_SINGULAR, STATUS_NEWTON,
                     STATUS_NONFINITE, STATUS_OK, load_rk_state, load_split_state, load_vi_state,
                     store_rk_state, store_split_state, store_vi_state)
from .rk import explicit_step
from .split import split_begin, split_end, split_speed2, split_stage
from .terms.inertia import FREE_FLOW_STAGES
from .so3 import norm2_lane
from .steppers import Split, Variational, stepper_kind
from .vi import (add_opt, newton_data, newton_iterate, newton_step, newton_stop, sub_select,
                 select_opt, vi_advance, vi_coefficients, vi_entropy, zero_like)

# the splitting sweeps below name the stages 0 … 4 of split_stage as literals
assert FREE_FLOW_STAGES == 5

#: members per block (lanes)
BLOCK = 128
#: row stride of the block buffer (doubles): BLOCK plus a pad, so that the
#: rows of one lane do not all fall into a few cache sets (a stride of 1 KiB
#: maps lane i of every row into 4 of the L1's 64 sets)
ROW = BLOCK + 8
#: when at most this many lanes of a block still iterate, they finish on a compact copy
NEWTON_COMPACT = BLOCK // 4
#: the largest state of any layout (vi: X, Γ, σ, μ, σ_{k+1}, R)
NSTATE_MAX = 20

#: the rows of a block buffer, in order: (name, number of rows).  The model's
#: parameter rows come last (their number depends on the model).
ROW_PARTS = (
    ("Y", NSTATE_MAX),  # state
    ("YB", NSTATE_MAX),  # RK: the other state buffer; VI: the state at the start of a step
    ("GN", 3), ("SN", 1), ("MUN", 3), ("RN", 9),  # VI: Γ', σ', μ', R' of the step
    ("X", 3), ("XS", 1), ("B", 3),  # VI: Newton iterate (X and, coupled, Δ) and the
    # constant part of its function
    ("TN", 1),  # VI, coupled: T(σ'), the same in every Newton iteration of the step
    ("SC0", 1), ("SCS", 1),  # VI: |X_k|∞ (and, coupled, |σ'|): scales of the stopping rule
    ("DP", 1), ("DPS", 1),  # VI: the last Newton correction of X (and, coupled, of Δ)
    ("RUN", 1), ("CODE", 1), ("ITS", 1),  # VI: Newton mask, outcome, iterations
    ("HW", 1), ("NTOT", 1), ("NMAX", 1), ("STEPS", 1), ("MEMBER", 1),  # statistics at entry
    ("FLAG", 1),  # per-step outcome (FLAG_*)
    ("W2", 1),  # max |Ω|² (times the squared substep factor) over this call
)


def _row_map(parts):
    out, r = {}, 0
    for name, size in parts:
        out[name] = (r, size)
        r += size
    return out, r


ROWS, NROWS_FIXED = _row_map(ROW_PARTS)
O_Y, O_YB, O_GN, O_SN, O_MUN, O_RN, O_X, O_XS, O_B, O_TN, O_SC0, O_SCS, O_DP, O_DPS, O_RUN, \
    O_CODE, O_ITS, \
    O_HW, O_NTOT, O_NMAX, O_STEPS, O_MEMBER, O_FLAG, O_W2 = (ROWS[name][0] * ROW
                                                              for name, _ in ROW_PARTS)
#: the first parameter row (rows mode)
O_P = NROWS_FIXED * ROW

# per-step outcome flags (row FLAG)
FLAG_OK = 0.0
FLAG_NEWTON = 1.0  # Newton failed: STATUS_NEWTON
FLAG_NONFINITE = 2.0  # STATUS_NONFINITE
FLAG_EXACT = 3.0  # an inline polynomial was out of range: redo with the exact operations

#: Newton outcome (row CODE) of a lane whose vectorized iteration used an inline
#: polynomial out of its range: newton_redo finishes its solve with the exact
#: operations (never seen outside a substep)
NEWTON_REDO = 3.0


def buffer_size(nparam: int) -> int:
    """Doubles in a block buffer for a model of ``nparam`` parameters."""
    return (NROWS_FIXED + nparam) * ROW


# --------------------------------------------------------------------------
# lane helpers


@lane
def lane_model(shared, template, S, i):
    """Lane i's model: ``shared``, or rebuilt from its parameter rows."""
    if shared is None:
        return unflatten(template, S, O_P + i, ROW)
    return shared


@lane
def lane_vi(vv, md, h, wl, wr):
    """The VI coefficients of a lane: the block's shared ones, or its own."""
    if vv is None:
        return vi_coefficients(md, h, wl, wr)
    return vv


@generic(is_present)
def shared_vi(shared, h, wl, wr):
    """The VI coefficients of a block that shares its parameters; None otherwise."""
    return None


@shared_vi.register(True)
def shared_vi_present(shared, h, wl, wr):
    return vi_coefficients(shared, h, wl, wr)


@generic(capability("entropy_dependent_inertia"))
def coupled_marker(inertia):
    """None for a constant inertia, 1.0 for the coupled top (its Newton solve has Δ)."""
    return None


@coupled_marker.register(True)
def coupled_marker_coupled(inertia):
    return 1.0


@generic(is_present)
def store1(x, S, off):
    """S[off] = x; nothing when x is None."""
    return None


@store1.register(True)
def store1_present(x, S, off):
    st(S, off, x)


@generic(is_present)
def store9(x, S, off):
    """The 9-tuple x into rows off, off + ROW, …; nothing when x is None."""
    return None


@store9.register(True)
def store9_present(x, S, off):
    st(S, off, x[0])
    st(S, off + ROW, x[1])
    st(S, off + 2 * ROW, x[2])
    st(S, off + 3 * ROW, x[3])
    st(S, off + 4 * ROW, x[4])
    st(S, off + 5 * ROW, x[5])
    st(S, off + 6 * ROW, x[6])
    st(S, off + 7 * ROW, x[7])
    st(S, off + 8 * ROW, x[8])


@generic(is_present)
def load1_if(marker, S, off):
    """S[off] when ``marker`` is not None; None otherwise."""
    return None


@load1_if.register(True)
def load1_present(marker, S, off):
    return ld(S, off)


@generic(is_present)
def load9_if(marker, S, off):
    """Rows off, off + ROW, … as a 9-tuple when ``marker`` is not None; None otherwise."""
    return None


@load9_if.register(True)
def load9_present(marker, S, off):
    return (ld(S, off), ld(S, off + ROW), ld(S, off + 2 * ROW), ld(S, off + 3 * ROW), ld(S, off + 4 * ROW),
            ld(S, off + 5 * ROW), ld(S, off + 6 * ROW), ld(S, off + 7 * ROW), ld(S, off + 8 * ROW))


@lane
def _track_w2(S, i, ww):
    """Running max of |Ω|² (row W2 starts at −1: no step yet)."""
    # + 0.0 is exact here (the row never holds −0) and keeps the store unconditional
    m = ld(S, O_W2 + i) + 0.0
    st(S, O_W2 + i, select(ww > m, ww, m))


@lane
def _max_h_omega(S, i, h):
    """max |h|·|Ω| over the member's steps: the value at entry or |h|·sqrt of
    the max of this call (as the straightforward kernel's max_h_omega)."""
    hm = ld(S, O_HW + i)
    w = ld(S, O_W2 + i)
    if not (w >= 0.0):
        return hm
    hw = abs(h) * np.sqrt(w)
    return hw if hw > hm else hm


# --------------------------------------------------------------------------
# explicit Runge–Kutta sweeps


@lane
def _rk_buffers(flip):
    """(source, destination) offsets of a vectorized RK step; flip is a
    literal, so both are compile-time constants."""
    if flip == 0:
        return O_Y, O_YB
    return O_YB, O_Y


@jit
def _rk_sweep(tab, model, shared, S, nb, h, flip):
    """One step of the tableau ``tab`` for lanes [0, nb) from one state buffer
    to the other.  A lane whose new state is not (cheaply) finite or whose
    inline exp was out of range gets FLAG_EXACT.  Returns the flagged count."""
    align_frame()
    src, dst = _rk_buffers(flip)
    nflag = 0
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        y = load_rk_state(md, S, src + i, ROW)
        w = y[0]
        _track_w2(S, i, norm2_lane(w[0], w[1], w[2]))
        yn, small = explicit_step(tab, md, y, h, False)
        upd = tree_sum_finite(yn) & small
        store_rk_state(md, S, dst + i, ROW, yn)
        st(S, O_FLAG + i, select(upd, FLAG_OK, FLAG_EXACT))
        nflag += 0 if upd else 1
    return nflag


# --------------------------------------------------------------------------
# splitting sweeps: a stage of the Strang step over all lanes at a time.  The
# passes are lane functions: LLVM inlines them into _split_step, where the
# buffer direction is a constant (constant row offsets: LLVM sees that the two
# buffers do not overlap) and no pass pays a call with the model's arguments
# (as separate functions the five calls per step cost 0.3 ns per member-step)


@lane
def _split_first(model, shared, S, nb, t, flip):
    """Stage 0 of a step's first Strang step, from the state in one buffer
    (``flip`` as in :func:`_rk_buffers`); the work state (μ, Γ, q, R) goes to
    the other, in the rows of a ``split`` state."""
    src, dst = _rk_buffers(flip)
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        y = load_split_state(md, S, src + i, ROW)
        _track_w2(S, i, split_speed2(md, y))
        store_split_state(md, S, dst + i, ROW, split_stage(md, 0, t, split_begin(md, y)))


@lane
def _load_work(md, S, off):
    """The work state a previous stage left at ``off`` (q = 0.0 without
    thermodynamics, as split_begin has it)."""
    m, G, q, R = load_split_state(md, S, off, ROW)
    return m, G, or_zero(q), R


@lane
def _split_stage_pass(model, shared, S, nb, stage, t, flip):
    """Stage ``stage`` of a Strang step of size t on the work states in the
    destination buffer."""
    src, dst = _rk_buffers(flip)
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        store_split_state(md, S, dst + i, ROW, split_stage(md, stage, t, _load_work(md, S, dst + i)))


@lane
def _split_last(model, shared, S, nb, t, flip):
    """The last stage of a step and its end: the new state in the
    destination buffer; a lane whose state is not finite gets
    FLAG_NONFINITE.  Returns the number of those."""
    src, dst = _rk_buffers(flip)
    nfail = 0
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        z = split_stage(md, 4, t, _load_work(md, S, dst + i))
        yn = split_end(md, load_split_state(md, S, src + i, ROW), z)
        upd = tree_finite(yn)
        store_split_state(md, S, dst + i, ROW, yn)
        st(S, O_FLAG + i, select(upd, FLAG_OK, FLAG_NONFINITE))
        nfail += 0 if upd else 1
    return nfail


@lane
def _split_sweep(factors, model, shared, S, nb, h, flip):
    """One step of the splitting with these factors, for lanes [0, nb) from
    one state buffer to the other: the stages of its Strang steps one after
    the other, each over all lanes (the same arithmetic per lane as
    :func:`.split.split_step`).  A step's five Cayley divisions are one
    dependent chain: run a lane at a time, its latency sets the cost of the
    step (the out-of-order window holds about one lane's step); a stage at
    a time, the lanes of a stage are independent and fill the vector units."""
    align_frame()
    ns = len(factors)
    nflag = 0
    for k in range(ns):
        t = factors[k] * h
        if k == 0:
            _split_first(model, shared, S, nb, t, flip)
        else:
            _split_stage_pass(model, shared, S, nb, 0, t, flip)
        _split_stage_pass(model, shared, S, nb, 1, t, flip)
        _split_stage_pass(model, shared, S, nb, 2, t, flip)
        _split_stage_pass(model, shared, S, nb, 3, t, flip)
        if k == ns - 1:
            nflag = _split_last(model, shared, S, nb, t, flip)
        else:
            _split_stage_pass(model, shared, S, nb, 4, t, flip)
    return nflag


@jit
def _split_step(factors, model, shared, S, nb, h, par):
    """One step of the splitting with substep factors ``factors`` from the
    rows at Y (par 0) or YB (par 1); returns the number of failed lanes."""
    if par == 0:
        return _split_sweep(factors, model, shared, S, nb, h, 0)
    return _split_sweep(factors, model, shared, S, nb, h, 1)


@jit
def _rk_exact(tab, model, shared, S, nb, h, flip):
    """Redo the FLAG_EXACT lanes with the straightforward kernel's operations;
    returns the number of lanes that failed (FLAG_NONFINITE)."""
    align_frame()
    src, dst = _rk_buffers(flip)
    nfail = 0
    for i in range(nb):
        if ld(S, O_FLAG + i) != FLAG_EXACT:
            continue
        md = lane_model(shared, model, S, i)
        yn, ok = explicit_step(tab, md, load_rk_state(md, S, src + i, ROW), h, True)
        if tree_finite(yn):
            store_rk_state(md, S, dst + i, ROW, yn)
            st(S, O_FLAG + i, FLAG_OK)
        else:
            st(S, O_FLAG + i, FLAG_NONFINITE)
            nfail += 1
    return nfail


@jit
def _rk_step(tab, model, shared, S, nb, h, par):
    """One RK step from the rows at Y (par 0) or YB (par 1); returns the number
    of failed lanes."""
    if par == 0:
        nflag = _rk_sweep(tab, model, shared, S, nb, h, 0)
        return _rk_exact(tab, model, shared, S, nb, h, 0) if nflag else 0
    nflag = _rk_sweep(tab, model, shared, S, nb, h, 1)
    return _rk_exact(tab, model, shared, S, nb, h, 1) if nflag else 0


# --------------------------------------------------------------------------
# variational integrator sweeps (simple's variational member step, lane by lane)


@jit
def _vi_prepare(model, shared, S, nb, vv, vvn, h, hn, g2, wl, wr, mode, tol, first):
    """Per lane: max |h_i X|², the step's Γ', σ', μ', R' (vi_advance), the next
    Newton function's constant part b, the predictor, |X|∞, the Newton mask
    and, if ``first``, Newton iteration 1 (as _newton_sweep does it; the
    predictor never leaves the registers).  Returns the number of lanes whose
    entropy needs the exact operations (FLAG_EXACT) and the number whose
    Newton iteration does (NEWTON_REDO)."""
    align_frame()
    nexact = 0
    nredo = 0
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        v = lane_vi(vv, md, h, wl, wr)
        vn = lane_vi(vvn, md, hn, wl, wr)
        y = load_vi_state(md, S, O_Y + i, ROW)
        X = y[0]
        _track_w2(S, i, g2 * norm2_lane(X[0], X[1], X[2]))
        G1, s1, mu1, R1, b, xp, ps, sc0, scs, ok = vi_advance(md, v, vn, y, hn, mode, False)
        tn = newton_data(md.inertia, md, s1)
        store1(tn, S, O_TN + i)
        st(S, O_GN + i, G1[0])
        st(S, O_GN + ROW + i, G1[1])
        st(S, O_GN + 2 * ROW + i, G1[2])
        store1(s1, S, O_SN + i)
        st(S, O_MUN + i, mu1[0])
        st(S, O_MUN + ROW + i, mu1[1])
        st(S, O_MUN + 2 * ROW + i, mu1[2])
        store9(R1, S, O_RN + i)
        b0, b1, b2 = b
        st(S, O_B + i, b0)
        st(S, O_B + ROW + i, b1)
        st(S, O_B + 2 * ROW + i, b2)
        st(S, O_SC0 + i, sc0)
        store1(scs, S, O_SCS + i)
        st(S, O_FLAG + i, select(ok, FLAG_OK, FLAG_EXACT))
        nexact += 0 if ok else 1
        x0, x1, x2 = xp
        d0, d1, d2, ds, det, okn = newton_step(md, vn, x0, x1, x2, ps, b0, b1, b2, tn, False)
        redo = first & (not okn)
        sing = (det == 0.0) | (not finite(det))
        n0 = x0 - d0
        n1 = x1 - d1
        n2 = x2 - d2
        ns = sub_select(ps, True, ds)
        step, steps, conv = newton_stop(n0, n1, n2, ns, d0, d1, d2, ds, sc0, scs, 0.0,
                                        zero_like(ps), tol)
        st(S, O_DP + i, step)
        store1(steps, S, O_DPS + i)
        bad = sing | (not (step == step))
        stay = sing | (not first) | redo
        st(S, O_X + i, select(stay, x0, n0))
        st(S, O_X + ROW + i, select(stay, x1, n1))
        st(S, O_X + 2 * ROW + i, select(stay, x2, n2))
        store1(sub_select(ps, not stay, ds), S, O_XS + i)
        code = select(bad, NEWTON_SINGULAR, select(conv, NEWTON_OK, NEWTON_MAXITER))
        st(S, O_CODE + i, select(redo, NEWTON_REDO, select(first, code, NEWTON_MAXITER)))
        st(S, O_ITS + i, select(first & (not redo), 1.0, 0.0))
        st(S, O_RUN + i, select(first & (bad | conv | redo), 0.0, 1.0))
        nredo += 1 if redo else 0
    return nexact, nredo


@jit
def _vi_entropy_exact(model, shared, S, nb, vv, h, wl, wr, mode):
    """σ' with the straightforward kernel's operations for FLAG_EXACT lanes."""
    align_frame()
    for i in range(nb):
        if ld(S, O_FLAG + i) != FLAG_EXACT:
            continue
        md = lane_model(shared, model, S, i)
        v = lane_vi(vv, md, h, wl, wr)
        y = load_vi_state(md, S, O_Y + i, ROW)
        s1, ok = vi_entropy(md, v, y, mode, True)
        store1(s1, S, O_SN + i)
        st(S, O_FLAG + i, FLAG_OK)


@jit
def _newton_sweep(model, shared, S, nb, vvn, hn, wl, wr, tol, it):
    """Newton iteration number ``it`` on every lane whose mask is set (the
    straightforward kernel's stopping rules, per lane).  A lane whose iteration
    needs the exact operations stops with NEWTON_REDO and its iterate and
    count unchanged.  Returns the number of lanes still running."""
    align_frame()
    nrun = 0
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        vn = lane_vi(vvn, md, hn, wl, wr)
        run = ld(S, O_RUN + i) != 0.0
        x0 = ld(S, O_X + i)
        x1 = ld(S, O_X + ROW + i)
        x2 = ld(S, O_X + 2 * ROW + i)
        xs = load1_if(coupled_marker(md.inertia), S, O_XS + i)
        tn = load1_if(coupled_marker(md.inertia), S, O_TN + i)
        d0, d1, d2, ds, det, okn = newton_step(md, vn, x0, x1, x2, xs, ld(S, O_B + i),
                                               ld(S, O_B + ROW + i), ld(S, O_B + 2 * ROW + i), tn,
                                               False)
        sing = (det == 0.0) | (not finite(det))
        n0 = x0 - d0
        n1 = x1 - d1
        n2 = x2 - d2
        prev = ld(S, O_DP + i)
        prevs = load1_if(xs, S, O_DPS + i)
        step, steps, conv = newton_stop(n0, n1, n2, sub_select(xs, True, ds), d0, d1, d2, ds,
                                        ld(S, O_SC0 + i), load1_if(xs, S, O_SCS + i), prev,
                                        prevs, tol)
        nanstep = not (step == step)
        move = run & okn & (not sing)
        # A lane that stays keeps its row values.  Written as x − (d or +0), not as
        # "new if move else old" (a masked store); exact: x − (+0) is x for every x
        st(S, O_X + i, x0 - select(move, d0, 0.0))
        st(S, O_X + ROW + i, x1 - select(move, d1, 0.0))
        st(S, O_X + 2 * ROW + i, x2 - select(move, d2, 0.0))
        store1(sub_select(xs, move, ds), S, O_XS + i)
        # the size of the last correction for the stopping rule (a lane that stops
        # here never reads it again; a NEWTON_REDO lane keeps the one it applied last,
        # and okn is the constant True but for the coupled top)
        st(S, O_DP + i, select(okn, step, prev))
        store1(select_opt(okn, steps, prevs), S, O_DPS + i)
        bad = sing | nanstep
        code_old = ld(S, O_CODE + i)
        code = select(okn, select(bad, NEWTON_SINGULAR, select(conv, NEWTON_OK, code_old)),
                      NEWTON_REDO)
        its_old = ld(S, O_ITS + i)
        # codes and counts are small integers: old + (new − old) is new exactly
        st(S, O_CODE + i, code_old + select(run, code - code_old, 0.0))
        st(S, O_ITS + i, its_old + select(run & okn, it - its_old, 0.0))
        still = run & okn & (not bad) & (not conv)
        st(S, O_RUN + i, select(still, 1.0, 0.0))
        nrun += 1 if still else 0
    return nrun


#: the rows a compacted Newton lane needs: X, XS, B, TN, SC0, SCS, DP, DPS, RUN, CODE, ITS
_COMPACT_ROWS = tuple(ROWS[name][0] + k for name in ("X", "XS", "B", "TN", "SC0", "SCS", "DP",
                                                     "DPS", "RUN", "CODE", "ITS")
                      for k in range(ROWS[name][1]))
_BACK_ROWS = tuple(ROWS[name][0] + k for name in ("X", "XS", "DP", "DPS", "RUN", "CODE", "ITS")
                   for k in range(ROWS[name][1]))


@jit
def _newton_compact(model, shared, S, S2, idx, nb, nparam, vvn, hn, wl, wr, tol, its, maxiter):
    """Finish the Newton iterations of the few lanes still running (iterations
    its+1 … maxiter) on a compact copy: their rows go to lanes 0 … k−1 of the
    scratch buffer S2, _newton_sweep runs there (same arithmetic per lane) and
    the results come back."""
    align_frame()
    k = np.int64(0)
    for i in range(nb):
        if ld(S, O_RUN + i) != 0.0:
            idx[k] = i
            k += 1
    for r in _COMPACT_ROWS:
        for j in range(k):
            st(S2, r * ROW + j, ld(S, r * ROW + idx[j]))
    if shared is None:
        for r in range(nparam):
            for j in range(k):
                st(S2, O_P + r * ROW + j, ld(S, O_P + r * ROW + idx[j]))
    nrun = k
    while its < maxiter and nrun > 0:
        its += 1
        nrun = _newton_sweep(model, shared, S2, k, vvn, hn, wl, wr, tol, its)
    for r in _BACK_ROWS:
        for j in range(k):
            st(S, r * ROW + idx[j], ld(S2, r * ROW + j))


@generic(is_present)
def newton_redo(marker, model, shared, S, nb, vvn, hn, wl, wr, tol, maxiter):
    """Finish the Newton solve of the coupled top's NEWTON_REDO lanes (the only
    model whose Newton step has an inline polynomial), compiled into the
    substep; nothing for the others (``marker`` None)."""
    return None


@newton_redo.register(True)
def newton_redo_coupled(marker, model, shared, S, nb, vvn, hn, wl, wr, tol, maxiter):
    """Finish the Newton solve of every NEWTON_REDO lane from its iterate
    with the exact operations (vi.newton_iterate, as the straightforward
    kernel iterates)."""
    for i in range(nb):
        if ld(S, O_CODE + i) != NEWTON_REDO:
            continue
        md = lane_model(shared, model, S, i)
        vn = lane_vi(vvn, md, hn, wl, wr)
        X, xs, code, its = newton_iterate(
            md, vn, (ld(S, O_B + i), ld(S, O_B + ROW + i), ld(S, O_B + 2 * ROW + i)),
            (ld(S, O_X + i), ld(S, O_X + ROW + i), ld(S, O_X + 2 * ROW + i)),
            load1_if(marker, S, O_XS + i), load1_if(marker, S, O_TN + i), ld(S, O_SC0 + i),
            load1_if(marker, S, O_SCS + i), tol, np.int64(ld(S, O_ITS + i)), maxiter,
            (ld(S, O_DP + i), load1_if(marker, S, O_DPS + i)))
        st(S, O_X + i, X[0])
        st(S, O_X + ROW + i, X[1])
        st(S, O_X + 2 * ROW + i, X[2])
        store1(xs, S, O_XS + i)
        st(S, O_CODE + i, code)
        st(S, O_ITS + i, its)
        st(S, O_RUN + i, 0.0)


@lane
def _new_state(md, S, i):
    """The state the step would accept, from the work rows."""
    return ((ld(S, O_X + i), ld(S, O_X + ROW + i), ld(S, O_X + 2 * ROW + i)),
            (ld(S, O_GN + i), ld(S, O_GN + ROW + i), ld(S, O_GN + 2 * ROW + i)),
            load1_if(md.thermo, S, O_SN + i),
            (ld(S, O_MUN + i), ld(S, O_MUN + ROW + i), ld(S, O_MUN + 2 * ROW + i)),
            add_opt(load1_if(md.thermo, S, O_SN + i),
                    load1_if(coupled_marker(md.inertia), S, O_XS + i)),
            load9_if(md.attitude, S, O_RN + i))


@jit
def _vi_check(model, shared, S, nb):
    """After the Newton sweeps: flag the lanes whose step fails (Newton did not
    converge, or the new state is not finite) and accumulate the Newton
    statistics of every lane.  Returns the number of failed lanes; the state
    rows are not touched."""
    nfail = 0
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        its = ld(S, O_ITS + i)
        st(S, O_NTOT + i, ld(S, O_NTOT + i) + its)
        nm = ld(S, O_NMAX + i)
        # max of two small non-negative integers, exact, without a select on the
        # row's own value
        st(S, O_NMAX + i, 0.5 * ((its + nm) + abs(its - nm)))
        conv = ld(S, O_CODE + i) == NEWTON_OK
        upd = conv & tree_finite(_new_state(md, S, i)) & (ld(S, O_FLAG + i) == FLAG_OK)
        st(S, O_FLAG + i, select(upd, FLAG_OK, select(conv, FLAG_NONFINITE, FLAG_NEWTON)))
        nfail += 0 if upd else 1
    return nfail


@jit
def _vi_accept(model, shared, S, nb):
    """Move every lane on to its new state (failed lanes were retired first)."""
    for i in range(nb):
        md = lane_model(shared, model, S, i)
        store_vi_state(md, S, O_Y + i, ROW, _new_state(md, S, i))


@jit
def _vi_substep(model, shared, S, S2, idx, nb, nparam, vv, vvn, h, hn, g2, wl, wr, mode, tol,
                maxiter):
    """One substep of lanes [0, nb) up to _vi_check; returns the number of
    failed lanes (FLAG_NEWTON or FLAG_NONFINITE)."""
    align_frame()
    first = maxiter >= 1
    nexact, nredo = _vi_prepare(model, shared, S, nb, vv, vvn, h, hn, g2, wl, wr, mode, tol, first)
    if nexact:
        _vi_entropy_exact(model, shared, S, nb, vv, h, wl, wr, mode)
    its = np.int64(1) if first else np.int64(0)
    nrun = 0
    for i in range(nb):
        nrun += ld(S, O_RUN + i) != 0.0
    while its < maxiter and nrun > 0:
        if nrun <= NEWTON_COMPACT and nrun < nb:
            _newton_compact(model, shared, S, S2, idx, nb, nparam, vvn, hn, wl, wr, tol, its,
                            maxiter)
            break
        its += 1
        nrun = _newton_sweep(model, shared, S, nb, vvn, hn, wl, wr, tol, its)
    newton_redo(coupled_marker(model.inertia), model, shared, S, nb, vvn, hn, wl, wr, tol, maxiter)
    return _vi_check(model, shared, S, nb)


# --------------------------------------------------------------------------
# the block driver


@jit
def _retire(S, i, nb, nrows, n, cur, done, h, Y, ISTAT, FSTAT):
    """Write failed lane i back (status, failing step, statistics; the state
    is the last accepted one, in the rows at cur) and move lane nb−1 into its
    place."""
    m = int(ld(S, O_MEMBER + i))
    for k in range(n):
        Y[m, k] = ld(S, cur + k * ROW + i)
    flag = ld(S, O_FLAG + i)
    ISTAT[m, IS_STATUS] = STATUS_NEWTON if flag == FLAG_NEWTON else STATUS_NONFINITE
    steps = int(ld(S, O_STEPS + i)) + done
    ISTAT[m, IS_FAIL_STEP] = steps + 1
    ISTAT[m, IS_STEPS] = steps
    ISTAT[m, IS_NEWTON_TOTAL] = int(ld(S, O_NTOT + i))
    ISTAT[m, IS_NEWTON_MAX] = int(ld(S, O_NMAX + i))
    FSTAT[m, FS_MAX_H_OMEGA] = _max_h_omega(S, i, h)
    last = nb - 1
    if i != last:
        for r in range(nrows):
            st(S, r * ROW + i, ld(S, r * ROW + last))


@jit
def _fill_block(Y, P, m0, m1, nparam, with_scratch, ISTAT, FSTAT):
    """The block buffer of members [m0, m1) that are still running (lanes
    0 … nb−1), and the Newton compaction scratch (S2, idx; VI only)."""
    n = Y.shape[1]
    nrows = NROWS_FIXED + nparam
    S = np.zeros(nrows * ROW)
    S2 = np.zeros(nrows * ROW if with_scratch else 0)
    idx = np.zeros(BLOCK if with_scratch else 0, np.int64)
    nb = np.int64(0)
    for m in range(m0, m1):
        if ISTAT[m, IS_STATUS] != STATUS_OK:
            continue
        for k in range(n):
            st(S, O_Y + k * ROW + nb, Y[m, k])
        for k in range(nparam):
            st(S, O_P + k * ROW + nb, P[m, k])
        st(S, O_HW + nb, FSTAT[m, FS_MAX_H_OMEGA])
        st(S, O_W2 + nb, -1.0)
        st(S, O_NTOT + nb, ISTAT[m, IS_NEWTON_TOTAL])
        st(S, O_NMAX + nb, ISTAT[m, IS_NEWTON_MAX])
        st(S, O_STEPS + nb, ISTAT[m, IS_STEPS])
        st(S, O_MEMBER + nb, m)
        nb += 1
    return S, S2, idx, nb, nrows


@jit
def _store_output(S, nb, n, cur, OUT, j):
    """Output j of every running lane: its state in the rows at cur."""
    for i in range(nb):
        m = int(ld(S, O_MEMBER + i))
        for k in range(n):
            OUT[m, j, k] = ld(S, cur + k * ROW + i)


@jit
def _write_back(S, nb, n, cur, done, h, Y, ISTAT, FSTAT):
    for i in range(nb):
        m = int(ld(S, O_MEMBER + i))
        for k in range(n):
            Y[m, k] = ld(S, cur + k * ROW + i)
        ISTAT[m, IS_STEPS] = int(ld(S, O_STEPS + i)) + done
        ISTAT[m, IS_NEWTON_TOTAL] = int(ld(S, O_NTOT + i))
        ISTAT[m, IS_NEWTON_MAX] = int(ld(S, O_NMAX + i))
        FSTAT[m, FS_MAX_H_OMEGA] = _max_h_omega(S, i, h)


@jit
def _retire_failed(S, nb, nrows, n, cur, done, h, Y, ISTAT, FSTAT):
    """Retire every lane whose flag is not FLAG_OK; returns the new lane count."""
    i = np.int64(0)
    while i < nb:
        if ld(S, O_FLAG + i) != FLAG_OK:
            _retire(S, i, nb, nrows, n, cur, done, h, Y, ISTAT, FSTAT)
            nb -= 1
        else:
            i += 1
    return nb


@generic(stepper_kind)
def uses_newton(stepper):
    """Whether a method's blocks need the Newton compaction scratch."""
    return False


@uses_newton.register(Variational)
def uses_newton_vi(stepper):
    return True


# the explicit step is pasted into the driver by numba (inline "ir"): LLVM then
# compiles the RK sweeps as for a loop written in place; behind an LLVM-inlined
# call the RK4 sweep measured 7-18 % slower on Zen 5
@generic(stepper_kind, inline="ir")
def block_step(stepper, model, shared, S, S2, idx, nb, nparam, nrows, n, cur, done, h, Y, ISTAT,
               FSTAT):
    """One step of lanes [0, nb) whose state is in the rows at ``cur``:
    returns (nfail, nb'), the lanes that failed and are still to be retired
    (FLAG_NEWTON or FLAG_NONFINITE, their last accepted state at ``cur``) and
    the lane count.  Explicit: from one state buffer to the other (the
    failed lanes keep their state in the source buffer)."""
    align_frame()
    par = 0 if cur == O_Y else 1
    return _rk_step(stepper.tab, model, shared, S, nb, h, par), nb


@block_step.register(Split)
def block_step_split(stepper, model, shared, S, S2, idx, nb, nparam, nrows, n, cur, done, h, Y,
                      ISTAT, FSTAT):
    """A splitting: as an explicit step, its Strang steps a stage at a time."""
    align_frame()
    par = 0 if cur == O_Y else 1
    return _split_step(stepper.factors, model, shared, S, nb, h, par), nb


@block_step.register(Variational, inline="llvm")
def block_step_vi(stepper, model, shared, S, S2, idx, nb, nparam, nrows, n, cur, done, h, Y,
                   ISTAT, FSTAT):
    """The variational integrator: its substeps factors[s]·h, each accepted
    in the rows at Y, the lanes that fail in a substep retired at once (with
    the state at the start of the step: in Y for one substep, where a failed
    step is not accepted, else copied to YB first)."""
    factors = stepper.factors
    ns = len(factors)
    start = O_Y if ns == 1 else O_YB
    if ns > 1:
        for k in range(n):
            for i in range(nb):
                st(S, O_YB + k * ROW + i, ld(S, O_Y + k * ROW + i))
    for s in range(ns):
        hs = factors[s] * h
        hn = factors[(s + 1) % ns] * h
        vv = shared_vi(shared, hs, stepper.wl, stepper.wr)
        vvn = shared_vi(shared, hn, stepper.wl, stepper.wr)
        g2 = factors[s] * factors[s]
        nfail = _vi_substep(model, shared, S, S2, idx, nb, nparam, vv, vvn, hs, hn, g2, stepper.wl,
                            stepper.wr, stepper.mode, stepper.tol, stepper.maxiter)
        if nfail:
            nb = _retire_failed(S, nb, nrows, n, start, done, h, Y, ISTAT, FSTAT)
            if nb == 0:
                break
        _vi_accept(model, shared, S, nb)
    return 0, nb


@generic(stepper_kind, inline="ir")
def next_rows(stepper, cur):
    """Where the state of a block is after a step that started at ``cur``
    (explicit: the other state buffer)."""
    return O_YB if cur == O_Y else O_Y


@next_rows.register(Variational, inline="llvm")
def next_rows_vi(stepper, cur):
    return O_Y


@jit(nogil=True)
def advance_blocks(stepper, model, shared, Y, P, b0, b1, h, every, n_out, OUT, j0, ISTAT, FSTAT):
    """Blocks b0 … b1−1, ``every`` × ``n_out`` steps of the method whose
    kernel data is ``stepper`` (:mod:`.steppers`; see the module docstring)."""
    align_frame()
    N, n = Y.shape
    nparam = P.shape[1] if shared is None else 0
    for bi in range(b0, b1):
        m0 = bi * BLOCK
        S, S2, idx, nb, nrows = _fill_block(Y, P, m0, min(N, m0 + BLOCK), nparam,
                                            uses_newton(stepper), ISTAT, FSTAT)
        if nb == 0:
            continue
        done = np.int64(0)
        cur = O_Y
        for j in range(n_out):
            for _ in range(every):
                nfail, nb = block_step(stepper, model, shared, S, S2, idx, nb, nparam, nrows, n,
                                       cur, done, h, Y, ISTAT, FSTAT)
                if nfail:
                    nb = _retire_failed(S, nb, nrows, n, cur, done, h, Y, ISTAT, FSTAT)
                cur = next_rows(stepper, cur)
                if nb == 0:
                    break
                done += 1
            if nb == 0:
                break
            _store_output(S, nb, n, cur, OUT, j0 + j)
        _write_back(S, nb, n, cur, done, h, Y, ISTAT, FSTAT)

