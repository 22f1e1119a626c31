"""The variational integrator in node form (liethermo.top.kernels.vi) and its discrete laws."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import H_PAPER, OMEGA0, R0, make_physics, paper_numbers, paper_physics, random_body
from liethermo.top.methods import MethodChoice
from liethermo.top.kernels import layout as L
from liethermo.top.kernels import vi
from liethermo.top.kernels._jit import jit
from liethermo.top.kernels.gen import abs_or_zero
from liethermo.top.kernels.terms.thermo import SYMMETRIC
from liethermo.top.methods import LAW_KELVIN_NOETHER, LAW_UNIT_GAMMA, METHODS
from liethermo.top.physics import build_model
from liethermo.top.simulate import STATUS_NEWTON, STATUS_OK, simulate

REFERENCE = "data/reference/paper_vi_step_velocities.npz"


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _legendre(I, X, h):
    """M_h(X) = 𝕀X + (h/2) X×𝕀X + (h²/4)(X·𝕀X) X, written independently of the kernels."""
    IX = I * X
    return IX + 0.5 * h * np.cross(X, IX) + 0.25 * h * h * (X @ IX) * X


# ------------------------------------------------------------------ the paper's sequence
def test_paper_scene_reproduces_the_papers_step_velocities(paper):
    """With the paper's choices (first step velocity Ω(0), trapezoid friction,
    explicit entropy update) the node form produces the paper's sequence Ω_k:
    the stored step velocities, Γ_k, σ_k and R_k of 300 steps at h = 0.1 agree
    with a trajectory of the paper's scheme written in its original form
    (Ω_k as the unknown) to ≤ 1e-12, for both friction variants."""
    ref = np.load(Path_(REFERENCE))
    phys, om0, R = paper
    for friction in ("trapezoid", "endpoint"):
        tr = simulate(phys, om0, R, H_PAPER, 300, MethodChoice.of("vi", start="node", entropy="explicit", friction=friction), attitude=True)
        assert tr.status[0] == STATUS_OK
        np.testing.assert_allclose(tr.omega_step[0], ref[f"{friction}_omega_step"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(tr.gamma[0], ref[f"{friction}_gamma"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(tr.sigma[0], ref[f"{friction}_sigma"], rtol=1e-11, atol=0)
        np.testing.assert_allclose(tr.attitude[0], ref[f"{friction}_attitude"], rtol=0, atol=1e-12)


def Path_(rel):
    from pathlib import Path

    return Path(__file__).resolve().parents[1] / rel


# ------------------------------------------------------------------ one step vs the equations
@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
@pytest.mark.parametrize("entropy", ["explicit", "symmetric"])
def test_vi_steps_solve_the_node_form_equations(friction, entropy):
    """Every stored step satisfies the node form as written in docs/model.md,
    on a non-symmetric body with tilted χ and a diagonal friction:
    M_h(X_k) + w_L h C X_k = μ_k + (h/2) τ(Γ_k);  Γ_{k+1} = (I + hX̂/2)⁻¹(I − hX̂/2)Γ_k;
    R_{k+1} = R_k (I − hX̂/2)⁻¹(I + hX̂/2);  μ_{k+1} = M_{−h}(X_k) − w_R h C X_k + (h/2)τ(Γ_{k+1});
    and the entropy update (explicit: σ + hP/T(σ); symmetric: U(σ') − U(σ) = hP,
    P = X·CX), each to round-off relative to the size of its terms."""
    phys, om0, R = random_body(11, diagonal=True)
    h = 0.05
    wl, wr = vi.FRICTION_WEIGHTS[friction]
    tr = simulate(phys, om0, R, h, 200, MethodChoice.of("vi", friction=friction, entropy=entropy), attitude=True)
    assert tr.status[0] == STATUS_OK
    I, C, g = phys.inertia[0], phys.stokes_resistance[0], phys.gravity_torque[0]
    cv, T0 = phys.heat_capacity[0], phys.T0[0]
    X, G, s, mu, Rk = tr.omega_step[0], tr.gamma[0], tr.sigma[0], tr.momentum[0], tr.attitude[0]
    worst = dict(newton=0.0, gamma=0.0, R=0.0, mu=0.0, sigma=0.0)
    for k in range(200):
        Wh = _hat(X[k]) * h
        lhs = _legendre(I, X[k], h) + wl * h * C * X[k]
        rhs = mu[k] + 0.5 * h * np.cross(G[k], g)
        worst["newton"] = max(worst["newton"], np.abs(lhs - rhs).max() / np.abs(I * X[k]).max())
        Gn = np.linalg.solve(np.eye(3) + Wh / 2, (np.eye(3) - Wh / 2) @ G[k])
        worst["gamma"] = max(worst["gamma"], np.abs(Gn - G[k + 1]).max())
        Rn = Rk[k] @ np.linalg.solve(np.eye(3) - Wh / 2, np.eye(3) + Wh / 2)
        worst["R"] = max(worst["R"], np.abs(Rn - Rk[k + 1]).max())
        mun = _legendre(I, X[k], -h) - wr * h * C * X[k] + 0.5 * h * np.cross(G[k + 1], g)
        worst["mu"] = max(worst["mu"], np.abs(mun - mu[k + 1]).max() / np.abs(I * X[k]).max())
        P = X[k] @ (C * X[k])
        T = T0 * math.exp(s[k] / cv)
        if entropy == "explicit":
            sn = s[k] + h * P / T
        else:
            sn = s[k] + cv * math.log1p(h * P / (cv * T))
        worst["sigma"] = max(worst["sigma"], abs(sn - s[k + 1]) / abs(s[k + 1]))
    assert worst["newton"] <= 1e-13, worst
    assert worst["gamma"] <= 1e-14 and worst["R"] <= 1e-14, worst
    assert worst["mu"] <= 1e-14, worst
    assert worst["sigma"] <= 1e-14, worst
    # the node velocity is 𝕀⁻¹μ
    np.testing.assert_allclose(tr.omega[0], mu / I, rtol=1e-15)


# ------------------------------------------------------------------ symmetry
@jit
def _substep(model, y_row, h, mode, out):
    """One substep of size h of the node map from the state row y_row (the
    Newton solve of the next substep uses the same h)."""
    y = L.load_vi_state(model, y_row, 0, 1)
    v = vi.vi_coefficients(model, h, 0.5, 0.5)
    G1, s1, mu1, R1, b, xp, ps, sc0, scs, ok = vi.vi_advance(model, v, v, y, h, mode, True)
    X1, xs, code, its = vi.newton_solve(model, v, b, xp, ps, s1, sc0, scs, 1e-15, 50)
    L.store_vi_state(model, out, 0, 1, (X1, G1, s1, mu1, vi.add_opt(s1, xs), R1))
    return code


@jit
def _start(model, y_row, h):
    """μ₀ = 𝕀Ω(0) (in the momentum columns) → X₀ by the Newton solve of a step h."""
    y = L.load_vi_state(model, y_row, 0, 1)
    X, G, s, mu, sn, R = y
    v = vi.vi_coefficients(model, h, 0.5, 0.5)
    r0, r1, r2 = vi.node_rhs(model, v, mu, G)
    b = (-r0, -r1, -r2)
    ps = vi.entropy_predictor(model.inertia, model, v, X, s)
    X1, xs, code, its = vi.newton_solve(model, v, b, X, ps, s, 1.0, abs_or_zero(s), 1e-15, 50)
    L.store_vi_state(model, y_row, 0, 1, (X1, G, s, mu, vi.add_opt(s, xs), R))
    return code


@pytest.mark.parametrize("body", ["paper", "random", "coupled", "double_bracket"])
def test_node_map_is_symmetric(body):
    """Φ_{−h} ∘ Φ_h = id for trapezoid friction and the symmetric entropy
    update: a step with h from the node (Γ, μ, σ[, R]), then one with −h,
    returns to (Γ, μ, σ, R) to round-off (≤ 1e-13 relative) — the property
    that lets compositions raise the order; for the paper top, a random body
    with diagonal friction, the coupled top (𝕀(S)) and double-bracket friction."""
    if body == "paper":
        phys, om0, R = paper_physics(), OMEGA0[None], R0[None]
    elif body == "random":
        phys, om0, R = random_body(3, diagonal=True)
    elif body == "coupled":
        phys = replace(paper_physics(), heat_capacity=np.array([1e-3]), thermal_expansion=np.array([1e-3]))
        om0, R = OMEGA0[None] * 3.0, R0[None]
    else:
        phys = replace(paper_physics(), internal_friction=np.array([20.0]))
        om0, R = np.array([[3.0, -1.0, 2.0]]), R0[None]
    km = build_model(phys, attitude=True)
    lay = km.layout("vi")
    h = 0.1
    y = np.zeros(lay.size)
    y[lay.slice("omega_step")] = om0[0]
    y[lay.slice("gamma")] = R[0, 2]
    y[lay.slice("momentum")] = phys.inertia[0] * om0[0]
    y[lay.slice("attitude")] = R[0].ravel()
    assert _start(km.model, y, h) == L.NEWTON_OK
    y1 = np.empty_like(y)
    assert _substep(km.model, y, h, SYMMETRIC, y1) == L.NEWTON_OK
    # the node (Γ, μ, σ, R) at t_1; restart backwards from it with step −h
    back = y1.copy()
    back[lay.slice("omega_step")] = -y1[lay.slice("omega_step")]  # predictor only
    assert _start(km.model, back, -h) == L.NEWTON_OK
    y2 = np.empty_like(y)
    assert _substep(km.model, back, -h, SYMMETRIC, y2) == L.NEWTON_OK
    for part in ("gamma", "momentum", "attitude"):
        a, b = y[lay.slice(part)], y2[lay.slice(part)]
        assert np.abs(a - b).max() <= 1e-13 * np.abs(a).max(), (part, a, b)
    s1 = y1[lay.slice("sigma")][0]
    assert s1 > 0.0  # the forward step did produce heat ...
    assert abs(y2[lay.slice("sigma")][0]) <= 1e-13 * s1  # ... and the backward one took it back


# ------------------------------------------------------------------ invariants
def test_unit_gamma_and_rotation_over_ten_thousand_paper_steps(paper):
    """The VI moves Γ and R by Cayley rotations only: over 10⁴ steps at h = 0.1
    | |Γ_k| − 1 | ≤ 1e-13, |R_kᵀR_k − I| ≤ 1e-13 and Γ_k = R_kᵀe₃.  Contrast:
    RK4 at the same h drifts off the sphere by ≫ 1e-9 within 300 steps."""
    assert LAW_UNIT_GAMMA in METHODS["vi"].laws and LAW_UNIT_GAMMA not in METHODS["rk4"].laws
    phys, om0, R = paper
    tr = simulate(phys, om0, R, H_PAPER, 10_000, "vi", attitude=True)
    assert tr.status[0] == STATUS_OK
    G, Rk = tr.gamma[0], tr.attitude[0]
    assert np.abs(np.linalg.norm(G, axis=1) - 1.0).max() <= 1e-13
    assert np.abs(np.einsum("kji,kjl->kil", Rk, Rk) - np.eye(3)).max() <= 1e-13
    assert np.abs(G - Rk[:, 2, :]).max() <= 1e-13
    assert np.ptp(G, axis=0).min() > 0.5  # the top really moved
    rk4 = simulate(phys, om0, R, H_PAPER, 300, "rk4")
    assert np.nanmax(np.abs(np.linalg.norm(rk4.gamma[0], axis=1) - 1.0)) > 1e-9


@pytest.mark.parametrize("entropy", ["explicit", "symmetric"])
def test_entropy_never_decreases(entropy, paper):
    """Both updates add the non-negative work of the discrete friction: σ is
    non-decreasing over 10⁴ paper steps, strictly while the top spins."""
    phys, om0, R = paper
    s = simulate(phys, om0, R, H_PAPER, 10_000, MethodChoice.of("vi", entropy=entropy)).sigma[0]
    ds = np.diff(s)
    assert ds.min() >= 0.0 and np.all(ds[:100] > 0.0) and s[-1] > 0.0


def test_no_viscosity_no_entropy_and_no_thermodynamics(paper):
    """With μ = 0 nothing dissipates: the model has no thermodynamic term and no
    friction term (so no entropy is integrated), S stays S₀ exactly, and the
    mechanical energy is all that moves."""
    phys, om0, R = paper
    free = replace(phys, stokes_resistance=np.zeros((1, 3)))
    km = build_model(free)
    assert km.model.thermo is None and [type(t).__name__ for t in km.model.forces] == ["Gravity"]
    tr = simulate(free, om0, R, H_PAPER, 2000, "vi")
    assert tr.status[0] == STATUS_OK and not tr.layout.has("sigma")
    assert np.all(tr.sigma[0] == 0.0)


# ------------------------------------------------------------------ Kelvin–Noether
@pytest.mark.parametrize("body", ["paper", "random", "diagonal"])
@pytest.mark.parametrize("friction", ["trapezoid", "endpoint"])
def test_discrete_kelvin_noether_law_in_node_form(friction, body):
    """J_k = Γ_k·μ_k obeys, for every solution of the scheme,
    J_{k+1} − J_k = −h (w_L Γ_k + w_R Γ_{k+1})·C X_k (gravity does no work on it:
    Γ·(Γ×g⃗) = 0), to ≤ 1e-12 of max |J_{k+1} − J_k| over 2000 steps at h = 0.1;
    the law with the other weights fails (> 1e-3) whenever C is not isotropic
    (for an isotropic C both read −h Γ_k·cX_k since Γ_{k+1}·X_k = Γ_k·X_k)."""
    assert LAW_KELVIN_NOETHER in METHODS["vi"].laws
    if body == "paper":
        phys, om0, R = paper_physics(), OMEGA0[None], R0[None]
    else:
        phys, om0, R = random_body(7, diagonal=(body == "diagonal"))
    h = H_PAPER
    tr = simulate(phys, om0, R, h, 2000, MethodChoice.of("vi", friction=friction))
    assert tr.status[0] == STATUS_OK
    X, G, mu = tr.omega_step[0], tr.gamma[0], tr.momentum[0]
    C = phys.stokes_resistance[0]
    J = np.einsum("ki,ki->k", G, mu)
    dJ = np.diff(J)
    scale = np.abs(dJ).max()
    assert scale > 0.0

    def law(wl, wr):
        return -h * np.einsum("ki,ki->k", wl * G[:-1] + wr * G[1:], C * X[:-1])

    wl, wr = vi.FRICTION_WEIGHTS[friction]
    assert np.abs(dJ - law(wl, wr)).max() / scale <= 1e-12
    if body == "diagonal":
        wl2, wr2 = vi.FRICTION_WEIGHTS["endpoint" if friction == "trapezoid" else "trapezoid"]
        assert np.abs(dJ - law(wl2, wr2)).max() / scale > 1e-3


@jit
def _advance_row(model, h, wl, wr, Y, out):
    """vi_advance of the state row Y (layout ``vi``) with steps h, h: the new
    state (X of Y kept) into ``out``."""
    v = vi.vi_coefficients(model, h, wl, wr)
    y = L.load_vi_state(model, Y, 0, 1)
    G1, s1, mu1, R1, b, xp, ps, sc0, scs, ok = vi.vi_advance(model, v, v, y, h, SYMMETRIC, True)
    L.store_vi_state(model, out, 0, 1, (y[0], G1, s1, mu1, vi.add_opt(s1, ps), R1))


@pytest.mark.parametrize("case", ["free", "gravity", "stokes"])
def test_momentum_update_rotates_the_newton_right_hand_side(case):
    """The kernels' momentum update μ' = cay(−hX̂)(r − w_L h CX) − w_R h CX + (h/2)τ(Γ')
    equals the paper's M_{−h}(X) − w_R h CX + (h/2)τ(Γ') at the Newton solution
    (≤ 1e-15 relative), and keeps the laws for *any* X, here one 1e-3 off the
    solution: Γ'·μ' = Γ·μ without friction and |μ'| = |μ| for the free body,
    to round-off; with Stokes friction J' − J is the discrete law's
    −h(w_L Γ + w_R Γ')·CX.  The paper's form misses each law by about the
    residual (> 1e-6 here)."""
    rng = np.random.default_rng(5)
    I = rng.uniform(0.5e-3, 2.0e-3, 3)
    g = {"free": np.zeros(3), "gravity": 0.02 * rng.normal(size=3), "stokes": 0.02 * rng.normal(size=3)}[case]
    c = 2e-5 if case == "stokes" else 0.0
    phys = make_physics(I, c, g, 1e-3 if c else 1.0, friction=(c * np.array([0.7, 1.0, 1.6]) if c else None))
    model = build_model(phys).model
    lay = L.state_layout(model, "vi")
    h, (wl, wr) = 0.1, vi.FRICTION_WEIGHTS["trapezoid"]
    C = phys.stokes_resistance[0]
    Gam = rng.normal(size=3)
    Gam /= np.linalg.norm(Gam)
    X = 3.0 * rng.normal(size=3)
    tau = lambda G: np.cross(G, g) if np.any(g) else np.zeros(3)  # noqa: E731
    # the node momentum whose Newton solution is X
    mu = _legendre(I, X, h) + wl * h * C * X - 0.5 * h * tau(Gam)
    sol = None
    for Xk in (X, X * (1.0 + 1e-3) + 1e-3):
        Y = np.zeros(lay.size)
        Y[lay.slice("omega_step")], Y[lay.slice("gamma")], Y[lay.slice("momentum")] = Xk, Gam, mu
        out = np.zeros(lay.size)
        _advance_row(model, h, wl, wr, Y, out)
        G1, mu1 = out[lay.slice("gamma")], out[lay.slice("momentum")]
        paper = _legendre(I, Xk, -h) - wr * h * C * Xk + 0.5 * h * tau(G1)
        J, J1 = Gam @ mu, G1 @ mu1
        law = -h * (wl * Gam + wr * G1) @ (C * Xk)
        if sol is None:
            sol = np.abs(mu1 - paper).max() / np.abs(mu).max()
            assert sol <= 1e-15
            continue
        scale = np.abs(mu).max() * np.abs(Gam).max()
        assert abs((J1 - J) - law) <= 4e-16 * scale
        assert abs(Gam @ mu - G1 @ paper - (-law)) > 1e-6 * scale  # the paper's form, off the solution
        if case == "free":
            assert abs(np.linalg.norm(mu1) - np.linalg.norm(mu)) <= 4e-16 * np.linalg.norm(mu)
            assert abs(np.linalg.norm(paper) - np.linalg.norm(mu)) > 1e-6 * np.linalg.norm(mu)


def test_casimir_holds_at_the_newton_solution_not_at_any_iterate():
    """Under double-bracket friction |μ| is kept to round-off at the Newton
    solution, but not whatever X is (unlike Kelvin–Noether and the free body's
    |μ|): on the flat_spin body at h = 0.1 s an iterate 10⁻⁶ off (relative)
    moves |μ| by 10⁻¹⁰ … 10⁻⁷ relative (docs/model.md, "Newton iteration")."""
    from liethermo.top.initial import initial_conditions
    from liethermo.top.physics import physics_of_scene
    from liethermo.scene import load_scene

    sc = load_scene("flat_spin")
    phys = physics_of_scene(sc, 1)
    w0 = initial_conditions(sc)[0][0]
    model = build_model(phys).model
    lay = L.state_layout(model, "vi")
    I, lam, h = phys.inertia[0], phys.internal_friction[0], 0.1
    rng = np.random.default_rng(1)
    worst = {0.0: 0.0, 1e-6: 0.0}
    for _ in range(50):
        X = np.linalg.norm(w0) * rng.uniform(0.3, 1.5) * rng.normal(size=3) / np.sqrt(3.0)
        m = I * X + h * h / 4 * (X @ (I * X)) * X
        mu = _legendre(I, X, h) + 0.5 * h * lam * ((m @ m) * X - (m @ X) * m)  # Newton solution: X
        Gam = rng.normal(size=3)
        for off in worst:
            Y = np.zeros(lay.size)
            Y[lay.slice("omega_step")] = X * (1.0 + off * rng.normal(size=3))
            Y[lay.slice("gamma")], Y[lay.slice("momentum")] = Gam / np.linalg.norm(Gam), mu
            out = np.zeros(lay.size)
            _advance_row(model, h, 0.5, 0.5, Y, out)
            change = abs(np.linalg.norm(out[lay.slice("momentum")]) / np.linalg.norm(mu) - 1.0)
            worst[off] = max(worst[off], change)
    assert worst[0.0] <= 1e-15
    assert 1e-10 <= worst[1e-6] <= 1e-7, worst


@jit
def _solve(model, h, b, xp, scale0, tol, maxiter, out):
    v = vi.vi_coefficients(model, h, 0.5, 0.5)
    X, xs, code, its = vi.newton_solve(model, v, (b[0], b[1], b[2]), (xp[0], xp[1], xp[2]), None,
                                       None, scale0, None, tol, maxiter)
    out[0], out[1], out[2] = X
    return code, its


def test_newton_stop_on_predicted_convergence_is_within_tolerance():
    """The solve stops when its correction, or a tenth of the next one as
    quadratic convergence predicts it, is below tol·|X|∞.  Over 2 × 500
    random solves at h = 0.1 s (|X| ~ 1.7 and 5 rad/s, predictors 1 % and
    0.1 % off): the accepted X is within tol·|X|∞ of the solution iterated to
    its floating-point fixed point, no solve takes more than 3 iterations,
    and from the closer predictor the mean is ≤ 2.5 (the prediction fires);
    a single iteration is never accepted from a correction that is not
    itself below tol (maxiter = 1 fails)."""
    rng = np.random.default_rng(8)
    I = rng.uniform(0.5e-3, 2.0e-3, 3)
    phys = make_physics(I, 2e-5, 0.02 * rng.normal(size=3), 1e-3)
    model = build_model(phys).model
    h, tol = 0.1, 1e-14
    out, fp = np.empty(3), np.empty(3)
    for spin, off in ((1.0, 1e-2), (3.0, 1e-3)):
        its_all = []
        for _ in range(500):
            X = spin * rng.normal(size=3)
            b = -(_legendre(I, X, h) + 0.5 * h * phys.stokes_resistance[0] * X)
            xp = X * (1.0 + off * rng.normal(size=3))
            scale0 = np.abs(xp).max()
            code, its = _solve(model, h, b, xp, scale0, tol, 30, out)
            assert code == L.NEWTON_OK
            _solve(model, h, b, xp, scale0, 0.0, 12, fp)  # tol 0: iterate to the fixed point
            assert np.abs(out - fp).max() <= tol * np.abs(fp).max()
            its_all.append(its)
            code1, its1 = _solve(model, h, b, xp, scale0, tol, 1, out)
            assert code1 == L.NEWTON_MAXITER and its1 == 1
        assert max(its_all) <= 3
    assert np.mean(its_all) <= 2.5


# ------------------------------------------------------------------ Newton
@jit
def _newton_correction(model, v, x0, x1, x2, xs, b0, b1, b2, s1):
    """(d₀, d₁, d₂, d_s, det J): vi.newton_step at σ' = s1 with the exact
    operations (what the straightforward kernel computes)."""
    d0, d1, d2, ds, det, ok = vi.newton_step(model, v, x0, x1, x2, xs, b0, b1, b2,
                                             vi.newton_data(model.inertia, model, s1), True)
    return d0, d1, d2, ds, det


@jit
def _residual_jacobian(model, v, X, b, xs, s1, F, J):
    d0, d1, d2, ds, det = _newton_correction(model, v, X[0], X[1], X[2], xs, b[0], b[1], b[2], s1)
    r = vi.residual_jacobian(model, v, X[0], X[1], X[2], b[0], b[1], b[2])
    for i in range(3):
        F[i] = r[i]
        for j in range(3):
            J[i, j] = r[3 + 3 * i + j]
    return d0, d1, d2, det


@pytest.mark.parametrize("body", ["paper", "diagonal", "double_bracket"])
@pytest.mark.parametrize("h", [0.01, 0.1, 0.3])
def test_jacobian_matches_central_differences(body, h):
    """The analytic Jacobian is ∂F/∂X of the residual: central differences
    (F is a polynomial of low degree: the truncation error is tiny) agree to
    ≤ 1e-7 relative at random X far from the solution — with a diagonal
    friction and with the double-bracket friction's own Jacobian."""
    if body == "paper":
        phys = paper_physics()
    elif body == "diagonal":
        phys = random_body(5, diagonal=True)[0]
    else:
        phys = replace(paper_physics(), internal_friction=np.array([0.7]))
    model = build_model(phys).model
    v = vi.vi_coefficients(model, h, 0.5, 0.5)
    rng = np.random.default_rng(8)
    b = rng.normal(size=3) * 1e-3
    F, J, Fp, Fm, Jd = (np.empty(3), np.empty((3, 3)), np.empty(3), np.empty(3), np.empty((3, 3)))
    for _ in range(10):
        X = rng.normal(scale=5.0, size=3)
        _residual_jacobian(model, v, X, b, None, 0.0, F, J)
        Jfd = np.empty((3, 3))
        for j in range(3):
            dx = 1e-6 * max(1.0, abs(X[j]))
            Xp, Xm = X.copy(), X.copy()
            Xp[j] += dx
            Xm[j] -= dx
            _residual_jacobian(model, v, Xp, b, None, 0.0, Fp, Jd)
            _residual_jacobian(model, v, Xm, b, None, 0.0, Fm, Jd)
            Jfd[:, j] = (Fp - Fm) / (2 * dx)
        assert np.abs(J - Jfd).max() / np.abs(J).max() <= 1e-7


@jit
def _coupled_F(model, v, X, xs, b, s1):
    """The coupled top's 4-vector F(X, Δ) = (F₁, F₂) and its Newton correction."""
    d0, d1, d2, ds, det = _newton_correction(model, v, X[0], X[1], X[2], xs, b[0], b[1], b[2], s1)
    return d0, d1, d2, ds, det


def _coupled_residual_np(phys, h, X, D, b, s1):
    """F(X, Δ) of the coupled top, written from docs/model.md independently of the kernels."""
    I, C, cv, T0, al = (phys.inertia[0], phys.stokes_resistance[0], phys.heat_capacity[0], phys.T0[0],
                        phys.thermal_expansion[0])

    def phi(s):
        return 1.0 + al * (T0 * math.exp(s / cv) - T0)

    ss = 0.5 * (phi(s1) ** 2 + phi(s1 + D) ** 2)
    F1 = ss * _legendre(I, X, h) + 0.5 * h * C * X + b
    U = lambda s: cv * T0 * math.exp(s / cv)  # noqa: E731
    F2 = (U(s1 + D) - U(s1)) - 0.5 * (X @ (I * X)) * (phi(s1 + D) ** 2 - phi(s1) ** 2) - h * (X @ (C * X))
    return np.concatenate([F1, [F2]])


def test_coupled_newton_correction_is_the_newton_step_of_the_documented_residual():
    """For the coupled top the kernel's correction (d_X, d_Δ) equals
    J⁻¹F of the documented 4-vector residual, with J from central
    differences, to ≤ 1e-6 relative (at points off the solution)."""
    phys = replace(paper_physics(), heat_capacity=np.array([1e-3]), thermal_expansion=np.array([1e-3]))
    model = build_model(phys).model
    h = 0.05
    v = vi.vi_coefficients(model, h, 0.5, 0.5)
    rng = np.random.default_rng(2)
    for _ in range(6):
        X = rng.normal(scale=2.0, size=3)
        s1 = abs(rng.normal()) * 1e-5
        D = abs(rng.normal()) * 1e-6
        b = rng.normal(size=3) * 1e-3
        d = np.array(_coupled_F(model, v, X, D, b, s1)[:4])
        z = np.concatenate([X, [D]])
        F = _coupled_residual_np(phys, h, X, D, b, s1)
        Jfd = np.empty((4, 4))
        for j in range(4):
            dz = 1e-6 * max(1.0, abs(z[j])) if j < 3 else 1e-4 * max(abs(D), 1e-9)
            zp, zm = z.copy(), z.copy()
            zp[j] += dz
            zm[j] -= dz
            Jfd[:, j] = (_coupled_residual_np(phys, h, zp[:3], zp[3], b, s1)
                         - _coupled_residual_np(phys, h, zm[:3], zm[3], b, s1)) / (2 * dz)
        expect = np.linalg.solve(Jfd, F)
        np.testing.assert_allclose(d, expect, rtol=1e-6, atol=1e-9 * np.abs(expect).max())


def test_newton_converges_quadratically():
    """Newton's method with the exact Jacobian converges quadratically: at a
    hard step (h = 0.3, h|Ω| ≈ 8) the logarithm of the correction ratio
    log(e₂/e₁)/log(e₁/e₀) of the last informative pairs is ≥ 1.7; a wrong
    Jacobian would converge linearly (ratio → 1)."""
    phys = random_body(21)[0]
    model = build_model(phys).model
    h = 0.3
    v = vi.vi_coefficients(model, h, 0.5, 0.5)
    X = np.array([10.0, -20.0, 15.0])
    b = -_legendre(phys.inertia[0], X * 1.05, h)  # a solution near 1.05 X
    F, J = np.empty(3), np.empty((3, 3))
    steps = []
    for _ in range(12):
        d0, d1, d2, det = _residual_jacobian(model, v, X, b, None, 0.0, F, J)
        X = X - np.array([d0, d1, d2])
        steps.append(max(abs(d0), abs(d1), abs(d2)))
    xs = np.abs(X).max()
    informative = [e for e in steps if e > 1e-12 * xs]
    assert len(informative) >= 4, steps
    e0, e1, e2 = informative[-3:]
    assert math.log(e2 / e1) / math.log(e1 / e0) >= 1.7, steps


def test_newton_failure_is_reported_and_not_accepted(paper):
    """A huge spin (h|Ω| ≈ 42) with newton_maxiter = 2 cannot converge: the
    member gets STATUS_NEWTON at step 1 (the first solve, from its node
    momentum), takes no step, and every stored state after the initial one is
    NaN; with the default iteration cap the same run completes."""
    phys, om0, R = paper
    om = np.array([[0.0, 300.0, 300.0]])
    tr = simulate(phys, om, R, H_PAPER, 10, "vi", newton_maxiter=2)
    assert tr.status[0] == STATUS_NEWTON and tr.fail_step[0] == 1 and tr.steps_done[0] == 0
    assert np.all(np.isnan(tr.states[0, 1:]))
    ok = simulate(phys, om, R, H_PAPER, 10, "vi")
    assert ok.status[0] == STATUS_OK and np.all(np.isfinite(ok.states))
    # a failure after a few steps (paper start: no solve before step 1)
    tr = simulate(phys, om, R, H_PAPER, 10, MethodChoice.of("vi", start="node"), newton_maxiter=3)
    assert tr.status[0] == STATUS_NEWTON and tr.fail_step[0] == tr.steps_done[0] + 1
    k = tr.steps_done[0]
    assert np.all(np.isfinite(tr.states[0, : k + 1])) and np.all(np.isnan(tr.states[0, k + 1:]))


def test_paper_numbers_match_the_scene_code():
    """The paper scene built by the scene code (scene → physics) equals the one
    built here from the paper's raw numbers."""
    from liethermo.top.physics import physics_of_scene
    from liethermo.scene import load_scene

    d = paper_numbers()
    p = physics_of_scene(load_scene("paper"))
    np.testing.assert_allclose(p.inertia[0], d["inertia"], rtol=1e-15)
    np.testing.assert_allclose(p.stokes_resistance[0], [d["c"]] * 3, rtol=1e-15)
    np.testing.assert_allclose(p.gravity_torque[0], d["gvec"], rtol=1e-15)
    assert p.heat_capacity[0] == pytest.approx(d["cv"], rel=1e-15)
    assert d["m"] == pytest.approx(1.4137166941154071, rel=1e-15)
    assert d["ell"] == pytest.approx(0.00125, rel=1e-12)


def test_make_physics_helper_is_the_paper():
    d = paper_numbers()
    p = make_physics(d["inertia"], d["c"], d["gvec"], d["cv"])
    assert build_model(p).terms() == ["ConstantInertia", "IdealSolid", "StokesSphere", "Gravity"]


def test_friction_keeps_its_precision_at_tiny_steps():
    """The spherical top's exact decay Ω(t) = Ω(0) exp(−ct/I) at t = 0.5 s with
    steps so small that the friction of one step is 10⁻⁵ of the inertia: the
    compositions stay within 2e-13 of it (the friction folded into I + w_L h C
    and rounded once would lose ~εI/(hc) of its precision: 1.4e-12 for vi4,
    9.7e-12 for vi6 here)."""
    from liethermo.top.initial import initial_conditions
    from liethermo.top.physics import physics_of_scene
    from liethermo.scene import load_scene

    sc = load_scene("spherical_top")
    phys = physics_of_scene(sc, 1)
    om, R = initial_conditions(sc)
    I, c = phys.inertia[0, 0], phys.stokes_resistance[0, 0]
    for method, h, n in (("vi4", 2e-5, 25000), ("vi6", 5e-5, 10000)):
        tr = simulate(phys, om, R, h, n, method, every=n)
        exact = om[0] * np.exp(-c * h * n / I)
        assert np.abs(tr.omega[0, -1] - exact).max() <= 2e-13 * np.abs(om[0]).max(), method



@pytest.mark.parametrize("name, keys", [("paper", {}), ("flat_spin", {}), ("ellipsoid", {}),
                                        ("paper", {"fluid.quadratic_drag": 2e-4})])
def test_newton_jacobian_is_the_derivative_of_the_newton_function(name, keys):
    """The Jacobian the stability study conditions (vi.newton_jacobian) is
    dF/dX of the kernels' Newton function, nonlinear frictions included:
    central differences agree to 1e-7."""
    from liethermo.top.physics import build_model, physics_of_scene
    from liethermo.scene import load_scene

    model = build_model(physics_of_scene(load_scene(name, keys), 1)).model
    h, X = 0.1, np.array([3.0, -1.0, 20.0])
    v = vi.vi_coefficients(model, h, 0.5, 0.5)

    def F(x):
        return np.array(vi.residual_jacobian(model, v, *x, 0.0, 0.0, 0.0)[:3])

    J = vi.newton_jacobian(model, h, 0.5, 0.5, *X)
    eps = 1e-5
    fd = np.column_stack([(F(X + eps * e) - F(X - eps * e)) / (2 * eps) for e in np.eye(3)])
    assert np.max(np.abs(J - fd)) <= 1e-7 * np.max(np.abs(J))
