"""Model terms: the physics a scene chooses, as numba-compiled lane functions.

A model is a :class:`Model` namedtuple::

    Model(inertia, thermo, forces, attitude)

* ``inertia`` — exactly one inertia term: :class:`~.inertia.ConstantInertia`
  (𝕀 fixed) or :class:`~.inertia.ThermalInertia` (𝕀(S), the entropy feeds
  back into the motion);
* ``thermo`` — the internal energy U(S) of body and fluid
  (:class:`~.thermo.IdealSolid`), or None when nothing dissipates (the
  entropy then stays S₀ and is not integrated);
* ``forces`` — a tuple of force terms, frictions first, then conservative
  torques: :class:`~.stokes.StokesSphere`, :class:`~.stokes.StokesDiagonal`,
  :class:`~.double_bracket.DoubleBracket`, :class:`~.gravity.Gravity`;
* ``attitude`` — :data:`ATTITUDE` when R is integrated, else None.

Each term is a namedtuple of floats (its coefficients, computed once per
member in Python by the term module's ``coefficients``) whose *class* is part
of the numba type: the solvers call the protocol functions below, and numba
picks each term's implementation at compile time; a term that has nothing to
say to a protocol passes the accumulators through, an absent term is not
there at all.  A new friction law is one module with its namedtuple and its
implementations of the protocol, added to :func:`liethermo.physics.build_model`.

Protocol (all lane functions on floats; ``a``, ``p``, ``c``, ``t`` are
accumulators that start as None, see :func:`liethermo.kernels.gen.madd`):

``angular_acceleration(term, inertia, iscale, w0, w1, w2, G0, G1, G2, a0, a1, a2)``
    adds 𝕀₀⁻¹ f(Ω, Γ) (rad s⁻²): the term's force or torque over the
    reference inertia 𝕀₀; ``iscale`` is None (constant inertia) or the
    factor s with 𝕀(S) = s 𝕀₀.
``dissipated_power(term, inertia, iscale, w0, w1, w2, p)``
    adds −⟨f, Ω⟩ ≥ 0 (W): frictions only.
``discrete_power(term, inertia, h, x0, x1, x2, p)``
    adds the power −⟨D(X), X⟩ ≥ 0 of the variational integrator's discrete
    friction at the step velocity X (for a linear law, X·CX).
``linear_friction(term, c0, c1, c2)``
    adds the diagonal friction tensor C (N m s) of a friction linear in Ω
    (f = −CΩ); the variational integrator folds it into its Newton matrix.
``torque(term, G0, G1, G2, t0, t1, t2)``
    adds the conservative torque τ(Γ) (N m).
``nonlinear_friction(term, inertia, h, x0, x1, x2, f0, f1, f2, j00, …, j22)``
    adds the variational integrator's discrete friction D(X) of a nonlinear
    friction law, and its Jacobian ∂D/∂X (see the variational integrator).
"""

from __future__ import annotations

from collections import namedtuple

from numba import types
from numba.extending import overload

from .._jit import LANE_OPTIONS
from ..gen import compile_source, is_none, make_fold

Model = namedtuple("Model", "inertia thermo forces attitude")


class Attitude(namedtuple("Attitude", "on")):
    """Marker: the attitude R is integrated (its one field is unused)."""

    __slots__ = ()


#: the ``attitude`` slot of a model that integrates R
ATTITUDE = Attitude(1.0)

_PROTOCOLS: dict[str, tuple] = {}
#: (protocol name, term class) → implementation: what numba compiles, and what
#: plain Python (NUMBA_DISABLE_JIT=1) calls
_IMPLEMENTATIONS: dict[tuple[str, type], object] = {}


def _protocol(name: str, args: str, passthrough: str):
    """Declare a protocol function with the given argument list; terms that
    do not implement it return ``passthrough`` (their accumulators)."""
    ns: dict = {"_IMPLEMENTATIONS": _IMPLEMENTATIONS}
    fn = compile_source(f"def {name}({args}):\n"
                        f"    impl = _IMPLEMENTATIONS.get(({name!r}, type(term)))\n"
                        f"    if impl is None:\n"
                        f"        return {passthrough}\n"
                        f"    return impl({args})\n", ns, name, f"protocol {name}")
    _PROTOCOLS[name] = (fn, args)

    def typer(term, *rest):
        cls = getattr(term, "instance_class", None)
        if is_none(term) or name not in getattr(cls, "ROLES", frozenset()):
            return compile_source(f"def impl({args}):\n    return {passthrough}\n", {},
                                  label=f"protocol {name} passthrough for {getattr(cls, '__name__', 'None')}")
        return None

    tns = {"typer": typer}
    overload(fn, jit_options=LANE_OPTIONS)(
        compile_source(f"def _typer({args}):\n    return typer({args})\n", tns, "_typer",
                       f"protocol {name} typer"))
    return fn


angular_acceleration = _protocol(
    "angular_acceleration", "term, inertia, iscale, w0, w1, w2, G0, G1, G2, a0, a1, a2",
    "a0, a1, a2")
dissipated_power = _protocol("dissipated_power", "term, inertia, iscale, w0, w1, w2, p", "p")
discrete_power = _protocol("discrete_power", "term, inertia, h, x0, x1, x2, p", "p")
linear_friction = _protocol("linear_friction", "term, c0, c1, c2", "c0, c1, c2")
torque = _protocol("torque", "term, G0, G1, G2, t0, t1, t2", "t0, t1, t2")
nonlinear_friction = _protocol(
    "nonlinear_friction",
    "term, inertia, h, x0, x1, x2, f0, f1, f2, j00, j01, j02, j10, j11, j12, j20, j21, j22",
    "f0, f1, f2, j00, j01, j02, j10, j11, j12, j20, j21, j22")


def implements(protocol, cls):
    """Register ``impl`` (a function with the protocol's arguments) as the
    implementation of ``protocol`` for terms of class ``cls``."""
    fn, args = _PROTOCOLS[protocol.__name__]
    cls.ROLES = frozenset(getattr(cls, "ROLES", frozenset())) | {protocol.__name__}

    def deco(impl):
        _IMPLEMENTATIONS[(protocol.__name__, cls)] = impl

        def typer(term, *rest):
            if getattr(term, "instance_class", None) is cls:
                return impl
            return None

        tns = {"typer": typer}
        overload(fn, jit_options=LANE_OPTIONS)(
            compile_source(f"def _typer({args}):\n    return typer({args})\n", tns, "_typer",
                           f"protocol {protocol.__name__} typer for {cls.__name__}"))
        return impl

    return deco


#: folds of the force protocols over a tuple of terms
sum_angular_acceleration = make_fold(angular_acceleration, 8, 3, "sum_angular_acceleration")
sum_dissipated_power = make_fold(dissipated_power, 5, 1, "sum_dissipated_power")
sum_discrete_power = make_fold(discrete_power, 5, 1, "sum_discrete_power")
sum_linear_friction = make_fold(linear_friction, 0, 3, "sum_linear_friction")
sum_torque = make_fold(torque, 3, 3, "sum_torque")
sum_nonlinear_friction = make_fold(nonlinear_friction, 5, 12, "sum_nonlinear_friction")



__all__ = ["Model", "ATTITUDE", "Attitude", "angular_acceleration", "dissipated_power",
           "discrete_power", "linear_friction", "torque", "nonlinear_friction", "implements", "types"]
