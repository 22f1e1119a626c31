"""The model layer: scenes choose their physics, and each model's laws hold.

* which terms a scene compiles (absent terms are not in the model);
* the ellipsoid: uniform inertia, Jeffery's resistance (sphere limit);
* the coupled top 𝕀(S): energy conservation of the continuous model, the
  variational integrator's reduction to the decoupled scheme at α → 0;
* double-bracket friction: |μ| a Casimir, the flat spin on the major axis,
  energy lost = heat gained;
* scene validation of the new keys.
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from conftest import OMEGA0, R0, paper_physics
from liethermo.top.methods import MethodChoice
from liethermo.top.dataset import initial_energy, node_energies
from liethermo.top.kernels.terms.stokes import jeffery_resistance, oberbeck_resistance, pivot_drag
from liethermo.top.physics import build_model, physics_of_scene
from liethermo.scene import SceneError, builtin_scenes, load_scene
from liethermo.top.simulate import STATUS_OK, simulate


def _scene_ic(scene):
    return np.array([scene.initial.omega]), np.array([scene.initial.R])


def _energy_error(tr, om0, R):
    e = node_energies(tr)
    K0, V0 = initial_energy(tr.physics, om0, R)
    return (e["K"] - K0[:, None]) + (e["V"] - V0[:, None]) + e["dU"]


# ------------------------------------------------------------------ terms a scene compiles
@pytest.mark.parametrize("name,terms", [
    ("paper", ["ConstantInertia", "IdealSolid", "StokesSphere", "Gravity", "Attitude"]),
    ("spherical_top", ["ConstantInertia", "IdealSolid", "StokesSphere"]),
    ("free_ellipsoid", ["ConstantInertia", "IdealSolid", "StokesDiagonal"]),
    ("ellipsoid", ["ConstantInertia", "IdealSolid", "StokesDiagonal", "Gravity"]),
    ("coupled_egg", ["ThermalInertia", "IdealSolid", "StokesSphere", "Gravity", "Attitude"]),
    ("flat_spin", ["ConstantInertia", "IdealSolid", "DoubleBracket"]),
])
def test_a_scene_compiles_only_its_terms(name, terms):
    """The model of each built-in scene holds exactly the terms it needs: no
    gravity term for a body without gravity torque (g = 0, or a uniform
    ellipsoid about its centre), no friction or thermodynamics without
    dissipation, 𝕀(S) only with thermal expansion, R only when asked."""
    scene = load_scene(name)
    km = build_model(physics_of_scene(scene), scene.output.attitude)
    assert km.terms() == terms
    assert set(builtin_scenes()) >= {"paper", "coupled_egg", "ellipsoid", "free_ellipsoid",
                                      "spherical_top", "flat_spin"}


def test_no_gravity_no_friction_leave_only_the_inertia():
    scene = load_scene("paper", {"gravity.g": 0.0, "fluid.viscosity": 0.0, "output.attitude": False})
    km = build_model(physics_of_scene(scene))
    assert km.terms() == ["ConstantInertia"] and km.layout("rk").size == 6


def test_per_member_parameters_are_rows_shared_ones_are_not():
    phys = paper_physics(4)
    assert build_model(phys).shared is not None
    C = phys.stokes_resistance.copy()
    C[2] *= 2.0
    km = build_model(replace(phys, stokes_resistance=C))
    assert km.shared is None and km.P.shape[0] == 4
    assert np.array_equal(km.P[0], build_model(phys).P[0]) and not np.array_equal(km.P[2], km.P[0])


# ------------------------------------------------------------------ the ellipsoid
def test_jeffery_resistance_of_a_sphere_and_its_symmetries():
    """A sphere of radius a has C = 8πμa³ on every axis; permuting the
    semi-axes permutes C; a longer axis resists rotation about the others more."""
    a, mu = 0.05, 0.1
    np.testing.assert_allclose(jeffery_resistance([a, a, a], mu)[0], 8 * math.pi * mu * a**3, rtol=1e-14)
    C = jeffery_resistance([0.06, 0.05, 0.04], mu)[0]
    Cp = jeffery_resistance([0.05, 0.04, 0.06], mu)[0]
    np.testing.assert_allclose(Cp, C[[1, 2, 0]], rtol=1e-14)
    assert C[2] > C[1] > C[0]  # rotation about e3 moves the two longest axes through the fluid


def test_jeffery_resistance_of_a_prolate_spheroid_matches_the_closed_form():
    """Rotation of a prolate spheroid (a > b = c, e² = 1 − b²/a²) about its
    symmetry axis: C = (32π/3) μ a b² e³ / (2e − (1 − e²) ln((1 + e)/(1 − e)))
    (Perrin/Jeffery), to 1e-12."""
    a, b, mu = 0.08, 0.03, 0.2
    e = math.sqrt(1 - b * b / (a * a))
    closed = (32 * math.pi / 3) * mu * a * b * b * e**3 / (2 * e - (1 - e * e) * math.log((1 + e) / (1 - e)))
    assert jeffery_resistance([a, b, b], mu)[0, 0] == pytest.approx(closed, rel=1e-12)


def test_oberbeck_resistance_of_a_sphere_and_a_prolate_spheroid():
    """Translation: a sphere gives Stokes' 6πμa; a prolate spheroid (a > b = c,
    e² = 1 − b²/a², L = ln((1 + e)/(1 − e))) gives 16πμa e³/((1 + e²)L − 2e)
    along its axis and 32πμa e³/(2e + (3e² − 1)L) across it (Oberbeck;
    Chwang & Wu 1975), to 1e-12."""
    a, mu = 0.05, 0.3
    np.testing.assert_allclose(oberbeck_resistance([a, a, a], mu)[0], 6 * math.pi * mu * a, rtol=1e-14)
    a, b = 0.08, 0.03
    e = math.sqrt(1 - b * b / (a * a))
    L = math.log((1 + e) / (1 - e))
    K = oberbeck_resistance([a, b, b], mu)[0]
    assert K[0] == pytest.approx(16 * math.pi * mu * a * e**3 / ((1 + e * e) * L - 2 * e), rel=1e-12)
    assert K[1] == pytest.approx(32 * math.pi * mu * a * e**3 / (2 * e + (3 * e * e - 1) * L), rel=1e-12)
    assert K[2] == pytest.approx(K[1], rel=1e-14)
    assert K[0] < K[1]  # a needle moves more easily along its axis


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_pivot_drag_is_the_torque_of_the_centres_drag_and_diagonal_on_an_axis(axis):
    """The torque about the pivot of the force −K(Ω×d) on the centre is
    −DᵀKD Ω; for d on axis i it is diag with K_k d² at j, K_j d² at k, 0 at i."""
    K = np.array([1.0, 2.0, 3.0])
    rng = np.random.default_rng(axis)
    d = np.zeros(3)
    d[axis] = 0.7
    P = pivot_drag(K, d)
    for _ in range(3):
        w = rng.normal(size=3)
        np.testing.assert_allclose(-P @ w, np.cross(d, -K * np.cross(w, d)), rtol=1e-14, atol=1e-15)
    j, k = (axis + 1) % 3, (axis + 2) % 3
    expected = np.zeros(3)
    expected[j], expected[k] = K[k] * 0.49, K[j] * 0.49
    np.testing.assert_allclose(P, np.diag(expected), rtol=1e-14, atol=0)
    off = pivot_drag(K, [0.3, 0.0, 0.4])  # off an axis: symmetric, not diagonal
    np.testing.assert_allclose(off, off.T, atol=1e-16)
    assert abs(off[0, 2]) > 0.1


def test_the_ellipsoids_friction_about_its_pivot_and_the_papers_unchanged():
    """The ellipsoid scene (pivot 1 cm below the centre on axis 3): C = Jeffery's
    + diag(K₂d², K₁d², 0); the paper's sphere pivots at its centre: 8πηa³."""
    s = load_scene("ellipsoid")
    mu, ax, d = s.fluid.viscosity, np.array(s.body.semi_axes), np.array(s.body.center_of_mass)
    K = oberbeck_resistance(ax, mu)[0]
    C = physics_of_scene(s).stokes_resistance[0]
    np.testing.assert_allclose(C, jeffery_resistance(ax, mu)[0] + d[2] ** 2 * np.array([K[1], K[0], 0.0]),
                               rtol=1e-14)
    assert np.all(C[:2] > jeffery_resistance(ax, mu)[0, :2])
    free = physics_of_scene(load_scene("free_ellipsoid")).stokes_resistance[0]
    np.testing.assert_array_equal(free, jeffery_resistance(ax, mu)[0])  # about its centre: no drag
    paper = load_scene("paper")
    np.testing.assert_allclose(physics_of_scene(paper).stokes_resistance[0],
                               8 * math.pi * paper.fluid.viscosity * paper.body.radius**3, rtol=1e-15)
    with pytest.raises(SceneError) as exc:  # off an axis in a fluid: the drag would not be diagonal
        load_scene("free_ellipsoid", {"body.center_of_mass": [0.01, 0.0, 0.01], "body.inertia": [1e-3, 1e-3, 1e-3]})
    assert exc.value.key == "body.center_of_mass" and "diagonal" in str(exc.value)
    load_scene("free_ellipsoid", {"body.center_of_mass": [0.01, 0.0, 0.01], "body.inertia": [1e-3, 1e-3, 1e-3],
                                  "fluid.viscosity": 0.0})  # no fluid: no drag, any pivot


def test_the_pivoted_ellipsoid_balances_energy_against_the_reference():
    """With the pivot's drag the ellipsoid's run still conserves E = K + V + U:
    entropy production Ω·C_pivot Ω is the heat of the same torque.  The VI at
    h = 0.02 s follows the DOP853 reference over the first half second."""
    from liethermo.runner import run_scene

    over = {"integrator.steps": 250, "output.every": 25, "output.compare": [], "output.variables": "all"}
    vi, _ = run_scene(load_scene("ellipsoid", over), None, progress=False)
    ref, _ = run_scene(load_scene("ellipsoid", {**over, "integrator.method": "reference"}), None, progress=False)
    Emech = float(ref.mechanical_energy_initial[0])
    assert float(abs(ref.energy_error).max()) < 1e-9 * Emech
    assert float(abs(vi.energy_error).max()) < 2e-2 * Emech
    dS = float(ref.entropy[0, -1] - ref.entropy[0, 0])
    assert dS > 0
    # the first half second, before the heavy top's chaos separates the two
    np.testing.assert_allclose(vi.omega.values[:, :2], ref.omega.values[:, :2],
                               atol=2e-2 * float(abs(ref.omega[:, :2]).max()))


def test_ellipsoid_inertia_and_pivot():
    """Uniform density: I₁ = m(a₂² + a₃²)/5 (cyclic) about the centre; a
    centre of mass on axis 3 moves the pivot there (parallel-axis theorem on
    I₁ and I₂, not I₃); no gravity term when G = 0."""
    s = load_scene("free_ellipsoid")
    p = physics_of_scene(s)
    ax = np.array(s.body.semi_axes)
    m = 4 / 3 * math.pi * ax.prod() * s.body.density
    np.testing.assert_allclose(p.inertia[0], m / 5 * np.array([ax[1]**2 + ax[2]**2, ax[2]**2 + ax[0]**2,
                                                                ax[0]**2 + ax[1]**2]), rtol=1e-14)
    q = physics_of_scene(load_scene("free_ellipsoid", {"body.center_of_mass": [0.0, 0.0, 0.01]}))
    np.testing.assert_allclose(q.inertia[0] - p.inertia[0], [m * 1e-4, m * 1e-4, 0.0], rtol=1e-12, atol=1e-18)
    assert np.all(p.gravity_torque == 0.0)


# ------------------------------------------------------------------ the coupled top
@pytest.fixture(scope="module")
def egg():
    scene = load_scene("coupled_egg")
    om0, R = _scene_ic(scene)
    return physics_of_scene(scene), om0, R


def test_coupled_top_conserves_energy_and_heats_by_19_kelvin(egg):
    """The continuous coupled model conserves E = ½Ω·𝕀(S)Ω + V + U(S) (the
    reference: ≤ 1e-12 of the mechanical energy over 30 s); the top heats
    from 299.4 K to 318.3 K (18.9 K) and its inertia grows by 3.7 %."""
    phys, om0, R = egg
    tr = simulate(phys, om0, R, 0.05, 600, "reference", every=10)
    assert tr.status[0] == STATUS_OK
    dE = _energy_error(tr, om0, R)
    emech = 0.5 * om0[0] @ (phys.inertia[0] * om0[0]) + phys.gravity_torque[0] @ R[0, 2] + np.linalg.norm(phys.gravity_torque[0])
    assert np.abs(dE).max() <= 1e-12 * emech
    T = node_energies(tr)["T"][0]
    assert 317.0 < T[-1] < 319.5
    from liethermo.top.physics import inertia_scale

    growth = inertia_scale(phys, tr.sigma[:, -1:])[0, 0]
    assert 1.035 < growth < 1.045


def test_coupled_reduces_to_the_decoupled_scheme_at_zero_expansion(egg):
    """With α → 0 (α = 1e-300: the coupled kernel, with φ ≡ 1 in floating
    point) the coupled variational integrator gives the decoupled scheme with
    the symmetric entropy update, to round-off: Ω, Γ ≤ 1e-13, S ≤ 1e-13
    relative, over 600 steps (vi and vi4)."""
    phys, om0, R = egg
    p0 = replace(phys, thermal_expansion=np.array([0.0]))
    pt = replace(phys, thermal_expansion=np.array([1e-300]))
    assert build_model(pt).terms()[0] == "ThermalInertia" and build_model(p0).terms()[0] == "ConstantInertia"
    for method in ("vi", "vi4"):
        a = simulate(p0, om0, R, 0.05, 600, method)
        b = simulate(pt, om0, R, 0.05, 600, method)
        assert np.all(a.status == 0) and np.all(b.status == 0)
        assert np.abs(a.omega - b.omega).max() <= 1e-13
        assert np.abs(a.gamma - b.gamma).max() <= 1e-13
        assert np.abs(a.sigma - b.sigma).max() <= 1e-13 * np.abs(a.sigma).max()


def test_coupled_energy_error_of_the_vi_family_falls_with_the_order(egg):
    """The node-energy error of vi, vi4, vi6 on the coupled top at h = 0.05
    stays bounded (no drift: the error at the end is below its maximum) and
    falls with the order."""
    phys, om0, R = egg
    errs = []
    for method in ("vi", "vi4", "vi6"):
        tr = simulate(phys, om0, R, 0.05, 600, method)
        dE = np.abs(_energy_error(tr, om0, R)[0])
        errs.append(dE.max())
        assert dE[-1] < dE.max()
    assert errs[0] > errs[1] > errs[2]


# ------------------------------------------------------------------ double-bracket friction
@pytest.fixture(scope="module")
def spin():
    scene = load_scene("flat_spin")
    om0, R = _scene_ic(scene)
    return physics_of_scene(scene), om0, R


def _casimir_drift(tr, om0):
    I = tr.physics.inertia[0]
    mu = tr.momentum if tr.momentum is not None else I * tr.omega
    mu0 = np.linalg.norm(I * om0[0])
    return np.abs(np.linalg.norm(mu[0], axis=-1) - mu0).max() / mu0


def test_double_bracket_keeps_the_casimir_exactly_only_in_the_vi_family(spin):
    """|μ| is a Casimir of double-bracket friction: the variational
    integrators keep it to round-off (≤ 1e-13 relative, vi, vi4, vi6) and so
    does the reference's flow (≤ 1e-12); RK2 and RK4 do not (> 1e-12)."""
    phys, om0, R = spin
    for method in ("vi", "vi4", "vi6"):
        assert _casimir_drift(simulate(phys, om0, R, 0.01, 3000, method, every=10), om0) <= 1e-13
    assert _casimir_drift(simulate(phys, om0, R, 0.01, 3000, "reference", every=10), om0) <= 1e-12
    for method in ("rk2", "rk4"):
        assert _casimir_drift(simulate(phys, om0, R, 0.01, 3000, method, every=10), om0) > 1e-12


def test_flat_spin_ends_on_the_major_axis_with_heat_equal_to_energy_lost(spin):
    """The free body loses kinetic energy at fixed |μ| down to |μ|²/(2 I_max)
    and ends spinning about its major axis (axis 3, I₃ the largest): after
    60 s, |Ω₁|, |Ω₂| < 1e-3 |Ω₃| and K − K_min < 1e-6 K₀; the heat gained
    U(S) − U(S₀) equals the energy lost K₀ − K (the reference, ≤ 1e-12 of K₀)."""
    phys, om0, R = spin
    I = phys.inertia[0]
    assert np.argmax(I) == 2
    tr = simulate(phys, om0, R, 0.01, 6000, "reference", every=100)
    e = node_energies(tr)
    K, dU = e["K"][0], e["dU"][0]
    K0 = K[0]
    mu0 = np.linalg.norm(I * om0[0])
    Kmin = mu0**2 / (2 * I.max())
    assert K[-1] - Kmin < 1e-6 * K0 and K[-1] >= Kmin * (1 - 1e-12)
    w = tr.omega[0, -1]
    assert max(abs(w[0]), abs(w[1])) < 1e-3 * abs(w[2])
    assert np.abs((K0 - K) - dU).max() <= 1e-12 * K0
    # and the variational integrator ends on the same axis
    v = simulate(phys, om0, R, 0.01, 6000, "vi", every=100).omega[0, -1]
    assert max(abs(v[0]), abs(v[1])) < 1e-3 * abs(v[2])


# ------------------------------------------------------------------ scene validation
@pytest.mark.parametrize("override,key", [
    ("body.semi_axes=[0.05, 0.0, 0.03]", "body.semi_axes"),
    ("body.semi_axes=[0.05, -0.01, 0.03]", "body.semi_axes"),
    ("body.semi_axes=[0.05, 0.03]", "body.semi_axes"),
    ("body.thermal_expansion=-1e-3", "body.thermal_expansion"),
    ("body.thermal_expansion=nan", "body.thermal_expansion"),
    ("body.internal_friction=-1.0", "body.internal_friction"),
    ("body.internal_friction=inf", "body.internal_friction"),
    ("body.mass=0.0", "body.mass"),
    ("body.mass=\"heavy\"", "body.mass"),
    ("body.shape=\"cube\"", "body.shape"),
    ("thermo.heat_capacity=-5.0", "thermo.heat_capacity"),
    ("integrator.entropy=\"implicit\"", "integrator.entropy"),
    ("integrator.start=\"middle\"", "integrator.start"),
    ("integrator.method=\"vi8\"", "integrator.method"),
])
def test_bad_new_keys_are_rejected_naming_the_key(override, key):
    with pytest.raises(SceneError) as exc:
        load_scene("paper", [override])
    assert exc.value.key == key


def test_combinations_the_models_do_not_offer_are_rejected():
    with pytest.raises(SceneError) as exc:
        load_scene("coupled_egg", {"integrator.start": "node"})
    assert exc.value.key == "integrator.start"
    with pytest.raises(SceneError) as exc:
        load_scene("coupled_egg", {"body.internal_friction": 1.0})
    assert exc.value.key == "body.internal_friction"
    with pytest.raises(SceneError) as exc:
        load_scene("free_ellipsoid", {"body.center_of_mass": [0.01, 0.0, 0.01]})
    assert exc.value.key == "body.center_of_mass"


@pytest.mark.parametrize("override", ["body.internal_friction=-1", "body.semi_axes=[0,1,1]",
                                      "body.thermal_expansion=-0.1"])
def test_bad_new_keys_exit_2_with_one_line(override, tmp_path):
    out = tmp_path / "x.nc"
    p = subprocess.run([sys.executable, "-m", "liethermo.cli", "run", "paper", "-o", str(out),
                        "--set", override], capture_output=True, text=True)
    assert p.returncode == 2
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and override.split("=")[0] in lines[0]
    assert not out.exists()


@pytest.mark.slow
def test_every_builtin_scene_loads_and_runs_briefly():
    """Each built-in scene is valid and runs its own method for a few steps."""
    for name in builtin_scenes():
        scene = load_scene(name, {"integrator.steps": 4, "output.every": 1})
        if getattr(scene, "model", None) == "zeitlin":  # the second Lie group: its own runner
            from liethermo.zeitlin.run import simulate as zeitlin_simulate

            ds = zeitlin_simulate(scene.with_overrides({"zeitlin.N": 9, "ensemble.members": 2}), progress=False)
            assert (ds["status"] == 0).all(), name
            continue
        if getattr(scene, "model", None) == "torus":  # the third: its own runner
            from liethermo.torus.run import simulate as torus_simulate

            ds = torus_simulate(scene.with_overrides({"torus.N": 9, "ensemble.members": 2}), progress=False)
            assert (ds["status"] == 0).all(), name
            continue
        om0, R = _scene_ic(scene)
        tr = simulate(physics_of_scene(scene), om0, R, scene.integrator.h, 4, MethodChoice.of(scene.integrator.method, start=scene.integrator.start, entropy=scene.integrator.entropy, friction=scene.integrator.friction), attitude=scene.output.attitude)
        assert np.all(tr.status == STATUS_OK), name


def test_paper_keys_are_the_papers():
    s = load_scene("paper")
    assert (s.integrator.start, s.integrator.entropy, s.integrator.friction) == ("node", "explicit", "trapezoid")
    assert load_scene(None).integrator.start == "legendre"
    np.testing.assert_array_equal(np.array(s.initial.R), R0)
    np.testing.assert_array_equal(np.array(s.initial.omega), OMEGA0)


def test_a_coupled_top_that_would_start_below_zero_kelvin_is_refused(tmp_path, capsys):
    """T = T0 (1 − α Ω·𝕀₀Ω/c_v) at the start: a spin that makes it ≤ 0 is refused
    before any work, naming the key, in Python and on the command line; the
    ensemble's bound uses its fastest possible member."""
    import liethermo
    from liethermo.cli import main
    from liethermo.preflight import PreflightError, check_parameters

    fast = {"initial.omega": [30.0, 30.0, 30.0], "integrator.steps": 2}
    with pytest.raises(PreflightError, match=r"body.thermal_expansion.*T = T0 \(1 − α Ω·𝕀₀Ω/c_v\) ≤ 0"):
        liethermo.run("coupled_egg", fast, compare=False)
    assert main(["run", "coupled_egg", "-o", str(tmp_path / "x.nc"), "--set", "initial.omega=[30,30,30]"]) == 2
    assert "body.thermal_expansion" in capsys.readouterr().err and not list(tmp_path.iterdir())
    check_parameters(load_scene("coupled_egg"))  # the built-in scene starts warm
    check_parameters(load_scene("coupled_egg", {"initial.omega": [30.0, 30.0, 30.0], "thermo.heat_capacity": 1.0}))
    # members up to spin_range[1] |Ω(0)|: 1.5 × |(0, 16, 16)| is too fast, one member at (0, 16, 16) is not
    check_parameters(load_scene("coupled_egg", {"initial.omega": [0.0, 16.0, 16.0]}))
    with pytest.raises(PreflightError, match="spin_range"):
        check_parameters(load_scene("coupled_egg", {"initial.omega": [0.0, 16.0, 16.0], "ensemble.members": 8}))


def test_a_small_heat_capacity_keeps_the_vectorized_temperature():
    """1/T(σ) is a cubic valid to |σ/c_v| ≤ 2⁻¹⁶; an ensemble whose heat can
    take σ/c_v further (c_v = 1e-3 J/K: up to 1/8 here) gets the degree-8
    polynomial about the middle of that range, which agrees with
    exp to 2 ulp over all of it and never asks for the scalar path; the
    paper's top (c_v = 1300 J/K) keeps the cubic."""
    import math

    from liethermo.top.kernels._jit import jit
    from liethermo.top.kernels.terms import thermo
    from liethermo.top.initial import heat_bound, initial_conditions
    from liethermo.top.physics import mechanical_energy_scale

    scene = load_scene("coupled_egg", {"body.thermal_expansion": 0.0, "ensemble.members": 64,
                                       "initial.omega": [0.0, 1.3, 1.3]})
    phys = physics_of_scene(scene, 64)
    om0, R = initial_conditions(scene)
    heat = mechanical_energy_scale(phys, om0, R[:, 2, :])
    assert heat.max() <= heat_bound(scene, phys)
    th = build_model(phys, heat=heat.max()).model.thermo
    assert isinstance(th, thermo.IdealSolidWide)
    reach = math.log1p(heat.max() / (phys.heat_capacity[0] * phys.T0[0]))
    assert 0.05 < reach <= 0.125
    paper = physics_of_scene(load_scene("paper"), 1)
    assert isinstance(build_model(paper, heat=1.0).model.thermo, thermo.IdealSolid)
    assert isinstance(build_model(phys).model.thermo, thermo.IdealSolid)  # no bound given: the cubic

    @jit
    def inv(th, s):
        return thermo.inverse_temperature(th, s, False)

    for x in np.linspace(-1e-4, reach, 2001):
        s = x * th.cv
        f, ok = inv(th, s)
        exact = th.e0 * math.exp(s * th.m)
        assert ok and abs(f - exact) <= 2 * np.spacing(exact), x
    assert not inv(th, 0.2 * th.cv)[1]  # beyond its range the lane is redone exactly


def test_a_small_heat_capacity_gives_the_same_bits_however_the_ensemble_is_split():
    """The wide polynomial's centre comes from the scene (its largest possible
    heat), not from the members at hand: member chunks of 64 give the bits of
    one chunk of 200, and the first chunk alone gives its members' bits."""
    from liethermo.runner import run_scene

    over = {"body.thermal_expansion": 0.0, "ensemble.members": 200, "integrator.steps": 200,
            "output.every": 20, "output.compare": [], "integrator.method": "rk4"}
    whole, _ = run_scene(load_scene("coupled_egg", {**over, "output.member_chunk": 200}), None, progress=False)
    parts, _ = run_scene(load_scene("coupled_egg", {**over, "output.member_chunk": 64}), None, progress=False)
    first, _ = run_scene(load_scene("coupled_egg", {**over, "output.member_chunk": 64, "ensemble.members": 64}),
                         None, progress=False)
    for name in ("omega", "gamma", "entropy_change"):  # the stored state
        np.testing.assert_array_equal(whole[name].values, parts[name].values)
    np.testing.assert_array_equal(whole["omega"].values[:64], first["omega"].values)


# ------------------------------------------------------------------ the terms own their names

def _term_names() -> set[str]:
    from liethermo.top.kernels import terms

    names = set()
    for t in terms.registry():
        names.add(t.name)
        names.update(s.path for s in t.settings)
        names.update(s.name for s in t.settings if len(s.name) > 1)  # not "g": a common variable
        names.update(p.name for p in t.parameters)
        names.update(p.variable for p in t.parameters if p.variable)
    for m in terms._term_modules():
        if m.__name__.endswith(".inertia"):  # the inertia slot is the model's, not a term's
            continue
        names.add(m.__name__.rsplit(".", 1)[1])
        names.update(k for k, v in vars(m).items() if isinstance(v, type) and v.__module__ == m.__name__)
    return names


def test_no_module_outside_the_terms_names_a_term():
    """Outside the top's kernels/terms/ and the Zeitlin fluid (another model, with keys
    of its own, such as its viscosity), no identifier or string literal of the
    package — the studies included — is a term's name, scene key, parameter,
    dataset variable, module or class: the layers above the terms loop over
    the registry and ask it for a key by its role."""
    import ast
    import io
    import pathlib
    import tokenize

    import liethermo

    names = _term_names()
    assert {"stokes", "fluid.viscosity", "viscosity", "gravity", "stokes_resistance", "gravity_torque"} <= names
    root = pathlib.Path(liethermo.__file__).parent
    found = []
    for p in sorted(root.rglob("*.py")):
        rel = p.relative_to(root).as_posix()
        if rel.startswith(("top/kernels/terms/", "zeitlin/")):
            continue
        for tok in tokenize.generate_tokens(io.StringIO(p.read_text()).readline):
            if tok.type == tokenize.NAME and tok.string in names:
                found.append((rel, tok.start[0], tok.string))
            elif tok.type == tokenize.STRING and not tok.string.lower().startswith(("f", "rf", "fr", "b")):
                value = ast.literal_eval(tok.string)
                if value in names:
                    found.append((rel, tok.start[0], value))
    assert not found, found
