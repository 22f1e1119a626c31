"""Scenes: TOML descriptions of a run, their defaults, overrides and validation.

A scene is a two-level table ``{section: {key: value}}`` (SPEC §7).  Resolution
order: built-in defaults (the paper's values, SPEC §2) ← the TOML file ←
``--set SECTION.KEY=VALUE`` overrides.  :func:`validate` checks every rule of
SPEC §5 *before* any work starts and raises :class:`SceneError` naming the key
and the rule.  :func:`physical_parameters` turns a valid scene into the
kernel's parameter vector (SI units).
"""

from __future__ import annotations

import copy
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

import tomli_w

from .kernels.model import NPARAM, P_C, P_CV, P_GX, P_GY, P_GZ, P_I1, P_I2, P_I3, P_T0
from .methods import FRICTION, METHODS, STARTS

R_GAS = 8.314462618  # J mol⁻¹ K⁻¹ (SPEC §2)


class SceneError(ValueError):
    """An invalid scene: the message names the key and the rule it breaks."""

    def __init__(self, key: str, rule: str, value: Any = None, *, show_value: bool = True, what: str = "key"):
        self.key = key
        self.rule = rule
        msg = f"scene {what} '{key}': {rule}"
        if show_value:
            msg += f" (got {value!r})"
        super().__init__(msg)


#: Every known key, with its default (the paper scene, SPEC §2) and unit.
DEFAULTS: dict[str, dict[str, Any]] = {
    "scene": {"name": "custom", "description": ""},
    "body": {
        "radius": 0.05,  # m
        "density": 2700.0,  # kg m-3
        "molar_mass": 26.981539e-3,  # kg mol-1
        "upper_mass_fraction": 0.6,  # 1
        "inertia": "paper",  # "paper" or [I1, I2, I3] in kg m2
        "center_of_mass": "hemispheres",  # "hemispheres" or [x, y, z] in m
    },
    "fluid": {"viscosity": 0.1},  # kg m-1 s-1
    "gravity": {"g": 9.81},  # m s-2
    "thermo": {"T0": 300.0, "S0": 0.0},  # K, J K-1
    "initial": {
        "omega": [0.0, 1.0, 1.0],  # rad s-1 (body frame)
        "R": [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]],  # erratum E1
    },
    "integrator": {
        "method": "vi",
        "h": 0.1,  # s
        "steps": 300,
        "friction": "trapezoid",
        "start": "node",
        "newton_tol": 1e-14,
        "newton_maxiter": 30,
    },
    "ensemble": {
        "members": 1,
        "seed": 0,
        "spin_range": [0.5, 1.5],  # |Ω| drawn uniformly in this range × |initial.omega|
    },
    "output": {
        "every": 1,
        "attitude": False,  # also integrate and store R (needed for the centre-of-mass path)
        "compare": [],  # further methods run on the same scene (files OUT_<method>.nc)
        "figures": False,  # write PNG figures next to the netCDF
        "member_chunk": 65536,  # members simulated and written at a time (bounds memory)
    },
}

UNITS = {
    "body.radius": "m", "body.density": "kg m-3", "body.molar_mass": "kg mol-1",
    "body.upper_mass_fraction": "1", "body.inertia": "kg m2", "body.center_of_mass": "m",
    "fluid.viscosity": "kg m-1 s-1", "gravity.g": "m s-2", "thermo.T0": "K", "thermo.S0": "J K-1",
    "initial.omega": "rad s-1", "initial.R": "1", "integrator.h": "s",
}

#: Overrides that turn the defaults into the built-in paper scene.
PAPER_OVERRIDES = {
    "scene": {
        "name": "paper",
        "description": "Couéraud & Gay-Balmaz, Section 3: heavy top in Stokes flow "
        "(motor oil, aluminium ball of two hemispheres), h = 0.1 s, 30 s",
    },
    "output": {"attitude": True, "compare": ["rk2"], "figures": True},
}

BUILTIN = {"paper": PAPER_OVERRIDES}


def default_scene() -> dict:
    return copy.deepcopy(DEFAULTS)


def _merge(base: dict, new: dict, origin: str) -> None:
    for section, table in new.items():
        if section not in DEFAULTS:
            name = f"{section}.{next(iter(table))}" if isinstance(table, dict) and table else section
            raise SceneError(name, f"unknown section [{section}] in {origin}; known sections: "
                             f"{', '.join(sorted(DEFAULTS))}", show_value=False)
        if not isinstance(table, dict):
            raise SceneError(section, f"must be a table of keys in {origin}", table)
        for key, value in table.items():
            if key not in DEFAULTS[section]:
                raise SceneError(f"{section}.{key}", f"unknown key in {origin}; known keys of "
                                 f"[{section}]: {', '.join(sorted(DEFAULTS[section]))}",
                                 show_value=False)
            base[section][key] = value


def parse_override(text: str) -> tuple[str, str, Any]:
    """``SECTION.KEY=VALUE`` → (section, key, value); VALUE is a TOML value,
    and a bare word that is not valid TOML is taken as a string."""
    if "=" not in text:
        raise SceneError(text, "an override must read SECTION.KEY=VALUE", show_value=False)
    lhs, rhs = text.split("=", 1)
    lhs = lhs.strip()
    if lhs.count(".") != 1:
        raise SceneError(lhs, "an override key must read SECTION.KEY", show_value=False)
    section, key = lhs.split(".")
    try:
        value = tomllib.loads(f"v = {rhs.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = rhs.strip()
    return section, key, value


def load_scene(source: str | Path | dict | None = "paper", overrides: list[str] | dict | None = None,
               *, validate_scene: bool = True) -> dict:
    """Resolve a scene: defaults ← built-in name or TOML file (or dict) ← overrides."""
    scene = default_scene()
    if isinstance(source, dict):
        _merge(scene, source, "the scene")
    elif source is not None:
        src = str(source)
        if src in BUILTIN:
            _merge(scene, BUILTIN[src], f"built-in scene {src!r}")
        else:
            path = Path(src)
            if not path.is_file():
                raise SceneError(src, f"not found, and not a built-in scene ({', '.join(BUILTIN)})",
                                 show_value=False, what="file")
            try:
                data = tomllib.loads(path.read_text())
            except OSError as exc:
                raise SceneError(str(path), f"cannot be read ({exc.strerror})", show_value=False, what="file") from None
            except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
                raise SceneError(str(path), f"not valid TOML: {exc}", show_value=False, what="file") from None
            _merge(scene, data, str(path))
            if scene["scene"]["name"] == "custom":
                scene["scene"]["name"] = path.stem
    if overrides:
        if isinstance(overrides, dict):
            _merge(scene, overrides, "the overrides")
        else:
            for text in overrides:
                section, key, value = parse_override(text)
                _merge(scene, {section: {key: value}}, "--set")
    if validate_scene:
        validate(scene)
    return scene


def scene_to_toml(scene: dict) -> str:
    return tomli_w.dumps(scene)


# ----------------------------------------------------------------------------- validation

def _number(scene, section, key) -> float:
    v = scene[section][key]
    name = f"{section}.{key}"
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SceneError(name, "must be a number", v)
    if not math.isfinite(v):
        raise SceneError(name, "must be finite", v)
    return float(v)


def _integer(scene, section, key, minimum=1) -> int:
    v = scene[section][key]
    name = f"{section}.{key}"
    if isinstance(v, bool) or not isinstance(v, int):
        raise SceneError(name, "must be an integer", v)
    if v < minimum:
        raise SceneError(name, f"must be ≥ {minimum}", v)
    return int(v)


def _vector(scene, section, key, shape) -> np.ndarray:
    v = scene[section][key]
    name = f"{section}.{key}"
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
    return arr


def _has_bool(v) -> bool:
    if isinstance(v, bool):
        return True
    if isinstance(v, (list, tuple)):
        return any(_has_bool(x) for x in v)
    return False


def _choice(scene, section, key, choices) -> str:
    v = scene[section][key]
    if v not in choices:
        raise SceneError(f"{section}.{key}", f"must be one of {', '.join(map(repr, choices))}", v)
    return v


def validate(scene: dict) -> None:
    """Check every rule; raise SceneError naming the first key that breaks one."""
    for section, table in scene.items():
        for key in table:
            if section not in DEFAULTS or key not in DEFAULTS[section]:
                raise SceneError(f"{section}.{key}", "unknown key", show_value=False)
    for key in ("name", "description"):
        if not isinstance(scene["scene"][key], str):
            raise SceneError(f"scene.{key}", "must be a string", scene["scene"][key])
    for key in ("radius", "density", "molar_mass"):
        if _number(scene, "body", key) <= 0:
            raise SceneError(f"body.{key}", "must be > 0", scene["body"][key])
    f = _number(scene, "body", "upper_mass_fraction")
    if not 0.0 <= f <= 1.0:
        raise SceneError("body.upper_mass_fraction", "must lie in [0, 1]", f)
    inertia = scene["body"]["inertia"]
    if isinstance(inertia, str):
        if inertia != "paper":
            raise SceneError("body.inertia", 'must be "paper" or [I1, I2, I3] in kg m2', inertia)
    else:
        I = _vector(scene, "body", "inertia", (3,))
        if np.any(I <= 0):
            raise SceneError("body.inertia", "principal moments must be > 0 (kg m2)", inertia)
        s = I.sum()
        if np.any(2 * I > s * (1 + 1e-12)):
            raise SceneError("body.inertia", "principal moments of a rigid body satisfy the "
                             "triangle inequality I_i ≤ I_j + I_k", inertia)
    com = scene["body"]["center_of_mass"]
    if isinstance(com, str):
        if com != "hemispheres":
            raise SceneError("body.center_of_mass", 'must be "hemispheres" or [x, y, z] in m', com)
    else:
        _vector(scene, "body", "center_of_mass", (3,))
    if _number(scene, "fluid", "viscosity") < 0:
        raise SceneError("fluid.viscosity", "must be ≥ 0", scene["fluid"]["viscosity"])
    if _number(scene, "gravity", "g") < 0:
        raise SceneError("gravity.g", "must be ≥ 0", scene["gravity"]["g"])
    if _number(scene, "thermo", "T0") <= 0:
        raise SceneError("thermo.T0", "must be > 0 (kelvin)", scene["thermo"]["T0"])
    _number(scene, "thermo", "S0")
    _vector(scene, "initial", "omega", (3,))
    R = _vector(scene, "initial", "R", (3, 3))
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-12 or abs(np.linalg.det(R) - 1.0) > 1e-12:
        raise SceneError("initial.R", "must be a rotation matrix (RᵀR = I to 1e-12, det R = +1)",
                         scene["initial"]["R"])
    _choice(scene, "integrator", "method", sorted(METHODS))
    if _number(scene, "integrator", "h") <= 0:
        raise SceneError("integrator.h", "must be > 0 (seconds)", scene["integrator"]["h"])
    steps = _integer(scene, "integrator", "steps")
    _choice(scene, "integrator", "friction", sorted(FRICTION))
    _choice(scene, "integrator", "start", list(STARTS))
    tol = _number(scene, "integrator", "newton_tol")
    if not 0 < tol < 1e-3:
        raise SceneError("integrator.newton_tol", "must lie in (0, 1e-3)", tol)
    _integer(scene, "integrator", "newton_maxiter")
    _integer(scene, "ensemble", "members")
    _integer(scene, "ensemble", "seed", minimum=0)
    sr = _vector(scene, "ensemble", "spin_range", (2,))
    if not 0 <= sr[0] <= sr[1]:
        raise SceneError("ensemble.spin_range", "must be [lo, hi] with 0 ≤ lo ≤ hi", scene["ensemble"]["spin_range"])
    every = _integer(scene, "output", "every")
    if steps % every:
        raise SceneError("output.every", f"must divide integrator.steps = {steps}", every)
    for key in ("attitude", "figures"):
        if not isinstance(scene["output"][key], bool):
            raise SceneError(f"output.{key}", "must be true or false", scene["output"][key])
    comp = scene["output"]["compare"]
    if not isinstance(comp, list) or any(not isinstance(c, str) or c not in METHODS for c in comp):
        raise SceneError("output.compare", f"must be a list of methods from {sorted(METHODS)}", comp)
    _integer(scene, "output", "member_chunk")


# ----------------------------------------------------------------------------- physics

@dataclass(frozen=True)
class Body:
    """Derived physical quantities of a scene (SI units)."""

    mass: float  # kg
    inertia: np.ndarray  # kg m2, principal moments
    center_of_mass: np.ndarray  # m, body frame, from the fixed centre C
    stokes_coefficient: float  # c = 8πμa³, N m s
    heat_capacity: float  # c_v = 3 N0 R_gas, J K-1
    gravity_torque: np.ndarray  # mgℓχ = m g G, N m
    T0: float
    S0: float

    @property
    def ell(self) -> float:
        return float(np.linalg.norm(self.center_of_mass))


def body(scene: dict) -> Body:
    b = scene["body"]
    a = float(b["radius"])
    m = 4.0 / 3.0 * math.pi * a**3 * float(b["density"])
    m1 = float(b["upper_mass_fraction"]) * m
    m2 = m - m1
    if isinstance(b["inertia"], str):  # "paper" (erratum E5: the printed values, kept)
        I12 = 83.0 * a * a * m1 / 320.0 + a * a * m2 / 12.0
        I3 = 2.0 * a * a * m1 / 5.0 + a * a * m2 / 3.0
        inertia = np.array([I12, I12, I3])
    else:
        inertia = np.asarray(b["inertia"], dtype=np.float64)
    if isinstance(b["center_of_mass"], str):
        G = np.array([0.0, 0.0, 3.0 * m1 * a / (8.0 * m) - m2 * a / (2.0 * m)])
    else:
        G = np.asarray(b["center_of_mass"], dtype=np.float64)
    c = 8.0 * math.pi * float(scene["fluid"]["viscosity"]) * a**3
    cv = 3.0 * (m / float(b["molar_mass"])) * R_GAS
    return Body(mass=m, inertia=inertia, center_of_mass=G, stokes_coefficient=c, heat_capacity=cv,
                gravity_torque=m * float(scene["gravity"]["g"]) * G,
                T0=float(scene["thermo"]["T0"]), S0=float(scene["thermo"]["S0"]))


def physical_parameters(scene: dict) -> np.ndarray:
    """The kernel parameter vector (NPARAM,) of a scene."""
    bd = body(scene)
    p = np.empty(NPARAM)
    p[[P_I1, P_I2, P_I3]] = bd.inertia
    p[P_C] = bd.stokes_coefficient
    p[[P_GX, P_GY, P_GZ]] = bd.gravity_torque
    p[P_CV] = bd.heat_capacity
    p[P_T0] = bd.T0
    return p
