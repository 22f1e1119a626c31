"""Model terms: the physics a scene chooses, each term one module that owns all of it.

A term module (``stokes``, ``double_bracket``, …; the list is
:func:`_term_modules`) holds

* its kernel namedtuple(s): floats (its coefficients, computed once per
  member in Python) whose *class* is part of the numba type, with their
  implementations of the protocol functions below — numba picks each
  term's implementation at compile time; a term that has nothing to say to
  a protocol passes the accumulators through, and an absent term is not
  there at all;
* ``TERM``, an instance of a :class:`Term` subclass that declares the rest:
  its scene keys (:class:`Setting`), its per-member parameters and their
  dataset variables (:class:`Parameter`), how a scene gives them, which
  kernel parts it adds, the rules it sets on a scene, the methods it
  cannot run with, and its field, power and potential energy in plain numpy.

The layers above loop over :func:`registry` — the physics, the scene keys,
the dataset, ``liethermo keys`` and docs/scenes.md, the diagnostics and the
scipy baseline — and never name a term; solvers ask a term for a capability
(``CAPABILITIES`` on its kernel class, e.g. ``"entropy_dependent_inertia"``:
the entropy joins the variational integrator's Newton unknowns), not for its
class.  docs/model.md ("Adding a term") walks through one.

The kernels' model is a :class:`Model` namedtuple::

    Model(inertia, thermo, forces, attitude)

* ``inertia`` — exactly one inertia part: the constant 𝕀, or the part a
  term puts in its place (the coupled top's 𝕀(S));
* ``thermo`` — the internal energy U(S) of body and fluid, or None when
  nothing dissipates (the entropy then stays S₀ and is not integrated);
* ``forces`` — the force parts of the terms present, in registry order;
* ``attitude`` — :data:`ATTITUDE` when R is integrated, else None.

Protocol (lane functions; vectors are 3-tuples, ``w`` = (Ω₁, Ω₂, Ω₃), ``G``
= Γ, ``x`` the step velocity X, ``m`` = μ; the accumulators ``a``, ``c``,
``t``, ``f`` (3-tuples), ``J`` (a row-major 9-tuple) and ``p``, ``q``
(floats) hold None where no term has added anything yet, see
:func:`liethermo.top.kernels.gen.madd`; :data:`NONE3`, :data:`NONE9`):

``angular_acceleration(term, inertia, iscale, w, G, a) -> a``
    adds 𝕀₀⁻¹ f(Ω, Γ) (rad s⁻²): the term's force or torque over the
    reference inertia 𝕀₀; ``iscale`` is None (constant inertia) or the
    factor s with 𝕀(S) = s 𝕀₀.
``dissipated_power(term, inertia, iscale, w, p) -> p``
    adds −⟨f, Ω⟩ ≥ 0 (W): frictions only.
``discrete_power(term, inertia, h, x, p) -> p``
    adds the power −⟨D(X), X⟩ ≥ 0 of the variational integrator's discrete
    friction at the step velocity X (for a linear law, X·CX).
``linear_friction(term, c) -> c``
    adds the diagonal friction tensor C (N m s) of a friction linear in Ω
    (f = −CΩ); the variational integrator folds it into its Newton matrix.
``torque(term, G, t) -> t``
    adds the conservative torque τ(Γ) (N m).
``nonlinear_friction(term, inertia, h, x, f, J) -> (f, J)``
    adds the variational integrator's discrete friction D(X) of a nonlinear
    friction law, and its Jacobian ∂D/∂X (see the variational integrator).
``exact_flow(term, inertia, t, G, m, q) -> (m, q)``
    the exact flow over a time t of the sub-system with this term alone (Γ
    fixed): the new body momentum μ and the heat q (J) with the kinetic
    energy the flow dissipated added (the splitting integrators; a term
    with this flow declares the capability ``"exact_flow"``).

The inertia slot, when its part declares ``"entropy_dependent_inertia"``
(𝕀(S) = φ(S)² 𝕀₀), tells the solvers its law through these (``thermo`` the
model's internal energy, ``theta`` = θ(S) = U′(S)); the solvers never spell
φ out, so another law is another inertia part:

``inertia_scale(inertia, thermo, theta) -> φ``
    the factor φ(S) of the moments (1 for a constant inertia);
``inertia_scale_rate(inertia, thermo, theta) -> φ′``
    its derivative dφ/dS (1/(J K⁻¹));
``scale_square_change(inertia, thermo, theta, e) -> φ(S')² − φ(S)²``
    over a step from θ(S) to θ(S') = θ(S)(1 + e), without cancellation;
``temperature_correction(inertia, thermo, theta, K2) -> φφ′ K2``
    what the temperature T = −∂L/∂S lies below θ(S) at Ω·𝕀₀Ω = ``K2``
    (½ Ω·𝕀′(S)Ω).
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass
from typing import Any

import numpy as np

from numba import types

from ..dispatch import generic, is_nonempty, term_class

Model = namedtuple("Model", "inertia thermo forces attitude")


class Attitude(namedtuple("Attitude", "on")):
    """Marker: the attitude R is integrated (its one field is unused)."""

    __slots__ = ()


#: the ``attitude`` slot of a model that integrates R
ATTITUDE = Attitude(1.0)

# ----------------------------------------------------------------------------- the protocol
# Each protocol function is a generic keyed by the term's class; its body is
# what a term that has nothing to say returns (its accumulators).  A term
# module registers its implementation with ``@torque.register(Gravity)``.


@generic(term_class)
def angular_acceleration(term, inertia, iscale, w, G, a):
    """a + 𝕀₀⁻¹ f(Ω, Γ) (rad s⁻²): the term's force or torque over the reference inertia."""
    return a


@generic(term_class)
def dissipated_power(term, inertia, iscale, w, p):
    """p − ⟨f, Ω⟩ (W): frictions only."""
    return p


@generic(term_class)
def discrete_power(term, inertia, h, x, p):
    """p − ⟨D(X), X⟩ (W): the variational integrator's discrete friction at X."""
    return p


@generic(term_class)
def linear_friction(term, c):
    """c + the diagonal friction tensor C (N m s) of a friction linear in Ω."""
    return c


@generic(term_class)
def torque(term, G, t):
    """t + the conservative torque τ(Γ) (N m)."""
    return t


@generic(term_class)
def exact_flow(term, inertia, t, G, m, q):
    """(μ, q) after the exact flow over a time t of the term alone (Γ fixed)."""
    return m, q


@generic(term_class)
def nonlinear_friction(term, inertia, h, x, f, J):
    """(f + D(X), J + ∂D/∂X) of a nonlinear friction law."""
    return f, J


@generic(term_class)
def inertia_scale(term, thermo, theta):
    """φ(S) of the inertia part ``term`` (1 for a constant inertia)."""
    return 1.0


@generic(term_class)
def inertia_scale_rate(term, thermo, theta):
    """dφ/dS (1/(J K⁻¹)) of the inertia part ``term``."""
    return 0.0


@generic(term_class)
def scale_square_change(term, thermo, theta, e):
    """φ(S')² − φ(S)² over a step from θ(S) to θ(S)(1 + e)."""
    return 0.0


@generic(term_class)
def temperature_correction(term, thermo, theta, K2):
    """φφ′ K2: what T lies below θ(S) at Ω·𝕀₀Ω = K2."""
    return 0.0


# ----------------------------------------------------------------------------- folds over the terms
# A fold applies a protocol to every term of a tuple in order (the flows also
# last to first), threading the accumulators; the non-empty implementation
# handles the first term and folds the rest.


@generic(is_nonempty)
def sum_angular_acceleration(terms, inertia, iscale, w, G, a):
    """:func:`angular_acceleration` summed over ``terms``."""
    return a


@sum_angular_acceleration.register(True)
def sum_angular_acceleration_terms(terms, inertia, iscale, w, G, a):
    return sum_angular_acceleration(terms[1:], inertia, iscale, w, G,
                                    angular_acceleration(terms[0], inertia, iscale, w, G, a))


@generic(is_nonempty)
def sum_dissipated_power(terms, inertia, iscale, w, p):
    """:func:`dissipated_power` summed over ``terms``."""
    return p


@sum_dissipated_power.register(True)
def sum_dissipated_power_terms(terms, inertia, iscale, w, p):
    return sum_dissipated_power(terms[1:], inertia, iscale, w, dissipated_power(terms[0], inertia, iscale, w, p))


@generic(is_nonempty)
def sum_discrete_power(terms, inertia, h, x, p):
    """:func:`discrete_power` summed over ``terms``."""
    return p


@sum_discrete_power.register(True)
def sum_discrete_power_terms(terms, inertia, h, x, p):
    return sum_discrete_power(terms[1:], inertia, h, x, discrete_power(terms[0], inertia, h, x, p))


@generic(is_nonempty)
def sum_linear_friction(terms, c):
    """:func:`linear_friction` summed over ``terms``."""
    return c


@sum_linear_friction.register(True)
def sum_linear_friction_terms(terms, c):
    return sum_linear_friction(terms[1:], linear_friction(terms[0], c))


@generic(is_nonempty)
def sum_torque(terms, G, t):
    """:func:`torque` summed over ``terms``."""
    return t


@sum_torque.register(True)
def sum_torque_terms(terms, G, t):
    return sum_torque(terms[1:], G, torque(terms[0], G, t))


@generic(is_nonempty)
def sum_nonlinear_friction(terms, inertia, h, x, f, J):
    """:func:`nonlinear_friction` summed over ``terms``."""
    return f, J


@sum_nonlinear_friction.register(True)
def sum_nonlinear_friction_terms(terms, inertia, h, x, f, J):
    f1, J1 = nonlinear_friction(terms[0], inertia, h, x, f, J)
    return sum_nonlinear_friction(terms[1:], inertia, h, x, f1, J1)


@generic(is_nonempty)
def flow_forward(terms, inertia, t, G, m, q):
    """The terms' exact flows one after the other, in registry order."""
    return m, q


@flow_forward.register(True)
def flow_forward_terms(terms, inertia, t, G, m, q):
    m1, q1 = exact_flow(terms[0], inertia, t, G, m, q)
    return flow_forward(terms[1:], inertia, t, G, m1, q1)


@generic(is_nonempty)
def flow_backward(terms, inertia, t, G, m, q):
    """The terms' exact flows one after the other, last to first."""
    return m, q


@flow_backward.register(True)
def flow_backward_terms(terms, inertia, t, G, m, q):
    m1, q1 = exact_flow(terms[-1], inertia, t, G, m, q)
    return flow_backward(terms[:-1], inertia, t, G, m1, q1)


#: accumulators that no term has touched yet (a term adds to None as to nothing)
NONE3 = (None, None, None)
NONE9 = (None,) * 9



# ----------------------------------------------------------------------------- what a term declares

#: exact laws of the continuous motion that a run's summary checks
#: (:mod:`liethermo.top.findings`); each term says on which members it leaves a
#: law valid (:meth:`Term.keeps`), so the summary never names a term:
#:
#: * ``LAW_SPHERICAL_DECAY`` — for a spherical top (𝕀₀ = I₀·Id) the term's
#:   torque at Ω is −cΩ with one c for every axis, or 0 whenever μ ∥ Ω:
#:   then μ ∥ Ω for ever and Ω(t) = Ω₀e^{−ct/I₀};
#: * ``LAW_LAGRANGE_OMEGA3`` — for I₁ = I₂ the term adds −C₃Ω₃ or nothing to
#:   the third component of the torque: Ω₃(t) = Ω₃(0)e^{−C₃t/I₃};
#: * ``LAW_MOMENTUM_NORM`` — the term's torque is ⟂ μ (or it exerts none):
#:   |μ| is conserved.
LAW_SPHERICAL_DECAY = "spherical_decay"
LAW_LAGRANGE_OMEGA3 = "lagrange_omega3"
LAW_MOMENTUM_NORM = "momentum_norm"
LAWS = (LAW_SPHERICAL_DECAY, LAW_LAGRANGE_OMEGA3, LAW_MOMENTUM_NORM)

#: what a term's one scene key sets, for the layers (the studies) that vary or
#: check a kind of physics without naming the term that has it
#: (:func:`key_of`, :attr:`Term.role`):
#:
#: * ``ROLE_LINEAR_FRICTION`` — the strength of the friction linear in Ω (−CΩ);
#: * ``ROLE_MOMENTUM_FRICTION`` — the strength of a friction that keeps |μ|;
#: * ``ROLE_THERMAL_COUPLING`` — how the inertia grows with the temperature;
#: * ``ROLE_POTENTIAL`` — the strength of the conservative torque.
ROLE_LINEAR_FRICTION = "linear_friction"
ROLE_MOMENTUM_FRICTION = "momentum_friction"
ROLE_THERMAL_COUPLING = "thermal_coupling"
ROLE_POTENTIAL = "potential"
ROLES = (ROLE_LINEAR_FRICTION, ROLE_MOMENTUM_FRICTION, ROLE_THERMAL_COUPLING, ROLE_POTENTIAL)


@dataclass(frozen=True)
class Setting:
    """A scene key a term owns: a number ≥ ``minimum`` (> with ``open``), or
    the string ``word`` standing for a value the term works out itself."""

    section: str
    name: str
    default: Any
    unit: str
    doc: str
    minimum: float = 0.0
    open: bool = False
    word: str | None = None

    @property
    def path(self) -> str:
        return f"{self.section}.{self.name}"

    @property
    def rule(self) -> str:
        bound = f"{'>' if self.open else '≥'} {self.minimum:g}"
        return f'"{self.word}" | {bound}' if self.word else bound


@dataclass(frozen=True)
class Parameter:
    """A per-member physical parameter a term adds to the physics: an array
    of ``shape`` per member (a :class:`~liethermo.top.physics.Physics` field of
    that name, zero by default), or, with ``shape=None``, one value for the
    whole ensemble (``default``).  ``variable``: the name of its dataset
    variable ("" for none); ``always``: written even when every member has
    zero (else only when some member has it).  ``long_name``: short enough for
    an axis label; ``comment``: its formula or detail (the variable's
    ``comment`` attribute)."""

    name: str
    shape: tuple | None
    unit: str
    long_name: str
    variable: str | None = None
    always: bool = False
    default: Any = None
    comment: str = ""

    @property
    def variable_name(self) -> str:
        return self.name if self.variable is None else self.variable


class Term:
    """A physical term of the model and everything it owns.

    A term module defines its kernel namedtuple(s) with their protocol
    implementations (above) and one instance of a :class:`Term` subclass
    named ``TERM``, listed in :data:`REGISTRY`.  The layers above loop over
    the registry and never name a term: the scene keys (``settings``), the
    per-member parameters and dataset variables (``parameters``), the
    parameters of a scene (:meth:`parameters_of_scene`), the kernel parts
    (:meth:`kernel_parts`), the rules a scene must keep
    (:meth:`violations`), which methods it cannot run with
    (:meth:`refuses`), and its continuous field and energies in plain numpy
    (:meth:`torque`, :meth:`dissipated_power`, :meth:`potential_energy`),
    used by the diagnostics and the scipy baseline."""

    #: registry name (in messages and in Physics.acting)
    name: str = ""
    settings: tuple[Setting, ...] = ()
    parameters: tuple[Parameter, ...] = ()
    #: one paragraph of docs/scenes.md ("Choosing a model")
    scene_doc: str = ""
    #: a friction (it dissipates); ``nonlinear_friction``: its discrete form
    #: is not linear in the step velocity (the variational integrator adds it
    #: to its Newton residual and Jacobian through ``nonlinear_friction``)
    friction: bool = False
    nonlinear_friction: bool = False
    #: why the term has no exact flow (None: it has one): the splitting
    #: methods, which compose exact flows, refuse it with this reason
    no_exact_flow: str | None = None
    #: the term makes the inertia depend on the entropy where it acts
    sets_inertia: bool = False
    #: what its first scene key sets (one of :data:`ROLES`, or None): :func:`key_of`
    role: str | None = None

    def in_scene(self, s: dict) -> bool:
        """Whether the scene tables ``s`` switch the term on."""
        return False

    def parameters_of_scene(self, scene, body) -> dict:
        """This term's parameters of one member, from a resolved ``scene``
        and its ``body`` (:class:`~liethermo.top.physics.Body`)."""
        return {}

    def active(self, phys) -> np.ndarray:
        """(N,) bool: the members on which the term acts."""
        return np.zeros(phys.n, dtype=bool)

    def dissipates(self, phys) -> bool:
        """Whether the term turns mechanical energy into heat for some member."""
        return False

    def kernel_parts(self, phys) -> list:
        """[(slot, class, coefficients (N, k))]: what the kernels' model gets,
        none when no member needs the term.  ``slot`` is "inertia" (the term
        replaces the constant inertia) or "forces"."""
        return []

    def violations(self, s: dict):
        """Yield (key, rule, value) for every rule the scene tables ``s``
        break because of this term."""
        return ()

    def start_problem(self, scene, phys, kin2: float, what: str) -> tuple[str, str] | None:
        """(key, why) when some member of ``scene`` cannot start (its initial
        state breaks a law the term needs), None when all can; ``kin2``
        bounds Ω·𝕀₀Ω over the members, ``what`` says how (for the message)."""
        return None

    def vi_refusal(self, start: str, friction: str) -> tuple[str, str] | None:
        """(key, why) when the variational integrator cannot run this term's
        model, where it acts and something rubs, from the effective ``start``
        or with the effective ``friction``; None when it can.  The one
        statement of that rule: the scene's checks and
        :func:`liethermo.top.simulate.simulate` both ask it."""
        return None

    def expansion(self, phys, theta) -> tuple[np.ndarray, np.ndarray] | None:
        """(φ, φ′) with 𝕀(S) = φ²𝕀₀ at θ(S) (N, ...), in plain numpy, for a
        term that makes the inertia depend on the entropy; None otherwise."""
        return None

    def refuses(self, method) -> str | None:
        """Why ``method`` (a :class:`liethermo.top.methods.Method`) cannot run a
        model with this term (None: it can)."""
        if method.needs_exact_flows and self.no_exact_flow:
            return f"{self.no_exact_flow}; the vi and rk methods run it"
        return None

    # ---- plain numpy, (N, ..., 3) arrays with a leading member axis
    def torque(self, phys, omega, gamma, scale) -> np.ndarray | None:
        """The term's torque f(Ω, Γ) (N m); ``scale``: s of 𝕀(S) = s𝕀₀ (or 1)."""
        return None

    def linear_resistance(self, phys) -> np.ndarray | None:
        """(N, 3) diag C (N m s) of a friction −CΩ linear in Ω, in the body
        axes; None for a term that is not one."""
        return None

    def with_linear_resistance(self, phys, C) -> dict:
        """The fields of ``phys`` to replace so that the term's friction −CΩ
        linear in Ω has diag C (N, 3) (its shape kept); {} for a term that has none."""
        return {}

    def discrete_friction(self, phys, h, x) -> np.ndarray | None:
        """The variational integrator's discrete friction at the step velocity
        X (N, ..., 3) of a step h, in plain numpy (N m): C X for a linear law,
        D(X) (``nonlinear_friction``) otherwise; None for a term that exerts
        no friction.  A friction that does not give it here raises
        NotImplementedError (its discrete laws cannot be checked)."""
        if self.friction:
            raise NotImplementedError(f"term {self.name!r} does not give its discrete friction")
        return None

    def dissipated_power(self, phys, omega, scale) -> np.ndarray | None:
        """−⟨f, Ω⟩ ≥ 0 (W) of a friction."""
        return None

    def potential_energy(self, phys, gamma) -> np.ndarray | None:
        """V(Γ) (J) of a conservative torque."""
        return None

    def resting_gamma(self, phys) -> np.ndarray | None:
        """(N, 3) the Γ at which the term's potential is least (its resting
        attitude), None for a term without a potential."""
        return None

    def potential_span(self, phys) -> np.ndarray | float:
        """max V − min V over all attitudes (J), per member."""
        return 0.0

    def rate_bound(self, phys, omega_max) -> np.ndarray | float:
        """A bound (rad s⁻¹) on the rate the term adds to the motion at |Ω| ≤ ``omega_max``."""
        return 0.0

    # ---- what a run's summary says
    def keeps(self, law: str, phys) -> np.ndarray:
        """(N,) bool: the members on which the term leaves the exact ``law``
        (one of :data:`LAWS`) valid; by default those on which it does not act."""
        if law not in LAWS:
            raise ValueError(f"unknown law {law!r}: expected one of {list(LAWS)}")
        return ~np.asarray(self.active(phys), dtype=bool)

    def summary_lines(self, phys) -> list[str]:
        """Lines of a run's summary on what the term's parameters set (member 0's)."""
        return []


class ScalarTerm(Term):
    """A term with one number per member, the value of its one scene key (a
    ``Parameter`` of shape ()): it acts where that number is not 0, and as a
    force adds ``kernel_class`` with ``coefficients(value, 𝕀₀)``."""

    kernel_class: type | None = None
    coefficients = None

    @property
    def _key(self) -> Setting:
        return self.settings[0]

    @property
    def _param(self) -> str:
        return self.parameters[0].name

    def parameters_of_scene(self, scene, body) -> dict:
        return {self._param: np.float64(scene[self._key.section][self._key.name])}

    def in_scene(self, s: dict) -> bool:
        return s[self._key.section][self._key.name] > 0

    def active(self, phys) -> np.ndarray:
        return getattr(phys, self._param) != 0.0

    def dissipates(self, phys) -> bool:
        return self.friction and bool(np.any(self.active(phys)))

    def kernel_parts(self, phys) -> list:
        if not np.any(self.active(phys)):
            return []
        return [("forces", self.kernel_class, type(self).coefficients(getattr(phys, self._param), phys.inertia))]


def over_inertia(c: np.ndarray, inertia0: np.ndarray, width: int) -> np.ndarray:
    """(N, width + 3) coefficients [c, c/I_i] of a friction c (N, width; width
    1 for a scalar, 3 per axis) over the reference moments 𝕀₀ (N, 3)."""
    c = np.asarray(c, dtype=np.float64).reshape(-1, width)
    return np.hstack([c, c * (1.0 / np.asarray(inertia0, dtype=np.float64).reshape(-1, 3))])


def bcast(a: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Per-member values a (N, ...) broadcast against arrays (N, T, ..., 3) or (N, T, ...)."""
    extra = like.ndim - a.ndim
    return a.reshape(a.shape[:1] + (1,) * extra + a.shape[1:])


def sum3(x: np.ndarray) -> np.ndarray:
    """``np.sum(x, axis=-1)`` of a fresh array x (..., 3), bit for bit: numpy adds
    (x₀ + x₁) + x₂ onto 0 (so −0 sums to +0), here without its slow reduction
    over a short axis."""
    out = x[..., 0] + x[..., 1]
    out += x[..., 2]
    out += 0.0
    return out


def norm3(x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` of real vectors x (..., 3), bit for bit (numpy's
    is the square root of the reduced x·x)."""
    return np.sqrt(dot3(x, x))


#: below this many vectors :func:`dot3` stays in numpy (calling the compiled pass costs more)
DOT3_COMPILED_MIN = 256


def dot3(a: np.ndarray, b: np.ndarray, c: np.ndarray | None = None) -> np.ndarray:
    """``sum3(a * b)`` or ``sum3(a * b * c)`` of float arrays (..., 3) that broadcast
    together, bit for bit, in one pass without temporaries
    (:func:`liethermo.top.kernels.reductions.dot3_rows`) where they have two or three
    dimensions and enough vectors; numpy's expression otherwise."""
    from ..reductions import dot3_rows

    arrays = (a, b) if c is None else (a, b, c)
    shape = np.broadcast_shapes(*(x.shape for x in arrays))
    if (len(shape) not in (2, 3) or shape[-1] != 3 or int(np.prod(shape[:-1])) < DOT3_COMPILED_MIN
            or any(x.dtype != np.float64 for x in arrays) or not hasattr(dot3_rows, "overloads")):
        return sum3(a * b) if c is None else sum3(a * b * c)
    full = shape if len(shape) == 3 else (shape[0], 1, 3)
    views = [np.broadcast_to(x.reshape(x.shape[:1] + (1, 3)) if len(shape) == 2 and x.ndim == 2 else x, full)
             for x in arrays]
    if c is None:
        views.append(np.broadcast_to(np.ones(1), full))
    out = np.empty(full[:2])
    dot3_rows(*views, out)
    return out if len(shape) == 3 else out[:, 0]


def _term_modules():
    """The term modules, frictions before conservative torques: the one place
    that names them (adding a term is adding its module here)."""
    from . import double_bracket, gravity, inertia, quadratic_drag, stokes

    return (inertia, stokes, double_bracket, quadratic_drag, gravity)


class Registry(tuple):
    """The terms, in the order the kernels add them."""


def constant_inertia_part(phys) -> tuple:
    """(class, coefficients) of the inertia slot when no term takes it: 𝕀 = 𝕀₀."""
    from .inertia import ConstantInertia, constant_coefficients

    return ConstantInertia, constant_coefficients(phys.inertia)


_REGISTRY: list = []


def key_of(role: str) -> str:
    """The scene key (``section.name``) of the one term whose :attr:`Term.role` is ``role``."""
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}: expected one of {list(ROLES)}")
    keys = [t.settings[0].path for t in registry() if t.role == role]
    if len(keys) != 1:
        raise ValueError(f"role {role!r}: {len(keys)} terms have it, expected one")
    return keys[0]


def registry() -> Registry:
    """Every model term (the ``TERM`` of each module :func:`_term_modules` lists)."""
    if not _REGISTRY:
        _REGISTRY.append(Registry(m.TERM for m in _term_modules()))
    return _REGISTRY[0]


__all__ = ["Model", "ATTITUDE", "Attitude", "angular_acceleration", "dissipated_power",
           "discrete_power", "linear_friction", "torque", "nonlinear_friction", "exact_flow",
           "inertia_scale", "inertia_scale_rate", "scale_square_change", "temperature_correction", "types", "NONE3", "NONE9", "LAWS", "LAW_SPHERICAL_DECAY", "LAW_LAGRANGE_OMEGA3", "LAW_MOMENTUM_NORM", "ROLES", "ROLE_LINEAR_FRICTION",
           "ROLE_MOMENTUM_FRICTION", "ROLE_THERMAL_COUPLING", "ROLE_POTENTIAL", "key_of", "Term", "ScalarTerm", "Setting", "Parameter", "Registry", "registry", "bcast", "over_inertia"]
