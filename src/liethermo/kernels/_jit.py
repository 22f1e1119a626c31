"""All numba options of liethermo in one place.

* ``cache=True`` so that a second process does not recompile (set
  ``LIETHERMO_NUMBA_CACHE=0`` to switch it off, e.g. on a read-only install).
  Numba checks only the timestamp and size of the file that defines a
  cached function, not of the files of the functions it calls: after
  editing e.g. model.py, the cached ``ensemble.advance_ensemble`` still runs
  the old right-hand side.  When changing a kernel, delete
  ``kernels/__pycache__/*.nbi`` / ``*.nbc`` (or touch the calling modules);
* ``fastmath`` stays off: the kernels promise round-off-level invariants and
  must propagate NaN/inf, which the no-NaN/no-inf fast-math flags would break;
* ``error_model="numpy"``: a division by zero yields inf/NaN (caught by the
  per-member status logic) instead of raising inside a parallel loop.

Setting ``NUMBA_DISABLE_JIT=1`` runs every kernel as plain Python (slow, but
useful for debugging and for checking that the jitted code means what it says).
"""

from __future__ import annotations

import functools
import os

import numba

CACHE = os.environ.get("LIETHERMO_NUMBA_CACHE", "1") not in ("0", "false", "no")

jit = functools.partial(numba.njit, cache=CACHE, fastmath=False, error_model="numpy")
pjit = functools.partial(
    numba.njit, cache=CACHE, fastmath=False, error_model="numpy", parallel=True
)
prange = numba.prange
