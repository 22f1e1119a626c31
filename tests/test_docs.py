"""The documentation in docs/ states what the code does.

* docs/scenes.md is generated from the key registry and must be current;
* ``liethermo keys`` prints the same keys;
* the numbers docs/model.md quotes (the paper scene's derived values, the
  composition factors, the limits of negative substeps, the errata evidence,
  the energy diagnostics) are the code's;
* the discrete laws docs/model.md states hold in the forms it states them;
* every link to a section of docs/model.md, and every citation of one of its
  sections in the sources, names a heading that exists.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import OMEGA0, R0, paper_physics
from liethermo.top.methods import MethodChoice
from liethermo.cli import main
from liethermo.top.kernels.vi import FRICTION_WEIGHTS
from liethermo.top.methods import COMPOSITION_FACTORS
from liethermo.top.physics import physics_of_scene
from liethermo.scene import (SCENES_MARKDOWN_COMMAND, SceneError, _toml_value, builtin_scenes, keys_table,
                             load_scene, scenes_markdown)
from liethermo.top.scene import KEYS
from liethermo.top.simulate import STATUS_OK, simulate

ROOT = Path(__file__).resolve().parents[1]
MODEL_MD = ROOT / "docs" / "model.md"
SCENES_MD = ROOT / "docs" / "scenes.md"


@pytest.fixture(scope="module")
def model_md() -> str:
    return MODEL_MD.read_text(encoding="utf-8")


def _quotes(doc: str, text: str) -> bool:
    """Whether the documentation contains the text (line breaks as spaces)."""
    return " ".join(text.split()) in " ".join(doc.split())


def _number_in(doc: str, text: str) -> float:
    """A number as the documentation prints it (which must be there), as a float:
    "1.5·10⁻³" or, in formulas, "1.5\\cdot10^{-3}"."""
    assert _quotes(doc, text), f"the documentation does not quote {text}"
    text = re.sub(r"\\cdot10\^\{(-?\d+)\}", r"e\1", text)
    return float(text.replace("·10", "e").replace("⁻", "-").translate(
        str.maketrans("⁰¹²³⁴⁵⁶⁷⁸⁹", "0123456789")))


# ------------------------------------------------------------------ docs/scenes.md
def test_scenes_md_is_generated_from_the_key_registry():
    """docs/scenes.md is exactly what liethermo.scene.scenes_markdown() makes
    from KEYS and the built-in scenes: a key added, removed or changed without
    regenerating the file fails here."""
    current = SCENES_MD.read_text(encoding="utf-8")
    assert current == scenes_markdown(), (
        f"docs/scenes.md is out of date with the models' scene keys; regenerate it with\n"
        f"    cd {ROOT} && PYTHONPATH=src {SCENES_MARKDOWN_COMMAND}")


def test_scenes_md_lists_every_key_and_builtin_scene():
    """Each key appears once, in its section's table, with its unit and its
    default; each built-in scene with its description; table rows have as many
    cells as their header."""
    from liethermo.torus.scene import KEYS as TKEYS
    from liethermo.zeitlin.scene import KEYS as ZKEYS

    full = scenes_markdown()
    cut = full.index("## Keys of a Zeitlin fluid")
    cut2 = full.index("## Keys of a torus fluid")
    for keys, text, heading in ((KEYS, full[:cut], "### ["), (ZKEYS, full[cut:cut2], "### zeitlin scene: ["),
                                (TKEYS, full[cut2:], "### torus scene: [")):
        for k in keys:
            rows = [line for line in text.splitlines() if line.startswith(f"| `{k.path}` |")]
            assert len(rows) == 1, k.path
            cells = re.split(r"(?<!\\)\|", rows[0])[1:-1]
            assert len(cells) == 5, rows[0]
            assert cells[1].strip() == (k.unit or "—")
            assert cells[2].strip() == f"`{_toml_value(k.default)}`"
            start = text.index(f"{heading}{k.section}]")
            end = text.find(heading, start + 1)
            assert start < text.index(rows[0]) < (end if end > 0 else len(text))
    text = full
    for name, description in builtin_scenes().items():
        assert f"| `{name}` |" in text and description.split(":")[0] in text


def test_keys_command_prints_every_key(capsys):
    """``liethermo keys``: exit 0, one line per key with its unit (except
    dimensionless ones), its default and its rule; ``--markdown`` prints
    docs/scenes.md."""
    assert main(["keys"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    for k in KEYS:
        line = next(ln for ln in lines if ln.strip().startswith(k.path + " "))
        if k.unit and k.unit != "1":
            assert f"[{k.unit}]" in line, line
        assert f"({k.rule})" in line, line
    from liethermo.zeitlin.scene import KEYS as ZKEYS

    assert out.startswith(keys_table(markdown=False))
    for k in ZKEYS:  # after the top's keys, under their own heading
        assert f"  {k.path}" in out.split("a Zeitlin fluid")[1], k.path
    assert main(["keys", "--markdown"]) == 0
    assert capsys.readouterr().out == SCENES_MD.read_text(encoding="utf-8")


def test_keys_console_command():
    """``python -m liethermo.cli keys`` exits 0 and prints the table."""
    p = subprocess.run([sys.executable, "-m", "liethermo.cli", "keys"], capture_output=True,
                       text=True, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    assert "integrator.method = \"vi\"" in p.stdout and "fluid.viscosity [kg m-1 s-1] = 0.1" in p.stdout


# ------------------------------------------------------------------ the paper scene's numbers
def test_paper_scene_numbers_are_the_codes(model_md):
    """The derived values in docs/model.md, "The paper scene", are those of the
    scene code: m, ℓ, c, c_v to the last printed digit, 𝕀, N₀, g⃗, U₀, K₀ and
    E_mech,0 to the printed digits."""
    p = physics_of_scene(load_scene("paper"))
    assert p.mass[0] == pytest.approx(_number_in(model_md, "1.4137166941154071"), rel=1e-16)
    assert _quotes(model_md, "| $G_z = \\ell$ | 0.00125 m")
    np.testing.assert_allclose(p.center_of_mass[0], [0.0, 0.0, 0.00125], rtol=1e-12, atol=0)
    assert p.stokes_resistance[0, 0] == pytest.approx(_number_in(model_md, "3.1415926535897936·10⁻⁴"), rel=1e-16)
    assert np.all(p.stokes_resistance[0] == p.stokes_resistance[0, 0])
    assert p.heat_capacity[0] == pytest.approx(_number_in(model_md, "1306.9263327416309"), rel=1e-16)
    I = p.inertia[0]
    np.testing.assert_allclose(I, [_number_in(model_md, "6.6783·10⁻⁴")] * 2
                               + [_number_in(model_md, "1.31947·10⁻³")], rtol=1e-5)
    assert p.mass[0] / 26.981539e-3 == pytest.approx(_number_in(model_md, "52.3957"), abs=1e-4)
    np.testing.assert_allclose(p.gravity_torque[0], [0.0, 0.0, _number_in(model_md, "0.0173357")],
                               rtol=1e-6, atol=0)
    assert p.heat_capacity[0] * p.T0[0] == pytest.approx(_number_in(model_md, "3.92·10⁵"), rel=1e-2)
    sc = load_scene("paper")
    om0, R = np.array(sc.initial.omega), np.array(sc.initial.R)
    K0 = 0.5 * om0 @ (I * om0)
    assert K0 == pytest.approx(_number_in(model_md, "9.937·10⁻⁴"), rel=1e-4)
    assert p.gravity_torque[0] @ R[2] == 0.0
    emech = K0 + np.linalg.norm(p.gravity_torque[0])
    assert emech == pytest.approx(_number_in(model_md, "0.018329"), rel=1e-4)
    assert [sc.integrator.start, sc.integrator.entropy, sc.integrator.friction, sc.integrator.h,
            sc.integrator.steps] == ["node", "explicit", "trapezoid", 0.1, 300]
    assert list(sc.output.compare) == ["rk2"]


def test_composition_factors_are_the_documented_ones(model_md):
    """small_error: Suzuki's (p, p, 1 − 4p, p, p), p = 1/(4 − 4^{1/3}), and
    Kahan–Li's s9odr6a; triple_jump: Yoshida's (γ₁, γ₀, γ₁), γ₁ = 1/(2 − 2^{1/3}),
    γ₀ = 1 − 2γ₁, and its triple jump with δ₁ = 1/(2 − 2^{1/5}): the nine
    factors δ_iγ_j.  Each is a palindrome summing to 1; the decimals
    docs/model.md prints are the factors."""
    from liethermo.top.methods import METHODS

    C = COMPOSITION_FACTORS
    p = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))
    g1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
    g0 = 1.0 - 2.0 * g1
    d1 = 1.0 / (2.0 - 2.0 ** (1.0 / 5.0))
    d0 = 1.0 - 2.0 * d1
    assert METHODS["vi"].substeps() == (1.0,) and METHODS["split"].substeps() == (1.0,)
    assert C[("small_error", 4)] == (p, p, 1.0 - 4.0 * p, p, p)
    assert C[("triple_jump", 4)] == (g1, g0, g1)
    assert C[("triple_jump", 6)] == tuple(d * g for d in (d1, d0, d1) for g in (g1, g0, g1))
    for f in C.values():
        assert math.fsum(f) == pytest.approx(1.0, abs=1e-15)
        assert f == f[::-1]
    for name in ("vi4", "split4"):
        assert METHODS[name].substeps() == C[("small_error", 4)]
        assert METHODS[name].substeps("triple_jump") == C[("triple_jump", 4)]
    assert _number_in(model_md, "0.4144907717943757") == p
    assert _number_in(model_md, "-0.6579630871775028") == 1.0 - 4.0 * p
    assert _number_in(model_md, "1.3512071919596578") == g1
    assert _number_in(model_md, "-1.7024143839193155") == g0
    assert _number_in(model_md, "1.1746717580893635") == d1
    assert _number_in(model_md, "-1.349343516178727") == d0
    for key, printed in ((("triple_jump", 6), "1.5872, −1.9998, 1.5872, −1.8232, 2.2971, −1.8232, 1.5872, "
                                              "−1.9998, 1.5872"),
                         (("small_error", 6), "0.3922, 0.3326, −0.7062,\n  0.0822, 0.7985, 0.0822, −0.7062, "
                                              "0.3326, 0.3922")):
        assert _quotes(model_md, printed.replace("\n  ", " ")) or printed in model_md
        np.testing.assert_allclose([float(x.replace("−", "-")) for x in printed.replace("\n", " ").split(", ")],
                                   C[key], atol=5e-5)
    assert FRICTION_WEIGHTS == {"trapezoid": (0.5, 0.5), "endpoint": (1.0, 0.0)}


def test_negative_substep_limits_are_the_documented_ones(model_md):
    """The table of docs/model.md, "Negative substeps": the κ where a negative
    substep's Newton matrix is singular and the band where a friction mode grows."""
    from liethermo.top.methods import negative_substep_limits

    rows = (("vi4", "small_error", "| vi4 | −0.6580 | 3.0397 | 3.023 < κ < 3.055 |", -0.6580, [3.0397], (3.023, 3.055)),
            ("vi6", "small_error", "| vi6 | −0.7062 | 2.8319 | 2.728 < κ < 2.950 |", -0.7062, [2.8319], (2.728, 2.950)),
            ("vi4", "triple_jump", "| vi4, triple jump | −1.7024 | 1.1748 | 1.134 < κ < 1.200 |", -1.7024, [1.1748],
             (1.134, 1.200)),
            ("vi6", "triple_jump", "| vi6, triple jump | −1.9998 | 1.0001 and 1.0969 (factor −1.8232) | "
             "0.916 < κ < 1.133 |", -1.9998, [1.0001, 1.0969], (0.916, 1.133)))
    for method, comp, row, fmin, sing, band in rows:
        lim = negative_substep_limits(method, "trapezoid", comp)
        assert _quotes(model_md, row)
        assert lim["min_factor"] == pytest.approx(fmin, abs=5e-5)
        assert lim["kappa_singular"] == pytest.approx(sing, abs=5e-5)
        assert lim["growth_band"] == pytest.approx(band, abs=1e-3)
    p = paper_physics()
    kappa = p.stokes_resistance[0].max() * 0.1 / p.inertia[0].min()
    assert _quotes(model_md, f"$\\kappa = {kappa:.3f}$")


# ------------------------------------------------------------------ errata
def _cayley(w, v):
    s = 4.0 / (4.0 + w @ w)
    u = np.cross(w, v)
    return v + s * (u + 0.5 * np.cross(w, u))


def test_errata_e1_e2_e5_numbers(model_md):
    """E1: the printed R₀ has det 0 and rank 2, and a scene with it is rejected;
    the paper scene's R₀ rotates χ = e₃ to −e₂.  E2: without h the first paper
    step turns Γ by 1.231 rad instead of 0.141 rad and lands 0.733 away.  E5:
    the moments about the centre are (2/5 m₁ + 2/3 m₂)a² = 1.79071e-3 kg m²."""
    printed = np.array([[1.0, 0, 0], [0, 0, -1], [0, 0, 1]])
    assert np.linalg.det(printed) == 0.0 and np.linalg.matrix_rank(printed) == 2
    with pytest.raises(SceneError, match="initial.R"):
        load_scene("paper", {"initial.R": printed.tolist()})
    sc = load_scene("paper")
    R = np.array(sc.initial.R)
    np.testing.assert_array_equal(R @ [0, 0, 1.0], [0, -1.0, 0])
    np.testing.assert_array_equal(R[2], [0, 1.0, 0])
    w0 = np.array(sc.initial.omega)
    h = sc.integrator.h
    assert _quotes(model_md, "turns $\\Gamma$ by 1.231 rad instead of 0.141 rad and lands 0.733 away")
    assert 2 * math.atan(np.linalg.norm(w0) / 2) == pytest.approx(1.231, abs=5e-4)
    assert 2 * math.atan(h * np.linalg.norm(w0) / 2) == pytest.approx(0.141, abs=5e-4)
    gap = np.linalg.norm(_cayley(-w0, R[2]) - _cayley(-h * w0, R[2]))
    assert gap == pytest.approx(0.733, abs=5e-4)
    a, m = sc.body.radius, physics_of_scene(sc).mass[0]
    m1 = sc.body.upper_mass_fraction * m
    about_c = (0.4 * m1 + 2.0 / 3.0 * (m - m1)) * a * a
    assert about_c == pytest.approx(_number_in(model_md, "1.79071\\cdot10^{-3}"), rel=1e-5)
    assert 83.0 / 320.0 == pytest.approx(2.0 / 5.0 - (3.0 / 8.0) ** 2)  # about the hemisphere's own centre


def test_errata_e3_printed_law_is_the_endpoint_law(model_md):
    """E3: over 300 paper steps (the paper's start, h = 0.1 s) the paper's
    printed discrete Kelvin–Noether law I_{k+1} − I_k = −c h² Γ_{k+1}·X_{k+1},
    I_k = h Γ_k·M_h(X_k), holds to round-off with endpoint friction and fails by
    about 9 % of max |ΔI| with trapezoid friction, whose own law
    −(c/2) h² Γ_{k+1}·(X_k + X_{k+1}) holds to round-off."""
    assert _quotes(model_md, "0.090 with trapezoid friction, 1.1·10⁻¹⁴ with endpoint friction")
    phys = paper_physics()
    h = 0.1
    I, c = phys.inertia[0], phys.stokes_resistance[0, 0]

    def legendre(X):
        IX = I * X
        return IX + 0.5 * h * np.cross(X, IX) + 0.25 * h * h * (X @ IX) * X

    res = {}
    for friction in ("trapezoid", "endpoint"):
        tr = simulate(phys, OMEGA0[None], R0[None], h, 300, MethodChoice.of("vi", start="node", entropy="explicit", friction=friction))
        assert tr.status[0] == STATUS_OK
        X, G = tr.omega_step[0], tr.gamma[0]
        Ik = h * np.einsum("ki,ki->k", G, np.array([legendre(x) for x in X]))
        dI = np.diff(Ik)
        printed = -c * h * h * np.einsum("ki,ki->k", G[1:], X[1:])
        trapezoid = -0.5 * c * h * h * np.einsum("ki,ki->k", G[1:], X[:-1] + X[1:])
        res[friction] = (np.abs(dI - printed).max() / np.abs(dI).max(),
                         np.abs(dI - trapezoid).max() / np.abs(dI).max())
    assert res["endpoint"][0] <= 1e-13 and res["trapezoid"][1] <= 1e-13
    assert res["trapezoid"][0] == pytest.approx(0.090, abs=5e-4)


def test_errata_e4_paper_start_node_velocity(model_md):
    """E4: with the paper's start at h = 0.1 s the node velocity at t = 0 is
    𝕀⁻¹μ₀ = (−1.249, 1.031, 1.016) rad/s, not Ω(0) — half a step of the gravity
    torque, 1.30 rad/s — an energy error of 3.1 % of E_mech,0 at k = 0; the
    legendre start gives Ω(0) exactly."""
    from liethermo.top.laws import energy_errors

    phys = paper_physics()
    assert _quotes(model_md, "$\\mathbb{I}^{-1}\\mu_0 = (-1.249, 1.031, 1.016)$")
    tr = simulate(phys, OMEGA0[None], R0[None], 0.1, 1, MethodChoice.of("vi", start="node"))
    np.testing.assert_allclose(tr.omega[0, 0], [-1.249, 1.031, 1.016], atol=5e-4)
    tau = np.cross(R0[2], phys.gravity_torque[0])
    assert 0.05 * np.linalg.norm(tau) / phys.inertia[0, 0] == pytest.approx(1.30, abs=5e-3)
    e = energy_errors(tr, OMEGA0[None], R0[None])
    assert e["node"][0, 0] / e["scale"][0] == pytest.approx(0.031, abs=5e-4)
    tr = simulate(phys, OMEGA0[None], R0[None], 0.1, 1, MethodChoice.of("vi", start="legendre"))
    np.testing.assert_array_equal(tr.omega[0, 0], OMEGA0)


# ------------------------------------------------------------------ laws as documented
def _D(I, lam, h, X):
    """The discrete double-bracket friction D(X) = λ(|m|²X − (m·X)m), m = 𝕀X + (h²/4)(X·𝕀X)X."""
    IX = I * X
    m = IX + 0.25 * h * h * (X @ IX) * X
    return lam * ((m @ m) * X - (m @ X) * m)


@pytest.mark.parametrize("case", ["double_bracket_trapezoid", "double_bracket_endpoint", "coupled"])
def test_kelvin_noether_law_in_its_documented_general_form(case):
    """J_{k+1} − J_k = −h (w_L Γ_k + w_R Γ_{k+1})·(C X_k + D(X_k)), J_k = Γ_k·μ_k,
    also with double-bracket friction (D placed with the friction weights) and
    for the coupled top (mean inertia): ≤ 1e-13 of max |ΔJ| over 500 steps."""
    base = paper_physics()
    if case == "coupled":
        phys = replace(base, heat_capacity=np.array([1e-3]), thermal_expansion=np.array([1e-3]))
        friction = "trapezoid"
    else:
        phys = replace(base, internal_friction=np.array([0.7]))
        friction = case.rsplit("_", 1)[1]
    h = 0.1
    tr = simulate(phys, 3.0 * OMEGA0[None], R0[None], h, 500, MethodChoice.of("vi", friction=friction))
    assert tr.status[0] == STATUS_OK
    X, G, mu = tr.omega_step[0], tr.gamma[0], tr.momentum[0]
    I, C, lam = phys.inertia[0], phys.stokes_resistance[0], phys.internal_friction[0]
    wl, wr = FRICTION_WEIGHTS[friction]
    F = C * X[:-1] + np.array([_D(I, lam, h, x) for x in X[:-1]])
    dJ = np.diff(np.einsum("ki,ki->k", G, mu))
    law = -h * np.einsum("ki,ki->k", wl * G[:-1] + wr * G[1:], F)
    assert np.abs(dJ - law).max() <= 1e-13 * np.abs(dJ).max()


def test_coupled_top_node_form_as_documented():
    """Every step of the coupled top satisfies the three lines of docs/model.md,
    "The coupled top": s̄_k M⁰_h(X) + (h/2)CX = μ_k + (h/2)τ(Γ_k);
    U(S_{k+1}) − U(S_k) − ½X·(𝕀(S_{k+1}) − 𝕀(S_k))X = h X·CX;
    μ_{k+1} = s̄_k M⁰_{−h}(X) − (h/2)CX + (h/2)τ(Γ_{k+1}), s̄_k = ½(φ_k² + φ_{k+1}²)."""
    phys = replace(paper_physics(), heat_capacity=np.array([1e-3]), thermal_expansion=np.array([1e-3]))
    h = 0.05
    tr = simulate(phys, 3.0 * OMEGA0[None], R0[None], h, 200, "vi")
    assert tr.status[0] == STATUS_OK
    I0, C, g = phys.inertia[0], phys.stokes_resistance[0], phys.gravity_torque[0]
    cv, T0, al = phys.heat_capacity[0], phys.T0[0], phys.thermal_expansion[0]
    X, G, s, mu = tr.omega_step[0], tr.gamma[0], tr.sigma[0], tr.momentum[0]

    def M(x, hh):
        Ix = I0 * x
        return Ix + 0.5 * hh * np.cross(x, Ix) + 0.25 * hh * hh * (x @ Ix) * x

    def phi(sig):
        return 1.0 + al * (T0 * math.exp(sig / cv) - T0)

    worst = [0.0, 0.0, 0.0]
    for k in range(200):
        sbar = 0.5 * (phi(s[k]) ** 2 + phi(s[k + 1]) ** 2)
        scale = np.abs(mu[k]).max()
        r1 = sbar * M(X[k], h) + 0.5 * h * C * X[k] - mu[k] - 0.5 * h * np.cross(G[k], g)
        r3 = sbar * M(X[k], -h) - 0.5 * h * C * X[k] + 0.5 * h * np.cross(G[k + 1], g) - mu[k + 1]
        heat = h * X[k] @ (C * X[k])
        dU = cv * T0 * math.exp(s[k] / cv) * math.expm1((s[k + 1] - s[k]) / cv)
        r2 = dU - 0.5 * (X[k] @ (I0 * X[k])) * (phi(s[k + 1]) ** 2 - phi(s[k]) ** 2) - heat
        worst = [max(worst[0], np.abs(r1).max() / scale), max(worst[1], abs(r2) / heat),
                 max(worst[2], np.abs(r3).max() / scale)]
    assert worst[0] <= 1e-13 and worst[2] <= 1e-13 and worst[1] <= 1e-9, worst
    np.testing.assert_allclose(tr.omega[0], mu / (I0 * np.array([[phi(x) ** 2] for x in s])), rtol=1e-14)


def test_energy_diagnostics_table(model_md):
    """docs/model.md, "Energy diagnostics": on the paper scene's own 24-member
    ensemble (seed 0) at h = 0.05 s for 30 s, the median over members of
    max |E_k − E₀|/E_mech,0 is 0.0053 on node values and 0.096 in the paper's
    convention for vi (legendre, symmetric), 0.022 and 0.099 for vi with the
    paper's start, 0.011 for rk2 and 8.1e-5 for rk4."""
    from liethermo.top.initial import initial_conditions
    from liethermo.top.laws import energy_errors

    sc = load_scene("paper", {"ensemble.members": 24, "ensemble.seed": 0})
    om, R = initial_conditions(sc)
    phys = physics_of_scene(sc, 24)
    rows = {"| vi (legendre, symmetric) | 0.0053 | 0.096 |": ("vi", dict(start="legendre", entropy="symmetric")),
            "| vi (paper's start, explicit) | 0.022 | 0.099 |": ("vi", dict(start="node", entropy="explicit")),
            "| rk2 | 0.011 | — |": ("rk2", {}),
            "| rk4 | 8.1·10⁻⁵ | — |": ("rk4", {})}
    for row, (method, kw) in rows.items():
        assert _quotes(model_md, row), row
        documented = [c.strip() for c in row.strip("|").split("|")[1:]]
        tr = simulate(phys, om, R, 0.05, 600, MethodChoice.of(method, **kw))
        assert np.all(tr.status == STATUS_OK)
        e = energy_errors(tr, om, R)
        node = np.median(np.nanmax(np.abs(e["node"]), axis=1) / e["scale"])
        want = _number_in(row, documented[0])
        assert node == pytest.approx(want, rel=0.05), (row, node)
        if e["paper"] is not None:
            paper = np.median(np.nanmax(np.abs(e["paper"]), axis=1) / e["scale"])
            assert paper == pytest.approx(_number_in(row, documented[1]), rel=0.05), (row, paper)
            assert paper > 4 * node  # the paper's convention carries an error of its own


# ------------------------------------------------------------------ links and citations
def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to '-'."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def _headings(text: str) -> list[str]:
    out, code = [], False
    for line in text.splitlines():
        if line.startswith("```"):
            code = not code
        elif not code and line.startswith("#"):
            out.append(line.lstrip("#").strip())
    return out


def test_model_md_links_and_citations_resolve(model_md):
    """Every in-page link of docs/model.md and docs/scenes.md points at a
    heading of docs/model.md (or of the page itself), and every citation
    'docs/model.md … "Section"' in src/, tests/, studies/, benchmarks/,
    README.md and docs/ names an existing heading of docs/model.md."""
    headings = _headings(model_md)
    anchors = {_slug(h) for h in headings}
    assert len(anchors) == len(headings), "two headings share an anchor"
    for a in re.findall(r"\]\(#([^)]+)\)", model_md):
        assert a in anchors, a
    for a in re.findall(r"\]\(model\.md#([^)]+)\)", SCENES_MD.read_text(encoding="utf-8")):
        assert a in anchors, a
    cited = 0
    files = [ROOT / "README.md", *ROOT.glob("docs/*.md"), *ROOT.glob("src/**/*.py"),
             *ROOT.glob("src/**/*.toml"), *ROOT.glob("tests/*.py"), *ROOT.glob("studies/*.toml"),
             *ROOT.glob("benchmarks/*.md"), *ROOT.glob("benchmarks/*.py")]
    pattern = re.compile(r'docs/model\.md(?:#([\w-]+)|[,;:\s§(]*["“]([^"”]+)["”])')
    for f in files:
        text = f.read_text(encoding="utf-8")
        for anchor, title in pattern.findall(text):
            if anchor:
                assert anchor in anchors, (f, anchor)
            else:
                assert title in headings, (f, title)
            cited += 1
    assert cited >= 5


def _math_spans(text: str) -> list[str]:
    """The TeX of a markdown page: ```math blocks, $$ … $$ blocks, then $ … $ spans."""
    spans = re.findall(r"```math\n(.*?)```", text, re.S)
    text = re.sub(r"```.*?```", " ", text, flags=re.S)
    spans += re.findall(r"\$\$(.*?)\$\$", text, re.S)
    text = re.sub(r"\$\$.*?\$\$", " ", text, flags=re.S)
    return spans + re.findall(r"\$([^$\n]+)\$", text)


@pytest.mark.parametrize("page", ["README.md", *sorted(p.name for p in ROOT.glob("docs/*.md"))])
def test_markdown_math_is_intact(page):
    """No control character in a page, and no TeX command that lost its
    backslash escape: a \\r, \\t, \\f, \\v, \\b or \\n read as a control
    character turns \\rvert, \\rangle, \\rho, \\times, \\frac, \\vec into a line
    break or garbage and a bare "vert", "angle", "ho", "imes", "rac" or "ec";
    every \\lvert and \\langle has its \\rvert and \\rangle in the same span."""
    path = ROOT / page if page == "README.md" else ROOT / "docs" / page
    text = path.read_text(encoding="utf-8")
    bad = [(i + 1, line) for i, line in enumerate(text.splitlines())
           if re.search(r"[\x00-\x08\x0b-\x1f\x7f]", line)]
    assert not bad, f"{page}: control characters on lines {bad[:5]}"
    for span in _math_spans(text):
        bare = re.findall(r"(?<![\\\w])(vert|Vert|angle|ho|imes|heta|au|rac|frac|ec|abla)(?![a-zA-Z])", span)
        assert not bare, f"{page}: a TeX command lost its backslash in ${span}$: {bare}"
        for left, right in (("\\lvert", "\\rvert"), ("\\langle", "\\rangle"), ("\\lVert", "\\rVert")):
            assert span.count(left) == span.count(right), f"{page}: unbalanced {left} … {right} in ${span}$"


def test_model_md_citations_are_in_its_references(model_md):
    """Every citation [Author Year] (or [A Year; B Year]) in docs/model.md names an
    entry of its References section, every entry is cited, no work is cited in
    passing ("Jeffery's (1922)"), each entry gives authors, a title and the
    year of its key, and each key has a link definition (so a citation links to
    the list); a DOI, where given, has the form 10.NNNN/…."""
    body, refs = model_md.split("\n## References\n")
    entries = dict(re.findall(r"^\* \*\*\[([^\]]+)\]\*\* (.+?)(?=^\* |^\[|\Z)", refs, re.M | re.S))
    assert len(entries) >= 15, sorted(entries)
    cited = set()
    for group in re.findall(r"\[([A-Z][^\]\[]*?\b(?:1[6-9]|20)\d\d)\]", body):
        for key in group.split("; "):
            assert key in entries, f"cited but not in References: [{key}]"
            cited.add(key)
    assert {"Couéraud & Gay-Balmaz 2020", "Suzuki 1990", "Kahan & Li 1997", "Yoshida 1990"} <= cited
    assert set(entries) <= cited, f"listed but never cited: {sorted(set(entries) - cited)}"
    # a work is cited by its key, not in passing as "Name's (1922)" or "Name (1876)"
    informal = re.findall(r"\b[A-Z][a-z]+(?:'s)? \((?:1[6-9]|20)\d\d\)", body)
    assert not informal, informal
    for key, text in entries.items():
        year = key.rsplit(" ", 1)[1]
        assert f"({year})" in text or f"{year})" in text, (key, text)
        assert re.search(r"[\"*].+[\"*]", text, re.S), f"{key}: no title"
        assert f"[{key}]: #references" in refs, f"{key}: no link definition"
        for doi in re.findall(r"doi:(\S+)", text):
            assert re.fullmatch(r"10\.\d{4,5}/\S+", doi), doi


# ------------------------------------------------------------------ README.md
README = ROOT / "README.md"


def test_readme_is_short_and_its_commands_are_the_ones_that_run():
    """Under 150 lines; exactly two set-up commands (install + paper run, install +
    tests), the second the very line .ci/run executes; every local link and the
    figure exist; the first 60 lines hold both commands, the figure, the Python
    lines and the table of which method for what."""
    text = README.read_text(encoding="utf-8")
    lines = text.splitlines()
    assert len(lines) < 150, len(lines)
    setup = [ln for ln in lines if ln.startswith("python -m pip install")]
    assert setup == ["python -m pip install -e . && liethermo run paper",
                     "python -m pip install -e '.[test]' && python -m pytest -q"], setup
    assert setup[1] in (ROOT / ".ci" / "run").read_text().splitlines()
    first = "\n".join(lines[:60])
    for must in (setup[0], setup[1], "![", "liethermo.run(", "## Which method for what", "| a reference solution"):
        assert must in first, must
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", text):
        assert (ROOT / target).exists(), target


def test_readme_python_lines_run(tmp_path, monkeypatch):
    """The README's Python block, run as it stands in a fresh folder."""
    monkeypatch.chdir(tmp_path)
    code = re.search(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S).group(1)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    assert ns["ds"].attrs["method"] == "vi" and float(ns["err"].max()) < 1.0
    assert set(ns["runs"]) == {"vi", "rk2"}
    assert sorted(p.name for p in tmp_path.glob("paper*")) == [
        "paper.nc", "paper_center_of_mass.png", "paper_energies.png", "paper_entropy.png", "paper_rk2.nc",
        "paper_total_energy.png"]
    for d in ns["runs"].values():
        d.close()
    ns["ds"].close()


# ------------------------------------------------------------------ numbers of runs the docs quote
def test_coupled_egg_heating_is_quoted_as_its_run_gives_it(model_md):
    """coupled_egg's heating, start and end temperature and inertia growth, as its own run
    prints them, are the one set of numbers the scene, docs/api.md, docs/model.md and
    thermo.T0's description quote (T_0 = 300 K is not its starting temperature)."""
    from liethermo.runner import run_scene

    ds, summ = run_scene(load_scene("coupled_egg", {"output.attitude": False}), progress=False)
    f = summ.findings
    heating, start, end = f"{f['heating'][1]:.1f} K", f"{f['T_start'][1]:.1f} K", f"{f['T_end'][1]:.1f} K"
    growth = f"{f['inertia_change'][1]:.3g} %"
    assert (heating, start, end, growth) == ("19.0 K", "299.4 K", "318.4 K", "3.72 %")
    api_md = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    toml = (ROOT / "src" / "liethermo" / "scenes" / "coupled_egg.toml").read_text(encoding="utf-8")
    for doc in (api_md, model_md, toml):
        assert _quotes(doc, heating) and _quotes(doc, growth), doc[:80]
    for doc in (api_md, model_md, toml):
        assert _quotes(doc, start) and _quotes(doc, end)
    assert heating in builtin_scenes()["coupled_egg"] and growth in builtin_scenes()["coupled_egg"]
    t0 = next(k for k in KEYS if k.section == "thermo" and k.name == "T0")
    assert start in t0.doc and "initial temperature unless" in t0.doc


def test_api_md_accessor_example_prints_what_it_says():
    """The accessor example of docs/api.md, run as written: its printed sizes are the comment's."""
    import ast
    import contextlib
    import io

    api_md = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    block = next(b for b in re.findall(r"```python\n(.*?)```", api_md, re.S) if "band.sizes" in b)
    expected = re.search(r"print\(dict\(band\.sizes\)\)\s*# (\{.*\})", block).group(1)
    import liethermo

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(block, "docs/api.md", "exec"), {"liethermo": liethermo, "np": np})
    assert out.getvalue().splitlines()[-1] == str(ast.literal_eval(expected))


def test_scene_files_the_docs_run_are_shipped():
    """Every ``liethermo run FILE.toml`` in the README and docs/scenes.md (where a new
    user starts) names a shipped scene file that loads: the example of a scene of one's own."""
    named = set()
    for doc in [README, SCENES_MD]:
        named |= set(re.findall(r"liethermo run (\S+\.toml)", doc.read_text(encoding="utf-8")))
    assert "examples/my_scene.toml" in named
    for path in named:
        assert (ROOT / path).is_file(), path
        assert load_scene(str(ROOT / path)).name
