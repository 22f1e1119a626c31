"""The variational integrator in node form, and its compositions.

The paper's scheme (Cayley map on SO(3), discrete Lagrange–d'Alembert
principle, trapezoid friction) is a one-step map on node states
(Γ_k, μ_k, S_k), μ_k the body angular momentum at t_k, through the discrete
Legendre transforms

    M_{±h}(X) = 𝕀X ± (h/2) X×𝕀X + (h²/4)(X·𝕀X) X.

One step of size h from the node k, with the step velocity X = Ω_k
(≈ Ω(t_k + h/2)), a linear friction C (weights w_L + w_R = 1: trapezoid
½, ½; endpoint 1, 0), nonlinear frictions D(X) and conservative torques τ(Γ):

    solve   M_h(X) + w_L h (CX + D(X)) = μ_k + (h/2) τ(Γ_k)          (Newton)
            Γ_{k+1} = cay(−hX̂) Γ_k,   R_{k+1} = R_k cay(hX̂)
            μ_{k+1} = M_{−h}(X) − w_R h (CX + D(X)) + (h/2) τ(Γ_{k+1})
                    = cay(−hX̂)(r − w_L h (CX + D(X))) − w_R h (CX + D(X)) + (h/2) τ(Γ_{k+1})
            S_{k+1}: explicit  S + hP/T(S_k), or symmetric U(S_{k+1}) − U(S_k) = hP

with P = −⟨CX + D(X), X⟩ the power of the discrete friction and r the
Newton right-hand side.  Eliminating μ gives the paper's momentum equation
exactly.  The two forms of μ_{k+1} agree at the Newton solution because
M_{−h}(X) = cay(−hX̂) M_h(X) for every X ((Id − â)M_h = (1 + |a|²)𝕀X =
(Id + â)M_{−h}, a = hX/2); the kernels use the second, a rotation of r by
the matrix that turns Γ, so Kelvin–Noether, and |μ| of a body without
torques and friction, hold whatever X is, not only at the last digits of the
Newton solve (|μ| under the double bracket holds at the solution only).  The kernels hold the state
(X, Γ, σ, μ[, σ_{k+1}][, R]) in which X is the step velocity of the step that
*starts* at the node — it is solved at the end of the previous step — so that
a node's output carries the paper's Ω_k beside the node values, and the
Newton solve of a step uses the torque of the node it starts from:

    advance (vi_advance):  Γ', σ', R', μ' from (X, Γ, σ, μ) with size h;
                           the Newton right-hand side for the next step
                           (size h'): r = μ' + (h'/2) τ(Γ');
    solve (Newton):        X' with M_{h'}(X') + w_L h' C X' (+ …) = r.

The map is symmetric (Φ_{−h} ∘ Φ_h = id for trapezoid friction and the
symmetric entropy update), so symmetric compositions raise its order:
:data:`liethermo.top.methods.COMPOSITION_FACTORS` holds the substep factors, by
default ("small_error") Suzuki's five (order 4) and Kahan and Li's nine
(order 6), and Yoshida's triple jump (order 4) and its triple jump again
(order 6) as "triple_jump"; the kernels take them as data.

Newton: F(X) = M_h(X) + w_L h CX − r (+ w_L h D(X)), with the analytic
Jacobian

    J(X) = diag(I + w_L h C) + (h/2)(X̂𝕀 − (𝕀X)^) + (h²/4)(2 X (𝕀X)ᵀ + (X·𝕀X) Id),

solved in closed form (Cramer), started from an explicit Euler predictor
X + ½(h + h') Ω̇(X, Γ', σ') of the continuous equations, stopped when the
correction d, or the next one as quadratic convergence predicts it
(|d|³/|d_prev|²), is below ``tol · max(|X'|∞, |X|∞)``.  A step whose iteration does not
converge within ``maxiter`` iterations, or meets a singular or non-finite
Jacobian, fails and is never accepted.  With D₁ = ½(I₃ − I₂) (and
cyclically), component 1 of F reads

    F₁ = I₁X₁ + K₁X₁ + hD₁X₂X₃ + (h²/4)(X·𝕀X)X₁ − r₁,   K₁ = w_L h C₁,

and the lane functions below evaluate it with explicit fused multiply-adds,
shared by the straightforward and the vectorized kernels.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from ._jit import fma, jit, lane, select
from .equations import entropy_and_omega_rates, omega_rate
from .dispatch import capability, generic, is_present
from .gen import axpy_opt, finite, or_zero
from .lanemath import expm1_sel
from .layout import NEWTON_MAXITER, NEWTON_OK, NEWTON_SINGULAR
from .so3 import attitude_lane, cayley_lane, cross_lane
from .terms import (NONE3, NONE9, inertia_scale, inertia_scale_rate, scale_square_change, sum_discrete_power,
                    sum_linear_friction, sum_nonlinear_friction, sum_torque, temperature_correction)
from .terms.thermo import entropy_step, temperature

#: key: the inertia part makes the inertia depend on the entropy (the coupled top)
_COUPLED = capability("entropy_dependent_inertia")

#: friction weights (w_L, w_R): on the Newton side and on the update side
FRICTION_WEIGHTS = {"trapezoid": (0.5, 0.5), "endpoint": (1.0, 0.0)}


@generic(_COUPLED)
def _folded_friction(inertia, forces):
    """The linear friction C folded into M and K (None for the coupled top,
    whose inertia scales with S: see newton_step_coupled)."""
    return sum_linear_friction(forces, NONE3)


@_folded_friction.register(True)
def _folded_friction_coupled(inertia, forces):
    return None, None, None


@generic(is_present, arg=1)
def scale_opt(a, x):
    """``a·x``; None when ``x`` is None."""
    return None


@scale_opt.register(True)
def scale_opt_present(a, x):
    return a * x


class VICoefficients(namedtuple("VICoefficients",
                                "M1 M2 M3 K1 K2 K3 R1 R2 R3 hD1 hD2 hD3 h4 h2 hh wlh wrh h")):
    """Per-step-size coefficients: M = I + w_L h C (the Jacobian's diagonal),
    the linear friction of the Newton side K = w_L h C and of the update side
    R = −w_R h C (None without a folded linear friction), hD, h²/4, h²/2, h/2,
    w_L h, w_R h and h.

    The residual and the momentum update take 𝕀X and KX (RX) as separate
    terms, not MX with M = I + w_L h C rounded once: the friction of one step
    is about 10⁻⁵ 𝕀 at h = 10⁻⁴ s, and folded into 𝕀 it would keep only
    ~10⁻¹¹ of its own precision, a fixed error of the friction coefficient
    that grows as 1/h (an error floor of 10⁻¹¹ at t = 10 s; docs/model.md)."""

    __slots__ = ()


@lane
def vi_coefficients(model, h, wl, wr):
    """The :class:`VICoefficients` of a step of size h (s).  For the coupled
    top the linear friction is not folded into M and L (its inertia scales
    with S; see newton_step_coupled)."""
    I = model.inertia
    c0, c1, c2 = _folded_friction(model.inertia, model.forces)
    cl = wl * h
    cr = -(wr * h)
    return VICoefficients(axpy_opt(cl, c0, I.I1), axpy_opt(cl, c1, I.I2), axpy_opt(cl, c2, I.I3),
                          scale_opt(cl, c0), scale_opt(cl, c1), scale_opt(cl, c2),
                          scale_opt(cr, c0), scale_opt(cr, c1), scale_opt(cr, c2),
                          h * I.D1, h * I.D2, h * I.D3, 0.25 * (h * h), 0.5 * (h * h), 0.5 * h,
                          cl, wr * h, h)


@lane
def residual_jacobian(model, v, x0, x1, x2, b0, b1, b2):
    """F(X) = M_h(X) + w_L h (CX + D(X)) + b (b = −r) and the rows of J(X):
    (F₀, F₁, F₂, J00, J01, J02, J10, …, J22)."""
    I = model.inertia
    Q0 = I.I1 * x0
    Q1 = I.I2 * x1
    Q2 = I.I3 * x2
    h4xQ = v.h4 * fma(Q0, x0, fma(Q1, x1, Q2 * x2))
    F0 = fma(I.I1, x0, axpy_opt(x0, v.K1, fma(v.hD1 * x1, x2, fma(h4xQ, x0, b0))))
    F1 = fma(I.I2, x1, axpy_opt(x1, v.K2, fma(v.hD2 * x2, x0, fma(h4xQ, x1, b1))))
    F2 = fma(I.I3, x2, axpy_opt(x2, v.K3, fma(v.hD3 * x0, x1, fma(h4xQ, x2, b2))))
    hx0 = v.h2 * x0
    hx1 = v.h2 * x1
    hx2 = v.h2 * x2
    J00 = fma(Q0, hx0, v.M1 + h4xQ)
    J01 = fma(Q1, hx0, v.hD1 * x2)
    J02 = fma(Q2, hx0, v.hD1 * x1)
    J10 = fma(Q0, hx1, v.hD2 * x2)
    J11 = fma(Q1, hx1, v.M2 + h4xQ)
    J12 = fma(Q2, hx1, v.hD2 * x0)
    J20 = fma(Q0, hx2, v.hD3 * x1)
    J21 = fma(Q1, hx2, v.hD3 * x0)
    J22 = fma(Q2, hx2, v.M3 + h4xQ)
    (f0, f1, f2), (j00, j01, j02, j10, j11, j12, j20, j21, j22) = sum_nonlinear_friction(
        model.forces, I, v.h, (x0, x1, x2), NONE3, NONE9)
    w = v.wlh
    return (axpy_opt(w, f0, F0), axpy_opt(w, f1, F1), axpy_opt(w, f2, F2),
            axpy_opt(w, j00, J00), axpy_opt(w, j01, J01), axpy_opt(w, j02, J02),
            axpy_opt(w, j10, J10), axpy_opt(w, j11, J11), axpy_opt(w, j12, J12),
            axpy_opt(w, j20, J20), axpy_opt(w, j21, J21), axpy_opt(w, j22, J22))


@jit
def newton_jacobian(model, h, wl, wr, x0, x1, x2):
    """J(X) (3×3) of the Newton function of a step of size h, with every term
    of ``model`` (the nonlinear frictions' D′(X) included): the matrix whose
    conditioning the stability study maps.  For the coupled top it is the
    block in X at the step's own inertia (its linear friction is added in the
    Newton step, not here)."""
    v = vi_coefficients(model, h, wl, wr)
    r = residual_jacobian(model, v, x0, x1, x2, 0.0, 0.0, 0.0)
    J = np.empty((3, 3))
    J[0, 0], J[0, 1], J[0, 2] = r[3], r[4], r[5]
    J[1, 0], J[1, 1], J[1, 2] = r[6], r[7], r[8]
    J[2, 0], J[2, 1], J[2, 2] = r[9], r[10], r[11]
    return J


@lane
def solve3_lane(J00, J01, J02, J10, J11, J12, J20, J21, J22, r0, r1, r2):
    """(J⁻¹r, det J) by Cramer's rule: the rows of J⁻¹ are the cross products
    of J's columns divided by det.  Meaningless when det is 0 or not finite."""
    bc0, bc1, bc2 = cross_lane(J01, J11, J21, J02, J12, J22)
    det = fma(J00, bc0, fma(J10, bc1, J20 * bc2))
    ca0, ca1, ca2 = cross_lane(J02, J12, J22, J00, J10, J20)
    ab0, ab1, ab2 = cross_lane(J00, J10, J20, J01, J11, J21)
    inv = 1.0 / det
    d0 = fma(bc0, r0, fma(bc1, r1, bc2 * r2)) * inv
    d1 = fma(ca0, r0, fma(ca1, r1, ca2 * r2)) * inv
    d2 = fma(ab0, r0, fma(ab1, r1, ab2 * r2)) * inv
    return d0, d1, d2, det


@generic(_COUPLED)
def newton_data(inertia, model, s1):
    """What the Newton corrections of one solve share and need not recompute:
    T(σ') for the coupled top (σ' = s1), None otherwise."""
    return None


@newton_data.register(True)
def newton_data_coupled(inertia, model, s1):
    return temperature(model.thermo, s1)


@generic(is_present, arg=5)
def newton_step(model, v, x0, x1, x2, xs, b0, b1, b2, tn, exact):
    """One Newton correction d = J⁻¹F: (d₀, d₁, d₂, d_s, det J, ok).  For a
    constant inertia the unknown is X alone (``xs`` and d_s are None; ok is
    True); for the coupled top it is (X, Δ) with σ_{k+1} = σ' + Δ (see
    newton_step_coupled), ``tn`` = :func:`newton_data`, and with ``exact`` False
    the correction uses the small-argument expm1 and ok says whether that
    was valid (else the lane redoes it with ``exact``, as the entropy)."""
    F0, F1, F2, J00, J01, J02, J10, J11, J12, J20, J21, J22 = residual_jacobian(
        model, v, x0, x1, x2, b0, b1, b2)
    d0, d1, d2, det = solve3_lane(J00, J01, J02, J10, J11, J12, J20, J21, J22, F0, F1, F2)
    return d0, d1, d2, None, det, True


@newton_step.register(True)
def newton_step_coupled(model, v, x0, x1, x2, xs, b0, b1, b2, tn, exact):
    """Newton correction of the coupled top, unknowns (X, Δ), σ_{k+1} = σ' + Δ:

        F₁ = s*(Δ) M_h⁰(X) + w_L h CX − r,     s* = ½(φ(σ')² + φ(σ'+Δ)²)
        F₂ = U(σ'+Δ) − U(σ') − ½(X·𝕀₀X)(φ(σ'+Δ)² − φ(σ')²) − h X·CX

    (M_h⁰: the discrete Legendre transform of 𝕀₀), solved by block
    elimination of the 3×3 Jacobian of F₁ in X (det is that of the 4×4).
    θ(σ') = ``tn``; θ(σ'+Δ) = θ(σ')(1 + expm1(Δ/c_v)); φ, φ′ and the change
    of φ² are the inertia part's (:func:`.terms.inertia_scale` …)."""
    th = model.thermo
    I = model.inertia
    thp = tn
    e, ok = expm1_sel(xs * th.icv, exact)
    thn = fma(thp, e, thp)
    phip = inertia_scale(I, th, thp)
    phin = inertia_scale(I, th, thn)
    dphin = inertia_scale_rate(I, th, thn)
    dphi2 = scale_square_change(I, th, thp, e)  # φ(σ'+Δ)² − φ(σ')²
    ss = 0.5 * fma(phip, phip, phin * phin)
    a0, a1, a2, A00, A01, A02, A10, A11, A12, A20, A21, A22 = residual_jacobian(
        model, v, x0, x1, x2, 0.0, 0.0, 0.0)
    c0, c1, c2 = sum_linear_friction(model.forces, NONE3)
    c0, c1, c2 = or_zero(c0), or_zero(c1), or_zero(c2)
    wl = v.wlh
    F0 = fma(ss, a0, fma(wl * c0, x0, b0))
    F1 = fma(ss, a1, fma(wl * c1, x1, b1))
    F2 = fma(ss, a2, fma(wl * c2, x2, b2))
    J00, J01, J02 = fma(ss, A00, wl * c0), ss * A01, ss * A02
    J10, J11, J12 = ss * A10, fma(ss, A11, wl * c1), ss * A12
    J20, J21, J22 = ss * A20, ss * A21, fma(ss, A22, wl * c2)
    k = phin * dphin
    q0, q1, q2 = I.I1 * x0, I.I2 * x1, I.I3 * x2
    K2 = fma(q0, x0, fma(q1, x1, q2 * x2))
    P = fma(c0 * x0, x0, fma(c1 * x1, x1, (c2 * x2) * x2))
    Fs = fma(th.cv * thp, e, -fma(0.5 * K2, dphi2, v.h * P))
    h2 = 2.0 * v.h
    r0, r1, r2 = -fma(dphi2, q0, h2 * c0 * x0), -fma(dphi2, q1, h2 * c1 * x1), \
        -fma(dphi2, q2, h2 * c2 * x2)
    jss = thn - K2 * k
    u0, u1, u2, det = solve3_lane(J00, J01, J02, J10, J11, J12, J20, J21, J22, F0, F1, F2)
    w0, w1, w2, _ = solve3_lane(J00, J01, J02, J10, J11, J12, J20, J21, J22, k * a0, k * a1,
                                k * a2)
    den = jss - fma(r0, w0, fma(r1, w1, r2 * w2))
    ds = (Fs - fma(r0, u0, fma(r1, u1, r2 * u2))) / den
    return u0 - w0 * ds, u1 - w1 * ds, u2 - w2 * ds, ds, det * den, ok


#: the predicted next Newton correction must be below this fraction of the tolerance
PREDICTION_MARGIN = 0.1


@lane
def converged(step, scale, prev, tol):
    """Whether an iterate after a correction of size ``step`` (the one before
    was ``prev``; 0 before the first) is within tol·scale of the solution:
    the correction itself is that small, or quadratic convergence predicts
    the next one below a tenth of it, step·(step/prev)² ≤ tol·scale/10 (the
    margin: the prediction's constant is estimated from one ratio; without
    it 1 % of random solves stopped up to 5 tol·scale away, with it none of
    2000 beyond 0.5).  It never fires on a step that did not shrink: it
    would then need step ≤ tol·scale anyway."""
    lim = tol * scale
    return (step <= lim) | ((step * step) * step <= (PREDICTION_MARGIN * lim) * (prev * prev))


@generic(is_present, arg=3)
def newton_stop(x0, x1, x2, xs, d0, d1, d2, ds, scale0, scales, prev, prevs, tol):
    """(step, step_s, converged) for the new iterate (= old − d), with step =
    |d|∞ and step_s = |d_s| (None for a constant inertia): converged when
    :func:`converged` holds for X at the scale max(|X|∞, |X_k|∞) from the
    previous steps ``prev`` (and, for the coupled top, for Δ at the scale
    max(|Δ|, |σ'|) from ``prevs``).  ``step`` is NaN if any correction is.

    Stopping on the prediction saves the iteration that would only verify
    it.  The discrete laws do not rest on the last digits of X: the momentum
    update rotates the Newton right-hand side (:func:`vi_advance`), so the
    Kelvin–Noether law, and |μ| without torques and friction, are kept by
    construction whatever X is; the double bracket's |μ| moves by its
    friction times the Newton error."""
    step = max(abs(d0), abs(d1), abs(d2))
    scale = max(abs(x0), abs(x1), abs(x2), scale0)
    steps = abs(ds)
    ok = converged(step, scale, prev, tol) & converged(steps, max(abs(xs), scales), prevs, tol)
    return step + 0.0 * ds, steps, ok


@newton_stop.register(False)
def newton_stop_x(x0, x1, x2, xs, d0, d1, d2, ds, scale0, scales, prev, prevs, tol):
    step = max(abs(d0), abs(d1), abs(d2))
    scale = max(abs(x0), abs(x1), abs(x2), scale0)
    return step, None, converged(step, scale, prev, tol)


@generic(is_present)
def sub_select(x, c, d):
    """x − (d if c else +0) for an optional unknown (exact: x − (+0) is x); None when x is None."""
    return None


@sub_select.register(True)
def sub_select_present(x, c, d):
    return x - select(c, d, 0.0)


@generic(is_present, arg=1)
def select_opt(c, a, b):
    """a if c else b for an optional unknown (None when a is None)."""
    return None


@select_opt.register(True)
def select_opt_present(c, a, b):
    return select(c, a, b)


@generic(is_present, arg=1)
def add_opt(s, x):
    """σ' + Δ for the coupled top, None otherwise."""
    return None


@add_opt.register(True)
def add_opt_present(s, x):
    return s + x


@generic(is_present)
def attitude_step(R, w0, w1, w2):
    """R cay(ŵ), or None without the attitude."""
    return None


@attitude_step.register(True)
def attitude_step_present(R, w0, w1, w2):
    return attitude_lane(R, w0, w1, w2)


@lane
def vi_entropy(model, v, y, mode, exact):
    """(σ', ok): the entropy at the end of the step of size v.h from the
    ``vi``-layout state y (None without thermodynamics)."""
    X = y[0]
    P = sum_discrete_power(model.forces, model.inertia, v.h, X, None)
    return entropy_step(model.thermo, mode, v.h, P, y[2], exact)


@lane
def vi_advance(model, v, vn, y, hn, mode, exact):
    """Everything of one step of the ``vi`` layout state y = (X, Γ, σ, μ, σₙ, R)
    but the Newton solve of the next step: returns
    ``(Γ', σ', μ', R', b, X₀, Δ₀, |X|∞, scale_s, ok)`` with b = −r the
    constant part of the next step's Newton function, X₀ (and, for the
    coupled top, Δ₀; else None) its predictor, and ``ok`` whether every
    inline exp/log1p was valid (see thermo)."""
    return _advance(model.inertia, model, v, vn, y, hn, mode, exact)


@generic(_COUPLED)
def _advance(inertia, model, v, vn, y, hn, mode, exact):
    """Γ', σ', R', μ' and the next Newton data (see :func:`vi_advance`): a constant inertia."""
    X, G, s, mu, sn, R = y
    x0, x1, x2 = X
    h = v.h
    G0, G1, G2 = cayley_lane(-(h * x0), -(h * x1), -(h * x2), G[0], G[1], G[2])
    I = model.inertia
    s1, ok = vi_entropy(model, v, y, mode, exact)
    R1 = attitude_step(R, h * x0, h * x1, h * x2)
    (f0, f1, f2), (j00, j01, j02, j10, j11, j12, j20, j21, j22) = sum_nonlinear_friction(
        model.forces, I, h, (x0, x1, x2), NONE3, NONE9)
    # μ' = cay(−hX̂)(r − w_L h(CX + D)) − w_R h(CX + D) + (h/2)τ(Γ'), r = μ + (h/2)τ(Γ):
    # M_{−h}(X) = cay(−hX̂) M_h(X) for every X, so this is the paper's update at the
    # Newton solution, and a rotation of r whatever X is (module docstring)
    r0, r1, r2 = node_rhs(model, v, y[3], G)
    q0, q1, q2 = cayley_lane(-(h * x0), -(h * x1), -(h * x2),
                             axpy_opt(-v.wlh, f0, axpy_opt(-x0, v.K1, r0)),
                             axpy_opt(-v.wlh, f1, axpy_opt(-x1, v.K2, r1)),
                             axpy_opt(-v.wlh, f2, axpy_opt(-x2, v.K3, r2)))
    t0, t1, t2 = sum_torque(model.forces, (G0, G1, G2), NONE3)
    m0 = axpy_opt(-v.wrh, f0, axpy_opt(x0, v.R1, axpy_opt(v.hh, t0, q0)))
    m1 = axpy_opt(-v.wrh, f1, axpy_opt(x1, v.R2, axpy_opt(v.hh, t1, q1)))
    m2 = axpy_opt(-v.wrh, f2, axpy_opt(x2, v.R3, axpy_opt(v.hh, t2, q2)))
    b0 = -axpy_opt(vn.hh, t0, m0)
    b1 = -axpy_opt(vn.hh, t1, m1)
    b2 = -axpy_opt(vn.hh, t2, m2)
    hp = 0.5 * (h + vn.h)
    d0, d1, d2 = omega_rate(model, x0, x1, x2, G0, G1, G2, s1, exact)
    p0 = fma(hp, d0, x0)
    p1 = fma(hp, d1, x1)
    p2 = fma(hp, d2, x2)
    return ((G0, G1, G2), s1, (m0, m1, m2), R1, (b0, b1, b2), (p0, p1, p2), None,
            max(abs(x0), abs(x1), abs(x2)), None, ok)


@_advance.register(True)
def _advance_coupled(inertia, model, v, vn, y, hn, mode, exact):
    """The coupled top: σ' is the σ_{k+1} solved with X; μ' =
    s* M⁰_{−h}(X) − w_R h CX + (h/2)τ(Γ') with the mean inertia of the step,
    s* 𝕀₀, s* = ½(φ(σ)² + φ(σ')²), which is cay(−hX̂)(r − w_L h CX) by the
    Newton equation."""
    X, G, s, mu, sn, R = y
    x0, x1, x2 = X
    h = v.h
    G0, G1, G2 = cayley_lane(-(h * x0), -(h * x1), -(h * x2), G[0], G[1], G[2])
    R1 = attitude_step(R, h * x0, h * x1, h * x2)
    s1 = sn
    t0, t1, t2 = sum_torque(model.forces, (G0, G1, G2), NONE3)
    c0, c1, c2 = sum_linear_friction(model.forces, NONE3)
    c0, c1, c2 = or_zero(c0), or_zero(c1), or_zero(c2)
    # s* M⁰_{−h}(X) = cay(−hX̂)(r − w_L h CX), as for the constant inertia
    r0, r1, r2 = node_rhs(model, v, y[3], G)
    wl = v.wlh
    q0, q1, q2 = cayley_lane(-(h * x0), -(h * x1), -(h * x2), fma(-(wl * c0), x0, r0),
                             fma(-(wl * c1), x1, r1), fma(-(wl * c2), x2, r2))
    m0 = axpy_opt(v.hh, t0, fma(-v.wrh * c0, x0, q0))
    m1 = axpy_opt(v.hh, t1, fma(-v.wrh * c1, x1, q1))
    m2 = axpy_opt(v.hh, t2, fma(-v.wrh * c2, x2, q2))
    b0 = -axpy_opt(vn.hh, t0, m0)
    b1 = -axpy_opt(vn.hh, t1, m1)
    b2 = -axpy_opt(vn.hh, t2, m2)
    hp = 0.5 * (h + vn.h)
    # predictors: Ω̇ and Ṡ of the continuous equations at (X, Γ', σ')
    (d0, d1, d2), sd, _ = entropy_and_omega_rates(model, x0, x1, x2, G0, G1, G2, s1, exact)
    return ((G0, G1, G2), s1, (m0, m1, m2), R1, (b0, b1, b2),
            (fma(hp, d0, x0), fma(hp, d1, x1), fma(hp, d2, x2)), vn.h * sd,
            max(abs(x0), abs(x1), abs(x2)), abs(s1), True)


@generic(is_present)
def zero_like(x):
    """0.0, or None when x is None."""
    return None


@zero_like.register(True)
def zero_like_present(x):
    return 0.0


@lane
def newton_solve(model, vn, b, xp, xs, s1, scale0, scales, tol, maxiter):
    """Newton iterations 1 … maxiter from the predictor (X₀, Δ₀) as the block
    kernel runs them: returns (X, Δ, code, iterations); Δ is None for a
    constant inertia.  On a singular or non-finite Jacobian the iterate is
    the last one before it."""
    return newton_iterate(model, vn, b, xp, xs, newton_data(model.inertia, model, s1), scale0,
                          scales, tol, 0, maxiter, (0.0, zero_like(xs)))


@lane
def newton_iterate(model, vn, b, xp, xs, tn, scale0, scales, tol, its, maxiter, dprev):
    """Newton iterations its+1 … maxiter from the iterate (X, Δ) = (xp, xs)
    with the exact operations (``tn`` = :func:`newton_data`; ``dprev`` the
    sizes of the last corrections of X and Δ, :func:`newton_stop`): the rest
    of a solve (the block kernel finishes here a lane whose vectorized
    iteration was out of the small-argument range)."""
    x0, x1, x2 = xp
    b0, b1, b2 = b
    prev, prevs = dprev
    code = NEWTON_MAXITER
    run = maxiter >= 1
    while run and its < maxiter:
        its += 1
        d0, d1, d2, ds, det, ok = newton_step(model, vn, x0, x1, x2, xs, b0, b1, b2, tn, True)
        if det == 0.0 or not finite(det):
            code = NEWTON_SINGULAR
            break
        x0 -= d0
        x1 -= d1
        x2 -= d2
        xs = sub_select(xs, True, ds)
        step, steps, conv = newton_stop(x0, x1, x2, xs, d0, d1, d2, ds, scale0, scales, prev,
                                        prevs, tol)
        prev, prevs = step, steps
        if not (step == step):
            code = NEWTON_SINGULAR
            break
        if conv:
            code = NEWTON_OK
            break
    return (x0, x1, x2), xs, code, its


@lane
def momentum_map(model, v, x0, x1, x2, G0, G1, G2):
    """The node momentum μ_k of the step velocity X = Ω_k and the node Γ_k:
    μ_k = M_h(X) + w_L h (CX + D(X)) − (h/2) τ(Γ_k) (the Newton equation read
    backwards); the paper's start Ω₀ := Ω(0) is μ₀ of X = Ω(0).  (Constant
    inertia only: the coupled top starts from μ₀ = 𝕀Ω(0).)"""
    t0, t1, t2 = sum_torque(model.forces, (G0, G1, G2), NONE3)
    F0, F1, F2, j00, j01, j02, j10, j11, j12, j20, j21, j22 = residual_jacobian(
        model, v, x0, x1, x2, 0.0, 0.0, 0.0)
    return (axpy_opt(-v.hh, t0, F0), axpy_opt(-v.hh, t1, F1), axpy_opt(-v.hh, t2, F2))


@lane
def node_rhs(model, v, mu, G):
    """r = μ + (h/2) τ(Γ): the right-hand side of the Newton equation of a
    step of size v.h that starts from the node (Γ, μ)."""
    t0, t1, t2 = sum_torque(model.forces, G, NONE3)
    return axpy_opt(v.hh, t0, mu[0]), axpy_opt(v.hh, t1, mu[1]), axpy_opt(v.hh, t2, mu[2])


@generic(_COUPLED)
def entropy_predictor(inertia, model, v, X, s):
    """Δ₀ of the coupled top's first solve (None for a constant inertia)."""
    return None


@entropy_predictor.register(True)
def entropy_predictor_coupled(inertia, model, v, X, s):
    th = model.thermo
    I = inertia
    c0, c1, c2 = sum_linear_friction(model.forces, NONE3)
    x0, x1, x2 = X
    P = fma(or_zero(c0) * x0, x0, fma(or_zero(c1) * x1, x1, (or_zero(c2) * x2) * x2))
    th0 = temperature(th, s)
    K2 = fma(I.I1 * x0, x0, fma(I.I2 * x1, x1, (I.I3 * x2) * x2))
    return v.h * P / (th0 - temperature_correction(I, th, th0, K2))

