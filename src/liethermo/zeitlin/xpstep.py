"""The fluid's steps written once over an array namespace ``xp`` (numpy, or
CuPy on a GPU): every member of a batch at once, no numba, no Python loop
over members.

The arithmetic mirrors :mod:`.kernels` and :func:`.run.split_step` /
:func:`.run.rk4_step` operation by operation, so that with ``xp = numpy``
the steps agree with the CPU kernels to round-off (only sums are taken in
another order), with the same fixed-point rule, the same per-member
failures and the same heat:

* W's upper diagonals are gathered into a skewed array ``G[k, i, d] =
  W[k, i, (i + d) mod N]`` (entries with i ≥ N − d are padding, set to 0);
  a skew-Hermitian W is rebuilt from such an array by one gather;
* Δ_N⁻¹ on the blocks d ≥ 1: the Thomas recurrences with the stored
  factors, one row i at a time for all members and diagonals at once
  (N vector operations); block 0 through its stored inverse g0;
* the modes: each diagonal's real and imaginary rows times its block of
  eigenvectors, one batched product over the diagonals (blocks padded to
  N × N with zeros) or, where those would take too much memory, one
  product per diagonal;
* the products of the fixed point and of the vector field: batched
  complex ``matmul``.

Only what the run keeps goes back to the host (:func:`integrate_xp`).
"""

from __future__ import annotations

import functools
import time as _time

import numpy as np

# the array namespace of a backend and its host transfers are the run layer's (liethermo.gpu), shared
# with the torus; named here too for the callers of this module
from ..gpu import BACKENDS, CUPY_WHEEL, namespace, synchronize, to_host  # noqa: F401
from ..numerics import matrix_flow as mf
from . import kernels as zk

#: padded eigenvector blocks (two N³ float64 arrays) are used up to this many bytes
BATCHED_BLOCKS_BYTES = 2**31

# ----------------------------------------------------------------------------- the basis on xp


class XpBasis:
    """What the steps need of :func:`kernels.basis` (N), laid out for
    vector operations and moved to ``xp`` once."""

    def __init__(self, xp, N: int, batched: bool | None = None):
        b = zk.basis(N)
        self.xp, self.N, self.hbar, self.alpha, self.area = xp, N, b.hbar, b.alpha, b.area
        i = np.arange(N)[:, None]
        d = np.arange(N)[None, :]
        valid = i < N - d                                    # [i, d]
        # gather: G[k, i, d] = W[k, i, (i + d) mod N]
        self.gather_id = xp.asarray(i * N + (i + d) % N)
        self.valid_id = xp.asarray(valid)
        # rebuild W from upper values U (layout [i, d] or [d, i], flattened) and lower ones L = −conj(U)
        r = np.arange(N)[:, None]
        c = np.arange(N)[None, :]
        up = c >= r
        self.scatter_id = xp.asarray(np.where(up, r * N + (c - r), c * N + (r - c) + N * N).ravel())
        self.scatter_di = xp.asarray(np.where(up, (c - r) * N + r, (r - c) * N + c + N * N).ravel())
        # Thomas factors and the off-diagonals of −Δ's blocks, padded: [i, d], zero outside a block
        tinv = np.zeros((N, N))
        tc = np.zeros((N, N))
        offp = np.zeros((N, N))   # off[o + i − 1]: couples rows i − 1 and i (0 for i = 0)
        offn = np.zeros((N, N))   # off[o + i]: couples rows i and i + 1 (0 on a block's last row)
        diag = np.zeros((N, N))
        for dd in range(N):
            n, o = N - dd, b.offset[dd]
            diag[:n, dd] = b.diag[o:o + n]
            offn[:n, dd] = b.off[o:o + n]
            offp[1:n, dd] = b.off[o:o + n - 1]
            if dd >= 1:
                tinv[:n, dd] = b.tinv[o:o + n]
                tc[:n, dd] = b.tc[o:o + n]
        self.tinv, self.tc = xp.asarray(tinv), xp.asarray(tc)
        self.offp, self.offn, self.diag = xp.asarray(offp), xp.asarray(offn), xp.asarray(diag)
        self.g0t = xp.asarray(np.ascontiguousarray(b.g0.T))
        # modes, layout [d, j] (degree l = d + j): the exact viscous flow's rates and heat weights
        dj = np.arange(N)[:, None]
        jj = np.arange(N)[None, :]
        ell = (dj + jj).astype(float)
        inside = jj < N - dj
        self.ell = ell
        self.inside = inside
        self.weight = np.where(dj == 0, 1.0, 2.0)          # mode_weights, [d, 1]
        self._use_kernel()
        # eigenvector blocks, padded to N × N: V[d, i, j] (column j: degree d + j)
        nbytes = 2 * 8 * N ** 3
        self.batched = (nbytes <= BATCHED_BLOCKS_BYTES) if batched is None else bool(batched)
        blocks = [b.vecs[b.voff[dd]:b.voff[dd + 1]].reshape(N - dd, N - dd) for dd in range(N)]
        if self.batched:
            V = np.zeros((N, N, N))
            for dd, B in enumerate(blocks):
                V[dd, :N - dd, :N - dd] = B
            self.V = xp.asarray(V)
            self.Vt = xp.asarray(np.ascontiguousarray(np.swapaxes(V, 1, 2)))
        else:
            self.Vb = [xp.asarray(B) for B in blocks]
            self.Vbt = [xp.asarray(np.ascontiguousarray(B.T)) for B in blocks]

    # ---------------------------------------------------------------- Thomas

    def thomas_xp(self, r, s: float):
        """y = s·T_d⁻¹ r for every column (member row, diagonal d) of r
        (N_i, rows, N_d): the stored Thomas factors, one row i at a time."""
        xp, N = self.xp, self.N
        y = xp.empty_like(r)
        y[0] = (s * r[0]) * self.tinv[0]
        for i in range(1, N):
            y[i] = (s * r[i] - self.offp[i] * y[i - 1]) * self.tinv[i]
        y = xp.where(self.valid_id[:, None, :], y, 0.0)  # the padding stays 0 even after a non-finite entry
        for i in range(N - 2, -1, -1):
            y[i] -= self.tc[i] * y[i + 1]
        return y

    def thomas(self, r, s: float):
        if self._kernel is not None:
            return self._thomas_kernel(r, s)
        return self.thomas_xp(r, s)

    def _thomas_kernel(self, r, s: float):
        xp, N = self.xp, self.N
        r = xp.ascontiguousarray(r)
        y = xp.empty_like(r)
        cols = r.shape[1] * N
        threads = 128
        self._kernel(((cols + threads - 1) // threads,), (threads,),
                     (r, self.tinv, self.offp, self.tc, xp.float64(s), y, xp.int32(N), xp.int32(r.shape[1])))
        return y

    def _use_kernel(self) -> None:
        """On CuPy, the Thomas sweeps as one CUDA kernel (a thread per column,
        the rows in order: N launches fewer), kept only where it agrees with
        :meth:`thomas_xp` on a test input; ``thomas_backend`` says which runs."""
        self._kernel = None
        self.thomas_backend = "xp"
        xp = self.xp
        if getattr(xp, "RawKernel", None) is None:
            return
        try:
            self._kernel = xp.RawKernel(_THOMAS_CUDA, "thomas_sweeps", options=("--fmad=false",))
            rng = np.random.default_rng(0)
            r = xp.asarray(rng.standard_normal((self.N, 6, self.N)))
            a, b = self._thomas_kernel(r, -0.3), self.thomas_xp(r, -0.3)
            err = float(xp.abs(a - b).max()) / max(float(xp.abs(b).max()), 1e-300)
            if not err <= 1e-13:
                raise ArithmeticError(f"the Thomas kernel differs from the vector sweeps by {err:.2e}")
            self.thomas_backend = "kernel"
        except Exception as e:  # noqa: BLE001 (fall back to the vector sweeps, and say why)
            self._kernel = None
            self.thomas_backend = f"xp ({type(e).__name__}: {e})"

    # ---------------------------------------------------------------- gather / rebuild

    def diagonals(self, W):
        """G[k, i, d] = W[k, i, i + d] for i < N − d, 0 elsewhere: (M, N, N)."""
        xp, N = self.xp, self.N
        G = W.reshape(W.shape[0], N * N)[:, self.gather_id]
        return xp.where(self.valid_id, G, 0)

    def rebuild(self, U, layout: str = "id"):
        """The matrix with upper diagonals U ([k, i, d] or, layout "di",
        [k, d, i]) and lower ones −conj(U)."""
        xp, N = self.xp, self.N
        M = U.shape[0]
        U = U.reshape(M, N * N)
        UL = xp.concatenate([U, -xp.conj(U)], axis=1)
        idx = self.scatter_id if layout == "id" else self.scatter_di
        return UL[:, idx].reshape(M, N, N)


_THOMAS_CUDA = r"""
extern "C" __global__ void thomas_sweeps(const double* r, const double* tinv, const double* offp,
                                         const double* tc, const double s, double* y,
                                         const int N, const int rows)
{
    // column c = (row k, diagonal d) of the (N_i, rows, N_d) arrays; factors are (N_i, N_d)
    const long c = (long)blockIdx.x * blockDim.x + threadIdx.x;
    if (c >= (long)rows * N) return;
    const int d = (int)(c % N);
    const int n = N - d;
    const long stride = (long)rows * N;
    double prev = (s * r[c]) * tinv[d];
    y[c] = prev;
    for (int i = 1; i < n; i++) {
        const double v = (s * r[i * stride + c] - offp[i * N + d] * prev) * tinv[i * N + d];
        y[i * stride + c] = v;
        prev = v;
    }
    for (int i = n; i < N; i++) y[i * stride + c] = 0.0;
    for (int i = n - 2; i >= 0; i--) {
        const double v = y[i * stride + c] - tc[i * N + d] * prev;
        y[i * stride + c] = v;
        prev = v;
    }
}
"""


@functools.lru_cache(maxsize=8)
def _xp_basis(xp, N: int, batched):
    return XpBasis(xp, N, batched)


def xp_basis(xp, N: int, batched: bool | None = None) -> XpBasis:
    """The basis of N on ``xp``, built once per (xp, N)."""
    return _xp_basis(xp, int(N), batched)


def _cplx(re, im):
    """re + i·im (exact for finite parts)."""
    return re + 1j * im


def dagger(X):
    return X.conj().swapaxes(-1, -2)


# ----------------------------------------------------------------------------- Laplacian


def laplacian_inverse(W, xb: XpBasis, scale: float = 1.0):
    """scale · Δ_N⁻¹ W on the traceless part, as :func:`kernels.laplacian_inverse`."""
    xp, N = xb.xp, xb.N
    M = W.shape[0]
    s = -scale
    G = xb.diagonals(W)                                       # (M, N_i, N_d)
    r = xp.concatenate([G.real, G.imag], axis=0)              # (2M, N_i, N_d)
    r = xp.ascontiguousarray(xp.moveaxis(r, 1, 0))            # (N_i, 2M, N_d)
    y = xb.thomas(r, s)
    yr = xp.moveaxis(y[:, :M], 1, 0)                          # (M, N_i, N_d)
    yi = xp.moveaxis(y[:, M:], 1, 0)
    # block 0 (its l = 0 mode dropped): −g0 w₀ on the imaginary diagonal
    y0 = s * (W.imag.reshape(M, N * N)[:, :: N + 1] @ xb.g0t)  # (M, N)
    yr = xp.ascontiguousarray(yr)
    yi = xp.ascontiguousarray(yi)
    yr[:, :, 0] = 0.0
    yi[:, :, 0] = y0
    return xb.rebuild(_cplx(yr, yi), "id")


def laplacian(W, xb: XpBasis):
    """Δ_N W (W skew-Hermitian), as :func:`kernels.laplacian`."""
    xp = xb.xp
    G = xb.diagonals(W)                                       # (M, N_i, N_d)
    z = xp.zeros_like(G[:, :1])
    prev = xp.concatenate([z, G[:, :-1]], axis=1)
    nxt = xp.concatenate([G[:, 1:], z], axis=1)
    acc = xb.diag * G
    acc = acc + xb.offp * prev
    acc = acc + xb.offn * nxt
    return xb.rebuild(-acc, "id")


# ----------------------------------------------------------------------------- modes and the viscous flow


def _blocks(R, xb: XpBasis, transpose: bool):
    """R[d] (rows × N, block d's columns) times block d's eigenvectors (or their transpose)."""
    xp = xb.xp
    if xb.batched:
        return xp.matmul(R, xb.Vt if transpose else xb.V)
    Y = xp.zeros_like(R)
    for d in range(xb.N):
        n = xb.N - d
        B = xb.Vbt[d] if transpose else xb.Vb[d]
        Y[d, :, :n] = xp.matmul(R[d, :, :n], B)
    return Y


def to_modes(W, xb: XpBasis):
    """ω_lm of W, laid out [d, k, j] (degree l = d + j; zero outside the blocks)."""
    xp = xb.xp
    M = W.shape[0]
    G = xb.diagonals(W)                                       # (M, N_i, N_d)
    R = xp.concatenate([G.real, G.imag], axis=0)              # (2M, N_i, N_d)
    R = xp.ascontiguousarray(xp.transpose(R, (2, 0, 1)))      # (N_d, 2M, N_i)
    Y = _blocks(R, xb, False)
    return (Y[:, M:] - 1j * Y[:, :M]) / xb.alpha


def from_modes(C, xb: XpBasis):
    """W = iα Σ ω_lm T_lm from modes laid out [d, k, j] (m = 0: real part only)."""
    xp = xb.xp
    M = C.shape[1]
    R = xp.concatenate([-xb.alpha * C.imag, xb.alpha * C.real], axis=1)   # (N_d, 2M, N_j)
    Y = _blocks(R, xb, True)                                  # (N_d, 2M, N_i)
    re, im = Y[:, :M], Y[:, M:]
    re = xp.concatenate([xp.zeros_like(re[:1]), re[1:]], axis=0)  # the diagonal is imaginary
    U = _cplx(re, im)                                         # [d, k, i]
    return xb.rebuild(xp.ascontiguousarray(xp.moveaxis(U, 1, 0)), "di")


@functools.lru_cache(maxsize=64)
def _flow_factors(xp, xb: XpBasis, t: float, nu: float):
    lam = xb.ell * (xb.ell + 1.0)
    rate = np.where((xb.ell >= 1) & xb.inside, nu * (lam - 2.0), 0.0)
    lamp = np.where(lam > 0, lam, 1.0)
    keep = np.exp(-t * rate)
    lost = -np.expm1(-2.0 * t * rate)
    heat = np.where((xb.ell >= 1) & xb.inside, lost / lamp, 0.0) * xb.weight
    return xp.asarray(keep[:, None, :]), xp.asarray(heat[:, None, :])


def viscous_flow(W, t: float, nu: float, xb: XpBasis):
    """The exact flow of Ẇ = ν(Δ_N + 2)W for a time t and the heat it releases,
    as :func:`kernels.viscous_flow`."""
    xp = xb.xp
    if nu == 0.0 or t == 0.0:
        return W, xp.zeros(W.shape[0])
    keep, hw = _flow_factors(xp, xb, float(t), float(nu))
    C = to_modes(W, xb)
    heat = 0.5 * (xp.abs(C) ** 2 * hw).sum(axis=(0, 2))
    return from_modes(C * keep, xb), heat


# ----------------------------------------------------------------------------- isospectral midpoint


def _change(xp, Dn, D):
    """Per member, the largest change max(|Δre|, |Δim|) of D's entries, NaN
    where any part is NaN (as :func:`kernels._fixed_point_update`)."""
    M = Dn.shape[0]
    diff = Dn - D
    e = xp.maximum(xp.abs(diff.real), xp.abs(diff.imag)).reshape(M, -1)
    return xp.max(e, axis=1)


def isomp(W, h: float, xb: XpBasis, tol: float, max_iter: int, guess=None):
    """One isospectral midpoint step of every member, as :func:`kernels.isomp`:
    returns W', iterations, failed and the fixed point D (members that stop
    leave the batch, as there)."""
    xp = xb.xp
    M = W.shape[0]
    scale = h / (2.0 * xb.hbar)
    D = xp.zeros_like(W) if guess is None else xp.array(guess, dtype=xp.complex128)
    its = xp.zeros(M, dtype=xp.int64)
    failed = xp.zeros(M, dtype=bool)
    wmax = xp.maximum(xp.abs(W.real), xp.abs(W.imag)).reshape(M, -1).max(axis=1)
    thresh = tol * xp.where(wmax > 0, wmax, 1.0)
    X = xp.empty_like(W)
    active = xp.arange(M)
    Wa, Da, tha, lasta = W, D, thresh, xp.full(M, xp.inf)
    Wt = W + D
    whole = True
    while True:
        A = laplacian_inverse(Wt, xb, scale)
        Xa = xp.matmul(A, Wt)
        XA = xp.matmul(Xa, A)
        Dn = (Xa - dagger(Xa)) + XA
        ch = _change(xp, Dn, Da)
        Da = Dn
        Wt = Wa + Da
        its[active] += 1
        done = (ch <= tha) | ((ch >= lasta) & (ch <= 100.0 * tha))
        bad = ~xp.isfinite(ch)
        out = its[active] >= max_iter
        failed[active[bad | (out & ~done)]] = True
        stop = done | out | bad
        if bool(stop.all()):
            if whole:
                D, X = Da, Xa
            else:
                D[active], X[active] = Da, Xa
            break
        lasta = ch
        if bool(stop.any()):
            if whole:
                D, X = Da.copy(), Xa.copy()
                whole = False
            else:
                D[active[stop]], X[active[stop]] = Da[stop], Xa[stop]
            keep = ~stop
            active = active[keep]
            Wa, Da, Wt = Wa[keep], Da[keep], Wt[keep]
            tha, lasta = tha[keep], lasta[keep]
    return W + 2.0 * (X - dagger(X)), its, failed, D


# ----------------------------------------------------------------------------- the vector field and the steps


def rhs(W, nu: float, xb: XpBasis):
    """(Ẇ, q̇), as :func:`kernels.rhs`."""
    xp = xb.xp
    P = laplacian_inverse(W, xb)
    X = xp.matmul(P, W)
    dW = (X - dagger(X)) / xb.hbar
    if nu == 0.0:
        return dW, xp.zeros(W.shape[0])
    V = laplacian(W, xb) + 2.0 * W
    dW = dW + nu * V
    qdot = -(nu * xb.area) * xp.einsum("kij,kji->k", V, P).real
    return dW, qdot


class XpOps:
    """The sphere's operations on an array namespace, for
    :mod:`liethermo.numerics.matrix_flow`."""

    def __init__(self, xb: XpBasis):
        self.xb = xb
        self.xp = xb.xp

    def viscous_flow(self, W, t, nu):
        return viscous_flow(W, t, nu, self.xb)

    def isomp(self, W, h, tol, max_iter, guess):
        return isomp(W, h, self.xb, tol, max_iter, guess)

    def rhs(self, W, nu):
        return rhs(W, nu, self.xb)

    def asarray(self, a):
        return self.xp.asarray(np.ascontiguousarray(a, dtype=np.complex128))

    @staticmethod
    def to_host(a):
        return to_host(a)

    def synchronize(self):
        synchronize(self.xp)


def rk4_step(W, q, h: float, nu: float, xb: XpBasis):
    return mf.rk4_step(XpOps(xb), W, q, h, nu)


def Predictor(xp, substeps: int, M: int, N: int, order: int = 4, budget: int = 2**29,  # noqa: N802
              budget_members: int | None = None):
    """:class:`liethermo.numerics.matrix_flow.Predictor` on ``xp``."""
    return mf.Predictor(substeps, M, N, order, budget, budget_members, xp=xp)


def split_step(W, q, h, nu, xb: XpBasis, fac, tol, max_iter, guess=None, predictor=None, active=None):
    """One step of the split family (:func:`liethermo.numerics.matrix_flow.split_step`) on ``xb``'s namespace."""
    return mf.split_step(XpOps(xb), W, q, h, nu, fac, tol, max_iter, guess, predictor, active)


#: the methods these steps run; the reference (DOP853, scipy) runs on the CPU only
METHODS = ("split", "split4", "split6", "rk4")


def check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"method {method!r} does not run on the array-namespace backends "
                         f"(they run {', '.join(METHODS)}; the reference runs on the CPU)")


# ----------------------------------------------------------------------------- a run


def integrate_xp(xp, scene, W0: np.ndarray, *, method: str | None = None, progress=None,
                 keep_vorticity: bool | None = None, budget_members: int | None = None):
    """:func:`.run.integrate` with the steps on ``xp``: the same
    :class:`.run.Trajectory` (diagnostics recorded on the host from the
    kept steps' W, the same status, failed_step and iterations)."""
    from .run import Recorder, run_steps

    itg, out = scene["integrator"], scene["output"]
    method = method or itg["method"]
    check_method(method)
    b = zk.basis(scene["zeitlin"]["N"])
    M = W0.shape[0]
    rec = Recorder(M, int(itg["steps"]) // int(out["every"]) + 1, b,
                   bool(out["vorticity"] if keep_vorticity is None else keep_vorticity))
    rec.record(0, np.arange(M), W0, np.zeros(M))
    t0 = _time.perf_counter()
    return run_steps(XpOps(xp_basis(xp, scene["zeitlin"]["N"])), scene, W0, rec, method=method,
                     progress=progress, budget_members=budget_members, t0=t0)


# ----------------------------------------------------------------------------- memory


def memory_bytes(N: int, members: int, method: str, composition: str = "small_error",
                 budget: int = 2**29) -> int:
    """An upper estimate of the device memory a run of ``members`` members
    takes (the basis, the run's arrays and the peak of a step's temporaries),
    measured with numpy's allocations: a step holds at most about 22 arrays
    of the batch's size at once (16 for rk4), the predictor its history and
    the run 4 more (W, the guess, the active members' copies)."""
    from .run import factors

    check_method(method)
    unit = members * N * N * 16
    if method == "rk4":
        arrays = 16 + 4
    else:
        s = len(factors(method, composition))
        per = s * unit
        order = min(4, budget // per) if per else 4
        arrays = 22 + order * s + 4
    blocks = 2 * 8 * N ** 3
    if blocks > BATCHED_BLOCKS_BYTES:
        blocks = 2 * 8 * sum((N - d) ** 2 for d in range(N))
    tables = 16 * 8 * N * N
    return int(1.1 * (arrays * unit + blocks + tables))


# ----------------------------------------------------------------------------- timing


def _members(N: int, M: int, seed: int = 0) -> np.ndarray:
    """Random fields of unit energy, l ≤ min(8, N − 1)."""
    b = zk.basis(N)
    rng = np.random.default_rng(seed)
    sel = (b.ell >= 1) & (b.ell <= min(8, N - 1))
    C = np.zeros((M, b.modes), complex)
    C[:, sel] = rng.standard_normal((M, sel.sum())) + 1j * rng.standard_normal((M, sel.sum()))
    C[:, : N] = C[:, : N].real
    W = zk.from_modes(C, b)
    return W / np.sqrt(zk.energy_of_modes(zk.to_modes(W, b), b))[:, None, None]


def time_fluid_xp(xp, N: int, members: int, steps: int, method: str = "split", *, h: float = 0.01,
                  nu: float = 1e-3, tol: float = 1e-15, max_iter: int = 100, composition: str = "small_error",
                  warmup: int = 2) -> float:
    """Seconds per member-step of ``method`` on ``xp`` (warm: ``warmup``
    steps first; the fixed point started from the predictor, as in a run;
    the device synchronized before the clock is read).  Raises ArithmeticError
    when a split step's fixed point did not converge: the time of iterations
    that reach nothing is not a step's time."""
    check_method(method)
    return _time_steps(XpOps(xp_basis(xp, N)), xp.asarray(_members(N, members)), steps, method, h, nu, tol,
                       max_iter, composition, warmup)


def time_fluid_cpu(N: int, members: int, steps: int, method: str = "split", *, h: float = 0.01,
                   nu: float = 1e-3, tol: float = 1e-15, max_iter: int = 100, composition: str = "small_error",
                   warmup: int = 2) -> float:
    """The same figure for the numba kernels (:func:`.run.split_step`, :func:`.run.rk4_step`),
    refused in the same way when a fixed point did not converge."""
    from . import run as zr

    check_method(method)
    return _time_steps(zr.SphereOps(zk.basis(N)), _members(N, members), steps, method, h, nu, tol, max_iter,
                       composition, warmup)


def _time_steps(ops, W, steps: int, method: str, h: float, nu: float, tol: float, max_iter: int,
                composition: str, warmup: int) -> float:
    """:func:`time_fluid_xp` and :func:`time_fluid_cpu` on ``ops`` (:mod:`liethermo.numerics.matrix_flow`)."""
    xp = ops.xp
    M, N = W.shape[0], W.shape[-1]
    q = xp.zeros(M)
    fac = mf.factors(method, composition) if method != "rk4" else ()
    pred = mf.Predictor(len(fac), M, N, xp=xp) if fac else None
    act = xp.arange(M)
    failed = xp.zeros(M, dtype=bool)
    D = None

    def step(W, q, D):
        nonlocal failed
        if method == "rk4":
            W, q = mf.rk4_step(ops, W, q, h, nu)
            return W, q, None
        W, q, _, fl, D = mf.split_step(ops, W, q, h, nu, fac, tol, max_iter, D, pred, act)
        failed = failed | fl
        return W, q, D

    for _ in range(warmup):
        W, q, D = step(W, q, D)
    ops.synchronize()
    t0 = _time.perf_counter()
    for _ in range(steps):
        W, q, D = step(W, q, D)
    ops.synchronize()
    seconds = (_time.perf_counter() - t0) / (M * steps)
    bad = int(failed.sum())
    if bad:
        raise ArithmeticError(f"{method} at N = {N}, h = {h} s: the fixed point of {bad} of {M} member(s) did not "
                              f"converge within {max_iter} iterations, so there is no step to time (a smaller h "
                              "converges)")
    return seconds
