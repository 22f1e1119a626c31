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


class ConstantInertia(namedtuple("ConstantInertia",
                                 "I1 I2 I3 iI1 iI2 iI3 A1 A2 A3 D1 D2 D3")):
    __slots__ = ()


class ThermalInertia(namedtuple("ThermalInertia",
                                "I1 I2 I3 iI1 iI2 iI3 A1 A2 A3 D1 D2 D3 alpha")):
    __slots__ = ()
    #: the entropy feeds back into the motion: the continuous equations carry
    #: the temperature correction and the variational integrator solves for
    #: σ_{k+1} together with the step velocity
    CAPABILITIES = frozenset({"entropy_dependent_inertia"})


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

