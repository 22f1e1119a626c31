"""Scenes: what a run simulates, as a typed, validated, immutable value.

A scene is read from TOML (a file, or a built-in scene of ``liethermo/scenes/``)
in sections and keys (``[integrator] h = 0.05``).  Resolution order: the
model's defaults ← the built-in scene or file ← overrides
(``--set SECTION.KEY=VALUE``, or ``{"section.key": value}`` in Python).
Which model a scene is, the registry says (:func:`liethermo.models.model_of`);
that model's scene side (a :class:`SceneModel`) checks every rule *before*
any work starts and raises :class:`SceneError` naming the key and the rule.

This module holds what every model's scene uses: the error, the value
checks, :class:`Key` (a key's default, unit, rule and meaning, from which the
defaults, the validation messages, ``liethermo keys`` and ``docs/scenes.md``
are produced), merging tables and overrides, and :func:`load_scene`.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

import tomli_w

from .scene_files import builtin_scene_tables, builtin_scene_text, builtin_scenes  # noqa: F401


class SceneError(ValueError):
    """An invalid scene: the message names the key and the rule it breaks."""

    def __init__(self, key: str, rule: str, value: Any = None, *, show_value: bool = True, what: str = "key"):
        self.key = key
        self.rule = rule
        msg = f"scene {what} '{key}': {rule}"
        if show_value:
            msg += f" (got {value!r})"
        super().__init__(msg)


# ----------------------------------------------------------------------------- value checks


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def number(lo=None, hi=None, *, lo_open=False, hi_open=False):
    """A finite number within the given bounds."""

    def check(name, v, scene):
        if not _is_number(v):
            raise SceneError(name, "must be a number", v)
        if not math.isfinite(v):
            raise SceneError(name, "must be finite", v)
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise SceneError(name, f"must be {'>' if lo_open else '≥'} {lo:g}", v)
        if hi is not None and (v >= hi if hi_open else v > hi):
            raise SceneError(name, f"must be {'<' if hi_open else '≤'} {hi:g}", v)
        return float(v)

    return check


def integer(minimum=1, maximum=None):
    def check(name, v, scene):
        if isinstance(v, bool) or not isinstance(v, int):
            raise SceneError(name, "must be an integer", v)
        if v < minimum:
            raise SceneError(name, f"must be ≥ {minimum}", v)
        if maximum is not None and v > maximum:
            raise SceneError(name, f"must be ≤ {maximum}", v)
        return int(v)

    return check


def _has_bool(v) -> bool:
    if isinstance(v, bool):
        return True
    if isinstance(v, (list, tuple)):
        return any(_has_bool(x) for x in v)
    return False


def vector(shape, positive=False):
    def check(name, v, scene):
        try:
            if isinstance(v, (str, bool)) or _has_bool(v):
                raise TypeError
            arr = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise SceneError(name, f"must be an array of numbers of shape {shape}", v) from None
        if arr.shape != shape:
            raise SceneError(name, f"must be an array of numbers of shape {shape}", v)
        if not np.all(np.isfinite(arr)):
            raise SceneError(name, "must be finite", v)
        if positive and np.any(arr <= 0):
            raise SceneError(name, "every entry must be > 0", v)
        return arr.tolist()

    return check


def choice(*options):
    def check(name, v, scene):
        if not isinstance(v, str) or v not in options:
            raise SceneError(name, f"must be one of {', '.join(map(repr, options))}", v)
        return v

    return check


def word_or(word: str, other, aliases=()):
    """The string ``word`` (or one of its aliases), or a value ``other`` accepts."""

    def check(name, v, scene):
        if isinstance(v, str):
            if v == word or v in aliases:
                return word
            raise SceneError(name, f'must be "{word}" or {other.__doc__ or "a value"}', v)
        return other(name, v, scene)

    return check


def boolean(name, v, scene):
    if not isinstance(v, bool):
        raise SceneError(name, "must be true or false", v)
    return v


def string(name, v, scene):
    if not isinstance(v, str):
        raise SceneError(name, "must be a string", v)
    return v


@dataclass(frozen=True)
class Key:
    """One scene key: its default, unit, the rule its values obey, what it means."""

    section: str
    name: str
    default: Any
    unit: str
    rule: str
    doc: str
    check: Callable = dataclasses.field(repr=False, compare=False, default=None)

    @property
    def path(self) -> str:
        return f"{self.section}.{self.name}"


def _freeze(v):
    return tuple(_freeze(x) for x in v) if isinstance(v, list) else v


def _thaw(v):
    return [_thaw(x) for x in v] if isinstance(v, tuple) else v


def _merge(base: dict, new: dict, origin: str, defaults: dict, kind: str = "") -> None:
    """Merge the tables ``new`` into ``base``, refusing sections and keys that
    ``defaults`` (the model's) does not have; ``kind`` names the model in the
    messages (" of a Zeitlin scene")."""
    for section, table in new.items():
        if section not in defaults:
            name = f"{section}.{next(iter(table))}" if isinstance(table, dict) and table else section
            raise SceneError(name, f"unknown section [{section}]{kind} in {origin}; known sections: "
                             f"{', '.join(defaults)}", show_value=False)
        if not isinstance(table, dict):
            raise SceneError(section, f"must be a table of keys in {origin}", table)
        for key, value in table.items():
            if key not in defaults[section]:
                raise SceneError(f"{section}.{key}", f"unknown key{kind} in {origin}; known keys of "
                                 f"[{section}]: {', '.join(defaults[section])}", show_value=False)
            base[section][key] = copy.deepcopy(_thaw(value))


def parse_override(text: str) -> tuple[str, str, Any]:
    """``SECTION.KEY=VALUE`` → (section, key, value); VALUE is a TOML value,
    and a bare word that is not valid TOML is taken as a string, also as an
    item of a one-level list (``[rk4, vi]``)."""
    if "=" not in text:
        raise SceneError(text, "an override must read SECTION.KEY=VALUE", show_value=False)
    lhs, rhs = text.split("=", 1)
    lhs = lhs.strip()
    if lhs.count(".") != 1:
        raise SceneError(lhs, "an override key must read SECTION.KEY", show_value=False)
    section, key = lhs.split(".")
    rhs = rhs.strip()
    try:
        value = tomllib.loads(f"v = {rhs}")["v"]
    except tomllib.TOMLDecodeError:
        value = _bare_list(rhs)
    return section, key, value


_BARE_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_:+-]*")


def _bare_list(text: str):
    """``[rk4, vi]`` → ``["rk4", "vi"]``: a one-level list whose items are TOML
    values or bare words (a bare word is a string); anything else stays the
    text itself, which the key's rule then rejects by name."""
    if not (text.startswith("[") and text.endswith("]")):
        return text
    items = []
    for item in (i.strip() for i in text[1:-1].split(",")):
        if not item:
            continue
        if _BARE_WORD.fullmatch(item) and item not in ("true", "false", "inf", "nan"):
            items.append(item)
            continue
        try:
            items.append(tomllib.loads(f"v = {item}")["v"])
        except tomllib.TOMLDecodeError:
            return text
    return items


def _overrides_as_tables(overrides) -> list[tuple[dict, str]]:
    if not overrides:
        return []
    if isinstance(overrides, dict):
        tables: dict[str, dict] = {}
        for k, v in overrides.items():
            if isinstance(v, dict) and "." not in k:
                tables.setdefault(k, {}).update(v)
                continue
            if not isinstance(k, str) or k.count(".") != 1:
                raise SceneError(str(k), "an override key must read SECTION.KEY", show_value=False)
            s, name = k.split(".")
            tables.setdefault(s, {})[name] = v
        return [(tables, "the overrides")]
    out = []
    for text in overrides:
        section, key, value = parse_override(text)
        out.append(({section: {key: value}}, "--set"))
    return out


@dataclass(frozen=True)
class SceneModel:
    """The scene side of a model (its :attr:`liethermo.models.Model.scene_model`);
    this module never imports a model's package.  A scene whose tables
    ``marks`` is that model's (the registry decides, :func:`liethermo.models.model_of`):
    ``load(tables, origin, overrides, validate)`` gives its defaults ← tables ←
    overrides, validated into a ``scene_class`` (or, with ``validate`` False, as
    tables), and docs/scenes.md lists ``keys`` under ``title`` after ``intro``."""

    name: str
    marks: Callable[[dict], bool]
    load: Callable
    scene_class: type
    keys: tuple
    title: str
    intro: str


#: the name the scene side of a model had before every model had one
OtherModel = SceneModel


def _scene_model(source):
    """The scene side of the model of ``source`` (tables or a loaded scene)."""
    from .models import model_of

    return model_of(source).scene_model


def load_scene(source: str | Path | dict | Any | None = "paper",
               overrides: list[str] | dict | None = None, *, validate_scene: bool = True):
    """Resolve a scene: the model's defaults ← built-in name, TOML file, dict or a
    loaded scene ← overrides.

    Returns the model's validated scene (or, with ``validate_scene=False``, the
    unvalidated tables as a dict)."""
    if source is None:
        source = {}
    if not isinstance(source, (str, Path, dict)):  # a loaded scene
        return _scene_model(source).load(source.to_dict(), "the scene", overrides, validate_scene)
    if isinstance(source, dict):
        return _scene_model(source).load(source, "the scene", overrides, validate_scene)
    src = str(source)
    text = builtin_scene_text(src) if "/" not in src and not src.endswith(".toml") else None
    if text is not None:
        data = tomllib.loads(text)
        return _scene_model(data).load(data, f"built-in scene {src!r}", overrides, validate_scene)
    path = Path(src)
    if not path.is_file():
        raise SceneError(src, f"not found, and not a built-in scene ({', '.join(builtin_scenes())})",
                         show_value=False, what="file")
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise SceneError(str(path), f"cannot be read ({exc.strerror})", show_value=False, what="file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError(str(path), f"not valid TOML: {exc}", show_value=False, what="file") from None
    table = data.setdefault("scene", {})
    if isinstance(table, dict) and table.get("name", "custom") == "custom":
        table["name"] = path.stem  # a file's scene is named after it
    return _scene_model(data).load(data, str(path), overrides, validate_scene)


def scene_to_toml(scene) -> str:
    return scene.to_toml() if hasattr(scene, "to_toml") else tomli_w.dumps(scene)


# ----------------------------------------------------------------------------- key documentation


def keys_table(markdown: bool = True, keys: tuple[Key, ...] | None = None) -> str:
    """Every key of ``keys`` (default: the top's) with its unit, default and rule:
    the body of docs/scenes.md and of ``liethermo keys``."""
    if keys is None:
        from .models import get_model

        keys = get_model(UNMARKED_MODEL()).keys()
    lines = []
    for section in dict.fromkeys(k.section for k in keys):
        ks = [k for k in keys if k.section == section]
        if markdown:
            lines += [f"### [{section}]", "", "| key | unit | default | rule | meaning |",
                      "|---|---|---|---|---|"]
            for k in ks:
                lines.append(f"| `{k.path}` | {_md_cell(k.unit) or '—'} | `{_toml_value(k.default)}` | "
                             f"{_md_cell(k.rule)} | {_md_cell(k.doc)} |")
            lines.append("")
        else:
            lines.append(f"[{section}]")
            for k in ks:
                unit = f" [{k.unit}]" if k.unit and k.unit != "1" else ""
                lines.append(f"  {k.path}{unit} = {_toml_value(k.default)}   ({k.rule}) {k.doc}")
            lines.append("")
    return "\n".join(lines)


def _toml_value(v) -> str:
    """A value as one line of TOML."""
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return tomli_w.dumps({"v": v})[4:].strip()


def _md_cell(text: str) -> str:
    """Text as the content of a Markdown table cell: one line, with "|" (a
    cell border) and "<" (the start of an HTML tag) escaped."""
    return text.replace("\n", " ").replace("<", "&lt;").replace("|", "\\|")


#: the command that writes docs/scenes.md
SCENES_MARKDOWN_COMMAND = "python -m liethermo.cli keys --markdown > docs/scenes.md"

def UNMARKED_MODEL() -> str:  # noqa: N802  (the registry's constant, read late)
    from .models import UNMARKED_SCENES_MODEL

    return UNMARKED_SCENES_MODEL


def scenes_markdown() -> str:
    """The text of docs/scenes.md: the built-in scenes, then every model's
    introduction and keys with their units, defaults and rules (the top's first)."""
    from .models import models

    ms = sorted(models(), key=lambda m: m.name != UNMARKED_MODEL())
    first = ms[0].scene_model
    lines = ["# Scenes and their keys", "",
             f"<!-- Generated from the models' scene keys by `{SCENES_MARKDOWN_COMMAND}`; "
             "edit the keys, a model term's scene_doc or a model's scene intro, not this file. -->", "",
             first.intro.rstrip("\n"), "",
             "## Built-in scenes", "",
             "`liethermo run NAME` runs one; the files are in `src/liethermo/scenes/`.", "",
             "| scene | description |", "|---|---|"]
    for name, description in builtin_scenes().items():
        lines.append(f"| `{name}` | {_md_cell(description)} |")
    lines += ["", "## Keys", "",
              "Units are SI; 1 marks a dimensionless number, — a key without a unit.", "",
              keys_table(markdown=True, keys=first.keys).rstrip("\n")]
    for m in (m.scene_model for m in ms[1:]):
        lines += ["", f"## Keys of {m.title}", "", m.intro.rstrip("\n"), "",
                  keys_table(markdown=True, keys=m.keys).replace("### [", f"### {m.name} scene: [").rstrip("\n")]
    return "\n".join(lines) + "\n"
