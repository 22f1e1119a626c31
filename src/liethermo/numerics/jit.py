"""Numba options every model's kernels share."""

from __future__ import annotations

import os

#: whether compiled kernels are cached on disk (``LIETHERMO_NUMBA_CACHE=0`` switches it off)
CACHE = os.environ.get("LIETHERMO_NUMBA_CACHE", "1") not in ("0", "false", "no")
