"""liethermo: structure-preserving simulation of thermodynamic systems on Lie groups.

Importing the package compiles nothing; kernels compile (or load from the
numba cache) on first use.
"""

from __future__ import annotations

try:
    from importlib.metadata import version as _version

    __version__ = _version("liethermo")
except Exception:  # pragma: no cover - not installed
    __version__ = "0+unknown"
