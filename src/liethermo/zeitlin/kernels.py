"""Numeric core of the thermodynamic Zeitlin fluid on the sphere (no xarray, no I/O).

The vorticity is a skew-Hermitian, traceless matrix W ∈ su(N), stored as a
batch ``(members, N, N)`` of complex128.  Conventions:

* Hermitian spin matrices J_a of spin s = (N−1)/2, basis m_i = s − i;
* Laplacian Δ_N W = −Σ_a [J_a, [J_a, W]], eigenvalues −l(l+1), l = 0 … N−1.
  It maps each diagonal d of W (entries W[i, i+d]) to itself, as a symmetric
  tridiagonal matrix: applied and inverted in O(N²);
* ħ = 2/√(N²−1); Ẇ = (1/ħ)[P, W] + ν(Δ_N + 2)W with P = Δ_N⁻¹W;
* the quantized harmonics T_lm: the orthonormal (tr T T† = 1) eigenvectors of
  Δ_N, T_lm on diagonal m, with the phases of the spherical harmonics
  (Condon–Shortley): T_ll = (−1)^l J_+^l/‖J_+^l‖ and
  [J_−, T_lm] = √((l+m)(l−m+1)) T_l,m−1, so that conjugation by SU(N) acts on
  the T_lm exactly as rotations act on the Y_lm, at every N;
* the physical field (Berezin–Toeplitz): W = i√(N/4π) Σ_lm ω_lm T_lm is the
  matrix of the vorticity ω = Σ ω_lm Y_lm (s⁻¹) on the unit sphere, and
  (1/ħ)[P, W] advects it at the rate of Euler's equations (a Rossby–Haurwitz
  wave of degree l on a solid-body rotation Ω_b turns at Ω_b(1 − 2/(l(l+1)))
  exactly, at every N).  Traces become integrals: (4π/N) tr(f(−iW)) ≈ ∫ f(ω) dA;
  for quadratic quantities the relation is exact (∫ω² dA = (4π/N)‖W‖²);
* the modes: ω_lm for m ≥ 0, packed by diagonal m (``offset[m] + l − m``);
  ω_l,−m = (−1)^m conj(ω_lm) because ω is real, so a mode with m ≥ 1 counts
  twice in sums over all (l, m) (:func:`mode_weights`).  Energy
  H = ½∫|u|² dA = ½ Σ |ω_lm|²/(l(l+1)), enstrophy ½∫ω² dA, in the units of a
  layer of unit surface density on a sphere of radius 1 m (J and m² s⁻²).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from ..numerics.jit import CACHE


def hbar(N: int) -> float:
    return 2.0 / math.sqrt(N * N - 1.0)


def spin_matrices(N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hermitian J_x, J_y, J_z of spin (N−1)/2, [J_x, J_y] = i J_z."""
    m = (N - 1) / 2.0 - np.arange(N)
    jp = np.diag(_ladder_coefficients(N)[1:N], 1)  # J+ |m_i> = c_i |m_i + 1> = c_i |m_{i-1}>
    jx = (jp + jp.T) / 2.0
    jy = (jp - jp.T) / 2.0j
    return jx.astype(complex), jy, np.diag(m).astype(complex)


def laplacian_dense(W: np.ndarray) -> np.ndarray:
    """Δ_N W from its definition (tests; O(N³))."""
    out = np.zeros_like(W)
    for J in spin_matrices(W.shape[-1]):
        c = J @ W - W @ J
        out -= J @ c - c @ J
    return out


@dataclass(frozen=True)
class Basis:
    """Everything that depends on N alone, computed once per N.

    Packed mode index: diagonal d occupies ``offset[d] : offset[d] + N − d``,
    its entries ordered l = d … N−1.  ``vecs`` holds each block's eigenvectors
    column by column, packed the same way (block d is (N−d)×(N−d), starting at
    ``voff[d]``)."""

    N: int
    hbar: float
    offset: np.ndarray    # (N+1,) int64
    ell: np.ndarray       # (K,) degree l of each mode
    voff: np.ndarray      # (N+1,) int64
    vecs: np.ndarray      # (Σ (N−d)²,) float64, row-major per block
    g0: np.ndarray        # (N, N): −Δ_N⁻¹ on block 0 without its l = 0 mode, V diag(1/l(l+1)) Vᵀ
    diag: np.ndarray      # (K,) main diagonal of −Δ's blocks, packed like the modes
    off: np.ndarray       # (K,) off-diagonal of −Δ's blocks (entry i couples i and i+1)
    # Thomas factors of −Δ's blocks d ≥ 1 (block 0 is singular: solved through its modes)
    tc: np.ndarray        # (K,)
    tinv: np.ndarray      # (K,)

    @functools.cached_property
    def vecs_t(self) -> np.ndarray:
        """The blocks of ``vecs`` transposed, packed the same way (:func:`from_modes`, the
        CPU's steps): made on first use, not kept in the disk cache."""
        N, vecs, voff = self.N, self.vecs, self.voff
        out = np.empty_like(vecs)  # filled block by block: one copy in memory, not two
        for d in range(N):
            n = N - d
            out[voff[d]:voff[d + 1]].reshape(n, n)[...] = vecs[voff[d]:voff[d + 1]].reshape(n, n).T
        return out

    @functools.cached_property
    def block_views(self) -> tuple:
        """Per diagonal d: (first mode, end, block d of ``vecs`` as an (N−d)×(N−d) view):
        :func:`_blocks`' operands, sliced once per N."""
        return self._views(self.vecs)

    @functools.cached_property
    def block_views_t(self) -> tuple:
        """:attr:`block_views` of ``vecs_t`` (made, with ``vecs_t``, only where asked for)."""
        return self._views(self.vecs_t)

    def _views(self, vecs: np.ndarray) -> tuple:
        return tuple((int(self.offset[d]), int(self.offset[d + 1]),
                      vecs[self.voff[d]:self.voff[d + 1]].reshape(self.N - d, self.N - d))
                     for d in range(self.N))

    @property
    def modes(self) -> int:
        return int(self.offset[-1])

    @property
    def alpha(self) -> float:
        """√(N/4π): W = iα Σ ω_lm T_lm (the Berezin–Toeplitz scale)."""
        return math.sqrt(self.N / (4.0 * math.pi))

    @property
    def area(self) -> float:
        """4π/N = 1/α²: the area of the sphere per quantum state ((4π/N) tr ↔ ∫ dA)."""
        return 4.0 * math.pi / self.N

    @property
    def order(self) -> np.ndarray:
        """The order m ≥ 0 of each mode (its diagonal of W)."""
        return np.repeat(np.arange(self.N), np.arange(self.N, 0, -1))

    @property
    def lam(self) -> np.ndarray:
        """l(l+1) of each mode."""
        return self.ell * (self.ell + 1.0)


def _block(N: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Main and off-diagonal of −Δ_N restricted to diagonal d."""
    s = (N - 1) / 2.0
    m = s - np.arange(N)
    c = _ladder_coefficients(N)
    n = N - d
    i = np.arange(n)
    a = 2.0 * (s * (s + 1) - m[i] * m[i + d])
    b = -c[i[:-1] + 1] * c[i[:-1] + 1 + d]
    return a, b


def _ladder_coefficients(N: int) -> np.ndarray:
    """c[k] = ⟨m_{k−1}|J_+|m_k⟩ = √(s(s+1) − m_k(m_k+1)), k = 1 … N−1 (c[0] = c[N] = 0)."""
    s = (N - 1) / 2.0
    m = s - np.arange(N)
    c = np.zeros(N + 1)
    for k in range(1, N):
        c[k] = math.sqrt(s * (s + 1) - m[k] * (m[k] + 1))
    return c


def _lower(v: np.ndarray, m: int, c: np.ndarray) -> np.ndarray:
    """Diagonal m − 1 of [J_−, X], X holding ``v`` on diagonal m (m ≥ 1): O(N)."""
    n = len(v)
    u = np.zeros(n + 1)
    u[1:] += c[1:n + 1] * v              # (J_− X)[i, i+m−1] = c_i v_{i−1}
    u[:n] -= v * c[m:m + n]              # (X J_−)[i, i+m−1] = v_i c_{i+m}
    return u


def _orient(vs: list, N: int) -> None:
    """Give each block's eigenvectors (columns of ``vs[m]``, degrees l = m … N−1)
    the phases of the spherical harmonics, in place.

    T_ll is a multiple of J_+^l (the extremal weight), whose entries on
    diagonal l are all positive: its sign is (−1)^l, as Y_ll ∝ (−1)^l (x + iy)^l.
    Going down, T_l,m−1 = [J_−, T_lm]/√((l+m)(l−m+1)), the lowering of the
    Condon–Shortley harmonics.  Each rule compares whole vectors, never a single
    entry (entries of the high degrees fall below round-off as N grows), so it
    holds at every N; the ladder's length is checked as it goes."""
    c = _ladder_coefficients(N)
    if vs[0][:, 0].sum() < 0:  # T_00 ∝ the identity, as Y_00 > 0
        vs[0][:, 0] = -vs[0][:, 0]
    for l in range(1, N):
        top = vs[l][:, 0]
        if (top.sum() < 0) != (l % 2 == 1):
            vs[l][:, 0] = -top
        for m in range(l, 0, -1):
            u = _lower(vs[m][:, l - m], m, c)
            v = vs[m - 1][:, l - m + 1]
            dot = float(u @ v)
            want = math.sqrt((l + m) * (l - m + 1.0))
            if abs(abs(dot) - want) > 1e-8 * want:
                raise ArithmeticError(f"harmonic (l, m) = ({l}, {m - 1}) of N = {N}: [J_-, T_lm] has length "
                                      f"{abs(dot)!r} along it, not {want!r}")
            if dot < 0:
                vs[m - 1][:, l - m + 1] = -v


#: the version of the basis's construction and of its cache entry: a change of its values,
#: or of the arrays an entry holds, bumps it (the disk cache keys its entries by it,
#: :mod:`liethermo.diskcache`), so that two versions of the package sharing a cache
#: folder never read each other's entries
BASIS_VERSION = 2
#: the arrays of a :class:`Basis` (its cache entry: :attr:`Basis.vecs_t` is made from them)
_BASIS_ARRAYS = ("offset", "ell", "voff", "vecs", "g0", "diag", "off", "tc", "tinv")


@functools.lru_cache(maxsize=16)
def basis(N: int) -> Basis:
    """The basis of su(N), once per process, from the disk cache when it holds
    it (:mod:`liethermo.diskcache`: keyed by N, :data:`BASIS_VERSION` and the
    numpy and scipy versions, so its bits are those of :func:`compute_basis`)."""
    if not (isinstance(N, (int, np.integer)) and N >= 2):
        raise ValueError(f"N must be an integer of at least 2, not {N!r}")
    from ..diskcache import cached_arrays

    N = int(N)

    def build() -> dict:
        b = compute_basis(N)
        return {k: getattr(b, k) for k in _BASIS_ARRAYS}

    arrays = cached_arrays("zeitlin-basis", f"N{N}", BASIS_VERSION, build)
    if any(k not in arrays for k in _BASIS_ARRAYS) or arrays["offset"].shape != (N + 1,):
        arrays = build()  # a foreign file under the entry's name: computed, not read
    return Basis(N, hbar(N), **{k: arrays[k] for k in _BASIS_ARRAYS})


def basis_on_disk(N: int) -> bool:
    """Whether the disk cache holds the basis of su(N) (reading it is then quick)."""
    from ..diskcache import is_cached

    return is_cached("zeitlin-basis", f"N{int(N)}", BASIS_VERSION)


def compute_basis(N: int) -> Basis:
    """Compute the basis of su(N) (no cache): the eigenvectors of −Δ_N's
    tridiagonal blocks, oriented as the spherical harmonics, and the Thomas
    factors of the blocks."""
    from scipy.linalg import eigh_tridiagonal

    N = int(N)
    offset = np.zeros(N + 1, dtype=np.int64)
    voff = np.zeros(N + 1, dtype=np.int64)
    for d in range(N):
        offset[d + 1] = offset[d] + (N - d)
        voff[d + 1] = voff[d] + (N - d) ** 2
    K = int(offset[-1])
    ell = np.zeros(K)
    vecs = np.zeros(int(voff[-1]))
    diag = np.zeros(K)
    off = np.zeros(K)
    tc = np.zeros(K)
    tinv = np.zeros(K)
    blocks, vs = [], []
    for d in range(N):
        a, b = _block(N, d)
        w, v = eigh_tridiagonal(a, b)
        ls = np.arange(d, N)
        if not np.allclose(w, ls * (ls + 1.0), rtol=1e-9, atol=1e-9 * N * N):
            raise ArithmeticError(f"Laplacian block {d} of N = {N}: eigenvalues {w} are not l(l+1)")
        blocks.append((a, b))
        vs.append(v)
    _orient(vs, N)
    for d in range(N):
        a, b = blocks[d]
        n = N - d
        o = offset[d]
        ell[o:o + n] = np.arange(d, N)
        vecs[voff[d]:voff[d + 1]] = vs[d].ravel()
        diag[o:o + n] = a
        off[o:o + n - 1] = b
        if d >= 1:  # Thomas factors (non-singular: eigenvalues ≥ 2)
            cp = np.zeros(n)
            inv = np.zeros(n)
            for i in range(n):
                den = a[i] - (b[i - 1] * cp[i - 1] if i else 0.0)
                inv[i] = 1.0 / den
                cp[i] = b[i] * inv[i] if i < n - 1 else 0.0
            tc[o:o + n] = cp
            tinv[o:o + n] = inv
    v0 = vecs[: N * N].reshape(N, N)
    g0 = (v0[:, 1:] / (ell[1:N] * (ell[1:N] + 1.0))) @ v0[:, 1:].T
    return Basis(N, hbar(N), offset, ell, voff, vecs, np.ascontiguousarray(g0), diag, off, tc, tinv)


# ----------------------------------------------------------------------------- modes


@numba.njit(cache=CACHE, error_model="numpy")
def _gather_diagonals(W, offset, R):
    """R[:M] and R[M:] (2M × K): the real and imaginary parts of W's upper
    diagonals, diagonal d at columns offset[d] … offset[d+1]."""
    M, N = W.shape[0], W.shape[1]
    for k in range(M):
        for d in range(N):
            o = offset[d]
            for i in range(N - d):
                w = W[k, i, i + d]
                R[k, o + i] = w.real
                R[M + k, o + i] = w.imag


@numba.njit(cache=CACHE, error_model="numpy")
def _scatter_diagonals(Y, offset, W):
    """The skew-Hermitian W whose upper diagonals are Y[:M] + i Y[M:] (block 0: imaginary part only)."""
    M, N = W.shape[0], W.shape[1]
    for k in range(M):
        for d in range(N):
            o = offset[d]
            for i in range(N - d):
                if d == 0:
                    W[k, i, i] = complex(0.0, Y[M + k, o + i])
                else:
                    W[k, i, i + d] = complex(Y[k, o + i], Y[M + k, o + i])
                    W[k, i + d, i] = complex(-Y[k, o + i], Y[M + k, o + i])


def _blocks(b: Basis, R: np.ndarray, transpose: bool) -> np.ndarray:
    """Each diagonal's columns of R (2M × K) times its block of eigenvectors (or
    their transpose): one BLAS product per diagonal, all members at once."""
    Y = np.empty_like(R)
    for lo, hi, v in (b.block_views_t if transpose else b.block_views):
        np.matmul(R[:, lo:hi], v, out=Y[:, lo:hi])
    return Y


def to_modes(W: np.ndarray, b: Basis) -> np.ndarray:
    """The vorticity's coefficients ω_lm (m ≥ 0, packed, (members, K), s⁻¹) of
    the field whose matrix is W: ω_lm = −i⟨T_lm, W⟩/α from W's upper diagonals."""
    W = np.ascontiguousarray(W, dtype=np.complex128)
    M = W.shape[0]
    R = np.empty((2 * M, b.modes))
    _gather_diagonals(W, b.offset, R)
    Y = _blocks(b, R, False)
    return (Y[M:] - 1j * Y[:M]) / b.alpha


def from_modes(C: np.ndarray, b: Basis) -> np.ndarray:
    """The matrix W = iα Σ ω_lm T_lm of the real field with coefficients C
    (m ≥ 0; the imaginary part of the m = 0 coefficients is dropped: ω is real)."""
    C = np.asarray(C, dtype=np.complex128)
    Y = _blocks(b, np.concatenate([-b.alpha * C.imag, b.alpha * C.real]), True)
    W = np.empty((C.shape[0], b.N, b.N), dtype=np.complex128)
    _scatter_diagonals(Y, b.offset, W)
    return W


def mode_weights(b: Basis) -> np.ndarray:
    """1 for m = 0, 2 for m ≥ 1 (ω_l,−m mirrors ω_lm): ∫ω² dA = Σ weight·|ω_lm|²."""
    w = np.full(b.modes, 2.0)
    w[: b.N] = 1.0
    return w


def energy_of_modes(C: np.ndarray, b: Basis) -> np.ndarray:
    """H = ½∫|u|² dA = ½ Σ weight |ω_lm|² / l(l+1) in J (the l = 0 mode carries nothing)."""
    lam = b.lam
    inv = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
    return 0.5 * (np.abs(C) ** 2 * (mode_weights(b) * inv)).sum(axis=-1)


def spectrum_of_modes(C: np.ndarray, b: Basis) -> np.ndarray:
    """E_l in J, l = 1 … N−1: the energy of degree l (Σ_l E_l = H)."""
    lam = b.lam
    inv = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
    e = 0.5 * np.abs(C) ** 2 * (mode_weights(b) * inv)
    out = np.zeros(C.shape[:-1] + (b.N,))
    for l in range(b.N):
        out[..., l] = e[..., b.ell == l].sum(axis=-1)
    return out[..., 1:]


# ----------------------------------------------------------------------------- Laplacian


@numba.njit(cache=CACHE, error_model="numpy", nogil=True)
def _lapinv(W, scale, offset, g0, tc, tinv, off, P):
    """P = scale · Δ_N⁻¹ W on the traceless part: block 0 (singular, its l = 0
    mode dropped) through the stored g0, blocks d ≥ 1 by Thomas with stored
    factors.  The members are the innermost loop: their recurrences are
    independent, so they overlap instead of waiting on each other."""
    M, N = W.shape[0], W.shape[1]
    yr = np.empty((N, M))
    yi = np.empty((N, M))
    w0 = np.empty((M, N))
    for k in range(M):
        for i in range(N):
            w0[k, i] = W[k, i, i].imag
    for k in range(M):
        for i in range(N):
            acc = 0.0
            for j in range(N):
                acc += g0[i, j] * w0[k, j]
            P[k, i, i] = complex(0.0, -scale * acc)
    for d in range(1, N):
        n = N - d
        o = offset[d]
        for i in range(n):
            t = tinv[o + i]
            if i == 0:
                for k in range(M):
                    w = W[k, 0, d]
                    yr[0, k] = -scale * w.real * t
                    yi[0, k] = -scale * w.imag * t
            else:
                b = off[o + i - 1]
                for k in range(M):
                    w = W[k, i, i + d]
                    yr[i, k] = (-scale * w.real - b * yr[i - 1, k]) * t
                    yi[i, k] = (-scale * w.imag - b * yi[i - 1, k]) * t
        for i in range(n - 2, -1, -1):
            c = tc[o + i]
            for k in range(M):
                yr[i, k] -= c * yr[i + 1, k]
                yi[i, k] -= c * yi[i + 1, k]
        for k in range(M):
            for i in range(n):
                P[k, i, i + d] = complex(yr[i, k], yi[i, k])
                P[k, i + d, i] = complex(-yr[i, k], yi[i, k])


def laplacian_inverse(W: np.ndarray, b: Basis, scale: float = 1.0, out=None) -> np.ndarray:
    """scale · Δ_N⁻¹ W (W skew-Hermitian; its trace is ignored)."""
    P = np.empty_like(W) if out is None else out
    _lapinv(W, scale, b.offset, b.g0, b.tc, b.tinv, b.off, P)
    return P


@numba.njit(cache=CACHE, error_model="numpy")
def _lap(W, offset, diag, off, out):
    M, N = W.shape[0], W.shape[1]
    for k in range(M):
        for d in range(N):
            n = N - d
            o = offset[d]
            for i in range(n):
                acc = diag[o + i] * W[k, i, i + d]
                if i > 0:
                    acc += off[o + i - 1] * W[k, i - 1, i - 1 + d]
                if i < n - 1:
                    acc += off[o + i] * W[k, i + 1, i + 1 + d]
                out[k, i, i + d] = -acc
                if d > 0:
                    out[k, i + d, i] = acc.conjugate()


def laplacian(W: np.ndarray, b: Basis) -> np.ndarray:
    """Δ_N W (W skew-Hermitian), O(N²)."""
    out = np.empty_like(W)
    _lap(np.ascontiguousarray(W), b.offset, b.diag, b.off, out)
    return out


# ----------------------------------------------------------------------------- flows


def viscous_flow(W: np.ndarray, t: float, nu: float, b: Basis) -> tuple[np.ndarray, np.ndarray]:
    """The exact flow of Ẇ = ν(Δ_N + 2)W for a time t, and the heat it releases
    (the energy lost, a sum of non-negative terms: never negative in floating point)."""
    if nu == 0.0 or t == 0.0:
        return W, np.zeros(W.shape[0])
    C = to_modes(W, b)
    rate = nu * (b.lam - 2.0)  # ≥ 0 for l ≥ 1; the l = 0 mode is zero
    rate = np.where(b.ell >= 1, rate, 0.0)
    lam = np.where(b.lam > 0, b.lam, 1.0)
    keep = np.exp(-t * rate)
    lost = -np.expm1(-2.0 * t * rate)  # 1 − keep², ≥ 0
    heat = 0.5 * (np.abs(C) ** 2 * (mode_weights(b) * np.where(b.ell >= 1, lost / lam, 0.0))).sum(axis=-1)
    return from_modes(C * keep, b), heat


def _dagger(X):
    return np.conj(np.swapaxes(X, -1, -2))


def isomp(W: np.ndarray, h: float, b: Basis, tol: float, max_iter: int,
          guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One isospectral midpoint step of every member (:func:`_isomp`), the members split
    into groups over :func:`liethermo.threads.pooled_kernel_threads` threads from
    N = :data:`MEMBERS_SPLIT_N` on.  A member's iteration is its own (its Laplacian, its
    two one-matrix BLAS products, its update and its stopping rule), so its bits do not
    depend on the group it is computed in, nor on the thread."""
    cuts = member_groups(W.shape[0], b.N)
    if cuts is None:
        return _isomp(W, h, b, tol, max_iter, guess)
    from ..threads import thread_pool

    def part(lo, hi):
        return _isomp(W[lo:hi], h, b, tol, max_iter, None if guess is None else guess[lo:hi])

    pool = thread_pool(len(cuts) - 2, "liethermo-members")  # the caller takes the first group
    futs = [pool.submit(part, lo, hi) for lo, hi in zip(cuts[1:-1], cuts[2:])]
    parts = [part(cuts[0], cuts[1])] + [f.result() for f in futs]
    return tuple(np.concatenate(r) for r in zip(*parts))


#: from this N on, a batch's fixed points are split over the kernel threads by member
MEMBERS_SPLIT_N = 32


def member_groups(members: int, N: int) -> list[int] | None:
    """The cuts of ``members`` into one group per kernel thread
    (:func:`liethermo.threads.pooled_kernel_threads`), or None: one group."""
    from ..threads import pooled_kernel_threads

    k = min(pooled_kernel_threads(), members)
    if k < 2 or N < MEMBERS_SPLIT_N:
        return None
    return [members * i // k for i in range(k + 1)]


def _isomp(W: np.ndarray, h: float, b: Basis, tol: float, max_iter: int,
           guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One isospectral midpoint step (a Cayley conjugation, so W's spectrum is kept):

        W̃ = W + [A, W̃] + A W̃ A,  A = (h/2ħ) Δ_N⁻¹ W̃,  W' = W + 2[A, W̃],

    solved per member by fixed-point iteration on D = W̃ − W.  Two complex
    matrix products per iteration (X = A W̃; [A, W̃] = X − X†, A W̃ A = X A).
    A member stops when its correction is at most ``tol`` × max|W| (largest
    real or imaginary part, for the correction and for W; or when
    the correction stops falling below 100 × that, at round-off).  Returns W',
    the iterations per member and a flag per member: True where the iteration
    did not converge within ``max_iter``.  ``guess``: a first D (e.g. the
    previous step's, scaled to this step); the solution D is returned last."""
    M = W.shape[0]
    scale = h / (2.0 * b.hbar)
    D = np.zeros_like(W) if guess is None else np.array(guess, dtype=np.complex128, order="C")
    its = np.zeros(M, dtype=np.int64)
    failed = np.zeros(M, dtype=bool)
    wmax = np.maximum(np.abs(W.real), np.abs(W.imag)).reshape(M, -1).max(axis=1)
    thresh = tol * np.where(wmax > 0, wmax, 1.0)
    last = np.full(M, np.inf)
    X = np.empty_like(W)
    active = np.arange(M)
    # the active members' arrays, compacted when some stop (views of the whole batch until then)
    Wa, Da, Xa, tha, lasta = W, D, X, thresh, last
    Wt = W + D
    A = np.empty_like(W)
    XA = np.empty_like(W)
    change = np.empty(M)
    while True:
        laplacian_inverse(Wt, b, scale, out=A[: len(active)])
        np.matmul(A[: len(active)], Wt, out=Xa)
        np.matmul(Xa, A[: len(active)], out=XA[: len(active)])
        _fixed_point_update(Wa, Xa, XA, Da, Wt, change)  # D = X − X† + XA, W̃ = W + D, change
        ch = change[: len(active)]
        its[active] += 1
        done = (ch <= tha) | ((ch >= lasta) & (ch <= 100.0 * tha))
        bad = ~np.isfinite(ch)
        out = its[active] >= max_iter
        failed[active[bad | (out & ~done)]] = True
        stop = done | out | bad
        if stop.all():
            if Da is not D:
                D[active], X[active] = Da, Xa
            break
        lasta = ch.copy()
        if stop.any():
            if Da is not D:  # (while the whole batch is active, Da and Xa are D and X)
                D[active[stop]], X[active[stop]] = Da[stop], Xa[stop]
            keep = ~stop
            active = active[keep]
            Wa, Da, Xa, Wt = W[active], Da[keep], Xa[keep], Wt[keep]
            tha, lasta = tha[keep], lasta[keep]
    return W + 2.0 * (X - _dagger(X)), its, failed, D


@numba.njit(cache=CACHE, error_model="numpy", nogil=True)
def _fixed_point_update(W, X, XA, D, Wt, change):
    """D = X − X† + XA, W̃ = W + D and the largest change of D (the largest
    real or imaginary part of D_new − D_old), per member, in one pass; NaN
    where any part of the change is NaN, so that such a member never counts
    as converged."""
    M, N = X.shape[0], X.shape[1]
    for k in range(M):
        ch = 0.0
        for i in range(N):
            for j in range(N):
                x, y = X[k, i, j], X[k, j, i]
                xa = XA[k, i, j]
                re = (x.real - y.real) + xa.real
                im = (x.imag + y.imag) + xa.imag
                old = D[k, i, j]
                e = abs(re - old.real)
                f = abs(im - old.imag)
                if f > e or f != f:  # a NaN in either part is the change
                    e = f
                if e > ch or e != e:  # and stays the member's change
                    ch = e
                D[k, i, j] = complex(re, im)
                w = W[k, i, j]
                Wt[k, i, j] = complex(w.real + re, w.imag + im)
        change[k] = ch


def rhs(W: np.ndarray, nu: float, b: Basis) -> tuple[np.ndarray, np.ndarray]:
    """(Ẇ, q̇): the vector field and the heat rate in W (J s⁻¹),
    (4π/N)·ν⟨(Δ+2)W, P⟩ ≥ 0, with ⟨A, B⟩ = −tr(AB)."""
    P = laplacian_inverse(W, b)
    X = P @ W
    dW = (X - _dagger(X)) / b.hbar
    if nu == 0.0:
        return dW, np.zeros(W.shape[0])
    V = laplacian(W, b) + 2.0 * W
    dW = dW + nu * V
    qdot = -(nu * b.area) * np.einsum("kij,kji->k", V, P).real  # (4π/N)ν⟨V, P⟩ = −(4π/N)ν tr(VP)
    return dW, qdot


# ----------------------------------------------------------------------------- diagnostics


def casimirs(W: np.ndarray, ks=(2, 3, 4)) -> np.ndarray:
    """C_k = (4π/N) tr((−iW)^k) ≈ ∫ω^k dA, (members, len(ks)), in m² s⁻ᵏ: the
    power sums of the Hermitian vorticity matrix −iW's eigenvalues, scaled to
    integrals over the unit sphere (C_2 = ∫ω² dA exactly)."""
    N = W.shape[-1]
    H = -1j * W
    out = np.empty(W.shape[:-2] + (len(ks),))
    P = H
    power = 1
    for j, k in enumerate(ks):
        while power < k:
            P = P @ H
            power += 1
        out[..., j] = (4.0 * math.pi / N) * np.trace(P, axis1=-2, axis2=-1).real
    return out


def casimir_change(C: np.ndarray, C0: np.ndarray, b: Basis) -> np.ndarray:
    """The relative change of the matrix's power sums, k = 2, 3, 4 on the last
    axis of the Casimirs C and C0 (:func:`casimirs`):
    (tr((−iW)^k) − tr((−iW₀)^k)) / tr((−iW₀)²)^(k/2), which bounds it by 1 in size."""
    p, p0 = C / b.area, C0 / b.area
    return (p - p0) / p0[..., :1] ** (np.array([2, 3, 4]) / 2.0)


def angular_momentum(W: np.ndarray, b: Basis) -> np.ndarray:
    """L = ∫ x ω dA of the field of each W (see :func:`angular_momentum_of_modes`)."""
    return angular_momentum_of_modes(to_modes(W, b), b)


def angular_momentum_of_modes(C: np.ndarray, b: Basis) -> np.ndarray:
    """L = ∫ x ω dA (m³ s⁻¹ on the unit sphere; the angular momentum σ∫x × u dA
    of a layer of unit surface density σ), from the l = 1 coefficients
    ω_10 and ω_11: (members, 3).  A solid-body
    rotation Ω has ω = 2Ω·x and L = (8π/3)Ω."""
    w10, w11 = C[..., 1].real, C[..., b.offset[1]]
    out = np.empty(C.shape[:-1] + (3,))
    out[..., 0] = -math.sqrt(8 * math.pi / 3) * w11.real
    out[..., 1] = math.sqrt(8 * math.pi / 3) * w11.imag
    out[..., 2] = math.sqrt(4 * math.pi / 3) * w10
    return out


def enstrophy(W: np.ndarray) -> np.ndarray:
    """Z = ½∫ω² dA = (4π/N)·½‖W‖², in m² s⁻²."""
    return (2.0 * math.pi / W.shape[-1]) * (np.abs(W) ** 2).sum(axis=(-2, -1))


def diagnostics(W: np.ndarray, b: Basis) -> dict:
    """What a run records of a batch W, all of the field ω that W advects:
    energy H, spectrum E_l, Casimirs C_k for k = 2, 3, 4, angular momentum L,
    enstrophy Z."""
    C = to_modes(W, b)
    return {"H": energy_of_modes(C, b), "spec": spectrum_of_modes(C, b), "cas": casimirs(W),
            "L": angular_momentum_of_modes(C, b), "Z": enstrophy(W)}
