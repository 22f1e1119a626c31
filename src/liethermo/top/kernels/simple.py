"""The straightforward ensemble kernel: one member at a time.

:func:`advance_members` advances members ``m0 … m1−1`` in place, by the
step of the method whose kernel data (a stepper, :mod:`.steppers`) it is
given; :mod:`liethermo.top.kernels.parallel` runs member ranges
on threads (the functions release the GIL).  They are the reference the
vectorized block kernel (:mod:`.fast`) is tested against, bitwise: both call
the same lane functions.  Arrays (all caller-allocated):

* ``Y``     (N, n)          state, columns of :func:`.layout.state_layout`
* ``P``     (N, nparam)     per-member model parameters (the floats of the
                            model, :func:`.gen.flatten` order); read only
                            when ``shared`` is None
* ``OUT``   (N, j0 + n_out, n) receives the state after every ``every`` steps
                            in ``OUT[:, j0:j0 + n_out]`` (a run passes its whole
                            output array, so the kernels' types do not depend on
                            the member count)
* ``ISTAT`` (N, NISTAT)     int64: status, failing step, Newton iterations
                            (total, max per solve), steps done, reference
                            substeps (``rk`` with the reference tableau)
* ``FSTAT`` (N, NFSTAT)     float64: max |h_i|·|Ω| over the (sub)steps taken

``model`` is the model of the run (its values are used when ``shared`` is
the same model, i.e. when every member has the same parameters); its type
fixes the terms the kernel is compiled for.

Status codes (per member, never per ensemble): ``STATUS_OK``,
``STATUS_NEWTON`` (the Newton iteration did not converge or met a singular
Jacobian: the step was not accepted), ``STATUS_NONFINITE`` (the state became
inf/NaN, e.g. explicit RK2 blowing up).  A failed member stops advancing:
``Y`` keeps its last accepted state (the start of the failing step), its
later outputs are left untouched (callers pre-fill NaN) and the other
members go on.
"""

from __future__ import annotations

import math

import numpy as np

from ._jit import align_frame, jit, lane
from .dispatch import generic
from .gen import abs_or_zero, tree_finite, unflatten
from .layout import (FS_MAX_H_OMEGA, IS_FAIL_STEP, IS_NEWTON_MAX, IS_NEWTON_TOTAL, IS_NSUB,
                     IS_STATUS, IS_STEPS, NEWTON_OK, STATUS_NEWTON, STATUS_NONFINITE, STATUS_OK,
                     load_rk_state, load_split_state, load_vi_state, store_rk_state,
                     store_split_state, store_vi_state)
from .rk import explicit_step
from .split import split_speed2
from .so3 import norm2_lane
from .steppers import Split, Variational, stepper_kind
from .equations import omega_rate
from .vi import (add_opt, entropy_predictor, momentum_map, newton_solve, node_rhs, vi_advance,
                 vi_coefficients)


@lane
def member_model(shared, template, P, m):
    """The model of member m: ``shared`` if given, else its parameter row."""
    if shared is None:
        return unflatten(template, P[m], 0, 1)
    return shared


@lane
def max_h_omega(entry, h, w2max):
    """The running max |h|·|Ω| (FSTAT) after a call whose max |Ω|² (times the
    squared substep factor) was w2max (−1: no step)."""
    if not (w2max >= 0.0):
        return entry
    hw = abs(h) * math.sqrt(w2max)
    return hw if hw > entry else entry


@generic(stepper_kind)
def member_load(stepper, md, buf, base, stride):
    """The state of a member from ``buf[base + c·stride]`` (the layout of its method family)."""
    return load_rk_state(md, buf, base, stride)


@member_load.register(Variational)
def member_load_vi(stepper, md, buf, base, stride):
    return load_vi_state(md, buf, base, stride)


@member_load.register(Split)
def member_load_split(stepper, md, buf, base, stride):
    return load_split_state(md, buf, base, stride)


@generic(stepper_kind)
def member_store(stepper, md, buf, base, stride, y):
    """Store a member's state y into ``buf[base + c·stride]``."""
    store_rk_state(md, buf, base, stride, y)


@member_store.register(Variational)
def member_store_vi(stepper, md, buf, base, stride, y):
    store_vi_state(md, buf, base, stride, y)


@member_store.register(Split)
def member_store_split(stepper, md, buf, base, stride, y):
    store_split_state(md, buf, base, stride, y)


@generic(stepper_kind)
def speed2(stepper, md, y):
    """|Ω|² of an explicit method's state (the statistic max h|Ω|)."""
    w = y[0]
    return norm2_lane(w[0], w[1], w[2])


@speed2.register(Variational)
def speed2_vi(stepper, md, y):
    return 0.0


@speed2.register(Split)
def speed2_split(stepper, md, y):
    return split_speed2(md, y)


@generic(stepper_kind)
def member_sizes(stepper, h, ISTAT, m):
    """(h_s, n): what a step of member m is made of, worked out once per
    member.  Explicit: ``nsub`` substeps of h/nsub (0: the member's own
    count, ``ISTAT[m, IS_NSUB]``)."""
    ns = stepper.nsub if stepper.nsub > 0 else ISTAT[m, IS_NSUB]
    return h / ns, ns


@member_sizes.register(Variational)
def member_sizes_vi(stepper, h, ISTAT, m):
    return h, np.int64(1)


@generic(stepper_kind)
def member_step(stepper, md, y, h, sizes, w2, ISTAT, m):
    """One step of size h of member m from its state y: (y', w2', status),
    with w2' the running max |Ω|² (times the squared substep factor) and y'
    the state at the start of the step when status is not STATUS_OK.
    Explicit: the substeps ``sizes`` of the tableau (or the splitting)."""
    hs, ns = sizes
    ww = speed2(stepper, md, y)
    w2 = ww if ww > w2 else w2
    yn = y
    for _s in range(ns):
        yn, ok = explicit_step(stepper.tab, md, yn, hs, True)
    if not tree_finite(yn):
        return y, w2, STATUS_NONFINITE
    return yn, w2, STATUS_OK


@member_step.register(Variational)
def member_step_vi(stepper, md, y, h, sizes, w2, ISTAT, m):
    """The variational integrator: the composition of substeps of sizes
    factors[i]·h (one substep for ``vi``), each a Newton solve."""
    factors = stepper.factors
    ns = len(factors)
    ystart = y
    for i in range(ns):
        v = vi_coefficients(md, factors[i] * h, stepper.wl, stepper.wr)
        vn = vi_coefficients(md, factors[(i + 1) % ns] * h, stepper.wl, stepper.wr)
        X = y[0]
        ww = (factors[i] * factors[i]) * norm2_lane(X[0], X[1], X[2])
        w2 = ww if ww > w2 else w2
        G1, s1, mu1, R1, b, xp, ps, sc0, scs, ok = vi_advance(md, v, vn, y, vn.h, stepper.mode, True)
        X1, xs, code, its = newton_solve(md, vn, b, xp, ps, s1, sc0, scs, stepper.tol,
                                         stepper.maxiter)
        ISTAT[m, IS_NEWTON_TOTAL] += its
        if its > ISTAT[m, IS_NEWTON_MAX]:
            ISTAT[m, IS_NEWTON_MAX] = its
        yn = (X1, G1, s1, mu1, add_opt(s1, xs), R1)
        if code != NEWTON_OK:
            return ystart, w2, STATUS_NEWTON  # back to the start of the failing step
        if not tree_finite(yn):
            return ystart, w2, STATUS_NONFINITE
        y = yn
    return y, w2, STATUS_OK


@lane
def take_steps(stepper, md, y, h, sizes, w2, every, ISTAT, m):
    """``every`` steps of member m from its state y: (y', w2', failed).  A
    step that fails sets the member's status and failing step, and y' is
    then the state at the start of that step.  The member loops of the CPU
    (:func:`advance_members`) and of the GPU (:mod:`.cuda`) both run this."""
    for _ in range(every):
        k = ISTAT[m, IS_STEPS]
        yn, w2, status = member_step(stepper, md, y, h, sizes, w2, ISTAT, m)
        if status != STATUS_OK:
            ISTAT[m, IS_STATUS] = status
            ISTAT[m, IS_FAIL_STEP] = k + 1
            return y, w2, True
        y = yn
        ISTAT[m, IS_STEPS] = k + 1
    return y, w2, False


def array_ndim(a) -> int:
    """Key: the number of dimensions of an array (or of its numba type)."""
    return a.ndim


@generic(array_ndim)
def output_slot(OUT, j, m, n, N):
    """(buffer, base, stride) of output j of member m (of N, state size n)
    in the flat outputs of every member, member index fastest (the GPU:
    ``j·n·N + c·N + m``)."""
    return OUT, j * n * N + m, N


@output_slot.register(2)
def output_slot_rows(OUT, j, m, n, N):
    """In the (outputs, n) rows of the member itself (the CPU)."""
    return OUT[j], 0, 1


@lane
def advance_member(stepper, md, Y, base, stride, OUT, h, every, n_out, ISTAT, FSTAT, m, n, N):
    """Member m: its state from ``Y[base + c·stride]``, ``every`` × ``n_out``
    steps with an output after every ``every`` (:func:`output_slot`), its
    state back and its max |h|·|Ω|; returns how many outputs it wrote.  The
    CPU's member loop (:func:`advance_members`) and the GPU's thread
    (:mod:`.cuda`) both run this."""
    y = member_load(stepper, md, Y, base, stride)
    sizes = member_sizes(stepper, h, ISTAT, m)
    w2 = -1.0
    jdone = 0
    for j in range(n_out):
        y, w2, failed = take_steps(stepper, md, y, h, sizes, w2, every, ISTAT, m)
        if failed:
            break
        buf, ob, os = output_slot(OUT, j, m, n, N)
        member_store(stepper, md, buf, ob, os, y)
        jdone = j + 1
    member_store(stepper, md, Y, base, stride, y)
    FSTAT[m, FS_MAX_H_OMEGA] = max_h_omega(FSTAT[m, FS_MAX_H_OMEGA], h, w2)
    return jdone


@jit(nogil=True)
def advance_members(stepper, model, shared, Y, P, m0, m1, h, every, n_out, OUT, j0, ISTAT, FSTAT):
    """Members m0 … m1−1, ``every`` × ``n_out`` steps of the method whose
    kernel data is ``stepper`` (:mod:`.steppers`), output after every
    ``every`` steps into ``OUT[:, j0:j0 + n_out]``."""
    align_frame()
    for m in range(m0, m1):
        if ISTAT[m, IS_STATUS] != STATUS_OK:
            continue
        md = member_model(shared, model, P, m)
        advance_member(stepper, md, Y[m], 0, 1, OUT[m, j0:j0 + n_out], h, every, n_out, ISTAT, FSTAT, m,
                       Y.shape[1], Y.shape[0])


@jit(nogil=True)
def vi_start_members(model, shared, Y, P, m0, m1, h0, wl, wr, legendre, tol, maxiter, ISTAT):
    """The first step velocity X₀ and node momentum μ₀ of members m0 … m1−1,
    for a first (sub)step of size h0.  On entry the ``omega_step`` columns of
    Y hold the velocity to start from and ``momentum`` 𝕀Ω(0):

    * ``legendre`` False (the paper's start, and the staggered one): X₀ is
      given; μ₀ is its node momentum (:func:`.vi.momentum_map`);
    * ``legendre`` True: μ₀ = 𝕀Ω(0) is given; X₀ solves the Newton equation
      from it (a member whose solve fails gets STATUS_NEWTON at step 1)."""
    align_frame()
    for m in range(m0, m1):
        if ISTAT[m, IS_STATUS] != STATUS_OK:
            continue
        md = member_model(shared, model, P, m)
        X, G, s, mu, sn, R = load_vi_state(md, Y[m], 0, 1)
        v = vi_coefficients(md, h0, wl, wr)
        if legendre:
            r0, r1, r2 = node_rhs(md, v, mu, G)
            b = (-r0, -r1, -r2)
            d0, d1, d2 = omega_rate(md, X[0], X[1], X[2], G[0], G[1], G[2], s, True)
            hp = 0.5 * h0
            xp = (X[0] + hp * d0, X[1] + hp * d1, X[2] + hp * d2)
            ps = entropy_predictor(md.inertia, md, v, X, s)
            X1, xs, code, its = newton_solve(md, v, b, xp, ps, s, max(abs(X[0]), abs(X[1]),
                                                                      abs(X[2])), abs_or_zero(s), tol, maxiter)
            if code != NEWTON_OK or not tree_finite((X1, xs)):
                ISTAT[m, IS_STATUS] = STATUS_NEWTON
                ISTAT[m, IS_FAIL_STEP] = 1
                continue
            store_vi_state(md, Y[m], 0, 1, (X1, G, s, mu, add_opt(s, xs), R))
        else:
            mu1 = momentum_map(md, v, X[0], X[1], X[2], G[0], G[1], G[2])
            store_vi_state(md, Y[m], 0, 1, (X, G, s, mu1, sn, R))
