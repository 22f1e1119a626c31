"""The studies take their physics from the model: the Kelvin–Noether
residuals from the sum of the terms' torques and discrete frictions, energies
and powers summed over the terms, keys found by their role, guards from the
laws the terms keep."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import random_body
from liethermo.top.kernels import terms
from liethermo.top.physics import mechanical_energy_scale, potential_energy
from liethermo.top.simulate import simulate
from liethermo.studies.common import StudyError
from liethermo.studies.runner import load_study, validate_study
from liethermo.top.laws import continuous_kelvin_noether_residual, kelvin_noether_residual

STUDIES = Path(__file__).resolve().parents[1] / "studies"


def _stokes_only_continuous(traj) -> float:
    """The continuous defect with the Stokes torque −CΩ alone (what a study that
    re-derives the physics would write)."""
    phys, om, G = traj.physics, traj.omega, traj.gamma
    mu = phys.inertia[:, None, :] * om
    J = np.sum(G * mu, axis=-1)
    f = np.sum(G * phys.linear_resistance()[:, None, :] * om, axis=-1)
    res = J[:, 1:] - J[:, :-1] + 0.5 * traj.h * (f[:, 1:] + f[:, :-1])
    return float(np.max(np.abs(res)) / np.max(np.linalg.norm(mu, axis=-1)))


@pytest.mark.parametrize("extra", [{"quadratic_drag": 2e-4}, {"internal_friction": 0.7}])
def test_kelvin_noether_residuals_hold_under_every_friction(extra):
    """RK4 at h = 0.005: the continuous defect is its O(h³) quadrature error
    (< 2e-7 of |μ|) where the Stokes-only law is off by > 1e-6; the VI keeps
    the discrete law to round-off (< 1e-14) with its nonlinear frictions."""
    phys, om, R = random_body(7, diagonal=True)
    phys = replace(phys, **{k: np.array([v]) for k, v in extra.items()})
    tr = simulate(phys, 3 * om, R, 0.005, 200, "rk4")
    assert continuous_kelvin_noether_residual(tr)[0] < 2e-7
    assert _stokes_only_continuous(tr) > 1e-6
    tr = simulate(phys, 3 * om, R, 0.01, 100, "vi")
    assert kelvin_noether_residual(tr)[0] < 1e-14


def test_model_energies_and_powers_sum_the_terms():
    phys, om, R = random_body(3)
    G = R[:, 2, :]
    free = replace(phys, gravity_torque=np.zeros((1, 3)), quadratic_drag=np.array([1e-4]),
                   internal_friction=np.array([0.5]))
    # without a potential every torque is a friction: P = −⟨f, Ω⟩
    np.testing.assert_allclose(free.dissipated_power(om), -np.sum(free.torque(om, G) * om, axis=-1), rtol=1e-13)
    rest = phys.resting_gamma()
    np.testing.assert_allclose(phys.mechanical_energy(np.zeros(1), potential_energy(phys, rest)), 0.0,
                               atol=1e-15 * phys.potential_span()[0])
    K0 = 0.5 * np.sum(phys.inertia * om * om, axis=-1)
    assert np.array_equal(phys.mechanical_energy(K0, potential_energy(phys, G)),
                          mechanical_energy_scale(phys, om, G))
    C = np.array([[1e-3, 2e-3, 3e-3]])
    assert np.array_equal(phys.with_linear_resistance(C).linear_resistance(), C)


def test_roles_name_one_key_each():
    keys = [terms.key_of(r) for r in terms.ROLES]
    assert len(set(keys)) == len(keys)
    with pytest.raises(ValueError, match="unknown role 'x'"):
        terms.key_of("x")


def test_flat_spin_refuses_every_term_that_breaks_the_momentum_norm(tmp_path):
    src = (STUDIES / "flat_spin.toml").read_text()
    p = tmp_path / "bad.toml"
    p.write_text(src.replace("[options]", "[scene.fluid]\nquadratic_drag = 1e-4\n\n[options]"))
    with pytest.raises(StudyError, match="quadratic_drag break it"):
        validate_study(load_study(p))
