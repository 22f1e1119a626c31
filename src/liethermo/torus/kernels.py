"""Numeric core of Zeitlin's sine-bracket fluid on the torus T² = [0, 2π)² and
its thermodynamic extension (no xarray, no I/O; numpy, or any array module with
numpy's ``fft`` and ``linalg`` through :class:`Basis`'s ``xp``).

Conventions (docs/model.md, "The fluid on the torus"):

* N = 2M + 1 odd, ε = 2π/N, ħ = 4π/N, ζ = e^{4πi/N}, g = diag(ζ^a), h the cyclic
  shift (h_{a,a+1} = 1); T_m = e^{2πi m₁m₂/N} g^{m₁} h^{m₂}, i.e.
  (T_m)_{a, a+m₂} = e^{2πi m₁(m₂+2a)/N}; [T_m, T_n] = −2i sin(ε m×n) T_{m+n};
* a real field f = Σ f_m e^{i m·x} (|m_i| ≤ M) is the Hermitian matrix
  F = Σ f_m T_m; its modes are stored at index [m₁ mod N, m₂ mod N]
  (row: the wave number in x, column: in y);
* the transforms are FFTs (O(N² log N)): G_{j,m₂} = Σ_{m₁} f_{m₁m₂} e^{2πi m₁ j/N},
  F_{a,(a+m₂) mod N} = G_{(m₂+2a) mod N, m₂}, and back;
* ⟨A, B⟩ = (4π²/N) tr(AB) = ∫ab dA; Ẇ = (1/iħ)[W, P] + νΔW, P = Δ⁻¹W;
  K = ½∫|u|² dA = 2π² Σ |ω_m|²/|m|², in J for a layer of unit surface density;
* the conduction Laplacian is the monotone conjugation Laplacian
  L′(X) = −(N/2π)² Σ_{U ∈ {g′, h′}} (2X − UXU† − U†XU), g′ = g^{(N+1)/2},
  h′ = h^{(N+1)/2} (entrywise: a phase and a cyclic shift of both indices);
* the thermodynamic state is (W, S), S the entropy-density matrix;
  E(S) = c T₀ e^{S/c}, Θ = T₀ e^{S/c} − αΦ, Φ = cos y = ½(h + h†),
  H = K(W) + U(S), U(S) = (4π²/N) tr(E(S) − αΦS).

Every array is a batch ``(members, N, N)`` of complex128.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np

EPS_MACH = float(np.finfo(float).eps)


def dagger(X):
    return X.conj().swapaxes(-1, -2)


def herm(X):
    """The Hermitian part ½(X + X†) (keeps a product that should be Hermitian so to the last bit)."""
    return 0.5 * (X + dagger(X))


def jordan(A, B):
    """A ∘ B = ½(AB + BA)."""
    return 0.5 * (A @ B + B @ A)


def comm(A, B):
    return A @ B - B @ A


@dataclass(frozen=True, eq=False)
class Basis:
    """What depends on N (and the array module) alone."""

    N: int
    xp: object
    k2: object          # (N, N) |m|², 0 at m = 0
    inv_k2: object      # 1/|m|², 0 at m = 0
    lam_conj: object    # eigenvalues of L′ on T_m
    lam_graph: object   # eigenvalues of L on T_m
    perm: object        # F.flat = G.flat[perm]
    iperm: object       # G.flat = F.flat[iperm]
    phase1: object      # (N, N) 2 cos(2π(a−b)/N) (g′ conjugations)
    phase2: object      # (N, N) 2 cos(4π(a−b)/N) (g conjugations)
    Phi: object         # (N, N) Φ = cos y
    eye: object

    @property
    def M(self) -> int:
        return (self.N - 1) // 2

    @property
    def eps(self) -> float:
        return 2.0 * math.pi / self.N

    @property
    def hbar(self) -> float:
        return 4.0 * math.pi / self.N

    @property
    def area(self) -> float:
        """4π²/N: the weight of a trace in an integral."""
        return 4.0 * math.pi**2 / self.N

    @property
    def shift(self) -> int:
        return (self.N + 1) // 2

    @property
    def Lambda(self) -> float:
        """max |λ| of L′ (its stiffest mode, (M, M))."""
        return 2.0 * (self.N / math.pi) ** 2 * math.sin(math.pi * self.M / self.N) ** 2


def check_n(N) -> int:
    if not isinstance(N, (int, np.integer)) or isinstance(N, bool) or N < 3 or N % 2 == 0:
        raise ValueError(f"torus.N must be an odd integer ≥ 3 (2 must be invertible mod N; got {N!r})")
    return int(N)


def wave_numbers(N: int) -> np.ndarray:
    """The symmetric representatives m ∈ [−M, M] of the indices 0 … N−1."""
    i = np.arange(N)
    return np.where(i <= (N - 1) // 2, i, i - N)


@functools.lru_cache(maxsize=16)
def _basis(N: int, xp) -> Basis:
    N = check_n(N)
    m = wave_numbers(N).astype(float)
    m1, m2 = m[:, None], m[None, :]
    k2 = m1**2 + m2**2
    inv_k2 = np.divide(1.0, k2, out=np.zeros_like(k2), where=k2 > 0)
    lam_conj = -(N / math.pi) ** 2 * (np.sin(math.pi * m1 / N) ** 2 + np.sin(math.pi * m2 / N) ** 2)
    lam_graph = -(N / (2 * math.pi)) ** 2 * (np.sin(2 * math.pi * m1 / N) ** 2 + np.sin(2 * math.pi * m2 / N) ** 2)
    a = np.arange(N)[:, None]
    j = np.arange(N)[None, :]  # m₂ index
    rows, cols = np.broadcast_to(a, (N, N)), (a + j) % N
    grow, gcol = (j + 2 * a) % N, np.broadcast_to(j, (N, N))
    perm = np.empty(N * N, dtype=np.int64)
    perm[(rows * N + cols).ravel()] = (grow * N + gcol).ravel()
    iperm = np.empty(N * N, dtype=np.int64)
    iperm[perm] = np.arange(N * N)
    d = np.arange(N)[:, None] - np.arange(N)[None, :]
    h = np.roll(np.eye(N), 1, axis=1)  # h[a, a+1] = 1
    Phi = 0.5 * (h + h.T)
    as_x = lambda v, dt=None: xp.asarray(v) if dt is None else xp.asarray(v, dtype=dt)  # noqa: E731
    return Basis(N, xp, as_x(k2), as_x(inv_k2), as_x(lam_conj), as_x(lam_graph), as_x(perm), as_x(iperm),
                 as_x(2 * np.cos(2 * math.pi * d / N)), as_x(2 * np.cos(4 * math.pi * d / N)),
                 as_x(Phi, complex), as_x(np.eye(N), complex))


def basis(N: int, xp=np) -> Basis:
    return _basis(int(N), xp)


# ----------------------------------------------------------------------------- transforms


def from_modes(f, b: Basis):
    """F = Σ f_m T_m from modes f (..., N, N) at [m₁ mod N, m₂ mod N], by one FFT along m₁."""
    xp, N = b.xp, b.N
    G = xp.fft.ifft(xp.asarray(f, dtype=complex), axis=-2) * N
    return G.reshape(G.shape[:-2] + (N * N,))[..., b.perm].reshape(G.shape)


def to_modes(F, b: Basis):
    """f_m = tr(F T_m†)/N of a matrix F (..., N, N), by one FFT."""
    xp, N = b.xp, b.N
    F = xp.asarray(F)
    G = F.reshape(F.shape[:-2] + (N * N,))[..., b.iperm].reshape(F.shape)
    return xp.fft.fft(G, axis=-2) / N


def T(m1: int, m2: int, N: int) -> np.ndarray:
    """The basis matrix T_m from its definition (tests)."""
    a = np.arange(N)
    out = np.zeros((N, N), dtype=complex)
    out[a, (a + m2) % N] = np.exp(2j * np.pi * m1 * (m2 + 2 * a) / N)
    return out


def from_modes_direct(f: np.ndarray) -> np.ndarray:
    """Σ f_m T_m by the direct sum (tests; O(N⁴))."""
    N = f.shape[-1]
    ms = wave_numbers(N)
    out = np.zeros(f.shape[:-2] + (N, N), dtype=complex)
    for i, m1 in enumerate(ms):
        for j, m2 in enumerate(ms):
            out += f[..., i, j, None, None] * T(int(m1), int(m2), N)
    return out


def to_modes_direct(F: np.ndarray) -> np.ndarray:
    """tr(F T_m†)/N by the direct sum (tests)."""
    N = F.shape[-1]
    ms = wave_numbers(N)
    out = np.zeros(F.shape[:-2] + (N, N), dtype=complex)
    for i, m1 in enumerate(ms):
        for j, m2 in enumerate(ms):
            out[..., i, j] = np.einsum("...ab,ab->...", F, T(int(m1), int(m2), N).conj()) / N
    return out


def grid_values(f, b: Basis):
    """A field's values on the periodic grid x_j = 2πj/N, y_k = 2πk/N from its modes: (..., x, y)."""
    xp = b.xp
    return (xp.fft.ifft2(f, axes=(-2, -1)) * b.N * b.N).real


def modes_of_grid(v, b: Basis):
    """The modes of grid values (..., x, y) (the inverse of :func:`grid_values`)."""
    return b.xp.fft.fft2(v, axes=(-2, -1)) / (b.N * b.N)


# ----------------------------------------------------------------------------- operators


def laplacian(W, b: Basis):
    return from_modes(-b.k2 * to_modes(W, b), b)


def laplacian_inverse(W, b: Basis, scale: float = 1.0):
    """scale · Δ⁻¹W (the T₀ = I component of W is dropped)."""
    return from_modes((-scale) * b.inv_k2 * to_modes(W, b), b)


def viscous_flow(W, t: float, nu: float, b: Basis):
    """The exact viscous flow e^{νtΔ}W: ω_m ↦ e^{−ν|m|²t} ω_m."""
    if nu == 0.0 or t == 0.0:
        return W
    return from_modes(b.xp.exp(-nu * t * b.k2) * to_modes(W, b), b)


def conduction_laplacian(X, b: Basis, graph: bool = False):
    """L′(X) (monotone, the default) or L(X) (``graph``: nearest neighbours), entrywise, O(N²)."""
    xp = b.xp
    if graph:
        ph, k, c = b.phase2, 1, (b.N / (4 * math.pi)) ** 2
    else:
        ph, k, c = b.phase1, b.shift, (b.N / (2 * math.pi)) ** 2
    return -c * (4.0 * X - ph * X - xp.roll(X, -k, axis=(-2, -1)) - xp.roll(X, k, axis=(-2, -1)))


# ----------------------------------------------------------------------------- diagnostics of W


def kinetic_energy(W, b: Basis):
    """K = ½∫|u|² dA = 2π² Σ |ω_m|²/|m|² (J), per member."""
    f = to_modes(W, b)
    return 2.0 * math.pi**2 * (b.xp.abs(f) ** 2 * b.inv_k2).sum(axis=(-2, -1))


def enstrophy(W, b: Basis):
    """Z = ½∫ω² dA = (2π²/N) tr W² (m² s⁻²)."""
    return 0.5 * b.area * (b.xp.abs(W) ** 2).sum(axis=(-2, -1))


def casimirs(W, b: Basis, ks=(2, 3, 4)):
    """(4π²/N) tr W^k ≈ ∫ω^k dA, (members, len(ks)), from W's eigenvalues."""
    lam = b.xp.linalg.eigvalsh(W)
    return b.area * b.xp.stack([(lam**k).sum(axis=-1) for k in ks], axis=-1)


def trace(X):
    return X.diagonal(axis1=-2, axis2=-1).sum(axis=-1)


def trace_product(A, B):
    """tr(AB) per member (real part) without the product."""
    return (A * B.swapaxes(-1, -2)).sum(axis=(-2, -1)).real


# ----------------------------------------------------------------------------- the fluid's right-hand sides


def rhs_euler(W, nu: float, b: Basis):
    """Ẇ = (1/iħ)[W, P] + νΔW."""
    P = laplacian_inverse(W, b)
    dW = comm(W, P) / (1j * b.hbar)
    if nu:
        dW = dW + nu * laplacian(W, b)
    return dW


def rhs_sine(f: np.ndarray, nu: float) -> np.ndarray:
    """ω̇_k = Σ_{n≠0} sin(ε k×n)/ε · ω_{k−n} ω_n/|n|² − ν|k|²ω_k on the modes (the sine
    bracket, summed directly: O(N⁴); tests)."""
    N = f.shape[-1]
    ms = wave_numbers(N)
    eps = 2 * np.pi / N
    K1, K2 = np.meshgrid(ms, ms, indexing="ij")
    k2 = (K1**2 + K2**2).astype(float)
    out = np.zeros_like(f)
    for i, n1 in enumerate(ms):
        for j, n2 in enumerate(ms):
            if n1 == 0 and n2 == 0:
                continue
            cross = K1 * n2 - K2 * n1
            sub = np.roll(np.roll(f, i, axis=-2), j, axis=-1)  # f[k − n]
            out += np.sin(eps * cross) / eps * sub * f[..., i, j, None, None] / (n1 * n1 + n2 * n2)
    return out - nu * k2 * f


# ----------------------------------------------------------------------------- thermodynamics


@dataclass(frozen=True)
class Thermo:
    """The thermodynamic parameters: c (J K⁻¹ m⁻²), T₀ (K), α (buoyancy), ν, κ, and the
    conduction operator (``graph``: the nearest-neighbour L instead of the monotone L′)."""

    c: float = 1.0
    T0: float = 1.0
    alpha: float = 0.0
    nu: float = 0.0
    kappa: float = 0.0
    graph: bool = False


def eig(S, b: Basis):
    return b.xp.linalg.eigh(S)


def func(lam, V, fn):
    """V fn(λ) V† of an eigendecomposition."""
    return (V * fn(lam)[..., None, :]) @ dagger(V)


def internal(S, th: Thermo, b: Basis, lam=None):
    """(4π²/N) tr E(S) (J): the solid's internal energy."""
    if lam is None:
        lam = b.xp.linalg.eigvalsh(S)
    return b.area * th.c * th.T0 * b.xp.exp(lam / th.c).sum(axis=-1)


def potential(S, th: Thermo, b: Basis):
    """−α⟨Φ, S⟩ (J)."""
    return -th.alpha * b.area * trace_product(b.Phi, S)


def U(S, th: Thermo, b: Basis, lam=None):
    return internal(S, th, b, lam) + potential(S, th, b)


def theta(S, th: Thermo, b: Basis):
    """Θ = T₀ e^{S/c} − αΦ (K) and the eigenvalues of S."""
    lam, V = eig(S, b)
    T = func(lam, V, lambda x: th.T0 * b.xp.exp(x / th.c))
    if th.alpha:
        T = T - th.alpha * b.Phi
    return herm(T), lam


def temperature_range(S, th: Thermo, b: Basis):
    """min and max of T = T₀ e^{S/c} (K) per member."""
    lam = b.xp.linalg.eigvalsh(S)
    return th.T0 * b.xp.exp(lam[..., 0] / th.c), th.T0 * b.xp.exp(lam[..., -1] / th.c)


def theta_range(S, th: Thermo, b: Basis):
    """Extreme eigenvalues of Θ (K) per member."""
    Th, _ = theta(S, th, b)
    lt = b.xp.linalg.eigvalsh(Th)
    return lt[..., 0], lt[..., -1]


def inverse_jordan(Th, Q, b: Basis):
    """Θ⁻¹ ∘ Q and the eigenvalues of Θ (Θ⁻¹ by eigh; the caller checks Θ ≻ 0)."""
    lt, V = eig(Th, b)
    return jordan(func(lt, V, lambda x: 1.0 / x), Q), lt


def rhs_thermo(W, S, th: Thermo, b: Basis):
    """(Ẇ, Ṡ) of the continuous matrix model:
    Ẇ = (1/iħ)([W, P] + [Θ, S]) + νΔW, Ṡ = (1/iħ)[S, P] + Θ⁻¹∘(νW² + κL′Θ)."""
    P = laplacian_inverse(W, b)
    dW = comm(W, P)
    if th.alpha:
        dW = dW - th.alpha * comm(b.Phi, S)  # [Θ, S] = −α[Φ, S]: E′(S) commutes with S
    dW = dW / (1j * b.hbar)
    dS = comm(S, P) / (1j * b.hbar)
    if th.nu:
        dW = dW + th.nu * laplacian(W, b)
    if th.nu or th.kappa:
        Th, _ = theta(S, th, b)
        Q = 0.0
        if th.nu:
            Q = th.nu * (W @ W)
        if th.kappa:
            Q = Q + th.kappa * conduction_laplacian(Th, b, th.graph)
        J, _ = inverse_jordan(Th, Q, b)
        dS = dS + herm(J)
    return herm(dW), herm(dS)


def entropy_rate(W, S, th: Thermo, b: Basis):
    """Ṡ_tot = (4π²/N)[ν tr(Θ⁻¹W²) + κ tr(Θ⁻¹L′Θ)] (J K⁻¹ s⁻¹ per unit area density), per member."""
    Th, _ = theta(S, th, b)
    lt, V = eig(Th, b)
    Ti = func(lt, V, lambda x: 1.0 / x)
    r = 0.0
    if th.nu:
        r = r + th.nu * trace_product(Ti, W @ W)
    if th.kappa:
        r = r + th.kappa * trace_product(Ti, conduction_laplacian(Th, b, th.graph))
    return b.area * r


# ----------------------------------------------------------------------------- the ideal step I


#: per-member status of a torus run
STATUS_OK, STATUS_NOT_CONVERGED, STATUS_NON_FINITE, STATUS_THETA, STATUS_SUBSTEP = 0, 1, 2, 3, 4
STATUS_MEANINGS = {0: "ok", 1: "fixed_point_not_converged", 2: "non_finite", 3: "theta_not_positive",
                   4: "substep_too_small"}


def _cayley(p, b: Basis):
    """A = (I − p)⁻¹ and C = A(I + p) = 2A − I of a skew-Hermitian batch p."""
    A = b.xp.linalg.inv(b.eye - p)
    return A, 2.0 * A - b.eye


def _conjugate(C, X):
    """C X C† (Hermitian part)."""
    return herm(C @ X @ dagger(C))


def _coadjoint(W, S, A, C, bS, b: Basis):
    """S′ = CSC†, W′ = CWC† + [Z, S′], Z = 2AbA† (b = ``bS``, None at α = 0)."""
    S1 = _conjugate(C, S)
    W1 = C @ W @ dagger(C)
    if bS is not None:
        Z = 2.0 * (A @ bS @ dagger(A))
        W1 = W1 + comm(Z, S1)
    return herm(W1), S1


def _maxabs(X, xp):
    return xp.abs(X).reshape(X.shape[0], -1).max(axis=1)


def ideal_step(W, S, h: float, alpha: float, b: Basis, *, kind: str = "cmp", tol: float = 1e-14,
               max_iter: int = 100, guess=None):
    """One step h of the ideal flow (ν = κ = 0) in coadjoint form, per member:

    * ``cmp``: p = (ih/2ħ) Δ⁻¹((W + W′)/2), fixed point on W′ (energy- and Casimir-exact);
    * ``magmp`` (``isomp`` at α = 0): p = (ih/2ħ) Δ⁻¹W̃ with the midpoints W̃, S̃ of the
      Lie–Poisson midpoint rule (fixed point on W̃).

    The fixed point stops per member when its change is ≤ tol·max|W| or stops falling (after
    3 iterations); after ``max_iter`` the member is flagged.  ``guess``: the first iterate's
    offset from W (cmp: W′ − W, magmp: W̃ − W), e.g. extrapolated from the last steps.
    Returns W′, S′, iterations, failed (bool), and the solution's offset (for the next guess)."""
    xp = b.xp
    Mm = W.shape[0]
    sc = 1j * h / (2.0 * b.hbar)
    bS = (sc * alpha) * b.Phi if alpha else None
    X = W + (guess if guess is not None else 0.0)  # the unknown: W′ (cmp) or W̃ (magmp)
    wmax = _maxabs(W, xp)
    thresh = tol * xp.where(wmax > 0, wmax, 1.0)
    its = np.zeros(Mm, dtype=np.int64)
    failed = np.zeros(Mm, dtype=bool)
    last = np.full(Mm, np.inf)
    act = np.arange(Mm)
    A_out = xp.empty_like(W)
    C_out = xp.empty_like(W)
    while act.size:
        Wa, Xa = W[act], X[act]
        Sa = S[act] if bS is not None else None
        if kind == "cmp":
            p = laplacian_inverse(0.5 * (Wa + Xa), b, 1.0) * sc
            A, C = _cayley(p, b)
            # at α = 0 W′ does not depend on S: S is conjugated once, after the fixed point
            Xn = _conjugate(C, Wa) if bS is None else _coadjoint(Wa, Sa, A, C, bS, b)[0]
        else:
            p = laplacian_inverse(Xa, b, 1.0) * sc
            A, C = _cayley(p, b)
            Ad = dagger(A)
            rhs = Wa
            if bS is not None:
                St = A @ Sa @ Ad
                rhs = Wa + comm(bS, St) + bS @ St @ p + p @ St @ bS
            Xn = herm(A @ rhs @ Ad)
        ch = np.asarray(_to_host(_maxabs(Xn - Xa, xp)))
        th_a = np.asarray(_to_host(thresh[act]))
        its[act] += 1
        X[act] = Xn
        A_out[act], C_out[act] = A, C
        done = (ch <= th_a) | ((its[act] >= 3) & (ch >= last[act]))
        bad = ~np.isfinite(ch)
        out = its[act] >= max_iter
        failed[act[bad | (out & ~done)]] = True
        last[act] = ch
        act = act[~(done | out | bad)]
    if kind == "cmp":
        # the last iterate is already the coadjoint update of the last p
        return X, _conjugate(C_out, S), its, failed, X - W
    W1, S1 = _coadjoint(W, S, A_out, C_out, bS, b)
    return W1, S1, its, failed, X - W


def magmp_quflow_form(W, S, h, alpha, b: Basis, tol=1e-15):
    """MagMP's update in the midpoint form W_k + 2[p, W̃] + 2[b, S̃], S_k + 2[p, S̃] (test T18)."""
    W1, S1, _, _, D = ideal_step(W, S, h, alpha, b, kind="magmp", tol=tol)
    Wt = W + D
    sc = 1j * h / (2.0 * b.hbar)
    p = laplacian_inverse(Wt, b) * sc
    A = b.xp.linalg.inv(b.eye - p)
    St = A @ S @ dagger(A)
    bS = sc * alpha * b.Phi
    return (W1, S1), (W + 2 * comm(p, Wt) + 2 * comm(bS, St), S + 2 * comm(p, St))


def _to_host(a):
    get = getattr(a, "get", None)
    return get() if callable(get) else a


# ----------------------------------------------------------------------------- the viscous step V


class SubstepFailure(Exception):
    def __init__(self, status: int, why: str):
        super().__init__(why)
        self.status = status


def _posdef(Th, b: Basis) -> bool:
    lt = b.xp.linalg.eigvalsh(Th)
    return bool(lt[..., 0].min() > 0)


def viscous_step(W, S, tau: float, th: Thermo, b: Basis, depth: int = 0):
    """V(τ) of one member (W, S of shape (1, N, N)): the exact viscous flow of W and its
    heat deposited locally, S′ = S + σD with σ from U(S′) = U(S) + δK (Newton; energy
    exact) and D = Θ*⁻¹∘Q̄ ⪰ ... (Θ* at S + ½D₀).  Returns W′, S′."""
    xp = b.xp
    if th.nu == 0.0 or tau == 0.0:
        return W, S
    W1 = viscous_flow(W, tau, th.nu, b)
    Wh = viscous_flow(W, 0.5 * tau, th.nu, b)
    dK = float((kinetic_energy(W, b) - kinetic_energy(W1, b))[0])
    Qb = herm((th.nu * tau / 6.0) * (W @ W + 4.0 * (Wh @ Wh) + W1 @ W1))
    if dK <= 0.0 or not float(xp.abs(Qb).max()) > 0:
        return W1, S
    Th0, lam0 = theta(S, th, b)
    D0, lt0 = inverse_jordan(Th0, Qb, b)
    D0 = herm(D0)
    if not float(lt0.min()) > 0:
        raise SubstepFailure(STATUS_THETA, "Θ is not positive definite before the viscous step")
    Ths, _ = theta(S + 0.5 * D0, th, b)
    D, lts = inverse_jordan(Ths, Qb, b)
    D = herm(D)
    if not float(lts.min()) > 0 or not float(trace_product(Th0, D)[0]) > 0:
        D = D0
    U0 = float(U(S, th, b, lam0)[0])
    H = U0 + float(kinetic_energy(W, b)[0])
    # Newton, one step past the tolerance 4 ε H (it then stands at round-off), keeping the σ of the
    # smallest residual: the run's energy then drifts by round-off only, not by the tolerance
    sigma, best_F, best_sigma, within = 1.0, math.inf, 1.0, 0
    for _ in range(50):
        S1 = S + sigma * D
        Th1, lam1 = theta(S1, th, b)
        F = float(U(S1, th, b, lam1)[0]) - U0 - dK
        if abs(F) < best_F:
            best_F, best_sigma = abs(F), sigma
        within += abs(F) <= 4.0 * EPS_MACH * abs(H)
        if within == 2 or F == 0.0:
            break
        sigma -= F / (b.area * float(trace_product(Th1, D)[0]))
    sigma = best_sigma
    S1 = herm(S + sigma * D)
    if not _posdef(theta(S1, th, b)[0], b):
        if depth > 40:
            raise SubstepFailure(STATUS_SUBSTEP, "the viscous step lost Θ ≻ 0 at every halving")
        W, S = viscous_step(W, S, 0.5 * tau, th, b, depth + 1)
        return viscous_step(W, S, 0.5 * tau, th, b, depth + 1)
    return W1, S1


# ----------------------------------------------------------------------------- the conduction step C


def _conduction_field(S, th: Thermo, b: Basis):
    """F(S) = κ Θ⁻¹∘L′(Θ) and λ_min(Θ)."""
    Th, _ = theta(S, th, b)
    J, lt = inverse_jordan(Th, th.kappa * conduction_laplacian(Th, b, th.graph), b)
    return herm(J), float(lt.min())


@dataclass
class ConductionCount:
    """Conduction sub-steps taken and rejected (halved) over a run."""

    substeps: int = 0
    rejected: int = 0
    seconds: float = 0.0  # time spent in conduction steps


def conduction_step(S, tau: float, th: Thermo, b: Basis, count: ConductionCount | None = None):
    """C(τ) of one member (S of shape (1, N, N); W is fixed): explicit midpoint sub-steps of
    Ṡ = κΘ⁻¹∘L′Θ, each followed by the energy shift S + μI (U unchanged) and accepted iff
    Θ ≻ 0 and tr S does not fall; a rejected sub-step is halved."""
    if th.kappa == 0.0 or tau == 0.0:
        return S
    count = count if count is not None else ConductionCount()
    t0 = time.perf_counter()
    try:
        return _conduction(S, tau, th, b, count)
    finally:
        count.seconds += time.perf_counter() - t0


def _conduction(S, tau, th: Thermo, b: Basis, count: ConductionCount):
    lam = b.xp.linalg.eigvalsh(S)
    F, ltmin = _conduction_field(S, th, b)
    if not ltmin > 0:
        raise SubstepFailure(STATUS_THETA, "Θ is not positive definite before the conduction step")
    Tmax = th.T0 * math.exp(float(lam.max()) / th.c)
    tau_s = 1.8 * th.c * ltmin / (th.kappa * b.Lambda * Tmax)
    n = max(1, math.ceil(tau / tau_s))
    delta = tau / n
    U0 = float(U(S, th, b, lam)[0])  # every sub-step keeps it: the energy shift restores it exactly
    for _ in range(n):
        S, F = _conduction_substep(S, F, U0, delta, th, b, count, tau)
    return S


def _conduction_substep(S, F0, U0: float, delta, th: Thermo, b: Basis, count: ConductionCount, tau: float):
    """One accepted sub-step δ (or two of δ/2, recursively) from S with F0 = F(S): (S′, F(S′))."""
    xp = b.xp
    if delta < 1e-12 * tau:
        raise SubstepFailure(STATUS_SUBSTEP, f"a conduction sub-step was halved below 1e-12 of τ = {tau:g} s")

    def halve():
        count.rejected += 1
        S1, F1 = _conduction_substep(S, F0, U0, 0.5 * delta, th, b, count, tau)
        return _conduction_substep(S1, F1, U0, 0.5 * delta, th, b, count, tau)

    Fm, ltm = _conduction_field(S + 0.5 * delta * F0, th, b)
    if not ltm > 0:
        return halve()
    Sp = herm(S + delta * Fm)
    num = U0 + th.alpha * b.area * float(trace_product(b.Phi, Sp)[0])
    den = float(internal(Sp, th, b)[0])
    if not (num > 0 and den > 0):
        return halve()
    S1 = Sp + (th.c * math.log(num / den)) * b.eye
    F1, lt1 = _conduction_field(S1, th, b)  # Θ(S′)'s eigenvalues: the acceptance test, and the next F
    if not lt1 > 0:
        return halve()
    tr0, tr1 = float(trace(S).real[0]), float(trace(S1).real[0])
    if tr1 < tr0:
        if tr0 - tr1 <= 64 * EPS_MACH * (float(xp.abs(S.diagonal(axis1=-2, axis2=-1).real).sum()) + 1.0):
            count.substeps += 1  # at equilibrium: the entropy differences are below round-off
            return S, F0
        return halve()
    count.substeps += 1
    return S1, F1


# ----------------------------------------------------------------------------- helpers for states


def rest_state(theta0: float, th: Thermo, b: Basis, members: int = 1):
    """The isothermal rest state W = 0, S = c log((θ₀I + αΦ)/T₀) (Θ = θ₀I)."""
    if not theta0 > th.alpha:
        raise ValueError(f"the rest state needs θ₀ > α (θ₀ = {theta0}, α = {th.alpha})")
    lam, V = eig(theta0 * b.eye + th.alpha * b.Phi, b)
    S = herm(func(lam, V, lambda x: th.c * b.xp.log(x / th.T0)))
    S = b.xp.broadcast_to(S, (members, b.N, b.N)).copy()
    return b.xp.zeros_like(S), S


def energies(W, S, th: Thermo, b: Basis) -> dict:
    """Kinetic, internal, potential and total energy (J) per member."""
    K = kinetic_energy(W, b)
    I = internal(S, th, b)
    P = potential(S, th, b)
    return {"kinetic": K, "internal": I, "potential": P, "total": K + I + P}
