"""A run's summary states what its physics shows, chosen by the physics it
contains (not by the scene's name); its figures draw no panel the physics
leaves empty.

The numbers are checked against independent computations: the spherical
top's exact solution of conftest, the initial data's angle to the major axis,
the dataset's own temperature and momenta.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from conftest import OMEGA0, paper_numbers
from liethermo.top import plotting
from liethermo.top.findings import exact_spherical_top, merge_findings
from liethermo.top.model import ChunkStats
from liethermo.runner import run_scene
from liethermo.scene import load_scene


def _number(text: str, label: str) -> float:
    """The number printed right after ``label``."""
    m = re.search(re.escape(label) + r"\s*=?\s*([-+]?[0-9.]+(?:e[-+]?[0-9]+)?)", text)
    assert m, (label, text)
    return float(m.group(1))


def _run(scene, **over):
    ds, summ = run_scene(load_scene(scene, over), progress=False)
    return ds, "\n".join(summ.lines())


def test_exact_spherical_top_is_the_tests_own(spherical_top):
    st = spherical_top
    t = np.linspace(0.0, 20.0, 41)
    om, g, s = exact_spherical_top([st.I0], [st.c], [st.cv], [st.T0], st.omega0[None], st.gamma0[None], t)
    assert np.abs(om[0] - st.omega(t)).max() < 1e-15
    assert np.abs(g[0] - st.gamma(t)).max() < 1e-14
    assert np.abs(s[0] - st.sigma(t)).max() < 1e-13 * st.sigma(t[-1])
    # without friction: the free rotation, Γ turning about Ω₀ = w e₃ by −w t
    w = 2.0
    om, g, s = exact_spherical_top([1e-3], [0.0], [1.0], [300.0], np.array([[0.0, 0.0, w]]),
                                   np.array([[1.0, 0.0, 0.0]]), t)
    assert np.all(om[0] == [0.0, 0.0, w]) and np.all(s == 0.0)
    assert np.abs(g[0] - np.stack([np.cos(w * t), -np.sin(w * t), 0 * t], axis=-1)).max() < 1e-14


def test_spherical_top_summary_gives_its_error_against_the_exact_solution(spherical_top):
    """The printed errors are the dataset's against conftest's exact solution,
    and they fall as h² (the plain VI, legendre start)."""
    errs = []
    for h in (0.1, 0.05):
        ds, text = _run("spherical_top", **{"integrator.h": h, "integrator.steps": int(round(10.0 / h))})
        t = ds["t"].values
        om = ds["omega"].values[0]
        mine = np.abs(np.linalg.norm(om - spherical_top.omega(t), axis=-1)).max() / np.linalg.norm(spherical_top.omega0)
        gam = np.linalg.norm(ds["gamma"].values[0] - spherical_top.gamma(t), axis=-1).max()
        printed = _number(text, "|Omega - exact|/|Omega_0|")
        assert printed == pytest.approx(mine, rel=6e-3), text
        assert _number(text, "|Gamma - exact|") == pytest.approx(gam, rel=6e-3), text
        errs.append(printed)
    assert 3.5 < errs[0] / errs[1] < 4.5, errs
    assert errs[1] < 5e-4  # 2.3e-4 at h = 0.05 s


def test_paper_top_summary_gives_its_error_against_the_exact_omega3():
    """The paper's top is a Lagrange top: Ω₃(t) = Ω₃(0) e^{−ct/I₃} exactly
    (conftest's numbers); the summary's error is the dataset's against it."""
    d = paper_numbers()
    ds, text = _run("paper", **{"integrator.steps": 100, "output.compare": []})
    t = ds["t"].values
    om = ds["omega"].values[0]
    mine = np.abs(om[:, 2] - OMEGA0[2] * np.exp(-d["c"] * t / d["inertia"][2])).max() / np.linalg.norm(OMEGA0)
    assert _number(text, "max over the run |Omega_3 - exact|/|Omega_0|") == pytest.approx(mine, rel=6e-3), text
    assert 1e-3 < mine < 3e-2  # the paper's start and h: a first-order error


def test_findings_follow_the_physics_not_the_name():
    """The same physics under another name gets the same lines; the paper's
    top (gravity, a non-spherical inertia) gets no spherical-top line and no
    |mu| line but its exact Omega_3, and its friction line says "on every axis"."""
    _, a = _run("flat_spin", **{"integrator.steps": 300})
    _, b = _run("flat_spin", **{"integrator.steps": 300, "scene.name": "my_body"})
    lines = [ln for ln in a.splitlines() if "|mu|" in ln or "spin axis" in ln or "major axis" in ln]
    assert lines and all(ln in b for ln in lines)
    _, paper = _run("paper", **{"integrator.steps": 20})
    assert "exact solution" not in paper and "|mu|" not in paper and "spin axis" not in paper
    assert "exact Omega_3" in paper and "exact Omega_3" not in a  # flat_spin: internal friction
    assert re.search(r"Stokes friction +C = 0.0003142 N m s on every axis", paper), paper


def test_flat_spin_summary_keeps_mu_and_turns_to_the_major_axis():
    ds, text = _run("flat_spin")  # 30 s
    drift = _number(text, "||mu_k| - |mu_0||/|mu_0|")
    assert drift < 1e-13 and "kept to round-off" in text
    # Ω₀ = (6, 2, 1) against the major axis z (semi-axes 6, 5, 4 cm): acos(1/√41)
    assert "major axis (z, largest moment)" in text
    start = float(re.search(r"largest moment\): ([0-9.]+) deg at t = 0", text).group(1))
    assert start == pytest.approx(np.degrees(np.arccos(1.0 / np.sqrt(41.0))), abs=0.05)
    om = ds["omega"].values[0, -1]
    end = float(re.search(r"([0-9.e-]+) deg at t = 30 s", text).group(1))
    assert end == pytest.approx(np.degrees(np.arccos(abs(om[2]) / np.linalg.norm(om))), rel=1e-2)
    assert end < 1.0  # from 81 deg: a flat spin


def test_coupled_egg_summary_gives_heating_and_inertia_change():
    ds, text = _run("coupled_egg", **{"integrator.steps": 200})
    ds = ds.liethermo.derived()  # the temperature, from the stored state
    T = ds["temperature"].values[0]
    assert _number(text, "T(end) - T(0)") == pytest.approx(T[-1] - T[0], rel=1e-3)
    # I(S) = s I0: s = mu.Omega / Omega.I0 Omega, from the dataset's momenta
    mu, om, I0 = ds["angular_momentum"].values[0], ds["omega"].values[0], ds["inertia"].values  # stored once
    s = np.sum(mu * om, axis=-1) / np.sum(I0 * om * om, axis=-1)
    change = _number(text, "I(S_end) - I(S_0)")
    assert change == pytest.approx(100.0 * (s[-1] / s[0] - 1.0), rel=1e-2)
    assert change > 0.5  # the scene's point: a visible growth of the inertia


def test_ellipsoid_summary_gives_its_friction_tensor():
    ds, text = _run("ellipsoid", **{"integrator.steps": 10})
    C, I0 = ds["friction_coefficients"].values, ds["inertia"].values  # every member's: stored once
    m = re.search(r"Stokes friction tensor +C = diag\(([^)]*)\) N m s", text)
    assert m, text
    assert np.allclose([float(x) for x in m.group(1).split(",")], C, rtol=1e-3)
    assert len(set(np.round(C, 8))) == 3  # Jeffery's C of a triaxial body differs per axis
    tau = re.search(r"decay times I_i/C_i = ([^s]*) s", text).group(1)
    assert np.allclose([float(x) for x in tau.split(",")], I0 / C, rtol=5e-3)


def test_newton_line_says_per_solve_and_per_step():
    ds, text = _run("spherical_top", **{"integrator.method": "vi4", "integrator.steps": 20})
    per_step = float(ds["newton_iterations_mean"].values[0])
    m = re.search(r"Newton iterations +mean ([0-9.]+) per solve \(([0-9.]+) per step of 5 solves\), "
                  r"max (\d+) in one solve", text)
    assert m, text
    assert float(m.group(2)) == pytest.approx(per_step, abs=0.006)
    assert float(m.group(1)) == pytest.approx(per_step / 5, abs=0.006)
    assert int(m.group(3)) == int(ds["newton_iterations_max"].values[0]) <= per_step


def test_findings_merge_over_chunks_and_survive_a_journal():
    a = ChunkStats(findings={"heating": [1.0, 2.0], "mu_drift": [0.0, 1e-16]})
    b = ChunkStats.from_dict(json.loads(json.dumps(ChunkStats(findings={"heating": [0.5, 1.5]}).to_dict())))
    a.merge(b)
    assert a.findings == {"heating": [0.5, 2.0], "mu_drift": [0.0, 1e-16]}
    assert merge_findings({}, {"x": [1.0, 1.0]}) == {"x": [1.0, 1.0]}


def test_gravity_free_scene_draws_no_potential_energy_panel(tmp_path, monkeypatch):
    out = tmp_path / "f.nc"
    run_scene(load_scene("flat_spin", {"integrator.steps": 50}), out, progress=False)
    ylabels = {}
    save = plotting._save

    def record(fig, path, **kw):
        ylabels[path.name] = [ax.get_ylabel() for ax in fig.axes]
        return save(fig, path, **kw)

    monkeypatch.setattr(plotting, "_save", record)
    plotting.scene_figures({"vi": out}, tmp_path, stem="f")
    assert ylabels["f_energies.png"] == ["kinetic K (mJ)", "internal U - U0 (mJ)"]
