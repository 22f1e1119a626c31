"""Observed orders of convergence on node values, against exact solutions and
the high-accuracy reference.

Orders are fitted by least squares of log(error) against log(h) over levels
above the round-off floor (see conftest.fit_order), errors being the max
over the common times t = j·h0 of node values Ω(t_k), Γ_k, S_k and E_k.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import OMEGA0, R0, fit_order, paper_physics
from liethermo.top.methods import MethodChoice
from liethermo.top.dataset import initial_energy, node_energies
from liethermo.top.methods import METHODS
from liethermo.top.simulate import STATUS_OK, simulate


#: the method variants a MethodChoice carries
_VARIANTS = ("friction", "start", "entropy", "composition")


def test_reference_on_spherical_top_exact_solution(spherical_top):
    """The DOP853 reference reproduces the exact spherical-top solution
    (Ω, Γ, σ) to ≤ 1e-13 over 20 s."""
    st = spherical_top
    tr = simulate(st.physics, st.omega0[None], st.R0[None], 0.1, 200, "reference")
    t = tr.times
    assert np.abs(tr.omega[0] - st.omega(t)).max() <= 1e-13
    assert np.abs(tr.gamma[0] - st.gamma(t)).max() <= 1e-13
    assert np.abs(tr.sigma[0] - st.sigma(t)).max() <= 1e-13 * st.sigma(t[-1])


def test_reference_on_lagrange_top(paper):
    """With I₁ = I₂ and χ = e₃ (the paper's top), Ω₃(t) = Ω₃(0)e^{−ct/I₃} exactly;
    the reference holds it to 1e-14 over 30 s, and conserves E to 1e-12 of
    the mechanical energy."""
    phys, om0, R = paper
    tr = simulate(phys, om0, R, 0.1, 300, "reference")
    c, I3 = phys.stokes_resistance[0, 2], phys.inertia[0, 2]
    np.testing.assert_allclose(tr.omega[0, :, 2], om0[0, 2] * np.exp(-c * tr.times / I3), rtol=0, atol=1e-14)
    e = node_energies(tr)
    K0, V0 = initial_energy(phys, om0, R)
    dE = e["K"] - K0[:, None] + e["V"] - V0[:, None] + e["dU"]
    assert np.abs(dE).max() <= 1e-12 * (K0[0] + V0[0] + np.linalg.norm(phys.gravity_torque[0]))


def _node_errors(phys, om0, R, method, h, t_end, ref, h_ref, **kw):
    """Max over t = j·h0 of node-value errors in (Ω, Γ, S, E) against ``ref``."""
    steps = int(round(t_end / h))
    choice = MethodChoice.of(method, **{k: kw.pop(k) for k in _VARIANTS if k in kw})
    tr = simulate(phys, om0, R, h, steps, choice, **kw)
    assert tr.status[0] == STATUS_OK
    stride = int(round(h / h_ref))
    e = node_energies(tr)
    K0, V0 = initial_energy(phys, om0, R)
    dE = e["K"][0] - K0[0] + e["V"][0] - V0[0] + e["dU"][0]
    err = []
    for a, b in ((tr.omega[0], ref["omega"]), (tr.gamma[0], ref["gamma"])):
        err.append(np.linalg.norm(a - b[::stride][: len(a)], axis=-1).max())
    err.append(np.abs(tr.sigma[0] - ref["sigma"][::stride][: len(tr.sigma[0])]).max())
    err.append(np.abs(dE - ref["dE"][::stride][: len(dE)]).max())
    return np.array(err)


def _reference(phys, om0, R, h_ref, t_end):
    tr = simulate(phys, om0, R, h_ref, int(round(t_end / h_ref)), "reference")
    e = node_energies(tr)
    K0, V0 = initial_energy(phys, om0, R)
    return dict(omega=tr.omega[0], gamma=tr.gamma[0], sigma=tr.sigma[0],
                dE=e["K"][0] - K0[0] + e["V"][0] - V0[0] + e["dU"][0])


# (method, keywords, levels h0/2^k, expected order, tolerance)
ORDER_CASES = [
    ("vi", dict(start="legendre"), 0.05, 5, 2, 0.15),
    ("vi", dict(start="staggered"), 0.05, 5, 2, 0.15),
    ("vi", dict(start="node", entropy="explicit"), 0.05, 5, 1, 0.3),
    ("vi", dict(friction="endpoint"), 0.05, 5, 1, 0.35),
    ("vi4", {}, 0.05, 5, 4, 0.3),
    ("vi6", {}, 0.1, 5, 6, 0.7),
    ("vi4", dict(composition="triple_jump"), 0.05, 5, 4, 0.3),
    ("vi6", dict(composition="triple_jump"), 0.025, 5, 6, 0.7),
    ("split", {}, 0.05, 5, 2, 0.15),
    ("split4", {}, 0.05, 5, 4, 0.3),
    ("split6", {}, 0.1, 5, 6, 0.7),
    ("rk2", {}, 0.025, 5, 2, 0.3),
    ("rk4", {}, 0.05, 5, 4, 0.3),
]


@pytest.fixture(scope="module")
def paper_reference():
    phys, om0, R = paper_physics(), OMEGA0[None], R0[None]
    h_ref = 0.2 / 2**8
    return phys, om0, R, h_ref, _reference(phys, om0, R, h_ref, 4.0)


@pytest.mark.parametrize("method,kw,h0,levels,order,tol", ORDER_CASES,
                         ids=[f"{c[0]}-{'-'.join(c[1].values()) or 'default'}" for c in ORDER_CASES])
def test_node_orders_on_the_paper_scene(method, kw, h0, levels, order, tol, paper_reference):
    """Node values of every method converge with the order it declares (the
    plain VI: 2 with the legendre or staggered start, 1 with the paper's
    start or endpoint friction; vi4 and split4: 4; vi6 and split6: 6 within
    ±0.7, with either composition; split: 2), for Ω, Γ, S and E, on the paper
    scene over 4 s."""
    phys, om0, R, h_ref, ref = paper_reference
    m = METHODS[method]
    assert m.order(m.effective_start(kw.get("start", "legendre")),
                   kw.get("friction", "trapezoid")) == order
    hs = [h0 / 2**k for k in range(levels)]
    errs = np.array([_node_errors(phys, om0, R, method, h, 4.0, ref, h_ref, **kw) for h in hs])
    for j, name in enumerate(("Omega", "Gamma", "S", "E")):
        if order == 1 and name == "E":
            continue  # the first-order starts' energy error is the node momentum's, often of higher order
        p = fit_order(hs, errs[:, j], floor=1e-13 * (1.0 if j < 2 else np.abs(ref["sigma"]).max() if j == 2
                                                      else np.abs(ref["dE"]).max() + 1e-300))
        assert abs(p - order) <= tol, (name, p, errs[:, j])


def test_spherical_top_orders_against_the_exact_solution(spherical_top):
    """Against the exact spherical-top solution (no reference involved): vi
    (legendre) order 2, vi4 order 4 on Ω, Γ and S."""
    st = spherical_top
    t_end = 10.0
    for method, order, h0 in (("vi", 2, 0.2), ("vi4", 4, 0.4)):
        hs = [h0 / 2**k for k in range(5)]
        errs = []
        for h in hs:
            tr = simulate(st.physics, st.omega0[None], st.R0[None], h, int(round(t_end / h)), method)
            t = tr.times
            errs.append([np.abs(tr.omega[0] - st.omega(t)).max(), np.abs(tr.gamma[0] - st.gamma(t)).max(),
                         np.abs(tr.sigma[0] - st.sigma(t)).max()])
        errs = np.array(errs)
        for j in range(3):
            p = fit_order(hs, errs[:, j], floor=1e-14 if j < 2 else 1e-14 * st.sigma(t_end))
            assert abs(p - order) <= 0.3, (method, j, p, errs[:, j])


@pytest.mark.slow
@pytest.mark.parametrize("body", ["coupled", "double_bracket"])
def test_vi_family_orders_on_the_other_models(body):
    """The coupled top (𝕀(S)) and double-bracket friction: vi 2, vi4 4, vi6 6
    (±0.7) on node values against the reference."""
    phys = paper_physics()
    om0, R = OMEGA0[None] * 2.0, R0[None]
    if body == "coupled":
        phys = replace(phys, heat_capacity=np.array([1e-3]), thermal_expansion=np.array([1e-3]))
    else:
        phys = replace(phys, internal_friction=np.array([20.0]))
    h_ref = 0.2 / 2**8
    ref = _reference(phys, om0, R, h_ref, 2.0)
    for method, order, h0 in (("vi", 2, 0.05), ("vi4", 4, 0.05), ("vi6", 6, 0.025)):
        hs = [h0 / 2**k for k in range(5)]
        errs = np.array([_node_errors(phys, om0, R, method, h, 2.0, ref, h_ref) for h in hs])
        for j in (0, 1, 2):
            p = fit_order(hs, errs[:, j], floor=1e-13 * (1.0 if j < 2 else np.abs(ref["sigma"]).max()))
            assert abs(p - order) <= (0.7 if order == 6 else 0.3), (body, method, j, p, errs[:, j])


def test_step_velocity_is_a_midstep_velocity(paper_reference):
    """The stored step velocity Ω_k approximates Ω(t_k + h/2), not Ω(t_k): with
    a second-order start its error against Ω(t_k + h/2) is far below its
    distance to Ω(t_k).  (With the paper's start, Ω₀ := Ω(0) is taken for
    Ω(h/2): the whole trajectory lags by about h/2, a first-order error.)"""
    phys, om0, R, h_ref, ref = paper_reference
    h = 0.00625
    tr = simulate(phys, om0, R, h, 80, MethodChoice.of("vi", start="staggered"))
    stride = int(round(h / h_ref))
    half = stride // 2
    X = tr.omega_step[0][:80]  # Ω_k over the first 0.5 s, before phase errors add up
    at_mid = np.linalg.norm(X - ref["omega"][half::stride][:80], axis=-1).max()
    at_node = np.linalg.norm(X - ref["omega"][::stride][:80], axis=-1).max()
    assert at_mid < 0.05 * at_node
