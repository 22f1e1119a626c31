"""A cache on disk for arrays that take long to compute and depend on a few
numbers alone (the fluid's basis of su(N): 46 MB at N = 256; 2.9 GB and 41 s to
build on a 2-core Intel Xeon at N = 1024).

Where: ``LIETHERMO_CACHE_DIR`` if set, else the user's cache folder
(:func:`platformdirs.user_cache_dir`, e.g. ``~/.cache/liethermo``).
``LIETHERMO_CACHE=off`` (or ``0``, ``no``, ``false``) switches it off: every
value is computed.  ``LIETHERMO_CACHE_MAX_MB`` (default 8192: the basis of
su(1024) beside smaller ones) bounds its size: after a store, the entries used
least recently are removed until it fits.  A value larger than the limit on its
own is not written, and a line on stderr says so (and how to keep it).

An entry is one ``.npz`` file named by its kind, key and version and by the
numpy and scipy versions that computed it (their routines set the last
bits), so a value read back is the one a fresh computation here would give.
Entries are written to a temporary file in the folder and renamed into place:
runs at the same time compute a missing entry each and the last rename
wins, both complete; a reader never sees half a file (and a damaged one,
which zip's CRC-32 finds, is computed again and replaced).  A folder that
cannot be written (read-only, disk full) only means no cache: the value is
computed and used.
"""

from __future__ import annotations

import os
import re
import tempfile
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

#: the cache's default size limit, MB (LIETHERMO_CACHE_MAX_MB)
DEFAULT_MAX_MB = 8192
_OFF = {"0", "off", "no", "false"}


def cache_dir() -> Path | None:
    """The cache folder, or None when the cache is off."""
    if os.environ.get("LIETHERMO_CACHE", "").strip().lower() in _OFF:
        return None
    given = os.environ.get("LIETHERMO_CACHE_DIR")
    if given:
        return Path(given)
    import platformdirs

    return Path(platformdirs.user_cache_dir("liethermo", appauthor=False))


def max_bytes() -> int:
    """The size limit in bytes (LIETHERMO_CACHE_MAX_MB, MB)."""
    text = os.environ.get("LIETHERMO_CACHE_MAX_MB", "")
    try:
        mb = float(text) if text else DEFAULT_MAX_MB
    except ValueError:
        raise ValueError(f"LIETHERMO_CACHE_MAX_MB must be a number of MB, got {text!r}") from None
    if not mb >= 0:
        raise ValueError(f"LIETHERMO_CACHE_MAX_MB must be >= 0, got {text!r}")
    return int(mb * 2**20)


def entry_name(kind: str, key: str, version: int) -> str:
    import scipy

    raw = f"{kind}-{key}-v{version}-numpy{np.__version__}-scipy{scipy.__version__}"
    return re.sub(r"[^A-Za-z0-9_.=-]", "_", raw) + ".npz"


def is_cached(kind: str, key: str, version: int) -> bool:
    """Whether the cache holds an entry of (kind, key, version) (not read: it may still prove damaged)."""
    folder = cache_dir()
    return folder is not None and (folder / entry_name(kind, key, version)).is_file()


def cached_arrays(kind: str, key: str, version: int, compute: Callable[[], dict]) -> dict:
    """``compute()`` (a dict of numpy arrays), read from the cache when an entry
    of (kind, key, version) is there, else computed and stored."""
    folder = cache_dir()
    if folder is None:
        return compute()
    path = folder / entry_name(kind, key, version)
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}  # reads every member: zip checks its CRC-32
        os.utime(path)  # used now: evicted last
        return out
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError):
        pass  # not there, or damaged: compute it again
    out = compute()
    size, limit = sum(np.asarray(a).nbytes for a in out.values()), max_bytes()
    if size > limit:
        import sys

        from .faults import human_bytes

        print(f"liethermo: not caching {kind} {key} ({human_bytes(size)}): it is larger than the cache's "
              f"limit, LIETHERMO_CACHE_MAX_MB = {limit / 2**20:g}; set it higher to keep it", file=sys.stderr,
              flush=True)
        return out
    _store(folder, path, out)
    return out


def _store(folder: Path, path: Path, arrays: dict) -> None:
    tmp = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp", dir=folder)
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
        tmp = None
        evict(folder, max_bytes(), keep=path)
    except OSError:
        pass  # no room or no right to write: the value is used uncached
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass


def evict(folder: Path, limit: int, keep: Path | None = None) -> list[Path]:
    """Remove the entries used least recently until the folder's entries take at
    most ``limit`` bytes (``keep``, the entry just stored, goes last); returns them."""
    entries = []
    for p in folder.glob("*.npz"):
        try:
            st = p.stat()
        except OSError:
            continue
        entries.append((p == keep, st.st_mtime, st.st_size, p))
    entries.sort(key=lambda e: (e[0], e[1]))
    total = sum(e[2] for e in entries)
    removed = []
    for _, _, size, p in entries:
        if total <= limit:
            break
        try:
            p.unlink()
        except OSError:
            continue
        total -= size
        removed.append(p)
    return removed


__all__ = ["cache_dir", "cached_arrays", "is_cached", "evict", "max_bytes", "DEFAULT_MAX_MB"]
