"""One dispatch idiom for the kernels: generic functions with separately named
implementations, each the body that runs (no name rebound to generated code)."""

from __future__ import annotations

import ast
import importlib
import inspect
import re
import sys
from collections import namedtuple
from pathlib import Path

import numba
import pytest

from liethermo.top.kernels import fast, simple  # noqa: F401  (declare every generic)
from liethermo.top.kernels.dispatch import GENERICS, generic, is_nonempty, is_present, term_class
from liethermo.top.kernels.gen import compile_source

SRC = Path(__file__).resolve().parents[1] / "src" / "liethermo"


def own_definition_problem(fn) -> str | None:
    """None when ``fn``'s code object is its own top-level definition in its
    module's file (file and first line) and the module binds that name to it
    (or, for a generic's default, to the generic wrapping it); else what is wrong."""
    code = fn.__code__
    mod = sys.modules.get(fn.__module__)
    path = inspect.getsourcefile(mod) if mod is not None else None
    if path is None or code.co_filename != path:
        return f"{fn.__qualname__}: code from {code.co_filename}, not its module's file {path}"
    tree = ast.parse(Path(path).read_text())
    defs = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == fn.__name__]
    if len(defs) != 1:
        return f"{fn.__qualname__}: {len(defs)} top-level definitions of that name in {path}"
    line = min([d.lineno for d in defs[0].decorator_list] + [defs[0].lineno])
    if code.co_firstlineno != line:
        return f"{fn.__qualname__}: first line {code.co_firstlineno}, its definition is at {line}"
    bound = getattr(mod, fn.__name__, None)
    if bound is not fn and getattr(bound, "__wrapped__", None) is not fn:
        return f"{fn.__qualname__}: the name is bound to {bound!r}"
    return None


def test_every_implementation_is_its_own_definition():
    """For every kernel generic the registry holds, each implementation's code
    object has the file and first line of its own definition."""
    try:
        importlib.import_module("liethermo.top.kernels.cuda")  # declares none, but must not rebind
    except Exception:
        pass
    ours = [g for g in GENERICS if g.__module__.startswith("liethermo.")]
    assert len(ours) >= 40, len(ours)
    impls = [impl for g in ours for impl in g.implementations()]
    assert len(impls) >= 80, len(impls)
    problems = [p for p in map(own_definition_problem, impls) if p]
    assert not problems, "\n".join(problems)


def test_the_check_catches_generated_and_rebound_functions(tmp_path, monkeypatch):
    """Negative controls: a function made from generated source, and a name
    rebound to another function, both fail the check."""
    made = compile_source("def made(x):\n    return x\n", {}, "made", "test made")
    made.__module__ = __name__
    assert "not its module's file" in own_definition_problem(made)

    (tmp_path / "rebound_mod.py").write_text(
        "def f(x):\n    return x\n\n\n_original_f = f\n\n\n"
        "def _wrap(fn):\n    def f(x):\n        return fn(x)\n    return f\n\n\nf = _wrap(f)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("rebound_mod")
    assert "the name is bound" in own_definition_problem(mod._original_f)
    assert "its definition is at 1" in own_definition_problem(mod.f)


Marker = namedtuple("Marker", "value")
Other = namedtuple("Other", "value")


@generic(is_present)
def _maybe_double(x):
    """0.0 for None, else 2x."""
    return 0.0


@_maybe_double.register(True)
def _maybe_double_present(x):
    return 2.0 * x


@generic(term_class)
def _marker_value(m):
    """The default for any class without its own implementation."""
    return -1.0


@_marker_value.register(Marker)
def _marker_value_marker(m):
    return m.value


@generic(is_nonempty)
def _sum_values(terms, acc):
    """Fold: acc plus each term's _marker_value, first to last."""
    return acc


@_sum_values.register(True)
def _sum_values_terms(terms, acc):
    return _sum_values(terms[1:], acc + _marker_value(terms[0]))


@numba.njit
def _jitted(x, terms):
    return _maybe_double(x), _sum_values(terms, 0.0)


def test_generic_picks_by_key_compiled_and_in_python():
    """The key picks the same implementation when numba compiles a call (by
    type) and in plain Python (by value); a key with no implementation gets
    the default; a fold over a tuple recurses to its end at compile time."""
    terms = (Marker(1.5), Other(7.0), Marker(2.0))
    assert _jitted(None, terms) == (0.0, 1.5 - 1.0 + 2.0)
    assert _jitted(3.0, ()) == (6.0, 0.0)
    assert _maybe_double(None) == 0.0 and _maybe_double(3.0) == 6.0
    assert _sum_values(terms, 0.0) == 2.5
    assert _maybe_double.dispatch(None) is _maybe_double.__wrapped__
    assert _maybe_double.dispatch(1.0) is _maybe_double_present
    with pytest.raises(ValueError, match="second implementation"):
        _maybe_double.register(True)(lambda x: x)


def test_no_other_dispatch_mechanism_and_no_family_checks():
    """The home-made dispatch helpers are gone, and no module outside the method
    classes compares a method's family."""
    gone = re.compile(r"\b(by_stepper|none_dispatch|overload_by_capability|make_fold|overload_choice|"
                      r"_protocol|implements)\s*\(")
    family = re.compile(r"family\s*[!=]=")
    hits = []
    for path in SRC.rglob("*.py"):
        text = path.read_text()
        for k, line in enumerate(text.splitlines(), 1):
            if gone.search(line):
                hits.append(f"{path}:{k}: {line.strip()}")
            if family.search(line) and path.name != "methods.py":
                hits.append(f"{path}:{k}: {line.strip()}")
    assert not hits, "\n".join(hits)
