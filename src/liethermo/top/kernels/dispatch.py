"""Generic kernel functions: one registration idiom, in the spirit of
:func:`functools.singledispatch`.

A kernel function that does different things for different kinds of
argument is declared once, as a generic function whose body is its default
implementation; each other implementation is a separately named function
registered for a *key* of the argument the function dispatches on::

    @generic(stepper_kind)
    def member_load(stepper, md, buf, base, stride):
        \"\"\"The state of a member from its row.\"\"\"
        return load_rk_state(md, buf, base, stride)

    @member_load.register(Variational)
    def member_load_vi(stepper, md, buf, base, stride):
        return load_vi_state(md, buf, base, stride)

Numba picks the implementation when it types a call, from the numba type of
the argument; plain Python (``NUMBA_DISABLE_JIT=1``) picks it from the value
at each call.  Either way the key is computed by the same function, so the
two agree.  The implementations are ordinary functions bound to their own
names: go-to-definition and tracebacks land on the body that runs.

Keys used by the kernels:

* :func:`.steppers.stepper_kind` — the kind of a method's kernel data
  (explicit, splitting, variational);
* :func:`is_present` — whether an optional part is there (not ``None``): an
  absent part compiles to nothing;
* :func:`term_class` — the class of a model term (looked up along its MRO);
* :func:`capability` — whether a term declares a capability in its
  ``CAPABILITIES`` (solvers ask a term what it needs, never for its class);
* :func:`is_nonempty` — whether a tuple of terms has a first term: a fold over
  the terms is a generic whose non-empty implementation handles the first
  term and calls itself on the rest (numba compiles one instance per length,
  so the fold unrolls at compile time).

Every generic is listed in :data:`GENERICS` (a test checks that each
implementation's code is its own definition).
"""

from __future__ import annotations

import functools
import inspect

from .gen import is_none, register_overload

#: every generic kernel function, in the order they were declared
GENERICS: list = []


def is_present(x) -> bool:
    """Key: False for None (or its numba type), True otherwise."""
    return not is_none(x)


def term_class(x) -> type:
    """Key: the class of a term (instance or numba type); ``type(None)`` for an absent one."""
    if is_none(x):
        return type(None)
    return getattr(x, "instance_class", None) or type(x)


def has_capability(term, name: str) -> bool:
    """Whether a term (an instance, its class, or its numba type) declares
    ``name`` in its ``CAPABILITIES`` (e.g. ``"entropy_dependent_inertia"``:
    the entropy joins the motion)."""
    cls = getattr(term, "instance_class", None)
    if cls is None:
        cls = term if isinstance(term, type) else type(term)
    return name in getattr(cls, "CAPABILITIES", ())


def capability(name: str):
    """Key: whether the argument is a term that declares capability ``name``."""
    def key(x) -> bool:
        return has_capability(x, name)

    key.__name__ = f"capability[{name}]"
    return key


def is_nonempty(x) -> bool:
    """Key: whether a tuple (or its numba type) has at least one element."""
    return len(x) > 0


def generic(key, *, arg: int | tuple[int, ...] = 0, inline: str = "llvm"):
    """Declare a generic lane function: the decorated function is its default
    implementation and lends the generic its name, signature and docstring.

    ``key(x)`` maps the ``arg``-th argument (its numba type when numba
    compiles a call, its value in plain Python; with a tuple ``arg``, those
    arguments, as separate parameters of ``key``) to the key under which
    implementations are registered with ``@f.register(key_value)``; a class
    key is looked up along the MRO, and a key with no implementation gets
    the default.  ``inline`` (per implementation, default for all): "llvm"
    (compiled once per argument types, inlined by LLVM into every caller) or
    "ir" (numba pastes the code into its caller before compiling it: for the
    few driver-level functions that call sweeps)."""
    def declare(default):
        params = ", ".join(inspect.signature(default).parameters)
        which = (arg,) if isinstance(arg, int) else tuple(arg)

        def key_of(args):
            return key(*[args[i] for i in which])

        impls: dict = {}
        modes = {default: inline}

        def lookup(k):
            if isinstance(k, type):
                for c in k.__mro__:
                    if c in impls:
                        return impls[c]
            elif k in impls:
                return impls[k]
            return default

        @functools.wraps(default)
        def dispatcher(*args):
            return lookup(key_of(args))(*args)

        def register(k, *, inline: str | None = None):
            def add(impl):
                if k in impls:
                    raise ValueError(f"{default.__name__}: a second implementation for {k!r}")
                impls[k] = impl
                modes[impl] = inline or modes[default]
                return impl
            return add

        def typer_for(mode):
            def typer(*types):
                impl = lookup(key_of(types))
                return impl if modes[impl] == mode else None
            return typer

        for mode in ("llvm", "ir"):
            register_overload(dispatcher, params, typer_for(mode), f"generic {default.__name__}", mode)
        dispatcher.register = register
        dispatcher.dispatch = lambda *args: lookup(key_of(args))
        dispatcher.implementations = lambda: [default] + list(impls.values())
        GENERICS.append(dispatcher)
        return dispatcher

    return declare


__all__ = ["GENERICS", "capability", "generic", "has_capability", "is_nonempty",
           "is_present", "term_class"]
