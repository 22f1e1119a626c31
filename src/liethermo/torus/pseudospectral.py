"""A continuum reference for the torus fluid: a dealiased pseudo-spectral solver of
ω_t = {ω, ψ} + νΔω on [0, 2π)², ψ = Δ⁻¹ω, {f, g} = f_x g_y − f_y g_x (numpy FFTs,
2/3 rule, classical RK4).  It imports nothing of the model and shares no code with
the sine bracket, so agreement in N is a check from outside the model's convention
(tests/test_torus_numerics.py, the torus_resolution study).

Fields are given and returned as Fourier coefficients f̂[m₁ mod n, m₂ mod n] of
f = Σ f̂_m e^{i(m₁x + m₂y)} (the torus model's layout)."""

from __future__ import annotations

import numpy as np


class PseudoSpectral:
    def __init__(self, n: int, nu: float = 0.0):
        self.n, self.nu = n, nu
        k = np.fft.fftfreq(n, 1.0 / n)
        self.k1, self.k2 = np.meshgrid(k, k, indexing="ij")
        self.ksq = self.k1**2 + self.k2**2
        self.inv = np.divide(1.0, self.ksq, out=np.zeros_like(self.ksq), where=self.ksq > 0)
        cut = n / 3.0
        self.mask = (np.abs(self.k1) < cut) & (np.abs(self.k2) < cut)

    def rhs(self, w):
        psi = -self.inv * w
        g = lambda a: np.fft.ifft2(a).real  # noqa: E731  (grid values times 1/n², consistently)
        wx, wy = g(1j * self.k1 * w), g(1j * self.k2 * w)
        px, py = g(1j * self.k1 * psi), g(1j * self.k2 * psi)
        return self.mask * np.fft.fft2(wx * py - wy * px) - self.nu * self.ksq * w

    def run(self, w, t: float, dt: float):
        steps = int(round(t / dt))
        for _ in range(steps):
            k1 = self.rhs(w)
            k2 = self.rhs(w + 0.5 * dt * k1)
            k3 = self.rhs(w + 0.5 * dt * k2)
            k4 = self.rhs(w + dt * k3)
            w = w + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return w

    def from_modes(self, f: np.ndarray) -> np.ndarray:
        """Modes |m_i| ≤ M (an N × N array, N = 2M + 1) into this grid's coefficients (× n²)."""
        N = f.shape[-1]
        M = (N - 1) // 2
        w = np.zeros((self.n, self.n), complex)
        ms = np.arange(-M, M + 1)
        w[np.ix_(ms % self.n, ms % self.n)] = f[np.ix_(ms % N, ms % N)] * self.n**2
        return w * self.mask

    def to_modes(self, w: np.ndarray, N: int) -> np.ndarray:
        M = (N - 1) // 2
        ms = np.arange(-M, M + 1)
        f = np.zeros((N, N), complex)
        f[np.ix_(ms % N, ms % N)] = w[np.ix_(ms % self.n, ms % self.n)] / self.n**2
        return f


def section7_modes(N: int) -> np.ndarray:
    """ω₀ = cos x + cos y + 0.6 cos 2x + 0.2 cos 3x + 0.3 sin(x + 2y) as modes (N × N)."""
    f = np.zeros((N, N), complex)

    def put(m1, m2, v):
        f[m1 % N, m2 % N] += v
        f[-m1 % N, -m2 % N] += np.conj(v)

    put(1, 0, 0.5)
    put(0, 1, 0.5)
    put(2, 0, 0.3)
    put(3, 0, 0.1)
    put(1, 2, -0.15j)  # 0.3 sin(x + 2y) = 0.3 (e^{iθ} − e^{−iθ})/2i
    return f


def reference_modes(N: int, t: float = 1.0, nu: float = 0.0, n: int = 128, dt: float = 5e-3) -> np.ndarray:
    ps = PseudoSpectral(n, nu)
    return ps.to_modes(ps.run(ps.from_modes(section7_modes(max(N, 7))), t, dt), N)
