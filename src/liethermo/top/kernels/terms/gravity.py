"""Gravity: the heavy top's torque τ(Γ) = Γ × g⃗, g⃗ = m g ℓχ (N m), with the
potential energy V = g⃗·Γ.

Coefficients of :class:`Gravity`: g⃗ and its components over the reference
principal moments, g_z/I₁, g_y/I₁, g_x/I₂, g_z/I₂, g_y/I₃, g_x/I₃, so that
(𝕀₀⁻¹τ)₁ = (g_z/I₁)Γ₂ − (g_y/I₁)Γ₃ (and cyclically) costs two fused
multiply-adds.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from .._jit import fma
from ..gen import madd
from . import (LAW_LAGRANGE_OMEGA3, ROLE_POTENTIAL, Parameter, Setting, Term, angular_acceleration, bcast, exact_flow,
               dot3, torque)


class Gravity(namedtuple("Gravity", "gx gy gz gz1 gy1 gx2 gz2 gy3 gx3")):
    __slots__ = ()
    CAPABILITIES = frozenset({"exact_flow"})


def coefficients(gravity_torque: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 9) coefficients from g⃗ = m g ℓχ (N, 3) and 𝕀₀ (N, 3)."""
    g = np.asarray(gravity_torque, dtype=np.float64).reshape(-1, 3)
    iI = 1.0 / np.asarray(inertia0, dtype=np.float64).reshape(-1, 3)
    gx, gy, gz = g.T
    return np.stack([gx, gy, gz, gz * iI[:, 0], gy * iI[:, 0], gx * iI[:, 1], gz * iI[:, 1],
                     gy * iI[:, 2], gx * iI[:, 2]], axis=1)


def potential_energy(gravity_torque: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """V = g⃗·Γ (J): g⃗ (N, 3), Γ (N, ..., 3)."""
    g = np.asarray(gravity_torque, dtype=np.float64)
    g = g.reshape(g.shape[:1] + (1,) * (gamma.ndim - 2) + (3,))
    return dot3(g, gamma)


@angular_acceleration.register(Gravity)
def _acceleration(term, inertia, iscale, w, G, a):
    G0, G1, G2 = G
    a0, a1, a2 = a
    return (madd(term.gz1, G1, madd(-term.gy1, G2, a0)),
            madd(term.gx2, G2, madd(-term.gz2, G0, a1)),
            madd(term.gy3, G0, madd(-term.gx3, G1, a2)))


@torque.register(Gravity)
def _torque(term, G, t):
    G0, G1, G2 = G
    t0, t1, t2 = t
    return (madd(G1, term.gz, madd(-G2, term.gy, t0)),
            madd(G2, term.gx, madd(-G0, term.gz, t1)),
            madd(G0, term.gy, madd(-G1, term.gx, t2)))


@exact_flow.register(Gravity)
def _kick(term, inertia, t, G, m, q):
    """The exact flow of the torque alone (Γ fixed): μ ← μ + t Γ×g⃗."""
    G0, G1, G2 = G
    m0, m1, m2 = m
    return ((fma(t, fma(G1, term.gz, -(G2 * term.gy)), m0),
             fma(t, fma(G2, term.gx, -(G0 * term.gz)), m1),
             fma(t, fma(G0, term.gy, -(G1 * term.gx)), m2)), q)


class _Gravity(Term):
    name = "gravity"
    role = ROLE_POTENTIAL
    settings = (Setting("gravity", "g", 9.81, "m s-2", "gravitational acceleration"),)
    parameters = (Parameter("gravity_torque", (3,), "N m", "gravity torque m g l chi",
                            comment="m: mass, g: gravity, l chi: fixed point to centre of mass in the body frame",
                            always=True),)
    scene_doc = (
        "*Gravity* — `gravity.g` pulls on the centre of mass G, torque Γ×g⃗ with g⃗ = m g G "
        "and potential energy g⃗·Γ. `gravity.g = 0` (or a centre of mass at the fixed "
        "point, as for a uniform ellipsoid) removes it.")

    def parameters_of_scene(self, scene, body) -> dict:
        return {"gravity_torque": body.mass * float(scene["gravity"]["g"]) * body.center_of_mass}

    def active(self, phys):
        return np.any(phys.gravity_torque != 0.0, axis=-1)

    def kernel_parts(self, phys) -> list:
        if not np.any(phys.gravity_torque != 0.0):
            return []
        return [("forces", Gravity, coefficients(phys.gravity_torque, phys.inertia))]

    def in_scene(self, s: dict) -> bool:
        return s["gravity"]["g"] > 0

    def keeps(self, law, phys):
        if law == LAW_LAGRANGE_OMEGA3:  # G on the body's z axis: Γ × g⃗ has no z component
            return ~np.any(phys.gravity_torque[:, :2] != 0.0, axis=-1)
        return super().keeps(law, phys)

    def torque(self, phys, omega, gamma, scale):
        return np.cross(gamma, bcast(phys.gravity_torque, gamma))

    def potential_energy(self, phys, gamma):
        return potential_energy(phys.gravity_torque, gamma)

    def resting_gamma(self, phys):
        g = phys.gravity_torque
        return -g / np.linalg.norm(g, axis=1)[:, None]

    def potential_span(self, phys):
        return 2.0 * np.linalg.norm(phys.gravity_torque, axis=1)

    def rate_bound(self, phys, omega_max):
        return np.sqrt(np.linalg.norm(phys.gravity_torque, axis=1) / phys.inertia.min(axis=1))


TERM = _Gravity()
