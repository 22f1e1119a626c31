"""The Zeitlin fluid against physics it does not define itself: exact solutions
of Euler's equations on the sphere, rotations of the sphere, and a peer code.

A matrix W stands for the vorticity ω = Σ ω_lm Y_lm that (1/ħ)[P, W] advects
(W = i√(N/4π) Σ ω_lm T_lm).  These tests fail if that correspondence is off by
any factor or sign: the speed of a Rossby–Haurwitz wave depends on the scale
of ω, the angular momentum of a solid-body rotation on its orientation, and
a rotated field on every harmonic's phase."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.special import sph_harm_y

from liethermo.scene import load_scene
from liethermo.zeitlin import kernels as zk
from liethermo.zeitlin import plotting as zp
from liethermo.zeitlin import run as zr

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference" / "quflow_map.npz"


def _field_at(C: np.ndarray, b: zk.Basis, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """ω(θ, φ) = Σ_lm ω_lm Y_lm from the packed coefficients (m ≥ 0), by scipy's harmonics."""
    Y = sph_harm_y(b.ell.astype(int)[:, None], b.order[:, None], theta.ravel()[None], phi.ravel()[None])
    w = zk.mode_weights(b)
    return ((C[:, None] * Y).real * w[:, None]).sum(0).reshape(np.shape(theta))


def _wave_speed(ds, l: int, m: int) -> tuple[float, float]:
    """The wave's angular speed (rad s-1) from the phase of its stored ω_lm,
    and Ω_b (rad s-1) read from the dataset's angular momentum, L_z = (8π/3)Ω_b."""
    C = zr.vorticity_coefficients(ds)
    mode = int(np.flatnonzero((C["l"].values == l) & (C["m"].values == m))[0])
    phase = np.unwrap(np.angle(C.isel(member=0, mode=mode).values))
    rate = np.polyfit(ds["t"].values, phase, 1)[0]
    omega_b = float(ds["angular_momentum"].isel(member=0, t=0).sel(axis="z")) / (8 * math.pi / 3)
    return -rate / m, omega_b


@pytest.mark.parametrize("N", [8, 16, 48])
def test_a_rossby_haurwitz_wave_turns_at_the_exact_speed(N):
    """ω = 2Ω_b cos θ + a Re Y_lm turns eastward at c = Ω_b(1 − 2/(l(l+1))), an
    exact solution of Euler's equations on the sphere.  A run of the built-in
    scene (the DOP853 reference, stored vorticity) turns at c to 1e-8, with Ω_b
    read from the dataset's angular momentum; the vector field gives it to
    round-off."""
    for l, m in ((2, 1), (3, 2), (5, 3)):
        sc = load_scene("zeitlin_ideal", {
            "zeitlin.N": N, "initial.lmax": l, "initial.m": m, "initial.noise": 0.0, "ensemble.members": 1,
            "integrator.method": "reference", "integrator.h": 0.05, "integrator.steps": 40, "output.every": 4,
            "output.vorticity": True, "output.compare": []})
        ds = zr.simulate(sc, progress=False)
        speed, omega_b = _wave_speed(ds, l, m)
        exact = omega_b * (1 - 2 / (l * (l + 1)))
        assert omega_b > 0.1 and abs(speed / exact - 1) < 1e-8, (N, l, m, speed, exact)
        L = ds["angular_momentum"].values[0]
        assert np.abs(L[:, :2]).max() < 1e-12 * L[0, 2]  # about z only, and kept
        assert np.abs(L[:, 2] / L[0, 2] - 1).max() < 1e-11
        # the vector field itself: dω_lm/dt = −imc ω_lm for the wave, 0 for every other mode
        b = zk.basis(N)
        W0 = zr.initial_fields(sc)
        C0 = zk.to_modes(W0, b)[0]
        dC = zk.to_modes(zk.rhs(W0, 0.0, b)[0], b)[0]
        k = b.offset[m] + (l - m)
        assert abs(dC[k] / (-1j * m * exact * C0[k]) - 1) < 1e-12
        assert np.abs(np.delete(dC, k)).max() < 1e-12 * abs(dC[k])


@pytest.mark.parametrize("N", [8, 16, 48])
def test_a_single_degree_decays_at_the_exact_rate_and_its_energy_becomes_heat(N):
    """A field of one degree l is steady for Euler's nonlinearity ([Δ⁻¹W, W] = 0)
    and decays as e^{−ν(l(l+1)−2)t}, its energy as the square, all of it into
    heat.  The reference meets this to round-off; the splitting converges to it
    at order 2, RK4 at order 4."""
    l, nu, T = 4, 0.02, 3.0
    b = zk.basis(N)
    rng = np.random.default_rng(N)
    C = np.zeros(b.modes, complex)
    sel = b.ell == l
    C[sel] = rng.normal(size=sel.sum()) + 1j * rng.normal(size=sel.sum())
    C[: N] = C[: N].real
    W0 = zk.from_modes(C[None], b)

    def errors(method, h):
        steps = int(round(T / h))
        sc = load_scene("zeitlin_decay", {"zeitlin.N": N, "initial.lmax": min(6, N - 1), "fluid.kinematic_viscosity": nu,
                                          "ensemble.members": 1, "integrator.h": h, "integrator.steps": steps,
                                          "output.every": steps})
        traj = zr.integrate(sc, W0, method=method, progress=False, keep_vorticity=True)
        decay = np.exp(-nu * (l * (l + 1) - 2) * traj.times)
        err_c = np.abs(zk.to_modes(traj.W[0], b) - C[None] * decay[:, None]).max() / np.abs(C).max()
        H, q = traj.out.H[0], traj.q[0]
        return err_c, np.abs(H / (H[0] * decay ** 2) - 1).max(), np.abs((H + q) / H[0] - 1).max()

    ec, eh, eq = errors("reference", 0.1)
    assert ec < 1e-10 and eh < 1e-12 and eq < 1e-12, (ec, eh, eq)
    for method, order, hs in (("split", 2, (0.1, 0.05)), ("rk4", 4, (0.05, 0.025))):
        (e1, _, _), (e2, _, q2) = errors(method, hs[0]), errors(method, hs[1])
        assert abs(np.log2(e1 / e2) - order) < 0.25, (method, e1, e2)
        assert q2 < 1e-7, (method, q2)


def test_the_same_field_converges_in_n():
    """A member's initial field has the same coefficients at every N, so N = 16,
    32, 64 are one flow: its energy spectrum at t = 20 s differs less from the
    next N as N grows (ν = 1e-2 s-1, degrees l ≤ 6, RK4 at h = 0.005 s, whose
    time error is far below these differences)."""
    specs, fields = {}, {}
    for N in (16, 32, 64):
        sc = load_scene("zeitlin_decay", {"zeitlin.N": N, "fluid.kinematic_viscosity": 1e-2, "initial.lmax": 6,
                                          "ensemble.members": 2, "integrator.method": "rk4", "integrator.h": 0.005,
                                          "integrator.steps": 4000, "output.every": 4000, "output.compare": []})
        fields[N] = zk.to_modes(zr.initial_fields(sc), zk.basis(N))
        specs[N] = zr.simulate(sc, progress=False)["energy_spectrum"].values[:, -1, :15]
    b16 = zk.basis(16)
    for N in (32, 64):  # the coefficients of degrees l ≤ 6 are the same, and there are no others
        b = zk.basis(N)
        for k16 in np.flatnonzero(b16.ell <= 6):
            m, l = b16.order[k16], int(b16.ell[k16])
            assert np.abs(fields[N][:, b.offset[m] + l - m] - fields[16][:, k16]).max() < 1e-13
        assert np.abs(fields[N][:, b.ell > 6]).max() < 1e-13
    d1 = np.abs(specs[16] - specs[32]).sum(axis=1)
    d2 = np.abs(specs[32] - specs[64]).sum(axis=1)
    assert np.all(d2 < 0.5 * d1), (d1, d2)


@pytest.mark.parametrize("N", [128, 256])
def test_the_harmonics_rotate_as_spherical_harmonics_at_large_n(N):
    """Conjugating W by the SU(2) matrix of a rotation R turns its field into
    ω(R⁻¹x) exactly: every T_lm has the phase of Y_lm, also where the
    coherent-state symbols of the high degrees are far below round-off."""
    b = zk.basis(N)
    rng = np.random.default_rng(N)
    C = rng.standard_normal(b.modes) + 1j * rng.standard_normal(b.modes)
    C[:N] = C[:N].real
    W = zk.from_modes(C[None], b)[0]
    jx, jy, jz = zk.spin_matrices(N)
    a, be, g = 0.3, 1.1, -0.7
    U = expm(-1j * a * jz) @ expm(-1j * be * jy) @ expm(-1j * g * jz)
    C2 = zk.to_modes((U @ W @ U.conj().T)[None], b)[0]
    theta = np.arccos(rng.uniform(-1, 1, 40))
    phi = rng.uniform(0, 2 * np.pi, 40)
    x = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    Rz = lambda t: np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])  # noqa: E731
    Ry = lambda t: np.array([[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]])  # noqa: E731
    y = (Rz(a) @ Ry(be) @ Rz(g)).T @ x  # R⁻¹x
    rotated = _field_at(C, b, np.arccos(np.clip(y[2], -1, 1)), np.arctan2(y[1], y[0]))
    assert np.abs(_field_at(C2, b, theta, phi) - rotated).max() < 1e-12 * np.abs(rotated).max()
    # T_ll is (−1)^l J_+^l / ‖J_+^l‖: every entry of its diagonal has the sign (−1)^l
    for l in range(1, N):
        v = b.vecs[b.voff[l]:b.voff[l + 1]].reshape(N - l, N - l)[:, 0]
        assert np.all(v * (-1) ** l >= 0), l


def test_a_solid_body_rotation_has_the_angular_momentum_8pi_over_3_omega_and_is_steady():
    """ω = 2Ω·x (projected on the harmonics by quadrature, not by the kernels'
    formulas): the map gives 2Ω·x back, L = ∫x ω dA = (8π/3)Ω, and the vector
    field vanishes."""
    N = 16
    b = zk.basis(N)
    Omega = np.array([0.3, -0.5, 0.8])
    u, wq = np.polynomial.legendre.leggauss(8)
    th, ph = np.arccos(u)[:, None], (2 * np.pi * np.arange(16) / 16)[None, :]
    x = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th) * np.ones_like(ph)])
    f = 2 * np.tensordot(Omega, x, axes=1)
    C = np.zeros(b.modes, complex)
    for m in (0, 1):
        Y = sph_harm_y(1, m, th, ph)
        C[b.offset[m] + 1 - m] = (np.conj(Y) * f * wq[:, None]).sum() * 2 * np.pi / 16
    W = zk.from_modes(C[None], b)
    assert np.allclose(zk.angular_momentum(W, b)[0], 8 * np.pi / 3 * Omega, rtol=0, atol=1e-13)
    lon, lat, om = zp.vorticity_on_grid(W[0], 7, 9)
    xg = np.stack([np.cos(lat)[:, None] * np.cos(lon), np.cos(lat)[:, None] * np.sin(lon),
                   np.sin(lat)[:, None] * np.ones_like(lon)])
    assert np.abs(om - 2 * np.tensordot(Omega, xg, axes=1)).max() < 1e-13
    assert np.abs(zk.rhs(W, 0.0, b)[0]).max() < 1e-13 * np.abs(W).max()


def test_the_map_and_the_energies_agree_with_quflow():
    """quflow's own map of its vorticity matrices to functions, and its energy
    and enstrophy (data/reference/quflow_map.py wrote them).  quflow orders its
    spin basis m = −s … s, ours s … −s (the two are turned by π about the x
    axis, the same dynamics), and it measures areas with dA/4π."""
    ref = np.load(REFERENCE)
    for N in (5, 8, 16, 32):
        W = ref[f"W_{N}"][::-1, ::-1][None]
        b = zk.basis(N)
        C = zk.to_modes(W, b)[0]
        fun = ref[f"fun_{N}"]
        assert np.abs(_field_at(C, b, ref[f"theta_{N}"], ref[f"phi_{N}"]) - fun).max() < 1e-12 * np.abs(fun).max()
        assert abs(zk.energy_of_modes(C[None], b)[0] / (4 * np.pi * ref[f"energy_{N}"]) - 1) < 1e-13
        assert abs(zk.enstrophy(W)[0] / (4 * np.pi * ref[f"enstrophy_{N}"]) - 1) < 1e-13
