"""The variational integrator's energy error at t = 0: its start (the
paper's Ω₀ := Ω(0) as the first step velocity) puts it there, and the
summary, the figure, the variable's comment and the README say so where the
error is seen; a composition's step velocity is no paper's convention."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

import liethermo
from liethermo.top import plotting

ROOT = Path(__file__).resolve().parents[1]
SMALL = {"integrator.steps": 40, "output.compare": [], "output.figures": False}


def _summary(scene, overrides=None):
    """A run's dataset with its derived variables (the energies, from the stored state)."""
    return liethermo.run(scene, {**SMALL, **(overrides or {})}, compare=False).liethermo.derived()


def test_the_papers_start_is_named_where_its_error_at_t0_shows():
    ds = _summary("paper")
    e0 = abs(float(ds["energy_error"].values[0, 0])) / float(ds["mechanical_energy_initial"].values[0])
    assert 0.025 < e0 < 0.04  # the paper scene at h = 0.1 s: 3.1 % of E_mech,0
    text = ds.attrs["summary"]
    assert f"{e0:.3e} x E_mech,0 of it already at t = 0 (start 'node': Omega(0) is the first" in text
    for name in ("energy_error", "omega"):
        comment = ds[name].attrs["comment"]
        assert "start 'node' takes Omega(0) (the paper's start) as the first step velocity" in comment
        assert "energy_error is not 0" in comment and "docs/model.md, Starts" in comment
    # the default start begins from I Omega(0): nothing to explain
    ds = _summary("paper", {"integrator.start": "legendre"})
    assert ds["energy_error"].values[0, 0] == 0.0
    assert "at t = 0 (start" not in ds.attrs["summary"] and "start '" not in ds["energy_error"].attrs["comment"]


def test_a_composition_has_no_papers_convention_in_summary_or_figure(tmp_path, monkeypatch):
    ds = _summary("paper", {"integrator.method": "vi4"})
    assert "paper's convention" not in ds.attrs["summary"]
    assert "not the paper's quantity" in ds["energy_error_paper"].attrs["comment"]
    assert "paper's convention" in _summary("paper").attrs["summary"]  # vi has it

    seen = []
    real = plotting.legend_beside

    def spy(ax, *args, **kwargs):
        seen.append((ax, ax.get_legend_handles_labels()[1]))
        return real(ax, *args, **kwargs)

    monkeypatch.setattr(plotting, "legend_beside", spy)
    for method in ("vi4", "vi"):
        seen.clear()
        out = tmp_path / f"{method}.nc"
        liethermo.run("paper", {**SMALL, "integrator.method": method}, output=out, compare=False)
        plotting.scene_figures({method: out}, tmp_path, stem=method)
        (top_ax, top), (bottom_ax, bottom) = seen[-3], seen[-2]  # the total energy's two panels
        top_title, bottom_title = top_ax.get_title(), " ".join(bottom_ax.get_title().split())
        assert top_title.startswith("as in the paper") and bottom_title.startswith("over E_mech,0")
        drawn = any("paper's convention" in label for label in top + bottom)
        assert drawn == (method == "vi"), (method, top, bottom)
        assert ("at t = 0: start \"node\" takes Omega(0) as the first step velocity" in bottom_title
                ) == (method == "vi"), bottom_title


def test_the_readme_quotes_the_error_at_t0_the_run_gives():
    ds = _summary("paper")
    e0 = abs(float(ds["energy_error"].values[0, 0])) / float(ds["mechanical_energy_initial"].values[0])
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    said = re.search(r"The VI starts (\d+) % of E_mech,0 off at t = 0: the paper's start takes Ω\(0\) as its first "
                     r"step velocity", readme)
    assert said is not None and int(said.group(1)) == round(100 * e0)
    assert np.isfinite(e0)
