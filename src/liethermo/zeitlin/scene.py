"""Scenes of the thermodynamic Zeitlin fluid: keys, defaults, rules.

A scene with a ``[zeitlin]`` table is a Zeitlin fluid (the built-in
``zeitlin_decay`` and ``zeitlin_ideal`` are two).  Its keys are checked with
the same rules and messages as the top's (:mod:`liethermo.scene`); the
result is a :class:`ZeitlinScene`, which reads like the top's Scene
(``scene["integrator"]["h"]``, ``scene.name``).
"""

from __future__ import annotations

import numpy as np

from ..numerics.compositions import COMPOSITION_KINDS
from ..scene import (Key, SceneError, TableScene, boolean, choice, compare_check, declare_scene, integer, number,
                     string)

#: the methods a Zeitlin scene runs (names as for the top)
METHODS = ("split", "split4", "split6", "rk4", "reference")
INITIAL_KINDS = ("random", "rossby_haurwitz", "file")
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
        "rotation (l = 1), plus a random field of about the fraction initial.noise of the energy, the sum "
        "scaled to initial.energy; file: "
        "the coefficients ω_lm of initial.file, as they are (initial.lmax, m, energy, slope and noise do "
        "not apply)",
        choice(*INITIAL_KINDS)),
    Key("initial", "file", "", "", "a path (.nc, .npz, .npy), or empty",
        "kind = \"file\": the vorticity's spherical-harmonic coefficients C[l, m] = ω_lm in s-1 (m ≥ 0; "
        "shape (L+1, L+1): one field for every member, or (members, L+1, L+1)); a relative path is "
        "relative to the working folder; formats: docs/api.md, \"Your own initial data\"",
        string),
    Key("initial", "sha256", "", "", "64 hex digits, or empty",
        "the sha256 of initial.file, filled in when the scene is loaded and stored with the run: a "
        "resume, or a scene that gives it, is refused if the file has changed since", string),
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
        "further methods run on the same scene (files <OUT>_<method>.nc)", compare_check(METHODS)),
    Key("output", "figures", False, "", "true | false", "write PNG figures next to the netCDF", boolean),
    Key("output", "member_chunk", 64, "1", "integer ≥ 1",
        "members simulated and written at a time (bounds memory; a resumed run continues from the "
        "last complete chunk)", integer()),
)


class ZeitlinScene(TableScene):
    """A validated Zeitlin scene: sections of keys, read like TOML tables."""

    model = "zeitlin"

    def __repr__(self) -> str:
        return f"ZeitlinScene({self.name!r}, N={self._t['zeitlin']['N']}, method={self._t['integrator']['method']!r})"


def is_zeitlin(source) -> bool:
    """Whether scene tables (or a scene) describe a Zeitlin fluid: it has a [zeitlin] table."""
    if isinstance(source, ZeitlinScene):
        return True
    return isinstance(source, dict) and "zeitlin" in source


def _initial_file_rules(clean: dict) -> None:
    """initial.file is read (and checked) with kind "file" only; its sha256 is filled in."""
    ini = clean["initial"]
    if ini["kind"] != "file":
        for key in ("file", "sha256"):
            if ini[key]:
                raise SceneError(f"initial.{key}", 'is read only with initial.kind = "file"', ini[key])
        return
    if not ini["file"]:
        raise SceneError("initial.file", 'initial.kind = "file" needs the path of a coefficient file',
                         ini["file"])
    from .field import read_field

    C, digest = read_field("initial.file", ini["file"], clean["zeitlin"]["N"], ini["sha256"])
    members = clean["ensemble"]["members"]
    if C.shape[0] > 1 and C.shape[0] != members:
        raise SceneError("ensemble.members", f"must equal the {C.shape[0]} fields of initial.file "
                         f"{ini['file']} (or give one field for every member)", members)
    ini["sha256"] = digest


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


def _refuse(new: dict) -> None:
    fluid = new.get("fluid")
    if isinstance(fluid, dict) and "viscosity" in fluid:
        raise SceneError("fluid.viscosity", "a Zeitlin fluid's viscosity is fluid.kinematic_viscosity "
                         "(ν in s-1); fluid.viscosity is the top's dynamic viscosity (kg m-1 s-1)",
                         show_value=False)


INTRO = """\
A scene with a `[zeitlin]` table is a thermodynamic Zeitlin fluid on the sphere (docs/model.md,
"A second Lie group: the thermodynamic Zeitlin fluid"): the vorticity is a matrix W in su(N), viscosity turns its energy into heat.
It has keys of its own, below; sections it shares with the top (`[fluid]`, `[thermo]`, `[initial]`,
`[integrator]`, `[ensemble]`, `[output]`) hold only the keys listed here.  Its methods are `split`,
`split4`, `split6`, `rk4` and `reference`."""

#: the variables a Zeitlin run always writes (diagnostics of every stored time, the members' runs) ...
DEFAULT_VARIABLES = ("energy", "heat", "total_energy", "energy_error", "entropy", "temperature", "enstrophy",
                     "casimir", "casimir_drift", "angular_momentum", "energy_spectrum", "fixed_point_iterations",
                     "status", "failed_step", "initial_vorticity_real", "initial_vorticity_imag")
#: ... and the names ``output.variables`` takes: those, and the vorticity matrix W
#: (the group ``vorticity``, which ``output.vorticity = true`` also stores)
VARIABLES = {**{v: (v,) for v in DEFAULT_VARIABLES}, "vorticity": ("vorticity_real", "vorticity_imag"),
             "vorticity_real": ("vorticity_real",), "vorticity_imag": ("vorticity_imag",)}

#: the scene side of the fluid's model (registered with it: liethermo.zeitlin.model)
SCENE_MODEL = declare_scene("zeitlin", KEYS, methods=METHODS, marks=is_zeitlin, title="a Zeitlin fluid",
                            intro=INTRO, scene_class=ZeitlinScene, refuse=_refuse, check=_initial_file_rules, adjust=_follow_n,
                            noun="a Zeitlin scene", variables=VARIABLES,
                            switches={"vorticity": "output.vorticity"})
load = SCENE_MODEL.load
