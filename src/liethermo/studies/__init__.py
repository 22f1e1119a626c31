"""Studies: sweeps over scene keys, method comparisons, statistics, reports.

A study is a TOML file (``studies/NAME.toml``) run by ``liethermo study``.
Its ``[study]`` table names the ``kind`` — one of :data:`KINDS`, each a module
``liethermo.studies.<kind>`` — and the base scene; ``[sweep]`` maps scene
keys ``"section.key"`` to lists of values (a Cartesian product); ``methods``
lists the methods to compare; ``[reduced]`` overrides any of these for the
reduced-size mode the test suite runs.  See :mod:`liethermo.studies.common`
for the contract every study module follows.
"""

from __future__ import annotations

import importlib
from types import ModuleType

KINDS = ("paper", "convergence", "energy_drift", "work_precision", "stability", "viscosity_sweep",
         "long_drift", "coupling", "flat_spin", "zeitlin_convergence", "zeitlin_decay", "zeitlin_structure",
         "zeitlin_resolution")


def get_study(kind: str) -> ModuleType:
    """The module implementing a study kind (raises ValueError for an unknown kind)."""
    if kind not in KINDS:
        raise ValueError(f"unknown study kind {kind!r}: expected one of {', '.join(KINDS)}")
    return importlib.import_module(f"{__name__}.{kind}")
