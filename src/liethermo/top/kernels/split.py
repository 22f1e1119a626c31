"""Explicit thermodynamic splitting: a step is the composition of the terms' flows.

A splitting method is data (like an RK tableau, :mod:`.rk`): the factors
f_k of its symmetric composition, held on a marker class whose *type* the
kernels are compiled for.  One Strang step of size t is, in time order,

    E_{t/2}  ∘  T_t  ∘  E_{t/2}ᵀ,

where E runs the exact flows of the model's force terms one after the
other in registry order (frictions first: F, the friction and its heat;
then the conservative torques: V, the gravity kick) and back in reverse,
and T is the free rotation T¹_{t/2} T²_{t/2} T³_t T²_{t/2} T¹_{t/2}
(:func:`.terms.inertia.free_flow_stage`, Cayley rotations: five divisions).  The
step of size h composes Strang steps of sizes f_k h.  The force flows are the
exact flows of their sub-systems; the free rotations are the implicit
midpoint rule on theirs (a Cayley rotation, the exact flow of a modified
kinetic energy), symmetric like the exact flows, so the Strang step is
symmetric and its compositions reach orders 4 and 6.  The step keeps |Γ|
and RᵀR = I to round-off, is a Poisson map without friction, and moves the
heat exactly:
the friction flow takes kinetic energy ΔK and the step adds the sum of
the ΔK of its flows to the heat absorbed since the start, q = U − U₀ (a
small number, never T or U, whose size would swamp it).

The state is the ``split`` layout's (μ, Γ, q, R), what the flows move: a
step neither divides by 𝕀 nor turns heat into entropy; Ω = 𝕀⁻¹μ and
S = S(U₀ + q) are worked out at output.  The step is five stages per Strang
step (:func:`split_stage`); the one-member kernel runs them one after the
other (:func:`.rk.explicit_step`), the block kernel each over its lanes in
turn, with the same bits.

Terms without such a flow (capability ``"exact_flow"``) cannot be split:
a scene with one is refused before any work.
"""

from __future__ import annotations

import functools
from collections import namedtuple

from numba.extending import overload

from ._jit import LANE_OPTIONS, lane
from .dispatch import generic, has_capability, is_present
from .gen import compile_source
from .so3 import norm2_lane
from .terms import flow_backward, flow_forward
from .terms.inertia import FREE_FLOW_STAGES, free_flow_stage


class Splitting(tuple):
    """Base of the splitting marker classes; the class attributes are the data."""

    __slots__ = ()
    factors: tuple = ()
    order: int = 0


@functools.cache
def splitting(factors: tuple, order: int):
    """The marker instance of the symmetric composition of Strang steps with
    these factors (a class per distinct composition, cached).  The class name
    carries a digest of the factors: numba tells marker types apart, in memory
    and in its on-disk cache, by their names, and two compositions of the same
    length and order (Kahan–Li's and the double triple jump) must not share a
    kernel."""
    import hashlib

    factors = tuple(float(f) for f in factors)
    digest = hashlib.sha1(repr(factors).encode()).hexdigest()[:10]
    name = f"Splitting{len(factors)}o{order}x{digest}"
    cls = type(name, (namedtuple(name, "unused"), Splitting),
               {"__slots__": (), "factors": tuple(float(f) for f in factors), "order": int(order)})
    # a module attribute, so that pickle (numba's cache index) stores the class by
    # reference: pickled by value, it would come back as a new class whose numba
    # type equals no type in memory, and every process would compile the kernel again
    globals()[name] = cls
    return cls(0.0)


def __getattr__(name: str):
    """A splitting marker class by name, for unpickling a kernel cache index in a
    process that has not built it yet: every marker a splitting method can take is
    built on first request — the Strang step (order 2) and each composition of
    :data:`liethermo.numerics.compositions.COMPOSITION_FACTORS` with its order (what
    ``SplittingMethod.kernel_tableau`` passes to :func:`splitting`)."""
    if name.startswith("Splitting"):
        from ...numerics.compositions import COMPOSITION_FACTORS

        splitting((1.0,), 2)
        for (_, order), factors in COMPOSITION_FACTORS.items():
            splitting(factors, order)
        if name in globals():
            return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def splitting_class(t):
    """The marker class of a splitting marker's numba type, else None."""
    cls = getattr(t, "instance_class", None)
    return cls if isinstance(cls, type) and issubclass(cls, Splitting) and cls.factors else None


def can_split(model) -> str | None:
    """None if every part of the model has an exact flow, else the name of
    the first kernel part that has none."""
    parts = (model.inertia,) + tuple(model.forces)
    for part in parts:
        if not has_capability(part, "exact_flow"):
            return type(part).__name__
    return None


@lane
def split_begin(model, y):
    """The work state z = (μ, Γ, q, R) of a step from the ``split`` layout
    state y = (μ, Γ, q₀, R): the heat of the step starts at 0."""
    m, G, q0, R = y
    return m, G, 0.0, R


@lane
def split_speed2(model, y):
    """|Ω|² of the ``split`` layout state y (Ω = 𝕀⁻¹μ; the statistic max h|Ω|)."""
    m = y[0]
    I = model.inertia
    return norm2_lane(m[0] * I.iI1, m[1] * I.iI2, m[2] * I.iI3)


@lane
def split_stage(model, stage, t, z):
    """Part ``stage`` (a literal, 0 … 4) of a Strang step of size t on the
    work state z: stage k is flow k of the free rotation
    (:func:`.terms.inertia.free_flow_stage`), after E_{t/2} in stage 0 and
    before E_{t/2}ᵀ in stage 4.  The stages one after the other are the
    Strang step; the block kernel runs each over all its lanes before the
    next (a step's five divisions form one dependent chain; a stage at a
    time, the lanes keep the vector units busy)."""
    m, G, q, R = z
    I = model.inertia
    if stage == 0:
        m, q = flow_forward(model.forces, I, 0.5 * t, G, m, q)
    m0, m1, m2, G0, G1, G2, R = free_flow_stage(I, stage, t, m[0], m[1], m[2], G[0], G[1], G[2], R)
    m, G = (m0, m1, m2), (G0, G1, G2)
    if stage == FREE_FLOW_STAGES - 1:
        m, q = flow_backward(model.forces, I, 0.5 * t, G, m, q)
    return m, G, q, R


@generic(is_present)
def add_heat(q0, q):
    """q₀ + q, None without thermodynamics (no heat row)."""
    return None


@add_heat.register(True)
def add_heat_present(q0, q):
    return q0 + q


@lane
def split_end(model, y, z):
    """The ``split`` layout state at the end of a step that started at y with
    work state z: the heat of the step added to the heat absorbed so far
    (one rounding, of a sum that only grows when the step heats)."""
    m, G, q, R = z
    return m, G, add_heat(y[2], q), R


def split_step(tab, model, y, h, exact):
    """(y', True): one step of size h of the splitting ``tab`` from the
    ``split`` layout state y = (μ, Γ, q, R) (``exact`` is not used: no
    inline polynomial of the step has a limited range)."""
    z = split_begin(model, y)
    for f in type(tab).factors:
        t = f * h
        for stage in range(FREE_FLOW_STAGES):
            z = split_stage(model, stage, t, z)
    return split_end(model, y, z), True


def _split_source(cls) -> str:
    lines = ["def impl(tab, model, y, h, exact):",
             "    z = split_begin(model, y)"]
    for k, f in enumerate(cls.factors):
        lines += [f"    t{k} = {f!r} * h"]
        lines += [f"    z = split_stage(model, {stage}, t{k}, z)" for stage in range(FREE_FLOW_STAGES)]
    lines += ["    return split_end(model, y, z), True"]
    return "\n".join(lines) + "\n"


def _explicit_step_overload(tab, model, y, h, exact):
    cls = splitting_class(tab)
    if cls is None:
        return None
    ns = {"split_begin": split_begin, "split_stage": split_stage, "split_end": split_end}
    return compile_source(_split_source(cls), ns, label=f"split_step {cls.__name__} {cls.factors}")


def register(explicit_step) -> None:
    """Make ``explicit_step`` (of :mod:`.rk`) take splitting markers too."""
    overload(explicit_step, jit_options=LANE_OPTIONS)(_explicit_step_overload)
