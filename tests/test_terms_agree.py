"""Every term's numpy physics (its torque and dissipated power, which the laws,
the studies, the energy diagnostics and the plots use) agrees with its kernel
(the continuous equations the integrators and the reference step), in one
generic test over the registry: a term added without both in agreement, or
without a scene here that switches it on, fails it."""

import numpy as np
import pytest

from liethermo.scene import load_scene
from liethermo.top.kernels.terms import registry
from liethermo.top.laws import continuous_rhs
from liethermo.top.physics import inertia_scale, physics_of_scene, temperature

#: scenes that switch every term on, alone or together
SCENES = [("paper", {}), ("free_ellipsoid", {}), ("ellipsoid", {}), ("coupled_egg", {}),
          ("paper", {"fluid.quadratic_drag": 2e-4}), ("paper", {"body.internal_friction": 1.0}),
          ("free_ellipsoid", {"fluid.quadratic_drag": 1e-3, "body.internal_friction": 0.5})]


def _numpy_rates(phys, m, w, G, sigma):
    """(Ω̇, σ̇) from the terms' numpy forms: d/dt(s(σ) 𝕀₀Ω) = s 𝕀₀Ω × Ω + τ, σ̇ = P/T."""
    p = phys.take(slice(m, m + 1))
    I0 = p.inertia[0]
    sig = np.array([sigma])
    tau = p.torque(w[None], G[None], sig)[0]
    P = float(p.dissipated_power(w[None], sig)[0])
    sdot = P / float(temperature(p, w[None], sig)[0]) if P else 0.0
    def scale(x):  # s(σ): a number for a constant inertia, an array otherwise
        return float(np.broadcast_to(inertia_scale(p, x), (1,))[0])

    s, d = scale(sig), 1e-6 * max(1.0, abs(sigma))
    ds = (scale(sig + d) - scale(sig - d)) / (2 * d)
    mu = s * I0 * w
    wdot = (np.cross(mu, w) + tau - ds * sdot * I0 * w) / (s * I0)
    return wdot, sdot


@pytest.mark.parametrize("scene, overrides", SCENES)
def test_each_terms_numpy_physics_is_its_kernels(scene, overrides):
    sc = load_scene(scene, {**overrides, "ensemble.members": 3})
    phys = physics_of_scene(sc, 3)
    rng = np.random.default_rng(7)
    coupled = bool(phys.acting()["thermal_expansion"].any())
    for m in range(phys.n):
        f = continuous_rhs(phys, m)
        for _ in range(5):
            w = rng.normal(size=3) * 2.0
            G = rng.normal(size=3)
            G /= np.linalg.norm(G)
            sigma = abs(rng.normal()) * 1e-3
            out = f(0.0, np.concatenate([w, G, [sigma]]))
            wdot, sdot = _numpy_rates(phys, m, w, G, sigma)
            tol = 1e-7 if coupled else 1e-12  # the coupled inertia's s'(σ) by a central difference
            np.testing.assert_allclose(out[:3], wdot, rtol=tol, atol=tol * np.abs(wdot).max())
            np.testing.assert_allclose(out[3:6], np.cross(G, w), rtol=1e-15, atol=1e-15)
            np.testing.assert_allclose(out[6], sdot, rtol=tol, atol=1e-300)


def test_every_term_is_switched_on_by_a_scene_here():
    on = set()
    for scene, overrides in SCENES:
        phys = physics_of_scene(load_scene(scene, overrides), 1)
        on |= {name for name, acts in phys.acting().items() if acts.any()}
    assert on == {t.name for t in registry()}
