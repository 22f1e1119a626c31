"""Physics of an ensemble: per-member parameters, the model the kernels run,
and the energies of a state.

:class:`Physics` holds the physical parameters of N members (SI units, a
leading member axis), computed from a scene (:func:`physics_of_scene`) and
varied per member where a study needs it (``dataclasses.replace``).
:func:`build_model` turns it into the kernels' model — which terms a run
needs (an absent term is not compiled), their coefficients per member, and
whether all members share them.  The energy functions here are numpy (no
numba), for datasets and studies; docs/model.md has the formulas.

Bodies (``body.shape``):

* ``"hemispheres"`` — the paper's top: a solid upper hemisphere (mass
  fraction f) and a thin hollow lower hemisphere of radius a, density ρ,
  spinning about its centre C; inertia as printed in the paper (or given),
  centre of mass G = (0, 0, 3m₁a/(8m) − m₂a/(2m)), Stokes friction of a
  sphere c = 8πμa³;
* ``"ellipsoid"`` — a triaxial ellipsoid with semi-axes a₁, a₂, a₃ along
  its principal axes, of uniform density (or given mass, inertia and centre
  of mass) turning about a pivot at −G from its centre (G on a principal
  axis); rotational Stokes resistance of Jeffery (1922),
  C_i = (16πμ/3)(a_j² + a_k²)/(a_j²α_j + a_k²α_k),
  α_i = (2/3) R_D(a_j², a_k², a_i²) (Carlson's integral), plus the drag of
  its centre moving at v = Ω×G through the fluid: Oberbeck's (1876)
  translational resistance K_i = 16πμ/(χ₀ + a_i²α_i), χ₀ = 2 R_F(a₁², a₂², a₃²),
  seen about the pivot as DᵀKD with D = [G]×, so that the torque is
  −(C_rot + DᵀKD)Ω (diagonal for G on a principal axis).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .kernels import gen
from .kernels.layout import StateLayout, state_layout
from .kernels.terms import ATTITUDE, Model
from .kernels.terms import double_bracket as _db
from .kernels.terms import gravity as _gravity
from .kernels.terms import inertia as _inertia
from .kernels.terms import stokes as _stokes
from .kernels.terms import thermo as _thermo

R_GAS = 8.314462618  # J mol⁻¹ K⁻¹


@dataclass(frozen=True)
class Physics:
    """Physical parameters of N members; every array has N rows."""

    inertia: np.ndarray  # (N, 3) principal moments 𝕀₀ about the fixed point, kg m²
    center_of_mass: np.ndarray  # (N, 3) G in the body frame, from the fixed point, m
    mass: np.ndarray  # (N,) kg
    friction: np.ndarray  # (N, 3) diagonal Stokes friction C, N m s
    gravity_torque: np.ndarray  # (N, 3) g⃗ = m g G, N m
    heat_capacity: np.ndarray  # (N,) c_v, J K⁻¹
    T0: np.ndarray  # (N,) K
    S0: np.ndarray  # (N,) J K⁻¹
    thermal_expansion: np.ndarray  # (N,) α, K⁻¹
    internal_friction: np.ndarray  # (N,) λ, s kg⁻¹ m⁻²
    #: True if C is isotropic (a sphere), so the kernels use the scalar term
    isotropic_friction: bool = True

    @property
    def n(self) -> int:
        return int(self.inertia.shape[0])

    def take(self, index) -> "Physics":
        """The members ``index`` (a slice or index array)."""
        kw = {f.name: getattr(self, f.name)[index] for f in dataclasses.fields(self)
              if isinstance(getattr(self, f.name), np.ndarray)}
        return dataclasses.replace(self, **kw)

    def repeat(self, n: int) -> "Physics":
        """n copies of member 0."""
        return self.take(np.zeros(int(n), dtype=np.int64))

    @property
    def stokes_coefficient(self) -> np.ndarray:
        """c of an isotropic friction (N,); the mean of C otherwise."""
        return self.friction.mean(axis=1)

    @property
    def dissipative(self) -> bool:
        return bool(np.any(self.friction != 0.0) or np.any(self.internal_friction != 0.0))


# ----------------------------------------------------------------------------- bodies


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


def _hemispheres(body: dict, viscosity: float) -> tuple:
    a = float(body["radius"])
    m = (4.0 / 3.0 * math.pi * a**3 * float(body["density"])
         if isinstance(body["mass"], str) else float(body["mass"]))
    m1 = float(body["upper_mass_fraction"]) * m
    m2 = m - m1
    if isinstance(body["inertia"], str):  # the paper's printed values (docs/model.md, E5)
        I12 = 83.0 * a * a * m1 / 320.0 + a * a * m2 / 12.0
        I3 = 2.0 * a * a * m1 / 5.0 + a * a * m2 / 3.0
        inertia = np.array([I12, I12, I3])
    else:
        inertia = np.asarray(body["inertia"], dtype=np.float64)
    if isinstance(body["center_of_mass"], str):
        G = np.array([0.0, 0.0, 3.0 * m1 * a / (8.0 * m) - m2 * a / (2.0 * m)])
    else:
        G = np.asarray(body["center_of_mass"], dtype=np.float64)
    c = 8.0 * math.pi * viscosity * a**3
    return m, inertia, G, np.array([c, c, c]), True


def _ellipsoid(body: dict, viscosity: float) -> tuple:
    ax = np.asarray(body["semi_axes"], dtype=np.float64)
    m = (4.0 / 3.0 * math.pi * ax.prod() * float(body["density"])
         if isinstance(body["mass"], str) else float(body["mass"]))
    if isinstance(body["center_of_mass"], str):
        G = np.zeros(3)  # uniform: the centre of mass is the fixed centre
    else:
        G = np.asarray(body["center_of_mass"], dtype=np.float64)
    if isinstance(body["inertia"], str):
        # uniform density about the centre, moved to the fixed point (at −G from the
        # centre) by the parallel-axis theorem; G lies on a body axis (scene rule)
        a2 = ax * ax
        inertia = m / 5.0 * np.array([a2[1] + a2[2], a2[2] + a2[0], a2[0] + a2[1]])
        inertia = inertia + m * (G @ G - G * G)
    else:
        inertia = np.asarray(body["inertia"], dtype=np.float64)
    C = jeffery_resistance(ax, viscosity)[0]
    if np.any(G != 0.0):  # the centre, at G from the pivot, is dragged through the fluid
        C = C + np.diag(pivot_drag(oberbeck_resistance(ax, viscosity)[0], G))
    return m, inertia, G, C, False


SHAPES = {"hemispheres": _hemispheres, "ellipsoid": _ellipsoid}


def physics_of_scene(scene, members: int = 1) -> Physics:
    """The physics of a resolved scene, repeated for ``members`` members."""
    body = scene["body"]
    mu = float(scene["fluid"]["viscosity"])
    m, inertia, G, C, iso = SHAPES[body["shape"]](body, mu)
    hc = scene["thermo"]["heat_capacity"]
    cv = 3.0 * (m / float(body["molar_mass"])) * R_GAS if isinstance(hc, str) else float(hc)
    one = Physics(
        inertia=inertia[None].astype(np.float64), center_of_mass=G[None].astype(np.float64),
        mass=np.array([m]), friction=C[None].astype(np.float64),
        gravity_torque=(m * float(scene["gravity"]["g"]) * G)[None],
        heat_capacity=np.array([cv]), T0=np.array([float(scene["thermo"]["T0"])]),
        S0=np.array([float(scene["thermo"]["S0"])]),
        thermal_expansion=np.array([float(body["thermal_expansion"])]),
        internal_friction=np.array([float(body["internal_friction"])]),
        isotropic_friction=iso)
    return one.repeat(members) if members != 1 else one


# ----------------------------------------------------------------------------- the kernels' model


@dataclass(frozen=True)
class KernelModel:
    """The model a run compiles: ``model`` (the terms of member 0, whose type
    selects the code), ``P`` (N, nparam) every member's parameters, and
    ``shared`` (``model`` if all members share their parameters bitwise,
    else None)."""

    model: Model
    P: np.ndarray
    shared: Model | None

    @property
    def nparam(self) -> int:
        return int(self.P.shape[1])

    def layout(self, family: str) -> StateLayout:
        return state_layout(self.model, family)

    def terms(self) -> list[str]:
        """Names of the terms present, for labels and reports."""
        out = [type(self.model.inertia).__name__]
        if self.model.thermo is not None:
            out.append("IdealSolid")  # IdealSolidWide: the same physics, a wider polynomial
        out += [type(t).__name__ for t in self.model.forces]
        if self.model.attitude is not None:
            out.append("Attitude")
        return out


def build_model(phys: Physics, attitude: bool = False, heat=None) -> KernelModel:
    """The kernels' model of an ensemble: only the terms some member needs.
    ``heat``: an upper bound of the heat any member can produce (J; its
    initial mechanical energy above rest): where it could take σ/c_v beyond
    the cubic's range of 1/T, the ideal solid is evaluated with its wider
    polynomial (same physics, and still vectorized)."""
    N = phys.n
    I0 = phys.inertia
    dissipative = phys.dissipative
    coupled = dissipative and bool(np.any(phys.thermal_expansion != 0.0))
    parts: list[tuple[type, np.ndarray]] = []
    if coupled:
        parts.append((_inertia.ThermalInertia, _inertia.thermal_coefficients(I0, phys.thermal_expansion)))
    else:
        parts.append((_inertia.ConstantInertia, _inertia.constant_coefficients(I0)))
    thermo = None
    if dissipative:
        # a heat q ≥ 0 takes σ/c_v to at most ln(1 + q/(c_v T₀)); one bound for the
        # ensemble (its largest heat), so that members of one body share their model
        qmax = 0.0 if heat is None else float(heat)
        with np.errstate(all="ignore"):
            reach = np.log1p(qmax / (phys.heat_capacity * phys.T0))
        if np.any(reach > _thermo.EXP_SMALL):
            reach = np.where(np.isfinite(reach), reach, 0.0)
            thermo = (_thermo.IdealSolidWide, _thermo.coefficients_wide(phys.heat_capacity, phys.T0, reach))
        else:
            thermo = (_thermo.IdealSolid, _thermo.coefficients(phys.heat_capacity, phys.T0))
    forces: list[tuple[type, np.ndarray]] = []
    if np.any(phys.friction != 0.0):
        if phys.isotropic_friction:
            forces.append((_stokes.StokesSphere, _stokes.sphere_coefficients(phys.friction[:, 0], I0)))
        else:
            forces.append((_stokes.StokesDiagonal, _stokes.diagonal_coefficients(phys.friction, I0)))
    if np.any(phys.internal_friction != 0.0):
        forces.append((_db.DoubleBracket, _db.coefficients(phys.internal_friction, I0)))
    if np.any(phys.gravity_torque != 0.0):
        forces.append((_gravity.Gravity, _gravity.coefficients(phys.gravity_torque, I0)))
    blocks = [parts[0][1]] + ([thermo[1]] if thermo else []) + [f[1] for f in forces]
    if attitude:
        blocks.append(np.ones((N, 1)))
    P = np.ascontiguousarray(np.hstack(blocks), dtype=np.float64)

    def assemble(row: np.ndarray) -> Model:
        k = 0

        def take(cls):
            nonlocal k
            n = len(cls._fields)
            vals = [float(x) for x in row[k:k + n]]
            k += n
            return cls(*vals)

        inertia = take(parts[0][0])
        th = take(thermo[0]) if thermo else None
        fs = tuple(take(cls) for cls, _ in forces)
        att = take(type(ATTITUDE)) if attitude else None
        return Model(inertia, th, fs, att)

    template = assemble(P[0] if N else np.zeros(P.shape[1]))
    assert len(gen.flatten(template)) == P.shape[1]
    bits = P.view(np.int64)
    shared = template if (N == 0 or bool((bits == bits[0]).all())) else None
    return KernelModel(template, P, shared)


# ----------------------------------------------------------------------------- energies (numpy)


def _bcast(a: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Per-member values a (N, ...) broadcast against arrays (N, T, ...)."""
    return a.reshape(a.shape[:1] + (1,) * (like.ndim - a.ndim) + a.shape[1:])


def theta(phys: Physics, sigma: np.ndarray) -> np.ndarray:
    """θ(S) = U′(S) = T₀ exp(σ/c_v) in K, σ = S − S₀ (N, ...)."""
    return _bcast(phys.T0, sigma) * np.exp(sigma / _bcast(phys.heat_capacity, sigma))


def inertia_scale(phys: Physics, sigma: np.ndarray | None) -> np.ndarray | float:
    """s(S) with 𝕀(S) = s 𝕀₀: (1 + α(θ − T₀))² (1 without thermal expansion)."""
    if sigma is None or not np.any(phys.thermal_expansion != 0.0):
        return 1.0
    alpha = _bcast(phys.thermal_expansion, sigma)
    return (1.0 + alpha * (theta(phys, sigma) - _bcast(phys.T0, sigma))) ** 2


def node_velocity(phys: Physics, momentum: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    """Ω = 𝕀(S)⁻¹ μ (rad s⁻¹) for momenta (N, ..., 3)."""
    s = inertia_scale(phys, sigma)
    s = s[..., None] if isinstance(s, np.ndarray) else s
    return momentum / (_bcast(phys.inertia, momentum) * s)


def kinetic_energy(phys: Physics, omega: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    """K = ½ Ω·𝕀(S)Ω in J."""
    s = inertia_scale(phys, sigma)
    return 0.5 * s * np.sum(_bcast(phys.inertia, omega) * omega * omega, axis=-1)


def potential_energy(phys: Physics, gamma: np.ndarray) -> np.ndarray:
    """V = g⃗·Γ in J."""
    return _gravity.potential_energy(phys.gravity_torque, gamma)


def internal_energy_change(phys: Physics, sigma: np.ndarray) -> np.ndarray:
    """U(S) − U(S₀) = c_v T₀ expm1(σ/c_v) in J, without cancellation."""
    cv = _bcast(phys.heat_capacity, sigma)
    return cv * _bcast(phys.T0, sigma) * np.expm1(sigma / cv)


def temperature(phys: Physics, omega: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """T = −∂L/∂S in K: θ(S), less ½Ω·𝕀′(S)Ω = φφ′ Ω·𝕀₀Ω for an entropy-dependent inertia."""
    th = theta(phys, sigma)
    if not np.any(phys.thermal_expansion != 0.0):
        return th
    alpha = _bcast(phys.thermal_expansion, sigma)
    phi = 1.0 + alpha * (th - _bcast(phys.T0, sigma))
    dphi = alpha * th / _bcast(phys.heat_capacity, sigma)
    return th - phi * dphi * np.sum(_bcast(phys.inertia, omega) * omega * omega, axis=-1)


def mechanical_energy_scale(phys: Physics, omega0: np.ndarray, gamma0: np.ndarray) -> np.ndarray:
    """K₀ + V₀ + |g⃗| (N,): the initial mechanical energy above the resting state,
    the energy friction can turn into heat (the natural scale of E_k − E₀)."""
    K0 = kinetic_energy(phys, omega0, None)
    V0 = np.sum(phys.gravity_torque * gamma0, axis=-1)
    return K0 + V0 + np.linalg.norm(phys.gravity_torque, axis=-1)
