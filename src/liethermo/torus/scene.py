"""Scenes of the fluid on the torus: keys, defaults, rules.

A scene with a ``[torus]`` table is a Zeitlin fluid on the torus T² (the
built-in ``torus_euler``, ``torus_decay`` and ``torus_convection``).  Its keys
are checked with the rules and messages of every scene (:mod:`liethermo.scene`).
"""

from __future__ import annotations

from ..numerics.compositions import COMPOSITION_KINDS
from ..scene import (Key, SceneError, TableScene, boolean, choice, compare_check, declare_scene, integer, number,
                     string)

METHODS = ("cmp", "magmp", "isomp", "cmp4", "magmp4", "isomp4", "rk4", "reference")
INITIAL_KINDS = ("random", "kolmogorov", "taylor_green", "shell", "rest")
ENTROPY_KINDS = ("uniform", "patch", "random")
MAX_N = 511


def _n_check(name, v, scene):
    v = integer(5, MAX_N)(name, v, scene)
    if v % 2 == 0:
        raise SceneError(name, f"must be odd (2 must be invertible mod N for the clock-and-shift basis): "
                         f"use {v - 1} or {v + 1}", v)
    return v


def _kmax_check(name, v, scene):
    v = integer(1)(name, v, scene)
    N = scene["torus"]["N"]
    if isinstance(N, int) and v > (N - 1) // 2:
        raise SceneError(name, f"must be at most (torus.N − 1)/2 = {(N - 1) // 2} (the modes |m_i| ≤ M the "
                         "matrix holds)", v)
    return v


KEYS: tuple[Key, ...] = (
    Key("scene", "name", "torus", "", "a string", "name of the scene (files are named after it)", string),
    Key("scene", "description", "", "", "a string", "one line on what the scene is", string),
    Key("torus", "N", 31, "1", f"odd integer in [5, {MAX_N}]",
        "matrix size: W holds the Fourier modes |m₁|, |m₂| ≤ (N − 1)/2 of the vorticity on [0, 2π)²", _n_check),
    Key("fluid", "kinematic_viscosity", 0.0, "m2 s-1", "≥ 0", "kinematic viscosity ν: ω_t = {ω, ψ} + νΔω",
        number(0.0)),
    Key("thermo", "conductivity", 0.0, "W K-1", "≥ 0",
        "heat conductivity κ: the entropy gains Θ⁻¹∘κL′(Θ) (L′ the monotone conjugation Laplacian)",
        number(0.0)),
    Key("thermo", "buoyancy", 0.0, "K", "≥ 0",
        "buoyancy α: the potential energy −α∫Φ s dA, Φ = cos y; heat acts back on the flow", number(0.0)),
    Key("thermo", "areal_heat_capacity", 1.0, "J K-1 m-2", "> 0",
        "heat capacity per unit area c of the solid layer: internal energy c T₀ e^{s/c} per area",
        number(0.0, lo_open=True)),
    Key("thermo", "T0", 1.0, "K", "> 0", "temperature of zero entropy density: T = T₀ e^{s/c}",
        number(0.0, lo_open=True)),
    Key("initial", "kind", "random", "", " | ".join(f'"{k}"' for k in INITIAL_KINDS),
        "random: modes |m_i| ≤ initial.kmax drawn per member from ensemble.seed; kolmogorov: ω = −k cos ky; "
        "taylor_green: ω = 2 sin x sin y; shell: random modes of |m|² = initial.k; rest: W = 0 (each scaled to "
        "initial.energy, but rest)", choice(*INITIAL_KINDS)),
    Key("initial", "k", 1, "1", "integer ≥ 1", "kolmogorov: the wave number; shell: |m|²", integer(1)),
    Key("initial", "kmax", 4, "1", "integer in [1, (torus.N − 1)/2]",
        "random: the modes |m_i| ≤ kmax (the same coefficients at every N)", _kmax_check),
    Key("initial", "energy", 1.0, "J", "> 0",
        "kinetic energy ½∫|u|² dA of every member (unit surface density on the 2π-periodic square)",
        number(0.0, lo_open=True)),
    Key("initial", "entropy_kind", "uniform", "", " | ".join(f'"{k}"' for k in ENTROPY_KINDS),
        "uniform: s = 0 (with kind = \"rest\": the isothermal rest state Θ = θ₀); patch: s = a e^{−d²/2r²}, d the "
        "periodic distance to (π, π), projected onto the modes; random: modes |m_i| ≤ kmax of standard "
        "deviation a, per member", choice(*ENTROPY_KINDS)),
    Key("initial", "entropy_amplitude", 0.5, "J K-1 m-2", "≥ 0", "a: the entropy patch's height or the random "
        "entropy's standard deviation", number(0.0)),
    Key("initial", "entropy_radius", 0.6, "m", "> 0", "r: the entropy patch's radius", number(0.0, lo_open=True)),
    Key("initial", "theta0", 1.0, "K", "> thermo.buoyancy",
        "rest with a uniform entropy kind: the rest state's uniform Θ = θ₀", number(0.0, lo_open=True)),
    Key("integrator", "method", "cmp", "", " | ".join(f'"{m}"' for m in METHODS),
        "cmp: Strang V C I C V with the energy- and Casimir-exact Cayley midpoint; magmp: the same with the "
        "Lie–Poisson midpoint; isomp: magmp at α = 0; cmp4/magmp4/isomp4: the ideal step composed to order 4 "
        "(ν = κ = 0 only); rk4; reference: DOP853 at rtol 1e-12 (the studies' ground truth)", choice(*METHODS)),
    Key("integrator", "h", 0.01, "s", "> 0", "time step", number(0.0, lo_open=True)),
    Key("integrator", "steps", 1000, "1", "integer ≥ 1", "number of steps", integer()),
    Key("integrator", "composition", "triple_jump", "", " | ".join(f'"{c}"' for c in COMPOSITION_KINDS),
        "cmp4, magmp4, isomp4: Yoshida's triple jump or Suzuki's five stages", choice(*COMPOSITION_KINDS)),
    Key("integrator", "tol", 1e-14, "1", "in (0, 1e-3)",
        "the fixed point stops when its change is below tol × max|W| (or stops falling)",
        number(0.0, 1e-3, lo_open=True, hi_open=True)),
    Key("integrator", "max_iter", 100, "1", "integer in [1, 1000]",
        "fixed-point iterations before the member stops (status fixed_point_not_converged)", integer(1, 1000)),
    Key("ensemble", "members", 4, "1", "integer ≥ 1", "members (initial conditions drawn from the seed)",
        integer()),
    Key("ensemble", "seed", 0, "1", "integer ≥ 0", "seed of the random initial conditions", integer(0)),
    Key("ensemble", "device", "cpu", "", '"cpu" | "gpu"',
        "where the steps run: gpu runs every method but the reference on a CUDA device through CuPy "
        "(the kept outputs' diagnostics on the host; a file holds one device's run: the products round "
        "differently); refused before any work where CuPy or a device is missing", choice("cpu", "gpu")),
    Key("output", "every", 10, "1", "integer ≥ 1 dividing integrator.steps", "keep every k-th step", integer()),
    Key("output", "vorticity", False, "", "true | false",
        "also store W (vorticity_real, vorticity_imag); liethermo.torus.vorticity_modes(ds) gives ω_m", boolean),
    Key("output", "entropy_field", False, "", "true | false",
        "also store S (entropy_density_real, entropy_density_imag)", boolean),
    Key("output", "compare", [], "", "list of methods",
        "further methods run on the same scene (files <OUT>_<method>.nc)", compare_check(METHODS)),
    Key("output", "figures", False, "", "true | false", "write PNG figures next to the netCDF", boolean),
    Key("output", "theta_map", False, "", "true | false", "figures: add maps of Θ to those of T", boolean),
    Key("output", "animation", False, "", "true | false",
        "figures: also an animation of ω and T (GIF or MP4, whichever writer exists)", boolean),
    Key("output", "member_chunk", 16, "1", "integer ≥ 1",
        "members simulated and written at a time (a resumed run continues from the last complete chunk)",
        integer()),
)


class TorusScene(TableScene):
    """A validated torus scene: sections of keys, read like TOML tables."""

    model = "torus"

    def __repr__(self) -> str:
        return f"TorusScene({self.name!r}, N={self._t['torus']['N']}, method={self._t['integrator']['method']!r})"


def is_torus(source) -> bool:
    if isinstance(source, TorusScene):
        return True
    return isinstance(source, dict) and "torus" in source


def _refuse(new: dict) -> None:
    thermo = new.get("thermo")
    if isinstance(thermo, dict) and "heat_capacity" in thermo:
        raise SceneError("thermo.heat_capacity", "a torus scene's heat capacity is per unit area: "
                         "thermo.areal_heat_capacity (J K-1 m-2); thermo.heat_capacity is the top's (J K-1)",
                         show_value=False)


def _rules(clean: dict) -> None:
    th, ini, itg = clean["thermo"], clean["initial"], clean["integrator"]
    m = itg["method"]
    if m in ("cmp4", "magmp4", "isomp4") and (clean["fluid"]["kinematic_viscosity"] or th["conductivity"]):
        raise SceneError("integrator.method", "the order-4 composition runs at ν = κ = 0 only (its negative "
                         f"sub-step would run viscosity and conduction backwards): use {m[:-1]!r}", m)
    if m.startswith("isomp") and th["buoyancy"]:
        raise SceneError("integrator.method", "IsoMP has no buoyancy term: with thermo.buoyancy > 0 use \"magmp\" "
                         "or \"cmp\"", m)
    for other in clean["output"]["compare"]:
        if other in ("cmp4", "magmp4", "isomp4") and (clean["fluid"]["kinematic_viscosity"] or th["conductivity"]):
            raise SceneError("output.compare", f"{other!r} runs at ν = κ = 0 only", other)
        if other.startswith("isomp") and th["buoyancy"]:
            raise SceneError("output.compare", f"{other!r} has no buoyancy term (use \"magmp\")", other)
    if ini["kind"] == "rest" and ini["entropy_kind"] == "uniform" and not ini["theta0"] > th["buoyancy"]:
        raise SceneError("initial.theta0", f"the rest state needs θ₀ > thermo.buoyancy = {th['buoyancy']}",
                         ini["theta0"])


INTRO = """\
A scene with a `[torus]` table is Zeitlin's sine-bracket fluid on the torus
(docs/model.md, "The fluid on the torus"): vorticity W and entropy density S are N × N Hermitian matrices (N odd); viscosity heats the
fluid locally, heat is conducted, and buoyancy (Φ = cos y) carries it back into the flow.  Its methods are
`cmp`, `magmp`, `isomp`, `cmp4`, `magmp4`, `isomp4`, `rk4` and `reference`."""

#: the variables a torus run always writes (diagnostics of every stored time, the members' runs) ...
DEFAULT_VARIABLES = ("kinetic_energy", "internal_energy", "potential_energy", "total_energy", "energy_error",
                     "entropy", "enstrophy", "theta_min", "theta_max", "temperature_min", "temperature_max",
                     "casimir", "fixed_point_iterations", "status", "failed_step")
#: ... and the names ``output.variables`` takes: those, the vorticity W (group ``vorticity``,
#: also ``output.vorticity = true``) and the entropy density S (group ``entropy_field``,
#: also ``output.entropy_field = true``)
VARIABLES = {**{v: (v,) for v in DEFAULT_VARIABLES}, "vorticity": ("vorticity_real", "vorticity_imag"),
             "vorticity_real": ("vorticity_real",), "vorticity_imag": ("vorticity_imag",),
             "entropy_field": ("entropy_density_real", "entropy_density_imag"),
             "entropy_density_real": ("entropy_density_real",), "entropy_density_imag": ("entropy_density_imag",)}

SCENE_MODEL = declare_scene("torus", KEYS, methods=METHODS, marks=is_torus, title="a torus fluid", intro=INTRO,
                            scene_class=TorusScene, refuse=_refuse, check=_rules, noun="a torus scene",
                            variables=VARIABLES,
                            switches={"vorticity": "output.vorticity", "entropy_field": "output.entropy_field"})
load = SCENE_MODEL.load
