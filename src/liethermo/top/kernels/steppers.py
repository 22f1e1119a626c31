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

The layouts declare their per-kind functions as generics keyed by
:func:`stepper_kind` (:mod:`.dispatch`).
"""

from __future__ import annotations

from collections import namedtuple

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


__all__ = ["Explicit", "Split", "Variational", "stepper_kind"]
