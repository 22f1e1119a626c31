"""Scenes of the thermodynamic Zeitlin fluid: keys, defaults, rules.

A scene with a ``[zeitlin]`` table is a Zeitlin fluid (the built-in
``zeitlin_decay`` and ``zeitlin_ideal`` are two).  Its keys are checked with
the same rules and messages as the top's (:mod:`liethermo.scene`); the
result is a :class:`ZeitlinScene`, which reads like the top's Scene
(``scene["integrator"]["h"]``, ``scene.name``).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import tomli_w

from ..methods import COMPOSITION_KINDS
from ..scene import Key, OtherModel, SceneError, boolean, choice, integer, number, string

#: the methods a Zeitlin scene runs (names as for the top)
METHODS = ("split", "split4", "split6", "rk4", "reference")
INITIAL_KINDS = ("random", "rossby_haurwitz")
MAX_N = 1024


def _lmax_check(name, v, scene):
    v = integer(1)(name, v, scene)
    N = scene["zeitlin"]["N"]
    if isinstance(N, int) and v > N - 1:
        raise SceneError(name, f"must be at most zeitlin.N − 1 = {N - 1} (the degrees of su(N) are l = 1 … N−1): "
                         f"with zeitlin.N = {N} set initial.lmax ≤ {N - 1} too (it follows zeitlin.N only where "
                         "neither the scene nor an override sets it)", v)
    return v


def _m_check(name, v, scene):
    v = integer(0)(name, v, scene)
    lmax = scene["initial"]["lmax"]
    if isinstance(lmax, int) and v > lmax:
        raise SceneError(name, f"must be at most initial.lmax = {lmax} (|m| ≤ l): with initial.lmax = {lmax} "
                         f"set initial.m ≤ {lmax} too (it follows initial.lmax only where neither the scene nor "
                         "an override sets it)", v)
    return v


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _follow_n(d: dict, given: set) -> None:
    """The defaults that follow zeitlin.N: initial.lmax, where no scene or
    override sets it, is at most N − 1, and initial.m at most that lmax."""
    N, lmax = d["zeitlin"]["N"], d["initial"]["lmax"]
    if ("initial", "lmax") not in given and _is_int(N) and N >= 2 and _is_int(lmax):
        d["initial"]["lmax"] = lmax = min(int(lmax), int(N) - 1)
    m = d["initial"]["m"]
    if ("initial", "m") not in given and _is_int(lmax) and lmax >= 0 and _is_int(m):
        d["initial"]["m"] = min(int(m), int(lmax))


def _given(tables) -> set:
    return {(s, k) for s, t in tables.items() if isinstance(t, dict) for k in t} if isinstance(tables, dict) else set()


def _compare_check(name, v, scene):
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise SceneError(name, "must be a list of method names", v)
    for x in v:
        if x not in METHODS:
            raise SceneError(name, f"unknown method {x!r}; a Zeitlin scene runs {', '.join(METHODS)}", v)
    return list(v)


KEYS: tuple[Key, ...] = (
    Key("scene", "name", "zeitlin", "", "a string", "name of the scene (files are named after it)", string),
    Key("scene", "description", "", "", "a string", "one line on what the scene is", string),
    Key("zeitlin", "N", 32, "1", f"integer in [3, {MAX_N}]",
        "matrix size: the vorticity W ∈ su(N) holds the spherical harmonics of degree l = 1 … N−1",
        integer(3, MAX_N)),
    Key("fluid", "kinematic_viscosity", 1e-3, "s-1", "≥ 0",
        "kinematic viscosity ν on the unit sphere: Ẇ = (1/ħ)[P, W] + ν(Δ_N + 2)W", number(0.0)),
    Key("thermo", "heat_capacity", 1.0, "J K-1", "> 0", "heat capacity c_v of the fluid",
        number(0.0, lo_open=True)),
    Key("thermo", "T0", 300.0, "K", "> 0", "initial temperature", number(0.0, lo_open=True)),
    Key("initial", "kind", "random", "", " | ".join(f'"{k}"' for k in INITIAL_KINDS),
        "random: a random field of degrees 1 … lmax with the spectrum E_l ∝ l^(−slope), drawn per "
        "member from ensemble.seed; rossby_haurwitz: the mode (l = lmax, m) with solid-body "
        "rotation (l = 1), plus a random field of about the fraction initial.noise of the energy, "
        "the sum scaled to initial.energy",
        choice(*INITIAL_KINDS)),
    Key("initial", "lmax", 6, "1", "integer in [1, zeitlin.N − 1]",
        "highest degree of the initial field; left unset, 6 or zeitlin.N − 1 where that is smaller", _lmax_check),
    Key("initial", "m", 4, "1", "integer in [0, initial.lmax]",
        "rossby_haurwitz: the wave's order m; left unset, 4 or initial.lmax where that is smaller", _m_check),
    Key("initial", "energy", 1.0, "J", "> 0",
        "initial kinetic energy H(0) = ½∫|u|² dA of every member, its noise included (a layer of unit "
        "surface density on a sphere of radius 1 m); the same field at every zeitlin.N",
        number(0.0, lo_open=True)),
    Key("initial", "slope", 0.0, "1", "finite", "random: energy spectrum E_l ∝ l^(−slope) for l ≤ lmax",
        number()),
    Key("initial", "noise", 1e-3, "1", "in [0, 1)",
        "rossby_haurwitz: fraction of the energy given to the random field before the sum is scaled to "
        "initial.energy (it shares modes with the wave, so its share of H(0) is this to within about √noise)",
        number(0.0, 1.0, hi_open=True)),
    Key("integrator", "method", "split", "", " | ".join(f'"{m}"' for m in METHODS),
        "split: Strang splitting of the exact viscous-and-heat flow around the isospectral midpoint; "
        "split4/split6 its compositions; rk4; reference: DOP853 at tight tolerance", choice(*METHODS)),
    Key("integrator", "h", 0.01, "s", "> 0", "time step", number(0.0, lo_open=True)),
    Key("integrator", "steps", 1000, "1", "integer ≥ 1", "number of steps", integer()),
    Key("integrator", "composition", "small_error", "", " | ".join(f'"{c}"' for c in COMPOSITION_KINDS),
        "split4, split6: Suzuki's (order 4) and Kahan and Li's (order 6) compositions, or Yoshida's "
        "triple jumps", choice(*COMPOSITION_KINDS)),
    Key("integrator", "tol", 1e-15, "1", "in (0, 1e-3)",
        "split: the fixed-point iteration stops when its correction is below tol × max|W| "
        "(or stalls at round-off below 100 × that)", number(0.0, 1e-3, lo_open=True, hi_open=True)),
    Key("integrator", "max_iter", 100, "1", "integer in [1, 1000]",
        "split: fixed-point iterations before a step counts as failed (the member is flagged)",
        integer(1, 1000)),
    Key("ensemble", "members", 4, "1", "integer ≥ 1", "members (initial conditions drawn from the seed)",
        integer()),
    Key("ensemble", "seed", 0, "1", "integer ≥ 0", "seed of the random initial conditions", integer(0)),
    Key("ensemble", "device", "cpu", "", '"cpu" | "gpu"',
        "where the steps run: gpu runs every method but the reference on a CUDA device through CuPy, "
        "all members of a chunk at once; its results agree with the CPU's to round-off (BLAS products "
        "round differently), so a file holds one device's run; refused before any work where CuPy "
        "or a device is missing", choice("cpu", "gpu")),
    Key("output", "every", 10, "1", "integer ≥ 1 dividing integrator.steps", "keep every k-th step", integer()),
    Key("output", "vorticity", False, "", "true | false",
        "also store the vorticity matrix W (vorticity_real, vorticity_imag; "
        "liethermo.zeitlin.vorticity_coefficients(ds) gives its ω_lm)",
        boolean),
    Key("output", "compare", [], "", "list of methods",
        "further methods run on the same scene (files <OUT>_<method>.nc)", _compare_check),
    Key("output", "figures", False, "", "true | false", "write PNG figures next to the netCDF", boolean),
    Key("output", "member_chunk", 64, "1", "integer ≥ 1",
        "members simulated and written at a time (bounds memory; a resumed run continues from the "
        "last complete chunk)", integer()),
)
SECTIONS = tuple(dict.fromkeys(k.section for k in KEYS))
DEFAULTS: dict[str, dict[str, Any]] = {s: {k.name: k.default for k in KEYS if k.section == s} for s in SECTIONS}


class ZeitlinScene:
    """A validated Zeitlin scene: sections of keys, read like TOML tables."""

    model = "zeitlin"

    def __init__(self, tables: dict):
        self._t = {s: dict(tables[s]) for s in SECTIONS}

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
        return isinstance(other, ZeitlinScene) and other._t == self._t

    @property
    def name(self) -> str:
        return self._t["scene"]["name"]

    def to_dict(self) -> dict:
        return copy.deepcopy(self._t)

    def to_toml(self) -> str:
        return tomli_w.dumps(self._t)

    def with_overrides(self, overrides) -> "ZeitlinScene":
        return load(self._t, "the scene", overrides)

    def __repr__(self) -> str:
        return f"ZeitlinScene({self.name!r}, N={self._t['zeitlin']['N']}, method={self._t['integrator']['method']!r})"


def is_zeitlin(source) -> bool:
    """Whether scene tables (or a scene) describe a Zeitlin fluid: it has a [zeitlin] table."""
    if isinstance(source, ZeitlinScene):
        return True
    return isinstance(source, dict) and "zeitlin" in source


def merge(base: dict, new: dict, origin: str) -> None:
    """Merge scene tables into ``base``, refusing sections and keys a Zeitlin scene does not have."""
    from ..scene import _merge

    fluid = new.get("fluid") if isinstance(new, dict) else None
    if isinstance(fluid, dict) and "viscosity" in fluid:
        raise SceneError("fluid.viscosity", "a Zeitlin fluid's viscosity is fluid.kinematic_viscosity "
                         "(ν in s-1); fluid.viscosity is the top's dynamic viscosity (kg m-1 s-1)",
                         show_value=False)
    _merge(base, new, origin, DEFAULTS, " of a Zeitlin scene")


def load(tables: dict, origin: str, overrides=None, validate_scene: bool = True):
    """Defaults ← ``tables`` ← overrides, validated (or, with ``validate_scene``
    False, the merged tables)."""
    from ..scene import _overrides_as_tables

    d = copy.deepcopy(DEFAULTS)
    merge(d, tables, origin)
    given = _given(tables)
    for table, o in _overrides_as_tables(overrides):
        merge(d, table, o)
        given |= _given(table)
    _follow_n(d, given)
    return validate(d) if validate_scene else d


def validate(d: dict) -> ZeitlinScene:
    clean = copy.deepcopy(DEFAULTS)
    for s in SECTIONS:
        clean[s].update(d.get(s, {}))
    for k in KEYS:
        clean[k.section][k.name] = k.check(k.path, clean[k.section][k.name], clean)
    steps, every = clean["integrator"]["steps"], clean["output"]["every"]
    if steps % every:
        raise SceneError("output.every", f"must divide integrator.steps = {steps}", every)
    return ZeitlinScene(clean)


def keys_table() -> str:
    lines = []
    for s in SECTIONS:
        lines.append(f"[{s}]")
        for k in KEYS:
            if k.section == s:
                unit = f" [{k.unit}]" if k.unit and k.unit != "1" else ""
                lines.append(f"  {k.path}{unit} = {k.default!r}   ({k.rule}) {k.doc}")
        lines.append("")
    return "\n".join(lines)


INTRO = """\
A scene with a `[zeitlin]` table is a thermodynamic Zeitlin fluid on the sphere (docs/model.md,
"A second Lie group: the thermodynamic Zeitlin fluid"): the vorticity is a matrix W in su(N), viscosity turns its energy into heat.
It has keys of its own, below; sections it shares with the top (`[fluid]`, `[thermo]`, `[initial]`,
`[integrator]`, `[ensemble]`, `[output]`) hold only the keys listed here.  Its methods are `split`,
`split4`, `split6`, `rk4` and `reference`."""

#: the scene side of the fluid's model (registered with it: liethermo.zeitlin.model)
SCENE_MODEL = OtherModel(name="zeitlin", marks=is_zeitlin, load=load, scene_class=ZeitlinScene, keys=KEYS,
                         title="a Zeitlin fluid", intro=INTRO)
