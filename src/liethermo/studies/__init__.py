"""Studies: sweeps over scene keys, method comparisons, statistics, reports.

A study is a TOML file (``studies/NAME.toml``) run by ``liethermo study``.
Its ``[study]`` table names the ``kind`` — one of :func:`kinds` (the generic kinds and the registered models'),
or a module of the user's (``mypkg.mystudy``) that declares ``STUDY`` — and the base scene; ``[sweep]`` maps scene
keys ``"section.key"`` to lists of values (a Cartesian product); ``methods``
lists the methods to compare; ``[reduced]`` overrides any of these for the
reduced-size mode the test suite runs, ``[model.<name>]`` for a base scene of
that model.  Each kind's module declares one
:class:`liethermo.studies.framework.Study` (docs/studies.md).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType

#: the study files that come with the source (``studies/`` beside ``src/``)
SHIPPED_STUDIES = Path(__file__).resolve().parents[3] / "studies"


def shipped_studies() -> dict[str, Path]:
    """The shipped study files by name (``convergence`` → studies/convergence.toml)."""
    if not SHIPPED_STUDIES.is_dir():
        return {}
    return {p.stem: p for p in sorted(SHIPPED_STUDIES.glob("*.toml"))}

#: the study kinds that run on every model offering what they need (a reference
#: solution, an error norm, an energy), declared here once: {kind: module}
GENERIC_KINDS = {k: f"{__name__}.{k}" for k in ("convergence", "energy_drift", "long_drift", "work_precision")}


def kinds() -> dict[str, str]:
    """Every study kind and its module: the generic ones (:data:`GENERIC_KINDS`) and
    those of the registered models (:attr:`liethermo.models.Model.study_kinds`)."""
    from ..models import study_kinds

    return {**GENERIC_KINDS, **study_kinds()}


def __getattr__(name: str):
    if name == "KINDS":  # the kinds as a constant, read when asked for
        return tuple(kinds())
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def is_module_kind(kind: str) -> bool:
    """A kind written as a module path (``mypkg.mystudy``): a study of the user's own."""
    return "." in kind


def get_study(kind: str) -> ModuleType:
    """The module implementing a study kind: a known kind's, or the module a
    dotted kind names (raises ValueError for an unknown kind)."""
    if is_module_kind(kind):
        try:
            mod = importlib.import_module(kind)
        except ImportError as exc:
            raise ValueError(f"study kind {kind!r}: the module cannot be imported ({exc})") from None
        if not hasattr(mod, "STUDY"):
            raise ValueError(f"study kind {kind!r}: the module declares no STUDY "
                             "(a liethermo.studies.framework.Study)")
        return mod
    known = kinds()
    if kind not in known:
        raise ValueError(f"unknown study kind {kind!r}: expected one of {', '.join(known)} "
                         "or a module path (mypkg.mystudy)")
    return importlib.import_module(known[kind])
