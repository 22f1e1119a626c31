"""The built-in scenes: TOML files in ``liethermo/scenes/``.

Read without the scene machinery (no numba), so that ``liethermo --help``
lists them quickly; :mod:`liethermo.scene` loads and validates them.
"""

from __future__ import annotations

import sys
from importlib import resources

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def builtin_scene_tables() -> dict[str, dict]:
    """Names of the built-in scenes → their TOML tables (not validated)."""
    out = {}
    for f in sorted(resources.files("liethermo").joinpath("scenes").iterdir(), key=lambda p: p.name):
        if f.name.endswith(".toml"):
            out[f.name[:-5]] = tomllib.loads(f.read_text())
    return out


def builtin_scenes() -> dict[str, str]:
    """Names of the built-in scenes → their one-line descriptions."""
    return {name: data.get("scene", {}).get("description", "")
            for name, data in builtin_scene_tables().items()}


def builtin_scene_text(name: str) -> str | None:
    """The TOML text of the built-in scene ``name`` (None if there is none)."""
    f = resources.files("liethermo").joinpath("scenes", f"{name}.toml")
    return f.read_text() if f.is_file() else None
