"""The heavy top's scene: its keys (body, fluid terms, thermodynamics, initial
data, integrator, ensemble, output), their rules, and the typed, immutable
:class:`Scene` they validate into.

:data:`KEYS` is the one description of every key of a top's scene — default,
unit, rule, meaning — from which the defaults, the validation messages, the
command line's ``liethermo keys`` and ``docs/scenes.md`` are produced.  The
resolution order and the loading of files and overrides are the run layer's
(:func:`liethermo.scene.load_scene`); this module validates what it resolved.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import numpy as np
import tomli_w

from ..scene import (VARIABLES_DOC, Key, SceneError, SceneModel, _freeze, _merge, _overrides_as_tables, _thaw,
                     apply_switches, boolean, choice, integer, number, string, variables_key, vector, word_or)
from .methods import COMPOSITION_KINDS, ENTROPY_UPDATES, FRICTION, METHODS, STARTS

#: most Newton iterations a step may take: a converging solve takes fewer than 30
#: even at h|Ω| ≈ 1; the bound keeps a solve that does not converge from making
#: one kernel call of the run driver (≈ 0.1 s) outlast a stop signal for long
NEWTON_MAXITER_LIMIT = 200




def _inertia_check(name, v, scene):
    I = np.asarray(vector((3,), positive=True)(name, v, scene))
    if np.any(2 * I > I.sum() * (1 + 1e-12)):
        raise SceneError(name, "principal moments of a rigid body satisfy the triangle "
                         "inequality I_i ≤ I_j + I_k", v)
    return I.tolist()


_inertia_check.__doc__ = "[I1, I2, I3] in kg m2"
_com_check = vector((3,))
_com_check.__doc__ = "[x, y, z] in m"
_mass_check = number(0.0, lo_open=True)
_mass_check.__doc__ = "a mass in kg"
_cv_check = number(0.0, lo_open=True)
_cv_check.__doc__ = "a heat capacity in J/K"


def _rotation_check(name, v, scene):
    R = np.asarray(vector((3, 3))(name, v, scene))
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-12 or abs(np.linalg.det(R) - 1.0) > 1e-12:
        raise SceneError(name, "must be a rotation matrix (RᵀR = I to 1e-12, det R = +1)", v)
    return R.tolist()


def _spin_range_check(name, v, scene):
    sr = vector((2,))(name, v, scene)
    if not 0 <= sr[0] <= sr[1]:
        raise SceneError(name, "must be [lo, hi] with 0 ≤ lo ≤ hi", v)
    return sr


def _compare_check(name, v, scene):
    if not isinstance(v, list) or any(not isinstance(c, str) or c not in METHODS for c in v):
        raise SceneError(name, f"must be a list of methods from {sorted(METHODS)}", v)
    return list(v)


def _tol_check(name, v, scene):
    return number(0.0, 1e-3, lo_open=True, hi_open=True)(name, v, scene)


E1_ROTATION = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]

#: The scene keys of the body, the thermodynamics, the initial data, the
#: integrator, the ensemble and the output; the model terms add theirs
#: (:data:`KEYS`).  Defaults are the paper's body and fluid with the
#: integrator choices recommended for new scenes.
CORE_KEYS: tuple[Key, ...] = (
    Key("scene", "name", "custom", "", "a string", "name of the scene (files are named after it)", string),
    Key("scene", "description", "", "", "a string", "one line on what the scene is", string),
    Key("body", "shape", "hemispheres", "", '"hemispheres" | "ellipsoid"',
        "the body: the paper's top (a solid upper and a hollow lower hemisphere) or a "
        "triaxial ellipsoid; keys that do not apply to a shape take its own defaults",
        choice("hemispheres", "ellipsoid")),
    Key("body", "radius", 0.05, "m", "> 0", "hemispheres: radius a (also of the Stokes sphere)",
        number(0.0, lo_open=True)),
    Key("body", "semi_axes", [0.06, 0.05, 0.04], "m", "[a1, a2, a3], each > 0",
        "ellipsoid: semi-axes along the body axes (principal axes)", vector((3,), positive=True)),
    Key("body", "density", 2700.0, "kg m-3", "> 0", "density of the material (mass of a uniform body)",
        number(0.0, lo_open=True)),
    Key("body", "mass", "shape", "kg", '"shape" | > 0',
        'total mass; "shape": density × volume', word_or("shape", _mass_check)),
    Key("body", "molar_mass", 26.981539e-3, "kg mol-1", "> 0",
        "molar mass of the material (Dulong–Petit heat capacity 3 (m/M) R)", number(0.0, lo_open=True)),
    Key("body", "upper_mass_fraction", 0.6, "1", "in [0, 1]",
        "hemispheres: mass fraction of the solid upper hemisphere", number(0.0, 1.0)),
    Key("body", "inertia", "shape", "kg m2", '"shape" | [I1, I2, I3], each > 0, I_i ≤ I_j + I_k',
        'principal moments about the fixed point; "shape": the shape\'s own (hemispheres: the '
        "paper's printed values; ellipsoid: uniform density, m(a2² + a3²)/5 …)",
        word_or("shape", _inertia_check, aliases=("paper",))),
    Key("body", "center_of_mass", "shape", "m", '"shape" | [x, y, z]',
        'centre of mass G in the body frame, from the fixed point; "shape": hemispheres '
        "(0, 0, 3m1a/(8m) − m2a/(2m)); ellipsoid: the centre (no gravity torque). An "
        "ellipsoid's centre is at G, so a G ≠ 0 also drags its centre through the fluid",
        word_or("shape", _com_check, aliases=("hemispheres",))),
    Key("thermo", "T0", 300.0, "K", "> 0", "reference temperature θ(S_0) of the internal energy: the initial "
        "temperature unless body.thermal_expansion > 0, which starts T lower by φφ'Ω·𝕀₀Ω "
        "(coupled_egg: 299.4 K)", number(0.0, lo_open=True)),
    Key("thermo", "S0", 0.0, "J K-1", "finite", "initial entropy", number()),
    Key("thermo", "heat_capacity", "material", "J K-1", '"material" | > 0',
        'heat capacity c_v of the body (the fluid\'s is not counted); "material": Dulong–Petit 3 (m/M) R of the body\'s mass m',
        word_or("material", _cv_check)),
    Key("initial", "omega", [0.0, 1.0, 1.0], "rad s-1", "[Ω1, Ω2, Ω3], finite",
        "initial body angular velocity Ω(0)", vector((3,))),
    Key("initial", "R", E1_ROTATION, "1", "a rotation matrix",
        "initial attitude R(0) (body to space); Γ(0) = R(0)ᵀ e3", _rotation_check),
    Key("initial", "file", "", "", "a path (.nc, .npz, .npy), or empty",
        "Ω(0) in rad s-1 and, if it has them, the attitudes R(0) of every member, from a file "
        "(initial_omega (members, 3), initial_attitude (members, 3, 3)); ensemble.members must "
        "equal its members, initial.omega is not used, initial.R only where the file has no "
        "attitudes; a relative path is relative to the working folder (docs/api.md, \"Your own "
        "initial data\")", string),
    Key("initial", "sha256", "", "", "64 hex digits, or empty",
        "the sha256 of initial.file, filled in when the scene is loaded and stored with the run: a "
        "resume, or a scene that gives it, is refused if the file has changed since", string),
    Key("integrator", "method", "vi", "", " | ".join(f'"{m}"' for m in METHODS),
        "the integrator (see docs/model.md): the variational integrator in node form and its "
        "order-4 and order-6 compositions, the explicit thermodynamic splitting and its "
        "compositions, explicit RK2/RK4, the DOP853 reference",
        choice(*METHODS)),
    Key("integrator", "h", 0.1, "s", "> 0", "time step", number(0.0, lo_open=True)),
    Key("integrator", "steps", 300, "1", "integer ≥ 1", "number of steps", integer()),
    Key("integrator", "friction", "trapezoid", "", " | ".join(f'"{f}"' for f in FRICTION),
        "vi: discrete friction (the paper's trapezoid, or endpoint); vi4/vi6 use trapezoid",
        choice(*FRICTION)),
    Key("integrator", "start", "legendre", "", " | ".join(f'"{s}"' for s in STARTS),
        "vi: first step — legendre: node momentum μ0 = 𝕀Ω(0) (second order); node: the paper's "
        "Ω0 := Ω(0) as first step velocity (first order); staggered: Ω0 := Ω(h/2) from the "
        "reference.  vi4/vi6 always start from μ0 = 𝕀Ω(0)", choice(*STARTS)),
    Key("integrator", "entropy", "symmetric", "", " | ".join(f'"{e}"' for e in ENTROPY_UPDATES),
        "vi: entropy update — symmetric: U(S') − U(S) = the friction work of the step; explicit: "
        "the paper's S' = S + h P/T(S).  vi4/vi6 always use symmetric", choice(*ENTROPY_UPDATES)),
    Key("integrator", "composition", "small_error", "", " | ".join(f'"{c}"' for c in COMPOSITION_KINDS),
        "vi4, vi6, split4, split6: how the order-2 step is composed — small_error: Suzuki's 5 "
        "substeps (order 4) and Kahan and Li's 9 (order 6); triple_jump: Yoshida's triple jump "
        "(3 substeps, order 4) and its triple jump (9, order 6), whose error constants and "
        "negative substeps are larger", choice(*COMPOSITION_KINDS)),
    Key("integrator", "newton_tol", 1e-14, "1", "in (0, 1e-3)",
        "relative step tolerance of the Newton iteration", _tol_check),
    Key("integrator", "newton_maxiter", 30, "1", f"integer in [1, {NEWTON_MAXITER_LIMIT}]",
        "Newton iterations before a step counts as failed (a converging solve needs fewer than 30; "
        "the bound keeps one kernel call short enough to stop on a signal)",
        integer(1, NEWTON_MAXITER_LIMIT)),
    Key("ensemble", "members", 1, "1", "integer ≥ 1",
        "members; with more than one, initial conditions are drawn from the seed", integer()),
    Key("ensemble", "seed", 0, "1", "integer ≥ 0", "seed of the random initial conditions",
        integer(0)),
    Key("ensemble", "device", "cpu", "", '"cpu" | "gpu"',
        "where the steps run: gpu runs every method but the reference on a CUDA device "
        "(numba-cuda, one thread per member), with the same results bit for bit; refused before "
        "any work where no device can run it", choice("cpu", "gpu")),
    Key("ensemble", "spin_range", [0.5, 1.5], "1", "[lo, hi], 0 ≤ lo ≤ hi",
        "|Ω(0)| drawn uniformly in this range × |initial.omega|", _spin_range_check),
    Key("output", "every", 1, "1", "integer ≥ 1 dividing integrator.steps",
        "keep every k-th step", integer()),
    Key("output", "attitude", False, "", "true | false",
        "also integrate and store R (and the centre-of-mass path)", boolean),
    variables_key(lambda: variable_names(), VARIABLES_DOC + "; naming attitude or center_of_mass also "
                  "integrates R (as output.attitude = true), \"all\" does not"),
    Key("output", "compare", [], "", "list of methods",
        "further methods run on the same scene (files <OUT>_<method>.nc)", _compare_check),
    Key("output", "figures", False, "", "true | false", "write PNG figures next to the netCDF",
        boolean),
    Key("output", "member_chunk", 65536, "1", "integer ≥ 1",
        "members simulated and written at a time (bounds memory)", integer()),
)



#: The variables of a top's run file.  A file always holds the state the method
#: integrates, as its kernels carry it (:data:`STATE_VARIABLES`: those of the
#: method's state layout), the members' run (:data:`RUN_VARIABLES`) and the
#: parameters; every other variable derives from those bit for bit
#: (``ds.liethermo.derived()``) and is stored only when ``output.variables`` names it.
STATE_VARIABLES = {"omega": "omega", "omega_step": "omega_step", "momentum": "angular_momentum",
                   "gamma": "gamma", "sigma": "entropy_change", "heat": "heat", "attitude": "attitude"}
RUN_VARIABLES = ("status", "failed_at_step", "steps_done", "max_h_omega", "newton_iterations_mean",
                 "newton_iterations_max")
#: the derived variables, and (for ``initial.file`` scenes, whose data live in a file) the stored ones
DERIVED_VARIABLES = ("omega", "angular_momentum", "angular_momentum_norm", "vertical_angular_momentum", "entropy",
                     "temperature", "kinetic_energy", "potential_energy", "internal_energy", "total_energy",
                     "energy_error", "energy_error_paper", "mechanical_energy_initial", "initial_omega",
                     "initial_attitude", "center_of_mass")
#: named groups of variables ``output.variables`` takes
VARIABLE_GROUPS = {
    "energies": ("kinetic_energy", "potential_energy", "internal_energy", "total_energy", "energy_error",
                 "energy_error_paper", "mechanical_energy_initial"),
    "thermodynamics": ("entropy", "temperature", "internal_energy"),
    "momentum": ("angular_momentum", "angular_momentum_norm", "vertical_angular_momentum"),
    "initial": ("initial_omega", "initial_attitude"),
}
#: the names that integrate the attitude R (as ``output.attitude = true``)
ATTITUDE_NAMES = ("attitude", "center_of_mass")


def parameter_names() -> tuple[str, ...]:
    """The variables of the members' parameters: the body's, then every term's."""
    from .kernels.terms import registry

    return ("inertia", "heat_capacity") + tuple(prm.variable_name for t in registry() for prm in t.parameters
                                                if prm.shape is not None and prm.variable_name)


def variable_names() -> dict[str, tuple[str, ...]]:
    """Every name ``output.variables`` takes: ``{name: (variable, ...)}``."""
    single = (tuple(STATE_VARIABLES.values()) + RUN_VARIABLES + DERIVED_VARIABLES + parameter_names())
    return {**{v: (v,) for v in single}, **VARIABLE_GROUPS}


def _term_key(setting) -> Key:
    """The scene key of a term's :class:`~liethermo.top.kernels.terms.Setting`."""
    check = number(setting.minimum, lo_open=setting.open)
    if setting.word:
        check.__doc__ = f"a number {setting.rule.split('| ')[-1]}"
        check = word_or(setting.word, check)
    return Key(setting.section, setting.name, setting.default, setting.unit, setting.rule,
               setting.doc, check)


def _all_keys() -> tuple[Key, ...]:
    """The core keys with every term's keys after the core keys of their
    section (a section of its own goes before [thermo])."""
    from .kernels.terms import registry

    term_keys = [_term_key(st) for t in registry() for st in t.settings]
    sections = list(dict.fromkeys(k.section for k in CORE_KEYS))
    for k in term_keys:
        if k.section not in sections:
            sections.insert(sections.index("thermo"), k.section)
    out: list[Key] = []
    for sec in sections:
        out += [k for k in CORE_KEYS if k.section == sec]
        out += [k for k in term_keys if k.section == sec]
    return tuple(out)


#: Every scene key: :data:`CORE_KEYS` and the keys the model terms own.
KEYS: tuple[Key, ...] = _all_keys()
SECTIONS: tuple[str, ...] = tuple(dict.fromkeys(k.section for k in KEYS))
KEY_INDEX: dict[str, Key] = {k.path: k for k in KEYS}


def _defaults() -> dict:
    out: dict[str, dict] = {s: {} for s in SECTIONS}
    for k in KEYS:
        out[k.section][k.name] = copy.deepcopy(k.default)
    return out


DEFAULTS: dict[str, dict[str, Any]] = _defaults()


# ----------------------------------------------------------------------------- the typed scene


class _Section:
    """Mixin: a section reads like its TOML table."""

    def __getitem__(self, key: str):
        try:
            return getattr(self, key)
        except AttributeError:
            raise KeyError(key) from None

    def __contains__(self, key: str) -> bool:
        return key in self.keys()

    def keys(self):
        return [f.name for f in dataclasses.fields(self)]

    def items(self):
        return [(k, getattr(self, k)) for k in self.keys()]

    def __iter__(self):
        return iter(self.keys())


def _annotation(k: Key):
    """The type of a key's values in the typed scene (lists are tuples)."""
    if isinstance(k.default, str) and k.rule.startswith('"') and " | " in k.rule and not all(
            part.strip().startswith('"') for part in k.rule.split("|")):
        return "str | float | tuple"  # a word or a value
    return {bool: bool, int: int, float: float, str: str, list: tuple}.get(type(k.default), Any)


def _section_class(section: str):
    fields = [(k.name, _annotation(k)) for k in KEYS if k.section == section]
    cls = dataclasses.make_dataclass(section.capitalize() + "Section", fields, bases=(_Section,),
                                     frozen=True)
    cls.__module__ = __name__
    cls.__doc__ = f"The [{section}] section: " + ", ".join(
        f"{k.name} ({k.unit or '-'})" for k in KEYS if k.section == section)
    return cls


_SECTION_CLASSES = {sec: _section_class(sec) for sec in SECTIONS}


class _SceneMethods(_Section):
    """A resolved, validated scene (immutable).  Sections are attributes
    (``scene.body.shape``) and items (``scene["body"]["shape"]``); list values
    are tuples.  :meth:`with_overrides` makes a changed copy."""

    @property
    def name(self) -> str:
        return self.scene.name

    def to_dict(self) -> dict:
        """The scene as nested TOML tables (lists, not tuples)."""
        return {s: {k: _thaw(v) for k, v in getattr(self, s).items()} for s in SECTIONS}

    def to_toml(self) -> str:
        return tomli_w.dumps(self.to_dict())

    def with_overrides(self, overrides: dict | list | None) -> "Scene":
        """A validated copy with ``{"section.key": value}`` (or ``--set`` strings) applied."""
        return load(self.to_dict(), "the scene", overrides)

    def __deepcopy__(self, memo):
        return self


#: The typed scene: one frozen section per TOML table (:data:`SECTIONS`),
#: each with a field per key.
Scene = dataclasses.make_dataclass("Scene", [(sec, _SECTION_CLASSES[sec]) for sec in SECTIONS],
                                   bases=(_SceneMethods,), frozen=True)
Scene.__module__ = __name__
Scene.__doc__ = _SceneMethods.__doc__


def _scene_from_dict(d: dict) -> Scene:
    return Scene(**{s: _SECTION_CLASSES[s](**{k: _freeze(v) for k, v in d[s].items()})
                    for s in SECTIONS})




def validate(scene: dict) -> Scene:
    """Check every rule; raise SceneError naming the first key that breaks one.
    Returns the typed scene."""
    if isinstance(scene, Scene):
        scene = scene.to_dict()
    for section, table in scene.items():
        if section not in DEFAULTS or not isinstance(table, dict):
            raise SceneError(section, "unknown section", show_value=False)
        for key in table:
            if key not in DEFAULTS[section]:
                raise SceneError(f"{section}.{key}", "unknown key", show_value=False)
    clean = copy.deepcopy(DEFAULTS)
    for k in KEYS:
        clean[k.section][k.name] = k.check(k.path, scene[k.section][k.name], scene)
    apply_switches(clean, {"attitude": ATTITUDE_NAMES}, {"attitude": "output.attitude"}, every=False)
    _cross_rules(clean)
    return _scene_from_dict(clean)


def _cross_rules(s: dict) -> None:
    steps, every = s["integrator"]["steps"], s["output"]["every"]
    if steps % every:
        raise SceneError("output.every", f"must divide integrator.steps = {steps}", every)
    from .initial import check_file

    check_file(s)
    body = s["body"]
    if body["shape"] == "ellipsoid" and body["center_of_mass"] != "shape":
        G = np.asarray(body["center_of_mass"])
        if np.count_nonzero(G) > 1 and body["inertia"] == "shape":
            raise SceneError("body.center_of_mass", "an ellipsoid with its own inertia pivots "
                             "about a point on one of its axes: give G along a body axis, or "
                             "body.inertia explicitly", body["center_of_mass"])
    from .kernels.terms import registry

    for t in registry():
        for key, rule, value in t.violations(s):
            raise SceneError(key, rule, value)
    on = [t for t in registry() if t.in_scene(s)]
    for key, methods in (("integrator.method", [s["integrator"]["method"]]),
                         ("output.compare", s["output"]["compare"])):
        for m in methods:
            for t in on:
                why = t.refuses(METHODS[m])
                if why:
                    raise SceneError(key, f"method {m!r} cannot run the {t.name} term "
                                     f"({t.settings[0].path}): {why}", m)




SCENES_INTRO = """\
A scene is what a run simulates — the body, the fluid, gravity, the thermodynamics,
the initial data, the integrator, the ensemble and the output — as a TOML file of
sections and keys:

```toml
[integrator]
method = "vi4"
h = 0.05
```

**How a scene resolves.** Every key has a default (the tables below: the paper's
body and fluid, with the integrator choices recommended for new scenes). A built-in
scene name or a TOML file overrides some of them, and overrides given last win:
`--set SECTION.KEY=VALUE` on the command line (`VALUE` is a TOML value; a bare word
is taken as a string, also inside a list: `[rk4, vi]`), or `{"section.key": value}` in Python
(`liethermo.scene.load_scene(source, overrides)`):

    defaults  ←  built-in scene or TOML file  ←  --set SECTION.KEY=VALUE

```bash
liethermo run paper --set integrator.h=0.05 --set 'initial.omega=[2,-1,0.5]'
liethermo run examples/my_scene.toml -o out.nc --set integrator.method=rk4
```

Every rule below is checked before any work starts; a scene that breaks one is
rejected with one line naming the key and the rule (exit status 2, no output file).
Unknown sections and keys are errors too. `liethermo keys` prints these tables as
plain text.

**Choosing a model.** The kernels are compiled for the terms a scene needs and
nothing else (docs/model.md, "Model terms"):

* *The body* — `body.shape = "hemispheres"` is the paper's top: a ball of radius
  `body.radius` made of a solid upper and a thin hollow lower hemisphere, spinning
  about its centre, with the paper's printed inertia (docs/model.md, erratum E5).
  `body.shape = "ellipsoid"` is a triaxial ellipsoid with `body.semi_axes`, uniform
  density about its centre unless `body.mass`, `body.inertia` or `body.center_of_mass`
  say otherwise, pivoting at −G from its centre. Either shape takes explicit principal
  moments `body.inertia = [I1, I2, I3]`.
{terms}
* *No friction* — with every friction switched off nothing dissipates, and the
  entropy is not integrated (S stays S₀, T stays T₀).
* *The integrator* — `integrator.method`, and for `vi` the `start`, `friction` and
  `entropy` variants: their orders and the paper's choices are in docs/model.md
  ("The variational integrator", "Orders of convergence"). The paper scene uses the
  paper's choices (`start = "node"`, `entropy = "explicit"`).
"""


def _terms_markdown() -> str:
    """One bullet per model term (its ``scene_doc``), wrapped like the rest."""
    import textwrap

    from .kernels.terms import registry

    return "\n".join(textwrap.fill(t.scene_doc, 88, initial_indent="* ", subsequent_indent="  ")
                     for t in registry() if t.scene_doc)


def load(tables: dict, origin: str, overrides=None, validate_scene: bool = True):
    """A top's scene: :data:`DEFAULTS` ← ``tables`` (from ``origin``) ← ``overrides``,
    validated into a :class:`Scene` (or, with ``validate_scene`` False, as tables)."""
    scene = copy.deepcopy(DEFAULTS)
    _merge(scene, tables, origin, DEFAULTS)
    for table, where in _overrides_as_tables(overrides):
        _merge(scene, table, where, DEFAULTS)
    if not validate_scene:
        return scene
    return validate(scene)


#: the top's scenes for the run layer: a scene without another model's table is the top's
SCENE_MODEL = SceneModel(name="top", marks=lambda tables: False, load=load, scene_class=Scene, keys=KEYS,
                         title="the heavy top", intro=SCENES_INTRO.replace("{terms}", _terms_markdown()))
