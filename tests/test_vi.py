"""The variational integrator (liethermo.kernels.vi) and its discrete laws (SPEC §3–§5)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from liethermo.kernels import vi
from liethermo.kernels.so3 import cayley_apply
from liethermo.methods import FRICTION, LAW_KELVIN_NOETHER, LAW_UNIT_GAMMA, METHODS
from liethermo.simulate import STATUS_NEWTON, STATUS_OK, simulate

from conftest import H_PAPER, paper_numbers, random_body  # noqa: E402  (tests/ is on sys.path)


# ------------------------------------------------------------------ the scene itself
def test_paper_scene_matches_spec_derived_values(paper_params):
    """SPEC §2 lists the derived numbers of the paper scene; the conftest
    construction from a, ρ, μ, M must reproduce them (m, ℓ, 𝕀, c, c_v)."""
    d = paper_numbers()
    assert d["m"] == pytest.approx(1.4137166941154071, rel=1e-15)
    assert d["ell"] == pytest.approx(0.00125, rel=1e-12)
    assert d["Gz"] > 0  # χ = G/|G| = +e₃
    np.testing.assert_allclose(paper_params[0:3], [6.6783e-4, 6.6783e-4, 1.31947e-3], rtol=1e-5)
    assert paper_params[3] == pytest.approx(3.1415926535897936e-4, rel=1e-15)
    assert paper_params[7] == pytest.approx(1306.9263327416309, rel=1e-15)
    np.testing.assert_allclose(paper_params[4:7], [0.0, 0.0, d["m"] * 9.81 * d["ell"]], rtol=1e-15)


# ------------------------------------------------------------------ one step vs SPEC §3
def _spec_residual(X, omega, gamma_next, p, h, friction):
    """F(X) of SPEC §3, written independently of the kernels."""
    I = p[0:3]
    c = p[3]
    g = p[4:7]
    Pi = I * omega
    IX = I * X
    F = ((IX - Pi) / h + 0.5 * (np.cross(X, IX) + np.cross(omega, Pi))
         + h / 4.0 * ((X @ IX) * X - (omega @ Pi) * omega) - np.cross(gamma_next, g))
    if friction == "trapezoid":
        F += 0.5 * c * (X + omega)
    else:
        F += c * X
    # scale of the terms, for a relative round-off bound
    scale = np.abs(IX / h).max() + np.abs(Pi / h).max() + np.abs(g).max()
    return F, scale


@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
def test_vi_steps_solve_the_spec_equations(friction):
    """Every stored step of simulate(..., 'vi') satisfies SPEC §3 as written:
    Γ_{k+1} = (I + hΩ̂_k/2)⁻¹(I − hΩ̂_k/2)Γ_k, R_{k+1} = R_k(I − hΩ̂_k/2)⁻¹(I + hΩ̂_k/2),
    σ_{k+1} = σ_k + hc|Ω_k|²/(T₀e^{σ_k/c_v}), and F(Ω_{k+1}) = 0 to round-off
    (relative to the size of its terms); on a non-symmetric body with tilted χ."""
    y0, p = random_body(11, attitude=True)
    h = 0.05
    tr = simulate(y0, p, h, 200, "vi", friction=friction)
    assert tr.status[0] == STATUS_OK
    S = tr.states[0]
    worst_F = worst_G = worst_R = worst_s = 0.0
    for k in range(200):
        W = S[k, 0:3]
        Wh = np.array([[0.0, -W[2], W[1]], [W[2], 0.0, -W[0]], [-W[1], W[0], 0.0]]) * h
        Gn = np.linalg.solve(np.eye(3) + Wh / 2, (np.eye(3) - Wh / 2) @ S[k, 3:6])
        worst_G = max(worst_G, np.abs(Gn - S[k + 1, 3:6]).max())
        Rk = S[k, 7:16].reshape(3, 3)
        Rn = Rk @ np.linalg.solve(np.eye(3) - Wh / 2, np.eye(3) + Wh / 2)
        worst_R = max(worst_R, np.abs(Rn - S[k + 1, 7:16].reshape(3, 3)).max())
        sn = S[k, 6] + h * p[3] * (W @ W) / (p[8] * math.exp(S[k, 6] / p[7]))
        worst_s = max(worst_s, abs(sn - S[k + 1, 6]) / abs(S[k + 1, 6]))
        F, scale = _spec_residual(S[k + 1, 0:3], W, S[k + 1, 3:6], p, h, friction)
        worst_F = max(worst_F, np.abs(F).max() / scale)
    assert worst_G <= 1e-14, worst_G
    assert worst_R <= 1e-14, worst_R
    assert worst_s <= 1e-14, worst_s
    assert worst_F <= 1e-13, worst_F


# ------------------------------------------------------------------ invariants
def test_unit_gamma_and_rotation_over_ten_thousand_paper_steps(paper_y0_attitude, paper_params):
    """The VI moves Γ and R by Cayley rotations only, so over 10⁴ steps at the
    paper's h = 0.1 (1000 s): | |Γ_k| − 1 | ≤ 1e-13, |R_kᵀR_k − I| ≤ 1e-13, and
    Γ_k = R_kᵀe₃ stays consistent (the two updates are the same rotation).
    Contrast: RK4 at the same h drifts off the sphere by ≫ 1e-9 in 300 steps."""
    assert LAW_UNIT_GAMMA in METHODS["vi"].laws and LAW_UNIT_GAMMA not in METHODS["rk4"].laws
    tr = simulate(paper_y0_attitude, paper_params, H_PAPER, 10_000, "vi")
    assert tr.status[0] == STATUS_OK
    G = tr.gamma[0]
    R = tr.attitude[0]
    assert np.abs(np.linalg.norm(G, axis=1) - 1.0).max() <= 1e-13
    RtR = np.einsum("kji,kjl->kil", R, R) - np.eye(3)
    assert np.abs(RtR).max() <= 1e-13
    assert np.abs(np.linalg.det(R) - 1.0).max() <= 1e-13
    assert np.abs(G - R[:, 2, :]).max() <= 1e-13  # Rᵀe₃ is the third row of R
    # the top really moved: Γ explored the sphere
    assert np.ptp(G, axis=0).min() > 0.5
    rk4 = simulate(paper_y0_attitude, paper_params, H_PAPER, 300, "rk4")
    assert np.nanmax(np.abs(np.linalg.norm(rk4.gamma[0], axis=1) - 1.0)) > 1e-9


@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
def test_entropy_never_decreases(friction, paper_y0, paper_params):
    """σ_{k+1} − σ_k = hc|Ω_k|²/T ≥ 0 with c ≥ 0: σ is non-decreasing over 10⁴
    paper steps, strictly increasing while the top still spins (first 100 steps)."""
    tr = simulate(paper_y0, paper_params, H_PAPER, 10_000, "vi", friction=friction)
    s = tr.sigma[0]
    ds = np.diff(s)
    assert ds.min() >= 0.0
    assert np.all(ds[:100] > 0.0)
    assert s[-1] > 0.0


@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
def test_no_viscosity_no_entropy(friction, paper_y0, paper_params, random_body_factory):
    """With μ = 0 (c = 0) nothing is dissipated: σ stays exactly 0 (== 0.0, not
    merely small) at every step, on the paper scene and on a random body."""
    y1, p1 = random_body_factory(3)
    for y0, p in [(paper_y0, paper_params), (y1, p1)]:
        p = p.copy()
        p[3] = 0.0
        tr = simulate(y0, p, H_PAPER, 2000, "vi", friction=friction)
        assert tr.status[0] == STATUS_OK
        assert np.all(tr.sigma[0] == 0.0)


# ------------------------------------------------------------------ Kelvin–Noether
def _kn_quantity_np(W, G, p, h):
    """I_k = hΓ_k·(Π_k + (h/2)Ω_k×Π_k + (h²/4)(Ω_k·Π_k)Ω_k), SPEC §4 (vectorised)."""
    P = p[0:3] * W
    wP = np.einsum("ki,ki->k", W, P)[:, None]
    return h * np.einsum("ki,ki->k", G, P + h / 2 * np.cross(W, P) + h * h / 4 * wP * W)


def _kn_law(W, G, p, h, law):
    """Predicted I_{k+1} − I_k of SPEC §4."""
    c = p[3]
    if law == "trapezoid":
        return -(c / 2) * h * h * np.einsum("ki,ki->k", G[1:], W[:-1] + W[1:])
    return -c * h * h * np.einsum("ki,ki->k", G[1:], W[1:])


def _kn_scenes(paper_y0, paper_params):
    y1, p1 = random_body(7)
    assert abs(p1[4:7] @ np.array([0.0, 0.0, 1.0])) < 0.99 * np.linalg.norm(p1[4:7])  # χ tilted
    assert len(set(np.round(p1[0:3], 12))) == 3  # non-symmetric
    return {"paper": (paper_y0, paper_params), "random": (y1, p1)}


@pytest.mark.parametrize("scene", ["paper", "random"])
@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
def test_discrete_kelvin_noether_law(friction, scene, paper_y0, paper_params):
    """SPEC §4: the kernel's I_k (kelvin_noether_quantity) obeys, for every
    solution of the scheme, trapezoid: I_{k+1} − I_k = −(c/2)h²Γ_{k+1}·(Ω_k + Ω_{k+1});
    endpoint: I_{k+1} − I_k = −ch²Γ_{k+1}·Ω_{k+1}.  Residual ≤ 1e-12 · max|I_{k+1} − I_k|
    over 2000 steps at h = 0.1.  The law of the *other* variant must fail
    (relative residual > 1e-3), so the check discriminates between the variants."""
    assert LAW_KELVIN_NOETHER in METHODS["vi"].laws
    assert friction in FRICTION
    y0, p = _kn_scenes(paper_y0, paper_params)[scene]
    h = H_PAPER
    tr = simulate(y0, p, h, 2000, "vi", friction=friction)
    assert tr.status[0] == STATUS_OK
    W, G = tr.omega[0], tr.gamma[0]
    I_kernel = np.array([vi.kelvin_noether_quantity(W[k], G[k], p, h) for k in range(len(W))])
    I_np = _kn_quantity_np(W, G, p, h)
    np.testing.assert_allclose(I_kernel, I_np, rtol=1e-13, atol=1e-15 * np.abs(I_np).max())
    dI = np.diff(I_kernel)
    scale = np.abs(dI).max()
    assert scale > 0.0
    resid = np.abs(dI - _kn_law(W, G, p, h, friction)).max() / scale
    assert resid <= 1e-12, resid
    other = "endpoint" if friction == "trapezoid" else "trapezoid"
    assert np.abs(dI - _kn_law(W, G, p, h, other)).max() / scale > 1e-3


# ------------------------------------------------------------------ Newton
def _newton_setup(seed=21, h=0.1, omega=(3.0, -8.0, 5.0), friction="trapezoid"):
    _, p = random_body(seed)
    omega = np.array(omega)
    gamma = np.array([0.3, 0.4, math.sqrt(0.75)])
    gnext = np.empty(3)
    cayley_apply(-h * omega, gamma, gnext)
    alpha, beta = FRICTION[friction]
    b = np.empty(3)
    vi.momentum_constant(omega, gnext, p, h, beta, b)
    return p, h, omega, gnext, alpha, beta, b


@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
@pytest.mark.parametrize("h", [0.01, 0.1, 0.3])
def test_jacobian_matches_central_differences(friction, h):
    """momentum_jacobian is ∂F/∂X of momentum_residual: central differences
    (step 1e-6·max(1,|X_j|); F is cubic, so the truncation error is O(δ²)
    and tiny) agree to ≤ 1e-7 relative, at random X far from the solution."""
    p, h, omega, gnext, alpha, beta, b = _newton_setup(h=h, friction=friction)
    rng = np.random.default_rng(8)
    J = np.empty((3, 3))
    Fp = np.empty(3)
    Fm = np.empty(3)
    for _ in range(10):
        X = rng.normal(scale=5.0, size=3)
        vi.momentum_jacobian(X, p, h, alpha, J)
        Jfd = np.empty((3, 3))
        for j in range(3):
            dx = 1e-6 * max(1.0, abs(X[j]))
            Xp = X.copy()
            Xp[j] += dx
            Xm = X.copy()
            Xm[j] -= dx
            vi.momentum_residual(Xp, b, p, h, alpha, Fp)
            vi.momentum_residual(Xm, b, p, h, alpha, Fm)
            Jfd[:, j] = (Fp - Fm) / (2 * dx)
        rel = np.abs(J - Jfd).max() / np.abs(J).max()
        assert rel <= 1e-7, rel


def test_momentum_residual_is_the_spec_residual():
    """momentum_residual(X, momentum_constant(...)) = F(X) of SPEC §3 for both
    friction variants (α, β) = (½, ½) and (1, 0), at arbitrary X."""
    rng = np.random.default_rng(9)
    for friction in ("trapezoid", "endpoint"):
        p, h, omega, gnext, alpha, beta, b = _newton_setup(friction=friction)
        F = np.empty(3)
        for _ in range(10):
            X = rng.normal(scale=5.0, size=3)
            vi.momentum_residual(X, b, p, h, alpha, F)
            Fs, scale = _spec_residual(X, omega, gnext, p, h, friction)
            assert np.abs(F - Fs).max() <= 1e-14 * scale


def test_solve3_matches_numpy():
    """solve3(J, r) = J⁻¹r and returns det J (numpy.linalg.solve / det), relative
    to cond(J)·eps; a singular J returns det 0 and leaves ``out`` untouched."""
    rng = np.random.default_rng(10)
    out = np.empty(3)
    for _ in range(200):
        J = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-4, 4)
        r = rng.normal(size=3)
        det = vi.solve3(J, r, out)
        x = np.linalg.solve(J, r)
        cond = np.linalg.cond(J)
        assert np.abs(out - x).max() <= 1e-14 * cond * np.abs(x).max()
        assert det == pytest.approx(np.linalg.det(J), rel=1e-12 * cond)
    S = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]])
    out[:] = [7.0, 8.0, 9.0]
    assert vi.solve3(S, np.ones(3), out) == 0.0
    np.testing.assert_array_equal(out, [7.0, 8.0, 9.0])


@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
def test_newton_converges_quadratically(friction):
    """Newton's method with the exact Jacobian converges quadratically:
    e_{k+1} ≤ C e_k² with C = 2·|J(X*)⁻¹|∞·M/2, M = Imax(1 + 1.5h|X*|) a bound
    on |D²F| (½X×𝕀X and (h/4)(X·𝕀X)X are the quadratic/cubic terms), for every
    pair of steps above round-off.  Instrumented by hand with the kernel
    functions at a hard step (h = 0.3, |Ω| ≈ 27, h|Ω| ≈ 8: 6 iterations from
    the predictor).
    A wrong Jacobian converges linearly and breaks the bound as e_k → 0."""
    p, h, omega, gnext, alpha, beta, b = _newton_setup(h=0.3, omega=(10.0, -20.0, 15.0),
                                                       friction=friction)
    X = np.empty(3)
    vi.predictor(omega, gnext, p, h, X)
    F = np.empty(3)
    J = np.empty((3, 3))
    d = np.empty(3)
    steps = []
    for _ in range(10):
        vi.momentum_residual(X, b, p, h, alpha, F)
        vi.momentum_jacobian(X, p, h, alpha, J)
        vi.solve3(J, F, d)
        X -= d
        steps.append(np.abs(d).max())
    steps = np.array(steps)
    xs = np.abs(X).max()
    vi.momentum_residual(X, b, p, h, alpha, F)
    Fs, scale = _spec_residual(X, omega, gnext, p, h, friction)
    assert np.abs(Fs).max() <= 1e-14 * scale  # converged to the SPEC solution
    vi.momentum_jacobian(X, p, h, alpha, J)
    M = p[0:3].max() * (1.0 + 1.5 * h * np.linalg.norm(X))
    C = 2.0 * np.linalg.norm(np.linalg.inv(J), np.inf) * M / 2.0
    pairs = [(e0, e1) for e0, e1 in zip(steps[:-1], steps[1:]) if e1 > 1e-13 * xs]
    assert len(pairs) >= 3, steps
    for e0, e1 in pairs:
        assert e1 <= C * e0 * e0, (e0, e1, C)
    # log-ratio ~ 2 on the last two informative pairs
    (e0, e1), (e1b, e2) = pairs[-2], pairs[-1]
    assert math.log(e2 / e1b) / math.log(e1 / e0) > 1.7
    # and the kernel's own iteration agrees with the hand-run one
    Xk = np.empty(3)
    code, its = vi.newton_momentum(omega, gnext, p, h, alpha, beta, 1e-14, 30, Xk)
    assert code == vi.NEWTON_OK and its <= 8
    np.testing.assert_allclose(Xk, X, rtol=0, atol=4e-16 * xs * 10)


def test_newton_maxiter_is_reported():
    """At a hard step (h|Ω| ≈ 42) two Newton iterations cannot reach the
    tolerance: newton_momentum returns NEWTON_MAXITER (not OK); with 30
    iterations the same step converges (so it is the cap, not a singularity)."""
    p, h, omega, gnext, alpha, beta, b = _newton_setup(omega=(0.0, 300.0, 300.0))
    X = np.empty(3)
    code, its = vi.newton_momentum(omega, gnext, p, h, alpha, beta, 1e-14, 2, X)
    assert code == vi.NEWTON_MAXITER and its == 2
    code, its = vi.newton_momentum(omega, gnext, p, h, alpha, beta, 1e-14, 30, X)
    assert code == vi.NEWTON_OK and 2 < its <= 30


def test_newton_failure_is_not_accepted(paper_y0, paper_params):
    """simulate with newton_maxiter=2 on a huge spin (h|Ω| ≈ 42): the member gets
    STATUS_NEWTON at step 1, takes no step (steps_done 0), and every stored state
    after the initial one is NaN; the initial state is kept.  With the default
    iteration cap the same run completes."""
    y0 = paper_y0.copy()
    y0[0:3] = [0.0, 300.0, 300.0]
    tr = simulate(y0, paper_params, H_PAPER, 10, "vi", newton_maxiter=2)
    assert tr.status[0] == STATUS_NEWTON
    assert tr.fail_step[0] == 1 and tr.steps_done[0] == 0
    np.testing.assert_array_equal(tr.states[0, 0], y0)
    assert np.all(np.isnan(tr.states[0, 1:]))
    ok = simulate(y0, paper_params, H_PAPER, 10, "vi")
    assert ok.status[0] == STATUS_OK and np.all(np.isfinite(ok.states))
