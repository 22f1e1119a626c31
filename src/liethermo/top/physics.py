"""Physics of an ensemble: per-member parameters, the model the kernels run,
and the energies of a state.

:class:`Physics` holds the physical parameters of N members (SI units, a
leading member axis): the body's own, and those the model terms declare
(:mod:`liethermo.top.kernels.terms`), computed from a scene
(:func:`physics_of_scene`) and varied per member where a study needs it
(``dataclasses.replace``).  :func:`build_model` turns it into the kernels'
model — which terms a run needs (an absent term is not compiled), their
coefficients per member, and whether all members share them.  The energy
functions here are numpy (no numba), for datasets and studies; each sums
what the terms contribute; docs/model.md has the formulas.

Bodies (``body.shape``), as :class:`Body`, from which the terms take what
they need (the Stokes friction its size and shape, gravity its mass and
centre of mass):

* ``"hemispheres"`` — the paper's top: a solid upper hemisphere (mass
  fraction f) and a thin hollow lower hemisphere of radius a, density ρ,
  spinning about its centre C; inertia as printed in the paper (or given),
  centre of mass G = (0, 0, 3m₁a/(8m) − m₂a/(2m)); it meets the fluid as a
  sphere of radius a;
* ``"ellipsoid"`` — a triaxial ellipsoid with semi-axes a₁, a₂, a₃ along
  its principal axes, of uniform density (or given mass, inertia and centre
  of mass) turning about a pivot at −G from its centre (G on a principal
  axis).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..numerics import heat as _heat
from .kernels import gen
from .kernels.layout import StateLayout, state_layout
from .kernels.terms import ATTITUDE, Model, bcast, constant_inertia_part, dot3, registry
from .kernels.terms import thermo as _thermo

R_GAS = 8.314462618  # J mol⁻¹ K⁻¹


# ----------------------------------------------------------------------------- per-member parameters


class _PhysicsBase:
    """Methods of :class:`Physics` (whose fields come from the term registry)."""

    def __post_init__(self):
        n = int(np.asarray(self.inertia).shape[0])
        for t in registry():
            for prm in t.parameters:
                if getattr(self, prm.name) is None:
                    value = prm.default if prm.shape is None else np.zeros((n,) + prm.shape)
                    object.__setattr__(self, prm.name, value)

    @property
    def n(self) -> int:
        return int(self.inertia.shape[0])

    def take(self, index) -> "Physics":
        """The members ``index`` (a slice or index array)."""
        kw = {f.name: getattr(self, f.name)[index] for f in dataclasses.fields(self)
              if isinstance(getattr(self, f.name), np.ndarray)}
        return dataclasses.replace(self, **kw)

    def repeat(self, n: int) -> "Physics":
        """n copies of member 0: read-only views of its row (no copy; :attr:`uniform`)."""
        kw = {f.name: np.broadcast_to(v[:1], (int(n),) + v.shape[1:]) for f in dataclasses.fields(self)
              if isinstance(v := getattr(self, f.name), np.ndarray)}
        return dataclasses.replace(self, **kw)

    @property
    def uniform(self) -> bool:
        """Every per-member parameter is one row seen by every member (:meth:`repeat`):
        what holds for member 0 holds for all, without a pass over the members."""
        return all(v.strides[0] == 0 or v.shape[0] <= 1 for f in dataclasses.fields(self)
                   if isinstance(v := getattr(self, f.name), np.ndarray) and v.ndim >= 1)

    def one_row(self) -> "Physics":
        """Member 0 alone where it stands for every member (:attr:`uniform`), else every member."""
        return self.take(slice(0, 1)) if self.n > 1 and self.uniform else self

    def per_row(self, f):
        """``f(physics)``, per member (an array of leading length n, or a dict of them),
        worked out once on :meth:`one_row` and broadcast (read-only views) where the
        members share one row."""
        one = self.one_row()
        out = f(one)
        if one is self:
            return out

        def spread(v):
            return np.broadcast_to(v, (self.n,) + np.shape(v)[1:])

        return {k: spread(v) for k, v in out.items()} if isinstance(out, dict) else spread(out)

    @property
    def dissipative(self) -> bool:
        """Some term turns mechanical energy into heat for some member."""
        return any(t.dissipates(self) for t in registry())

    def acting(self) -> dict[str, np.ndarray]:
        """{term name: (N,) bool}: the terms acting on each member."""
        return {t.name: np.asarray(t.active(self), dtype=bool) for t in registry()}

    # the model's physics in plain numpy, summed over the terms (functions of this module)
    def torque(self, omega, gamma, sigma=None) -> np.ndarray:
        """Σ f(Ω, Γ) (N m) of every term, (N, ..., 3): :func:`torque`."""
        return torque(self, omega, gamma, sigma)

    def dissipated_power(self, omega, sigma=None) -> np.ndarray:
        """−Σ⟨f, Ω⟩ ≥ 0 (W) of the frictions, (N, ...): :func:`dissipated_power`."""
        return dissipated_power(self, omega, sigma)

    def mechanical_energy(self, K, V) -> np.ndarray:
        """K + V − min V ≥ 0 (J), the energy above rest: :func:`mechanical_energy`."""
        return mechanical_energy(self, K, V)

    def mechanical_energy_scale(self, omega0, gamma0) -> np.ndarray:
        """K₀ + V₀ − min V (N,) (J): :func:`mechanical_energy_scale`."""
        return mechanical_energy_scale(self, omega0, gamma0)

    def potential_span(self) -> np.ndarray:
        """max V − min V over all attitudes (J), (N,): :func:`potential_span`."""
        return potential_span(self)

    def resting_gamma(self) -> np.ndarray:
        """(N, 3) the Γ of least potential energy (the body at rest): :func:`resting_gamma`."""
        return resting_gamma(self)

    def linear_resistance(self) -> np.ndarray:
        """(N, 3) Σ diag C (N m s) of the frictions linear in Ω: :func:`linear_resistance`."""
        return linear_resistance(self)

    def with_linear_resistance(self, C) -> "Physics":
        """These members with the friction linear in Ω set to diag C (N, 3)
        (the term with :data:`~liethermo.top.kernels.terms.ROLE_LINEAR_FRICTION` takes it)."""
        from .kernels.terms import ROLE_LINEAR_FRICTION

        kw = {}
        for t in registry():
            if t.role == ROLE_LINEAR_FRICTION:
                kw.update(t.with_linear_resistance(self, C))
        return dataclasses.replace(self, **kw)

    def discrete_friction(self, h, x) -> np.ndarray:
        """The variational integrator's discrete friction at step velocities X: :func:`discrete_friction`."""
        return discrete_friction(self, h, x)

    def has_constant_inertia(self) -> np.ndarray:
        """(N,) bool: no term makes the member's inertia depend on S: :func:`has_constant_inertia`."""
        return has_constant_inertia(self)

    def breaking(self, law: str) -> list[str]:
        """Names of the terms that break the exact ``law`` on some member (:meth:`keeps`)."""
        return [t.name for t in registry() if not np.all(t.keeps(law, self))]

    def keeps(self, law: str) -> np.ndarray:
        """(N,) bool: the members on which every term leaves the exact ``law``
        of the motion valid (:data:`liethermo.top.kernels.terms.LAWS`)."""
        out = np.ones(self.n, dtype=bool)
        for t in registry():
            out &= t.keeps(law, self)
        return out


#: the body's own parameters; every term adds its own (:class:`~liethermo.top.kernels.terms.Parameter`)
_CORE_FIELDS = (
    ("inertia", "(N, 3) principal moments 𝕀₀ about the fixed point, kg m²"),
    ("center_of_mass", "(N, 3) G in the body frame, from the fixed point, m"),
    ("mass", "(N,) kg"),
    ("heat_capacity", "(N,) c_v, J K⁻¹"),
    ("T0", "(N,) K"),
    ("S0", "(N,) J K⁻¹"),
)


def _make_physics_class():
    fields = [(name, np.ndarray) for name, _ in _CORE_FIELDS]
    lines = [f"* ``{name}`` — {doc}" for name, doc in _CORE_FIELDS]
    for t in registry():
        for prm in t.parameters:
            fields.append((prm.name, object, dataclasses.field(default=None)))
            shape = ("one value" if prm.shape is None
                     else "(" + ", ".join(["N", *map(str, prm.shape)]) + ("," if not prm.shape else "") + ")")
            lines.append(f"* ``{prm.name}`` — {shape} {prm.unit} ({t.name}): {prm.long_name}"
                         + (f"; {prm.comment}" if prm.comment else ""))
    cls = dataclasses.make_dataclass("Physics", fields, bases=(_PhysicsBase,), frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = ("Physical parameters of N members (SI units, a leading member axis).  "
                   "The body's fields and those its terms declare (zero when not given):\n\n"
                   + "\n".join(lines))
    return cls


Physics = _make_physics_class()


# ----------------------------------------------------------------------------- bodies


@dataclass(frozen=True)
class Body:
    """One body, as a scene gives it: what the terms derive their parameters from."""

    shape: str
    mass: float
    inertia: np.ndarray  # (3,) principal moments about the fixed point, kg m²
    center_of_mass: np.ndarray  # (3,) G from the fixed point, m
    semi_axes: np.ndarray  # (3,) m (a sphere: three equal radii)
    sphere_radius: float | None  # the radius of a body that meets the fluid as a sphere


def _hemispheres(body: dict) -> Body:
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
    return Body("hemispheres", m, inertia, G, np.array([a, a, a]), a)


def _ellipsoid(body: dict) -> Body:
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
    return Body("ellipsoid", m, inertia, G, ax, None)


SHAPES = {"hemispheres": _hemispheres, "ellipsoid": _ellipsoid}


def body_of_scene(scene) -> Body:
    """The body a resolved scene describes."""
    return SHAPES[scene["body"]["shape"]](scene["body"])


def physics_of_scene(scene, members: int = 1) -> Physics:
    """The physics of a resolved scene, repeated for ``members`` members."""
    body = body_of_scene(scene)
    hc = scene["thermo"]["heat_capacity"]
    cv = 3.0 * (body.mass / float(scene["body"]["molar_mass"])) * R_GAS if isinstance(hc, str) else float(hc)
    kw = dict(inertia=body.inertia[None].astype(np.float64),
              center_of_mass=body.center_of_mass[None].astype(np.float64),
              mass=np.array([body.mass]), heat_capacity=np.array([cv]),
              T0=np.array([float(scene["thermo"]["T0"])]), S0=np.array([float(scene["thermo"]["S0"])]))
    for t in registry():
        shapes = {prm.name: prm.shape for prm in t.parameters}
        for name, value in t.parameters_of_scene(scene, body).items():
            kw[name] = value if shapes[name] is None else np.asarray(value, dtype=np.float64)[None]
    one = Physics(**kw)
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
        """Names of the kernel parts present, for labels and reports."""
        out = [type(self.model.inertia).__name__]
        if self.model.thermo is not None:
            out.append("IdealSolid")  # IdealSolidWide: the same physics, a wider polynomial
        out += [type(t).__name__ for t in self.model.forces]
        if self.model.attitude is not None:
            out.append("Attitude")
        return out


def _members_alike(phys: Physics) -> bool:
    """Do all members share every per-member parameter, bit for bit?"""
    N = phys.n
    if phys.uniform:
        return True
    for f in dataclasses.fields(phys):
        v = getattr(phys, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == N:
            b = np.ascontiguousarray(v).reshape(N, -1).view(np.uint8)
            if not (b == b[0]).all():
                return False
    return True


#: the kernel model last built for members that share one row: the chunks of a run
#: pass the same Physics object (``ResolvedRun.physics_for``), and get it again
_LAST_MODEL: list = []


def build_model(phys: Physics, attitude: bool = False, heat=None) -> KernelModel:
    """The kernels' model of an ensemble (:func:`_build_model`); for members sharing one
    row of parameters, the one built last for the same Physics object (its ``P`` is
    only read by the kernels)."""
    for p, a, q, km in list(_LAST_MODEL):
        if p is phys and a == attitude and q == heat:
            return km
    km = _build_model(phys, attitude, heat)
    if phys.n > 1 and phys.uniform:
        _LAST_MODEL[:] = [(phys, attitude, heat, km)]
    return km


def _build_model(phys: Physics, attitude: bool = False, heat=None) -> KernelModel:
    """The kernels' model of an ensemble: only the terms some member needs,
    in registry order.  ``heat``: an upper bound of the heat any member can
    produce (J; its initial mechanical energy above rest): where it could
    take σ/c_v beyond the cubic's range of 1/T, the ideal solid is evaluated
    with its wider polynomial (same physics, and still vectorized).

    Members that share every parameter bitwise (a scene's ensemble) get their
    model from one member, repeated: every coefficient is computed member by
    member, so the rows are the same bits, without the passes over N."""
    N = phys.n
    if N > 1 and _members_alike(phys):
        one = _build_model(phys.take(slice(0, 1)), attitude, heat)
        return KernelModel(one.model, np.repeat(one.P, N, axis=0), one.model)
    inertia = constant_inertia_part(phys)
    forces: list[tuple[type, np.ndarray]] = []
    for t in registry():
        for slot, cls, coef in t.kernel_parts(phys):
            if slot == "inertia":
                inertia = (cls, coef)
            else:
                forces.append((cls, coef))
    thermo = None
    if phys.dissipative:
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
    blocks = [inertia[1]] + ([thermo[1]] if thermo else []) + [f[1] for f in forces]
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

        ine = take(inertia[0])
        th = take(thermo[0]) if thermo else None
        fs = tuple(take(cls) for cls, _ in forces)
        att = take(type(ATTITUDE)) if attitude else None
        return Model(ine, th, fs, att)

    template = assemble(P[0] if N else np.zeros(P.shape[1]))
    assert len(gen.flatten(template)) == P.shape[1]
    bits = P.view(np.int64)
    shared = template if (N == 0 or bool((bits == bits[0]).all())) else None
    return KernelModel(template, P, shared)


# ----------------------------------------------------------------------------- energies (numpy)


def theta(phys: Physics, sigma: np.ndarray) -> np.ndarray:
    """θ(S) = U′(S) = T₀ exp(σ/c_v) in K, σ = S − S₀ (N, ...)."""
    return bcast(phys.T0, sigma) * np.exp(sigma / bcast(phys.heat_capacity, sigma))


def _expansion(phys: Physics, th: np.ndarray):
    """(φ, φ′) with 𝕀(S) = φ²𝕀₀ from the term that makes the inertia depend on S, or None."""
    for t in registry():
        out = t.expansion(phys, th)
        if out is not None:
            return out
    return None


def _entropy_sets_inertia(phys: Physics) -> bool:
    """Some term makes some member's inertia depend on S (only such a term gives
    :func:`_expansion`; without one, θ(S) need not be computed for it)."""
    return not bool(np.all(has_constant_inertia(phys.one_row())))


def inertia_scale(phys: Physics, sigma: np.ndarray | None) -> np.ndarray | float:
    """s(S) = φ² with 𝕀(S) = s 𝕀₀ (1 for a constant inertia)."""
    if sigma is None or not _entropy_sets_inertia(phys):
        return 1.0
    e = _expansion(phys, theta(phys, sigma))
    return 1.0 if e is None else e[0] ** 2


def node_velocity(phys: Physics, momentum: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    """Ω = 𝕀(S)⁻¹ μ (rad s⁻¹) for momenta (N, ..., 3)."""
    s = inertia_scale(phys, sigma)
    s = s[..., None] if isinstance(s, np.ndarray) else s
    return momentum / (bcast(phys.inertia, momentum) * s)


def kinetic_energy(phys: Physics, omega: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    """K = ½ Ω·𝕀(S)Ω in J."""
    s = inertia_scale(phys, sigma)
    return 0.5 * s * dot3(bcast(phys.inertia, omega), omega, omega)


def potential_energy(phys: Physics, gamma: np.ndarray) -> np.ndarray:
    """V(Γ) in J: the sum of the conservative terms' potentials."""
    V = np.zeros(gamma.shape[:-1])
    for t in registry():
        v = t.potential_energy(phys, gamma)
        if v is not None:
            V = V + v
    return V


def internal_energy_change(phys: Physics, sigma: np.ndarray) -> np.ndarray:
    """U(S) − U(S₀) = c_v T₀ expm1(σ/c_v) in J, without cancellation."""
    cv = bcast(phys.heat_capacity, sigma)
    return cv * bcast(phys.T0, sigma) * np.expm1(sigma / cv)


def entropy_of_heat(phys: Physics, heat: np.ndarray) -> np.ndarray:
    """σ = S − S₀ (J K⁻¹) of a body that absorbed ``heat`` = U − U₀ (J):
    c_v log1p(q/(c_v T₀)), the inverse of :func:`internal_energy_change`."""
    return _heat.entropy_of_heat(heat, bcast(phys.heat_capacity, heat), bcast(phys.T0, heat))


def temperature(phys: Physics, omega: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """T = −∂L/∂S in K: θ(S), less ½Ω·𝕀′(S)Ω = φφ′ Ω·𝕀₀Ω for an entropy-dependent inertia."""
    th = theta(phys, sigma)
    e = _expansion(phys, th)
    if e is None:
        return th
    phi, dphi = e
    return th - phi * dphi * dot3(bcast(phys.inertia, omega), omega, omega)


def torque(phys: Physics, omega: np.ndarray, gamma: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
    """Σ f(Ω, Γ) (N m): every term's torque, (N, ..., 3)."""
    s = inertia_scale(phys, sigma)
    f = np.zeros(np.broadcast_shapes(omega.shape, gamma.shape))
    for t in registry():
        ft = t.torque(phys, omega, gamma, s)
        if ft is not None:
            f = f + ft
    return f


def dissipated_power(phys: Physics, omega: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
    """−Σ⟨f_friction, Ω⟩ ≥ 0 (W), (N, ...)."""
    s = inertia_scale(phys, sigma)
    P = np.zeros(omega.shape[:-1])
    for t in registry():
        pt = t.dissipated_power(phys, omega, s)
        if pt is not None:
            P = P + pt
    return P


def potential_span(phys: Physics) -> np.ndarray:
    """max V − min V over all attitudes (J), per member (once for members that share a body)."""
    return phys.per_row(_potential_span)


def _potential_span(phys: Physics) -> np.ndarray:
    out = np.zeros(phys.n)
    for t in registry():
        out = out + t.potential_span(phys)
    return out


def mechanical_energy(phys: Physics, K: np.ndarray, V: np.ndarray) -> np.ndarray:
    """K + V − min V ≥ 0 (J): the mechanical energy above the resting state,
    from the kinetic and potential energies K, V (N, ...) of the members
    (min V = −½(max V − min V): every potential of the terms is odd in Γ)."""
    return K + V + bcast(0.5 * potential_span(phys), K)


def mechanical_energy_scale(phys: Physics, omega0: np.ndarray, gamma0: np.ndarray) -> np.ndarray:
    """K₀ + V₀ − min V (N,): the initial mechanical energy above the resting state,
    the energy friction can turn into heat (the natural scale of E_k − E₀)."""
    K0 = kinetic_energy(phys, omega0, None)
    V0 = potential_energy(phys, gamma0)
    return mechanical_energy(phys, K0, V0)


def resting_gamma(phys: Physics) -> np.ndarray:
    """(N, 3) the Γ at which V is least, from the one term with a potential
    (NaN where no term has one or, for a member, its potential is 0)."""
    for t in registry():
        with np.errstate(invalid="ignore", divide="ignore"):
            G = t.resting_gamma(phys)
        if G is not None:
            return G
    return np.full((phys.n, 3), np.nan)


def linear_resistance(phys: Physics) -> np.ndarray:
    """(N, 3) Σ diag C (N m s): the frictions −CΩ linear in Ω, in the body axes."""
    C = np.zeros((phys.n, 3))
    for t in registry():
        c = t.linear_resistance(phys)
        if c is not None:
            C = C + c
    return C


def discrete_friction(phys: Physics, h: float, x: np.ndarray) -> np.ndarray:
    """Σ of the variational integrator's discrete frictions at the step
    velocities X (N, ..., 3) of steps h (N m): Σ C X + Σ D(X).  Raises
    NotImplementedError where an acting friction does not give its discrete form."""
    F = np.zeros(x.shape)
    for t in registry():
        if not np.any(t.active(phys)):
            continue
        f = t.discrete_friction(phys, h, x)
        if f is not None:
            F = F + f
    return F


def has_constant_inertia(phys: Physics) -> np.ndarray:
    """(N,) bool: the members whose inertia no term makes depend on the entropy."""
    out = np.ones(phys.n, dtype=bool)
    for t in registry():
        if t.sets_inertia:
            out &= ~np.asarray(t.active(phys), dtype=bool)
    return out
