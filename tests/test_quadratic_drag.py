"""The quadratic drag term τ = −c₂|Ω|Ω: its scene key, its discrete form,
the orders of the methods, the entropy it produces and the energy balance."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import OMEGA0, R0, fit_order, paper_physics
from liethermo.top import physics as ph
from liethermo.top.dataset import initial_energy, node_energies
from liethermo.top.kernels import terms
from liethermo.top.kernels.terms.quadratic_drag import QuadraticDrag
from liethermo.scene import SceneError, load_scene
from liethermo.top.simulate import STATUS_OK, simulate

C2 = 3e-4  # kg m²: c₂|Ω|/I ≈ 0.6 s⁻¹ at the paper's spin


def _drag_physics(n=1, viscosity=True):
    phys = paper_physics(n)
    phys = replace(phys, quadratic_drag=np.full(n, C2))
    return phys if viscosity else replace(phys, stokes_resistance=np.zeros((n, 3)))


def test_the_scene_key_reaches_the_physics_and_the_dataset():
    from liethermo.api import run

    sc = load_scene("paper", {"fluid.quadratic_drag": C2, "integrator.steps": 20})
    assert ph.physics_of_scene(sc).quadratic_drag[0] == C2
    ds = run(sc, compare=False, output=None, progress=False)
    assert ds["quadratic_drag"].attrs["units"] == "kg m2"
    assert ds["quadratic_drag"].dims == () and float(ds["quadratic_drag"]) == C2  # every member's: stored once
    # the paper scene has none, so its files have no such variable
    plain = run(load_scene("paper", {"integrator.steps": 20}), compare=False, output=None, progress=False)
    assert "quadratic_drag" not in plain


@pytest.mark.parametrize("overrides, key", [
    ({"fluid.quadratic_drag": -1.0}, "fluid.quadratic_drag"),
    ({"fluid.quadratic_drag": "lots"}, "fluid.quadratic_drag"),
    ({"fluid.quadratic_drag": 1e-4, "body.thermal_expansion": 1e-3}, "fluid.quadratic_drag"),
])
def test_bad_scenes_are_refused_naming_the_key(overrides, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        load_scene("paper", overrides)


def test_discrete_jacobian_matches_finite_differences():
    """∂D/∂X of the variational integrator's discrete drag, D(X) = c₂|X|X,
    against central differences; D and its power ⟨D, X⟩ = c₂|X|³."""
    import numba

    jit = numba.njit(error_model="numpy")
    term = QuadraticDrag(C2, 0.0, 0.0, 0.0)
    nl = jit(terms.nonlinear_friction.dispatch(term))  # the drag's own implementations
    pw = jit(terms.discrete_power.dispatch(term))
    assert nl is not None and terms.nonlinear_friction.dispatch(None) is not terms.nonlinear_friction.dispatch(term)
    rng = np.random.default_rng(3)
    for X in rng.standard_normal((5, 3)):
        f, Jt = nl(term, None, 0.1, tuple(X), (0.0,) * 3, (0.0,) * 9)
        D, J = np.array(f), np.array(Jt).reshape(3, 3)
        np.testing.assert_allclose(D, C2 * np.linalg.norm(X) * X, rtol=1e-15)
        eps = 1e-6
        Jfd = np.empty((3, 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = eps
            Jfd[:, j] = (np.array(nl(term, None, 0.1, tuple(X + e), (0.0,) * 3, (0.0,) * 9)[0])
                         - np.array(nl(term, None, 0.1, tuple(X - e), (0.0,) * 3, (0.0,) * 9)[0])) / (2 * eps)
        np.testing.assert_allclose(J, Jfd, rtol=1e-8, atol=1e-14)
        assert pw(term, None, 0.1, tuple(X), 0.0) == pytest.approx(C2 * np.linalg.norm(X) ** 3, rel=1e-15)
    f0, J0 = nl(term, None, 0.1, (0.0, 0.0, 0.0), (0.0,) * 3, (0.0,) * 9)
    assert np.all(np.array(f0) == 0.0) and np.all(np.array(J0) == 0.0)


def _reference(phys, om0, R, h_ref, t_end):
    tr = simulate(phys, om0, R, h_ref, int(round(t_end / h_ref)), "reference")
    e = node_energies(tr)
    K0, V0 = initial_energy(phys, om0, R)
    return {"omega": tr.omega[0], "gamma": tr.gamma[0], "sigma": tr.sigma[0],
            "dE": e["K"][0] - K0[0] + e["V"][0] - V0[0] + e["dU"][0], "tr": tr}


@pytest.fixture(scope="module")
def drag_reference():
    phys = _drag_physics()
    om0, R = OMEGA0[None] * 2.0, R0[None]
    h_ref = 0.2 / 2**8
    return phys, om0, R, h_ref, _reference(phys, om0, R, h_ref, 2.0)


@pytest.mark.parametrize("method, order, h0", [("vi", 2, 0.05), ("rk2", 2, 0.025), ("vi4", 4, 0.05)])
def test_orders_with_the_quadratic_drag(drag_reference, method, order, h0):
    """vi and rk2 are of order 2 and vi4 of order 4 on Ω, Γ and S against the
    reference with the drag switched on (and the paper's Stokes friction)."""
    phys, om0, R, h_ref, ref = drag_reference
    hs = [h0 / 2**k for k in range(4)]
    errs = []
    for h in hs:
        steps = int(round(2.0 / h))
        tr = simulate(phys, om0, R, h, steps, method)
        assert tr.status[0] == STATUS_OK
        stride = int(round(h / h_ref))
        errs.append([np.linalg.norm(tr.omega[0] - ref["omega"][::stride], axis=-1).max(),
                     np.linalg.norm(tr.gamma[0] - ref["gamma"][::stride], axis=-1).max(),
                     np.abs(tr.sigma[0] - ref["sigma"][::stride]).max()])
    errs = np.array(errs)
    for j in range(3):
        p = fit_order(hs, errs[:, j], floor=1e-13 * (1.0 if j < 2 else np.abs(ref["sigma"]).max()))
        assert abs(p - order) <= 0.3, (method, j, p, errs[:, j])


def test_energy_balance_against_the_reference(drag_reference):
    """The reference keeps E = K + V + U to 1e-9 of the heat it makes, and the
    heat U(S) − U(S₀) is the time integral of the term's own numpy power
    c₂|Ω|³ (plus the Stokes part Ω·CΩ) along the trajectory."""
    phys, om0, R, h_ref, ref = drag_reference
    tr = ref["tr"]
    heat = float(ph.internal_energy_change(phys, tr.sigma)[0, -1])
    assert heat > 0.0
    assert np.abs(ref["dE"]).max() < 1e-9 * heat
    P = ph.dissipated_power(phys, tr.omega, tr.sigma)[0]  # W
    t = tr.times
    w = np.full(t.size, h_ref)  # Simpson on the 2^k+1 nodes
    w[1:-1:2], w[2:-1:2] = 4 * h_ref, 2 * h_ref
    integral = float(np.sum(w * P) / 3.0)
    assert integral == pytest.approx(heat, rel=1e-9)
    drag_only = replace(phys, stokes_resistance=np.zeros((1, 3)))
    assert float(np.sum(w * ph.dissipated_power(drag_only, tr.omega, tr.sigma)[0]) / 3.0) > 0.2 * heat


@pytest.mark.parametrize("kernel", ["simple", "fast"])
def test_entropy_never_decreases_and_the_kernels_agree(kernel):
    """An ensemble of 64 members with the drag only (no Stokes friction):
    the symmetric entropy update makes σ non-decreasing at every step, and
    both ensemble loops give the same states."""
    from liethermo.scene import load_scene as ls
    from liethermo.top.initial import initial_conditions

    sc = ls("free_ellipsoid", {"fluid.quadratic_drag": C2, "ensemble.members": 64})
    phys = ph.physics_of_scene(sc, 64)
    w0, R = initial_conditions(sc)
    tr = simulate(phys, w0, R, 0.05, 200, "vi", kernel=kernel)
    assert np.all(tr.status == STATUS_OK)
    assert np.all(np.diff(tr.sigma, axis=1) >= 0.0)
    assert np.all(tr.sigma[:, -1] > 0.0)
    other = simulate(phys, w0, R, 0.05, 200, "vi", kernel="fast" if kernel == "simple" else "simple")
    np.testing.assert_allclose(tr.states, other.states, rtol=1e-12, atol=1e-15)
