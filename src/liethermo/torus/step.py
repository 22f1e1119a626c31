"""The steps of the torus fluid over a batch of members, and its run loop
(no xarray, no I/O).

A member's state is (W, S).  The methods:

* ``cmp`` (default), ``magmp``, ``isomp`` — the Strang splitting
  V(h/2) C(h/2) I(h) C(h/2) V(h/2) with the ideal step I of that kind
  (:func:`.kernels.ideal_step`), V the viscous step and C the conduction step;
  ``isomp`` is MagMP's form at α = 0 (refused with buoyancy);
* ``cmp4``, ``magmp4``, ``isomp4`` — the ideal step composed to order 4
  (``integrator.composition``), at ν = κ = 0 only;
* ``rk4`` — classical Runge–Kutta 4 on the continuous right-hand side
  (:func:`.kernels.rhs_thermo`);
* ``reference`` — DOP853 (scipy) at rtol :data:`REFERENCE_RTOL` on the same right-hand
  side, per member, restarted at every step (any h).

Every method but ``reference`` runs on the array module of its basis
(``b.xp``: numpy, or CuPy on a GPU, :data:`XP_METHODS`); the run loop moves
only the kept outputs and the per-member flags to the host.

The member bookkeeping (statuses, the members that leave, the outputs) is the
shared :func:`liethermo.numerics.matrix_flow.run_members`; the fixed point's
first guess is the shared :class:`liethermo.numerics.matrix_flow.Predictor`.
"""

from __future__ import annotations

import numpy as np

from ..gpu import to_host
from ..numerics import matrix_flow as mf
from ..numerics.compositions import COMPOSITION_FACTORS
from . import kernels as tk

REFERENCE_RTOL = 1e-12
IDEAL = {"cmp": "cmp", "magmp": "magmp", "isomp": "magmp"}
METHODS = ("cmp", "magmp", "isomp", "cmp4", "magmp4", "isomp4", "rk4", "reference")


COMPOSED = ("cmp4", "magmp4", "isomp4")
#: the methods that run on an array namespace other than numpy (CuPy); the reference uses scipy on the host
XP_METHODS = tuple(m for m in METHODS if m != "reference")


def ideal_kind(method: str) -> str | None:
    return IDEAL.get(method[:-1] if method in COMPOSED else method)


def substep_factors(method: str, composition: str) -> tuple[float, ...]:
    if method in COMPOSED:
        return COMPOSITION_FACTORS[(composition, 4)]
    return (1.0,)


def check_method(method: str, th: tk.Thermo) -> None:
    """Refuse, in one line, a method the physics rules out."""
    if method not in METHODS:
        raise ValueError(f"integrator.method {method!r} is not a torus method ({', '.join(METHODS)})")
    if method in COMPOSED and (th.nu or th.kappa):
        raise ValueError(f"integrator.method {method!r}: the order-4 composition runs at ν = κ = 0 only (its "
                         "negative sub-step would run viscosity and conduction backwards); use "
                         f"{method[:-1]!r}")
    if method.startswith("isomp") and th.alpha:
        raise ValueError(f"integrator.method {method!r}: IsoMP has no buoyancy term; with thermo.buoyancy > 0 "
                         "use \"magmp\" (its Lie–Poisson form with buoyancy) or \"cmp\"")


def check_xp_method(method: str) -> None:
    """Refuse, in one line, a method the array-namespace backends do not run."""
    if method not in XP_METHODS:
        raise ValueError(f"method {method!r} does not run on the array-namespace backends "
                         f"(they run {', '.join(XP_METHODS)}; the reference runs on the CPU)")


def memory_bytes(N: int, members: int, method: str, composition: str = "triple_jump",
                 budget_members: int | None = None) -> int:
    """An upper estimate of the device memory a run of ``members`` members takes
    on an array namespace (:func:`drive` with ``b.xp`` CuPy), measured with
    numpy's allocations: at most about 28 arrays of the batch's size at once
    (24 for rk4; the ideal step's fixed point, its Cayley factors, the state and
    its active members' copy) besides the predictor's history, and the basis and
    one member's V and C (24 matrices)."""
    check_xp_method(method)
    unit = members * N * N * 16
    if ideal_kind(method) is None:
        arrays = 24 * unit
    else:
        pred = mf.Predictor(len(substep_factors(method, composition)), members, N, budget_members=budget_members)
        arrays = 28 * unit + pred.order * len(pred.hist) * unit
    return int(arrays + (96 + 24 * 16) * N * N)


def dissipative(W, S, tau: float, th: tk.Thermo, b: tk.Basis, status: np.ndarray, count, order: str):
    """V(τ) then C(τ) (``order="VC"``) or C then V (``"CV"``) per member; a member that
    fails gets its status (and keeps its state)."""
    if not (th.nu or th.kappa) or tau == 0.0:
        return W, S
    W = W.copy()
    S = S.copy()
    for i in range(W.shape[0]):
        if status[i]:
            continue
        w, s = W[i:i + 1], S[i:i + 1]
        try:
            for part in order:
                if part == "V":
                    w, s = tk.viscous_step(w, s, tau, th, b)
                else:
                    s = tk.conduction_step(s, tau, th, b, count)
        except tk.SubstepFailure as e:
            status[i] = e.status
            continue
        W[i], S[i] = w[0], s[0]
    return W, S


def strang_step(W, S, h: float, th: tk.Thermo, b: tk.Basis, *, method: str, composition: str, tol: float,
                max_iter: int, predictor=None, active=None, count=None):
    """One step of the splitting on a batch: W′, S′, fixed-point iterations, status per member."""
    kind = ideal_kind(method)
    status = np.zeros(W.shape[0], dtype=np.int8)
    its = np.zeros(W.shape[0])
    W, S = dissipative(W, S, 0.5 * h, th, b, status, count, "VC")
    for i, f in enumerate(substep_factors(method, composition)):
        g = predictor.guess(i, active) if predictor is not None else None
        W1, S1, it, failed, D = tk.ideal_step(W, S, f * h, th.alpha, b, kind=kind, tol=tol, max_iter=max_iter,
                                              guess=g)
        if predictor is not None:
            predictor.remember(i, active, D)
        W, S = W1, S1
        its += it
        status[(status == 0) & failed] = tk.STATUS_NOT_CONVERGED
    W, S = dissipative(W, S, 0.5 * h, th, b, status, count, "CV")
    return W, S, its, status


def rk4_step(W, S, h: float, th: tk.Thermo, b: tk.Basis):
    """One classical RK4 step on the continuous right-hand side."""
    return mf.rk4(lambda z: tk.rhs_thermo(z[0], z[1], th, b), (W, S), h)


def reference_step(W, S, h: float, th: tk.Thermo, b: tk.Basis):
    """DOP853 over h per member at rtol REFERENCE_RTOL; status 2 where it fails."""
    from scipy.integrate import solve_ivp

    N = b.N
    W, S = W.copy(), S.copy()
    status = np.zeros(W.shape[0], dtype=np.int8)

    def f(t, y):
        z = y.view(np.complex128).reshape(2, 1, N, N)
        dW, dS = tk.rhs_thermo(z[0], z[1], th, b)
        return np.concatenate([dW.ravel(), dS.ravel()]).view(np.float64)

    for i in range(W.shape[0]):
        y0 = np.concatenate([W[i].ravel(), S[i].ravel()]).view(np.float64)
        atol = REFERENCE_RTOL * max(np.abs(y0).max(), 1e-300)
        sol = solve_ivp(f, (0.0, h), y0, method="DOP853", rtol=REFERENCE_RTOL, atol=atol, t_eval=[h])
        if not sol.success:
            status[i] = tk.STATUS_NON_FINITE
            continue
        z = sol.y[:, -1].copy().view(np.complex128).reshape(2, N, N)
        W[i], S[i] = tk.herm(z[0]), tk.herm(z[1])
    return W, S, status


def theta_status(S, th: tk.Thermo, b: tk.Basis, status: np.ndarray) -> np.ndarray:
    """Flag (status 3) the members whose Θ is not positive definite (α > 0; at α = 0 Θ = T₀e^{S/c} ≻ 0)."""
    if not th.alpha:
        return status
    lo, _ = tk.theta_range(S, th, b)
    lo = np.asarray(tk._to_host(lo))
    return np.where((status == 0) & ~(lo > 0), tk.STATUS_THETA, status).astype(np.int8)


def drive(W0, S0, record, *, th: tk.Thermo, b: tk.Basis, method: str, composition: str = "triple_jump",
          h: float, steps: int, every: int, tol: float = 1e-14, max_iter: int = 100,
          budget_members: int | None = None, bar=None, check_stop=None, count=None):
    """Run the members (W0, S0) ``steps`` steps; ``record(j, members, (W, S))`` at every
    ``every``-th step.  Returns (iterations (members, outputs), status, failed_step)."""
    check_method(method, th)
    xp = b.xp
    if xp is not np:
        check_xp_method(method)
    M, N = W0.shape[0], b.N
    count = count if count is not None else tk.ConductionCount()
    kind = ideal_kind(method)
    predictor = None
    if kind is not None:
        predictor = mf.Predictor(len(substep_factors(method, composition)), M, N, budget_members=budget_members,
                                 xp=xp)

    def step(state, k, act):
        W, S = state
        its = np.zeros(W.shape[0])
        if method == "reference":
            W, S, st = reference_step(W, S, h, th, b)
        elif method == "rk4":
            W, S = rk4_step(W, S, h, th, b)
            st = np.zeros(W.shape[0], dtype=np.int8)
        else:
            W, S, its, st = strang_step(W, S, h, th, b, method=method, composition=composition, tol=tol,
                                        max_iter=max_iter, predictor=predictor, active=act, count=count)
        return (W, S), its, theta_status(S, th, b, st)

    return mf.run_members((xp.array(W0, copy=True), xp.array(S0, copy=True)), step, record, xp=xp,
                          to_host=to_host, steps=steps, every=every, bar=bar,
                          check_stop=check_stop)


def integrate(W0, S0, *, th: tk.Thermo, b: tk.Basis, method: str, h: float, steps: int, every: int = 1, **kw):
    """Every kept state of the members: W, S (members, outputs, N, N), status, failed_step, iterations."""
    M, N = W0.shape[0], b.N
    n_out = steps // every + 1
    Ws = np.full((M, n_out, N, N), np.nan + 0j)
    Ss = np.full((M, n_out, N, N), np.nan + 0j)
    Ws[:, 0], Ss[:, 0] = W0, S0

    def record(j, members, state):
        Ws[members, j], Ss[members, j] = state

    its, status, failed = drive(W0, S0, record, th=th, b=b, method=method, h=h, steps=steps, every=every, **kw)
    return Ws, Ss, status, failed, its
