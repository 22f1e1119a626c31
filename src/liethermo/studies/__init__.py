"""Studies: sweeps over scene keys, method comparisons, statistics, reports.

A study is a TOML file (``studies/NAME.toml``) run by ``liethermo study``.
Its ``[study]`` table names the ``kind`` — one of :func:`kinds` (the registered models'), each a module
``liethermo.studies.<kind>`` — and the base scene; ``[sweep]`` maps scene
keys ``"section.key"`` to lists of values (a Cartesian product); ``methods``
lists the methods to compare; ``[reduced]`` overrides any of these for the
reduced-size mode the test suite runs, ``[model.<name>]`` for a base scene of
that model.  Each kind's module declares one
:class:`liethermo.studies.framework.Study` (docs/studies.md).
"""

from __future__ import annotations

import importlib
from types import ModuleType

def kinds() -> tuple[str, ...]:
    """Every study kind: those of the registered models (:attr:`liethermo.models.Model.study_kinds`)."""
    from ..models import study_kinds

    return tuple(study_kinds())


def __getattr__(name: str):
    if name == "KINDS":  # the kinds as a constant, read when asked for
        return kinds()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def get_study(kind: str) -> ModuleType:
    """The module implementing a study kind (raises ValueError for an unknown kind)."""
    known = kinds()
    if kind not in known:
        raise ValueError(f"unknown study kind {kind!r}: expected one of {', '.join(known)}")
    return importlib.import_module(f"{__name__}.{kind}")
