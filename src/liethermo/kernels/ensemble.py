"""Ensemble drivers: advance N members, each with its own state and parameters.

``advance_member`` is the one-trajectory unit that tests read;
``advance_ensemble`` loops ``prange`` over members and calls it.  Both work in
place on caller-allocated arrays so that a long run can be advanced in chunks
(for a progress bar, chunked output and resumption):

* ``Y``     (N, n)          state, flat layout of model.py (n = 7 or 16)
* ``P``     (N, NPARAM)     parameters, layout of model.py
* ``OUT``   (N, n_out, n)   receives the state after every ``every`` steps
* ``ISTAT`` (N, NISTAT)     int64: status, failing step, Newton iterations
                            (total, max per step), steps done, and the
                            member's own reference substep count (read
                            when the ``nsub`` argument is ≤ 0; set by the
                            caller from the member's initial data, so a
                            member never depends on its neighbours)
* ``FSTAT`` (N, NFSTAT)     float64: max h|Ω_k| over the steps taken

Status codes (per member, never per ensemble): ``STATUS_OK``,
``STATUS_NEWTON`` (the VI's Newton iteration did not converge or met a
singular Jacobian: the step was not accepted), ``STATUS_NONFINITE`` (the
state became inf/NaN, e.g. explicit RK2 blowing up).  A failed member stops
advancing; its later outputs are left untouched (callers pre-fill NaN) and
the other members go on.

(No division by a run constant happens per step in the kernels this module
calls: model.rhs, rk, vi multiply by precomputed reciprocals.)
"""

from __future__ import annotations

import numpy as np

from ._jit import jit, pjit, prange
from .rk import DOP853_STAGES, dop853_step, rk2_step, rk4_step
from .vi import NEWTON_OK, vi_step

METHOD_VI, METHOD_RK2, METHOD_RK4, METHOD_REFERENCE = 0, 1, 2, 3

STATUS_OK, STATUS_NEWTON, STATUS_NONFINITE = 0, 1, 2

IS_STATUS, IS_FAIL_STEP, IS_NEWTON_TOTAL, IS_NEWTON_MAX, IS_STEPS, IS_NSUB = range(6)
NISTAT = 6
FS_MAX_H_OMEGA = 0
NFSTAT = 1


@jit
def _all_finite(y, n):
    for i in range(n):
        if not np.isfinite(y[i]):
            return False
    return True


@jit
def advance_member(method, y, p, h, n, every, n_out, alpha, beta, tol, maxiter,
                   nsub, A, B, out, istat, fstat):
    """Advance one member by ``every * n_out`` steps of size h, storing the
    state after every ``every`` steps in ``out[0:n_out]``."""
    if istat[IS_STATUS] != STATUS_OK:
        return
    ynew = np.empty(n)
    work = np.empty((DOP853_STAGES, n))
    tmp = np.empty(n)
    if nsub <= 0:
        nsub = istat[IS_NSUB]
    hs = h / nsub
    for j in range(n_out):
        for _ in range(every):
            k = istat[IS_STEPS]
            hw = h * np.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
            if hw > fstat[FS_MAX_H_OMEGA]:
                fstat[FS_MAX_H_OMEGA] = hw
            if method == METHOD_VI:
                code, its = vi_step(y, p, h, n, alpha, beta, tol, maxiter, ynew)
                istat[IS_NEWTON_TOTAL] += its
                if its > istat[IS_NEWTON_MAX]:
                    istat[IS_NEWTON_MAX] = its
                if code != NEWTON_OK:
                    istat[IS_STATUS] = STATUS_NEWTON
                    istat[IS_FAIL_STEP] = k + 1
                    return
            elif method == METHOD_RK2:
                rk2_step(y, p, h, n, work, ynew)
            elif method == METHOD_RK4:
                rk4_step(y, p, h, n, work, ynew)
            else:
                for i in range(n):
                    tmp[i] = y[i]
                for _s in range(nsub):
                    dop853_step(tmp, p, hs, n, A, B, work, ynew, tmp)
                for i in range(n):
                    ynew[i] = tmp[i]
            if not _all_finite(ynew, n):
                istat[IS_STATUS] = STATUS_NONFINITE
                istat[IS_FAIL_STEP] = k + 1
                return
            for i in range(n):
                y[i] = ynew[i]
            istat[IS_STEPS] = k + 1
        for i in range(n):
            out[j, i] = y[i]


@pjit
def advance_ensemble(method, Y, P, h, every, n_out, alpha, beta, tol, maxiter,
                     nsub, A, B, OUT, ISTAT, FSTAT):
    """prange over members of :func:`advance_member` (same arguments, batched)."""
    N, n = Y.shape
    for m in prange(N):
        advance_member(method, Y[m], P[m], h, n, every, n_out, alpha, beta, tol,
                       maxiter, nsub, A, B, OUT[m], ISTAT[m], FSTAT[m])
