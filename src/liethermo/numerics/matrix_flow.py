"""The steps and the run loop of a Zeitlin fluid, written once for every
geometry and every array namespace.

A Zeitlin fluid's state is a batch of vorticity matrices W (members × N × N)
and the heat q each member has made.  Its methods are

* ``split`` and its compositions: the exact dissipative flow over half a
  substep, the Lie–Poisson midpoint step (a fixed point) over a substep, the
  exact flow again (adjacent half flows merged into one), with the substep
  factors of :mod:`.compositions`;
* ``rk4``: classical Runge–Kutta on (W, q).

What is specific to a geometry (the sphere's Laplacian and modes, the
torus's) and to a backend (numpy with numba kernels, or an array namespace
such as CuPy) comes in an ``ops`` object with

* ``xp`` — the array module;
* ``viscous_flow(W, t, nu) -> (W, dq)`` — the exact dissipative flow over t;
* ``isomp(W, h, tol, max_iter, guess) -> (W, iterations, failed, D)`` — one
  midpoint step and its fixed point D;
* ``rhs(W, nu) -> (dW, dq)`` — the vector field;
* ``asarray(a)`` (host to backend, a copy) and ``to_host(a)``;
* ``synchronize()`` — wait for the device.

:func:`drive` runs the members of a batch: the members that fail (fixed
point not converged, non-finite state) leave the batch with their status and
step, and ``record(j, members, W, q)`` gets the kept output times on the host.
"""

from __future__ import annotations

import numpy as np

from .compositions import COMPOSITION_FACTORS

#: per-member status of a run
STATUS_OK, STATUS_NOT_CONVERGED, STATUS_NON_FINITE = 0, 1, 2


def factors(method: str, composition: str) -> tuple[float, ...]:
    """The substep factors of a split method (``split``: one substep)."""
    if method == "split":
        return (1.0,)
    return COMPOSITION_FACTORS[(composition, 4 if method == "split4" else 6)]


def budget_members(scene) -> int:
    """The batch size that sets the predictor's order (:class:`Predictor`):
    the scene's chunk of members, not the chunk computed."""
    return min(int(scene["ensemble"]["members"]), int(scene["output"]["member_chunk"]))


class Predictor:
    """The first guess of each substep's fixed point: the same substep's
    solutions D of the last steps, extrapolated by a polynomial (order 4:
    4D₁ − 6D₂ + 4D₃ − D₄).  At h = 0.01 s, N = 32 on the sphere this starts the
    iteration close enough to save about 3 of 7 iterations (6.9 → 4.1 per
    step); its memory (order × substeps × members × N² complex) is kept under
    ``budget`` bytes by lowering the order.

    The order is set by ``budget_members`` (default M): a run in member chunks
    gives every chunk the order of the largest, so that a member's bits do not
    depend on the chunk it is computed in."""

    COEF = {1: (1.0,), 2: (2.0, -1.0), 3: (3.0, -3.0, 1.0), 4: (4.0, -6.0, 4.0, -1.0)}

    def __init__(self, substeps: int, M: int, N: int, order: int = 4, budget: int = 2**29,
                 budget_members: int | None = None, xp=np):
        per = substeps * (M if budget_members is None else budget_members) * N * N * 16
        self.order = min(order, budget // per) if per else order
        self.shape = (M, N, N)
        self.xp = xp
        self.hist: list[list] = [[] for _ in range(substeps)]

    def guess(self, i: int, active):
        H = self.hist[i]
        p = min(self.order, len(H))
        if p == 0:
            return None
        c = self.COEF[p]
        g = c[0] * H[-1][active]
        for j in range(1, p):
            g += c[j] * H[-1 - j][active]
        return g

    def remember(self, i: int, active, D) -> None:
        if self.order == 0:
            return
        H = self.hist[i]
        arr = H.pop(0) if len(H) == self.order else self.xp.zeros(self.shape, dtype=self.xp.complex128)
        arr[active] = D
        H.append(arr)


def split_step(ops, W, q, h, nu, fac, tol, max_iter, guess=None, predictor: Predictor | None = None,
               active=None):
    """One step of the split family on a batch: returns W', q', iterations,
    failed, and the last substep's fixed point D per unit substep.  Each
    substep's fixed point starts from ``predictor``'s extrapolation (members
    ``active`` of its history) where it has one, else from the previous
    substep's D scaled to this substep (``guess``: the last step's, per unit)."""
    xp = ops.xp
    its = xp.zeros(W.shape[0], dtype=xp.int64)
    failed = xp.zeros(W.shape[0], dtype=bool)
    pending = fac[0] * h / 2.0  # adjacent viscous half flows merge into one exact flow
    D = guess  # nearly linear in the substep: scaled from the last one
    for i, f in enumerate(fac):
        W, dq = ops.viscous_flow(W, pending, nu)
        q = q + dq
        g = predictor.guess(i, active) if predictor is not None else None
        if g is None and D is not None:
            g = D * f
        W, it, fl, Df = ops.isomp(W, f * h, tol, max_iter, g)
        if predictor is not None:
            predictor.remember(i, active, Df)
        D = Df / f
        its += it
        failed |= fl
        pending = f * h / 2.0 + (fac[i + 1] * h / 2.0 if i + 1 < len(fac) else 0.0)
    W, dq = ops.viscous_flow(W, pending, nu)
    return W, q + dq, its, failed, D


def rk4(f, y: tuple, h: float) -> tuple:
    """One classical Runge–Kutta 4 step of a state given as a tuple of arrays,
    ``f(y) -> ẏ`` (a tuple of the same shapes)."""
    k1 = f(y)
    k2 = f(tuple(a + 0.5 * h * k for a, k in zip(y, k1)))
    k3 = f(tuple(a + 0.5 * h * k for a, k in zip(y, k2)))
    k4 = f(tuple(a + h * k for a, k in zip(y, k3)))
    return tuple(a + (h / 6.0) * (c1 + 2.0 * c2 + 2.0 * c3 + c4) for a, c1, c2, c3, c4 in zip(y, k1, k2, k3, k4))


def rk4_step(ops, W, q, h, nu):
    """One classical Runge–Kutta 4 step of (W, q) (q does not act back on W)."""
    return rk4(lambda y: ops.rhs(y[0], nu), (W, q), h)


def run_members(state0: tuple, step, record, *, xp, to_host, steps: int, every: int, bar=None,
                check_stop=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The member bookkeeping of every matrix fluid's run: ``steps`` steps of the
    batch ``state0`` (a tuple of backend arrays with a leading member axis).
    ``step(state, k, act) -> (state, iterations, status)`` advances the members
    ``act`` (their part of the state; iterations and status per member on the
    host, status 0 where the step went well); a member with a status, or a
    non-finite state, leaves the batch with its status (:data:`STATUS_NON_FINITE`
    for the latter) and step, without numpy's overflow warnings on the way.  Every
    ``every`` steps ``record(j, members, state)`` gets the members still running, on
    the host (a member's huge but finite values give infinite diagnostics, silently).  Returns ``(mean iterations
    per step (members, outputs), status (members,), failed_step (members,), −1
    where none)``; ``bar.update(1)`` after each step, ``check_stop()`` before each."""
    M = state0[0].shape[0]
    n_out = steps // every + 1
    its = np.zeros((M, n_out))
    status = np.zeros(M, dtype=np.int8)
    failed_step = np.full(M, -1, dtype=np.int64)
    state = tuple(state0)
    active = np.arange(M)
    acc_its = np.zeros(M)
    for k in range(1, steps + 1):
        if check_stop is not None:
            check_stop()
        if active.size == 0:
            break
        act = xp.asarray(active)
        with np.errstate(over="ignore", invalid="ignore"):  # a member that blows up is flagged below
            sub, it, st = step(tuple(a[act] for a in state), k, act)
        acc_its[active] += it
        fin = None
        for a in sub:
            f = xp.isfinite(a).reshape(a.shape[0], -1).all(axis=1)
            fin = f if fin is None else fin & f
        finite = to_host(fin)
        st = np.where((st == STATUS_OK) & ~finite, STATUS_NON_FINITE, st).astype(np.int8)
        bad = st != STATUS_OK
        status[active[bad]] = st[bad]
        failed_step[active[bad]] = k
        for a, s in zip(state, sub):
            a[act] = s
        active = active[~bad]
        if k % every == 0:
            j = k // every
            act = xp.asarray(active)
            with np.errstate(over="ignore", invalid="ignore"):  # huge but finite values: inf diagnostics
                record(j, active, tuple(to_host(a[act]) for a in state))
            its[active, j] = acc_its[active] / every
            acc_its[:] = 0.0
        if bar is not None:
            bar.update(1)
    return its, status, failed_step


def drive(ops, W0: np.ndarray, record, *, method: str, composition: str, h: float, steps: int, every: int,
          nu: float, tol: float, max_iter: int, budget_members: int | None = None, bar=None,
          check_stop=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the members ``W0`` (host array, members × N × N) ``steps`` steps of
    ``method`` (``split``, ``split4``, ``split6`` or ``rk4``).  Every ``every``
    steps, ``record(j, members, W, q)`` gets the members still running, on the
    host.  Returns ``(iterations per step (members, outputs), status (members,),
    failed_step (members,), −1 where none))``; ``bar.update(1)`` after each step,
    ``check_stop()`` before each."""
    xp = ops.xp
    M, N = W0.shape[0], W0.shape[-1]
    fac = factors(method, composition) if method != "rk4" else ()
    predictor = Predictor(len(fac), M, N, budget_members=budget_members, xp=xp) if method != "rk4" else None
    guess = xp.zeros_like(ops.asarray(W0))
    none = np.zeros(M)

    def step(state, k, act):
        Wa, qa = state
        if method == "rk4":
            Wa, qa = rk4_step(ops, Wa, qa, h, nu)
            return (Wa, qa), none[:Wa.shape[0]], np.zeros(Wa.shape[0], dtype=np.int8)
        Wa, qa, it, bad, Da = split_step(ops, Wa, qa, h, nu, fac, tol, max_iter,
                                         None if k == 1 else guess[act], predictor, act)
        guess[act] = Da
        return (Wa, qa), ops.to_host(it), np.where(ops.to_host(bad), STATUS_NOT_CONVERGED, STATUS_OK)

    out = run_members((ops.asarray(W0), xp.zeros(M)), step, lambda j, m, s: record(j, m, *s), xp=xp,
                      to_host=ops.to_host, steps=steps, every=every, bar=bar, check_stop=check_stop)
    ops.synchronize()
    return out
