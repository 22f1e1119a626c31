"""What a method hands the ensemble drivers: its kernel data, whose type picks its step.

There is one driver loop per memory layout — :func:`.simple.advance_members`
(one member at a time) and :func:`.fast.advance_blocks` (blocks of lanes) —
and every method runs through it.  The driver owns what all methods share:
the members or blocks, the outputs every ``every`` steps, the step counts,
the status of a member that fails and the running max |h|·|Ω|.  The method
gives one *stepper*, a namedtuple of its data, and the driver calls the step
that the stepper's type selects when numba compiles the driver:

* :class:`Explicit` — an explicit Runge–Kutta tableau or a splitting
  (:mod:`.rk`, :mod:`.split`): the marker ``tab`` whose type fixes the
  straight-line step, and ``nsub`` substeps of h/nsub per step (the
  one-member layout; 0: each member's own count, ``ISTAT[m, IS_NSUB]``, as
  the reference sets it);
* :class:`Split` — a splitting (:mod:`.split`): as :class:`Explicit`,
  with its substep factors as data, which the block layout's sweeps take;
* :class:`Variational` — the variational integrator in node form: the
  substep factors of a composition (one for ``vi``), the friction weights,
  the entropy update and the Newton tolerance and iteration limit.

:func:`by_stepper` builds a generic function from one implementation per
kind of stepper; the layouts define their steps with it.
"""

from __future__ import annotations

from collections import namedtuple

from .gen import overload_choice

#: an explicit method: its tableau (or splitting) marker and substeps per step
Explicit = namedtuple("Explicit", "tab nsub")
#: a splitting: an explicit method (marker, substeps) whose substep factors
#: the block layout also takes as data, to run its Strang steps a stage at a time
Split = namedtuple("Split", "tab nsub factors")
#: the variational integrator: substep factors (a tuple), friction weights
#: (wl, wr), entropy update marker, Newton tolerance and iteration limit
Variational = namedtuple("Variational", "factors wl wr mode tol maxiter")


def stepper_kind(stepper) -> type:
    """:class:`Explicit`, :class:`Split` or :class:`Variational`: the kind of
    a stepper or of its numba type."""
    cls = getattr(stepper, "instance_class", None) or type(stepper)
    if cls not in (Explicit, Split, Variational):
        raise TypeError(f"not a stepper: {stepper!r}")
    return cls


def by_stepper(explicit, variational, split=None, inline_explicit: str = "llvm"):
    """A generic lane function that is ``explicit`` for an :class:`Explicit`
    first argument, ``variational`` for a :class:`Variational` one and
    ``split`` (default: ``explicit``) for a :class:`Split` one (chosen when
    numba types the call).  ``explicit`` lends its name and signature.
    ``inline_explicit="ir"``: numba pastes the explicit (and split)
    implementation into its caller (see :func:`.gen.register_overload`)."""
    impls = {Explicit: explicit, Split: explicit if split is None else split,
             Variational: variational}
    return overload_choice(explicit, lambda t: impls[stepper_kind(t)],
                           label=f"by_stepper {explicit.__name__}",
                           inline=lambda impl: "llvm" if impl is variational else inline_explicit)


__all__ = ["Explicit", "Split", "Variational", "by_stepper", "stepper_kind"]
