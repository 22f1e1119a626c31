"""Stokes friction: the torque −CΩ of a body turning in a viscous fluid.

* :class:`StokesSphere` — a sphere of radius a, C = c·Id, c = 8πμa³ (N m s);
* :class:`StokesDiagonal` — a triaxial ellipsoid (Jeffery 1922), C =
  diag(C₁, C₂, C₃) in the body's principal frame (docs/model.md), plus the
  drag of its centre when it pivots about another point (Oberbeck 1876):
  about a pivot at −G from the centre the centre moves at v = Ω×G and the
  translational resistance K adds DᵀKD with D = [G]×.

Coefficients: the friction coefficients and K_i = C_i/I_i (over the reference
principal moments).  Dissipated power −⟨f, Ω⟩ = Ω·CΩ (W).  Both are linear in
Ω, so the variational integrator folds C into its Newton matrix.
"""

from __future__ import annotations

from collections import namedtuple

import math

import numpy as np

from .._jit import fma, lane
from ..lanemath import expm1_lane
from ..gen import cadd, madd
from ..so3 import norm2_lane
from . import (LAW_LAGRANGE_OMEGA3, LAW_SPHERICAL_DECAY, ROLE_LINEAR_FRICTION, Parameter, Setting, Term, bcast, over_inertia, angular_acceleration, discrete_power, dissipated_power,
               exact_flow, linear_friction)


class StokesSphere(namedtuple("StokesSphere", "c K1 K2 K3")):
    __slots__ = ()
    CAPABILITIES = frozenset({"exact_flow"})


class StokesDiagonal(namedtuple("StokesDiagonal", "C1 C2 C3 K1 K2 K3")):
    __slots__ = ()
    CAPABILITIES = frozenset({"exact_flow"})


def sphere_coefficients(c: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 4) from c (N,) and 𝕀₀ (N, 3)."""
    return over_inertia(c, inertia0, 1)


def diagonal_coefficients(C: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    """(N, 6) from diag C (N, 3) and 𝕀₀ (N, 3)."""
    return over_inertia(C, inertia0, 3)


@angular_acceleration.register(StokesSphere)
def _sphere_acc(term, inertia, iscale, w, G, a):
    w0, w1, w2 = w
    a0, a1, a2 = a
    return madd(-term.K1, w0, a0), madd(-term.K2, w1, a1), madd(-term.K3, w2, a2)


@dissipated_power.register(StokesSphere)
def _sphere_power(term, inertia, iscale, w, p):
    w0, w1, w2 = w
    return madd(term.c, norm2_lane(w0, w1, w2), p)


@discrete_power.register(StokesSphere)
def _sphere_discrete_power(term, inertia, h, x, p):
    x0, x1, x2 = x
    return madd(term.c, norm2_lane(x0, x1, x2), p)


@linear_friction.register(StokesSphere)
def _sphere_linear(term, c):
    c0, c1, c2 = c
    return cadd(term.c, c0), cadd(term.c, c1), cadd(term.c, c2)


@angular_acceleration.register(StokesDiagonal)
def _diag_acc(term, inertia, iscale, w, G, a):
    w0, w1, w2 = w
    a0, a1, a2 = a
    return madd(-term.K1, w0, a0), madd(-term.K2, w1, a1), madd(-term.K3, w2, a2)


@dissipated_power.register(StokesDiagonal)
def _diag_power(term, inertia, iscale, w, p):
    w0, w1, w2 = w
    return madd(term.C1 * w0, w0, madd(term.C2 * w1, w1, madd(term.C3 * w2, w2, p)))


@discrete_power.register(StokesDiagonal)
def _diag_discrete_power(term, inertia, h, x, p):
    x0, x1, x2 = x
    return madd(term.C1 * x0, x0, madd(term.C2 * x1, x1, madd(term.C3 * x2, x2, p)))


@linear_friction.register(StokesDiagonal)
def _diag_linear(term, c):
    c0, c1, c2 = c
    return cadd(term.C1, c0), cadd(term.C2, c1), cadd(term.C3, c2)


@lane
def _friction_flow(term, inertia, t, m0, m1, m2, q):
    """μ_i ← μ_i e^{−K_i t} (the exact flow of μ̇_i = −C_i Ω_i), with the
    kinetic energy it takes, Σ μ_i² w_i, w_i = ½(1 − e^{−2K_i t})/I_i =
    ½ d_i(2 − d_i)/I_i, d_i = −expm1(−K_i t) (no cancellation), added to the
    heat q.  Backward in time (t < 0) it gives the heat back exactly.  The
    factors depend on t and the member only: a sweep over members that share
    their parameters computes them once (:func:`..lanemath.expm1_lane` is
    plain arithmetic that LLVM hoists and vectorizes)."""
    I = inertia
    d0, d1, d2 = -expm1_lane(-(term.K1 * t)), -expm1_lane(-(term.K2 * t)), -expm1_lane(-(term.K3 * t))
    w0, w1, w2 = (0.5 * I.iI1) * (d0 * (2.0 - d0)), (0.5 * I.iI2) * (d1 * (2.0 - d1)), (0.5 * I.iI3) * (d2 * (2.0 - d2))
    dK = fma(m0 * m0, w0, fma(m1 * m1, w1, (m2 * m2) * w2))
    # μ − μd (one rounding, of the result): μ(1 − d) would round 1 − d the same way every step
    return (fma(-m0, d0, m0), fma(-m1, d1, m1), fma(-m2, d2, m2)), q + dK


@exact_flow.register(StokesSphere)
def _sphere_flow(term, inertia, t, G, m, q):
    m0, m1, m2 = m
    return _friction_flow(term, inertia, t, m0, m1, m2, q)


@exact_flow.register(StokesDiagonal)
def _diag_flow(term, inertia, t, G, m, q):
    m0, m1, m2 = m
    return _friction_flow(term, inertia, t, m0, m1, m2, q)


# ----------------------------------------------------------------------------- resistance of a body


def jeffery_resistance(semi_axes, viscosity) -> np.ndarray:
    """Rotational Stokes resistance (N m s) of an ellipsoid about its principal
    axes (Jeffery 1922): torque −C_iΩ_i; a sphere of radius a gives 8πμa³."""
    from scipy.special import elliprd

    a = np.asarray(semi_axes, dtype=np.float64).reshape(-1, 3)
    a2 = a * a
    alpha = np.empty_like(a)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        alpha[:, i] = (2.0 / 3.0) * elliprd(a2[:, j], a2[:, k], a2[:, i])
    C = np.empty_like(a)
    mu = np.asarray(viscosity, dtype=np.float64).reshape(-1)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        C[:, i] = (16.0 * math.pi * mu / 3.0) * (a2[:, j] + a2[:, k]) / (
            a2[:, j] * alpha[:, j] + a2[:, k] * alpha[:, k])
    return C


def oberbeck_resistance(semi_axes, viscosity) -> np.ndarray:
    """Translational Stokes resistance (N s m-1) of an ellipsoid along its
    principal axes (Oberbeck 1876): force −K_i v_i on its centre moving at v;
    K_i = 16πμ/(χ₀ + a_i²α_i) with χ₀ = 2 R_F(a₁², a₂², a₃²) and α_i as in
    :func:`jeffery_resistance`.  A sphere of radius a gives 6πμa."""
    from scipy.special import elliprd, elliprf

    a = np.asarray(semi_axes, dtype=np.float64).reshape(-1, 3)
    a2 = a * a
    chi0 = 2.0 * elliprf(a2[:, 0], a2[:, 1], a2[:, 2])
    K = np.empty_like(a)
    mu = np.asarray(viscosity, dtype=np.float64).reshape(-1)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        alpha_i = (2.0 / 3.0) * elliprd(a2[:, j], a2[:, k], a2[:, i])
        K[:, i] = 16.0 * math.pi * mu / (chi0 + a2[:, i] * alpha_i)
    return K


def pivot_drag(K, d) -> np.ndarray:
    """DᵀKD with D = [d]× (d × v = D v): the resistance about a pivot at −d
    from the centre of a body whose centre, moving at v = Ω×d, feels the
    force −Kv (K diagonal in the body frame).  A 3×3 symmetric positive
    semi-definite matrix, diagonal when d lies on a principal axis."""
    d = np.asarray(d, dtype=np.float64)
    D = np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
    return D.T @ np.diag(np.asarray(K, dtype=np.float64)) @ D


# ----------------------------------------------------------------------------- the term


class _Stokes(Term):
    name = "stokes"
    settings = (Setting("fluid", "viscosity", 0.1, "kg m-1 s-1",
                        "dynamic viscosity μ of the Stokes fluid (friction torque −CΩ)"),)
    parameters = (
        Parameter("stokes_resistance", (3,), "N m s", "Stokes resistance C",
                  comment="rotational Stokes resistance: friction torque -C Omega",
                  variable="friction_coefficients", always=True),
        Parameter("isotropic_resistance", None, "",
                  "C = c Id for every member (a sphere): the kernels use the scalar form",
                  variable="", default=True),
    )
    friction = True
    role = ROLE_LINEAR_FRICTION
    scene_doc = (
        "*Stokes friction* — `fluid.viscosity = η > 0` turns the body in a viscous fluid, "
        "torque −CΩ: a sphere of radius a (the paper's top) has C = 8πηa³; an ellipsoid "
        "has Jeffery's diagonal rotational resistance and, pivoting at −G from its centre "
        "(`body.center_of_mass = G` on a body axis), the drag of its centre seen about the "
        "pivot (Oberbeck's resistance). `fluid.viscosity = 0` removes it.")

    def parameters_of_scene(self, scene, body) -> dict:
        mu = float(scene["fluid"]["viscosity"])
        if body.sphere_radius is not None:
            c = 8.0 * math.pi * mu * body.sphere_radius ** 3
            return {"stokes_resistance": np.array([c, c, c]), "isotropic_resistance": True}
        C = jeffery_resistance(body.semi_axes, mu)[0]
        G = body.center_of_mass
        if np.any(G != 0.0):  # the centre, at G from the pivot, is dragged through the fluid
            C = C + np.diag(pivot_drag(oberbeck_resistance(body.semi_axes, mu)[0], G))
        return {"stokes_resistance": C, "isotropic_resistance": False}

    def active(self, phys) -> np.ndarray:
        return np.any(phys.stokes_resistance != 0.0, axis=-1)

    def dissipates(self, phys) -> bool:
        return bool(np.any(phys.stokes_resistance != 0.0))

    def kernel_parts(self, phys) -> list:
        if not np.any(phys.stokes_resistance != 0.0):
            return []
        if phys.isotropic_resistance:
            return [("forces", StokesSphere, sphere_coefficients(phys.stokes_resistance[:, 0], phys.inertia))]
        return [("forces", StokesDiagonal, diagonal_coefficients(phys.stokes_resistance, phys.inertia))]

    def violations(self, s: dict):
        body = s["body"]
        if (body["shape"] == "ellipsoid" and body["center_of_mass"] != "shape"
                and np.count_nonzero(body["center_of_mass"]) > 1 and s["fluid"]["viscosity"] > 0):
            yield ("body.center_of_mass", "an ellipsoid in a viscous fluid pivots about a "
                   "point on one of its axes (the drag of its centre about the pivot is "
                   "then diagonal, as the kernels need): give G along a body axis",
                   body["center_of_mass"])

    def in_scene(self, s: dict) -> bool:
        return s["fluid"]["viscosity"] > 0

    @staticmethod
    def _isotropic(C: np.ndarray) -> np.ndarray:
        """Rows of C (…, 3) whose three entries are equal (to 1e-12): C = c·Id."""
        return np.ptp(C, axis=-1) <= 1e-12 * np.max(np.abs(C), axis=-1)

    def keeps(self, law, phys):
        if law == LAW_SPHERICAL_DECAY:  # −CΩ with C = c·Id
            return self._isotropic(phys.stokes_resistance)
        if law == LAW_LAGRANGE_OMEGA3:  # C is diagonal in the body axes: −C₃Ω₃
            return np.ones(phys.n, dtype=bool)
        return super().keeps(law, phys)

    def summary_lines(self, phys) -> list[str]:
        C, I0 = phys.stokes_resistance, phys.inertia
        if not np.any(C != 0.0):
            return []
        with np.errstate(divide="ignore"):
            tau = np.where(C > 0, I0 / np.where(C > 0, C, 1.0), np.inf)
        what = "" if bool(np.all(C == C[0])) else " (member 0; the members differ)"
        times = ", ".join(f"{x:.3g}" for x in tau[0])
        if self._isotropic(C[0]):
            return [f"  Stokes friction           C = {C[0, 0]:.4g} N m s on every axis{what}; "
                    f"decay times I_i/C_i = {times} s"]
        return [f"  Stokes friction tensor    C = diag({', '.join(f'{x:.4g}' for x in C[0])}) N m s"
                f"{what} (body axes x, y, z);",
                f"                            decay times I_i/C_i = {times} s"]

    def torque(self, phys, omega, gamma, scale):
        return -bcast(phys.stokes_resistance, omega) * omega

    def linear_resistance(self, phys):
        return phys.stokes_resistance

    def with_linear_resistance(self, phys, C):
        return {"stokes_resistance": C}

    def discrete_friction(self, phys, h, x):
        return bcast(phys.stokes_resistance, x) * x

    def dissipated_power(self, phys, omega, scale):
        return np.sum(bcast(phys.stokes_resistance, omega) * omega * omega, axis=-1)

    def rate_bound(self, phys, omega_max):
        return phys.stokes_resistance.max(axis=1) / phys.inertia.min(axis=1)


TERM = _Stokes()
