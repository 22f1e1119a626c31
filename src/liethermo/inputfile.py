"""Input files a scene names (``initial.file``): read once, identified by
their sha256, refused in one line (:class:`liethermo.scene.SceneError`
naming the key) when missing, unreadable or of an unknown format."""

from __future__ import annotations

import hashlib
from pathlib import Path

from .scene import SceneError

SUFFIXES = (".npy", ".npz", ".nc")


def read_bytes(key: str, path: str) -> bytes:
    """The bytes of a scene's input file, or a SceneError naming ``key``."""
    p = Path(path)
    if p.suffix not in SUFFIXES:
        raise SceneError(key, f"must be a {', '.join(SUFFIXES)} file", path)
    try:
        return p.read_bytes()
    except FileNotFoundError:
        raise SceneError(key, "no such file", path) from None
    except IsADirectoryError:
        raise SceneError(key, "is a folder, not a file", path) from None
    except OSError as exc:
        raise SceneError(key, f"cannot be read ({exc.strerror or exc})", path) from None
    except ValueError:  # e.g. a NUL byte in the path
        raise SceneError(key, "is not a valid path", path) from None


def sha256_of_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def read_checked(key: str, path: str, sha256: str = "") -> tuple[bytes, str]:
    """(bytes, sha256) of the file; with ``sha256`` given, the file must still have it."""
    data = read_bytes(key, path)
    digest = sha256_of_bytes(data)
    if sha256 and digest != sha256:
        raise SceneError("initial.sha256", f"{path} has changed: its sha256 is {digest[:16]}…, the scene's "
                         f"{sha256[:16]}… (to run it as it is now, leave initial.sha256 out)", show_value=False)
    return data, digest


def units_ok(u, allowed) -> bool:
    return str(u).strip() in allowed


def npz_arrays(key: str, path: str, data: bytes, name: str, optional=(), units=(), what: str = "") -> list:
    """The array ``name`` of a ``.npz`` file's bytes, then each of ``optional``
    (None where absent); a ``units`` entry of the file must be one of ``units``
    (``what`` says what in which unit, for the refusal)."""
    import io

    import numpy as np

    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        if name not in z.files:
            raise SceneError(key, f"{path}: a .npz file must hold the array '{name}' "
                             f"(it holds {', '.join(z.files) or 'nothing'})", show_value=False)
        if units and "units" in z.files and not units_ok(z["units"], units):
            raise SceneError(key, f"{path}: units {str(z['units'])!r}: {what}", show_value=False)
        return [z[name]] + [z[o] if o in z.files else None for o in optional]


def foreign(key: str, path: str, exc: BaseException) -> SceneError:
    """The refusal of a file that cannot be parsed as its suffix says."""
    first = str(exc).splitlines()[0] if str(exc) else "no details"
    return SceneError(key, f"{path} cannot be read as a {Path(path).suffix} file ({type(exc).__name__}: {first})",
                      show_value=False)
