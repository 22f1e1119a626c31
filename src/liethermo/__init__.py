"""liethermo: structure-preserving simulation of thermodynamic systems on Lie groups.

The Python interface (docs/api.md)::

    import liethermo
    ds = liethermo.run("paper", {"integrator.h": 0.05}, compare=False)  # the VI: an xarray Dataset
    ds.liethermo.relative_energy_error().plot.line(x="t")

``run``, ``study``, ``load_scene``, ``open_dataset``, ``open_runs``, the ``ds.liethermo``
accessor and the errors they raise on bad input (``SceneError``,
``PreflightError``) come from :mod:`liethermo.api`, loaded on first use.  Importing
the package compiles nothing and loads neither xarray nor numba (about 0.1 s);
kernels compile (or load from the numba cache) on first use.
"""

from __future__ import annotations

import sys

from .version import __version__

__all__ = ["run", "study", "load_scene", "open_dataset", "open_runs", "StudyResult", "SceneError",
           "PreflightError", "__version__"]

#: the public names, loaded from liethermo.api on first use: ``import liethermo`` and the
#: command line's help then start without xarray and numba
_API = {"run", "study", "load_scene", "open_dataset", "open_runs", "StudyResult", "SceneError", "PreflightError"}


def __getattr__(name: str):
    if name in _API:
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'liethermo' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | _API)


class _AccessorOnXarrayImport:
    """A meta-path finder that registers ``ds.liethermo`` right after xarray's
    own import, so that ``import liethermo`` need not import xarray (about a
    third of a second) for the accessor to exist whenever a dataset does."""

    def find_spec(self, name, path=None, target=None):
        if name != "xarray":
            return None
        import importlib.util

        if self in sys.meta_path:
            sys.meta_path.remove(self)  # once, and not for the look-up just below
        spec = importlib.util.find_spec(name)
        loader = getattr(spec, "loader", None)
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        exec_module = loader.exec_module

        def exec_then_register(module):
            exec_module(module)
            from . import accessor  # noqa: F401

        loader.exec_module = exec_then_register
        return spec


if "xarray" in sys.modules:
    from . import accessor as _accessor  # noqa: E402,F401
else:
    sys.meta_path.insert(0, _AccessorOnXarrayImport())
