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


def _is_bool(v) -> bool:
    """A Python or a numpy boolean."""
    return isinstance(v, (bool, np.bool_))


def _is_integer(v) -> bool:
    """A Python or a numpy integer (not a boolean, not a float that happens to be whole)."""
    return isinstance(v, (int, np.integer)) and not _is_bool(v)


def _is_number(v) -> bool:
    """A Python or a numpy integer or float (not a boolean, not complex)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not _is_bool(v)


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
        if not _is_integer(v):
            raise SceneError(name, "must be an integer", v)
        if v < minimum:
            raise SceneError(name, f"must be ≥ {minimum}", v)
        if maximum is not None and v > maximum:
            raise SceneError(name, f"must be ≤ {maximum}", v)
        return int(v)

    return check


def _has_bool(v) -> bool:
    if _is_bool(v):
        return True
    if isinstance(v, np.ndarray):
        return v.dtype == np.bool_
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
        return str(v)

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
    if not _is_bool(v):
        raise SceneError(name, "must be true or false", v)
    return bool(v)


def string(name, v, scene):
    if not isinstance(v, str):
        raise SceneError(name, "must be a string", v)
    return str(v)


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


# ----------------------------------------------------------------------------- what every model's scene has


def compare_check(methods: tuple[str, ...]):
    """The rule of ``output.compare``: a list of the model's ``methods``."""
    def check(name, v, scene):
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise SceneError(name, "must be a list of method names", v)
        for x in v:
            if x not in methods:
                raise SceneError(name, f"unknown method {x!r}; this model runs {', '.join(methods)}", v)
        return list(v)

    return check


#: the name of ``output.variables`` that asks for every variable a model can write
ALL_VARIABLES = "all"


def variables_key(names, doc: str) -> Key:
    """The key ``output.variables`` of a model: a list of names, each a variable
    or a named group of variables of ``names`` (``{name: (variable, ...)}``, or a
    function that gives it), or ``"all"``, stored beyond the model's default
    set.  An unknown name is refused with the valid ones."""

    def check(name, v, scene):
        if isinstance(v, str):
            v = [v]
        if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) for x in v):
            raise SceneError(name, f'must be "{ALL_VARIABLES}" or a list of variable names', v)
        valid = names() if callable(names) else names
        for x in v:
            if x != ALL_VARIABLES and x not in valid:
                known = ", ".join([f'"{ALL_VARIABLES}"'] + sorted(valid))
                raise SceneError(name, f"unknown variable {x!r}; valid names: {known}", show_value=False)
        return list(dict.fromkeys(v))

    return Key("output", "variables", [], "", f'"{ALL_VARIABLES}" | list of variable or group names', doc, check)


def requested_variables(scene, names) -> set[str] | None:
    """The variables ``output.variables`` of ``scene`` asks for, its groups
    expanded through ``names`` (``{name: (variable, ...)}``); None: every one."""
    out_table = scene["output"]
    asked = out_table["variables"] if "variables" in out_table else ()
    if ALL_VARIABLES in asked:
        return None
    out: set[str] = set()
    for x in asked:
        out.update(names.get(x, (x,)))
    return out


def run_keys(methods: tuple[str, ...], variables=None) -> tuple[Key, ...]:
    """The keys the run layer reads of every model's scene, for a model whose methods
    are ``methods`` (the first is the default); a model's key of the same path
    replaces one of these (its own default or meaning).  ``variables``: the
    names ``output.variables`` takes (:func:`variables_key`; the model's
    ``{name: (variable, ...)}``, or a function that gives it; none: ``"all"``
    only, for a model whose files hold every variable it has)."""
    out = (
        Key("scene", "name", "custom", "", "a string", "name of the scene (files are named after it)", string),
        Key("scene", "description", "", "", "a string", "one line on what the scene is", string),
        Key("integrator", "method", methods[0], "", " | ".join(f'"{m}"' for m in methods), "the integrator",
            choice(*methods)),
        Key("integrator", "h", 0.1, "s", "> 0", "time step", number(0.0, lo_open=True)),
        Key("integrator", "steps", 100, "1", "integer ≥ 1", "number of steps", integer()),
        Key("ensemble", "members", 1, "1", "integer ≥ 1", "members", integer()),
        Key("output", "every", 1, "1", "integer ≥ 1 dividing integrator.steps", "keep every k-th step", integer()),
        Key("output", "compare", [], "", "list of methods",
            "further methods run on the same scene (files <OUT>_<method>.nc)", compare_check(methods)),
        Key("output", "figures", False, "", "true | false", "write PNG figures next to the netCDF", boolean),
        Key("output", "member_chunk", 65536, "1", "integer ≥ 1",
            "members simulated and written at a time (bounds memory)", integer()),
    )
    return out + (variables_key(variables or {}, VARIABLES_DOC),)


#: what ``output.variables`` means, for every model
VARIABLES_DOC = ('variables stored beyond the model\'s default set: variable names, group names or "all" '
                 "(docs/netcdf.md lists each model's; ds.liethermo.derived() gives those a file does not hold "
                 "where the model derives them)")


#: the paths of :func:`run_keys`: what the run layer reads of every scene
RUN_KEY_PATHS = tuple(k.path for k in run_keys(("-",)))


class TableScene:
    """A validated scene of a model declared with :func:`declare_scene`: sections
    of keys, read like TOML tables (``scene["integrator"]["h"]``), immutable."""

    def __init__(self, tables: dict, load: Callable):
        self._t = {s: dict(t) for s, t in tables.items()}
        self._load = load

    def __getitem__(self, section: str) -> dict:
        return dict(self._t[section])

    def __contains__(self, section) -> bool:
        return section in self._t

    def keys(self):
        return self._t.keys()

    def __iter__(self):
        return iter(self._t)

    def items(self):
        return ((s, dict(t)) for s, t in self._t.items())

    def __eq__(self, other) -> bool:
        return type(other) is type(self) and other._t == self._t

    __hash__ = None

    @property
    def name(self) -> str:
        return self._t["scene"]["name"]

    def to_dict(self) -> dict:
        return copy.deepcopy(self._t)

    def to_toml(self) -> str:
        return tomli_w.dumps(self._t)

    def with_overrides(self, overrides):
        """A validated copy with ``{"section.key": value}`` (or ``--set`` strings) applied."""
        return self._load(self._t, "the scene", overrides)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, method={self._t['integrator']['method']!r})"


def _given(tables) -> set:
    """The (section, key) pairs that scene tables set."""
    return {(sec, k) for sec, t in tables.items() if isinstance(t, dict) for k in t} if isinstance(tables, dict) else set()


def declare_scene(name: str, keys: tuple[Key, ...], *, methods: tuple[str, ...], marks: Callable[[dict], bool],
                  title: str, intro: str = "", defaults: dict | None = None, scene_class: type = TableScene,
                  check: Callable[[dict], None] | None = None,
                  refuse: Callable[[dict], None] | None = None, noun: str | None = None,
                  adjust: Callable[[dict, set], None] | None = None, variables: dict | None = None,
                  switches: dict | None = None) -> SceneModel:
    """The scene side of a model from its own ``keys``: the keys every run reads
    (:func:`run_keys`, with ``defaults`` ``{"section.key": value}`` of the model's
    own) are added where the model does not declare them, after the model's keys of
    their section.  A scene is its defaults ← tables ← overrides, every key checked
    by its rule, ``output.every`` dividing ``integrator.steps``, then ``check(tables)``
    (rules across keys, raising :class:`SceneError`); ``refuse(tables)`` sees every
    table merged in first (a message for a key of another model).  ``noun`` names
    such a scene in messages ("a Zeitlin scene"; default ``title``).  ``adjust(tables,
    given)`` sets defaults that follow other keys, before the checks; ``given`` holds
    the (section, key) pairs the scene's tables and the overrides set.

    ``variables`` (``{name: (variable, ...)}``: every variable and group the
    model can store beyond its default set) are the names ``output.variables``
    takes (without them, ``"all"`` only);
    ``switches`` (``{name: "output.KEY"}``) names the boolean keys that store a
    group, which naming the group (or one of its variables, or ``"all"``) sets."""
    own = {k.path for k in keys}
    out = list(keys)
    for k in run_keys(tuple(methods), variables):
        if k.path in own:
            continue
        if defaults and k.path in defaults:
            k = dataclasses.replace(k, default=defaults[k.path])
        same = [i for i, x in enumerate(out) if x.section == k.section]
        out.insert(same[-1] + 1 if same else len(out), k)
    keys = tuple(out)
    sections = tuple(dict.fromkeys(k.section for k in keys))
    base = {sec: {k.name: copy.deepcopy(k.default) for k in keys if k.section == sec} for sec in sections}
    kind = f" of {noun or title}"

    def merge(into: dict, new: dict, origin: str) -> None:
        if refuse is not None and isinstance(new, dict):
            refuse(new)
        _merge(into, new, origin, base, kind)

    def validate(d: dict):
        clean = copy.deepcopy(base)
        for sec in sections:
            clean[sec].update(d.get(sec, {}))
        for k in keys:
            clean[k.section][k.name] = k.check(k.path, clean[k.section][k.name], clean)
        apply_switches(clean, variables or {}, switches or {})
        steps, every = clean["integrator"]["steps"], clean["output"]["every"]
        if steps % every:
            raise SceneError("output.every", f"must divide integrator.steps = {steps}", every)
        if check is not None:
            check(clean)
        return scene_class(clean, load)

    def load(tables: dict, origin: str, overrides=None, validate_scene: bool = True):
        d = copy.deepcopy(base)
        merge(d, tables, origin)
        given = _given(tables)
        for table, where in _overrides_as_tables(overrides):
            merge(d, table, where)
            given |= _given(table)
        if adjust is not None:
            adjust(d, given)
        return validate(d) if validate_scene else d

    return SceneModel(name=name, marks=marks, load=load, scene_class=scene_class, keys=keys, title=title,
                      intro=intro)


def apply_switches(clean: dict, variables: dict, switches: dict, every: bool = True) -> None:
    """Set the boolean output keys of ``switches`` (``{group: "output.KEY"}``) whose
    group ``output.variables`` of the validated tables ``clean`` names, itself, by
    one of its variables or (``every``) by ``"all"``: a switch and the names say
    the same thing, and the stored scene says it both ways."""
    asked = set(clean["output"].get("variables") or ())
    for group, path in switches.items():
        if group in asked or asked & set(variables.get(group, ())) or (every and ALL_VARIABLES in asked):
            section, key = path.split(".")
            clean[section][key] = True


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
        from .models import UNMARKED_SCENES_MODEL, get_model

        keys = get_model(UNMARKED_SCENES_MODEL).keys()
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

def scenes_markdown() -> str:
    """The text of docs/scenes.md: the built-in scenes, then every model's
    introduction and keys with their units, defaults and rules (the top's first)."""
    from .models import UNMARKED_SCENES_MODEL, models

    ms = sorted(models(), key=lambda m: m.name != UNMARKED_SCENES_MODEL)
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
