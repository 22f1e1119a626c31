"""Inertia terms: the kinetic energy ½ Ω·𝕀Ω and what the solvers need of it.

:class:`ConstantInertia` — 𝕀 = diag(I₁, I₂, I₃) (kg m²) in the body's
principal frame.  Its coefficients, computed once per member:

* ``iI`` = 1/I_i (correctly rounded reciprocals: no division per step);
* ``A``  = ((I₂−I₃)/I₁, (I₃−I₁)/I₂, (I₁−I₂)/I₃): Euler's gyroscopic
  coefficients, (𝕀⁻¹(𝕀Ω×Ω))₁ = A₁Ω₂Ω₃ (and cyclically);
* ``D``  = ½(I₃−I₂, I₁−I₃, I₂−I₁): (½ X×𝕀X)₁ = D₁X₂X₃, the variational
  integrator's discrete Legendre transforms
  M_{±h}(X) = 𝕀X ± (h/2) X×𝕀X + (h²/4)(X·𝕀X) X.

:class:`ThermalInertia` — the fully coupled top, 𝕀(S) = s(S) 𝕀₀ with
s = φ², φ = 1 + α(θ(S) − T₀), θ(S) = U′(S) (docs/model.md): the same
coefficients of 𝕀₀ (the gyroscopic A is scale-free) and the linear thermal
expansion coefficient α (1/K).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from .._jit import fma, lane
from ..dispatch import generic, is_present
from . import (LAW_MOMENTUM_NORM, ROLE_THERMAL_COUPLING, Parameter, ScalarTerm, Setting, bcast, inertia_scale,
               inertia_scale_rate, scale_square_change, temperature_correction)


class ConstantInertia(namedtuple("ConstantInertia",
                                 "I1 I2 I3 iI1 iI2 iI3 A1 A2 A3 D1 D2 D3")):
    __slots__ = ()
    #: the free rotation has a flow the splitting runs (:func:`free_flow_stage`: Cayley
    #: rotations, not the exact ones, but symmetric, so the compositions keep their order)
    CAPABILITIES = frozenset({"exact_flow"})


class ThermalInertia(namedtuple("ThermalInertia",
                                "I1 I2 I3 iI1 iI2 iI3 A1 A2 A3 D1 D2 D3 alpha")):
    __slots__ = ()
    #: the entropy feeds back into the motion: the continuous equations carry
    #: the temperature correction and the variational integrator solves for
    #: σ_{k+1} together with the step velocity
    CAPABILITIES = frozenset({"entropy_dependent_inertia"})


# ----------------------------------------------------------------------------- 𝕀(S) = φ(S)² 𝕀₀
# φ = 1 + α(θ − T₀), θ = U′(S); each written once, in the operations the
# solvers used to spell out (so the kernels keep their bits)


@lane
def _phi(term, thermo, theta):
    return fma(term.alpha, theta - thermo.T0, 1.0)


@lane
def _dphi(term, thermo, theta):
    """φ′ = dφ/dS = αθ′(S) = αθ/c_v."""
    return (term.alpha * theta) * thermo.icv


@inertia_scale.register(ThermalInertia)
def _thermal_scale(term, thermo, theta):
    return _phi(term, thermo, theta)


@inertia_scale_rate.register(ThermalInertia)
def _thermal_scale_rate(term, thermo, theta):
    return _dphi(term, thermo, theta)


@scale_square_change.register(ThermalInertia)
def _thermal_scale_square_change(term, thermo, theta, e):
    """φ(S')² − φ(S)² = (φ' − φ)(φ' + φ), φ' − φ = α(θ' − θ) = αθe."""
    return (term.alpha * (theta * e)) * (_phi(term, thermo, fma(theta, e, theta)) + _phi(term, thermo, theta))


@temperature_correction.register(ThermalInertia)
def _thermal_temperature_correction(term, thermo, theta, K2):
    """½ Ω·𝕀′(S)Ω = φφ′ Ω·𝕀₀Ω."""
    return (_phi(term, thermo, theta) * _dphi(term, thermo, theta)) * K2


def _base(I: np.ndarray) -> np.ndarray:
    I = np.asarray(I, dtype=np.float64).reshape(-1, 3)
    I1, I2, I3 = I.T
    iI = 1.0 / I
    A = np.stack([(I2 - I3) * iI[:, 0], (I3 - I1) * iI[:, 1], (I1 - I2) * iI[:, 2]], axis=1)
    D = 0.5 * np.stack([I3 - I2, I1 - I3, I2 - I1], axis=1)
    return np.hstack([I, iI, A, D])


def constant_coefficients(inertia: np.ndarray) -> np.ndarray:
    """(N, 12) coefficients of ConstantInertia from the principal moments (N, 3)."""
    return _base(inertia)


def thermal_coefficients(inertia0: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(N, 13) coefficients of ThermalInertia from 𝕀₀ (N, 3) and α (N,)."""
    return np.hstack([_base(inertia0), np.asarray(alpha, dtype=np.float64).reshape(-1, 1)])


# ----------------------------------------------------------------------------- free rotation (Cayley)


@lane
def _cayley(tau):
    """(−2τ², 2τ, 1/(1 + τ²)): the Cayley rotation by θ′ = 2 atan τ is
    (a_j, a_k) ↦ (a_j + (−2τ²a_j + 2τa_k)/(1 + τ²), a_k + (−2τ²a_k − 2τa_j)/(1 + τ²))
    (cos θ′ − 1 = −2τ²/(1 + τ²), sin θ′ = 2τ/(1 + τ²)).  One division, which
    runs while the numerators are formed; only the small increments are
    rounded before the last addition, so the rotation keeps |a| without the
    bias that rounding 1 − τ² and 1 + τ² the same way step after step gives."""
    return -2.0 * (tau * tau), tau + tau, 1.0 / fma(tau, tau, 1.0)


@lane
def _turn(c, s, r, aj, ak):
    """(a_j, a_k) turned (c = −2τ², s = 2τ, r = 1/(1 + τ²); see :func:`_cayley`)."""
    return fma(fma(aj, c, ak * s), r, aj), fma(fma(ak, c, -(aj * s)), r, ak)


@generic(is_present)
def turn_rows(R, axis, c, s, r):
    """R ← R cay(θ′ ê_axis) for R a row-major 9-tuple (each row turns as a
    body vector); None without the attitude."""
    return None


@turn_rows.register(True)
def turn_rows_present(R, axis, c, s, r):
    """R ← R cay(θ′ ê_axis) for R a row-major 9-tuple: each row turns as a body vector."""
    if axis == 0:
        r01, r02 = _turn(c, s, r, R[1], R[2])
        r11, r12 = _turn(c, s, r, R[4], R[5])
        r21, r22 = _turn(c, s, r, R[7], R[8])
        return (R[0], r01, r02, R[3], r11, r12, R[6], r21, r22)
    if axis == 1:
        r02, r00 = _turn(c, s, r, R[2], R[0])
        r12, r10 = _turn(c, s, r, R[5], R[3])
        r22, r20 = _turn(c, s, r, R[8], R[6])
        return (r00, R[1], r02, r10, R[4], r12, r20, R[7], r22)
    r00, r01 = _turn(c, s, r, R[0], R[1])
    r10, r11 = _turn(c, s, r, R[3], R[4])
    r20, r21 = _turn(c, s, r, R[6], R[7])
    return (r00, r01, R[2], r10, r11, R[5], r20, r21, R[8])


@lane
def _axis_flow(inertia, axis, t, m0, m1, m2, G0, G1, G2, R):
    """Tⁱ_t: the flow of the kinetic energy about body axis ``axis`` alone,
    by the implicit midpoint rule on that linear sub-flow (a Cayley
    rotation): μ_i and so ω = μ_i/I_i are fixed, μ and Γ (and the rows of R)
    turn together by θ′ = 2 atan(tω/2) about e_i, not by the exact tω (a lag
    of (tω)³/12 per flow); symmetric, T_{−t} = T_t⁻¹."""
    I = inertia
    if axis == 0:
        c, s, r = _cayley(m0 * ((0.5 * t) * I.iI1))
        m1, m2 = _turn(c, s, r, m1, m2)
        G1, G2 = _turn(c, s, r, G1, G2)
    elif axis == 1:
        c, s, r = _cayley(m1 * ((0.5 * t) * I.iI2))
        m2, m0 = _turn(c, s, r, m2, m0)
        G2, G0 = _turn(c, s, r, G2, G0)
    else:
        c, s, r = _cayley(m2 * ((0.5 * t) * I.iI3))
        m0, m1 = _turn(c, s, r, m0, m1)
        G0, G1 = _turn(c, s, r, G0, G1)
    return m0, m1, m2, G0, G1, G2, turn_rows(R, axis, c, s, r)


#: the number of flows of :func:`free_flow_stage`
FREE_FLOW_STAGES = 5


@lane
def free_flow_stage(inertia, stage, t, m0, m1, m2, G0, G1, G2, R):
    """Flow number ``stage`` (a literal, 0 … 4) of the free rigid body over a
    time t, the symmetric splitting T¹_{t/2} T²_{t/2} T³_t T²_{t/2} T¹_{t/2}
    of its kinetic energy, in time order: each flow a Cayley rotation, one
    division each; the five together are a symmetric Poisson map that keeps
    |μ|, |Γ|, Γ·μ and the orthogonality of R to round-off."""
    if stage == 0 or stage == 4:
        return _axis_flow(inertia, 0, 0.5 * t, m0, m1, m2, G0, G1, G2, R)
    if stage == 1 or stage == 3:
        return _axis_flow(inertia, 1, 0.5 * t, m0, m1, m2, G0, G1, G2, R)
    return _axis_flow(inertia, 2, t, m0, m1, m2, G0, G1, G2, R)


class _ThermalExpansion(ScalarTerm):
    """The coupled top: thermal expansion makes the inertia depend on S."""

    name = "thermal_expansion"
    settings = (Setting("body", "thermal_expansion", 0.0, "K-1",
                        "linear thermal expansion α: 𝕀(S) = 𝕀₀ (1 + α(θ − T0))², the fully coupled top"),)
    parameters = (Parameter("thermal_expansion", (), "K-1",
                            "thermal expansion alpha",
                            comment="linear thermal expansion: I(S) = I0 (1 + alpha (theta - T0))^2"),)
    no_exact_flow = "the entropy-dependent inertia has no exact flow"
    scene_doc = (
        "*Thermal expansion* — `body.thermal_expansion = α > 0` makes the inertia depend "
        "on the entropy, 𝕀(S) = 𝕀₀(1 + α(θ − T₀))²: the fully coupled top. Give it a small "
        "`thermo.heat_capacity` to see the heating (the built-in `coupled_egg`). With `vi` "
        "and a friction it needs `integrator.start = \"legendre\"` and "
        "`integrator.friction = \"trapezoid\"`; frictions whose discrete form is nonlinear "
        "(such as the internal friction) are not available with it.")

    sets_inertia = True
    role = ROLE_THERMAL_COUPLING

    def keeps(self, law, phys):
        if law == LAW_MOMENTUM_NORM:  # no torque: μ is conserved whatever 𝕀(S) does
            return np.ones(phys.n, dtype=bool)
        return super().keeps(law, phys)

    def coupled(self, phys) -> bool:
        """The inertia follows the entropy: something expands and something heats."""
        return phys.dissipative and bool(np.any(phys.thermal_expansion != 0.0))

    def kernel_parts(self, phys) -> list:
        if not self.coupled(phys):
            return []
        return [("inertia", ThermalInertia, thermal_coefficients(phys.inertia, phys.thermal_expansion))]

    def violations(self, s: dict):
        from . import registry

        if not self.in_scene(s):
            return
        for t in registry():
            if t.nonlinear_friction and t.in_scene(s):
                key = t.settings[0]
                yield (key.path, "is not available together with body.thermal_expansion > 0",
                       s[key.section][key.name])
        integ = s["integrator"]
        vi_plain = integ["method"] == "vi" or "vi" in s["output"]["compare"]
        rubs = any(t.friction and t.in_scene(s) for t in registry())
        if vi_plain and rubs:
            for key, value in (("integrator.start", integ["start"]), ("integrator.friction", integ["friction"])):
                problem = self.vi_refusal(integ["start"] if key.endswith("start") else "legendre",
                                          integ["friction"] if key.endswith("friction") else "trapezoid")
                if problem is not None:
                    yield (problem[0], problem[1], value)

    def vi_refusal(self, start: str, friction: str) -> tuple[str, str] | None:
        """The coupled top's variational integrator solves for σ_{k+1} with the
        step velocity from the node momentum, with the trapezoid friction."""
        if start != "legendre":
            return ("integrator.start", 'the coupled top (body.thermal_expansion > 0) starts '
                    'from its node momentum: use "legendre"')
        if friction == "endpoint":
            return ("integrator.friction", "the coupled top has the trapezoid friction only")
        return None

    def start_problem(self, scene, phys, kin2: float, what: str) -> tuple[str, str] | None:
        """The coupled top's temperature T = θ − φφ′ Ω·𝕀₀Ω must start positive
        for every member: at S₀ (θ = T₀, φ = 1, φ′ = αT₀/c_v) that is
        α Ω·𝕀₀Ω < c_v; ``kin2`` bounds Ω·𝕀₀Ω over the members (``what`` says how)."""
        alpha = float(phys.thermal_expansion[0])
        cv = float(phys.heat_capacity[0])
        if alpha <= 0.0 or alpha * kin2 < cv:
            return None
        return ("body.thermal_expansion",
                f"the coupled top would start at a temperature T = T0 (1 − α {what}/c_v) ≤ 0 "
                f"(α {what} = {alpha * kin2:.3g} J/K against c_v = {cv:.3g} J/K); lower α or the "
                f"spin, or raise thermo.heat_capacity")

    def expansion(self, phys, theta):
        """(φ, φ′) of 𝕀(S) = φ²𝕀₀ at θ(S) (N, ...): φ = 1 + α(θ − T₀),
        φ′ = dφ/dS = αθ/c_v; None without thermal expansion."""
        if not np.any(phys.thermal_expansion != 0.0):
            return None
        alpha = bcast(phys.thermal_expansion, theta)
        phi = 1.0 + alpha * (theta - bcast(phys.T0, theta))
        return phi, alpha * theta / bcast(phys.heat_capacity, theta)


TERM = _ThermalExpansion()
