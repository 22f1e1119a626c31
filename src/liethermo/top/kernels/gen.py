"""Typing-time code generation for kernels that are generic over the model.

Numba compiles a kernel once per argument *type*.  A model is a namedtuple of
term namedtuples (:mod:`liethermo.top.kernels.terms`); its type says which terms a
scene uses.  The generic functions here are numba ``@overload``\\ s whose
implementation is written, at typing time, as straight-line source text for
the argument types at hand: one line per term or per float, no loop over
terms and no branch on an absent one.  So an absent term costs nothing, and a
kernel compiles only the terms its scene uses.

Values handled here are *trees*: floats, ``None`` (an absent part) and
(named)tuples of trees.  A model, a part-wise state ``(Ω, Γ, σ, …)`` and a
tuple of forces are all trees.

* :func:`madd` — ``a·b + acc`` with one rounding, or ``a·b`` when ``acc`` is
  ``None``: how every term adds its contribution to an accumulator, so the
  first term present starts the sum without an extra operation;
* :func:`unflatten` — rebuild a tree of the template's type from consecutive
  floats ``p[base + k·stride]`` (a parameter row of the straightforward
  kernel, or a lane's parameter rows in the block kernel);
* :func:`tree_fma`, :func:`tree_finite`, :func:`tree_select` — part-wise
  operations on states;
* :func:`flatten` (plain Python) — the floats of a tree in the order
  :func:`unflatten` reads them;
* :func:`compile_source` — the one place generated source becomes code: each
  piece gets a file name that says what it is (``<liethermo-generated
  fold sum_torque #12>``), its lines are registered with :mod:`linecache` so
  that a traceback shows them, and with ``LIETHERMO_DUMP_SOURCE=<folder>``
  every piece is also written there as a ``.py`` file to read.
"""

from __future__ import annotations

import itertools
import linecache
import os
import re
from pathlib import Path

from numba import types
from numba.extending import overload

from ._jit import LANE_OPTIONS, fma, lane, ld

_counter = itertools.count()


def is_none(ty) -> bool:
    """Is the numba type ``ty`` the type of ``None`` (an absent part)?"""
    return isinstance(ty, (types.NoneType, types.Omitted)) or ty is None


def _is_tuple(ty) -> bool:
    return isinstance(ty, types.BaseTuple)


def leaves(ty, expr: str) -> list[str]:
    """Source expressions of the float leaves of a value of type ``ty`` that
    is reachable as ``expr``, in tree order."""
    if is_none(ty):
        return []
    if _is_tuple(ty):
        out = []
        for k, t in enumerate(ty.types):
            out += leaves(t, f"{expr}[{k}]")
        return out
    return [expr]


def count_leaves(ty) -> int:
    return len(leaves(ty, "x"))


def build(ty, items, ns: dict) -> str:
    """Source of an expression that builds a value of type ``ty`` from the
    successive float expressions of the iterator ``items``; namedtuple
    classes are put into ``ns`` under fresh names."""
    if is_none(ty):
        return "None"
    if _is_tuple(ty):
        parts = [build(t, items, ns) for t in ty.types]
        cls = getattr(ty, "instance_class", None)
        if isinstance(ty, (types.NamedTuple, types.NamedUniTuple)) and cls is not None:
            name = f"_cls{next(_counter)}"
            ns[name] = cls
            return f"{name}({', '.join(parts)})"
        if len(parts) == 1:
            return f"({parts[0]},)"
        return "(" + ", ".join(parts) + ")"
    return next(items)


_GENERATED = itertools.count()


def compile_source(src: str, ns: dict, name: str = "impl", label: str | None = None):
    """Execute the generated source ``src`` in ``ns`` (with :func:`fma`
    available) and return ``ns[name]``.  ``label`` says what the code is (by
    default ``name``): it goes into the file name that tracebacks show,
    ``<liethermo-generated LABEL #N>``, whose lines :mod:`linecache` then
    knows; with ``LIETHERMO_DUMP_SOURCE`` set to a folder the source is also
    written there as ``LABEL-N.py`` (ending in a comment with that name), and
    that file is the code's file name."""
    ns.setdefault("fma", fma)
    label = label or name
    n = next(_GENERATED)
    filename = f"<liethermo-generated {label} #{n}>"
    folder = os.environ.get("LIETHERMO_DUMP_SOURCE")
    if folder:  # the code's file is the dumped one: tracebacks name a file on disk
        path = Path(folder) / f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', label)}-{n}.py"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{src}# {filename}\n")  # the name last: line numbers stay the code's
        filename = str(path.resolve())
    linecache.cache[filename] = (len(src), None, src.splitlines(True), filename)
    exec(compile(src, filename, "exec"), ns)
    return ns[name]


def flatten(value) -> list[float]:
    """The floats of a tree (plain Python), in the order :func:`unflatten` reads them."""
    if value is None:
        return []
    if isinstance(value, tuple):
        out = []
        for v in value:
            out += flatten(v)
        return out
    return [float(value)]


# ----------------------------------------------------------------------------- madd


@lane
def madd(a, b, acc):
    """``a·b + acc`` rounded once; ``a·b`` when ``acc`` is None."""
    if acc is None:
        return a * b
    return fma(a, b, acc)


@lane
def cadd(x, acc):
    """``x + acc``; ``x`` when ``acc`` is None."""
    if acc is None:
        return x
    return x + acc


@lane
def axpy_opt(a, x, y):
    """``fma(a, x, y)``; ``y`` when ``x`` is None (a term that is absent)."""
    if x is None:
        return y
    return fma(a, x, y)


def register_overload(fn, args: str, typer, label: str, inline: str = "llvm") -> None:
    """The one overload factory.  Numba compiles a call of the generic
    function ``fn`` (whose parameters are ``args``) with the implementation
    that ``typer(*argument types)`` returns, or tries fn's other overloads
    when it returns None.  Numba wants the typer to have ``fn``'s signature:
    it gets one through generated source labelled ``LABEL typer``.
    ``inline``: "llvm" (a lane function: compiled once per argument types,
    then inlined by LLVM into every caller) or "ir" (numba pastes its code
    into the caller before compiling it: for the few driver-level functions
    that call sweeps, whose code then is the same as if written in place)."""
    if inline == "ir":
        deco = overload(fn, inline="always", jit_options={**LANE_OPTIONS, "forceinline": False})
    else:
        deco = overload(fn, jit_options=LANE_OPTIONS)
    deco(compile_source(f"def _typer({args}):\n    return typer({args})\n", {"typer": typer},
                        "_typer", f"{label} typer"))


@lane
def abs_or_zero(x):
    """|x|, or 0.0 when ``x`` is None."""
    if x is None:
        return 0.0
    return abs(x)


@lane
def or_zero(x):
    """``x``, or 0.0 when ``x`` is None (an accumulator no term touched)."""
    if x is None:
        return 0.0
    return x


# ----------------------------------------------------------------------------- trees


def unflatten(template, p, base, stride):
    """A tree of the template's type from ``p[base + k·stride]``, k = 0, 1, …"""
    k = 0

    def rebuild(t):
        nonlocal k
        if t is None:
            return None
        if isinstance(t, tuple):
            parts = [rebuild(x) for x in t]
            return type(t)(*parts) if hasattr(t, "_fields") else tuple(parts)
        v = float(p[base + k * stride])
        k += 1
        return v

    return rebuild(template)


@overload(unflatten, jit_options=LANE_OPTIONS)
def _unflatten(template, p, base, stride):
    n = count_leaves(template)
    ns: dict = {}
    ns["ld"] = ld
    expr = build(template, iter([f"ld(p, base + {k} * stride)" for k in range(n)]), ns)
    return compile_source(f"def impl(template, p, base, stride):\n    return {expr}\n", ns,
                          label=f"unflatten {n} floats")


def _tree_map(f, *trees):
    t0 = trees[0]
    if t0 is None:
        return None
    if isinstance(t0, tuple):
        parts = [_tree_map(f, *xs) for xs in zip(*trees)]
        return type(t0)(*parts) if hasattr(t0, "_fields") else tuple(parts)
    return f(*trees)


def _leaves(t) -> list:
    if t is None:
        return []
    if isinstance(t, tuple):
        return [v for x in t for v in _leaves(x)]
    return [t]


def _pairwise(terms: list):
    while len(terms) > 1:
        terms = [terms[k] + terms[k + 1] if k + 1 < len(terms) else terms[k]
                 for k in range(0, len(terms), 2)]
    return terms[0]


def tree_fma(a, x, y):
    """Leaf-wise ``fma(a, x, y)`` of two trees of the same shape."""
    return _tree_map(lambda u, v: fma(a, u, v), x, y)


@overload(tree_fma, jit_options=LANE_OPTIONS)
def _tree_fma(a, x, y):
    lx, ly = leaves(x, "x"), leaves(y, "y")
    if len(lx) != len(ly):
        return None
    ns: dict = {}
    expr = build(y, iter([f"fma(a, {u}, {v})" for u, v in zip(lx, ly)]), ns)
    return compile_source(f"def impl(a, x, y):\n    return {expr}\n", ns, label=f"tree_fma {len(lx)} leaves")


def tree_finite(x):
    """Whether every leaf is finite, decided exactly: the sum of (v − v) over
    the leaves is 0 exactly when all are (it adds zeros, so it cannot overflow)."""
    lx = _leaves(x)
    return not lx or _pairwise([v - v for v in lx]) == 0.0


@overload(tree_finite, jit_options=LANE_OPTIONS)
def _tree_finite(x):
    lx = leaves(x, "x")
    if not lx:
        return lambda x: True
    terms = [f"({v} - {v})" for v in lx]
    while len(terms) > 1:  # pairwise: a shallow tree of adds
        terms = [f"({terms[k]} + {terms[k + 1]})" if k + 1 < len(terms) else terms[k]
                 for k in range(0, len(terms), 2)]
    return compile_source(f"def impl(x):\n    return {terms[0]} == 0.0\n", {}, label=f"tree_finite {len(lx)} leaves")


def tree_sum_finite(x):
    """A cheap test: whether the sum of the leaves is finite.  True implies
    every leaf is finite; False may also mean that finite leaves overflowed
    in the sum (the caller then decides exactly, with :func:`tree_finite`)."""
    lx = _leaves(x)
    if not lx:
        return True
    s = _pairwise(list(lx))
    return s - s == 0.0


@overload(tree_sum_finite, jit_options=LANE_OPTIONS)
def _tree_sum_finite(x):
    lx = leaves(x, "x")
    if not lx:
        return lambda x: True
    terms = list(lx)
    while len(terms) > 1:
        terms = [f"({terms[k]} + {terms[k + 1]})" if k + 1 < len(terms) else terms[k]
                 for k in range(0, len(terms), 2)]
    return compile_source(f"def impl(x):\n    s = {terms[0]}\n    return s - s == 0.0\n", {},
                          label=f"finite sum {len(lx)} leaves")


def tree_select(c, x, y):
    """Leaf-wise ``x if c else y`` as selects (no branch)."""
    return _tree_map(lambda u, v: u if c else v, x, y)


@overload(tree_select, jit_options=LANE_OPTIONS)
def _tree_select(c, x, y):
    from ._jit import select

    lx, ly = leaves(x, "x"), leaves(y, "y")
    if len(lx) != len(ly):
        return None
    ns: dict = {"select": select}
    expr = build(y, iter([f"select(c, {u}, {v})" for u, v in zip(lx, ly)]), ns)
    return compile_source(f"def impl(c, x, y):\n    return {expr}\n", ns, label=f"tree_select {len(lx)} leaves")


@lane
def finite(x):
    """x − x == 0: true for finite x, false for ±inf and NaN."""
    return x - x == 0.0

