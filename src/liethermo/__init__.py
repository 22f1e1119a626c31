"""liethermo: structure-preserving simulation of thermodynamic systems on Lie groups.

The Python interface (docs/api.md)::

    import liethermo
    ds = liethermo.run("paper", {"integrator.h": 0.05}, compare=False)  # the VI: an xarray Dataset
    ds.liethermo.relative_energy_error().plot.line(x="t")

``run``, ``study``, ``load_scene``, ``open_dataset``, the ``ds.liethermo``
accessor and the errors they raise on bad input (``SceneError``,
``PreflightError``) come from :mod:`liethermo.api`.  Importing the package compiles
nothing; kernels compile (or load from the numba cache) on first use.
"""

from __future__ import annotations

try:
    from importlib.metadata import version as _version

    __version__ = _version("liethermo")
except Exception:  # pragma: no cover - not installed
    __version__ = "0+unknown"

from .api import PreflightError, SceneError, StudyResult, load_scene, open_dataset, run, study  # noqa: E402
from .zeitlin import scene as _zeitlin_scene  # noqa: E402,F401  (registers the Zeitlin fluid's scenes)

__all__ = ["run", "study", "load_scene", "open_dataset", "StudyResult", "SceneError", "PreflightError",
           "__version__"]
