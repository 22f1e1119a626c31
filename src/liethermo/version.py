"""The installed version of liethermo (files record it)."""

from __future__ import annotations

try:
    from importlib.metadata import version as _version

    __version__ = _version("liethermo")
except Exception:  # pragma: no cover - not installed
    __version__ = "0+unknown"
