"""The torus fluid's numerics against facts from outside its own convention: the
algebra of the clock-and-shift basis, the sine bracket summed mode by mode, exact
solutions, a pseudo-spectral continuum solver, and the first and second laws on
every sub-step."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from liethermo.torus import kernels as tk
from liethermo.torus import step as ts
from liethermo.torus.pseudospectral import PseudoSpectral, section7_modes


@pytest.fixture(autouse=True)
def one_blas_thread():
    """As a run does: the small matrices' LAPACK calls on one thread (pools cost more than they give)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        yield


def modes(N, d):
    """A real field's modes from {m: f_m} (the conjugates at −m added)."""
    f = np.zeros((1, N, N), complex)
    for (m1, m2), v in d.items():
        f[0, m1 % N, m2 % N] += v
        f[0, -m1 % N, -m2 % N] += np.conj(v)
    return f


def thermo_state(N):
    """The §7 vorticity and s₀ = 0.6 cos(x + y) − 0.2 sin 2y."""
    b = tk.basis(N)
    W = tk.from_modes(section7_modes(N)[None], b)
    S = tk.from_modes(modes(N, {(1, 1): 0.3, (0, 2): 0.1j}), b)
    return b, W, S


def H(W, S, th, b):
    return float(tk.kinetic_energy(W, b)[0] + tk.U(S, th, b)[0])


def S_tot(S, b):
    return float(b.area * tk.trace(S).real[0])


def run(W, S, th, b, method, h, steps, every=None, **kw):
    every = every or steps
    return ts.integrate(W, S, th=th, b=b, method=method, h=h, steps=steps, every=every, **kw)


# ----------------------------------------------------------------------------- T1–T4: algebra


def test_t1_clock_and_shift_algebra():
    N = 11
    ms = tk.wave_numbers(N)
    eps = 2 * math.pi / N
    err = 0.0
    for m1, m2 in itertools.product(ms, ms):
        Tm = tk.T(m1, m2, N)
        err = max(err, np.abs(Tm.conj().T - tk.T(-m1, -m2, N)).max())
        for n1, n2 in itertools.product(ms, ms):
            Tn = tk.T(n1, n2, N)
            lhs = Tm @ Tn - Tn @ Tm
            rhs = -2j * math.sin(eps * (m1 * n2 - m2 * n1)) * tk.T(m1 + n1, m2 + n2, N)
            err = max(err, np.abs(lhs - rhs).max(), abs(np.trace(Tm @ Tn.conj().T) - N * ((m1, m2) == (n1, n2))))
    assert err <= 1e-13
    # an even N is refused: 2 is not invertible mod N
    with pytest.raises(ValueError, match="odd"):
        tk.basis(12)


@pytest.mark.parametrize("N", [9, 15, 31])
def test_t2_fft_transforms_match_the_direct_sum(N):
    b = tk.basis(N)
    rng = np.random.default_rng(N)
    f = rng.standard_normal((2, N, N)) + 1j * rng.standard_normal((2, N, N))
    F = tk.from_modes(f, b)
    Fd = tk.from_modes_direct(f)
    assert np.abs(F - Fd).max() <= 1e-12 * np.abs(Fd).max()
    assert np.abs(tk.to_modes(F, b) - tk.to_modes_direct(Fd)).max() <= 1e-12 * np.abs(f).max()
    assert np.abs(tk.to_modes(F, b) - f).max() <= 1e-14 * np.abs(f).max() * 10  # round trip
    # a real field is a Hermitian matrix
    g = tk.modes_of_grid(rng.standard_normal((1, N, N)), b)
    G = tk.from_modes(g, b)
    assert np.abs(G - tk.dagger(G)).max() <= 1e-14 * np.abs(G).max()


def test_t3_laplacians_on_the_basis():
    N = 15
    b = tk.basis(N)
    ms = tk.wave_numbers(N)
    err = 0.0
    for m1, m2 in itertools.product(ms, ms):
        Tm = tk.T(m1, m2, N)[None]
        i, j = m1 % N, m2 % N
        err = max(err, np.abs(tk.conduction_laplacian(Tm, b) - b.lam_conj[i, j] * Tm).max(),
                  np.abs(tk.conduction_laplacian(Tm, b, graph=True) - b.lam_graph[i, j] * Tm).max(),
                  np.abs(tk.laplacian(Tm, b) + (m1 * m1 + m2 * m2) * Tm).max())
    assert err <= 1e-12
    # L′ is monotone in |m₁| ≤ M (0.985 … 22.5 at N = 15); L's finest mode conducts at only 0.246
    rates = -b.lam_conj[1:8, 0]
    assert np.all(np.diff(rates) > 0) and rates[0] == pytest.approx(0.98546, abs=1e-5)
    assert rates[-1] == pytest.approx(22.548, abs=1e-3)
    assert -b.lam_graph[7, 0] == pytest.approx(0.2464, abs=1e-4)
    rng = np.random.default_rng(3)
    W = tk.from_modes(tk.modes_of_grid(rng.standard_normal((1, N, N)), b), b)
    W0 = W - tk.trace(W)[:, None, None] / N * np.eye(N)  # mean-free
    assert np.abs(tk.laplacian_inverse(tk.laplacian(W0, b), b) - W0).max() <= 1e-12 * np.abs(W0).max()
    assert abs(tk.trace(tk.conduction_laplacian(W, b))[0]) <= 1e-12 * np.abs(W).max() * N


@pytest.mark.parametrize("N", [9, 15, 31])
def test_t4_matrix_rhs_is_the_sine_bracket(N):
    b = tk.basis(N)
    rng = np.random.default_rng(N + 1)
    f = tk.modes_of_grid(rng.standard_normal((1, N, N)), b)
    f[..., 0, 0] = 0
    W = tk.from_modes(f, b)
    d_matrix = tk.to_modes(tk.rhs_euler(W, 0.1, b), b)
    d_sine = tk.rhs_sine(f, 0.1)
    assert np.abs(d_matrix - d_sine).max() <= 1e-13 * np.abs(d_sine).max()
    # negative control: [P, W] instead of [W, P] is the wrong sign
    assert np.abs(-d_matrix - d_sine).max() > 0.1 * np.abs(d_sine).max()


# ----------------------------------------------------------------------------- T5–T7: the fluid


SHEAR = {(0, 2): -1.0}  # ω = −2 cos 2y
TG = {(1, 1): -0.5, (1, -1): 0.5}  # ω = 2 sin x sin y
SHELL5 = {(1, 2): 0.5, (2, -1): 0.35j, (2, 1): 0.2, (-1, 2): 0.1 - 0.3j}


def test_t5_exact_states():
    N = 31
    b = tk.basis(N)
    th = tk.Thermo()
    for d in (SHEAR, TG, SHELL5):
        W = tk.from_modes(modes(N, d), b)
        assert np.abs(tk.rhs_euler(W, 0.0, b)).max() <= 1e-14
        S = np.zeros_like(W)
        Ws, *_ = run(W, S, th, b, "cmp", 0.1, 10)
        assert np.abs(Ws[0, -1] - W[0]).max() <= 1e-14 * np.abs(W).max() * 10
    W = tk.from_modes(modes(N, SHEAR), b)
    Ws, *_ = run(W, np.zeros_like(W), th, b, "isomp", 0.1, 10)
    assert np.abs(Ws[0, -1] - W[0]).max() <= 1e-12 * np.abs(W).max()
    thn = tk.Thermo(nu=0.1)
    Ws, *_ = run(W, np.zeros_like(W), thn, b, "cmp", 0.1, 100)
    assert np.abs(Ws[0, -1] - math.exp(-0.1 * 4 * 10) * W[0]).max() <= 1e-12 * np.abs(W).max()
    # IsoMP drifts on Taylor–Green and the shell by O(h²): 8.1, 2.1, 0.53 ·10⁻⁵ and 2.5, 0.64, 0.16 ·10⁻⁴
    for d, c in ((TG, 8.1e-3), (SHELL5, 2.5e-2)):
        W = tk.from_modes(modes(N, d), b)
        drift = []
        for h in (0.1, 0.05, 0.025):
            Ws, *_ = run(W, np.zeros_like(W), th, b, "isomp", h, round(1 / h))
            drift.append(np.abs(Ws[0, -1] - W[0]).max() / np.abs(W).max())
            assert drift[-1] <= 1.2 * c * h * h
        assert math.log2(drift[0] / drift[2]) / 2 == pytest.approx(2.0, abs=0.1)


def test_t6_casimirs_energy_and_time_orders():
    N = 31
    b = tk.basis(N)
    th = tk.Thermo()
    W = tk.from_modes(section7_modes(N)[None], b)
    S = np.zeros_like(W)
    C0 = tk.casimirs(W, b)
    K0 = tk.kinetic_energy(W, b)
    for method in ("isomp", "isomp4", "cmp"):
        Ws, *_ = run(W, S, th, b, method, 0.05, 1000, every=1000)
        C = tk.casimirs(Ws[:, -1], b)
        assert np.abs(C - C0).max() / np.abs(C0).max() <= 1e-12, method
        if method == "cmp":
            assert abs(tk.kinetic_energy(Ws[:, -1], b) - K0)[0] / K0[0] <= 1e-13
    ref, *_ = run(W, S, th, b, "rk4", 1e-3, 1000)
    for method, order, tol in (("cmp", 2, 0.1), ("isomp", 2, 0.1), ("cmp4", 4, 0.2)):
        errs = []
        for h in (0.04, 0.02, 0.01):
            Ws, *_ = run(W, S, th, b, method, h, round(1 / h))
            errs.append(np.abs(Ws[0, -1] - ref[0, -1]).max())
        p = np.polyfit(np.log([0.04, 0.02, 0.01]), np.log(errs), 1)[0]
        assert p == pytest.approx(order, abs=tol), (method, errs)


def test_t7_convergence_to_the_pseudo_spectral_reference():
    ps = PseudoSpectral(128)
    w = ps.run(ps.from_modes(section7_modes(7)), 1.0, 5e-3)
    errs = []
    for N, expected in ((15, 8.39e-2), (31, 2.18e-2)):
        b = tk.basis(N)
        W = tk.from_modes(section7_modes(N)[None], b)
        Ws, *_ = run(W, np.zeros_like(W), tk.Thermo(), b, "rk4", 2.5e-3, 400)
        fr = ps.to_modes(w, N)
        errs.append(np.linalg.norm(tk.to_modes(Ws[:, -1], b)[0] - fr) / np.linalg.norm(fr))
        assert errs[-1] == pytest.approx(expected, rel=0.2)
    assert math.log(errs[0] / errs[1]) / math.log(31 / 15) >= 1.8
    # the time scaling: d ω/dt (matrix : continuum) at t = 0 is 1 − O(N⁻²): 0.863, 0.967 at 15, 31
    for N, ratio in ((15, 0.863), (31, 0.967)):
        b = tk.basis(N)
        W = tk.from_modes(section7_modes(N)[None], b)
        dm = tk.to_modes(tk.rhs_euler(W, 0.0, b), b)[0]
        dc = ps.to_modes(ps.rhs(ps.from_modes(section7_modes(N))), N)
        r = (np.vdot(dc, dm) / np.vdot(dc, dc)).real
        assert r == pytest.approx(ratio, abs=5e-3)


# ----------------------------------------------------------------------------- T8–T9: the laws of the RHS


def test_t8_first_and_second_law_of_the_rhs():
    b, W, S = thermo_state(15)
    th = tk.Thermo(alpha=0.3, nu=0.02, kappa=0.05)
    dW, dS = tk.rhs_thermo(W, S, th, b)
    P = tk.laplacian_inverse(W, b)
    Th, _ = tk.theta(S, th, b)
    dK = -b.area * tk.trace_product(P, dW)[0]
    dU = b.area * tk.trace_product(Th, dS)[0]
    assert abs(dK + dU) <= 1e-13 * (abs(dK) + abs(dU))
    rate = tk.entropy_rate(W, S, th, b)[0]
    assert abs(b.area * tk.trace(dS).real[0] - rate) <= 1e-13 * abs(rate)
    assert rate > 0
    # tr(Θ⁻¹L′Θ) ≥ 0 for random Θ ≻ 0 with condition numbers up to e²⁰
    rng = np.random.default_rng(8)
    worst = np.inf
    for _ in range(200):
        Q, _r = np.linalg.qr(rng.standard_normal((15, 15)) + 1j * rng.standard_normal((15, 15)))
        lam = np.exp(rng.uniform(0, rng.uniform(0, 20), 15))
        T = (Q * lam) @ Q.conj().T
        worst = min(worst, tk.trace_product(np.linalg.inv(T), tk.conduction_laplacian(T[None], b))[0])
    assert worst >= 0


def test_t9_the_spectral_laplacian_breaks_the_second_law():
    N = 15
    b = tk.basis(N)
    # Θ(x) = 1, e³, e⁶, e³, 1, … on the grid x_j = 2πj/N (diagonal entry a holds x_{2a mod N})
    j = (2 * np.arange(N)) % N
    Th = np.diag(np.exp(3 - 3 * np.cos(np.pi * j / 2))).astype(complex)[None]
    inv = np.linalg.inv(Th)
    assert tk.trace_product(inv, tk.laplacian(Th, b))[0] < 0
    assert tk.trace_product(inv, tk.conduction_laplacian(Th, b))[0] > 0
    assert tk.trace_product(inv, tk.conduction_laplacian(Th, b, graph=True))[0] > 0


# ----------------------------------------------------------------------------- T10–T19: the scheme


@pytest.mark.parametrize("method", ["cmp", "magmp"])
def test_t10_ideal_casimirs(method):
    b, W, S = thermo_state(15)
    th = tk.Thermo(alpha=0.3)
    Ws, Ss, st, *_ = run(W, S, th, b, method, 0.05, 1000)
    assert st[0] == 0
    W1, S1 = Ws[:, -1], Ss[:, -1]

    def cas(W, S):
        lam, V = np.linalg.eigh(S)
        return np.array([tk.trace(S @ S).real[0], tk.trace(S @ S @ S).real[0], tk.trace(W @ S).real[0],
                         tk.trace(W @ S @ S).real[0], np.exp(lam).sum()])

    c0, c1 = cas(W, S), cas(W1, S1)
    # relative to each Casimir's size, or to N max|S|^k max|W|^l where it vanishes by symmetry
    w, s = np.abs(W).max(), np.abs(S).max()
    scale = np.maximum(np.abs(c0), 15 * np.array([s**2, s**3, w * s, w * s * s, 1.0]))
    assert np.all(np.abs(c1 - c0) <= 1e-12 * scale), np.abs(c1 - c0) / scale
    assert abs(tk.trace(S1).real[0] - tk.trace(S).real[0]) <= 1e-12 * 15 * np.abs(S).max()


def test_t11_energy_cmp_exact_magmp_bounded():
    b, W, S = thermo_state(15)
    th = tk.Thermo(alpha=0.2, nu=0.02, kappa=0.05)
    H0 = H(W, S, th, b)
    Ws, Ss, st, *_ = run(W, S, th, b, "cmp", 0.1, 100, every=10)
    dH = [abs(H(Ws[:, j], Ss[:, j], th, b) - H0) / H0 for j in range(Ws.shape[1])]
    assert max(dH) <= 1e-13
    drift = []
    for h in (0.1, 0.05):
        Ws, Ss, *_ = run(W, S, th, b, "magmp", h, round(2 / h), every=round(0.5 / h))
        drift.append(max(abs(H(Ws[:, j], Ss[:, j], th, b) - H0) / H0 for j in range(Ws.shape[1])))
    assert 1e-9 < drift[0] < 1e-2 and 3.0 < drift[0] / drift[1] < 5.0  # bounded, O(h²)


def test_t12_t17_laws_on_every_substep_over_the_grid():
    """ν ∈ {0, .02, .5}, κ ∈ {0, .05, 1, 20}, α ∈ {0, .3}, h ∈ {.05, .5} to t = 1 (CMP):
    every V and C sub-step keeps H to 1e-14, no sub-step lowers S_tot, Θ ≻ 0 (T17)."""
    b, W0, S0 = thermo_state(15)
    worst = {"V": 0.0, "C": 0.0, "I": 0.0}
    least = 0.0
    theta_min = np.inf
    count = tk.ConductionCount()
    for nu, kappa, alpha, h in itertools.product([0, 0.02, 0.5], [0, 0.05, 1, 20], [0, 0.3], [0.05, 0.5]):
        th = tk.Thermo(alpha=alpha, nu=nu, kappa=kappa)
        W, S = W0.copy(), S0.copy()
        for _ in range(round(1 / h)):
            for part, tau in (("V", h / 2), ("C", h / 2), ("I", h), ("C", h / 2), ("V", h / 2)):
                H0, s0 = H(W, S, th, b), S_tot(S, b)
                if part == "V":
                    W, S = tk.viscous_step(W, S, tau, th, b)
                elif part == "C":
                    S = tk.conduction_step(S, tau, th, b, count)
                else:
                    W, S, _, failed, _ = tk.ideal_step(W, S, tau, alpha, b, kind="cmp")
                    assert not failed.any()
                worst[part] = max(worst[part], abs(H(W, S, th, b) - H0) / abs(H0))
                least = min(least, (S_tot(S, b) - s0) / (abs(s0) + 4 * math.pi**2))
            theta_min = min(theta_min, float(tk.theta_range(S, th, b)[0][0]))
    assert worst["V"] <= 1e-14 and worst["C"] <= 1e-14 and worst["I"] <= 1e-14
    assert least >= -1e-14
    assert theta_min == pytest.approx(0.356, abs=2e-3)
    assert count.substeps > 1000 and count.rejected == 0


def test_t13_strang_order_two_against_rk4():
    b, W, S = thermo_state(15)
    th = tk.Thermo(alpha=0.2, nu=0.02, kappa=0.05)
    ref_W, ref_S, *_ = run(W, S, th, b, "rk4", 0.1 / 32, 32)
    errs = []
    for h in (0.1 / 2, 0.1 / 4, 0.1 / 8):
        Ws, Ss, *_ = run(W, S, th, b, "cmp", h, round(0.1 / h))
        errs.append(max(np.abs(Ws[0, -1] - ref_W[0, -1]).max(), np.abs(Ss[0, -1] - ref_S[0, -1]).max()))
    p = np.polyfit(np.log([2, 4, 8]), np.log(errs), 1)[0]
    assert -p == pytest.approx(2.0, abs=0.1), errs


def test_t14_relaxation_to_uniform_temperature_and_maximal_entropy():
    b, W, S = thermo_state(15)
    th = tk.Thermo(kappa=5.0)
    K0, U0 = tk.kinetic_energy(W, b)[0], tk.U(S, th, b)[0]
    Ws, Ss, st, *_ = run(W, S, th, b, "cmp", 0.1, 300)
    lo, hi = tk.theta_range(Ss[:, -1], th, b)
    K1 = tk.kinetic_energy(Ws[:, -1], b)[0]
    theta_inf = (U0 + K0 - K1) / (4 * math.pi**2 * th.c)
    mean = tk.trace(Ss[:, -1]).real  # Θ = e^S: its mean from the eigenvalues
    lam = np.linalg.eigvalsh(Ss[0, -1])
    tmean = np.exp(lam).mean()
    assert (hi[0] - lo[0]) / tmean <= 1e-6
    assert abs(tmean - theta_inf) / theta_inf <= 1e-7
    s_max = 4 * math.pi**2 * th.c * math.log(theta_inf / th.T0)
    assert abs(S_tot(Ss[:, -1], b) - s_max) / abs(s_max) <= 1e-7
    assert mean is not None


def test_t15_isothermal_rest_state_is_steady():
    b = tk.basis(15)
    th = tk.Thermo(alpha=0.3, nu=0.1, kappa=1.0)
    W, S = tk.rest_state(1.0, th, b)
    Ws, Ss, st, *_ = run(W, S, th, b, "cmp", 0.1, 100)
    assert np.abs(Ss[0, -1] - S[0]).max() <= 1e-13 and np.abs(Ws[0, -1]).max() <= 1e-13
    lo, hi = tk.theta_range(Ss[:, -1], th, b)
    assert hi[0] - lo[0] <= 1e-13


def test_t18_magmp_final_form_is_quflows():
    b, W, S = thermo_state(15)
    (W1, S1), (W2, S2) = tk.magmp_quflow_form(W, S, 0.05, 0.3, b)
    assert np.abs(W1 - W2).max() <= 1e-14 * np.abs(W).max() * 10
    assert np.abs(S1 - S2).max() <= 1e-14 * np.abs(S).max() * 10


def test_t19_positivity_loss_is_detected_per_member():
    N = 15
    b = tk.basis(N)
    W = 3 * tk.from_modes(section7_modes(N)[None], b)
    S = tk.from_modes(modes(N, {(0, 1): 0.3}), b)  # 0.6 cos y
    W2, S2 = np.concatenate([W, W]), np.concatenate([S, 0 * S])  # the second member stays positive
    th = tk.Thermo(alpha=0.7)
    Ws, Ss, st, failed, _ = run(W2, S2, th, b, "cmp", 0.05, 400, every=1)
    assert st[0] == tk.STATUS_THETA and 155 <= failed[0] <= 165, (st, failed)
    assert np.isnan(Ws[0, failed[0]:]).all()
    thn = tk.Thermo(alpha=0.7, nu=0.02)
    Ws, Ss, st, failed, _ = run(W, S, thn, b, "cmp", 0.05, 400)
    assert st[0] == 0


def test_compositions_refused_with_dissipation():
    b, W, S = thermo_state(9)
    with pytest.raises(ValueError, match="ν = κ = 0 only"):
        run(W, S, tk.Thermo(kappa=0.1), b, "cmp4", 0.1, 1)
    with pytest.raises(ValueError, match="magmp"):
        run(W, S, tk.Thermo(alpha=0.1), b, "isomp", 0.1, 1)
